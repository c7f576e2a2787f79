"""A submission's episodes on the lab's runners, lab faults re-run free, then scored.

Each episode goes to a live runner (``alive/runner/*``, taken in turn) as a
sealed :class:`Episode`. A runner that dies mid-episode, does not answer, is
busy, or cannot start a sandbox is the lab's fault: the episode runs again on
a runner alive then (at most ``LAB_RETRIES`` times, waiting for one to come
back), and the count is kept (``lab_reruns``) so the student is told. Only
when the lab cannot run it at all does the submission fail, not counted
against the quota.
"""

from __future__ import annotations

import itertools
import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

import zenoh

from common import keys
from common.ask import NoReply, QueryFailed, Seal, WrongReply, alive_keys, ask
from common.keys import AliveKind
from common.lab_errors import LabError
from common.messages import (
    STUDENT_CAUSES,
    Episode,
    EpisodeReport,
    EpisodeResult,
    GradeData,
    GradeResult,
    Heat,
    HeatReport,
    Message,
)
from services.grader.assignment import Assignment
from services.grader.episode_recordings import EpisodeRecordings, EpisodeRun
from services.grader.grading_db import Pending
from services.grader.score import MissingMetric, metrics

log = logging.getLogger("wart.grader")

LAB_RETRIES = 4
RUNNER_WAIT_S = 30.0  # how long an episode waits for a runner to be alive
M = TypeVar("M", bound=Message)


def _in_words(runner: str, exc: LabError) -> str:
    """Why a runner gave no report, as the lab's reports say it."""
    if isinstance(exc, NoReply | WrongReply):
        return f"runner {runner} did not answer (it stopped or died)"
    if exc.reply is not None:
        return f"runner {runner}: {exc.reply.message}"
    if isinstance(exc, QueryFailed):
        return f"runner {runner}: {exc.reason}"
    return f"runner {runner}: {exc}"  # the grader's own session could not seal the request


@dataclass(frozen=True)
class Graded:
    episodes: list[EpisodeResult]
    mean: float | None
    low: float | None
    lab_failed: str  # "" or why the lab could not grade it
    grader_failed: str = ""  # "" or why the teacher's grader function gave no score


