"""Sim2D engine benchmark: N Khepera, all sensors on, obstacle avoidance, 10 ms steps.

Headless, no network. For each N prints simulated seconds per CPU second
(``time.process_time``: what to compare on a shared machine) and per wall
second, best and median of ``--repeats`` runs, then where the CPU time goes
per simulated second: physics (arms, drive, pymunk step, reading body state),
sensing (IR, ambient, presence: every 20 ms of simulated time), control (the
obstacle-avoidance rule and ``set_speeds_all``). Publishing is not included
(no network). Figures are recorded in docs/BENCHMARKS.md. Run:

    .venv/bin/python bench/engine_bench.py [--sim-seconds 5] [--sizes 10 35 100 1000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

from common.sim2d import kernels
from common.sim2d.agents import agent_type
from common.sim2d.entities import ShapeSpec
from common.sim2d.wander import braitenberg
from common.sim2d.world import World


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
    world.set_speeds_all(braitenberg(world.proximity))


def run(n: int, sim_seconds: float, profile: bool = False) -> tuple[float, float, dict[str, float]]:
    """(sim s per CPU s, sim s per wall s, CPU s per sim s by phase if ``profile``)."""
    world = build(n)
    steps = round(sim_seconds / world.tick_s)
    for _ in range(20):  # warm up
        control(world)
        world.step()
    world.profile = profile
    control_cpu = 0.0
    cpu0, wall0 = time.process_time(), time.perf_counter()
    for _ in range(steps):
        if profile:
            t = time.process_time()
            control(world)
            control_cpu += time.process_time() - t
        else:
            control(world)
        world.step()
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    phases = {k: v / sim_seconds for k, v in world.phase_cpu.items()}
    phases["control"] = control_cpu / sim_seconds
    return sim_seconds / cpu, sim_seconds / wall, phases


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=[10, 35, 100, 1000])
    p.add_argument("--sim-seconds", type=float, default=5.0)
    p.add_argument("--repeats", type=int, default=3)
    args = p.parse_args()
    print(f"kernels ready in {kernels.warm_up():.2f} s (compiled, or loaded from the cache)")
    print(
        f"{'N':>6} {'sim s / CPU s':>20} {'sim s / wall s':>20}   "
        "CPU ms per simulated s: physics / sensing / control"
    )
    print(f"{'':>6} {'best  median':>20} {'best  median':>20}")
    for n in args.sizes:
        seconds = args.sim_seconds if n < 1000 else args.sim_seconds / 2
        runs = [run(n, seconds) for _ in range(args.repeats)]
        cpu = [r[0] for r in runs]
        wall = [r[1] for r in runs]
        _, _, ph = run(n, seconds, profile=True)
        print(
            f"{n:>6} {max(cpu):>12.1f} {statistics.median(cpu):>7.1f}"
            f" {max(wall):>12.1f} {statistics.median(wall):>7.1f}"
            f"   {ph['physics'] * 1e3:7.1f} / {ph['sensing'] * 1e3:7.1f} / "
            f"{ph['control'] * 1e3:6.1f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
