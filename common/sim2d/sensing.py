"""Every agent's sensors at once: IR proximity, ambient light, gripper presence.

No per-robot Python loop: one compiled kernel (common/sim2d/kernels.py)
casts every robot's rays against the circles (robots, round objects, round
obstacles) of the 3x3 grid cells around it, the static obstacle edges binned
in its own cell, and the edges of movable polygons nearby, then applies the
response curve and the seeded noise, the ambient model and the gripper's
presence barrier. This module prepares the kernel's tables: per-agent sensor
layouts (rebuilt when agents change) and the static geometry (rebuilt when
obstacles or the arena change); a sensing pass only gathers what moves.

Readings (see the "Sensor models" part of docs/WORLDS.md):
- proximity: each sensor casts ``rays_per_sensor`` rays across its spread; the
  nearest hit distance goes through the type's response curve, times the sensor's
  gain (1 but on a real robot's twin); seeded noise.
- ambient: each lit light within a sensor's cone and radius, not hidden by an
  obstacle (a ray from the robot's centre), lowers the reading.
- presence: the gripper's light barrier sees a round object between the fingers.

Noise: one 64-bit key per pass from the world's seeded generator (NoiseKeys);
the kernel derives every sensor's Gaussian noise from the key, the agent's slot
and the sensor (common/sim2d/kernels.py: ``normal``), so a seed gives the same
readings on any number of threads, and no numpy call draws noise per pass.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

# The packs' layouts (packs.py, no numba); the kernels through compiled.py.
from common.sim2d import compiled
from common.sim2d import packs as K
from common.sim2d.entities import Light

if TYPE_CHECKING:
    from common.sim2d.entities import Agent, MovableObject, Obstacle
    from common.sim2d.specs import AgentTypeSpec

_MIN_CELL_MM = 120.0
# Below this many agents a pass runs on one thread even when more are allowed. A
# judgement, not a measured crossover: a pass at 10 robots takes ~15 us, less than
# waking a pool, and on the shared development machine no thread count beat one at
# any size (docs/BENCHMARKS.md, "Sim2D engine").
PARALLEL_MIN_AGENTS = 256


class SensedWorld(Protocol):
    """What sensing reads of a world: public state only, never written back."""

    width: float
    height: float
    layout: int
    sim_time: float
    threads: int  # threads a sensing pass may use (kernels.sense_parallel)
    agents: list[Agent]
    objects: list[MovableObject]
    obstacles: dict[str, Obstacle]
    lights: list[Light]
    agent_pose: np.ndarray
    object_pose: np.ndarray
    arm: np.ndarray

    def holding(self) -> np.ndarray: ...

    def slot_of(self, agent: Agent) -> int: ...

    def on_floor(self, obj: MovableObject) -> bool: ...


def _types(agents: Sequence[Agent]) -> list[tuple[AgentTypeSpec, np.ndarray]]:
    """(type, agent slots) per robot type, in order of first appearance."""
    by_type: dict[str, list[int]] = {}
    for slot, agent in enumerate(agents):
        by_type.setdefault(agent.spec.name, []).append(slot)
    return [(agents[slots[0]].spec, np.array(slots)) for slots in by_type.values()]


# --- sensor components --------------------------------------------------------------
# One class per kind of sensor a robot carries (Enki's IRSensor, ARGoS's sensor
# interfaces): each lays out its sensors for every agent at once and writes its
# columns of the kernel's per-agent tables. The kernel then reads them all in one
# pass over the robots.


@dataclass(frozen=True)
class ProximitySensors:
    """The IR proximity ring: rays across each sensor's spread, a response curve per type."""

    sensors: int  # per agent (padded)
    rays_per_sensor: int  # padded
    # (types, S*K, 5): x, y, angle, cos(angle), sin(angle) in the robot frame, one
    # layout per robot type (agent_i's I_TYPE column): per agent, 10,000 copies of
    # the same 1 KB were read from memory every pass.
    ray_local: np.ndarray
    reach: np.ndarray  # (N,) farthest any ray reaches from the centre
    curve_x: np.ndarray  # (types, points) response curves, padded
    curve_y: np.ndarray
    curve_n: np.ndarray  # (types,) points used
    gain: np.ndarray  # (types, S) each sensor's gain on its type's curve
    counts: np.ndarray  # (types, S) each sensor's additive noise σ (counts)

    @classmethod
    def build(
        cls,
        agents: Sequence[Agent],
        types: list[tuple[AgentTypeSpec, np.ndarray]],
        f: np.ndarray,
        i_tab: np.ndarray,
    ) -> ProximitySensors:
        """The ring of every agent."""
        n = len(agents)
        s_max = max((len(a.spec.proximity.poses) for a in agents), default=8)
        k_max = max((a.spec.proximity.rays_per_sensor for a in agents), default=1)
        ray_local = np.zeros((len(types), s_max * k_max, 5))
        reach = np.zeros(n)
        for g, (spec, slots) in enumerate(types):
            prox = spec.proximity
            k = prox.rays_per_sensor
            offsets = (
                np.linspace(-prox.spread_rad / 2, prox.spread_rad / 2, k) if k > 1 else np.zeros(1)
            )
            for i, pose in enumerate(prox.poses):
                for j in range(k_max):
                    # padding rays repeat the sensor's last ray: they change no minimum
                    angle = pose.heading_rad + offsets[min(j, k - 1)]
                    ray_local[g, i * k_max + j] = (
                        pose.x_mm,
                        pose.y_mm,
                        angle,
                        np.cos(angle),
                        np.sin(angle),
                    )
            for i in range(len(prox.poses), s_max):
                ray_local[g, i * k_max : (i + 1) * k_max] = ray_local[g, 0]
            reach[slots] = spec.sensor_reach_mm
        f[:, K.F_REACH] = reach
        points = max((len(t.proximity.curve.distances_mm) for t, _ in types), default=2)
        curve_x = np.zeros((len(types), points))
        curve_y = np.zeros((len(types), points))
        curve_n = np.zeros(len(types), dtype=np.int64)
        gain = np.ones((len(types), s_max))
        counts = np.zeros((len(types), s_max))
        for g, (spec, slots) in enumerate(types):
            p = spec.proximity
            c = p.curve
            curve_n[g] = len(c.distances_mm)
            curve_x[g, : curve_n[g]] = c.distances_mm
            curve_y[g, : curve_n[g]] = c.values
            k = len(p.poses)
            gain[g, :k] = [p.gain(i) for i in range(k)]
            counts[g, :k] = [p.counts(i) for i in range(k)]
            f[slots, K.F_PROX_NOISE_FRACTION] = p.noise_fraction
            f[slots, K.F_PROX_MAX] = float(p.max_value)
            i_tab[slots, K.I_PROX_SENSORS] = k
            i_tab[slots, K.I_TYPE] = g
        return cls(s_max, k_max, ray_local, reach, curve_x, curve_y, curve_n, gain, counts)


