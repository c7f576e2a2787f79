"""Two sandboxes never share a uid, even when two runners of one host start them; a runner
that is not root limits a sandbox's processes from inside it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from services.runner.sandbox import Sandbox
from services.runner.sandbox_host import _give_uid, _take_uid
from services.runner.stage import SandboxLimits
from tests.conftest import REPO

HOLDER = """
import sys
from services.runner.sandbox_host import _take_uid
print(_take_uid(), flush=True)
sys.stdin.read()
"""


def test_a_uid_claimed_by_another_runner_is_not_handed_out_until_that_runner_dies() -> None:
    other = subprocess.Popen(
        [sys.executable, "-c", HOLDER],
        cwd=REPO,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert other.stdout is not None
        theirs = int(other.stdout.readline())
        mine = [_take_uid() for _ in range(3)]
        try:
            assert theirs not in mine
            assert len(set(mine)) == 3
        finally:
            for uid in mine:
                _give_uid(uid)
    finally:
        other.kill()  # a crash: no release call, the kernel drops its lock
        other.wait()
    # The lowest free uids again (a few spare, should other runners of this
    # machine take some meanwhile): the dead runner's uid is among them.
    again = [_take_uid() for _ in range(20)]
    try:
        assert theirs in again
    finally:
        for uid in again:
            _give_uid(uid)


def test_a_runner_that_is_not_root_limits_processes_inside_the_sandbox(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    # Not root (a container's user): the uid is shared with the runner and the pod's
    # other services, so a per-uid limit set outside refused the sandbox its namespaces.
    # The child sets it inside, where only the sandbox's own processes count (the fork
    # bomb then stops at the limit: tests/containers/test_podman_lab.py runs one so).
    limits = SandboxLimits()
    source = (
        b"from common.controller import Controller\n"
        b"class C(Controller):\n"
        b"    def do_work(self, robot): pass\n"
    )
    sandbox = Sandbox(source, limits=limits, on_command=lambda _c: None, on_output=lambda _l: None)
    monkeypatch.setattr(os, "geteuid", lambda: 10001)
    argv = sandbox.command_line(tmp_path, 5, 6)
    assert not any(a.startswith("--nproc") for a in argv)
    assert argv[-1] == f"nproc={limits.processes}"
    assert argv.index("prlimit") < argv.index("bwrap") < argv.index(f"nproc={limits.processes}")
