"""Every agent's sensors at once: IR proximity, ambient light, gripper presence.

No per-robot Python loop: rays of all agents are numpy arrays of shape
(agents, rays); candidates come from a uniform grid (services/engine/geometry.py);
per-ray minima are taken with ``np.minimum.reduceat`` over pairs sorted by
agent. The only loops are over robot *types* and light sources, both few.

Readings (see docs/ENGINE.md for the curves):
- proximity: each sensor casts ``rays_per_sensor`` rays across its spread; the
  nearest hit distance goes through the type's response curve; seeded noise.
- ambient: each lit light within a sensor's cone and radius, not hidden by an
  obstacle (a ray from the robot's centre), lowers the reading.
- presence: the gripper's light barrier sees a round object between the fingers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from services.engine import geometry
from services.engine.specs import AmbientSpec, ProximitySpec

if TYPE_CHECKING:
    from services.engine.entities import Agent
    from services.engine.world import World

_MIN_CELL_MM = 120.0


@dataclass(frozen=True)
class AgentSensing:
    """The agents' sensor layouts as padded arrays (rebuilt when agents change)."""

    sensors: int  # proximity sensors per agent (padded)
    rays_per_sensor: int  # padded
    ray_local: np.ndarray  # (N, S*K, 3): x, y, angle in the robot frame
    reach: np.ndarray  # (N,) farthest any ray reaches from the centre
    prox_groups: list[tuple[ProximitySpec, np.ndarray]]  # (spec, agent slots) per type
    amb_local: np.ndarray  # (N, A, 3)
    amb_valid: np.ndarray  # (N, A)
    amb_groups: list[tuple[AmbientSpec, np.ndarray]]
    gripper: np.ndarray  # (N, 4): presence x0, x1, half width, has gripper (1/0)

    @classmethod
    def build(cls, agents: list[Agent]) -> AgentSensing:
        n = len(agents)
        s_max = max((len(a.spec.proximity.poses) for a in agents), default=8)
        k_max = max((a.spec.proximity.rays_per_sensor for a in agents), default=1)
        a_max = max((len(a.spec.ambient.poses) for a in agents), default=8)
        ray_local = np.zeros((n, s_max * k_max, 3))
        reach = np.zeros(n)
        amb_local = np.zeros((n, a_max, 3))
        amb_valid = np.zeros((n, a_max), dtype=bool)
        gripper = np.zeros((n, 4))
        by_type: dict[str, list[int]] = {}
        for slot, agent in enumerate(agents):
            spec = agent.spec
            prox = spec.proximity
            k = prox.rays_per_sensor
            offsets = (
                np.linspace(-prox.spread_rad / 2, prox.spread_rad / 2, k) if k > 1 else np.zeros(1)
            )
            for i, pose in enumerate(prox.poses):
                for j in range(k_max):
                    # padding rays repeat the sensor's last ray: they change no minimum
                    off = offsets[min(j, k - 1)]
                    ray_local[slot, i * k_max + j] = (pose.x_mm, pose.y_mm, pose.heading_rad + off)
            for i in range(len(prox.poses), s_max):
                ray_local[slot, i * k_max : (i + 1) * k_max] = ray_local[slot, 0]
            reach[slot] = spec.sensor_reach_mm
            for i, pose in enumerate(spec.ambient.poses):
                amb_local[slot, i] = (pose.x_mm, pose.y_mm, pose.heading_rad)
                amb_valid[slot, i] = True
            if agent.has_gripper and spec.gripper is not None:
                g = spec.gripper
                gripper[slot] = (*g.presence_x_mm, g.presence_half_width_mm, 1.0)
            by_type.setdefault(spec.name, []).append(slot)
        prox_groups = []
        amb_groups = []
        for slots in by_type.values():
            spec = agents[slots[0]].spec
            prox_groups.append((spec.proximity, np.array(slots)))
            amb_groups.append((spec.ambient, np.array(slots)))
        return cls(
            s_max, k_max, ray_local, reach, prox_groups, amb_local, amb_valid, amb_groups, gripper
        )


