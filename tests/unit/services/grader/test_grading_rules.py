"""Assignments, score rules and the grader's fair queue (issue 36), without a lab."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.messages import EpisodeReport
from services.grader.assignment import AssignmentError, parse_assignment
from services.grader.fair_queue import FairQueue
from services.grader.score import RuleError, metrics, parse_rule

MAPS = Path(__file__).resolve().parents[4] / "maps"
GOOD = b"""
name = "reach-goal"
course = "robotics-26"
map = "empty"
robot = "k1"
time_limit = 10
episodes = 3
opens = 2026-11-01T08:00:00Z
deadline = 2026-12-01T18:00:00Z
late = { penalty_per_day = 10 }
quota = 10
[[start]]
x = 200
y = 500
[[zones]]
id = "goal"
shape = "circle"
x = 800
y = 500
radius = 80
[score]
name = "points"
unit = "pts"
order = "higher"
rule = '100 * reached("goal") - 5 * collisions() - time_to("goal")'
"""


def report(**fields: object) -> EpisodeReport:
    return EpisodeReport(cause="ok", sim_seconds=10.0, **fields)  # type: ignore[arg-type]


def test_a_rule_scores_an_episodes_events() -> None:
    rule = parse_rule('100 * reached("goal") - 5 * collisions() - time_to("goal")')
    assert rule.zones == {"goal"}
    hit = report(reached={"goal": 4.5}, collisions={"wall": 1, "object": 3})
    assert rule.evaluate(hit, 10.0) == pytest.approx(100 - 5 - 4.5)  # pushing objects is free
    assert rule.evaluate(report(), 10.0) == pytest.approx(-10.0)  # never there: the limit
    both = parse_rule('max(delivered(), 0) * 10 + delivered("ball1") - distance() / 0')
    assert both.evaluate(report(delivered={"ball1": 2.0}), 10.0) == pytest.approx(11.0)
    assert metrics(hit, ["goal"], 10.0)["time_to_goal"] == 4.5


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ('__import__("os").system("x")', "call a function by its name"),
        ("time.__class__", "Attribute is not allowed"),
        ('eval("1")', "unknown function eval()"),
        ("x + 1", "unknown name 'x'"),
        ("reached(goal)", 'takes a quoted name, e.g. reached("goal")'),
        ('collisions("floor")', "collisions() counts one of wall, obstacle, robot, object"),
        ("time(1)", "time() takes 0 argument(s)"),
        ("2 ** 1000", "Pow is not allowed"),
        ("[1][0]", "is not allowed"),
        ("1 +", "not an expression"),
        ("1" * 600, "longer than 500"),
    ],
)
def test_a_rule_outside_the_grammar_is_refused_with_where(text: str, problem: str) -> None:
    with pytest.raises(RuleError, match=None) as info:
        parse_rule(text)
    assert problem in str(info.value)


def test_an_assignment_file_is_checked_whole() -> None:
    a, map_text = parse_assignment(GOOD, "a.toml", MAPS)
    assert (a.episodes, a.seeds, a.quota, a.late, a.penalty_per_day) == (
        3,
        [1, 2, 3],
        10,
        "penalty",
        10,
    )
    assert '"goal"' in map_text and a.start(4).x == 200
    bad = GOOD.replace(b'robot = "k1"', b'robot = "k9"').replace(b"episodes = 3", b"episodes = 0")
    bad = bad.replace(b'reached("goal")', b'reached("nest")') + b"colour = 1\n"
    with pytest.raises(AssignmentError) as info:
        parse_assignment(bad, "a.toml", MAPS)
    text = str(info.value)
    assert "episodes: 0 is not within 1..20" in text
    assert "score.colour: unknown field" in text  # [score] is the open table at the end
    fixed = bad.replace(b"episodes = 0", b"episodes = 3").replace(b"colour = 1\n", b"")
    with pytest.raises(AssignmentError) as info:
        parse_assignment(fixed, "a.toml", MAPS)
    assert "robot: the map empty has no robot k9 (it has k1)" in str(info.value)
    assert "score.rule: names zone 'nest', which the map lacks (has goal)" in str(info.value)
    with pytest.raises(AssignmentError, match="over 64 KiB"):
        parse_assignment(b"#" * 70_000, "a.toml", MAPS)
    with pytest.raises(AssignmentError, match="deadline: before the opening"):
        parse_assignment(GOOD.replace(b"2026-12-01", b"2026-10-01"), "a.toml", MAPS)


def test_the_queue_takes_students_in_turn() -> None:
    q: FairQueue[str] = FairQueue()
    for i in range(10):
        q.put("greedy", f"g{i}")
    assert q.put("alice", "a0") == 2  # behind one of greedy's, not ten
    assert q.put("bob", "b0") == 3
    q.put_first("carol", "lab-rerun")
    order = [q.get(0)[1] for _ in range(5)]  # type: ignore[index]
    assert order == ["lab-rerun", "g0", "a0", "b0", "g1"]
    assert len(q) == 8
