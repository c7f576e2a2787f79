"""Runners scaled on the grader's queue: the rule (depth to replicas, bounds, cool-down),
and the lab file's settings, refused in words when wrong."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import pytest

from services.lab.kube.runner_scale import ScaleRule
from services.lab.labfile import LabFileError, RunnerScale, parse

KUBE_EXAMPLE = Path(__file__).parents[4] / "deploy" / "kubernetes" / "lab.toml"


def test_the_depth_wants_one_pod_per_per_replica_submissions_within_the_bounds() -> None:
    rule = ScaleRule(RunnerScale(min_replicas=1, max_replicas=4, per_replica=2))
    assert [rule.wanted(d) for d in (0, 1, 2, 3, 4, 7, 8, 9, 100)] == [1, 1, 1, 2, 2, 4, 4, 4, 4]
    assert ScaleRule(RunnerScale(0, 3, per_replica=1)).wanted(0) == 0  # none while idle


def test_up_at_once_down_only_after_the_cool_down_to_the_most_it_needed() -> None:
    rule = ScaleRule(RunnerScale(min_replicas=1, max_replicas=5, per_replica=2, cooldown_s=60))
    assert rule.decide(depth=9, current=1, now=0) == 5  # a class submits: the cap at once
    assert rule.decide(depth=3, current=5, now=10) == 5  # low: the cool-down starts
    assert rule.decide(depth=6, current=5, now=40) == 5  # still low (3 would do), remembered
    assert rule.decide(depth=0, current=5, now=69) == 5  # 59 s: not yet
    assert rule.decide(depth=0, current=5, now=70) == 3  # 60 s low: the most the window wanted
    assert rule.decide(depth=0, current=3, now=80) == 3  # a new window
    assert rule.decide(depth=0, current=3, now=140) == 1  # the minimum


def test_a_burst_within_the_cool_down_starts_it_again() -> None:
    rule = ScaleRule(RunnerScale(min_replicas=1, max_replicas=4, per_replica=1, cooldown_s=30))
    assert rule.decide(0, 4, now=0) == 4
    assert rule.decide(4, 4, now=20) == 4  # the queue fills again: no flapping
    assert rule.decide(0, 4, now=40) == 4  # 20 s low since: not 30
    assert rule.decide(0, 4, now=70) == 1


def test_replicas_out_of_bounds_are_brought_back_within_them() -> None:
    rule = ScaleRule(RunnerScale(min_replicas=2, max_replicas=3, cooldown_s=600))
    assert rule.decide(0, 0, now=0) == 2  # scaled to none by hand: the minimum again
    assert rule.decide(0, 9, now=1) == 3  # by hand above the cap: the cap, no cool-down


def lab(runner: dict[str, Any]) -> dict[str, Any]:
    data = tomllib.loads(KUBE_EXAMPLE.read_text())
    services = data["hosts"][0]["services"]
    services[:] = [s for s in services if s["kind"] != "runner"]
    services.append({"kind": "runner", "name": "grading", **runner})
    return data


def test_the_settings_are_read_with_their_defaults() -> None:
    done = parse(lab({"min_replicas": 0, "max_replicas": 6}), KUBE_EXAMPLE)
    (runner,) = [s for s in done.hosts[0].services if s.kind == "runner"]
    assert runner.scale == RunnerScale(0, 6, per_replica=2, cooldown_s=300.0)
    example = parse(tomllib.loads(KUBE_EXAMPLE.read_text()), KUBE_EXAMPLE)
    # Agent contexts use a runner of one name: never a scaled one, whose pods are named apart.
    assert example.runner_for("cluster") == "runner"


@pytest.mark.parametrize(
    ("runner", "said"),
    [
        ({"max_replicas": 4}, "needs both min_replicas and max_replicas"),
        ({"min_replicas": 3, "max_replicas": 2}, "min_replicas (3) is above max_replicas (2)"),
        ({"min_replicas": 0, "max_replicas": 0}, "max_replicas: 0 is out of range (1 to 100)"),
        ({"min_replicas": 1, "max_replicas": "4"}, "max_replicas: expected an integer"),
        ({"min_replicas": 1, "max_replicas": 4, "per_replica": 0}, "per_replica: 0 is out"),
        ({"min_replicas": 1, "max_replicas": 4, "cooldown_s": -1}, "cooldown_s: -1 is out"),
        ({"min_replicas": 1, "max_replicas": 4, "cooldown": 5}, "unknown field cooldown"),
    ],
)
def test_a_wrong_setting_is_refused_with_its_field(runner: dict[str, Any], said: str) -> None:
    with pytest.raises(LabFileError, match=r"hosts\[0\]\.services\[[0-9]+\]") as refused:
        parse(lab(runner), KUBE_EXAMPLE)
    assert said in str(refused.value)


def test_an_agent_context_may_not_name_a_scaled_runner() -> None:
    data = lab({"min_replicas": 1, "max_replicas": 2})
    data["hosts"][0]["services"].append(
        {"kind": "agent", "name": "desk", "world": "arena1", "runner": "grading"}
    )
    with pytest.raises(LabFileError, match="runner 'grading' is scaled on the grader's queue"):
        parse(data, KUBE_EXAMPLE)
