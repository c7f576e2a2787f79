"""One world's sample and command bundles, shared by a process's robot links.

A process that drives many robots of one world (the runner, a swarm) gives
its :class:`~common.world.remote_robot.ZenohRobotLink` s one shared
:class:`WorldChannel`: each tick's samples of every leased agent arrive in
one message (``world/<w>/samples``) and the controllers' commands leave in as
few messages as the burst allows (``world/<w>/cmds``). :class:`SwarmTick` is
one tick of it in arrays, for one thread answering many robots. Split from
common/world/remote_robot.py (the link itself), which still exports both.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Generic, TypeVar

import zenoh

from common import keys
from common.controller import (
    COUNTER_LIMIT,
    MAX_SPEED,
)
from common.messages import (
    MAC_ITEM_COUNTERS,
    MAC_ITEM_SPEEDS,
    MAC_ITEM_STRUCT,
    MAX_BUNDLED,
    AgentCommand,
    BundledCommand,
    CommandBundle,
    MacCommandBundle,
    MessageError,
    SampleBundle,
    SensorSample,
    decode,
    encode,
)

if TYPE_CHECKING:  # the links this channel carries; remote_robot imports this module
    from common.world.remote_robot import ZenohRobotLink

log = logging.getLogger("wart.remote_robot")
L = TypeVar("L", bound=Callable[..., None])

_pack_item = MAC_ITEM_STRUCT.pack  # 50 times a second per robot: one lookup less


def _check_pair(name: str, pair: tuple[int, int], bound: int) -> None:
    """ValueError unless ``pair`` is a tuple of two ints (not bools) within ±``bound``."""
    if type(pair) is tuple and len(pair) == 2:
        a, b = pair
        if type(a) is int and type(b) is int and -bound <= a <= bound and -bound <= b <= bound:
            return
    raise ValueError(f"{name} must be a tuple of two integers within ±{bound}")


class SwarmTick:
    """One tick of a swarm listener (:meth:`WorldChannel.on_swarm`): readings in, commands out.

    ``agents[i]``'s decoded, validated ``SensorSample`` is ``samples[i]``, for
    the agents of this process's links that the world's bundle carried (a
    malformed sample leaves its agent out). :meth:`send` commands one of them
    through its link: MACed under its lease (or signed before the MAC lease
    arrived) exactly as ``link.send`` does, and held until the listener
    returns, so the tick's commands leave in one bundle.

    The array shape of the controller API, for one process driving many
    robots: no per-robot ``KheperaState`` or ``RobotCommand`` object, whose
    Python cost per robot was what separated our loop from a plain Zenoh one
    (docs/BENCHMARKS.md). Valid for the listener's call only.
    """

    __slots__ = (
        "_item_agents",
        "_items",
        "_links",
        "_macs",
        "_now",
        "_out",
        "_sent",
        "agents",
        "samples",
        "tick",
    )

    def __init__(
        self,
        tick: int,
        agents: list[str],
        samples: list[SensorSample],
        links: dict[str, ZenohRobotLink],
    ) -> None:
        self.tick, self.agents, self.samples, self._links = tick, agents, samples, links
        self._now = time.time()  # every command of the tick is sealed at this time
        self._out: list[BundledCommand] = []  # signed (before a MAC lease): a CommandBundle
        # MACed under a MAC lease: the MacCommandBundle's arrays, one record and MAC each
        self._item_agents: list[str] = []
        self._items: list[bytes] = []
        self._macs: list[bytes] = []
        self._sent: list[ZenohRobotLink] = []

    def send(
        self,
        agent: str,
        *,
        speeds: tuple[int, int] | None = None,
        counters: tuple[int, int] | None = None,
    ) -> bool:
        """Command ``agent``: wheel speeds (±MAX_SPEED) and/or position counters to set.

        ValueError for values that are not two ints in range (checked here, so
        a bug shows in the controller, not as a refusal in the world's log);
        False if no link of this channel drives ``agent`` (or it is closed).
        """
        flags, left, right, a, b = 0, 0, 0, 0, 0
        if speeds is not None:
            _check_pair("speeds", speeds, MAX_SPEED)
            flags, (left, right) = MAC_ITEM_SPEEDS, speeds
        if counters is not None:
            _check_pair("counters", counters, COUNTER_LIMIT)
            flags |= MAC_ITEM_COUNTERS
            a, b = counters
        link = self._links.get(agent)
        if link is None or link._closed.is_set():
            return False
        now = self._now
        try:
            session = link._session()
            lease = link._mac_lease
            if lease is not None and lease.session_id == session.session_id and now <= lease.end:
                # Under its MAC lease: one 29-byte record and its MAC, for the tick's
                # MacCommandBundle (no AgentCommand or MacCommand encoded per robot).
                record = _pack_item(session.next_seq(), now, flags, left, right, a, b)
                self._item_agents.append(agent)
                self._items.append(record)
                self._macs.append(lease.mac.item_tag(record))
                link.mac_sent += 1
            else:  # signed, until the MAC lease arrives: in a CommandBundle as before
                payload, _ = link._seal(
                    AgentCommand(agent=agent, speeds=speeds, counters=counters), now
                )
                self._out.append(BundledCommand(agent, payload))
        except Exception as exc:  # a closed session at shutdown, a lost login
            log.debug("could not send a command to %s: %s", agent, exc)
            return False
        # Handed to the channel in one go when the listeners return (one lock and one
        # clock read a tick instead of one per robot).
        self._sent.append(link)
        link.sent += 1
        return True


class _Listeners(Generic[L]):
    """Callbacks held in a tuple that is replaced whole under ``lock``: the channel's
    thread reads ``now`` without taking the lock."""

    def __init__(self, lock: threading.Lock) -> None:
        self._lock = lock
        self.now: tuple[L, ...] = ()

    def add(self, listener: L) -> Callable[[], None]:
        """Add ``listener``; returns the function that removes it."""
        with self._lock:
            self.now = (*self.now, listener)

        def remove() -> None:
            with self._lock:
                self.now = tuple(x for x in self.now if x is not listener)

        return remove


class WorldChannel:
    """One world's sample bundles in and command bundles out, shared by a process's links.

    Samples: one subscriber to ``world/<w>/samples``; each bundle's raw
    samples are handed to the attached links of those agents (decoded only
    when a controller reads). The world puts a bundle only for agents under
    a lease in force: a link on a channel sees no samples outside its slot.

    Commands: :meth:`submit` queues a sealed command (:meth:`submit_item` a
    MACed record); the first thread that finds no put in flight sends every
    queued command in one CommandBundle (the records in one
    MacCommandBundle), and commands queued meanwhile leave in its next put. Nothing waits for a
    batch to fill: alone, a command leaves at once; in a burst of 20, in a
    few messages instead of 20.

    Ticks: :meth:`on_tick` runs code in the channel's own thread right after
    each bundle was handed out, with its commands held until it returns: one
    thread answering many robots (a swarm) then costs no thread hand-off per
    robot and one message per tick. :meth:`on_swarm` does the same with the
    tick's decoded samples in arrays (:class:`SwarmTick`), without the
    per-robot controller objects.
    """

    def __init__(self, zsession: zenoh.Session, realm: str, world: str) -> None:
        self.realm, self.world = realm, world
        self._links: dict[str, ZenohRobotLink] = {}
        self._links_lock = threading.Lock()
        self._pending: list[BundledCommand] = []
        # MACed command records (link.send under a MAC lease), as MacCommandBundle's
        # arrays: agents, records, MACs (appended together under _pending_lock)
        self._pending_items: tuple[list[str], list[bytes], list[bytes]] = ([], [], [])
        self._pending_lock = threading.Lock()
        self._sending = threading.Lock()
        self._held = threading.local()  # burst() depth of the calling thread
        self._tick_listeners = _Listeners[Callable[[int, list[str]], None]](self._links_lock)
        self._swarm_listeners = _Listeners[Callable[[SwarmTick], None]](self._links_lock)
        self.bundles = 0  # sample bundles received
        self.puts = 0  # command bundles sent
        self.commands = 0  # commands sent in them
        self._publisher = zsession.declare_publisher(
            keys.world_commands(realm, world),
            congestion_control=zenoh.CongestionControl.DROP,
            express=True,
        )
        self._subscriber = zsession.declare_subscriber(
            keys.world_samples(realm, world), self._on_bundle
        )

    def attach(self, link: ZenohRobotLink) -> None:
        """Hand ``link`` its agent's samples from now on (the newest link of an agent wins:
        a slot's run may start while the one before it is still closing)."""
        with self._links_lock:
            self._links = {**self._links, link.agent: link}  # copied: the callback reads lock-free

    def detach(self, link: ZenohRobotLink) -> None:
        with self._links_lock:
            if self._links.get(link.agent) is link:
                self._links = {a: x for a, x in self._links.items() if a != link.agent}

    def _on_bundle(self, sample: zenoh.Sample) -> None:
        try:
            bundle = decode(sample.payload, SampleBundle)
        except MessageError as exc:
            log.warning("ignored a malformed sample bundle of %s: %s", self.world, exc)
            return
        if bundle.world != self.world or len(bundle.agents) != len(bundle.samples):
            log.warning(
                "ignored a sample bundle naming world %s with %d agents for %d samples",
                bundle.world,
                len(bundle.agents),
                len(bundle.samples),
            )
            return
        self.bundles += 1
        links = self._links
        listeners, swarms = self._tick_listeners.now, self._swarm_listeners.now
        if not (listeners or swarms):
            # Controller threads only (the runner): every woken thread waits for this
            # one to give up the GIL, so hand the samples out and return.
            for agent, raw in zip(bundle.agents, bundle.samples, strict=True):
                link = links.get(agent)
                if link is not None:
                    link.deliver(bytes(raw))
            return
        delivered = []
        raws = []
        for agent, raw in zip(bundle.agents, bundle.samples, strict=True):
            link = links.get(agent)
            if link is not None:
                data = bytes(raw)
                link.deliver(data)
                delivered.append(agent)
                raws.append(data)
        if not delivered:
            return
        with self.burst():
            for listener in listeners:
                try:
                    listener(bundle.tick, delivered)
                except Exception:  # one faulty listener must not starve the others
                    log.exception("a tick listener of %s failed (kept serving)", self.world)
            if swarms:
                self._run_swarms(swarms, bundle.tick, delivered, raws, links)

    def _run_swarms(
        self,
        swarms: tuple[Callable[[SwarmTick], None], ...],
        tick: int,
        delivered: list[str],
        raws: list[bytes],
        links: dict[str, ZenohRobotLink],
    ) -> None:
        agents, samples = [], []
        for agent, raw in zip(delivered, raws, strict=True):
            try:  # each sample decoded once for every swarm listener; validated as any input
                sample = decode(raw, SensorSample)
            except MessageError as exc:
                log.warning("ignored a malformed sensor sample of %s: %s", agent, exc)
                continue
            if sample.agent != agent:
                log.warning("ignored a sample of %s filed under %s", sample.agent, agent)
                continue
            agents.append(agent)
            samples.append(sample)
        if not agents:
            return
        handed = SwarmTick(tick, agents, samples, links)
        for swarm in swarms:
            try:
                swarm(handed)
            except Exception:  # as for tick listeners: the others still run
                log.exception("a swarm listener of %s failed (kept serving)", self.world)
            finally:  # what it sent before failing goes out too, as with link.send
                if handed._items:
                    self._put_mac_items(handed._item_agents, handed._items, handed._macs)
                    handed._item_agents, handed._items, handed._macs = [], [], []
                if handed._out:
                    with self._pending_lock:
                        self._pending.extend(handed._out)
                    handed._out = []
        now = time.monotonic()
        for link in handed._sent:  # their keep-alives are not due
            link._last_send = now

    def _put_mac_items(self, agents: list[str], items: list[bytes], macs: list[bytes]) -> None:
        """Put MACed command records (a swarm tick's, or links') as MacCommandBundles, now."""
        for i in range(0, len(agents), MAX_BUNDLED):
            j = i + MAX_BUNDLED
            if i == 0 and len(agents) <= MAX_BUNDLED:  # the usual case: no copies
                bundle = MacCommandBundle(agents=agents, items=b"".join(items), macs=b"".join(macs))
            else:
                bundle = MacCommandBundle(
                    agents=agents[i:j], items=b"".join(items[i:j]), macs=b"".join(macs[i:j])
                )
            payload = encode(bundle)
            try:
                self._publisher.put(payload)
            except Exception as exc:  # a closed session at shutdown
                log.debug("could not put a command bundle of %s: %s", self.world, exc)
                return
            self.puts += 1
            self.commands += min(j, len(agents)) - i

    def on_tick(self, listener: Callable[[int, list[str]], None]) -> Callable[[], None]:
        """Call ``listener(tick, agents)`` after each bundle that brought ``agents`` a sample.

        It runs in the channel's thread (keep it short: the next bundle waits
        for it), after the links have their samples, so ``link.latest()`` is
        that tick's; the commands it sends leave together when it returns.
        Returns the function that removes it.
        """
        return self._tick_listeners.add(listener)

    def on_swarm(self, listener: Callable[[SwarmTick], None]) -> Callable[[], None]:
        """Call ``listener(tick)`` with each bundle's decoded samples of this channel's agents.

        Like :meth:`on_tick` (the channel's thread, after the links have their
        samples, commands held until it returns), but the listener reads
        ``tick.samples`` and answers with ``tick.send(agent, speeds=...)``.
        Returns the function that removes it.
        """
        return self._swarm_listeners.add(listener)

    @contextlib.contextmanager
    def burst(self) -> Iterator[None]:
        """Hold this thread's commands until the block ends, then send them in one bundle.

        For code that answers many robots in one thread (a swarm controller):
        one message for the burst instead of one per robot.
        """
        self._held.count = getattr(self._held, "count", 0) + 1
        try:
            yield
        finally:
            self._held.count -= 1
            if self._held.count == 0:
                self._flush()

    def submit(self, agent: str, payload: bytes) -> None:
        """Send ``payload`` (what would go on ``agent/<agent>/cmd``) in the next bundle."""
        with self._pending_lock:
            self._pending.append(BundledCommand(agent, payload))
        if not getattr(self._held, "count", 0):
            self._flush()

    def submit_item(self, agent: str, record: bytes, mac: bytes) -> None:
        """Send one MACed command record (``MAC_ITEM_STRUCT``) and its MAC in the next
        MacCommandBundle: what ``link.send`` makes of speeds or counters under a MAC lease."""
        with self._pending_lock:
            agents, records, macs = self._pending_items
            agents.append(agent)
            records.append(record)
            macs.append(mac)
        if not getattr(self._held, "count", 0):
            self._flush()

    def _flush(self) -> None:
        # Runs in a controller's thread, once per command when a burst is sparse:
        # locals and no empty lists swapped, as the others of the burst wait for the GIL.
        sending, pending_lock = self._sending, self._pending_lock
        while sending.acquire(False):
            try:
                with pending_lock:
                    batch, items = self._pending, self._pending_items
                    if batch:
                        self._pending = []
                    if items[0]:
                        self._pending_items = ([], [], [])
                if items[0]:
                    self._put_mac_items(*items)
                for i in range(0, len(batch), MAX_BUNDLED):
                    chunk = batch[i : i + MAX_BUNDLED]
                    self._publisher.put(encode(CommandBundle(commands=chunk)))
                    self.puts += 1
                    self.commands += len(chunk)
            finally:
                sending.release()
            # Queued while this put was in flight, by threads that found it sending
            # (they queue before they try, so one of them or this sends it).
            with pending_lock:
                if not self._pending and not self._pending_items[0]:
                    return

    def close(self) -> None:
        for handle in (self._subscriber, self._publisher):
            try:
                handle.undeclare()
            except Exception as exc:
                log.debug("undeclare: %s", exc)
