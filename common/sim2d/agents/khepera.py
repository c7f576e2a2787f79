"""The Khepera I as written in Python before robot files (khepera.toml is checked against it).

From the K-Team manual's numbers (docs/WORLDS.md "Sensor models").

- Drive: speed in pulses per 10 ms, 0.08 mm a pulse (about 8 mm/s a unit),
  wheel base 53 mm, clamped to +-127; 32-bit position counters in pulses.
- 8 IR proximity sensors at the manual's positions. The manual's exact curve
  is not available, so the default is a documented, calibratable table: 1023
  touching, about 500 at 12 mm, about 100 at 30 mm, 0 beyond 50 mm, close to
  the published Khepera I curves (steep near the body, a long tail).
- 8 ambient light sensors at the same positions: about 500 in the dark, down
  to about 50 under a strong light.
- 2 LEDs, and the gripper turret (arm 165 up .. 255 down, fingers, an object
  presence barrier, the held object's resistivity).
"""

from __future__ import annotations

from common.sim2d.specs import (
    AgentTypeSpec,
    AmbientSpec,
    DriveSpec,
    GripperSpec,
    ProximitySpec,
    ResponseCurve,
    poses_deg,
)

# The manual's sensor positions, robot frame (x forward, y left), degrees CCW.
SENSOR_POSES = poses_deg(
    (10.0, 24.0, 90.0),  # 0 left
    (19.0, 17.0, 45.0),  # 1 front-left
    (25.0, 6.0, 0.0),  # 2 front
    (25.0, -6.0, 0.0),  # 3 front
    (19.0, -17.0, -45.0),  # 4 front-right
    (10.0, -24.0, -90.0),  # 5 right
    (-24.0, -10.0, 180.0),  # 6 back-right
    (-24.0, 10.0, 180.0),  # 7 back-left
)

# Distance from the sensor (mm) -> raw value. Calibrate by replacing this table.
PROXIMITY_CURVE = ResponseCurve(
    distances_mm=(0.0, 2.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0, 45.0, 50.0),
    values=(1023.0, 1000.0, 870.0, 600.0, 390.0, 250.0, 160.0, 100.0, 60.0, 32.0, 12.0, 0.0),
)

DRIVE = DriveSpec(wheel_base_mm=53.0, mm_per_pulse=0.08, unit_time_s=0.01, max_speed=127)

SPEC = AgentTypeSpec(
    name="khepera",
    radius_mm=27.5,
    mass_g=70.0,
    colour="#2e8b57",
    drive=DRIVE,
    proximity=ProximitySpec(poses=SENSOR_POSES, curve=PROXIMITY_CURVE),
    ambient=AmbientSpec(poses=SENSOR_POSES),
    leds=2,
    gripper=GripperSpec(),
)
