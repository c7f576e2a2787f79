"""The controller API that follows the robot: which calls a robot type's components give.

A robot file names its components (common/robots/, docs/ROBOTS.md); each
component's role gives a controller its calls (the drive ``set_speeds``, the
IR ring ``proximity()``, the gripper ``close_gripper()`` ...), and each batched
sensor is read by its name in the file: a ``[components.floor]`` floor sensor
is ``robot.floor()`` (or ``robot.read("floor")``). :class:`RobotApi` holds one
type's components; Check (common/controller/advice.py) validates a
controller's calls against the chosen robot's ("this robot has no gripper").

Standard library only, like the rest of this package: the sandbox copies it.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

# The calls each role of component gives (the names of common.controller.Khepera).
ROLE_CALLS: dict[str, tuple[str, ...]] = {
    "drive": ("set_speeds", "stop", "speeds", "position", "set_position"),
    "proximity": ("proximity",),
    "ambient": ("ambient",),
    "leds": ("set_leds",),
    "gripper": (
        "set_arm",
        "arm_up",
        "arm_down",
        "arm",
        "open_gripper",
        "close_gripper",
        "gripper_closed",
        "object_present",
        "resistivity",
    ),
}
# What every robot answers, whatever its components.
COMMON_CALLS = ("time", "read", "sensors", "has")
ROLE_NAMES = {
    "drive": "drive",
    "proximity": "IR proximity ring",
    "ambient": "ambient light sensors",
    "leds": "LEDs",
    "gripper": "gripper",
}

MAX_PARTS = 32  # batched sensors a robot may carry (common/robots/robotfile.py: components)
MAX_PART_VALUES = 64  # numbers in one sensor's reading
_PART_NAME = re.compile(r"^[a-z][a-z0-9_]{0,31}$")
_INT32 = 2**31


def check_parts(data: Any) -> dict[str, tuple[int, ...]]:
    """Sensor readings by name from a plain mapping (they cross a process boundary)."""
    if not isinstance(data, Mapping):
        raise ValueError("parts: expected a mapping of sensor name to integers")
    if len(data) > MAX_PARTS:
        raise ValueError(f"parts: at most {MAX_PARTS} sensors")
    out: dict[str, tuple[int, ...]] = {}
    for name, values in data.items():
        if not isinstance(name, str) or not _PART_NAME.match(name):
            raise ValueError(f"parts: {name!r} is not a sensor name")
        if not isinstance(values, list | tuple) or len(values) > MAX_PART_VALUES:
            raise ValueError(f"parts.{name}: expected at most {MAX_PART_VALUES} integers")
        if not all(type(v) is int and -_INT32 <= v < _INT32 for v in values):
            raise ValueError(f"parts.{name}: expected 32-bit integers")
        out[name] = tuple(values)
    return out


@dataclass(frozen=True)
class RobotApi:
    """One robot type's components as a controller sees them: (name, role) in file order."""

    type_name: str
    components: tuple[tuple[str, str], ...]

    @classmethod
    def of(cls, type_name: str, components: Iterable[tuple[str, str]]) -> RobotApi:
        return cls(type_name, tuple((str(n), str(r)) for n, r in components))

    @property
    def roles(self) -> set[str]:
        return {role for _, role in self.components}

    @property
    def sensors(self) -> tuple[str, ...]:
        """The batched sensors, read as ``robot.<name>()``."""
        return tuple(name for name, role in self.components if role == "sensor")

    def calls(self) -> frozenset[str]:
        """Every call a controller of this type may make."""
        names = set(COMMON_CALLS) | set(self.sensors)
        for role in self.roles:
            names.update(ROLE_CALLS.get(role, ()))
        return frozenset(names)

    def missing(self, call: str) -> str | None:
        """Why ``call`` is not there on this robot, when another robot type has it."""
        for role, calls in ROLE_CALLS.items():
            if call in calls and role not in self.roles:
                return f"this robot ({self.type_name}) has no {ROLE_NAMES[role]}"
        return None
