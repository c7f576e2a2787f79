"""A run's result summary, from its recording alone: how far, how long, what it hit, how it ended.

Collisions are counted from the frames (common/recording/contacts.py): the
robot's footprint (disc and tongs) touching the arena's edge, an obstacle or
another robot; each stretch of touching one kind of thing is one collision
with it, as the dry run counts. Objects gripped are the robot's fingers going to ``holding``;
objects delivered are those that end inside a nest zone having started
outside. Errors are read from the output: a traceback's last line of the
controller's file, and the exception that ended it.
"""

from __future__ import annotations

import re

import msgspec
import numpy as np

from common.messages import WorldSnapshot
from common.recording import contacts
from common.recording.reader import Recording

MOVING_MM_S = 5.0  # slower than this is standing (sensor noise, a push)
JUMP_MM = 200.0  # a step longer than this between frames is an edit or a teleport, not travel

_TRACE = re.compile(r'File "([^"]+)", line (\d+)')
_EXC = re.compile(r"^([A-Za-z_][\w.]*(?:Error|Exception|Interrupt|Exit))(?::\s*(.*))?$")


class ErrorInfo(msgspec.Struct, frozen=True, kw_only=True):
    kind: str  # the exception's name
    message: str
    file: str
    line: int | None  # in the controller's file, when the traceback names it


class Summary(msgspec.Struct, frozen=True, kw_only=True):
    """The numbers of one run (``wart report`` prints them; stored as ``<run>.summary.json``)."""

    request_id: str
    user: str
    agent: str
    world: str
    ctx: str
    mode: str
    filename: str
    start: float
    duration_s: float
    status: str  # finished | cancelled | refused | unknown (a truncated file)
    reason: str
    distance_mm: float
    moving_s: float
    collisions: int  # with anything: the sum of collided_with
    contact_s: float
    gripped: int
    delivered: int
    frames: int
    samples: int
    commands: int
    output_lines: int
    errors: list[ErrorInfo]
    truncated: str = ""
    # The world's kind: "real" runs on robots (durations are wall-clock time), "sim" simulated.
    world_kind: str = "sim"
    # Collisions by what was hit: "wall" (the arena's edge), "obstacle", "robot".
    collided_with: dict[str, int] = msgspec.field(default_factory=dict)


def summarize(rec: Recording) -> Summary:
    info = rec.info
    assert info is not None  # read_recording refuses a file without one
    xs, ys, hs, ts, fingers = track(rec, info.agent)
    distance, moving = _travel(xs, ys, ts)
    snap = rec.snapshot
    collided: dict[str, int] = {}
    contact = 0.0
    if snap is not None and len(xs):
        me = contacts.agent_info(snap, info.agent)
        gaps = contacts.map_contact(snap, contacts.radius_of(snap, info.agent), xs, ys, hs, me)
        gaps["robot"] = contacts.robot_gaps(rec, info.agent, snap)
        collided, contact = contacts.count_collisions(gaps, ts)
    gripped = int(np.count_nonzero((fingers[1:] == 2) & (fingers[:-1] != 2))) if len(fingers) else 0
    duration = float(ts[-1] - ts[0]) if len(ts) > 1 else 0.0
    end = rec.end
    return Summary(
        request_id=info.request_id,
        user=info.user,
        agent=info.agent,
        world=info.world,
        ctx=info.ctx,
        mode=info.mode,
        filename=info.filename,
        start=info.start,
        duration_s=round(duration, 3),
        status=end.status if end else "unknown",
        reason=end.reason if end else "the recording ends without saying (cut short)",
        distance_mm=round(distance, 1),
        moving_s=round(moving, 2),
        collisions=sum(collided.values()),
        collided_with=collided,
        contact_s=round(contact, 2),
        gripped=gripped,
        delivered=_delivered(rec, snap),
        frames=len(rec.frames),
        samples=len(rec.samples),
        commands=len(rec.commands),
        output_lines=len(rec.output),
        errors=_errors([o.record.message for o in rec.output], info.filename),
        world_kind=snap.kind if snap is not None else "sim",
        truncated=rec.truncated,
    )


def track(
    rec: Recording, agent: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The agent's x, y (mm), heading (rad), sim time (s) and fingers over the frames it is in."""
    xs, ys, hs, ts, fingers = [], [], [], [], []
    for stamped in rec.frames:
        f = stamped.record
        try:
            row = f.rows.index(agent)
        except ValueError:
            continue
        xs.append(f.x[row])
        ys.append(f.y[row])
        hs.append(f.heading[row] if row < len(f.heading) else 0.0)
        ts.append(f.sim_time)
        fingers.append(f.fingers[row] if row < len(f.fingers) else 0)
    return np.array(xs), np.array(ys), np.array(hs), np.array(ts), np.array(fingers, dtype=int)


def _travel(xs: np.ndarray, ys: np.ndarray, ts: np.ndarray) -> tuple[float, float]:
    if len(xs) < 2:
        return 0.0, 0.0
    steps = np.hypot(np.diff(xs), np.diff(ys))
    dt = np.diff(ts)
    steps[steps > JUMP_MM] = 0.0
    ok = dt > 0
    speed = np.zeros_like(steps)
    speed[ok] = steps[ok] / dt[ok]
    return float(steps.sum()), float(dt[ok & (speed > MOVING_MM_S)].sum())


def _delivered(rec: Recording, snap: WorldSnapshot | None) -> int:
    if snap is None or not rec.frames:
        return 0
    nests = [z for z in snap.items if z.category == "zone" and z.kind == "nest"]
    if not nests:
        return 0
    first, last = rec.frames[0].record, rec.frames[-1].record

    def in_nest(frame_rows: list[str], x: list[float], y: list[float]) -> set[str]:
        names = frame_rows[first.agents :]
        px = np.array(x[first.agents :])
        py = np.array(y[first.agents :])
        hit = np.zeros(px.shape, bool)
        for nest in nests:
            hit |= contacts.clearance(nest, px, py) <= 0
        return {n for n, h in zip(names, hit, strict=False) if h}

    before = in_nest(first.rows, first.x, first.y)
    after = in_nest(last.rows, last.x, last.y)
    return len(after - before)


def _errors(lines: list[str], filename: str) -> list[ErrorInfo]:
    """Each traceback in the output: its exception and the deepest line in the controller's file
    (the framework's frames around it are skipped when the file's name is known)."""
    base = filename.rsplit("/", 1)[-1]
    errors: list[ErrorInfo] = []
    ours: tuple[str, int] | None = None
    last: tuple[str, int] | None = None
    for raw in lines:
        for text in raw.splitlines():
            m = _TRACE.search(text)
            if m:
                last = (m.group(1), int(m.group(2)))
                if base and m.group(1).rsplit("/", 1)[-1] == base:
                    ours = last
                continue
            e = _EXC.match(text.strip())
            if e and not text[:1].isspace() and (ours or last):
                where = ours or last
                assert where is not None
                errors.append(
                    ErrorInfo(
                        kind=e.group(1),
                        message=(e.group(2) or "")[:300],
                        file=where[0],
                        line=where[1],
                    )
                )
                ours = last = None
    return errors
