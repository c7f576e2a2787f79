"""Dry-run speed: wall-clock seconds for 5 simulated seconds of a controller in the sandbox.

Plays the runner (services/runner/dryrun.py ``dry_run``) on the foraging map,
robot k3, with examples/01_braitenberg.py (period 50 ms, one state a 20 ms
tick): sandbox start, 250 lockstep ticks, the sandbox's end. The first run
also builds the seccomp filter and the CPU cgroup.

    .venv/bin/python -m bench.bench_dry_run --runs 7
"""

from __future__ import annotations

import statistics
import sys
from pathlib import Path

from bench import cli as bench_cli
from common.sim2d import maps
from common.world import packing
from services.runner.dryrun import dry_run

REPO = Path(__file__).resolve().parent.parent


def main() -> int:
    p = bench_cli.parser("bench_dry_run", __doc__)
    p.add_argument("--runs", type=int, default=7)
    p.add_argument("--seconds", type=float, default=5.0)
    args = p.parse_args()
    snap = packing.snapshot(maps.load_map(REPO / "maps" / "foraging.json", name="w1", seed=3))
    source = (REPO / "examples" / "01_braitenberg.py").read_bytes()
    walls = []
    for n in range(args.runs):
        report = dry_run(snap, "k3", source, seconds=args.seconds)
        walls.append(report.wall_seconds)
        print(
            f"run {n + 1}: {report.verdict}; {report.sim_seconds:g} s simulated in "
            f"{report.wall_seconds:.2f} s",
            flush=True,
        )
    median = statistics.median(walls)
    print(
        f"\nmedian {median:.2f} s wall for {args.seconds:g} simulated s "
        f"({args.seconds / median:.1f}x real time; min {min(walls):.2f}, max {max(walls):.2f})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
