"""Compiled (numba) kernels for the engine's per-tick work: drive and physics, sensing.

Why compiled: at small N a tick's cost was the fixed overhead of ~150 small
numpy calls (a few microseconds each), not arithmetic; at large N the
vectorised passes built big temporaries. One loop per job, compiled once,
does the same arithmetic with none of that overhead (see docs/BENCHMARKS.md).

The geometry was written to match the earlier numpy implementation operation
for operation (same formulas, same order); since issue 22's swarm work the
sensor noise is drawn in the kernel from a per-pass key (same laws, other
numbers than numpy's draws), the ambient cone needs no trigonometry and
shortcuts skip work that cannot change a reading (docs/BENCHMARKS.md, "A
sensing pass at 10,000 robots"). Kernels are cached on disk (``cache=True``, in
``__pycache__`` or ``NUMBA_CACHE_DIR``): the first start of a fresh checkout
compiles them (a few seconds), later starts load them. :func:`warm_up` does
that explicitly and returns the time it took, so the engine can report it.

Grid: one uniform grid over the arena plus one cell of margin on every side,
cell >= the longest sensor reach + the largest radius. Static obstacle edges
are binned once (into every cell within one cell of their bounding box, CSR
arrays built in common/sim2d/sensing.py); circles (robots, round objects,
round obstacles) are binned each pass with a counting sort. A robot looks at
the circles of its 3x3 cells and the edges of its own cell. Cells outside the
grid are clamped to its border: that only adds far candidates, and a hit
beyond the sensor's range reads the same as no hit.
"""

from __future__ import annotations

import math
import os
import time
from typing import Any, NamedTuple

import numba
import numpy as np
from numba import njit, prange

from common.sim2d import chipmunk as C
from common.sim2d import discs

# Column indices of the per-agent float table (AgentSensing.agent_f).
F_REACH = 0
F_RADIUS = 1
F_PROX_NOISE_FRACTION = 2
F_PROX_NOISE_COUNTS = 3
F_PROX_MAX = 4
F_AMB_HALF_ANGLE = 5
F_AMB_DROP = 6
F_AMB_DARK = 7
F_AMB_FLOOR = 8
F_AMB_NOISE_FRACTION = 9
F_GRIP_X0 = 10
F_GRIP_X1 = 11
F_GRIP_HALF_WIDTH = 12
F_HAS_GRIP = 13
F_ARM_LOWERED_ABOVE = 14
F_AMB_COS_HALF = 15  # cos(F_AMB_HALF_ANGLE): the cone test without an angle
N_AGENT_F = 16

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
# work itself and slowed the other processes (docs/BENCHMARKS.md, issue 22). Passive
# workers sleep instead. Read once, when numba first loads OpenMP; a value the user
# set wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

_CACHE = True
# Numba's option for a kernel compiled without reference counting. Each array a
# compiled function receives (tuples of them included) or takes a view of is
# counted in and out with an atomic operation, and an inlined helper counts its
# array arguments at each call: at 10 robots that was about 14 % of a step
# (docs/BENCHMARKS.md, issue 22, 2026-11-26). A kernel that allocates nothing
# and returns no array needs none of it: its callers hold every array it
# touches. One that returned an array (a buffer it had filled) corrupted the
# heap: its caller released a reference it was never given. Numba refuses to
# compile an allocation in such a kernel.
_UNCOUNTED: dict[str, Any] = {"_nrt": False}
# Threads a kernel may use: numba's pool, sized at import (NUMBA_NUM_THREADS, default
# the machine's cores); set_num_threads can only lower it.
MAX_THREADS = int(numba.config.NUMBA_NUM_THREADS)


@njit(cache=_CACHE)
def read_bodies(fns, agents, objects):  # pragma: no cover
    """(pose, vel, obj): agents' x, y, heading and vx, vy, w; objects' x, y, heading.

    ``agents`` and ``objects`` are cpBody addresses (common/sim2d/chipmunk.py).
    """
    n, m = len(agents), len(objects)
    pose = np.empty((n, 3))
    vel = np.empty((n, 3))
    obj = np.empty((m, 3))
    for a in range(n):
        b = agents[a]
        pose[a, 0], pose[a, 1] = C.get_vect(fns[C.GET_POSITION], b)
        pose[a, 2] = C.get_double(fns[C.GET_ANGLE], b)
        vel[a, 0], vel[a, 1] = C.get_vect(fns[C.GET_VELOCITY], b)
        vel[a, 2] = C.get_double(fns[C.GET_ANGULAR_VELOCITY], b)
    for o in range(m):
        b = objects[o]
        obj[o, 0], obj[o, 1] = C.get_vect(fns[C.GET_POSITION], b)
        obj[o, 2] = C.get_double(fns[C.GET_ANGLE], b)
    return pose, vel, obj


@njit(cache=_CACHE)
def physics_tick(
    fns,
    space_step,
    space,
    substep_s,
    substeps,
    controls,
    agents,
    objects,
    cmd,
    mm_s_per_unit,
    wheel_base,
    counters,
    pulses_per_tick,
):  # pragma: no cover
    """Drive, step chipmunk ``substeps`` times, and read the bodies back.

    Each robot's kinematic control body gets the velocity its wheel speeds
    give along the robot's current heading (the pivot and gear joints pull
    the robot after it); the position counters advance by this tick's pulses.
    Returns :func:`read_bodies` of the result. With ``substeps`` 0 it only
    drives: the caller steps the space through pymunk and reads it after.
    ``space_step`` is the address of chipmunk's step for this kind of space
    (cpSpaceStep, or cpHastySpaceStep for a threaded space).
    """
    for a in range(len(controls)):
        w0 = cmd[a, 0] * mm_s_per_unit[a]
        w1 = cmd[a, 1] * mm_s_per_unit[a]
        v = (w0 + w1) / 2.0
        theta = C.get_double(fns[C.GET_ANGLE], agents[a])
        c = controls[a]
        C.set_vect(fns[C.SET_VELOCITY], c, v * math.cos(theta), v * math.sin(theta))
        C.set_double(fns[C.SET_ANGULAR_VELOCITY], c, (w1 - w0) / wheel_base[a])
        counters[a, 0] += cmd[a, 0] * pulses_per_tick[a]
        counters[a, 1] += cmd[a, 1] * pulses_per_tick[a]
    for _ in range(substeps):
        C.set_double(space_step, space, substep_s)
    return read_bodies(fns, agents, objects)