@dataclass(frozen=True)
class StaticGeometry:
    """Obstacles as segments (binned in a grid) and circles, for sensing."""

    segments: np.ndarray  # (S, 4)
    grid: geometry.SegmentGrid
    circle_centres: np.ndarray  # (C, 2)
    circle_radii: np.ndarray  # (C,)

    @classmethod
    def build(cls, world: World, cell_mm: float | None = None) -> StaticGeometry:
        w, h = world.width, world.height
        segs: list[tuple[float, float, float, float]] = [
            (0.0, 0.0, w, 0.0),
            (w, 0.0, w, h),
            (w, h, 0.0, h),
            (0.0, h, 0.0, 0.0),
        ]
        centres: list[tuple[float, float]] = []
        radii: list[float] = []
        for obstacle in world.obstacles.values():
            if obstacle.shape.kind == "circle":
                centres.append((obstacle.x, obstacle.y))
                radii.append(obstacle.shape.radius_mm)
                continue
            pts = obstacle.shape.world_vertices(obstacle.x, obstacle.y, obstacle.heading)
            for a, b in zip(pts, pts[1:] + pts[:1], strict=True):
                segs.append((a[0], a[1], b[0], b[1]))
        segments = np.array(segs, dtype=np.float64)
        cell = cell_mm or cell_size(world)
        return cls(
            segments,
            geometry.SegmentGrid.build(segments, cell),
            np.array(centres, dtype=np.float64).reshape(-1, 2),
            np.array(radii, dtype=np.float64),
        )


def cell_size(world: World) -> float:
    reach = float(world.agent_sensing.reach.max()) if len(world.agents) else 0.0
    radius = max(
        [a.spec.radius_mm for a in world.agents]
        + [o.shape.bounding_radius_mm for o in world.objects]
        + [o.shape.bounding_radius_mm for o in world.obstacles.values() if o.shape.kind == "circle"]
        + [0.0]
    )
    return max(_MIN_CELL_MM, reach + radius)


def _min_by_agent(dist: np.ndarray, agents: np.ndarray, t: np.ndarray) -> None:
    """dist[a] = min(dist[a], t rows of a); ``agents`` sorted ascending."""
    if len(agents) == 0:
        return
    starts = np.flatnonzero(np.r_[True, agents[1:] != agents[:-1]])
    mins = np.minimum.reduceat(t, starts, axis=0)
    rows = agents[starts]
    dist[rows] = np.minimum(dist[rows], mins)


