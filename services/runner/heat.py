"""A competition's heat: several entries' controllers in one world at once, in lockstep.

Each entry's controller runs in its own sandbox (services/runner/sandbox.py, as a graded
episode's) on its own robot of the assignment's map, placed at its start pose. Every
tick each controller still running gets its robot's state; once all have answered
(or ended), their commands are applied and the world steps once: the slowest controller
slows the heat, never the other way round. A controller that raises, loops or exits
ends its own run only: its robot stops there and the others go on. Each entry's events
are kept apart (services/runner/episode.py's: zones reached, deliveries, distance, and
its robot's new contacts by kind, so a collision between two entries counts for both),
with the world's frames for the heat's recording.
"""

from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass, field

from common.controller import RobotCommand
from common.controller.actuators import apply_command
from common.messages import (
    TRACE_EVERY_S,
    EpisodeReport,
    Heat,
    HeatReport,
    TraceFrame,
    TracePoint,
)
from common.sim2d.world import EditError, World
from common.world import packing
from services.runner.dryrun import _error_line
from services.runner.episode import (
    MAX_OUTPUT,
    _cause,
    _deliveries,
    _rows,
    assignment_world,
    episode_wall_limit,
    place_robot,
)
from services.runner.lockstep import Lockstep, Touches
from services.runner.sandbox import SandboxLimits

STOP = RobotCommand(speeds=(0, 0))
# A controller that has not answered one tick's state in this long (wall clock, counted from
# when it had loaded: a sandbox's start takes seconds on a busy host) is ended as a timeout,
# so that one loop does not hold the others until the heat's own limit.
TICK_ANSWER_S = 5.0


@dataclass
class _Entry:
    run: Lockstep
    slot: int
    touches: Touches
    active: bool = True
    collisions: dict[str, int] = field(default_factory=dict)
    reached: dict[str, float] = field(default_factory=dict)
    delivered: dict[str, float] = field(default_factory=dict)
    distance: float = 0.0
    last: tuple[float, float] = (0.0, 0.0)
    trace: list[TracePoint] = field(default_factory=list)


def build_heat_world(request: Heat) -> tuple[World, list[int]]:
    """The heat's World and each entry's robot slot (ValueError for a bad map or pose)."""
    world = assignment_world(request.map, "heat", request.seed)
    slots = [
        place_robot(world, e.agent, e.x, e.y, e.heading, f"start pose of {e.agent}")
        for e in request.entries
    ]
    if len(set(slots)) != len(slots):
        raise ValueError("two entries on one robot")
    return world, slots


def run_heat(request: Heat, *, limits: SandboxLimits | None = None) -> HeatReport:
    """Run the heat; ValueError for a bad map, RuntimeError/OSError if a sandbox cannot start."""
    wall_s = episode_wall_limit(request.seconds) + 2.0 * len(request.entries)
    world, slots = build_heat_world(request)
    world.step()  # fills the arrays (and compiles a runner's kernels): no entry's time
    entries: list[_Entry] = []
    try:
        for e, slot in zip(request.entries, slots, strict=True):
            run = Lockstep(e.source, e.filename, world, slot, wall_s=wall_s, limits=limits,
                           max_output=MAX_OUTPUT, max_line=256)  # fmt: skip
            entries.append(_Entry(run=run, slot=slot, touches=Touches(world, slot)))
        deadline = time.monotonic() + wall_s
        for entry in entries:
            entry.run.sandbox.start(wall_s)
        started = time.monotonic()
        snapshot = packing.snapshot(world)
        frames = _loop(request, world, entries, deadline)
    finally:
        for entry in entries:
            entry.run.stop("the heat ended")
    took = round(time.monotonic() - started, 3)
    return HeatReport(
        entries=[_report(request, world, e, took) for e in entries],
        snapshot=snapshot,
        frames=frames,
    )


def _loop(request: Heat, world: World, entries: list[_Entry], deadline: float) -> list[TraceFrame]:
    """Step the world with every entry still running; the heat's frames."""
    ticks = round(request.seconds / world.tick_s)
    trace_every = max(1, round(TRACE_EVERY_S / world.tick_s))
    check_every = max(1, round(0.1 / world.tick_s))
    nests = [z for z in world.zones.values() if z.kind == "nest"]
    t0 = world.sim_time
    frames: list[TraceFrame] = [(0.0, _rows(world))]
    for e in entries:
        x, y, heading = (float(v) for v in world.agent_pose[e.slot][:3])
        e.last = (x, y)
        e.trace.append((0.0, x, y, heading))
    for tick in range(ticks):
        live = [e for e in entries if e.active]
        if not live:
            break
        for e in live:
            if not e.run.offer():
                e.active = False
        for e in live:
            if e.active and not e.run.answer(deadline, TICK_ANSWER_S):
                e.active = False
                if e.run.timed_out:  # stopped now: its loop must not slow the others' heat
                    e.run.stop("it did not answer in time")
        for e in entries:
            robot = world.actuators(e.slot)
            for command in e.run.take() if e.active else [STOP]:
                with contextlib.suppress(EditError):
                    apply_command(command, robot)
        world.step()
        at = round(world.sim_time - t0, 3)
        for e in entries:
            for what, _ident in e.touches.new_contacts():
                e.collisions[what] = e.collisions.get(what, 0) + 1
            x, y = (float(v) for v in world.agent_pose[e.slot][:2])
            e.distance += math.hypot(x - e.last[0], y - e.last[1])
            e.last = (x, y)
            for zone in world.zones.values():
                if zone.id not in e.reached and zone.contains(x, y):
                    e.reached[zone.id] = at
            if (tick + 1) % trace_every == 0:
                heading = round(float(world.agent_pose[e.slot][2]), 4)
                e.trace.append((at, round(x, 2), round(y, 2), heading))
        if nests and tick % check_every == 0:
            # An object delivered in a heat counts for every entry still in it (shared world).
            for e in entries:
                _deliveries(world, nests, e.delivered, at)
        if (tick + 1) % trace_every == 0:
            frames.append((at, _rows(world)))
    return frames


def _report(request: Heat, world: World, e: _Entry, took: float) -> EpisodeReport:
    run = e.run
    ticks = round(request.seconds / world.tick_s)
    sandbox = run.sandbox
    if run.steps >= ticks:
        cause, detail = "ok", f"ran its {request.seconds:g} simulated s"
    else:
        cause, detail = _cause(sandbox, run.timed_out, finished_early=True)
    error = sandbox.error_text
    return EpisodeReport(
        cause=cause,  # type: ignore[arg-type]
        detail=detail[:256],
        error_line=_error_line(error) if error else None,
        sim_seconds=round(e.trace[-1][0] if e.trace else 0.0, 3),
        wall_seconds=took,
        steps=run.steps,
        collisions=e.collisions,
        reached=e.reached,
        delivered=e.delivered,
        distance_mm=round(e.distance, 1),
        output=run.output,
        trace=e.trace,
    )
