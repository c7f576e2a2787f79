"""WorldChannel: one world's sample bundles in, command bundles out, shared by many links.

The Zenoh session is faked (a publisher that records puts, a subscriber whose
callback the test calls): what is tested is the routing and the batching.
"""

from __future__ import annotations

import threading
import time

import msgspec
import pytest

from common import keys
from common.auth import AuthError, RegistryIdentity, Verifier, issue_session
from common.controller import RobotCommand
from common.messages import (
    AgentCommand,
    AuthEnvelope,
    CommandBundle,
    MacCommandBundle,
    SampleBundle,
    SensorSample,
    decode,
    encode,
)
from common.world.remote_robot import SwarmTick, WorldChannel, ZenohRobotLink
from tests.kit.fakezenoh import FakeSample, FakeSession
from tests.kit.leases import mac_leased_swarm

REALM, WORLD = "r", "w"


def sample(agent: str, tick: int) -> SensorSample:
    return SensorSample(
        world=WORLD,
        agent=agent,
        tick=tick,
        sim_time=tick * 0.02,
        proximity=[tick] * 8,
        ambient=[500] * 8,
        counters=(tick, -tick),
        speeds=(0, 0),
        leds=[0, 0],
    )


def bundle(agents: list[str], tick: int) -> bytes:
    return encode(
        SampleBundle(
            world=WORLD,
            tick=tick,
            agents=agents,
            samples=[msgspec.Raw(encode(sample(a, tick))) for a in agents],
        )
    )


IDENTITY = RegistryIdentity.generate()
RUNNER = issue_session(IDENTITY, REALM, "runner", ["control"])


def link_on(zs: FakeSession, channel: WorldChannel, agent: str) -> ZenohRobotLink:
    return ZenohRobotLink(
        zs,  # type: ignore[arg-type]
        REALM,
        WORLD,
        agent,
        lambda: RUNNER,
        keepalive=3600.0,  # no keep-alives in these tests
        channel=channel,
    )


def make(zs: FakeSession, agents: list[str]) -> tuple[WorldChannel, list[ZenohRobotLink]]:
    channel = WorldChannel(zs, REALM, WORLD)  # type: ignore[arg-type]
    return channel, [link_on(zs, channel, agent) for agent in agents]


def sent_commands(zs: FakeSession) -> list[tuple[str, bytes]]:
    """(agent, payload) of every command put, in put order."""
    out = []
    for payload in zs.publishers[keys.world_commands(REALM, WORLD)].puts:
        out += [(c.agent, c.payload) for c in decode(payload, CommandBundle).commands]
    return out


def deliver(zs: FakeSession, data: bytes) -> None:
    zs.callbacks[keys.world_samples(REALM, WORLD)](FakeSample(data))


def test_each_link_gets_its_own_agents_sample_from_a_bundle() -> None:
    zs = FakeSession()
    channel, (k0, k1) = make(zs, ["k0", "k1"])
    assert not any("/agent/" in key and key.endswith("/sensors") for key in zs.callbacks), (
        "links on a channel declare no per-agent sensor subscriber"
    )
    deliver(zs, bundle(["k1", "k9", "k0"], tick=7))  # k9: nobody here drives it
    assert k0.samples == 1 and k1.samples == 1
    assert k0.latest().counters == (7, -7) and k1.latest().proximity == (7,) * 8
    deliver(zs, bundle(["k1"], tick=8))  # a bundle need not hold every agent
    assert k0.samples == 1 and k1.samples == 2 and k1.latest().counters == (8, -8)
    assert channel.bundles == 2


def test_malformed_or_mismatched_bundles_are_ignored_and_the_channel_keeps_serving() -> None:
    zs = FakeSession()
    channel, (k0,) = make(zs, ["k0"])
    deliver(zs, b"\x93not a bundle")
    other_world = msgspec.structs.replace(decode(bundle(["k0"], 1), SampleBundle), world="x")
    deliver(zs, encode(other_world))
    short = msgspec.structs.replace(decode(bundle(["k0"], 1), SampleBundle), agents=["k0", "k1"])
    deliver(zs, encode(short))
    assert k0.samples == 0 and channel.bundles == 0
    deliver(zs, bundle(["k0"], tick=3))
    assert k0.samples == 1 and k0.latest().counters == (3, -3)
    # A bundle whose sample for k0 is garbage: the link keeps its last good state.
    bad = SampleBundle(world=WORLD, tick=4, agents=["k0"], samples=[msgspec.Raw(b"\xc1")])
    deliver(zs, encode(bad))
    assert k0.latest().counters == (3, -3)


