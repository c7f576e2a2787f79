"""Bounded traffic with a sandboxed child: reads never buffer more than a line's
limit, writes never block.

A child that prints without a newline must not grow the runner (a plain
``for line in pipe`` reads the whole "line" before anyone can look at its
length), and a child that stops reading must not stall the runner (a blocking
write to a full pipe waits for the child forever).
"""

from __future__ import annotations

import errno
import os
import select
import time
from collections.abc import Callable, Iterator

CHUNK = 64 * 1024
PIPE_BUF = select.PIPE_BUF


def read_lines(
    fd: int, max_line: int, on_bytes: Callable[[int], None] = lambda n: None
) -> Iterator[tuple[bytes, bool]]:
    """Yield ``(line, cut)`` from ``fd`` until EOF, each line at most ``max_line`` bytes.

    A longer line is cut: its first ``max_line`` bytes come with ``cut=True``
    and the rest, up to the next newline, is read and dropped. ``on_bytes``
    hears the size of every chunk read, dropped or not.
    """
    held = bytearray()
    skipping = False
    while True:
        try:
            chunk = os.read(fd, CHUNK)
        except InterruptedError:
            continue
        if not chunk:
            if held and not skipping:
                yield bytes(held), False
            return
        on_bytes(len(chunk))
        start = 0
        while start < len(chunk):
            end = chunk.find(b"\n", start)
            piece = chunk[start:] if end < 0 else chunk[start:end]
            start = len(chunk) if end < 0 else end + 1
            if skipping:
                skipping = end < 0
                continue
            room = max_line - len(held)
            if len(piece) > room:
                held += piece[:room]
                yield bytes(held), True
                held.clear()
                skipping = end < 0
            elif end < 0:
                held += piece
            else:
                held += piece
                yield bytes(held), False
                held.clear()


def write_nowait(fd: int, data: bytes) -> bool:
    """Write all of ``data`` to a non-blocking pipe now, or nothing; False if it is full.

    A pipe writes up to PIPE_BUF bytes in one piece or not at all, so a line
    is never cut in two by a full pipe. Raises OSError if the pipe is closed.
    """
    if len(data) > PIPE_BUF:
        raise ValueError(f"a message to the sandbox is limited to {PIPE_BUF} bytes")
    try:
        os.write(fd, data)
        return True
    except BlockingIOError:
        return False
    except OSError as exc:
        if exc.errno == errno.EAGAIN:
            return False
        raise


class RateBudget:
    """A token bucket: ``rate`` units per second, bursts up to ``burst`` (one second's worth)."""

    def __init__(self, rate: float, burst: float | None = None) -> None:
        self.rate = float(rate)
        self.capacity = float(burst if burst is not None else rate)
        self.tokens = self.capacity
        self.stamp = time.monotonic()

    def take(self, amount: float = 1.0) -> bool:
        now = time.monotonic()
        self.tokens = min(self.capacity, self.tokens + (now - self.stamp) * self.rate)
        self.stamp = now
        if self.tokens >= amount:
            self.tokens -= amount
            return True
        return False
