"""Typed parameter schemas of robot components, and their validation.

A component type (common/robots/components.py, or a plugin's) declares each of
its parameters as a :class:`Param`: name, kind, unit, default, range and a
line of documentation. The same declaration validates a robot file
(common/robots/robotfile.py), prints ``wart robots describe`` and writes the
controller API's table in docs/CONTROLLERS.md, so the three never disagree
(the role of ARGoS's ``REGISTER_SENSOR`` documentation, across a pip-installed
plugin boundary).

No network and no numpy here: a schema is data.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

_IDENT = re.compile(r"^[a-z][a-z0-9_]{0,31}$")
_COLOUR = re.compile(r"^#[0-9a-fA-F]{6}$")

KINDS = ("number", "integer", "boolean", "text", "colour", "choice", "numbers", "points", "poses")
"""What a parameter can be: a number, an integer, true/false, a short text, a
``#rrggbb`` colour, one of ``choices``, a list of numbers, a list of
``[x mm, y mm]`` points or a list of ``[x mm, y mm, heading degrees]`` poses,
in the robot frame (x forward, y left)."""

Segment = tuple[float, float, float, float]
REQUIRED: Any = None  # a Param whose default is REQUIRED must be given in the file
MAX_ITEMS = 64  # the longest list any parameter may hold (a ring of 64 sensors)


class SchemaError(ValueError):
    """A component type declares a bad schema (a plugin's mistake, not a user's)."""


@dataclass(frozen=True)
class Param:
    """One parameter of a component type, as a robot file sets it."""

    name: str
    kind: str
    doc: str
    unit: str = ""
    default: Any = REQUIRED
    lo: float | None = None
    hi: float | None = None
    choices: tuple[str, ...] = ()
    max_items: int = MAX_ITEMS

    @property
    def required(self) -> bool:
        return self.default is None

    def problem(self, value: Any) -> str | None:
        """Why ``value`` is not valid for this parameter, in a user's words; None if it is."""
        kind = self.kind
        if kind == "number" or kind == "integer":
            if kind == "integer" and (isinstance(value, bool) or not isinstance(value, int)):
                return f"must be an integer, got {_show(value)}"
            if isinstance(value, bool) or not isinstance(value, int | float):
                return f"must be a number, got {_show(value)}"
            if not math.isfinite(value):
                return f"must be a finite number, got {_show(value)}"
            return self._range(value)
        if kind == "boolean":
            return None if isinstance(value, bool) else f"must be true or false, got {_show(value)}"
        if kind == "text":
            if not isinstance(value, str):
                return f"must be a text, got {_show(value)}"
            return None if len(value) <= 200 else "must be at most 200 characters"
        if kind == "colour":
            ok = isinstance(value, str) and _COLOUR.match(value)
            return None if ok else f'must be a colour "#rrggbb", got {_show(value)}'
        if kind == "choice":
            if value in self.choices:
                return None
            return f"must be one of {', '.join(self.choices)}, got {_show(value)}"
        if kind == "numbers":
            # Empty only where that is the default (a list "none" means nothing but 1 each).
            if not isinstance(value, list) or (not value and self.default != []):
                return f"must be a list of numbers, got {_show(value)}"
            if len(value) > self.max_items:
                return f"must hold at most {self.max_items} numbers, got {len(value)}"
            for i, v in enumerate(value):
                if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                    return f"item {i}: must be a number, got {_show(v)}"
                bad = self._range(v)
                if bad:
                    return f"item {i}: {bad}"
            return None
        if kind == "poses" or kind == "points":
            size = 3 if kind == "poses" else 2
            form = "[x_mm, y_mm, heading_deg]" if kind == "poses" else "[x_mm, y_mm]"
            if not isinstance(value, list):
                return f"must be a list of {form} {kind}, got {_show(value)}"
            if len(value) > self.max_items:
                return f"must hold at most {self.max_items} {kind}, got {len(value)}"
            for i, pose in enumerate(value):
                if (
                    not isinstance(pose, list)
                    or len(pose) != size
                    or any(
                        isinstance(v, bool)
                        or not isinstance(v, int | float)
                        or not math.isfinite(v)
                        for v in pose
                    )
                ):
                    return f"item {i}: must be {form}, got {_show(pose)}"
                if any(abs(v) > 1000 for v in pose[:2]) or (size == 3 and abs(pose[2]) > 360):
                    return f"item {i}: x and y within ±1000 mm, heading within ±360°"
            return None
        raise SchemaError(f"parameter {self.name}: unknown kind {kind!r}")

    def _range(self, value: float) -> str | None:
        if self.lo is not None and value < self.lo:
            return f"must be at least {self.lo:g}{_unit(self.unit)}, got {value!r}"
        if self.hi is not None and value > self.hi:
            return f"must be at most {self.hi:g}{_unit(self.unit)}, got {value!r}"
        return None

    def default_text(self) -> str:
        if self.required:
            return "required"
        if isinstance(self.default, bool):
            return "true" if self.default else "false"
        if isinstance(self.default, str):
            return f'"{self.default}"'
        return show_value(self.default)

    def range_text(self) -> str:
        if self.kind == "choice":
            return " | ".join(self.choices)
        if self.lo is None and self.hi is None:
            return ""
        lo = "" if self.lo is None else f"{self.lo:g}"
        hi = "" if self.hi is None else f"{self.hi:g}"
        return f"{lo}..{hi}"


