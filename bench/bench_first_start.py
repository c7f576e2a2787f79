"""A newcomer's start: a fresh clone's first ``./dev up``, then a second one.

Clones this repository into a temporary directory, runs ``./dev up`` there on
free ports with its own state directory, and prints the seconds from the
command to the page's address ("web viewer: http...") and to "The lab is
running", then stops it (Ctrl-C) and does the same again (the second start:
packages installed, kernels cached). The first start's figure includes the
install (from the local package caches once they hold the downloads) and runs
while the engine compiles its kernels. Prints the load average beside each.

    python -m bench.bench_first_start [--runs-second 3] [--keep]
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench import cli as bench_cli
from bench.labproc import REPO
from tests.kit.procs import free_port


def one_start(repo: Path, state: Path, timeout: float) -> tuple[float | None, float | None, str]:
    """Seconds to the address and to everything up; the command's output."""
    t0 = time.monotonic()
    proc = subprocess.Popen(
        [
            "./dev",
            "up",
            "--state-dir",
            str(state),
            "--port",
            str(free_port()),
            "--http-port",
            str(free_port()),
            "--no-multicast-scouting",
        ],
        cwd=repo,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    address = running = None
    lines: list[str] = []
    assert proc.stdout is not None
    try:
        for line in proc.stdout:
            lines.append(line)
            now = time.monotonic() - t0
            if address is None and "web viewer: http" in line:
                address = now
                print(f"    page's address after {now:.1f} s", flush=True)
            if "The lab is running" in line:
                running = now
                break
            if now > timeout:
                break
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
    return address, running, "".join(lines)


def main() -> int:
    p = bench_cli.parser("bench_first_start", __doc__)
    p.add_argument("--runs-second", type=int, default=3, help="second starts to time")
    p.add_argument("--timeout", type=float, default=600.0, help="seconds a start may take")
    p.add_argument("--keep", action="store_true", help="keep the clone (its logs)")
    args = p.parse_args()
    top = Path(tempfile.mkdtemp(prefix="wart-first-start-"))
    repo = top / "repo"
    subprocess.run(["git", "clone", "-q", str(REPO), str(repo)], check=True)
    try:
        print(f"fresh clone in {repo}; first start (install, and the kernels compiling)")
        address, running, out = one_start(repo, top / "state", args.timeout)
        load = os.getloadavg()
        if running is None:
            print(out[-3000:])
            print("the first start did not finish")
            return 1
        print(
            f"first start: address {address:.1f} s, everything up {running:.1f} s "
            f"(load {load[0]:.1f} {load[1]:.1f} {load[2]:.1f})"
        )
        seconds = []
        for i in range(args.runs_second):
            address, running, out = one_start(repo, top / "state", args.timeout)
            if address is None or running is None:
                print(out[-3000:])
                return 1
            seconds.append(address)
            load = os.getloadavg()
            print(
                f"second start {i + 1}: address {address:.2f} s, everything up {running:.2f} s "
                f"(load {load[0]:.1f})"
            )
        seconds.sort()
        print(f"second start, the page's address: median {seconds[len(seconds) // 2]:.2f} s")
    finally:
        if args.keep:
            print(f"kept: {top}")
        else:
            shutil.rmtree(top, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
