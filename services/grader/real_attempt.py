"""A submission's real-robot attempt: queued on a real arena's agent context, scored from its
recording the same way as a simulated episode (docs/COURSES.md, "A real-robot attempt").

After a submission's simulated episodes (and only once they passed, where the assignment
says ``after = "simulation-passed"``), the grader queues the student's file on the arena's
robot like a student's deploy run, under its own service account (``wart course
assignment add`` grants it ``deploy`` on that robot): the context's queue, slot and lease,
the runner's sandbox, the bridge and the serial link. When the run ends the grader fetches
the context's recording of it (common/recording/), turns the robot's poses and IR samples
into the same events as a simulated episode (zones reached, distance, time) and scores it
with the assignment's rule; a grader function runs on it on a runner, as after a simulated
episode. The result is the submission's "real" row.

What the lab did (the arena is not there, the robot left the world because its bridge or
serial link died, the runner stopped, the context stopped) is the lab's fault: the attempt
is queued again, free, up to ``REAL_RETRIES`` times, then the row says so (cause ``lab``).
"""

from __future__ import annotations

import itertools
import json
import logging
import math
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

from common.client.agent_client import FINAL, AgentClient
from common.client.lab_client import LabClient
from common.lab_errors import LabError
from common.messages import STUDENT_CAUSES, EpisodeReport, EpisodeResult, RequestStatus
from common.recording.reader import Recording, read_recording
from common.sim2d import maps
from services.grader.assignment import Assignment
from services.grader.grading_db import Pending
from services.grader.score import judge, metrics

log = logging.getLogger("wart.grader.real")

REAL_RETRIES = 3  # a lab fault queues the attempt again, free, this many times
RETRY_WAIT_S = 5.0  # times the try: a robot or bridge coming back takes seconds
POSE_GAP_S = 1.5  # no pose of the robot for this long in its run: the arena lost it
SAMPLE_EVERY_S = 0.1  # the grader function's poses and IR, as in simulation
# (cause, detail) from a finished run's reason: the runner's words for the student's code
_STUDENT_REASONS = (
    ("raised", "exception"),
    ("hung", "timeout"),
    ("out of memory", "memory"),
    ("output flood", "output"),
    ("CPU time", "cpu"),
)
# A grader function on a runner: the episode's data -> (metrics, error, line)
GradeFunction = Callable[[Assignment, bytes], tuple[dict[str, float], str, int | None]]


