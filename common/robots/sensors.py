"""Batched sensors a robot file can add: a floor (line) sensor, a range finder, a bumper.

Each measures every robot that carries it in one set of numpy operations
(no per-robot Python loop), from the world's public state: poses, radii, the
static geometry sensing already keeps (walls, obstacle edges, round
obstacles) and the floor layer. Readings are computed when someone reads
them (common/sim2d/parts.py, once per tick), so a world whose robots carry
none of these pays nothing. Noise is drawn from a generator seeded by the
world's seed, the tick and the component's name: a seeded run repeats.

Candidate pairs come from common/sim2d/geometry.py's uniform grids: a range
finder looks at circles within its cell (max range plus the largest radius)
and at the edges binned in its origin's cell.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from common.robots.components import cross, ray
from common.robots.schema import ApiCall, ComponentType, Param, Segment
from common.sim2d import geometry
from common.sim2d.floor import FloorLayer


def _body_points(world: Any, slots: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """World positions of body-frame points: (len(slots), len(xy), 2)."""
    pose = world.agent_pose[slots]
    c, s = np.cos(pose[:, 2])[:, None], np.sin(pose[:, 2])[:, None]
    x, y = xy[None, :, 0], xy[None, :, 1]
    return np.stack([pose[:, 0, None] + c * x - s * y, pose[:, 1, None] + s * x + c * y], axis=-1)


def _noise(key: int, shape: tuple[int, ...], sigma: float) -> np.ndarray:
    if sigma <= 0:
        return np.zeros(shape)
    return np.random.default_rng(key).normal(0.0, sigma, shape)


def _circles(world: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every round thing a ray or a bumper meets: centres, radii, owning agent slot (-1)."""
    static = world.sensors.static_geometry(world)
    n = len(world.agents)
    centres = [world.agent_pose[:, :2], static.circle_centres]
    radii = [world.tables.radius, static.circle_radii]
    owner = [np.arange(n), np.full(len(static.circle_radii), -1)]
    rows = [
        i
        for i, obj in enumerate(world.objects)
        if obj.shape.kind == "circle" and world.on_floor(obj)
    ]
    if rows:
        centres.append(world.object_pose[rows, :2])
        radii.append(np.array([world.objects[i].shape.radius_mm for i in rows]))
        owner.append(np.full(len(rows), -1))
    return (
        np.concatenate(centres).reshape(-1, 2),
        np.concatenate(radii).astype(np.float64),
        np.concatenate(owner).astype(np.int64),
    )


def _segment_grid(world: Any, cell: float) -> geometry.SegmentGrid:
    """The walls and obstacle edges binned at ``cell`` (kept until the obstacles change)."""
    static = world.sensors.static_geometry(world)
    cache = world.__dict__.setdefault("_part_grids", {})
    key = (id(static), cell)
    grid = cache.get(key)
    if grid is None:
        if len(cache) > 8:
            cache.clear()
        grid = cache[key] = geometry.SegmentGrid.build(static.segments, cell)
        cache[("static", cell)] = static  # keeps id(static) from being reused while cached
    return grid


class FloorSensor(ComponentType):
    name = "floor_sensor"
    doc = (
        "Downward sensors that read the floor's shade under points of the body: 0 black .. "
        "255 white (the map's floor layer; a white floor without one). For line following."
    )
    params = (
        Param(
            "points",
            "points",
            "where each sensor looks, [x, y] in the robot frame",
            "mm",
            max_items=16,
        ),
        Param("noise", "number", "Gaussian noise σ", "counts", 2.0, lo=0.0, hi=255.0),
    )
    api = (
        ApiCall(
            "{name}()",
            "Reading of one shade per point, 0 (black) .. 255 (white)",
            "the floor under each point",
        ),
    )

    @classmethod
    def reading_size(cls, values: Mapping[str, Any]) -> int:
        return len(values["points"])

    @classmethod
    def cross_check(cls, values: Mapping[str, Any]) -> list[tuple[str, str]]:
        return [] if values["points"] else [("points", "needs at least one point")]

    @classmethod
    def preview(cls, values: Mapping[str, Any]) -> list[Segment]:
        return [s for x, y in values["points"] for s in cross(float(x), float(y))]

    @classmethod
    def measure(cls, world: Any, slots: Any, values: Mapping[str, Any], key: int) -> Any:
        xy = np.array(values["points"], dtype=np.float64).reshape(-1, 2)
        pts = _body_points(world, slots, xy)
        floor: FloorLayer = getattr(world, "floor", None) or FloorLayer()
        grey = floor.sample(pts.reshape(-1, 2)).reshape(len(slots), len(xy))
        grey = grey + _noise(key, grey.shape, float(values["noise"]))
        return np.clip(np.rint(grey), 0, 255).astype(np.int32)


