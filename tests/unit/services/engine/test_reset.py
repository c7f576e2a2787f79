"""Reset (the editor's button): the world puts a robot back at its start pose, for whom it may.

The engine's own request handler, with real sealed envelopes and a real
lease from an agent context's session; only Zenoh's query is a stand-in.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from common import keys
from common.auth import AuthError, RegistryIdentity, Session, issue_session
from common.messages import EditResult, Lease, Message, ResetAgent, WorldEdit
from common.sim2d import maps
from common.world.leases import RESET_AFTER_STOP_S
from services.engine.service import EngineService, EngineSettings

REALM, AGENT = "lab", "k0"
MAPS = Path(__file__).parents[4] / "maps"


@dataclass
class Query:
    key_expr: str
    payload: bytes


class Lab:
    def __init__(self) -> None:
        self.registry = RegistryIdentity.generate()
        world = maps.load_map(MAPS / "empty.json", name="w1")
        self.world_name = world.name
        settings = EngineSettings(registry_key=bytes(self.registry.verify_key), maps_dir=MAPS)
        self.engine = EngineService(None, REALM, world, settings)  # type: ignore[arg-type]
        self.context = issue_session(self.registry, REALM, "ctx-arena", ["lease"])
        self.runner = issue_session(self.registry, REALM, "runner", ["run"])
        self.alice = issue_session(self.registry, REALM, "alice", ["deploy"])
        self.bob = issue_session(self.registry, REALM, "bob", ["deploy"])
        self.teacher = issue_session(self.registry, REALM, "teacher", ["edit_map"])
        self.agent = world.agents[0].id
        self.home = world.homes[self.agent]

    def lease_for_alice_run_by_the_runner(self, start: float = -1, end: float = 60) -> None:
        """Alice's run's lease, from ``start`` to ``end`` seconds from now (the context
        republishes it with an earlier end when the run stops)."""
        now = time.time()
        lease = Lease(
            lease_id="L1",
            world=self.world_name,
            agent=self.agent,
            holder_user="runner",
            holder_session=self.runner.session_id,
            start=now + start,
            end=now + end,
            requester_session=self.alice.session_id,
        )
        key = keys.agent_lease(REALM, self.world_name, self.agent)
        self.engine.leases.accept_lease(key, self.context.seal(key, lease))

    def reset(self, who: Session) -> Message:
        """Ask the engine as ``who``; its sim thread is this test's drain loop."""
        key = keys.world_edit(REALM, self.world_name)
        query = Query(key, who.seal(key, WorldEdit(op=ResetAgent(id=self.agent))))
        answer: list[Any] = []

        def ask() -> None:
            try:
                answer.append(self.engine._on_edit(query))  # type: ignore[arg-type]
            except AuthError as exc:
                answer.append(exc)

        asker = threading.Thread(target=ask)
        asker.start()
        while asker.is_alive():
            self.engine._drain()
            asker.join(0.01)
        self.engine._drain()
        return answer[0]

    def push_robot(self) -> None:
        x, y, h = self.home
        self.engine.world.move(self.agent, x + 100, y, h + 1.0)

    def assert_refused(self, reply: object, words: str) -> None:
        """The reset was refused as forbidden, saying ``words``; the robot stayed pushed."""
        assert isinstance(reply, AuthError) and reply.code == "forbidden"
        assert words in reply.message
        assert self.engine.world.pose_of(self.agent)[0] == pytest.approx(self.home[0] + 100)


@pytest.fixture
def lab() -> Lab:
    return Lab()


def test_nobody_may_reset_a_robot_nobody_holds(lab: Lab) -> None:
    lab.push_robot()
    lab.assert_refused(lab.reset(lab.alice), "reset it while your controller holds it")


def test_another_student_may_not_reset_a_robot_someone_holds(lab: Lab) -> None:
    lab.lease_for_alice_run_by_the_runner()
    lab.push_robot()
    lab.assert_refused(lab.reset(lab.bob), "someone else's controller")


def test_the_student_whose_upload_holds_it_resets_it_to_the_start_pose(lab: Lab) -> None:
    lab.lease_for_alice_run_by_the_runner()
    lab.push_robot()
    reply = lab.reset(lab.alice)
    assert isinstance(reply, EditResult), reply
    assert lab.engine.world.pose_of(lab.agent) == pytest.approx(lab.home, abs=1e-6)


def test_a_map_editor_may_reset_any_robot(lab: Lab) -> None:
    lab.push_robot()
    assert isinstance(lab.reset(lab.teacher), EditResult)
    assert lab.engine.world.pose_of(lab.agent) == pytest.approx(lab.home, abs=1e-6)


def test_an_expired_lease_no_longer_lets_its_student_reset(lab: Lab) -> None:
    lab.lease_for_alice_run_by_the_runner()
    key = keys.world_edit(REALM, lab.world_name)
    sealed = lab.alice.seal(key, WorldEdit(op=ResetAgent(id=lab.agent)))
    assert lab.engine.verifier is not None
    principal, _ = lab.engine.verifier.open(key, sealed, WorldEdit)
    assert lab.engine.leases.may_reset(principal, lab.agent) is None
    past_the_window = time.time() + 60 + RESET_AFTER_STOP_S + 5
    refused = lab.engine.leases.may_reset(principal, lab.agent, now=past_the_window)
    assert refused is not None and "not yours now" in refused


def test_stop_then_reset_the_student_may_put_back_the_robot_just_stopped(lab: Lab) -> None:
    lab.lease_for_alice_run_by_the_runner()
    lab.push_robot()
    lab.lease_for_alice_run_by_the_runner(start=-10, end=-0.5)  # Stop: ended just now
    refused = lab.reset(lab.bob)  # not bob's run: still refused
    assert isinstance(refused, AuthError) and "not yours now" in refused.message
    reply = lab.reset(lab.alice)
    assert isinstance(reply, EditResult), reply
    assert lab.engine.world.pose_of(lab.agent) == pytest.approx(lab.home, abs=1e-6)
