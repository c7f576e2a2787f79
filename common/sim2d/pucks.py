"""Movable objects on the discs drive: pucks pushed through the robots' contact solver.

The discs drive (common/sim2d/discs.py) solves every contact by projection.
Its movable objects are discs of the same solver, after the robots in its
arrays (index ``n + j`` for object ``j``): a pair of an object with a robot
or another object is pushed apart by mass like two robots, and obstacles and
the border push objects out as they push robots. What differs:

- **How they move.** A robot follows its wheels; an object keeps the velocity
  it was last given (the distance the contacts moved it over the substep,
  divided by the substep, as position-based dynamics does) less floor
  friction: its speed falls by ``mu * g`` each second, the deceleration
  the joints drive's floor joints give (bodies.floor_friction), so an object
  nobody pushes comes to rest within a few substeps.
- **Shape.** Every object is a disc in the solver: a ball its own circle, a
  box or polygon the circle of its bounding radius (it never turns when
  pushed). The sensors still see a box's edges (sensing._objects).
- **The gripper.** An object whose centre is between a robot's open, lowered
  tongs does not collide with that robot (the collision exception area,
  thesis 6.8.3): :func:`drop_pairs` removes such pairs. A held object rides
  at its place in the holder's frame, set every substep; while the arm is
  down it still meets others, and whatever pushes it moves its holder (the
  two are one rigid body, :func:`carry_pushes`); raised, it meets nothing.

Everything here runs inside discs.tick_into, serially and in a fixed order:
same seed, same run.
"""

from __future__ import annotations

import math

from numba import njit

# The arrays' builders, in plain numpy (re-exported: the kernels' callers and tests use pucks.X).
from common.sim2d import jitcache  # noqa: F401 (where numba caches the kernels below)
from common.sim2d.packs import _UNCOUNTED
from common.sim2d.pucks_tables import FLOOR_G_MM_S2 as FLOOR_G_MM_S2
from common.sim2d.pucks_tables import objects_table as objects_table
from common.sim2d.pucks_tables import scene_buffers as scene_buffers

_CACHE = True


@njit(cache=_CACHE, inline="always")
def _lowered(a, arm, grip):  # pragma: no cover
    return arm[a] >= grip[a, 3]


@njit(cache=_CACHE, inline="always")
def _held_at(j, holder, offset, px, py, th):  # pragma: no cover
    """Where held object ``j`` is: its place in its holder's frame, in the world."""
    h = holder[j]
    c = math.cos(th[h])
    s = math.sin(th[h])
    lx = offset[j, 0]
    ly = offset[j, 1]
    return px[h] + c * lx - s * ly, py[h] + s * lx + c * ly, th[h] + offset[j, 2]


@njit(cache=_CACHE, **_UNCOUNTED)
def start_substep(n, objects, arm, px, py, th, v, w, sx, sy, h):  # pragma: no cover
    """Objects before the contacts: free ones slide on their velocity, held ones ride.

    The robots have already moved along their arcs. ``v``, ``w`` hold a free
    object's vx, vy; ``sx``, ``sy`` get where each object starts the substep
    (its velocity at the end is the distance from there).
    """
    holder, offset = objects[3], objects[4]
    for j in range(holder.shape[0]):
        i = n + j
        sx[j] = px[i]
        sy[j] = py[i]
        if holder[j] >= 0:
            px[i], py[i], th[i] = _held_at(j, holder, offset, px, py, th)
        else:
            px[i] += v[i] * h
            py[i] += w[i] * h


@njit(cache=_CACHE, inline="always")
def keeps(a, b, n, holder, grip, fingers, arm, px, py, th):  # pragma: no cover
    """Whether the pair of discs ``a`` < ``b`` collides (:func:`drop_pairs` says when not).

    Reads only: common/sim2d/discs_split.py applies it to each thread's pairs.
    """
    if b >= n:
        jb = b - n
        hb = holder[jb]
        if hb >= 0 and (hb == a or not _lowered(hb, arm, grip)):
            return False
        if a >= n:
            ha = holder[a - n]
            if ha >= 0 and (ha == hb or not _lowered(ha, arm, grip)):
                return False
        elif hb < 0 and fingers[a] == 0 and _lowered(a, arm, grip):
            c = math.cos(th[a])
            s = math.sin(th[a])
            dx = px[b] - px[a]
            dy = py[b] - py[a]
            lx = c * dx + s * dy
            ly = -s * dx + c * dy
            if grip[a, 0] <= lx <= grip[a, 1] and abs(ly) <= grip[a, 2]:
                return False
    return True