class EpisodeRunner:
    def __init__(
        self, session: zenoh.Session, realm: str, seal: Seal, runner_wait: float = RUNNER_WAIT_S
    ) -> None:
        self.session = session
        self.runner_wait = runner_wait
        self.realm = realm
        self.seal = seal
        self._turn = itertools.count()
        self._stop = threading.Event()

    def stop(self) -> None:
        self._stop.set()

    def runners(self) -> list[str]:
        """The runners alive now (their liveliness tokens)."""
        runners = keys.alive_of_kind(self.realm, AliveKind.RUNNER)
        try:
            found = alive_keys(self.session, runners, what="runners", timeout=2.0)
        except LabError as exc:  # the session closing
            log.debug("no runner list: %s", exc)
            return []
        return sorted({key.rsplit("/", 1)[-1] for key in found})

    def _pick(self) -> str | None:
        deadline = time.monotonic() + self.runner_wait
        while not self._stop.is_set():
            found = self.runners()
            if found:
                return found[next(self._turn) % len(found)]
            if time.monotonic() >= deadline:
                return None
            self._stop.wait(0.5)
        return None

    def once(self, request: Episode) -> EpisodeReport:
        """One try: the runner's report, or a report with cause ``lab``."""
        runner = self._pick()
        if runner is None:
            return EpisodeReport(cause="lab", detail="no runner is alive in the lab")
        key = keys.runner_episode(self.realm, runner)
        timeout = 15.0 + 1.5 * request.seconds + 10.0
        if request.grader is not None:
            timeout += request.grader_seconds + 10.0
        try:
            return self._ask(runner, key, request, EpisodeReport, timeout)
        except LabError as exc:
            return EpisodeReport(cause="lab", detail=_in_words(runner, exc)[:256])

    def _ask(self, runner: str, key: str, request: Message, expected: type[M], timeout: float) -> M:
        return ask(
            self.session,
            key,
            request,
            expected,
            what=f"runner {runner}",
            timeout=timeout,
            seal=self.seal,
        )

    def heat(self, request: Heat) -> HeatReport:
        """A competition's heat of several entries on one runner; lab faults run it again
        (the whole heat: it is one world), at last every entry's report says ``lab``."""
        detail = "no runner is alive in the lab"
        for tries in range(LAB_RETRIES + 1):
            if tries:
                self._stop.wait(min(2.0, 0.5 * tries))
            runner = self._pick()
            if runner is None:
                break
            key = keys.runner_heat(self.realm, runner)
            timeout = 15.0 + 1.5 * request.seconds + 10.0 + 3.0 * len(request.entries)
            try:
                answer = self._ask(runner, key, request, HeatReport, timeout)
            except LabError as exc:
                detail = _in_words(runner, exc)
                continue
            if all(r.cause != "lab" for r in answer.entries):
                return answer
            detail = answer.entries[0].detail
            if self._stop.is_set():
                break
        lab = EpisodeReport(cause="lab", detail=detail[:256])
        return HeatReport(entries=[lab] * len(request.entries))

    def grade_data(self, a: Assignment, episode: bytes) -> tuple[dict[str, float], str, int | None]:
        """The assignment's grader function on a real attempt's data, on a runner:
        (metrics, the teacher's error, its line); RuntimeError if no runner could run it."""
        request = GradeData(
            grader=a.grader_source.encode(),
            grader_filename=a.grader_file,
            grader_seconds=a.grader_seconds,
            episode=episode,
        )
        problem = "no runner is alive in the lab"
        for _ in range(LAB_RETRIES):
            runner = self._pick()
            if runner is None:
                break
            key = keys.runner_grade(self.realm, runner)
            try:
                answer = self._ask(runner, key, request, GradeResult, a.grader_seconds + 30.0)
                return answer.metrics, answer.error, answer.line
            except (NoReply, WrongReply):
                pass  # the problem said stays the last one known
            except QueryFailed as exc:
                problem = _in_words(runner, exc)
                continue  # asked again at once
            except LabError as exc:
                problem = _in_words(runner, exc)
            self._stop.wait(1.0)
        raise RuntimeError(f"the grader function could not run: {problem}")

    def grade(
        self,
        sub: Pending,
        a: Assignment,
        map_text: str,
        recordings: EpisodeRecordings | None = None,
        *,
        already: Sequence[EpisodeResult] = (),
        done: Callable[[EpisodeResult], None] = lambda _e: None,
    ) -> Graded:
        """Run and score each episode; with ``recordings``, each is traced and kept to replay.

        ``already``: the episodes a previous grading of this submission scored before it
        stopped (kept, not run again); ``done`` is called with each episode as it is scored.
        """
        kept = {e.episode: e for e in already if not e.real and e.score is not None}
        rule = a.score
        run = EpisodeRun.of(sub, a, a.name, sub.id, "graded")
        zones = sorted(rule.zones)
        results: list[EpisodeResult] = []
        for n in range(a.episodes):
            if n in kept:
                results.append(kept[n])
                continue
            start = a.start(n)
            request = Episode(
                submission=sub.id,
                episode=n,
                user=sub.user,
                map=map_text,
                agent=a.robot,
                seed=a.seeds[n],
                x=start.x,
                y=start.y,
                heading=math.radians(start.heading_deg),
                seconds=a.time_limit,
                source=sub.source,
                filename=sub.filename,
                trace=recordings is not None,
                grader=a.grader_source.encode() if a.grader_file else None,
                grader_filename=a.grader_file or "grader.py",
                grader_seconds=a.grader_seconds,
            )
            reruns = 0
            began = time.time()
            report = self.once(request)
            while report.cause == "lab" and reruns < LAB_RETRIES and not self._stop.is_set():
                reruns += 1
                log.warning(
                    "episode %d of %s: the lab's fault (%s); running it again, free (%d)",
                    n,
                    sub.id,
                    report.detail,
                    reruns,
                )
                self._stop.wait(min(2.0, 0.5 * reruns))
                began = time.time()
                report = self.once(request)
            replay = False
            if report.cause != "lab" and recordings is not None:
                replay = recordings.record(run, sub.id, n, report, began)
            if report.cause == "lab":
                results.append(
                    EpisodeResult(
                        episode=n,
                        seed=a.seeds[n],
                        cause="lab",
                        detail=report.detail,
                        lab_reruns=reruns,
                    )
                )
                return Graded(results, None, None, report.detail)
            # An episode the student's code ended is scored as the world stood then.
            teacher = report.grader_error
            score = 0.0
            if not teacher:
                try:
                    score = rule.evaluate(report, a.time_limit)
                except MissingMetric as exc:
                    teacher = f"{a.grader_file}: {exc}"
            if teacher:
                # The teacher's grader failed: no score, and the student is not charged.
                results.append(
                    EpisodeResult(
                        episode=n,
                        seed=a.seeds[n],
                        cause="grader",
                        detail=f"the teacher's grader failed: {teacher}"[:256],
                        error_line=report.grader_line,
                        metrics=metrics(report, zones, a.time_limit),
                        lab_reruns=reruns,
                        output=report.output[-20:],
                        replay=replay,
                    )
                )
                return Graded(results, None, None, "", teacher)
            detail = report.detail
            if report.cause in STUDENT_CAUSES:
                detail = f"your controller: {detail}"
            if reruns:
                detail = f"{detail} (re-run {reruns}x after a lab fault, free)"
            results.append(
                EpisodeResult(
                    episode=n,
                    seed=a.seeds[n],
                    cause=report.cause,
                    detail=detail[:256],
                    error_line=report.error_line,
                    score=round(score, 4),
                    metrics=metrics(report, zones, a.time_limit),
                    lab_reruns=reruns,
                    terms=[(t, round(v, 4)) for t, v in rule.terms(report, a.time_limit)],
                    output=report.output[-20:],
                    replay=replay,
                )
            )
            done(results[-1])
        scores = [r.score for r in results if r.score is not None]
        mean = round(sum(scores) / len(scores), 4) if scores else None
        return Graded(results, mean, min(scores) if scores else None, "")
