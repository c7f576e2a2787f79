"""The control loop of bench_control_latency, written with plain zenoh-python: the peer.

What any Zenoh user pays for the same loop, with none of ours: no login, no
lease, no MAC, no replay window, no RobotLink or WorldChannel. Same shape as
ours, message for message, so the comparison isolates what our layers cost:

- the *engine* (:class:`PlainEngine`, a thread of the bench's process with
  its own Zenoh session) steps the same Sim2D world of Khepera at 50 Hz and
  puts each tick's SensorSamples in one SampleBundle (express), exactly the
  bytes our engine puts (``packing.samples``, same encoding);
- the *controllers* (``python -m bench.plain_peer``, one client process)
  subscribe to that bundle and answer each sample with a plain encoded
  AgentCommand echoing the sample's time; ``--inline``: all of them in the
  subscriber's callback and one CommandBundle per tick (as ours with
  ``WorldChannel.on_tick``); else one thread per controller, woken by the
  callback, their commands leaving in as few CommandBundles as a burst allows
  (a put in flight collects what comes meanwhile), as ours do;
- the engine decodes each command bundle in its subscriber callback and
  stamps each command when decoded and validated (*accepted*), and applies
  it at its next tick.

The keys are the project's own (``keys.world_samples`` / ``world_commands``)
of a world with another name, so the key expressions are as long as ours.
The payloads differ only in what our security adds: a plain command is an
encoded AgentCommand (about 20 bytes), ours a MacCommand around it.
"""

from __future__ import annotations

import argparse
import queue
import sys
import threading
import time
from typing import Any

import msgspec
import zenoh

from common import keys
from common.messages import (
    MAX_BUNDLED,
    AgentCommand,
    BundledCommand,
    CommandBundle,
    MessageError,
    SampleBundle,
    SensorSample,
    decode,
    encode,
)
from common.service import close_session, open_session
from common.sim2d.world import World
from common.world import packing
from common.zconfig import NetworkOptions

PEER_WORLD = "peer"


