"""Agent contexts with real processes: queues, leases, remote and deployed controllers."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from common.client.agent_client import FINAL, AgentClient, DriveResult
from common.controller import Controller, Khepera
from common.lab_errors import NotFound
from common.messages import ControlQueued
from tests.conftest import Procs, Router, wait_for
from tests.integration.controllers.forward import Forward
from tests.kit.agentkit import (
    Poses,
    agent_user,
    start_agent_context,
    start_agent_lab,
    start_engine,
)
from tests.kit.lab import ProcessLab, make_lab, module_lab

# One worker starts the module's lab once.
pytestmark = [pytest.mark.one_worker, pytest.mark.shared_router]
CONTROLLERS = Path(__file__).with_name("controllers")


@pytest.fixture(scope="module")
def lab(module_router: Router, tmp_path_factory: pytest.TempPathFactory) -> Iterator[ProcessLab]:
    """One lab for the module's tests: each drives its own robots (k0, k1 or k2), and
    each leaves their queues empty and the context's settings as it found them."""
    with module_lab(module_router, tmp_path_factory.mktemp("lab")) as lab:
        start_agent_lab(lab)
        yield lab


def drives_away(poses: Poses, agent: str, mm: float, timeout: float, what: str) -> None:
    """Wait until ``agent`` is more than ``mm`` from where it is now.

    A condition, not a window: on a loaded machine a controller's first commands
    can take a while to reach the world after its slot starts.
    """
    start = poses.xy(agent)
    wait_for(lambda: float(np.linalg.norm(poses.xy(agent) - start)) > mm, timeout, what)


def moved(poses: Poses, agent: str, seconds: float) -> float:
    """How far ``agent`` moved (mm) over ``seconds`` of wall time from now."""
    before = poses.xy(agent)
    time.sleep(seconds)  # a measurement window, not a wait for a condition
    return float(np.linalg.norm(poses.xy(agent) - before))


def test_two_users_take_turns_and_see_their_position(lab: ProcessLab) -> None:
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
        drives_away(poses, "k0", 10, 15, "k0 driven by alice's controller")
        a.join(15)
        assert results["alice"].status == "finished", results["alice"]
        wait_for(lambda: bob.position_of_user("bob", "k0") == 0, 10, "bob's slot")
        drives_away(poses, "k0", 10, 15, "k0 driven by bob's controller in his slot")
        b.join(15)
        assert results["bob"].status == "finished", results["bob"]
        assert results["alice"].iterations > 10 and results["bob"].iterations > 10


def sealed_command(lab: ProcessLab, client: AgentClient, speeds: tuple[int, int]) -> None:
    """Put one AgentCommand for k0 sealed with ``client``'s session (it may hold no lease)."""
    from common import keys
    from common.messages import AgentCommand

    session = client.client.session
    assert session is not None
    key = keys.agent_cmd(lab.router.realm, "w1", "k0")
    client.client.z.put(key, session.seal(key, AgentCommand(agent="k0", speeds=speeds)))


def test_commands_without_the_current_lease_move_nothing(lab: ProcessLab) -> None:
    class Still(Controller):
        def do_work(self, robot: Khepera) -> None:
            robot.set_speeds(0, 0)

    with lab.zsession() as z, agent_user(lab, "alice") as alice, agent_user(lab, "bob") as bob:
        poses = Poses(z, lab.router.realm)
        done: list[DriveResult] = []
        t = threading.Thread(target=lambda: done.append(alice.drive("k0", Still())))
        t.start()
        wait_for(lambda: alice.position_of_user("alice", "k0") == 0, 10, "alice's slot")
        # bob holds no lease: his commands are refused while alice holds k0
        start = poses.xy("k0")
        for _ in range(20):
            sealed_command(lab, bob, (40, 40))
            time.sleep(0.02)  # pacing the flood, not waiting for a condition
        assert float(np.linalg.norm(poses.xy("k0") - start)) < 3
        t.join(15)
        assert done and done[0].status == "finished"
        # alice's lease has expired: her own commands move nothing now
        start = poses.xy("k0")
        for _ in range(20):
            sealed_command(lab, alice, (40, 40))
            time.sleep(0.02)
        assert float(np.linalg.norm(poses.xy("k0") - start)) < 3


