"""A CPU share per sandbox, so a busy loop or a fork bomb cannot starve the engine.

Each sandbox gets a cgroup of its own with a quota of ``fraction`` of one
core, inside the runner's group, whose quota leaves one core of the machine
to everything else (the engine first): cgroup v2 ``cpu.max`` where the unified hierarchy has the cpu
controller, else cgroup v1 ``cpu.cfs_quota_us``. The sandbox enters its
cgroup before anything of it runs (a shell writes its own pid to
``cgroup.procs`` and then execs the sandbox), so every process it forks is
counted. Where no cgroup can be made (no write access, no cpu controller) the
sandbox runs at nice 19 only, with RLIMIT_CPU as the end: :attr:`mode` says
which one is in force, and the runner logs it at start.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import os
import time
from pathlib import Path

log = logging.getLogger("wart.runner.cpu")

_ROOT = Path("/sys/fs/cgroup")
_PERIOD_US = 100_000
_instances = itertools.count(1)
NICE_ONLY = "nice 19 + RLIMIT_CPU (no cgroup could be made here)"


def _own_cgroup_dirs() -> list[tuple[str, Path]]:
    """(version, directory) of this process's cpu cgroup, v2 first."""
    found: list[tuple[str, Path]] = []
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        return found
    for line in lines:
        number, controllers, path = line.split(":", 2)
        if number == "0" and controllers == "":
            unified = _ROOT / path.lstrip("/")
            if "cpu" in _read(_ROOT / "cgroup.controllers").split():
                found.insert(0, ("v2", unified))
        elif "cpu" in controllers.split(","):
            found.append(("v1", _ROOT / "cpu" / path.lstrip("/")))
    return found


def _remove_stale(parent: Path) -> None:
    """Remove the empty groups of runners that are gone (a crash skips close())."""
    for group in parent.glob("wart-runner-*"):
        pid = group.name.split("-")[2]  # wart-runner-<pid>-<n>
        if pid.isdigit() and not Path(f"/proc/{pid}").exists():
            for path in [*group.iterdir(), group]:
                if path.is_dir():
                    with contextlib.suppress(OSError):
                        path.rmdir()


def _read(path: Path) -> str:
    try:
        return path.read_text()
    except OSError:
        return ""


class CpuShare:
    """Makes, enters and removes the sandboxes' cpu cgroups (or says it cannot)."""

    def __init__(self, fraction: float) -> None:
        if not 0.01 <= fraction <= 64:
            raise ValueError("the CPU share must be 0.01..64 cores")
        self.quota_us = int(_PERIOD_US * fraction)
        # All sandboxes together leave one core to the engine and the runner.
        self.total_us = int(_PERIOD_US * max(fraction, (os.cpu_count() or 1) - 1))
        self.version = ""
        self.base: Path | None = None
        self._owner = os.getpid()
        for version, parent in _own_cgroup_dirs():
            _remove_stale(parent)
            # One group per CpuShare, not per process: a process may hold several
            # (tests do), and one closing must not remove another's group.
            base = parent / f"wart-runner-{os.getpid()}-{next(_instances)}"
            try:
                base.mkdir(exist_ok=True)
                if version == "v2":
                    # The per-sandbox groups get quotas of their own: let them use cpu.
                    (base / "cgroup.subtree_control").write_text("+cpu")
                self._limit(version, base, self.total_us)
            except OSError as exc:
                log.debug("no %s cpu cgroup under %s: %s", version, parent, exc)
                with contextlib.suppress(OSError):
                    base.rmdir()
                continue
            self.version, self.base = version, base
            break

    @property
    def mode(self) -> str:
        if self.base is None:
            return NICE_ONLY
        knob = "cpu.max" if self.version == "v2" else "cpu.cfs_quota_us"
        return (
            f"cgroup {self.version} {knob} = {self.quota_us / _PERIOD_US:.2f} core per sandbox,"
            f" {self.total_us / _PERIOD_US:.2f} for all"
        )

    @staticmethod
    def _limit(version: str, group: Path, quota_us: int) -> None:
        if version == "v2":
            (group / "cpu.max").write_text(f"{quota_us} {_PERIOD_US}")
        else:
            (group / "cpu.cfs_period_us").write_text(str(_PERIOD_US))
            (group / "cpu.cfs_quota_us").write_text(str(quota_us))

    def prefix(self, name: str) -> list[str]:
        """The argv that puts what follows into cgroup ``name`` (made now), then nice 19."""
        nice = ["nice", "-n", "19"]
        if self.base is None:
            return nice
        group = self.base / name
        try:
            group.mkdir(exist_ok=True)
            self._limit(self.version, group, self.quota_us)
        except OSError as exc:
            log.warning("sandbox %s runs at nice 19 only: its cpu cgroup failed: %s", name, exc)
            return nice
        procs = str(group / "cgroup.procs")
        return ["sh", "-c", 'echo $$ > "$0" && exec "$@"', procs, *nice]

    def release(self, name: str) -> None:
        """Remove cgroup ``name`` once its processes are gone (they may take a moment)."""
        if self.base is None:
            return
        group = self.base / name
        for _ in range(20):
            try:
                group.rmdir()
                return
            except FileNotFoundError:
                return
            except OSError:
                time.sleep(0.05)
        log.warning("could not remove the cpu cgroup %s", group)

    def close(self) -> None:
        # A forked child inherits the atexit hook that calls this: only the process
        # that made the group may remove it (a test's forked helper once did).
        if self.base is not None and os.getpid() == self._owner:
            with contextlib.suppress(OSError):
                self.base.rmdir()
