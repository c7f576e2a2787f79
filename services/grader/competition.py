"""A competition: every team's entry on an assignment's arena, in heats, ranked live.

Each team's latest (or best) graded submission is its entry; a student with no
team is a team of one. Entries run one per heat, in turn, as an episode on the
lab's runners (services/grader/episodes.py: lab faults re-run free), with the
assignment's map, first start pose and first seed, so every entry faces the
same world; the assignment's score ranks them in its order. With ``per_heat``
N > 1 a heat holds N entries in one world at once, each on its own robot
(services/grader/heats.py).

As each heat ends the standings are published, sealed, on
``grader/<g>/competition/<name>`` and written to ``<root>/<name>/standings.json``;
the heat's run (the robot's path, the controller file, how it ended) is an MCAP
recording beside it (common/recording/writer.py), readable by ``read_recording``.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path

import msgspec

from common.messages import STUDENT_CAUSES, Episode, EpisodeReport, StandingEntry, Standings
from services.grader.assignment import Assignment
from services.grader.episode_recordings import EpisodeRun, record_episode
from services.grader.episodes import LAB_RETRIES, EpisodeRunner
from services.grader.grading_db import GradingStore, Pending
from services.grader.heats import (
    HeatError,
    heat_request,
    heat_robots,
    record_heat,
    score_heat,
)
from services.grader.score import judge

log = logging.getLogger("wart.grader")

Publish = Callable[[Standings], None]
STANDINGS = "standings.json"


class CompetitionError(ValueError):
    """A competition that cannot run (no entries, a name in use, ...): said to the teacher."""


def pick_entries(store: GradingStore, a: Assignment, pick: str) -> list[tuple[str, Pending]]:
    """(team, submission) for each team with a graded submission, teams in name order."""
    teams = store.teams(a.course)
    chosen: dict[str, tuple[Pending, float]] = {}
    higher = a.order == "higher"
    for sub, score in store.graded(a.name):  # oldest first: a later one replaces
        team = teams.get(sub.user)
        if team is None:
            continue  # no longer a student of the course
        held = chosen.get(team)
        better = held is None or (score > held[1] if higher else score < held[1])
        if pick == "latest" or better:
            chosen[team] = (sub, score)
    return [(team, chosen[team][0]) for team in sorted(chosen)]


def ranked(entries: list[StandingEntry], order: str) -> list[StandingEntry]:
    """Run entries ranked by score in the order (ties share a rank), then those waiting."""
    run = [e for e in entries if e.score is not None]
    rest = [e for e in entries if e.score is None]
    run.sort(key=lambda e: (-(e.score or 0.0) if order == "higher" else (e.score or 0.0), e.heat))
    out: list[StandingEntry] = []
    rank, previous = 0, None
    for i, e in enumerate(run):
        if e.score != previous:
            rank, previous = i + 1, e.score
        out.append(msgspec.structs.replace(e, rank=rank))
    return out + [msgspec.structs.replace(e, rank=0) for e in rest]


class Competitions:
    def __init__(
        self, store: GradingStore, episodes: EpisodeRunner, root: Path, publish: Publish
    ) -> None:
        self.store = store
        self.episodes = episodes
        self.root = root
        self.publish = publish
        self._lock = threading.Lock()
        self._live: dict[str, Standings] = {}
        self._threads: list[threading.Thread] = []

    def recover(self) -> list[str]:
        """Competitions a grader stopped mid-way (found running at start): marked stopped,
        the heats not run said so; their names. They are not run again: the teacher
        starts a new one (a heat half-run would be unfair to re-run for one team only)."""
        stopped = []
        for path in sorted(self.root.glob(f"*/{STANDINGS}")):
            st = self.standings(path.parent.name)
            if st is None or st.status != "running":
                continue
            why = "not run: the grader stopped during the competition"
            entries = [
                e if e.cause != "waiting" else msgspec.structs.replace(e, detail=why)
                for e in st.entries
            ]
            self._save(msgspec.structs.replace(st, status="stopped", heat=0, entries=entries))
            stopped.append(st.competition)
        return stopped

    def standings(self, name: str) -> Standings | None:
        with self._lock:
            live = self._live.get(name)
        if live is not None:
            return live
        path = self.root / name / STANDINGS
        try:
            return msgspec.json.decode(path.read_bytes(), type=Standings)
        except (OSError, msgspec.DecodeError, msgspec.ValidationError):
            return None

    def start(self, name: str, a: Assignment, map_text: str, pick: str, per_heat: int) -> Standings:
        """The first standings (every entry waiting); the heats run on a thread."""
        if per_heat > 1:
            try:
                heat_robots(a, map_text, per_heat)
            except HeatError as exc:
                raise CompetitionError(str(exc)) from None
        entries = pick_entries(self.store, a, pick)
        if not entries:
            raise CompetitionError(
                f"no entries: no team of {a.course} has a graded submission to {a.name}"
            )
        with self._lock:
            if name in self._live or (self.root / name).exists():
                raise CompetitionError(f"a competition named {name} exists already")
            (self.root / name).mkdir(parents=True)
            first = Standings(
                competition=name,
                assignment=a.name,
                course=a.course,
                score_name=a.score_name,
                unit=a.unit,
                order=a.order,  # type: ignore[arg-type]
                status="running",
                heats=math.ceil(len(entries) / per_heat),
                heat=1,
                entries=[
                    StandingEntry(
                        rank=0,
                        team=team[:256],
                        user=sub.user,
                        submission=sub.id,
                        heat=n // per_heat + 1,
                    )
                    for n, (team, sub) in enumerate(entries)
                ],
                at=time.time(),
            )
            self._live[name] = first
        self._save(first)
        thread = threading.Thread(
            target=self._run,
            args=(first, a, map_text, entries, per_heat),
            name=f"compete-{name}",
            daemon=True,
        )
        thread.start()
        self._threads.append(thread)
        return first

    def join(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        for thread in self._threads:
            thread.join(max(0.0, deadline - time.monotonic()))

    def _save(self, st: Standings) -> None:
        path = self.root / st.competition / STANDINGS
        tmp = path.with_name(path.name + ".part")
        tmp.write_bytes(msgspec.json.encode(st))
        tmp.replace(path)

    def _update(self, st: Standings) -> None:
        with self._lock:
            self._live[st.competition] = st
        self._save(st)
        try:
            self.publish(st)
        except Exception as exc:  # the session closing: the file still has it
            log.debug("standings of %s not published: %s", st.competition, exc)

    def _run(
        self,
        st: Standings,
        a: Assignment,
        map_text: str,
        entries: list[tuple[str, Pending]],
        per_heat: int = 1,
    ) -> None:
        for n in range(0, len(entries), per_heat):
            heat = n // per_heat + 1
            st = msgspec.structs.replace(st, heat=heat, at=time.time())
            self._update(st)
            group = entries[n : n + per_heat]
            if per_heat == 1:
                team, sub = group[0]
                ran = [self._heat(st.competition, heat, team, sub, a, map_text)]
            else:
                ran = self._heat_of(st, heat, group, a, map_text, per_heat)
            by_sub = {e.submission: e for e in ran}
            done = [by_sub.get(e.submission, e) if e.heat == heat else e for e in st.entries]
            st = msgspec.structs.replace(st, entries=ranked(done, a.order), at=time.time())
            for entry in ran:
                log.info("competition %s heat %d (%s): %s", st.competition, heat, entry.team,
                         entry.detail)  # fmt: skip
        st = msgspec.structs.replace(st, status="finished", heat=0, at=time.time())
        self._update(st)
        with self._lock:
            self._live.pop(st.competition, None)

    def _heat_of(
        self,
        st: Standings,
        heat: int,
        group: list[tuple[str, Pending]],
        a: Assignment,
        map_text: str,
        per_heat: int,
    ) -> list[StandingEntry]:
        """A heat of several entries in one world (services/grader/heats.py)."""
        subs = [sub for _team, sub in group]
        request = heat_request(st.competition, heat, a, map_text, subs, per_heat)
        began = time.time()
        report = self.episodes.heat(request)
        path = self.root / st.competition / f"heat-{heat:03d}.mcap"
        try:
            recorded = record_heat(path, st.competition, heat, a, request, report, began)
        except (OSError, ValueError) as exc:
            log.warning("heat %d of %s not recorded: %s", heat, st.competition, exc)
            recorded = ""
        bases = [
            StandingEntry(rank=0, team=team[:256], user=sub.user, submission=sub.id, heat=heat)
            for team, sub in group
        ]
        return score_heat(a, request, report, bases, recorded)

    def _heat(
        self, name: str, heat: int, team: str, sub: Pending, a: Assignment, map_text: str
    ) -> StandingEntry:
        start = a.start(0)
        request = Episode(
            submission=sub.id,
            episode=0,
            user=sub.user,
            map=map_text,
            agent=a.robot,
            seed=a.seeds[0],
            x=start.x,
            y=start.y,
            heading=math.radians(start.heading_deg),
            seconds=a.time_limit,
            source=sub.source,
            filename=sub.filename,
            trace=True,
            grader=a.grader_source.encode() if a.grader_file else None,
            grader_filename=a.grader_file or "grader.py",
            grader_seconds=a.grader_seconds,
        )
        began = time.time()
        report = self.episodes.once(request)
        tries = 0
        while report.cause == "lab" and tries < LAB_RETRIES:
            tries += 1  # the lab's fault costs no team its heat: run again
            time.sleep(min(2.0, 0.5 * tries))
            report = self.episodes.once(request)
        base = StandingEntry(rank=0, team=team[:256], user=sub.user, submission=sub.id, heat=heat)
        path = self.root / name / f"heat-{heat:03d}.mcap"
        recorded = self._record(path, name, heat, sub, a, report, began)
        if report.cause == "lab":
            return msgspec.structs.replace(
                base, cause="lab", detail=f"the lab could not run it: {report.detail}"[:256],
                recording=recorded,
            )  # fmt: skip
        score, teacher = judge(a.score, report, a.time_limit, a.grader_file)
        if teacher:
            return msgspec.structs.replace(
                base, cause="grader", detail=f"the teacher's grader failed: {teacher}"[:256],
                recording=recorded,
            )  # fmt: skip
        detail = report.detail
        if report.cause in STUDENT_CAUSES:
            detail = f"the entry's controller: {detail}"
        return msgspec.structs.replace(
            base, score=round(score, 4), cause=report.cause, detail=detail[:256],
            recording=recorded,
        )  # fmt: skip

    def _record(
        self,
        path: Path,
        name: str,
        heat: int,
        sub: Pending,
        a: Assignment,
        report: EpisodeReport,
        began: float,
    ) -> str:
        """The heat's MCAP recording; its path ("" if it could not be written)."""
        run = EpisodeRun.of(sub, a, name, f"{name}-heat-{heat}", "competition")
        try:
            record_episode(path, run, report, began)
        except (OSError, ValueError) as exc:
            log.warning("heat %d of %s not recorded: %s", heat, name, exc)
            return ""
        return str(path)


def own_entries(standings: Standings, user: str, team: str) -> Standings:
    """The standings as a student sees them while the assignment's leaderboard is hidden:
    their own team's entry alone (the others' ranks, names and scores stay here)."""
    mine = [e for e in standings.entries if e.team == team or e.user == user]
    return msgspec.structs.replace(standings, entries=mine)
