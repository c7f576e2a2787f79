"""Compiled drive and physics steps: chipmunk's bodies driven and read, wheel commands set."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from common.sim2d import chipmunk as C
from common.sim2d import jitcache  # noqa: F401 (where numba caches the kernels below)
from common.sim2d.chipmunk_calls import get_double, get_vect, set_double, set_vect
from common.sim2d.packs import _CACHE


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
        pose[a, 0], pose[a, 1] = get_vect(fns[C.GET_POSITION], b)
        pose[a, 2] = get_double(fns[C.GET_ANGLE], b)
        vel[a, 0], vel[a, 1] = get_vect(fns[C.GET_VELOCITY], b)
        vel[a, 2] = get_double(fns[C.GET_ANGULAR_VELOCITY], b)
    for o in range(m):
        b = objects[o]
        obj[o, 0], obj[o, 1] = get_vect(fns[C.GET_POSITION], b)
        obj[o, 2] = get_double(fns[C.GET_ANGLE], b)
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
    counters,
    rates,
):  # pragma: no cover
    """Drive, step chipmunk ``substeps`` times, and read the bodies back.

    Each robot's kinematic control body gets the velocity its wheel speeds
    give along the robot's current heading (the pivot and gear joints pull
    the robot after it); the position counters advance by this tick's pulses.
    Returns :func:`read_bodies` of the result. With ``substeps`` 0 it only
    drives: the caller steps the space through pymunk and reads it after.
    ``space_step`` is the address of chipmunk's step for this kind of space
    (cpSpaceStep, or cpHastySpaceStep for a threaded space). ``rates``: each
    robot's (mm/s per unit of speed, wheel base, pulses per unit a tick), the
    discs drive's ``drive`` without its discs (discs.tick_into).
    """
    mm_s_per_unit, wheel_base, pulses_per_tick = rates
    for a in range(len(controls)):
        w0 = cmd[a, 0] * mm_s_per_unit[a]
        w1 = cmd[a, 1] * mm_s_per_unit[a]
        v = (w0 + w1) / 2.0
        theta = get_double(fns[C.GET_ANGLE], agents[a])
        c = controls[a]
        set_vect(fns[C.SET_VELOCITY], c, v * math.cos(theta), v * math.sin(theta))
        set_double(fns[C.SET_ANGULAR_VELOCITY], c, (w1 - w0) / wheel_base[a])
        counters[a, 0] += cmd[a, 0] * pulses_per_tick[a]
        counters[a, 1] += cmd[a, 1] * pulses_per_tick[a]
    for _ in range(substeps):
        set_double(space_step, space, substep_s)
    return read_bodies(fns, agents, objects)


# Columns of the velocity drive's per-agent table (World.tables.servo).
S_MASS = 0
S_MOMENT = 1
S_MAX_FORCE = 2
S_MAX_TORQUE = 3


@njit(cache=_CACHE)
def servo_forces(fns, agents, cmd, rates, servo, memory, h):  # pragma: no cover
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
    no history (a new, moved or removed robot): its term is zero. ``rates``: as
    :func:`physics_tick`'s.
    """
    mm_s_per_unit, wheel_base, _ = rates
    for a in range(len(agents)):
        b = agents[a]
        w0 = cmd[a, 0] * mm_s_per_unit[a]
        w1 = cmd[a, 1] * mm_s_per_unit[a]
        v = (w0 + w1) / 2.0
        theta = get_double(fns[C.GET_ANGLE], b)
        vx, vy = get_vect(fns[C.GET_VELOCITY], b)
        w = get_double(fns[C.GET_ANGULAR_VELOCITY], b)
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
        set_vect(fns[C.SET_FORCE], b, fx, fy)
        set_double(fns[C.SET_TORQUE], b, t)


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
    counters,
    rates,
    servo,
    memory,
):  # pragma: no cover
    """:func:`physics_tick` for the velocity drive (no control bodies, no joints).

    Before each of the ``substeps`` steps, :func:`servo_forces` sets every
    robot's force and torque; the position counters advance by this tick's
    pulses. With ``substeps`` 0 it only counts: the caller sets the forces and
    steps the space through pymunk, one step at a time.
    """
    pulses_per_tick = rates[2]
    for a in range(len(agents)):
        counters[a, 0] += cmd[a, 0] * pulses_per_tick[a]
        counters[a, 1] += cmd[a, 1] * pulses_per_tick[a]
    for _ in range(substeps):
        servo_forces(fns, agents, cmd, rates, servo, memory, substep_s)
        set_double(space_step, space, substep_s)
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
