"""What a sandbox sees of the runner: its limits, and the files staged for it.

The stage is a fresh directory bound read-only at /ctl inside the sandbox: the child
program, common/controller/ (standard library only) under lib/, the student's file
under user/, and the sandbox's own /proc/meminfo. A program that reads
/proc/meminfo (to size a buffer, a cache, a pool) sees the memory it may use, not
the host's: MemTotal is the sandbox's memory limit, MemFree and MemAvailable what
its address space leaves after the writable tmpfs, no swap.
"""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from common import controller as controller_api

_CHILD = Path(__file__).with_name("child.py")
_API = Path(controller_api.__file__).parent  # the whole package: standard library only
MEMINFO = "meminfo"  # in the stage; bound over the sandbox's /proc/meminfo


@dataclass(frozen=True)
class SandboxLimits:
    cpu_seconds: int = 120
    memory_bytes: int = 256 * 1024 * 1024
    processes: int = 16
    open_files: int = 64
    file_size_bytes: int = 1024 * 1024
    output_lines_per_second: int = 50
    commands_per_second: int = 200
    output_bytes_per_second: int = 64 * 1024  # faster than this (4 s of burst) ends the run
    cpu_share: float = 0.5  # of one core, where a cpu cgroup can be made
    # A do_work that has not returned for this long ends the run, told where it was
    # (0: only when the slot's end nears, see PROBE_AHEAD_S in sandbox.py).
    hang_seconds: float = 0.0

    def __post_init__(self) -> None:
        if self.memory_bytes < 64 << 20:
            raise ValueError("a sandbox needs a memory limit of at least 64 MB")
        if not 0 <= self.hang_seconds <= 24 * 3600:
            raise ValueError("hang_seconds is 0 (off) or a positive number of seconds")

    @property
    def writable_bytes(self) -> int:
        """The tmpfs space (/work, /tmp and /dev/shm together): it is host memory, so it is
        a quarter of the memory limit and the address space gets the rest."""
        return self.memory_bytes // 4

    @property
    def address_space_bytes(self) -> int:
        return self.memory_bytes - self.writable_bytes


def meminfo_text(limits: SandboxLimits) -> str:
    """/proc/meminfo as the sandbox sees it (the fields programs read, in kB)."""
    total = limits.memory_bytes >> 10
    available = limits.address_space_bytes >> 10
    fields = [
        ("MemTotal", total),
        ("MemFree", available),
        ("MemAvailable", available),
        ("Buffers", 0),
        ("Cached", 0),
        ("SwapCached", 0),
        ("Shmem", 0),
        ("SwapTotal", 0),
        ("SwapFree", 0),
        ("CommitLimit", available),
    ]
    return "".join(f"{name + ':':<16}{kb:>8} kB\n" for name, kb in fields)


def stage_files(source: bytes, limits: SandboxLimits, episode: bytes | None = None) -> Path:
    """A new stage for one run (the caller removes it when the run is over); ``episode``:
    a teacher's grader's input, user/episode.json."""
    stage = Path(tempfile.mkdtemp(prefix="wart-sandbox-"))
    (stage / "lib" / "common").mkdir(parents=True)
    (stage / "user").mkdir()
    shutil.copy(_CHILD, stage / "child.py")
    shutil.copytree(
        _API,
        stage / "lib" / "common" / "controller",
        ignore=shutil.ignore_patterns("__pycache__"),
    )
    (stage / "lib" / "common" / "__init__.py").write_text("")
    (stage / "user" / "controller.py").write_bytes(source)
    if episode is not None:
        (stage / "user" / "episode.json").write_bytes(episode)
    (stage / MEMINFO).write_text(meminfo_text(limits))
    for path in [stage, *stage.rglob("*")]:
        path.chmod(0o755 if path.is_dir() else 0o644)
    return stage
