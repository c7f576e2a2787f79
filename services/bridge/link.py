"""SerialKheperaLink: one request at a time over a serial port, the host pattern every client uses.

Write the command, reassemble reply lines from partial reads, skip (and log)
lines that do not answer it (the reset banner, noise, stale replies), check
the reply, and on a timeout or a malformed reply drain the input and retry;
after ``tries`` attempts raise a clear error. A port that vanished (the robot
was unplugged) raises :class:`LinkOffline` and the link stays closed: the
robot handle (robot.py) reopens the port when it comes back.

The transport is any serial-like object (:class:`SerialLike`), so unit tests
can feed split bytes; :meth:`SerialKheperaLink.open` makes a pyserial port with the
robot's framing (8 data bits, no parity, 2 stop bits).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, TypeVar, cast

import serial

from services.bridge.protocol import (
    DEFAULT_DIALECT,
    MAX_LINE,
    CommandNotFound,
    Dialect,
    MalformedReply,
    ProtocolError,
    Request,
    classify_line,
    split_reply,
)

log = logging.getLogger("wart.bridge.link")

T = TypeVar("T")

BAUD_RATES = (9600, 19200, 38400)


class SerialLike(Protocol):
    """What the link needs of a port (pyserial's Serial has all of it)."""

    def write(self, data: bytes, /) -> int | None: ...
    def read(self, size: int = 1, /) -> bytes: ...
    @property
    def in_waiting(self) -> int: ...
    def close(self) -> None: ...


class LinkError(ProtocolError):
    """The request could not be completed (no valid answer after every try)."""


class LinkTimeout(LinkError):
    """No reply to the command within the timeout, on every try."""


class LinkOffline(LinkError):
    """The port is gone (unplugged, closed) or could not be opened."""


@dataclass(frozen=True)
class LinkOptions:
    """Timing and retry policy: the usual host pattern (docs/KHEPERA_PROTOCOL.md)."""

    reply_timeout: float = 0.3  # seconds to wait for the reply line of one try
    tries: int = 3
    read_slice: float = 0.02  # pyserial read timeout: how often a waiting read wakes up
    dialect: Dialect = DEFAULT_DIALECT

    def __post_init__(self) -> None:
        if not 0.01 <= self.reply_timeout <= 10:
            raise ValueError(f"reply_timeout {self.reply_timeout} s out of range 0.01..10")
        if not 1 <= self.tries <= 10:
            raise ValueError(f"tries {self.tries} out of range 1..10")


@dataclass
class LinkStats:
    requests: int = 0
    retries: int = 0
    timeouts: int = 0
    malformed: int = 0
    skipped_lines: int = 0
    banners: int = 0  # reset banners seen: the robot rebooted, its counters restarted


@dataclass
class _Outcome:
    """What one try produced: a decoded value, or why not."""

    value: object = None
    error: str = "no reply"
    not_found: bool = False


class SerialKheperaLink:
    """Thread-safe request/reply over one port. ``request`` returns the typed result."""

    def __init__(
        self,
        transport: SerialLike,
        options: LinkOptions | None = None,
        *,
        name: str = "khepera",
        on_banner: Callable[[str], None] | None = None,
    ) -> None:
        self._port = transport
        self.options = options or LinkOptions()
        self.name = name
        self.stats = LinkStats()
        self._on_banner = on_banner
        self._lock = threading.Lock()
        self._buf = bytearray()
        self._closed = False

    @classmethod
    def open(
        cls,
        port: str,
        baud: int = 38400,
        options: LinkOptions | None = None,
        *,
        on_banner: Callable[[str], None] | None = None,
    ) -> SerialKheperaLink:
        """Open ``port`` with the robot's framing; LinkOffline if it is missing or busy."""
        if baud not in BAUD_RATES:
            raise ValueError(f"baud {baud} is not one the Khepera supports {BAUD_RATES}")
        opts = options or LinkOptions()
        try:
            ser = serial.Serial(
                port,
                baudrate=baud,
                bytesize=serial.EIGHTBITS,
                parity=serial.PARITY_NONE,
                stopbits=serial.STOPBITS_TWO,
                timeout=opts.read_slice,
                write_timeout=1.0,
                xonxoff=False,
                rtscts=False,
                exclusive=True,
            )
        except (serial.SerialException, OSError) as exc:
            raise LinkOffline(f"{port}: cannot open: {exc}") from exc
        return cls(ser, opts, name=port, on_banner=on_banner)

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        with self._lock:
            self._close_locked()

    def _close_locked(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._port.close()
        except (serial.SerialException, OSError) as exc:
            log.debug("%s: close: %s", self.name, exc)

    # ------------------------------------------------------------ requests

    def request(self, req: Request[T]) -> T:
        """Send ``req``, return its decoded reply (else LinkError, CommandNotFound, LinkOffline)."""
        with self._lock:
            if self._closed:
                raise LinkOffline(f"{self.name}: link is closed")
            self.stats.requests += 1
            try:
                return self._request_locked(req)
            except (serial.SerialException, OSError) as exc:
                # pyserial reports a vanished device as a read/write failure (EIO on
                # a hung-up tty, "readiness to read but returned no data").
                self._close_locked()
                raise LinkOffline(f"{self.name}: port lost: {exc}") from exc

    def _request_locked(self, req: Request[T]) -> T:
        wire = req.encode(self.options.dialect)
        last = "no reply"
        not_found = 0
        for attempt in range(self.options.tries):
            if attempt:
                self.stats.retries += 1
            # Whatever is already waiting is not ours (a late reply to an earlier
            # try, a banner): read it out so it cannot be mistaken for the answer.
            self._drain()
            self._port.write(wire)
            outcome = self._await_reply(req)
            if outcome.value is not None:
                return cast(T, outcome.value)
            last = outcome.error
            if outcome.not_found:
                not_found += 1
        what = wire.rstrip().decode("ascii", "replace")
        if not_found == self.options.tries:
            raise CommandNotFound(f"{self.name}: robot does not know command {what!r}")
        if last == "no reply":
            raise LinkTimeout(
                f"{self.name}: no reply to {what!r} after {self.options.tries} tries "
                f"of {self.options.reply_timeout:.2f} s"
            )
        raise LinkError(
            f"{self.name}: no valid reply to {what!r} after {self.options.tries} tries: {last}"
        )

    def _await_reply(self, req: Request[T]) -> _Outcome:
        deadline = time.monotonic() + self.options.reply_timeout
        dialect = self.options.dialect
        while True:
            line = self._read_line(deadline)
            if line is None:
                self.stats.timeouts += 1
                return _Outcome()
            kind = classify_line(line, dialect)
            if kind == "not_found":
                return _Outcome(error=f"robot says {line!r}", not_found=True)
            if kind == "banner":
                self.stats.banners += 1
                log.warning("%s: robot reset banner: %r", self.name, line)
                if self._on_banner is not None:
                    self._on_banner(line)
                continue
            if kind == "reply":
                reply = split_reply(line)
                if reply.letter != req.reply_letter:
                    self._skip(
                        line, f"stale or foreign reply while waiting for {req.reply_letter!r}"
                    )
                    continue
                try:
                    return _Outcome(value=req.decode(reply))
                except MalformedReply as exc:
                    self.stats.malformed += 1
                    log.warning("%s: bad reply %r: %s", self.name, line, exc)
                    return _Outcome(error=str(exc))
            self._skip(line, "noise")

    def _skip(self, line: str, why: str) -> None:
        self.stats.skipped_lines += 1
        log.info("%s: skipped line (%s): %r", self.name, why, line)

    # ------------------------------------------------------------ bytes to lines

    def _read_line(self, deadline: float) -> str | None:
        """The next non-empty line (CR, LF or both end it) or None at the deadline."""
        while True:
            line = self._pop_line()
            if line is not None:
                if line:
                    return line
                continue
            if time.monotonic() >= deadline:
                return None
            chunk = self._port.read(1)  # blocks at most read_slice
            if chunk:
                waiting = self._port.in_waiting
                if waiting:
                    chunk += self._port.read(waiting)
                self._buf += chunk
                if len(self._buf) > MAX_LINE and not any(b in self._buf for b in b"\r\n"):
                    # A run of bytes with no line end is noise; keep memory bounded.
                    self._skip(self._buf[:40].decode("ascii", "replace") + "...", "overlong")
                    self._buf.clear()

    def _pop_line(self) -> str | None:
        for i, byte in enumerate(self._buf):
            if byte in (0x0D, 0x0A):
                raw = bytes(self._buf[:i])
                del self._buf[: i + 1]
                return raw.decode("ascii", "replace").strip()
        return None

    def _drain(self) -> None:
        pending = self._port.in_waiting
        if pending:
            self._buf += self._port.read(pending)
        while (line := self._pop_line()) is not None:
            if not line:
                continue
            if classify_line(line, self.options.dialect) == "banner":
                self.stats.banners += 1
                log.warning("%s: robot reset banner: %r", self.name, line)
                if self._on_banner is not None:
                    self._on_banner(line)
            else:
                self._skip(line, "unsolicited")
        if self._buf:
            self._skip(self._buf.decode("ascii", "replace"), "partial line dropped")
            self._buf.clear()
