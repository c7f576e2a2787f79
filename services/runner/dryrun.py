"""A dry run: a few simulated seconds of an uploaded controller in a private copy of the arena.

Robotarium's ``debug()`` tells a student before a run whether it "will run" on
the testbed; this is ours. The controller is untrusted code, so it runs in
the same :class:`~services.runner.sandbox.Sandbox` as a deployed one (the
child in lockstep: one state in, its commands and a ``step`` out), never in
a lab process. The world is the runner's own: a Sim2D ``World`` built from
the arena's public snapshot (obstacles, objects, lights, robots where they
stand), stepped here one tick per answer, headless and as fast as the child
answers, until ``seconds`` of simulated time or :data:`DRY_RUN_WALL_S` of
wall-clock time, whichever comes first.

Grading (docs/CONTROLLERS.md): "will NOT run" if the controller does not load,
raises (with the line of the controller file) or does not answer in time. A
collision with a wall, an obstacle or another robot is a warning ("will run,
with a warning: 1 collision, ..."): the controller runs, and a bump is what a
student tunes next, not a failure; pushing movable objects is fine (foraging
does it). Saturated wheels (commands at the robot's top speed) are reported,
not failed: the robot only clamps them.
"""

from __future__ import annotations

import contextlib
import re
import time

from common.controller.actuators import apply_command
from common.messages import DryRunCollision, DryRunReport, WorldSnapshot
from common.sim2d.world import EditError
from common.twin.arena import world_from_snapshot
from common.twin.twinfile import Twin
from services.runner.lockstep import Lockstep, Touches
from services.runner.sandbox import SandboxLimits

DRY_RUN_WALL_S = 20.0
"""Longest wall-clock limit of a dry run, sandbox start included (a hostile controller's end)."""


def wall_limit(seconds: float) -> float:
    """The wall-clock limit of a dry run of ``seconds``: 20 s for the default 5 s.

    Generous (a loaded 2-core machine starts a sandbox in 1-3 s and steps a
    well-behaved controller at 4-5x real time), never more than DRY_RUN_WALL_S.
    """
    return min(DRY_RUN_WALL_S, 5.0 + 3.0 * seconds)


MAX_COLLISIONS = 100
MAX_OUTPUT = 50
_LINE = re.compile(r'File "/ctl/user/controller\.py", line (\d+)')


def _article(what: str) -> str:
    return "an" if what[:1] in ("a", "e", "i", "o", "u") else "a"


def _error_line(text: str) -> int | None:
    found = _LINE.findall(text)
    return int(found[-1]) if found else None


def _last_line(text: str) -> str:
    lines = [ln.strip() for ln in text.strip().splitlines() if ln.strip()]
    return lines[-1] if lines else "it raised an exception"


def dry_run(
    snap: WorldSnapshot,
    agent: str,
    source: bytes,
    *,
    filename: str = "controller.py",
    seconds: float = 5.0,
    limits: SandboxLimits | None = None,
    wall_s: float | None = None,
    twin: Twin | None = None,
    why_not_twin: str = "",
) -> DryRunReport:
    """Run ``source`` on ``agent`` of a private copy of ``snap``'s world; what it saw.

    ``twin``: the real robot's twin (common/twin/), simulated instead of the datasheet's
    Khepera when it is ``agent``'s and the agent is a Khepera; the report's ``model``
    says which was used, and ``why_not_twin`` why a real robot's twin could not be had.
    Raises ValueError if the world cannot be rebuilt or has no such robot,
    RuntimeError if no sandbox can run here.
    """
    started = time.monotonic()
    wall_s = wall_limit(seconds) if wall_s is None else wall_s
    kinds = {a.id: a.type for a in snap.agents}
    if twin is not None and (twin.robot != agent or kinds.get(agent) != "khepera"):
        twin = None  # a twin is a Khepera's: another robot keeps its own model
    world = world_from_snapshot(snap, twin)
    try:
        slot = world.agent_slot(agent)
    except KeyError:
        raise ValueError(f"no robot {agent} in world {snap.world}") from None
    kind = kinds.get(agent, "")
    model = (
        f"simulated with {twin.model()}"
        if twin is not None
        else ("the datasheet Khepera" if kind == "khepera" else f"the {kind} robot type")
    )
    if twin is None and why_not_twin and kind == "khepera":
        model += f" ({why_not_twin})"
    top = float(world.tables.max_speed[slot])
    run = Lockstep(
        source, filename, world, slot, wall_s=wall_s, limits=limits, max_output=MAX_OUTPUT
    )
    sandbox = run.sandbox
    collisions: list[DryRunCollision] = []
    touches = Touches(world, slot)
    saturated = wheel_commands = 0
    ticks = round(seconds / world.tick_s)
    world.step()  # one idle tick: the world's arrays (poses, readings) are filled by a step
    t0 = world.sim_time
    try:
        for mine in run.ticks(ticks):
            robot = world.actuators(slot)
            for command in mine:
                if command.speeds is not None:
                    wheel_commands += 1
                    if max(abs(command.speeds[0]), abs(command.speeds[1])) >= top:
                        saturated += 1
                # The engine's own mapping: the dry run's robot obeys what the lab's would
                # (arm or grip to a robot without a gripper is ignored, as there).
                with contextlib.suppress(EditError):
                    apply_command(command, robot)
            world.step()
            for what, ident in touches.new_contacts():
                if len(collisions) < MAX_COLLISIONS:
                    collisions.append(
                        DryRunCollision(at=round(world.sim_time - t0, 3), what=what, ident=ident)  # type: ignore[arg-type]
                    )
    finally:
        run.stop("the dry run ended")
    steps, timed_out, output = run.steps, run.timed_out, run.output
    wall = time.monotonic() - started
    error = sandbox.error_text
    sim = world.sim_time - t0
    line = _error_line(error) if error else None
    if error:
        where = f"line {line}: " if line else ""
        verdict = f"will NOT run: {where}{_last_line(error)}"
    elif timed_out:
        verdict = (
            f"will NOT run: it did not answer within {wall_s:g} s of wall-clock time, at "
            f"{sim:.2f} simulated s (an endless loop, or too slow for its period)"
        )
    elif steps < ticks:
        verdict = f"will NOT run: it ended at {sim:.2f} simulated s ({sandbox.exit_reason})"
    else:
        hits = [c for c in collisions if c.what != "object"]
        if hits:
            first = hits[0]
            what = first.what + (f" {first.ident}" if first.ident else "")
            verdict = (
                f"will run, with a warning: {len(hits)} collision{'s' * (len(hits) != 1)}, "
                f"the first with {_article(first.what)} {what} at {first.at:.2f} s"
            )
        else:
            verdict = "will run"
        if saturated:
            verdict += f" ({saturated} of {wheel_commands} wheel commands at top speed)"
    return DryRunReport(
        will_run=verdict.startswith("will run"),
        verdict=verdict[:256],
        sim_seconds=round(sim, 3),
        wall_seconds=round(wall, 3),
        steps=steps,
        collisions=collisions,
        saturated=saturated,
        commands=wheel_commands,
        error_line=line,
        error=error[-256:] if error else "",
        output=output,
        model=model[:256],
    )
