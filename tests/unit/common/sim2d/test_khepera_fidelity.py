"""The Khepera model against the manual's numbers (no network)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.sim2d.agents import agent_type
from common.sim2d.agents.khepera import PROXIMITY_CURVE
from common.sim2d.entities import ShapeSpec
from common.sim2d.world import DRIVES, OBJECT_DRIVES, World

KHEPERA = agent_type("khepera")
# Tests marked with DRIVES run with both drives (World(drive=...)): what a controller
# sees (speeds, turns, counters, walls, the gripper) must not depend on it.


def lone_khepera(x: float = 500.0, y: float = 500.0, heading: float = 0.0, **kw) -> World:
    world = World(1000.0, 1000.0, seed=7, **kw)
    world.add_agent("k1", KHEPERA, x, y, heading)
    return world


@pytest.mark.parametrize("drive", DRIVES)
def test_speed_10_for_one_second_travels_80_mm(drive: str) -> None:
    world = lone_khepera(drive=drive)
    world.set_speeds(0, 10, 10)
    world.run(1.0)
    travelled = world.agent_pose[0, 0] - 500.0
    assert travelled == pytest.approx(80.0, rel=0.02)
    assert abs(world.agent_pose[0, 1] - 500.0) < 0.01


@pytest.mark.parametrize("drive", DRIVES)
def test_opposite_speeds_turn_at_the_wheel_base_rate(drive: str) -> None:
    world = lone_khepera(drive=drive)
    world.set_speeds(0, 10, -10)
    world.run(1.0)
    expected = -(2 * 10 * 8.0) / 53.0  # rad/s: wheel speeds 80 mm/s over a 53 mm base
    assert world.agent_pose[0, 2] == pytest.approx(expected, rel=0.02)
    assert np.hypot(*(world.agent_pose[0, :2] - 500.0)) < 0.5  # turned on the spot


@pytest.mark.parametrize("drive", DRIVES)
def test_counters_count_pulses_and_can_be_set(drive: str) -> None:
    world = lone_khepera(drive=drive)
    world.set_speeds(0, 10, -5)
    world.run(0.5)
    # 10 pulses per 10 ms for 0.5 s = 500 pulses; -5 -> -250.
    assert world.counters[0].tolist() == pytest.approx([500.0, -250.0])
    world.set_counters(0, 7, -7)
    assert world.counters[0].tolist() == [7, -7]


def test_speeds_clamp_to_127() -> None:
    world = lone_khepera()
    world.set_speeds(0, 500, -500)
    assert world.cmd[0].tolist() == [127, -127]


def test_ir_rises_along_the_curve_as_a_wall_approaches() -> None:
    world = World(1000.0, 1000.0, seed=3)
    world.add_obstacle("wall", ShapeSpec.box(20.0, 600.0), 700.0, 500.0)
    world.add_agent("k1", KHEPERA, 500.0, 500.0, 0.0)
    wall_face = 690.0
    readings = []
    for x in (600.0, 630.0, 640.0, 650.0, 655.0, 660.0, 662.0):
        world.move("k1", x, 500.0, 0.0)
        world.sense()
        front = world.proximity[0, 2:4].mean()
        distance = wall_face - (x + 25.0)  # front sensors sit 25 mm ahead of the centre
        readings.append(front)
        expected = float(PROXIMITY_CURVE(np.array([distance]))[0])
        assert front == pytest.approx(expected, abs=0.06 * 1023 * 0.5 + 8), (x, distance)
    assert readings == sorted(readings), readings
    assert readings[0] < 10 and readings[-1] > 700
    # The side sensors see nothing.
    assert world.proximity[0, 0] < 15 and world.proximity[0, 5] < 15


def test_a_wall_at_the_edge_of_the_ir_range_is_still_seen() -> None:
    """The sensing kernel skips static edges beyond a robot's reach: never one a ray reads."""
    world = World(1000.0, 1000.0, seed=3)
    world.add_obstacle("wall", ShapeSpec.box(20.0, 600.0), 700.0, 500.0)  # face at x = 690
    world.add_agent("k1", KHEPERA, 500.0, 500.0, 0.0)
    for distance in (40.0, 44.0, 47.0):  # from the front sensors; the curve ends at 50 mm
        world.move("k1", 690.0 - 25.0 - distance, 500.0, 0.0)
        world.sense()
        front = world.proximity[0, 2:4]
        expected = float(PROXIMITY_CURVE(np.array([distance]))[0])
        assert front.mean() == pytest.approx(expected, abs=8), (distance, front)
        assert front.max() > 0, (distance, front)


def test_ambient_falls_near_a_light_and_returns_to_dark_when_occluded() -> None:
    world = World(2000.0, 1000.0, seed=5)
    world.add_light("lamp", 1000.0, 500.0, intensity=1.0, radius_mm=400.0)
    world.add_agent("k1", KHEPERA, 500.0, 500.0, 0.0)  # facing the lamp
    values = []
    for x in (500.0, 700.0, 850.0, 940.0):
        world.move("k1", x, 500.0, 0.0)
        world.sense()
        values.append(world.ambient[0, 2:4].mean())
    assert values[0] == pytest.approx(500, abs=30)  # out of range: dark
    assert values[0] > values[1] > values[2] > values[3]
    assert values[3] < 200
    # A wall between the robot and the lamp: back to about 500.
    world.add_obstacle("screen", ShapeSpec.box(10.0, 300.0), 975.0, 500.0)
    world.sense()
    assert world.ambient[0, 2:4].mean() == pytest.approx(500, abs=30)


