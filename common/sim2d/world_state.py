"""A Sim2D world's state: what one world holds and every part of it reads and writes.

The arena's size, the pymunk space, the things (obstacles, movable objects,
lights, zones, agents), the per-agent arrays indexed by an agent's slot (its
index in :attr:`WorldState.agents`), the per-agent tables, the counters (tick,
simulated time, layout). The World's parts (common/sim2d/world.py: the ticker,
the editor, the actuators, the gripper turrets) each take this object and keep
their own caches; the discs drive's helpers (common/sim2d/world_discs.py) take
it too. :class:`EditError` is here, where the state and every part can raise it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pymunk

from common.sim2d import bodies, sensing
from common.sim2d.bodies import id_of
from common.sim2d.collision import CAT_ALL, TONGS_MASK_LIGHT
from common.sim2d.drives import DRIVES
from common.sim2d.entities import Agent, Light, MovableObject, Obstacle, Zone
from common.sim2d.floor import FloorLayer
from common.sim2d.packs import MAX_THREADS

if TYPE_CHECKING:
    from common.sim2d.world_discs import DiscObjects


class EditError(ValueError):
    """An edit or a map would break the world's rules; the message says which and why."""


class CopiedOnRead:
    """A per-agent array the fused tick writes in its own buffer (WorldTicker's fused path).

    Read, it is a copy of that buffer taken at the first read after the tick:
    an array a caller took never changes under it, as when every tick made new
    arrays, and an array nobody reads is not copied (at 10 robots the five
    copies were 2.3 us of a 17 us step, and a controller reads one or two).
    Set, it is that value until the next fused tick.

    The value and the buffer are kept in the holder's ``__dict__`` as ``_<name>``
    and ``_<name>_buffer`` (the ticker hands a buffer over there), or with
    ``of_state`` in its ``state``'s: the World's array is its state's. (A flag
    and the lookups spelled out, the cheapest read: a controller reads one every
    tick.)
    """

    def __init__(self, *, of_state: bool = False) -> None:
        self.of_state = of_state

    def __set_name__(self, owner: type, name: str) -> None:
        self.value = "_" + name
        self.buffer = "_" + name + "_buffer"

    def __get__(self, holder: Any, owner: type | None = None) -> np.ndarray:
        d = holder.state.__dict__ if self.of_state else holder.__dict__
        buffer = d[self.buffer]
        if buffer is not None:
            d[self.value] = buffer.copy()
            d[self.buffer] = None
        return d[self.value]

    def __set__(self, holder: Any, value: np.ndarray) -> None:
        d = holder.state.__dict__ if self.of_state else holder.__dict__
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
    # The slots of robots whose wheels slip or obey late (common/sim2d/real_wheels.py);
    # empty for datasheet robots.
    imperfect: tuple[int, ...] = ()


