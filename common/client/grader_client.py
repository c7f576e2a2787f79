"""A student's or teacher's calls on the grader: submit, one's submissions, the leaderboard."""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import zenoh

from common import keys
from common.auth import AuthError
from common.client.lab_client import LabClient
from common.lab_errors import LabError
from common.messages import (
    AssignmentInfo,
    AssignmentList,
    ClassQuery,
    ClassTable,
    ClassTables,
    CompetitionChanged,
    CompetitionQuery,
    CompetitionRun,
    EpisodeReplayGet,
    GradingChanged,
    Leaderboard,
    LeaderboardQuery,
    Message,
    MessageError,
    MyAssignments,
    OkReply,
    RecordingChunk,
    SetPseudonym,
    Standings,
    SubmissionInfo,
    SubmissionList,
    SubmissionsQuery,
    Submit,
    SubmitAccepted,
)

GRADER = "grader"
log = logging.getLogger("wart.client")
M = TypeVar("M", bound=Message)


class GraderClient:
    def __init__(self, client: LabClient, grader: str = GRADER) -> None:
        self.client = client
        self.grader = grader
        self.key = keys.grader_request(client.realm, grader)

    def _ask(self, message: Message, expected: type[M], what: str) -> M:
        return self.client._ask(
            self.key,
            message,
            expected,
            what,
            not_found="no grader answered (is `wart grader` running?)",
            timeout=10.0,
        )

    def submit(
        self, assignment: str, source: bytes, filename: str = "controller.py"
    ) -> SubmitAccepted:
        message = Submit(assignment=assignment, source=source, filename=filename)
        return self._ask(message, SubmitAccepted, "submit")

    def submissions(
        self, assignment: str, user: str | None = None, submission: str | None = None
    ) -> list[SubmissionInfo]:
        query = SubmissionsQuery(assignment=assignment, user=user, submission=submission)
        return list(self._ask(query, SubmissionList, "submissions").submissions)

    def wait_graded(self, assignment: str, submission: str, timeout: float) -> SubmissionInfo:
        """The submission once graded (or failed); TimeoutError after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while True:
            found = self.submissions(assignment, submission=submission)
            if found and found[0].status in ("graded", "failed"):
                return found[0]
            if time.monotonic() >= deadline:
                raise TimeoutError(f"{submission} not graded within {timeout:g} s")
            time.sleep(0.5)

    def fetch_episode(self, assignment: str, submission: str, episode: int, dest: Path) -> Path:
        """One graded episode's recording (one's own; a teacher: anyone's) into ``dest``.

        Written to ``dest.part`` first: an interrupted download leaves no file that looks whole.
        """
        part = dest.with_name(dest.name + ".part")
        offset, total = 0, None
        with part.open("wb") as out:
            while total is None or offset < total:
                ask = EpisodeReplayGet(
                    assignment=assignment, submission=submission, episode=episode, offset=offset
                )
                chunk = self._ask(ask, RecordingChunk, f"episode {episode} of {submission}")
                total = chunk.total
                if not chunk.data and offset < total:
                    raise LabError(f"episode {episode} of {submission} shrank: try again")
                out.write(chunk.data)
                offset += len(chunk.data)
        part.replace(dest)
        return dest

    def assignments(self) -> list[AssignmentInfo]:
        """The assignments of my courses."""
        return list(self._ask(MyAssignments(), AssignmentList, "assignments").assignments)

    def set_pseudonym(self, assignment: str, pseudonym: str) -> str:
        """Show under ``pseudonym`` on the leaderboards of the assignment's course ("": none)."""
        message = SetPseudonym(assignment=assignment, pseudonym=pseudonym)
        return self._ask(message, OkReply, "pseudonym").detail

    def leaderboard(self, assignment: str) -> Leaderboard:
        return self._ask(LeaderboardQuery(assignment=assignment), Leaderboard, "leaderboard")

    def run_competition(
        self, assignment: str, name: str | None = None, pick: str = "latest", per_heat: int = 1
    ) -> Standings:
        """Start a competition (the course's teachers): its first standings, all waiting."""
        message = CompetitionRun(
            assignment=assignment,
            name=name,
            pick=pick,  # type: ignore[arg-type]
            per_heat=per_heat,
        )
        return self._ask(message, Standings, "competition")

    def standings(self, name: str) -> Standings:
        return self._ask(CompetitionQuery(name=name), Standings, "competition")

    def watch_standings(
        self, name: str | None, on_standings: Callable[[Standings], None]
    ) -> Callable[[], None]:
        """Call ``on_standings`` with the standings of each competition the grader says
        changed (one, or all with None), as the grader gives them to this user (the
        announcement carries no entry); the returned function stops watching."""
        if name is None:
            key = keys.grader_standings_all(self.client.realm, self.grader)
        else:
            key = keys.grader_standings(self.client.realm, self.grader, name)
        # Asked on a thread of its own, in order: a query inside the Zenoh callback
        # would hold the session's thread until its answer.
        changed: queue.Queue[str | None] = queue.Queue()

        def ask() -> None:
            while (competition := changed.get()) is not None:
                try:
                    found = self.standings(competition)
                except LabError as exc:
                    log.info("the standings of %s: %s", competition, exc)
                    continue
                on_standings(found)

        threading.Thread(target=ask, name="standings", daemon=True).start()
        unwatch = self._watch(key, CompetitionChanged, lambda c: changed.put(c.competition))

        def stop() -> None:
            unwatch()
            changed.put(None)

        return stop

    def class_tables(self, course: str | None = None) -> list[ClassTable]:
        """The teacher's view of ``course`` (None: of every course I teach; none for a
        student). LabError if refused (a student naming a course)."""
        return list(self._ask(ClassQuery(course=course), ClassTables, "class").tables)

    def watch_changes(self, on_change: Callable[[GradingChanged], None]) -> Callable[[], None]:
        """Call ``on_change`` as submissions of any course change state (queued, running,
        graded, failed); the returned function stops watching."""
        return self._watch(
            keys.grader_changed_all(self.client.realm, self.grader), GradingChanged, on_change
        )

    def _watch(
        self, key: str, kind: type[M], on_message: Callable[[M], None]
    ) -> Callable[[], None]:
        """A subscriber that passes on what a service sealed (the grader), nothing else."""

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                principal, message = self.client.verifier.open(
                    str(sample.key_expr), sample.payload, kind
                )
            except (AuthError, MessageError) as exc:
                log.warning("ignored %s: %s", kind.__name__, exc)
                return
            if not principal.has("lease"):  # a service's seal (the grader's), not a person's
                log.warning("ignored %s sealed by %s, not a service", kind.__name__, principal.user)
                return
            on_message(message)

        subscriber = self.client.z.declare_subscriber(key, on_sample)
        return subscriber.undeclare


def submitted_words(accepted: SubmitAccepted) -> str:
    """What a student is told when a submission is taken."""
    words = (
        f"submitted {accepted.submission}: place {accepted.position} in the queue; "
        f"{accepted.used} of {accepted.quota} graded runs in the last 24 h"
    )
    return words + (f"; {accepted.note}" if accepted.note else "")
