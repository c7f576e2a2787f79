"""The Sim2D world (thesis 6.7.2, AgentWorldSim2D): a pymunk space in millimetres.

One world is stepped by one thread (pymunk is not thread-safe). Collision rules
follow the thesis, through pymunk:

- obstacles are static bodies: they never move, and push anything out;
- agents are dynamic bodies pulled by a kinematic control body through
  force-limited pivot and gear joints (pymunk's tank pattern, ``drive="joints"``,
  the default), or driven by a force-limited velocity servo with the same
  limits (``drive="velocity"``, no joints: for swarms); either way walls push
  them back and two agents share the push; or (``drive="discs"``, for swarms
  of robots and obstacles only) moved along their wheels' arcs by a compiled
  tick that solves disc contacts itself, chipmunk not stepped
  (common/sim2d/discs.py);
- movable objects are dynamic bodies held to the floor by force-limited
  joints to the static body (top-down friction: nothing slides forever);
- the gripper's collision exception area lets an object between the open
  tongs overlap the robot (thesis 6.8.3).

Per-agent state lives in numpy arrays indexed by the agent's slot (its index
in :attr:`World.agents`), so a tick has no per-robot Python loop. The
per-tick work runs in compiled kernels (common/sim2d/kernels.py): one sets
the control bodies' velocities, steps chipmunk and reads the bodies back,
calling chipmunk's C functions directly (common/sim2d/chipmunk.py); one
casts every sensor (common/sim2d/sensing.py prepares its tables).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pymunk

from common.controller.actuators import Actuators
from common.sim2d import bodies, chipmunk, discs, fused, heap, kernels, sensing
from common.sim2d.collision import (
    CAT_ALL,
    CAT_OBSTACLE,
    CAT_ROBOT,
    COLL_OBJECT,
    COLL_ROBOT,
    COLL_TONGS,
    TONGS_MASK_LIGHT,
)
from common.sim2d.drives import DRIVES, OBJECT_DRIVES
from common.sim2d.entities import (
    Agent,
    Light,
    LightMode,
    MovableObject,
    Obstacle,
    ShapeSpec,
    Zone,
)
from common.sim2d.gripper import GripperTurrets
from common.sim2d.specs import AgentTypeSpec


class EditError(ValueError):
    """An edit or a map would break the world's rules; the message says which and why."""


# How robots are driven (World(drive=...)): "joints", pymunk's tank pattern (a
# kinematic control body per robot pulling it through a pivot and a gear joint), or
# "velocity", a force-limited servo on the robot's own body set by the compiled tick
# (kernels.servo_forces): the same velocity constraint and force limits without the
# two joints and the extra body, which were most of chipmunk's step in a swarm
# (docs/BENCHMARKS.md, issue 22). With "velocity" a lowered gripper's tongs also
# collide with movable objects only (collision.TONGS_MASK_LIGHT), not with robots,
# other tongs or obstacles: the other half of a swarm's step. "joints" stays the
# default, its trajectories unchanged: the sim-beside-real comparisons and recorded
# runs were made with it, and tongs that no longer touch walls and robots are a
# change of the model (docs/ARCHITECTURE.md section 9, "Drives").
__all__ = ["DRIVES", "OBJECT_DRIVES", "EditError", "World"]


class _CopiedOnRead:
    """A per-agent array the fused tick writes in its own buffer (World._step_fused).

    Read, it is a copy of that buffer taken at the first read after the tick:
    an array a caller took never changes under it, as when every tick made new
    arrays, and an array nobody reads is not copied (at 10 robots the five
    copies were 2.3 us of a 17 us step, and a controller reads one or two).
    Set, it is that value until the next fused tick.
    """

    def __set_name__(self, owner: type, name: str) -> None:
        self.value = "_" + name
        self.buffer = "_" + name + "_buffer"

    def __get__(self, world: object, owner: type | None = None) -> np.ndarray:
        d = world.__dict__
        buffer = d[self.buffer]
        if buffer is not None:
            d[self.value] = buffer.copy()
            d[self.buffer] = None
        return d[self.value]  # type: ignore[no-any-return]

    def __set__(self, world: object, value: np.ndarray) -> None:
        d = world.__dict__
        d[self.value] = value
        d[self.buffer] = None


@dataclass(frozen=True)
class Tables:
    """Per-agent constants derived from the agents' types (rebuilt when agents change)."""

    mm_s_per_unit: np.ndarray  # (N,)
    pulses_per_s_per_unit: np.ndarray  # (N,)
    wheel_base: np.ndarray  # (N,)
    max_speed: np.ndarray  # (N,)
    radius: np.ndarray  # (N,)
    has_gripper: np.ndarray  # (N,) bool
    arm_rate: np.ndarray  # (N,) arm position units per second (0 without a gripper)
    arm_lowered_above: np.ndarray  # (N,) arm position at and above which the tongs are down
    servo: np.ndarray  # (N, 4) the velocity drive's mass, moment, max force, max torque
    mass: np.ndarray  # (N,) g: how the discs drive shares a push between two robots


