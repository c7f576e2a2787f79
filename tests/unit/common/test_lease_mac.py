"""MAC leases: the world obeys MacCommands only from the holder of the current lease's key."""

from __future__ import annotations

import time

import msgspec
import pytest

from common import keys
from common.auth import AuthError, RegistryIdentity, Session, Verifier, issue_session
from common.leasemac import (
    CommandMac,
    WorldBoxKeys,
    check_world_token,
    command_mac,
    mac_command,
    new_lease_key,
    open_key,
    seal_key,
)
from common.leases import LeaseBook
from common.messages import (
    AgentCommand,
    BundledCommand,
    Lease,
    MacCommand,
    SignedToken,
    decode,
    encode,
)

REALM, WORLD, AGENT = "lab", "w1", "k1"
CMD = keys.agent_cmd(REALM, WORLD, AGENT)
LEASE_KEY = keys.agent_lease(REALM, WORLD, AGENT)


class Setup:
    def __init__(self) -> None:
        self.registry = RegistryIdentity.generate()
        self.context = issue_session(self.registry, REALM, "ctx-arena", ["lease"])
        self.holder = issue_session(self.registry, REALM, "alice", ["control"])
        self.world = issue_session(self.registry, REALM, "engine-w1", ["world"])
        self.verifier = Verifier(self.registry.verify_key, REALM)
        self.book = LeaseBook(REALM, WORLD, self.verifier, WorldBoxKeys(lambda: self.world))
        self.k = new_lease_key()

    def lease(
        self, *, lease_id: str = "L1", start: float | None = None, end: float | None = None
    ) -> Lease:
        now = time.time()
        return Lease(
            lease_id=lease_id,
            world=WORLD,
            agent=AGENT,
            holder_user="alice",
            holder_session=self.holder.session_id,
            start=now - 1 if start is None else start,
            end=now + 60 if end is None else end,
            holder_key=seal_key(self.k, self.holder.keys.box_public_key),
            world_key=seal_key(self.k, self.world.keys.box_public_key),
            world_box=self.world.keys.box_public_key,
        )

    def grant(self, lease: Lease | None = None) -> Lease:
        return self.book.accept_lease(
            LEASE_KEY, self.context.seal(LEASE_KEY, lease or self.lease())
        )

    def command(
        self,
        *,
        key: bytes | None = None,
        seq: int = 1,
        lease_id: str = "L1",
        on: str = CMD,
        now: float | None = None,
        speeds: tuple[int, int] = (10, 10),
    ) -> bytes:
        message = AgentCommand(agent=AGENT, speeds=speeds)
        sent = time.time() if now is None else now
        return mac_command(key or self.k, on, lease_id, seq, message, sent)


@pytest.fixture
def s() -> Setup:
    return Setup()


def test_mac_command_from_the_holder_is_obeyed(s: Setup) -> None:
    s.grant()
    assert s.book.has_mac_key(AGENT)
    agent, command = s.book.check_command(CMD, s.command())
    assert agent == AGENT and command.speeds == (10, 10)
    # The holder opens its own copy of the same key.
    assert open_key(s.lease().holder_key or b"", s.holder.keys.box_key) == s.k


def test_signed_commands_still_work_under_a_mac_lease(s: Setup) -> None:
    s.grant()
    agent, _ = s.book.check_command(CMD, s.holder.seal(CMD, AgentCommand(agent=AGENT)))
    assert agent == AGENT


def test_wrong_key_is_refused(s: Setup) -> None:
    s.grant()
    with pytest.raises(AuthError, match="MAC does not match"):
        s.book.check_command(CMD, s.command(key=new_lease_key()))
    assert s.book.commands_refused == 1


def test_altered_body_is_refused(s: Setup) -> None:
    s.grant()
    good = decode(s.command(), MacCommand)
    altered = msgspec.structs.replace(
        good, body=encode(AgentCommand(agent=AGENT, speeds=(127, -127)))
    )
    with pytest.raises(AuthError, match="MAC does not match"):
        s.book.check_command(CMD, encode(altered))


def test_moved_to_another_agent_key_is_refused(s: Setup) -> None:
    s.grant()
    other = keys.agent_cmd(REALM, WORLD, "k2")
    # MACed for k1's key, put on k2's: k2 has no lease at all.
    with pytest.raises(AuthError):
        s.book.check_command(other, s.command())
    # Even if k2 had the same lease and key, the key expression is under the MAC.
    lease2 = msgspec.structs.replace(s.lease(), agent="k2")
    key2 = keys.agent_lease(REALM, WORLD, "k2")
    s.book.accept_lease(key2, s.context.seal(key2, lease2))
    with pytest.raises(AuthError, match="MAC does not match"):
        s.book.check_command(other, s.command())


