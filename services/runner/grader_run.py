"""A teacher's grader function, run once on an episode's data in the students' sandbox.

An assignment may name a Python file defining ``grade(episode) -> dict[str, float]``
(docs/COURSES.md, "A grader function"). After each episode the runner stages the
file and the episode's data (:func:`episode_data`, a plain JSON structure, not our
classes) in a sandbox like a controller's (services/runner/sandbox.py: no network,
CPU-time, memory and output limits, a wall-clock kill) and the child calls grade()
once (services/runner/child.py, ``grade`` mode). Whatever goes wrong there (an
exception, a loop, a flood of output, a result that is not names to numbers) is the
teacher's fault: :class:`GraderOutcome` says so in words, with the file and line,
and the grader service neither scores the run nor charges the student for it.
"""

from __future__ import annotations

import json
import re
import time
from dataclasses import dataclass
from typing import Any

from services.runner.sandbox import Sandbox, SandboxLimits

GRADER_SECONDS = 10.0  # an assignment's default time for grade() (wall clock)
MAX_GRADER_SECONDS = 60.0
_LINE = re.compile(r'File "/ctl/user/controller\.py", line (\d+)')
EPISODE_FORMAT = 1  # the version of episode_data's structure (docs/COURSES.md)


@dataclass(frozen=True)
class GraderOutcome:
    metrics: dict[str, float]
    error: str = ""  # "" or why the grader gave no metrics, in the teacher's words
    line: int | None = None  # the line of the grader's file where it failed, when known


def grader_limits(base: SandboxLimits | None, seconds: float) -> SandboxLimits:
    """The runner's sandbox limits for a grader that has ``seconds``: CPU within that, told
    where it was stuck a second before its end."""
    base = base or SandboxLimits()
    return SandboxLimits(
        cpu_seconds=max(1, min(base.cpu_seconds, int(seconds))),
        memory_bytes=base.memory_bytes,
        processes=base.processes,
        open_files=base.open_files,
        file_size_bytes=base.file_size_bytes,
        output_lines_per_second=base.output_lines_per_second,
        commands_per_second=1,  # a grader drives nothing
        output_bytes_per_second=base.output_bytes_per_second,
        cpu_share=base.cpu_share,
        hang_seconds=max(0.5, seconds - 1.0),
    )


def run_grader(
    source: bytes,
    filename: str,
    episode: dict[str, Any],
    *,
    seconds: float = GRADER_SECONDS,
    limits: SandboxLimits | None = None,
) -> GraderOutcome:
    """grade(episode) in a sandbox; RuntimeError/OSError if no sandbox can start (the lab's)."""
    data = json.dumps(episode, separators=(",", ":")).encode()
    sandbox = Sandbox(
        source,
        filename=filename,
        limits=grader_limits(limits, seconds),
        on_command=lambda command: None,
        on_output=lambda line: None,  # a grader's prints are not kept (a flood ends it)
        grade_input=data,
    )
    started = time.monotonic()
    sandbox.start(seconds + 1.0)
    if not sandbox.wait(seconds + 10.0):
        sandbox.stop(grace=0.2, reason=f"grade() did not return in {seconds:g} s")
    if sandbox.metrics is not None and not sandbox.error_text:
        return GraderOutcome(metrics=sandbox.metrics)
    return _failure(sandbox, filename, time.monotonic() - started, seconds)


def _failure(sandbox: Sandbox, filename: str, took: float, seconds: float) -> GraderOutcome:
    error, reason = sandbox.error_text, sandbox.exit_reason
    if error:
        found = _LINE.findall(error)
        line = int(found[-1]) if found else None
        lines = [ln.strip() for ln in error.strip().splitlines() if ln.strip()]
        last = lines[-1] if lines else "it raised an exception"
        where = f"{filename}, line {line}" if line else filename
        if "out of memory" in reason:
            return GraderOutcome({}, f"{where}: {reason}", line)
        return GraderOutcome({}, f"{where}: {last}", line)
    if reason.startswith("hung:"):
        match = re.search(r":(\d+)", reason.split("it was at", 1)[-1])
        return GraderOutcome({}, f"{filename}: {reason}", int(match.group(1)) if match else None)
    if "output flood" in reason:
        return GraderOutcome({}, f"{filename}: {reason}")
    if "CPU time" in reason:
        return GraderOutcome({}, f"{filename}: {reason}")
    if took >= seconds:
        return GraderOutcome({}, f"{filename}: grade() did not return in {seconds:g} s")
    return GraderOutcome({}, f"{filename}: ended without a result ({reason or 'no reason'})")


def episode_data(
    *,
    robot: str,
    seed: int,
    time_limit: float,
    cause: str,
    sim_seconds: float,
    distance_mm: float,
    samples: list[list[float]],
    contacts: list[list[Any]],
    reached: dict[str, float],
    delivered: dict[str, float],
    collisions: dict[str, int],
    zones: dict[str, dict[str, Any]],
    source: str = "simulation",
) -> dict[str, Any]:
    """The structure grade() receives (plain JSON types; docs/COURSES.md documents it)."""
    return {
        "format": EPISODE_FORMAT,
        "source": source,  # "simulation" or "real"
        "robot": robot,
        "seed": seed,
        "time_limit": time_limit,
        "cause": cause,
        "sim_seconds": sim_seconds,
        "distance_mm": distance_mm,
        # [t s, x mm, y mm, heading rad], one each 0.1 simulated s
        "poses": [s[:4] for s in samples],
        # [t s, ir0 .. ir7] proximity readings 0..1023 at the same times
        "ir": [[s[0], *s[4:]] for s in samples],
        "contacts": contacts,  # [t s, "wall"|"obstacle"|"robot"|"object", id]
        "events": {"reached": reached, "delivered": delivered, "collisions": collisions},
        "zones": zones,  # id -> {"kind", "x", "y"}
    }
