"""Logs stay bounded: repeats are summarised, files rotate, crash loops back off."""

from __future__ import annotations

import io
import logging
import os
import sys
import threading
from pathlib import Path

import pytest

from common.log import (
    SUMMARY_WINDOW_S,
    RepeatSummary,
    RotatingFile,
    _summary_window,
    pump,
    setup_logging,
)
from services.lab.supervisor import BACKOFF_FIRST, BACKOFF_MAX, next_backoff


class Collect(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


@pytest.mark.parametrize(
    ("raw", "window"),
    [(None, SUMMARY_WINDOW_S), ("2", 2.0), ("soon", SUMMARY_WINDOW_S), ("0", SUMMARY_WINDOW_S)],
)
def test_the_summary_window_comes_from_the_environment_or_the_default(
    monkeypatch: pytest.MonkeyPatch, raw: str | None, window: float
) -> None:
    if raw is None:
        monkeypatch.delenv("WART_LOG_SUMMARY_S", raising=False)
    else:
        monkeypatch.setenv("WART_LOG_SUMMARY_S", raw)
    assert _summary_window() == window


def test_a_bad_summary_window_is_said_in_the_log(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setenv("WART_LOG_SUMMARY_S", "ten")
    with caplog.at_level(logging.WARNING, logger="wart.log"):
        assert _summary_window() == SUMMARY_WINDOW_S
    assert "WART_LOG_SUMMARY_S='ten' is not a number of seconds" in caplog.text


def test_a_repeated_warning_is_printed_a_few_times_then_counted() -> None:
    summary = RepeatSummary(window_s=60.0, first=3)
    sink = Collect()
    sink.addFilter(summary)
    log = logging.getLogger("test.flood")
    log.addHandler(sink)
    log.propagate = False
    try:
        for i in range(20_000):
            log.warning("dropped a message on %s: %s", f"key/{i % 7}", "not authenticated")
        log.warning("another kind of message")
        assert len(sink.lines) == 4  # 3 of the flood, 1 of the other kind
        assert summary.suppressed == 19_997
        summary.window_s = 0.0  # the window is over: the count comes out once
        summary.flush()
        assert sink.lines[-1].startswith("19997 more like this in the last 0 s (last: dropped")
        summary.flush()
        assert len(sink.lines) == 5  # said once, not again
    finally:
        log.removeHandler(sink)


def test_rotating_file_keeps_at_most_its_cap(tmp_path: Path) -> None:
    path = tmp_path / "engine.log"
    out = RotatingFile(path, max_bytes=4096, backups=2)
    for i in range(1000):
        out.write(f"line {i} {'x' * 50}\n".encode())
    out.close()
    files = sorted(tmp_path.iterdir())
    assert [f.name for f in files] == ["engine.log", "engine.log.1", "engine.log.2"]
    assert sum(f.stat().st_size for f in files) <= 3 * 4096
    assert path.read_text().rstrip().endswith("x" * 50)  # the newest lines are in the live file
    assert "line 999 " in path.read_text()


def test_pump_copies_a_pipe_into_the_rotating_file(tmp_path: Path) -> None:
    read_end, write_end = os.pipe()
    sink = RotatingFile(tmp_path / "child.log", max_bytes=2048, backups=1)
    thread = threading.Thread(target=pump, args=(read_end, sink))
    thread.start()
    os.write(write_end, b"y" * 100_000)  # a flood with no newline at all
    os.close(write_end)
    thread.join(5)
    assert not thread.is_alive()
    sizes = [p.stat().st_size for p in tmp_path.iterdir()]
    assert sum(sizes) <= 2 * 2048


def test_rotating_file_refuses_silly_limits(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="max_bytes"):
        RotatingFile(tmp_path / "x.log", max_bytes=10)


def test_first_restart_is_immediate_and_a_crash_loop_backs_off() -> None:
    waits = [BACKOFF_FIRST]
    for _ in range(10):
        waits.append(next_backoff(waits[-1]))
    assert waits[:6] == [0.1, 0.5, 1.0, 2.0, 4.0, 8.0]
    assert waits[-1] == BACKOFF_MAX


def test_a_log_line_after_the_stderr_it_was_set_up_with_was_closed_still_comes_out(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A command run inside another program (a test calling a CLI's main) sets up logging
    while sys.stderr is that program's stream; a thread of it logs after the stream is
    closed: the line goes to the stderr of now, not into "--- Logging error ---"."""
    root = logging.getLogger()
    saved = (root.handlers[:], root.level)
    borrowed, now = io.StringIO(), io.StringIO()
    try:
        monkeypatch.setattr(sys, "stderr", borrowed)
        setup_logging("INFO")
        logging.getLogger("wart.test").info("while borrowed")
        borrowed.close()
        monkeypatch.setattr(sys, "stderr", now)
        monkeypatch.setattr(logging, "raiseExceptions", True)
        logging.getLogger("wart.test").info("after it was closed")
    finally:
        root.handlers[:] = saved[0]
        root.setLevel(saved[1])
    assert "wart.test: after it was closed" in now.getvalue()
    assert "Logging error" not in now.getvalue()
