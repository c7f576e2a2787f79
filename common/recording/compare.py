"""Sim beside real: two recordings of the same controller compared as numbers.

Typically run A is the simulated robot (an engine's world) and run B the real
one (the Khepera bridge's world), both started from the same pose. Both are
put on one clock, the time since their slot's start (each record's log time
minus ``RunInfo.start``: both are the agent context's wall clock, whereas
``sim_time`` is the engine's tick clock in one and the bridge's poll clock in
the other, so it cannot be compared).

The numbers:

- final pose error: the distance (mm) and heading difference (rad) between
  the two robots' last recorded poses; also the start pose offset, so a
  reader can tell a divergence from a different start;
- path length ratio: B's path over A's (1.0: they travelled as far);
- collisions of each, counted on one map: the one of the two snapshots that
  has obstacles (a bridge's snapshot has the arena's size but no obstacles,
  the real walls are not known to it), so both tracks meet the same walls;
- per-sensor mean difference of IR proximity and ambient light, B minus A
  (signed) and its absolute value, over time-aligned samples: B's samples
  interpolated linearly at the times of A's, over the span both cover.

A real run whose arena had a camera carries the robot's tracked poses: those
are where the robot really was, so its track is taken from them rather than
from the bridge's frames (odometry between camera frames, and adrift without
one); the side says which (``poses_from``).

Both recordings must be of a Khepera-type robot (the snapshot names the
robot's type). A recording without frames of its robot is refused
(:class:`CompareError`); one cut short, or shorter than the other, is
compared over what it holds, with a warning saying so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import msgspec
import numpy as np

from common.messages import WorldSnapshot
from common.recording import contacts
from common.recording.reader import Recording, RecordingError
from common.recording.summary import JUMP_MM

ROBOT_TYPE = "khepera"
SENSORS = 8  # a Khepera's IR emitters/receivers: proximity and ambient per sensor
MIN_ALIGNED = 2  # fewer aligned samples than this give no sensor differences


class CompareError(RecordingError):
    """Two recordings that cannot be compared (not a Khepera, no frames of the robot)."""


class Side(msgspec.Struct, frozen=True, kw_only=True):
    """One of the two runs, as the comparison saw it."""

    label: str  # what the report calls it (the file's stem)
    path: str
    request_id: str
    world: str
    agent: str
    ctx: str
    filename: str
    status: str  # finished | cancelled | refused | unknown (cut short)
    duration_s: float  # first to last frame of the robot, on the slot's clock
    frames: int
    samples: int
    start_pose: tuple[float, float, float]  # x mm, y mm, heading rad
    final_pose: tuple[float, float, float]
    path_mm: float
    collisions: int
    contact_s: float
    truncated: str = ""
    poses_from: str = "frames"  # or "camera": the robot's tracked poses (a real run)


class Comparison(msgspec.Struct, frozen=True, kw_only=True):
    """Run B against run A (``wart report A --against B``; ``--json`` prints this)."""

    a: Side
    b: Side
    map_from: str  # the label of the run whose snapshot gave the map ("" without one)
    start_offset_mm: float  # how far apart the two runs started
    final_pose_error_mm: float
    final_heading_error_rad: float  # B minus A, wrapped to [-pi, pi]
    path_length_ratio: float | None  # B / A; None when A did not move
    aligned_samples: int
    aligned_span_s: float
    ir_mean_diff: list[float]  # per sensor, B minus A
    ir_mean_abs_diff: list[float]
    ambient_mean_diff: list[float]
    ambient_mean_abs_diff: list[float]
    warnings: list[str]


@dataclass(frozen=True)
class Track:
    """A run's robot: poses and sensor samples on the slot's clock (s since its start)."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    sample_t: np.ndarray
    from_camera: bool
    proximity: np.ndarray  # samples x SENSORS
    ambient: np.ndarray


