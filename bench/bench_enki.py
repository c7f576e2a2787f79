"""Our Sim2D engine against Enki (C++), the same scenario in the same run.

For each N, ``--repeats`` rounds; in each round our engine (in-process, as
bench/engine_bench.py runs it) and Enki (bench/enki/khepera_world.cpp, compiled
here with g++ against Debian's libenki-dev, run as a subprocess that reports its
own CPU time) simulate the same world in turn, the order alternating between
rounds. Printed per N: simulated seconds per CPU second for each, the median of
the per-round ratios (ours over Enki's, above 1 = we are faster) and the load
average. Figures go in docs/BENCHMARKS.md, "Swarms and small worlds (issue 22)".

The scenario is engine_bench's world as Enki can have it: the same arena, the
same pillars, the same robot poses (written to a file Enki's program reads), the
Braitenberg rule of common/sim2d/wander.py on both sides (Enki's IR distances go
through our response curve first), 10 ms steps, IR sensors refreshed every
step (100 a simulated second) in both, collisions and walls on. What differs is
listed in docs/BENCHMARKS.md beside the figures: each simulator's own physics,
IR model and noise; no gripper turret and no light (Enki's Khepera has neither),
while our ambient sensors still run (500 in the dark).

    .venv/bin/python -m bench.bench_enki [--sizes 10 35 100 1000 3000]
        [--sim-seconds 2] [--swarm-seconds 0.5] [--repeats 3] [--drives joints discs]
        [--rule compiled] [--full]

``--full`` gives our world what a lab's has and Enki's cannot: gripper turrets,
the lamp and a movable ball for every two robots (issue 35's "full scenario").

Needs g++ and libenki-dev (``apt-get install -y g++ libenki-dev``); without them
it says so and exits with status 2. The compiled program is cached in
build/bench-enki/ under the source's hash.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from bench import cli as bench_cli
from common.sim2d import compiled
from common.sim2d.wander import CRUISE, WEIGHTS
from common.sim2d.world import DRIVES, World
from tests.kit.worlds import control, scenario_world

REPO = Path(__file__).resolve().parents[1]
ENKI_SOURCE = REPO / "bench" / "enki" / "khepera_world.cpp"
BUILD_DIR = REPO / "build" / "bench-enki"
ENKI_HEADER = Path("/usr/include/enki/robots/khepera/Khepera.h")
CXX_FLAGS = ("-O2", "-std=c++17")
INSTALL_HINT = "install them with: apt-get install -y g++ libenki-dev (Debian 12: libenki2 1.6.99)"
TICK_S = 0.01  # Enki's program steps 10 ms too (its kDt)
WARM_UP_TICKS = 20  # as engine_bench.run and Enki's program
SWARM_N = 1000  # from this size on, --swarm-seconds applies

MAX_N = 20_000
MAX_SIM_SECONDS = 600.0
MAX_REPEATS = 50


class EnkiUnavailable(RuntimeError):
    """g++ or libenki-dev is missing, or the program did not compile."""


@dataclass(frozen=True)
class EnkiRun:
    """One line of Enki's program: ``enki n=.. steps=.. sim_s=.. cpu_s=.. ...``."""

    n: int
    steps: int
    sim_s: float
    cpu_s: float
    sim_per_cpu: float
    ir_updates_per_sim_s: float
    inside: int


def parse_enki_line(line: str) -> EnkiRun:
    """The program's one result line, or ValueError saying what is wrong with it."""
    words = line.split()
    if not words or words[0] != "enki":
        raise ValueError(f"not an Enki result line: {line!r}")
    fields: dict[str, str] = {}
    for word in words[1:]:
        key, eq, value = word.partition("=")
        if not eq:
            raise ValueError(f"bad field {word!r} in {line!r}")
        fields[key] = value
    try:
        return EnkiRun(
            n=int(fields["n"]),
            steps=int(fields["steps"]),
            sim_s=float(fields["sim_s"]),
            cpu_s=float(fields["cpu_s"]),
            sim_per_cpu=float(fields["sim_per_cpu"]),
            ir_updates_per_sim_s=float(fields["ir_updates_per_sim_s"]),
            inside=int(fields["inside"]),
        )
    except KeyError as e:
        raise ValueError(f"field {e} missing from {line!r}") from None