class World:
    """A bounded 2D world: arena, obstacles, movable objects, lights, zones and agents."""

    # Written by the fused tick into its buffers, copied when read (_CopiedOnRead).
    agent_pose = _CopiedOnRead()
    agent_vel = _CopiedOnRead()
    proximity = _CopiedOnRead()
    ambient = _CopiedOnRead()
    presence = _CopiedOnRead()

    def __init__(
        self,
        width_mm: float,
        height_mm: float,
        *,
        seed: int = 0,
        tick_s: float = 0.02,
        sensor_period_s: float = 0.02,
        substeps: int | None = None,
        name: str = "world",
        threads: int = 1,
        physics_threads: int = 1,
        drive: str = "joints",
    ) -> None:
        if not (width_mm > 0 and height_mm > 0):
            raise EditError("the arena's width and height must be positive")
        if not tick_s > 0:
            raise EditError("the tick must be positive")
        if not 1 <= threads <= kernels.MAX_THREADS:
            raise EditError(f"threads must be between 1 and {kernels.MAX_THREADS}")
        if not 1 <= physics_threads <= kernels.MAX_THREADS:
            raise EditError(f"physics threads must be between 1 and {kernels.MAX_THREADS}")
        if drive not in DRIVES:
            raise EditError(f"drive must be one of {', '.join(DRIVES)}, not {drive!r}")
        self.drive = drive
        # A tick's freed arrays stay in the heap for the next tick (common/sim2d/heap.py).
        heap.keep_freed_memory()
        # What lowered tongs collide with (the gripper turret sets it on arms it lowers).
        self.tongs_mask = CAT_ALL if drive == "joints" else TONGS_MASK_LIGHT
        # Whether the robots' tongs are in the space. Tongs that collide with movable
        # objects only (the velocity drive) can meet nothing while the world has none,
        # so they stay out of it then (_sync_tongs): in a swarm they were two of every
        # robot's three shapes in chipmunk's bounding-box tree. They carry no mass.
        self._tongs_in = drive == "joints"
        # Sensing threads: the parallel kernel gives the serial kernel's readings bit
        # for bit (each robot's pass reads shared state and writes its own row only).
        self.threads = threads
        # Physics threads: chipmunk's threaded ("hasty") space, whose solver splits
        # the constraints between threads. Its results depend on the thread count
        # and the scheduling, so it is opt-in (see docs/BENCHMARKS.md, issue 22).
        self.physics_threads = physics_threads
        self.name = name
        self.seed = seed
        self.tick_s = tick_s
        self.sensor_period_s = sensor_period_s
        # Physics never steps more than 10 ms at a time: a speed change then shows
        # up in the pose within 10 ms whatever the tick (pymunk integrates the
        # position before it solves the joints that set the new velocity).
        self.substeps = substeps or max(1, math.ceil(tick_s / 0.01 - 1e-9))
        self.width = float(width_mm)
        self.height = float(height_mm)
        self.rng = np.random.default_rng(seed)
        self.noise = sensing.NoiseKeys(self.rng)  # sensor noise keys: the only draw from rng
        self.sensors = sensing.SensorSuite(self.noise)
        self.grippers = GripperTurrets(self)
        self.tick = 0
        self.sim_time = 0.0
        self.layout = 1  # bumped whenever objects are added, removed or change shape
        self._next_sense = 0.0
        self._serial = 0
        # CPU seconds per phase, accumulated while ``profile`` is true (bench/engine_bench.py).
        self.profile = False
        self.phase_cpu = {"physics": 0.0, "sensing": 0.0}

        self.space = pymunk.Space(threaded=physics_threads > 1)
        if physics_threads > 1:
            self.space.threads = physics_threads
        self.space.damping = 1.0
        if drive == "velocity":
            # The servo's forces are set before the step, so the solver's iterations
            # go to the contacts alone: with chipmunk's 10, a crowd of 140 pressed into
            # a corner overlapped by up to 14 mm (the joints drive: 7); with 20, 11.
            # At 10,000 robots in the bench's density the step cost the same.
            self.space.iterations = 20
        self._step_fn = chipmunk.FUNCTIONS[
            chipmunk.HASTY_SPACE_STEP if physics_threads > 1 else chipmunk.SPACE_STEP
        ]
        exception = self.grippers.collision_exception
        self.space.on_collision(COLL_ROBOT, COLL_OBJECT, pre_solve=exception)
        self.space.on_collision(COLL_TONGS, COLL_OBJECT, pre_solve=exception)
        self._walls: list[pymunk.Shape] = []
        self._build_walls()

        self.obstacles: dict[str, Obstacle] = {}
        self.objects: list[MovableObject] = []
        self.lights: list[Light] = []
        self.zones: dict[str, Zone] = {}
        self.agents: list[Agent] = []
        # Each agent's start pose (where it was added, or a map editor last put it):
        # where reset_agent puts it back.
        self.homes: dict[str, tuple[float, float, float]] = {}
        self._agent_by_body: dict[int, Agent] = {}
        self._object_by_body: dict[int, MovableObject] = {}

        self._init_agent_state(0)
        self._rebuild_tables()
        self.object_pose = np.zeros((0, 3))
        # cpBody addresses for the compiled physics tick (common/sim2d/chipmunk.py),
        # rebuilt at the first tick after any layout change (every add and remove bumps
        # the layout): an address kept past its body's removal would read freed memory.
        self._space_address = np.uint64(chipmunk.space_address(self.space))
        self._agent_bodies = self._control_bodies = self._object_bodies = np.zeros(
            0, dtype=np.uint64
        )
        self._rows_layout = -1
        self._servo_memory = np.zeros((0, 6))
        # The discs drive (common/sim2d/discs.py): the sensing grid it last binned
        # the round obstacles of, with those bins; and whether the robots' pymunk
        # bodies are where the robots are (the drive moves the robots, not them).
        self._disc_circles: tuple[object, tuple[np.ndarray, np.ndarray]] = (
            None,
            (np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64)),
        )
        self._bodies_placed = True
        # The discs drive's fused tick (common/sim2d/fused.py): its state, built at
        # the first tick after anything it holds changed (_FusedTick.key).
        self._fused: _FusedTick | None = None

    # -- per-agent state -------------------------------------------------------------

    def _init_agent_state(self, n: int) -> None:
        self.cmd = np.zeros((n, 2))  # wheel speeds, the type's units, clamped
        self.counters = np.zeros((n, 2))  # position counters, pulses
        self.proximity = np.zeros((n, 8), dtype=np.int32)
        self.ambient = np.zeros((n, 8), dtype=np.int32)
        self.leds = np.zeros((n, 8), dtype=np.uint8)
        self.arm = np.zeros(n)
        self.arm_target = np.zeros(n)
        self.fingers = np.zeros(n, dtype=np.int8)
        self.presence = np.zeros(n, dtype=np.int32)
        self.agent_pose = np.zeros((n, 3))
        self.agent_vel = np.zeros((n, 3))

    _STATE = (
        "cmd",
        "counters",
        "proximity",
        "ambient",
        "leds",
        "arm",
        "arm_target",
        "fingers",
        "presence",
        "agent_pose",
        "agent_vel",
    )

    def _append_agent_state(self, pose: tuple[float, float, float], arm: float) -> None:
        for name in self._STATE:
            arr = getattr(self, name)
            row = np.zeros((1, *arr.shape[1:]), dtype=arr.dtype)
            setattr(self, name, np.concatenate([arr, row]))
        self.agent_pose[-1] = pose
        self.arm[-1] = self.arm_target[-1] = arm

    def _delete_agent_state(self, slot: int) -> None:
        for name in self._STATE:
            setattr(self, name, np.delete(getattr(self, name), slot, axis=0))

    def _rebuild_tables(self) -> None:
        specs = [a.spec for a in self.agents]
        self.tables = Tables(
            mm_s_per_unit=np.array([s.drive.mm_per_s(np.float64(1.0)) for s in specs]),
            pulses_per_s_per_unit=np.array([1.0 / s.drive.unit_time_s for s in specs]),
            wheel_base=np.array([s.drive.wheel_base_mm for s in specs]),
            max_speed=np.array([float(s.drive.max_speed) for s in specs]),
            radius=np.array([s.radius_mm for s in specs]),
            has_gripper=np.array([a.has_gripper for a in self.agents], dtype=bool),
            arm_rate=np.array(
                [s.gripper.arm_rate_per_s if s.gripper else 0.0 for s in specs], dtype=float
            ),
            arm_lowered_above=np.array(
                [s.gripper.lowered_above if s.gripper else np.inf for s in specs], dtype=float
            ),
            servo=np.array(
                [
                    (
                        a.body.mass,
                        a.body.moment,
                        a.spec.drive.max_force,
                        a.spec.drive.max_torque,
                    )
                    for a in self.agents
                ],
                dtype=float,
            ).reshape(-1, 4),
            mass=np.array([a.body.mass for a in self.agents], dtype=float),
        )
        self._slot_of = {a.serial: slot for slot, a in enumerate(self.agents)}
        self._slot_by_id = {a.id: slot for slot, a in enumerate(self.agents)}
        self.sensors.fit(self.agents, self.tables.radius, self.tables.arm_lowered_above)

    # -- ids ---------------------------------------------------------------------

    def ids(self) -> set[str]:
        return (
            set(self.obstacles)
            | {o.id for o in self.objects}
            | {light.id for light in self.lights}
            | set(self.zones)
            | {a.id for a in self.agents}
        )

    def _check_new_id(self, ident: str) -> None:
        # Not ``ident in self.ids()``: building that set for every add made adding
        # 10,000 robots quadratic (about 40 s); ``homes`` holds every agent's id.
        if (
            ident in self.homes
            or ident in self.obstacles
            or ident in self.zones
            or any(o.id == ident for o in self.objects)
            or any(light.id == ident for light in self.lights)
        ):
            raise EditError(f"an object named {ident!r} already exists in this world")

    def agent_slot(self, agent_id: str) -> int:
        """The agent's row in the state arrays; KeyError if there is no such agent."""
        return self._slot_by_id[agent_id]

    def slot_of(self, agent: Agent) -> int:
        """The agent's row in the state arrays."""
        return self._slot_of[agent.serial]

    def agent_of_body(self, body: pymunk.Body) -> Agent | None:
        return self._agent_by_body.get(id_of(body))

    def on_floor(self, obj: MovableObject) -> bool:
        """On the floor, or held by a lowered arm: what IR sensors and the barrier see."""
        return obj.held_by is None or self.grippers.lowered(self.slot_of(obj.held_by))

    def find_object(self, ident: str) -> MovableObject | None:
        return next((o for o in self.objects if o.id == ident), None)

    # -- arena -------------------------------------------------------------------

    def _build_walls(self) -> None:
        for shape in self._walls:
            self.space.remove(shape)
        self._walls = bodies.walls(self.space.static_body, self.width, self.height)
        self.space.add(*self._walls)
        self.sensors.obstacles_changed()

    def resize(self, width_mm: float, height_mm: float) -> None:
        if not (width_mm > 0 and height_mm > 0):
            raise EditError("the arena's width and height must be positive")
        old = (self.width, self.height)
        self.width, self.height = float(width_mm), float(height_mm)
        outside = [i for i in self.ids() if not self._inside_arena_id(i)]
        if outside:
            self.width, self.height = old
            raise EditError(
                f"the arena {width_mm:.0f} x {height_mm:.0f} mm would leave outside: "
                + ", ".join(sorted(outside)[:10])
            )
        self._build_walls()
        self.layout += 1

    def _inside(self, pts: Iterable[tuple[float, float]], margin: float = 0.0) -> bool:
        return all(
            x - margin >= -1e-6
            and x + margin <= self.width + 1e-6
            and y - margin >= -1e-6
            and y + margin <= self.height + 1e-6
            for x, y in pts
        )

    def _shape_inside(self, shape: ShapeSpec, x: float, y: float, heading: float) -> bool:
        if shape.kind == "circle":
            return self._inside([(x, y)], shape.radius_mm)
        return self._inside(shape.world_vertices(x, y, heading))

    def _inside_arena_id(self, ident: str) -> bool:
        x, y, heading = self.pose_of(ident)
        shape = self.shape_of(ident)
        return shape is None or self._shape_inside(shape, x, y, heading)

    # -- obstacles ------------------------------------------------------------------

    def add_obstacle(
        self,
        ident: str,
        shape: ShapeSpec,
        x: float,
        y: float,
        heading: float = 0.0,
        colour: str = "#808080",
    ) -> Obstacle:
        self._check_new_id(ident)
        if not self._shape_inside(shape, x, y, heading):
            raise EditError(f"obstacle {ident} would stick out of the arena")
        body, shapes = bodies.obstacle(shape, x, y, heading)
        self.space.add(body, *shapes)
        overlapping = self._agents_touching(shapes)
        if overlapping:
            self.space.remove(body, *shapes)
            raise EditError(f"obstacle {ident} would overlap agent(s) {', '.join(overlapping)}")
        obstacle = Obstacle(ident, shape, x, y, heading, colour, body, shapes)
        self.obstacles[ident] = obstacle
        self.sensors.obstacles_changed()
        self.layout += 1
        return obstacle

    def _place_bodies(self) -> None:
        """On the discs drive, put the robots' bodies where the robots are, for a query.

        Chipmunk is not stepped on that drive, so the bodies stay where an edit
        last put them; an edit that asks the space what a shape overlaps needs
        them where the robots are.
        """
        if self.drive != "discs" or self._bodies_placed:
            return
        for slot, agent in enumerate(self.agents):
            x, y, heading = self.agent_pose[slot]
            agent.body.position, agent.body.angle = (float(x), float(y)), float(heading)
            self.space.reindex_shapes_for_body(agent.body)
        self._bodies_placed = True

    def _agents_touching(self, shapes: list[pymunk.Shape]) -> list[str]:
        self._place_bodies()
        found = []
        for shape in shapes:
            for info in self.space.shape_query(shape):
                agent = self._agent_by_body.get(id_of(info.shape.body)) if info.shape else None
                if agent is not None and info.shape is agent.shape:
                    found.append(agent.id)
        return sorted(set(found))

    # -- movable objects -----------------------------------------------------------------

    def add_object(
        self,
        ident: str,
        kind: str,
        shape: ShapeSpec,
        x: float,
        y: float,
        heading: float = 0.0,
        *,
        mass_g: float = 10.0,
        friction: float = 0.5,
        resistivity: int = 128,
        colour: str = "#ff8c00",
    ) -> MovableObject:
        self._check_new_id(ident)
        if self.drive == "discs":
            raise EditError(
                f"object {ident}: this world runs the discs drive (for swarms), which has "
                "no movable objects; run it with the joints or velocity drive"
            )
        if not self._shape_inside(shape, x, y, heading):
            raise EditError(f"object {ident} would stick out of the arena")
        if mass_g <= 0:
            raise EditError(f"object {ident}: mass must be positive")
        body, shapes = bodies.movable_object(shape, x, y, heading, mass_g)
        if self._blocked(shapes, CAT_OBSTACLE | CAT_ROBOT, body):
            raise EditError(f"object {ident} would overlap an obstacle or an agent")
        obj = MovableObject(ident, kind, shape, mass_g, friction, resistivity, colour, body, shapes)
        obj.floor_joints = bodies.floor_friction(
            self.space.static_body, body, mass_g, friction, shape
        )
        self.space.add(body, *shapes, *obj.floor_joints)
        self.objects.append(obj)
        self._object_by_body[id_of(body)] = obj
        self._sync_tongs()
        self.layout += 1
        return obj

    def _sync_tongs(self) -> None:
        """Tongs into the space, or out of it, as the objects they could touch come and go."""
        wanted = self.drive == "joints" or bool(self.objects)
        if wanted == self._tongs_in:
            return
        tongs = [tong for agent in self.agents for tong in agent.tongs]
        if tongs:
            if wanted:
                self.space.add(*tongs)
            else:
                self.space.remove(*tongs)
        self._tongs_in = wanted

    def _blocked(self, shapes: list[pymunk.Shape], mask: int, body: pymunk.Body) -> bool:
        self._place_bodies()
        for shape in shapes:
            shape.cache_bb()
            for info in self.space.shape_query(shape):
                other = info.shape
                if other is None or other.body is body:
                    continue
                points = info.contact_point_set.points
                # A real overlap, not two shapes merely touching.
                if (
                    other.filter.categories & mask
                    and points
                    and min(p.distance for p in points) < -0.5
                ):
                    return True
        return False

    # -- lights and zones ---------------------------------------------------------------

    def add_light(
        self,
        ident: str,
        x: float,
        y: float,
        *,
        intensity: float = 1.0,
        radius_mm: float = 300.0,
        mode: LightMode = "on",
        period_s: float = 1.0,
        colour: str = "#ffd700",
    ) -> Light:
        self._check_new_id(ident)
        if not self._inside([(x, y)]):
            raise EditError(f"light {ident} is outside the arena")
        if period_s <= 0 or radius_mm <= 0 or intensity < 0:
            raise EditError(f"light {ident}: period and radius must be positive, intensity >= 0")
        light = Light(ident, x, y, intensity, radius_mm, mode, period_s, colour)
        self.lights.append(light)
        self.layout += 1
        return light

    def add_zone(
        self,
        ident: str,
        kind: str,
        shape: ShapeSpec,
        x: float,
        y: float,
        heading: float = 0.0,
        colour: str = "#c8e6c9",
    ) -> Zone:
        self._check_new_id(ident)
        if not self._shape_inside(shape, x, y, heading):
            raise EditError(f"zone {ident} would stick out of the arena")
        zone = Zone(ident, kind, shape, x, y, heading, colour)
        self.zones[ident] = zone
        self.layout += 1
        return zone

    # -- agents ----------------------------------------------------------------------

    def add_agent(
        self,
        ident: str,
        spec: AgentTypeSpec,
        x: float,
        y: float,
        heading: float = 0.0,
        *,
        gripper: bool = True,
        colour: str | None = None,
        defer_tables: bool = False,
    ) -> Agent:
        """Add a robot. ``defer_tables``: the caller adds many, then calls finish_agents()."""
        self._check_new_id(ident)
        r = spec.radius_mm
        if not self._inside([(x, y)], r):
            raise EditError(f"agent {ident} at ({x:.0f}, {y:.0f}) would stick out of the arena")
        hits = self.space.point_query((x, y), r - 0.5, pymunk.ShapeFilter(mask=CAT_OBSTACLE))
        if hits:
            raise EditError(f"agent {ident} at ({x:.0f}, {y:.0f}) would overlap an obstacle")
        self._serial += 1
        fitted = gripper and spec.gripper is not None
        agent = bodies.agent(
            ident,
            spec,
            self._serial,
            x,
            y,
            heading,
            fitted,
            joints=self.drive == "joints",
            tongs_mask=self.tongs_mask,
        )
        agent.colour = colour or spec.colour
        self.space.add(*agent.physics(tongs=self._tongs_in))
        self.agents.append(agent)
        self._agent_by_body[id_of(agent.body)] = agent
        arm = float(spec.gripper.arm_down) if spec.gripper else 0.0
        self._append_agent_state((x, y, heading), arm)
        self.homes[ident] = (float(x), float(y), float(heading))
        if not defer_tables:
            self._rebuild_tables()
        self.layout += 1
        return agent

    def finish_agents(self) -> None:
        """Rebuild the per-agent tables after add_agent(..., defer_tables=True)."""
        self._rebuild_tables()

    # -- generic edits ------------------------------------------------------------------

    def pose_of(self, ident: str) -> tuple[float, float, float]:
        for slot, agent in enumerate(self.agents):
            if agent.id == ident:
                x, y, h = self.agent_pose[slot]
                return float(x), float(y), float(h)
        for obj in self.objects:
            if obj.id == ident and obj.body is not None:
                return obj.body.position.x, obj.body.position.y, obj.body.angle
        if ident in self.obstacles:
            o = self.obstacles[ident]
            return o.x, o.y, o.heading
        if ident in self.zones:
            z = self.zones[ident]
            return z.x, z.y, z.heading
        for light in self.lights:
            if light.id == ident:
                return light.x, light.y, 0.0
        raise EditError(f"no object named {ident!r} in this world")

    def shape_of(self, ident: str) -> ShapeSpec | None:
        for agent in self.agents:
            if agent.id == ident:
                return ShapeSpec.circle(agent.spec.radius_mm)
        obj = self.find_object(ident)
        if obj is not None:
            return obj.shape
        if ident in self.obstacles:
            return self.obstacles[ident].shape
        if ident in self.zones:
            return self.zones[ident].shape
        return None  # lights are points

    def move(self, ident: str, x: float, y: float, heading: float | None = None) -> None:
        """Move (and optionally rotate) anything; validated, undone if it breaks a rule."""
        old = self.pose_of(ident)
        heading = old[2] if heading is None else heading
        shape = self.shape_of(ident)
        if shape is not None and not self._shape_inside(shape, x, y, heading):
            raise EditError(f"{ident} would stick out of the arena at ({x:.0f}, {y:.0f})")
        if shape is None and not self._inside([(x, y)]):
            raise EditError(f"{ident} would be outside the arena at ({x:.0f}, {y:.0f})")
        for light in self.lights:
            if light.id == ident:
                light.x, light.y = x, y
                self.layout += 1
                return
        if ident in self.zones:
            z = self.zones[ident]
            z.x, z.y, z.heading = x, y, heading
            self.layout += 1
            return
        if ident in self.obstacles:
            o = self.obstacles[ident]
            assert o.body is not None
            o.body.position, o.body.angle = (x, y), heading
            self.space.reindex_shapes_for_body(o.body)
            overlapping = self._agents_touching(o.shapes)
            if overlapping:
                o.body.position, o.body.angle = (o.x, o.y), o.heading
                self.space.reindex_shapes_for_body(o.body)
                raise EditError(f"obstacle {ident} would overlap agent(s) {', '.join(overlapping)}")
            o.x, o.y, o.heading = x, y, heading
            self.sensors.obstacles_changed()
            self.layout += 1
            return
        for slot, agent in enumerate(self.agents):
            if agent.id == ident:
                r = agent.spec.radius_mm
                hits = self.space.point_query(
                    (x, y), r - 0.5, pymunk.ShapeFilter(mask=CAT_OBSTACLE)
                )
                if hits:
                    raise EditError(
                        f"agent {ident} at ({x:.0f}, {y:.0f}) would overlap an obstacle"
                    )
                for b in (agent.body, agent.control):
                    if b is None:
                        continue
                    b.position, b.angle = (x, y), heading
                    b.velocity, b.angular_velocity = (0, 0), 0.0
                self.space.reindex_shapes_for_body(agent.body)
                self.agent_pose[slot] = (x, y, heading)
                self.layout += 1
                return
        obj = self.find_object(ident)
        if obj is not None and obj.body is not None:
            if obj.held_by is not None:
                self.grippers.release(obj)
            old_pos, old_angle = obj.body.position, obj.body.angle
            obj.body.position, obj.body.angle = (x, y), heading
            self.space.reindex_shapes_for_body(obj.body)
            if self._blocked(obj.shapes, CAT_OBSTACLE, obj.body):
                obj.body.position, obj.body.angle = old_pos, old_angle
                self.space.reindex_shapes_for_body(obj.body)
                raise EditError(f"object {ident} would overlap an obstacle at ({x:.0f}, {y:.0f})")
            obj.body.velocity, obj.body.angular_velocity = (0, 0), 0.0
            self.layout += 1
            return
        raise EditError(f"no object named {ident!r} in this world")

    def set_home(self, ident: str) -> None:
        """Make an agent's current pose its start pose (a map editor placed it)."""
        if ident in self.homes:
            self.homes[ident] = self.pose_of(ident)

    def reset_agent(self, ident: str) -> tuple[float, float, float]:
        """Put an agent back at its start pose, at rest; returns the pose."""
        home = self.homes.get(ident)
        if home is None:
            raise EditError(f"no agent named {ident!r} in this world")
        self.move(ident, *home)
        return home

    def rotate(self, ident: str, heading: float) -> None:
        x, y, _ = self.pose_of(ident)
        self.move(ident, x, y, heading)

    def remove(self, ident: str) -> None:
        if ident in self.obstacles:
            o = self.obstacles.pop(ident)
            self.space.remove(o.body, *o.shapes)
            self.sensors.obstacles_changed()
        elif ident in self.zones:
            del self.zones[ident]
        elif any(light.id == ident for light in self.lights):
            self.lights = [light for light in self.lights if light.id != ident]
        elif (obj := self.find_object(ident)) is not None:
            if obj.held_by is not None:
                self.grippers.release(obj)
            self.space.remove(obj.body, *obj.shapes, *obj.floor_joints)
            self.objects.remove(obj)
            self._object_by_body.pop(id_of(obj.body), None)
            self._sync_tongs()
        else:
            try:
                slot = self.agent_slot(ident)
            except KeyError:
                raise EditError(f"no object named {ident!r} in this world") from None
            agent = self.agents[slot]
            if agent.held is not None:
                self.grippers.release(agent.held)
            self.space.remove(*agent.physics(tongs=self._tongs_in))
            del self.agents[slot]
            self.homes.pop(ident, None)
            self._agent_by_body.pop(id_of(agent.body), None)
            self._delete_agent_state(slot)
            self._rebuild_tables()
        self.layout += 1

    # -- actuators (common.controller.actuators: one robot's through actuators(slot)) -----

    def actuators(self, slot: int) -> RobotActuators:
        """The robot in ``slot`` as :class:`common.controller.actuators.Actuators`."""
        return RobotActuators(self, slot)

    def set_speeds(self, slot: int, left: float, right: float) -> None:
        top = self.tables.max_speed[slot]
        self.cmd[slot] = (float(np.clip(left, -top, top)), float(np.clip(right, -top, top)))

    def set_speeds_all(self, speeds: npt.ArrayLike) -> None:
        """Every agent's (left, right) at once, rounded and clamped per type: the bulk path."""
        s = np.asarray(speeds, dtype=np.float64)
        if s.shape != self.cmd.shape:
            raise ValueError(
                f"expected {self.cmd.shape} wheel speeds (one row per agent), got {s.shape}"
            )
        kernels.clamp_speeds(s, self.tables.max_speed, self.cmd)

    def set_counters(self, slot: int, left: int, right: int) -> None:
        self.counters[slot] = (left, right)

    def set_leds(self, slot: int, leds: Sequence[bool]) -> None:
        """LED i on or off as ``leds[i]``; LEDs the robot's type lacks are ignored."""
        for led, on in enumerate(leds[: self.agents[slot].spec.leds]):
            self.leds[slot, led] = 1 if on else 0

    def set_arm(self, slot: int, position: int) -> None:
        if not self.grippers.set_arm(slot, position):
            raise EditError(f"{self.agents[slot].id} has no gripper")

    def set_grip(self, slot: int, closed: bool) -> None:
        if not self.grippers.set_grip(slot, closed):
            raise EditError(f"{self.agents[slot].id} has no gripper")

    def resistivity(self, slot: int) -> int:
        return self.grippers.resistivity(slot)

    def holding(self) -> np.ndarray:
        """(N,) bool: which agents hold an object."""
        return self.grippers.holding()

    # -- stepping -------------------------------------------------------------------------

    def _refresh_rows(self) -> None:
        self._agent_bodies = chipmunk.addresses([a.body for a in self.agents])
        self._control_bodies = chipmunk.addresses(
            [a.control for a in self.agents if a.control is not None]
        )
        # The velocity drive's memory of the last step (kernels.servo_forces); NaN: none.
        # An edit may have moved or stopped any robot, so after one it starts afresh.
        self._servo_memory = np.full((len(self.agents), 6), np.nan)
        self._object_bodies = chipmunk.addresses([o.body for o in self.objects if o.body])
        self._rows_layout = self.layout

    def _fused_key(self) -> tuple[object, ...]:
        """What a fused tick's state was built from: a new one is built when any differs."""
        return (
            self.layout,
            self.tables,
            self.sensors.agents,
            self.sensors.current_static(),
            self.cmd,
            self.counters,
            self.arm,
            self.tick_s,
            self.substeps,
        )

    def _fused_state(self) -> _FusedTick:
        f = self._fused
        # Spelled out rather than a loop over _fused_key(): this runs every tick,
        # and at 10 robots the generator alone was 1.5 us of a 25 us step.
        if f is not None:
            k = f.key
            if (
                k[0] == self.layout
                and k[1] is self.tables
                and k[2] is self.sensors.agents
                and k[3] is self.sensors.current_static()
                and k[4] is self.cmd
                and k[5] is self.counters
                and k[6] is self.arm
                and k[7] == self.tick_s
                and k[8] == self.substeps
            ):
                return f
        t = self.tables
        static = self.sensors.static_geometry(self)
        n = len(self.agents)
        pose = np.array(self.agent_pose, dtype=np.float64, order="C")
        vel = np.array(self.agent_vel, dtype=np.float64, order="C")
        readings = (
            np.zeros((n, self.proximity.shape[1]), dtype=np.int32),
            np.zeros((n, self.ambient.shape[1]), dtype=np.int32),
            np.zeros(n, dtype=np.int32),
        )
        drive = (
            t.mm_s_per_unit,
            t.wheel_base,
            t.radius,
            t.mass,
            self.tick_s * t.pulses_per_s_per_unit,
        )
        scene = static.scene
        circles = discs.bin_circles(
            static.circle_centres, static.circle_radii, scene.grid_nx, scene.grid_ny, scene.cell
        )
        holding = np.zeros(n, dtype=bool)  # the discs drive has no movable objects to hold
        tables = self.sensors.agents.kernel_tables
        objects = (*static.no_objects, sensing.NO_EDGES)
        state = fused.new_state(
            pose,
            vel,
            self.cmd,
            self.counters,
            self.arm,
            holding,
            drive,
            circles,
            tables,
            static.kernel_scene,
            objects,
            readings,
            (self.width, self.height, self.tick_s / self.substeps),
            self.substeps,
        )
        # Keyed on what it was built from after the build: static_geometry may
        # have just made the static scene.
        f = self._fused = _FusedTick(
            self._fused_key(),
            state,
            fused.entry(state),
            pose,
            vel,
            *readings,
            holding,
            tables,
            static.kernel_scene,
            objects,
            n >= sensing.PARALLEL_MIN_AGENTS,
        )
        return f

    def _step_fused(self) -> None:
        """:meth:`step` on the discs drive as one compiled call (common/sim2d/fused.py).

        The same work in the same order as the general path: arms, drive and
        contacts, then a sensing pass when one is due (its noise key drawn only
        then, as SensorSuite.packs draws it).
        """
        dt = self.tick_s
        grippers = self.grippers
        if grippers.arms_moving:  # the check move_arms starts with, without the call
            grippers.move_arms(dt)
        f = self._fused_state()
        tick = self.tick + 1
        sim_time = tick * dt
        sense = sim_time + 1e-9 >= self._next_sense
        if sense:
            lights = self.sensors.lit(self, sim_time)
            key = self.noise.next()
        else:
            lights, key = sensing.NO_LIGHTS, np.uint64(0)
        on_threads = sense and f.swarm and self.threads > 1
        f.call(f.state, sense and not on_threads, key, lights)
        if on_threads:
            # The same pass on the world's threads, in the state's own arrays.
            sensing.sense_on_threads(
                (f.pose, self.arm, f.holding),
                f.tables,
                f.scene,
                (*f.objects, lights, key),
                (f.proximity, f.ambient, f.presence),
                self.threads,
            )
        # The buffers are handed out as copies at their first read (_CopiedOnRead).
        d = self.__dict__
        d["_agent_pose_buffer"] = f.pose
        d["_agent_vel_buffer"] = f.vel
        self._bodies_placed = False
        self.tick = tick
        self.sim_time = sim_time
        if sense:
            d["_proximity_buffer"] = f.proximity
            d["_ambient_buffer"] = f.ambient
            d["_presence_buffer"] = f.presence
            self._next_sense = sim_time + self.sensor_period_s - 1e-9

    def step(self) -> None:
        """Advance one tick: arms, drive, physics, counters, carried objects, sensors."""
        profile = self.profile
        # The discs drive in one compiled call, its sensing pass too where it runs
        # on one thread (fused.tick says why). Not while profiling: the profile times physics
        # and sensing apart, which the general path below does with the same
        # results.
        if self.drive == "discs" and not profile and self.agents and not self.grippers.held:
            self._step_fused()
            return
        # The fused state's buffers would fall behind this tick: built afresh if needed.
        self._fused = None
        if profile:
            t0 = time.process_time()
        dt = self.tick_s
        self.grippers.move_arms(dt)
        if self._rows_layout != self.layout:
            self._refresh_rows()
        t = self.tables
        # Straight through chipmunk unless pymunk's own step has bookkeeping to do
        # (bodies or shapes just added or removed): then drive only, and step via pymunk.
        via_pymunk = chipmunk.space_step_pending(self.space)
        sub = dt / self.substeps
        if self.drive == "discs":
            # Chipmunk is not stepped: the robots' bodies stay where they were
            # placed, for the edits' overlap queries (_place_bodies), and the
            # world has no movable objects on this drive.
            via_pymunk = False
            static = self.sensors.static_geometry(self)
            if self._disc_circles[0] is not static:
                scene = static.scene
                self._disc_circles = (
                    static,
                    discs.bin_circles(
                        static.circle_centres,
                        static.circle_radii,
                        scene.grid_nx,
                        scene.grid_ny,
                        scene.cell,
                    ),
                )
            pose, vel = discs.tick(
                self.agent_pose,
                self.cmd,
                t.mm_s_per_unit,
                t.wheel_base,
                t.radius,
                t.mass,
                self.counters,
                dt * t.pulses_per_s_per_unit,
                static.kernel_scene,
                self._disc_circles[1],
                self.width,
                self.height,
                sub,
                self.substeps,
            )
            obj = self.object_pose
            self._bodies_placed = False
        elif self.drive == "joints":
            pose, vel, obj = kernels.physics_tick(
                chipmunk.FUNCTIONS,
                self._step_fn,
                self._space_address,
                sub,
                0 if via_pymunk else self.substeps,
                self._control_bodies,
                self._agent_bodies,
                self._object_bodies,
                self.cmd,
                t.mm_s_per_unit,
                t.wheel_base,
                self.counters,
                dt * t.pulses_per_s_per_unit,
            )
        else:
            pose, vel, obj = kernels.physics_tick_servo(
                chipmunk.FUNCTIONS,
                self._step_fn,
                self._space_address,
                sub,
                0 if via_pymunk else self.substeps,
                self._agent_bodies,
                self._object_bodies,
                self.cmd,
                t.mm_s_per_unit,
                t.wheel_base,
                self.counters,
                dt * t.pulses_per_s_per_unit,
                t.servo,
                self._servo_memory,
            )
        if via_pymunk:
            for _ in range(self.substeps):
                if self.drive == "velocity":
                    kernels.servo_forces(
                        chipmunk.FUNCTIONS,
                        self._agent_bodies,
                        self.cmd,
                        t.mm_s_per_unit,
                        t.wheel_base,
                        t.servo,
                        self._servo_memory,
                        sub,
                    )
                self.space.step(sub)
            pose, vel, obj = kernels.read_bodies(
                chipmunk.FUNCTIONS, self._agent_bodies, self._object_bodies
            )
        self.agent_pose, self.agent_vel, self.object_pose = pose, vel, obj
        self.grippers.carry()
        self.tick += 1
        self.sim_time = self.tick * dt
        if profile:
            t1 = time.process_time()
            self.phase_cpu["physics"] += t1 - t0
        if self.sim_time + 1e-9 >= self._next_sense:
            self.sense()
            self._next_sense = self.sim_time + self.sensor_period_s - 1e-9
            if profile:
                self.phase_cpu["sensing"] += time.process_time() - t1

    def sense(self) -> None:
        """Recompute every agent's proximity, ambient and gripper presence readings."""
        n = len(self.agents)
        if n == 0:
            return
        out = kernels.Readings(
            np.empty((n, self.proximity.shape[1]), dtype=np.int32),
            np.empty((n, self.ambient.shape[1]), dtype=np.int32),
            np.empty(n, dtype=np.int32),
        )
        self.proximity, self.ambient, self.presence = self.sensors.read(self, out)

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds / self.tick_s)):
            self.step()

    # -- reading ---------------------------------------------------------------------------

    def lights_on(self) -> np.ndarray:
        return np.array([light.is_on(self.sim_time) for light in self.lights], dtype=bool)

    def gripper_state(self, slot: int) -> int:
        """0 open, 1 closed, 2 holding."""
        return self.grippers.state(slot)