def robot_track(rec: Recording) -> Track:
    """The slot's robot of ``rec``: every frame it appears in and every complete sample."""
    assert rec.info is not None  # read_recording refuses a file without one
    agent, start = rec.info.agent, rec.info.start
    t, x, y, h = [], [], [], []
    for seen in rec.tracked:
        for robot in seen.record.robots:
            if robot.agent == agent:
                t.append(seen.t - start)
                x.append(robot.x)
                y.append(robot.y)
                h.append(robot.heading)
    from_camera = len(t) >= 2
    if not from_camera:
        t, x, y, h = [], [], [], []
    for stamped in [] if from_camera else rec.frames:
        f = stamped.record
        try:
            row = f.rows.index(agent)
        except ValueError:
            continue
        if row < min(len(f.x), len(f.y), len(f.heading)):
            t.append(stamped.t - start)
            x.append(f.x[row])
            y.append(f.y[row])
            h.append(f.heading[row])
    st, prox, amb = [], [], []
    for sample in rec.samples:
        r = sample.record
        # A sample of another robot, or of another type's sensor count, is not compared.
        if r.agent == agent and len(r.proximity) == SENSORS and len(r.ambient) == SENSORS:
            st.append(sample.t - start)
            prox.append(r.proximity)
            amb.append(r.ambient)
    return Track(
        t=np.array(t, dtype=float),
        x=np.array(x, dtype=float),
        y=np.array(y, dtype=float),
        heading=np.array(h, dtype=float),
        sample_t=np.array(st, dtype=float),
        proximity=np.array(prox, dtype=float).reshape(-1, SENSORS),
        ambient=np.array(amb, dtype=float).reshape(-1, SENSORS),
        from_camera=from_camera,
    )


def check_khepera(rec: Recording, label: str) -> None:
    """CompareError unless ``rec``'s robot is a Khepera, as its world's snapshot says."""
    assert rec.info is not None
    agent = rec.info.agent
    snap = rec.snapshot
    if snap is None:
        raise CompareError(
            f"{label} ({rec.path}) has no world snapshot: cannot tell what robot {agent} is"
            + (f" ({rec.truncated})" if rec.truncated else "")
        )
    kinds = {a.id: a.type for a in snap.agents}
    if agent not in kinds:
        raise CompareError(f"{label} ({rec.path}): robot {agent} is not in its world's snapshot")
    if kinds[agent] != ROBOT_TYPE:
        raise CompareError(
            f"{label} ({rec.path}): robot {agent} is a {kinds[agent]}, not a {ROBOT_TYPE}: "
            "only Khepera runs are compared"
        )


def compare(a: Recording, b: Recording, labels: tuple[str, str] | None = None) -> Comparison:
    """Run ``b`` against run ``a``; CompareError when they cannot be compared."""
    la, lb = labels or (a.path.stem, b.path.stem)
    if la == lb:
        la, lb = f"{la} (A)", f"{lb} (B)"
    for rec, label in ((a, la), (b, lb)):
        check_khepera(rec, label)
    ta, tb = robot_track(a), robot_track(b)
    for rec, tr, label in ((a, ta, la), (b, tb, lb)):
        if not len(tr.t):
            assert rec.info is not None
            why = f": {rec.truncated}" if rec.truncated else ""
            raise CompareError(
                f"{label} ({rec.path}) is empty: no frames of robot {rec.info.agent}{why}"
            )
    warnings: list[str] = []
    snap, map_from = _map(a, b, la, lb, warnings)
    side_a = _side(a, ta, la, snap)
    side_b = _side(b, tb, lb, snap)
    for side in (side_a, side_b):
        if side.truncated:
            warnings.append(
                f"{side.label} is cut short ({side.truncated}): compared as far as it goes"
            )
        elif side.status == "unknown":
            warnings.append(f"{side.label} ends without saying how: compared as far as it goes")
    ends = (float(ta.t[-1]), float(tb.t[-1]))
    if abs(ends[0] - ends[1]) > 0.5:
        short, long_ = (side_a, side_b) if ends[0] < ends[1] else (side_b, side_a)
        warnings.append(
            f"{short.label}'s robot is recorded for {min(ends):.1f} s, {long_.label}'s for "
            f"{max(ends):.1f} s: the final poses are each run's last"
        )
    start_offset = math.hypot(ta.x[0] - tb.x[0], ta.y[0] - tb.y[0])
    if start_offset > 20.0:
        warnings.append(
            f"the runs start {start_offset:.0f} mm apart: not the same start pose, "
            "so the final pose error mixes that offset in"
        )
    final_error = math.hypot(ta.x[-1] - tb.x[-1], ta.y[-1] - tb.y[-1])
    heading_error = _wrap(float(tb.heading[-1] - ta.heading[-1]))
    ratio: float | None = None
    if side_a.path_mm > 1.0:
        ratio = side_b.path_mm / side_a.path_mm
    else:
        warnings.append(f"{la}'s robot did not move: no path length ratio")
    n, span, sensors = _sensor_diffs(ta, tb)
    if n < MIN_ALIGNED:
        warnings.append(
            "fewer than two time-aligned sensor samples "
            f"({len(ta.sample_t)} in {la}, {len(tb.sample_t)} in {lb}): no sensor differences"
        )
    return Comparison(
        a=side_a,
        b=side_b,
        map_from=map_from,
        start_offset_mm=round(start_offset, 1),
        final_pose_error_mm=round(final_error, 1),
        final_heading_error_rad=round(heading_error, 4),
        path_length_ratio=None if ratio is None else round(ratio, 3),
        aligned_samples=n,
        aligned_span_s=round(span, 2),
        ir_mean_diff=sensors[0],
        ir_mean_abs_diff=sensors[1],
        ambient_mean_diff=sensors[2],
        ambient_mean_abs_diff=sensors[3],
        warnings=warnings,
    )


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def _has_obstacles(snap: WorldSnapshot | None) -> bool:
    return snap is not None and any(i.category == "obstacle" for i in snap.items)


