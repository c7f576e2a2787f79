"""The physical robot behind an emulated Khepera: the RobotBody interface and a kinematic body.

The emulator's firmware (emulator.py) keeps what the robot's microcontroller
keeps (LEDs, PID gains, the speed profile, bus bytes) and asks a RobotBody for
everything physical: wheels, counters, sensors, the gripper. Phase 2 plugs
the Sim2D Khepera model in here so the emulated robot senses a simulated
arena; :class:`KinematicBody` is the stand-in: exact differential-drive
kinematics in the manual's units, sensors set by hand.

Units are the robot's: pulses, pulses per 10 ms, 10-bit readings, arm 0..255.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from common.controller.actuators import Actuators

TICK = 0.01  # s: the speed unit is pulses per 10 ms


@runtime_checkable
class RobotBody(Actuators, Protocol):
    """Everything physical the emulated firmware needs. ``now`` is time.monotonic() seconds.

    Its actuators are the one interface every robot has
    (:class:`common.controller.actuators.Actuators`: speeds, counters, LEDs,
    arm, grip); the rest is what only the serial firmware asks of a body.

    Every method may be called from the emulator's I/O thread; an
    implementation shared with another thread (a simulation engine) must
    lock its own state.
    """

    def advance(self, now: float) -> None:
        """Bring the body's state up to ``now`` (a kinematic body integrates it)."""

    def set_pwm(self, left: int, right: int) -> None:
        """Open-loop drive, -255..255 per wheel."""

    def move_to(self, left: int, right: int, vmax: tuple[int, int], acc: tuple[int, int]) -> None:
        """Position control: drive each wheel to its absolute counter target with the J profile."""

    def speed(self) -> tuple[int, int]:
        """Current wheel speeds, pulses per 10 ms."""

    def counters(self) -> tuple[int, int]:
        """Position counters, pulses (32-bit signed on the robot)."""

    def motion_status(self) -> tuple[int, int, int, int, int, int]:
        """Per wheel: on target (0/1), mode (0 position, 1 speed; polarity uncertain), error."""

    def proximity(self) -> tuple[int, ...]:
        """Eight IR proximity readings 0..1023, sensor order of docs/KHEPERA_PROTOCOL.md."""

    def ambient(self) -> tuple[int, ...]:
        """Eight ambient light readings 0..1023."""

    def analog(self, channel: int) -> int:
        """One 10-bit A/D channel."""

    def finger_position(self) -> int: ...

    def arm_position(self) -> int: ...

    def object_present(self) -> int: ...

    def resistivity(self) -> int: ...

    def reset(self) -> None:
        """What a robot reset does to the body: motors stop, counters restart at 0."""


@dataclass(frozen=True)
class KinematicSpec:
    """Khepera I geometry and units (docs/KHEPERA_PROTOCOL.md "Body and units")."""

    mm_per_pulse: float = 0.08  # some K-Team code says 1/12 mm
    wheel_base_mm: float = 53.0
    pwm_to_speed: float = 127 / 255  # open-loop PWM as a steady speed, a crude stand-in
    finger_open: int = 0
    finger_closed: int = 200


@dataclass
class Pose:
    x: float = 0.0  # mm
    y: float = 0.0  # mm
    heading: float = 0.0  # rad, counter-clockwise from +x