@dataclass(frozen=True)
class ApiCall:
    """One call a controller makes on a component: a reading or a command."""

    call: str  # as a controller writes it: "floor()" or "set_leds(*on)"
    returns: str  # what it gives or takes, with units
    doc: str


class ComponentType:
    """A kind of part a robot file can name (``type = "..."`` in a component's table).

    Subclasses set the class attributes; :func:`check_schema` verifies them
    when the registry loads the type (a plugin with a bad schema is refused
    with the reason, and the lab runs without it).

    ``role`` says how the engine uses it: ``body``, ``drive``, ``proximity``,
    ``ambient``, ``leds`` and ``gripper`` are the engine's own components (one
    each at most); ``sensor`` is a batched sensor read for every robot that
    carries it at once (:meth:`measure`), whose readings a controller gets
    under the component's name.
    """

    name: ClassVar[str] = ""
    doc: ClassVar[str] = ""
    role: ClassVar[str] = "sensor"
    params: ClassVar[tuple[Param, ...]] = ()
    api: ClassVar[tuple[ApiCall, ...]] = ()
    version: ClassVar[str] = "1"

    @classmethod
    def cross_check(cls, values: Mapping[str, Any]) -> list[tuple[str, str]]:
        """(parameter, problem) pairs that span several parameters (lists of equal length)."""
        return []

    @classmethod
    def reading_size(cls, values: Mapping[str, Any]) -> int:
        """How many numbers one robot's reading holds (role ``sensor``)."""
        return 0

    @classmethod
    def preview(cls, values: Mapping[str, Any]) -> list[Segment]:
        """How the component looks on the body: line segments (x0, y0, x1, y1) in mm, robot
        frame (x forward, y left), for the builder's drawing (rays, beams, points); none
        by default."""
        return []

    @classmethod
    def measure(cls, world: Any, slots: Any, values: Mapping[str, Any], key: int) -> Any:
        """Every listed robot's reading at once: a (len(slots), reading_size) array.

        ``world`` is the Sim2D world (read only: poses, obstacles, the floor
        layer), ``slots`` the robots carrying this component, ``values`` its
        validated parameters and ``key`` a seed for its noise (the world's
        seed and tick): the same run gives the same readings.
        """
        raise NotImplementedError


ROLES = ("body", "drive", "proximity", "ambient", "leds", "gripper", "sensor")
UNIQUE_ROLES = ("body", "drive", "proximity", "ambient", "leds", "gripper")


def check_schema(component: Any) -> None:
    """Raise SchemaError naming what is wrong with a component type's declaration."""
    if not (isinstance(component, type) and issubclass(component, ComponentType)):
        raise SchemaError(f"{component!r} is not a ComponentType subclass")
    name = component.name
    if not isinstance(name, str) or not _IDENT.match(name):
        raise SchemaError(f"component type name {name!r} must match {_IDENT.pattern}")
    if not component.doc.strip():
        raise SchemaError(f"{name}: no doc")
    if component.role not in ROLES:
        raise SchemaError(f"{name}: role {component.role!r} is not one of {', '.join(ROLES)}")
    seen: set[str] = set()
    for p in component.params:
        if not isinstance(p, Param):
            raise SchemaError(f"{name}: {p!r} is not a Param")
        if not _IDENT.match(p.name) or p.name in ("type", "name"):
            raise SchemaError(f"{name}: parameter name {p.name!r} is not allowed")
        if p.name in seen:
            raise SchemaError(f"{name}: parameter {p.name} declared twice")
        seen.add(p.name)
        if p.kind not in KINDS:
            raise SchemaError(
                f"{name}.{p.name}: unknown kind {p.kind!r} (kinds: {', '.join(KINDS)})"
            )
        if not p.doc.strip():
            raise SchemaError(f"{name}.{p.name}: no doc")
        if p.kind == "choice" and not p.choices:
            raise SchemaError(f"{name}.{p.name}: a choice needs choices")
        if not p.required:
            empty_list = p.kind in ("numbers", "points", "poses") and p.default == []
            bad = None if empty_list else p.problem(p.default)
            if bad:
                raise SchemaError(f"{name}.{p.name}: its default {bad}")
    if component.role == "sensor" and component.measure is ComponentType.measure:
        raise SchemaError(f"{name}: a sensor must define measure()")


def show_value(value: Any) -> str:
    """A parameter's value as a robot file would write it, shortened."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, list):
        text = "[" + ", ".join(show_value(v) for v in value) + "]"
        return text if len(text) <= 40 else f"[{len(value)} items]"
    return str(value)


def _unit(unit: str) -> str:
    return f" {unit}" if unit else ""


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."
