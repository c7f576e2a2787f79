"""Named, frozen specifications of robot bodies and their components.

Every number carries its unit in its name or docstring (millimetres, radians,
seconds, grams). An agent type is one :class:`AgentTypeSpec`: a body plus
components (drive, IR proximity ring, ambient light ring, LEDs, an optional
gripper turret), and any batched sensors (:class:`PartSpec`: floor, range
finder, bumper, a plugin's). The world is generic over these specs; a robot
type is a TOML file (common/robots/robotfile.py compiles it into one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class SensorPose:
    """Where a sensor sits on the robot, in the robot frame (x forward, y left)."""

    x_mm: float
    y_mm: float
    heading_rad: float


def poses_deg(*rows: tuple[float, float, float]) -> tuple[SensorPose, ...]:
    """Sensor poses from (x mm, y mm, heading in degrees) rows, as manuals list them."""
    return tuple(SensorPose(x, y, math.radians(h)) for x, y, h in rows)


@dataclass(frozen=True)
class ResponseCurve:
    """A piecewise-linear map from distance (mm) to a raw sensor value.

    Calibratable: a lab measures its robots and replaces the table. Beyond the
    last distance the value is the last entry.
    """

    distances_mm: tuple[float, ...]
    values: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.distances_mm) != len(self.values) or len(self.values) < 2:
            raise ValueError("a response curve needs at least two (distance, value) points")
        if any(b <= a for a, b in zip(self.distances_mm, self.distances_mm[1:], strict=False)):
            raise ValueError("response curve distances must increase")

    @property
    def range_mm(self) -> float:
        return self.distances_mm[-1]

    def __call__(self, distance_mm: np.ndarray) -> np.ndarray:
        return np.interp(distance_mm, self.distances_mm, self.values)


@dataclass(frozen=True)
class DriveSpec:
    """Differential drive in the robot's native speed unit.

    A wheel speed of ``s`` units moves the wheel ``s * mm_per_pulse`` mm every
    ``unit_time_s`` seconds; the position counters count pulses.
    """

    wheel_base_mm: float
    mm_per_pulse: float
    unit_time_s: float  # the speed unit is pulses per this many seconds
    max_speed: int  # commands are clamped to +-max_speed units
    max_force: float = 2.0e6  # g*mm/s^2 the motors can push with (tank pattern pivot)
    max_torque: float = 5.0e8  # g*mm^2/s^2 (tank pattern gear)
    # A real robot's drive as its twin fitted it (common/twin/): the share of each
    # wheel's commanded motion the floor gives (slip), and how long after a command the
    # wheels obey it. The datasheet's robot: (1, 1) and 0, and the world skips them
    # (common/sim2d/real_wheels.py).
    wheel_scale: tuple[float, float] = (1.0, 1.0)
    latency_s: float = 0.0

    @property
    def imperfect(self) -> bool:
        return self.wheel_scale != (1.0, 1.0) or self.latency_s > 0.0

    def mm_per_s(self, speed_units: np.ndarray) -> np.ndarray:
        return speed_units * (self.mm_per_pulse / self.unit_time_s)


@dataclass(frozen=True)
class ProximitySpec:
    """An IR proximity ring: each sensor casts ``rays_per_sensor`` rays over ``spread_rad``.

    The reading is ``gain * curve(nearest hit distance)`` with multiplicative noise of
    ``noise_fraction`` (standard deviation) plus additive ``noise_counts`` (each
    sensor's own where ``noise_counts_each`` gives them), clipped to ``0..max_value``.
    """

    poses: tuple[SensorPose, ...]
    curve: ResponseCurve
    max_value: int = 1023
    rays_per_sensor: int = 3
    spread_rad: float = math.radians(30.0)  # total angle covered by the rays of one sensor
    noise_fraction: float = 0.03
    noise_counts: float = 2.0
    # A real robot's sensors as its twin fitted them (common/twin/): each sensor's reading
    # as a share of the curve's, and each one's additive noise in place of noise_counts.
    # Empty: 1 each, noise_counts each (the datasheet's robot).
    gains: tuple[float, ...] = ()
    noise_counts_each: tuple[float, ...] = ()

    def gain(self, sensor: int) -> float:
        return self.gains[sensor] if self.gains else 1.0

    def counts(self, sensor: int) -> float:
        return self.noise_counts_each[sensor] if self.noise_counts_each else self.noise_counts


@dataclass(frozen=True)
class AmbientSpec:
    """An ambient light ring (the Khepera Simulator's model).

    Each lit, visible light within ``half_angle_rad`` of a sensor's axis lowers
    the reading by ``cos(1.5 * bearing) * closeness * drop * intensity``, where
    closeness falls linearly from 1 at the light to 0 at the light's radius.
    """

    poses: tuple[SensorPose, ...]
    dark_value: int = 500
    floor_value: int = 50
    drop: float = 450.0
    half_angle_rad: float = math.radians(60.0)
    noise_fraction: float = 0.02


@dataclass(frozen=True)
class GripperSpec:
    """A gripper turret in front of the body (Khepera's gripper, thesis 6.8.3).

    The grip area is a box in the robot frame between the tongs; an object whose
    centre lies in it does not collide with the robot while the grip is open
    and the arm down (the collision exception area).
    """

    arm_down: int = 255  # arm position when on the floor
    arm_up: int = 165  # arm position fully raised
    lowered_above: int = 230  # the tongs touch the floor at or above this position
    arm_rate_per_s: float = 300.0  # arm position units per second
    tong_x_mm: tuple[float, float] = (20.0, 52.0)  # tongs from..to, robot frame
    tong_width_mm: float = 4.0
    gap_mm: float = 28.0  # between the open tongs
    grip_x_mm: tuple[float, float] = (28.0, 50.0)  # collision exception area along x
    presence_x_mm: tuple[float, float] = (30.0, 46.0)  # the light barrier between the fingers
    presence_half_width_mm: float = 10.0
    empty_resistivity: int = 255  # open circuit: nothing between the fingers


@dataclass(frozen=True)
class PartSpec:
    """A batched sensor a robot carries beyond the engine's own rings (floor, range, bumper).

    ``component`` is its type (a common.robots.schema.ComponentType subclass: it
    measures every robot carrying it at once), ``values`` its validated
    parameters, ``name`` the name the robot file gives it: the name a
    controller reads it by.
    """

    name: str
    component: Any
    values: dict[str, Any]
    size: int  # numbers in one robot's reading


@dataclass(frozen=True)
class ComponentInfo:
    """One component of a robot type as its file names it: what the controller API follows."""

    name: str  # the name in the robot file (components.<name>)
    type: str  # the component type (body, ir_proximity, floor_sensor, ...)
    role: str  # body, drive, proximity, ambient, leds, gripper, sensor
    values: dict[str, Any] = field(default_factory=dict)  # its parameters, defaults filled in


@dataclass(frozen=True)
class AgentTypeSpec:
    """Everything the world needs to simulate one robot type."""

    name: str
    radius_mm: float
    mass_g: float
    colour: str
    drive: DriveSpec
    proximity: ProximitySpec
    ambient: AmbientSpec
    leds: int = 2
    gripper: GripperSpec | None = None
    extra: dict[str, float] = field(default_factory=dict)
    parts: tuple[PartSpec, ...] = ()
    components: tuple[ComponentInfo, ...] = ()  # empty: a spec written in Python
    source: str = ""  # the robot file it was compiled from
    # That file's text: what a world sends along with its robots of this type, so a
    # process without the file (a runner, the grader) can simulate them.
    text: str = field(default="", compare=False, repr=False)

    @property
    def sensor_reach_mm(self) -> float:
        """How far from the centre any IR ray can see (0 without an IR ring)."""
        if not self.proximity.poses:
            return 0.0
        origin = max(math.hypot(p.x_mm, p.y_mm) for p in self.proximity.poses)
        return origin + self.proximity.curve.range_mm
