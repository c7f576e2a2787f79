"""A graded episode: a submission's controller for an assignment's time in a private world.

The dry run's machinery (services/runner/dryrun.py: the sandbox in lockstep,
one state in and a ``step`` out, the robot's new contacts) on a World built
from the assignment's map with its seed and start pose, instead of a copy of
a running arena. What it records is what an assignment's score reads
(services/grader/score.py): the time each zone was first reached by the
robot's centre, the time each movable object first lay in a zone of kind
``nest``, the robot's new contacts by kind, the distance it drove and the
simulated time. How it ended is the ``cause``: the student's code (an
exception with its line, a timeout, memory, CPU, an output flood) or the lab
(the sandbox could not start): the grader re-runs a lab fault for free.
"""

from __future__ import annotations

import contextlib
import json
import math
import time

from common.controller.actuators import apply_command
from common.messages import (
    MAX_TRACE_ROWS,
    TRACE_EVERY_S,
    Episode,
    EpisodeReport,
    TraceFrame,
    TracePoint,
    WorldSnapshot,
)
from common.sim2d import maps
from common.sim2d.entities import Zone
from common.sim2d.world import EditError, World
from common.world import packing
from services.runner.dryrun import _error_line, _last_line
from services.runner.grader_run import GraderOutcome, episode_data, run_grader
from services.runner.lockstep import Lockstep, Touches
from services.runner.sandbox import Sandbox, SandboxLimits

MAX_OUTPUT = 20
MAX_CONTACTS = 1000  # a grader's contact list (collisions still counts them all)
DELIVERY_EVERY_S = 0.1  # objects in nests are looked at this often (simulated s)


def episode_wall_limit(seconds: float) -> float:
    """Wall-clock time an episode may take: a well-behaved controller steps at several
    times real time on a loaded 2-core machine; a loop is caught well before this."""
    return 10.0 + 1.5 * seconds


def assignment_world(map_json: str, name: str, seed: int) -> World:
    """The World of an assignment's map (JSON) with ``seed``; ValueError for a bad map."""
    try:
        data = json.loads(map_json)
    except ValueError as exc:
        raise ValueError(f"the {name}'s map is not JSON: {exc}") from None
    return maps.build_world(
        maps.parse_map(json.dumps(data), source="assignment map"),
        name=name,
        seed=seed,
        source="assignment map",
    )


def place_robot(
    world: World, agent: str, x: float, y: float, heading: float, pose: str = "start pose"
) -> int:
    """The robot's slot, the robot moved to its start pose (ValueError if it cannot be)."""
    try:
        slot = world.agent_slot(agent)
    except KeyError:
        raise ValueError(f"the map has no robot {agent}") from None
    try:
        world.move(agent, x, y, heading)
    except EditError as exc:
        raise ValueError(f"{pose}: {exc}") from None
    return slot


def build_episode_world(request: Episode) -> World:
    """The episode's World: its map with its seed, the robot at its start pose (ValueError)."""
    world = assignment_world(request.map, "episode", request.seed)
    place_robot(world, request.agent, request.x, request.y, request.heading)
    return world


def _cause(sandbox: Sandbox, timed_out: bool, finished_early: bool) -> tuple[str, str]:
    """(cause, detail) of an episode that did not run its whole time."""
    error = sandbox.error_text
    reason = sandbox.exit_reason
    if error:
        line = _error_line(error)
        where = f"line {line}: " if line else ""
        if "out of memory" in reason:
            return "memory", f"{where}{reason}"
        return "exception", f"{where}{_last_line(error)}"
    if "output flood" in reason:
        return "output", reason
    if "CPU time" in reason:
        return "cpu", reason
    if timed_out:
        return "timeout", "it did not answer in time (an endless loop, or too slow for its period)"
    if "SIGKILL" in reason or "SIGSEGV" in reason:
        # The kernel's OOM killer, or the address-space limit, ends it by a signal.
        return "memory", f"{reason} (out of memory?)"
    if finished_early and reason == "the controller finished":
        return "finished", "the controller returned before the time limit"
    return "ended", reason or "the controller ended"


