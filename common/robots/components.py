"""The engine's own component types: body, drive, IR proximity, ambient light, LEDs, gripper.

Each declares its parameters (common/robots/schema.py) and the controller
calls it gives; common/robots/robotfile.py compiles them into the engine's
:class:`common.sim2d.specs.AgentTypeSpec`, so the compiled kernels are
unchanged: a robot file is another way to write the same spec. The batched
sensors a robot may add (floor, range finder, bumper) are in
common/robots/sensors.py. Defaults are the Khepera's (common/sim2d/agents/khepera.py),
so a file sets only what differs.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from typing import Any

from common.robots.schema import ApiCall, ComponentType, Param, Segment

_GRIPPER_REF = "the Khepera's gripper turret, thesis 6.8.3"


class Body(ComponentType):
    name = "body"
    role = "body"
    doc = "The robot's disc: its size, mass and colour in the world view."
    params = (
        Param(
            "shape",
            "choice",
            "the body's outline (the engine's robots are discs)",
            "",
            "circle",
            choices=("circle",),
        ),
        Param("radius_mm", "number", "radius of the disc", "mm", lo=5.0, hi=500.0),
        Param(
            "mass_g", "number", "mass (pushes between robots share by mass)", "g", lo=1.0, hi=1e6
        ),
        Param("colour", "colour", "colour in the world view", "", "#2e8b57"),
    )

    @classmethod
    def preview(cls, values: Mapping[str, Any]) -> list[Segment]:
        """The rim (32 chords) and the heading (a line forward, a third beyond the rim)."""
        r = float(values["radius_mm"])
        rim = [(r * math.cos(a), r * math.sin(a)) for a in (i * math.pi / 16 for i in range(33))]
        return [(*a, *b) for a, b in itertools.pairwise(rim)] + [(0.0, 0.0, 1.3 * r, 0.0)]


def ray(x: float, y: float, angle: float, length: float) -> Segment:
    """A segment from (x, y) along ``angle`` (radians), robot frame."""
    return (x, y, x + length * math.cos(angle), y + length * math.sin(angle))


def cross(x: float, y: float, size: float = 3.0) -> list[Segment]:
    return [(x - size, y, x + size, y), (x, y - size, x, y + size)]


class Drive(ComponentType):
    name = "differential_drive"
    role = "drive"
    doc = (
        "Two wheels on a common axle with position counters. A speed of s units moves a "
        "wheel s * mm_per_pulse mm every unit_time_s seconds."
    )
    params = (
        Param("wheel_base_mm", "number", "distance between the wheels", "mm", lo=1.0, hi=1000.0),
        Param(
            "mm_per_pulse",
            "number",
            "distance a wheel moves per counter pulse",
            "mm",
            lo=1e-4,
            hi=100.0,
        ),
        Param(
            "unit_time_s",
            "number",
            "the speed unit is pulses per this many seconds",
            "s",
            lo=1e-4,
            hi=10.0,
        ),
        Param(
            "max_speed",
            "integer",
            "commands are clamped to ±max_speed units",
            "units",
            lo=1,
            hi=32767,
        ),
        Param(
            "max_force",
            "number",
            "force the motors can push with",
            "g·mm/s²",
            2.0e6,
            lo=1.0,
            hi=1e12,
        ),
        Param(
            "max_torque",
            "number",
            "torque the motors can turn with",
            "g·mm²/s²",
            5.0e8,
            lo=1.0,
            hi=1e14,
        ),
        Param(
            "wheel_scale",
            "numbers",
            "the share of each wheel's commanded motion the robot makes [left, right] "
            "(slip; a real robot's twin: wart calibrate)",
            "",
            [1.0, 1.0],
            lo=0.5,
            hi=1.5,
            max_items=2,
        ),
        Param(
            "latency_s",
            "number",
            "how long after a command the wheels obey it (a real robot's twin)",
            "s",
            0.0,
            lo=0.0,
            hi=0.5,
        ),
    )
    api = (
        ApiCall(
            "set_speeds(left, right)",
            "wheel speeds in the drive's units, clamped",
            "start the wheels",
        ),
        ApiCall("stop()", "-", "both wheels at 0"),
        ApiCall("speeds()", "Reading of 2 speeds (units)", "the speeds in force"),
        ApiCall("position()", "Reading of 2 counters (pulses)", "the wheels' position counters"),
        ApiCall("set_position(left, right)", "pulses", "set the position counters"),
    )

    @classmethod
    def cross_check(cls, values: Mapping[str, Any]) -> list[tuple[str, str]]:
        if len(values["wheel_scale"]) != 2:
            return [("wheel_scale", "must be two numbers [left, right]")]
        return []


class IrProximity(ComponentType):
    name = "ir_proximity"
    role = "proximity"
    doc = (
        "A ring of infrared proximity sensors. Each casts rays_per_sensor rays over spread_deg; "
        "the nearest hit goes through the response table (distance -> value, linear between "
        "rows, the last value beyond), times the sensor's gain (sensor_gains), then Gaussian "
        "noise of noise_fraction of the value plus noise_counts (or the sensor's "
        "sensor_noise_counts), clipped to 0..max_value."
    )
    params = (
        Param(
            "poses",
            "poses",
            "each sensor's [x, y, heading] on the body, robot frame",
            "mm, mm, °",
            max_items=16,
        ),
        Param(
            "table_mm", "numbers", "response table: distances, increasing", "mm", lo=0.0, hi=2000.0
        ),
        Param(
            "table_values",
            "numbers",
            "response table: the value at each distance",
            "counts",
            lo=0.0,
            hi=65535.0,
        ),
        Param("max_value", "integer", "largest reading", "counts", 1023, lo=1, hi=65535),
        Param("rays_per_sensor", "integer", "rays each sensor casts", "", 3, lo=1, hi=15),
        Param(
            "spread_deg",
            "number",
            "total angle the rays of one sensor cover",
            "°",
            30.0,
            lo=0.0,
            hi=180.0,
        ),
        Param(
            "noise_fraction",
            "number",
            "noise σ as a fraction of the value",
            "",
            0.03,
            lo=0.0,
            hi=1.0,
        ),
        Param("noise_counts", "number", "additive noise σ", "counts", 2.0, lo=0.0, hi=1000.0),
        Param(
            "sensor_gains",
            "numbers",
            "each sensor's reading as a share of the response table's, in the order of poses "
            "(a real robot's twin: wart calibrate); none: 1 each",
            "",
            [],
            lo=0.05,
            hi=10.0,
            max_items=16,
        ),
        Param(
            "sensor_noise_counts",
            "numbers",
            "each sensor's additive noise σ in place of noise_counts, in the order of poses "
            "(a real robot's twin); none: noise_counts each",
            "counts",
            [],
            lo=0.0,
            hi=1000.0,
            max_items=16,
        ),
    )
    api = (
        ApiCall(
            "proximity()",
            "Reading of one value per sensor (counts, larger is closer)",
            "the IR ring, in the order of poses",
        ),
    )

    @classmethod
    def preview(cls, values: Mapping[str, Any]) -> list[Segment]:
        """Each sensor's rays, as far as its response table reaches."""
        k = int(values["rays_per_sensor"])
        spread = math.radians(float(values["spread_deg"]))
        reach = float(values["table_mm"][-1])
        offsets = [spread * (i / (k - 1) - 0.5) for i in range(k)] if k > 1 else [0.0]
        return [
            ray(x, y, math.radians(h) + o, reach) for x, y, h in values["poses"] for o in offsets
        ]

    @classmethod
    def cross_check(cls, values: Mapping[str, Any]) -> list[tuple[str, str]]:
        out = []
        xs, ys = values["table_mm"], values["table_values"]
        if len(xs) != len(ys):
            out.append(("table_values", f"must hold as many values as table_mm ({len(xs)})"))
        elif len(xs) < 2:
            out.append(("table_mm", "a response table needs at least two rows"))
        elif any(b <= a for a, b in itertools.pairwise(xs)):
            out.append(("table_mm", "distances must increase"))
        sensors = len(values["poses"])
        for key in ("sensor_gains", "sensor_noise_counts"):
            given = len(values[key])
            if given and given != sensors:
                out.append((key, f"must hold one number per sensor ({sensors}), got {given}"))
        return out