def test_cancel_a_waiting_request(lab: ProcessLab) -> None:
    with agent_user(lab, "alice") as alice, agent_user(lab, "bob") as bob:
        done: list[DriveResult] = []
        t = threading.Thread(target=lambda: done.append(alice.drive("k1", Forward())))
        t.start()
        wait_for(lambda: alice.position_of_user("alice", "k1") == 0, 10, "alice's slot")
        queued = bob.queue("k1", "remote")
        assert queued.position == 1 and queued.start_eta is not None
        assert queued.start_eta > time.time()
        wait_for(lambda: bob.position_of_user("bob", "k1") == 1, 10, "bob waiting")
        bob.cancel(queued.request_id)
        status = bob.wait_status(queued.request_id, FINAL, timeout=5)
        assert status is not None and status.status == "cancelled"
        wait_for(lambda: bob.position_of_user("bob", "k1") is None, 10, "bob gone from the queue")
        # bob may not cancel alice's request; the owner may (and that stops it)
        rid = alice.statuses_of_user("alice")[0]
        with pytest.raises(Exception, match="not yours"):
            bob.cancel(rid)
        with agent_user(lab, "ida") as ida:
            ida.cancel(rid)
        t.join(10)
        assert done and done[0].status == "cancelled" and "ida" in done[0].reason


def test_robot_stops_when_the_controller_process_is_killed(lab: ProcessLab, procs: Procs) -> None:
    with lab.zsession() as z, agent_user(lab, "carol") as carol:
        poses = Poses(z, lab.router.realm)
        proc = procs.start(
            "control",
            [
                "control",
                str(CONTROLLERS / "forward.py"),
                "--context",
                "arena",
                "--agent",
                "k2",
                "--user",
                "alice",
                *lab.net_args(),
            ],
            env={"WART_PASSWORD": "correct horse"},
        )
        wait_for(
            lambda: carol.state() and carol.position_of_user("alice", "k2") == 0,
            20,
            "alice's wart control driving",
        )
        wait_for(lambda: moved(poses, "k2", 0.2) > 5, 10, "k2 moving")
        proc.kill9()
        killed = time.monotonic()
        # The engine's watchdog (300 ms) stops it; generous bound for a loaded machine.
        wait_for(lambda: moved(poses, "k2", 0.15) < 0.5, 5, "k2 stopped")
        assert time.monotonic() - killed < 2.0


def test_only_the_host_or_an_instructor_manages_the_context(lab: ProcessLab) -> None:
    from common.lab_errors import NotAllowed

    with agent_user(lab, "alice") as alice, agent_user(lab, "ida") as ida:
        for call in (
            lambda: alice.settings(slot_seconds=5),
            lambda: alice.settings(enabled=False),
            lambda: alice.stop_agent("k0"),
        ):
            with pytest.raises(NotAllowed, match="owner of arena"):
                call()
        assert "k1" in ida.settings(enabled=False, agent="k1")
        with pytest.raises(NotAllowed, match="disabled"):
            alice.queue("k1", "remote")
        try:
            ida.settings(enabled=True, agent="k1", slot_seconds=3)
            assert ida.state().slot_seconds == 3
            done: list[DriveResult] = []
            t = threading.Thread(target=lambda: done.append(alice.drive("k1", Forward())))
            t.start()
            wait_for(lambda: alice.position_of_user("alice", "k1") == 0, 10, "alice's slot")
            # Said in names, not the request's id.
            assert ida.stop_agent("k1", "demo over") == "stopping alice's controller on k1"
            t.join(10)
            assert done and done[0].status == "cancelled" and "demo over" in done[0].reason
        finally:  # the module's lab is shared: k1 enabled, the slot as the lab started it
            ida.settings(enabled=True, agent="k1", slot_seconds=2.5)


def test_a_context_started_before_its_world_says_so_and_then_serves_it(
    router: Router, procs: Procs, tmp_path: Path
) -> None:
    # `wart up` and `wart host` start a lab's services together: a context may
    # come up before its world, and must pick the world up when it appears.
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    start_agent_context(lab)
    with agent_user(lab, "alice") as alice:
        with pytest.raises(NotFound, match=r"world w1 has not answered yet .* try again"):
            alice.queue("k0", "remote")
        start_engine(lab)

        def queued() -> ControlQueued | None:
            try:
                return alice.queue("k0", "remote")
            except NotFound:
                return None

        assert wait_for(queued, 10, "the context to learn the world's robots")
