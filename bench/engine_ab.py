"""A/B of the engine's step between two checkouts, under the same load (issue 22).

Starts one long-lived worker process per tree (``PYTHONPATH`` set to it),
each building ``bench/engine_bench.py``'s world once (N Khepera, discs drive,
all sensors), then asks them in turn, round after round (the order swapped
every round), to run ``--ticks`` ticks of rule and step, and prints for each
tree the wall and CPU milliseconds per simulated second (median and best of
the rounds; the CPU of the process, and of the sim thread alone), simulated
seconds per wall second, and the per-round wall ratio of the first tree to
the second. Interleaving at the scale of a second is what
makes a comparison hold on a machine whose speed drifts by half within
minutes (docs/BENCHMARKS.md).

    git archive OLD | tar -x -C /tmp/before
    .venv/bin/python -m bench.engine_ab --trees /tmp/before . --robots 10000 --threads 2

The same tree twice is an A/A run: how far apart two identical runs land.
``--balls 0.5``: the full scenario's balls (``engine_bench --balls``).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from bench import cli as bench_cli


def worker(tree: str, robots: int, threads: int, balls: float) -> None:
    """One tree's side: build the world, then run the ticks each line on stdin asks for."""
    # Loading another checkout is the job: its path goes first, then its own modules
    # (its engine_bench's world and rule, its kernels) are imported.
    sys.path.insert(0, tree)
    from bench.engine_bench import build, control
    from common.sim2d import kernels

    kernels.warm_up()
    world = build(robots, threads=threads, drive="discs", balls=balls)
    for _ in range(30):
        control(world)
        world.step()
    print("ready", flush=True)
    for line in sys.stdin:
        ticks = int(line)
        wall0, cpu0 = time.perf_counter(), time.process_time()
        sim0 = time.thread_time()
        for _ in range(ticks):
            control(world)
            world.step()
        per_sim_s = 1000.0 / (ticks * world.tick_s)
        wall = (time.perf_counter() - wall0) * per_sim_s
        cpu = (time.process_time() - cpu0) * per_sim_s
        # The sim thread's own share: on an idle machine the wall is about this
        # plus its waits for the workers (BENCHMARKS.md, issue 35).
        sim = (time.thread_time() - sim0) * per_sim_s
        print(f"{wall:.5g} {cpu:.5g} {sim:.5g}", flush=True)


def main(argv: list[str] | None = None) -> None:
    p = bench_cli.parser("engine_ab", __doc__)
    p.add_argument("--trees", nargs=2, required=True, metavar="DIR", help="two checkouts")
    p.add_argument("--robots", type=int, default=10000)
    p.add_argument("--threads", type=int, default=2, help="sensing threads (World.threads)")
    p.add_argument("--balls", type=float, default=0.0, help="movable balls per robot")
    p.add_argument("--rounds", type=int, default=12)
    p.add_argument("--ticks", type=int, default=100, help="ticks a tree runs per round")
    p.add_argument("--worker", metavar="DIR", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker:
        worker(args.worker, args.robots, args.threads, args.balls)
        return
    for name in ("robots", "threads", "rounds", "ticks"):
        if getattr(args, name) <= 0:
            p.error(f"--{name} must be positive")
    if not 0 <= args.balls <= 10:
        p.error("--balls must be between 0 and 10")
    trees = [str(Path(t).resolve()) for t in args.trees]
    for tree in trees:
        if not (Path(tree) / "common" / "sim2d" / "world.py").is_file():
            p.error(f"{tree} is not a checkout of this project")
    this = str(Path(__file__).resolve())
    workers = []
    for tree in trees:
        env = {**os.environ, "PYTHONPATH": tree}
        command = [sys.executable, this, "--trees", *trees, "--worker", tree]
        command += ["--robots", str(args.robots), "--threads", str(args.threads)]
        command += ["--balls", str(args.balls)]
        workers.append(
            subprocess.Popen(
                command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env
            )
        )
    for tree, proc in zip(trees, workers, strict=True):
        print(
            f"building {args.robots} robots in {tree} (compiles its kernels if needed)", flush=True
        )
        assert proc.stdout is not None
        if proc.stdout.readline().strip() != "ready":
            sys.exit(f"the worker of {tree} failed")
    # By position, not by path: an A/A run names the same tree twice.
    wall: list[list[float]] = [[], []]
    cpu: list[list[float]] = [[], []]
    sim: list[list[float]] = [[], []]
    for r in range(args.rounds):
        order = [0, 1] if r % 2 == 0 else [1, 0]
        for i in order:
            proc = workers[i]
            assert proc.stdin is not None and proc.stdout is not None
            proc.stdin.write(f"{args.ticks}\n")
            proc.stdin.flush()
            w, c, t = proc.stdout.readline().split()
            wall[i].append(float(w))
            cpu[i].append(float(c))
            sim[i].append(float(t))
        print(
            f"  round {r + 1} (load {os.getloadavg()[0]:.1f}): "
            f"{wall[0][-1]:.3g}, {wall[1][-1]:.3g} ms",
            flush=True,
        )
    for proc in workers:
        assert proc.stdin is not None
        proc.stdin.close()
        proc.wait()
    for i, tree in enumerate(trees):
        med = statistics.median(wall[i])
        print(
            # Three figures: a small world's step is under a millisecond a simulated second.
            f"{tree}: wall ms per simulated s {med:.3g} (best {min(wall[i]):.3g}), "
            f"CPU {statistics.median(cpu[i]):.3g} "
            f"(the sim thread {statistics.median(sim[i]):.3g}); "
            f"simulated s per wall s {1000 / med:.4g}"
        )
    ratios = [a / b for a, b in zip(wall[0], wall[1], strict=True)]
    print(f"wall, first tree over second, per round: median {statistics.median(ratios):.3f}")


if __name__ == "__main__":
    main()