@dataclass(frozen=True)
class _FusedTick:
    """A discs world's fused tick state and the buffers it writes (World._fused_state)."""

    key: tuple[object, ...]
    state: fused.TickState
    call: Callable[[fused.TickState, bool, np.uint64, np.ndarray], None]  # fused.entry(state)
    pose: np.ndarray
    vel: np.ndarray
    proximity: np.ndarray
    ambient: np.ndarray
    presence: np.ndarray
    # What a sensing pass on threads reads besides the poses (World._step_fused):
    # the state's own, as fused.tick's pass reads them.
    holding: np.ndarray
    tables: tuple[object, ...]
    scene: tuple[object, ...]
    objects: tuple[object, ...]
    swarm: bool  # enough robots for a pass on threads (sensing.PARALLEL_MIN_AGENTS)


class RobotActuators(Actuators):
    """One robot of a World as :class:`common.controller.actuators.Actuators`.

    A view by slot, made per command (``World.actuators``): a slot changes
    when a robot before it is removed, so it is not kept across edits.
    A robot without a gripper refuses arm and grip with an EditError (a ValueError).
    """

    __slots__ = ("slot", "world")

    def __init__(self, world: World, slot: int) -> None:
        self.world, self.slot = world, slot

    def set_speeds(self, left: int, right: int) -> None:
        self.world.set_speeds(self.slot, left, right)

    def set_counters(self, left: int, right: int) -> None:
        self.world.set_counters(self.slot, left, right)

    def set_leds(self, leds: Sequence[bool]) -> None:
        self.world.set_leds(self.slot, leds)

    def set_arm(self, position: int) -> None:
        self.world.set_arm(self.slot, position)

    def set_grip(self, closed: bool) -> None:
        self.world.set_grip(self.slot, closed)


def id_of(body: pymunk.Body) -> int:
    return int(body.id)