def test_a_lone_command_leaves_at_once_sealed_for_its_agents_own_key() -> None:
    zs = FakeSession()
    channel, (k0,) = make(zs, ["k0"])
    k0.send(RobotCommand(speeds=(5, 5)))
    sent = sent_commands(zs)
    assert [agent for agent, _ in sent] == ["k0"] and channel.puts == 1
    # Sealed for k0's own cmd key, which is what the world checks a bundled command on.
    verifier = Verifier(IDENTITY.verify_key, REALM)
    principal, command = verifier.open(keys.agent_cmd(REALM, WORLD, "k0"), sent[0][1], AgentCommand)
    assert principal.user == "runner" and command.speeds == (5, 5)
    with pytest.raises(AuthError):
        verifier.open(keys.agent_cmd(REALM, WORLD, "k1"), sent[0][1], AgentCommand)


def test_a_burst_from_many_threads_is_batched_and_nothing_is_lost_or_reordered() -> None:
    zs = FakeSession(hold_s=0.002)  # each put takes 2 ms: commands pile up behind it
    agents = [f"k{i}" for i in range(20)]
    channel, links = make(zs, agents)
    per_link = 30
    start = threading.Barrier(len(links))

    def drive(link: ZenohRobotLink) -> None:
        start.wait()
        for n in range(per_link):
            link.send(RobotCommand(counters=(n, 0)))

    threads = [threading.Thread(target=drive, args=(link,)) for link in links]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    sent = sent_commands(zs)
    assert len(sent) == len(agents) * per_link == channel.commands
    assert channel.puts < len(sent) / 3, f"{channel.puts} puts for {len(sent)} commands"
    for agent in agents:
        mine = [p for a, p in sent if a == agent]
        counters = [
            decode(decode(p, AuthEnvelope).body, AgentCommand).counters[0]  # type: ignore[index]
            for p in mine
        ]
        assert counters == list(range(per_link)), f"{agent}'s commands out of order"


def test_burst_sends_one_threads_commands_in_one_message() -> None:
    zs = FakeSession()
    channel, links = make(zs, [f"k{i}" for i in range(12)])
    with channel.burst():
        for link in links:
            link.send(RobotCommand(speeds=(1, 1)))
        assert channel.puts == 0  # held until the block ends
    assert channel.puts == 1 and len(sent_commands(zs)) == 12


def test_a_closed_link_stops_getting_samples_and_a_newer_link_takes_its_agent() -> None:
    zs = FakeSession()
    channel, (old,) = make(zs, ["k0"])
    new = link_on(zs, channel, "k0")
    deliver(zs, bundle(["k0"], tick=1))
    assert (old.samples, new.samples) == (0, 1), "the newest link of an agent wins"
    old.close(stop=False)  # the older run closing must not unhook the newer one
    deliver(zs, bundle(["k0"], tick=2))
    assert new.samples == 2
    new.close(stop=False)
    deliver(zs, bundle(["k0"], tick=3))
    assert new.samples == 2


def test_a_tick_listener_answers_every_robot_of_a_bundle_in_one_message() -> None:
    zs = FakeSession()
    channel, links = make(zs, ["k0", "k1", "k2"])
    by_agent = {link.agent: link for link in links}
    seen: list[tuple[int, list[str]]] = []

    def swarm(tick: int, agents: list[str]) -> None:
        seen.append((tick, agents))
        for agent in agents:
            state = by_agent[agent].latest()  # already this tick's sample
            by_agent[agent].send(RobotCommand(counters=(state.counters[0], 0)))

    def broken(_tick: int, _agents: list[str]) -> None:
        raise RuntimeError("a bug in someone's swarm code")

    channel.on_tick(broken)  # first: its failure must not keep swarm from running
    remove = channel.on_tick(swarm)
    deliver(zs, bundle(["k2", "k9", "k0"], tick=5))  # k9 is not driven here
    assert seen == [(5, ["k2", "k0"])]
    assert channel.puts == 1, "the listener's commands leave in one message"
    sent = sent_commands(zs)
    assert [agent for agent, _ in sent] == ["k2", "k0"]
    counters = [decode(decode(p, AuthEnvelope).body, AgentCommand).counters for _, p in sent]
    assert counters == [(5, 0), (5, 0)]
    deliver(zs, bundle(["k9"], tick=6))  # nothing for this process: no call
    assert len(seen) == 1
    remove()
    deliver(zs, bundle(["k1"], tick=7))
    assert len(seen) == 1 and links[1].samples == 1 and channel.puts == 1


