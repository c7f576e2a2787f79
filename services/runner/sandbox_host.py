"""What the sandboxes of one host share: the check that they can run, the seccomp
program, the CPU share's cgroup, and a uid of its own for each running sandbox.

Sandbox (services/runner/sandbox.py) takes these for each run.
"""

from __future__ import annotations

import atexit
import fcntl
import functools
import logging
import os
import shutil
import tempfile
import threading
from pathlib import Path

import psutil

from services.runner.cpushare import CpuShare
from services.runner.syscalls import SANDBOX_PYTHON, SyscallFilterError, build_filter

log = logging.getLogger("wart.runner.sandbox")


def sandbox_problem() -> str | None:
    """None if sandboxes can run here, else what is missing."""
    if shutil.which("bwrap") is None:
        return "bubblewrap is not installed (Debian package bubblewrap)"
    if not Path(SANDBOX_PYTHON).exists():
        return f"{SANDBOX_PYTHON} is missing (Debian package python3)"
    if os.geteuid() == 0 and shutil.which("setpriv") is None:
        return "setpriv is missing (Debian package util-linux)"
    if shutil.which("prlimit") is None:
        return "prlimit is missing (Debian package util-linux)"
    try:
        syscall_filter()
    except SyscallFilterError as exc:
        return str(exc)
    return None


@functools.lru_cache(maxsize=1)
def syscall_filter() -> bytes:
    """The seccomp program every sandbox gets, built once per runner."""
    return build_filter()


_cpu_lock = threading.Lock()
_cpu_shares: dict[float, CpuShare] = {}


def cpu_share(fraction: float) -> CpuShare:
    """The runner's one CpuShare for ``fraction`` (its cgroup directory is per runner)."""
    with _cpu_lock:
        share = _cpu_shares.get(fraction)
        if share is None:
            share = _cpu_shares[fraction] = CpuShare(fraction)
            atexit.register(share.close)  # its cgroup directory outlives it otherwise
            log.info("CPU share of a sandbox: %s", share.mode)
        return share


def release_cpu_share(fraction: float) -> None:
    """Remove the CpuShare of ``fraction`` and its cgroup; the next cpu_share() makes anew."""
    with _cpu_lock:
        share = _cpu_shares.pop(fraction, None)
    if share is not None:
        share.close()


_uid_lock = threading.Lock()
_uid_claims: dict[int, int] = {}  # uid -> the open file whose lock claims it
_UID_BASE = 61000
_UID_COUNT = 1000


def _uid_claim_dir() -> Path:
    """Where the claims live: one lock file per uid, shared by every runner of the host."""
    for base in (Path("/run/lock"), Path(tempfile.gettempdir())):
        path = base / "wart-sandbox-uids"
        try:
            path.mkdir(mode=0o700, exist_ok=True)
        except OSError:
            continue
        if os.access(path, os.W_OK):
            return path
    raise OSError("no directory for the sandboxes' uid claims (/run/lock, the temp dir)")


def _take_uid() -> int:
    """A uid of its own for one sandbox, for as long as it runs.

    RLIMIT_NPROC counts processes per uid, and a process may signal another
    of its uid: two sandboxes must never share one, even from two runners of
    the same host. So each claim is an flock on a file per uid (released by
    the kernel if the runner dies), and a uid that still owns a process (a
    zombie left by a crash) is skipped.
    """
    claims = _uid_claim_dir()
    busy = {p.info["uids"].real for p in psutil.process_iter(["uids"]) if p.info["uids"]}
    with _uid_lock:
        for uid in range(_UID_BASE, _UID_BASE + _UID_COUNT):
            if uid in busy or uid in _uid_claims:
                continue
            fd = os.open(claims / str(uid), os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:  # another runner's sandbox has it
                os.close(fd)
                continue
            _uid_claims[uid] = fd
            return uid
    raise OSError(f"all {_UID_COUNT} sandbox uids from {_UID_BASE} are in use")


def _give_uid(uid: int) -> None:
    with _uid_lock:
        fd = _uid_claims.pop(uid, None)
    if fd is not None:
        os.close(fd)  # closing drops the flock