def sense(world: World) -> None:
    n = len(world.agents)
    if n == 0:
        return
    layout = world.agent_sensing
    static = world.static_geometry
    assert layout is not None and static is not None
    cell = static.grid.cell_mm
    if cell < cell_size(world):  # an object larger than the grid was made for arrived
        static = world.static_geometry = StaticGeometry.build(world)
        cell = static.grid.cell_mm
    pose = world.agent_pose
    xy = pose[:, :2]
    c = np.cos(pose[:, 2])[:, None]
    s = np.sin(pose[:, 2])[:, None]
    rl = layout.ray_local
    origins = np.stack(
        [
            xy[:, 0:1] + c * rl[..., 0] - s * rl[..., 1],
            xy[:, 1:2] + s * rl[..., 0] + c * rl[..., 1],
        ],
        axis=-1,
    )
    angle = pose[:, 2:3] + rl[..., 2]
    dirs = np.stack([np.cos(angle), np.sin(angle)], axis=-1)
    dist = np.full(angle.shape, np.inf)

    # Circles: agents, round objects on the floor, round obstacles.
    round_objects = [
        (i, o)
        for i, o in enumerate(world.objects)
        if o.shape.kind == "circle" and _on_floor(world, o)
    ]
    obj_xy = (
        world.object_pose[[i for i, _ in round_objects], :2] if round_objects else np.zeros((0, 2))
    )
    obj_owner = np.array(
        [world._slot_of[o.held_by.serial] if o.held_by else -1 for _, o in round_objects],
        dtype=np.int64,
    )
    centres = np.concatenate([xy, obj_xy, static.circle_centres])
    radii = np.concatenate(
        [world.tables.radius, [o.shape.radius_mm for _, o in round_objects], static.circle_radii]
    )
    owner = np.concatenate(
        [np.arange(n), obj_owner, np.full(len(static.circle_radii), -1, dtype=np.int64)]
    )
    pa, pc = geometry.circle_pairs(xy, centres, cell)
    if len(pa):
        d2 = np.sum((centres[pc] - xy[pa]) ** 2, axis=1)
        keep = (owner[pc] != pa) & (d2 < (layout.reach[pa] + radii[pc]) ** 2)
        pa, pc = pa[keep], pc[keep]
        t = geometry.ray_circle(origins[pa], dirs[pa], centres[pc][:, None, :], radii[pc][:, None])
        _min_by_agent(dist, pa, t)

    # Obstacle edges through the static grid.
    sa, ss = static.grid.pairs(xy)
    if len(sa):
        t = geometry.ray_segment(origins[sa], dirs[sa], static.segments[ss][:, None, :])
        _min_by_agent(dist, sa, t)

    # Edges of movable boxes and polygons (few): every agent against every edge nearby.
    edges = _object_edges(world)
    if len(edges):
        mid = (edges[:, :2] + edges[:, 2:]) / 2
        half = np.hypot(*(edges[:, 2:] - edges[:, :2]).T) / 2
        near = (
            np.sum((xy[:, None, :] - mid[None]) ** 2, axis=2)
            < (layout.reach[:, None] + half[None]) ** 2
        )
        ea, ee = np.nonzero(near)
        if len(ea):
            t = geometry.ray_segment(origins[ea], dirs[ea], edges[ee][:, None, :])
            _min_by_agent(dist, ea, t)

    per_sensor = dist.reshape(n, layout.sensors, layout.rays_per_sensor).min(axis=2)
    prox = np.zeros((n, world.proximity.shape[1]), dtype=np.int32)
    for spec, slots in layout.prox_groups:
        k = len(spec.poses)
        value = spec.curve(per_sensor[slots, :k])
        noise = world.rng.standard_normal((2, len(slots), k))
        value = value * (1.0 + spec.noise_fraction * noise[0]) + spec.noise_counts * noise[1]
        prox[slots[:, None], np.arange(k)[None, :]] = np.clip(np.rint(value), 0, spec.max_value)
    world.proximity = prox

    _presence(world, pa, pc, centres, n)
    _ambient(world, static)


def _on_floor(world: World, obj: object) -> bool:
    held_by = getattr(obj, "held_by", None)
    if held_by is None:
        return True
    slot = world._slot_of[held_by.serial]
    return bool(world.arm[slot] >= world.tables.arm_lowered_above[slot])


def _object_edges(world: World) -> np.ndarray:
    edges: list[tuple[float, float, float, float]] = []
    for i, obj in enumerate(world.objects):
        if obj.shape.kind == "circle" or not _on_floor(world, obj):
            continue
        x, y, h = world.object_pose[i]
        pts = obj.shape.world_vertices(x, y, h)
        for a, b in zip(pts, pts[1:] + pts[:1], strict=True):
            edges.append((a[0], a[1], b[0], b[1]))
    return np.array(edges, dtype=np.float64).reshape(-1, 4)


def _presence(world: World, pa: np.ndarray, pc: np.ndarray, centres: np.ndarray, n: int) -> None:
    """The gripper's light barrier: a round object's centre between the fingers, arm down."""
    grip = world.agent_sensing.gripper if world.agent_sensing else np.zeros((n, 4))
    presence = np.zeros(n, dtype=np.int32)
    holding = np.array([a.held is not None for a in world.agents], dtype=bool)
    presence[holding] = 255
    is_object = (pc >= n) & (pc < n + len(world.objects))
    if len(pa) and np.any(is_object):
        a, c = pa[is_object], pc[is_object]
        keep = grip[a, 3] > 0
        a, c = a[keep], c[keep]
        pose = world.agent_pose[a]
        d = centres[c] - pose[:, :2]
        co, si = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        lx = co * d[:, 0] + si * d[:, 1]
        ly = -si * d[:, 0] + co * d[:, 1]
        inside = (lx >= grip[a, 0]) & (lx <= grip[a, 1]) & (np.abs(ly) <= grip[a, 2])
        inside &= world.arm[a] >= world.tables.arm_lowered_above[a]
        presence[a[inside]] = 255
    world.presence = presence