@dataclass(frozen=True)
class AmbientSensors:
    """Ambient light sensors: a cone each; lit lights in reach lower the reading."""

    local: np.ndarray  # (types, A, 5): x, y, heading, cos, sin of heading, robot frame
    valid: np.ndarray  # (types, A)

    @classmethod
    def build(
        cls,
        agents: Sequence[Agent],
        types: list[tuple[AgentTypeSpec, np.ndarray]],
        f: np.ndarray,
        i_tab: np.ndarray,
    ) -> AmbientSensors:
        a_max = max((len(a.spec.ambient.poses) for a in agents), default=8)
        local = np.zeros((len(types), a_max, 5))
        valid = np.zeros((len(types), a_max), dtype=bool)
        for g, (spec, _) in enumerate(types):
            for i, pose in enumerate(spec.ambient.poses):
                h = pose.heading_rad
                local[g, i] = (pose.x_mm, pose.y_mm, h, np.cos(h), np.sin(h))
                valid[g, i] = True
        for spec, slots in types:
            a = spec.ambient
            k = len(a.poses)
            f[slots, K.F_AMB_HALF_ANGLE] = a.half_angle_rad
            f[slots, K.F_AMB_COS_HALF] = np.cos(a.half_angle_rad)
            f[slots, K.F_AMB_DROP] = a.drop
            f[slots, K.F_AMB_DARK] = float(a.dark_value)
            f[slots, K.F_AMB_FLOOR] = float(a.floor_value)
            f[slots, K.F_AMB_NOISE_FRACTION] = a.noise_fraction
            i_tab[slots, K.I_AMB_SENSORS] = k
        return cls(local, valid)