class AmbientLight(ComponentType):
    name = "ambient_light"
    role = "ambient"
    doc = (
        "Ambient light sensors (the Khepera Simulator's model): each lit light within "
        "half_angle_deg of a sensor's axis lowers the reading from dark_value by up to drop, "
        "not below floor_value; Gaussian noise of noise_fraction of the value."
    )
    params = (
        Param(
            "poses",
            "poses",
            "each sensor's [x, y, heading] on the body, robot frame",
            "mm, mm, °",
            max_items=16,
        ),
        Param("dark_value", "integer", "the reading in the dark", "counts", 500, lo=0, hi=65535),
        Param(
            "floor_value",
            "integer",
            "the reading under the strongest light",
            "counts",
            50,
            lo=0,
            hi=65535,
        ),
        Param(
            "drop",
            "number",
            "how far one light of intensity 1 lowers the reading",
            "counts",
            450.0,
            lo=0.0,
            hi=65535.0,
        ),
        Param(
            "half_angle_deg",
            "number",
            "half the cone a sensor sees lights in",
            "°",
            60.0,
            lo=0.0,
            hi=180.0,
        ),
        Param(
            "noise_fraction",
            "number",
            "noise σ as a fraction of the value",
            "",
            0.02,
            lo=0.0,
            hi=1.0,
        ),
    )
    api = (
        ApiCall(
            "ambient()",
            "Reading of one value per sensor (counts, smaller is brighter)",
            "the light sensors, in the order of poses",
        ),
    )

    @classmethod
    def preview(cls, values: Mapping[str, Any]) -> list[Segment]:
        """A short tick along each sensor's axis."""
        return [ray(x, y, math.radians(h), 8.0) for x, y, h in values["poses"]]


