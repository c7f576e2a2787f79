"""The discs drive's physics: robots as discs, moved by their wheels, contacts solved here.

Why: at 10,000 robots chipmunk's step cost about 1.5 µs a robot a tick, more
than a swarm's whole budget (docs/BENCHMARKS.md), and in a small
world its fixed cost alone matched Enki's whole step. A lab's worlds need none
of what makes a general solver expensive: every robot is a disc, obstacles
never move, and movable objects are discs too (common/sim2d/pucks.py: after
the robots in these arrays, moved by their pushes rather than by wheels).
This is every world's default drive.

The model, per substep (the world's ``substeps``, at most 10 ms each):

- each robot moves along the exact arc its wheel speeds give (differential
  drive, no slip), from where it is;
- contacts are then solved by projection, as position-based dynamics does:
  two overlapping discs are pushed apart along the line between their centres,
  in inverse proportion to their masses, except that a pair never pushes a
  robot into a wall it touches (the other one takes the whole push); a disc
  overlapping an obstacle's edge, a round obstacle or the arena's border is
  pushed straight out of it. Gauss-Seidel sweeps over the contacts found at
  the start of the substep, from the walls outward (contacts._layers_into), until
  no pair overlaps by more than TOLERANCE_MM; the last word always goes to
  the obstacles, so a robot never ends a substep inside a wall or a pillar,
  while two robots pressed together in a crowd may still overlap by a little
  (5 mm in the tests' crowds; chipmunk left up to 7 to 14: docs/BENCHMARKS.md);
- contacts do not turn a robot (frictionless discs): its heading follows its
  wheels alone;
- the position counters advance by the commanded pulses, as with the other
  drives (the wheels turn whether or not the robot gets anywhere).

Contacts are found with a uniform grid (cell: the largest pair of radii plus
the farthest a robot can move in a substep and a margin), binned with a
counting sort each substep, and the obstacles' edges come from the sensing
grid (common/sim2d/sensing.py StaticGeometry), which lists for each cell every
edge within one cell of it. Everything is serial and in a fixed order, so a
run is reproducible bit for bit; a swarm with threads runs the per-disc
loops on them (common/sim2d/discs_split.py), with the same bits.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from common.sim2d import aot, contacts, pairs, pucks, rays
from common.sim2d.contacts import _obstacles_first, bin_circles, layers_work, sweeps
from common.sim2d.jitcache import stamp_with_callees
from common.sim2d.packs import _COUNTED, _UNCOUNTED
from common.sim2d.pairs import _pairs, _pairs_into

_CACHE = True

# Added (mm) to how far a contact can push within a substep (the tick's top
# speed, twice): pairs and obstacles within that at the start of a substep are
# its candidate contacts.
SLACK_MM = 2.0


@njit(cache=_CACHE, inline="always")
def _arc(x, y, th, v, w, h):  # pragma: no cover
    """Pose after ``h`` s on the arc of forward speed ``v`` (mm/s) and turn rate ``w``."""
    if abs(w) < 1e-9:
        return x + v * h * math.cos(th), y + v * h * math.sin(th), th
    th1 = th + w * h
    k = v / w
    return x + k * (math.sin(th1) - math.sin(th)), y - k * (math.cos(th1) - math.cos(th)), th1


@njit(cache=_CACHE, inline="always")
def _wheels(
    a, pose, cmd, mm_s_per_unit, wheel_base, counters, pulses_per_tick, px, py, th, v, w
):  # pragma: no cover
    """Robot ``a`` at a tick's start: its pose, speed and turn rate, counters advanced.

    Returns its wheels' speeds (mm/s), whose fastest sets the tick's contact margin.
    """
    px[a] = pose[a, 0]
    py[a] = pose[a, 1]
    th[a] = pose[a, 2]
    w0 = cmd[a, 0] * mm_s_per_unit[a]
    w1 = cmd[a, 1] * mm_s_per_unit[a]
    v[a] = (w0 + w1) / 2.0
    w[a] = (w1 - w0) / wheel_base[a]
    counters[a, 0] += cmd[a, 0] * pulses_per_tick[a]
    counters[a, 1] += cmd[a, 1] * pulses_per_tick[a]
    return w0, w1


@njit(cache=_CACHE, inline="always")
def _objects_in(n, objects, radius, px, py, th, v, w, top_speed, top_radius):  # pragma: no cover
    """The objects into the discs' slots after the ``n`` robots; returns the top speed and radius.

    ``top_speed`` and ``top_radius``: the robots'; the objects' raise them.

    An object's v, w are its vx, vy (pucks.py); a held one rides as fast as its holder.
    """
    opose, ovel = objects[0], objects[1]
    for j in range(opose.shape[0]):
        i = n + j
        px[i] = opose[j, 0]
        py[i] = opose[j, 1]
        th[i] = opose[j, 2]
        v[i] = ovel[j, 0]
        w[i] = ovel[j, 1]
        top_speed = max(top_speed, math.sqrt(v[i] * v[i] + w[i] * w[i]))
        top_radius = max(top_radius, radius[i])
    return top_speed, top_radius


@njit(cache=_CACHE, inline="always")
def _reach(top_speed, top_radius, substep_s):  # pragma: no cover
    """(margin, cell) of a tick's contacts for its fastest disc and its largest one.

    How far a contact can push a robot in one substep: two robots meeting head
    on at top speed overlap by up to both their moves. Pairs and obstacles this
    close at the start of a substep are its candidate contacts. Robots found in
    non-neighbouring cells are at least a cell apart, farther than the largest
    pair plus the margin: they cannot touch within the substep. (A held object
    is a gripper's length ahead of a robot: both top radii cover it, as its
    holder's own disc is within the margin of it.)
    """
    margin = 2.0 * top_speed * substep_s + SLACK_MM
    return margin, 2.0 * top_radius + margin + 1.0


@njit(cache=_CACHE, inline="always")
def _poses_out(pose, h, px, py, th, v, w, out, vel, objects):  # pragma: no cover
    """A tick's end: the robots' poses into ``out``, their mean velocities over ``h`` s into
    ``vel``; the objects' poses and velocities into their table."""
    for a in range(pose.shape[0]):
        # The velocity before the pose: ``out`` may be ``pose`` itself.
        vel[a, 0] = (px[a] - pose[a, 0]) / h
        vel[a, 1] = (py[a] - pose[a, 1]) / h
        vel[a, 2] = w[a]
        out[a, 0] = px[a]
        out[a, 1] = py[a]
        out[a, 2] = th[a]
    opose, ovel = objects[0], objects[1]
    n = pose.shape[0]
    for j in range(opose.shape[0]):
        i = n + j
        opose[j, 0] = px[i]
        opose[j, 1] = py[i]
        opose[j, 2] = th[i]
        ovel[j, 0] = v[i]
        ovel[j, 1] = w[i]
        ovel[j, 2] = 0.0


@njit(cache=_CACHE)
def tick(robots, drive, scene, circles, geometry, substeps, objects):  # pragma: no cover
    """One tick of the discs drive: returns (pose, vel) of every robot, new arrays.

    See :func:`tick_into`, which this calls with fresh output arrays (the
    objects move in place).
    """
    n = robots[0].shape[0]
    width, height, _ = geometry
    out = np.empty((n, 3))
    vel = np.empty((n, 3))
    buffers = drive_buffers(n, objects[0].shape[0], width, height, drive[3])
    tick_into(robots, drive, scene, circles, geometry, substeps, objects, (out, vel), buffers)
    return out, vel


@njit(cache=_CACHE)
def drive_buffers(robots, k, width, height, radius):  # pragma: no cover
    """The work arrays of :func:`tick_into` for ``robots`` robots and ``k`` objects in this arena.

    ``radius``: the discs' radii, the robots' then the objects'.

    Kept by common/sim2d/fused.py from tick to tick: without a tick's
    twenty-odd allocations the drive took about 8 % less at 10 robots
    (docs/history/). The pair grid's cell offsets
    are sized for its smallest cell (robots standing still); the pairs' table
    for four pairs a robot, a crowd's (it grows if a tick needs more).
    """
    n = robots + k  # discs: the robots, then the objects (common/sim2d/pucks.py)
    smallest = 2.0 * (np.max(radius) if n else 0.0) + SLACK_MM + 1.0
    ncell = (math.floor(width / smallest) + 1) * (math.floor(height / smallest) + 1)
    return (
        np.empty(n),  # px, py, th: the poses being moved
        np.empty(n),
        np.empty(n),
        np.empty(n),  # v, w: forward speed and turn rate
        np.empty(n),
        np.empty(n, dtype=np.int64),  # near: the robots near an obstacle
        np.empty(n, dtype=np.bool_),  # is_near
        np.empty(n, dtype=np.bool_),  # pushed: by a pair, this substep
        np.empty(n, dtype=np.bool_),  # moved: by a pair, this sweep
        np.empty(n, dtype=np.bool_),  # held: pushed out of an obstacle
        np.empty(n, dtype=np.int64),  # layer (contacts._layers_into)
        np.empty((n, 2, 2)),  # normals, count (_wall_normals)
        np.zeros(n, dtype=np.int64),
        np.empty(n, dtype=np.int64),  # _pairs: home, slot, sk, sx, sy, sr, start, out
        np.empty(n, dtype=np.int64),
        np.empty(n, dtype=np.int64),
        np.empty(n),
        np.empty(n),
        np.empty(n),
        np.empty(ncell + 1, dtype=np.int64),
        np.empty((max(16, 4 * n), 2), dtype=np.int64),
        np.empty(k),  # sx, sy: where each object started the substep (pucks.py)
        np.empty(k),
        layers_work(max(16, 4 * n)),  # contacts._layers_into, for as many pairs as out holds
    )


# Inlined where called (numba's IR): a call passes every array of these tuples
# as separate arguments, about 0.1 us a call at 10 robots.
@njit(cache=_CACHE, inline="always", **_UNCOUNTED)
def _contacts(
    pairs, work, n, k, objects, arm, discs, limits, scene, circles, flags
):  # pragma: no cover
    """A substep's contacts once its ``pairs`` are found: :func:`tick_into`'s, in its arrays.

    Held objects' pairs dropped, the obstacles first, then the pairs' sweeps in
    layers (``work``: contacts.layers_work for at least these pairs).
    """
    px, py, th, radius, mass = discs
    margin, width, height = limits
    near, is_near, pushed, moved, count, held = flags[:6]
    if k:
        pairs = pairs[: pucks.drop_pairs(pairs, n, objects, arm, px, py, th)]
    m = _obstacles_first(
        px, py, radius, margin, width, height, scene, circles, near, is_near, pushed, moved,
        count, held,
    )  # fmt: skip
    if pairs.shape[0] != 0:
        # (No two discs close: the sweeps would move nobody, and the walls'
        # normals and the layers serve only them: most substeps of a sparse
        # world, about 0.5 us of a 10-robot tick.)
        sweeps(pairs, work, m, (px, py, radius, mass), (width, height, scene, circles), flags)


@njit(cache=_CACHE, **_COUNTED)
def _contacts_grown(
    n, k, objects, arm, discs, limits, cell, scene, circles, pair_buffers, flags
):  # pragma: no cover
    """:func:`_contacts` with its pairs and layers in new arrays: more than the buffers hold."""
    px, py, _, radius, _ = discs
    margin, width, height = limits
    pairs = _pairs(px, py, radius, width, height, cell, margin, pair_buffers)
    work = layers_work(pairs.shape[0])
    _contacts(pairs, work, n, k, objects, arm, discs, limits, scene, circles, flags)


@njit(cache=_CACHE, inline="always", **_UNCOUNTED)  # inlined as _contacts is
def tick_into(
    robots, drive, scene, circles, geometry, substeps, objects, into, buffers
):  # pragma: no cover
    """One tick of the discs drive: every robot's new pose and velocity into ``into``.

    The arguments are grouped as common/sim2d/fused.py's TickState holds them:

    - ``robots``: (pose, cmd, counters, arm). ``pose`` (N, 3) is where the
      robots are (read only, unless it is ``into``'s pose: fused.py moves its
      own buffer in place); ``cmd`` (N, 2) their wheel speeds in the type's
      units; ``counters`` advance in place; ``arm`` is World.arm.
    - ``drive``: (mm_s_per_unit, wheel_base, pulses_per_tick) per robot, then
      (radius, mass) per disc (the N robots, then the objects); the counters
      advance by ``pulses_per_tick`` per unit of speed.
    - ``scene``: the sensing grid's static scene as a plain tuple
      (packs.StaticScene's layout); ``circles`` its round obstacles binned by
      :func:`bin_circles`.
    - ``geometry``: (width, height, substep s) of the arena and the tick, in
      ``substeps`` substeps.
    - ``objects``: the movable objects (pucks.objects_table's layout), moved in place.
    - ``into``: (pose, vel): the tick's poses and its mean velocities, x, y
      (mm/s) and turn rate (rad/s).
    - ``buffers``: the work arrays, :func:`drive_buffers` for these discs and this arena.
    """
    pose, cmd, counters, arm = robots
    mm_s_per_unit, wheel_base, pulses_per_tick, radius, mass = drive
    width, height, substep_s = geometry
    out, vel = into
    n = pose.shape[0]
    k = objects[0].shape[0]
    px, py, th, v, w, near, is_near, pushed, moved, held, layer, normals, count = buffers[:13]
    sx, sy = buffers[21], buffers[22]
    top_speed = 0.0
    top_radius = 0.0
    for a in range(n):
        w0, w1 = _wheels(
            a, pose, cmd, mm_s_per_unit, wheel_base, counters, pulses_per_tick, px, py, th, v, w
        )
        top_speed = max(top_speed, max(abs(w0), abs(w1)))
        top_radius = max(top_radius, radius[a])
    robot_speed = top_speed  # the objects' speed limit (pucks.end_substep)
    top_speed, top_radius = _objects_in(n, objects, radius, px, py, th, v, w, top_speed, top_radius)
    margin, cell = _reach(top_speed, top_radius, substep_s)
    pair_buffers = buffers[13:21]
    discs = (px, py, th, radius, mass)  # what _contacts takes, grouped
    limits = (margin, width, height)
    flags = (near, is_near, pushed, moved, count, held, layer, normals)
    for _ in range(substeps):
        for a in range(n):
            px[a], py[a], th[a] = _arc(px[a], py[a], th[a], v[a], w[a], substep_s)
        if k:
            pucks.start_substep(n, objects, arm, px, py, th, v, w, sx, sy, substep_s)
        pairs = pair_buffers[7]
        found = _pairs_into(px, py, radius, width, height, cell, margin, pair_buffers)
        if 0 <= found <= pairs.shape[0]:
            _contacts(
                pairs[:found], buffers[23], n, k, objects, arm, discs, limits, scene, circles, flags
            )
        else:  # more pairs than the buffers hold (a crowd): in arrays made for them
            _contacts_grown(
                n, k, objects, arm, discs, limits, cell, scene, circles, pair_buffers, flags
            )
        if k:
            pucks.end_substep(n, objects, arm, px, py, th, v, w, sx, sy, substep_s, robot_speed)
    _poses_out(pose, substep_s * substeps, px, py, th, v, w, out, vel, objects)


def warm_up() -> None:
    """Compile (or load from the on-disk cache) this drive's kernels: kernels.warm_up calls it."""
    one = np.ones(1)
    robots = (np.zeros((1, 3)), np.zeros((1, 2)), np.zeros((1, 2)), np.zeros(1))
    circles = bin_circles(*aot.circles_sample())
    objects = pucks.objects_table(0, 1)
    tick(
        robots,
        (one, one, one, one, one),
        aot.scene_sample(),
        circles,
        (100.0, 100.0, 0.01),
        1,
        objects,
    )


# tick_into calls the contact kernels: their edits must reach its cache too.
stamp_with_callees(__name__, contacts, pairs, pucks, rays)
