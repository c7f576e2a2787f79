"""Where a command's CPU goes, machine-wide: every process's CPU time, by kind.

Runs COMMAND, reads every process's CPU time from /proc once a second while it
runs, and prints the CPU seconds of each kind of process (Chromium's renderer,
an xdist worker, `python -m services.cli engine`, and a test forkserver's child
by the command it names itself: `forked wart engine`, ...) beside the machine's
busy seconds from /proc/stat. What a test suite's own accounting cannot see: the
CPU of processes it did not reap (a browser, the services a forkserver made).

    .venv/bin/python -m bench.cpu_by_process -- ./dev test -q
    .venv/bin/python -m bench.cpu_by_process --top 40 -- .venv/bin/python -m pytest tests/browser

A process started while COMMAND runs is counted from its start (its first
second included: a service's imports, a renderer's first page); one that was
already running, from the first sample. What a process spends after the last
sample before it ends, and one that lives less than a sample, is missed: the
machine's busy seconds say how much that was.
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

from bench import cli as bench_cli

TICKS_PER_S = os.sysconf("SC_CLK_TCK")
_CHROMIUM_TYPE = re.compile(r"--type=(\S+)")
_UTILITY = re.compile(r"--utility-sub-type=(\S+)")


def uptime_ticks() -> int:
    """Clock ticks since boot: the unit of a process's start time in /proc/<pid>/stat."""
    with open("/proc/uptime") as uptime:
        return int(float(uptime.read().split()[0]) * TICKS_PER_S)


def machine_busy_ticks() -> int:
    """Busy ticks of every CPU since boot (user, nice, system, irq, softirq, steal)."""
    with open("/proc/stat") as stat:
        fields = [int(v) for v in stat.readline().split()[1:]]
    return sum(fields) - fields[3] - fields[4]  # less idle and iowait


def kind_of(pid: int) -> str | None:
    """A process's kind, from its command line; None if it is gone or has none."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            argv = [a.decode(errors="replace") for a in f.read().split(b"\0") if a]
    except OSError:
        return None
    if not argv:
        return None
    # Chromium rewrites its title: the whole command line may be its first argument.
    whole = " ".join(argv)
    program = os.path.basename(whole.split(" ")[0])
    if "chrom" in program or "headless_shell" in program:
        found = _CHROMIUM_TYPE.search(whole)
        kind = found.group(1) if found else "browser"
        utility = _UTILITY.search(whole) if kind == "utility" else None
        return f"chromium {kind}" + (f" {utility.group(1)}" if utility else "")
    if "python" in program:
        rest = argv[1:]
        if "-m" in rest:
            at = rest.index("-m")
            words = rest[at + 1 : at + 3]
            if words[:1] == ["tests.kit.forkserver"]:
                return _forked_kind(pid)
            if words[:1] == ["pytest"]:
                words = words[:1]
            return "python -m " + " ".join(words)
        if "-c" in rest:
            code = rest[rest.index("-c") + 1]
            if "execnet" in code or "sys.stdin.readline" in code:
                return "python pytest-xdist worker"
            return "python -c " + code[:30].replace("\n", " ")
        scripts = [a for a in rest if not a.startswith("-")]
        return "python " + (os.path.basename(scripts[0]) if scripts else "")
    return program


FORKSERVER = "python -m tests.kit.forkserver"
ZYGOTE = "chromium zygote"
# Kinds a process leaves by renaming itself: a forkserver's child (its comm), a renderer
# Chromium's zygote forked (its title). Asked again at each sample while they hold.
TRANSIENT = (FORKSERVER, ZYGOTE)


def _forked_kind(pid: int) -> str:
    """A test forkserver's child names itself (its comm, "wart engine"): that, not the server's."""
    try:
        comm = Path(f"/proc/{pid}/comm").read_text().strip()
    except OSError:
        comm = ""
    words = comm.split()[:2]  # "wart engine --m": the command, not its cut arguments
    return "forked " + " ".join(words) if words[:1] == ["wart"] else FORKSERVER


class Sampler:
    """CPU seconds by kind of process, from /proc, until stopped."""

    def __init__(self, period_s: float = 1.0) -> None:
        self.period_s = period_s
        self.by_kind: collections.Counter[str] = collections.Counter()
        self._seen: dict[int, tuple[str, int, int]] = {}  # pid: kind, ticks, start
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.busy_start = machine_busy_ticks()
        self.started_at = uptime_ticks()
        self.busy_ticks = 0

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()
        self._sample()
        self.busy_ticks = machine_busy_ticks() - self.busy_start

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self._sample()

    def _sample(self) -> None:
        for entry in os.listdir("/proc"):
            if not entry.isdigit():
                continue
            pid = int(entry)
            try:
                with open(f"/proc/{pid}/stat") as f:
                    fields = f.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            ticks = int(fields[11]) + int(fields[12])  # utime, stime
            started = int(fields[19])  # starttime, ticks since boot
            seen = self._seen.get(pid)
            if seen is None or seen[2] != started:  # new, or a new process on an old pid
                kind = kind_of(pid)
                if kind is None:
                    continue
                # A process started since the sampler: all its CPU is the command's.
                # One already running: only what it spends from now on.
                seen = (kind, 0 if started >= self.started_at else ticks, started)
            kind, last, _ = seen
            if kind in TRANSIENT:  # a child just forked may have named itself since
                kind = kind_of(pid) or kind
            self.by_kind[kind] += ticks - last
            self._seen[pid] = (kind, ticks, started)


def main(argv: list[str] | None = None) -> int:
    parser = bench_cli.parser("cpu_by_process", __doc__)
    parser.add_argument("--top", type=int, default=25, help="kinds of process printed (25)")
    parser.add_argument("--period", type=float, default=1.0, help="seconds between samples")
    parser.add_argument("command", nargs=argparse.REMAINDER, help="the command, after --")
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("give the command to measure after --")
    if args.period <= 0:
        parser.error("--period must be above 0")
    sampler = Sampler(args.period)
    sampler.start()
    started = time.monotonic()
    try:
        code = subprocess.call(command)
    except FileNotFoundError:
        parser.error(f"no such command: {command[0]}")
    except KeyboardInterrupt:
        code = 130
    wall = time.monotonic() - started
    sampler.stop()
    busy = sampler.busy_ticks / TICKS_PER_S
    seen = sum(sampler.by_kind.values()) / TICKS_PER_S
    print(
        f"\n{wall:.0f} s wall on {os.cpu_count()} CPUs; the machine busy {busy:.0f} s",
        file=sys.stderr,
    )
    print(
        f"{seen:8.1f} s  seen in processes sampled (the rest: shorter than a sample)",
        file=sys.stderr,
    )
    for kind, ticks in sampler.by_kind.most_common(args.top):
        print(f"{ticks / TICKS_PER_S:8.1f} s  {kind}", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
