"""SerialKheperaLink over a scripted transport: replies in pieces, noise, retries, a vanished port.

The transport is a small serial-like object that answers each written
command with the byte chunks a test scripts, so every read boundary is
chosen by the test. (The same behaviour over a real pty is in
test_bridge_emulator.py.)
"""

from __future__ import annotations

from collections import deque

import pytest
import serial

from services.bridge import protocol as P
from services.bridge.link import LinkError, LinkOffline, LinkOptions, LinkTimeout, SerialKheperaLink


class ScriptedPort:
    """Each write pops the next script entry: the chunks to make readable, one per read."""

    def __init__(self, *script: list[bytes]) -> None:
        self.script = deque(script)
        self.written: list[bytes] = []
        self.chunks: deque[bytes] = deque()
        self.gone = False
        self.closed = False

    def write(self, data: bytes, /) -> int:
        if self.gone:
            raise serial.SerialException("write failed: [Errno 5] Input/output error")
        self.written.append(data)
        if self.script:
            self.chunks.extend(self.script.popleft())
        return len(data)

    def read(self, size: int = 1, /) -> bytes:
        if self.gone:
            raise serial.SerialException("device reports readiness to read but returned no data")
        if not self.chunks:
            return b""  # a read timeout
        chunk = self.chunks.popleft()
        if len(chunk) > size:
            self.chunks.appendleft(chunk[size:])
            chunk = chunk[:size]
        return chunk

    @property
    def in_waiting(self) -> int:
        # Only the current chunk counts as arrived: the next one is a later read.
        return len(self.chunks[0]) if self.chunks else 0

    def close(self) -> None:
        self.closed = True


FAST = LinkOptions(reply_timeout=0.05)


def test_reply_split_across_many_reads() -> None:
    port = ScriptedPort([b"n,12,", b"0,3,10", b"23,40,0,0,", b"7\r", b"\n"])
    link = SerialKheperaLink(port, FAST)
    assert link.request(P.read_proximity()) == P.SensorArray((12, 0, 3, 1023, 40, 0, 0, 7))
    assert port.written == [b"N\r"]


def test_banner_noise_and_stale_replies_are_skipped() -> None:
    banner = b"\r\nROM of minirobot KHEPERA Version 5.02 Rev. 5.01\r\n"
    port = ScriptedPort([banner, b"\xfe#noise\r\n", b"e,1,2\r\n", b"garbage\r\n", b"h,5,6\r\n"])
    link = SerialKheperaLink(port, FAST)
    assert link.request(P.read_counters()) == P.WheelPair(5, 6)
    assert link.stats.banners == 1 and link.stats.skipped_lines == 3 and link.stats.retries == 0


def test_timeout_then_retry_succeeds() -> None:
    port = ScriptedPort([], [b"d\r\n"])
    link = SerialKheperaLink(port, FAST)
    assert link.request(P.set_speed(1, 1)) == P.ACK
    assert port.written == [b"D,1,1\r", b"D,1,1\r"] and link.stats.retries == 1


def test_malformed_reply_is_retried_then_reported() -> None:
    port = ScriptedPort([b"n,1,2\r\n"], [b"n,1\r\n"], [b"n,x\r\n"])
    link = SerialKheperaLink(port, FAST)
    with pytest.raises(LinkError, match="no valid reply to 'N' after 3 tries"):
        link.request(P.read_proximity())
    assert len(port.written) == 3 and link.stats.malformed == 3


def test_no_reply_at_all_is_a_timeout() -> None:
    link = SerialKheperaLink(ScriptedPort(), FAST)
    with pytest.raises(LinkTimeout, match="no reply to 'B' after 3 tries"):
        link.request(P.read_version())


@pytest.mark.parametrize("answer", [b"Command not found\r\n", b"z,Command not found\r\n"])
def test_command_not_found_is_typed(answer: bytes) -> None:
    link = SerialKheperaLink(ScriptedPort([answer], [answer], [answer]), FAST)
    with pytest.raises(P.CommandNotFound, match="does not know command 'X'"):
        link.request(P.raw("X"))


def test_vanished_port_is_offline_and_stays_closed() -> None:
    port = ScriptedPort()
    port.gone = True
    link = SerialKheperaLink(port, FAST)
    with pytest.raises(LinkOffline, match="port lost"):
        link.request(P.read_version())
    assert link.closed and port.closed
    with pytest.raises(LinkOffline, match="closed"):
        link.request(P.read_version())


def test_overlong_noise_without_line_end_is_dropped() -> None:
    port = ScriptedPort([b"x" * 300, b"\r\nb,5.02,5.01\r\n"])
    link = SerialKheperaLink(port, FAST)
    assert link.request(P.read_version()) == P.Version("5.02", "5.01")
