"""MAC leases: the world obeys MacCommands only from the holder of the current lease's key."""

from __future__ import annotations

import time

import msgspec
import numpy as np
import pytest

from common import keys
from common.auth import AuthError, RegistryIdentity, Session, Verifier, issue_session
from common.messages import (
    MAC_ITEM_BYTES,
    MAC_ITEM_COUNTERS,
    MAC_ITEM_DTYPE,
    MAC_ITEM_SPEEDS,
    MAC_ITEM_STRUCT,
    AgentCommand,
    BundledCommand,
    Lease,
    MacCommand,
    MacCommandBundle,
    MessageError,
    SignedToken,
    WorldStop,
    decode,
    encode,
)
from common.world.leasemac import (
    CommandMac,
    WorldBoxKeys,
    check_world_token,
    command_mac,
    item_mac,
    mac_command,
    new_lease_key,
    open_key,
    seal_key,
)
from common.world.leases import LeaseBook
from tests.kit.leases import mac_lease

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
        return mac_lease(
            self.k,
            self.holder,
            self.world,
            lease_id=lease_id,
            world_name=WORLD,
            agent=AGENT,
            start=now - 1 if start is None else start,
            end=now + 60 if end is None else end,
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


# -- MacCommandBundle: a swarm's commands in arrays, each item MACed on its own

K2_CMD = keys.agent_cmd(REALM, WORLD, "k2")
K2_LEASE = keys.agent_lease(REALM, WORLD, "k2")


def record(
    seq: int,
    *,
    sent_at: float | None = None,
    speeds: tuple[int, int] | None = (10, 10),
    counters: tuple[int, int] | None = None,
    flags: int | None = None,
) -> bytes:
    """One item's record, as SwarmTick.send packs it."""
    if flags is None:
        flags = (0 if speeds is None else MAC_ITEM_SPEEDS) | (
            0 if counters is None else MAC_ITEM_COUNTERS
        )
    return MAC_ITEM_STRUCT.pack(
        seq,
        time.time() if sent_at is None else sent_at,
        flags,
        *(speeds or (0, 0)),
        *(counters or (0, 0)),
    )


def mac_bundle(items: list[tuple[str, bytes, bytes]]) -> MacCommandBundle:
    """A bundle of (agent, record, mac) items, through the wire and back."""
    bundle = MacCommandBundle(
        agents=[a for a, _, _ in items],
        items=b"".join(r for _, r, _ in items),
        macs=b"".join(m for _, _, m in items),
    )
    return decode(encode(bundle), MacCommandBundle)


def test_a_mac_bundle_round_trips_and_numpy_reads_its_records() -> None:
    mac = CommandMac(new_lease_key(), CMD, "L1")
    records = [record(7, sent_at=12.5, speeds=(-3, 4)), record(8, counters=(-(2**31), 5))]
    original = MacCommandBundle(
        agents=["k1", "k2"], items=b"".join(records), macs=b"".join(map(mac.item_tag, records))
    )
    assert decode(encode(original), MacCommandBundle) == original
    assert len(records[0]) == MAC_ITEM_BYTES == 29
    rows = np.frombuffer(original.items, MAC_ITEM_DTYPE)  # the documented layout
    assert rows["seq"].tolist() == [7, 8] and rows["sent_at"][0] == 12.5
    assert rows["flags"].tolist() == [MAC_ITEM_SPEEDS, MAC_ITEM_SPEEDS | MAC_ITEM_COUNTERS]
    assert rows["speeds"][0].tolist() == [-3, 4] and rows["counters"][1].tolist() == [-(2**31), 5]
    # An item's MAC is never a MacCommand's over the same bytes (personalised apart).
    assert mac.item_tag(records[0]) != mac.tag(7, 12.5, records[0][16:])
    assert item_mac(s_key := new_lease_key(), CMD, "L1", records[0]) == CommandMac(
        s_key, CMD, "L1"
    ).item_tag(records[0])


def two_holders(s: Setup) -> tuple[CommandMac, CommandMac, Session]:
    """alice holds k1 (key s.k), bob holds k2 (its own key); their item MACs."""
    s.grant()
    bob = issue_session(s.registry, REALM, "bob", ["control"])
    k2 = new_lease_key()
    now = time.time()
    lease = mac_lease(
        k2, bob, s.world, lease_id="L2", world_name=WORLD, agent="k2", start=now - 1, end=now + 60
    )
    s.book.accept_lease(K2_LEASE, s.context.seal(K2_LEASE, lease))
    return CommandMac(s.k, CMD, "L1"), CommandMac(k2, K2_CMD, "L2"), bob


def test_a_mac_bundle_obeys_its_good_items_and_refuses_each_bad_one_alone(s: Setup) -> None:
    alice, bob, _ = two_holders(s)
    obeyed: list[tuple[str, AgentCommand]] = []

    def item(mac: CommandMac, agent: str, rec: bytes) -> tuple[str, bytes, bytes]:
        return agent, rec, mac.item_tag(rec)

    good = item(alice, AGENT, record(1, speeds=(1, 1)))
    tampered = bytearray(record(2, speeds=(2, 2)))
    tag = alice.item_tag(bytes(tampered))
    tampered[17] = 127  # the left speed, after the MAC was made
    guessed = CommandMac(new_lease_key(), CMD, "L1")
    old_lease = CommandMac(s.k, CMD, "L0")  # the right key, another lease id
    items = [
        good,
        (AGENT, bytes(tampered), tag),  # altered in flight
        item(guessed, AGENT, record(3)),  # forged: a guessed key
        good,  # replayed within the same bundle
        item(bob, AGENT, record(4)),  # bob's key, for alice's robot: another agent's lease
        item(alice, "k2", record(5)),  # alice's key, filed under bob's robot
        item(CommandMac(s.k, K2_CMD, "L1"), AGENT, record(6)),  # MACed for k2's key
        item(old_lease, AGENT, record(7)),
        item(alice, "k3", record(8)),  # k3 has no lease here
        item(alice, AGENT, record(9, sent_at=time.time() + 100)),  # 100 s ahead
        item(alice, AGENT, record(10, sent_at=s.book.started_at - 1)),  # before the world started
        item(alice, AGENT, record(11, flags=0x80)),  # MACed, but flags nobody knows
        item(bob, "k2", record(12, speeds=(5, 5))),  # bob's own robot: obeyed
        item(alice, AGENT, record(13, speeds=None, counters=(7, 8))),  # counters only: obeyed
    ]
    refused = s.book.check_mac_bundle(mac_bundle(items), lambda a, c: obeyed.append((a, c)))
    assert [(a, c.speeds, c.counters) for a, c in obeyed] == [
        (AGENT, (1, 1), None),
        ("k2", (5, 5), None),
        (AGENT, None, (7, 8)),
    ]
    assert len(refused) == len(items) - 3, refused
    expected = [
        "MAC does not match",  # tampered
        "MAC does not match",  # guessed key
        "replayed",
        "MAC does not match",  # bob's key on k1
        "MAC does not match",  # alice's key on k2
        "MAC does not match",  # moved from k2's key
        "MAC does not match",  # another lease id
        "no lease",
        "off this world's clock",
        "before this world started",
        "unknown command flags",
    ]
    for why, got in zip(expected, refused, strict=True):
        assert why in got, (why, got)
    assert s.book.commands_accepted == 3 and s.book.commands_refused == len(items) - 3
    # The whole bundle replayed: nothing obeyed a second time.
    obeyed.clear()
    assert len(s.book.check_mac_bundle(mac_bundle(items), lambda a, c: obeyed.append((a, c)))) == (
        len(items)
    )
    assert obeyed == []


def test_a_mac_bundle_under_an_expired_or_revoked_lease_or_an_emergency_stop_is_refused(
    s: Setup,
) -> None:
    alice, bob, bob_session = two_holders(s)
    now = time.time()
    s.grant(s.lease(start=now - 30, end=now - 1))  # alice's lease on k1 ended
    obeyed: list[str] = []
    items = [
        (AGENT, r := record(1), alice.item_tag(r)),
        ("k2", r2 := record(2), bob.item_tag(r2)),
    ]
    refused = s.book.check_mac_bundle(mac_bundle(items), lambda a, c: obeyed.append(a))
    assert obeyed == ["k2"] and len(refused) == 1 and "not in force" in refused[0]
    # Bob's session revoked: his lease is dropped, his next item refused.
    assert s.book.revoke_session(bob_session.session_id) == ["k2"]
    items = [("k2", r := record(3), bob.item_tag(r))]
    refused = s.book.check_mac_bundle(mac_bundle(items), lambda a, c: obeyed.append(a))
    assert obeyed == ["k2"] and "no lease" in refused[0]
    # A new lease for alice, then an emergency stop: everything refused.
    s.grant(s.lease(lease_id="L3"))
    fresh = CommandMac(s.k, CMD, "L3")
    stop = s.context.seal(keys.world_estop(REALM, WORLD), WorldStop(engaged=True, by="ctx"))
    s.book.accept_stop(keys.world_estop(REALM, WORLD), stop)
    items = [(AGENT, r := record(4), fresh.item_tag(r))]
    refused = s.book.check_mac_bundle(mac_bundle(items), lambda a, c: obeyed.append(a))
    assert obeyed == ["k2"] and "emergency stop" in refused[0]


def test_a_mac_bundle_whose_lengths_disagree_is_refused_whole(s: Setup) -> None:
    alice, _, _ = two_holders(s)
    r = record(1)
    obeyed: list[str] = []
    for bad in (
        MacCommandBundle(agents=[AGENT, AGENT], items=r, macs=alice.item_tag(r) * 2),
        MacCommandBundle(agents=[AGENT], items=r + b"\0", macs=alice.item_tag(r)),
        MacCommandBundle(agents=[AGENT], items=r, macs=alice.item_tag(r)[:31]),
    ):
        with pytest.raises(MessageError, match="MacCommandBundle of"):
            s.book.check_mac_bundle(bad, lambda a, c: obeyed.append(a))
    assert obeyed == []
    # The world that refused them still obeys the good item after.
    s.book.check_mac_bundle(
        MacCommandBundle(agents=[AGENT], items=r, macs=alice.item_tag(r)),
        lambda a, c: obeyed.append(a),
    )
    assert obeyed == [AGENT]


def test_a_world_that_cannot_obey_one_item_of_a_mac_bundle_still_obeys_the_others(
    s: Setup,
) -> None:
    alice, bob, _ = two_holders(s)
    obeyed: list[str] = []

    def bridge_without_k1(agent: str, _command: AgentCommand) -> None:
        if agent == AGENT:
            raise AuthError("not_found", f"no robot {agent} on this bridge")
        obeyed.append(agent)

    items = [(AGENT, r := record(1), alice.item_tag(r)), ("k2", r2 := record(2), bob.item_tag(r2))]
    refused = s.book.check_mac_bundle(mac_bundle(items), bridge_without_k1)
    assert obeyed == ["k2"] and len(refused) == 1 and "no robot k1" in refused[0]
