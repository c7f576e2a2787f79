"""How robots are driven (World(drive=...)): the joints drive and the swarm's velocity drive.

What a user sees must not depend on the drive: robots stop at walls, cannot
overlap or push each other through a wall, push light objects, and their
position counters follow the commanded wheel speeds while the pose follows
the counters. Both drives run every test; tests/unit/common/sim2d/
test_khepera_fidelity.py and test_examples.py run the manual's numbers, the
gripper and the example controllers with both too.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from common.sim2d.agents import agent_type
from common.sim2d.entities import ShapeSpec
from common.sim2d.maps import load_map
from common.sim2d.world import DRIVES, OBJECT_DRIVES, EditError, World
from services.engine.main import main as engine_main

KHEPERA = agent_type("khepera")
R = KHEPERA.radius_mm
REPO = Path(__file__).resolve().parents[4]


def _gaps(pose: np.ndarray) -> np.ndarray:
    gaps = np.hypot(*(pose[:, None, :2] - pose[None, :, :2]).transpose(2, 0, 1))
    np.fill_diagonal(gaps, np.inf)
    return gaps


def test_the_drive_is_checked_by_the_world_the_maps_and_the_engine(capsys) -> None:
    with pytest.raises(EditError, match="drive must be one of joints, velocity, discs"):
        World(500.0, 500.0, drive="tank")
    world = load_map(REPO / "maps" / "maze.json", name="m", drive="velocity")
    assert world.drive == "velocity"
    assert len(world.space.constraints) == 0, "the velocity drive has no joints"
    with pytest.raises(SystemExit) as exc:
        engine_main(["--map", str(REPO / "maps" / "empty.json"), "--drive", "tank"])
    assert exc.value.code == 2
    assert "--drive: invalid choice" in capsys.readouterr().err


@pytest.mark.parametrize("drive", DRIVES)
def test_a_crowd_driven_into_a_corner_stays_inside_and_apart(drive: str) -> None:
    # 140 robots flat out toward the top-right corner for 3 s: each is pushed by
    # the ones behind it, and the front rows by the whole crowd.
    world = World(1000.0, 1200.0, seed=1, tick_s=0.01, drive=drive)
    for i in range(140):
        x, y = 80.0 + 62.0 * (i % 14), 40.0 + 62.0 * (i // 14)
        world.add_agent(f"k{i}", KHEPERA, x, y, 0.6, defer_tables=True)
    world.finish_agents()
    world.set_speeds_all(np.full((140, 2), 60.0))
    world.run(3.0)
    pose = world.agent_pose
    assert pose[:, 0].max() > 1000.0 - R - 5.0, "the crowd never reached the wall"
    # Measured: at most 3 to 6 mm into a wall with either drive, up to 7 mm between
    # two robots' discs with the joints drive and 11 with the velocity drive (chipmunk's
    # soft contacts under the push of the whole crowd); a robot pushed through a wall
    # or another robot would be tens of mm past.
    past = max(
        (pose[:, 0] + R - 1000.0).max(),
        (pose[:, 1] + R - 1200.0).max(),
        (R - pose[:, 0]).max(),
        (R - pose[:, 1]).max(),
    )
    assert past < 10.0, f"a robot {past:.1f} mm into a wall"
    assert _gaps(pose).min() > 2 * R - 15.0, "robots passed into each other"


@pytest.mark.parametrize("drive", DRIVES)
def test_a_robot_cannot_push_another_through_a_wall_or_into_itself(drive: str) -> None:
    world = World(1000.0, 600.0, seed=1, drive=drive)
    world.add_agent("pushed", KHEPERA, 1000.0 - R - 2.0, 300.0, 0.0)
    world.add_agent("pusher", KHEPERA, 800.0, 300.0, 0.0)
    world.set_speeds(1, 127, 127)  # flat out into its stopped neighbour
    world.run(3.0)
    pushed, pusher = world.agent_pose
    assert pushed[0] <= 1000.0 - R + 1.0, "pushed into the wall"
    assert pusher[0] > 1000.0 - 4 * R - 25.0, "the pusher never got there (tongs first)"
    assert math.dist(pushed[:2], pusher[:2]) > 2 * R - 1.0, "the robots overlap"


@pytest.mark.parametrize("drive", OBJECT_DRIVES)
def test_a_robot_pushes_a_light_box_ahead_of_it(drive: str) -> None:
    world = World(1500.0, 1000.0, seed=2, drive=drive)
    world.add_agent("k1", KHEPERA, 300.0, 500.0, 0.0)
    world.add_object("box", "box", ShapeSpec.box(40.0, 40.0), 360.0, 500.0, mass_g=20.0)
    world.set_arm(0, 165)  # arm up: the body pushes
    world.set_speeds(0, 10, 10)
    world.run(2.0)
    assert world.object_pose[0, 0] - 360.0 == pytest.approx(160.0 - 10.5, abs=15.0)
    # Its centre is 20 mm behind the face the robot pushes (a few mm less if it turned
    # or the contact gives a little); a box the robot drove into would be closer.
    assert world.object_pose[0, 0] > world.agent_pose[0, 0] + R + 15.0, "pushed, not overlapped"


@pytest.mark.parametrize("drive", DRIVES)
def test_counters_follow_the_commands_and_the_pose_follows_the_counters(drive: str) -> None:
    # Speeds changing every half second, turns and straights: the counters add up
    # the commanded pulses, and dead reckoning from them lands where the robot is.
    world = World(2000.0, 2000.0, seed=3, tick_s=0.01, drive=drive)
    world.add_agent("k", KHEPERA, 1000.0, 1000.0, 0.0)
    drive_spec = KHEPERA.drive
    mm_per_pulse, base = drive_spec.mm_per_pulse, drive_spec.wheel_base_mm
    x, y, th = 1000.0, 1000.0, 0.0
    pulses = np.zeros(2)
    last = world.counters[0].copy()
    for left, right in [(10, 10), (12, -12), (5, 15), (20, 20), (-8, -8), (15, 5), (0, 0)]:
        world.set_speeds(0, left, right)
        for _ in range(50):
            world.step()
            dl, dr = (world.counters[0] - last) * mm_per_pulse
            last = world.counters[0].copy()
            d, dth = (dl + dr) / 2.0, (dr - dl) / base
            x += d * math.cos(th + dth / 2)
            y += d * math.sin(th + dth / 2)
            th += dth
        pulses += np.array([left, right]) * 50 * (world.tick_s / drive_spec.unit_time_s)
    assert world.counters[0].tolist() == pytest.approx(pulses.tolist())
    pose = world.agent_pose[0]
    assert math.dist((x, y), pose[:2]) < 3.0, ((x, y), pose[:2])
    assert math.remainder(th - pose[2], math.tau) == pytest.approx(0.0, abs=0.02)


def test_velocity_drive_tongs_touch_objects_only() -> None:
    # With the velocity drive lowered tongs collide with movable objects only: the
    # disc meets the wall (the joints drive stops 25 mm short, on its tongs), and a
    # ball beside the gap between the tongs is still pushed by a tong.
    for drive, stop in (("velocity", 1000.0 - R), ("joints", 1000.0 - 52.0)):
        world = World(1000.0, 1000.0, seed=1, drive=drive)
        world.add_agent("k", KHEPERA, 800.0, 500.0, 0.0)
        world.set_speeds(0, 20, 20)
        world.run(2.0)
        assert world.agent_pose[0, 0] == pytest.approx(stop, abs=1.5), drive
    world = World(1500.0, 1000.0, seed=1, drive="velocity")
    world.add_agent("k", KHEPERA, 300.0, 500.0, 0.0)
    # A ball centred on the left tong's line, outside the exception area's gap.
    world.add_object("ball", "ball", ShapeSpec.circle(8.0), 380.0, 518.0, mass_g=5.0)
    world.set_speeds(0, 10, 10)
    world.run(1.5)
    assert world.object_pose[0, 0] > world.agent_pose[0, 0] + 52.0, "the tong pushed it"


def test_velocity_drive_tongs_are_in_the_space_only_while_there_are_objects() -> None:
    # Tongs that touch objects only cannot touch anything without objects: they
    # stay out of chipmunk's space then (a swarm's cost), and come back with the
    # first object, so a ball added to a running world is gripped as usual.
    world = World(1500.0, 1000.0, seed=1, drive="velocity")
    for i in range(3):
        world.add_agent(f"k{i}", KHEPERA, 300.0, 200.0 + 300.0 * i, 0.0)
    walls = 4
    assert len(world.space.shapes) == walls + 3, "discs only"
    world.run(0.5)
    world.add_object("ball", "ball", ShapeSpec.circle(10.0), 380.0, 500.0, mass_g=5.0)
    assert len(world.space.shapes) == walls + 3 * 3 + 1
    world.set_speeds(1, 5, 5)
    for _ in range(200):
        world.step()
        if world.presence[1]:
            break
    world.set_speeds(1, 0, 0)
    world.set_grip(1, closed=True)
    assert world.gripper_state(1) == 2, "gripped"
    world.remove("ball")
    assert len(world.space.shapes) == walls + 3
    world.remove("k0")
    world.add_object("box", "box", ShapeSpec.box(20.0, 20.0), 1000.0, 500.0)
    assert len(world.space.shapes) == walls + 2 * 3 + 1
    world.run(0.2)
