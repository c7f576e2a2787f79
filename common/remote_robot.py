"""A robot over Zenoh: the RobotLink that ``wart control`` and the runner drive robots with.

:class:`ZenohRobotLink` turns the agent's ``SensorSample`` stream into
:class:`~common.controller.KheperaState` and a controller's command dicts
into ``AgentCommand`` messages sealed with the driving session (the one the
agent's lease names). A simulated world and a real one publish the same
keys and messages, so the same controller drives either, unchanged.

The sensor callback only keeps the newest raw sample (a slow controller must
never stall the Zenoh session); decoding happens when the controller reads.
While the link is open, a keep-alive (an empty command, which only feeds the
world's watchdog) goes out when the controller has sent nothing for
``keepalive`` seconds: a controller that set its speeds once keeps moving,
and one whose process dies stops within the watchdog's 300 ms.

Given a verifier, the link also listens to the agent's lease: when the lease
names its session and carries the lease key sealed to it (a MAC lease,
common/leasemac.py), commands go out as MacCommands (a keyed BLAKE2b, a few
µs for the world to check) instead of Ed25519 envelopes. Until such a lease
arrives (the context republishes it every second), commands are signed.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from common import keys
from common.auth import AuthError, Session, Verifier
from common.controller import (
    ARM_UP,
    LIGHT_SENSORS,
    MAX_SPEED,
    PROXIMITY_SENSORS,
    KheperaState,
)
from common.leasemac import mac_command, open_key
from common.messages import (
    AgentCommand,
    Lease,
    MessageError,
    SensorSample,
    decode,
)

log = logging.getLogger("wart.remote_robot")

PRESENCE_THRESHOLD = 128
"""A presence barrier reading at or above this means an object is between the fingers."""


def _fit(values: list[int], count: int, fill: int) -> tuple[int, ...]:
    """Exactly ``count`` values within 0..1023 (robot types differ in sensor counts)."""
    out = values[:count]
    if len(out) < count:
        out = out + [fill] * (count - len(out))
    if out and (min(out) < 0 or max(out) > 1023):  # rare: clamp only then (per sample, 50 Hz)
        out = [max(0, min(1023, v)) for v in out]
    return tuple(out)


def state_from_sample(sample: SensorSample) -> KheperaState:
    """What a controller sees of one SensorSample."""
    gripper = sample.gripper
    leds = [bool(v) for v in sample.leds[:2]] + [False, False]
    return KheperaState(
        time=sample.sim_time,
        speeds=(
            max(-MAX_SPEED, min(MAX_SPEED, sample.speeds[0])),
            max(-MAX_SPEED, min(MAX_SPEED, sample.speeds[1])),
        ),
        counters=(sample.counters[0], sample.counters[1]),
        proximity=_fit(sample.proximity, PROXIMITY_SENSORS, 0),
        ambient=_fit(sample.ambient, LIGHT_SENSORS, 500),
        leds=(leds[0], leds[1]),
        arm=gripper.arm if gripper else ARM_UP,
        gripper_closed=bool(gripper and gripper.fingers != "open"),
        object_present=bool(gripper and gripper.presence >= PRESENCE_THRESHOLD),
        resistivity=gripper.resistivity if gripper else 0,
    )


def state_to_dict(state: KheperaState) -> dict[str, Any]:
    """The plain mapping the sandbox's child reads back with KheperaState.from_dict."""
    return {
        "time": state.time,
        "speeds": list(state.speeds),
        "counters": list(state.counters),
        "proximity": list(state.proximity),
        "ambient": list(state.ambient),
        "leds": list(state.leds),
        "arm": state.arm,
        "gripper_closed": state.gripper_closed,
        "object_present": state.object_present,
        "resistivity": state.resistivity,
    }


def command_from_dict(agent: str, command: dict[str, Any]) -> AgentCommand:
    """A controller's command dict as an AgentCommand; ValueError if it is not one."""
    speeds = command.get("speeds")
    leds = command.get("leds")
    counters = command.get("counters")
    grip = command.get("grip")
    unknown = set(command) - {"speeds", "leds", "counters", "arm", "grip"}
    if unknown:
        raise ValueError(f"unknown command fields: {', '.join(sorted(unknown))}")
    return AgentCommand(
        agent=agent,
        speeds=(int(speeds[0]), int(speeds[1])) if speeds is not None else None,
        counters=(int(counters[0]), int(counters[1])) if counters is not None else None,
        leds=[1 if bool(v) else 0 for v in leds] if leds is not None else None,
        arm=int(command["arm"]) if command.get("arm") is not None else None,
        fingers=None if grip is None else ("closed" if grip else "open"),
    )


