"""An e-puck-like robot as written in Python before robot files (epuck.toml: checked against it).

Numbers from the e-puck's public documentation: 70 mm body, 53 mm wheel base,
stepper motors of 1000 steps per wheel turn on 41 mm wheels (0.129 mm a step),
speed in steps per second clamped to +-1000, 8 IR sensors (0..4095, useful to
about 60 mm). No gripper.
"""

from __future__ import annotations

from common.sim2d.specs import (
    AgentTypeSpec,
    AmbientSpec,
    DriveSpec,
    ProximitySpec,
    ResponseCurve,
    poses_deg,
)

_SENSORS = poses_deg(
    (30.0, -10.0, -17.0),
    (22.0, -22.0, -49.0),
    (0.0, -31.0, -90.0),
    (-26.0, -17.0, -150.0),
    (-26.0, 17.0, 150.0),
    (0.0, 31.0, 90.0),
    (22.0, 22.0, 49.0),
    (30.0, 10.0, 17.0),
)

SPEC = AgentTypeSpec(
    name="epuck",
    radius_mm=35.0,
    mass_g=150.0,
    colour="#3a7bd5",
    drive=DriveSpec(wheel_base_mm=53.0, mm_per_pulse=0.129, unit_time_s=1.0, max_speed=1000),
    proximity=ProximitySpec(
        poses=_SENSORS,
        curve=ResponseCurve(
            distances_mm=(0.0, 5.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0),
            values=(4095.0, 3400.0, 2500.0, 1200.0, 600.0, 300.0, 120.0, 0.0),
        ),
        max_value=4095,
    ),
    ambient=AmbientSpec(poses=_SENSORS, dark_value=4000, floor_value=100, drop=3600.0),
    leds=8,
)
