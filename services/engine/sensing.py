"""Every agent's sensors at once: IR proximity, ambient light, gripper presence.

No per-robot Python loop: one compiled kernel (services/engine/kernels.py)
casts every robot's rays against the circles (robots, round objects, round
obstacles) of the 3x3 grid cells around it, the static obstacle edges binned
in its own cell, and the edges of movable polygons nearby, then applies the
response curve and the seeded noise, the ambient model and the gripper's
presence barrier. This module prepares the kernel's tables: per-agent sensor
layouts (rebuilt when agents change) and the static geometry (rebuilt when
obstacles or the arena change); a sensing pass only gathers what moves.

Readings (see the "Sensor models" part of docs/ARCHITECTURE.md section 9):
- proximity: each sensor casts ``rays_per_sensor`` rays across its spread; the
  nearest hit distance goes through the type's response curve; seeded noise.
- ambient: each lit light within a sensor's cone and radius, not hidden by an
  obstacle (a ray from the robot's centre), lowers the reading.
- presence: the gripper's light barrier sees a round object between the fingers.

Noise: ``noise_total`` standard normal values per pass from the world's
generator, laid out as the earlier per-type draws were (per type: proximity
multiplicative and additive, then per type: ambient), so a seed gives the same
readings. They are drawn in blocks of many passes (NoiseStream): one numpy call
costs as much as the kernel's whole pass at 10 robots, and a block hands out
exactly the values the per-pass draws would have, in the same order.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from services.engine import kernels as K
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
    ray_local: np.ndarray  # (N, S*K, 5): x, y, angle, cos(angle), sin(angle) in the robot frame
    reach: np.ndarray  # (N,) farthest any ray reaches from the centre
    prox_groups: list[tuple[ProximitySpec, np.ndarray]]  # (spec, agent slots) per type
    amb_local: np.ndarray  # (N, A, 3)
    amb_valid: np.ndarray  # (N, A)
    amb_groups: list[tuple[AmbientSpec, np.ndarray]]
    gripper: np.ndarray  # (N, 4): presence x0, x1, half width, has gripper (1/0)
    # The kernel's packed tables (services/engine/kernels.py names the columns).
    agent_f: np.ndarray  # (N, kernels.N_AGENT_F)
    agent_i: np.ndarray  # (N, kernels.N_AGENT_I)
    curve_x: np.ndarray  # (types, points) response curves, padded
    curve_y: np.ndarray
    curve_n: np.ndarray  # (types,) points used
    noise_total: int  # standard normal draws per sensing pass

    @classmethod
    def build(
        cls, agents: list[Agent], radius: np.ndarray, arm_lowered_above: np.ndarray
    ) -> AgentSensing:
        n = len(agents)
        s_max = max((len(a.spec.proximity.poses) for a in agents), default=8)
        k_max = max((a.spec.proximity.rays_per_sensor for a in agents), default=1)
        a_max = max((len(a.spec.ambient.poses) for a in agents), default=8)
        ray_local = np.zeros((n, s_max * k_max, 5))
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
                    angle = pose.heading_rad + off
                    ray_local[slot, i * k_max + j] = (
                        pose.x_mm,
                        pose.y_mm,
                        angle,
                        np.cos(angle),
                        np.sin(angle),
                    )
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

        # Packed per-agent tables for the kernel.
        f = np.zeros((n, K.N_AGENT_F))
        i_tab = np.zeros((n, K.N_AGENT_I), dtype=np.int64)
        f[:, K.F_REACH] = reach
        f[:, K.F_RADIUS] = radius
        f[:, K.F_GRIP_X0 : K.F_HAS_GRIP + 1] = gripper
        f[:, K.F_ARM_LOWERED_ABOVE] = arm_lowered_above
        curves = [p.curve for p, _ in prox_groups]
        points = max((len(c.distances_mm) for c in curves), default=2)
        curve_x = np.zeros((len(curves), points))
        curve_y = np.zeros((len(curves), points))
        curve_n = np.zeros(len(curves), dtype=np.int64)
        # Noise layout, in the order the draws were made one type at a time:
        # per type (2, agents, sensors) for proximity, then per type (agents, sensors).
        offset = 0
        for g, (p, slots) in enumerate(prox_groups):
            c = p.curve
            curve_n[g] = len(c.distances_mm)
            curve_x[g, : curve_n[g]] = c.distances_mm
            curve_y[g, : curve_n[g]] = c.values
            k = len(p.poses)
            f[slots, K.F_PROX_NOISE_FRACTION] = p.noise_fraction
            f[slots, K.F_PROX_NOISE_COUNTS] = p.noise_counts
            f[slots, K.F_PROX_MAX] = float(p.max_value)
            i_tab[slots, K.I_PROX_SENSORS] = k
            i_tab[slots, K.I_CURVE] = g
            i_tab[slots, K.I_PROX_NOISE_MUL] = offset + np.arange(len(slots)) * k
            i_tab[slots, K.I_PROX_NOISE_ADD] = offset + (len(slots) + np.arange(len(slots))) * k
            offset += 2 * len(slots) * k
        for a, slots in amb_groups:
            k = len(a.poses)
            f[slots, K.F_AMB_HALF_ANGLE] = a.half_angle_rad
            f[slots, K.F_AMB_DROP] = a.drop
            f[slots, K.F_AMB_DARK] = float(a.dark_value)
            f[slots, K.F_AMB_FLOOR] = float(a.floor_value)
            f[slots, K.F_AMB_NOISE_FRACTION] = a.noise_fraction
            i_tab[slots, K.I_AMB_SENSORS] = k
            i_tab[slots, K.I_AMB_NOISE] = offset + np.arange(len(slots)) * k
            offset += len(slots) * k
        return cls(
            s_max,
            k_max,
            ray_local,
            reach,
            prox_groups,
            amb_local,
            amb_valid,
            amb_groups,
            gripper,
            f,
            i_tab,
            curve_x,
            curve_y,
            curve_n,
            offset,
        )


@dataclass(frozen=True)
class StaticGeometry:
    """Obstacles as segments (binned in a dense grid) and circles, for sensing.

    Built once and rebuilt only when obstacles or the arena change (or an object
    larger than the grid was made for arrives).
    """

    segments: np.ndarray  # (S, 4), the arena's 4 walls first
    circle_centres: np.ndarray  # (C, 2)
    circle_radii: np.ndarray  # (C,)
    cell_mm: float
    nx: int  # grid cells along x and y (one margin cell on every side)
    ny: int
    cell_start: np.ndarray  # (nx * ny + 1,) CSR offsets, cell index = ix * ny + iy
    cell_items: np.ndarray  # segment index of each (cell, segment) entry
    occluders: np.ndarray  # segments that can hide a light (all but the arena's walls)
    # Circles passed to the kernel when there are no movable objects.
    no_objects: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

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
        cell = float(cell_mm or cell_size(world))
        nx = int(np.floor(w / cell)) + 3
        ny = int(np.floor(h / cell)) + 3
        # Every segment goes into every cell within one cell of its bounding box.
        buckets: list[list[int]] = [[] for _ in range(nx * ny)]
        for s, (ax, ay, bx, by) in enumerate(segments):
            x0 = max(int(np.floor(min(ax, bx) / cell)), 0)
            x1 = min(int(np.floor(max(ax, bx) / cell)) + 2, nx - 1)
            y0 = max(int(np.floor(min(ay, by) / cell)), 0)
            y1 = min(int(np.floor(max(ay, by) / cell)) + 2, ny - 1)
            for ix in range(x0, x1 + 1):
                for iy in range(y0, y1 + 1):
                    buckets[ix * ny + iy].append(s)
        start = np.zeros(nx * ny + 1, dtype=np.int64)
        start[1:] = np.cumsum([len(b) for b in buckets])
        items = np.array([s for b in buckets for s in b], dtype=np.int64)
        centres_a = np.array(centres, dtype=np.float64).reshape(-1, 2)
        radii_a = np.array(radii, dtype=np.float64)
        return cls(
            segments,
            centres_a,
            radii_a,
            cell,
            nx,
            ny,
            start,
            items,
            np.ascontiguousarray(segments[4:]),
            (
                centres_a,
                radii_a,
                np.full(len(radii_a), -1, dtype=np.int64),
                np.zeros(len(radii_a), dtype=bool),
            ),
        )


def cell_size(world: World) -> float:
    """Grid cell: the longest sensor reach plus the largest radius (at least 120 mm)."""
    cached = world._cell_cache
    if cached is not None and cached[0] == world.layout:
        return cached[1]
    reach = float(world.agent_sensing.reach.max()) if len(world.agents) else 0.0
    radius = max(
        [a.spec.radius_mm for a in world.agents]
        + [o.shape.bounding_radius_mm for o in world.objects]
        + [o.shape.bounding_radius_mm for o in world.obstacles.values() if o.shape.kind == "circle"]
        + [0.0]
    )
    value = max(_MIN_CELL_MM, reach + radius)
    world._cell_cache = (world.layout, value)
    return value


_NO_EDGES = np.zeros((0, 4))
_NO_LIGHTS = np.zeros((0, 4))


class NoiseStream:
    """Standard normal values from ``rng``, handed out in order, drawn in blocks.

    ``take(n)`` returns the next ``n`` values of the generator's stream: the same
    values, in the same order, as ``rng.standard_normal(n)`` called each time
    (numpy's Generator fills arrays sequentially from its bit stream), for a
    fraction of the per-call overhead.
    """

    def __init__(self, rng: np.random.Generator, block: int = 4096) -> None:
        self._rng = rng
        self._block = block
        self._buf = np.zeros(0)
        self._pos = 0

    def take(self, n: int) -> np.ndarray:
        end = self._pos + n
        if end > len(self._buf):
            rest = self._buf[self._pos :]
            fresh = self._rng.standard_normal(max(self._block, 32 * n))
            self._buf = np.concatenate([rest, fresh]) if len(rest) else fresh
            self._pos, end = 0, n
        out = self._buf[self._pos : end]
        self._pos = end
        return out


def _on_floor(world: World, obj: object) -> bool:
    held_by = getattr(obj, "held_by", None)
    if held_by is None:
        return True
    slot = world._slot_of[held_by.serial]
    return bool(world.arm[slot] >= world.tables.arm_lowered_above[slot])


def _objects(
    world: World, static: StaticGeometry
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Circles other than the agents (round objects on the floor, round obstacles) and edges."""
    if not world.objects:
        return (*static.no_objects, _NO_EDGES)
    idx: list[int] = []
    radius: list[float] = []
    owner: list[int] = []
    edges: list[tuple[float, float, float, float]] = []
    for i, obj in enumerate(world.objects):
        if not _on_floor(world, obj):
            continue
        if obj.shape.kind == "circle":
            idx.append(i)
            radius.append(obj.shape.radius_mm)
            owner.append(world._slot_of[obj.held_by.serial] if obj.held_by else -1)
            continue
        x, y, h = world.object_pose[i]
        pts = obj.shape.world_vertices(x, y, h)
        for a, b in zip(pts, pts[1:] + pts[:1], strict=True):
            edges.append((a[0], a[1], b[0], b[1]))
    xy = np.concatenate([world.object_pose[idx, :2], static.circle_centres])
    r = np.concatenate([np.array(radius, dtype=np.float64), static.circle_radii])
    own = np.concatenate([np.array(owner, dtype=np.int64), static.no_objects[2]])
    is_obj = np.zeros(len(r), dtype=bool)
    is_obj[: len(idx)] = True
    return xy, r, own, is_obj, np.array(edges, dtype=np.float64).reshape(-1, 4)


_lights_cache: dict[tuple[tuple[float, float, float, float], ...], np.ndarray] = {}


def _lights(world: World) -> np.ndarray:
    """(L, 4) x, y, radius, intensity of the lights on now (edited live: keyed on values)."""
    key = tuple(
        (light.x, light.y, light.radius_mm, light.intensity)
        for light in world.lights
        if light.intensity > 0 and light.is_on(world.sim_time)
    )
    if not key:
        return _NO_LIGHTS
    table = _lights_cache.get(key)
    if table is None:
        if len(_lights_cache) > 64:  # blinking sets alternate; edits make new ones
            _lights_cache.clear()
        table = _lights_cache[key] = np.array(key, dtype=np.float64)
    return table


def sense(world: World) -> None:
    n = len(world.agents)
    if n == 0:
        return
    layout = world.agent_sensing
    static = world.static_geometry
    assert layout is not None and static is not None
    if static.cell_mm < cell_size(world):  # an object larger than the grid was made for arrived
        static = world.static_geometry = StaticGeometry.build(world)
    circ_xy, circ_r, circ_owner, circ_obj, edges = _objects(world, static)
    holding = world.holding()
    noise = world.noise.take(layout.noise_total)
    prox = np.empty((n, world.proximity.shape[1]), dtype=np.int32)
    amb = np.empty((n, world.ambient.shape[1]), dtype=np.int32)
    presence = np.empty(n, dtype=np.int32)
    K.sense(
        world.agent_pose,
        layout.ray_local,
        layout.sensors,
        layout.rays_per_sensor,
        layout.agent_f,
        layout.agent_i,
        layout.curve_x,
        layout.curve_y,
        layout.curve_n,
        world.arm,
        holding,
        circ_xy,
        circ_r,
        circ_owner,
        circ_obj,
        edges,
        static.segments,
        static.cell_start,
        static.cell_items,
        static.nx,
        static.ny,
        static.cell_mm,
        static.occluders,
        static.circle_centres,
        static.circle_radii,
        layout.amb_local,
        layout.amb_valid,
        _lights(world),
        noise,
        prox,
        amb,
        presence,
    )
    world.proximity = prox
    world.ambient = amb
    world.presence = presence
