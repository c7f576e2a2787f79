"""The sandbox's syscall filter: a seccomp BPF program handed to ``bwrap --seccomp``.

The program is built by libseccomp's own Python bindings (Debian package
python3-seccomp) rather than by hand: they know every architecture's syscall
numbers and the checks that stop 32-bit and x32 calls from slipping past a
64-bit filter. The bindings exist for Debian's /usr/bin/python3 (the
sandbox's interpreter), not for the runner's venv, so the runner runs this
file under that interpreter once and keeps the bytes it prints:

    /usr/bin/python3 -I services/runner/syscalls.py > filter.bpf

Everything not listed here is allowed: the point is to take away the kernel
interfaces an unprivileged process can still reach and that have a history of
privilege escalations (namespaces, BPF, perf, keyrings, io_uring, ptrace),
and every socket family but AF_UNIX (the network namespace is empty anyway).
"""

from __future__ import annotations

import errno
import subprocess
import sys
from pathlib import Path

SANDBOX_PYTHON = "/usr/bin/python3"

# Refused with EPERM.
DENIED = (
    "ptrace",
    "process_vm_readv",
    "process_vm_writev",
    "mount",
    "umount2",
    "pivot_root",
    "chroot",
    "move_mount",
    "open_tree",
    "fsopen",
    "fsconfig",
    "fsmount",
    "fspick",
    "mount_setattr",
    "unshare",
    "setns",
    "kexec_load",
    "kexec_file_load",
    "bpf",
    "perf_event_open",
    "keyctl",
    "add_key",
    "request_key",
    "personality",
    "init_module",
    "finit_module",
    "delete_module",
    "reboot",
    "swapon",
    "swapoff",
    "acct",
    "quotactl",
    "syslog",
    "userfaultfd",
    "io_uring_setup",
    "io_uring_enter",
    "io_uring_register",
    "open_by_handle_at",
    "name_to_handle_at",
    "fanotify_init",
)

# clone() with any of these flags makes a namespace: refused like unshare().
_NAMESPACE_FLAGS = (
    0x00020000,  # CLONE_NEWNS
    0x02000000,  # CLONE_NEWCGROUP
    0x04000000,  # CLONE_NEWUTS
    0x08000000,  # CLONE_NEWIPC
    0x10000000,  # CLONE_NEWUSER
    0x20000000,  # CLONE_NEWPID
    0x40000000,  # CLONE_NEWNET
)
_AF_UNIX = 1


class SyscallFilterError(RuntimeError):
    pass


def build_filter() -> bytes:
    """The BPF program, built by /usr/bin/python3 with libseccomp.

    Raises SyscallFilterError (saying what to install) if it cannot be built.
    """
    try:
        done = subprocess.run(
            [SANDBOX_PYTHON, "-I", str(Path(__file__).resolve())],
            capture_output=True,
            timeout=30,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise SyscallFilterError(f"could not run {SANDBOX_PYTHON}: {exc}") from None
    if done.returncode != 0 or not done.stdout or len(done.stdout) % 8:
        detail = done.stderr.decode("utf-8", "replace").strip().splitlines()[-1:] or ["no output"]
        raise SyscallFilterError(
            f"could not build the syscall filter ({detail[0]}); "
            "is python3-seccomp (Debian package) installed?"
        )
    return done.stdout


def _export() -> int:
    # Runs under /usr/bin/python3, where Debian's bindings live.
    import seccomp

    denied = seccomp.ERRNO(errno.EPERM)
    rules = seccomp.SyscallFilter(defaction=seccomp.ALLOW)
    for name in DENIED:  # a name libseccomp does not know fails the build: no silent hole
        rules.add_rule(denied, name)
    for flag in _NAMESPACE_FLAGS:
        rules.add_rule(denied, "clone", seccomp.Arg(0, seccomp.MASKED_EQ, flag, flag))
    # glibc falls back to clone() when clone3() says ENOSYS; clone3's flags sit
    # in memory a filter cannot read, so it must go.
    rules.add_rule(seccomp.ERRNO(errno.ENOSYS), "clone3")
    rules.add_rule(
        seccomp.ERRNO(errno.EAFNOSUPPORT), "socket", seccomp.Arg(0, seccomp.NE, _AF_UNIX)
    )
    sys.stdout.flush()
    rules.export_bpf(sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(_export())
