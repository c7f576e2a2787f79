"""The arena's emergency stop as every world checks it (LeaseBook.accept_stop)."""

from __future__ import annotations

import time

import pytest

from common import keys
from common.auth import AuthError, RegistryIdentity, Session, Verifier, issue_session
from common.messages import AgentCommand, Lease, WorldStop
from common.world.leases import LeaseBook

REALM, WORLD, AGENT = "lab", "w1", "k1"
STOP = keys.world_estop(REALM, WORLD)
CMD = keys.agent_cmd(REALM, WORLD, AGENT)
LEASE = keys.agent_lease(REALM, WORLD, AGENT)


class Setup:
    def __init__(self) -> None:
        self.registry = RegistryIdentity.generate()
        self.context = issue_session(self.registry, REALM, "ctx-arena", ["lease"])
        self.student = issue_session(self.registry, REALM, "alice", ["control", "kick"])
        self.book = LeaseBook(REALM, WORLD, Verifier(self.registry.verify_key, REALM))

    def lease(self) -> None:
        now = time.time()
        lease = Lease(
            lease_id="L1",
            world=WORLD,
            agent=AGENT,
            holder_user="alice",
            holder_session=self.student.session_id,
            start=now - 1,
            end=now + 60,
        )
        self.book.accept_lease(LEASE, self.context.seal(LEASE, lease))

    def command(self) -> bytes:
        return self.student.seal(CMD, AgentCommand(agent=AGENT, speeds=(10, 10)))

    def stop(self, engaged: bool, by: Session | None = None) -> bytes:
        reason = "emergency stop by ida" if engaged else ""
        return (by or self.context).seal(STOP, WorldStop(engaged=engaged, by="ida", reason=reason))


@pytest.fixture
def s() -> Setup:
    return Setup()


def test_a_stop_drops_every_lease_and_refuses_commands_until_released(s: Setup) -> None:
    s.lease()
    assert s.book.check_command(CMD, s.command())[0] == AGENT
    stop = s.book.accept_stop(STOP, s.stop(True))
    assert stop is not None and stop.engaged
    assert s.book.lease_of(AGENT) is None
    with pytest.raises(AuthError, match="emergency stop by ida"):
        s.book.check_command(CMD, s.command())
    with pytest.raises(AuthError, match="refused: emergency stop"):
        s.lease()
    released = s.book.accept_stop(STOP, s.stop(False))
    assert released is not None and not released.engaged
    s.lease()  # the context's next slot
    assert s.book.check_command(CMD, s.command())[0] == AGENT


def test_a_replayed_stop_has_no_effect_beyond_the_first(s: Setup) -> None:
    captured = s.stop(True)
    assert s.book.accept_stop(STOP, captured) is not None
    with pytest.raises(AuthError, match="replay"):
        s.book.accept_stop(STOP, captured)
    assert s.book.accept_stop(STOP, s.stop(False)) is not None
    with pytest.raises(AuthError, match="replay"):  # it cannot stop the arena again
        s.book.accept_stop(STOP, captured)
    assert s.book.stopped == ""


def test_a_late_stop_cannot_undo_a_newer_release(s: Setup) -> None:
    assert s.book.accept_stop(STOP, s.stop(True)) is not None
    late = s.stop(True)  # a republication, delivered after the release below
    assert s.book.accept_stop(STOP, s.stop(False)) is not None
    assert s.book.accept_stop(STOP, late) is None  # sealed before the release: ignored
    assert s.book.stopped == ""


def test_only_a_principal_with_lease_stops_a_world(s: Setup) -> None:
    with pytest.raises(AuthError, match="lease"):
        s.book.accept_stop(STOP, s.stop(True, by=s.student))
    assert s.book.stopped == ""


def test_a_stop_sealed_before_the_world_started_is_refused(s: Setup) -> None:
    captured = s.stop(True)
    restarted = LeaseBook(REALM, WORLD, Verifier(s.registry.verify_key, REALM))
    restarted.started_at = time.time() + 1  # (a restart after the capture)
    with pytest.raises(AuthError, match="before this world started"):
        restarted.accept_stop(STOP, captured)
