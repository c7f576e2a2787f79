"""``wart grader``: submissions to assignments, graded automatically in simulation.

A student (a member of the assignment's course) sends a sealed
:class:`Submit` on ``grader/<name>/request``. The grader checks the opening,
the deadline and late policy, and the quota (graded runs in a rolling 24 h;
runs the lab failed do not count), pre-checks the controller like every
upload, writes the submission to the registry's database and queues it,
round-robin by student (services/grader/fair_queue.py). Workers take
submissions in turn and run the assignment's seeded episodes on the lab's
runners (services/grader/episodes.py), score each with the assignment's rule
and keep the per-episode table with the mean and min. On the same key:
:class:`SubmissionsQuery` (one's own; a teacher: anyone's) and
:class:`LeaderboardQuery` (best per student, hidden from students until the
deadline where the assignment says so).

Submissions not graded when the grader stops (or dies) are found again at its
start and graded then. Token: ``alive/grader/<name>``.
"""

from __future__ import annotations

import math
import queue
import re
import threading
import time
from pathlib import Path
from typing import cast

import zenoh

from common import keys, qos
from common.ask import alive_keys
from common.auth import Principal, Verifier
from common.client.service_login import ServiceLogin
from common.controller.upload_gate import PrecheckError, precheck
from common.keys import (
    AliveKind,
    grader_changed,
    grader_graded,
    grader_request,
    grader_standings,
)
from common.lab_errors import LabError
from common.messages import (
    PSEUDONYM_PATTERN,
    AssignmentInfo,
    AssignmentList,
    ClassQuery,
    ClassTables,
    CompetitionChanged,
    CompetitionQuery,
    CompetitionRun,
    EpisodeReplayGet,
    EpisodeResult,
    Graded,
    GradingChanged,
    Leaderboard,
    LeaderboardQuery,
    Message,
    MyAssignments,
    OkReply,
    SetPseudonym,
    Standings,
    SubmissionList,
    SubmissionsQuery,
    Submit,
    SubmitAccepted,
)
from common.service import RequestError, Service
from services.grader.assignment import DAY_S, Assignment
from services.grader.bans import BANNED, BanWatch
from services.grader.class_view import class_table
from services.grader.competition import CompetitionError, Competitions, own_entries
from services.grader.episode_recordings import EpisodeRecordings
from services.grader.episodes import RUNNER_WAIT_S, EpisodeRunner
from services.grader.fair_queue import FairQueue
from services.grader.grading_db import GradingStore, Pending
from services.grader.leaderboard import leaderboard
from services.grader.queue_depth import QueueDepth
from services.grader.real_attempt import RealAttempt
from services.grader.results_desk import ResultsDesk
from services.lab.database import DbError

WORKERS = 2  # submissions graded at once (a runner serves 2 episodes at once)
GRADER_TRIES = 3  # the grader's own failures on one submission before it is failed, not counted
TEACHERS = frozenset({"teacher"})
GRADER_FAILED = "the teacher's grader failed: "  # a submission's message (wart course finds it)


def info(a: Assignment) -> AssignmentInfo:
    return AssignmentInfo(
        name=a.name,
        course=a.course,
        title=a.title[:256],
        opens=a.opens,
        deadline=a.deadline,
        episodes=a.episodes,
        time_limit=a.time_limit,
        score_name=a.score_name,
        unit=a.unit,
        order=a.order,  # type: ignore[arg-type]
        quota=a.quota,
        rule=a.rule[:256],
    )


def _when(t: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(t))