def _ambient(world: World, static: StaticGeometry) -> None:
    n = len(world.agents)
    layout = world.agent_sensing
    assert layout is not None
    total = np.zeros((n, layout.amb_local.shape[1]))
    lit = [light for light in world.lights if light.is_on(world.sim_time) and light.intensity > 0]
    xy = world.agent_pose[:, :2]
    if lit:
        lxy = np.array([(light.x, light.y) for light in lit])
        radius = np.array([light.radius_mm for light in lit])
        intensity = np.array([light.intensity for light in lit])
        d2 = np.sum((xy[:, None, :] - lxy[None]) ** 2, axis=2)
        pa, pl = np.nonzero(d2 < (radius[None] + 40.0) ** 2)
        if len(pa):
            visible = ~_occluded(xy[pa], lxy[pl], static)
            pa, pl = pa[visible], pl[visible]
        if len(pa):
            pose = world.agent_pose[pa]
            local = layout.amb_local[pa]  # (P, A, 3)
            co, si = np.cos(pose[:, 2])[:, None], np.sin(pose[:, 2])[:, None]
            sx = pose[:, 0:1] + co * local[..., 0] - si * local[..., 1]
            sy = pose[:, 1:2] + si * local[..., 0] + co * local[..., 1]
            vx = lxy[pl, 0][:, None] - sx
            vy = lxy[pl, 1][:, None] - sy
            bearing = np.angle(np.exp(1j * (np.arctan2(vy, vx) - pose[:, 2:3] - local[..., 2])))
            closeness = np.clip(1.0 - np.hypot(vx, vy) / radius[pl][:, None], 0.0, 1.0)
            half = np.zeros(len(pa))
            drop = np.zeros(len(pa))
            for spec, slots in layout.amb_groups:
                mask = np.isin(pa, slots)
                half[mask] = spec.half_angle_rad
                drop[mask] = spec.drop
            cone = np.abs(bearing) < half[:, None]
            contrib = np.where(cone, np.cos(1.5 * bearing), 0.0) * closeness
            contrib *= (drop * intensity[pl])[:, None] * layout.amb_valid[pa]
            np.add.at(total, pa, contrib)
    amb = np.zeros_like(world.ambient)
    for spec, slots in layout.amb_groups:
        k = len(spec.poses)
        value = np.clip(spec.dark_value - total[slots, :k], spec.floor_value, spec.dark_value)
        value = value * (1.0 + spec.noise_fraction * world.rng.standard_normal((len(slots), k)))
        amb[slots[:, None], np.arange(k)[None, :]] = np.clip(np.rint(value), 0, 1023 * 4)
    world.ambient = amb


def _occluded(p: np.ndarray, q: np.ndarray, static: StaticGeometry) -> np.ndarray:
    """Whether an obstacle lies on each segment p -> q (chunked to bound memory)."""
    out = np.zeros(len(p), dtype=bool)
    segs = static.segments[4:]  # the arena's own walls never stand between two inside points
    chunk = max(1, 200_000 // max(1, len(segs) + len(static.circle_radii)))
    for start in range(0, len(p), chunk):
        a, b = p[start : start + chunk], q[start : start + chunk]
        hit = np.zeros(len(a), dtype=bool)
        if len(segs):
            hit |= geometry.segments_cross(a[:, None, :], b[:, None, :], segs[None]).any(axis=1)
        if len(static.circle_radii):
            d = b - a
            length = np.hypot(d[:, 0], d[:, 1])
            unit = d / np.maximum(length, 1e-9)[:, None]
            t = geometry.ray_circle(
                a[:, None, :],
                unit[:, None, :],
                static.circle_centres[None],
                static.circle_radii[None],
            )
            hit |= (t < length[:, None]).any(axis=1)
        out[start : start + chunk] = hit
    return out