@dataclass
class KinematicBody:
    """Differential drive integrated exactly (arc per step); sensors are values tests set.

    Position control (C) drives each wheel at the profile's max speed toward
    its target and stops on it; acceleration is ignored (a documented
    simplification: the host only sees counters and K's status).
    """

    spec: KinematicSpec = field(default_factory=KinematicSpec)
    pose: Pose = field(default_factory=Pose)
    proximity_values: list[int] = field(default_factory=lambda: [0] * 8)
    ambient_values: list[int] = field(default_factory=lambda: [500] * 8)
    analog_values: dict[int, int] = field(default_factory=dict)
    object_value: int = 0
    resistivity_value: int = 0
    leds: tuple[bool, ...] = (False, False)  # as the firmware last set them
    _counts: list[float] = field(default_factory=lambda: [0.0, 0.0])
    _speed: list[float] = field(default_factory=lambda: [0.0, 0.0])
    _mode: str = "speed"  # "speed" | "position"
    _target: list[int] = field(default_factory=lambda: [0, 0])
    _vmax: list[int] = field(default_factory=lambda: [20, 20])
    _fingers_closed: bool = False
    _arm: int = 165
    _last: float | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def advance(self, now: float) -> None:
        with self._lock:
            if self._last is None:
                self._last = now
                return
            dt, self._last = now - self._last, now
            # Sub-steps of one speed tick keep position-control stops exact enough.
            while dt > 1e-9:
                step = min(dt, TICK)
                self._step(step)
                dt -= step

    def _step(self, dt: float) -> None:
        ticks = dt / TICK
        delta = [0.0, 0.0]
        for i in (0, 1):
            if self._mode == "position":
                remaining = self._target[i] - self._counts[i]
                move = math.copysign(min(abs(remaining), self._vmax[i] * ticks), remaining)
                self._speed[i] = (
                    0.0 if abs(remaining) < 0.5 else math.copysign(self._vmax[i], remaining)
                )
                delta[i] = move
            else:
                delta[i] = self._speed[i] * ticks
            self._counts[i] += delta[i]
        dl, dr = (d * self.spec.mm_per_pulse for d in delta)
        d_center, d_theta = (dl + dr) / 2, (dr - dl) / self.spec.wheel_base_mm
        mid = self.pose.heading + d_theta / 2
        self.pose.x += d_center * math.cos(mid)
        self.pose.y += d_center * math.sin(mid)
        self.pose.heading = math.remainder(self.pose.heading + d_theta, math.tau)

    def set_speeds(self, left: int, right: int) -> None:
        with self._lock:
            self._mode, self._speed = "speed", [float(left), float(right)]

    def set_pwm(self, left: int, right: int) -> None:
        k = self.spec.pwm_to_speed
        self.set_speeds(round(left * k), round(right * k))

    def move_to(self, left: int, right: int, vmax: tuple[int, int], acc: tuple[int, int]) -> None:
        with self._lock:
            self._mode, self._target, self._vmax = (
                "position",
                [left, right],
                [max(1, v) for v in vmax],
            )

    def speed(self) -> tuple[int, int]:
        with self._lock:
            return round(self._speed[0]), round(self._speed[1])

    def counters(self) -> tuple[int, int]:
        with self._lock:
            return _wrap32(round(self._counts[0])), _wrap32(round(self._counts[1]))

    def set_counters(self, left: int, right: int) -> None:
        with self._lock:
            self._counts = [float(left), float(right)]
            if self._mode == "position":
                self._target = [left, right]

    def motion_status(self) -> tuple[int, int, int, int, int, int]:
        with self._lock:
            out: list[int] = []
            for i in (0, 1):
                if self._mode == "position":
                    err = round(self._target[i] - self._counts[i])
                    out += [int(err == 0), 0, err]
                else:
                    out += [1, 1, 0]
            return out[0], out[1], out[2], out[3], out[4], out[5]

    def proximity(self) -> tuple[int, ...]:
        return tuple(_sensor(v) for v in self.proximity_values)

    def ambient(self) -> tuple[int, ...]:
        return tuple(_sensor(v) for v in self.ambient_values)

    def analog(self, channel: int) -> int:
        return _sensor(self.analog_values.get(channel, 0))

    def set_leds(self, leds: Sequence[bool]) -> None:
        with self._lock:
            self.leds = tuple(bool(on) for on in leds[:2])

    def set_grip(self, closed: bool) -> None:
        self._fingers_closed = closed

    def set_arm(self, position: int) -> None:
        self._arm = max(0, min(255, position))

    def finger_position(self) -> int:
        return self.spec.finger_closed if self._fingers_closed else self.spec.finger_open

    def arm_position(self) -> int:
        return self._arm

    def object_present(self) -> int:
        return self.object_value

    def resistivity(self) -> int:
        return self.resistivity_value

    def reset(self) -> None:
        with self._lock:
            self._counts, self._speed, self._mode = [0.0, 0.0], [0.0, 0.0], "speed"


def _sensor(value: int) -> int:
    return max(0, min(1023, int(value)))


def _wrap32(value: int) -> int:
    """The robot's counters are 32-bit signed and wrap."""
    return (value + 2**31) % 2**32 - 2**31
