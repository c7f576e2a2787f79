"""The compiled physics tick calls chipmunk directly: it must agree with pymunk."""

from __future__ import annotations

import numpy as np
import pymunk
import pytest

from common.sim2d import chipmunk, kernels
from common.sim2d.agents import agent_type
from common.sim2d.entities import ShapeSpec
from common.sim2d.sensing import NoiseKeys
from common.sim2d.wander import braitenberg
from common.sim2d.world import World

KHEPERA = agent_type("khepera")


def test_read_bodies_matches_pymunk_accessors() -> None:
    space = pymunk.Space()
    bodies = []
    for i in range(5):
        body = pymunk.Body(10.0, 100.0)
        body.position = (10.0 * i + 0.25, -3.5 * i)
        body.angle = 0.3 * i - 1.0
        body.velocity = (i * 1.5, -i * 2.25)
        body.angular_velocity = 0.125 * i
        space.add(body, pymunk.Circle(body, 5.0))
        bodies.append(body)
    addr = chipmunk.addresses(bodies)
    pose, vel, obj = kernels.read_bodies(chipmunk.FUNCTIONS, addr, addr[:2])
    for i, b in enumerate(bodies):
        assert tuple(pose[i]) == (b.position.x, b.position.y, b.angle)
        assert tuple(vel[i]) == (b.velocity.x, b.velocity.y, b.angular_velocity)
    assert np.array_equal(obj, pose[:2])


def test_physics_tick_drives_control_bodies_and_counts_pulses() -> None:
    space = pymunk.Space()
    robot = pymunk.Body(10.0, 100.0)
    robot.angle = np.pi / 2
    control = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
    space.add(robot, control, pymunk.Circle(robot, 5.0))
    counters = np.zeros((1, 2))
    kernels.physics_tick(
        chipmunk.FUNCTIONS,
        chipmunk.FUNCTIONS[chipmunk.SPACE_STEP],
        np.uint64(chipmunk.space_address(space)),
        0.01,
        0,  # drive only
        chipmunk.addresses([control]),
        chipmunk.addresses([robot]),
        np.zeros(0, dtype=np.uint64),
        np.array([[10.0, 20.0]]),  # wheel speeds
        counters,
        # mm/s per unit, wheel base, pulses per unit this tick
        (np.array([8.0]), np.array([53.0]), np.array([0.5])),
    )
    # 80 and 160 mm/s wheels: 120 mm/s forward along the heading (+y), turning left.
    assert control.velocity.x == pytest.approx(0.0, abs=1e-9)
    assert control.velocity.y == pytest.approx(120.0)
    assert control.angular_velocity == pytest.approx(80.0 / 53.0)
    assert counters.tolist() == [[5.0, 10.0]]


def _busy_world(seed: int = 3, drive: str = "joints") -> World:
    world = World(700.0, 700.0, seed=seed, tick_s=0.01, sensor_period_s=0.02, drive=drive)
    world.add_obstacle("pillar", ShapeSpec.box(60, 60), 350.0, 350.0)
    rng = np.random.default_rng(seed)
    placed = 0
    while placed < 12:
        x, y = rng.uniform(60, 640, 2)
        try:
            if placed < 8:
                world.add_agent(
                    f"k{placed}", KHEPERA, float(x), float(y), float(rng.uniform(-3, 3))
                )
            else:
                world.add_object(f"o{placed}", "ball", ShapeSpec.circle(20), float(x), float(y))
        except ValueError:
            continue
        placed += 1
    return world


def _trajectory(world: World, ticks: int) -> np.ndarray:
    rows = []
    for t in range(ticks):
        world.set_speeds_all(braitenberg(world.proximity))
        if t == 100:  # a body added mid-run: that tick goes through pymunk's step
            world.add_object("late", "box", ShapeSpec.box(30, 30), 30.0, 30.0)
        world.step()
        rows.append(np.concatenate([world.agent_pose.ravel(), world.object_pose.ravel()[:12]]))
    return np.array(rows)


@pytest.mark.parametrize("drive", ["joints", "velocity"])
def test_stepping_through_chipmunk_gives_pymunks_trajectory(monkeypatch, drive: str) -> None:
    direct = _trajectory(_busy_world(drive=drive), 300)
    monkeypatch.setattr(chipmunk, "space_step_pending", lambda space: True)
    via_pymunk = _trajectory(_busy_world(drive=drive), 300)
    assert np.abs(direct[-1] - direct[0]).max() > 50.0  # the robots did move
    assert np.array_equal(direct, via_pymunk)


def test_noise_keys_hand_out_the_generators_raw_words_in_order() -> None:
    keys = NoiseKeys(np.random.default_rng(11), block=64)
    per_pass = np.random.default_rng(11)
    for _ in range(300):  # across several blocks
        assert keys.next() == per_pass.bit_generator.random_raw()


