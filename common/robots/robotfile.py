"""Robot files: a robot type as TOML, validated against the component schemas, compiled.

A robot file names its components, each a table ``[components.<name>]`` with
``type = "<component type>"`` and that type's parameters (docs/ROBOTS.md)::

    format = "wart-robot"
    version = 1
    name = "khepera"
    description = "The Khepera I"

    [components.body]
    type = "body"
    radius_mm = 27.5
    mass_g = 70.0

A file is data only: read with tomllib, never executed, at most
:data:`MAX_BYTES`, and it can name only component types the lab has (its
registry). Every problem is collected and reported together, each with the
file, the line and the field (tomllib gives no lines for values, so the line
is found in the text), and nothing is compiled unless the whole file is
valid: no robot type starts half-built.

Compiled, a file is the engine's :class:`common.sim2d.specs.AgentTypeSpec`,
the same frozen spec the Python-written types were (the Khepera and e-puck
files give the specs common/sim2d/agents/khepera.py and epuck.py wrote, field
for field: tests/unit/common/robots/test_shipped.py).
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from common.handed_in import load_toml
from common.robots.schema import UNIQUE_ROLES, ComponentType
from common.sim2d.specs import (
    AgentTypeSpec,
    AmbientSpec,
    ComponentInfo,
    DriveSpec,
    GripperSpec,
    PartSpec,
    ProximitySpec,
    ResponseCurve,
    SensorPose,
)

FORMAT = "wart-robot"
VERSION = 1
MAX_BYTES = 64 * 1024
MAX_COMPONENTS = 32
TOP_KEYS = ("format", "version", "name", "description", "components")
_NAME = re.compile(r"^[a-z][a-z0-9_-]{0,31}$")
_PART = re.compile(r"^[a-z][a-z0-9_]{0,31}$")
# What a robot handle already answers to (common/controller/): a sensor of a
# robot file is read as robot.<name>(), so it may not take one of these names.
RESERVED = frozenset(
    {
        "set_speeds", "stop", "speeds", "position", "set_position", "proximity", "ambient",
        "time", "set_leds", "set_arm", "arm_up", "arm_down", "arm", "open_gripper",
        "close_gripper", "gripper_closed", "object_present", "resistivity", "read",
        "components", "sensors", "has", "type_name", "leds",
    }
)  # fmt: skip


@dataclass(frozen=True)
class Problem:
    """One thing wrong with a robot file: where (line, field) and what."""

    line: int | None
    field: str
    message: str


class RobotFileError(ValueError):
    """A robot file is refused; ``str()`` is what a user reads: file, line, field, problem."""

    def __init__(self, source: str, problems: list[Problem]) -> None:
        self.source = source
        self.problems = problems
        lines = [
            f"{source}:{p.line}: {p.field}: {p.message}"
            if p.line
            else f"{source}: {p.field}: {p.message}"
            for p in problems
        ]
        super().__init__("\n".join(lines))


class _Lines:
    """Where a key is written in a TOML text (tomllib keeps no positions)."""

    def __init__(self, text: str) -> None:
        self.lines = text.splitlines()
        self.headers: dict[str, int] = {}
        for i, line in enumerate(self.lines, 1):
            m = re.match(r"^\s*\[\s*([^\[\]]+?)\s*\]\s*(#.*)?$", line)
            if m:
                self.headers[re.sub(r"\s+", "", m.group(1)).replace('"', "")] = i

    def _key_in(self, start: int, key: str) -> int | None:
        pattern = re.compile(rf"^\s*\"?{re.escape(key)}\"?\s*=")
        for i in range(start, len(self.lines)):
            line = self.lines[i]
            if re.match(r"^\s*\[", line):
                return None
            if pattern.match(line):
                return i + 1
        return None

    def of(self, table: str | None, key: str | None = None) -> int | None:
        """The line of ``key`` in ``[table]`` (top level when None), else of the table."""
        if table is None:
            return self._key_in(0, key) if key else None
        header = self.headers.get(table)
        if header is None:  # a dotted key or an inline table: the first mention
            name = table.rsplit(".", 1)[-1]
            for i, line in enumerate(self.lines, 1):
                if re.search(rf"\b{re.escape(name)}\b", line):
                    return i
            return None
        if key is None:
            return header
        return self._key_in(header, key) or header


def too_big(source: str, size: int) -> RobotFileError:
    """The refusal of a file over MAX_BYTES (said before it is read)."""
    message = f"is {size} bytes; robot files are limited to {MAX_BYTES}"
    return RobotFileError(source, [Problem(None, "file", message)])


def parse(
    data: bytes | str, source: str, components: Mapping[str, type[ComponentType]]
) -> AgentTypeSpec:
    """Validate a robot file's bytes and compile it; RobotFileError with every problem."""
    raw = data.encode() if isinstance(data, str) else data
    if len(raw) > MAX_BYTES:
        raise too_big(source, len(raw))
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise RobotFileError(
            source, [Problem(None, "file", f"is not UTF-8 text (byte {exc.start})")]
        ) from None
    try:
        doc = load_toml(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        line = int(m.group(1)) if m else None
        raise RobotFileError(source, [Problem(line, "file", f"is not valid TOML: {exc}")]) from None
    checked = _validate(doc, _Lines(text), components)
    if isinstance(checked, list):
        raise RobotFileError(source, checked)
    return _compile(*checked, source=source, text=text)


def _validate(
    doc: dict[str, Any], where: _Lines, components: Mapping[str, type[ComponentType]]
) -> list[Problem] | tuple[str, list[tuple[str, type[ComponentType], dict[str, Any]]]]:
    problems: list[Problem] = []

    def fail(table: str | None, key: str | None, field: str, message: str) -> None:
        problems.append(Problem(where.of(table, key), field, message))

    for key in doc:
        if key not in TOP_KEYS:
            fail(None, key, key, f"unknown field (a robot file has {', '.join(TOP_KEYS)})")
    if doc.get("format") != FORMAT:
        fail(None, "format", "format", f'must be "{FORMAT}", got {doc.get("format")!r}')
    version = doc.get("version")
    if version != VERSION:
        fail(
            None,
            "version",
            "version",
            f"must be {VERSION} (this lab reads version {VERSION}), got {version!r}",
        )
    name = doc.get("name")
    if not isinstance(name, str) or not _NAME.match(name):
        fail(
            None, "name", "name", f"is required: a type name matching {_NAME.pattern}, got {name!r}"
        )
    desc = doc.get("description", "")
    if not isinstance(desc, str) or len(desc) > 500:
        fail(None, "description", "description", "must be a text of at most 500 characters")
    table = doc.get("components")
    if not isinstance(table, dict) or not table:
        fail(
            None, "components", "components", "is required: at least [components.body] and a drive"
        )
        return problems
    if len(table) > MAX_COMPONENTS:
        fail(
            None,
            "components",
            "components",
            f"at most {MAX_COMPONENTS} components, got {len(table)}",
        )
        return problems
    known = ", ".join(sorted(components))
    parts: list[tuple[str, type[ComponentType], dict[str, Any]]] = []
    roles: dict[str, str] = {}
    for part_name, entry in table.items():
        t = f"components.{part_name}"
        if not _PART.match(part_name):
            fail(t, None, t, f"a component's name must match {_PART.pattern}")
            continue
        if not isinstance(entry, dict):
            fail(t, None, t, "must be a table with a type")
            continue
        type_name = entry.get("type")
        if type_name is None:
            fail(t, None, f"{t}.type", f"is required (component types: {known})")
            continue
        component = components.get(type_name) if isinstance(type_name, str) else None
        if component is None:
            fail(
                t,
                "type",
                f"{t}.type",
                f"unknown component type {type_name!r} (this lab has: {known})",
            )
            continue
        if component.role == "sensor" and part_name in RESERVED:
            fail(
                t,
                None,
                t,
                f"{part_name!r} is a name of the robot's own API; name this sensor otherwise",
            )
        if component.role in UNIQUE_ROLES:
            if component.role in roles:
                fail(
                    t,
                    "type",
                    f"{t}.type",
                    f"a robot has one {component.role} ({roles[component.role]} already)",
                )
                continue
            roles[component.role] = t
        values: dict[str, Any] = {}
        declared = {p.name: p for p in component.params}
        for key in entry:
            if key != "type" and key not in declared:
                fail(
                    t,
                    key,
                    f"{t}.{key}",
                    f"unknown parameter of {type_name} (it has: {', '.join(declared) or 'none'})",
                )
        ok = True
        for p in component.params:
            if p.name not in entry:
                if p.required:
                    fail(t, None, f"{t}.{p.name}", f"is required ({p.doc})")
                    ok = False
                else:
                    values[p.name] = p.default
                continue
            bad = p.problem(entry[p.name])
            if bad:
                fail(t, p.name, f"{t}.{p.name}", bad)
                ok = False
            else:
                values[p.name] = entry[p.name]
        if ok:
            for key, message in component.cross_check(values):
                fail(t, key, f"{t}.{key}", message)
        parts.append((part_name, component, values))
    for role in ("body", "drive"):
        if role not in roles:
            fail(None, "components", "components", f"a robot needs a {role} component")
    if problems:
        return problems
    return str(name), parts


def _compile(
    name: str,
    parts: list[tuple[str, type[ComponentType], dict[str, Any]]],
    source: str,
    text: str = "",
) -> AgentTypeSpec:
    by_role = {c.role: v for _, c, v in parts if c.role != "sensor"}
    body, drive = by_role["body"], by_role["drive"]
    prox = by_role.get("proximity")
    amb = by_role.get("ambient")
    grip = by_role.get("gripper")
    proximity = (
        ProximitySpec(
            poses=_poses(prox["poses"]),
            curve=ResponseCurve(
                tuple(float(v) for v in prox["table_mm"]),
                tuple(float(v) for v in prox["table_values"]),
            ),
            max_value=prox["max_value"],
            rays_per_sensor=prox["rays_per_sensor"],
            spread_rad=math.radians(float(prox["spread_deg"])),
            noise_fraction=float(prox["noise_fraction"]),
            noise_counts=float(prox["noise_counts"]),
            gains=tuple(float(v) for v in prox["sensor_gains"]),
            noise_counts_each=tuple(float(v) for v in prox["sensor_noise_counts"]),
        )
        if prox
        else ProximitySpec(poses=(), curve=ResponseCurve((0.0, 1.0), (0.0, 0.0)))
    )
    ambient = (
        AmbientSpec(
            poses=_poses(amb["poses"]),
            dark_value=amb["dark_value"],
            floor_value=amb["floor_value"],
            drop=float(amb["drop"]),
            half_angle_rad=math.radians(float(amb["half_angle_deg"])),
            noise_fraction=float(amb["noise_fraction"]),
        )
        if amb
        else AmbientSpec(poses=())
    )
    gripper = (
        GripperSpec(
            arm_down=grip["arm_down"],
            arm_up=grip["arm_up"],
            lowered_above=grip["lowered_above"],
            arm_rate_per_s=float(grip["arm_rate_per_s"]),
            tong_x_mm=_pair(grip["tong_x_mm"]),
            tong_width_mm=float(grip["tong_width_mm"]),
            gap_mm=float(grip["gap_mm"]),
            grip_x_mm=_pair(grip["grip_x_mm"]),
            presence_x_mm=_pair(grip["presence_x_mm"]),
            presence_half_width_mm=float(grip["presence_half_width_mm"]),
            empty_resistivity=grip["empty_resistivity"],
        )
        if grip
        else None
    )
    return AgentTypeSpec(
        name=name,
        radius_mm=float(body["radius_mm"]),
        mass_g=float(body["mass_g"]),
        colour=body["colour"],
        drive=DriveSpec(
            wheel_base_mm=float(drive["wheel_base_mm"]),
            mm_per_pulse=float(drive["mm_per_pulse"]),
            unit_time_s=float(drive["unit_time_s"]),
            max_speed=drive["max_speed"],
            max_force=float(drive["max_force"]),
            max_torque=float(drive["max_torque"]),
            wheel_scale=_pair(drive["wheel_scale"]),
            latency_s=float(drive["latency_s"]),
        ),
        proximity=proximity,
        ambient=ambient,
        leds=by_role["leds"]["count"] if "leds" in by_role else 0,
        gripper=gripper,
        parts=tuple(
            PartSpec(n, c, v, c.reading_size(v)) for n, c, v in parts if c.role == "sensor"
        ),
        components=tuple(ComponentInfo(n, c.name, c.role, v) for n, c, v in parts),
        source=source,
        text=text,
    )


def _poses(rows: list[list[float]]) -> tuple[SensorPose, ...]:
    """As common.sim2d.specs.poses_deg: the same radians, bit for bit."""
    return tuple(SensorPose(float(x), float(y), math.radians(float(h))) for x, y, h in rows)


def _pair(values: list[float]) -> tuple[float, float]:
    return (float(values[0]), float(values[1]))
