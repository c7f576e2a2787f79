"""A robot over Zenoh: the RobotLink that ``wart control`` and the runner drive robots with.

:class:`ZenohRobotLink` turns the agent's ``SensorSample`` stream into
:class:`~common.controller.KheperaState` and a controller's RobotCommands
into ``AgentCommand`` messages sealed with the driving session (the one the
agent's lease names). A simulated world and a real one publish the same
keys and messages, so the same controller drives either, unchanged.

The sensor callback only keeps the newest raw sample (a slow controller must
never stall the Zenoh session); decoding happens when the controller reads.
While the link is open, a keep-alive (an empty command, which only feeds the
world's watchdog) goes out when the controller has sent nothing for
``keepalive`` seconds: a controller that set its speeds once keeps moving,
and one whose process dies stops within the watchdog's 300 ms.

A process that drives many robots of one world (the runner) gives its links
one shared :class:`WorldChannel`: each tick's samples of every leased agent
then arrive in one message (``world/<w>/samples``) and the controllers'
commands leave in as few messages as the burst allows (``world/<w>/cmds``).
On a loaded host Zenoh's cost per message, not per byte, is what delays a
burst of 20 robots' samples and commands (docs/BENCHMARKS.md).

Given a verifier, the link also listens to the agent's lease: when the lease
names its session and carries the lease key sealed to it (a MAC lease,
common/world/leasemac.py), commands go out as MacCommands (a keyed BLAKE2b, a few
µs for the world to check) instead of Ed25519 envelopes. Until such a lease
arrives (the context republishes it every second), commands are signed.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterator

import zenoh

from common import keys
from common.auth import AuthError, Session, Verifier
from common.controller import (
    ARM_UP,
    COUNTER_LIMIT,
    LIGHT_SENSORS,
    MAX_SPEED,
    PROXIMITY_SENSORS,
    KheperaState,
    RobotCommand,
)
from common.messages import (
    MAC_ITEM_COUNTERS,
    MAC_ITEM_SPEEDS,
    MAC_ITEM_STRUCT,
    MAX_BUNDLED,
    AgentCommand,
    BundledCommand,
    CommandBundle,
    Lease,
    MacCommandBundle,
    MessageError,
    SampleBundle,
    SensorSample,
    decode,
    encode,
)
from common.world.leasemac import CommandMac, open_key

log = logging.getLogger("wart.remote_robot")

PRESENCE_THRESHOLD = 128
"""A presence barrier reading at or above this means an object is between the fingers."""


def _fit(values: list[int], count: int, fill: int) -> tuple[int, ...]:
    """Exactly ``count`` values within 0..1023 (robot types differ in sensor counts)."""
    if len(values) == count:  # the usual case, 50 times a second per robot: no copies
        out = tuple(values)
    elif len(values) > count:
        out = tuple(values[:count])
    else:
        out = (*values, *([fill] * (count - len(values))))
    if out and (min(out) < 0 or max(out) > 1023):  # rare: clamp only then
        out = tuple(max(0, min(1023, v)) for v in out)
    return out


def _speed(value: int) -> int:
    return value if -MAX_SPEED <= value <= MAX_SPEED else max(-MAX_SPEED, min(MAX_SPEED, value))


def state_from_sample(sample: SensorSample) -> KheperaState:
    """What a controller sees of one SensorSample."""
    gripper = sample.gripper
    leds = sample.leds
    left, right = sample.speeds
    proximity, ambient = sample.proximity, sample.ambient
    # The usual sample (a Khepera's 8 + 8 readings, in range) as tuples at once;
    # _fit pads, cuts and clamps the others.
    if len(proximity) == PROXIMITY_SENSORS and min(proximity) >= 0 and max(proximity) <= 1023:
        prox = tuple(proximity)
    else:
        prox = _fit(proximity, PROXIMITY_SENSORS, 0)
    if len(ambient) == LIGHT_SENSORS and min(ambient) >= 0 and max(ambient) <= 1023:
        amb = tuple(ambient)
    else:
        amb = _fit(ambient, LIGHT_SENSORS, 500)
    return KheperaState(
        time=sample.sim_time,
        speeds=(
            left if -MAX_SPEED <= left <= MAX_SPEED else _speed(left),
            right if -MAX_SPEED <= right <= MAX_SPEED else _speed(right),
        ),
        counters=sample.counters,
        proximity=prox,
        ambient=amb,
        leds=(bool(leds[0]) if leds else False, bool(leds[1]) if len(leds) > 1 else False),
        arm=gripper.arm if gripper else ARM_UP,
        gripper_closed=bool(gripper and gripper.fingers != "open"),
        object_present=bool(gripper and gripper.presence >= PRESENCE_THRESHOLD),
        resistivity=gripper.resistivity if gripper else 0,
    )


def agent_command(agent: str, command: RobotCommand) -> AgentCommand:
    """A controller's command as the AgentCommand the world obeys."""
    return AgentCommand(
        agent=agent,
        speeds=command.speeds,
        counters=command.counters,
        leds=None if command.leds is None else list(command.leds),
        arm=command.arm,
        grip=command.grip,
    )


