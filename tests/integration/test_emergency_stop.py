"""The arena host's emergency stop, with real processes: four deployed controllers end at once.

Registry, engine (with a service identity: MAC leases, as under ``wart up``),
runner and agent context are real ``wart`` processes; students and the host
are AgentClients in this process.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from common import keys
from common.client.agent_client import FINAL
from common.lab_errors import LabError
from common.messages import EmergencyStop, ErrorReply, OkReply, decode
from services.bridge.simbody import SimBody
from tests.conftest import REPO, Procs, Router, needs_sandbox, wait_for
from tests.kit.agentkit import (
    CTX,
    Motion,
    agent_user,
    agent_users,
    bridged_robot,
    deploy_running,
    start_agent_context,
    start_agent_lab,
    start_runner,
)
from tests.kit.lab import PASSWORD, ProcessLab, make_lab

pytestmark = [pytest.mark.one_worker, needs_sandbox, pytest.mark.shared_router]
FORWARD = (Path(__file__).with_name("controllers") / "forward.py").read_bytes()
ROBOTS = ("k0", "k1", "k2", "k3")


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> Iterator[ProcessLab]:
    lab = make_lab(router, procs, tmp_path)
    start_agent_lab(lab, identity=True, slot=120.0)
    yield lab


def test_the_host_stops_four_running_controllers_and_holds_the_arena(
    lab: ProcessLab, procs: Procs
) -> None:
    with (
        lab.zsession() as z,
        agent_users(lab, "alice", "bob", "carol", "ida") as (alice, bob, carol, ida),
    ):
        motion = Motion(z, lab.router.realm)
        owners = {"k0": alice, "k1": bob, "k2": carol, "k3": alice}
        rids = deploy_running(owners, FORWARD)
        wait_for(lambda: motion.moving(ROBOTS, 0.0), 30, "the four robots to drive")

        # A student without the right is refused, and nothing stops.
        with pytest.raises(LabError, match="only the owner of arena or a user with 'kick'"):
            bob.emergency_stop("I want my turn")
        assert motion.moving(ROBOTS, 0.0)

        pressed = time.monotonic()
        detail = ida.emergency_stop("a robot fell off the table")
        assert "4 controllers ended" in detail
        for agent, who in owners.items():
            status = who.wait_status(rids[agent], FINAL, timeout=20)
            assert status is not None, f"{agent}'s request never ended"
            assert status.status == "cancelled"
            assert status.reason == "emergency stop by ida: a robot fell off the table"
        wait_for(lambda: motion.at_rest_since(ROBOTS, pressed), 20, "every robot at rest")

        # Held: a new request waits (the arena says why), nothing starts.
        state = carol.state()
        assert state.estop.startswith("emergency stop by ida")
        queued = carol.queue("k2", "deploy", source=FORWARD, filename="forward.py")
        assert queued.start_eta is None
        assert carol.wait_status(queued.request_id, {"running"}, timeout=2.0) is None
        assert motion.at_rest_since(ROBOTS, pressed)

        # A replay of the host's stop request is refused (each envelope once).
        session = ida.client.session
        assert session is not None
        key = keys.ctx_request(lab.router.realm, CTX)
        captured = session.seal(key, EmergencyStop(engaged=False))
        first = [r.ok.payload for r in z.get(key, payload=captured, timeout=10) if r.ok]
        assert isinstance(decode(first[0], (OkReply, ErrorReply)), OkReply)  # released
        again = [r.ok.payload for r in z.get(key, payload=captured, timeout=10) if r.ok]
        replayed = decode(again[0], (OkReply, ErrorReply))
        assert isinstance(replayed, ErrorReply) and "replay" in replayed.message

        # Released: the held request starts and drives k2.
        assert carol.wait_status(queued.request_id, {"running"}, timeout=30)
        moved_from = time.monotonic()
        wait_for(lambda: motion.moving(["k2"], moved_from), 30, "k2 to drive again")
        motion.close()


def test_wart_arena_estop_and_release(lab: ProcessLab, procs: Procs) -> None:
    def arena(verb: str, user: str, *extra: str) -> tuple[int, str]:
        args = ["arena", *lab.net_args(), verb, "--context", CTX, "--user", user, *extra]
        proc = procs.start(f"arena-{verb}-{user}", args, env={"WART_PASSWORD": PASSWORD})
        return proc.popen.wait(60), proc.output()

    code, out = arena("estop", "bob")
    assert code == 1 and "only the owner of arena or a user with 'kick'" in out, out
    code, out = arena("estop", "ida", "--reason", "fire drill")
    assert code == 0 and "emergency stop: every robot stopped" in out, out
    with agent_user(lab, "carol") as carol:
        assert carol.state().estop == "emergency stop by ida: fire drill"
        code, out = arena("release", "ida")
        assert code == 0 and "released" in out, out
        assert carol.state().estop == ""


@pytest.fixture
def real_lab(router: Router, procs: Procs, tmp_path: Path) -> Iterator[tuple[ProcessLab, SimBody]]:
    """A real-robot arena: the Khepera bridge on an emulated robot (a real pty)."""
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    with (
        SimBody.from_map(REPO / "maps" / "empty.json", seed=5) as body,
        bridged_robot(lab, body, tmp_path / "khepera0", "500,500,0"),
    ):
        start_runner(lab)
        start_agent_context(lab, slot=120.0)
        yield lab, body


def test_the_emergency_stop_halts_a_real_robot_through_the_bridge(
    real_lab: tuple[ProcessLab, SimBody],
) -> None:
    lab, body = real_lab
    with agent_user(lab, "alice") as alice, agent_user(lab, "ida") as ida:
        queued = alice.queue("k1", "deploy", source=FORWARD, filename="forward.py")
        assert alice.wait_status(queued.request_id, {"running"}, timeout=60)
        wait_for(lambda: body.speed() != (0, 0), 30, "the emulated Khepera's motors to turn")
        ida.emergency_stop()
        final = alice.wait_status(queued.request_id, FINAL, timeout=20)
        assert final is not None and final.reason == "emergency stop by ida"
        wait_for(lambda: body.speed() == (0, 0), 5, "the bridge to halt the motors")
    # The bridge itself obeyed the world stop (not only the runner's last command).
    bridge = next(p for p in lab.procs.started if p.name == "bridge")
    wait_for(lambda: "emergency stop by ida: every robot stopped" in bridge.output(), 10, "its log")