class RealAttempt:
    """Runs real attempts one at a time (a real robot runs one controller at once)."""

    def __init__(
        self,
        client: LabClient,
        grade: GradeFunction,
        stop: threading.Event,
        relogin: Callable[[], object] = lambda: None,
    ) -> None:
        self.client = client
        self.relogin = relogin  # a grant made after the grader logged in needs a new session
        self.grade = grade
        self.stop = stop

    def run(self, sub: Pending, a: Assignment, map_text: str) -> EpisodeResult:
        reruns = 0
        while True:
            result, lab_fault = self._once(sub, a, map_text, reruns)
            if not lab_fault or reruns >= REAL_RETRIES or self.stop.is_set():
                return result
            reruns += 1
            log.warning("real attempt of %s: the lab's fault (%s); queued again, free", sub.id,
                        result.detail)  # fmt: skip
            self.stop.wait(RETRY_WAIT_S * reruns)

    def _once(
        self, sub: Pending, a: Assignment, map_text: str, reruns: int
    ) -> tuple[EpisodeResult, bool]:
        base = {"episode": a.episodes, "seed": 0, "real": True, "lab_reruns": reruns}

        def lab(detail: str) -> tuple[EpisodeResult, bool]:
            return EpisodeResult(cause="lab", detail=detail[:256], **base), True  # type: ignore[arg-type]

        agents = AgentClient(self.client, a.real_arena)
        try:
            # A new session each attempt: the grant of deploy on the robot (wart course
            # assignment add) may be newer than the grader's session, which carries its grants.
            self.relogin()
            agents.join()
        except LabError as exc:
            return lab(f"the real arena {a.real_arena} did not answer: {exc}")
        try:
            queued = agents.queue(a.real_robot, "deploy", source=sub.source, filename=sub.filename)
            log.info("real attempt of %s queued on %s/%s (%s, position %d)", sub.id,
                     a.real_arena, a.real_robot, queued.request_id, queued.position)  # fmt: skip
            wait = (queued.start_eta or 0.0) + queued.slot_seconds + 120.0
            final = _wait_final(agents, queued.request_id, wait, self.stop)
            if final is None:
                return lab(f"the real arena {a.real_arena} did not end the run in {wait:.0f} s")
            if final.status != "finished":
                return lab(f"the real run was {final.status}: {final.reason}")
            recording = _fetch(agents, queued.request_id)
        except LabError as exc:
            return lab(f"the real arena {a.real_arena}: {exc}")
        finally:
            agents.leave()
        if recording is None:
            return lab("the real run's recording could not be read")
        lost = pose_gap(recording, final, a.real_time_limit)
        if lost:
            return lab(lost)
        cause, detail = _cause(final)
        report, data = real_episode(recording, a, map_text, cause)
        if a.grader_file:
            try:
                values, error, line = self.grade(a, episode_json(data))
            except RuntimeError as exc:
                return lab(str(exc))
            report = _with_metrics(report, values, error, line)
        score, teacher = judge(a.score, report, a.real_time_limit, a.grader_file)
        shown = metrics(report, sorted(a.score.zones), a.real_time_limit)
        if teacher:
            detail = f"the teacher's grader failed: {teacher}"
            return EpisodeResult(cause="grader", detail=detail[:256], metrics=shown, **base), False  # type: ignore[arg-type]
        if cause in STUDENT_CAUSES:
            detail = f"your controller: {detail}"
        if reruns:
            detail = f"{detail} (queued again {reruns}x after a lab fault, free)"
        return (
            EpisodeResult(
                cause=cause,  # type: ignore[arg-type]
                detail=f"on {a.real_arena}/{a.real_robot}: {detail}"[:256],
                score=round(score, 4),
                metrics=shown,
                **base,  # type: ignore[arg-type]
            ),
            False,
        )


def _wait_final(
    agents: AgentClient, request_id: str, wait: float, stop: threading.Event
) -> RequestStatus | None:
    deadline = time.monotonic() + wait
    while time.monotonic() < deadline and not stop.is_set():
        final = agents.wait_status(request_id, FINAL, timeout=5.0, stop=stop)
        if final is not None:
            return final
        try:  # a missed event: ask where it stands
            now = agents.request_status(request_id)
        except LabError:
            continue
        if now is not None and now.status is not None and now.status.status in FINAL:
            return now.status
    return None


def _fetch(agents: AgentClient, request_id: str) -> Recording | None:
    """The run's recording, once the context has closed it (its trail after the slot)."""
    with tempfile.TemporaryDirectory(prefix="wart-real-") as tmp:
        for _ in range(30):
            listed = {r.name: r for r in agents.recordings().recordings}
            found = listed.get(request_id)
            if found is not None and found.status:
                path = agents.download(request_id, Path(tmp) / f"{request_id}.mcap")
                return read_recording(path)
            time.sleep(1.0)
    return None


def pose_gap(rec: Recording, final: RequestStatus, limit: float) -> str:
    """What was missing if the robot's pose did not come all through its run (up to ``limit``
    s), else "": the bridge died, its serial link or the robot went offline, the camera lost
    it. The context's slot runs on regardless; the grader tells it from the recording."""
    times = sorted(p.t for p in rec.poses)
    start = final.start if final.start is not None else (times[0] if times else 0.0)
    end = min(final.end if final.end is not None else start + limit, start + limit)
    if end - start < POSE_GAP_S:
        return ""  # too short a run to tell (the controller ended it at once)
    if not times:
        return "the real arena recorded no pose of the robot: its bridge or camera lost it"
    edges = [start, *(t for t in times if start <= t <= end), end]
    for a, b in itertools.pairwise(edges):
        if b - a > POSE_GAP_S:
            return (
                f"the real arena lost the robot from {a - start:.1f} s to {b - start:.1f} s of "
                "its run (no pose: its bridge, serial link or camera went away)"
            )
    return ""