class GraderService(Service):
    kind = AliveKind.GRADER

    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        name: str,
        *,
        registry_key: bytes,
        login: ServiceLogin,
        store: GradingStore,
        workers: int = WORKERS,
        runner_wait: float = RUNNER_WAIT_S,
        competitions: Path | None = None,
        graded: Path | None = None,
    ) -> None:
        super().__init__(session, realm, name)
        self.verifier = Verifier(registry_key, realm)
        self._registry_key = registry_key
        self._bans: BanWatch | None = None
        self.login = login
        self.store = store
        self.workers = workers
        self.queue: FairQueue[Pending] = FairQueue()
        self.depth = QueueDepth(session, realm, name, self.queue.__len__)
        self.episodes = EpisodeRunner(
            session, realm, lambda k, m: login.session.seal(k, m), runner_wait
        )
        self.competitions = Competitions(
            store, self.episodes, competitions or Path("competitions"), self._publish
        )
        self.recordings = EpisodeRecordings(graded or Path("graded"))
        self.results = ResultsDesk(store, self.recordings)
        self._threads: list[threading.Thread] = []
        # Real-robot attempts, one at a time (services/grader/real_attempt.py).
        self._real_stop = threading.Event()
        self.real = RealAttempt(
            login.client, self.episodes.grade_data, self._real_stop, relogin=login.login
        )
        self._reals: queue.Queue[Pending | None] = queue.Queue()
        self._submit_lock = threading.Lock()  # quota checked and submission written as one
        self._grader_failures: dict[str, int] = {}  # submission -> the grader's failed tries

    def on_start(self) -> None:
        for sub in self.store.pending():
            self.log.info("submission %s of %s was not graded: queued again", sub.id, sub.user)
            self.store.set_status(sub.id, "queued")
            self.queue.put(sub.user, sub)
        for sub in self.store.real_pending():
            self.log.info("the real-robot attempt of %s was not run: queued again", sub.id)
            self._reals.put(sub)
        for name in self.competitions.recover():
            self.log.warning("competition %s was running when the grader stopped: stopped", name)
        self._bans = BanWatch(
            self.session, self.realm, self._registry_key, self.verifier, self._banned
        )
        self.serve(grader_request(self.realm, self.ident), self._on_request, workers=2)
        for i in range(self.workers):
            thread = threading.Thread(target=self._work, name=f"grade-{i}", daemon=True)
            thread.start()
            self._threads.append(thread)
        thread = threading.Thread(target=self._work_real, name="real", daemon=True)
        thread.start()
        self._threads.append(thread)
        self.depth.start()

    def on_stop(self, timeout: float) -> None:
        if self._bans is not None:
            self._bans.close()
        self.queue.close()
        self._real_stop.set()
        self.depth.stop()
        self._reals.put(None)
        self.episodes.stop()
        deadline = time.monotonic() + timeout
        self.competitions.join(timeout / 2)
        for thread in self._threads:
            thread.join(max(0.0, deadline - time.monotonic()))

    # -- requests

    def _on_request(self, query: zenoh.Query) -> Message:
        principal, request = self.verifier.open(
            str(query.key_expr),
            query.payload,
            (
                Submit,
                SubmissionsQuery,
                LeaderboardQuery,
                SetPseudonym,
                MyAssignments,
                CompetitionRun,
                CompetitionQuery,
                ClassQuery,
                EpisodeReplayGet,
            ),
        )
        if isinstance(request, ClassQuery):
            return self._class(principal, request.course)
        if isinstance(request, MyAssignments):
            return AssignmentList(
                assignments=[info(a) for a in self.store.assignments_of(principal.user)][-500:]
            )
        if isinstance(request, CompetitionQuery):
            return self._standings(principal, request.name)
        named = cast(
            Submit
            | SubmissionsQuery
            | LeaderboardQuery
            | SetPseudonym
            | CompetitionRun
            | EpisodeReplayGet,
            request,
        )
        try:
            assignment, _map = self.store.assignment(named.assignment)
        except DbError as exc:
            raise RequestError("not_found", str(exc)) from None
        if isinstance(request, SubmissionsQuery) and "lti" in principal.roles:
            # The LTI tool catches up on scores it did not hear announced (services/lti/):
            # it reads, never writes; a submission's source is not in these answers.
            found = self.store.submissions(assignment.name, request.user, request.submission)
            return SubmissionList(submissions=found[-500:])
        role = self.store.role_in(assignment.course, principal.user)
        if role is None and not principal.has("admin"):
            raise RequestError(
                "forbidden", f"{principal.user} is not in the course {assignment.course}"
            )
        teacher = role in TEACHERS or principal.has("admin")
        if isinstance(request, CompetitionRun):
            if not teacher:
                raise RequestError(
                    "forbidden", f"only the teachers of {assignment.course} run a competition"
                )
            name = request.name or f"{assignment.name}-{time.strftime('%Y%m%d-%H%M%S')}"
            try:
                return self.competitions.start(
                    name, assignment, _map, request.pick, request.per_heat
                )
            except CompetitionError as exc:
                raise RequestError("bad_request", str(exc)) from None
        if isinstance(request, Submit):
            return self._submit(principal, request, assignment)
        if isinstance(request, SetPseudonym):
            return self._pseudonym(principal.user, assignment, request.pseudonym.strip())
        if isinstance(request, EpisodeReplayGet):
            return self.results.episode(principal.user, teacher, assignment, request)
        if isinstance(request, SubmissionsQuery):
            # A teacher names a submission by its id alone; anyone else sees only their own.
            user = request.user or (None if teacher and request.submission else principal.user)
            if user != principal.user and not teacher:
                raise RequestError("forbidden", "only the course's teachers see others' runs")
            return self.results.submissions(assignment, user, request.submission, teacher)
        return self.leaderboard(assignment, teacher)

    def _standings(self, principal: Principal, name: str) -> Standings:
        found = self.competitions.standings(name)
        if found is None:
            raise RequestError("not_found", f"no competition named {name}")
        role = self.store.role_in(found.course, principal.user)
        if role is None and not principal.has("admin"):
            raise RequestError("forbidden", f"{principal.user} is not in the course {found.course}")
        if role in TEACHERS or principal.has("admin"):
            return found
        try:
            a, _map = self.store.assignment(found.assignment)
            hidden = a.hidden and time.time() < a.deadline
        except DbError:  # its assignment is gone: nothing says the standings are public
            hidden = True
        if not hidden:
            return found
        team = self.store.teams(found.course).get(principal.user, principal.user)
        return own_entries(found, principal.user, team)

    def _class(self, principal: Principal, course: str | None) -> ClassTables:
        """The teacher's view of ``course`` (None: of each course the asker teaches)."""
        if course is None:
            courses = self.store.taught_by(principal.user)
        else:
            title = self.store.course_title(course)
            if title is None:
                raise RequestError("not_found", f"no course named {course}")
            role = self.store.role_in(course, principal.user)
            if role not in TEACHERS and not principal.has("admin"):
                raise RequestError(
                    "forbidden", f"only the teachers of {course} see its class (whole roster)"
                )
            courses = [(course, title)]
        queued = [sub.id for _user, sub in self.queue.order()]
        return ClassTables(
            tables=[
                class_table(
                    name,
                    title,
                    self.store.students(name),
                    self.store.course_submissions(name),
                    queued,
                )
                for name, title in courses[:100]
            ]
        )

    def _changed(self, sub: Pending, status: str, course: str | None = None) -> None:
        """Say that ``sub`` changed (no score, no name: each page asks for what it may see)."""
        try:
            course = course or self.store.assignment(sub.assignment)[0].course
            key = grader_changed(self.realm, self.ident, course)
            change = GradingChanged(
                course=course,
                assignment=sub.assignment,
                submission=sub.id,
                status=status,  # type: ignore[arg-type]
                at=time.time(),
            )
            self.session.put(key, self.login.session.seal(key, change), **qos.of(grader_changed))
        except Exception as exc:  # a page that misses it catches up at its next refresh
            self.log.warning("could not publish the change of %s: %s", sub.id, exc)

    def _publish(self, standings: Standings) -> None:
        """Say the standings changed: anyone may read a put, so it carries no entry."""
        key = grader_standings(self.realm, self.ident, standings.competition)
        changed = CompetitionChanged(
            competition=standings.competition,
            assignment=standings.assignment,
            course=standings.course,
            status=standings.status,
            heat=standings.heat,
            at=standings.at,
        )
        self.session.put(key, self.login.session.seal(key, changed), **qos.of(grader_standings))

    def _submit(self, principal: Principal, request: Submit, a: Assignment) -> Message:
        now = time.time()
        if now < a.opens:
            raise RequestError("forbidden", f"{a.name} opens at {_when(a.opens)}")
        late_days = 0
        if now > a.deadline:
            if a.late == "refuse":
                raise RequestError(
                    "forbidden", f"the deadline of {a.name} was {_when(a.deadline)}: closed"
                )
            late_days = math.ceil((now - a.deadline) / DAY_S)
        try:
            precheck(request.source, request.filename)
        except PrecheckError as exc:
            raise RequestError("bad_request", f"not submitted: {exc}") from None
        if a.real_arena and not self._arena_alive(a.real_arena):
            raise RequestError(
                "not_found",
                f"{a.name} asks for a real-robot attempt on the arena {a.real_arena}, which is "
                f"not in the lab (no agent context {a.real_arena} is alive): nothing submitted; "
                "tell your teacher",
            )
        user = principal.user
        with self._submit_lock:
            since = now - DAY_S
            used = self.store.counted_since(a.name, user, since)
            if used >= a.quota:
                oldest = self.store.oldest_counted_since(a.name, user, since) or now
                raise RequestError(
                    "forbidden",
                    f"quota: {used} of {a.quota} graded runs in the last 24 h; the next is "
                    f"possible at {_when(oldest + DAY_S)} (runs the lab failed do not count)",
                    retry_after=max(1.0, oldest + DAY_S - now),
                )
            sub = self.store.add_submission(
                a.name, user, request.filename, request.source, late_days
            )
            position = self.queue.put(user, sub)
        self._changed(sub, "queued", a.course)
        self.log.info("submission %s of %s to %s queued (%d)", sub.id, user, a.name, position)
        note = ""
        if late_days:
            note = f"late by {late_days} day(s): {late_days * a.penalty_per_day:g} off the score"
        return SubmitAccepted(
            submission=sub.id,
            position=position,
            used=used + 1,
            quota=a.quota,
            late_days=late_days,
            note=note,
        )

    def _arena_alive(self, arena: str) -> bool:
        key = keys.alive(self.realm, AliveKind.CONTEXT, arena)
        try:
            return bool(alive_keys(self.session, key, what=f"arena {arena}", timeout=2.0))
        except LabError as exc:  # the session closing
            self.log.debug("no arena list: %s", exc)
            return False

    def _pseudonym(self, user: str, a: Assignment, pseudonym: str) -> OkReply:
        if pseudonym and not re.match(PSEUDONYM_PATTERN, pseudonym):
            raise RequestError(
                "bad_request", "a pseudonym is 1 to 32 letters, digits, spaces, '_', '-', '.'"
            )
        try:
            self.store.set_pseudonym(a.course, user, pseudonym)
        except DbError as exc:
            raise RequestError("conflict", str(exc)) from None
        if not pseudonym:
            return OkReply(detail=f"your roster name shows on {a.course}'s leaderboards")
        return OkReply(detail=f"you show as {pseudonym} on {a.course}'s leaderboards")

    def leaderboard(self, a: Assignment, teacher: bool) -> Leaderboard:
        return leaderboard(self.store, a, teacher)

    # -- grading

    def _banned(self, user: str) -> None:
        for sub in self.queue.remove_user(user):
            self._not_graded_banned(sub)

    def _not_graded_banned(self, sub: Pending) -> None:
        self.log.info("submission %s of %s not graded: the account is banned", sub.id, sub.user)
        self._fail_uncounted(sub, [], BANNED)
        self._changed(sub, "failed")

    def _work(self) -> None:
        while True:
            item = self.queue.get()
            if item is None:
                return
            _user, sub = item
            if self._bans is not None and self._bans.before_ban(sub.user, sub.submitted_at):
                self._not_graded_banned(sub)  # taken from the queue as the ban came
                continue
            try:
                with self.depth.grading():
                    self._grade(sub)
                self._grader_failures.pop(sub.id, None)
            except Exception as exc:
                self._grader_failed(sub, exc)

    def _fail_uncounted(self, sub: Pending, episodes: list[EpisodeResult], message: str) -> None:
        """A submission that could not be graded through no fault of the student's."""
        self.store.finish(
            sub.id,
            episodes,
            status="failed",
            counted=False,
            mean=None,
            low=None,
            penalty=0.0,
            message=message,
        )

    def _grader_failed(self, sub: Pending, exc: Exception) -> None:
        """The grader's own fault: queued again at the head, and given up after a few tries.

        Left "queued" without a place in the queue it waited for the grader's next
        start; one that fails every time (a broken assignment row) must not loop.
        """
        tries = self._grader_failures.get(sub.id, 0) + 1
        self._grader_failures[sub.id] = tries
        self.log.error(
            "grading %s failed (try %d of %d)", sub.id, tries, GRADER_TRIES, exc_info=exc
        )
        if tries < GRADER_TRIES:
            self.store.set_status(sub.id, "queued", "the grader failed: queued again")
            self.queue.put_first(sub.user, sub)
            self._changed(sub, "queued")
            return
        self._grader_failures.pop(sub.id, None)
        self._fail_uncounted(
            sub,
            [],
            f"the lab could not grade it (the grader failed {tries} times: {exc}): "
            "not counted against your quota; submit again",
        )
        self._changed(sub, "failed")

    def _grade(self, sub: Pending) -> None:
        a, map_text = self.store.assignment(sub.assignment)
        self.store.set_status(sub.id, "running")
        self._changed(sub, "running", a.course)
        before = self.store.submissions(sub.assignment, sub.user, sub.id)
        graded = self.episodes.grade(
            sub,
            a,
            map_text,
            self.recordings,
            already=before[0].episodes if before else (),
            done=lambda e: self.store.add_episode(sub.id, e),
        )
        if self.stopped and graded.lab_failed:
            return  # the grader is stopping: left queued, graded at the next start
        if graded.lab_failed:
            self._fail_uncounted(
                sub,
                graded.episodes,
                f"the lab could not grade it ({graded.lab_failed}): not counted "
                "against your quota; submit again",
            )
            self.log.warning("submission %s: the lab failed: %s", sub.id, graded.lab_failed)
            self._changed(sub, "failed", a.course)
            return
        if graded.grader_failed:
            self._fail_uncounted(
                sub,
                graded.episodes,
                f"{GRADER_FAILED}{graded.grader_failed}"[:200]
                + ": not counted against your quota; your teacher is told",
            )
            self.log.warning(
                "submission %s: the teacher's grader of %s failed: %s",
                sub.id,
                a.name,
                graded.grader_failed,
            )
            return
        late = self.store.submissions(sub.assignment, sub.user, sub.id)[0].late_days
        taken = late * a.penalty_per_day
        # Stored as what comes off the mean: an addition when lower is better.
        penalty = taken if a.order == "higher" else -taken
        reruns = sum(e.lab_reruns for e in graded.episodes)
        message = f"{a.score_name}: mean {graded.mean:g}, min {graded.low:g}"
        if reruns:
            message += f"; {reruns} episode run(s) failed through the lab and ran again, free"
        self.store.finish(
            sub.id,
            graded.episodes,
            status="graded",
            counted=True,
            mean=graded.mean,
            low=graded.low,
            penalty=penalty,
            message=message,
        )
        self.log.info("submission %s of %s graded: %s", sub.id, sub.user, message)
        if a.real_arena:
            passed = all(e.cause in ("ok", "finished") for e in graded.episodes)
            if passed or a.real_after == "always":
                self.store.set_message(
                    sub.id, f"{message}; its real-robot attempt is queued on {a.real_arena}"
                )
                self._reals.put(sub)
            else:
                self.store.set_message(
                    sub.id, f"{message}; no real-robot attempt: an episode did not pass"
                )
        self._changed(sub, "graded", a.course)
        self._announce(sub, a)

    def _announce(self, sub: Pending, a: Assignment) -> None:
        """Say a submission is graded (the lti service passes scores back to an LMS).

        Published once, after the score is written, with no student and no score
        (anyone may read a put): the lti service asks for them, as a listener that
        missed this (down, unreachable) does at its next catch-up.
        """
        key = grader_graded(self.realm, self.ident)
        graded = Graded(
            submission=sub.id, assignment=a.name, course=a.course, graded_at=time.time()
        )
        try:
            self.session.put(key, self.login.session.seal(key, graded), **qos.of(grader_graded))
        except Exception as exc:  # a closing session, a lapsed login: the score is kept
            self.log.warning("could not announce submission %s as graded: %s", sub.id, exc)

    def _work_real(self) -> None:
        while True:
            sub = self._reals.get()
            if sub is None:
                return
            try:
                a, map_text = self.store.assignment(sub.assignment)
                result = self.real.run(sub, a, map_text)
                before = self.store.submissions(sub.assignment, sub.user, sub.id)[0].message
                head = before.split("; its real-robot attempt", 1)[0]
                if result.score is not None:
                    said = f"real-robot attempt: {a.score_name} {result.score:g}"
                else:
                    said = f"real-robot attempt: {result.cause}: {result.detail}"
                self.store.add_real(sub.id, result, f"{head}; {said}")
                self._changed(sub, "graded", a.course)  # the pages read the real row now
                self.log.info("real attempt of %s: %s %s", sub.id, result.cause, result.detail)
            except Exception:
                self.log.exception("the real attempt of %s failed", sub.id)