def test_replayed_command_is_refused(s: Setup) -> None:
    s.grant()
    payload = s.command(seq=7)
    s.book.check_command(CMD, payload)
    with pytest.raises(AuthError, match="replayed"):
        s.book.check_command(CMD, payload)
    # Out of order but unseen is fine; a republished lease keeps the window.
    s.grant()
    s.book.check_command(CMD, s.command(seq=5))
    with pytest.raises(AuthError, match="replayed"):
        s.book.check_command(CMD, s.command(seq=7))


def test_stale_command_is_refused(s: Setup) -> None:
    s.book.started_at = 0.0  # a world running for long: only freshness refuses it
    s.grant()
    with pytest.raises(AuthError, match="off this service's clock"):
        s.book.check_command(CMD, s.command(now=time.time() - 120))


def test_command_sealed_before_the_world_started_is_refused(s: Setup) -> None:
    s.grant()
    s.book.check_command(CMD, s.command(seq=1))
    s.book.started_at = time.time() + 0.001  # the world restarted just now
    with pytest.raises(AuthError, match="sealed before this world started"):
        s.book.check_command(CMD, s.command(seq=2, now=time.time() - 0.5))
    s.book.check_command(CMD, s.command(seq=3, now=time.time() + 0.01))


def test_expired_lease_is_refused(s: Setup) -> None:
    now = time.time()
    s.grant(s.lease(start=now - 30, end=now - 1))
    with pytest.raises(AuthError, match="not in force"):
        s.book.check_command(CMD, s.command())


def test_command_under_an_older_lease_id_is_refused(s: Setup) -> None:
    s.grant()
    with pytest.raises(AuthError, match="not k1's current lease"):
        s.book.check_command(CMD, s.command(lease_id="L0"))


def test_a_kept_command_mac_signs_as_the_one_shot_function() -> None:
    k = new_lease_key()
    kept = CommandMac(k, CMD, "L1")
    for seq in (1, 2, 10**9):
        assert kept.tag(seq, 1.5, b"body") == command_mac(k, CMD, "L1", seq, 1.5, b"body")
    assert kept.tag(1, 1.5, b"body") != CommandMac(k, CMD + "x", "L1").tag(1, 1.5, b"body")
    assert kept.tag(1, 1.5, b"body") != CommandMac(k, CMD, "L2").tag(1, 1.5, b"body")


def test_a_lease_resealed_with_a_new_key_drops_the_old_one(s: Setup) -> None:
    s.grant()
    assert s.book.check_command(CMD, s.command(seq=1))[0] == AGENT
    old = s.k
    s.k = new_lease_key()  # same lease id, new key: the world must stop trusting the old one
    s.grant()
    with pytest.raises(AuthError, match="MAC does not match"):
        s.book.check_command(CMD, s.command(key=old, seq=2))
    assert s.book.check_command(CMD, s.command(seq=3))[0] == AGENT


def test_lease_without_a_key_for_the_world_refuses_mac(s: Setup) -> None:
    plain = msgspec.structs.replace(s.lease(), world_key=None, world_box=None, holder_key=None)
    s.grant(plain)
    assert not s.book.has_mac_key(AGENT)
    with pytest.raises(AuthError, match="no key for this world"):
        s.book.check_command(CMD, s.command())


def test_key_sealed_to_another_world_refuses_mac(s: Setup) -> None:
    stranger = issue_session(s.registry, REALM, "engine-w9", ["world"])
    lease = msgspec.structs.replace(
        s.lease(),
        world_key=seal_key(s.k, stranger.keys.box_public_key),
        world_box=stranger.keys.box_public_key,
    )
    s.grant(lease)
    with pytest.raises(AuthError, match="no key for this world"):
        s.book.check_command(CMD, s.command())


def test_world_without_identity_refuses_mac_but_obeys_signatures(s: Setup) -> None:
    book = LeaseBook(REALM, WORLD, s.verifier)
    book.accept_lease(LEASE_KEY, s.context.seal(LEASE_KEY, s.lease()))
    with pytest.raises(AuthError, match="no key for this world"):
        book.check_command(CMD, s.command())
    book.check_command(CMD, s.holder.seal(CMD, AgentCommand(agent=AGENT)))


def test_world_renewed_its_session_and_still_opens_earlier_leases(s: Setup) -> None:
    first = s.world
    s.book.box_keys.current()  # type: ignore[union-attr]
    s.world = issue_session(s.registry, REALM, "engine-w1", ["world"])
    lease = msgspec.structs.replace(s.lease(), world_key=seal_key(s.k, first.keys.box_public_key))
    s.grant(msgspec.structs.replace(lease, world_box=first.keys.box_public_key))
    s.book.check_command(CMD, s.command())


