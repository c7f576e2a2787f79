"""A swarm in the array API (WorldChannel.on_swarm) against a real engine, under MAC leases.

A real router; the engine (with an identity, so leases carry MAC keys) in
this process as the bench runs it; the swarm's links on their own client
session. What a user cares about: the swarm's leased robots move and the
others do not, its commands are MACed, and on the same bundle key a forged
command (a guessed lease key) or a replayed bundle moves nothing.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
import zenoh

from common import keys
from common.auth import RegistryIdentity, Session, Verifier, issue_session
from common.messages import (
    MAC_ITEM_SPEEDS,
    MAC_ITEM_STRUCT,
    AgentCommand,
    BundledCommand,
    CommandBundle,
    Lease,
    MacCommandBundle,
    encode,
)
from common.service import close_session, open_session
from common.sim2d.agents import agent_type
from common.sim2d.world import World
from common.world.leasemac import CommandMac, mac_command, new_lease_key
from common.world.remote_robot import SwarmTick, WorldChannel, ZenohRobotLink
from services.engine.service import EngineService, EngineSettings
from tests.conftest import Router, wait_for
from tests.kit.leases import mac_lease

WORLD = "swarm"
AGENTS = ("k0", "k1", "k2")


class Arena:
    def __init__(self, router: Router) -> None:
        self.realm = router.realm
        self.registry = RegistryIdentity.generate()
        self.world_session = issue_session(self.registry, self.realm, "engine-t", ["world"])
        self.context = issue_session(self.registry, self.realm, "ctx", ["lease"])
        self.alice = issue_session(self.registry, self.realm, "alice", ["control"])
        world = World(2000, 2000, seed=1, tick_s=0.02, name=WORLD)
        for i, agent in enumerate(AGENTS):
            world.add_agent(agent, agent_type("khepera"), 300 + 500 * i, 1000, 0.0)
        self.world_z = open_session(router.options(), wait=10)
        self.engine = EngineService(
            self.world_z,
            self.realm,
            world,
            EngineSettings(tick_s=0.02, registry_key=self.registry.verify_key),
            identity=lambda: self.world_session,
        ).start()
        self.leases: dict[str, tuple[Lease, bytes]] = {}

    def grant(self, agent: str, holder: Session) -> bytes:
        """A MAC lease on ``agent`` to ``holder``, as the agent context grants it; its key."""
        k = new_lease_key()
        now = time.time()
        lease = mac_lease(
            k,
            holder,
            self.world_session,
            lease_id=f"L-{agent}",
            world_name=WORLD,
            agent=agent,
            start=now,
            end=now + 120,
        )
        self.leases[agent] = (lease, k)
        self.republish()
        return k

    def republish(self) -> None:
        for agent, (lease, _) in self.leases.items():
            key = keys.agent_lease(self.realm, WORLD, agent)
            self.world_z.put(key, self.context.seal(key, lease))

    def xs(self) -> np.ndarray:
        return np.array([self.engine.world.pose_of(agent)[0] for agent in AGENTS])

    def put_refused(self, z: zenoh.Session, bundles: list[bytes], each: int, what: str) -> None:
        """Put ``bundles`` on the world's commands key, wait until the engine has refused
        ``each`` commands of every one, then a few ticks (where an obeyed one would move)."""
        refused = self.engine.commands_refused
        for payload in bundles:
            z.put(keys.world_commands(self.realm, WORLD), payload)
        wait_for(lambda: self.engine.commands_refused >= refused + each * len(bundles), 10, what)
        time.sleep(0.2)  # a few ticks in which a wrongly obeyed command would move them

    def close(self) -> None:
        self.engine.stop()
        close_session(self.world_z)


@pytest.fixture
def arena(router: Router) -> Iterator[Arena]:
    arena = Arena(router)
    yield arena
    arena.close()


def test_a_swarm_drives_its_leased_robots_with_macs_and_forged_or_replayed_bundles_do_not(
    router: Router, arena: Arena
) -> None:
    realm = arena.realm
    swarm_z = open_session(router.options(), wait=10)
    spy_z = open_session(router.options(), wait=10)
    captured: list[bytes] = []
    spy_lock = threading.Lock()

    def on_bundle(sample: zenoh.Sample) -> None:  # anyone may listen to the bundle key
        with spy_lock:
            captured.append(bytes(sample.payload.to_bytes()))

    spy = spy_z.declare_subscriber(keys.world_commands(realm, WORLD), on_bundle)
    channel = WorldChannel(swarm_z, realm, WORLD)
    verifier = Verifier(arena.registry.verify_key, realm)
    links = {
        agent: ZenohRobotLink(
            swarm_z,
            realm,
            WORLD,
            agent,
            lambda: arena.alice,
            keepalive=3600.0,  # every command below is the swarm's
            verifier=verifier,
            channel=channel,
        )
        for agent in AGENTS
    }
    ticks: list[list[str]] = []

    def forward(tick: SwarmTick) -> None:
        ticks.append(list(tick.agents))
        for agent, sample in zip(tick.agents, tick.samples, strict=True):
            assert sample.agent == agent
            tick.send(agent, speeds=(20, 20))

    try:
        wait_for(lambda: arena.engine.world.tick > 10, 60, "the engine ticking")
        start = arena.xs()
        for agent in ("k1", "k2"):  # alice holds these two; k0 has no lease
            arena.grant(agent, arena.alice)

        def macs_in() -> bool:  # the links' lease subscribers may match after the first put
            arena.republish()
            return all(links[a]._mac_lease is not None for a in ("k1", "k2"))

        wait_for(macs_in, 10, "the MAC leases at the links")
        remove = channel.on_swarm(forward)
        wait_for(lambda: float((arena.xs() - start)[1:].min()) > 40.0, 10, "k1 and k2 driven")
        assert abs(float(arena.xs()[0] - start[0])) < 1.0, "k0 has no lease: not driven"
        assert ticks and all(agents == ["k1", "k2"] for agents in ticks)
        assert links["k1"].mac_sent == links["k1"].sent > 0, "every swarm command MACed"
        assert arena.engine.leases.mac_accepted >= links["k1"].sent
        remove()
        # The engine's watchdog stops them once the commands stop.
        wait_for(lambda: not arena.engine.world.cmd[1:].any(), 5, "the watchdog stopping them")
        # Zero wheel speeds show in the pose a tick later: wait until they stand still
        # (a loaded machine once took the last tick's 1.6 mm for an obeyed forgery).
        at_rest = [arena.xs()]

        def standing_still() -> bool:
            time.sleep(0.1)  # a few 20 ms ticks between two looks
            now = arena.xs()
            still_now = float(np.abs(now - at_rest[0]).max()) < 0.01
            at_rest[0] = now
            return still_now

        wait_for(standing_still, 5, "the stopped robots to stand still")
        with spy_lock:
            replay = list(captured[-20:])
        assert replay, "the spy saw the swarm's bundles"

        # A forged bundle: k1's lease id is public, its key is not (a guess here).
        refused = arena.engine.commands_refused
        still = arena.xs()
        cmd_key = keys.agent_cmd(realm, WORLD, "k1")
        for seq in range(1, 26):
            forged = mac_command(
                new_lease_key(),
                cmd_key,
                "L-k1",
                10**6 + seq,
                AgentCommand(agent="k1", speeds=(60, 60)),
                time.time(),
            )
            spy_z.put(
                keys.world_commands(realm, WORLD),
                encode(CommandBundle(commands=[BundledCommand("k1", forged)])),
            )
        wait_for(lambda: arena.engine.commands_refused >= refused + 25, 10, "forgeries refused")
        # Replayed: the swarm's own valid bundles, captured on the wire, put again.
        arena.put_refused(spy_z, replay, 2, "replays refused")
        assert float(np.abs(arena.xs() - still).max()) < 1.0, "forged or replayed: nothing moved"
    finally:
        for link in links.values():
            link.close(stop=False)
        channel.close()
        spy.undeclare()
        close_session(spy_z)
        close_session(swarm_z)


def test_one_array_bundle_moves_the_robot_of_its_good_item_and_none_of_its_bad_ones(
    router: Router, arena: Arena
) -> None:
    """A MacCommandBundle through a real router: each item is checked on its own. alice's
    good item for k1 is obeyed in every bundle; in the same bundles, a tampered copy of
    bob's item for k2, an item for k2 MACed under alice's lease, and one for k0 (no
    lease) move nothing, and the bundles put again later move nothing either."""
    realm = arena.realm
    bob = issue_session(arena.registry, realm, "bob", ["control"])
    put_z = open_session(router.options(), wait=10)
    try:
        wait_for(lambda: arena.engine.world.tick > 10, 60, "the engine ticking")
        alice = CommandMac(
            arena.grant("k1", arena.alice), keys.agent_cmd(realm, WORLD, "k1"), "L-k1"
        )
        k2 = keys.agent_cmd(realm, WORLD, "k2")
        bobs = CommandMac(arena.grant("k2", bob), k2, "L-k2")
        alice_on_k2 = CommandMac(arena.leases["k1"][1], k2, "L-k1")
        # Both keys in before the first bundle: an item refused only for want of its key
        # would be obeyed when put again below (its seq never entered the window).
        wait_for(
            lambda: all(arena.engine.leases.has_mac_key(a) for a in ("k1", "k2")),
            10,
            "the leases at the engine",
        )
        start = arena.xs()
        sent: list[bytes] = []
        seq = 0

        def item(mac: CommandMac, agent: str, speeds: tuple[int, int]) -> tuple[str, bytes, bytes]:
            nonlocal seq
            seq += 1
            record = MAC_ITEM_STRUCT.pack(seq, time.time(), MAC_ITEM_SPEEDS, *speeds, 0, 0)
            return agent, record, mac.item_tag(record)

        def put_bundle() -> bool:
            agent, record, mac = item(bobs, "k2", (60, 60))
            tampered = (agent, record[:17] + b"\x7f" + record[18:], mac)
            items = [
                tampered,
                item(alice, "k1", (40, 40)),
                item(alice_on_k2, "k2", (60, 60)),
                item(alice, "k0", (60, 60)),
            ]
            payload = encode(
                MacCommandBundle(
                    agents=[a for a, _, _ in items],
                    items=b"".join(r for _, r, _ in items),
                    macs=b"".join(m for _, _, m in items),
                )
            )
            sent.append(payload)
            put_z.put(keys.world_commands(realm, WORLD), payload)
            return float(arena.xs()[1] - start[1]) > 40.0

        refused = arena.engine.commands_refused
        wait_for(put_bundle, 10, "k1 driven by its good items")
        moved = arena.xs() - start
        assert abs(float(moved[0])) < 1.0 and abs(float(moved[2])) < 1.0, "k0, k2 did not move"
        wait_for(
            lambda: arena.engine.commands_refused >= refused + 3 * len(sent),
            10,
            "every bad item refused",
        )
        # The watchdog stops k1; the same bundles put again move nothing.
        wait_for(lambda: not arena.engine.world.cmd[1:].any(), 5, "the watchdog stopping k1")
        still = arena.xs()
        arena.put_refused(put_z, sent, 4, "the replayed bundles refused")
        assert float(np.abs(arena.xs() - still).max()) < 1.0, "replayed: nothing moved"
    finally:
        close_session(put_z)
