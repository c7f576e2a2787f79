"""Sim2D engine benchmark: N Khepera, all sensors on, obstacle avoidance, 10 ms steps.

Headless, no network. Prints simulated seconds per CPU second and per wall
second for each N (figures recorded in docs/BENCHMARKS.md). Run:

    .venv/bin/python bench/engine_bench.py [--sim-seconds 5] [--sizes 10 35 100 1000]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from services.engine.agents import agent_type
from services.engine.entities import ShapeSpec
from services.engine.world import World

# Braitenberg obstacle avoidance: each sensor pushes the opposite wheel.
# Sensor order: 0 left, 1 front-left, 2-3 front, 4 front-right, 5 right, 6-7 back.
_W_LEFT = np.array([4, 3, 2, 1, -1, -2, 0, 0]) / 400.0
_W_RIGHT = -_W_LEFT[::-1].copy()
_W_RIGHT[[6, 7]] = 0.0


def build(n: int, seed: int = 1) -> World:
    """A square arena sized so robots cover about 10 % of the floor, with a few pillars."""
    side = max(600.0, math.sqrt(n * math.pi * 27.5**2 / 0.10))
    world = World(side, side, seed=seed, tick_s=0.01, sensor_period_s=0.02)
    rng = np.random.default_rng(seed)
    for i in range(max(1, n // 50)):
        x, y = rng.uniform(100, side - 100, 2)
        world.add_obstacle(f"pillar{i}", ShapeSpec.box(60, 60), float(x), float(y))
    spec = agent_type("khepera")
    placed = 0
    while placed < n:
        x, y = rng.uniform(40, side - 40, 2)
        try:
            world.add_agent(f"k{placed}", spec, float(x), float(y), float(rng.uniform(-3, 3)))
        except ValueError:
            continue
        placed += 1
    world.add_light("lamp", side / 2, side / 2, radius_mm=side / 3)
    return world


def control(world: World) -> None:
    prox = world.proximity.astype(np.float64)
    left = 8.0 + prox @ _W_LEFT
    right = 8.0 + prox @ _W_RIGHT
    world.set_speeds_all(np.stack([left, right], axis=1))


def run(n: int, sim_seconds: float) -> tuple[float, float]:
    world = build(n)
    steps = round(sim_seconds / world.tick_s)
    for _ in range(20):  # warm up
        control(world)
        world.step()
    cpu0, wall0 = time.process_time(), time.perf_counter()
    for _ in range(steps):
        control(world)
        world.step()
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    return sim_seconds / cpu, sim_seconds / wall


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=[10, 35, 100, 1000])
    p.add_argument("--sim-seconds", type=float, default=5.0)
    args = p.parse_args()
    print(f"{'N':>6} {'sim s / CPU s':>14} {'sim s / wall s':>15}")
    for n in args.sizes:
        per_cpu, per_wall = run(n, args.sim_seconds if n < 1000 else args.sim_seconds / 2)
        print(f"{n:>6} {per_cpu:>14.1f} {per_wall:>15.1f}", flush=True)


if __name__ == "__main__":
    main()
