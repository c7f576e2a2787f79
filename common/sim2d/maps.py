"""Map files: a human-readable JSON schema with a version, validated with clear errors.

See docs/MAPS.md for the schema. Every error names the file, the field path
(``objects[3].radius``) and, where it can, the line. Saving writes only inside
the maps directory the engine was given, under a plain name.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

from common.files import write_atomic
from common.keys import is_ident
from common.sim2d.drives import DEFAULT_DRIVE
from common.sim2d.entities import ShapeSpec
from common.sim2d.floor import FloorLayer, FloorLine
from common.sim2d.map_robots import MapRobotTypes, RobotTypeError, carried_files
from common.sim2d.world import EditError, World

FORMAT = "wart-map"
VERSION = 1
SECTIONS = ("obstacles", "objects", "lights", "zones", "agents", "agent_groups")
_COLOUR = re.compile(r"^#[0-9a-fA-F]{6}$")
_LIMIT_MM = 100_000.0  # 100 m: larger than any lab


class MapError(ValueError):
    """A map file or map entry is invalid; the message names the field (and line)."""


class _Fields:
    """Typed reads of one JSON object, with errors that name the field path."""

    def __init__(self, data: Any, path: str, text: str | None = None) -> None:
        if not isinstance(data, dict):
            raise MapError(f"{path}: must be an object {{...}}, got {type(data).__name__}")
        self.data = data
        self.path = path
        self.text = text
        self.used: set[str] = set()

    def _where(self, key: str) -> str:
        where = f"{self.path}.{key}" if self.path else key
        ident = self.data.get("id")
        if self.text and isinstance(ident, str):
            line = _line_of(self.text, ident)
            if line:
                where = f"line {line}: {where}"
        return where

    def fail(self, key: str, problem: str) -> MapError:
        return MapError(f"{self._where(key)}: {problem}")

    def has(self, key: str) -> bool:
        return key in self.data

    def number(
        self,
        key: str,
        default: float | None = None,
        *,
        lo: float = -_LIMIT_MM,
        hi: float = _LIMIT_MM,
        positive: bool = False,
    ) -> float:
        self.used.add(key)
        if key not in self.data:
            if default is None:
                raise self.fail(key, "is required")
            return default
        value = self.data[key]
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not math.isfinite(value)
        ):
            raise self.fail(key, f"must be a number, got {value!r}")
        if positive and value <= 0:
            raise self.fail(key, f"must be positive, got {value}")
        if not lo <= value <= hi:
            raise self.fail(key, f"must be between {lo:g} and {hi:g}, got {value}")
        return float(value)

    def text_field(
        self, key: str, default: str | None = None, choices: tuple[str, ...] = ()
    ) -> str:
        self.used.add(key)
        value = self.data.get(key, default)
        if value is None:
            raise self.fail(key, "is required")
        if not isinstance(value, str):
            raise self.fail(key, f"must be a string, got {value!r}")
        if choices and value not in choices:
            raise self.fail(key, f"must be one of {', '.join(choices)}, got {value!r}")
        return value

    def ident(self, key: str = "id") -> str:
        value = self.text_field(key)
        if not is_ident(value):
            raise self.fail(key, f"{value!r} is not a valid name (letters, digits, _ - .)")
        return value

    def colour(self, default: str) -> str:
        value = self.text_field("colour", default)
        if not _COLOUR.match(value):
            raise self.fail("colour", f"must look like #rrggbb, got {value!r}")
        return value

    def boolean(self, key: str, default: bool) -> bool:
        self.used.add(key)
        value = self.data.get(key, default)
        if not isinstance(value, bool):
            raise self.fail(key, f"must be true or false, got {value!r}")
        return value

    def point(self, key: str) -> tuple[float, float]:
        self.used.add(key)
        value = self.data.get(key)
        if (
            not isinstance(value, list)
            or len(value) != 2
            or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
        ):
            raise self.fail(key, f"must be [x, y] in mm, got {value!r}")
        return float(value[0]), float(value[1])

    def heading(self) -> float:
        return math.radians(self.number("heading_deg", 0.0, lo=-3600, hi=3600))

    def check_unknown(self) -> None:
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            raise self.fail(unknown[0], "is not a field of this entry (a typo?)")


def _line_of(text: str, ident: str) -> int | None:
    match = re.search(r'"id"\s*:\s*"' + re.escape(ident) + '"', text)
    return text.count("\n", 0, match.start()) + 1 if match else None


def _shape(f: _Fields, allowed: tuple[str, ...]) -> tuple[ShapeSpec, float, float, float]:
    """A shape and its pose (x, y, heading) from an entry."""
    kind = f.text_field("shape", choices=allowed)
    if kind == "wall":
        a = f.point("from")
        b = f.point("to")
        thickness = f.number("thickness", 10.0, positive=True)
        length = math.hypot(b[0] - a[0], b[1] - a[1])
        if length <= 0:
            raise f.fail("to", "a wall needs two different end points")
        shape = ShapeSpec.box(length + thickness, thickness)
        heading = math.atan2(b[1] - a[1], b[0] - a[0])
        return shape, (a[0] + b[0]) / 2, (a[1] + b[1]) / 2, heading
    x, y, heading = f.number("x"), f.number("y"), f.heading()
    if kind == "circle":
        return ShapeSpec.circle(f.number("radius", positive=True)), x, y, heading
    if kind == "box":
        w = f.number("width", positive=True)
        h = f.number("height", positive=True)
        return ShapeSpec.box(w, h), x, y, heading
    f.used.add("points")
    pts = f.data.get("points")
    if not isinstance(pts, list) or len(pts) < 3:
        raise f.fail("points", "a polygon needs a list of at least 3 [x, y] points (mm)")
    points: list[tuple[float, float]] = []
    for i, p in enumerate(pts):
        if not (isinstance(p, list) and len(p) == 2 and all(isinstance(v, int | float) for v in p)):
            raise f.fail(f"points[{i}]", f"must be [x, y], got {p!r}")
        points.append((float(p[0]), float(p[1])))
    shape = ShapeSpec("polygon", points_mm=tuple(points))
    if shape.area_mm2() <= 0:
        raise f.fail("points", "the polygon has no area")
    return shape, x, y, heading


def add_entry(
    world: World,
    section: str,
    entry: Any,
    path: str,
    text: str | None = None,
    types: MapRobotTypes | None = None,
) -> None:
    """Validate one map entry and add it to the world (edits use this too).

    ``types``: the robot types the map carries besides the lab's (none: the lab's only).
    """
    f = _Fields(entry, path, text)
    types = types or MapRobotTypes()
    try:
        if section == "obstacles":
            ident = f.ident()
            shape, x, y, h = _shape(f, ("box", "circle", "polygon", "wall"))
            colour = f.colour("#808080")
            f.check_unknown()
            world.add_obstacle(ident, shape, x, y, h, colour)
        elif section == "objects":
            ident = f.ident()
            kind = f.text_field("kind", "ball")
            shape, x, y, h = _shape(f, ("circle", "box", "polygon"))
            mass = f.number("mass", 10.0, positive=True)
            friction = f.number("friction", 0.5, lo=0.0, hi=10.0)
            resistivity = int(f.number("resistivity", 128, lo=0, hi=255))
            colour = f.colour("#ff8c00")
            f.check_unknown()
            world.add_object(
                ident,
                kind,
                shape,
                x,
                y,
                h,
                mass_g=mass,
                friction=friction,
                resistivity=resistivity,
                colour=colour,
            )
        elif section == "lights":
            ident = f.ident()
            x, y = f.number("x"), f.number("y")
            intensity = f.number("intensity", 1.0, lo=0.0, hi=100.0)
            radius = f.number("radius", 300.0, positive=True)
            mode = f.text_field("mode", "on", ("on", "off", "blink"))
            period = f.number("period", 1.0, positive=True)
            colour = f.colour("#ffd700")
            f.check_unknown()
            world.add_light(
                ident,
                x,
                y,
                intensity=intensity,
                radius_mm=radius,
                mode=mode,  # type: ignore[arg-type]
                period_s=period,
                colour=colour,
            )
        elif section == "zones":
            ident = f.ident()
            kind = f.text_field("kind", "zone")
            shape, x, y, h = _shape(f, ("circle", "box", "polygon"))
            colour = f.colour("#c8e6c9")
            f.check_unknown()
            world.add_zone(ident, kind, shape, x, y, h, colour)
        elif section == "agents":
            ident = f.ident()
            type_name = f.text_field("type", "khepera", types.names())
            spec = types.spec(type_name, ident)
            x, y, h = f.number("x"), f.number("y"), f.heading()
            gripper = f.boolean("gripper", True)
            colour = f.colour(spec.colour)
            f.check_unknown()
            world.add_agent(ident, spec, x, y, h, gripper=gripper, colour=colour)
        elif section == "agent_groups":
            _add_group(world, f, types)
        else:
            raise MapError(f"{path}: unknown section {section!r} (known: {', '.join(SECTIONS)})")
    except EditError as exc:
        where = (
            f"line {_line_of(text, f.data.get('id', ''))}: "
            if text and f.data.get("id") and _line_of(text, str(f.data.get("id")))
            else ""
        )
        raise MapError(f"{where}{path}: {exc}") from None
    except RobotTypeError as exc:  # it names the robot and its type: the user's words
        raise MapError(str(exc)) from None


def _add_group(world: World, f: _Fields, types: MapRobotTypes) -> None:
    """Many agents on a grid: ``count`` of ``type`` named ``prefix0..`` inside ``area``."""
    type_name = f.text_field("type", "khepera", types.names())
    count = int(f.number("count", lo=1, hi=10_000))
    prefix = f.text_field("prefix", "k")
    f.used.add("area")
    area = f.data.get("area")
    if not (
        isinstance(area, list) and len(area) == 4 and all(isinstance(v, int | float) for v in area)
    ):
        raise f.fail("area", "must be [x0, y0, x1, y1] in mm")
    x0, y0, x1, y1 = (float(v) for v in area)
    spacing = f.number("spacing", 80.0, positive=True)
    heading = f.heading()
    gripper = f.boolean("gripper", False)
    f.check_unknown()
    cols = int((x1 - x0) // spacing)
    rows = int((y1 - y0) // spacing)
    spec = types.spec(type_name, f"{prefix}0")
    placed = 0
    try:
        for cell in range(cols * rows):
            if placed == count:
                break
            r, c = divmod(cell, cols)
            x = x0 + spacing / 2 + c * spacing
            y = y0 + spacing / 2 + r * spacing
            try:
                world.add_agent(
                    f"{prefix}{placed}", spec, x, y, heading, gripper=gripper, defer_tables=True
                )
            except EditError as exc:
                if "overlap an obstacle" in str(exc):
                    continue  # a pillar stands on this grid point: use the next one
                raise
            placed += 1
    finally:
        world.finish_agents()
    if placed < count:
        raise f.fail("count", f"only {placed} of {count} agents fit in the area at {spacing:g} mm")


def parse_map(text: str, source: str = "map") -> dict[str, Any]:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise MapError(f"{source}: line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    if not isinstance(data, dict):
        raise MapError(f"{source}: a map is a JSON object {{...}}")
    if data.get("format") != FORMAT:
        raise MapError(f'{source}: format: must be "{FORMAT}" (is this a map file?)')
    version = data.get("version")
    if version != VERSION:
        raise MapError(f"{source}: version: this engine reads version {VERSION}, got {version!r}")
    return data


def build_world(
    data: dict[str, Any],
    *,
    name: str,
    seed: int = 0,
    tick_s: float = 0.02,
    text: str | None = None,
    source: str = "map",
    sensor_period_s: float = 0.02,
    threads: int = 1,
    physics_threads: int = 1,
    drive: str = DEFAULT_DRIVE,
) -> World:
    """A new world from a parsed map (errors name ``source`` and the field).

    ``threads``, ``physics_threads`` and ``drive``: see World (sensing and chipmunk
    threads, how robots are driven).
    """
    try:
        top = _Fields(data, "", text)
        for key in ("format", "version", "name", "description", *SECTIONS):
            top.used.add(key)
        top.used.update(("arena", "floor", "robot_types"))
        top.check_unknown()
        try:
            types = MapRobotTypes.read(data.get("robot_types", {}))
        except RobotTypeError as exc:
            raise MapError(str(exc)) from None
        arena = _Fields(data.get("arena"), "arena", text)
        world = World(
            arena.number("width", positive=True),
            arena.number("height", positive=True),
            seed=seed,
            tick_s=tick_s,
            name=name,
            sensor_period_s=sensor_period_s,
            threads=threads,
            physics_threads=physics_threads,
            drive=drive,
        )
        arena.check_unknown()
        if "floor" in data:
            world.floor = _floor(data["floor"], world, text)
        for section in SECTIONS:
            entries = data.get(section, [])
            if not isinstance(entries, list):
                raise MapError(f"{section}: must be a list [...]")
            for i, entry in enumerate(entries):
                add_entry(world, section, entry, f"{section}[{i}]", text, types)
    except MapError as exc:
        raise MapError(f"{source}: {exc}") from None
    return world


MAX_FLOOR_LINES = 256
MAX_LINE_POINTS = 512


def _floor(data: Any, world: World, text: str | None) -> FloorLayer:
    """The optional floor layer: a shade and painted lines (docs/MAPS.md, "floor")."""
    f = _Fields(data, "floor", text)
    colour = f.colour("#ffffff")
    f.used.add("lines")
    lines = f.data.get("lines", [])
    if not isinstance(lines, list) or len(lines) > MAX_FLOOR_LINES:
        raise f.fail("lines", f"must be a list of at most {MAX_FLOOR_LINES} lines")
    f.check_unknown()
    out = []
    for i, entry in enumerate(lines):
        g = _Fields(entry, f"floor.lines[{i}]", text)
        width = g.number("width", 20.0, lo=0.1, hi=1000.0)
        line_colour = g.colour("#000000")
        g.used.add("points")
        points = g.data.get("points")
        if not isinstance(points, list) or not 2 <= len(points) <= MAX_LINE_POINTS:
            raise g.fail("points", f"must be a list of 2 to {MAX_LINE_POINTS} [x, y] points")
        xy = []
        for j, p in enumerate(points):
            if not (
                isinstance(p, list)
                and len(p) == 2
                and all(isinstance(v, int | float) and not isinstance(v, bool) for v in p)
                and all(math.isfinite(v) for v in p)
            ):
                raise g.fail(f"points[{j}]", f"must be [x, y] in mm, got {p!r}")
            if not (0 <= p[0] <= world.width and 0 <= p[1] <= world.height):
                raise g.fail(f"points[{j}]", f"{p!r} is outside the arena")
            xy.append((float(p[0]), float(p[1])))
        g.check_unknown()
        out.append(FloorLine(tuple(xy), width, line_colour))
    return FloorLayer(colour, tuple(out))


def load_map(
    path: Path,
    *,
    name: str,
    seed: int = 0,
    tick_s: float = 0.02,
    threads: int = 1,
    physics_threads: int = 1,
    drive: str = DEFAULT_DRIVE,
) -> World:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise MapError(f"{path}: cannot read the map: {exc.strerror}") from None
    return build_world(
        parse_map(text, str(path)),
        name=name,
        seed=seed,
        tick_s=tick_s,
        text=text,
        source=str(path),
        threads=threads,
        physics_threads=physics_threads,
        drive=drive,
    )


def _r(value: float) -> float:
    return round(float(value), 3)


def _shape_fields(shape: ShapeSpec) -> dict[str, Any]:
    if shape.kind == "circle":
        return {"shape": "circle", "radius": _r(shape.radius_mm)}
    if shape.kind == "box":
        return {"shape": "box", "width": _r(shape.width_mm), "height": _r(shape.height_mm)}
    return {"shape": "polygon", "points": [[_r(x), _r(y)] for x, y in shape.points_mm]}


def world_to_map(world: World, name: str) -> dict[str, Any]:
    """The world as a map (current poses; agents listed one by one)."""

    def pose(x: float, y: float, h: float) -> dict[str, float]:
        return {"x": _r(x), "y": _r(y), "heading_deg": _r(math.degrees(h))}

    out: dict[str, Any] = {
        "format": FORMAT,
        "version": VERSION,
        "name": name,
        "arena": {"width": _r(world.width), "height": _r(world.height)},
        "obstacles": [
            {"id": o.id, **_shape_fields(o.shape), **pose(o.x, o.y, o.heading), "colour": o.colour}
            for o in world.obstacles.values()
        ],
        "objects": [
            {
                "id": o.id,
                "kind": o.kind,
                **_shape_fields(o.shape),
                **pose(*world.pose_of(o.id)),
                "mass": _r(o.mass_g),
                "friction": _r(o.friction),
                "resistivity": o.resistivity,
                "colour": o.colour,
            }
            for o in world.objects
        ],
        "lights": [
            {
                "id": light.id,
                "x": _r(light.x),
                "y": _r(light.y),
                "intensity": light.intensity,
                "radius": _r(light.radius_mm),
                "mode": light.mode,
                "period": light.period_s,
                "colour": light.colour,
            }
            for light in world.lights
        ],
        "zones": [
            {
                "id": z.id,
                "kind": z.kind,
                **_shape_fields(z.shape),
                **pose(z.x, z.y, z.heading),
                "colour": z.colour,
            }
            for z in world.zones.values()
        ],
        "agents": [
            {
                "id": a.id,
                "type": a.spec.name,
                **pose(*world.pose_of(a.id)),
                "gripper": a.gripper_fitted,
                "colour": a.colour,
            }
            for a in world.agents
        ],
    }
    files = carried_files(a.spec for a in world.agents)
    if files:  # the lab's own types need no file: every process has them
        out["robot_types"] = files
    if world.floor is not None:
        out["floor"] = {
            "colour": world.floor.colour,
            "lines": [
                {
                    "points": [[_r(x), _r(y)] for x, y in line.points],
                    "width": _r(line.width_mm),
                    "colour": line.colour,
                }
                for line in world.floor.lines
            ],
        }
    return out


def map_path(maps_dir: Path, name: str) -> Path:
    """``maps_dir/<name>.json``; the name is a plain identifier, never a path."""
    if not is_ident(name) or name.startswith("."):
        raise MapError(f"map name {name!r} is not a plain name (letters, digits, _ - .)")
    stem = name[:-5] if name.endswith(".json") else name
    return maps_dir / f"{stem}.json"


def save_map(world: World, maps_dir: Path, name: str) -> Path:
    path = map_path(maps_dir, name)
    maps_dir.mkdir(parents=True, exist_ok=True)
    # a reader never sees half a map, and a saved map survives a crash
    write_atomic(path, (json.dumps(world_to_map(world, name), indent=1) + "\n").encode())
    return path


def list_maps(maps_dir: Path) -> list[str]:
    if not maps_dir.is_dir():
        return []
    return sorted(p.stem for p in maps_dir.glob("*.json") if is_ident(p.stem))