class _MacLease:
    """The lease key this link's session holds, from a MAC lease, and its MAC on the link's key."""

    __slots__ = ("end", "lease_id", "mac", "sealed", "session_id")

    def __init__(
        self, lease_id: str, session_id: bytes, key: bytes, sealed: bytes, cmd_key: str
    ) -> None:
        self.lease_id, self.session_id, self.sealed = lease_id, session_id, sealed
        self.mac = CommandMac(key, cmd_key, lease_id)
        self.end = 0.0


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
    (docs/BENCHMARKS.md, issue 22). Valid for the listener's call only.
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


class WorldChannel:
    """One world's sample bundles in and command bundles out, shared by a process's links.

    Samples: one subscriber to ``world/<w>/samples``; each bundle's raw
    samples are handed to the attached links of those agents (decoded only
    when a controller reads). The world puts a bundle only for agents under
    a lease in force: a link on a channel sees no samples outside its slot.

    Commands: :meth:`submit` queues a sealed command; the first thread that
    finds no put in flight sends every queued command in one CommandBundle,
    and commands queued meanwhile leave in its next put. Nothing waits for a
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
        self._pending_lock = threading.Lock()
        self._sending = threading.Lock()
        self._held = threading.local()  # burst() depth of the calling thread
        self._tick_listeners: tuple[Callable[[int, list[str]], None], ...] = ()
        self._swarm_listeners: tuple[Callable[[SwarmTick], None], ...] = ()
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
        delivered = []
        raws = []
        for agent, raw in zip(bundle.agents, bundle.samples, strict=True):
            link = links.get(agent)
            if link is not None:
                data = bytes(raw)
                link.deliver(data)
                delivered.append(agent)
                raws.append(data)
        listeners, swarms = self._tick_listeners, self._swarm_listeners
        if not delivered or not (listeners or swarms):
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
        """Put MACed command records (a swarm tick's) as MacCommandBundles, now."""
        for i in range(0, len(agents), MAX_BUNDLED):
            j = i + MAX_BUNDLED
            payload = encode(
                MacCommandBundle(
                    agents=agents[i:j], items=b"".join(items[i:j]), macs=b"".join(macs[i:j])
                )
            )
            try:
                self._publisher.put(payload)
            except Exception as exc:  # a closed session at shutdown
                log.debug("could not put a command bundle of %s: %s", self.world, exc)
                return
            self.puts += 1
            self.commands += len(agents[i:j])

    def on_tick(self, listener: Callable[[int, list[str]], None]) -> Callable[[], None]:
        """Call ``listener(tick, agents)`` after each bundle that brought ``agents`` a sample.

        It runs in the channel's thread (keep it short: the next bundle waits
        for it), after the links have their samples, so ``link.latest()`` is
        that tick's; the commands it sends leave together when it returns.
        Returns the function that removes it.
        """
        with self._links_lock:
            self._tick_listeners = (*self._tick_listeners, listener)

        def remove() -> None:
            with self._links_lock:
                self._tick_listeners = tuple(x for x in self._tick_listeners if x is not listener)

        return remove

    def on_swarm(self, listener: Callable[[SwarmTick], None]) -> Callable[[], None]:
        """Call ``listener(tick)`` with each bundle's decoded samples of this channel's agents.

        Like :meth:`on_tick` (the channel's thread, after the links have their
        samples, commands held until it returns), but the listener reads
        ``tick.samples`` and answers with ``tick.send(agent, speeds=...)``.
        Returns the function that removes it.
        """
        with self._links_lock:
            self._swarm_listeners = (*self._swarm_listeners, listener)

        def remove() -> None:
            with self._links_lock:
                self._swarm_listeners = tuple(x for x in self._swarm_listeners if x is not listener)

        return remove

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

    def _flush(self) -> None:
        while self._sending.acquire(blocking=False):
            try:
                with self._pending_lock:
                    batch, self._pending = self._pending, []
                for i in range(0, len(batch), MAX_BUNDLED):
                    chunk = batch[i : i + MAX_BUNDLED]
                    self._publisher.put(encode(CommandBundle(commands=chunk)))
                    self.puts += 1
                    self.commands += len(chunk)
            finally:
                self._sending.release()
            with self._pending_lock:
                if not self._pending:
                    return

    def close(self) -> None:
        for handle in (self._subscriber, self._publisher):
            try:
                handle.undeclare()
            except Exception as exc:
                log.debug("undeclare: %s", exc)


class ZenohRobotLink:
    """A RobotLink to ``world/<world>/agent/<agent>`` over an open Zenoh session.

    ``session`` returns the driving session at send time (a service's
    session may be renewed while it runs). ``verifier`` (the registry key's)
    lets it accept MAC leases; without one it always signs. ``channel``: get
    samples and send commands through a shared :class:`WorldChannel` (of the
    same world) instead of the agent's own keys.
    """

    def __init__(
        self,
        zsession: zenoh.Session,
        realm: str,
        world: str,
        agent: str,
        session: Callable[[], Session],
        *,
        keepalive: float = 0.1,
        verifier: Verifier | None = None,
        channel: WorldChannel | None = None,
    ) -> None:
        if channel is not None and channel.world != world:
            raise ValueError(f"a channel of world {channel.world} cannot carry {world}/{agent}")
        self.world = world
        self.agent = agent
        self._session = session
        self._cmd_key = keys.agent_cmd(realm, world, agent)
        self._channel = channel
        self._publisher = (
            zsession.declare_publisher(
                self._cmd_key, congestion_control=zenoh.CongestionControl.DROP, express=True
            )
            if channel is None
            else None
        )
        self._lock = threading.Lock()
        self._raw: bytes | None = None
        self._raw_seq = 0
        self._decoded_seq = 0
        self._state = KheperaState()
        self._fresh = threading.Condition(self._lock)
        self._waiting = 0  # threads in wait_sample (under _lock)
        self._last_send = 0.0
        self._closed = threading.Event()
        self.samples = 0
        self.sent = 0
        self.refused = 0  # commands that could not be turned into an AgentCommand
        self.mac_sent = 0  # of ``sent``, those MACed under a MAC lease
        self._verifier = verifier
        self._mac_lease: _MacLease | None = None
        self._lease_key = keys.agent_lease(realm, world, agent)
        self._lease_sub = (
            zsession.declare_subscriber(self._lease_key, self._on_lease)
            if verifier is not None
            else None
        )
        self._subscriber = None
        self._watch = None
        if channel is not None:
            channel.attach(self)
        else:
            self._subscriber = zsession.declare_subscriber(
                keys.agent_sensors(realm, world, agent), self._on_sample
            )
            # A world of many robots publishes a robot's samples once it is watched.
            self._watch = zsession.liveliness().declare_token(keys.agent_watch(realm, world, agent))
        self._keepalive_s = keepalive
        self._keepalive = threading.Thread(
            target=self._keep_alive, name=f"keepalive-{agent}", daemon=True
        )
        self._keepalive.start()

    # -- the Zenoh side (callback: keep it short)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        self.deliver(bytes(sample.payload.to_bytes()))

    def deliver(self, raw: bytes) -> None:
        """Keep ``raw`` (an encoded SensorSample) as the newest; wake whoever waits.

        One thread delivers to a link (its subscriber's, or its channel's), so
        the sample and its number are set without the lock, the sample first
        (``latest`` relies on that order). The lock is taken only to wake a
        waiter: ``wait_sample`` counts itself in ``_waiting`` under the lock
        before it tests the number, so either it sees the new number or this
        sees it waiting and notifies (after it released the lock in ``wait``).
        """
        self._raw = raw
        self._raw_seq += 1
        self.samples += 1
        if self._waiting:  # a swarm answering in the channel's thread waits on nothing
            with self._fresh:
                self._fresh.notify_all()

    def _on_lease(self, sample: zenoh.Sample) -> None:
        assert self._verifier is not None
        try:
            principal, lease = self._verifier.open(self._lease_key, sample.payload, Lease)
            if not principal.has("lease") or lease.agent != self.agent or lease.world != self.world:
                return  # not a lease this link may trust; the world refuses it too
            session = self._session()
            if lease.holder_session != session.session_id or lease.holder_key is None:
                return
            current = self._mac_lease
            if current is not None and current.sealed == lease.holder_key:
                current.end = lease.end  # a republication (maybe ended early): same key
                return
            key = open_key(lease.holder_key, session.keys.box_key)
        except (AuthError, MessageError) as exc:
            log.debug("ignored a lease on %s: %s", self.agent, exc)
            return
        except Exception as exc:  # not logged in (yet), a session closing
            log.debug("could not read a lease on %s: %s", self.agent, exc)
            return
        self._mac_lease = _MacLease(
            lease.lease_id, session.session_id, key, lease.holder_key, self._cmd_key
        )
        self._mac_lease.end = lease.end
        log.info("lease %s on %s: commands MACed from now on", lease.lease_id, self.agent)

    # -- RobotLink

    def latest(self) -> KheperaState:
        # Read without the lock: deliver() sets _raw before _raw_seq, so the raw
        # sample read after the number is at least that new (one lock a read
        # less, 50 times a second per robot).
        seq = self._raw_seq
        if seq == self._decoded_seq:
            return self._state
        raw = self._raw
        if raw is None:
            return self._state
        try:
            state = state_from_sample(decode(raw, SensorSample))
        except MessageError as exc:
            log.warning("ignored a malformed sensor sample of %s: %s", self.agent, exc)
            state = self._state
        with self._lock:
            if seq > self._decoded_seq:
                self._state, self._decoded_seq = state, seq
            return self._state

    def send(self, command: RobotCommand) -> None:
        if self._closed.is_set():
            return
        self._put(agent_command(self.agent, command))

    def _seal(self, message: AgentCommand, now: float) -> tuple[bytes, bool]:
        """``message`` for this link's key: MACed under its MAC lease if it holds one in
        force at ``now`` (True), else signed with the driving session (False)."""
        session = self._session()
        lease = self._mac_lease
        if lease is not None and lease.session_id == session.session_id and now <= lease.end:
            return lease.mac.command(session.next_seq(), message, now), True
        return session.seal(self._cmd_key, message), False

    def _put(self, message: AgentCommand) -> bool:
        """MAC (or sign) ``message`` for this link's key and send it; False if it could not."""
        try:
            payload, mac = self._seal(message, time.time())
            if self._channel is not None:
                self._channel.submit(self.agent, payload)
            else:
                assert self._publisher is not None
                self._publisher.put(payload)
        except Exception as exc:  # a closed session at shutdown, a lost login
            log.debug("could not send a command to %s: %s", self.agent, exc)
            return False
        self.sent += 1
        self.mac_sent += mac
        self._last_send = time.monotonic()
        return True

    # -- extras for relays and tools

    def wait_sample(self, after: int, timeout: float) -> int:
        """Block until a sample newer than number ``after`` arrived; returns the newest number."""
        with self._fresh:
            self._waiting += 1
            try:
                self._fresh.wait_for(
                    lambda: self._raw_seq > after or self._closed.is_set(), timeout
                )
            finally:
                self._waiting -= 1
            return self._raw_seq

    def _keep_alive(self) -> None:
        while not self._closed.wait(self._keepalive_s / 2):
            if time.monotonic() - self._last_send >= self._keepalive_s:
                self._put(AgentCommand(agent=self.agent))

    def close(self, *, stop: bool = True) -> None:
        """Stop the keep-alive and undeclare; with ``stop``, first tell the robot to stop."""
        if self._closed.is_set():
            return
        if stop:
            self._put(AgentCommand(agent=self.agent, speeds=(0, 0)))
        self._closed.set()
        with self._fresh:
            self._fresh.notify_all()
        if self._channel is not None:
            self._channel.detach(self)
        for handle in (self._subscriber, self._watch, self._publisher, self._lease_sub):
            if handle is None:
                continue
            try:
                handle.undeclare()
            except Exception as exc:
                log.debug("undeclare: %s", exc)

    def __enter__(self) -> ZenohRobotLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
