"""The numbered example controllers do what their docstrings say, in the sample maps.

Fast: each runs against an in-process World (no Zenoh) through the same
controller API, stepping the world between do_work calls.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.controller import Controller, load_controller
from common.controller.upload_gate import precheck
from common.sim2d.drives import DEFAULT_DRIVE
from common.sim2d.maps import load_map
from common.sim2d.world import DRIVES, World
from tests.conftest import REPO
from tests.kit.worldlink import run_in_world

EXAMPLES = sorted((REPO / "examples").glob("[0-9][0-9]_*.py"))


def world(name: str, keep: str, seed: int = 1, drive: str = DEFAULT_DRIVE) -> World:
    w = load_map(REPO / "maps" / f"{name}.json", name="t", seed=seed, drive=drive)
    for agent in [a.id for a in w.agents if a.id != keep]:
        w.remove(agent)  # alone in the map: other robots are not what is tested
    return w


def example(prefix: str) -> Controller:
    (path,) = [p for p in EXAMPLES if p.name.startswith(prefix)]
    return load_controller(path)


class Track:
    """Path length and sensor statistics of one agent, sampled after each control step."""

    def __init__(self, w: World, agent: str) -> None:
        self.slot = w.agent_slot(agent)
        self.last = w.agent_pose[self.slot, :2].copy()
        self.path = 0.0
        self.steps = 0
        self.touching = 0
        self.wall_on_left = 0

    def __call__(self, w: World) -> None:
        pose = w.agent_pose[self.slot, :2].copy()
        self.path += float(np.linalg.norm(pose - self.last))
        self.last = pose
        self.steps += 1
        prox = w.proximity[self.slot]
        self.touching += int(prox.max() > 900)
        self.wall_on_left += int(max(prox[0], prox[1]) > 60)


def test_every_example_passes_the_precheck_and_says_what_it_teaches() -> None:
    assert [p.name[:2] for p in EXAMPLES] == ["01", "02", "03", "04"]
    for path in EXAMPLES:
        precheck(path.read_bytes(), path.name)
        text = path.read_text()
        assert "What it teaches" in text and "Suits:" in text, path.name


# Both drives (World(drive=...)): a controller must behave the same whichever the
# engine runs; the velocity drive is the swarm option (docs/WORLDS.md).
@pytest.mark.parametrize("drive", DRIVES)
def test_braitenberg_avoids_the_maze_walls(drive: str) -> None:
    w = world("maze", "k1", drive=drive)
    track = Track(w, "k1")
    run_in_world(example("01"), w, "k1", 40.0, track)
    assert track.path > 1000, "it keeps moving"
    assert track.touching / track.steps < 0.05, "it rarely touches a wall"


@pytest.mark.parametrize("drive", DRIVES)
def test_wall_follower_keeps_a_wall_on_its_left(drive: str) -> None:
    w = world("maze", "k1", drive=drive)
    track = Track(w, "k1")
    run_in_world(example("02"), w, "k1", 40.0, track)
    assert track.path > 800
    assert track.wall_on_left / track.steps > 0.6


def test_phototaxis_reaches_the_lamp() -> None:
    w = world("phototaxis", "k0")
    slot = w.agent_slot("k0")
    start = math.dist(w.agent_pose[slot, :2], (1700, 750))
    link = run_in_world(example("03"), w, "k0", 60.0)
    end = math.dist(w.agent_pose[slot, :2], (1700, 750))
    assert start > 1400 and end < 250, (start, end)
    assert link.latest().leds == (True, True), "LEDs on under the lamp"


@pytest.mark.parametrize("seed", [1])
def test_forager_brings_a_ball_to_the_nest(seed: int) -> None:
    w = world("foraging", "k0", seed)

    def in_nest() -> set[str]:
        return {o.id for o in w.objects if math.dist(w.pose_of(o.id)[:2], (250, 600)) < 150}

    assert in_nest() == set()
    forager = example("04")
    # 300 s, not 120: in 120 s the forager delivered a ball for 1 seed in 12 (only
    # seed 1's noise happened to do it); in 300 s for 4 to 5 seeds in 8 with either
    # noise generator (docs/BENCHMARKS.md, "A sensing pass at 10,000 robots").
    run_in_world(forager, w, "k0", 300.0)
    assert in_nest(), "at least one ball was carried into the nest"
    assert forager.carried >= 1  # type: ignore[attr-defined]
