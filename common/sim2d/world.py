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

A World is a state and the parts that work on it, each given what it needs:
its :class:`~common.sim2d.world_state.WorldState` (``state``: the arena, the
space, the things, the per-agent arrays indexed by an agent's slot, its index
in :attr:`World.agents`, and the counters); the gripper turrets (gripper.py);
the ticker (world_tick.py: the tick, in compiled kernels, so a tick has no
per-robot Python loop); the editor (world_edits.py: live edits, by the rules);
the actuators (world_actuators.py: what a command sets). The World's
attributes are its state's, read and set through, and its methods are the
parts' own, bound once, so callers see one object.
"""

from __future__ import annotations

from operator import attrgetter
from typing import TYPE_CHECKING, Any, Generic, TypeVar, overload

import numpy as np
import pymunk

from common.sim2d.drives import DEFAULT_DRIVE, DRIVES, OBJECT_DRIVES
from common.sim2d.entities import Agent, Light, MovableObject, Obstacle, Zone
from common.sim2d.floor import FloorLayer
from common.sim2d.gripper import GripperTurrets
from common.sim2d.sensing import NoiseKeys, SensorSuite
from common.sim2d.world_actuators import RobotActuators, WorldActuators
from common.sim2d.world_edits import WorldEditor
from common.sim2d.world_state import CopiedOnRead, EditError, Tables, WorldState
from common.sim2d.world_tick import WorldTicker

# How robots are driven (World(drive=...)): "discs" (the default, DEFAULT_DRIVE), a
# compiled disc solver for robots and objects alike; "joints", pymunk's tank pattern (a
# kinematic control body per robot pulling it through a pivot and a gear joint), kept
# with its trajectories unchanged; or "velocity", a
# force-limited servo on the robot's own body set by the compiled tick
# (kernels.servo_forces), whose lowered tongs collide with movable objects only
# (collision.TONGS_MASK_LIGHT). docs/WORLDS.md, "Drives".
__all__ = ["DRIVES", "OBJECT_DRIVES", "EditError", "RobotActuators", "Tables", "World"]

T = TypeVar("T")


class _OfState(property, Generic[T]):
    """A World attribute that is its state's: read, and set unless ``settable`` is false.

    A property with a C getter (attrgetter), not a descriptor written in Python:
    a read costs what a plain property's does, a third of a Python
    ``__get__``'s (callers such as the engine read these every tick).
    """

    def __init__(self, name: str, *, settable: bool = True) -> None:
        def put(world: World, value: T) -> None:
            setattr(world.state, name, value)

        super().__init__(attrgetter("state." + name), put if settable else None)

    if TYPE_CHECKING:  # what the getter and setter above take and give, for mypy

        @overload
        def __get__(self, world: None, owner: type, /) -> _OfState[T]: ...
        @overload
        def __get__(self, world: object, owner: type | None = None, /) -> T: ...
        def __get__(self, world: object, owner: type | None = None, /) -> Any: ...
        def __set__(self, world: object, value: T, /) -> None: ...


class World:
    """A bounded 2D world: arena, obstacles, movable objects, lights, zones and agents.

    Its state is a :class:`~common.sim2d.world_state.WorldState` (``state``);
    the attributes below are the state's, read and set through. Its parts:
    ``grippers``, ``ticker``, ``editor`` and ``actuation``, whose methods it
    binds in ``__init__`` (module docstring).
    """

    # The state's per-agent arrays the fused tick writes, copied when read (CopiedOnRead).
    agent_pose = CopiedOnRead(of_state=True)
    agent_vel = CopiedOnRead(of_state=True)
    proximity = CopiedOnRead(of_state=True)
    ambient = CopiedOnRead(of_state=True)
    presence = CopiedOnRead(of_state=True)
    object_pose = CopiedOnRead(of_state=True)
    # The state's other per-agent arrays (one row per slot) and tables.
    cmd = _OfState[np.ndarray]("cmd")
    counters = _OfState[np.ndarray]("counters")
    leds = _OfState[np.ndarray]("leds")
    arm = _OfState[np.ndarray]("arm")
    arm_target = _OfState[np.ndarray]("arm_target")
    fingers = _OfState[np.ndarray]("fingers")
    tables = _OfState[Tables]("tables")
    # Its things.
    agents = _OfState[list[Agent]]("agents")
    obstacles = _OfState[dict[str, Obstacle]]("obstacles")
    objects = _OfState[list[MovableObject]]("objects")
    lights = _OfState[list[Light]]("lights")
    zones = _OfState[dict[str, Zone]]("zones")
    floor = _OfState[FloorLayer | None]("floor")
    homes = _OfState[dict[str, tuple[float, float, float]]]("homes")
    # Its settings, arena and counters.
    drive = _OfState[str]("drive")
    tongs_mask = _OfState[int]("tongs_mask")
    threads = _OfState[int]("threads")
    physics_threads = _OfState[int]("physics_threads")
    name = _OfState[str]("name")
    seed = _OfState[int]("seed")
    tick_s = _OfState[float]("tick_s")
    sensor_period_s = _OfState[float]("sensor_period_s")
    substeps = _OfState[int]("substeps")
    width = _OfState[float]("width")
    height = _OfState[float]("height")
    tick = _OfState[int]("tick")
    sim_time = _OfState[float]("sim_time")
    layout = _OfState[int]("layout")
    profile = _OfState[bool]("profile")
    phase_cpu = _OfState[dict[str, float]]("phase_cpu")
    # Made once with the state: the World's parts hold them.
    space = _OfState[pymunk.Space]("space", settable=False)
    rng = _OfState[np.random.Generator]("rng", settable=False)
    noise = _OfState[NoiseKeys]("noise", settable=False)
    sensors = _OfState[SensorSuite]("sensors", settable=False)

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
        self.state = state = WorldState(
            width_mm,
            height_mm,
            seed=seed,
            tick_s=tick_s,
            sensor_period_s=sensor_period_s,
            substeps=substeps,
            name=name,
            threads=threads,
            physics_threads=physics_threads,
            drive=drive,
        )
        self.grippers = grippers = GripperTurrets(state)
        self.ticker = ticker = WorldTicker(state, grippers)
        self.editor = editor = WorldEditor(state, grippers)
        self.actuation = actuation = WorldActuators(state, grippers)
        # The parts' methods, bound once: a call goes straight to the part (World.step
        # is the ticker's, with no call of the World's in between).
        # Ids and slots (the state's).
        self.ids = state.ids
        self.agent_slot = state.agent_slot
        self.slot_of = state.slot_of
        self.agent_of_body = state.agent_of_body
        self.find_object = state.find_object
        # Reading.
        self.on_floor = state.on_floor
        self.lights_on = state.lights_on
        self.holding = state.holding
        self.gripper_state = grippers.state
        self.resistivity = grippers.resistivity
        # Stepping.
        self.step = ticker.step
        self.sense = ticker.sense
        self.run = ticker.run
        # Live edits.
        self.resize = editor.resize
        self.add_obstacle = editor.add_obstacle
        self.add_object = editor.add_object
        self.add_light = editor.add_light
        self.add_zone = editor.add_zone
        self.add_agent = editor.add_agent
        self.finish_agents = editor.finish_agents
        self.pose_of = editor.pose_of
        self.shape_of = editor.shape_of
        self.move = editor.move
        self.set_home = editor.set_home
        self.reset_agent = editor.reset_agent
        self.rotate = editor.rotate
        self.remove = editor.remove
        # Commands.
        self.actuators = actuation.actuators
        self.set_speeds = actuation.set_speeds
        self.set_speeds_all = actuation.set_speeds_all
        self.set_counters = actuation.set_counters
        self.set_leds = actuation.set_leds
        self.set_arm = actuation.set_arm
        self.set_grip = actuation.set_grip