@pytest.mark.parametrize("drive", OBJECT_DRIVES)
def test_robot_grips_a_ball_and_carries_it(drive: str) -> None:
    world = World(1500.0, 1000.0, seed=2, drive=drive)
    world.add_agent("k1", KHEPERA, 300.0, 500.0, 0.0)
    world.add_object("ball", "ball", ShapeSpec.circle(10.0), 380.0, 500.0, mass_g=5.0)
    world.set_speeds(0, 5, 5)  # 40 mm/s onto the ball, tongs open and down
    for _ in range(200):
        world.step()
        if world.presence[0]:
            break
    assert world.presence[0] == 255, "the ball never got between the fingers"
    world.set_speeds(0, 0, 0)
    world.set_grip(0, closed=True)
    assert world.gripper_state(0) == 2
    assert world.resistivity(0) == world.objects[0].resistivity
    world.set_arm(0, 165)  # lift
    world.set_speeds(0, 10, 10)
    start = world.object_pose[0, :2].copy()
    world.run(1.0)
    moved = world.object_pose[0, :2] - start
    assert moved[0] == pytest.approx(80.0, rel=0.1)
    # Drop it: it stays where it was let go.
    world.set_speeds(0, 0, 0)
    world.set_arm(0, 255)
    world.run(0.5)
    world.set_grip(0, closed=False)
    assert world.gripper_state(0) == 0 and world.objects[0].held_by is None
    where = world.object_pose[0, :2].copy()
    world.set_speeds(0, -10, -10)
    world.run(0.5)
    assert np.hypot(*(world.object_pose[0, :2] - where)) < 1.0


@pytest.mark.parametrize("drive", OBJECT_DRIVES)
def test_a_ball_outside_the_exception_area_is_pushed(drive: str) -> None:
    world = World(1500.0, 1000.0, seed=2, drive=drive)
    world.add_agent("k1", KHEPERA, 300.0, 500.0, 0.0)
    world.add_object("ball", "ball", ShapeSpec.circle(10.0), 370.0, 540.0, mass_g=5.0)
    world.set_arm(0, 165)  # arm up: no tongs, the body pushes
    world.run(0.5)
    world.move("ball", 360.0, 500.0)
    world.set_speeds(0, 10, 10)
    world.run(1.0)
    assert world.object_pose[0, 0] > 380.0  # pushed ahead of the robot


@pytest.mark.parametrize("drive", DRIVES)
def test_walls_stop_a_robot(drive: str) -> None:
    world = lone_khepera(x=900.0, drive=drive)
    world.set_speeds(0, 60, 60)
    world.run(2.0)
    assert world.agent_pose[0, 0] <= 1000.0 - 27.5 + 1.0


@pytest.mark.parametrize("drive", DRIVES)
def test_same_seed_same_trajectory(drive: str) -> None:
    def run(seed: int) -> np.ndarray:
        world = World(1000.0, 1000.0, seed=seed, drive=drive)
        world.add_obstacle("box", ShapeSpec.box(100, 100), 500.0, 700.0)
        for i in range(6):
            world.add_agent(f"k{i}", KHEPERA, 200.0 + 100 * i, 400.0, math.pi / 2)
        for _ in range(150):
            prox = world.proximity.astype(float)
            left = 5 + (prox[:, 3:6].sum(1) - prox[:, 0:3].sum(1)) / 200
            right = 5 + (prox[:, 0:3].sum(1) - prox[:, 3:6].sum(1)) / 200
            world.set_speeds_all(np.stack([left, right], axis=1))
            world.step()
        return np.concatenate([world.agent_pose.ravel(), world.proximity.ravel()])

    assert np.array_equal(run(11), run(11))
    assert not np.array_equal(run(11), run(12))


@pytest.mark.parametrize("drive", DRIVES)
def test_epuck_is_a_second_type_in_the_same_world(drive: str) -> None:
    world = World(1000.0, 1000.0, seed=1, drive=drive)
    world.add_agent("k1", KHEPERA, 300.0, 500.0)
    world.add_agent("e1", agent_type("epuck"), 600.0, 500.0)
    world.set_speeds(1, 1000, 1000)  # 1000 steps/s of 0.129 mm
    world.run(1.0)
    assert world.agent_pose[1, 0] - 600.0 == pytest.approx(129.0, rel=0.03)
    assert not world.agents[1].has_gripper


@pytest.mark.parametrize("drive", OBJECT_DRIVES)
def test_presence_sees_round_objects_not_round_obstacles(drive: str) -> None:
    world = lone_khepera(drive=drive)
    world.add_object("crate", "box", ShapeSpec.box(30.0, 30.0), 700.0, 700.0)
    world.add_obstacle("post", ShapeSpec.circle(5.0), 538.0, 500.0)  # between the fingers
    world.step()
    assert world.presence[0] == 0
    world.remove("post")
    world.add_object("ball", "ball", ShapeSpec.circle(5.0), 538.0, 500.0, mass_g=5.0)
    world.step()
    assert world.presence[0] == 255


@pytest.mark.parametrize("drive", DRIVES)
def test_an_edit_between_ticks_is_seen_by_the_next_tick(drive: str) -> None:
    world = lone_khepera(drive=drive)
    world.set_speeds(0, 10, 10)
    world.run(0.2)
    world.move("k1", 200.0, 300.0, 0.0)
    world.step()
    # The drives with bodies start again from rest; the discs drive's robots move
    # at their wheels' speed at once (10 units: 1.6 mm in a 20 ms tick).
    x = 200.0 + (1.6 if drive == "discs" else 0.0)
    assert np.hypot(world.agent_pose[0, 0] - x, world.agent_pose[0, 1] - 300.0) < 1.0
