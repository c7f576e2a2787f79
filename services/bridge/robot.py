"""KheperaRobot: the thesis's KheperaReal over a SerialKheperaLink, plus auto-detection of robots.

One I/O thread per robot owns its link, so everything on the wire happens in
one order: queued commands first (in the order they were given), then the
next sensor request of the polling round (proximity, ambient, counters,
speeds and, every few rounds, the gripper). Readers get the newest
:class:`RobotState` snapshot (the thesis's "stale by one update" values,
kept fresh by the poll instead of by the controller's own queries).

Safety: a watchdog sets the motors to zero when no command came for
``watchdog`` seconds (300 ms by default), :meth:`KheperaRobot.halt` does it at
once (the lease ended), and stopping the robot does it before the port closes.

A port that vanishes (unplugged) or stops answering makes the robot
offline; the thread reopens the port every ``reconnect_interval`` seconds
and is online again as soon as the robot answers B.

Odometry is in odometry.py; auto-detection and the Fleet in detect.py.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar

from common.controller.actuators import Actuators
from services.bridge import protocol as P
from services.bridge.link import LinkError, LinkOffline, LinkOptions, SerialKheperaLink
from services.bridge.odometry import Odometry, Pose

log = logging.getLogger("wart.bridge.robot")

T = TypeVar("T")

LEDS = 2  # a Khepera I has two LEDs (L,0 and L,1)


class RobotStopped(LinkError):
    """The robot handle was stopped before the command could be sent."""


class CommandDropped(LinkError):
    """A queued command was dropped by halt() before it was sent."""


@dataclass(frozen=True)
class RobotOptions:
    """Polling, safety and odometry settings of one robot."""

    baud: int = 38400
    poll_interval: float = 0.05  # s from the start of one sensor round to the next (0: flat out)
    watchdog: float = 0.3  # s without a command before the motors are zeroed
    reconnect_interval: float = 0.5  # s between attempts to reopen a lost port
    offline_after: int = 2  # consecutive failed requests (each after all its tries) = offline
    gripper: bool | None = None  # None: ask the turret (T,1,B) when the robot comes online
    gripper_every: int = 4  # poll the gripper every Nth round (it changes slowly)
    mm_per_pulse: float = 0.08  # some K-Team code says 1/12 mm
    wheel_base_mm: float = 53.0
    link: LinkOptions = field(default_factory=LinkOptions)

    def __post_init__(self) -> None:
        if self.poll_interval < 0 or self.watchdog <= 0 or self.reconnect_interval <= 0:
            raise ValueError("poll_interval >= 0, watchdog > 0 and reconnect_interval > 0 required")
        if self.gripper_every < 1 or self.offline_after < 1:
            raise ValueError("gripper_every and offline_after must be at least 1")
        if self.mm_per_pulse <= 0 or self.wheel_base_mm <= 0:
            raise ValueError("mm_per_pulse and wheel_base_mm must be positive")


@dataclass(frozen=True)
class GripperState:
    arm: int  # 0..255, about 165 up to 255 down
    fingers: int  # finger position reading
    object: int  # object-presence barrier reading
    resistivity: int = 255  # of the held object (T,1,F); 255 with nothing held


@dataclass(frozen=True)
class RobotState:
    """One consistent snapshot of what the host knows of the robot (None: not read yet)."""

    port: str
    online: bool = False
    version: P.Version | None = None
    proximity: tuple[int, ...] | None = None
    ambient: tuple[int, ...] | None = None
    counters: P.WheelPair | None = None
    speed: P.WheelPair | None = None
    gripper: GripperState | None = None
    leds: tuple[int, int] = (0, 0)  # as last set by L (the robot cannot be asked)
    pose: Pose = field(default_factory=Pose)  # frozen: the same as one shared default
    rounds: int = 0  # completed sensor rounds since start
    updated: float = 0.0  # time.monotonic() of the last completed round
    # time.time() when the robot was where ``pose`` says: the middle of the counters'
    # request and its answer (0: never read). Not the round's end: a loaded host reads the
    # rest of the round for tens of ms while the robot drives on.
    pose_at: float = 0.0
    watchdog_stops: int = 0
    errors: int = 0  # requests that failed after all their tries


@dataclass
class _Queued:
    request: P.Request[Any]
    future: Future[Any]


LinkFactory = Callable[[str, int, LinkOptions, Callable[[str], None]], SerialKheperaLink]


def _open_link(
    port: str, baud: int, options: LinkOptions, on_banner: Callable[[str], None]
) -> SerialKheperaLink:
    return SerialKheperaLink.open(port, baud, options, on_banner=on_banner)


class KheperaRobot(Actuators):
    """A real or emulated Khepera on one serial port: start it, read ``state()``, send commands.

    Its actuators are the one interface every robot has
    (:class:`common.controller.actuators.Actuators`), each a serial request.
    """

    def __init__(
        self,
        port: str,
        options: RobotOptions | None = None,
        *,
        link_factory: LinkFactory = _open_link,
    ) -> None:
        self.port = port
        self.options = options or RobotOptions()
        self._link_factory = link_factory
        self._link: SerialKheperaLink | None = None
        self._state = RobotState(port=port)
        self._state_lock = threading.Lock()
        self._queue: deque[_Queued] = deque()
        self._wake = threading.Condition()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._listeners: list[Callable[[RobotState], None]] = []
        self._odometry = Odometry(self.options.mm_per_pulse, self.options.wheel_base_mm)
        self._pose_at = 0.0  # time.time() of the counter reading behind the odometry's pose
        self._last_command = 0.0
        self._motors_on = False
        self._halt_requested = False
        self._gripper = self.options.gripper
        self._failures = 0
        self._online_event = threading.Event()
        self.commands_failed = 0  # actuator requests that failed (logged as they fail)

    # ------------------------------------------------------------ lifecycle

    def start(self) -> KheperaRobot:
        if self._thread is None:
            self._thread = threading.Thread(
                target=self._run, name=f"khepera {self.port}", daemon=True
            )
            self._thread.start()
        return self

    def stop(self, timeout: float = 3.0) -> None:
        """Zero the motors (if the robot answers), close the port, end the thread."""
        self._stop.set()
        with self._wake:
            self._wake.notify_all()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                log.error("%s: I/O thread did not stop within %.1f s", self.port, timeout)
            self._thread = None

    def __enter__(self) -> KheperaRobot:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------ what callers use

    @property
    def online(self) -> bool:
        return self._state.online

    def state(self) -> RobotState:
        with self._state_lock:
            return self._state

    def add_listener(self, callback: Callable[[RobotState], None]) -> None:
        """Called from the I/O thread after every sensor round and on online/offline changes."""
        self._listeners.append(callback)

    def wait_online(self, timeout: float) -> bool:
        return self._online_event.wait(timeout)

    # -- actuators (common.controller.actuators.Actuators): each queues its request;
    # nobody waits on it (a Zenoh callback calls these), so a failure is logged and counted.

    def set_speeds(self, left: int, right: int) -> None:
        """Wheel speeds in pulses per 10 ms (clamped to ±127); keeps the watchdog fed."""
        self._actuate(P.set_speed(left, right))

    def set_counters(self, left: int, right: int) -> None:
        self._actuate(P.set_counters(left, right))

    def set_leds(self, leds: Sequence[bool]) -> None:
        """A Khepera has two LEDs; more are ignored."""
        for led, on in enumerate(leds[:LEDS]):
            self._actuate(P.set_led(led, P.LED_ON if on else P.LED_OFF))

    def set_arm(self, position: int) -> None:
        self._actuate(P.gripper_arm(position))

    def set_grip(self, closed: bool) -> None:
        self._actuate(P.gripper_fingers(closed))

    def _actuate(self, request: P.Request[Any]) -> None:
        self.command(request).add_done_callback(lambda f: self._actuator_done(request, f))

    def _actuator_done(self, request: P.Request[Any], future: Future[Any]) -> None:
        exc = future.exception()
        if exc is None:
            return
        self.commands_failed += 1
        if isinstance(exc, LinkOffline):  # expected while unplugged: the state says offline
            log.debug("%s: command %s failed: %s", self.port, request.letter, exc)
        elif isinstance(exc, P.ProtocolError):  # unanswered, not understood
            log.warning("%s: command %s failed: %s", self.port, request.letter, exc)
        else:
            log.error("%s: command %s failed: %r", self.port, request.letter, exc)

    def command(self, request: P.Request[T]) -> Future[T]:
        """Queue any request; it is sent before the next sensor request, in call order.

        The future fails at once with LinkOffline while the robot is offline.
        """
        future: Future[T] = Future()
        if self._stop.is_set():
            future.set_exception(RobotStopped(f"{self.port}: robot handle is stopped"))
            return future
        if not self._state.online:
            # Refused, not kept: a motor command replayed when the robot returns
            # (maybe minutes later) would move it for no one.
            future.set_exception(LinkOffline(f"{self.port}: robot offline"))
            return future
        with self._wake:
            self._last_command = time.monotonic()
            self._queue.append(_Queued(request, future))
            self._wake.notify_all()
        return future

    def keepalive(self) -> None:
        """Feed the watchdog without sending anything (a controller's empty command)."""
        with self._wake:
            self._last_command = time.monotonic()

    def halt(self) -> None:
        """Zero the motors now (the lease ended, an operator stop).

        Commands still queued are dropped (their futures fail with
        CommandDropped): they were given for a slot that is over, and a
        queued ``D`` sent after the halt would start the robot again.
        Commands given after halt() are sent as usual.
        """
        with self._wake:
            self._halt_requested = True
            queued, self._queue = list(self._queue), deque()
            self._wake.notify_all()
        for item in queued:
            if not item.future.done():
                item.future.set_exception(CommandDropped(f"{self.port}: halted before it was sent"))

    def set_pose(self, pose: Pose) -> None:
        """Place the odometry estimate (e.g. where the robot was put in the arena)."""
        self._odometry.set_pose(pose)
        self._pose_at = time.time()
        self._update(pose=pose, pose_at=self._pose_at)

    # ------------------------------------------------------------ the I/O thread

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                if self._link is None:
                    if not self._connect():
                        self._stop.wait(self.options.reconnect_interval)
                    continue
                try:
                    self._cycle()
                except LinkOffline as exc:
                    self._go_offline(str(exc))
        finally:
            self._shutdown()

    def _connect(self) -> bool:
        try:
            link = self._link_factory(
                self.port, self.options.baud, self.options.link, self._on_banner
            )
        except LinkOffline as exc:
            log.debug("%s: %s", self.port, exc)
            return False
        try:
            version = link.request(P.read_version())
            if self.options.gripper is None:
                try:
                    link.request(P.gripper_version())
                    self._gripper = True
                except P.ProtocolError:
                    self._gripper = False
            # Whatever the robot was doing before we (re)connected is nobody's command.
            link.request(P.set_speed(0, 0))
            # The pose is measured from here: a command sent the moment the robot is
            # online moves it before the first sensor round reads the counters.
            counters = link.request(P.read_counters())
        except P.ProtocolError as exc:
            log.info("%s: opened but no Khepera answered: %s", self.port, exc)
            link.close()
            return False
        self._link, self._failures, self._motors_on = link, 0, False
        self._odometry.rebaseline((counters.left, counters.right), time.monotonic())
        log.info(
            "%s: Khepera online (BIOS %s, protocol %s, gripper %s)",
            self.port,
            version.bios,
            version.protocol,
            "yes" if self._gripper else "no",
        )
        self._update(online=True, version=version)
        self._online_event.set()
        return True

    def _go_offline(self, why: str) -> None:
        log.warning("%s: Khepera offline: %s", self.port, why)
        if self._link is not None:
            self._link.close()
        self._link, self._motors_on = None, False
        self._online_event.clear()
        self._fail_queued(LinkOffline(f"{self.port}: robot offline"))
        self._update(online=False)

    def _shutdown(self) -> None:
        link = self._link
        if link is not None:
            try:
                link.request(P.set_speed(0, 0))
            except P.ProtocolError as exc:
                log.warning("%s: could not zero the motors at stop: %s", self.port, exc)
            link.close()
        self._link = None
        self._fail_queued(RobotStopped(f"{self.port}: robot handle stopped"))
        self._update(online=False)

    def _fail_queued(self, exc: Exception) -> None:
        with self._wake:
            queued, self._queue = list(self._queue), deque()
        for item in queued:
            if not item.future.done():
                item.future.set_exception(exc)

    def _cycle(self) -> None:
        """One pass: halt, queued commands, watchdog, then one sensor round; then wait."""
        next_round = time.monotonic()
        while not self._stop.is_set():
            self._service_commands()
            now = time.monotonic()
            if now >= next_round:
                self._sensor_round()
                next_round = max(next_round + self.options.poll_interval, time.monotonic())
                continue
            with self._wake:
                if not self._queue and not self._halt_requested and not self._stop.is_set():
                    self._wake.wait(min(next_round - now, self._watchdog_due() - now, 0.1))

    def _watchdog_due(self) -> float:
        return self._last_command + self.options.watchdog if self._motors_on else math.inf

    def _service_commands(self) -> None:
        """Halt first, then every queued command, then the watchdog."""
        if self._halt_requested:
            self._halt_requested = False
            self._zero_motors("halt")
        while True:
            with self._wake:
                if not self._queue:
                    break
                item = self._queue.popleft()
            if not item.future.set_running_or_notify_cancel():
                continue
            try:
                result = self._request(item.request)
            except LinkOffline as exc:
                item.future.set_exception(exc)
                raise
            except P.ProtocolError as exc:
                item.future.set_exception(exc)
                continue
            self._after_command(item.request)
            item.future.set_result(result)
        if time.monotonic() >= self._watchdog_due():
            log.warning(
                "%s: no command for %.0f ms: motors zeroed", self.port, self.options.watchdog * 1000
            )
            self._zero_motors("watchdog")

    def _after_command(self, request: P.Request[Any]) -> None:
        letter = request.letter
        if letter in ("D", "P"):
            self._motors_on = any(v != 0 for v in request.fields)
        elif letter == "C":
            self._motors_on = True
        elif letter == "G":
            # Counters set by hand are not a movement; the wheels' travel after it is.
            left, right = (int(f) for f in request.fields)
            self._odometry.rebaseline((left, right), time.monotonic())
        elif letter == "L":
            led, action = (int(f) for f in request.fields)
            leds = list(self._state.leds)
            if 0 <= led < len(leds):
                leds[led] = 1 - leds[led] if action == 2 else action
                self._update(leds=(leds[0], leds[1]))

    def _zero_motors(self, why: str) -> None:
        try:
            self._request(P.set_speed(0, 0))
        except LinkOffline:
            raise
        except P.ProtocolError as exc:
            log.error("%s: could not zero the motors (%s): %s", self.port, why, exc)
            return
        self._motors_on = False
        if why == "watchdog":
            with self._state_lock:
                self._state = replace(self._state, watchdog_stops=self._state.watchdog_stops + 1)

    def _request(self, request: P.Request[T]) -> T:
        """One request on the link, counting failures; too many in a row means offline."""
        link = self._link
        if link is None:
            raise LinkOffline(f"{self.port}: robot offline")
        try:
            result = link.request(request)
        except P.CommandNotFound:
            self._failures = 0  # the robot answered: it is there
            raise
        except LinkOffline:
            raise
        except LinkError:
            self._failures += 1
            with self._state_lock:
                self._state = replace(self._state, errors=self._state.errors + 1)
            if self._failures >= self.options.offline_after:
                raise LinkOffline(
                    f"{self.port}: {self._failures} requests in a row unanswered"
                ) from None
            raise
        self._failures = 0
        return result

    def _sensor_round(self) -> None:
        changes: dict[str, Any] = {}
        reads: list[tuple[str, Callable[[], object]]] = [
            ("proximity", lambda: self._request(P.read_proximity()).values),
            ("ambient", lambda: self._request(P.read_ambient()).values),
            ("counters", self._read_counters),
            ("speed", lambda: self._request(P.read_speed())),
        ]
        rounds = self._state.rounds
        if self._gripper and rounds % self.options.gripper_every == 0:
            reads.append(("gripper", self._read_gripper))
        for name, read in reads:
            # Commands go before every sensor request, so a slow round never delays them.
            self._service_commands()
            try:
                changes[name] = read()
            except LinkOffline:
                raise
            except P.ProtocolError as exc:
                log.warning("%s: %s read failed: %s", self.port, name, exc)
        changes["pose"], changes["pose_at"] = self._odometry.pose, self._pose_at
        self._update(rounds=rounds + 1, updated=time.monotonic(), **changes)

    def _read_counters(self) -> P.WheelPair:
        # The pose is advanced the moment the counters are read, not at the end of the
        # round: a reset banner seen by a later read of the same round (E, the gripper)
        # must rebaseline after this reading, or the round would end by taking the
        # pre-reset counters as the new reference and the next delta would run backwards.
        asked = time.time()
        counters = self._request(P.read_counters())
        self._odometry.update(counters.left, counters.right, time.monotonic())
        self._pose_at = (asked + time.time()) / 2
        return counters

    def _read_gripper(self) -> GripperState:
        return GripperState(
            arm=self._request(P.gripper_arm_position()).value,
            fingers=self._request(P.gripper_finger_position()).value,
            object=self._request(P.gripper_object()).value,
            resistivity=self._request(P.gripper_resistivity()).value,
        )

    def _on_banner(self, line: str) -> None:
        # The robot rebooted: its counters restarted at zero, its motors and LEDs are off.
        self._odometry.rebaseline()
        self._motors_on = False
        self._update(leds=(0, 0))

    def _update(self, **changes: Any) -> None:
        with self._state_lock:
            self._state = replace(self._state, **changes)
            state = self._state
        for callback in list(self._listeners):
            try:
                callback(state)
            except Exception:  # a listener's bug must not stop the robot's I/O
                log.exception("%s: state listener failed", self.port)
