"""A controller whose do_work never returns is told so, with its file and line (issue 38).

In the real sandbox first (the runner's side), then end to end through an agent
context, a runner and an engine: the run's end notice and its recording say the same.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.client.agent_client import FINAL
from common.controller import KheperaState
from common.recording import read_recording, summarize
from services.runner.sandbox import Sandbox, SandboxLimits
from tests.conftest import Procs, Router, needs_sandbox, wait_for
from tests.kit.agentkit import (
    CTX,
    agent_user,
    start_agent_lab,
)
from tests.kit.lab import ProcessLab, make_lab

# Line 8 is the loop: what the student is told.
SPIN = b"""from common.controller import Controller, Khepera


class Spin(Controller):
    period = 0.05

    def do_work(self, robot: Khepera) -> None:
        while True:
            pass
"""

SLEEPY = b"""import time

from common.controller import Controller


class Sleepy(Controller):
    def do_work(self, robot):
        self.wait_for_ever()

    def wait_for_ever(self):
        while True:
            time.sleep(0.5)
"""


def _run(source: bytes, slot: float, **limits: float) -> tuple[str, float]:
    output: list[str] = []
    sandbox = Sandbox(
        source,
        filename="spin.py",
        limits=SandboxLimits(**limits),  # type: ignore[arg-type]
        on_command=lambda _c: None,
        on_output=output.append,
    )
    started = time.monotonic()
    sandbox.start(slot)
    sandbox.send_state(KheperaState(time=1.0))
    assert sandbox.wait(slot + 15), "the sandbox did not end"
    return sandbox.exit_reason, time.monotonic() - started


@needs_sandbox
def test_a_do_work_stuck_for_its_whole_slot_is_told_its_line() -> None:
    reason, took = _run(SPIN, slot=4.0)
    match = re.fullmatch(
        r"hung: do_work did not return for (\d+) s; it was at spin\.py:(\d+) \(in do_work\)",
        reason,
    )
    assert match, reason
    assert int(match.group(2)) in (8, 9)  # the `while True:` line or its `pass`
    assert int(match.group(1)) >= 2
    assert took < 4.0 + 3.0


@needs_sandbox
def test_a_configured_hang_time_ends_it_early_naming_the_inner_function() -> None:
    reason, took = _run(SLEEPY, slot=60.0, hang_seconds=1.5)
    assert reason.startswith("hung: do_work did not return for 2 s") or reason.startswith(
        "hung: do_work did not return for 1 s"
    ), reason
    assert "spin.py:12 (in wait_for_ever)" in reason
    assert took < 15.0  # not the 60 s slot


HUNG = re.compile(
    r"hung: do_work did not return for \d+ s; it was at spin\.py:(8|9) \(in do_work\)"
)


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> Iterator[ProcessLab]:
    lab = make_lab(router, procs, tmp_path)
    start_agent_lab(lab, slot=4.0)
    yield lab


@needs_sandbox
def test_the_end_notice_and_the_recording_say_where_it_hung(lab: ProcessLab) -> None:
    with agent_user(lab, "alice") as alice:
        queued = alice.queue("k1", "deploy", source=SPIN, filename="spin.py")
        final = alice.wait_status(queued.request_id, FINAL, timeout=40)
        assert final is not None and final.status == "finished", final
        assert HUNG.fullmatch(final.reason), final.reason  # not "its slot ended"
    path = lab.state / "rooms" / "recordings" / CTX / "alice" / f"{queued.request_id}.mcap"
    wait_for(path.with_name(f"{queued.request_id}.summary.json").exists, 20, "the recording")
    summary = summarize(read_recording(path))
    assert HUNG.fullmatch(summary.reason), summary.reason
