"""A command whose Zenoh session is still closing when it ends exits with its own code."""

from __future__ import annotations

import subprocess
import sys

from tests.kit.procs import REPO

COMMAND = """
import sys, zenoh
from common.service import close_session, exit_process
config = zenoh.Config()
config.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(config)
print("carol banned until 17:28 UTC")  # the command's result, not flushed yet
closed = close_session(session, timeout=0.0)  # a busy machine: the close outlives the wait
print("closed in time" if closed else "still closing")
END(3)
"""


def _run(end: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", COMMAND.replace("END", end)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_a_session_still_closing_at_the_end_does_not_abort_the_command() -> None:
    ended = _run("exit_process")
    assert (ended.returncode, ended.stderr) == (3, ""), ended
    assert ended.stdout.splitlines()[0] == "carol banned until 17:28 UTC"


def test_without_it_the_interpreters_shutdown_aborts() -> None:
    """What exit_process is for: Zenoh's thread comes back during the shutdown.

    A race: the close may still end before the wait, or before the shutdown reaches
    what it breaks (a clean exit 3). Tried up to five times, the abort must show at
    least once; if it never does, this Zenoh may no longer need exit_process."""
    outcomes = []
    for _ in range(5):
        ended = _run("sys.exit")
        if ended.returncode == -6:
            assert "exception not rethrown" in ended.stderr, ended
            return
        assert (ended.returncode, ended.stderr) == (3, ""), ended  # nothing else may happen
        outcomes.append((ended.stdout.splitlines() or ["(nothing printed)"])[-1])
    raise AssertionError(f"the shutdown never aborted in 5 tries: {outcomes}")
