"""A part's background thread: it ends on stop, starts again, and a stuck one is named."""

from __future__ import annotations

import logging
import threading

import pytest

from common.worker import Worker


def test_stop_wakes_the_loop_joins_it_and_a_start_runs_it_again() -> None:
    rounds: list[int] = []
    wake = threading.Event()

    def loop() -> None:
        while not worker.stopping.is_set():
            rounds.append(1)
            wake.wait(60)  # asleep on something else: only the wake ends this
            wake.clear()

    worker = Worker(loop, "test-loop", wake=wake.set)
    worker.start()
    worker.start()  # running: not a second thread
    assert worker.stop(5.0) and not worker.running
    assert [t.name for t in threading.enumerate()].count("test-loop") == 0
    worker.start()
    assert worker.running
    assert worker.stop(5.0)
    assert len(rounds) >= 2


def test_a_worker_never_started_stops_without_waking() -> None:
    woken: list[bool] = []
    worker = Worker(lambda: None, "never", wake=lambda: woken.append(True))
    assert worker.stop(0.1)
    assert woken == []  # an http server's shutdown() would wait forever for its loop


def test_a_loop_that_does_not_end_is_named_in_the_log(caplog: pytest.LogCaptureFixture) -> None:
    release = threading.Event()
    worker = Worker(lambda: release.wait(30), "stuck-loop")
    worker.start()
    with caplog.at_level(logging.WARNING, logger="common.worker"):
        assert not worker.stop(0.05)
    assert "thread stuck-loop did not end within 0.1 s of its stop" in caplog.text
    release.set()


def test_wait_returns_as_soon_as_the_worker_stops() -> None:
    seen: list[bool] = []
    started = threading.Event()

    def loop() -> None:
        started.set()
        seen.append(worker.wait(60))

    worker = Worker(loop, "waiter")
    worker.start()
    started.wait(5)
    assert worker.stop(5.0)
    assert seen == [True]