class Leds(ComponentType):
    name = "leds"
    role = "leds"
    doc = "LEDs on the robot's top, drawn in the world view."
    params = (Param("count", "integer", "how many LEDs", "", 2, lo=1, hi=8),)
    api = (ApiCall("set_leds(*on)", "one boolean per LED", "switch the LEDs"),)


class Gripper(ComponentType):
    name = "gripper"
    role = "gripper"
    doc = (
        f"A gripper turret in front of the body ({_GRIPPER_REF}): an arm that lowers two "
        "tongs, fingers that close on a round object, a light barrier between them, and the "
        "held object's resistivity."
    )
    params = (
        Param("arm_down", "integer", "arm position on the floor", "", 255, lo=0, hi=255),
        Param("arm_up", "integer", "arm position fully raised", "", 165, lo=0, hi=255),
        Param(
            "lowered_above",
            "integer",
            "the tongs touch the floor at or above this position",
            "",
            230,
            lo=0,
            hi=255,
        ),
        Param("arm_rate_per_s", "number", "arm speed", "positions/s", 300.0, lo=1.0, hi=10000.0),
        Param(
            "tong_x_mm",
            "numbers",
            "tongs from..to along x, robot frame",
            "mm",
            [20.0, 52.0],
            lo=-500.0,
            hi=500.0,
            max_items=2,
        ),
        Param("tong_width_mm", "number", "width of a tong", "mm", 4.0, lo=0.1, hi=100.0),
        Param("gap_mm", "number", "gap between the open tongs", "mm", 28.0, lo=1.0, hi=500.0),
        Param(
            "grip_x_mm",
            "numbers",
            "collision exception area along x",
            "mm",
            [28.0, 50.0],
            lo=-500.0,
            hi=500.0,
            max_items=2,
        ),
        Param(
            "presence_x_mm",
            "numbers",
            "the light barrier between the fingers, along x",
            "mm",
            [30.0, 46.0],
            lo=-500.0,
            hi=500.0,
            max_items=2,
        ),
        Param(
            "presence_half_width_mm",
            "number",
            "half width of the light barrier",
            "mm",
            10.0,
            lo=0.1,
            hi=500.0,
        ),
        Param(
            "empty_resistivity", "integer", "resistivity with nothing held", "", 255, lo=0, hi=255
        ),
    )
    api = (
        ApiCall("set_arm(position)", "0..255", "move the arm"),
        ApiCall("arm_up()", "-", "raise the arm"),
        ApiCall("arm_down()", "-", "lower the arm"),
        ApiCall("arm()", "int 0..255", "the arm's position"),
        ApiCall("open_gripper()", "-", "open the fingers"),
        ApiCall("close_gripper()", "-", "close the fingers"),
        ApiCall("gripper_closed()", "bool", "whether the fingers are closed"),
        ApiCall("object_present()", "bool", "the light barrier between the fingers"),
        ApiCall("resistivity()", "int", "the held object's resistivity"),
    )

    @classmethod
    def cross_check(cls, values: Mapping[str, Any]) -> list[tuple[str, str]]:
        return [
            (p, "must be two numbers [from, to], from < to")
            for p in ("tong_x_mm", "grip_x_mm", "presence_x_mm")
            if len(values[p]) != 2 or values[p][0] >= values[p][1]
        ]


BUILT_IN: tuple[type[ComponentType], ...] = (Body, Drive, IrProximity, AmbientLight, Leds, Gripper)
