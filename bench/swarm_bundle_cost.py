"""CPU per tick of a swarm's commands, both ends: MacCommands in a CommandBundle against
one MacCommandBundle (issue 22).

Hot loop, no network: 20 robots under MAC leases held by one session (as the
runner holds them), the sender's side through the real ``SwarmTick.send``
and ``WorldChannel`` (a fake Zenoh session that only keeps the puts) and the
world's through the real ``LeaseBook``. The two wire forms alternate batch
by batch in the same run (``time.thread_time``: CPU of this thread only, so
other users of the machine move it less than wall time), and the medians
over the batches are printed:

- *sender, per-item* (the path before MacCommandBundle): per robot an
  AgentCommand, its MacCommand (encode, MAC, encode) and a BundledCommand,
  then one CommandBundle, as ``SwarmTick.send`` did;
- *sender, arrays*: ``SwarmTick.send`` as it is (one 29-byte record and its
  MAC per robot, one MacCommandBundle);
- *world, per-item*: decode the CommandBundle, ``LeaseBook.check_bundle``;
- *world, arrays*: decode the MacCommandBundle, ``LeaseBook.check_mac_bundle``;
- the plain peer's world for scale: decode a CommandBundle of plain
  AgentCommands and each command (what bench/plain_peer.py does);
- the whole client tick, ours: a SampleBundle handed to the channel's
  subscriber callback, the bench's swarm reaction (``on_swarm``: echo each
  sample's time in counters), the MacCommandBundle put; and the peer's
  (bench/plain_peer.py's inline callback: decode, ``answer`` each sample,
  one CommandBundle put).

    .venv/bin/python -m bench.swarm_bundle_cost [--robots 20] [--batches 15]
"""

from __future__ import annotations

import functools
import statistics
import sys
import time
from collections.abc import Callable
from typing import Any

import msgspec

from bench import cli as bench_cli
from bench.plain_peer import answers
from common import keys
from common.auth import RegistryIdentity, issue_session
from common.messages import (
    AgentCommand,
    BundledCommand,
    CommandBundle,
    MacCommandBundle,
    SampleBundle,
    SensorSample,
    decode,
    encode,
)
from common.world.leases import LeaseBook
from common.world.remote_robot import SwarmTick, WorldChannel, ZenohRobotLink
from tests.kit.fakezenoh import FakePublisher, FakeSample, FakeSession
from tests.kit.leases import mac_leased_swarm

REALM, WORLD = "bench", "swarm"


def setup(n: int) -> tuple[WorldChannel, dict[str, ZenohRobotLink], LeaseBook, FakeSession]:
    identity = RegistryIdentity.generate()
    runner = issue_session(identity, REALM, "runner", ["control"])
    agents = [f"k{i}" for i in range(n)]
    zs, channel, links, book = mac_leased_swarm(
        identity, runner, REALM, WORLD, agents, agents, 3600.0
    )
    for link in links:
        assert link._mac_lease is not None
    return channel, {link.agent: link for link in links}, book, zs


def sample(agent: str, world: str = WORLD) -> SensorSample:
    """A Khepera's sample at rest: nothing near it, the room's light, its wheels still."""
    return SensorSample(
        world=world,
        agent=agent,
        tick=1,
        sim_time=0.02,
        proximity=[0] * 8,
        ambient=[500] * 8,
        counters=(0, 0),
        speeds=(0, 0),
        leds=[0, 0],
    )