def fit_gripper_barriers(
    agents: Sequence[Agent], arm_lowered_above: np.ndarray, f: np.ndarray
) -> None:
    """The gripper's light barrier: sees a round object between the lowered tongs (no noise)."""
    for slot, agent in enumerate(agents):
        g = agent.spec.gripper
        if agent.has_gripper and g is not None:
            f[slot, K.F_GRIP_X0 : K.F_HAS_GRIP + 1] = (
                *g.presence_x_mm,
                g.presence_half_width_mm,
                1.0,
            )
    f[:, K.F_ARM_LOWERED_ABOVE] = arm_lowered_above


@dataclass(frozen=True)
class AgentSensing:
    """Every agent's sensor components, and the kernel's tables packed from them."""

    proximity: ProximitySensors
    ambient: AmbientSensors
    tables: K.SensorTables
    kernel_tables: tuple[object, ...]  # ``tables`` as a plain tuple (SensorSuite.read)

    @classmethod
    def build(
        cls, agents: Sequence[Agent], radius: np.ndarray, arm_lowered_above: np.ndarray
    ) -> AgentSensing:
        n = len(agents)
        types = _types(agents)
        f = np.zeros((n, K.N_AGENT_F))
        i_tab = np.zeros((n, K.N_AGENT_I), dtype=np.int64)
        f[:, K.F_RADIUS] = radius
        ring = ProximitySensors.build(agents, types, f, i_tab)
        ambient = AmbientSensors.build(agents, types, f, i_tab)
        fit_gripper_barriers(agents, arm_lowered_above, f)
        tables = K.SensorTables(
            ring.ray_local,
            ring.sensors,
            ring.rays_per_sensor,
            f,
            i_tab,
            ring.curve_x,
            ring.curve_y,
            ring.curve_n,
            ambient.local,
            ambient.valid,
            ring.gain,
            ring.counts,
        )
        return cls(ring, ambient, tables, tuple(tables))


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
    scene: K.StaticScene  # the same, packed for the kernel
    kernel_scene: tuple[object, ...]  # ``scene`` as a plain tuple (SensorSuite.read)
    # Circles passed to the kernel when there are no movable objects.
    no_objects: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

    @classmethod
    def build(
        cls, width: float, height: float, obstacles: Sequence[Obstacle], cell_mm: float
    ) -> StaticGeometry:
        w, h = width, height
        segs: list[tuple[float, float, float, float]] = [
            (0.0, 0.0, w, 0.0),
            (w, 0.0, w, h),
            (w, h, 0.0, h),
            (0.0, h, 0.0, 0.0),
        ]
        centres: list[tuple[float, float]] = []
        radii: list[float] = []
        for obstacle in obstacles:
            if obstacle.shape.kind == "circle":
                centres.append((obstacle.x, obstacle.y))
                radii.append(obstacle.shape.radius_mm)
                continue
            pts = obstacle.shape.world_vertices(obstacle.x, obstacle.y, obstacle.heading)
            for a, b in zip(pts, pts[1:] + pts[:1], strict=True):
                segs.append((a[0], a[1], b[0], b[1]))
        segments = np.array(segs, dtype=np.float64)
        cell = float(cell_mm)
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
        scene = K.StaticScene(
            segments,
            start,
            items,
            nx,
            ny,
            cell,
            np.ascontiguousarray(segments[4:]),
            centres_a,
            radii_a,
        )
        no_objects = (
            centres_a,
            radii_a,
            np.full(len(radii_a), -1, dtype=np.int64),
            np.zeros(len(radii_a), dtype=bool),
        )
        return cls(segments, centres_a, radii_a, cell, scene, tuple(scene), no_objects)