class RangeFinder(ComponentType):
    name = "range_finder"
    doc = (
        "A range finder with a configurable beam: beams rays spread evenly over fov_deg around "
        "its heading, each reading the distance to the nearest wall, obstacle, robot or round "
        "object, max_range_mm when nothing is in range; Gaussian noise of noise_mm."
    )
    params = (
        Param(
            "pose",
            "numbers",
            "[x, y, heading] on the body, robot frame",
            "mm, mm, °",
            [0.0, 0.0, 0.0],
            lo=-1000.0,
            hi=1000.0,
            max_items=3,
        ),
        Param("beams", "integer", "number of rays", "", 1, lo=1, hi=64),
        Param(
            "fov_deg",
            "number",
            "angle the rays spread over (0: one direction)",
            "°",
            0.0,
            lo=0.0,
            hi=360.0,
        ),
        Param(
            "max_range_mm", "number", "farthest distance measured", "mm", 500.0, lo=10.0, hi=5000.0
        ),
        Param("noise_mm", "number", "Gaussian noise σ", "mm", 0.0, lo=0.0, hi=1000.0),
    )
    api = (
        ApiCall(
            "{name}()",
            "Reading of one distance per beam (mm from the sensor)",
            "beams from its right edge to its left (counter-clockwise)",
        ),
    )

    @classmethod
    def reading_size(cls, values: Mapping[str, Any]) -> int:
        return int(values["beams"])

    @classmethod
    def cross_check(cls, values: Mapping[str, Any]) -> list[tuple[str, str]]:
        return [] if len(values["pose"]) == 3 else [("pose", "must be [x, y, heading]")]

    @classmethod
    def preview(cls, values: Mapping[str, Any]) -> list[Segment]:
        """Each beam at full range."""
        beams, reach = int(values["beams"]), float(values["max_range_mm"])
        x, y, h = (float(v) for v in values["pose"])
        fov = math.radians(float(values["fov_deg"]))
        offsets = [fov * (i / (beams - 1) - 0.5) for i in range(beams)] if beams > 1 else [0.0]
        return [ray(x, y, math.radians(h) + o, reach) for o in offsets]

    @classmethod
    def measure(cls, world: Any, slots: Any, values: Mapping[str, Any], key: int) -> Any:
        beams, reach = int(values["beams"]), float(values["max_range_mm"])
        x, y, h = (float(v) for v in values["pose"])
        fov = math.radians(float(values["fov_deg"]))
        offsets = np.linspace(-fov / 2, fov / 2, beams) if beams > 1 else np.zeros(1)
        n = len(slots)
        origins = _body_points(world, slots, np.array([[x, y]]))[:, 0, :]  # (n, 2)
        angle = world.agent_pose[slots, 2][:, None] + math.radians(h) + offsets[None, :]
        o = np.repeat(origins, beams, axis=0)
        d = np.stack([np.cos(angle).ravel(), np.sin(angle).ravel()], axis=1)
        dist = np.full(n * beams, reach)
        grid = _segment_grid(world, max(reach, 120.0))
        which, seg = grid.pairs(o)
        if len(which):
            t = geometry.ray_segment(o[which], d[which], grid.segments[seg])
            np.minimum.at(dist, which, t)
        centres, radii, owner = _circles(world)
        cell = reach + float(radii.max(initial=0.0))
        which, ci = geometry.circle_pairs(o, centres, cell)
        own = np.asarray(slots)[which // beams]
        keep = owner[ci] != own  # a robot's own body does not block its sensor
        which, ci = which[keep], ci[keep]
        if len(which):
            t = geometry.ray_circle(o[which], d[which], centres[ci], radii[ci])
            np.minimum.at(dist, which, t)
        dist = dist + _noise(key, dist.shape, float(values["noise_mm"]))
        return np.clip(np.rint(dist), 0, reach).astype(np.int32).reshape(n, beams)


class Bumper(ComponentType):
    name = "bumper"
    doc = (
        "A ring of touch switches round the body: count equal sectors, the first centred on "
        "offset_deg from the front, going counter-clockwise; a switch reads 1 while a wall, "
        "obstacle, robot or round object is within reach_mm of the body in its sector."
    )
    params = (
        Param("count", "integer", "switches round the body", "", 4, lo=1, hi=32),
        Param(
            "reach_mm", "number", "how close a thing presses a switch", "mm", 1.0, lo=0.0, hi=50.0
        ),
        Param(
            "offset_deg",
            "number",
            "centre of the first switch from the front",
            "°",
            0.0,
            lo=-180.0,
            hi=180.0,
        ),
    )
    api = (
        ApiCall(
            "{name}()", "Reading of one 0/1 per switch", "1 while something touches that sector"
        ),
    )

    @classmethod
    def reading_size(cls, values: Mapping[str, Any]) -> int:
        return int(values["count"])

    @classmethod
    def preview(cls, values: Mapping[str, Any]) -> list[Segment]:
        """The borders between switches, short radial marks (the body's radius is not known
        here: drawn from 20 to 40 mm from the centre)."""
        count = int(values["count"])
        width = 2 * math.pi / count
        first = math.radians(float(values["offset_deg"])) - width / 2
        out = []
        for i in range(count):
            a = first + i * width
            out.append((20 * math.cos(a), 20 * math.sin(a), 40 * math.cos(a), 40 * math.sin(a)))
        return out

    @classmethod
    def measure(cls, world: Any, slots: Any, values: Mapping[str, Any], key: int) -> Any:
        slots = np.asarray(slots)
        count, reach = int(values["count"]), float(values["reach_mm"])
        n = len(slots)
        pose = world.agent_pose[slots]
        radius = world.tables.radius[slots]
        out = np.zeros((n, count), dtype=np.int32)
        rows: list[np.ndarray] = []
        bearings: list[np.ndarray] = []
        centres, radii, owner = _circles(world)
        cell = 2 * float(radii.max(initial=0.0)) + reach
        which, ci = geometry.circle_pairs(pose[:, :2], centres, cell)
        keep = owner[ci] != slots[which]
        which, ci = which[keep], ci[keep]
        gap = centres[ci] - pose[which, :2]
        touching = np.hypot(gap[:, 0], gap[:, 1]) - radii[ci] - radius[which] <= reach
        rows.append(which[touching])
        bearings.append(np.arctan2(gap[touching, 1], gap[touching, 0]))
        grid = _segment_grid(world, max(120.0, 2 * float(radius.max(initial=0.0)) + reach))
        which, seg = grid.pairs(pose[:, :2])
        if len(which):
            s = grid.segments[seg]
            a, e = s[:, :2], s[:, 2:] - s[:, :2]
            p = pose[which, :2]
            t = np.clip(
                np.sum((p - a) * e, axis=1) / np.maximum(np.sum(e * e, axis=1), 1e-12), 0, 1
            )
            gap = a + t[:, None] * e - p
            touching = np.hypot(gap[:, 0], gap[:, 1]) - radius[which] <= reach
            rows.append(which[touching])
            bearings.append(np.arctan2(gap[touching, 1], gap[touching, 0]))
        row = np.concatenate(rows)
        if len(row):
            bearing = np.concatenate(bearings) - pose[row, 2] - math.radians(values["offset_deg"])
            width = 2 * math.pi / count
            sector = np.floor(np.mod(bearing + width / 2, 2 * math.pi) / width).astype(np.int64)
            out[row, np.minimum(sector, count - 1)] = 1
        return out


BUILT_IN: tuple[type[ComponentType], ...] = (FloorSensor, RangeFinder, Bumper)