def enki_missing() -> str | None:
    """Why Enki's program cannot be built here, or None if it can."""
    if shutil.which("g++") is None:
        return f"g++ is not installed; {INSTALL_HINT}"
    if not ENKI_HEADER.exists():
        return f"libenki-dev is not installed ({ENKI_HEADER} is missing); {INSTALL_HINT}"
    return None


def compile_enki(build_dir: Path = BUILD_DIR) -> Path:
    """The compiled program, built once per version of its source and flags."""
    reason = enki_missing()
    if reason:
        raise EnkiUnavailable(reason)
    source = ENKI_SOURCE.read_bytes()
    digest = hashlib.sha256(source + " ".join(CXX_FLAGS).encode()).hexdigest()[:16]
    binary = build_dir / f"khepera_world-{digest}"
    if binary.exists():
        return binary
    build_dir.mkdir(parents=True, exist_ok=True)
    # Compiled under a temporary name and renamed: two runs at once (a test and a bench)
    # never see a half-written program.
    fd, tmp = tempfile.mkstemp(dir=build_dir, prefix=".khepera_world-")
    os.close(fd)
    cmd = ["g++", *CXX_FLAGS, "-o", tmp, str(ENKI_SOURCE), "-lenki"]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        Path(tmp).unlink(missing_ok=True)
        raise EnkiUnavailable(f"{' '.join(cmd)} failed:\n{done.stderr.strip()}")
    os.replace(tmp, binary)
    return binary


def write_scenario(world: World, path: Path) -> None:
    """The arena, pillars and robot poses, in the format bench/enki/khepera_world.cpp reads."""
    if world.width != world.height:
        raise ValueError("Enki's program takes square arenas only")
    lines = [f"arena {world.width!r}"]
    for o in world.obstacles.values():
        if o.shape.kind != "box" or o.heading != 0.0:
            raise ValueError(f"obstacle {o.id}: only unrotated boxes are written for Enki")
        lines.append(f"pillar {o.x!r} {o.y!r} {o.shape.width_mm!r} {o.shape.height_mm!r}")
    for x, y, heading in world.agent_pose:
        lines.append(f"robot {float(x)!r} {float(y)!r} {float(heading)!r}")
    path.write_text("\n".join(lines) + "\n")


