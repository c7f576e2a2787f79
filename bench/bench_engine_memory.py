"""An engine's resident memory at 10 and 1,000 robots, and where it goes.

Starts a router and the registry, then for each size and each kernels' path
(``WART_KERNELS``: ``aot``, the module compiled ahead of time, and ``jit``,
numba's kernels loaded from its cache: common/sim2d/aot.py) a real ``wart
engine`` on a generated map of that many Khepera (the default drive), waits
until its world ticks, and prints its RSS (psutil) after --settle seconds.
Then, each in a fresh interpreter, what the engine's imports cost on their
own (numpy, llvmlite, numba, pymunk, zenoh, the engine module, its kernels
on either path), so the table says where the memory goes.

    python -m bench.bench_engine_memory [--sizes 10 1000] [--paths aot jit] [--settle 5]
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import psutil

from bench import cli as bench_cli
from bench.labproc import REPO, BenchLab
from common.keys import AliveKind
from common.sim2d import aot

ENGINE = "import services.engine.main; from common.sim2d import compiled"
# (label, WART_KERNELS ("": a library's, the same either way), code)
IMPORTS = (
    ("python alone", "", "pass"),
    ("+ numpy", "", "import numpy"),
    ("+ llvmlite's LLVM", "", "import numpy, llvmlite.binding"),
    ("+ numba", "", "import numpy, numba"),
    ("+ pymunk (chipmunk)", "", "import numpy, numba, pymunk"),
    ("+ zenoh", "", "import numpy, numba, pymunk, zenoh"),
    ("the engine's imports (jit)", "jit", ENGINE),
    ("+ its kernels loaded (jit)", "jit", f"{ENGINE}; compiled.warm_up()"),
    ("numpy, pymunk, zenoh", "", "import numpy, pymunk, zenoh"),
    ("the engine's imports (aot)", "aot", ENGINE),
    ("+ its kernels loaded (aot)", "aot", f"{ENGINE}; compiled.warm_up()"),
)


def map_of(robots: int, path: Path) -> Path:
    """An empty arena with ``robots`` Khepera on a grid, 150 mm apart."""
    base = json.loads((REPO / "maps" / "empty.json").read_text())
    side = math.ceil(math.sqrt(robots))
    size = 150.0 * (side + 1)
    base["arena"] = {**base.get("arena", {}), "width": size, "height": size}
    base["agents"] = [
        {
            "id": f"k{i}",
            "type": "khepera",
            "x": 150.0 * (1 + i % side),
            "y": 150.0 * (1 + i // side),
            "heading_deg": 0,
        }
        for i in range(robots)
    ]
    for key in ("obstacles", "objects", "lights", "zones"):
        base[key] = []
    path.write_text(json.dumps(base))
    return path


def import_rss(code: str, path: str) -> float:
    """MiB resident after ``code`` in a fresh interpreter on that kernels' path."""
    out = subprocess.run(
        [
            sys.executable,
            "-c",
            # VmRSS, not ru_maxrss: the latter survives exec, so it would be this bench's own
            f"{code}\nprint([l for l in open('/proc/self/status') if l.startswith('VmRSS')][0])",
        ],
        cwd=REPO,
        env={**os.environ, "WART_KERNELS": path},
        capture_output=True,
        text=True,
        check=True,
    )
    return int(out.stdout.split()[-2]) / 1024  # "VmRSS:  123456 kB"


def main() -> int:
    p = bench_cli.parser("bench_engine_memory", __doc__)
    p.add_argument("--sizes", type=int, nargs="+", default=[10, 1000])
    p.add_argument("--settle", type=float, default=5.0, help="seconds of ticking before reading")
    p.add_argument(
        "--paths",
        nargs="+",
        choices=("aot", "jit"),
        default=["aot", "jit"],
        help="the kernels' paths to measure (WART_KERNELS; aot needs the module built: "
        "python -m common.sim2d.aot_build)",
    )
    args = p.parse_args()
    try:
        aot.load()
    except aot.Unavailable as exc:
        if "aot" in args.paths:
            p.error(f"--paths aot: the ahead-of-time module is {exc}")
    lab = BenchLab([], "bench-password")
    try:
        lab.start()
        for n in args.sizes:
            for kernels in args.paths:
                world = f"m{n}{kernels}"
                path = map_of(n, lab.tmp / f"{world}.json")
                os.environ["WART_KERNELS"] = kernels  # the engine's environment (tests/kit/lab.py)
                lab.spawn(
                    ["engine", "--map", str(path), "--world", world, *lab.net()],
                    (AliveKind.WORLD, world),
                )
                engine = psutil.Process(lab.procs[-1].pid)
                time.sleep(args.settle)
                rss = engine.memory_info().rss / 2**20
                print(
                    f"engine of {n} robots, kernels {kernels}: {rss:.0f} MiB resident "
                    f"(load {psutil.getloadavg()[0]:.1f})",
                    flush=True,
                )
                lab.procs[-1].terminate()
                lab.procs[-1].wait(10)
    finally:
        lab.stop()
    print("where it goes (each line a fresh interpreter, resident after it):")
    for label, kernels, code in IMPORTS:
        if kernels in args.paths or not kernels:
            print(f"  {label:<28} {import_rss(code, kernels or 'jit'):6.0f} MiB", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
