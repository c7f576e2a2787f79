"""The Sim2D world (thesis 6.7.2, AgentWorldSim2D): a bounded floor in millimetres.

One world is stepped by one thread (pymunk is not thread-safe). Collision rules
follow the thesis; how they are solved is the world's drive
(common/sim2d/drives.py, docs/WORLDS.md "Drives"):

- ``drive="discs"`` (the default): robots and movable objects are discs of one
  compiled contact solver, robots moved along their wheels' arcs, objects by
  the pushes they get less floor friction; chipmunk is not stepped
  (common/sim2d/discs.py, pucks.py, world_discs.py);
- ``drive="joints"``: a pymunk space: robots are dynamic bodies pulled by a
  kinematic control body through force-limited pivot and gear joints
  (pymunk's tank pattern), movable objects dynamic bodies held to the floor by
  force-limited joints (top-down friction); ``drive="velocity"``: the same
  space, robots driven by a force-limited velocity servo (no joints);
- on every drive obstacles never move and push anything out, two robots share
  a push, and the gripper's collision exception area lets an object between
  the open tongs overlap the robot (thesis 6.8.3).

Per-agent state lives in numpy arrays indexed by the agent's slot (its index
in :attr:`World.agents`), so a tick has no per-robot Python loop. The
per-tick work runs in compiled kernels (common/sim2d/kernels.py): one sets
the control bodies' velocities, steps chipmunk and reads the bodies back,
calling chipmunk's C functions directly (common/sim2d/chipmunk.py); one
casts every sensor (common/sim2d/sensing.py prepares its tables).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pymunk

from common.sim2d import chipmunk, heap, sensing, world_discs
from common.sim2d.bodies import id_of
from common.sim2d.collision import (
    CAT_ALL,
    COLL_OBJECT,
    COLL_ROBOT,
    COLL_TONGS,
    TONGS_MASK_LIGHT,
)
from common.sim2d.drives import DEFAULT_DRIVE, DRIVES, OBJECT_DRIVES
from common.sim2d.entities import (
    Agent,
    Light,
    MovableObject,
    Obstacle,
    Zone,
)
from common.sim2d.floor import FloorLayer
from common.sim2d.gripper import GripperTurrets
from common.sim2d.packs import MAX_THREADS
from common.sim2d.world_actuators import RobotActuators, WorldActuators
from common.sim2d.world_edits import EditError, WorldEdits
from common.sim2d.world_tick import WorldTick, _FusedTick

# How robots are driven (World(drive=...)): "discs" (the default, DEFAULT_DRIVE), a
# compiled disc solver for robots and objects alike; "joints", pymunk's tank pattern (a
# kinematic control body per robot pulling it through a pivot and a gear joint), the
# default before issue 35 and kept, its trajectories unchanged; or "velocity", a
# force-limited servo on the robot's own body set by the compiled tick
# (kernels.servo_forces), whose lowered tongs collide with movable objects only
# (collision.TONGS_MASK_LIGHT). docs/WORLDS.md, "Drives".
__all__ = ["DRIVES", "OBJECT_DRIVES", "EditError", "RobotActuators", "World"]


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
        return d[self.value]

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


class World(WorldEdits, WorldActuators, WorldTick):
    """A bounded 2D world: arena, obstacles, movable objects, lights, zones and agents.

    This module holds the model (construction, per-agent state, ids, reading);
    each other job is a mixin in its own module: live edits (world_edits.py),
    actuators (world_actuators.py), the tick (world_tick.py).
    """

    # Written by the fused tick into its buffers, copied when read (_CopiedOnRead).
    agent_pose = _CopiedOnRead()
    agent_vel = _CopiedOnRead()
    proximity = _CopiedOnRead()
    ambient = _CopiedOnRead()
    presence = _CopiedOnRead()
    object_pose = _CopiedOnRead()

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
        drive: str = DEFAULT_DRIVE,
    ) -> None:
        if not (width_mm > 0 and height_mm > 0):
            raise EditError("the arena's width and height must be positive")
        if not tick_s > 0:
            raise EditError("the tick must be positive")
        if not 1 <= threads <= MAX_THREADS:
            raise EditError(f"threads must be between 1 and {MAX_THREADS}")
        if not 1 <= physics_threads <= MAX_THREADS:
            raise EditError(f"physics threads must be between 1 and {MAX_THREADS}")
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
        # The floor's shade and painted lines (floor sensors read it); None: plain white.
        self.floor: FloorLayer | None = None
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
        # The split drive's work arrays on the general path (discs_split.split_buffers).
        self._split_work: tuple[np.ndarray, ...] = ()
        self._bodies_placed = True
        # The discs drive's movable objects in its arrays (common/sim2d/world_discs.py).
        self._discs: world_discs.DiscObjects | None = None
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
            mm_s_per_unit=np.array([s.drive.mm_per_s(np.asarray(1.0)) for s in specs]),
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

    # -- reading ---------------------------------------------------------------------------

    def lights_on(self) -> np.ndarray:
        return np.array([light.is_on(self.sim_time) for light in self.lights], dtype=bool)

    def gripper_state(self, slot: int) -> int:
        """0 open, 1 closed, 2 holding."""
        return self.grippers.state(slot)

    def resistivity(self, slot: int) -> int:
        return self.grippers.resistivity(slot)

    def holding(self) -> np.ndarray:
        """(N,) bool: which agents hold an object."""
        return self.grippers.holding()
