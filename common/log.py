"""Logging set-up shared by every process: plain words, one line per event, bounded.

Two things keep a flood from filling the disk: a repeated message is printed a
few times, then counted and summarised once per window ("412 more like this in
the last 10 s"), and the files the supervisor writes children's output to
rotate at a size cap (:class:`RotatingFile`).
"""

from __future__ import annotations

import logging
import logging.handlers
import os
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import zenoh

SUMMARY_WINDOW_S = 10.0
FIRST_IN_WINDOW = 5  # occurrences of one message printed in full per window
LOG_FILE_MAX_BYTES = 10 * 1024 * 1024
LOG_FILE_BACKUPS = 3


@dataclass
class _Window:
    start: float
    count: int
    last: logging.LogRecord


class RepeatSummary(logging.Filter):
    """Lets the first few records of one kind through per window, then counts the rest.

    A record's kind is its logger, level and message template (before the
    arguments are put in), so "dropped a message on %s: %s" is one kind
    whatever key or reason fills it. At the end of a window in which records
    were held back, one line says how many and of what kind.
    """

    def __init__(self, window_s: float = SUMMARY_WINDOW_S, first: int = FIRST_IN_WINDOW) -> None:
        super().__init__()
        self.window_s = window_s
        self.first = first
        self._lock = threading.Lock()
        self._kinds: dict[tuple[str, int, str], _Window] = {}
        self.suppressed = 0

    def filter(self, record: logging.LogRecord) -> bool:
        if getattr(record, "summary", False):
            return True
        kind = (record.name, record.levelno, str(record.msg))
        now = time.monotonic()
        with self._lock:
            window = self._kinds.get(kind)
            if window is None or now - window.start >= self.window_s:
                self._kinds[kind] = _Window(now, 1, record)
                if window is not None and window.count > self.first:
                    self._summarise(kind, window.count - self.first, window.last)
                if len(self._kinds) > 10_000:  # many kinds: forget the quiet ones
                    self._forget(now)
                return True
            window.count += 1
            window.last = record
            if window.count <= self.first:
                return True
            self.suppressed += 1
            return False

    def flush(self) -> None:
        """Summarise every window that has ended with records held back."""
        now = time.monotonic()
        with self._lock:
            for kind, window in list(self._kinds.items()):
                if now - window.start >= self.window_s and window.count > self.first:
                    self._summarise(kind, window.count - self.first, window.last)
                    window.count = self.first

    def _forget(self, now: float) -> None:
        for kind, window in list(self._kinds.items()):
            if now - window.start >= self.window_s and window.count <= self.first:
                del self._kinds[kind]

    def _summarise(self, kind: tuple[str, int, str], held: int, last: logging.LogRecord) -> None:
        name, level, _ = kind
        logging.getLogger(name).log(
            level,
            "%d more like this in the last %.0f s (last: %s)",
            held,
            self.window_s,
            last.getMessage()[:300],
            extra={"summary": True},
        )


class StderrHandler(logging.StreamHandler):
    """Writes to ``sys.stderr`` as it is when a record comes, not as it was at set-up.

    A command run inside another program (a test calls a CLI's ``main``) sets up
    logging while that program has put its own stream in ``sys.stderr``; a thread
    that logs after the stream was given back and closed must not fail on it.
    """

    def __init__(self) -> None:
        super().__init__(sys.stderr)

    @property
    def stream(self) -> object:
        return sys.stderr

    @stream.setter
    def stream(self, _value: object) -> None:
        pass


_summary: RepeatSummary | None = None


def setup_logging(level: str | None = None) -> RepeatSummary:
    """Log to stderr as ``time level name: message``; WART_LOG_LEVEL or --log-level sets it.

    WART_LOG_SUMMARY_S sets the summary window (default 10 s); tests shorten it
    so a flood's summary line comes out without a 10-15 s wait.
    """
    global _summary
    chosen = (level or os.environ.get("WART_LOG_LEVEL") or "INFO").upper()
    logging.basicConfig(
        level=getattr(logging, chosen, logging.INFO),
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
        handlers=[StderrHandler()],
        force=True,
    )
    if _summary is None:
        _summary = RepeatSummary(window_s=_summary_window())
        threading.Thread(target=_flush_forever, args=(_summary,), daemon=True).start()
    for handler in logging.getLogger().handlers:
        handler.addFilter(_summary)
    # Zenoh's own Rust logs are noisy at info; show only its errors unless RUST_LOG says more.
    zenoh.init_log_from_env_or(ZENOH_LOG_FILTER)
    return _summary