def test_a_controller_thread_waiting_for_a_sample_wakes_when_its_bundle_arrives() -> None:
    # The runner's controller threads block in wait_sample; the channel only
    # notifies a link someone waits on, and that one must still be woken.
    zs = FakeSession()
    _channel, (k0, k1) = make(zs, ["k0", "k1"])
    got: list[int] = []
    waiter = threading.Thread(target=lambda: got.append(k0.wait_sample(0, 30.0)))
    waiter.start()
    while not k0._waiting:  # wait until it is really waiting (a condition, not a sleep)
        time.sleep(0.001)
    deliver(zs, bundle(["k1", "k0"], tick=5))
    waiter.join(30.0)
    assert got == [1] and k0.latest().counters == (5, -5)
    assert k1.wait_sample(0, 0.0) == 1  # no waiter: the sample is kept all the same
    assert k0._waiting == 0 and k1._waiting == 0


def test_a_swarm_listener_reads_the_ticks_samples_in_arrays_and_answers_in_one_message() -> None:
    zs = FakeSession()
    channel, links = make(zs, ["k0", "k1", "k2"])
    seen: list[tuple[int, list[str], list[int]]] = []

    def swarm(tick: SwarmTick) -> None:
        seen.append((tick.tick, tick.agents, [s.counters[0] for s in tick.samples]))
        for agent, s in zip(tick.agents, tick.samples, strict=True):
            assert tick.send(agent, speeds=(3, -3), counters=(s.counters[0], 0))

    def broken(tick: SwarmTick) -> None:
        tick.send("k1", speeds=(1, 1))  # what it sent before failing still goes out
        raise RuntimeError("a bug in someone's swarm code")

    remove_broken = channel.on_swarm(broken)  # first: its failure must not stop swarm
    remove = channel.on_swarm(swarm)
    deliver(zs, bundle(["k2", "k9", "k0"], tick=5))  # k9 is not driven here
    assert seen == [(5, ["k2", "k0"], [5, 5])]
    assert channel.puts == 1, "the listeners' commands leave in one message"
    sent = sent_commands(zs)
    assert [agent for agent, _ in sent] == ["k1", "k2", "k0"]
    assert (links[1].sent, links[2].sent, links[0].sent) == (1, 1, 1)
    remove_broken()
    sent = sent[1:]
    # Each sealed for its agent's own cmd key, exactly as link.send would.
    verifier = Verifier(IDENTITY.verify_key, REALM)
    for agent, payload in sent:
        _, command = verifier.open(keys.agent_cmd(REALM, WORLD, agent), payload, AgentCommand)
        assert (command.agent, command.speeds, command.counters) == (agent, (3, -3), (5, 0))
    assert links[2].latest().counters == (5, -5), "the links still get their samples"
    remove()
    deliver(zs, bundle(["k1"], tick=6))
    assert len(seen) == 1 and channel.puts == 1


def test_a_swarm_listener_cannot_send_bad_values_or_drive_robots_it_has_no_link_for() -> None:
    zs = FakeSession()
    channel, (k0,) = make(zs, ["k0"])
    errors: list[str] = []
    results: list[bool] = []

    def swarm(tick: SwarmTick) -> None:
        for bad in ((200, 0), (1, 2, 3), (True, 0), (1.5, 0), [1, 1]):
            try:
                tick.send("k0", speeds=bad)  # type: ignore[arg-type]
            except ValueError as exc:
                errors.append(str(exc))
        results.append(tick.send("k7", speeds=(1, 1)))  # no link here for k7
        results.append(tick.send("k0", speeds=(1, 1)))

    channel.on_swarm(swarm)
    # k0's sample is garbage in this bundle: k0 is left out of the tick, nothing is called.
    garbage = SampleBundle(world=WORLD, tick=4, agents=["k0"], samples=[msgspec.Raw(b"\xc1")])
    deliver(zs, encode(garbage))
    # A sample filed under k0 that is another agent's: left out too.
    spoofed = SampleBundle(
        world=WORLD, tick=4, agents=["k0"], samples=[msgspec.Raw(encode(sample("k1", 4)))]
    )
    deliver(zs, encode(spoofed))
    assert errors == [] and results == []
    deliver(zs, bundle(["k0"], tick=5))
    assert len(errors) == 5 and results == [False, True]
    assert [agent for agent, _ in sent_commands(zs)] == ["k0"]
    k0.close(stop=False)
    results.clear()
    deliver(zs, bundle(["k0"], tick=6))  # a closed link is detached: no call at all
    assert results == []