# The per-agent arrays, one row per slot: grown and shrunk together as agents come and go.
_AGENT_ROWS = (
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


class WorldState:
    """One world's mutable state: arena, space, things, per-agent arrays and tables, counters.

    It knows the world's ids and slots and keeps its per-agent arrays and tables
    in step with its agents; the rules of stepping, editing and commanding are
    the World's parts'.
    """

    # Written by the fused tick into its buffers, copied when read (CopiedOnRead).
    agent_pose = CopiedOnRead()
    agent_vel = CopiedOnRead()
    proximity = CopiedOnRead()
    ambient = CopiedOnRead()
    presence = CopiedOnRead()
    object_pose = CopiedOnRead()

    def __init__(
        self,
        width_mm: float,
        height_mm: float,
        *,
        seed: int,
        tick_s: float,
        sensor_period_s: float,
        substeps: int | None,
        name: str,
        threads: int,
        physics_threads: int,
        drive: str,
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
        # What lowered tongs collide with (the gripper turret sets it on arms it lowers).
        self.tongs_mask = CAT_ALL if drive == "joints" else TONGS_MASK_LIGHT
        # Whether the robots' tongs are in the space. Tongs that collide with movable
        # objects only (the velocity drive) can meet nothing while the world has none,
        # so they stay out of it then (WorldEditor's _sync_tongs): in a swarm they were
        # two of every robot's three shapes in chipmunk's bounding-box tree. They carry
        # no mass.
        self.tongs_in = drive == "joints"
        # Sensing threads: the parallel kernel gives the serial kernel's readings bit
        # for bit (each robot's pass reads shared state and writes its own row only).
        self.threads = threads
        # Physics threads: chipmunk's threaded ("hasty") space, whose solver splits
        # the constraints between threads. Its results depend on the thread count
        # and the scheduling, so it is opt-in (see docs/BENCHMARKS.md).
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
        self.tick = 0
        self.sim_time = 0.0
        self.layout = 1  # bumped whenever objects are added, removed or change shape
        self.next_sense = 0.0  # the simulated time of the next sensing pass
        self.serial = 0  # the last agent's serial (each agent's is unique in the world)
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
        self.walls: list[pymunk.Shape] = []
        self.build_walls()

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
        self.agent_by_body: dict[int, Agent] = {}
        self.object_by_body: dict[int, MovableObject] = {}

        self._init_agent_rows(0)
        self.rebuild_tables()
        self.object_pose = np.zeros((0, 3))
        # The discs drive (common/sim2d/world_discs.py): the movable objects in its
        # arrays, and whether the robots' and objects' pymunk bodies are where they are
        # (the drive moves them in its arrays, not their bodies).
        self.discs: DiscObjects | None = None
        self.bodies_placed = True
        # Bumped by every grip and release (the gripper turrets): the discs drive's
        # arrays are rebuilt then.
        self.grip_version = 0
        # Agents holding an object (the gripper turrets count them): while none do, the
        # usual case, holding() builds no list and a tick carries nothing.
        self.holders = 0

    # -- arena -------------------------------------------------------------------

    def build_walls(self) -> None:
        """The arena's walls, at its size, in the space (in place of the old ones)."""
        for shape in self.walls:
            self.space.remove(shape)
        self.walls = bodies.walls(self.space.static_body, self.width, self.height)
        self.space.add(*self.walls)
        self.sensors.obstacles_changed()

    # -- per-agent state -------------------------------------------------------------

    def _init_agent_rows(self, n: int) -> None:
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

    def append_agent_rows(self, pose: tuple[float, float, float], arm: float) -> None:
        """A row more in every per-agent array, for an agent just appended to ``agents``."""
        for name in _AGENT_ROWS:
            arr = getattr(self, name)
            row = np.zeros((1, *arr.shape[1:]), dtype=arr.dtype)
            setattr(self, name, np.concatenate([arr, row]))
        self.agent_pose[-1] = pose
        self.arm[-1] = self.arm_target[-1] = arm

    def delete_agent_rows(self, slot: int) -> None:
        """The row of a removed agent out of every per-agent array."""
        for name in _AGENT_ROWS:
            setattr(self, name, np.delete(getattr(self, name), slot, axis=0))

    def rebuild_tables(self) -> None:
        """The per-agent tables, the slot maps and the sensors fitted to today's agents."""
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
            imperfect=tuple(i for i, s in enumerate(specs) if s.drive.imperfect),
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

    def check_new_id(self, ident: str) -> None:
        """EditError if anything in this world is named ``ident`` already."""
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
        return self.agent_by_body.get(id_of(body))

    def find_object(self, ident: str) -> MovableObject | None:
        return next((o for o in self.objects if o.id == ident), None)

    # -- arms ------------------------------------------------------------------------

    def arm_lowered(self, slot: int) -> bool:
        """Whether the agent's arm is down (its tongs reach the floor)."""
        return bool(self.arm[slot] >= self.tables.arm_lowered_above[slot])

    def on_floor(self, obj: MovableObject) -> bool:
        """On the floor, or held by a lowered arm: what IR sensors and the barrier see."""
        return obj.held_by is None or self.arm_lowered(self.slot_of(obj.held_by))

    def holding(self) -> np.ndarray:
        """(N,) bool: which agents hold an object."""
        agents = self.agents
        if not self.holders:
            return np.zeros(len(agents), dtype=bool)
        return np.array([a.held is not None for a in agents], dtype=bool)

    # -- reading ---------------------------------------------------------------------------

    def lights_on(self) -> np.ndarray:
        return np.array([light.is_on(self.sim_time) for light in self.lights], dtype=bool)
