"""bench/cpu_by_process.py counts a child's CPU under the child's kind."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from bench import cpu_by_process
from bench.cpu_by_process import Sampler, kind_of

# One worker: the sampler counts by kind of process, and these tests' children share one.
pytestmark = pytest.mark.one_worker

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
    # Counted from its start; what it spent after the last sample (0.1 s) is lost.
    assert 0.85 <= burned <= 1.3, sampler.by_kind
    assert sampler.busy_ticks > 0


# Burns one second, then lives on idle long enough to be sampled.
BURN_THEN_IDLE = BURN + "time.sleep(3.0)\n"


def test_a_process_started_after_the_sampler_is_counted_from_its_start() -> None:
    # A sample every 2 s: the child's burst is over by the first sample that sees it,
    # and it was all spent while the command ran (a service's imports, a page's load).
    sampler = Sampler(period_s=2.0)
    sampler.start()
    child = subprocess.Popen([sys.executable, "-c", BURN_THEN_IDLE])
    try:
        assert child.wait(timeout=120) == 0
    finally:
        child.kill()
        sampler.stop()
    burned = sum(v for k, v in sampler.by_kind.items() if "time.process" in k) / 100
    assert 0.9 <= burned <= 1.3, sampler.by_kind


def test_a_process_running_before_the_sampler_is_counted_from_then() -> None:
    child = subprocess.Popen([sys.executable, "-c", BURN_THEN_IDLE])
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # until its burst is (about) over
            with open(f"/proc/{child.pid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            if int(fields[11]) + int(fields[12]) >= 95:
                break
            time.sleep(0.02)
        else:
            raise AssertionError("the child never burned its second")
        sampler = Sampler(period_s=0.1)
        sampler.start()
        assert child.wait(timeout=120) == 0
    finally:
        child.kill()
    sampler.stop()
    burned = sum(v for k, v in sampler.by_kind.items() if "time.process" in k) / 100
    assert burned <= 0.2, sampler.by_kind


def test_a_forked_child_is_counted_under_the_kind_it_renames_itself_to(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Chromium's renderers are forked by its zygote and keep its command line until they
    # retitle themselves: their CPU is the renderer's, not the zygote's.
    child = subprocess.Popen([sys.executable, "-c", BURN_THEN_IDLE])
    sampled = {"n": 0}

    def kind_of_renamed(pid: int) -> str | None:
        if pid != child.pid:
            return None
        sampled["n"] += 1
        return "chromium zygote" if sampled["n"] == 1 else "chromium renderer"

    monkeypatch.setattr(cpu_by_process, "kind_of", kind_of_renamed)
    sampler = Sampler(period_s=0.1)
    sampler.start()
    try:
        assert child.wait(timeout=120) == 0
    finally:
        child.kill()
        sampler.stop()
    assert sampled["n"] >= 2
    assert sampler.by_kind["chromium renderer"] >= 90, sampler.by_kind
    assert sampler.by_kind["chromium zygote"] <= 20, sampler.by_kind


def test_a_process_gone_has_no_kind() -> None:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    assert kind_of(child.pid) is None
