"""A competition's heat of several entries in one world (``--per-heat N`` > 1).

The entries of a heat run at once on one runner (services/runner/heat.py), each team's
controller on its own robot of the assignment's map: the assignment's robot first, then
the map's other robots in order, at the assignment's start poses in order (start[i] for
the heat's i-th entry). Each entry is scored from the same heat with the assignment's
rule; its collisions are its own robot's contacts, so two entries that meet both count
one robot collision. The heat is one MCAP recording (every robot's pose, the world's
frames for a replay, each entry's file attached, the printed lines of each).
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import msgspec

from common.messages import (
    STUDENT_CAUSES,
    Heat,
    HeatEntry,
    HeatReport,
    StandingEntry,
    TraceFrame,
    WorldSnapshot,
)
from common.recording import schema as s
from common.recording.writer import RecordingWriter, pose_record
from common.sim2d import maps
from services.grader.assignment import Assignment, StartPose
from services.grader.grading_db import Pending


class HeatError(ValueError):
    """A heat of this size cannot run on this assignment: said to the teacher."""


def heat_robots(a: Assignment, map_text: str, per_heat: int) -> list[tuple[str, StartPose]]:
    """The robot and start pose of each place in a heat of ``per_heat`` entries."""
    try:
        world = maps.build_world(maps.parse_map(map_text, source="assignment map"), name="heats")
    except ValueError as exc:
        raise HeatError(f"the assignment's map: {exc}") from None
    robots = [a.robot] + [x.id for x in world.agents if x.id != a.robot]
    if per_heat > len(robots):
        raise HeatError(
            f"the map {a.map_name} has {len(robots)} robot(s) ({', '.join(robots)}): a heat "
            f"holds at most {len(robots)} entries (--per-heat {len(robots)})"
        )
    if len(a.starts) < per_heat:
        raise HeatError(
            f"{a.name} has {len(a.starts)} start pose(s): a heat of {per_heat} needs one "
            "[[start]] per entry"
        )
    if a.grader_file:
        raise HeatError(
            f"{a.name} has a grader function: heats of several entries run without one "
            "(not supported yet; --per-heat 1)"
        )
    return [(robots[i], a.starts[i]) for i in range(per_heat)]


def heat_request(
    name: str, heat: int, a: Assignment, map_text: str, subs: list[Pending], per_heat: int
) -> Heat:
    places = heat_robots(a, map_text, per_heat)
    return Heat(
        competition=name,
        heat=heat,
        map=map_text,
        seed=a.seeds[0],
        seconds=a.time_limit,
        entries=[
            HeatEntry(
                submission=sub.id,
                user=sub.user,
                agent=robot,
                x=start.x,
                y=start.y,
                heading=math.radians(start.heading_deg),
                source=sub.source,
                filename=sub.filename,
            )
            for sub, (robot, start) in zip(subs, places, strict=False)
        ],
    )


def score_heat(
    a: Assignment, request: Heat, report: HeatReport, bases: list[StandingEntry], recorded: str
) -> list[StandingEntry]:
    """Each entry's standing from the heat's report (in the request's order)."""
    out = []
    for base, e, r in zip(bases, request.entries, report.entries, strict=True):
        base = msgspec.structs.replace(base, recording=recorded)
        if r.cause == "lab":
            detail = f"the lab could not run it: {r.detail}"
            out.append(msgspec.structs.replace(base, cause="lab", detail=detail[:256]))
            continue
        score = a.score.evaluate(r, a.time_limit)
        detail = f"on {e.agent}: {r.detail}"
        if r.cause in STUDENT_CAUSES:
            detail = f"on {e.agent}: the entry's controller: {r.detail}"
        hits = r.collisions.get("robot", 0)
        if hits:
            detail += f"; {hits} collision(s) with another robot"
        out.append(
            msgspec.structs.replace(base, score=round(score, 4), cause=r.cause, detail=detail[:256])
        )
    return out


def record_heat(
    path: Path, name: str, heat: int, a: Assignment, request: Heat, report: HeatReport,
    began: float,
) -> str:  # fmt: skip
    """The heat's MCAP recording; its path."""
    first = request.entries[0]
    joined = b"".join(e.source for e in request.entries)
    writer = RecordingWriter(
        path,
        s.RunInfo(
            ctx=name,
            world=a.map_name,
            agent=first.agent,
            user=first.user,
            request_id=f"{name}-heat-{heat}",
            mode="competition",
            filename=first.filename,
            start=began,
            planned_end=began + a.time_limit,
            source_sha256=hashlib.sha256(
                first.source if len(request.entries) == 1 else joined
            ).hexdigest(),
        ),
    )
    for e in request.entries:
        writer.attach_source(f"{e.agent}-{e.user}-{e.filename}", e.source, began)
    if report.snapshot is not None:
        writer.write(s.SNAPSHOT, report.snapshot, began)
        write_frames(writer, report.snapshot, report.frames, began)
    for e, r in zip(request.entries, report.entries, strict=True):
        topic = s.pose_topic(e.agent)
        for t, x, y, heading in r.trace:
            writer.write(topic, pose_record(x, y, heading, began + t), began + t)
        for line in r.output:
            log_line = s.LogLine(s.stamp(began), 2, f"[{e.agent}] {line}", "controller",
                                 e.filename, 0)  # fmt: skip
            writer.write(s.OUTPUT, log_line, began)
    end = began + max((r.sim_seconds for r in report.entries), default=0.0)
    causes = ", ".join(f"{e.agent} {r.cause}" for e, r in zip(request.entries, report.entries,
                                                              strict=True))  # fmt: skip
    writer.finish(s.RunEnd(status="finished", reason=causes[:200], at=end))
    return str(path)


def write_frames(
    writer: RecordingWriter, snap: WorldSnapshot, frames: list[TraceFrame], began: float
) -> None:
    """A heat's or an episode's frames (every row's pose each traced step): what a replay draws."""
    n_agents = len(snap.agents)
    for tick, (t, flat) in enumerate(frames):
        n = min(len(snap.rows), len(flat) // 3)
        record = s.FrameRecord(
            tick=tick,
            sim_time=t,
            layout=snap.layout,
            agents=min(n_agents, n),
            rows=list(snap.rows[:n]),
            x=flat[0 : 3 * n : 3],
            y=flat[1 : 3 * n : 3],
            heading=flat[2 : 3 * n : 3],
            fingers=[0] * min(n_agents, n),
        )
        writer.write(s.FRAME, record, began + t)
