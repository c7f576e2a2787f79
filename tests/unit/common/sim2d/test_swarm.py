"""Swarms on more than one core (issue 22): parallel sensing, chipmunk's threaded space."""

from __future__ import annotations

from collections.abc import Iterable

import numba
import numpy as np
import pytest

from common.sim2d import kernels, packs, rays, sensing
from common.sim2d.agents import agent_type
from common.sim2d.entities import ShapeSpec
from common.sim2d.packs import StaticScene
from common.sim2d.wander import braitenberg
from common.sim2d.world import EditError, World

KHEPERA = agent_type("khepera")
TWO = min(2, packs.MAX_THREADS)
needs_two_cores = pytest.mark.skipif(
    packs.MAX_THREADS < 2, reason="numba's pool has one thread on this machine"
)


def _crowd(seed: int = 4, **kw) -> World:
    """Robots, balls held and free, a box, a round and a square obstacle, two lights."""
    world = World(900.0, 900.0, seed=seed, tick_s=0.01, sensor_period_s=0.02, **kw)
    world.add_obstacle("pillar", ShapeSpec.box(60, 60), 450.0, 450.0)
    world.add_obstacle("post", ShapeSpec.circle(25), 200.0, 650.0)
    world.add_light("lamp", 450.0, 300.0, radius_mm=400.0)
    world.add_light("blink", 150.0, 150.0, radius_mm=300.0, mode="blink", period_s=0.3)
    rng = np.random.default_rng(seed)
    placed = 0
    while placed < 48:
        x, y = rng.uniform(60, 840, 2)
        try:
            if placed < 40:
                world.add_agent(
                    f"k{placed}",
                    KHEPERA,
                    float(x),
                    float(y),
                    float(rng.uniform(-3, 3)),
                    defer_tables=True,
                )
            elif placed < 46:
                world.add_object(f"ball{placed}", "ball", ShapeSpec.circle(15), float(x), float(y))
            else:
                world.add_object(f"box{placed}", "box", ShapeSpec.box(30, 30), float(x), float(y))
        except ValueError:
            continue
        placed += 1
    world.finish_agents()
    return world


def _run(world: World, ticks: int) -> np.ndarray:
    rows = []
    for t in range(ticks):
        world.set_speeds_all(braitenberg(world.proximity))
        if t == 30:  # some grippers close: presence, held objects, owners in the kernel
            for slot in range(0, 40, 3):
                world.set_grip(slot, closed=True)
        world.step()
        rows.append(
            np.concatenate(
                [
                    world.agent_pose.ravel(),
                    world.proximity.ravel(),
                    world.ambient.ravel(),
                    world.presence.ravel(),
                ]
            )
        )
    return np.array(rows)


def test_parallel_sensing_reads_the_serial_readings_bit_for_bit(monkeypatch) -> None:
    # The parallel kernel only runs from PARALLEL_MIN_AGENTS robots up; lowered here
    # so a world of 40 takes it (and still has crowded cells, objects, lights).
    monkeypatch.setattr(sensing, "PARALLEL_MIN_AGENTS", 1)
    serial = _run(_crowd(threads=1), 120)
    parallel = _run(_crowd(threads=TWO), 120)
    n = 40
    assert (serial[:, 3 * n : 3 * n + 8 * n] > 0).any(), "no proximity reading: a vacuous test"
    assert np.array_equal(serial, parallel)


@pytest.mark.parametrize("threads", [1, TWO])
def test_the_parallel_kernel_alone_matches_the_serial_one(threads: int) -> None:
    world = _crowd()
    world.run(0.5)
    tables, scene, moving = world.sensors.packs(world, world.sim_time)
    robots = (world.agent_pose, world.arm, world.holding())

    def fresh() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # Filled with a value no reading has: a row the kernel skipped would show.
        return (
            np.full(world.proximity.shape, -7, dtype=np.int32),
            np.full(world.ambient.shape, -7, dtype=np.int32),
            np.full(world.presence.shape, -7, dtype=np.int32),
        )

    want, got = fresh(), fresh()
    kernels.sense(robots, tables, scene, moving, want)
    numba.set_num_threads(threads)
    kernels.sense_parallel(robots, tables, scene, moving, got, threads)
    for a, b in zip(want, got, strict=True):
        assert (a != -7).all()
        assert np.array_equal(a, b)


def test_thread_counts_are_checked() -> None:
    for bad in (0, -1, packs.MAX_THREADS + 1):
        with pytest.raises(EditError, match="threads"):
            World(500.0, 500.0, threads=bad)
        with pytest.raises(EditError, match="threads"):
            World(500.0, 500.0, physics_threads=bad)


