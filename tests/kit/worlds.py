"""The engine benchmarks' worlds: the Khepera arena they measure, its rule, and a tick's hash.

bench/engine_bench.py times these worlds, bench/bench_enki.py runs the scenario
against Enki's, bench/drive_hashes.py hashes their ticks; the simulator's unit
tests check the kernels and drives on the same worlds.
"""

from __future__ import annotations

import hashlib
import math

import numpy as np

from common.sim2d.agents import agent_type
from common.sim2d.drives import DEFAULT_DRIVE
from common.sim2d.entities import ShapeSpec
from common.sim2d.specs import AgentTypeSpec
from common.sim2d.wander import CRUISE, WEIGHTS, braitenberg
from common.sim2d.world import World

SENSOR_PERIOD_S = 0.01  # Enki refreshes IR every step: ours every tick as well
FULL_BALLS = 0.5  # the full scenario: movable balls per robot in our world


def build(
    n: int,
    seed: int = 1,
    *,
    threads: int = 1,
    physics_threads: int = 1,
    gripper: bool = True,
    drive: str = DEFAULT_DRIVE,
    sensor_period_s: float = 0.02,
    lamp: bool = True,
    balls: float = 0.0,
    spec: AgentTypeSpec | None = None,
) -> World:
    """A square arena sized so robots cover about 10 % of the floor, with a few pillars.

    ``sensor_period_s`` and ``lamp`` are for :func:`scenario_world`: Enki refreshes
    its IR sensors every step and has no lights, so its scenario is this one with
    10 ms sensing and no lamp. ``balls``: movable balls per robot (the full
    scenario: objects to push and grip), placed after the robots, so the
    robots' poses do not depend on it.
    """
    side = max(600.0, math.sqrt(n * math.pi * 27.5**2 / 0.10))
    world = World(
        side,
        side,
        seed=seed,
        tick_s=0.01,
        sensor_period_s=sensor_period_s,
        threads=threads,
        physics_threads=physics_threads,
        drive=drive,
    )
    rng = np.random.default_rng(seed)
    for i in range(max(1, n // 50)):
        x, y = rng.uniform(100, side - 100, 2)
        world.add_obstacle(f"pillar{i}", ShapeSpec.box(60, 60), float(x), float(y))
    spec = spec or agent_type("khepera")
    apart = 2 * spec.radius_mm + 2.0
    taken: dict[tuple[int, int], list[tuple[float, float]]] = {}
    placed = 0
    while placed < n:
        x, y = rng.uniform(40, side - 40, 2)
        ix, iy = int(x // apart), int(y // apart)
        near = (
            p
            for gx in range(ix - 1, ix + 2)
            for gy in range(iy - 1, iy + 2)
            for p in taken.get((gx, gy), ())
        )
        if any((px - x) ** 2 + (py - y) ** 2 < apart**2 for px, py in near):
            continue
        try:
            world.add_agent(
                f"k{placed}",
                spec,
                float(x),
                float(y),
                float(rng.uniform(-3, 3)),
                gripper=gripper,
                defer_tables=True,
            )
        except ValueError:
            continue
        taken.setdefault((ix, iy), []).append((float(x), float(y)))
        placed += 1
    world.finish_agents()
    placed = 0
    while placed < round(balls * n):
        x, y = rng.uniform(40, side - 40, 2)
        try:
            world.add_object(
                f"ball{placed}", "ball", ShapeSpec.circle(10.0), float(x), float(y), mass_g=5.0
            )
        except ValueError:
            continue
        placed += 1
    if lamp:
        world.add_light("lamp", side / 2, side / 2, radius_mm=side / 3)
    return world


def control(world: World) -> None:
    world.set_speeds_all(braitenberg(world.proximity))


def advance(world: World, ticks: int) -> World:
    """``world`` after ``ticks`` more ticks, its robots steered by :func:`control` before each."""
    for _ in range(ticks):
        control(world)
        world.step()
    return world


def scenario_world(n: int, drive: str = "joints", full: bool = False) -> World:
    """engine_bench's world without what Enki lacks: no gripper turret, no lamp; IR every tick.

    ``full``: our world as a lab's is, with what Enki's cannot have: gripper
    turrets, the lamp and a movable ball for every two robots (FULL_BALLS). The
    robots and pillars are the same either way (the balls are placed after them).
    """
    if full:
        return build(n, sensor_period_s=SENSOR_PERIOD_S, drive=drive, balls=FULL_BALLS)
    return build(n, gripper=False, lamp=False, sensor_period_s=SENSOR_PERIOD_S, drive=drive)


def tick_digest(world: World) -> str:
    """Everything a tick moves or reads: poses, velocities, counters, objects, readings.

    bench/drive_hashes.py prints it each tick; tests/unit/common/sim2d/test_discs_split.py
    compares the split and serial drives by it.
    """
    h = hashlib.sha256()
    for a in (
        world.agent_pose,
        world.agent_vel,
        world.counters,
        world.object_pose,
        world.proximity,
        world.ambient,
        world.presence,
    ):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


__all__ = [
    "CRUISE",
    "FULL_BALLS",
    "SENSOR_PERIOD_S",
    "WEIGHTS",
    "advance",
    "build",
    "control",
    "scenario_world",
    "tick_digest",
]