def run_enki(binary: Path, scenario: Path, sim_seconds: float) -> EnkiRun:
    done = subprocess.run(
        [str(binary), str(scenario), repr(sim_seconds)],
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        raise RuntimeError(f"Enki's program failed ({done.returncode}): {done.stderr.strip()}")
    return parse_enki_line(done.stdout.strip().splitlines()[-1])


def compiled_control(world: World) -> None:
    """The same Braitenberg rule as engine_bench.control, compiled (compiled.braitenberg_speeds).

    Enki's side runs the rule in C++: with ``--rule compiled`` (the default) both
    sides run it compiled, and the comparison is of the simulators, not of
    numpy's per-call cost (about 5 us a tick at 10 robots, a third of Enki's step).
    """
    compiled.braitenberg_speeds(world.proximity, WEIGHTS, CRUISE, world.tables.max_speed, world.cmd)


RULES = {"numpy": control, "compiled": compiled_control}


def run_ours(
    n: int, sim_seconds: float, drive: str, rule: str = "compiled", full: bool = False
) -> float:
    """Simulated seconds per CPU second of our engine, timed as engine_bench.run times it."""
    world = scenario_world(n, drive, full)
    act = RULES[rule]
    for _ in range(WARM_UP_TICKS):
        act(world)
        world.step()
    steps = round(sim_seconds / world.tick_s)
    cpu0 = time.process_time()
    for _ in range(steps):
        act(world)
        world.step()
    return steps * world.tick_s / (time.process_time() - cpu0)


def robot_count(text: str) -> int:
    n = int(text)
    if not 1 <= n <= MAX_N:
        raise argparse.ArgumentTypeError(f"a size must be between 1 and {MAX_N}, not {n}")
    return n


def positive_seconds(text: str) -> float:
    s = float(text)
    if not 0 < s <= MAX_SIM_SECONDS:  # also refuses nan
        raise argparse.ArgumentTypeError(f"must be above 0 and at most {MAX_SIM_SECONDS:g}")
    return s


def rounds(text: str) -> int:
    r = int(text)
    if not 1 <= r <= MAX_REPEATS:
        raise argparse.ArgumentTypeError(f"must be between 1 and {MAX_REPEATS}, not {r}")
    return r


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = bench_cli.parser("bench_enki", __doc__)
    # The converters' names appear in argparse's messages ("invalid robot_count value").
    p.add_argument(
        "--sizes",
        type=robot_count,
        nargs="+",
        default=[10, 35, 100, 1000, 3000],
        help=f"robot counts, each 1 to {MAX_N}",
    )
    p.add_argument(
        "--sim-seconds",
        type=positive_seconds,
        default=2.0,
        help=f"simulated seconds below N = {SWARM_N}",
    )
    p.add_argument(
        "--swarm-seconds",
        type=positive_seconds,
        default=0.5,
        help=f"simulated seconds from N = {SWARM_N}",
    )
    p.add_argument("--repeats", type=rounds, default=3, help="A/B rounds per size")
    p.add_argument(
        "--drives",
        nargs="+",
        choices=DRIVES,
        default=["joints", "discs"],
        help="our drives to run, each against Enki (World(drive=...))",
    )
    p.add_argument(
        "--full",
        action="store_true",
        help="our world full-featured: gripper turrets, the lamp, a movable ball for "
        "every two robots (Enki's as it can have it: robots and pillars)",
    )
    p.add_argument(
        "--rule",
        choices=sorted(RULES),
        default="compiled",
        help="our side's Braitenberg rule: compiled (numba, as Enki's is C++) or numpy "
        "(engine_bench's, as the engine's --wander runs it)",
    )
    args = p.parse_args(argv)
    if len(set(args.drives)) != len(args.drives):
        p.error("--drives: each drive once")
    return args


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        binary = compile_enki()
    except EnkiUnavailable as e:
        print(f"bench_enki: {e}", file=sys.stderr)
        return 2
    print(f"Enki's program: {binary.relative_to(REPO)}")
    print(f"kernels ready in {compiled.warm_up():.2f} s: {compiled.WHY}")
    kind = "full (grippers, lamp, balls)" if args.full else "as Enki"
    print(f"our rule: {args.rule}; our world {kind}; load average before: {_load()}")
    print(f"{'N':>5} {'round':>5}  {'what':<14} {'sim s / CPU s':>13} {'CPU us a step':>13}  load")
    with tempfile.TemporaryDirectory(prefix="bench-enki-") as tmp:
        for n in args.sizes:
            seconds = args.sim_seconds if n < SWARM_N else args.swarm_seconds
            scenario = Path(tmp) / f"n{n}.txt"
            write_scenario(scenario_world(n), scenario)
            ours: dict[str, list[float]] = {d: [] for d in args.drives}
            enki: list[float] = []
            ratios: dict[str, list[float]] = {d: [] for d in args.drives}
            for r in range(args.repeats):
                got: dict[str, float] = {}
                # Alternate who goes first, so a load that rises or falls within a
                # round does not always favour the same side.
                order = [*args.drives, "enki"] if r % 2 == 0 else ["enki", *args.drives]
                for what in order:
                    if what == "enki":
                        run = run_enki(binary, scenario, seconds)
                        if run.n != n or run.inside != n:
                            raise RuntimeError(f"Enki's run does not match N = {n}: {run}")
                        got[what] = run.sim_per_cpu
                    else:
                        got[what] = run_ours(n, seconds, what, args.rule, args.full)
                    print(
                        f"{n:>5} {r + 1:>5}  {what:<14} {got[what]:>13.4g} "
                        f"{TICK_S / got[what] * 1e6:>13.1f}  {os.getloadavg()[0]:.2f}",
                        flush=True,
                    )
                enki.append(got["enki"])
                for d in args.drives:
                    ours[d].append(got[d])
                    ratios[d].append(got[d] / got["enki"])
            summary = [f"enki={statistics.median(enki):.4g}"]
            for d in args.drives:
                summary.append(f"ours_{d}={statistics.median(ours[d]):.4g}")
                summary.append(f"ratio_{d}={statistics.median(ratios[d]):.3g}")
            print(
                f"result n={n} sim_s={seconds:g} {' '.join(summary)} load={os.getloadavg()[0]:.2f}",
                flush=True,
            )
    print(f"load average after: {_load()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