def run_episode(
    request: Episode, *, limits: SandboxLimits | None = None, wall_s: float | None = None
) -> EpisodeReport:
    """Run the episode; ValueError for a bad map or pose, RuntimeError/OSError if no
    sandbox can start (the lab's fault: the caller says so)."""
    wall_s = episode_wall_limit(request.seconds) if wall_s is None else wall_s
    world = build_episode_world(request)
    slot = world.agent_slot(request.agent)
    # One idle tick before the clock starts: it fills the world's arrays (poses, readings),
    # and a runner's first one compiles the kernels, which is no student's time.
    world.step()
    started = time.monotonic()
    run = Lockstep(
        request.source,
        request.filename,
        world,
        slot,
        wall_s=wall_s,
        limits=limits,
        max_output=MAX_OUTPUT,
        max_line=256,
    )
    sandbox = run.sandbox
    touches = Touches(world, slot)
    collisions: dict[str, int] = {}
    reached: dict[str, float] = {}
    delivered: dict[str, float] = {}
    nests = [z for z in world.zones.values() if z.kind == "nest"]
    check_every = max(1, round(DELIVERY_EVERY_S / world.tick_s))
    distance = 0.0
    ticks = round(request.seconds / world.tick_s)
    t0 = world.sim_time
    last = world.agent_pose[slot][:2].copy()
    trace: list[TracePoint] = []
    trace_every = max(1, round(TRACE_EVERY_S / world.tick_s))
    frames: list[TraceFrame] = []
    snapshot: WorldSnapshot | None = None
    grading = request.grader is not None
    samples: list[list[float]] = []  # a grader's poses and IR readings (grader_run.py)
    contacts: list[list[object]] = []
    if grading:
        samples.append(_sample(world, slot, 0.0))
    if request.trace:
        trace.append((0.0, float(last[0]), float(last[1]), float(world.agent_pose[slot][2])))
        snapshot = packing.snapshot(world)
        frames.append((0.0, _rows(world)))
    try:
        for tick, mine in enumerate(run.ticks(ticks)):
            robot = world.actuators(slot)
            for command in mine:
                with contextlib.suppress(EditError):
                    apply_command(command, robot)
            world.step()
            at = round(world.sim_time - t0, 3)
            for what, ident in touches.new_contacts():
                collisions[what] = collisions.get(what, 0) + 1
                if grading and len(contacts) < MAX_CONTACTS:
                    contacts.append([at, what, ident])
            x, y = (float(v) for v in world.agent_pose[slot][:2])
            distance += math.hypot(x - last[0], y - last[1])
            last = (x, y)
            for zone in world.zones.values():
                if zone.id not in reached and zone.contains(x, y):
                    reached[zone.id] = at
            if nests and tick % check_every == 0:
                _deliveries(world, nests, delivered, at)
            if request.trace and (tick + 1) % trace_every == 0:
                heading = round(float(world.agent_pose[slot][2]), 4)
                trace.append((at, round(x, 2), round(y, 2), heading))
                frames.append((at, _rows(world)))
            if grading and (tick + 1) % trace_every == 0:
                samples.append(_sample(world, slot, at))
    finally:
        run.stop("the episode ended")
    steps, timed_out, output = run.steps, run.timed_out, run.output
    if nests:
        _deliveries(world, nests, delivered, round(world.sim_time - t0, 3))
    sim = world.sim_time - t0
    if steps >= ticks:
        cause, detail = "ok", f"ran its {request.seconds:g} simulated s"
    else:
        cause, detail = _cause(sandbox, timed_out, finished_early=True)
    error = sandbox.error_text
    graded = GraderOutcome({})
    if request.grader is not None:
        zones = {z.id: {"kind": z.kind, "x": z.x, "y": z.y} for z in world.zones.values()}
        data = episode_data(
            robot=request.agent,
            seed=request.seed,
            time_limit=request.seconds,
            cause=cause,
            sim_seconds=round(sim, 3),
            distance_mm=round(distance, 1),
            samples=samples,
            contacts=contacts,
            reached=reached,
            delivered=delivered,
            collisions=collisions,
            zones=zones,
        )
        graded = run_grader(
            request.grader,
            request.grader_filename,
            data,
            seconds=request.grader_seconds,
            limits=limits,
        )
    return EpisodeReport(
        cause=cause,  # type: ignore[arg-type]
        detail=detail[:256],
        error_line=_error_line(error) if error else None,
        sim_seconds=round(sim, 3),
        wall_seconds=round(time.monotonic() - started, 3),
        steps=steps,
        collisions=collisions,
        reached=reached,
        delivered=delivered,
        distance_mm=round(distance, 1),
        output=output,
        trace=trace,
        snapshot=snapshot,
        frames=frames,
        grader_metrics=graded.metrics,
        grader_error=graded.error[:256],
        grader_line=graded.line,
    )


def _sample(world: World, slot: int, at: float) -> list[float]:
    """t, x, y, heading and the proximity readings of the robot now (a grader's input)."""
    x, y, heading = (float(v) for v in world.agent_pose[slot][:3])
    ir = [int(v) for v in world.proximity[slot].tolist()[:8]]
    return [at, round(x, 2), round(y, 2), round(heading, 4), *ir]


def _deliveries(world: World, nests: list[Zone], delivered: dict[str, float], at: float) -> None:
    """Objects lying in a nest now, first time noted."""
    poses = world.object_pose if world.drive == "discs" else None
    for j, obj in enumerate(world.objects):
        if obj.id in delivered:
            continue
        if poses is not None and j < len(poses):
            x, y = float(poses[j][0]), float(poses[j][1])
        else:
            x, y, _ = world.pose_of(obj.id)
        if any(nest.contains(x, y) for nest in nests):
            delivered[obj.id] = at


def _rows(world: World) -> list[float]:
    """x, y, heading of each of the world's first MAX_TRACE_ROWS rows (robots, then objects)."""
    poses = packing.frame(world).poses.to_numpy()[:MAX_TRACE_ROWS]
    out: list[float] = []
    for x, y, heading in poses[:, :3]:
        out += (round(float(x), 2), round(float(y), 2), round(float(heading), 4))
    return out
