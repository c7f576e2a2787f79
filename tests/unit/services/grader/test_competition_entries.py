"""A competition's entries (one per team, latest or best) and its ranking, without a lab."""

from __future__ import annotations

from pathlib import Path
from typing import Any, cast

import pytest

from common.messages import StandingEntry, Standings
from services.grader.assignment import parse_assignment
from services.grader.competition import (
    CompetitionError,
    Competitions,
    own_entries,
    pick_entries,
    ranked,
)
from services.grader.grading_db import GradingStore, Pending
from tests.unit.services.grader.test_grading_rules import GOOD, MAPS


class FakeStore:
    """The two queries a competition makes of the grading store."""

    def __init__(self, teams: dict[str, str], graded: list[tuple[str, str, float]]) -> None:
        self._teams = teams
        self._graded = [
            (Pending(sub, "reach-goal", user, "c.py", b"", float(i)), score)
            for i, (user, sub, score) in enumerate(graded)
        ]

    def teams(self, course: str) -> dict[str, str]:
        return self._teams

    def graded(self, assignment: str) -> list[tuple[Pending, float]]:
        return self._graded


def assignment(order: str = "higher") -> Any:
    text = GOOD.replace(b'order = "higher"', f'order = "{order}"'.encode())
    return parse_assignment(text, "a.toml", MAPS)[0]


TEAMS = {"alice": "red", "dan": "red", "bob": "blue", "carol": "carol", "eve": "eve"}
GRADED = [("alice", "s1", 90.0), ("dan", "s2", 10.0), ("bob", "s3", 5.0), ("carol", "s4", 7.0)]


def test_each_team_enters_its_latest_or_best_graded_submission() -> None:
    store = cast(GradingStore, FakeStore(TEAMS, [*GRADED, ("mallory", "s9", 999.0)]))
    latest = pick_entries(store, assignment(), "latest")
    # One entry per team, in team order; eve has nothing graded; mallory left the course.
    assert [(team, sub.id) for team, sub in latest] == [
        ("blue", "s3"),
        ("carol", "s4"),
        ("red", "s2"),
    ]
    best = pick_entries(store, assignment(), "best")
    assert dict((team, sub.id) for team, sub in best)["red"] == "s1"
    lowest = pick_entries(store, assignment("lower"), "best")
    assert dict((team, sub.id) for team, sub in lowest)["red"] == "s2"


def entry(team: str, heat: int, score: float | None) -> StandingEntry:
    cause = "waiting" if score is None else "ok"
    return StandingEntry(
        rank=0, team=team, user="u", submission="s", heat=heat, score=score, cause=cause
    )


def test_ranking_follows_the_scores_order_ties_share_a_rank_waiting_last() -> None:
    entries = [entry("a", 1, 3.0), entry("b", 2, None), entry("c", 3, 9.0), entry("d", 4, 3.0)]
    high = ranked(entries, "higher")
    assert [(e.team, e.rank) for e in high] == [("c", 1), ("a", 2), ("d", 2), ("b", 0)]
    low = ranked(entries, "lower")
    assert [(e.team, e.rank) for e in low] == [("a", 1), ("d", 1), ("c", 3), ("b", 0)]


def test_no_entries_and_several_per_heat_are_refused(tmp_path: Path) -> None:
    store = cast(GradingStore, FakeStore(TEAMS, []))
    runs = Competitions(store, cast(Any, None), tmp_path, lambda st: None)
    with pytest.raises(CompetitionError, match="no entries: no team of robotics-26 has a graded"):
        runs.start("final", assignment(), "{}", "latest", 1)
    a, map_text = parse_assignment(GOOD, "a.toml", MAPS)
    with pytest.raises(CompetitionError, match=r"has 1 robot\(s\) \(k1\): a heat holds at most 1"):
        runs.start("final", a, map_text, "latest", 2)
    assert not (tmp_path / "final").exists()  # nothing half-written


def test_a_competition_the_grader_stopped_mid_way_is_marked_stopped(tmp_path: Path) -> None:
    store = cast(GradingStore, FakeStore(TEAMS, GRADED))
    saved = Competitions(store, cast(Any, None), tmp_path, lambda st: None)
    # As the grader left it when it died after heat 1: one entry run, two waiting.
    running = Standings(
        competition="final",
        assignment="reach-goal",
        course="robotics-26",
        score_name="points",
        unit="pts",
        order="higher",
        status="running",
        heats=3,
        heat=2,
        entries=[entry("blue", 1, 5.0), entry("carol", 2, None), entry("red", 3, None)],
    )
    (tmp_path / "final").mkdir()
    saved._save(running)
    again = Competitions(store, cast(Any, None), tmp_path, lambda st: None)
    assert again.recover() == ["final"]
    found = again.standings("final")
    assert found is not None and found.status == "stopped" and found.heat == 0
    assert [e.detail for e in found.entries][1:] == [
        "not run: the grader stopped during the competition"
    ] * 2
    assert again.recover() == []  # once


def test_a_hidden_leaderboards_standings_show_a_student_their_own_teams_entry_alone() -> None:
    st = Standings(
        competition="final", assignment="reach-goal", course="c", score_name="score", unit="",
        order="higher", status="running", heats=3,
        entries=[entry("red", 1, 90.0), entry("blue", 2, 5.0), entry("carol", 3, None)],
    )  # fmt: skip
    assert [e.team for e in own_entries(st, "dan", "red").entries] == ["red"]
    assert own_entries(st, "eve", "eve").entries == []  # no entry of hers: nothing
