"""The discs drive (World(drive="discs"), common/sim2d/discs.py): swarm physics without chipmunk.

What a user relies on: a robot goes exactly where its wheels take it until
something is in the way; it never ends inside a wall, a pillar or the arena's
border; two robots meeting share the push and end apart; an edit sees where
the robots really are; a world on this drive refuses movable objects with a
message that says what to do; and the same seed gives the same run.
test_drive.py, test_khepera_fidelity.py and test_examples.py run this drive
beside the other two as well.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.sim2d.agents import agent_type
from common.sim2d.entities import ShapeSpec
from common.sim2d.world import EditError, World
from tests.kit.worlds import advance, build, tick_digest

KHEPERA = agent_type("khepera")
R = KHEPERA.radius_mm
MM_S = KHEPERA.drive.mm_per_s(np.float64(1.0))  # mm/s per speed unit
BASE = KHEPERA.drive.wheel_base_mm


def discs_world(width: float = 1000.0, height: float = 600.0, **kw: object) -> World:
    return World(width, height, seed=1, tick_s=0.01, drive="discs", **kw)  # type: ignore[arg-type]


def test_a_free_robot_follows_the_exact_arc_of_its_wheels() -> None:
    world = discs_world(2000.0, 2000.0)
    world.add_agent("k", KHEPERA, 1000.0, 1000.0, 0.3)
    world.set_speeds(0, 10, 20)
    world.run(1.0)
    v = (10 + 20) / 2 * MM_S
    w = (20 - 10) * MM_S / BASE
    th1 = 0.3 + w * 1.0
    x = 1000.0 + v / w * (math.sin(th1) - math.sin(0.3))
    y = 1000.0 - v / w * (math.cos(th1) - math.cos(0.3))
    assert world.agent_pose[0].tolist() == pytest.approx([x, y, th1], abs=1e-6)
    assert world.counters[0].tolist() == pytest.approx(
        [10 / KHEPERA.drive.unit_time_s, 20 / KHEPERA.drive.unit_time_s]
    )


def test_a_robot_driven_into_the_wall_stops_touching_it_and_keeps_its_heading() -> None:
    world = discs_world()
    world.add_agent("k", KHEPERA, 800.0, 300.0, 0.0)
    world.set_speeds(0, 127, 127)  # flat out: 1 m/s
    world.run(1.0)
    x, y, th = world.agent_pose[0]
    assert x == pytest.approx(1000.0 - R, abs=1e-9)
    assert (y, th) == pytest.approx((300.0, 0.0))
    assert abs(world.agent_vel[0, 0]) < 1e-6, "it is stopped, not bouncing"


@pytest.mark.parametrize(
    ("shape", "reach"),
    [(ShapeSpec.box(100.0, 100.0), 50.0 + R), (ShapeSpec.circle(40.0), 40.0 + R)],
)
def test_a_robot_driven_into_a_pillar_stops_outside_it(shape: ShapeSpec, reach: float) -> None:
    world = discs_world()
    world.add_obstacle("pillar", shape, 600.0, 300.0)
    world.add_agent("k", KHEPERA, 300.0, 310.0, 0.0)  # a little off centre: it slides
    world.set_speeds(0, 60, 60)
    for _ in range(150):
        world.step()
        x, y, _ = world.agent_pose[0]
        if shape.kind == "circle":
            gap = math.dist((x, y), (600.0, 300.0))
        else:  # outside the box's faces, or beyond a corner
            gap = math.hypot(max(abs(x - 600.0) - 50.0, 0.0), max(abs(y - 300.0) - 50.0, 0.0))
            gap += 50.0
        assert gap >= reach - 1e-6, f"{gap - reach:.3f} mm into the pillar"
    assert world.agent_pose[0, 0] > 500.0 - R - 1.0, "it got to the pillar"


def test_two_robots_head_on_end_touching_and_share_the_push() -> None:
    world = discs_world()
    world.add_agent("a", KHEPERA, 300.0, 300.0, 0.0)
    world.add_agent("b", KHEPERA, 700.0, 300.0, math.pi)
    world.set_speeds(0, 40, 40)
    world.set_speeds(1, 40, 40)
    world.run(2.0)
    a, b = world.agent_pose
    assert b[0] - a[0] == pytest.approx(2 * R, abs=0.3)
    assert (a[0] + b[0]) / 2 == pytest.approx(500.0, abs=1e-6), "equal robots: equal shares"
    # A faster one pushes a slower one back: the pair moves at the difference's half.
    world.set_speeds(0, 60, 60)
    before = world.agent_pose[:, 0].copy()
    world.run(1.0)
    moved = world.agent_pose[:, 0] - before
    assert moved == pytest.approx([10 * MM_S, 10 * MM_S], abs=0.5)


def test_a_crowd_never_ends_a_tick_inside_a_wall() -> None:
    world = discs_world(800.0, 800.0)
    for i in range(100):
        world.add_agent(f"k{i}", KHEPERA, 60.0 + 68.0 * (i % 10), 60.0 + 68.0 * (i // 10), 0.8)
    world.set_speeds_all(np.full((100, 2), 127.0))
    for _ in range(200):
        world.step()
        pose = world.agent_pose
        assert pose[:, :2].min() >= R - 1e-9 and pose[:, :2].max() <= 800.0 - R + 1e-9
    gaps = np.hypot(*(pose[:, None, :2] - pose[None, :, :2]).transpose(2, 0, 1))
    np.fill_diagonal(gaps, np.inf)
    assert gaps.min() > 2 * R - 10.0, "robots passed into each other"


def test_an_edit_sees_where_the_robots_have_driven() -> None:
    # Chipmunk is not stepped on this drive: the robots' bodies must still be where
    # the robots are when an edit asks what a new obstacle would overlap.
    world = discs_world()
    world.add_agent("k", KHEPERA, 200.0, 300.0, 0.0)
    world.set_speeds(0, 50, 50)
    world.run(1.0)
    x = float(world.agent_pose[0, 0])
    assert x == pytest.approx(200.0 + 50 * MM_S, abs=1e-6)
    with pytest.raises(EditError, match=r"would overlap agent\(s\) k"):
        world.add_obstacle("post", ShapeSpec.box(30.0, 30.0), x, 300.0)
    world.add_obstacle("post", ShapeSpec.box(30.0, 30.0), 200.0, 300.0)  # where it was
    world.move("k", 700.0, 150.0, 1.0)
    world.step()
    assert world.agent_pose[0].tolist() == pytest.approx(
        [700.0 + 50 * MM_S * 0.01 * math.cos(1.0), 150.0 + 50 * MM_S * 0.01 * math.sin(1.0), 1.0]
    )


def test_same_seed_same_swarm_run_bit_for_bit() -> None:
    first, again = (advance(build(300, seed=4, drive="discs"), 100) for _ in range(2))
    assert tick_digest(first) == tick_digest(again)


def test_a_wandering_swarm_stays_in_the_arena_and_out_of_the_pillars() -> None:
    world = build(1000, seed=2, drive="discs")
    pillars = [o for o in world.obstacles.values()]
    start = world.agent_pose.copy()
    pose = advance(world, 150).agent_pose
    assert np.hypot(*(pose[:, :2] - start[:, :2]).T).mean() > 20.0, "the swarm moves"
    assert pose[:, :2].min() >= R - 1e-9
    assert pose[:, :2].max() <= world.width - R + 1e-9
    for p in pillars:  # 60 mm boxes: no centre within R of a face
        dx = np.maximum(np.abs(pose[:, 0] - p.x) - 30.0, 0.0)
        dy = np.maximum(np.abs(pose[:, 1] - p.y) - 30.0, 0.0)
        assert np.hypot(dx, dy).min() >= R - 1e-6, p.id


def test_a_crowd_with_more_contacts_than_the_buffers_hold_moves_as_with_room() -> None:
    # The drive keeps its pair table and the pair grid's offsets from tick to
    # tick (four pairs a disc); a crowd that needs more gets them in new arrays,
    # and must move exactly as if they had been there all along.
    from common.sim2d import compiled, discs

    world = build(40, seed=4, drive="discs", balls=0.5)
    for i, (x, y, _) in enumerate(world.agent_pose.copy()):
        world.move(f"k{i}", float(x), float(y), float(np.arctan2(-y, -x)))
    for _ in range(150):  # flat out into the corner: pressed together
        world.set_speeds_all(np.full((len(world.agents), 2), 127.0))
        world.step()
    world.profile = True  # the general path: compiled.discs_tick gets the drive's arguments
    seen: list[tuple] = []
    real = compiled.discs_tick
    compiled.discs_tick = lambda *args: seen.append(args) or real(*args)  # type: ignore[assignment]
    try:
        world.step()
    finally:
        compiled.discs_tick = real  # type: ignore[assignment]
    robots, drive, scene, circles, geometry, substeps, objects = seen[0]
    pose, cmd, counters, arm = robots
    radius = drive[3]
    width, height, _ = geometry
    n, k = len(pose), len(objects[0])

    def tick(buffers: tuple) -> tuple[np.ndarray, ...]:
        out, vel, c, o = np.empty((n, 3)), np.empty((n, 3)), counters.copy(), objects
        o = tuple(a.copy() for a in objects)
        robots = (pose, cmd, c, arm)
        discs.tick_into(robots, drive, scene, circles, geometry, substeps, o, (out, vel), buffers)
        return (out, vel, c, o[0], o[1])

    roomy = discs.drive_buffers(n, k, width, height, radius)
    cramped = list(discs.drive_buffers(n, k, width, height, radius))
    cramped[19] = np.empty(1, dtype=np.int64)  # the grid's offsets: one cell's worth
    cramped[20] = np.empty((1, 2), dtype=np.int64)  # the pair table: one pair
    found = discs._pairs(pose[:, 0].copy(), pose[:, 1].copy(), radius, width, height, 56.0,
                         1.0, roomy[13:21])  # fmt: skip
    assert len(found) > 40, "a crowd: more pairs than discs"
    for a, b in zip(tick(roomy), tick(tuple(cramped)), strict=True):
        assert np.array_equal(a, b)
