"""The real-robot path end to end: an example controller drives the emulated Khepera
through an agent context, the bridge and the serial protocol, in both run modes.

The emulated robot (Sim2D-backed, on a real pty) runs in this test process so
the test can see where its body really is; the bridge, registry, runner and
agent context are real processes on a real router. The agent context is the
same one that serves simulated worlds: it cannot tell the difference.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.client.agent_client import FINAL
from common.controller import load_controller
from services.bridge.simbody import SimBody
from tests.conftest import REPO, Procs, Router, needs_sandbox, wait_for
from tests.kit.agentkit import agent_user, bridged_robot, start_agent_context, start_runner
from tests.kit.lab import ProcessLab, make_lab

pytestmark = needs_sandbox
EXAMPLE = REPO / "examples" / "01_braitenberg.py"


@pytest.fixture
def body() -> Iterator[SimBody]:
    with SimBody.from_map(REPO / "maps" / "empty.json", seed=5) as sim:
        yield sim


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path, body: SimBody) -> Iterator[ProcessLab]:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    with bridged_robot(lab, body, tmp_path / "khepera0", "500,500,0"):
        start_runner(lab)
        start_agent_context(lab, slot=3.0)
        yield lab


def travelled(body: SimBody, since: tuple[float, float, float]) -> float:
    x, y, _ = body.pose()
    return math.hypot(x - since[0], y - since[1])


def test_example_controller_drives_the_emulated_robot_in_both_run_modes(
    lab: ProcessLab, body: SimBody
) -> None:
    with agent_user(lab, "alice") as alice:
        # remote: the student's process runs the controller, over Zenoh, to the bridge
        start = body.pose()
        result = alice.drive("k1", load_controller(EXAMPLE))
        assert result.status == "finished" and result.iterations > 10, result
        remote = travelled(body, start)
        # deploy: the same file, uploaded and run in the runner's sandbox
        start = body.pose()
        queued = alice.queue("k1", "deploy", source=EXAMPLE.read_bytes(), filename=EXAMPLE.name)
        final = alice.wait_status(queued.request_id, FINAL, timeout=30)
        assert final is not None and final.status == "finished", final
        deployed = travelled(body, start)
    # Braitenberg cruises forward: in a 3 s slot the robot covers well over 50 mm.
    assert remote > 50 and deployed > 50, (remote, deployed)
    # And once the slots are over, the lease has ended: the bridge halted the motors.
    wait_for(lambda: body.speed() == (0, 0), 5, "the motors to stop after the last slot")
