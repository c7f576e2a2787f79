"""Compiled (numba) kernels for the engine's per-tick work: drive and physics, sensing.

Why compiled: at small N a tick's cost was the fixed overhead of ~150 small
numpy calls (a few microseconds each), not arithmetic; at large N the
vectorised passes built big temporaries. One loop per job, compiled once,
does the same arithmetic with none of that overhead (see docs/BENCHMARKS.md).

The geometry was written to match the earlier numpy implementation operation
for operation (same formulas, same order), but the
sensor noise is drawn in the kernel from a per-pass key (same laws, other
numbers than numpy's draws), the ambient cone needs no trigonometry and
shortcuts skip work that cannot change a reading (docs/BENCHMARKS.md, "A
sensing pass at 10,000 robots"). Kernels are cached on disk (``cache=True``, in
``~/.cache/wart/numba`` for every checkout of the same sources: jitcache.py): the
first start after their sources change compiles them, later starts load them. :func:`warm_up` does
that explicitly and returns the time it took, so the engine can report it.
The World calls them through common/sim2d/compiled.py, which runs the same
kernels compiled ahead of time where that module is built (aot.py): then
numba is not loaded at all.

Grid: one uniform grid over the arena plus one cell of margin on every side,
cell >= the longest sensor reach + the largest radius. Static obstacle edges
are binned once (into every cell within one cell of their bounding box, CSR
arrays built in common/sim2d/sensing.py); circles (robots, round objects,
round obstacles) are binned each pass with a counting sort. A robot looks at
the circles of its 3x3 cells and the edges of its own cell. Cells outside the
grid are clamped to its border: that only adds far candidates, and a hit
beyond the sensor's range reads the same as no hit.

The kernels live in one module per job, and this one gathers the kernels
callers use as ``kernels.NAME`` and warms them all up: physics.py (drive,
chipmunk's step, body state), noise.py (the sensors' Gaussian noise),
rays.py (rays, occlusion, the lights' shadows), sense_pass.py (the sensing
pass itself); discs.py and contacts.py hold the discs drive. The packs'
layouts and shared settings (columns, MAX_THREADS) are common/sim2d/packs.py's,
imported from there. A kernel calling one in another file has
that file's contents in its cache's stamp (common/sim2d/jitcache.py).
"""

from __future__ import annotations

import time

import numpy as np

from common.sim2d import aot, discs
from common.sim2d import chipmunk as C
from common.sim2d.noise import normal, normals
from common.sim2d.packs import (
    I_AMB_SENSORS,
    I_PROX_SENSORS,
    N_AGENT_F,
    N_AGENT_I,
    MovingScene,
    Readings,
    Robots,
    SensorTables,
    StaticScene,
)
from common.sim2d.physics import (
    braitenberg_speeds,
    clamp_speeds,
    physics_tick,
    physics_tick_servo,
    read_bodies,
    servo_forces,
)
from common.sim2d.rays import ambient_gain
from common.sim2d.sense_pass import (
    circle_buffers,
    scratch_buffers,
    sense,
    sense_into,
    sense_parallel,
)

# The kernels callers use as kernels.NAME (the engine, sensing.py, the benches); the
# kernels' helpers stay in their modules (rays._occluded, sense_pass._circles...).
__all__ = [
    "ambient_gain",
    "braitenberg_speeds",
    "circle_buffers",
    "clamp_speeds",
    "normal",
    "normals",
    "physics_tick",
    "physics_tick_servo",
    "read_bodies",
    "scratch_buffers",
    "sense",
    "sense_into",
    "sense_parallel",
    "servo_forces",
    "warm_up",
]


def warm_up() -> float:
    """Compile (or load from the on-disk cache) every kernel; returns the seconds it took."""
    t0 = time.perf_counter()
    none = np.zeros(0, dtype=np.uint64)  # no bodies: compiles without touching chipmunk
    step = (C.FUNCTIONS, C.FUNCTIONS[C.SPACE_STEP], np.uint64(0), 0.01, 0)
    cmd, counters = np.zeros((0, 2)), np.zeros((0, 2))
    rates = (np.ones(0), np.ones(0), np.ones(0))
    servo, memory = np.ones((0, 4)), np.zeros((0, 6))
    physics_tick(*step, none, none, none, cmd, counters, rates)
    physics_tick_servo(*step, none, none, cmd, counters, rates, servo, memory)
    servo_forces(C.FUNCTIONS, none, cmd, rates, servo, memory, 0.01)
    read_bodies(C.FUNCTIONS, none, none)
    clamp_speeds(np.zeros((1, 2)), np.ones(1), np.zeros((1, 2)))
    braitenberg_speeds(
        np.zeros((1, 8), dtype=np.int32), np.zeros((8, 2)), 8.0, np.ones(1), np.zeros((1, 2))
    )
    f = np.zeros((1, N_AGENT_F))
    i = np.zeros((1, N_AGENT_I), dtype=np.int64)
    i[0, I_PROX_SENSORS] = 1
    i[0, I_AMB_SENSORS] = 1
    packs = (
        Robots(np.zeros((1, 3)), np.zeros(1), np.zeros(1, dtype=np.bool_)),
        SensorTables(
            np.zeros((1, 1, 5)),
            1,
            1,
            f,
            i,
            np.array([[0.0, 1.0]]),
            np.array([[1.0, 0.0]]),
            np.array([2], dtype=np.int64),
            np.zeros((1, 1, 5)),
            np.ones((1, 1), dtype=np.bool_),
            np.ones((1, 1)),
            np.zeros((1, 1)),
        ),
        StaticScene(*aot.scene_sample()),
        MovingScene(
            np.zeros((0, 2)),
            np.zeros(0),
            np.zeros(0, dtype=np.int64),
            np.zeros(0, dtype=np.bool_),
            np.zeros((0, 4)),
            np.zeros((0, 4)),
            np.uint64(1),
        ),
        Readings(
            np.zeros((1, 1), dtype=np.int32),
            np.zeros((1, 1), dtype=np.int32),
            np.zeros(1, dtype=np.int32),
        ),
    )
    # Plain tuples, as SensorSuite.read passes them.
    robots, tables, scene, moving, out = (tuple(p) for p in packs)
    sense(robots, tables, scene, moving, out)
    sense_parallel(robots, tables, scene, moving, out, 1)
    discs.warm_up()
    # Imported here: common/sim2d/fused.py builds on this module.
    from common.sim2d import discs_split, fused

    fused.warm_up()
    discs_split.warm_up()
    return time.perf_counter() - t0
