"""Install costs: the client (`pip install wart-lab`) against the lab and the extras.

For each install: a fresh virtualenv (uv), the project installed from this repository
(not editable) with an empty uv cache of its own (every package downloaded), the time
that took and the virtualenv's size; then the same into a second fresh virtualenv from
that cache (warm). ``--pip`` measures pip too (``pip install --no-cache-dir``), as a
student without uv installs. docs/FROM_YOUR_LAPTOP.md holds today's figures.

    .venv/bin/python -m bench.bench_install
    .venv/bin/python -m bench.bench_install --only client lab --pip
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench import cli as bench_cli
from tests.kit.client_install import uv

REPO = Path(__file__).resolve().parent.parent
INSTALLS = {"client": "", "ros": "[ros]", "notebook": "[notebook]", "lab": "[lab]"}


def size_mb(path: Path) -> float:
    """Its size on disk, as `du -sm` says it (blocks, not the files' lengths)."""
    done = subprocess.run(["du", "-sm", str(path)], capture_output=True, text=True, check=True)
    return float(done.stdout.split()[0])


def timed(argv: list[str]) -> float:
    started = time.monotonic()
    done = subprocess.run(argv, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed:\n{done.stderr[-2000:]}")
    return time.monotonic() - started


def with_uv(tool: str, spec: str, tmp: Path) -> tuple[float, float, float]:
    """(seconds from an empty cache, seconds from the warm cache, MB of the venv)."""
    cache = tmp / "cache"
    seconds = []
    for name in ("cold", "warm"):
        venv = tmp / name
        timed([tool, "venv", "-q", "--python", sys.executable, str(venv)])
        python = str(venv / "bin" / "python")
        seconds.append(
            timed(
                [tool, "pip", "install", "-q", "--cache-dir", str(cache), "--python", python, spec]
            )
        )
    return seconds[0], seconds[1], size_mb(tmp / "cold")


def with_pip(spec: str, tmp: Path) -> tuple[float, float]:
    venv = tmp / "pip"
    timed([sys.executable, "-m", "venv", str(venv)])
    pip = str(venv / "bin" / "pip")
    return timed([pip, "install", "-q", "--no-cache-dir", spec]), size_mb(venv)


def main() -> int:
    p = bench_cli.parser("bench_install", __doc__)
    p.add_argument("--only", nargs="+", choices=sorted(INSTALLS), help="these installs only")
    p.add_argument("--pip", action="store_true", help="pip too (slower: no cache, bytecode)")
    args = p.parse_args()
    tool = uv()
    if tool is None:
        print("uv is needed (./dev installs it beside the lab's Python)", file=sys.stderr)
        return 2
    print("| install | uv, empty cache | uv, warm cache | size (uv) | pip, no cache | size (pip) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name in args.only or INSTALLS:
        spec = f"{REPO}{INSTALLS[name]}"
        tmp = Path(tempfile.mkdtemp(prefix=f"bench-install-{name}-"))
        try:
            cold, warm, mb = with_uv(tool, spec, tmp)
            pip_s, pip_mb = with_pip(spec, tmp) if args.pip else (None, None)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        pip_cells = f"{pip_s:.1f} s | {pip_mb:.0f} MB" if pip_s is not None else "- | -"
        print(f"| {name} | {cold:.1f} s | {warm:.1f} s | {mb:.0f} MB | {pip_cells} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
