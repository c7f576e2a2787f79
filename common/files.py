"""Files written so that an acknowledged write survives a crash or a power cut.

``write_atomic`` replaces a file whole (a reader sees the old or the new, never
half); ``Journal`` appends records and syncs each before it returns, and reads
back every whole record, ignoring a tail torn by a crash mid-append.
"""

from __future__ import annotations

import os
import struct
import threading
from collections.abc import Iterator
from pathlib import Path

_LENGTH = struct.Struct(">I")
MAX_RECORD = 1 << 20


def fsync_dir(directory: Path) -> None:
    """Make a rename or a new file in ``directory`` durable."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomic(path: Path, data: bytes, *, durable: bool = True, mode: int | None = None) -> None:
    """Replace ``path`` with ``data``: written to a temporary file, synced, renamed, synced.

    ``durable=False`` skips both syncs, for a file rewritten many times a second
    whose readers need it whole, never that it outlives a crash. ``mode`` (0o600
    for keys and students' code): the file's permissions from its first byte, so
    that no other account can read it between its writing and a chmod after.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    # a name of its own per writer: two threads saving at once must not share a temp file
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC
    fd = os.open(tmp, flags, 0o666 if mode is None else mode)
    with open(fd, "wb") as out:
        if mode is not None:
            os.fchmod(out.fileno(), mode)  # a temp file left by a crash had its own mode
        out.write(data)
        if durable:
            out.flush()
            os.fsync(out.fileno())
    os.replace(tmp, path)
    if durable:
        fsync_dir(path.parent)


class Journal:
    """An append-only file of length-prefixed records, each synced before ``append`` returns."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def append(self, record: bytes) -> None:
        if len(record) > MAX_RECORD:
            raise ValueError(f"a journal record is at most {MAX_RECORD} bytes")
        new = not self.path.exists()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "ab") as out:
            out.write(_LENGTH.pack(len(record)) + record)
            out.flush()
            os.fsync(out.fileno())
        if new:
            fsync_dir(self.path.parent)

    def records(self) -> Iterator[bytes]:
        """Every whole record, oldest first (a torn last record, from a crash, is skipped)."""
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            return
        at = 0
        while at + _LENGTH.size <= len(data):
            (size,) = _LENGTH.unpack_from(data, at)
            if size > MAX_RECORD or at + _LENGTH.size + size > len(data):
                return
            yield data[at + _LENGTH.size : at + _LENGTH.size + size]
            at += _LENGTH.size + size

    def restart(self, first: bytes) -> None:
        """Replace the journal by one holding only ``first``."""
        write_atomic(self.path, _LENGTH.pack(len(first)) + first)
