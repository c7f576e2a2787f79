"""Assignments, score rules and the grader's fair queue (issue 36), without a lab."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from common.controller.pipe import PipeError, check_metrics
from common.messages import EpisodeReport
from services.grader.assignment import AssignmentError, parse_assignment
from services.grader.fair_queue import FairQueue
from services.grader.score import MissingMetric, RuleError, metrics, parse_rule

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


def test_a_score_is_shown_term_by_term_as_the_rule_is_written() -> None:
    rule = parse_rule('100 * reached("goal") - 5 * collisions() - time_to("goal")')
    hit = report(reached={"goal": 4.5}, collisions={"wall": 1})
    terms = rule.terms(hit, 10.0)
    assert terms == [
        ('100 * reached("goal")', 100.0),
        ("- 5 * collisions()", -5.0),
        ('- time_to("goal")', -4.5),
    ]
    assert sum(v for _, v in terms) == pytest.approx(rule.evaluate(hit, 10.0))
    # A subtraction of a sum flips its terms' signs; a product stays one term.
    nested = parse_rule('10 - (reached("goal") + 2 * collisions()) + max(1, 2) * 3')
    terms = nested.terms(hit, 10.0)
    assert [t for t, _ in terms] == [
        "10",
        '- reached("goal")',
        "- 2 * collisions()",
        "max(1, 2) * 3",
    ]
    assert sum(v for _, v in terms) == pytest.approx(nested.evaluate(hit, 10.0))
    long = parse_rule(" + ".join(["time()"] * 40))
    terms = long.terms(hit, 10.0)
    assert len(terms) == 16 and terms[-1][0] == "the other terms"
    assert sum(v for _, v in terms) == pytest.approx(long.evaluate(hit, 10.0))


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


def test_a_rule_reads_the_graders_metrics_and_a_missing_one_is_the_teachers() -> None:
    rule = parse_rule('100 * reached("goal") - metric("wobble")')
    assert rule.metrics == {"wobble"}
    graded = report(reached={"goal": 1.0}, grader_metrics={"wobble": 2.5})
    assert rule.evaluate(graded, 10.0) == pytest.approx(97.5)
    assert metrics(graded, [], 10.0)["wobble"] == 2.5  # shown beside ours
    with pytest.raises(MissingMetric, match=r"grade\(\) returned no metric 'wobble'"):
        rule.evaluate(report(grader_metrics={"wobbel": 1.0}), 10.0)
    with pytest.raises(RuleError, match=r"metric\(\) takes a quoted name"):
        parse_rule("metric(3)")


def test_a_grader_file_is_checked_at_add(tmp_path: Path) -> None:
    text = GOOD.replace(b"quota = 10", b'quota = 10\ngrader = "g.py"\ngrader_time_limit = 5')
    (tmp_path / "g.py").write_text("import math\n\ndef grade(episode):\n    return {}\n")
    a, _ = parse_assignment(text, "a.toml", MAPS, base=tmp_path)
    assert (a.grader_file, a.grader_seconds) == ("g.py", 5.0)
    assert "def grade(episode)" in a.grader_source  # stored with the assignment
    assert type(a).from_json(a.to_json()) == a
    (tmp_path / "g.py").write_text("def grade():\n    return {}\n")
    with pytest.raises(AssignmentError, match=r"g.py, line 1: grade\(\) takes the episode"):
        parse_assignment(text, "a.toml", MAPS, base=tmp_path)
    (tmp_path / "g.py").write_bytes(b"\xff")
    with pytest.raises(AssignmentError, match=r"g\.py is not UTF-8 text"):
        parse_assignment(text, "a.toml", MAPS, base=tmp_path)
    escape = GOOD.replace(b"quota = 10", b'quota = 10\ngrader = "../g.py"')
    with pytest.raises(AssignmentError, match="grader: a Python file beside the assignment"):
        parse_assignment(escape, "a.toml", MAPS, base=tmp_path)


@pytest.mark.parametrize(
    ("value", "problem"),
    [
        ([1], "grade() returned list, not a dict of names to numbers"),
        ({"a b": 1}, "grade() returned a metric named 'a b'"),
        ({"x": "1"}, "grade() returned x=str, not a number"),
        ({"x": float("nan")}, "grade() returned x=nan, not a finite number"),
        ({"x": 10**400}, "not a finite number"),
        ({f"m{i}": i for i in range(33)}, "grade() returned 33 metrics; at most 32"),
    ],
)
def test_what_a_grader_returns_is_checked(value: object, problem: str) -> None:
    with pytest.raises(PipeError, match=re.escape(problem)):
        check_metrics(value)
    assert check_metrics({"wobble": 1, "ir.peak-2": 3.5}) == {"wobble": 1.0, "ir.peak-2": 3.5}


@pytest.mark.parametrize(
    ("line", "problem"),
    [
        (b'visibility = "later"', "visibility: one of now, after_deadline, after_release"),
        (b'visibility = ["now", "now"]', "visibility: 2 value(s) for 3 episode(s)"),
        (b"visibility = 3", "visibility: one of now, after_deadline, after_release"),
    ],
)
def test_a_visibility_that_is_not_one_per_episode_is_refused(line: bytes, problem: str) -> None:
    with pytest.raises(AssignmentError, match=re.escape(problem)):
        parse_assignment(line + b"\n" + GOOD, "a.toml", MAPS)


def test_each_episode_is_shown_when_its_visibility_says() -> None:
    text = b'visibility = ["now", "after_deadline", "after_release"]\n' + GOOD
    a, _ = parse_assignment(text, "a.toml", MAPS)
    before, after = a.deadline - 1, a.deadline + 1
    assert [a.shown_after(n, before, None) for n in range(3)] == [
        "",
        "shown after the deadline, 2026-12-01 18:00 UTC",
        "shown when your teacher releases the results",
    ]
    assert [a.shown_after(n, after, None) == "" for n in range(3)] == [True, True, False]
    assert [a.shown_after(n, before, released_at=before) == "" for n in range(3)] == [
        True, False, True,
    ]  # fmt: skip
    everything, _ = parse_assignment(GOOD, "a.toml", MAPS)
    assert everything.visibility == [] and everything.shown_after(2, before, None) == ""