@needs_two_cores
def test_threaded_space_keeps_a_crowd_inside_the_walls_and_apart() -> None:
    # 30 robots driven flat out into the right-hand wall for 3 s: 60 joints and
    # many contacts, above chipmunk's threshold for solving on both threads.
    world = World(1000.0, 600.0, seed=1, physics_threads=2)
    assert world.space.threaded and world.space.threads == 2
    for i in range(30):
        world.add_agent(f"k{i}", KHEPERA, 100.0 + 60.0 * (i % 5), 60.0 + 80.0 * (i // 5), 0.0)
    world.set_speeds_all(np.full((30, 2), 60.0))
    world.run(3.0)
    pose = world.agent_pose
    r = KHEPERA.radius_mm
    assert pose[:, 0].max() > 800.0, "the crowd never reached the wall"
    assert (pose[:, 0] <= 1000.0 - r + 1.0).all() and (pose[:, 1] >= r - 1.0).all()
    assert (pose[:, 1] <= 600.0 - r + 1.0).all()
    gaps = np.hypot(*(pose[:, None, :2] - pose[None, :, :2]).transpose(2, 0, 1))
    np.fill_diagonal(gaps, np.inf)
    assert gaps.min() > 2 * r - 3.0, "robots passed into each other"


@needs_two_cores
def test_threaded_space_drives_grips_and_pushes_like_the_serial_one() -> None:
    # The same short scenario on both spaces: a robot drives 80 mm in 1 s, and a
    # ball in its way ends up ahead of it (pushed with the drive's bounded force).
    for physics_threads in (1, 2):
        world = World(1500.0, 1000.0, seed=2, physics_threads=physics_threads)
        world.add_agent("k1", KHEPERA, 300.0, 500.0, 0.0)
        world.add_object("ball", "ball", ShapeSpec.circle(10.0), 360.0, 500.0, mass_g=5.0)
        world.set_arm(0, 165)  # arm up: the body pushes
        world.set_speeds(0, 10, 10)
        world.run(1.0)
        assert world.agent_pose[0, 0] - 300.0 == pytest.approx(80.0, rel=0.1)
        assert world.object_pose[0, 0] > world.agent_pose[0, 0] + 27.0


def _scatter_boxes(
    world: World, rng: np.random.Generator, count: int, box: ShapeSpec, turn: float
) -> None:
    """``count`` boxes box0.. anywhere 100 mm or more inside the walls, each turned by a
    random angle below ``turn`` radians."""
    for i in range(count):
        x, y = rng.uniform(100, world.width - 100), rng.uniform(100, world.height - 100)
        world.add_obstacle(f"box{i}", box, x, y, float(rng.uniform(0, turn)))


def _occluded_both_ways(scene: StaticScene, seg: Iterable[float]) -> tuple[bool, bool]:
    """Whether an obstacle hides the segment, testing every edge and walking the grid."""
    full = rays._occluded(*seg, scene.occ_segs, scene.static_xy, scene.static_r)
    along = rays._occluded_grid(
        *seg,
        scene.segs,
        scene.grid_start,
        scene.grid_items,
        scene.grid_nx,
        scene.grid_ny,
        scene.cell,
        scene.static_xy,
        scene.static_r,
    )
    return full, along


def test_occlusion_along_the_grid_answers_as_testing_every_obstacle() -> None:
    # 40 boxes (160 edges) and 3 round obstacles; a robot-to-light segment is hidden
    # or not the same whether every edge is tested or only those binned along it.
    world = World(3000.0, 2000.0, seed=1)
    rng = np.random.default_rng(8)
    _scatter_boxes(world, rng, 40, ShapeSpec.box(60, 30), 3.0)
    for i in range(3):
        world.add_obstacle(f"post{i}", ShapeSpec.circle(25), 700.0 + 800 * i, 1000.0)
    world.add_agent("k", KHEPERA, 50.0, 50.0)
    scene = world.sensors.static_geometry(world).scene
    hidden = 0
    for p in rng.uniform([0, 0, 0, 0], [3000, 2000, 3000, 2000], size=(3000, 4)):
        full, along = _occluded_both_ways(scene, p)
        assert full == along, p
        hidden += full
    assert 300 < hidden < 2700, "too few or too many hidden segments: a weak test"


def test_occlusion_along_the_grid_holds_on_grid_lines_and_corners() -> None:
    # The walk samples a cell apart per axis; segments from grid corner to grid
    # corner, along grid lines and short ones, against small boxes placed across
    # grid lines, answer as testing every edge.
    world = World(2400.0, 1800.0, seed=1)
    world.add_agent("k", KHEPERA, 50.0, 50.0)
    cell = world.sensors.static_geometry(world).cell_mm
    rng = np.random.default_rng(21)
    for i in range(60):
        gx, gy = rng.integers(1, int(2400 // cell)), rng.integers(1, int(1800 // cell))
        x = gx * cell + rng.choice([-1.0, 0.0, 1.0]) * rng.uniform(0, 8)
        y = gy * cell + rng.choice([-1.0, 0.0, 1.0]) * rng.uniform(0, 8)
        world.add_obstacle(f"b{i}", ShapeSpec.box(12, 3), x, y, float(rng.uniform(0, 3.2)))
    scene = world.sensors.static_geometry(world).scene
    corners = np.stack(np.meshgrid(np.arange(0, 2400, cell), np.arange(0, 1800, cell)), -1)
    corners = corners.reshape(-1, 2)
    hidden = 0
    for _ in range(4000):
        p = corners[rng.integers(len(corners))]
        kind = rng.integers(3)
        if kind == 0:  # corner to corner
            q = corners[rng.integers(len(corners))]
        elif kind == 1:  # along a grid line
            q = (
                p + np.array([rng.uniform(-900, 900), 0.0])
                if rng.integers(2)
                else p + np.array([0.0, rng.uniform(-900, 900)])
            )
        else:  # short, near a corner
            q = p + rng.uniform(-cell, cell, 2)
        seg = (float(p[0]), float(p[1]), float(q[0]), float(q[1]))
        full, along = _occluded_both_ways(scene, seg)
        assert full == along, seg
        hidden += full
    assert hidden > 100, "too few hidden segments: a weak test"


def test_shadow_bins_clear_only_segments_no_obstacle_crosses() -> None:
    # rays._shadows: a robot whose bin says "in the light" must be one the walk
    # (and the test of every edge) finds not hidden. Boxes and posts anywhere,
    # lights among them (some right beside an obstacle), points anywhere and
    # points just beside the obstacles, seen from the lights.
    world = World(3000.0, 2000.0, seed=1)
    rng = np.random.default_rng(5)
    _scatter_boxes(world, rng, 50, ShapeSpec.box(60, 20), 3.2)
    for i in range(6):
        world.add_obstacle(f"post{i}", ShapeSpec.circle(20), *rng.uniform([100, 100], [2900, 1900]))
    world.add_agent("k", KHEPERA, 30.0, 30.0)
    scene = world.sensors.static_geometry(world).scene
    occ = scene.occ_segs

    def clearance(x: float, y: float) -> float:
        edges = min(rays._point_segment_d2(x, y, e) for e in occ) ** 0.5
        posts = np.hypot(*(scene.static_xy - (x, y)).T) - scene.static_r
        return float(min(edges, posts.min()))

    open_spots = [p for p in rng.uniform([0, 0], [3000, 2000], (400, 2)) if clearance(*p) > 300]
    lights = np.array(
        [
            [*open_spots[0], 2000.0, 1.0],  # away from every obstacle
            [*open_spots[1], 1500.0, 1.0],
            [occ[0, 0] + 3.0, occ[0, 1] + 3.0, 1500.0, 1.0],  # next to a box's corner
            [*(scene.static_xy[0] + (25.0, 0.0)), 1500.0, 1.0],  # next to a post
            [*(scene.static_xy[1] + (230.0, 0.0)), 1500.0, 1.0],  # a post just beyond 200 mm
        ]
    )
    shadows = rays._shadows(lights, occ, scene.static_xy, scene.static_r, rays.SHADOW_BINS)
    clear = walked = 0
    for li, (lx, ly, _, _) in enumerate(lights):
        points = rng.uniform([0, 0], [3000, 2000], size=(1500, 2))
        # just beside obstacle corners, where a bin's edge and a segment graze
        corners = occ[rng.integers(len(occ), size=1500), :2] + rng.normal(0, 2.0, (1500, 2))
        for px, py in np.concatenate([points, corners]):
            if rays._in_light(shadows[li], px - lx, py - ly):
                clear += 1
                assert not rays._occluded(px, py, lx, ly, occ, scene.static_xy, scene.static_r)
            else:
                walked += 1
    assert clear > 1000 and walked > 3000, (clear, walked)
