"""The avoidance rule of `wart engine --wander` turns a Khepera away from walls on both sides."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.sim2d.agents import agent_type
from common.sim2d.entities import ShapeSpec
from common.sim2d.wander import WEIGHTS, braitenberg
from common.sim2d.world import World

KHEPERA = agent_type("khepera")
WALL_X = 700.0


def approach(heading: float, seconds: float = 4.0) -> tuple[float, float]:
    """A Khepera driven by the rule toward a long wall; (its final heading, its largest x)."""
    world = World(1000.0, 1000.0, seed=7)
    world.add_obstacle("wall", ShapeSpec.box(20, 900), WALL_X, 500.0)
    world.add_agent("k1", KHEPERA, 500.0, 500.0, heading)
    furthest = 0.0
    for _ in range(round(seconds / world.tick_s)):
        world.set_speeds_all(braitenberg(world.proximity))
        world.step()
        furthest = max(furthest, float(world.agent_pose[0, 0]))
    return float(world.agent_pose[0, 2]), furthest


def test_the_rule_is_its_own_mirror_image() -> None:
    # Sensor i on the left is sensor 5 - i on the right: each wheel answers its side alike.
    for i in range(6):
        assert WEIGHTS[i, 0] == WEIGHTS[5 - i, 1]
    assert not WEIGHTS[6:].any()  # the back sensors do not steer


@pytest.mark.parametrize("side", [+1, -1], ids=["wall-on-the-right", "wall-on-the-left"])
def test_a_robot_turns_away_from_a_wall_on_either_side(side: int) -> None:
    heading, furthest = approach(side * 0.5)
    radius = KHEPERA.radius_mm
    assert furthest < WALL_X - 10 - radius + 1.0  # never pressed into the wall
    # Turned away: further to its own side, so it now points back from the wall.
    assert side * math.remainder(heading, 2 * math.pi) > math.pi / 2


def test_both_sides_turn_alike() -> None:
    right, _ = approach(+0.5)
    left, _ = approach(-0.5)
    turned = np.array([math.remainder(right, 2 * math.pi), -math.remainder(left, 2 * math.pi)])
    assert turned[0] == pytest.approx(turned[1], abs=0.35)  # seeded sensor noise differs


def test_the_compiled_rule_sets_the_speeds_the_numpy_rule_sets() -> None:
    # bench/bench_enki.py runs the rule compiled (Enki's is C++): the same speeds,
    # but for a sum within rounding of half a unit, which may round either way.
    from common.sim2d import kernels
    from common.sim2d.wander import CRUISE

    rng = np.random.default_rng(3)
    prox = rng.integers(0, 1024, size=(500, 8)).astype(np.int32)
    top = np.full(500, 20.0)
    want = np.zeros((500, 2))
    kernels.clamp_speeds(braitenberg(prox), top, want)
    got = np.zeros((500, 2))
    kernels.braitenberg_speeds(prox, WEIGHTS, CRUISE, top, got)
    raw = braitenberg(prox)
    tie = np.abs(raw - np.floor(raw) - 0.5) < 1e-9
    assert np.array_equal(got[~tie], want[~tie])
    assert np.all(np.abs(got - want) <= 1.0)
