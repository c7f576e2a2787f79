"""A world's ticker: the tick (arms, drive, physics, counters, carried objects, sensors).

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

from common.sim2d import chipmunk, compiled, heap, pucks_tables, sensing, world_discs
from common.sim2d.packs import Readings
from common.sim2d.real_wheels import RealWheels

if TYPE_CHECKING:
    from common.sim2d.gripper import GripperTurrets
    from common.sim2d.world_state import WorldState


def _split_drive(threads: int, robots: int) -> ModuleType | None:
    """discs_split (the drive on the world's threads) where a world may split its drive.

    Imported only there: it is numba's (a parallel loop the ahead-of-time module
    cannot hold), and such a world senses on numba's threads already; a world on one
    thread never loads it. The caller still compares its discs with SPLIT_MIN_DISCS.
    """
    if threads <= 1 or robots < sensing.PARALLEL_MIN_AGENTS:
        return None
    from common.sim2d import discs_split  # numba's: loaded only by worlds that split

    return discs_split


class WorldTicker:
    """Steps and senses one world's state, keeping what its ticks reuse.

    Its own: the compiled physics tick's body addresses and the velocity drive's
    memory, the discs drive's binned obstacles and work arrays, and the fused
    tick (``fused``: the discs drive's state for one compiled call, built again
    when anything it was built from changes).
    """

    def __init__(self, state: WorldState, grippers: GripperTurrets) -> None:
        # Bound once, for the step: the state's sensors and noise keys are made
        # with it and never replaced.
        self._state = state
        self._grippers = grippers
        self._sensors = state.sensors
        self._noise = state.noise
        # A tick's freed arrays stay in the heap for the next tick (common/sim2d/heap.py).
        heap.keep_freed_memory()
        self._step_fn = chipmunk.FUNCTIONS[
            chipmunk.HASTY_SPACE_STEP if state.physics_threads > 1 else chipmunk.SPACE_STEP
        ]
        # cpBody addresses for the compiled physics tick (common/sim2d/chipmunk.py),
        # rebuilt at the first tick after any layout change (every add and remove bumps
        # the layout): an address kept past its body's removal would read freed memory.
        self._space_address = np.uint64(chipmunk.space_address(state.space))
        self._agent_bodies = self._control_bodies = self._object_bodies = np.zeros(
            0, dtype=np.uint64
        )
        self._rows_layout = -1
        self._servo_memory = np.zeros((0, 6))
        # The discs drive (common/sim2d/discs.py): the sensing grid it last binned
        # the round obstacles of, with those bins.
        self._disc_circles: tuple[object, tuple[np.ndarray, np.ndarray]] = (
            None,
            (np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64)),
        )
        # The split drive's work arrays on the general path (discs_split.split_buffers).
        self._split_work: tuple[np.ndarray, ...] = ()
        # The discs drive's fused tick (common/sim2d/fused.py): its state, built at
        # the first tick after anything it holds changed (FusedTick.key).
        self.fused: FusedTick | None = None
        self._wheels = RealWheels(state)

    def _refresh_rows(self) -> None:
        s = self._state
        self._agent_bodies = chipmunk.addresses([a.body for a in s.agents])
        self._control_bodies = chipmunk.addresses(
            [a.control for a in s.agents if a.control is not None]
        )
        # The velocity drive's memory of the last step (kernels.servo_forces); NaN: none.
        # An edit may have moved or stopped any robot, so after one it starts afresh.
        self._servo_memory = np.full((len(s.agents), 6), np.nan)
        self._object_bodies = chipmunk.addresses([o.body for o in s.objects if o.body])
        self._rows_layout = s.layout

    def _rates(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each robot's (mm/s per unit of speed, wheel base, pulses per unit a tick)."""
        s = self._state
        t = s.tables
        return (t.mm_s_per_unit, t.wheel_base, s.tick_s * t.pulses_per_s_per_unit)

    def _drive(
        self, objs: world_discs.DiscObjects, rates: tuple[np.ndarray, ...] | None = None
    ) -> tuple[np.ndarray, ...]:
        """The discs drive's table (discs.tick_into's ``drive``): the robots' rates (these,
        or :meth:`_rates`), then every disc's radius and mass."""
        return (*(rates or self._rates()), objs.radius, objs.mass)

    def _fused_key(self) -> tuple[object, ...]:
        """What a fused tick's state was built from: a new one is built when any differs."""
        s = self._state
        return (
            s.layout,
            s.tables,
            self._sensors.agents,
            self._sensors.current_static(),
            s.cmd,
            s.counters,
            s.arm,
            s.tick_s,
            s.substeps,
            s.discs,
        )

    def _new_fused_state(self) -> FusedTick:
        """The fused tick's state built afresh (_step_fused checks whether the last one holds)."""
        s = self._state
        objs = world_discs.disc_objects(s)
        static = self._sensors.static_geometry(s)
        n = len(s.agents)
        pose = np.array(s.agent_pose, dtype=np.float64, order="C")
        vel = np.array(s.agent_vel, dtype=np.float64, order="C")
        readings = (
            np.zeros((n, s.proximity.shape[1]), dtype=np.int32),
            np.zeros((n, s.ambient.shape[1]), dtype=np.int32),
            np.zeros(n, dtype=np.int32),
        )
        drive = self._drive(objs)
        scene = static.scene
        circles = compiled.bin_circles(
            static.circle_centres, static.circle_radii, scene.grid_nx, scene.grid_ny, scene.cell
        )
        holding = objs.holding
        tables = self._sensors.agents.kernel_tables
        objects = pucks_tables.scene_buffers(
            len(objs.objects), objs.edges, len(static.circle_radii)
        )
        geometry = (s.width, s.height, s.tick_s / s.substeps)
        state, call = compiled.new_tick(
            (
                pose,
                vel,
                s.cmd,
                s.counters,
                s.arm,
                holding,
                drive,
                circles,
                tables,
                static.kernel_scene,
                objs.table,
                objects,
                readings,
                geometry,
                s.substeps,
            )
        )
        split = None
        nd = n + len(objs.objects)
        discs_split = _split_drive(s.threads, n)
        if discs_split is not None and nd >= discs_split.SPLIT_MIN_DISCS:
            from common.sim2d import discs  # numba's, as discs_split

            # The drive on the world's threads (discs_split.py): the state's
            # arrays, work arrays of its own (the fused tick's are scratch too).
            split = (
                (pose, s.cmd, s.counters, s.arm),
                drive,
                static.kernel_scene,
                circles,
                geometry,
                s.substeps,
                objs.table,
                (pose, vel),
                discs.drive_buffers(n, len(objs.objects), s.width, s.height, objs.radius),
                discs_split.split_buffers(nd),
            )
        # Keyed on what it was built from after the build: static_geometry may
        # have just made the static scene.
        f = self.fused = FusedTick(
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

    def _step_fused(self, s: WorldState) -> None:
        """:meth:`step` on the discs drive as one compiled call (common/sim2d/fused.py).

        The same work in the same order as the general path: arms, drive and
        contacts, then a sensing pass when one is due (its noise key drawn only
        then, as SensorSuite.packs draws it).
        """
        dt = s.tick_s
        grippers = self._grippers
        if grippers.arms_moving:  # the check move_arms starts with, without the call
            grippers.move_arms(dt)
        f = self.fused
        # The state holds while nothing it was built from changed (_fused_key).
        # Spelled out rather than a loop over _fused_key(), and here rather than in
        # a method: this runs every tick (at 10 robots a generator was 1.5 us of a
        # 25 us step, and a method call 0.05 us of an 8 us one).
        if f is None:
            f = self._new_fused_state()
        else:
            k = f.key
            sensors = self._sensors
            objs = f.discs
            if not (
                k[0] == s.layout
                and k[1] is s.tables
                and k[2] is sensors.agents
                and k[3] is sensors.current_static()
                and k[4] is s.cmd
                and k[5] is s.counters
                and k[6] is s.arm
                and k[7] == s.tick_s
                and k[8] == s.substeps
                # k[9] is world_discs.current(s), spelled out: d's key is
                # world_discs._key (layout, grip version, tables, fingers, arm),
                # taken with this one, so its layout, tables and arm are k[0], k[1]
                # and k[6], checked above (the call was 0.15 us a tick).
                and s.discs is objs
                and objs.key[1] == s.grip_version
                and objs.key[3] is s.fingers
            ):
                f = self._new_fused_state()
        tick = s.tick + 1
        sim_time = tick * dt
        sense = sim_time + 1e-9 >= s.next_sense
        if sense:
            lights = self._sensors.lit(s, sim_time)
            key = self._noise.next()
        else:
            lights, key = sensing.NO_LIGHTS, np.uint64(0)
        on_threads = f.swarm and s.threads > 1
        if on_threads and f.split is not None:
            from common.sim2d import discs_split  # loaded when the split was made

            discs_split.on_threads(f.split, s.threads)
        else:
            f.call(f.state, sense and not on_threads, key, lights)
        if sense and on_threads:
            # The same pass on the world's threads, in the state's own arrays.
            o = f.objects
            m, e = compiled.scene_into(len(f.pose), f.discs.table, s.arm, f.scene[7], f.scene[8], o)
            sensing.sense_on_threads(
                (f.pose, s.arm, f.holding),
                f.tables,
                f.scene,
                (o[0][:m], o[1][:m], o[2][:m], o[3][:m], o[4][:e], lights, key),
                (f.proximity, f.ambient, f.presence),
                s.threads,
            )
        # The buffers are handed out as copies at their first read (CopiedOnRead).
        d = s.__dict__
        d["_agent_pose_buffer"] = f.pose
        d["_agent_vel_buffer"] = f.vel
        d["_object_pose_buffer"] = f.discs.table[0]  # (0, 3) once the last object went
        s.bodies_placed = False
        s.tick = tick
        s.sim_time = sim_time
        if sense:
            d["_proximity_buffer"] = f.proximity
            d["_ambient_buffer"] = f.ambient
            d["_presence_buffer"] = f.presence
            s.next_sense = sim_time + s.sensor_period_s - 1e-9

    def step(self) -> None:
        """Advance one tick: arms, drive, physics, counters, carried objects, sensors."""
        s = self._state
        imperfect = s.tables.imperfect
        if imperfect:  # robots whose wheels slip or obey late (a real robot's twin)
            self._wheels.before(imperfect)
        profile = s.profile
        # The discs drive in one compiled call, its sensing pass too where it runs
        # on one thread (fused.tick says why). Not while profiling: the profile times physics
        # and sensing apart, which the general path below does with the same
        # results. A world with no robots (all deleted) takes it too: the general path is
        # numba's, loaded or compiled at its first use, seconds in which the world answers
        # no snapshot or edit.
        if s.drive == "discs" and not profile:
            self._step_fused(s)
            if imperfect:
                self._wheels.after(imperfect)
            return
        # The fused state's buffers would fall behind this tick: built afresh if needed.
        self.fused = None
        if profile:
            t0 = time.process_time()
        dt = s.tick_s
        self._grippers.move_arms(dt)
        if self._rows_layout != s.layout:
            self._refresh_rows()
        t = s.tables
        # Straight through chipmunk unless pymunk's own step has bookkeeping to do
        # (bodies or shapes just added or removed): then drive only, and step via pymunk.
        via_pymunk = chipmunk.space_step_pending(s.space)
        sub = dt / s.substeps
        rates = self._rates()
        if s.drive == "discs":
            # Chipmunk is not stepped: the robots' and objects' bodies stay where
            # they were placed, for the edits' overlap queries (world_discs.place_bodies);
            # the objects move in the drive's arrays (world_discs.py).
            via_pymunk = False
            objs = world_discs.disc_objects(s)
            static = self._sensors.static_geometry(s)
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
                (s.agent_pose, s.cmd, s.counters, s.arm),
                self._drive(objs, rates),
                static.kernel_scene,
                self._disc_circles[1],
                (s.width, s.height, sub),
                s.substeps,
                objs.table,
            )
            n = len(s.agents)
            nd = n + len(objs.objects)
            discs_split = _split_drive(s.threads, n)
            if discs_split is not None and nd >= discs_split.SPLIT_MIN_DISCS:
                if len(self._split_work) == 0 or len(self._split_work[0]) != nd:
                    self._split_work = discs_split.split_buffers(nd)
                pose, vel = discs_split.tick(*args, s.threads, self._split_work)
            else:
                pose, vel = compiled.discs_tick(*args)
            obj = objs.table[0].copy()
            s.bodies_placed = False
        elif s.drive == "joints":
            pose, vel, obj = compiled.physics_tick(
                chipmunk.FUNCTIONS,
                self._step_fn,
                self._space_address,
                sub,
                0 if via_pymunk else s.substeps,
                self._control_bodies,
                self._agent_bodies,
                self._object_bodies,
                s.cmd,
                s.counters,
                rates,
            )
        else:
            pose, vel, obj = compiled.physics_tick_servo(
                chipmunk.FUNCTIONS,
                self._step_fn,
                self._space_address,
                sub,
                0 if via_pymunk else s.substeps,
                self._agent_bodies,
                self._object_bodies,
                s.cmd,
                s.counters,
                rates,
                t.servo,
                self._servo_memory,
            )
        if via_pymunk:
            for _ in range(s.substeps):
                if s.drive == "velocity":
                    compiled.servo_forces(
                        chipmunk.FUNCTIONS,
                        self._agent_bodies,
                        s.cmd,
                        rates,
                        t.servo,
                        self._servo_memory,
                        sub,
                    )
                s.space.step(sub)
            pose, vel, obj = compiled.read_bodies(
                chipmunk.FUNCTIONS, self._agent_bodies, self._object_bodies
            )
        s.agent_pose, s.agent_vel, s.object_pose = pose, vel, obj
        if s.drive != "discs":  # there the drive carries them (pucks.py)
            self._grippers.carry()
        s.tick += 1
        s.sim_time = s.tick * dt
        if profile:
            t1 = time.process_time()
            s.phase_cpu["physics"] += t1 - t0
        if s.sim_time + 1e-9 >= s.next_sense:
            self.sense()
            s.next_sense = s.sim_time + s.sensor_period_s - 1e-9
            if profile:
                s.phase_cpu["sensing"] += time.process_time() - t1
        if imperfect:
            self._wheels.after(imperfect)

    def sense(self) -> None:
        """Recompute every agent's proximity, ambient and gripper presence readings."""
        s = self._state
        n = len(s.agents)
        if n == 0:
            return
        out = Readings(
            np.empty((n, s.proximity.shape[1]), dtype=np.int32),
            np.empty((n, s.ambient.shape[1]), dtype=np.int32),
            np.empty(n, dtype=np.int32),
        )
        s.proximity, s.ambient, s.presence = self._sensors.read(s, out)

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds / self._state.tick_s)):
            self.step()


@dataclass(frozen=True)
class FusedTick:
    """A discs world's fused tick state and the buffers it writes (WorldTicker._new_fused_state)."""

    key: tuple[object, ...]
    state: object  # fused.TickState, or its address in the ahead-of-time module
    call: Callable[[Any, bool, np.uint64, np.ndarray], None]  # compiled.new_tick's tick
    pose: np.ndarray
    vel: np.ndarray
    proximity: np.ndarray
    ambient: np.ndarray
    presence: np.ndarray
    # What a sensing pass on threads reads besides the poses (WorldTicker._step_fused):
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