def _token(s: Setup, session: Session) -> SignedToken:
    return session.signed_token


def test_world_identity_token_is_checked(s: Setup) -> None:
    assert check_world_token(s.verifier, _token(s, s.world), WORLD).user == "engine-w1"
    # Without the 'world' permission: refused.
    with pytest.raises(AuthError, match="without the 'world' permission"):
        check_world_token(s.verifier, _token(s, s.holder), WORLD)
    # Signed by another registry (forged): refused.
    forger = RegistryIdentity.generate()
    fake = issue_session(forger, REALM, "engine-w1", ["world"])
    with pytest.raises(AuthError, match="not signed by this lab's registry"):
        check_world_token(s.verifier, fake.signed_token, WORLD)
    # A valid signature beside another token's bytes: the key sealed to is never the forger's.
    tampered = SignedToken(token=fake.signed_token.token, signature=s.world.signed_token.signature)
    try:
        token = check_world_token(s.verifier, tampered, WORLD)
    except AuthError:
        pass
    else:  # the verifier's cache answers with the token that signature was made for
        assert token.box_key == s.world.keys.box_public_key != fake.keys.box_public_key
    fresh = Verifier(s.registry.verify_key, REALM)
    with pytest.raises(AuthError, match="not signed by this lab's registry"):
        check_world_token(fresh, tampered, WORLD)
    # Expired: refused.
    old = issue_session(s.registry, REALM, "engine-w1", ["world"], ttl=1, now=time.time() - 10)
    with pytest.raises(AuthError, match="expired"):
        check_world_token(s.verifier, old.signed_token, WORLD)


def test_a_bundle_obeys_each_valid_command_and_refuses_forged_replayed_and_misfiled_ones(
    s: Setup,
) -> None:
    """check_bundle: each item checked as on its agent's own key; a refusal spares the others."""
    s.grant()
    obeyed: list[tuple[str, AgentCommand]] = []
    replayed = s.command(seq=2)
    other_key = keys.agent_cmd(REALM, WORLD, "k2")
    items = [
        BundledCommand(AGENT, s.command(seq=1, speeds=(1, 1))),  # valid
        BundledCommand(AGENT, s.command(key=new_lease_key(), seq=3)),  # forged: a guessed key
        BundledCommand(AGENT, replayed),  # valid the first time ...
        BundledCommand(AGENT, replayed),  # ... refused the second
        BundledCommand("k2", s.command(seq=4, on=other_key)),  # k2 has no lease here
        BundledCommand(AGENT, s.command(seq=5, on=other_key)),  # MACed for k2's key, filed as k1
        BundledCommand("bad name!", s.command(seq=6)),  # not an agent name
        BundledCommand(AGENT, b"\x93garbage"),
        BundledCommand(AGENT, s.command(seq=7, speeds=(7, 7))),  # valid, after all the others
    ]
    refused = s.book.check_bundle(items, lambda agent, command: obeyed.append((agent, command)))
    assert [(a, c.speeds) for a, c in obeyed] == [
        (AGENT, (1, 1)),
        (AGENT, (10, 10)),
        (AGENT, (7, 7)),
    ]
    assert len(refused) == 6, refused
    assert "MAC does not match" in refused[0] and "replayed" in refused[1]
    assert "k2 has no lease" in refused[2] and "MAC does not match" in refused[3]
    # The whole bundle replayed: nothing obeyed a second time.
    obeyed.clear()
    assert len(s.book.check_bundle(items, lambda a, c: obeyed.append((a, c)))) == len(items)
    assert obeyed == []


def test_a_bundle_under_an_expired_lease_is_refused_and_a_refusing_world_spares_the_rest(
    s: Setup,
) -> None:
    now = time.time()
    s.grant(s.lease(start=now - 30, end=now - 1))
    refused = s.book.check_bundle([BundledCommand(AGENT, s.command())], lambda a, c: None)
    assert len(refused) == 1 and "not in force" in refused[0]
    s.grant(s.lease(lease_id="L2"))

    def bridge_without_k1(agent: str, _command: AgentCommand) -> None:
        raise AuthError("not_found", f"no robot {agent} on this bridge")

    items = [BundledCommand(AGENT, s.command(seq=n, lease_id="L2")) for n in (1, 2)]
    refused = s.book.check_bundle(items, bridge_without_k1)
    assert len(refused) == 2 and all("no robot k1" in r for r in refused)