def main() -> int:
    p = bench_cli.parser("swarm_bundle_cost", __doc__)
    p.add_argument("--robots", type=int, default=20)
    p.add_argument("--batches", type=int, default=15)
    p.add_argument("--ticks", type=int, default=200, help="ticks per batch")
    args = p.parse_args()
    n, ticks = args.robots, args.ticks
    channel, links, book, zs = setup(n)
    agents = list(links)
    samples = [sample(a) for a in agents]
    pub = zs.publishers[keys.world_commands(REALM, WORLD)]

    def send_per_item() -> bytes:  # SwarmTick.send before MacCommandBundle, for one tick
        now = time.time()
        out = []
        for agent in agents:
            link = links[agent]
            payload, _ = link._seal(AgentCommand(agent=agent, counters=(20, 0)), now)
            out.append(BundledCommand(agent, payload))
        return encode(CommandBundle(commands=out))

    def send_arrays() -> bytes:  # SwarmTick.send as it is, and the channel's put
        tick = SwarmTick(1, agents, samples, links)
        for agent in agents:
            tick.send(agent, counters=(20, 0))
        channel._put_mac_items(tick._item_agents, tick._items, tick._macs)
        return pub.puts.pop()

    plain = [
        encode(
            CommandBundle(
                commands=[
                    BundledCommand(a, encode(AgentCommand(agent=a, counters=(20, 0))))
                    for a in agents
                ]
            )
        )
        for _ in range(ticks)
    ]
    obeyed: list[str] = []

    def obey(agent: str, _command: AgentCommand) -> None:
        obeyed.append(agent)

    def world_per_item(payloads: list[bytes]) -> None:
        for payload in payloads:
            book.check_bundle(decode(payload, CommandBundle).commands, obey)

    def world_arrays(payloads: list[bytes]) -> None:
        for payload in payloads:
            book.check_mac_bundle(decode(payload, MacCommandBundle), obey)

    def world_plain(payloads: list[bytes]) -> None:
        for payload in payloads:
            for item in decode(payload, CommandBundle).commands:
                command = decode(item.payload, AgentCommand)
                if command.agent == item.agent:
                    obey(item.agent, command)

    samples_in = encode(
        SampleBundle(
            world=WORLD, tick=1, agents=agents, samples=[msgspec.Raw(encode(x)) for x in samples]
        )
    )
    on_samples = zs.callbacks[keys.world_samples(REALM, WORLD)]

    def react(tick: SwarmTick) -> None:  # bench_control_latency's --swarm reaction
        for agent, x in zip(tick.agents, tick.samples, strict=True):
            tick.send(agent, counters=(round(x.sim_time * 1000), 0))

    channel.on_swarm(react)
    mine = set(agents)
    peer_pub = FakePublisher()

    def client_ours() -> None:
        for _ in range(ticks):
            on_samples(FakeSample(samples_in))
        pub.puts.clear()

    def client_peer() -> None:  # plain_peer.controllers' on_bundle, --inline
        for _ in range(ticks):
            bundle = decode(samples_in, SampleBundle)
            if bundle.world != WORLD or len(bundle.agents) != len(bundle.samples):
                continue
            items = answers(bundle, mine)
            if items:
                peer_pub.put(encode(CommandBundle(commands=items)))
        peer_pub.puts.clear()

    def timed(fn: Callable[[], Any]) -> tuple[float, Any]:
        start = time.thread_time()
        out = fn()
        return (time.thread_time() - start) * 1e6 / ticks, out

    figures: dict[str, list[float]] = {
        k: [] for k in ("sender per-item", "sender arrays", "world per-item", "world arrays")
    }
    figures["peer's world"] = []
    figures["client tick, ours"] = []
    figures["client, peer's"] = []
    sizes = {}
    for _ in range(args.batches):
        us, old = timed(lambda: [send_per_item() for _ in range(ticks)])
        figures["sender per-item"].append(us)
        us, new = timed(lambda: [send_arrays() for _ in range(ticks)])
        figures["sender arrays"].append(us)
        sizes = {"per-item": len(old[0]), "arrays": len(new[0]), "plain": len(plain[0])}
        obeyed.clear()
        us, _ = timed(functools.partial(world_per_item, old))
        figures["world per-item"].append(us)
        us, _ = timed(functools.partial(world_arrays, new))
        figures["world arrays"].append(us)
        us, _ = timed(lambda: world_plain(plain))
        figures["peer's world"].append(us)
        us, _ = timed(client_ours)
        figures["client tick, ours"].append(us)
        us, _ = timed(client_peer)
        figures["client, peer's"].append(us)
        if len(obeyed) != 3 * n * ticks:
            raise RuntimeError(f"{3 * n * ticks - len(obeyed)} commands refused: {book.stopped}")
    print(
        f"{n} robots under MAC leases, {args.batches} batches of {ticks} ticks, "
        "CPU (thread_time) per tick, median over batches (best):"
    )
    for name, values in figures.items():
        print(f"  {name:<18} {statistics.median(values):7.1f} µs  ({min(values):.1f})")
    print(
        f"  bytes a tick: CommandBundle of MacCommands {sizes['per-item']}, MacCommandBundle "
        f"{sizes['arrays']}, the peer's CommandBundle of AgentCommands {sizes['plain']}"
    )
    for link in links.values():
        link.close(stop=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