def _cause(final: RequestStatus) -> tuple[str, str]:
    reason = final.reason or "its slot ended"
    if "slot ended" in reason:
        return "ok", f"ran its slot ({reason})"
    for words, cause in _STUDENT_REASONS:
        if words in reason:
            return cause, reason
    if "finished" in reason or "returned" in reason:
        return "finished", reason
    return "ended", reason


def real_episode(
    rec: Recording, a: Assignment, map_text: str, cause: str
) -> tuple[EpisodeReport, dict[str, object]]:
    """The run's events (as a simulated episode's) and a grader function's input."""
    world = maps.build_world(maps.parse_map(map_text, source="assignment map"), name="real")
    zones = list(world.zones.values())
    # The recording's poses are its run's robot's (the context records that one).
    poses = sorted(((p.t, p.record) for p in rec.poses), key=lambda tp: tp[0])
    samples = sorted(
        ((s.t, s.record) for s in rec.samples if s.record.agent == a.real_robot),
        key=lambda ts: ts[0],
    )
    start = poses[0][0] if poses else (samples[0][0] if samples else 0.0)
    reached: dict[str, float] = {}
    distance = 0.0
    last: tuple[float, float] | None = None
    rows: list[list[float]] = []
    next_row = 0.0
    ir_at = 0
    for t, p in poses:
        at = round(t - start, 3)
        if at > a.real_time_limit:
            break
        x, y = p.pose.position.x * 1000.0, p.pose.position.y * 1000.0
        q = p.pose.orientation
        heading = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
        if last is not None:
            distance += math.hypot(x - last[0], y - last[1])
        last = (x, y)
        for zone in zones:
            if zone.id not in reached and zone.contains(x, y):
                reached[zone.id] = at
        if at + 1e-9 >= next_row:
            while ir_at + 1 < len(samples) and samples[ir_at + 1][0] <= t:
                ir_at += 1
            ir = list(samples[ir_at][1].proximity[:8]) if samples else []
            rows.append([at, round(x, 2), round(y, 2), round(heading, 4), *(ir + [0] * 8)[:8]])
            next_row += SAMPLE_EVERY_S
    seconds = min(a.real_time_limit, rows[-1][0] if rows else 0.0)
    report = EpisodeReport(
        cause=cause,  # type: ignore[arg-type]
        sim_seconds=round(seconds, 3),
        reached=reached,
        distance_mm=round(distance, 1),
    )
    data: dict[str, object] = {
        "format": 1,
        "source": "real",
        "robot": a.real_robot,
        "seed": 0,
        "time_limit": a.real_time_limit,
        "cause": cause,
        "sim_seconds": report.sim_seconds,
        "distance_mm": report.distance_mm,
        "poses": [r[:4] for r in rows],
        "ir": [[r[0], *r[4:]] for r in rows],
        "contacts": [],  # a real arena measures no contacts (yet)
        "events": {"reached": reached, "delivered": {}, "collisions": {}},
        "zones": {z.id: {"kind": z.kind, "x": z.x, "y": z.y} for z in zones},
    }
    return report, data


def _with_metrics(
    report: EpisodeReport, values: dict[str, float], error: str, line: int | None
) -> EpisodeReport:
    return EpisodeReport(
        cause=report.cause,
        sim_seconds=report.sim_seconds,
        reached=report.reached,
        distance_mm=report.distance_mm,
        grader_metrics=values,
        grader_error=error[:256],
        grader_line=line,
    )


def episode_json(data: dict[str, object]) -> bytes:
    return json.dumps(data, separators=(",", ":")).encode()