# Columns of the velocity drive's per-agent table (World.tables.servo).
S_MASS = 0
S_MOMENT = 1
S_MAX_FORCE = 2
S_MAX_TORQUE = 3


@njit(cache=_CACHE)
def servo_forces(fns, agents, cmd, mm_s_per_unit, wheel_base, servo, memory, h):  # pragma: no cover
    """The velocity drive: each robot's force and torque for the next step of ``h`` s.

    The force that brings the body's velocity to what its wheel speeds give (along
    its heading now, no sideways slip) and its angular velocity to the wheels'
    turn rate within this step, limited to the motors' force and torque: the
    velocity constraint the tank pattern's pivot and gear joints solve, without
    the joints. Chipmunk applies forces when it integrates velocities, after it
    has moved the bodies and before it solves the contacts, so a wall or a
    neighbour still has the last word on the velocity and robots are not driven
    into walls (overwriting the velocity instead squeezed robots through walls
    in crowds: /work/shared/VISER_PYMUNK_NOTES.md). Chipmunk clears the forces
    after each step.

    The joints are solved together with the contacts, so a robot held back (its
    tongs against a wall, a neighbour in the way) pushes and turns with up to
    the motors' limits. A force computed before the step cannot see the contacts,
    so ``memory`` (N, 6: the velocity when the last forces were set, and those
    forces) carries what the contacts took during the last step (the change of
    velocity the servo's own force does not explain) into this one's force: held
    back, a robot's push grows to the limit within a few steps, as a stalled
    motor's does; free, that term is zero. A row whose first value is NaN has
    no history (a new, moved or removed robot): its term is zero.
    """
    for a in range(len(agents)):
        b = agents[a]
        w0 = cmd[a, 0] * mm_s_per_unit[a]
        w1 = cmd[a, 1] * mm_s_per_unit[a]
        v = (w0 + w1) / 2.0
        theta = C.get_double(fns[C.GET_ANGLE], b)
        vx, vy = C.get_vect(fns[C.GET_VELOCITY], b)
        w = C.get_double(fns[C.GET_ANGULAR_VELOCITY], b)
        m = servo[a, S_MASS] / h
        moment = servo[a, S_MOMENT] / h
        fx = (v * math.cos(theta) - vx) * m
        fy = (v * math.sin(theta) - vy) * m
        t = ((w1 - w0) / wheel_base[a] - w) * moment
        if memory[a, 0] == memory[a, 0]:  # not NaN: the contacts' share of the last step
            fx += memory[a, 3] - (vx - memory[a, 0]) * m
            fy += memory[a, 4] - (vy - memory[a, 1]) * m
            t += memory[a, 5] - (w - memory[a, 2]) * moment
        f = math.sqrt(fx * fx + fy * fy)
        top = servo[a, S_MAX_FORCE]
        if f > top:
            fx *= top / f
            fy *= top / f
        top = servo[a, S_MAX_TORQUE]
        if t > top:
            t = top
        elif t < -top:
            t = -top
        memory[a, 0] = vx
        memory[a, 1] = vy
        memory[a, 2] = w
        memory[a, 3] = fx
        memory[a, 4] = fy
        memory[a, 5] = t
        C.set_vect(fns[C.SET_FORCE], b, fx, fy)
        C.set_double(fns[C.SET_TORQUE], b, t)


@njit(cache=_CACHE)
def physics_tick_servo(
    fns,
    space_step,
    space,
    substep_s,
    substeps,
    agents,
    objects,
    cmd,
    mm_s_per_unit,
    wheel_base,
    counters,
    pulses_per_tick,
    servo,
    memory,
):  # pragma: no cover
    """:func:`physics_tick` for the velocity drive (no control bodies, no joints).

    Before each of the ``substeps`` steps, :func:`servo_forces` sets every
    robot's force and torque; the position counters advance by this tick's
    pulses. With ``substeps`` 0 it only counts: the caller sets the forces and
    steps the space through pymunk, one step at a time.
    """
    for a in range(len(agents)):
        counters[a, 0] += cmd[a, 0] * pulses_per_tick[a]
        counters[a, 1] += cmd[a, 1] * pulses_per_tick[a]
    for _ in range(substeps):
        servo_forces(fns, agents, cmd, mm_s_per_unit, wheel_base, servo, memory, substep_s)
        C.set_double(space_step, space, substep_s)
    return read_bodies(fns, agents, objects)


@njit(cache=_CACHE)
def clamp_speeds(speeds, top, cmd):  # pragma: no cover
    """cmd = speeds rounded to whole units and clamped to +-top per agent; NaN stops the wheel."""
    for a in range(cmd.shape[0]):
        for k in range(2):
            cmd[a, k] = _wheel_command(speeds[a, k], top[a])


@njit(cache=_CACHE, inline="always")
def _wheel_command(speed, top):  # pragma: no cover
    """A speed rounded to whole units and clamped to +-top; NaN stops the wheel."""
    s = np.rint(speed)
    if s != s:
        return 0.0
    if s > top:
        return top
    if s < -top:
        return -top
    return s


@njit(cache=_CACHE)
def braitenberg_speeds(proximity, weights, cruise, top, cmd):  # pragma: no cover
    """common/sim2d/wander.py's rule, compiled, straight into ``cmd`` as clamp_speeds sets it.

    cmd[a] = clamp(rint(cruise + proximity[a, :S] @ weights)), S = len(weights).
    For bench/bench_enki.py, whose Enki side runs the same rule in C++; the
    sum goes sensor by sensor, so a speed at exactly half a unit may round
    otherwise than numpy's product (the engine's own rule stays numpy's).
    """
    for a in range(cmd.shape[0]):
        for k in range(2):
            s = 0.0
            for i in range(weights.shape[0]):
                s += proximity[a, i] * weights[i, k]
            cmd[a, k] = _wheel_command(cruise + s, top[a])


