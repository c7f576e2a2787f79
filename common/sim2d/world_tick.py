"""A World's tick: arms, drive, physics, counters, carried objects, then sensors.

The per-tick work runs in compiled kernels (common/sim2d/compiled.py: compiled
ahead of time, or numba's), calling chipmunk's C functions directly
(common/sim2d/chipmunk.py); on the discs drive the whole tick is one compiled
call (common/sim2d/fused.py).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

from common.sim2d import chipmunk, compiled, pucks_tables, sensing, world_discs
from common.sim2d.packs import Readings

if TYPE_CHECKING:
    import pymunk

    from common.sim2d.entities import Agent, Light, MovableObject, Obstacle
    from common.sim2d.gripper import GripperTurrets
    from common.sim2d.world_state import Tables, WorldState


def _split_drive(threads: int, robots: int) -> ModuleType | None:
    """discs_split (the drive on the world's threads) where a world may split its drive.

    Imported only there: it is numba's (a parallel loop the ahead-of-time module
    cannot hold), and such a world senses on numba's threads already; a world on one
    thread never loads it. The caller still compares its discs with SPLIT_MIN_DISCS.
    """
    if threads <= 1 or robots < sensing.PARALLEL_MIN_AGENTS:
        return None
    from common.sim2d import discs_split

    return discs_split


class WorldTick:
    """World's stepping methods (a mixin of :class:`~common.sim2d.world.World`)."""

    if TYPE_CHECKING:  # the World's state the tick reads and writes (common/sim2d/world.py)
        state: WorldState
        width: float
        height: float
        drive: str
        layout: int
        tick: int
        sim_time: float
        tick_s: float
        substeps: int
        sensor_period_s: float
        threads: int
        profile: bool
        phase_cpu: dict[str, float]
        space: pymunk.Space
        sensors: sensing.SensorSuite
        noise: sensing.NoiseKeys
        grippers: GripperTurrets
        tables: Tables
        agents: list[Agent]
        objects: list[MovableObject]
        obstacles: dict[str, Obstacle]
        lights: list[Light]
        agent_pose: np.ndarray
        agent_vel: np.ndarray
        object_pose: np.ndarray
        proximity: np.ndarray
        ambient: np.ndarray
        presence: np.ndarray
        cmd: np.ndarray
        counters: np.ndarray
        arm: np.ndarray
        _agent_bodies: np.ndarray
        _control_bodies: np.ndarray
        _object_bodies: np.ndarray
        _servo_memory: np.ndarray
        _space_address: np.uint64
        _step_fn: Any
        _rows_layout: int
        _disc_circles: tuple[object, tuple[np.ndarray, np.ndarray]]
        _split_work: tuple[np.ndarray, ...]
        _fused: _FusedTick | None
        fingers: np.ndarray

        def holding(self) -> np.ndarray: ...

        def slot_of(self, agent: Agent) -> int: ...

        def on_floor(self, obj: MovableObject) -> bool: ...

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
            self.state.discs,
        )

    def _new_fused_state(self) -> _FusedTick:
        """The fused tick's state built afresh (_step_fused checks whether the last one holds)."""
        t = self.tables
        objs = world_discs.disc_objects(self.state)
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
            self.tick_s * t.pulses_per_s_per_unit,
            objs.radius,
            objs.mass,
        )
        scene = static.scene
        circles = compiled.bin_circles(
            static.circle_centres, static.circle_radii, scene.grid_nx, scene.grid_ny, scene.cell
        )
        holding = objs.holding
        tables = self.sensors.agents.kernel_tables
        objects = pucks_tables.scene_buffers(
            len(objs.objects), objs.edges, len(static.circle_radii)
        )
        state, call = compiled.new_tick(
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
            objs.table,
            objects,
            readings,
            (self.width, self.height, self.tick_s / self.substeps),
            self.substeps,
        )
        split = None
        nd = n + len(objs.objects)
        discs_split = _split_drive(self.threads, n)
        if discs_split is not None and nd >= discs_split.SPLIT_MIN_DISCS:
            from common.sim2d import discs

            # The drive on the world's threads (discs_split.py): the state's
            # arrays, work arrays of its own (the fused tick's are scratch too).
            split = (
                pose,
                self.cmd,
                t.mm_s_per_unit,
                t.wheel_base,
                objs.radius,
                objs.mass,
                self.counters,
                drive[2],
                static.kernel_scene,
                circles,
                self.width,
                self.height,
                self.tick_s / self.substeps,
                self.substeps,
                pose,
                vel,
                discs.drive_buffers(n, len(objs.objects), self.width, self.height, objs.radius),
                objs.table,
                self.arm,
                discs_split.split_buffers(nd),
            )
        # Keyed on what it was built from after the build: static_geometry may
        # have just made the static scene.
        f = self._fused = _FusedTick(
            self._fused_key(),
            state,
            call,
            pose,
            vel,
            *readings,
            holding,
            tables,
            static.kernel_scene,
            objects,
            objs,
            n >= sensing.PARALLEL_MIN_AGENTS,
            split,
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
        f = self._fused
        # The state holds while nothing it was built from changed (_fused_key).
        # Spelled out rather than a loop over _fused_key(), and here rather than in
        # a method: this runs every tick (at 10 robots a generator was 1.5 us of a
        # 25 us step, and a method call 0.05 us of an 8 us one).
        if f is None:
            f = self._new_fused_state()
        else:
            k = f.key
            sensors = self.sensors
            objs = f.discs
            if not (
                k[0] == self.layout
                and k[1] is self.tables
                and k[2] is sensors.agents
                and k[3] is sensors.current_static()
                and k[4] is self.cmd
                and k[5] is self.counters
                and k[6] is self.arm
                and k[7] == self.tick_s
                and k[8] == self.substeps
                # k[9] is world_discs.current(self), spelled out: d's key is
                # world_discs._key (layout, grip version, tables, fingers, arm),
                # taken with this one, so its layout, tables and arm are k[0], k[1]
                # and k[6], checked above (the call was 0.15 us a tick).
                and self.state.discs is objs
                and objs.key[1] == self.state.grip_version
                and objs.key[3] is self.fingers
            ):
                f = self._new_fused_state()
        tick = self.tick + 1
        sim_time = tick * dt
        sense = sim_time + 1e-9 >= self.state.next_sense
        if sense:
            lights = self.sensors.lit(self, sim_time)
            key = self.noise.next()
        else:
            lights, key = sensing.NO_LIGHTS, np.uint64(0)
        on_threads = f.swarm and self.threads > 1
        if on_threads and f.split is not None:
            from common.sim2d import discs_split  # loaded when the split was made

            discs_split.on_threads(f.split, self.threads)
        else:
            f.call(f.state, sense and not on_threads, key, lights)
        if sense and on_threads:
            # The same pass on the world's threads, in the state's own arrays.
            o = f.objects
            m, e = compiled.scene_into(
                len(f.pose), f.discs.table, self.arm, f.scene[7], f.scene[8], o
            )
            sensing.sense_on_threads(
                (f.pose, self.arm, f.holding),
                f.tables,
                f.scene,
                (o[0][:m], o[1][:m], o[2][:m], o[3][:m], o[4][:e], lights, key),
                (f.proximity, f.ambient, f.presence),
                self.threads,
            )
        # The buffers are handed out as copies at their first read (_CopiedOnRead).
        d = self.state.__dict__
        d["_agent_pose_buffer"] = f.pose
        d["_agent_vel_buffer"] = f.vel
        d["_object_pose_buffer"] = f.discs.table[0]  # (0, 3) once the last object went
        self.state.bodies_placed = False
        self.tick = tick
        self.sim_time = sim_time
        if sense:
            d["_proximity_buffer"] = f.proximity
            d["_ambient_buffer"] = f.ambient
            d["_presence_buffer"] = f.presence
            self.state.next_sense = sim_time + self.sensor_period_s - 1e-9

    def step(self) -> None:
        """Advance one tick: arms, drive, physics, counters, carried objects, sensors."""
        profile = self.profile
        # The discs drive in one compiled call, its sensing pass too where it runs
        # on one thread (fused.tick says why). Not while profiling: the profile times physics
        # and sensing apart, which the general path below does with the same
        # results.
        if self.drive == "discs" and not profile and self.agents:
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
            # Chipmunk is not stepped: the robots' and objects' bodies stay where
            # they were placed, for the edits' overlap queries (_place_bodies);
            # the objects move in the drive's arrays (world_discs.py).
            via_pymunk = False
            objs = world_discs.disc_objects(self.state)
            static = self.sensors.static_geometry(self)
            if self._disc_circles[0] is not static:
                scene = static.scene
                self._disc_circles = (
                    static,
                    compiled.bin_circles(
                        static.circle_centres,
                        static.circle_radii,
                        scene.grid_nx,
                        scene.grid_ny,
                        scene.cell,
                    ),
                )
            args = (
                self.agent_pose,
                self.cmd,
                t.mm_s_per_unit,
                t.wheel_base,
                objs.radius,
                objs.mass,
                self.counters,
                dt * t.pulses_per_s_per_unit,
                static.kernel_scene,
                self._disc_circles[1],
                self.width,
                self.height,
                sub,
                self.substeps,
                objs.table,
                self.arm,
            )
            n = len(self.agents)
            nd = n + len(objs.objects)
            discs_split = _split_drive(self.threads, n)
            if discs_split is not None and nd >= discs_split.SPLIT_MIN_DISCS:
                if len(self._split_work) == 0 or len(self._split_work[0]) != nd:
                    self._split_work = discs_split.split_buffers(nd)
                pose, vel = discs_split.tick(*args, self.threads, self._split_work)
            else:
                pose, vel = compiled.discs_tick(*args)
            obj = objs.table[0].copy()
            self.state.bodies_placed = False
        elif self.drive == "joints":
            pose, vel, obj = compiled.physics_tick(
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
            pose, vel, obj = compiled.physics_tick_servo(
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
                    compiled.servo_forces(
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
            pose, vel, obj = compiled.read_bodies(
                chipmunk.FUNCTIONS, self._agent_bodies, self._object_bodies
            )
        self.agent_pose, self.agent_vel, self.object_pose = pose, vel, obj
        if self.drive != "discs":  # there the drive carries them (pucks.py)
            self.grippers.carry()
        self.tick += 1
        self.sim_time = self.tick * dt
        if profile:
            t1 = time.process_time()
            self.phase_cpu["physics"] += t1 - t0
        if self.sim_time + 1e-9 >= self.state.next_sense:
            self.sense()
            self.state.next_sense = self.sim_time + self.sensor_period_s - 1e-9
            if profile:
                self.phase_cpu["sensing"] += time.process_time() - t1

    def sense(self) -> None:
        """Recompute every agent's proximity, ambient and gripper presence readings."""
        n = len(self.agents)
        if n == 0:
            return
        out = Readings(
            np.empty((n, self.proximity.shape[1]), dtype=np.int32),
            np.empty((n, self.ambient.shape[1]), dtype=np.int32),
            np.empty(n, dtype=np.int32),
        )
        self.proximity, self.ambient, self.presence = self.sensors.read(self, out)

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds / self.tick_s)):
            self.step()


@dataclass(frozen=True)
class _FusedTick:
    """A discs world's fused tick state and the buffers it writes (World._new_fused_state)."""

    key: tuple[object, ...]
    state: object  # fused.TickState, or its address in the ahead-of-time module
    call: Callable[[Any, bool, np.uint64, np.ndarray], None]  # compiled.new_tick's tick
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
    objects: tuple[np.ndarray, ...]  # pucks.scene_buffers: the pass's moving scene
    discs: world_discs.DiscObjects  # the objects' arrays the state holds
    swarm: bool  # enough robots for a pass on threads (sensing.PARALLEL_MIN_AGENTS)
    # discs_split.tick_into_split's arguments, where the drive is split over the
    # world's threads (discs_split.SPLIT_MIN_DISCS discs or more); else None.
    split: tuple[object, ...] | None
