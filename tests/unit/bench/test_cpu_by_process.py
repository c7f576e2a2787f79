"""bench/cpu_by_process.py counts a child's CPU under the child's kind."""

from __future__ import annotations

import subprocess
import sys
import time

from bench.cpu_by_process import Sampler, kind_of

# Burns one second of its own CPU time, however busy the machine is.
BURN = "import time\nwhile time.process_time() < 1.0:\n    pass\n"


def test_a_busy_child_is_counted_under_its_kind() -> None:
    sampler = Sampler(period_s=0.1)
    sampler.start()
    child = subprocess.Popen([sys.executable, "-c", BURN])
    try:
        deadline = time.monotonic() + 5
        while kind_of(child.pid) is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert kind_of(child.pid) == "python -c import time while time.process"
        assert child.wait(timeout=120) == 0
    finally:
        child.kill()
        sampler.stop()
    burned = sampler.by_kind["python -c import time while time.process"] / 100
    # Counted from its first sample on: at most a sample's worth (0.1 s) before it is lost.
    assert 0.6 <= burned <= 1.3, sampler.by_kind
    assert sampler.busy_ticks > 0


def test_a_process_gone_has_no_kind() -> None:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    assert kind_of(child.pid) is None
