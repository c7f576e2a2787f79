"""A kicked user loses everything at once: robot, queue, map edits, private messages.

Real router, registry, engine (with an identity: MAC leases) and agent context
processes. The admin kicks a user from the server; every service follows the
registry's signed revocation on its own.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from common import keys
from common.client.agent_client import DriveResult
from common.client.private_mail import PrivateText
from common.controller import Controller, Khepera
from common.messages import EditResult, ErrorReply, MoveItem, WorldEdit, decode
from tests.conftest import Router, wait_for
from tests.kit.agentkit import (
    WORLD,
    Poses,
    agent_user,
    start_agent_context,
    start_engine,
)
from tests.kit.lab import ProcessLab, module_lab

# One worker starts the module's lab once.
pytestmark = pytest.mark.one_worker


class Forward(Controller):
    period = 0.05

    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(15, 15)


@pytest.fixture(scope="module")
def lab(module_router: Router, tmp_path_factory: pytest.TempPathFactory) -> Iterator[ProcessLab]:
    """One lab for both tests: each kicks another user (alice, ida) and ends its requests."""
    with module_lab(module_router, tmp_path_factory.mktemp("lab")) as lab:
        lab.start_registry()
        start_engine(lab, identity=True)
        start_agent_context(lab, slot=30.0)
        yield lab


def _still_for(poses: Poses, agent: str, seconds: float) -> float:
    """How far ``agent`` moved during ``seconds`` (mm)."""
    start = poses.xy(agent).copy()
    time.sleep(seconds)  # a measurement window, not a wait for a condition
    return float(np.linalg.norm(poses.xy(agent) - start))


def test_a_kicked_user_loses_the_robot_the_queue_and_the_edits(lab: ProcessLab) -> None:
    realm = lab.router.realm
    with (
        lab.zsession() as z,
        agent_user(lab, "alice") as alice,
        agent_user(lab, "carol") as carol,
        lab.client("admin") as admin,
    ):
        poses = Poses(z, realm)
        done: list[DriveResult] = []
        t = threading.Thread(target=lambda: done.append(alice.drive("k0", Forward())))
        t.start()
        wait_for(lambda: alice.position_of_user("alice", "k0") == 0, 10, "alice's slot")
        start = poses.xy("k0").copy()
        wait_for(lambda: np.linalg.norm(poses.xy("k0") - start) > 10, 10, "k0 driven by alice")
        # carol waits behind alice; she is not kicked and must keep her place
        queued = carol.queue("k0", "remote")
        assert queued.position == 1

        kicked_at = time.monotonic()
        admin.kick_from_server("alice", "sharing her password")
        stopped_after = wait_for(
            lambda: (time.monotonic() - kicked_at) if _still_for(poses, "k0", 0.1) < 0.5 else None,
            5,
            "k0 to stop after the kick",
        )
        print(f"k0 stopped {stopped_after * 1000:.0f} ms after the kick (measured in 100 ms steps)")
        assert isinstance(stopped_after, float) and stopped_after < 1.5
        # alice's link keeps MACing commands with the keys she had: they are refused
        assert _still_for(poses, "k0", 1.0) < 1.0
        t.join(15)
        assert done and done[0].status == "cancelled", done
        assert "kicked" in done[0].reason, done[0].reason
        wait_for(lambda: carol.position_of_user("carol", "k0") == 0, 10, "carol's turn")
        carol.cancel_quietly(queued.request_id)


def test_a_kicked_instructor_cannot_edit_and_private_messages_are_dropped(lab: ProcessLab) -> None:
    realm = lab.router.realm
    edit_key = keys.world_edit(realm, WORLD)
    move = WorldEdit(op=MoveItem(id="rock1", x=800.0, y=900.0))
    with lab.client("ida") as ida, lab.client("bob") as bob, lab.client("admin") as admin:
        received: list[PrivateText] = []
        bob.on_private = received.append
        assert ida.send_private("bob", "before the kick")
        wait_for(lambda: len(received) == 1, 10, "bob to get ida's first message")
        assert ida.session is not None
        sealed_edit = ida.session.seal(edit_key, move)
        admin.kick_from_server("ida", "rogue edits")
        # her old session still signs; every service refuses it
        time.sleep(0.5)  # the revocation travels (pushed, not polled)
        replies = list(ida.z.get(edit_key, payload=ida.session.seal(edit_key, move), timeout=10))
        answer = decode(replies[0].ok.payload, (EditResult, ErrorReply))
        assert isinstance(answer, ErrorReply) and answer.code == "unauthenticated", answer
        assert "revoked" in answer.message
        replies = list(ida.z.get(edit_key, payload=sealed_edit, timeout=10))
        answer = decode(replies[0].ok.payload, (EditResult, ErrorReply))
        assert isinstance(answer, ErrorReply), answer
        # Sealed by her session as her client would, put straight on bob's inbox (the
        # registry would refuse her the key lookup now): bob's client must drop it.
        assert bob.session is not None
        inbox = keys.user_inbox(realm, "bob")
        late = ida._encrypt("bob", bob.session.keys.box_public_key, "after the kick")
        ida.z.put(inbox, ida.session.seal(inbox, late))
        time.sleep(0.5)  # a delivered message would arrive in milliseconds
        assert [m.text for m in received] == ["before the kick"]
