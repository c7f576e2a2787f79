"""Sim2D engine benchmark: N Khepera, all sensors on, obstacle avoidance, 10 ms steps.

Headless, no network. For each N prints simulated seconds per CPU second
(``time.process_time``: what to compare on a shared machine) and per wall
second, best and median of ``--repeats`` runs, then where the CPU time goes
per simulated second: physics (arms, drive, pymunk step, reading body state),
sensing (IR, ambient, presence: every 20 ms of simulated time), control (the
obstacle-avoidance rule and ``set_speeds_all``). Publishing is not included
(no network). Figures are recorded in docs/BENCHMARKS.md. Run:

    .venv/bin/python -m bench.engine_bench [--sim-seconds 5] [--sizes 10 35 100 1000] [--repeats 3]

Swarms (issue 22): ``--sizes 10000 --sim-seconds 1 --repeats 1 --threads 2
--physics-threads 2`` (sensing on 2 threads, chipmunk's threaded space). Worlds
of 1,000 robots and more get ``--sim-seconds / 2`` unless ``--swarm-seconds``
says otherwise; ``--progress`` prints each simulated second as it goes.
``--compare-threads`` runs the same size with threads 1 and with ``--threads``
interleaved, so the ratio is measured under the same load. ``--drive velocity``
drives robots with World(drive="velocity") (no joints, light tongs);
``--compare-drives [A B]`` runs two drives interleaved (default the joints
drive and the velocity drive; ``--compare-drives velocity discs`` for the
discs drive), each with ``--threads`` / ``--physics-threads``.
``--compare-types`` runs the Khepera as written in Python
(common/sim2d/agents/khepera.py) and as its robot file compiles it
(common/robots/shipped/khepera.toml, the one the lab runs: issue 34), interleaved.
Robots are placed apart (no two overlap at the start): the first versions
placed them anywhere, and at 3,000 robots and more the first simulated second
went on pushing overlapping robots apart.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

from bench import cli as bench_cli
from common.sim2d import compiled
from common.sim2d.agents import agent_type, khepera
from common.sim2d.drives import DEFAULT_DRIVE, DRIVES
from common.sim2d.specs import AgentTypeSpec
from tests.kit.worlds import build, control


def run(
    n: int,
    sim_seconds: float,
    profile: bool = False,
    *,
    threads: int = 1,
    physics_threads: int = 1,
    progress: bool = False,
    gripper: bool = True,
    drive: str = DEFAULT_DRIVE,
    balls: float = 0.0,
    spec: AgentTypeSpec | None = None,
) -> tuple[float, float, dict[str, float]]:
    """(sim s per CPU s, sim s per wall s, CPU s per sim s by phase if ``profile``)."""
    t0 = time.perf_counter()
    world = build(
        n,
        threads=threads,
        physics_threads=physics_threads,
        gripper=gripper,
        drive=drive,
        balls=balls,
        spec=spec,
    )
    if progress:
        print(f"  built {n} robots in {time.perf_counter() - t0:.1f} s", flush=True)
    steps = round(sim_seconds / world.tick_s)
    per_second = round(1.0 / world.tick_s)
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
        if progress and world.tick % per_second == 0:
            print(
                f"  {world.sim_time:.0f} sim s: {time.process_time() - cpu0:.1f} CPU s, "
                f"{time.perf_counter() - wall0:.1f} wall s",
                flush=True,
            )
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    phases = {k: v / sim_seconds for k, v in world.phase_cpu.items()}
    phases["control"] = control_cpu / sim_seconds
    return sim_seconds / cpu, sim_seconds / wall, phases


def main() -> None:
    p = bench_cli.parser("engine_bench", __doc__)
    p.add_argument("--sizes", type=int, nargs="+", default=[10, 35, 100, 1000])
    p.add_argument("--sim-seconds", type=float, default=5.0)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--swarm-seconds", type=float, help="sim seconds at N >= 1000")
    p.add_argument("--threads", type=int, default=1, help="sensing threads (World.threads)")
    p.add_argument(
        "--physics-threads", type=int, default=1, help="chipmunk threads (threaded space)"
    )
    p.add_argument("--progress", action="store_true", help="print every simulated second")
    p.add_argument(
        "--no-gripper",
        action="store_true",
        help="robots without the gripper turret (IR and ambient on, no tongs, no barrier)",
    )
    p.add_argument(
        "--drive",
        choices=DRIVES,
        default=DEFAULT_DRIVE,
        help=f"World(drive=...): {DEFAULT_DRIVE} (default), joints or velocity",
    )
    p.add_argument(
        "--balls",
        type=float,
        default=0.0,
        help="movable balls per robot (0.5: the full scenario, objects to push and grip)",
    )
    mode = p.add_mutually_exclusive_group()
    mode.add_argument(
        "--compare-threads",
        action="store_true",
        help="each repeat: threads 1 then --threads/--physics-threads, interleaved",
    )
    mode.add_argument(
        "--compare-types",
        action="store_true",
        help="each repeat: the Khepera written in Python, then from khepera.toml, interleaved",
    )
    mode.add_argument(
        "--compare-drives",
        nargs="*",
        metavar="DRIVE",
        help="each repeat: two drives interleaved (default: joints velocity; e.g. "
        "--compare-drives velocity discs)",
    )
    args = p.parse_args()
    if args.compare_drives is not None:
        drives = args.compare_drives or ["joints", "velocity"]
        if len(drives) != 2 or any(d not in DRIVES for d in drives):
            p.error(f"--compare-drives takes two drives of {', '.join(DRIVES)}")
        args.compare_drives = drives
    if not 0 <= args.balls <= 10:
        p.error("--balls must be between 0 and 10")
    for name in ("sim_seconds", "repeats", "threads", "physics_threads"):
        if getattr(args, name) <= 0:
            p.error(f"--{name.replace('_', '-')} must be positive")
    if any(n <= 0 for n in args.sizes):
        p.error("--sizes must be positive")
    print(f"kernels ready in {compiled.warm_up():.2f} s: {compiled.WHY}")
    print(
        f"threads: sensing {args.threads}, physics {args.physics_threads}; "
        f"gripper turrets {'off' if args.no_gripper else 'on'}; drive {args.drive}; "
        f"balls per robot {args.balls:g}; "
        f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}"
    )
    if args.compare_threads or args.compare_drives or args.compare_types:
        compare(args)
        return
    print(
        f"{'N':>6} {'sim s / CPU s':>20} {'sim s / wall s':>20}   "
        "CPU ms per simulated s: physics / sensing / control"
    )
    print(f"{'':>6} {'best  median':>20} {'best  median':>20}")
    for n in args.sizes:
        seconds = sized_seconds(args, n)
        kw = {
            "threads": args.threads,
            "physics_threads": args.physics_threads,
            "progress": args.progress,
            "gripper": not args.no_gripper,
            "drive": args.drive,
            "balls": args.balls,
        }
        runs = [run(n, seconds, **kw) for _ in range(args.repeats)]
        cpu = [r[0] for r in runs]
        wall = [r[1] for r in runs]
        _, _, ph = run(n, seconds, profile=True, **kw)
        print(
            f"{n:>6} {max(cpu):>12.3g} {statistics.median(cpu):>7.3g}"
            f" {max(wall):>12.3g} {statistics.median(wall):>7.3g}"
            f"   {ph['physics'] * 1e3:7.1f} / {ph['sensing'] * 1e3:7.1f} / "
            f"{ph['control'] * 1e3:6.1f}",
            flush=True,
        )

    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


def sized_seconds(args: argparse.Namespace, n: int) -> float:
    if n < 1000:
        return float(args.sim_seconds)
    return float(args.swarm_seconds or args.sim_seconds / 2)


def compare(args: argparse.Namespace) -> None:
    """Two configurations interleaved (threads, or drives): ratios under the same load."""
    print(
        f"{'N':>6} {'repeat':>6}  {'config':<32} {'sim s / CPU s':>14} {'sim s / wall s':>15}  load"
    )
    configs: list[tuple[int, int, str, str]]  # sensing, physics threads, drive, Khepera from
    if args.compare_drives:
        first, second = args.compare_drives
        configs = [
            (args.threads, args.physics_threads, first, "file"),
            (args.threads, args.physics_threads, second, "file"),
        ]
    elif args.compare_types:
        configs = [
            (args.threads, args.physics_threads, args.drive, "python"),
            (args.threads, args.physics_threads, args.drive, "file"),
        ]
    else:
        configs = [
            (1, 1, args.drive, "file"),
            (args.threads, args.physics_threads, args.drive, "file"),
        ]
    specs = {"python": khepera.SPEC, "file": agent_type("khepera")}
    for n in args.sizes:
        seconds = sized_seconds(args, n)
        cpus: dict[tuple[int, int, str, str], list[float]] = {c: [] for c in configs}
        walls: dict[tuple[int, int, str, str], list[float]] = {c: [] for c in configs}
        for r in range(args.repeats):
            for config in configs:
                threads, physics, drive, source = config
                per_cpu, per_wall, _ = run(
                    n,
                    seconds,
                    threads=threads,
                    physics_threads=physics,
                    progress=args.progress,
                    gripper=not args.no_gripper,
                    drive=drive,
                    balls=args.balls,
                    spec=specs[source],
                )
                cpus[config].append(per_cpu)
                walls[config].append(per_wall)
                label = f"sensing {threads}, physics {physics}, {drive}"
                if args.compare_types:
                    label = f"khepera from {source}, {drive}"
                print(
                    f"{n:>6} {r + 1:>6}  {label:<32} {per_cpu:>14.3f} {per_wall:>15.3f}"
                    f"  {os.getloadavg()[0]:.1f}",
                    flush=True,
                )
        a, b = configs
        print(
            f"{n:>6} median speed-up, second over first: "
            f"CPU {statistics.median(cpus[b]) / statistics.median(cpus[a]):.2f}x, "
            f"wall {statistics.median(walls[b]) / statistics.median(walls[a]):.2f}x",
            flush=True,
        )


if __name__ == "__main__":
    main()