def test_set_speeds_all_checks_shape_rounds_clamps_and_stops_on_nan() -> None:
    world = World(1000.0, 1000.0, seed=1)
    world.add_agent("a", KHEPERA, 300.0, 300.0)
    world.add_agent("b", KHEPERA, 700.0, 700.0)
    with pytest.raises(ValueError, match=r"\(2, 2\)"):
        world.set_speeds_all(np.zeros((3, 2)))
    top = float(world.tables.max_speed[0])
    world.set_speeds_all([[2.4, np.nan], [top + 50, -(top + 50)]])
    assert world.cmd.tolist() == [[2.0, 0.0], [top, -top]]


def test_moving_a_light_moves_the_bright_readings() -> None:
    # The lit-lights table is cached between passes: an edit must still show.
    world = World(1000.0, 1000.0, seed=1, sensor_period_s=0.02)
    world.add_agent("k", KHEPERA, 500.0, 500.0, 0.0)
    world.add_light("lamp", 560.0, 500.0, radius_mm=400.0)  # just ahead
    world.run(0.1)
    front, back = [2, 3], [6, 7]  # Khepera ambient sensors facing ahead and behind
    assert world.ambient[0, front].max() < 200 < world.ambient[0, back].min()
    world.lights[0].x = 440.0  # behind the robot now
    world.run(0.1)
    assert world.ambient[0, back].max() < 200 < world.ambient[0, front].min()


def _edited_trajectory(seed: int, ticks: int, drive: str = "joints") -> list[np.ndarray]:
    """Random live edits between ticks: agents and objects come and go, move, grip."""
    world = _busy_world(seed, drive)
    rng = np.random.default_rng(seed + 100)
    rows: list[np.ndarray] = []
    for serial in range(ticks):
        world.set_speeds_all(braitenberg(world.proximity))
        _random_edit(world, rng, serial)
        world.step()
        _assert_arrays_are_the_bodies(world)
        rows.append(np.concatenate([world.agent_pose.ravel(), world.object_pose.ravel()]))
    return rows


def _random_edit(world: World, rng: np.random.Generator, serial: int, arms: bool = False) -> None:
    """One draw of 12 for a live edit: an agent or object comes, goes or moves, a gripper
    opens or shuts (with ``arms``, an arm lifts); the other draws edit nothing."""
    op = rng.integers(0, 12)
    x, y = (float(v) for v in rng.uniform(60, 640, 2))
    try:
        if op == 0:
            world.add_agent(f"n{serial}", KHEPERA, x, y, 0.0)
        elif op == 1 and len(world.agents) > 1:
            world.remove(world.agents[int(rng.integers(len(world.agents)))].id)
        elif op == 2:
            world.add_object(f"b{serial}", "ball", ShapeSpec.circle(20), x, y)
        elif op == 3 and world.objects:
            world.remove(world.objects[int(rng.integers(len(world.objects)))].id)
        elif op == 4 and world.agents:
            world.move(world.agents[int(rng.integers(len(world.agents)))].id, x, y)
        elif op == 5 and world.objects:
            world.move(world.objects[int(rng.integers(len(world.objects)))].id, x, y)
        elif op == 6 and world.agents:
            slot = int(rng.integers(len(world.agents)))
            world.set_grip(slot, bool(rng.integers(2)))
        elif op == 7 and arms and world.agents:
            world.set_arm(int(rng.integers(len(world.agents))), int(rng.integers(165, 256)))
    except ValueError:
        pass  # an edit the world refused (overlap, outside): the world is unchanged


def _assert_arrays_are_the_bodies(world: World) -> None:
    """The world's pose arrays hold exactly its bodies' states, as pymunk reads them."""
    agents = [[a.body.position.x, a.body.position.y, a.body.angle] for a in world.agents]
    assert world.agent_pose.tolist() == agents
    with_body = [o for o in world.objects if o.body is not None]
    assert len(world.object_pose) == len(with_body)
    for row, o in zip(world.object_pose.tolist(), with_body, strict=True):
        if o.held_by is None:  # a held object is carried after the read, by design
            assert row == [o.body.position.x, o.body.position.y, o.body.angle]


@pytest.mark.parametrize(("seed", "drive"), [(1, "joints"), (2, "joints"), (1, "velocity")])
def test_live_edits_between_ticks_step_the_same_as_pymunk(
    monkeypatch, seed: int, drive: str
) -> None:
    # Bodies added, removed and moved between ticks: the compiled tick must never
    # read a body that is gone, nor miss one that arrived (checked against pymunk's
    # own accessors every tick), and must step as pymunk's Space.step does.
    direct = _edited_trajectory(seed, 400, drive)
    monkeypatch.setattr(chipmunk, "space_step_pending", lambda space: True)
    via_pymunk = _edited_trajectory(seed, 400, drive)
    assert len(direct) == len(via_pymunk)
    for a, b in zip(direct, via_pymunk, strict=True):
        assert np.array_equal(a, b)
