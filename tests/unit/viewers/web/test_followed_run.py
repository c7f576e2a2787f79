"""A page that comes to a run late: what it printed before, then what comes, none twice."""

from __future__ import annotations

import threading

from tests.kit.waits import wait_for
from viewers.web.adapters import LabError, OutputEvent, OutputSoFar
from viewers.web.followed_run import RESUMED_NOTE, FollowedRun
from viewers.web.run_output import RunOutput, as_text


class FakeHtml:
    content = ""


class FakeGui:
    def add_html(self, content: str) -> FakeHtml:
        return FakeHtml()


class SlowContext:
    """The lab's side: the run's output so far, answered when the test lets it."""

    user = "alice"

    def __init__(self, so_far: OutputSoFar | None) -> None:
        self.so_far = so_far
        self.answer = threading.Event()
        self.asked = threading.Event()

    def output_so_far(self, ctx: str, request_id: str) -> OutputSoFar:
        self.asked.set()
        self.answer.wait(10)
        if self.so_far is None:
            raise LabError("context arena not found")
        return self.so_far


def shown(output: RunOutput) -> list[str]:
    return [text for text, _ in as_text(output.printed)]


def event(first: int, *lines: str, request: str = "k1-1-a") -> OutputEvent:
    return OutputEvent("arena", request, "k1", "alice", lines, first)


def make(so_far: OutputSoFar | None) -> tuple[FollowedRun, RunOutput, SlowContext, list[int]]:
    output = RunOutput(FakeGui())  # type: ignore[arg-type]
    context = SlowContext(so_far)
    raised: list[int] = []
    lock = threading.Lock()
    followed = FollowedRun(context, output, lock, lambda: raised.append(1))  # type: ignore[arg-type]
    return followed, output, context, raised


def test_lines_that_come_while_the_output_so_far_is_asked_follow_it_none_twice() -> None:
    followed, output, context, _ = make(OutputSoFar(3, ("d", "e", "f")))
    output.note("following your run on k1, started elsewhere")
    followed.follow("k1-1-a")
    followed.catch_up("arena", "k1", "k1-1-a", replace=False)
    assert context.asked.wait(5)
    with followed.lock:
        followed.show(event(5, "f", "g"))  # "f" is in the answer too
        followed.show(event(7, "h"))
    context.answer.set()
    wait_for(lambda: shown(output)[-1] == "h", 5, "the held lines shown")
    assert shown(output) == [
        "following your run on k1, started elsewhere",
        "3 earlier line(s) not kept",
        *"defgh",
    ]
    with followed.lock:
        followed.show(event(7, "h"))  # the same event again
        followed.show(event(10, "k"))  # two lines never came
        followed.show(event(0, "x", request="k1-0-old"))  # an earlier run's trailing line
    assert shown(output)[-2:] == ["2 line(s) not received here", "k"]


def test_a_restarted_viewers_copy_is_replaced_by_the_contexts_counted_one() -> None:
    followed, output, context, _ = make(OutputSoFar(0, ("a", "b")))
    output.put_back(("<i>running on k1</i>", "a"), ())  # the book's copy: no count
    followed.follow("k1-1-a")
    followed.catch_up("arena", "k1", "k1-1-a", replace=True)
    context.answer.set()
    wait_for(lambda: RESUMED_NOTE in shown(output), 5, "the context's copy")
    assert shown(output) == [RESUMED_NOTE, "a", "b"]  # "b" came while no viewer listened
    assert output.next_line == 2


def test_when_the_context_cannot_say_the_lines_that_come_still_show() -> None:
    followed, output, context, _ = make(None)
    followed.follow("k1-1-a")
    followed.catch_up("arena", "k1", "k1-1-a", replace=False)
    with followed.lock:
        followed.show(event(4, "e"))
    context.answer.set()
    wait_for(lambda: shown(output) == ["e"], 5, "the held line")
    assert output.next_line == 5


def test_an_answer_about_a_run_no_longer_followed_is_dropped() -> None:
    followed, output, context, _ = make(OutputSoFar(0, ("old",)))
    followed.follow("k1-1-a")
    followed.catch_up("arena", "k1", "k1-1-a", replace=False)
    assert context.asked.wait(5)
    with followed.lock:
        followed.follow("k1-2-b")  # the student started another run meanwhile
        followed.show(event(0, "new", request="k1-2-b"))
    context.answer.set()

    def answered() -> bool:  # the asking thread has taken its answer and ended
        return not any(t.name == "output-k1-1-a" for t in threading.enumerate())

    wait_for(answered, 5, "the old run's answer taken")
    assert shown(output) == ["new"]
