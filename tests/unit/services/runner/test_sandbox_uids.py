"""Two sandboxes never share a uid, even when two runners of one host start them."""

from __future__ import annotations

import subprocess
import sys

from services.runner.sandbox_host import _give_uid, _take_uid
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