NO_EDGES = np.zeros((0, 4))
NO_LIGHTS = np.zeros((0, 4))


class NoiseKeys:
    """One 64-bit noise key per sensing pass from ``rng``, drawn in blocks.

    ``next()`` returns the generator's next raw 64-bit output: the same keys, in
    the same order, whatever the block size (numpy's bit generators hand out raw
    words in sequence), for a fraction of a numpy call per pass.
    """

    def __init__(self, rng: np.random.Generator, block: int = 256) -> None:
        # The method is a C iterator's __next__: no Python frame per key (a third of
        # what indexing the block and counting cost, 0.12 us a pass).
        self.next: Callable[[], np.uint64] = itertools.chain.from_iterable(
            _key_blocks(rng, block)
        ).__next__


def _key_blocks(rng: np.random.Generator, block: int) -> Iterator[list[np.uint64]]:
    """Blocks of the generator's raw words as numpy uint64 scalars (the kernel's key type)."""
    while True:
        yield list(rng.bit_generator.random_raw(block))


class SensorSuite:
    """Every sensor of every agent of one world, read in one compiled pass.

    The world tells it when agents come or go (:meth:`fit`) and when obstacles
    or the arena change (:meth:`obstacles_changed`); :meth:`read` then reads the
    world's public state (:class:`SensedWorld`) and returns the readings.
    """

    def __init__(self, noise: NoiseKeys) -> None:
        self.noise = noise
        self.agents = AgentSensing.build([], np.zeros(0), np.zeros(0))
        self._static: StaticGeometry | None = None
        self._cell: tuple[int, float] | None = None  # (world layout, grid cell)
        self._lights: dict[tuple[tuple[float, float, float, float], ...], np.ndarray] = {}
        # While no light blinks (lit): (Light.edits, world layout, its list of lights,
        # their count, their table).
        self._steady: tuple[int, int, object, int, np.ndarray] = (-1, -1, None, 0, NO_LIGHTS)

    def fit(
        self, agents: Sequence[Agent], radius: np.ndarray, arm_lowered_above: np.ndarray
    ) -> None:
        """Lay out the sensors of these agents (slot order)."""
        self.agents = AgentSensing.build(agents, radius, arm_lowered_above)
        self._cell = None

    def obstacles_changed(self) -> None:
        self._static = None

    def current_static(self) -> StaticGeometry | None:
        """The static geometry as last built, None once obstacles changed (no rebuild)."""
        return self._static

    def cell_size(self, world: SensedWorld) -> float:
        """Grid cell: the longest sensor reach plus the largest radius (at least 120 mm)."""
        if self._cell is not None and self._cell[0] == world.layout:
            return self._cell[1]
        reach = self.agents.proximity.reach
        radius = max(
            [a.spec.radius_mm for a in world.agents]
            + [o.shape.bounding_radius_mm for o in world.objects]
            + [
                o.shape.bounding_radius_mm
                for o in world.obstacles.values()
                if o.shape.kind == "circle"
            ]
            + [0.0]
        )
        value = max(_MIN_CELL_MM, (float(reach.max()) if len(reach) else 0.0) + radius)
        self._cell = (world.layout, value)
        return value

    def static_geometry(self, world: SensedWorld) -> StaticGeometry:
        cell = self.cell_size(world)
        # Rebuilt when obstacles changed, or an object larger than the grid was made for arrived.
        if self._static is None or self._static.cell_mm < cell:
            self._static = StaticGeometry.build(
                world.width, world.height, list(world.obstacles.values()), cell
            )
        return self._static

    def packs(
        self, world: SensedWorld, sim_time: float
    ) -> tuple[tuple[object, ...], tuple[object, ...], tuple[object, ...]]:
        """The kernel's tables, static scene and moving scene of one pass at ``sim_time``.

        Draws the pass's noise key: call once per pass. The packs go to the kernel as
        plain tuples, laid out as K.SensorTables, K.StaticScene and K.MovingScene:
        numba's dispatcher types a plain tuple of arrays on its C fast path, a
        named tuple through Python (measured: 13 against 23 us a call at 10
        robots, more than the sensing itself).
        """
        static = self.static_geometry(world)
        layout = self.agents
        moving = (
            *_objects(world, static),
            self.lit(world, sim_time),
            self.noise.next(),
        )
        return layout.kernel_tables, static.kernel_scene, moving

    def read(self, world: SensedWorld, out: K.Readings) -> K.Readings:
        """Every agent's proximity, ambient and presence readings, written into ``out``."""
        tables, scene, moving = self.packs(world, world.sim_time)
        robots = (world.agent_pose, world.arm, world.holding())
        if world.threads > 1 and len(world.agent_pose) >= PARALLEL_MIN_AGENTS:
            sense_on_threads(robots, tables, scene, moving, tuple(out), world.threads)
        else:
            compiled.sense(robots, tables, scene, moving, tuple(out))
        return out

    def lit(self, world: SensedWorld, sim_time: float) -> np.ndarray:
        """(L, 4) x, y, radius, intensity of the lights on at ``sim_time`` (keyed on values)."""
        if not world.lights:  # the common case in a swarm, every pass: no generator
            return NO_LIGHTS
        steady = self._steady
        if (
            steady[0] == Light.edits
            and steady[1] == world.layout
            and steady[2] is world.lights
            and steady[3] == len(world.lights)
        ):
            # No light blinks, none was added or removed, none changed since: the
            # same table. Working it out was 0.6 us a pass with one lamp, 6 % of a
            # 10-robot step.
            return steady[4]
        table = self._lit(world, sim_time)
        if not any(light.mode == "blink" for light in world.lights):
            self._steady = (Light.edits, world.layout, world.lights, len(world.lights), table)
        return table

    def _lit(self, world: SensedWorld, sim_time: float) -> np.ndarray:
        key = tuple(
            (light.x, light.y, light.radius_mm, light.intensity)
            for light in world.lights
            if light.intensity > 0 and light.is_on(sim_time)
        )
        if not key:
            return NO_LIGHTS
        table = self._lights.get(key)
        if table is None:
            if len(self._lights) > 64:  # blinking sets alternate; edits make new ones
                self._lights.clear()
            table = self._lights[key] = np.array(key, dtype=np.float64)
        return table