@njit(cache=_CACHE, **_UNCOUNTED)
def drop_pairs(pairs, n, objects, arm, px, py, th):  # pragma: no cover
    """Keep the pairs that collide (compacted in place, order kept); returns how many.

    Dropped: a held object with its holder, and with anything while its arm is
    up; a robot with an object whose centre is between its open, lowered tongs
    (the collision exception area).
    """
    holder, grip, fingers = objects[3], objects[5], objects[6]
    m = 0
    for q in range(pairs.shape[0]):
        a = pairs[q, 0]
        b = pairs[q, 1]  # a < b: an object is always b, or both are
        if keeps(a, b, n, holder, grip, fingers, arm, px, py, th):
            pairs[m, 0] = a
            pairs[m, 1] = b
            m += 1
    return m


@njit(cache=_CACHE, **_UNCOUNTED)
def end_substep(n, objects, arm, px, py, th, v, w, sx, sy, h, cap):  # pragma: no cover
    """Objects after the contacts: pushes on held ones move their holders; velocities; friction.

    A lowered, held object that the contacts moved carries its holder by the
    same distance (one rigid body), and rides back to its place on it. A free
    object's velocity is the distance it moved over the substep, at most
    ``cap`` (the fastest wheel's speed: a deep overlap resolved in one
    substep, a ball leaving the tongs' exception area inside the robot's disc,
    would otherwise throw it at metres a second), less floor friction.
    """
    decel, holder, offset = objects[2], objects[3], objects[4]
    for j in range(holder.shape[0]):
        i = n + j
        hj = holder[j]
        if hj >= 0:
            x, y, _ = _held_at(j, holder, offset, px, py, th)
            if _lowered(hj, arm, objects[5]):
                px[hj] += px[i] - x
                py[hj] += py[i] - y
            px[i], py[i], th[i] = _held_at(j, holder, offset, px, py, th)
            v[i] = (px[i] - sx[j]) / h
            w[i] = (py[i] - sy[j]) / h
            continue
        vx = (px[i] - sx[j]) / h
        vy = (py[i] - sy[j]) / h
        speed = math.sqrt(vx * vx + vy * vy)
        slower = min(speed, cap) - decel[j] * h
        if slower <= 0.0:
            v[i] = 0.0
            w[i] = 0.0
        else:
            v[i] = vx * slower / speed
            w[i] = vy * slower / speed


@njit(cache=_CACHE, **_UNCOUNTED)
def scene_into(n, objects, arm, static_xy, static_r, buffers):  # pragma: no cover
    """The sensing pass's moving scene of objects: returns (circles, edges) counts in ``buffers``.

    As sensing._objects builds it: the round objects on the floor (or held by a
    lowered arm) in order, owned by their holder or -1, then the round
    obstacles; the edges of the other objects on the floor. ``buffers``:
    pucks_tables.scene_buffers.
    """
    pose, holder, grip, is_round, verts, vstart = (
        objects[0],
        objects[3],
        objects[5],
        objects[7],
        objects[8],
        objects[9],
    )
    cxy, cr, cown, cobj, edges = buffers
    radius = objects[10]
    m = 0
    e = 0
    for j in range(holder.shape[0]):
        hj = holder[j]
        if hj >= 0 and not _lowered(hj, arm, grip):
            continue
        if is_round[j]:
            cxy[m, 0] = pose[j, 0]
            cxy[m, 1] = pose[j, 1]
            cr[m] = radius[j]
            cown[m] = hj
            cobj[m] = True
            m += 1
            continue
        c = math.cos(pose[j, 2])
        s = math.sin(pose[j, 2])
        lo = vstart[j]
        hi = vstart[j + 1]
        for p in range(lo, hi):
            q = p + 1 if p + 1 < hi else lo
            edges[e, 0] = pose[j, 0] + c * verts[p, 0] - s * verts[p, 1]
            edges[e, 1] = pose[j, 1] + s * verts[p, 0] + c * verts[p, 1]
            edges[e, 2] = pose[j, 0] + c * verts[q, 0] - s * verts[q, 1]
            edges[e, 3] = pose[j, 1] + s * verts[q, 0] + c * verts[q, 1]
            e += 1
    for c in range(static_r.shape[0]):
        cxy[m, 0] = static_xy[c, 0]
        cxy[m, 1] = static_xy[c, 1]
        cr[m] = static_r[c]
        cown[m] = -1
        cobj[m] = False
        m += 1
    return m, e