class _MacLease:
    """The lease key this link's session holds, from a MAC lease."""

    __slots__ = ("end", "key", "lease_id", "sealed", "session_id")

    def __init__(self, lease_id: str, session_id: bytes, key: bytes, sealed: bytes) -> None:
        self.lease_id, self.session_id, self.key, self.sealed = lease_id, session_id, key, sealed
        self.end = 0.0


class ZenohRobotLink:
    """A RobotLink to ``world/<world>/agent/<agent>`` over an open Zenoh session.

    ``session`` returns the driving session at send time (a service's
    session may be renewed while it runs). ``verifier`` (the registry key's)
    lets it accept MAC leases; without one it always signs.
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
    ) -> None:
        self.world = world
        self.agent = agent
        self._session = session
        self._cmd_key = keys.agent_cmd(realm, world, agent)
        self._publisher = zsession.declare_publisher(
            self._cmd_key, congestion_control=zenoh.CongestionControl.DROP, express=True
        )
        self._lock = threading.Lock()
        self._raw: bytes | None = None
        self._raw_seq = 0
        self._decoded_seq = 0
        self._state = KheperaState()
        self._fresh = threading.Condition(self._lock)
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
        self._subscriber = zsession.declare_subscriber(
            keys.agent_sensors(realm, world, agent), self._on_sample
        )
        self._keepalive_s = keepalive
        self._keepalive = threading.Thread(
            target=self._keep_alive, name=f"keepalive-{agent}", daemon=True
        )
        self._keepalive.start()

    # -- the Zenoh side (callback: keep it short)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        raw = bytes(sample.payload.to_bytes())
        with self._fresh:
            self._raw = raw
            self._raw_seq += 1
            self.samples += 1
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
        self._mac_lease = _MacLease(lease.lease_id, session.session_id, key, lease.holder_key)
        self._mac_lease.end = lease.end
        log.info("lease %s on %s: commands MACed from now on", lease.lease_id, self.agent)

    # -- RobotLink

    def latest(self) -> KheperaState:
        with self._lock:
            if self._raw_seq == self._decoded_seq or self._raw is None:
                return self._state
            raw, seq = self._raw, self._raw_seq
        try:
            state = state_from_sample(decode(raw, SensorSample))
        except MessageError as exc:
            log.warning("ignored a malformed sensor sample of %s: %s", self.agent, exc)
            state = self._state
        with self._lock:
            if seq > self._decoded_seq:
                self._state, self._decoded_seq = state, seq
            return self._state

    def send(self, command: dict[str, Any]) -> None:
        if self._closed.is_set():
            return
        try:
            message = command_from_dict(self.agent, command)
        except (ValueError, TypeError, IndexError, KeyError) as exc:
            self.refused += 1
            log.warning("refused a command for %s: %s", self.agent, exc)
            return
        self._put(message)

    def _put(self, message: AgentCommand) -> None:
        mac = False
        try:
            session = self._session()
            lease = self._mac_lease
            now = time.time()
            if lease is not None and lease.session_id == session.session_id and now <= lease.end:
                seq = session.next_seq()
                payload = mac_command(lease.key, self._cmd_key, lease.lease_id, seq, message, now)
                mac = True
            else:
                payload = session.seal(self._cmd_key, message)
            self._publisher.put(payload)
        except Exception as exc:  # a closed session at shutdown, a lost login
            log.debug("could not send a command to %s: %s", self.agent, exc)
            return
        self.sent += 1
        self.mac_sent += mac
        self._last_send = time.monotonic()

    # -- extras for relays and tools

    def wait_sample(self, after: int, timeout: float) -> int:
        """Block until a sample newer than number ``after`` arrived; returns the newest number."""
        with self._fresh:
            self._fresh.wait_for(lambda: self._raw_seq > after or self._closed.is_set(), timeout)
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
        for handle in (self._subscriber, self._publisher, self._lease_sub):
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
