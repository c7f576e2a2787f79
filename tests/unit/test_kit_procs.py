"""The kit's processes stop with the test that started them, even one killed outright.

A CI job's time-out or a `kill -9` runs no teardown; a lab left serving would hold
its ports and a core for the rest of the machine's day (seen: a whole lab of a
killed run still ticking 34 minutes later).
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import psutil

from tests.kit.lab import REPO
from tests.kit.waits import wait_for

TEST_PROCESS = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from tests.kit.lab import Procs, free_port
    procs = Procs(Path(sys.argv[1]))
    router = procs.start("router", ["router", "--listen", f"tcp/127.0.0.1:{free_port()}",
                                    "--no-multicast-scouting"])
    print(router.popen.pid, flush=True)
    time.sleep(600)
    """
)


def test_a_test_process_killed_outright_takes_its_services_with_it(tmp_path) -> None:
    test = subprocess.Popen(
        [sys.executable, "-c", TEST_PROCESS, str(tmp_path)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert test.stdout is not None
        router = psutil.Process(int(test.stdout.readline()))
        assert router.is_running()
        test.kill()  # no teardown runs
        test.wait(10)
        wait_for(
            lambda: not router.is_running() or router.status() == psutil.STATUS_ZOMBIE,
            30,
            "the router to stop with its test",
        )
    finally:
        test.kill()
