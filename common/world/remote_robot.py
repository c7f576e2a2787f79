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
one shared :class:`WorldChannel` (common/world/world_channel.py): each
tick's samples of every leased agent then arrive in one message
(``world/<w>/samples``) and the controllers' commands leave in as few
messages as the burst allows (``world/<w>/cmds``).
On a loaded host Zenoh's cost per message, not per byte, is what delays a
burst of 20 robots' samples and commands (docs/BENCHMARKS.md).

Given a verifier, the link also listens to the agent's lease: when the lease
names its session and carries the lease key sealed to it (a MAC lease,
common/world/leasemac.py), commands go out as MacCommands (a keyed BLAKE2b, a few
µs for the world to check) instead of Ed25519 envelopes; on a channel, speeds
and counters go as MacCommandBundle items (a record and its MAC, as a swarm
tick's). Until such a lease arrives (the context republishes it every
second), commands are signed.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import threading
import time
from collections.abc import Callable

import zenoh

from common import keys
from common.auth import AuthError, Session, Verifier
from common.controller import (
    ARM_UP,
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
    AgentCommand,
    Lease,
    MessageError,
    SensorSample,
    decode,
)
from common.world.leasemac import CommandMac, open_key
from common.world.world_channel import SwarmTick as SwarmTick  # callers import it from here
from common.world.world_channel import WorldChannel

log = logging.getLogger("wart.remote_robot")

_pack_item = MAC_ITEM_STRUCT.pack  # 50 times a second per robot: one lookup less

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
    # Positional, in _STATE_FIELDS' order (checked at import): 0.3 µs less than by
    # keyword, 50 times a second per robot in the controller's own thread.
    return KheperaState(
        sample.sim_time,
        (
            left if -MAX_SPEED <= left <= MAX_SPEED else _speed(left),
            right if -MAX_SPEED <= right <= MAX_SPEED else _speed(right),
        ),
        sample.counters,
        prox,
        amb,
        (bool(leds[0]) if leds else False, bool(leds[1]) if len(leds) > 1 else False),
        gripper.arm if gripper else ARM_UP,
        bool(gripper and gripper.fingers != "open"),
        bool(gripper and gripper.presence >= PRESENCE_THRESHOLD),
        gripper.resistivity if gripper else 0,
        {k: tuple(v) for k, v in sample.parts.items()} if sample.parts else {},
    )


_STATE_FIELDS = (
    "time",
    "speeds",
    "counters",
    "proximity",
    "ambient",
    "leds",
    "arm",
    "gripper_closed",
    "object_present",
    "resistivity",
    "parts",
)
if tuple(f.name for f in dataclasses.fields(KheperaState)) != _STATE_FIELDS:
    raise ImportError("KheperaState's fields changed: update state_from_sample's positional call")


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
        # Released: a sample (or the close) may be new to a waiter. A bare lock, not a
        # Condition: deliver() then releases it in one C call instead of notifying
        # under the lock in Python, for each of the bundle's links, while every
        # woken controller thread waits for the channel's thread to give up the GIL.
        self._signal = threading.Lock()
        self._signal.acquire()
        self._waiting = 0  # threads blocked in wait_sample (under _lock; for tests)
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
        (``latest`` relies on that order), then the signal released: a waiter
        tests the number before it blocks on the signal, so either it sees the
        new number or its acquire returns at once. No lock is taken here.
        """
        self._raw = raw
        self._raw_seq += 1
        self.samples += 1
        if self._signal.locked():
            self._raise_signal()

    def _raise_signal(self) -> None:
        # Several threads may release it at once (this, close, a waiter passing it on).
        with contextlib.suppress(RuntimeError):
            self._signal.release()

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
        channel, lease = self._channel, self._mac_lease
        if (
            channel is not None
            and lease is not None
            and command.leds is None
            and command.arm is None
            and command.grip is None
            and self._send_item(channel, lease, command)
        ):
            return
        self._put(agent_command(self.agent, command))

    def _send_item(self, channel: WorldChannel, lease: _MacLease, command: RobotCommand) -> bool:
        """Speeds or counters under the MAC lease, as one MacCommandBundle item; False if
        the lease is not this session's or not in force (the caller then signs).

        The item is what a swarm tick sends (SwarmTick.send): a 29-byte record and
        its MAC under the lease key, bound to this agent's key expression and the
        lease id, checked by the world exactly as a MacCommand (lease in force,
        fresh, sequence number unseen). It spares the encoded AgentCommand and
        MacCommand per command here and their two decodes in the world, which
        checks the items of a bundle in one pass: the runner's 20 controller
        threads each send one a tick (docs/BENCHMARKS.md, "Control loop").
        RobotCommand checked the values' types and ranges when it was made.
        """
        try:
            session = self._session()
            now = time.time()
            if lease.session_id != session.session_id or now > lease.end:
                return False
            flags, left, right, a, b = 0, 0, 0, 0, 0
            speeds, counters = command.speeds, command.counters
            if speeds is not None:
                flags, (left, right) = MAC_ITEM_SPEEDS, speeds
            if counters is not None:
                flags |= MAC_ITEM_COUNTERS
                a, b = counters
            record = _pack_item(session.next_seq(), now, flags, left, right, a, b)
            channel.submit_item(self.agent, record, lease.mac.item_tag(record))
        except Exception as exc:  # a closed session at shutdown, a lost login: as _put
            log.debug("could not send a command to %s: %s", self.agent, exc)
            return True
        self.sent += 1
        self.mac_sent += 1
        self._last_send = time.monotonic()
        return True

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
        """Block until a sample newer than number ``after`` arrived; returns the newest number.

        Several threads may wait on one link: the one the signal wakes passes
        it on before it returns, so each of them wakes for the new sample (the
        signal then stays raised, and a later wait finds it stale: it tests the
        number again and blocks).
        """
        seq = self._raw_seq
        if seq > after or self._closed.is_set():
            return seq
        deadline = time.monotonic() + timeout
        signal = self._signal
        with self._lock:
            self._waiting += 1
        try:
            while True:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not signal.acquire(True, remaining):
                    return self._raw_seq
                seq = self._raw_seq
                if seq > after or self._closed.is_set():
                    self._raise_signal()  # for another thread waiting on this link
                    return seq
        finally:
            with self._lock:
                self._waiting -= 1

    def _keep_alive(self) -> None:
        # Asleep until a keep-alive would be due, not woken every half period: the
        # runner has a link (and this thread) per robot, and a controller that sends
        # every tick never needs one; every wake-up takes the GIL from the loop.
        period = self._keepalive_s
        wait = period
        while not self._closed.wait(wait):
            idle = time.monotonic() - self._last_send
            if idle >= period:
                self._put(AgentCommand(agent=self.agent))
                wait = period
            else:
                wait = period - idle

    def close(self, *, stop: bool = True) -> None:
        """Stop the keep-alive and undeclare; with ``stop``, first tell the robot to stop."""
        if self._closed.is_set():
            return
        if stop:
            self._put(AgentCommand(agent=self.agent, speeds=(0, 0)))
        self._closed.set()
        self._raise_signal()
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
