"""One sensing pass of the engine bench's world, timed and split (issue 22).

Builds ``bench/engine_bench.py``'s world (N Khepera, all sensors on, a pillar
per 50 robots, one lamp a third of the arena wide), steps it a few ticks so
robots have neighbours in reach, then times ``world.sense()`` passes in CPU
time (``time.process_time``) and, each round, the parts of a pass:

- ``noise``: drawing the pass's Gaussian noise in Python (trees that draw it
  before the kernel; 0 where the kernel draws its own), the mean of 64 draws:
  they come in blocks of 32 passes, so one draw in 32 pays for them all,
- ``circles``: binning the circles into the grid (``sense_pass._circles``; in older
  trees ``kernels._circles``),
- ``ir``: the kernel with every robot's reach set to 0 subtracted from the
  whole kernel (rays, candidates, curve; presence goes with it),
- ``ambient``: the whole kernel less the kernel without lights,
- ``kernel``: the whole kernel alone (packs built once, outside the timing),
- ``pass``: ``world.sense()`` as the engine calls it (packs, noise, readings),
  the mean of ``--passes`` passes in a row (block draws of noise included),
- ``wall``: the same passes' wall time,
- ``after step``: a pass right after a physics tick (the world moves on: the
  engine's case, caches as chipmunk's step left them), the mean of ``--passes``,
- ``pass x2``, ``wall x2``: the same on 2 threads (``World.threads``), CPU and wall.

``--tree DIR`` (repeatable) runs the same measurement in other checkouts
(e.g. a ``git archive`` of the commit before a change), one worker process
per tree, each building its world once; rounds alternate between the trees,
so an A/B comparison is made under the same load. Each part's figure is the
best of 5 calls in a round, the passes' the mean of ``--passes``; the table
prints the median of the rounds' figures (and their best). Keep it short: the
machine is shared.

    .venv/bin/python -m bench.bench_sensing --sizes 1000 10000 --rounds 3
    .venv/bin/python -m bench.bench_sensing --sizes 10000 --tree /tmp/before --tree .
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from bench import cli as bench_cli

PARTS = (
    "noise",
    "circles",
    "ir",
    "ambient",
    "kernel",
    "pass",
    "wall",
    "after step",
    "pass x2",
    "wall x2",
)
_MAX_SIZE = 20000


def _positive_int(top: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
        if not 1 <= value <= top:
            raise argparse.ArgumentTypeError(f"{value} is not between 1 and {top}")
        return value

    return parse


def _tree(text: str) -> Path:
    path = Path(text).resolve()
    if not (path / "common" / "sim2d" / "kernels.py").is_file():
        raise argparse.ArgumentTypeError(f"{text}: no common/sim2d/kernels.py there")
    return path


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = bench_cli.parser("bench_sensing", __doc__)
    p.add_argument(
        "--sizes", type=_positive_int(_MAX_SIZE), nargs="+", default=[1000, 10000], help="robots"
    )
    p.add_argument("--rounds", type=_positive_int(50), default=3, help="rounds (alternating trees)")
    p.add_argument(
        "--passes", type=_positive_int(320), default=32, help="passes in a row per round"
    )
    p.add_argument(
        "--tree",
        type=_tree,
        action="append",
        help="a checkout to measure (repeatable; default: this one)",
    )
    p.add_argument("--no-threads", action="store_true", help="skip the 2-thread pass")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.tree and len(set(args.tree)) != len(args.tree):
        p.error("--tree: the same checkout twice")
    return args


# --- worker: runs inside one tree ----------------------------------------------------


def _best_cpu(fn: Callable[[], object], passes: int) -> float:
    best = math.inf
    for _ in range(passes):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best * 1e3


def _mean(fn: Callable[[], object], passes: int, clock: Callable[[], float]) -> float:
    t0 = clock()
    for _ in range(passes):
        fn()
    return (clock() - t0) / passes * 1e3


class _Subject:
    """One world of one tree, and the parts of its sensing pass as callables."""

    def __init__(self, n: int) -> None:
        # The worker's tree's own modules (its PYTHONPATH): another checkout's, in an A/B.
        from bench import engine_bench
        from common.sim2d import kernels as K

        self.K = K
        # The circle binning and the packs' layouts: in kernels.py in trees before
        # it was split by job.
        try:
            from common.sim2d import packs, sense_pass

            self.circles = sense_pass._circles
            self.layout: Any = packs
        except ImportError:
            self.circles = K._circles  # type: ignore[attr-defined]  # an older tree's
            self.layout = K
        self.world = engine_bench.build(n, drive="velocity")
        for _ in range(6):  # a few ticks: neighbours in reach, readings to steer by
            engine_bench.control(self.world)
            self.world.step()
        w = self.world
        self.robots = (w.agent_pose, w.arm, w.holding())
        self.tables, self.scene, self.moving = w.sensors.packs(w, w.sim_time)
        mf = self.layout.MovingScene._fields
        tf = self.layout.SensorTables._fields
        moving: list[Any] = list(self.moving)
        moving[mf.index("lights")] = moving[mf.index("lights")][:0]
        self.moving_dark = tuple(moving)
        tables: list[Any] = list(self.tables)
        f = tables[tf.index("agent_f")].copy()
        f[:, self.layout.F_REACH] = 0.0
        tables[tf.index("agent_f")] = f
        self.tables_blind = tuple(tables)
        self.total = int(getattr(w.sensors.agents, "noise_total", 0))

    def _out(self) -> tuple[Any, ...]:
        w = self.world
        return (w.proximity.copy(), w.ambient.copy(), w.presence.copy())

    def kernel(self, tables: Any = None, moving: Any = None) -> None:
        self.K.sense(
            self.robots,
            tables or self.tables,
            self.scene,
            moving or self.moving,
            self._out(),
        )

    def _after_step(self, passes: int) -> float:
        """A pass right after a physics tick, as the engine runs it (caches as the tick left)."""
        # The worker's tree's own modules (its PYTHONPATH): another checkout's, in an A/B.
        from bench import engine_bench

        w = self.world
        total = 0.0
        for _ in range(passes):
            engine_bench.control(w)
            w.step()  # the world's own pass falls on every other tick; not timed
            t0 = time.process_time()
            w.sense()
            total += time.process_time() - t0
        return total / passes * 1e3

    def measure(self, passes: int, threads: bool) -> dict[str, float]:
        w = self.world
        stream = getattr(w, "noise", None)
        res: dict[str, float] = {}
        take = getattr(stream, "take", None)
        res["noise"] = (
            _mean(lambda: take(self.total), 64, time.process_time) if take and self.total else 0.0
        )
        res["circles"] = _best_cpu(
            lambda: self.circles(self.robots, self.tables, self.scene, self.moving), 5
        )
        whole = _best_cpu(self.kernel, 5)
        res["ir"] = whole - _best_cpu(lambda: self.kernel(tables=self.tables_blind), 5)
        res["ambient"] = whole - _best_cpu(lambda: self.kernel(moving=self.moving_dark), 5)
        res["kernel"] = whole
        w.threads = 1
        t0 = time.perf_counter()
        res["pass"] = _mean(w.sense, passes, time.process_time)
        res["wall"] = (time.perf_counter() - t0) / passes * 1e3
        res["after step"] = self._after_step(passes)
        if threads and self.layout.MAX_THREADS >= 2:
            w.threads = 2
            t0 = time.perf_counter()
            res["pass x2"] = _mean(w.sense, passes, time.process_time)
            res["wall x2"] = (time.perf_counter() - t0) / passes * 1e3
            w.threads = 1
        return res


def worker() -> None:
    """Answers one JSON request a line: {"n": N, "passes": P, "threads": bool}."""
    # The worker's tree's own kernels (its PYTHONPATH): another checkout's, in an A/B.
    from common.sim2d import kernels

    kernels.warm_up()
    subjects: dict[int, _Subject] = {}
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        req = json.loads(line)
        n = int(req["n"])
        if n not in subjects:
            subjects = {n: _Subject(n)}  # one world at a time: 10,000 robots is big
        res = subjects[n].measure(int(req["passes"]), bool(req["threads"]))
        print(json.dumps(res), flush=True)


# --- driver ----------------------------------------------------------------------------


class _Worker:
    def __init__(self, tree: Path) -> None:
        env = dict(os.environ, PYTHONPATH=str(tree))
        script = Path(__file__).resolve()
        # The worker imports the tree's packages; this file's own code is only the harness.
        # Its sys.path line puts that tree first: loading another checkout is the job.
        code = (
            "import sys, runpy; sys.path.insert(0, sys.argv[1]); "
            "sys.argv = [sys.argv[2], '--worker']; runpy.run_path(sys.argv[0], run_name='__main__')"
        )
        self.tree = tree
        self.proc = subprocess.Popen(
            [sys.executable, "-c", code, str(tree), str(script)],
            cwd=tree,
            env=env,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        self._read()

    def _read(self) -> dict[str, Any]:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            raise SystemExit(f"worker in {self.tree} exited ({self.proc.wait()})")
        return dict(json.loads(line))

    def ask(self, n: int, passes: int, threads: bool) -> dict[str, float]:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps({"n": n, "passes": passes, "threads": threads}) + "\n")
        self.proc.stdin.flush()
        return self._read()

    def close(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        self.proc.wait()


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    if args.worker:
        worker()
        return 0
    trees = args.tree or [Path(__file__).resolve().parent.parent]
    print(f"load average {_load()}; trees: {', '.join(str(t) for t in trees)}", flush=True)
    workers = [_Worker(t) for t in trees]
    try:
        for n in args.sizes:
            got: dict[int, list[dict[str, float]]] = {i: [] for i in range(len(trees))}
            for r in range(args.rounds):
                order = range(len(trees)) if r % 2 == 0 else reversed(range(len(trees)))
                for i in order:
                    res = workers[i].ask(n, args.passes, not args.no_threads)
                    got[i].append(res)
                    print(
                        f"  N={n} round {r + 1} tree {i}: pass {res['pass']:.2f} ms, "
                        f"kernel {res['kernel']:.2f} ms (load {_load()})",
                        flush=True,
                    )
            print(f"N = {n}: CPU ms a pass, median of {args.rounds} rounds (best)")
            print(f"  {'tree':<40} " + " ".join(f"{p:>14}" for p in PARTS))
            for i, tree in enumerate(trees):
                cells = []
                for part in PARTS:
                    vals = [g[part] for g in got[i] if part in g]
                    cells.append(
                        f"{statistics.median(vals):>7.2f} ({min(vals):>5.2f})"
                        if vals
                        else f"{'-':>14}"
                    )
                print(f"  {str(tree)[-40:]:<40} " + " ".join(cells), flush=True)
    finally:
        for w in workers:
            w.close()
    print(f"load average after {_load()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
