"""Movable objects on the discs drive (common/sim2d/pucks.py, world_discs.py): what a user sees.

Objects are pushed by a robot driving into them and come to rest when it
stops; robots and objects do not overlap (beyond the solver's small
tolerance) however hard a crowd pushes; walls and obstacles hold objects; the
gripper picks, carries and drops one; the lab's maps load on this drive by
default; edits and grips between ticks are seen by the next tick; and the
fused tick gives the general path's run bit for bit with objects too.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from common.sim2d.agents import agent_type
from common.sim2d.drives import DEFAULT_DRIVE
from common.sim2d.entities import ShapeSpec
from common.sim2d.maps import load_map
from common.sim2d.world import World

KHEPERA = agent_type("khepera")
R = KHEPERA.radius_mm
REPO = Path(__file__).resolve().parents[4]


def discs_world(width: float = 1000.0, height: float = 600.0) -> World:
    return World(width, height, seed=1, tick_s=0.01, drive="discs")


def test_the_default_drive_is_discs_and_the_foraging_map_loads_on_it() -> None:
    assert DEFAULT_DRIVE == "discs"
    assert World(100.0, 100.0).drive == "discs"
    world = load_map(REPO / "maps" / "foraging.json", name="f", seed=1)
    assert world.drive == "discs"
    assert len(world.objects) == 14 and len(world.agents) >= 1
    world.run(0.5)  # steps, objects and all
    assert world.object_pose.shape == (14, 3)


@pytest.mark.parametrize("kind", ["ball", "box"])
def test_a_robot_pushes_an_object_and_it_stops_when_the_robot_stops(kind: str) -> None:
    world = discs_world()
    world.add_agent("k", KHEPERA, 200.0, 300.0, 0.0)
    shape = ShapeSpec.circle(10.0) if kind == "ball" else ShapeSpec.box(40.0, 40.0)
    world.add_object("o", kind, shape, 300.0, 300.0, mass_g=10.0)
    world.set_arm(0, 165)  # arm up: the body pushes (no exception area)
    world.set_speeds(0, 10, 10)  # 80 mm/s
    world.run(2.0)
    robot, obj = world.agent_pose[0], world.object_pose[0]
    assert obj[0] - 300.0 > 80.0, "pushed along"
    assert abs(obj[1] - 300.0) < 1.0, "straight ahead"
    contact = R + shape.bounding_radius_mm
    assert obj[0] - robot[0] == pytest.approx(contact, abs=2.0), "in contact, not overlapping"
    world.set_speeds(0, 0, 0)
    world.run(0.1)
    rest = world.object_pose[0].copy()
    world.run(1.0)
    assert np.array_equal(world.object_pose[0], rest), "at rest once nobody pushes it"
    assert np.hypot(*world.agent_vel[0, :2]) == 0.0


def _overlaps(world: World) -> tuple[float, float]:
    """Deepest overlap of two discs (robots and objects), and of a disc past the border."""
    n = len(world.agents)
    xy = np.concatenate([world.agent_pose[:, :2], world.object_pose[:, :2]])
    r = np.concatenate([world.tables.radius, [o.shape.bounding_radius_mm for o in world.objects]])
    gaps = np.hypot(*(xy[:, None] - xy[None, :]).transpose(2, 0, 1)) - (r[:, None] + r[None, :])
    np.fill_diagonal(gaps, np.inf)
    assert n == len(world.agents)
    outside = max(
        float(np.max(r - xy[:, 0])),
        float(np.max(r - xy[:, 1])),
        float(np.max(xy[:, 0] + r - world.width)),
        float(np.max(xy[:, 1] + r - world.height)),
    )
    return -float(gaps.min()), outside


def test_a_crowd_with_balls_pressed_into_a_corner_stays_apart_and_inside() -> None:
    world = discs_world(800.0, 800.0)
    rng = np.random.default_rng(5)
    for i in range(30):
        world.add_agent(f"k{i}", KHEPERA, 450.0 + 60.0 * (i % 6), 450.0 + 60.0 * (i // 6), 3.9)
    for j in range(20):
        x, y = 100.0 + 30.0 * (j % 5), 100.0 + 30.0 * (j // 5) + rng.uniform(0, 5)
        world.add_object(f"b{j}", "ball", ShapeSpec.circle(10.0), x, y, mass_g=5.0)
    for slot in range(30):
        world.set_arm(slot, 165)
    world.set_speeds_all(np.full((30, 2), 20.0))  # all of them flat out toward the corner
    worst, outside = 0.0, 0.0
    for _ in range(300):
        world.step()
        o, w = _overlaps(world)
        worst, outside = max(worst, o), max(outside, w)
    assert outside <= 1e-9, "a robot or a ball past the arena's border"
    assert worst < 6.0, f"two discs overlap by {worst:.1f} mm"
    # The balls were pushed into the corner, not driven over.
    assert world.object_pose[:, :2].max() < 400.0


def test_walls_and_obstacles_hold_objects() -> None:
    world = discs_world()
    world.add_obstacle("post", ShapeSpec.box(40.0, 200.0), 600.0, 300.0)
    world.add_agent("k1", KHEPERA, 400.0, 300.0, 0.0)
    world.add_agent("k2", KHEPERA, 800.0, 100.0, 0.0)
    world.add_object("b1", "ball", ShapeSpec.circle(10.0), 460.0, 300.0, mass_g=5.0)
    world.add_object("b2", "ball", ShapeSpec.circle(10.0), 880.0, 100.0, mass_g=5.0)
    for slot in range(2):
        world.set_arm(slot, 165)
        world.set_speeds(slot, 20, 20)
    world.run(3.0)
    b1, b2 = world.object_pose[0], world.object_pose[1]
    assert b1[0] == pytest.approx(580.0 - 10.0, abs=0.5), "held by the post's face"
    assert b2[0] == pytest.approx(1000.0 - 10.0, abs=0.5), "held by the arena's wall"
    k1, k2 = world.agent_pose[0], world.agent_pose[1]
    assert k1[0] == pytest.approx(570.0 - 10.0 - R, abs=1.0), "the robot stops at the ball"
    assert k2[0] == pytest.approx(990.0 - 10.0 - R, abs=1.0)


def test_the_gripper_picks_carries_and_drops_a_ball_through_a_crowd() -> None:
    world = discs_world()
    world.add_agent("k", KHEPERA, 200.0, 300.0, 0.0)
    world.add_agent("other", KHEPERA, 500.0, 250.0, math.pi / 2)
    world.add_object("ball", "ball", ShapeSpec.circle(10.0), 280.0, 300.0, mass_g=5.0)
    world.set_speeds(0, 5, 5)  # tongs open and down: the ball comes between them
    for _ in range(300):
        world.step()
        if world.presence[0]:
            break
    assert world.presence[0] == 255
    world.set_speeds(0, 0, 0)
    world.set_grip(0, closed=True)
    assert world.gripper_state(0) == 2
    world.set_arm(0, 165)
    world.set_speeds(0, 10, 10)
    world.run(2.0)  # carried over the other robot's path: raised, it meets nothing
    robot, ball = world.agent_pose[0], world.object_pose[0]
    ahead = (ball[0] - robot[0]) * math.cos(robot[2]) + (ball[1] - robot[1]) * math.sin(robot[2])
    assert 28.0 <= ahead <= 50.0 and abs(ball[1] - robot[1]) < 10.0, "rides in the grip"
    assert ball[0] > 400.0
    world.set_speeds(0, 0, 0)
    world.set_arm(0, 255)
    world.run(0.5)
    world.set_grip(0, closed=False)
    assert world.gripper_state(0) == 0
    where = world.object_pose[0].copy()
    world.set_speeds(0, -10, -10)
    world.run(1.0)
    assert np.hypot(*(world.object_pose[0, :2] - where[:2])) < 1.0, "left where it was dropped"
    assert world.pose_of("ball")[0] == pytest.approx(where[0]), "the edits see it there"


def test_a_held_ball_with_the_arm_down_pushes_and_is_pushed_with_its_holder() -> None:
    world = discs_world()
    world.add_agent("k", KHEPERA, 700.0, 300.0, 0.0)
    world.add_object("ball", "ball", ShapeSpec.circle(10.0), 738.0, 300.0, mass_g=5.0)
    world.set_grip(0, closed=True)
    assert world.gripper_state(0) == 2
    world.set_speeds(0, 20, 20)  # into the wall, the ball first
    world.run(2.0)
    robot, ball = world.agent_pose[0], world.object_pose[0]
    assert ball[0] <= 1000.0 - 10.0 + 1e-6, "the wall holds the held ball"
    assert robot[0] == pytest.approx(ball[0] - 38.0, abs=0.5), "and so its holder"


def test_edits_between_ticks_are_seen_and_the_fused_tick_is_the_general_path() -> None:
    def build(profile: bool) -> World:
        world = load_map(REPO / "maps" / "foraging.json", name="f", seed=3, tick_s=0.01)
        world.profile = profile  # profiled: the general path, not the fused call
        return world

    fast, slow = build(False), build(True)
    rng = np.random.default_rng(1)
    speeds = rng.uniform(-5, 15, (len(fast.agents), 2))
    for t in range(400):
        for world in (fast, slow):
            if t == 0:
                world.set_speeds_all(speeds)
            elif t == 100:
                world.move("ball3", 700.0, 900.0)
            elif t == 150:
                world.remove("ball5")
            elif t == 200:
                world.add_object("late", "ball", ShapeSpec.circle(10.0), 1500.0, 100.0)
            elif t == 250:
                world.set_speeds_all(-speeds)
            world.step()
        assert np.array_equal(fast.agent_pose, slow.agent_pose), t
        assert np.array_equal(fast.object_pose, slow.object_pose), t
        assert np.array_equal(fast.proximity, slow.proximity), t


def test_a_swarm_with_balls_sensed_on_two_threads_is_the_one_thread_run() -> None:
    from tests.kit.worlds import advance, build, tick_digest

    one, two = (advance(build(300, threads=n, drive="discs", balls=0.5), 60) for n in (1, 2))
    assert tick_digest(one) == tick_digest(two)
    fresh = build(300, balls=0.5)
    start = np.array([fresh.pose_of(o.id)[:2] for o in fresh.objects])
    pushed = np.hypot(*(one.object_pose[:, :2] - start).T)
    assert pushed.max() > 1.0, "some balls were pushed"


def _edited_discs_run(seed: int, ticks: int, profile: bool) -> list[np.ndarray]:
    """Random live edits between ticks (test_chipmunk's), on the discs drive."""
    from common.sim2d.wander import braitenberg
    from tests.unit.common.sim2d.test_chipmunk import _busy_world, _random_edit

    world = _busy_world(seed, "discs")
    world.profile = profile  # profiled: the general path, not the fused call
    rng = np.random.default_rng(seed + 100)
    rows: list[np.ndarray] = []
    for serial in range(ticks):
        world.set_speeds_all(braitenberg(world.proximity))
        _random_edit(world, rng, serial, arms=True)
        world.step()
        # Every object's pose as the edits see it (the bodies, placed) is the drive's.
        placed = np.array([world.pose_of(o.id) for o in world.objects]).reshape(-1, 3)
        assert np.array_equal(placed, world.object_pose), serial
        rows.append(np.concatenate([world.agent_pose.ravel(), world.object_pose.ravel()]))
    return rows


@pytest.mark.parametrize("seed", [1, 2])
def test_random_live_edits_and_grips_run_the_same_on_both_paths(seed: int) -> None:
    fast = _edited_discs_run(seed, 400, profile=False)
    slow = _edited_discs_run(seed, 400, profile=True)
    assert len(fast) == len(slow)
    for a, b in zip(fast, slow, strict=True):
        assert np.array_equal(a, b)