def sense_on_threads(
    robots: tuple[np.ndarray, ...],
    tables: tuple[object, ...],
    scene: tuple[object, ...],
    moving: tuple[object, ...],
    out: tuple[np.ndarray, ...],
    threads: int,
) -> None:
    """kernels.sense_parallel on ``threads`` threads: the packs as SensorSuite.packs makes them."""
    # numba's always (aot_build.py says why): imported at the first pass on threads.
    import numba

    from common.sim2d import kernels

    # Both settings are per calling thread (the sim thread's). Chunks handed out
    # one at a time: on a shared machine a worker may be descheduled, and the
    # others then take its share instead of waiting for it at the barrier.
    numba.set_num_threads(threads)
    chunk = numba.set_parallel_chunksize(1)
    try:
        kernels.sense_parallel(robots, tables, scene, moving, out, threads)
    finally:
        numba.set_parallel_chunksize(chunk)


def _objects(
    world: SensedWorld, static: StaticGeometry
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Circles other than the agents (round objects on the floor, round obstacles) and edges."""
    if not world.objects:
        return (*static.no_objects, NO_EDGES)
    idx: list[int] = []
    radius: list[float] = []
    owner: list[int] = []
    edges: list[tuple[float, float, float, float]] = []
    for i, obj in enumerate(world.objects):
        if not world.on_floor(obj):
            continue
        if obj.shape.kind == "circle":
            idx.append(i)
            radius.append(obj.shape.radius_mm)
            owner.append(world.slot_of(obj.held_by) if obj.held_by else -1)
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
