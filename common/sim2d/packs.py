"""What every kernel module shares: cache settings and the sensing packs' layouts.

The packs and column indices are the sensing kernel's argument layouts
(common/sim2d/sensing.py builds them).
"""

from __future__ import annotations

import os
from typing import Any, NamedTuple

import numpy as np

# Column indices of the per-agent float table (AgentSensing.agent_f).
F_REACH = 0
F_RADIUS = 1
F_PROX_NOISE_FRACTION = 2  # the additive noise is per sensor (SensorTables.prox_counts)
F_PROX_MAX = 3
F_AMB_HALF_ANGLE = 4
F_AMB_DROP = 5
F_AMB_DARK = 6
F_AMB_FLOOR = 7
F_AMB_NOISE_FRACTION = 8
F_GRIP_X0 = 9
F_GRIP_X1 = 10
F_GRIP_HALF_WIDTH = 11
F_HAS_GRIP = 12
F_ARM_LOWERED_ABOVE = 13
F_AMB_COS_HALF = 14  # cos(F_AMB_HALF_ANGLE): the cone test without an angle
N_AGENT_F = 15

# Column indices of the per-agent int table (AgentSensing.agent_i).
I_PROX_SENSORS = 0  # real (unpadded) proximity sensors
I_TYPE = 1  # the agent's type: row of the response curves and the sensor layouts
I_AMB_SENSORS = 2
N_AGENT_I = 3


# The sensing kernel's arguments, packed by what changes when: a pack is built
# once and kept until what it holds changes (numba takes named tuples as they are).
class Robots(NamedTuple):
    """What moves every tick."""

    pose: np.ndarray  # (N, 3) agents' x, y, heading
    arm: np.ndarray  # (N,) arm positions
    holding: np.ndarray  # (N,) bool


class SensorTables(NamedTuple):
    """The agents' sensors (rebuilt when agents come or go)."""

    ray_local: np.ndarray  # (types, S*K, 5) rays in the robot frame: x, y, angle, cos, sin
    sensors: int  # S (padded proximity sensors per agent)
    rays_per_sensor: int  # K
    agent_f: np.ndarray  # (N, N_AGENT_F) per-agent floats
    agent_i: np.ndarray  # (N, N_AGENT_I) per-agent ints
    curve_x: np.ndarray  # (G, L) response curves, padded
    curve_y: np.ndarray
    curve_n: np.ndarray  # (G,) points used
    amb_local: np.ndarray  # (types, A, 5) ambient sensors, robot frame: x, y, angle, cos, sin
    amb_valid: np.ndarray  # (types, A) bool
    # (types, S) each IR sensor's gain on the response curve and its additive noise σ
    # (counts): 1 and the type's noise_counts, unless a twin's robot file gives its own.
    prox_gain: np.ndarray
    prox_counts: np.ndarray


class StaticScene(NamedTuple):
    """Obstacles and the arena's walls (rebuilt when they change)."""

    segs: np.ndarray  # (S, 4) static edges (arena walls first)
    grid_start: np.ndarray  # (nx*ny + 1,) CSR offsets into grid_items, cell-major
    grid_items: np.ndarray  # static edge index per (cell, edge) entry
    grid_nx: int
    grid_ny: int
    cell: float
    occ_segs: np.ndarray  # (O, 4) static edges that can hide a light (not the arena's walls)
    static_xy: np.ndarray  # (Q, 2) round obstacles (they hide lights too)
    static_r: np.ndarray


class MovingScene(NamedTuple):
    """Objects, lights and the noise key of one sensing pass."""

    circ_xy: np.ndarray  # (C, 2) other circles: round objects on the floor, round obstacles
    circ_r: np.ndarray  # (C,)
    circ_owner: np.ndarray  # (C,) agent slot that does not see it (holder), or -1
    circ_is_object: np.ndarray  # (C,) bool: a movable object (the gripper's barrier sees it)
    edges: np.ndarray  # (E, 4) edges of movable polygons on the floor
    lights: np.ndarray  # (L, 4) lit lights: x, y, radius, intensity
    noise_key: np.uint64  # this pass's noise key, drawn from the world's generator


class Readings(NamedTuple):
    proximity: np.ndarray  # (N, P) int32
    ambient: np.ndarray  # (N, A) int32
    presence: np.ndarray  # (N,) int32


# OpenMP's workers (numba's threading layer here) spin after each parallel region
# by default: on the lab's shared 2-core machines that burned 4 to 5x the CPU of the
# work itself and slowed the other processes (docs/BENCHMARKS.md). Passive
# workers sleep instead. Read once, when numba first loads OpenMP; a value the user
# set wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

_CACHE = True
# Numba's option for a kernel compiled without reference counting. Each array a
# compiled function receives (tuples of them included) or takes a view of is
# counted in and out with an atomic operation, and an inlined helper counts its
# array arguments at each call: at 10 robots that was about 14 % of a step
# (docs/history/). A kernel that allocates nothing
# and returns no array needs none of it: its callers hold every array it
# touches. One that returned an array (a buffer it had filled) corrupted the
# heap: its caller released a reference it was never given. Numba refuses to
# compile an allocation in such a kernel.
_UNCOUNTED: dict[str, Any] = {"_nrt": False}
# A kernel an uncounted one calls must say it is counted. Numba compiles a
# callee with its caller's reference counting unless the callee sets its own,
# so a counted kernel first compiled from an uncounted caller would be built
# uncounted (numba then refuses its allocations, or, where it allocates none,
# the uncounted build is cached and later handed to counted callers too).
_COUNTED: dict[str, Any] = {"_nrt": True}
# Threads a kernel may use: numba's pool, sized at import (NUMBA_NUM_THREADS, default
# the CPUs this process may run on); set_num_threads can only lower it. Worked out as
# numba.config does it (numba_threads, tests/unit/common/sim2d/test_aot.py compares),
# so that an engine on the ahead-of-time kernels knows it without importing numba.


def numba_threads() -> int:
    """numba.config.NUMBA_NUM_THREADS, without importing numba (numba/core/config.py)."""
    try:
        default = max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        default = max(1, os.cpu_count() or 1)
    try:
        return int(os.environ["NUMBA_NUM_THREADS"])
    except (KeyError, ValueError):  # unset, or numba would warn and take the default
        return default


MAX_THREADS = numba_threads()
