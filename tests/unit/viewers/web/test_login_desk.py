"""The viewer's login desk: every queued login is run or told to retry, never forgotten."""

from __future__ import annotations

import threading
import time

import pytest

from viewers.web import login
from viewers.web.login import LoginDesk, LoginForm

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


class _Shown:
    """What the form's message and button hold: all the page would show."""

    content = ""
    visible = False
    disabled = True


def test_the_answer_is_never_overwritten_by_a_late_progress_message(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # A loaded machine preempts the progress thread between its check and its write;
    # the answer shown in between must still be what the student reads at the end.
    form = object.__new__(LoginForm)
    form.error, form.submit, form.closed = _Shown(), _Shown(), False
    form.desk = LoginDesk(workers=1, queue_wait=60.0)
    form._busy, form._message = threading.Lock(), threading.Lock()
    form._done = threading.Event()
    form.client = type("Client", (), {"client_id": 7})()
    form.address = type("Address", (), {"label": "the lab"})()
    writing, answered = threading.Event(), threading.Event()

    def preempted(waited: float, queued_here: int) -> str:
        writing.set()
        answered.wait(1.0)  # the answer lands here when nothing orders the two writes
        return "Logging in... 5 s"

    monkeypatch.setattr(login, "progress_words", preempted)
    form._busy.acquire()
    clicked = time.monotonic() - 5.0
    progress = threading.Thread(target=form._progress, args=(clicked, form._done))
    progress.start()
    try:
        assert writing.wait(WAIT)

        def answer_now() -> None:
            form._answered("Could not log in: wrong password", clicked)
            answered.set()

        answer = threading.Thread(target=answer_now)
        answer.start()
        answer.join(WAIT)
        progress.join(WAIT)
        assert form.error.content == "**Could not log in: wrong password**"
        assert form.submit.disabled is False
    finally:
        form._done.set()
        form.desk.close()
