"""A world's robot types travel with it: a map or a snapshot carries the robot file of every
type its robots use that the lab does not ship, and whoever rebuilds the world (a runner's
dry run, a graded episode, a map loaded elsewhere) simulates them from those files, for
that world alone, or says which robot's type cannot be simulated and why."""

from __future__ import annotations

import json
from dataclasses import replace
from typing import Any

import pytest

from common.robots import registry
from common.sim2d import maps
from common.sim2d.map_robots import MAX_TYPES, carried_files
from common.world import packing
from services.runner.dryrun import world_from_snapshot
from services.runner.episode import assignment_world
from tests.conftest import REPO
from tests.kit.robots import SCOUT


def a_map(**types: str) -> dict[str, Any]:
    return {
        "format": "wart-map",
        "version": 1,
        "arena": {"width": 1000, "height": 1000},
        "robot_types": dict(types),
        "agents": [
            {"id": "k0", "type": "khepera", "x": 100, "y": 100},
            {"id": "s1", "type": "scout", "x": 500, "y": 500},
        ],
    }


def test_a_map_s_robot_type_is_simulated_for_that_world_only() -> None:
    world = maps.build_world(a_map(scout=SCOUT), name="w1")
    assert [a.spec.name for a in world.agents] == ["khepera", "scout"]
    assert [p.name for p in world.agents[1].spec.parts] == ["eye"]
    assert "scout" not in registry.default().robots  # never the process's own type
    # Another lab's scout of the same name, in the same process: each world has its own.
    other = maps.build_world(a_map(scout=SCOUT.replace("beams = 3", "beams = 5")), name="w2")
    assert other.agents[1].spec.parts[0].size == 5
    assert world.agents[1].spec.parts[0].size == 3


def test_the_snapshot_carries_the_files_a_runner_needs_and_no_shipped_one() -> None:
    snap = packing.snapshot(maps.build_world(a_map(scout=SCOUT), name="w1"))
    assert snap.robot_files == {"scout": SCOUT}
    dry = world_from_snapshot(snap)  # what the runner builds for a dry run
    assert [(a.id, a.spec.name) for a in dry.agents] == [("k0", "khepera"), ("s1", "scout")]
    assert dry.agents[1].spec.parts[0].size == 3


def test_a_saved_map_carries_its_types_to_a_graded_episode() -> None:
    world = maps.build_world(a_map(scout=SCOUT), name="w1")
    saved = maps.world_to_map(world, "class")
    assert saved["robot_types"] == {"scout": SCOUT}
    episode = assignment_world(json.dumps(saved), "episode", 3)  # the runner's episode world
    assert episode.agents[1].spec.name == "scout"
    plain = maps.world_to_map(maps.load_map(REPO / "maps" / "empty.json", name="e"), "e")
    assert "robot_types" not in plain  # maps of shipped types are as they were


@pytest.mark.parametrize(
    ("types", "said"),
    [
        (
            {"scout": SCOUT.replace("beams = 3", "beams = 99")},
            "world w1: robot type 'scout' (s1) is not valid here: "
            "scout.toml:20: components.eye.beams: must be at most 64, got 99",
        ),
        (
            {"scout": SCOUT.replace('"range_finder"', '"laser_cannon"')},
            "world w1: robot type 'scout' (s1) is not valid here: scout.toml:18: "
            "components.eye.type: unknown component type 'laser_cannon'",
        ),
        (
            {"scout": SCOUT.replace('name = "scout"', 'name = "rover"')},
            "world w1: robot type 'scout' (s1) is not valid here: its robot file names it 'rover'",
        ),
        (
            {"scout": SCOUT, "khepera": SCOUT.replace('"scout"', '"khepera"')},
            "world w1: robot type 'khepera' (k0) is not valid here: 'khepera' is a type the lab "
            "ships; a world may not redefine it",
        ),
        (
            {"scout": "x" * 70_000},
            "world w1: robot_types.scout: must be a robot file's text (at most 65536 characters)",
        ),
    ],
    ids=["bad field", "unknown component", "another name", "a shipped name", "huge"],
)
def test_a_bad_type_fails_the_world_that_uses_it_with_the_robot_and_the_reason(
    types: dict[str, str], said: str
) -> None:
    with pytest.raises(maps.MapError) as caught:
        maps.build_world(a_map(**types), name="w1", source="world w1")
    assert str(caught.value).startswith(said), str(caught.value)


def test_a_type_no_robot_uses_is_never_compiled() -> None:
    data = a_map(scout=SCOUT, broken="not toml at all [")
    world = maps.build_world(data, name="w1")
    assert len(world.agents) == 2


def test_a_world_carries_at_most_as_many_files_as_a_reader_takes() -> None:
    khepera = registry.default().robots["khepera"]
    many = [replace(khepera, name=f"type{i}", text=f"# type{i}") for i in range(40)]
    files = carried_files([khepera, *many, many[0]])
    assert len(files) == MAX_TYPES and "khepera" not in files  # shipped: never sent
    assert list(files)[:2] == ["type0", "type1"]
