"""The viewer's login desk: every queued login is run or told to retry, never forgotten."""

from __future__ import annotations

import threading

import pytest

from viewers.web.login import LoginDesk

WAIT = 10.0  # how long a test waits for a condition that should hold at once


def test_a_login_stuck_behind_busy_workers_is_told_to_retry() -> None:
    desk = LoginDesk(workers=1, queue_wait=0.2)
    release = threading.Event()
    started, ran, too_late = threading.Event(), threading.Event(), threading.Event()

    def stuck() -> None:  # a login whose registry never answers, holding the one worker
        started.set()
        release.wait(WAIT)

    try:
        desk.submit(stuck, lambda: None)
        assert started.wait(WAIT)
        desk.submit(ran.set, too_late.set)
        # Answered while the worker is still stuck: the student is not left waiting.
        assert too_late.wait(WAIT)
        assert not ran.is_set()
        assert desk.waiting == 0
    finally:
        release.set()
        desk.close()


def test_logins_run_in_turn_when_workers_are_free() -> None:
    desk = LoginDesk(workers=2, queue_wait=60.0)
    done = [threading.Event() for _ in range(5)]
    late = threading.Event()
    try:
        for event in done:
            desk.submit(event.set, late.set)
        assert all(event.wait(WAIT) for event in done)
        assert not late.is_set()
    finally:
        desk.close()


def test_a_stopping_viewer_answers_every_waiting_login() -> None:
    desk = LoginDesk(workers=1, queue_wait=60.0)
    release = threading.Event()
    started = threading.Event()
    told = [threading.Event() for _ in range(3)]

    def stuck() -> None:
        started.set()
        release.wait(WAIT)

    desk.submit(stuck, lambda: None)
    assert started.wait(WAIT)
    for event in told:
        desk.submit(lambda: None, event.set)
    desk.close()
    release.set()
    assert all(event.is_set() for event in told)
    after = threading.Event()
    desk.submit(lambda: None, after.set)  # a click after the stop: answered at once
    assert after.is_set()


def test_a_failing_callback_does_not_stop_the_desk() -> None:
    desk = LoginDesk(workers=1, queue_wait=60.0)
    ok = threading.Event()

    def broken() -> None:
        raise RuntimeError("a bug in one page's login")

    try:
        desk.submit(broken, lambda: None)
        desk.submit(ok.set, lambda: None)
        assert ok.wait(WAIT)
    finally:
        desk.close()


@pytest.mark.parametrize("workers,wait", [(0, 1.0), (1, 0.0)])
def test_a_desk_needs_a_worker_and_a_wait(workers: int, wait: float) -> None:
    with pytest.raises(ValueError):
        LoginDesk(workers=workers, queue_wait=wait)