# --- Gaussian noise, counter-based -----------------------------------------------------
# Every sensor's noise of a pass is a function of (the pass's key, the agent's slot,
# the sensor): a key is one 64-bit draw from the world's seeded generator per pass
# (sensing.NoiseKeys), and the kernel derives the normals itself. So the noise costs
# no numpy call and no buffer (at 10,000 robots numpy's draw of 240,000 normals a pass
# was about 4 ms, a quarter of the pass), a chunk of robots on any thread draws
# exactly what one thread would, and the same seed still gives the same readings.
#
# Words: SplitMix64 (Steele, Lea, Flood 2014), word j of sensor stream i being the
# generator's output at counter i * 2**16 + j from the key: consecutive counters are
# consecutive SplitMix64 outputs, a generator that passes BigCrush. Normals: the
# Marsaglia-Tsang ziggurat with 256 layers, as numpy's ``standard_normal`` does it
# (same tables' construction, same 52-bit layout of a word, same tail and wedges):
# one word and no transcendental call about 99 % of the time.
_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_U30, _U27, _U31 = np.uint64(30), np.uint64(27), np.uint64(31)
_U1, _U8, _U11, _U16 = np.uint64(1), np.uint64(8), np.uint64(11), np.uint64(16)
_BYTE = np.uint64(0xFF)
_MANTISSA = np.uint64(0x000FFFFFFFFFFFFF)
_ZIG_R = 3.6541528853610088  # start of the tail
_ZIG_V = 0.00492867323399  # area of each layer


