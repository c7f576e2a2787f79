"""SimBody: the emulated Khepera's physical robot is a Khepera of a Sim2D world.

The emulator's firmware asks a :class:`~services.bridge.body.RobotBody` for
everything physical; this one answers from the Sim2D engine's Khepera model
(the same drive, IR curve, ambient model and gripper as ``wart engine``), so
the emulated robot's sensors respond to a simulated arena loaded from a map:
walls and obstacles raise its IR readings, lamps lower its ambient readings,
balls can be gripped.

Wheels may slip (``slip``): the robot then moves less than its wheels turn,
as a real Khepera's does on a smooth floor, so the counters the host reads
overstate the motion and its odometry drifts: the left wheel by ``slip``, the
right by half of it, so the drift turns as well as stretches. A body file
(services/bridge/body_truth.py) sets each wheel's grip, the wheel base, the delay
before a command moves the wheels, and each IR sensor's gain and noise: the
ground truth ``wart calibrate`` is tested against. Given a truth
file, the thread writes the robots' true poses there about 30 times a second
for the synthetic camera (common/tracking/truth.py), which then corrects that
drift as a real overhead camera does.

Threads: pymunk is not thread-safe, so the world is touched only under
``self._lock``. Our own thread steps it at ``tick_s``, paced to the wall
clock (the robot keeps moving whether or not the host asks anything); the
emulator's I/O thread calls the RobotBody methods, which take the same lock
for a read or a command between two ticks, after running the ticks already
due: a loaded host starves the stepping thread, and the robot must still be
where the wall clock says when it is read, as a real one is.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from common.sim2d.maps import load_map
from common.sim2d.world import EditError, World
from common.tracking.truth import now_truth, write_truth
from common.worker import Worker
from services.bridge.body import KinematicSpec
from services.bridge.body_truth import BodyTruth

log = logging.getLogger("wart.bridge.simbody")
STALL_S = 0.5  # a stepping thread this late loses the time instead of making it up


class SimBody:
    """A RobotBody over one agent of a Sim2D World stepped by its own thread."""

    def __init__(
        self,
        world: World,
        agent: str | None = None,
        *,
        spec: KinematicSpec | None = None,
        speed: float = 1.0,
        slip: float = 0.0,
        truth: Path | None = None,
        body: BodyTruth | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not 0.0 <= slip < 0.5:
            raise ValueError(
                f"slip must be 0 to 0.5 (a fraction of the wheels' motion); got {slip}"
            )
        if not world.agents:
            raise ValueError("the map has no agents: the emulated Khepera needs one to be")
        self.world = world
        self.agent = agent or world.agents[0].id
        try:
            self.slot = world.agent_slot(self.agent)
        except KeyError:
            raise ValueError(f"the map has no agent {self.agent!r}") from None
        kind = world.agents[self.slot].spec.name
        if kind != "khepera":
            raise ValueError(f"agent {self.agent!r} is a {kind}, not a khepera")
        self.spec = spec or KinematicSpec()
        self.rate = speed  # times real time
        self._lock = threading.Lock()
        self._mode = "speed"  # "speed" | "position" (C: counter targets)
        self._target = (0, 0)
        self._vmax = (20, 20)
        self._worker = Worker(self._run, "sim-body")
        self.ticks = 0
        self.body = body or BodyTruth.slipping(slip)
        # What the floor gives of each wheel's turn (1: no slip).
        self._grip = self.body.wheel_scale
        if self.body.wheel_base_mm is not None:
            world.tables.wheel_base[self.slot] = self.body.wheel_base_mm
        # Speed commands wait out the body's latency here: (due on the monotonic clock, l, r).
        self._pending: deque[tuple[float, float, float]] = deque()
        self._noise = np.random.default_rng(self.body.seed)
        self._clock = clock  # a rehearsal (services/bridge/rehearse.py) keeps simulated time
        self.truth = truth
        self._truth_at = 0.0
        self._due: float | None = None  # the next tick, while our thread steps the world

    @classmethod
    def from_map(
        cls,
        path: Path,
        agent: str | None = None,
        *,
        seed: int = 0,
        tick_s: float = 0.01,
        slip: float = 0.0,
        truth: Path | None = None,
        body: BodyTruth | None = None,
    ) -> SimBody:
        """Load a map (MapError names the field) and take ``agent`` (default: the first one)."""
        world = load_map(path, name="emulator", seed=seed, tick_s=tick_s)
        return cls(world, agent, slip=slip, truth=truth, body=body)

    # ------------------------------------------------------------ the stepping thread

    def start(self) -> SimBody:
        if not self._worker.running:
            with self._lock:
                self.world.sense()  # readings valid before the first tick
            self._worker.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        self._worker.stop(timeout)
        with self._lock:
            self._due = None

    def __enter__(self) -> SimBody:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        with self._lock:
            self._due = time.monotonic()
        while not self._worker.stopping.is_set():
            with self._lock:
                self._catch_up()
                truth = self._true_poses()
                due = self._due
            if truth is not None and self.truth is not None:
                try:
                    write_truth(self.truth, now_truth(self.world.width, self.world.height, truth))
                except OSError as exc:
                    log.warning("cannot write the truth file %s: %s", self.truth, exc)
            if due is not None:
                self._worker.wait(max(0.0, due - time.monotonic()))

    def _catch_up(self) -> None:
        """Under the lock: the ticks due by now, so whatever is read or commanded finds
        the robot where the wall clock says, not where a starved stepping thread left it
        (a loaded host's thread ran late, then caught up in a burst: a reading meanwhile
        was of a robot up to half a second behind its time, stamped with the time).
        After a longer stall the time is lost, not made up (a robot does not leap)."""
        if self._due is None:
            return  # no stepping thread: a driver with its own clock ticks the world
        now = time.monotonic()
        if now - self._due > STALL_S:
            self._due = now
        period = self.world.tick_s / self.rate
        while self._due <= now:
            try:
                self._tick(self._due)
            except Exception:  # one bad tick must not freeze the robot for good
                log.exception("sim body: error in tick %d (kept running)", self.world.tick)
            self._due += period

    def _true_poses(self) -> dict[str, tuple[float, float, float]] | None:
        """Every robot's pose when a truth file is due (about 30 a second), else None."""
        now = time.monotonic()
        if self.truth is None or now - self._truth_at < 0.033:
            return None
        self._truth_at = now
        poses = self.world.agent_pose
        return {
            a.id: (float(poses[i, 0]), float(poses[i, 1]), float(poses[i, 2]))
            for i, a in enumerate(self.world.agents)
        }

    def _counted(self, wheel: int) -> float:
        """The counter the host reads: the wheel's turn, not the slipping robot's motion."""
        return float(self.world.counters[self.slot, wheel]) / self._grip[wheel]

    def _drive(self, left: float, right: float) -> None:
        self.world.set_speeds(self.slot, left * self._grip[0], right * self._grip[1])

    def _tick(self, at: float | None = None) -> None:
        """One tick; ``at``: when it is due on the body's clock (None: now)."""
        self._obey_due(self._clock() if at is None else at)
        self._position_control()
        self.world.step()
        # Again after the step, so a wheel that just reached its target
        # reads speed 0 now, not one tick later.
        self._position_control()
        self.ticks += 1

    def tick(self) -> None:
        """One tick of the world, as the stepping thread does: for a driver that keeps
        its own clock instead of starting the thread."""
        with self._lock:
            self._tick()

    def _obey_due(self, now: float) -> None:
        """The speed commands whose latency has passed by ``now`` move the wheels."""
        while self._pending and self._pending[0][0] <= now:
            _, left, right = self._pending.popleft()
            self._drive(left, right)

    def _position_control(self) -> None:
        """C: each wheel at up to its profile speed toward its counter target, stopping on it."""
        if self._mode != "position":
            return
        w, s = self.world, self.slot
        per_tick = w.tick_s * float(w.tables.pulses_per_s_per_unit[s])  # pulses a unit a tick
        out = []
        for i in (0, 1):
            remaining = self._target[i] - self._counted(i)
            out.append(max(-self._vmax[i], min(self._vmax[i], remaining / per_tick)))
        self._drive(out[0], out[1])

    # ------------------------------------------------------------ RobotBody

    def advance(self, now: float) -> None:
        """Nothing to do: the world is stepped by its own thread, on the wall clock."""

    def set_speeds(self, left: int, right: int) -> None:
        with self._lock:
            self._catch_up()
            self._mode = "speed"
            if self.body.latency_s <= 0.0:
                self._drive(left, right)
                return
            self._pending.append((self._clock() + self.body.latency_s / self.rate, left, right))

    def set_pwm(self, left: int, right: int) -> None:
        k = self.spec.pwm_to_speed
        self.set_speeds(round(left * k), round(right * k))

    def move_to(self, left: int, right: int, vmax: tuple[int, int], acc: tuple[int, int]) -> None:
        with self._lock:
            self._catch_up()
            self._mode, self._target = "position", (left, right)
            self._vmax = (max(1, vmax[0]), max(1, vmax[1]))

    def speed(self) -> tuple[int, int]:
        with self._lock:
            self._catch_up()
            cmd = self.world.cmd[self.slot]
            return round(float(cmd[0]) / self._grip[0]), round(float(cmd[1]) / self._grip[1])

    def counters(self) -> tuple[int, int]:
        with self._lock:
            self._catch_up()
            return _wrap32(round(self._counted(0))), _wrap32(round(self._counted(1)))

    def set_counters(self, left: int, right: int) -> None:
        with self._lock:
            self._catch_up()
            self.world.set_counters(self.slot, left * self._grip[0], right * self._grip[1])
            if self._mode == "position":
                self._target = (left, right)

    def motion_status(self) -> tuple[int, int, int, int, int, int]:
        with self._lock:
            self._catch_up()
            out: list[int] = []
            for i in (0, 1):
                if self._mode == "position":
                    err = round(self._target[i] - self._counted(i))
                    out += [int(err == 0), 0, err]
                else:
                    out += [1, 1, 0]
            return out[0], out[1], out[2], out[3], out[4], out[5]

    def proximity(self) -> tuple[int, ...]:
        with self._lock:
            self._catch_up()
            raw = np.asarray(self.world.proximity[self.slot, :8], dtype=float)
            read = raw * np.asarray(self.body.ir_gain)
            if self.body.ir_noise_counts > 0.0:
                read = read + self._noise.normal(0.0, self.body.ir_noise_counts, read.shape)
            return tuple(_sensor(float(v)) for v in read)

    def ambient(self) -> tuple[int, ...]:
        with self._lock:
            return tuple(_sensor(v) for v in self.world.ambient[self.slot, :8])

    def analog(self, channel: int) -> int:
        return 0  # nothing is wired to the A/D inputs of the simulated robot

    def set_leds(self, leds: Sequence[bool]) -> None:
        """The simulated robot shows them (a viewer of its world draws them)."""
        with self._lock:
            self.world.set_leds(self.slot, leds)

    def set_grip(self, closed: bool) -> None:
        with self._lock:
            try:
                self.world.set_grip(self.slot, closed)
            except EditError as exc:  # a map agent with "gripper": false
                log.info("sim body: %s", exc)

    def set_arm(self, position: int) -> None:
        with self._lock:
            try:
                self.world.set_arm(self.slot, position)
            except EditError as exc:
                log.info("sim body: %s", exc)

    def finger_position(self) -> int:
        with self._lock:
            closed = self.world.gripper_state(self.slot) != 0
        return self.spec.finger_closed if closed else self.spec.finger_open

    def arm_position(self) -> int:
        with self._lock:
            return max(0, min(255, round(float(self.world.arm[self.slot]))))

    def object_present(self) -> int:
        with self._lock:
            return max(0, min(255, int(self.world.presence[self.slot])))

    def resistivity(self) -> int:
        with self._lock:
            return max(0, min(255, self.world.resistivity(self.slot)))

    def reset(self) -> None:
        with self._lock:
            self._catch_up()
            self._mode = "speed"
            self._pending.clear()
            self.world.set_speeds(self.slot, 0, 0)
            self.world.set_counters(self.slot, 0, 0)

    # ------------------------------------------------------------ for tests and displays

    def pose(self) -> tuple[float, float, float]:
        """Where the simulated robot is: x mm, y mm, heading rad (world frame)."""
        with self._lock:
            self._catch_up()
            x, y, h = self.world.agent_pose[self.slot]
            return float(x), float(y), float(h)

    def place(self, x: float, y: float, heading: float) -> None:
        """Put the robot somewhere else in its arena (EditError if it would overlap)."""
        with self._lock:
            self.world.move(self.agent, x, y, heading)
            self.world.sense()


def _sensor(value: float) -> int:
    return max(0, min(1023, int(value)))


def _wrap32(value: int) -> int:
    return (value + 2**31) % 2**32 - 2**31
