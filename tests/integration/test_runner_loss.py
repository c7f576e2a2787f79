"""A runner cut off for a moment keeps its students' runs; a runner that crashed ends them.

The runner is a client of its own router, meshed with the lab's (as on a
second host). Killing that router takes the runner's liveliness token away
from the agent context while the runner and its sandboxes run on: the
context asks the runner what it still runs rather than trusting the token,
so the student's controller goes on. A runner killed and restarted runs
nothing of before: the student is told why their controller ended.

The other far end of a run, its world, frozen mid-slot (a swapping or hung
host): the student is told their robot's readings stopped, and when they
return, instead of a controller that "runs" on a robot that neither reads
nor moves.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest

from common.keys import AliveKind
from tests.conftest import Proc, Procs, Router, free_port, needs_sandbox, wait_for
from tests.kit.agentkit import (
    WORLD,
    start_agent_context,
    start_deploy,
    start_engine,
    start_runner,
)
from tests.kit.lab import ProcessLab, make_lab
from tests.kit.procs import start_router

pytestmark = needs_sandbox
CONTROLLERS = Path(__file__).with_name("controllers")
RUNNER_END = "the lab's runner runner stopped"


class RunnerHost:
    """The runner on its own router ("a second host"), each restartable."""

    def __init__(self, lab: ProcessLab) -> None:
        self.lab = lab
        self.port = free_port()
        self.router = self.start_router()
        self.runner = self.start_runner()

    def start_router(self) -> Proc:
        router = start_router(
            self.lab.procs,
            self.lab.realm,
            "router-b",
            port=self.port,
            connect=[self.lab.router.endpoint],
            log_name="router-b",
        )
        return router.proc

    def start_runner(self) -> Proc:
        # A client of router-b, as a runner on its own host is of its host's router.
        router_b = Router(self.lab.realm, self.port, self.router)
        return replace(self.lab, router=router_b).start_runner()


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> Iterator[ProcessLab]:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    start_engine(lab)
    yield lab


def deploy(lab: ProcessLab) -> Proc:
    proc = start_deploy(lab, CONTROLLERS / "forward.py", "k2", "bob")
    wait_for(lambda: "running on k2" in proc.output(), 60, "bob's controller running")
    return proc


def test_a_runner_cut_off_by_its_router_keeps_the_run_and_a_crashed_one_ends_it(
    lab: ProcessLab, procs: Procs
) -> None:
    host = RunnerHost(lab)
    context = start_agent_context(lab, slot=60.0)
    student = deploy(lab)

    # Its router dies and comes back: the runner and its sandbox live on, but for a
    # moment every token of that side is gone from the context's view.
    host.router.kill9()
    time.sleep(1.0)
    host.router = host.start_router()
    lab.wait_alive(AliveKind.RUNNER, "runner", host.runner)
    wait_for(
        lambda: "it was a blip" in context.output() or RUNNER_END in student.output(),
        30,
        "the context to ask the runner what it still runs",
    )
    assert RUNNER_END not in student.output(), student.output()
    assert student.popen.poll() is None, "bob's deploy ended at a router blip"

    # Now the runner itself crashes and is restarted: bob's controller is gone,
    # and he is told why, without waiting for his slot's end.
    host.runner.kill9()
    crashed = time.monotonic()
    host.runner = host.start_runner()
    assert student.popen.wait(30) is not None
    assert RUNNER_END in student.output(), student.output()
    assert time.monotonic() - crashed < 30, "told within the check, not at the slot's end"
    assert "it came back without them" in context.output(), context.output()


def test_a_frozen_world_is_said_to_the_student_and_so_is_its_return(lab: ProcessLab) -> None:
    start_runner(lab)
    start_agent_context(lab, slot=120.0)
    engine = next(p for p in lab.procs.started if p.name == "engine")
    student = start_deploy(lab, CONTROLLERS / "forward.py", "k2", "bob")
    wait_for(lambda: "controller Forward started" in student.output(), 60, "bob's controller")
    assert "no readings" not in student.output(), student.output()

    os.kill(engine.popen.pid, signal.SIGSTOP)
    try:
        wait_for(
            lambda: "[runner] no readings from k2 for 5 s" in student.output(),
            30,
            "bob to be told his robot's readings stopped",
        )
    finally:
        os.kill(engine.popen.pid, signal.SIGCONT)
    said = student.output()
    assert f"world {WORLD} sends none" in said and "tell the lab's staff" in said, said

    wait_for(
        lambda: "[runner] readings from k2 again after" in student.output(),
        30,
        "bob to be told the readings are back",
    )
    assert student.popen.poll() is None, "the run ended instead of going on"