def _ziggurat_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ki, wi, fi) for 256 layers, built as Marsaglia and Tsang (2000) and numpy do."""
    m1 = 2.0**52
    ki = np.zeros(256, dtype=np.int64)  # below 2**52: compared with a word's 52 bits
    wi = np.zeros(256)
    fi = np.zeros(256)
    dn = tn = _ZIG_R
    q = _ZIG_V / math.exp(-0.5 * dn * dn)
    ki[0] = int((dn / q) * m1)
    wi[0] = q / m1
    wi[255] = dn / m1
    fi[0] = 1.0
    fi[255] = math.exp(-0.5 * dn * dn)
    for i in range(254, 0, -1):
        dn = math.sqrt(-2.0 * math.log(_ZIG_V / dn + math.exp(-0.5 * dn * dn)))
        ki[i + 1] = int((dn / tn) * m1)
        tn = dn
        fi[i] = math.exp(-0.5 * dn * dn)
        wi[i] = dn / m1
    return ki, wi, fi


_ZIG_KI, _ZIG_WI, _ZIG_FI = _ziggurat_tables()


@njit(cache=_CACHE, inline="always")
def _word(key, stream, j):  # pragma: no cover
    """The ``j``-th 64-bit word of noise stream ``stream`` under ``key`` (SplitMix64)."""
    z = key + ((np.uint64(stream) << _U16) + np.uint64(j)) * _GAMMA
    z = (z ^ (z >> _U30)) * _M1
    z = (z ^ (z >> _U27)) * _M2
    return z ^ (z >> _U31)


@njit(cache=_CACHE, inline="always")
def _unit(word):  # pragma: no cover
    """A double in [0, 1) from the top 53 bits of a word."""
    return float(word >> _U11) * (1.0 / 9007199254740992.0)


@njit(cache=_CACHE, inline="always")
def normal(key, stream):  # pragma: no cover
    """One standard normal value: stream ``stream`` of ``key`` (numpy's ziggurat on its words).

    Inlined, and the sign applied without a branch: a call per value and a
    mispredicted branch on a random bit cost more than the rest (14 against 5 ns).
    """
    j = 0
    while True:
        r = _word(key, stream, j)
        j += 1
        idx = np.int64(r & _BYTE)
        r = r >> _U8
        rabs = np.int64((r >> _U1) & _MANTISSA)
        x = float(rabs) * _ZIG_WI[idx] * (1.0 - 2.0 * float(r & _U1))
        if rabs < _ZIG_KI[idx]:
            return x  # inside the layer's rectangle: about 99 % of draws
        if idx == 0:  # the tail beyond R (Marsaglia's method)
            while True:
                xx = -(1.0 / _ZIG_R) * math.log1p(-_unit(_word(key, stream, j)))
                yy = -math.log1p(-_unit(_word(key, stream, j + 1)))
                j += 2
                if yy + yy > xx * xx:
                    return -(_ZIG_R + xx) if (rabs >> 8) & 1 else _ZIG_R + xx
        f0 = _ZIG_FI[idx - 1]
        f1 = _ZIG_FI[idx]
        u = _unit(_word(key, stream, j))
        j += 1
        if (f0 - f1) * u + f1 < math.exp(-0.5 * x * x):
            return x  # under the curve in the layer's wedge


@njit(cache=_CACHE)
def normals(key, first, count):  # pragma: no cover
    """Streams ``first`` to ``first + count - 1`` of ``key``, one normal each (for tests)."""
    out = np.empty(count)
    k = np.uint64(key)
    for i in range(count):
        out[i] = normal(k, first + i)
    return out


@njit(cache=_CACHE, inline="always")
def _ray_circle(ox, oy, dx, dy, cx, cy, r):  # pragma: no cover
    f0 = ox - cx
    f1 = oy - cy
    b = f0 * dx + f1 * dy
    c = (f0 * f0 + f1 * f1) - r * r
    if c <= 0.0:
        return 0.0
    disc = b * b - c
    if disc < 0.0:
        return np.inf
    t = -b - math.sqrt(disc)
    if t >= 0.0:
        return t
    return np.inf


@njit(cache=_CACHE, inline="always")
def _ray_segment(ox, oy, dx, dy, ax, ay, bx, by):  # pragma: no cover
    ex = bx - ax
    ey = by - ay
    denom = dx * ey - dy * ex
    if abs(denom) < 1e-12:
        return np.inf
    wx = ax - ox
    wy = ay - oy
    t = (wx * ey - wy * ex) / denom
    u = (wx * dy - wy * dx) / denom
    if u >= 0.0 and u <= 1.0 and t >= 0.0:
        return t
    return np.inf


@njit(cache=_CACHE, inline="always")
def _directions(dx, dy, ray_local, g, r0, k, co, si):  # pragma: no cover
    """Rays r0 .. r0 + k - 1 of layout ``g`` turned by the robot's heading (cos co, sin si).

    cos/sin(th + angle) by the angle-addition formula, from the layout's cos/sin of
    each ray's angle: no trigonometry per ray. Returns True (the rays are ready).
    """
    for r in range(r0, r0 + k):
        ca = ray_local[g, r, 3]
        sa = ray_local[g, r, 4]
        dx[r] = co * ca - si * sa
        dy[r] = si * ca + co * sa
    return True


@njit(cache=_CACHE, inline="always")
def _point_segment_d2(px, py, seg):  # pragma: no cover
    """Squared distance from (px, py) to the segment seg = (ax, ay, bx, by)."""
    ax = seg[0]
    ay = seg[1]
    ex = seg[2] - ax
    ey = seg[3] - ay
    length2 = ex * ex + ey * ey
    u = 0.0
    if length2 > 0.0:
        u = min(max(((px - ax) * ex + (py - ay) * ey) / length2, 0.0), 1.0)
    qx = ax + u * ex - px
    qy = ay + u * ey - py
    return qx * qx + qy * qy


@njit(cache=_CACHE, inline="always")
def _cell(v, cell, n):  # pragma: no cover
    """Grid index of a coordinate (one margin cell below 0), clamped to the grid."""
    i = math.floor(v / cell) + 1
    if i < 0:
        return 0
    if i >= n:
        return n - 1
    return i


@njit(cache=_CACHE, inline="always")
def _interp(x, xp, fp, n):  # pragma: no cover
    """np.interp(x, xp[:n], fp[:n]) for one value, with numpy's exact arithmetic."""
    if x < xp[0]:
        return fp[0]
    if x > xp[n - 1]:
        return fp[n - 1]
    if x != x:  # NaN
        return x
    j = 0
    while j + 1 < n and xp[j + 1] <= x:
        j += 1
    if j == n - 1 or xp[j] == x:
        return fp[j]
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    res = slope * (x - xp[j]) + fp[j]
    if res != res:
        res = slope * (x - xp[j + 1]) + fp[j + 1]
        if res != res and fp[j] == fp[j + 1]:
            res = fp[j]
    return res


@njit(cache=_CACHE, inline="always")
def ambient_gain(vx, vy, d, ax, ay, cos_half):  # pragma: no cover
    """cos(1.5 * bearing) if |bearing| < the cone's half angle, else 0; no trigonometry.

    (vx, vy): sensor to light, ``d`` its length (> 0); (ax, ay): the sensor's unit
    axis; ``cos_half``: cos of the half angle (in [0, pi]). With c = cos(bearing)
    = (v . a) / d, |bearing| < half is c > cos(half) (cos falls on [0, pi]), and
    cos(3b/2) = cos(b) cos(b/2) - sin(b) sin(b/2) = (2c - 1) * sqrt((1 + c) / 2),
    since cos(b/2) >= 0 for |b| <= pi. The earlier formula (hypot, two atan2, a
    sin, a cos and a cos per sensor) was most of the ambient model's time.
    """
    c = (vx * ax + vy * ay) / d
    if not c > cos_half:
        return 0.0
    return (2.0 * c - 1.0) * math.sqrt(0.5 * (1.0 + c))


@njit(cache=_CACHE)
def _circle_on_segment(px, py, dx, dy, length, circ_xy, circ_r):  # pragma: no cover
    """Whether a round obstacle lies on the segment from p along (dx, dy), ``length`` long."""
    if circ_r.shape[0]:
        scale = max(length, 1e-9)
        ux = dx / scale
        uy = dy / scale
        for c in range(circ_r.shape[0]):
            t = _ray_circle(px, py, ux, uy, circ_xy[c, 0], circ_xy[c, 1], circ_r[c])
            if t < length:
                return True
    return False


@njit(cache=_CACHE)
def _occluded(px, py, qx, qy, occ_segs, circ_xy, circ_r):  # pragma: no cover
    """Whether a static obstacle lies on the segment p -> q."""
    dx = qx - px
    dy = qy - py
    for s in range(occ_segs.shape[0]):
        t = _ray_segment(
            px, py, dx, dy, occ_segs[s, 0], occ_segs[s, 1], occ_segs[s, 2], occ_segs[s, 3]
        )
        if t <= 1.0:
            return True
    return _circle_on_segment(px, py, dx, dy, math.hypot(dx, dy), circ_xy, circ_r)


@njit(cache=_CACHE)
def _occluded_grid(
    px, py, qx, qy, segs, grid_start, grid_items, grid_nx, grid_ny, cell, circ_xy, circ_r
):  # pragma: no cover
    """:func:`_occluded`, testing only the static edges binned along the segment p -> q.

    Every occluding edge of ``occ_segs`` is ``segs[4:]`` (the arena's 4 walls come
    first and never hide a light). Points are sampled along p -> q at most one cell
    apart along each axis, so every point of the segment is within half a cell of
    a sample along each axis: its cell and the sample's differ by at most one in x
    and in y. An edge is binned in every cell within one cell of its bounding box,
    so every crossing edge is binned in some sampled cell and tested, with the
    same formula: the answer is the same as testing them all. With obstacles in
    proportion to the swarm that full test was O(robots x obstacles): 10,000
    robots, 200 pillars, one wide lamp. (Samples were half a cell apart along
    the segment before: 2 to 3 times as many, for the same answer.)
    """
    dx = qx - px
    dy = qy - py
    length = math.hypot(dx, dy)
    steps = math.ceil(max(abs(dx), abs(dy)) / cell) + 1
    last = -1
    for i in range(steps + 1):
        f = min(i / steps, 1.0)
        k = _cell(px + f * dx, cell, grid_nx) * grid_ny + _cell(py + f * dy, cell, grid_ny)
        if k == last:
            continue
        last = k
        for p in range(grid_start[k], grid_start[k + 1]):
            sg = grid_items[p]
            if sg < 4:
                continue
            t = _ray_segment(px, py, dx, dy, segs[sg, 0], segs[sg, 1], segs[sg, 2], segs[sg, 3])
            if t <= 1.0:
                return True
    return _circle_on_segment(px, py, dx, dy, length, circ_xy, circ_r)


# Angular bins around a light for :func:`_shadows`: 2 pi / 1024, about 0.35 degrees.
SHADOW_BINS = 1024
# An occluder nearer a light than this shades every bin (see _shadows).
_SHADOW_NEAR_MM = 200.0


@njit(cache=_CACHE, inline="always")
def _shade_arc(row, start, span, d):  # pragma: no cover
    """row[b] = min(row[b], d) for the bins of angles start .. start + span, and one each side."""
    nb = row.shape[0]
    scale = nb / (2.0 * math.pi)
    b0 = math.floor((start + math.pi) * scale) - 1
    b1 = math.floor((start + span + math.pi) * scale) + 1
    if b1 - b0 + 1 >= nb:
        b0 = 0
        b1 = nb - 1
    for b in range(b0, b1 + 1):
        k = b % nb
        if d < row[k]:
            row[k] = d


@njit(cache=_CACHE)
def _shadows(lights, occ_segs, circ_xy, circ_r, nb):  # pragma: no cover
    """(lights, nb): per light and angular bin around it, how near the light an occluder comes.

    An occluder (static edge that can hide a light, round obstacle) is entered,
    with its distance from the light, in every bin its angular extent seen from
    the light covers, plus one bin each side; one nearer the light than
    _SHADOW_NEAR_MM in every bin. A robot at distance r from the light, in a bin
    whose value exceeds r + 1 mm, has nothing between it and the light: an
    occluder in that bin is more than 1 mm farther from the light than any point
    of the robot-to-light segment, and one in no neighbouring bin is at least a
    bin (0.0061 rad) off the segment's direction and 200 mm from the light, so
    more than 1.2 mm off the segment. Either way the walk's formula cannot meet
    it: :func:`_sense_range` skips the walk (same answer), which at 10,000 robots
    round a lamp among 200 pillars is most of them. O(lights x occluders) a pass.
    """
    out = np.full((lights.shape[0], nb), np.inf)
    for li in range(lights.shape[0]):
        lx = lights[li, 0]
        ly = lights[li, 1]
        row = out[li]
        for sg in range(occ_segs.shape[0]):
            d = math.sqrt(_point_segment_d2(lx, ly, occ_segs[sg]))
            if d < _SHADOW_NEAR_MM:
                _shade_arc(row, -math.pi, 2.0 * math.pi, d)
                continue
            ta = math.atan2(occ_segs[sg, 1] - ly, occ_segs[sg, 0] - lx)
            tb = math.atan2(occ_segs[sg, 3] - ly, occ_segs[sg, 2] - lx)
            span = tb - ta
            if span > math.pi:
                span -= 2.0 * math.pi
            elif span < -math.pi:
                span += 2.0 * math.pi
            # An edge that does not pass through the light covers the shorter arc.
            if span < 0.0:
                _shade_arc(row, tb, -span, d)
            else:
                _shade_arc(row, ta, span, d)
        for c in range(circ_r.shape[0]):
            vx = circ_xy[c, 0] - lx
            vy = circ_xy[c, 1] - ly
            centre = math.sqrt(vx * vx + vy * vy)
            d = centre - circ_r[c]
            if d < _SHADOW_NEAR_MM:
                _shade_arc(row, -math.pi, 2.0 * math.pi, d)
                continue
            half = math.asin(circ_r[c] / centre)
            _shade_arc(row, math.atan2(vy, vx) - half, 2.0 * half, d)
    return out


@njit(cache=_CACHE, inline="always")
def _in_light(shadow, dx, dy):  # pragma: no cover
    """Whether the bins say nothing lies between a robot at (dx, dy) from a light and it."""
    if shadow.shape[0] == 0:
        return False  # no bins this pass: walk
    nb = shadow.shape[0]
    b = math.floor((math.atan2(dy, dx) + math.pi) * (nb / (2.0 * math.pi))) % nb
    return math.sqrt(dx * dx + dy * dy) + 1.0 < shadow[b]


# Robots from which a pass bins the occluders round each light (_shadows): below,
# its O(lights x occluders) cost is more than the robots' walks it spares.
SHADOW_MIN_AGENTS = 256


@njit(cache=_CACHE)
def _shadow_table(robots, scene, moving):  # pragma: no cover
    """:func:`_shadows` of this pass's lights, or no bins (every robot walks).

    Only where robots walk along the grid (more than 64 occluding edges) and
    are many; otherwise (lights, 0), which :func:`_in_light` reads as "walk".
    """
    lights = moving[5]
    occ_segs, static_xy, static_r = scene[6], scene[7], scene[8]
    if occ_segs.shape[0] > 64 and robots[0].shape[0] >= SHADOW_MIN_AGENTS:
        return _shadows(lights, occ_segs, static_xy, static_r, SHADOW_BINS)
    return np.full((lights.shape[0], 0), np.inf)


@njit(cache=_CACHE)
def _circles(robots, tables, scene, moving):  # pragma: no cover
    """:func:`_circles_into` buffers of its own."""
    nc = robots[0].shape[0] + moving[1].shape[0]
    buffers = circle_buffers(nc, scene[3] * scene[4])
    _circles_into(robots, tables, scene, moving, buffers)
    return buffers


@njit(cache=_CACHE)
def circle_buffers(nc, ncell):  # pragma: no cover
    """Buffers for :func:`_circles_into`: ``nc`` circles binned in ``ncell`` cells."""
    return (
        np.empty(nc),
        np.empty(nc),
        np.empty(nc),
        np.empty(nc, dtype=np.int64),
        np.empty(nc, dtype=np.bool_),
        np.empty(ncell + 1, dtype=np.int64),
        np.empty(nc, dtype=np.int64),
        np.empty(nc, dtype=np.int64),
    )


@njit(cache=_CACHE, **_UNCOUNTED)
def _circles_into(robots, tables, scene, moving, buffers):  # pragma: no cover
    """Every circle (the agents, each owning itself, then the others), binned cell by cell.

    Fills ``buffers`` (:func:`circle_buffers`): (cx, cy, cr, cown, cobj,
    count, citems, ccell). A counting sort puts the circles in the grid's
    order: ``count`` holds the CSR offsets per cell, and cx, cy, cr, cown,
    cobj are the circles in that order, cell after cell (a circle's index
    there is its place in the sort, not its index among the circles), so a
    robot's neighbours are read from three runs of memory, not from all over
    it. ``citems`` holds each place's index among the circles; ``ccell``
    each circle's cell. Within a cell the circles keep their order (agents
    first, by slot). Serial: O(circles + cells), a small share of a pass.
    Buffers rather than new arrays, so that common/sim2d/fused.py can keep
    them from tick to tick. The runs are filled backwards, which needs no
    copy of the offsets.
    """
    pose = robots[0]
    agent_f = tables[3]
    grid_nx, grid_ny, cell = scene[3], scene[4], scene[5]
    circ_xy, circ_r, circ_owner, circ_is_object = moving[0], moving[1], moving[2], moving[3]
    cx, cy, cr, cown, cobj, count, citems, ccell = buffers
    n = pose.shape[0]
    nc_extra = circ_r.shape[0]
    nc = n + nc_extra

    ncell = grid_nx * grid_ny
    for k in range(ncell + 1):
        count[k] = 0
    for c in range(nc):
        if c < n:
            x, y = pose[c, 0], pose[c, 1]
        else:
            x, y = circ_xy[c - n, 0], circ_xy[c - n, 1]
        k = _cell(x, cell, grid_nx) * grid_ny + _cell(y, cell, grid_ny)
        ccell[c] = k
        count[k] += 1
    # count[k]: the end of cell k's run; walking the circles backwards, each
    # takes the last free place of its cell's run, so the circles of a cell come
    # out in increasing order, and count[k] ends at the run's start.
    for k in range(1, ncell):
        count[k] += count[k - 1]
    count[ncell] = nc
    for c in range(nc - 1, -1, -1):
        k = ccell[c]
        count[k] -= 1
        p = count[k]
        citems[p] = c
        if c < n:
            cx[p] = pose[c, 0]
            cy[p] = pose[c, 1]
            cr[p] = agent_f[c, F_RADIUS]
            cown[p] = c
            cobj[p] = False
        else:
            cx[p] = circ_xy[c - n, 0]
            cy[p] = circ_xy[c - n, 1]
            cr[p] = circ_r[c - n]
            cown[p] = circ_owner[c - n]
            cobj[p] = circ_is_object[c - n]


@njit(cache=_CACHE)
def scratch_buffers(tables, scene, moving, nc):  # pragma: no cover
    """One worker's scratch arrays: ray directions, nearest hits, candidates."""
    nrays = tables[0].shape[1]
    return (
        np.empty(nrays),
        np.empty(nrays),
        np.empty(tables[1]),
        np.empty(tables[8].shape[1]),
        np.empty(nc, dtype=np.int64),
        np.empty(moving[4].shape[0], dtype=np.int64),
        np.empty(scene[0].shape[0], dtype=np.int64),
    )


@njit(cache=_CACHE, **_UNCOUNTED)
def _sense_range(
    lo, hi, robots, tables, scene, moving, out, circles, shadows, scratch
):  # pragma: no cover
    """Readings of agents ``lo`` to ``hi - 1``: reads shared state, writes their rows only.

    Each agent's readings depend only on the shared inputs (poses, tables, the
    circle grid, the pass's noise key: its noise streams are its slot's), never
    on another agent's pass, so any split of the agents between workers gives
    the same bits.
    """
    pose, arm, holding = robots
    (
        ray_local,
        sensors,
        rays_per_sensor,
        agent_f,
        agent_i,
        curve_x,
        curve_y,
        curve_n,
        amb_local,
        amb_valid,
    ) = tables
    segs, grid_start, grid_items, grid_nx, grid_ny, cell, occ_segs, static_xy, static_r = scene
    edges, lights = moving[4], moving[5]
    key = np.uint64(moving[6])  # a plain int key would turn the words' arithmetic to floats
    prox_out, amb_out, presence_out = out
    cx, cy, cr, cown, cobj, count = circles[:6]
    dx, dy, per_sensor, total, cand, ecand, scand = scratch
    n_amb = amb_local.shape[1]
    n_prox = prox_out.shape[1]
    # Noise streams per agent: proximity sensor j is stream slot * stride + j,
    # ambient sensor j is slot * stride + n_prox + j.
    stride = n_prox + amb_out.shape[1]

    for a in range(lo, hi):
        x = pose[a, 0]
        y = pose[a, 1]
        th = pose[a, 2]
        co = math.cos(th)
        si = math.sin(th)
        reach = agent_f[a, F_REACH]
        g = agent_i[a, I_TYPE]

        # Candidates. Circles: in the 3x3 cells around the agent and within reach.
        ncand = 0
        seen = False
        if holding[a]:
            seen = True
        ix = _cell(x, cell, grid_nx)
        iy = _cell(y, cell, grid_ny)
        for gx in range(max(ix - 1, 0), min(ix + 2, grid_nx)):
            for gy in range(max(iy - 1, 0), min(iy + 2, grid_ny)):
                k = gx * grid_ny + gy
                # c: the circle's place in the grid's order (_circles_into)
                for c in range(count[k], count[k + 1]):
                    if cown[c] == a:
                        continue
                    ddx = cx[c] - x
                    ddy = cy[c] - y
                    lim = reach + cr[c]
                    if not (ddx * ddx + ddy * ddy < lim * lim):
                        continue
                    cand[ncand] = c
                    ncand += 1
                    # The gripper's light barrier: a movable object's centre between the fingers.
                    if (
                        not seen
                        and cobj[c]
                        and agent_f[a, F_HAS_GRIP] > 0.0
                        and arm[a] >= agent_f[a, F_ARM_LOWERED_ABOVE]
                    ):
                        lx = co * ddx + si * ddy
                        ly = -si * ddx + co * ddy
                        if (
                            lx >= agent_f[a, F_GRIP_X0]
                            and lx <= agent_f[a, F_GRIP_X1]
                            and abs(ly) <= agent_f[a, F_GRIP_HALF_WIDTH]
                        ):
                            seen = True
        presence_out[a] = 255 if seen else 0
        # Static edges binned in the agent's own cell, kept only if within reach (plus
        # 1 mm against rounding): a farther edge can only be hit beyond the response
        # curve's range, which reads as no hit, so dropping it changes no bit. In a
        # small arena most cells hold a wall or a pillar far from the robot; this
        # spares their rays and, with nothing near, all ray casting.
        k = ix * grid_ny + iy
        nseg = 0
        lim = reach + 1.0
        for p in range(grid_start[k], grid_start[k + 1]):
            sg = grid_items[p]
            ax = segs[sg, 0]
            ay = segs[sg, 1]
            ex = segs[sg, 2] - ax
            ey = segs[sg, 3] - ay
            length2 = ex * ex + ey * ey
            u = 0.0
            if length2 > 0.0:
                u = min(max(((x - ax) * ex + (y - ay) * ey) / length2, 0.0), 1.0)
            qx = ax + u * ex - x
            qy = ay + u * ey - y
            if qx * qx + qy * qy < lim * lim:
                scand[nseg] = sg
                nseg += 1
        # Edges of movable polygons (few): every one whose midpoint is within reach.
        nedge = 0
        for e in range(edges.shape[0]):
            mx = (edges[e, 0] + edges[e, 2]) / 2
            my = (edges[e, 1] + edges[e, 3]) / 2
            half = math.hypot(edges[e, 2] - edges[e, 0], edges[e, 3] - edges[e, 1]) / 2
            lim = reach + half
            if (x - mx) ** 2 + (y - my) ** 2 < lim * lim:
                ecand[nedge] = e
                nedge += 1

        # Nearest hit per sensor, sensor by sensor. A sensor's rays share its origin,
        # and a shape at least the curve's range (+1 mm against rounding) from that
        # origin can only be hit at or beyond the range, which reads as no hit (the
        # curve's last value): none of its rays is cast at it. Most of a
        # neighbour's 24 ray tests were of sensors facing away from it. A sensor's
        # ray directions are worked out only once something passes that test.
        # (The nearest hit is a minimum over the same hits whatever the order.)
        far = curve_x[g, curve_n[g] - 1] + 1.0
        for s in range(sensors):
            m = np.inf
            if ncand or nseg or nedge:  # nothing near: every ray misses, skip the casting
                r0 = s * rays_per_sensor
                lx = ray_local[g, r0, 0]
                ly = ray_local[g, r0, 1]
                sx = x + co * lx - si * ly
                sy = y + si * lx + co * ly
                ready = False  # this sensor's ray directions worked out
                for q in range(ncand):
                    c = cand[q]
                    fx = sx - cx[c]
                    fy = sy - cy[c]
                    lim = cr[c] + far
                    if fx * fx + fy * fy >= lim * lim:
                        continue
                    if not ready:
                        ready = _directions(dx, dy, ray_local, g, r0, rays_per_sensor, co, si)
                    for r in range(r0, r0 + rays_per_sensor):
                        t = _ray_circle(sx, sy, dx[r], dy[r], cx[c], cy[c], cr[c])
                        if t < m:
                            m = t
                for q in range(nseg + nedge):  # static edges, then movable polygons' edges
                    sg = segs[scand[q]] if q < nseg else edges[ecand[q - nseg]]
                    if _point_segment_d2(sx, sy, sg) >= far * far:
                        continue
                    if not ready:
                        ready = _directions(dx, dy, ray_local, g, r0, rays_per_sensor, co, si)
                    for r in range(r0, r0 + rays_per_sensor):
                        t = _ray_segment(sx, sy, dx[r], dy[r], sg[0], sg[1], sg[2], sg[3])
                        if t < m:
                            m = t
            per_sensor[s] = m
        ng = curve_n[g]
        nf = agent_f[a, F_PROX_NOISE_FRACTION]
        ncounts = agent_f[a, F_PROX_NOISE_COUNTS]
        top = agent_f[a, F_PROX_MAX]
        for j in range(n_prox):
            if j >= agent_i[a, I_PROX_SENSORS]:
                prox_out[a, j] = 0
                continue
            v = _interp(per_sensor[j], curve_x[g], curve_y[g], ng)
            # v * (1 + nf * z1) + ncounts * z2, with z1 and z2 independent standard
            # normals, is normal with mean v and this standard deviation: one draw.
            sd = math.sqrt((v * nf) ** 2 + ncounts * ncounts)
            v = v + sd * normal(key, a * stride + j)
            v = np.rint(v)
            v = min(max(v, 0.0), top)
            prox_out[a, j] = np.int32(v)

        # Ambient light: lit lights in range and not hidden by a static obstacle.
        for i in range(n_amb):
            total[i] = 0.0
        for li in range(lights.shape[0]):
            lxx = lights[li, 0]
            lyy = lights[li, 1]
            radius = lights[li, 2]
            ddx = x - lxx
            ddy = y - lyy
            if not (ddx * ddx + ddy * ddy < (radius + 40.0) ** 2):
                continue
            if _in_light(shadows[li], ddx, ddy):
                hidden = False
            elif occ_segs.shape[0] > 64:  # many obstacles: only those along the way
                hidden = _occluded_grid(
                    x,
                    y,
                    lxx,
                    lyy,
                    segs,
                    grid_start,
                    grid_items,
                    grid_nx,
                    grid_ny,
                    cell,
                    static_xy,
                    static_r,
                )
            else:
                hidden = _occluded(x, y, lxx, lyy, occ_segs, static_xy, static_r)
            if hidden:
                continue
            scale = agent_f[a, F_AMB_DROP] * lights[li, 3]
            cos_half = agent_f[a, F_AMB_COS_HALF]
            for i in range(n_amb):
                l0 = amb_local[g, i, 0]
                l1 = amb_local[g, i, 1]
                sx = x + co * l0 - si * l1
                sy = y + si * l0 + co * l1
                vx = lxx - sx
                vy = lyy - sy
                d = math.sqrt(vx * vx + vy * vy)
                closeness = 1.0 - d / radius
                if closeness <= 0.0:
                    continue  # beyond the light's radius: adds exactly nothing
                closeness = min(closeness, 1.0)
                if d > 0.0:
                    # the sensor's axis, th + its angle, by the angle-addition formula
                    ca = amb_local[g, i, 3]
                    sa = amb_local[g, i, 4]
                    contrib = ambient_gain(
                        vx, vy, d, co * ca - si * sa, si * ca + co * sa, cos_half
                    )
                else:  # the light on the sensor itself: bearing 0
                    contrib = 1.0
                contrib = contrib * closeness
                contrib *= scale * (1.0 if amb_valid[g, i] else 0.0)
                total[i] += contrib
        dark = agent_f[a, F_AMB_DARK]
        floor = agent_f[a, F_AMB_FLOOR]
        anf = agent_f[a, F_AMB_NOISE_FRACTION]
        for j in range(amb_out.shape[1]):
            if j >= agent_i[a, I_AMB_SENSORS]:
                amb_out[a, j] = 0
                continue
            v = min(max(dark - total[j], floor), dark)
            v = v * (1.0 + anf * normal(key, a * stride + n_prox + j))
            v = np.rint(v)
            v = min(max(v, 0.0), 1023.0 * 4)
            amb_out[a, j] = np.int32(v)


@njit(cache=_CACHE)
def sense(robots, tables, scene, moving, out):  # pragma: no cover
    """Every agent's proximity, ambient and presence readings, written into ``out``.

    ``robots`` (Robots), ``tables`` (SensorTables), ``scene`` (StaticScene),
    ``moving`` (MovingScene) and ``out`` (Readings) are the packs defined above,
    passed as plain tuples in that layout (see SensorSuite.read: dispatch cost).
    """
    nc = robots[0].shape[0] + moving[1].shape[0]
    buffers = circle_buffers(nc, scene[3] * scene[4])
    sense_into(
        robots, tables, scene, moving, out, buffers, scratch_buffers(tables, scene, moving, nc)
    )


@njit(cache=_CACHE)
def sense_into(robots, tables, scene, moving, out, buffers, scratch):  # pragma: no cover
    """:func:`sense` in the caller's ``buffers`` (:func:`circle_buffers`) and ``scratch``.

    For common/sim2d/fused.py, whose state keeps them from tick to tick: the
    same readings, without a pass's allocations.
    """
    _circles_into(robots, tables, scene, moving, buffers)
    shadows = _shadow_table(robots, scene, moving)
    n = robots[0].shape[0]
    _sense_range(0, n, robots, tables, scene, moving, out, buffers, shadows, scratch)


@njit(cache=_CACHE, parallel=True)
def sense_parallel(robots, tables, scene, moving, out, threads):  # pragma: no cover
    """:func:`sense` on ``threads`` threads: the agents split into chunks, same readings.

    The caller sets numba's thread count for its thread (numba.set_num_threads;
    calling it in here would keep the kernel out of the on-disk cache).

    The circle grid and the lights' shadow bins are built once (serially) and
    shared read-only; each chunk
    has its own scratch arrays and writes only its agents' rows of ``out``;
    an agent's noise depends only on the pass's key and its slot. So the result is bit-identical to
    :func:`sense` whatever the thread count (tests/unit/common/sim2d/test_swarm.py).
    """
    circles = _circles(robots, tables, scene, moving)
    shadows = _shadow_table(robots, scene, moving)
    n = robots[0].shape[0]
    nc = circles[0].shape[0]
    # A few chunks per thread: robots in crowded cells cost more, and equal
    # shares of robots are not equal shares of work.
    chunks = min(n, 8 * threads)
    for c in prange(chunks):
        lo = n * c // chunks
        hi = n * (c + 1) // chunks
        scratch = scratch_buffers(tables, scene, moving, nc)
        _sense_range(lo, hi, robots, tables, scene, moving, out, circles, shadows, scratch)


def warm_up() -> float:
    """Compile (or load from the on-disk cache) every kernel; returns the seconds it took."""
    t0 = time.perf_counter()
    none = np.zeros(0, dtype=np.uint64)  # no bodies: compiles without touching chipmunk
    physics_tick(
        C.FUNCTIONS,
        C.FUNCTIONS[C.SPACE_STEP],
        np.uint64(0),
        0.01,
        0,
        none,
        none,
        none,
        np.zeros((0, 2)),
        np.ones(0),
        np.ones(0),
        np.zeros((0, 2)),
        np.ones(0),
    )
    physics_tick_servo(
        C.FUNCTIONS,
        C.FUNCTIONS[C.SPACE_STEP],
        np.uint64(0),
        0.01,
        0,
        none,
        none,
        np.zeros((0, 2)),
        np.ones(0),
        np.ones(0),
        np.zeros((0, 2)),
        np.ones(0),
        np.ones((0, 4)),
        np.zeros((0, 6)),
    )
    servo_forces(
        C.FUNCTIONS,
        none,
        np.zeros((0, 2)),
        np.ones(0),
        np.ones(0),
        np.ones((0, 4)),
        np.zeros((0, 6)),
        0.01,
    )
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
        ),
        StaticScene(
            np.zeros((0, 4)),
            np.zeros(2, dtype=np.int64),
            np.zeros(0, dtype=np.int64),
            1,
            1,
            100.0,
            np.zeros((0, 4)),
            np.zeros((0, 2)),
            np.zeros(0),
        ),
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
    sense(*(tuple(p) for p in packs))  # plain tuples, as SensorSuite.read passes them
    sense_parallel(*(tuple(p) for p in packs), 1)
    discs.warm_up()
    # Imported here: common/sim2d/fused.py builds on this module.
    from common.sim2d import fused

    fused.warm_up()
    return time.perf_counter() - t0
