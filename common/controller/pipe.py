"""The sandbox's pipe, typed: every message between the runner and its sandboxed child.

The runner (services/runner/sandbox.py) and the child it starts inside the
sandbox (services/runner/child.py) talk over two pipes, one JSON object per
line, tagged by ``"t"``. These dataclasses are those lines, as the wire's
``common/messages/`` are Zenoh's: one :func:`encode`, and one decode per
direction that checks every field. The child's side is untrusted: a hostile
controller can write anything on its pipe, so :func:`decode_from_child`
refuses whatever is not exactly one of :data:`FromChild` with a
:class:`PipeError` saying why, and the runner logs it and keeps serving.

Standard library only, like the rest of this package: the child imports it
inside the sandbox.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from common.controller import KheperaState, RobotCommand

MAX_LINE_BYTES = 4096
"""A line longer than this is cut by the runner's reader and refused whole."""

MAX_NAME_CHARS = 64  # a controller's class name, as the runner shows it
MAX_ERROR_CHARS = 4000  # a traceback's text, as the runner keeps it


class PipeError(ValueError):
    """A line that is not one of the pipe's messages; the text says why."""


# -- runner -> child


@dataclass(frozen=True)
class State:
    """The robot's newest state (each tick of a dry run's world, in lockstep)."""

    state: KheperaState


@dataclass(frozen=True)
class Stop:
    """End the controller: cleanup runs, then the child exits."""


@dataclass(frozen=True)
class Probe:
    """Just before the slot ends: is do_work stuck? (answered with Hung only if it is)."""


# -- child -> runner


@dataclass(frozen=True)
class Command:
    """A command for the robot: the runner forwards it once checked and within the rate."""

    command: RobotCommand


@dataclass(frozen=True)
class Ready:
    """The controller loaded; ``controller`` is its class's name."""

    controller: str


@dataclass(frozen=True)
class Step:
    """Lockstep (a dry run): the state was handled, ``n`` do_work calls so far."""

    n: int


@dataclass(frozen=True)
class Failed:
    """The controller could not load, or raised; ``message`` is the traceback."""

    message: str


@dataclass(frozen=True)
class Hung:
    """do_work has not returned for ``seconds``; the student's file was at ``line``, in
    ``function`` (the innermost frame of the controller's own file in the main thread)."""

    seconds: float
    line: int
    function: str


@dataclass(frozen=True)
class Done:
    """The controller's loop ended normally after ``iterations`` do_work calls."""

    iterations: int


@dataclass(frozen=True)
class Metrics:
    """A teacher's grader (child.py's ``grade`` mode): what its ``grade(episode)`` returned,
    names to finite numbers, checked by the child and again by the runner."""

    values: dict[str, float]


ToChild = State | Stop | Probe
FromChild = Command | Ready | Step | Failed | Hung | Done | Metrics

MAX_METRICS = 32  # a grader's metrics per episode
MAX_METRIC_NAME = 32

HUNG_AFTER_S = 1.0
"""A do_work still running this long when the slot's end nears is reported as hung."""

_TAGS: dict[type, str] = {
    State: "state",
    Stop: "stop",
    Command: "cmd",
    Ready: "ready",
    Step: "step",
    Failed: "error",
    Probe: "probe",
    Hung: "hung",
    Done: "done",
    Metrics: "metrics",
}


def encode(message: ToChild | FromChild) -> bytes:
    """One line of the pipe (with its newline)."""
    body: dict[str, Any]
    if isinstance(message, State):
        body = message.state.to_dict()
    elif isinstance(message, Command):
        body = message.command.to_dict()
    elif isinstance(message, Ready):
        body = {"controller": message.controller}
    elif isinstance(message, Step):
        body = {"n": message.n}
    elif isinstance(message, Failed):
        body = {"message": message.message}
    elif isinstance(message, Done):
        body = {"iterations": message.iterations}
    elif isinstance(message, Hung):
        body = {"seconds": message.seconds, "line": message.line, "function": message.function}
    elif isinstance(message, Metrics):
        body = {"values": message.values}
    else:
        body = {}
    line = json.dumps({"t": _TAGS[type(message)], **body}, separators=(",", ":"))
    return (line + "\n").encode()


def _object(line: bytes | str) -> tuple[str, dict[str, Any]]:
    try:
        data = json.loads(line)
    except (ValueError, RecursionError) as exc:  # RecursionError: [[[[...]]]] nested deep
        raise PipeError(f"not JSON ({type(exc).__name__})") from None
    if not isinstance(data, dict):
        raise PipeError("not a JSON object")
    kind = data.pop("t", None)
    if not isinstance(kind, str):
        raise PipeError('no "t" tag')
    return kind, data


