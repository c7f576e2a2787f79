"""The sandbox's pipe is typed like the wire: one encode, one checked decode per direction."""

from __future__ import annotations

import pytest

from common.controller import KheperaState, RobotCommand, pipe

FROM_CHILD = [
    pipe.Command(RobotCommand(speeds=(10, -10))),
    pipe.Command(RobotCommand(grip=True)),
    pipe.Ready("Avoid"),
    pipe.Step(3),
    pipe.Failed("Traceback ...\nZeroDivisionError"),
    pipe.Hung(30.5, 8, "do_work"),
    pipe.Done(42),
]


@pytest.mark.parametrize("message", FROM_CHILD, ids=lambda m: type(m).__name__)
def test_every_child_message_round_trips(message: pipe.FromChild) -> None:
    line = pipe.encode(message)
    assert line.endswith(b"\n") and line.count(b"\n") == 1
    assert pipe.decode_from_child(line) == message


@pytest.mark.parametrize(
    "message",
    [
        pipe.State(KheperaState(time=1.5, speeds=(3, 4), leds=(True, False))),
        pipe.Stop(),
        pipe.Probe(),
    ],
    ids=lambda m: type(m).__name__,
)
def test_every_runner_message_round_trips(message: pipe.ToChild) -> None:
    assert pipe.decode_to_child(pipe.encode(message)) == message


@pytest.mark.parametrize(
    ("line", "why"),
    [
        (b"not json", "not JSON"),
        (b"[1, 2]", "not a JSON object"),
        (b'{"speeds": [1, 1]}', 'no "t" tag'),
        (b'{"t": 7}', 'no "t" tag'),
        (b'{"t": "fly"}', "unknown message 'fly'"),
        (b'{"t": "state", "time": 1}', "unknown message 'state'"),  # not the child's to send
        (b'{"t": "cmd", "speeds": [500, 0]}', "cmd: speeds must be two integers"),
        (b'{"t": "cmd", "speeds": [1, 1], "arm": 3}', "cmd: a command sets exactly one"),
        (b'{"t": "step", "n": -1}', "step: n must be a non-negative integer"),
        (b'{"t": "step", "n": true}', "step: n must be a non-negative integer"),
        (b'{"t": "done"}', "done: iterations must be"),
        (b'{"t": "ready", "controller": ["x"]}', "ready: controller must be a string"),
        (b'{"t": "error", "message": "x", "pid": 1}', "error: unknown fields pid"),
        (b"[" * 100_000, "not JSON"),
    ],
)
def test_a_hostile_line_is_refused_with_the_reason(line: bytes, why: str) -> None:
    with pytest.raises(pipe.PipeError, match=why.replace("(", r"\(").replace("[", r"\[")):
        pipe.decode_from_child(line)


def test_long_texts_are_cut_to_what_the_runner_keeps() -> None:
    ready = pipe.decode_from_child(pipe.encode(pipe.Ready("C" * 1000)))
    assert isinstance(ready, pipe.Ready) and len(ready.controller) == pipe.MAX_NAME_CHARS
    failed = pipe.decode_from_child(pipe.encode(pipe.Failed("x" * 10_000)))
    assert isinstance(failed, pipe.Failed) and len(failed.message) == pipe.MAX_ERROR_CHARS


def test_the_child_refuses_a_bad_state() -> None:
    with pytest.raises(pipe.PipeError, match="state: speeds: expected 2 integers"):
        pipe.decode_to_child(b'{"t": "state", "speeds": [1]}')


@pytest.mark.parametrize(
    ("line", "why"),
    [
        (b'{"t":"hung","seconds":"a lot","line":8,"function":"f"}', "seconds must be"),
        (b'{"t":"hung","seconds":-1,"line":8,"function":"f"}', "seconds must be"),
        (b'{"t":"hung","seconds":3,"line":8.5,"function":"f"}', "line must be"),
        (b'{"t":"hung","seconds":3,"line":-2,"function":"f"}', "line must be"),
        (b'{"t":"hung","seconds":3,"line":8,"function":7}', "function must be"),
        (b'{"t":"hung","seconds":3,"line":8,"function":"f","x":1}', "unknown fields x"),
    ],
)
def test_a_hung_report_is_checked_field_by_field(line: bytes, why: str) -> None:
    with pytest.raises(pipe.PipeError, match=why):
        pipe.decode_from_child(line)


def test_a_hung_run_is_said_with_the_students_file_line_and_function() -> None:
    long_name = pipe.decode_from_child(
        b'{"t":"hung","seconds":29.7,"line":8,"function":"' + b"f" * 500 + b'"}'
    )
    assert isinstance(long_name, pipe.Hung) and len(long_name.function) == pipe.MAX_NAME_CHARS
    assert pipe.hung_reason(pipe.Hung(29.7, 8, "do_work"), "spin.py") == (
        "hung: do_work did not return for 30 s; it was at spin.py:8 (in do_work)"
    )
    # No frame of the student's file on the stack (stuck inside the library): no line.
    assert pipe.hung_reason(pipe.Hung(5.0, 0, ""), "spin.py") == (
        "hung: do_work did not return for 5 s; it was at spin.py"
    )
