"""Each graded episode as a recording: what a student replays of their own submission.

Every episode the grader runs is traced (every row's pose each ``TRACE_EVERY_S``
simulated seconds, the world as it began) and written as an MCAP recording in the
same format as a recorded run (common/recording/): the page's replay reads it as
it reads any run, and ``wart report`` summarises it. Files live at
``<root>/<assignment>/<user>/<submission>/episode-NN.mcap``; the newest
:data:`KEEP` submissions of each student per assignment keep theirs, so a class
that submits all term does not fill the disk.

A competition's heat of one entry is the same recording (services/grader/competition.py).
"""

from __future__ import annotations

import hashlib
import logging
import shutil
from dataclasses import dataclass
from pathlib import Path

from common.messages import EpisodeReport, RecordingChunk
from common.messages.recording import MAX_CHUNK
from common.recording import schema as s
from common.recording.writer import RecordingWriter, pose_record
from services.grader.assignment import Assignment
from services.grader.grading_db import Pending
from services.grader.heats import write_frames

log = logging.getLogger("wart.grader")

KEEP = 10  # submissions per student and assignment whose episodes stay replayable


@dataclass(frozen=True)
class EpisodeRun:
    """Whose episode a recording holds, and what ran in it."""

    ctx: str  # the assignment's (or competition's) name: the recording's context
    request_id: str
    mode: str  # "graded" or "competition"
    user: str
    world: str
    agent: str
    filename: str
    source: bytes
    time_limit: float

    @classmethod
    def of(cls, sub: Pending, a: Assignment, ctx: str, request_id: str, mode: str) -> EpisodeRun:
        """A submission's run on an assignment's robot and map."""
        return cls(ctx, request_id, mode, sub.user, a.map_name, a.robot, sub.filename,
                   sub.source, a.time_limit)  # fmt: skip


def record_episode(path: Path, run: EpisodeRun, report: EpisodeReport, began: float) -> None:
    """Write ``report``'s traced episode to ``path`` (OSError or ValueError if it cannot)."""
    writer = RecordingWriter(
        path,
        s.RunInfo(
            ctx=run.ctx,
            world=run.world,
            agent=run.agent,
            user=run.user,
            request_id=run.request_id,
            mode=run.mode,
            filename=run.filename,
            start=began,
            planned_end=began + run.time_limit,
            source_sha256=hashlib.sha256(run.source).hexdigest(),
        ),
    )
    writer.attach_source(run.filename, run.source, began)
    if report.snapshot is not None:
        writer.write(s.SNAPSHOT, report.snapshot, began)
        write_frames(writer, report.snapshot, report.frames, began)
    topic = s.pose_topic(run.agent)
    for t, x, y, heading in report.trace:
        writer.write(topic, pose_record(x, y, heading, began + t), began + t)
    for line in report.output:
        writer.write(s.OUTPUT, s.LogLine(s.stamp(began), 2, line, "controller", run.filename, 0),
                     began)  # fmt: skip
    reason = f"{report.cause}: {report.detail}" if report.detail else report.cause
    writer.finish(s.RunEnd(status="finished", reason=reason[:200], at=began + report.sim_seconds))


class EpisodeRecordings:
    """The graded episodes' recordings under ``root``, kept per student and assignment."""

    def __init__(self, root: Path, keep: int = KEEP) -> None:
        self.root = root
        self.keep = keep

    def path(self, assignment: str, user: str, submission: str, episode: int) -> Path:
        return self.root / assignment / user / submission / f"episode-{episode:02d}.mcap"

    def record(self, run: EpisodeRun, submission: str, episode: int,
               report: EpisodeReport, began: float) -> bool:  # fmt: skip
        """Write one episode; False (logged) when it could not be written: grading goes on."""
        path = self.path(run.ctx, run.user, submission, episode)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            record_episode(path, run, report, began)
        except (OSError, ValueError) as exc:
            log.warning("episode %d of %s not recorded (no replay): %s", episode, submission, exc)
            return False
        if episode == 0:
            self._prune(run.ctx, run.user)
        return True

    def has(self, assignment: str, user: str, submission: str, episode: int) -> bool:
        return self.path(assignment, user, submission, episode).is_file()

    def chunk(
        self, assignment: str, user: str, submission: str, episode: int, offset: int
    ) -> RecordingChunk:
        """Bytes of one episode's recording from ``offset``; FileNotFoundError if none is kept."""
        path = self.path(assignment, user, submission, episode)
        with path.open("rb") as f:
            total = path.stat().st_size
            f.seek(min(offset, total))
            data = f.read(MAX_CHUNK)
        return RecordingChunk(
            name=f"{submission}-{episode}", offset=min(offset, total), total=total, data=data
        )

    def _prune(self, assignment: str, user: str) -> None:
        """Keep the newest ``keep`` submissions' episodes of ``user`` on ``assignment``."""
        folder = self.root / assignment / user
        try:
            subs = sorted(
                (p for p in folder.iterdir() if p.is_dir()), key=lambda p: p.stat().st_mtime
            )
        except OSError:
            return
        for old in subs[: max(0, len(subs) - self.keep)]:
            shutil.rmtree(old, ignore_errors=True)