def _only(kind: str, data: dict[str, Any], *names: str) -> None:
    extra = sorted(str(k)[:32] for k in data if k not in names)
    if extra:
        raise PipeError(f"{kind}: unknown fields {', '.join(extra)}")


def _count(kind: str, data: dict[str, Any], name: str) -> int:
    _only(kind, data, name)
    value = data.get(name)
    if type(value) is not int or value < 0:
        raise PipeError(f"{kind}: {name} must be a non-negative integer")
    return value


def _text(kind: str, data: dict[str, Any], name: str, limit: int) -> str:
    _only(kind, data, name)
    value = data.get(name)
    if not isinstance(value, str):
        raise PipeError(f"{kind}: {name} must be a string")
    return value[:limit]


def decode_from_child(line: bytes | str) -> FromChild:
    """A line the child wrote, checked field by field; PipeError (saying why) if it is not one."""
    kind, data = _object(line)
    if kind == "cmd":
        try:
            return Command(RobotCommand.from_dict(data))
        except (ValueError, TypeError) as exc:
            raise PipeError(f"cmd: {exc}") from None
    if kind == "ready":
        return Ready(_text(kind, data, "controller", MAX_NAME_CHARS))
    if kind == "step":
        return Step(_count(kind, data, "n"))
    if kind == "error":
        return Failed(_text(kind, data, "message", MAX_ERROR_CHARS))
    if kind == "done":
        return Done(_count(kind, data, "iterations"))
    if kind == "hung":
        _only(kind, data, "seconds", "line", "function")
        seconds, lineno, function = data.get("seconds"), data.get("line"), data.get("function")
        if not isinstance(seconds, int | float) or isinstance(seconds, bool):
            raise PipeError("hung: seconds must be a number of seconds")
        if not 0 <= seconds < 1e7:
            raise PipeError("hung: seconds must be a number of seconds")
        if type(lineno) is not int or not 0 <= lineno < 10**7:
            raise PipeError("hung: line must be a line number")
        if not isinstance(function, str):
            raise PipeError("hung: function must be a string")
        return Hung(float(seconds), lineno, function[:MAX_NAME_CHARS])
    if kind == "metrics":
        _only(kind, data, "values")
        return Metrics(check_metrics(data.get("values")))
    raise PipeError(f"unknown message {kind[:32]!r}")


def check_metrics(values: Any) -> dict[str, float]:
    """A grader's result as metrics, or PipeError saying what is wrong with it."""
    if not isinstance(values, dict):
        raise PipeError(f"grade() returned {type(values).__name__}, not a dict of names to numbers")
    if len(values) > MAX_METRICS:
        raise PipeError(f"grade() returned {len(values)} metrics; at most {MAX_METRICS}")
    out: dict[str, float] = {}
    for name, value in values.items():
        ok_name = isinstance(name, str) and 0 < len(name) <= MAX_METRIC_NAME
        if not ok_name or not all(c.isalnum() or c in "_-." for c in name):
            shown = repr(name)[:40]
            raise PipeError(
                f"grade() returned a metric named {shown}: names are 1 to {MAX_METRIC_NAME} "
                "letters, digits, '_', '-', '.'"
            )
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise PipeError(f"grade() returned {name}={type(value).__name__}, not a number")
        try:
            number = float(value)
        except OverflowError:
            number = float("inf")
        if number != number or number in (float("inf"), float("-inf")):
            raise PipeError(f"grade() returned {name}={str(value)[:20]}, not a finite number")
        out[name] = number
    return out


def hung_reason(hung: Hung, filename: str, what: str = "do_work") -> str:
    """How a hung run ended, in the student's words: their file, its line and function."""
    where = f"{filename}:{hung.line}" if hung.line else filename
    function = f" (in {hung.function})" if hung.function else ""
    return f"hung: {what} did not return for {hung.seconds:.0f} s; it was at {where}{function}"


def decode_to_child(line: bytes | str) -> ToChild:
    """A line the runner wrote, as the child reads it; PipeError if it is not one."""
    kind, data = _object(line)
    if kind == "stop":
        _only(kind, data)
        return Stop()
    if kind == "probe":
        _only(kind, data)
        return Probe()
    if kind == "state":
        try:
            return State(KheperaState.from_dict(data))
        except (ValueError, TypeError, OverflowError) as exc:
            raise PipeError(f"state: {exc}") from None
    raise PipeError(f"unknown message {kind[:32]!r}")