def log_to_file(
    name: str, path: Path, terminal_level: int = logging.ERROR
) -> logging.handlers.RotatingFileHandler:
    """Logger ``name`` (and those under it) to its own rotating file, like a child's log.

    For a service that runs inside another process (``wart up``'s host "local"): its
    lines (a refused request, a fuzzer's junk) go to the file; the terminal it shares
    with the operator gets only ``terminal_level`` and above, what they must act on.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    file = logging.handlers.RotatingFileHandler(
        path, maxBytes=LOG_FILE_MAX_BYTES, backupCount=LOG_FILE_BACKUPS, encoding="utf-8"
    )
    terminal = logging.StreamHandler(sys.stderr)
    terminal.setLevel(terminal_level)
    for handler in (file, terminal):
        handler.setFormatter(
            logging.Formatter("%(asctime)s %(levelname)-7s %(name)s: %(message)s", "%H:%M:%S")
        )
        if _summary is not None:
            handler.addFilter(_summary)
    logger = logging.getLogger(name)
    for old in list(logger.handlers):  # a second start in one process (tests)
        logger.removeHandler(old)
        old.close()
    logger.addHandler(file)
    logger.addHandler(terminal)
    logger.propagate = False
    return file


# Errors only, but not zenoh's "Unknown token id=0" from a client's token routing:
# zenoh 1.x logs it at ERROR when a peer froze or left or a service restarted, and
# nothing we watch changes with it (tokens, queries and puts carried on). It showed
# in 52 logs of the kept test runs, and on a student's terminal under `wart deploy`
# when a world froze for 5 s. RUST_LOG still overrides the whole filter.
ZENOH_LOG_FILTER = "error,zenoh::net::routing::hat::client::token=off"


def _summary_window() -> float:
    raw = os.environ.get("WART_LOG_SUMMARY_S")
    if not raw:
        return SUMMARY_WINDOW_S
    try:
        window = float(raw)
    except ValueError:
        window = float("nan")
    if 0.1 <= window <= 3600.0:
        return window
    logging.getLogger("wart.log").warning(
        "WART_LOG_SUMMARY_S=%r is not a number of seconds between 0.1 and 3600: "
        "repeated lines are summarised every %g s",
        raw,
        SUMMARY_WINDOW_S,
    )
    return SUMMARY_WINDOW_S


def _flush_forever(summary: RepeatSummary) -> None:
    while True:
        time.sleep(summary.window_s / 2)
        summary.flush()


class RotatingFile:
    """An append-only log file that rotates at ``max_bytes`` (``.1`` ... ``.N`` kept).

    The supervisor writes each child's output through one, so a child that
    floods its output cannot fill the disk: at most (backups + 1) × max_bytes.
    """

    def __init__(
        self, path: Path, max_bytes: int = LOG_FILE_MAX_BYTES, backups: int = LOG_FILE_BACKUPS
    ) -> None:
        if max_bytes < 1024 or backups < 1:
            raise ValueError("a rotating log needs max_bytes >= 1024 and at least one backup")
        self.path, self.max_bytes, self.backups = path, max_bytes, backups
        self._lock = threading.Lock()
        self._file = open(path, "ab")  # noqa: SIM115 - held for the writer's lifetime
        self._size = self._file.tell()

    def write(self, data: bytes) -> None:
        with self._lock:
            while data:
                room = self.max_bytes - self._size
                if room <= 0:
                    self._rotate()
                    room = self.max_bytes
                part, data = data[:room], data[room:]
                self._file.write(part)
                self._size += len(part)
            self._file.flush()

    def _rotate(self) -> None:
        self._file.close()
        for i in range(self.backups - 1, 0, -1):
            older = self.path.with_name(f"{self.path.name}.{i}")
            if older.exists():
                older.replace(self.path.with_name(f"{self.path.name}.{i + 1}"))
        self.path.replace(self.path.with_name(f"{self.path.name}.1"))
        self._file = open(self.path, "ab")  # noqa: SIM115
        self._size = 0

    def close(self) -> None:
        with self._lock:
            self._file.close()


def pump(source: int, sink: RotatingFile) -> None:
    """Copy a child's output (a pipe's file descriptor) into ``sink`` until it closes."""
    try:
        while True:
            chunk = os.read(source, 65536)
            if not chunk:
                return
            sink.write(chunk)
    except OSError:
        return
    finally:
        os.close(source)