def _map(
    a: Recording, b: Recording, la: str, lb: str, warnings: list[str]
) -> tuple[WorldSnapshot | None, str]:
    """The map both tracks are judged on: A's, unless only B's has obstacles."""
    sa, sb = a.snapshot, b.snapshot
    if _has_obstacles(sa) and _has_obstacles(sb):
        assert sa is not None and sb is not None
        if (sa.width, sa.height, len(sa.items)) != (sb.width, sb.height, len(sb.items)):
            warnings.append(f"the two worlds' maps differ: collisions counted on {la}'s")
        return sa, la
    if _has_obstacles(sb):
        return sb, lb
    return (sa, la) if sa is not None else (sb, lb if sb is not None else "")


def _side(rec: Recording, tr: Track, label: str, snap: WorldSnapshot | None) -> Side:
    assert rec.info is not None
    steps = np.hypot(np.diff(tr.x), np.diff(tr.y))
    steps[steps > JUMP_MM] = 0.0  # an edit or a teleport, not travel (as the summary counts)
    collisions, contact = (0, 0.0)
    if snap is not None and len(tr.x):
        # Walls and obstacles only: the two runs' other robots are not the same ones.
        me = contacts.agent_info(rec.snapshot, rec.info.agent)
        radius = contacts.radius_of(rec.snapshot, rec.info.agent)
        gaps = contacts.map_contact(snap, radius, tr.x, tr.y, tr.heading, me)
        collided, contact = contacts.count_collisions(gaps, tr.t)
        collisions = sum(collided.values())
    return Side(
        label=label,
        path=str(rec.path),
        request_id=rec.info.request_id,
        world=rec.info.world,
        agent=rec.info.agent,
        ctx=rec.info.ctx,
        filename=rec.info.filename,
        status=rec.end.status if rec.end else "unknown",
        duration_s=round(float(tr.t[-1] - tr.t[0]), 3),
        frames=len(tr.t),
        samples=len(tr.sample_t),
        start_pose=(
            round(float(tr.x[0]), 1),
            round(float(tr.y[0]), 1),
            round(float(tr.heading[0]), 4),
        ),
        final_pose=(
            round(float(tr.x[-1]), 1),
            round(float(tr.y[-1]), 1),
            round(float(tr.heading[-1]), 4),
        ),
        path_mm=round(float(steps.sum()), 1),
        collisions=collisions,
        contact_s=round(contact, 2),
        truncated=rec.truncated,
        poses_from="camera" if tr.from_camera else "frames",
    )


def aligned_samples(ta: Track, tb: Track) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t, a, b)``: A's sample times within the span B covers, A's readings there and B's
    interpolated at those times; readings are samples x 16 (the 8 IR, then the 8 ambient)."""
    width = 2 * SENSORS
    if len(ta.sample_t) < 1 or len(tb.sample_t) < MIN_ALIGNED:
        return np.zeros(0), np.zeros((0, width)), np.zeros((0, width))
    order = np.argsort(tb.sample_t, kind="stable")
    bt = tb.sample_t[order]
    b_read = np.hstack([tb.proximity, tb.ambient])[order]
    inside = (ta.sample_t >= bt[0]) & (ta.sample_t <= bt[-1])
    t = ta.sample_t[inside]
    a_read = np.hstack([ta.proximity, ta.ambient])[inside]
    b_at = np.column_stack([np.interp(t, bt, b_read[:, k]) for k in range(width)])
    return t, a_read, b_at.reshape(-1, width)


def _sensor_diffs(ta: Track, tb: Track) -> tuple[int, float, list[list[float]]]:
    t, a_read, b_read = aligned_samples(ta, tb)
    if len(t) < MIN_ALIGNED:
        return len(t), 0.0, [[], [], [], []]
    diff = b_read - a_read
    signed = diff.mean(axis=0)
    absolute = np.abs(diff).mean(axis=0)

    def r(v: np.ndarray) -> list[float]:
        return [round(float(x), 2) for x in v]

    return (
        len(t),
        float(t[-1] - t[0]),
        [r(signed[:SENSORS]), r(absolute[:SENSORS]), r(signed[SENSORS:]), r(absolute[SENSORS:])],
    )
