"""Robot files for the tests: the wheeled robot most of them start from, and the scout
(that robot with a range finder)."""

from __future__ import annotations


def wheeled_robot(name: str, components: str = "") -> str:
    """The text of a robot file named ``name``: a body (30 mm, 80 g) and a differential
    drive, on lines 1 to 17 (the body's mass on line 8), then ``components``: more
    ``[components.*]`` tables, each after a blank line."""
    return (
        f"""\
format = "wart-robot"
version = 1
name = "{name}"

[components.body]
type = "body"
radius_mm = 30.0
mass_g = 80.0

[components.drive]
type = "differential_drive"
wheel_base_mm = 50.0
mm_per_pulse = 0.1
unit_time_s = 0.01
max_speed = 100
"""
        + components
    )


# The scout: the wheeled robot with a three-beam range finder, ``eye``, at its front.
SCOUT = wheeled_robot(
    "scout",
    """
[components.eye]
type = "range_finder"
pose = [30.0, 0.0, 0.0]
beams = 3
fov_deg = 40.0
max_range_mm = 300.0
""",
)