def test_a_swarm_under_mac_leases_sends_one_array_bundle_that_the_world_accepts() -> None:
    """Links holding MAC leases: the tick's commands leave as one MacCommandBundle, each
    item MACed under its own agent's lease; a link still without one signs, as before."""
    # k2's lease has not arrived yet
    zs, channel, links, book = mac_leased_swarm(
        IDENTITY, RUNNER, REALM, WORLD, ("k0", "k1", "k2"), ("k0", "k1"), 60
    )

    def swarm(tick: SwarmTick) -> None:
        for agent, s in zip(tick.agents, tick.samples, strict=True):
            assert tick.send(agent, speeds=(3, -3), counters=(s.counters[0], 0))

    channel.on_swarm(swarm)
    deliver(zs, bundle(["k0", "k1", "k2"], tick=5))
    puts = zs.publishers[keys.world_commands(REALM, WORLD)].puts
    assert len(puts) == 2 and channel.commands == 3
    arrays = decode(puts[0], MacCommandBundle)
    assert arrays.agents == ["k0", "k1"]
    assert [c.agent for c in decode(puts[1], CommandBundle).commands] == ["k2"]  # signed
    assert [link.mac_sent for link in links] == [1, 1, 0]
    obeyed: list[tuple[str, AgentCommand]] = []
    assert book.check_mac_bundle(arrays, lambda a, c: obeyed.append((a, c))) == []
    assert [(a, c.speeds, c.counters) for a, c in obeyed] == [
        ("k0", (3, -3), (5, 0)),
        ("k1", (3, -3), (5, 0)),
    ]
    # Captured and put again: refused, item by item.
    assert len(book.check_mac_bundle(arrays, lambda a, c: obeyed.append((a, c)))) == 2
    assert len(obeyed) == 2
    for link in links:
        link.close(stop=False)


def test_controller_threads_under_mac_leases_send_items_the_world_accepts_once() -> None:
    """The runner's path: each controller thread's speeds or counters leave as a MACed
    MacCommandBundle item (what a swarm tick sends); what an item cannot carry (LEDs)
    still leaves as a MacCommand; the world obeys each once and refuses a replay."""
    zs, channel, (k0, k1), book = mac_leased_swarm(
        IDENTITY, RUNNER, REALM, WORLD, ("k0", "k1"), ("k0", "k1"), 60
    )
    with channel.burst():  # as a burst of threads would: one message for the items
        k0.send(RobotCommand(speeds=(3, -3)))
        k1.send(RobotCommand(counters=(7, 0)))
        k1.send(RobotCommand(leds=(True, False)))
    puts = zs.publishers[keys.world_commands(REALM, WORLD)].puts
    assert len(puts) == 2 and channel.commands == 3
    assert (k0.sent, k0.mac_sent, k1.sent, k1.mac_sent) == (1, 1, 2, 2)
    arrays = decode(puts[0], MacCommandBundle)
    assert arrays.agents == ["k0", "k1"]
    obeyed: list[tuple[str, AgentCommand]] = []
    assert book.check_mac_bundle(arrays, lambda a, c: obeyed.append((a, c))) == []
    (leds,) = decode(puts[1], CommandBundle).commands
    assert book.check_bundle([leds], lambda a, c: obeyed.append((a, c))) == []
    assert [(a, c.speeds, c.counters, c.leds) for a, c in obeyed] == [
        ("k0", (3, -3), None, None),
        ("k1", None, (7, 0), None),
        ("k1", None, None, [1, 0]),
    ]
    assert len(book.check_mac_bundle(arrays, lambda a, c: obeyed.append((a, c)))) == 2
    assert len(obeyed) == 3
    for link in (k0, k1):
        link.close(stop=False)


def test_several_threads_waiting_on_one_link_all_wake_for_its_new_sample() -> None:
    zs = FakeSession()
    _channel, (k0,) = make(zs, ["k0"])
    got: list[int] = []
    waiters = [
        threading.Thread(target=lambda: got.append(k0.wait_sample(0, 30.0))) for _ in range(3)
    ]
    for waiter in waiters:
        waiter.start()
    while k0._waiting < 3:  # all really waiting (a condition, not a sleep)
        time.sleep(0.001)
    deliver(zs, bundle(["k0"], tick=5))
    for waiter in waiters:
        waiter.join(30.0)
    assert got == [1, 1, 1] and k0._waiting == 0
    assert k0.wait_sample(1, 0.01) == 1  # nothing newer: times out (a stale wake-up is no sample)
    k0.close(stop=False)


def test_an_idle_link_sends_empty_keep_alive_commands_for_the_watchdog() -> None:
    zs = FakeSession()
    channel = WorldChannel(zs, REALM, WORLD)  # type: ignore[arg-type]
    link = ZenohRobotLink(
        zs,  # type: ignore[arg-type]
        REALM,
        WORLD,
        "k0",
        lambda: RUNNER,
        keepalive=0.05,
        channel=channel,
    )
    puts = zs.publishers[keys.world_commands(REALM, WORLD)].puts
    deadline = time.monotonic() + 30.0
    while len(puts) < 2 and time.monotonic() < deadline:  # idle: keep-alives go out
        time.sleep(0.01)
    link.close(stop=False)
    commands = [decode(decode(p, AuthEnvelope).body, AgentCommand) for _, p in sent_commands(zs)]
    assert len(commands) >= 2
    assert all(c.agent == "k0" and c.speeds is None and c.counters is None for c in commands)