class PlainEngine:
    """A Sim2D world stepped at ``tick_s``, samples out and commands in over plain Zenoh.

    ``publishing`` cleared: the engine still steps and builds each tick's
    samples, but puts nothing (the bench alternates blocks of ours and the
    peer's; both engines always do the same work but the put).
    """

    def __init__(self, options: NetworkOptions, world: World, tick_s: float = 0.02) -> None:
        self.world, self.tick_s = world, tick_s
        self.z = open_session(options, wait=10)
        realm = options.realm
        self._pub = self.z.declare_publisher(keys.world_samples(realm, world.name), express=True)
        self._sub = self.z.declare_subscriber(
            keys.world_commands(realm, world.name), self._on_commands
        )
        self._slots = {agent.id: i for i, agent in enumerate(world.agents)}
        self._inbox: queue.SimpleQueue[tuple[int, AgentCommand, float]] = queue.SimpleQueue()
        self.publishing = threading.Event()
        self.recording = False
        self.published: dict[tuple[str, int], float] = {}  # (agent, sample ms) -> put time
        self.accepted: list[float] = []
        self.applied: list[float] = []
        self.commands = 0
        self.refused = 0
        self._halt = threading.Event()
        self._thread = threading.Thread(target=self._run, name="plain-engine", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._halt.set()
        self._thread.join(5)
        for handle in (self._sub, self._pub):
            handle.undeclare()
        close_session(self.z)

    def _on_commands(self, sample: zenoh.Sample) -> None:
        # Validated like any input from the network: typed decode, known agents only.
        try:
            bundle = decode(sample.payload, CommandBundle)
        except MessageError:
            self.refused += 1
            return
        for item in bundle.commands:
            slot = self._slots.get(item.agent)
            try:
                command = decode(item.payload, AgentCommand)
            except MessageError:
                command = None
            if slot is None or command is None or command.agent != item.agent:
                self.refused += 1
                continue
            self._inbox.put((slot, command, time.monotonic()))

    def _apply(self, slot: int, command: AgentCommand, received: float, now: float) -> None:
        if command.speeds is not None:
            self.world.set_speeds(slot, *command.speeds)
        self.commands += 1
        counters = command.counters
        if counters is None or not self.recording:
            return
        sent = self.published.get((command.agent, counters[0]))
        if sent is not None:
            self.accepted.append(received - sent)
            self.applied.append(now - sent)

    def _run(self) -> None:
        world = self.world
        slots = list(range(len(world.agents)))
        next_tick = time.monotonic()
        while not self._halt.is_set():
            now = time.monotonic()
            while True:
                try:
                    self._apply(*self._inbox.get_nowait(), now)
                except queue.Empty:
                    break
            world.step()
            samples = packing.samples(world, slots)
            payload = encode(
                SampleBundle(
                    world=world.name,
                    tick=world.tick,
                    agents=[s.agent for s in samples],
                    samples=[msgspec.Raw(encode(s)) for s in samples],
                )
            )
            if self.publishing.is_set():
                sent = time.monotonic()
                self._pub.put(payload)
                ms = round(world.sim_time * 1000)
                for s in samples:  # after the put: not timed
                    self.published[(s.agent, ms)] = sent
            next_tick += self.tick_s
            delay = next_tick - time.monotonic()
            if delay > 0:
                self._halt.wait(delay)
            elif delay < -0.5:
                next_tick = time.monotonic()


class _Sender:
    """Commands out in as few bundles as a burst allows: a put in flight collects the rest."""

    def __init__(self, pub: Any) -> None:
        self._pub = pub
        self._pending: list[BundledCommand] = []
        self._lock = threading.Lock()
        self._sending = threading.Lock()

    def submit(self, item: BundledCommand) -> None:
        with self._lock:
            self._pending.append(item)
        while self._sending.acquire(blocking=False):
            try:
                with self._lock:
                    batch, self._pending = self._pending, []
                if batch:
                    self._pub.put(encode(CommandBundle(commands=batch[:MAX_BUNDLED])))
            finally:
                self._sending.release()
            with self._lock:
                if not self._pending:
                    return


def answer(agent: str, raw: bytes) -> BundledCommand | None:
    """A controller's whole reaction: read the sample, command the robot (echo its time)."""
    try:
        sample = decode(raw, SensorSample)
    except MessageError:
        return None
    command = AgentCommand(agent=agent, counters=(round(sample.sim_time * 1000), 0))
    return BundledCommand(agent, encode(command))


def answers(bundle: SampleBundle, mine: set[str]) -> list[BundledCommand]:
    """The controllers' commands for ``bundle``'s samples of the agents in ``mine``."""
    return [
        item
        for agent, raw in zip(bundle.agents, bundle.samples, strict=True)
        if agent in mine and (item := answer(agent, bytes(raw))) is not None
    ]


def controllers(args: argparse.Namespace) -> int:
    """The peer's controllers' process: answer every sample of agents k0..k<n-1>."""
    options = NetworkOptions(realm=args.realm, connect=(args.connect,))
    z = open_session(options, wait=10)
    mine = {f"k{i}" for i in range(args.controllers)}
    pub = z.declare_publisher(
        keys.world_commands(args.realm, PEER_WORLD),
        congestion_control=zenoh.CongestionControl.DROP,
        express=True,
    )
    sender = _Sender(pub)
    # threads mode: agent -> [newest raw sample, its number], one condition each
    newest: dict[str, list[Any]] = {a: [b"", 0] for a in mine}
    fresh = {a: threading.Condition() for a in mine}
    stop = threading.Event()

    def on_bundle(sample: zenoh.Sample) -> None:
        try:
            bundle = decode(sample.payload, SampleBundle)
        except MessageError:
            return
        if bundle.world != PEER_WORLD or len(bundle.agents) != len(bundle.samples):
            return
        if args.inline:
            items = answers(bundle, mine)
            if items:
                pub.put(encode(CommandBundle(commands=items)))
            return
        for agent, raw in zip(bundle.agents, bundle.samples, strict=True):
            cond = fresh.get(agent)
            if cond is None:
                continue
            with cond:
                slot = newest[agent]
                slot[0], slot[1] = bytes(raw), slot[1] + 1
                cond.notify_all()

    def react(agent: str) -> None:
        seen = 0
        cond, slot = fresh[agent], newest[agent]
        while not stop.is_set():
            with cond:
                if slot[1] == seen:
                    cond.wait(0.5)
                if slot[1] == seen:
                    continue
                raw, seen = slot[0], slot[1]
            item = answer(agent, raw)
            if item is not None:
                sender.submit(item)

    if not args.inline:
        for agent in sorted(mine):
            threading.Thread(target=react, args=(agent,), daemon=True).start()
    sub = z.declare_subscriber(keys.world_samples(args.realm, PEER_WORLD), on_bundle)
    print("ready", flush=True)
    sys.stdin.readline()  # the bench says when to stop
    stop.set()
    sub.undeclare()
    pub.undeclare()
    close_session(z)
    return 0


def main() -> int:
    p = argparse.ArgumentParser(description="the plain peer's controllers (started by the bench)")
    p.add_argument("--controllers", type=int, required=True)
    p.add_argument("--realm", required=True)
    p.add_argument("--connect", required=True)
    p.add_argument("--inline", action="store_true")
    return controllers(p.parse_args())


if __name__ == "__main__":
    sys.exit(main())
