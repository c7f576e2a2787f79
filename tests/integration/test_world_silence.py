"""A student whose robot's readings stop is told so, and told again when they return.

The world (here the engine) is frozen mid-slot, as a swapping or hung host
would freeze it: its controller would otherwise "run" on while the robot
neither reads nor moves, with nothing on the student's screen to say why.
"""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest

from services.runner.sandbox import sandbox_problem
from tests.conftest import Procs, Router, wait_for
from tests.integration.agentkit import WORLD, start_agent_context, start_engine, start_runner
from tests.integration.labkit import PASSWORD, Lab, make_lab

pytestmark = [
    pytest.mark.integration,
    pytest.mark.skipif(sandbox_problem() is not None, reason=f"no sandbox: {sandbox_problem()}"),
]
FORWARD = Path(__file__).with_name("controllers") / "forward.py"


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> Iterator[Lab]:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    start_runner(lab)
    start_agent_context(lab, slot=120.0)
    yield lab


def test_a_frozen_world_is_said_to_the_student_and_so_is_its_return(lab: Lab, procs: Procs) -> None:
    engine = start_engine(lab)
    student = procs.start(
        "deploy",
        [
            "deploy",
            str(FORWARD),
            "--context",
            "arena",
            "--agent",
            "k2",
            "--user",
            "bob",
            *lab.net_args(),
        ],
        env={"WART_PASSWORD": PASSWORD},
    )
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
