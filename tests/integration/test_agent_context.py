"""Agent contexts with real processes: queues, leases, remote and deployed controllers."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from common.agent_client import FINAL, AgentClient, DriveResult
from common.controller import Controller, Khepera
from common.messages import OutputLines
from tests.conftest import Procs, Router, wait_for
from tests.integration.agentkit import (
    Poses,
    agent_user,
    start_agent_context,
    start_engine,
    start_runner,
)
from tests.integration.labkit import Lab, make_lab

pytestmark = pytest.mark.integration
CONTROLLERS = Path(__file__).with_name("controllers")


class Forward(Controller):
    period = 0.05

    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(12, 12)


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> Iterator[Lab]:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    start_engine(lab)
    start_runner(lab)
    start_agent_context(lab)
    yield lab


def moved(poses: Poses, agent: str, seconds: float) -> float:
    """How far ``agent`` moved (mm) over ``seconds`` of wall time from now."""
    before = poses.xy(agent)
    time.sleep(seconds)  # a measurement window, not a wait for a condition
    return float(np.linalg.norm(poses.xy(agent) - before))


def test_two_users_take_turns_and_see_their_position(lab: Lab) -> None:
    with lab.zsession() as z, agent_user(lab, "alice") as alice, agent_user(lab, "bob") as bob:
        poses = Poses(z, lab.router.realm)
        results: dict[str, DriveResult] = {}
        waits: dict[str, list[int]] = {"alice": [], "bob": []}

        def drive(name: str, client: AgentClient) -> None:
            results[name] = client.drive(
                "k0", Forward(), on_wait=lambda p, _e: waits[name].append(p)
            )

        a = threading.Thread(target=drive, args=("alice", alice))
        a.start()
        wait_for(
            lambda: alice.latest_state and alice.position_of_user("alice", "k0") == 0,
            10,
            "alice's slot",
        )
        b = threading.Thread(target=drive, args=("bob", bob))
        b.start()
        wait_for(lambda: waits["bob"], 10, "bob told his position")
        assert waits["bob"][0] == 1
        assert moved(poses, "k0", 0.5) > 10, "alice's controller drives during her slot"
        a.join(15)
        assert results["alice"].status == "finished", results["alice"]
        wait_for(lambda: bob.position_of_user("bob", "k0") == 0, 10, "bob's slot")
        assert moved(poses, "k0", 0.5) > 10, "bob's controller drives during his slot"
        b.join(15)
        assert results["bob"].status == "finished", results["bob"]
        assert results["alice"].iterations > 10 and results["bob"].iterations > 10
