"""The discs drive's contacts: pairs found, obstacles pushed out of, sweeps solved.

The kernels common/sim2d/discs.py's tick runs each substep, once the robots
have moved along their arcs (the model is in that module's docstring) and
the pairs that may touch are found (common/sim2d/pairs.py): the round
obstacles binned in the sensing grid (:func:`bin_circles`), the obstacle
phase (:func:`_obstacles_first`), the
walls' normals and the layers from the walls outward, and the Gauss-Seidel
sweeps (:func:`_solve_contacts`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from common.sim2d import rays
from common.sim2d.jitcache import stamp_with_callees
from common.sim2d.rays import _cell  # the sensing grid's cells: the static scene is binned in it

_CACHE = True
# Kernels that allocate nothing and return no array: no reference counting
# (common/sim2d/packs.py, _UNCOUNTED, says why and what it requires).
_UNCOUNTED: dict[str, Any] = {"_nrt": False}
_COUNTED: dict[str, Any] = {"_nrt": True}  # packs.py's _COUNTED says why it is spelled out

# Contact sweeps per substep: until no pair overlaps by more than TOLERANCE_MM,
# at most MAX_SWEEPS. A free swarm needs one or two; a crowd pressed into a
# corner by robots that keep driving needs more to carry the push through its
# rows (140 robots at speed 60 into a corner for 3 s, solved in the cells'
# order: 27.6 mm of overlap with 4 fixed sweeps, 11 with 10, 4.4 with 20).
MAX_SWEEPS = 16
TOLERANCE_MM = 0.25


@njit(cache=_CACHE, inline="always")
def _from_segment(x, y, ax, ay, bx, by):  # pragma: no cover
    """(dx, dy): from the point of segment a-b nearest (x, y) to (x, y)."""
    ex = bx - ax
    ey = by - ay
    length2 = ex * ex + ey * ey
    u = 0.0
    if length2 > 0.0:
        u = min(max(((x - ax) * ex + (y - ay) * ey) / length2, 0.0), 1.0)
    return x - (ax + u * ex), y - (ay + u * ey)


@njit(cache=_CACHE, inline="always")
def _out_of_segment(x, y, r, ax, ay, bx, by):  # pragma: no cover
    """(x, y) pushed out of segment a-b to ``r`` from it, if closer."""
    dx, dy = _from_segment(x, y, ax, ay, bx, by)
    d2 = dx * dx + dy * dy
    if d2 >= r * r:
        return x, y
    d = math.sqrt(d2)
    if d < 1e-9:
        # The centre on the edge itself: out along the edge's left normal (the
        # outside of a counter-clockwise polygon).
        ex = bx - ax
        ey = by - ay
        ln = math.sqrt(ex * ex + ey * ey)
        if ln == 0.0:
            return x + r, y
        return x - ey / ln * r, y + ex / ln * r
    k = (r - d) / d
    return x + dx * k, y + dy * k


@njit(cache=_CACHE)
def bin_circles(static_xy, static_r, grid_nx, grid_ny, grid_cell):  # pragma: no cover
    """Round obstacles binned like the sensing grid's edges: CSR (start, items).

    Each goes into every cell within one cell of its bounding box, so a robot
    finds every round obstacle it can touch in its own cell's list.
    """
    ncell = grid_nx * grid_ny
    start = np.zeros(ncell + 1, dtype=np.int64)
    for rep in range(2):
        fill = start[:-1].copy()
        items = np.empty(start[ncell], dtype=np.int64)
        for c in range(static_r.shape[0]):
            r = static_r[c]
            # Grid indices carry the sensing grid's margin cell (+1): from one
            # cell before the box's first to one after its last.
            x0 = max((math.floor((static_xy[c, 0] - r) / grid_cell)), 0)
            x1 = min((math.floor((static_xy[c, 0] + r) / grid_cell)) + 2, grid_nx - 1)
            y0 = max((math.floor((static_xy[c, 1] - r) / grid_cell)), 0)
            y1 = min((math.floor((static_xy[c, 1] + r) / grid_cell)) + 2, grid_ny - 1)
            for ix in range(x0, x1 + 1):
                for iy in range(y0, y1 + 1):
                    k = ix * grid_ny + iy
                    if rep == 0:
                        start[k + 1] += 1
                    else:
                        items[fill[k]] = c
                        fill[k] += 1
        if rep == 0:
            for k in range(ncell):
                start[k + 1] += start[k]
    return start, items


@njit(cache=_CACHE, inline="always")
def _near_obstacle(
    x, y, r, margin, width, height, scene, circ_start, circ_items
):  # pragma: no cover
    """Whether a robot at (x, y) is within ``margin`` of touching an obstacle or the border."""
    segs, grid_start, grid_items, grid_nx, grid_ny, grid_cell = scene[:6]
    static_xy, static_r = scene[7], scene[8]
    reach = r + margin
    if x < reach or y < reach or x > width - reach or y > height - reach:
        return True
    k = _cell(x, grid_cell, grid_nx) * grid_ny + _cell(y, grid_cell, grid_ny)
    for p in range(grid_start[k], grid_start[k + 1]):
        s = grid_items[p]
        dx, dy = _from_segment(x, y, segs[s, 0], segs[s, 1], segs[s, 2], segs[s, 3])
        if dx * dx + dy * dy < reach * reach:
            return True
    for p in range(circ_start[k], circ_start[k + 1]):
        c = circ_items[p]
        dx = x - static_xy[c, 0]
        dy = y - static_xy[c, 1]
        lim = reach + static_r[c]
        if dx * dx + dy * dy < lim * lim:
            return True
    return False


@njit(cache=_CACHE, inline="always")
def _out_of_obstacles(x, y, r, width, height, scene, circ_start, circ_items):  # pragma: no cover
    """(x, y) pushed out of every obstacle edge and round obstacle near it, then the border."""
    segs, grid_start, grid_items, grid_nx, grid_ny, grid_cell = scene[:6]
    static_xy, static_r = scene[7], scene[8]
    k = _cell(x, grid_cell, grid_nx) * grid_ny + _cell(y, grid_cell, grid_ny)
    for p in range(grid_start[k], grid_start[k + 1]):
        s = grid_items[p]
        x, y = _out_of_segment(x, y, r, segs[s, 0], segs[s, 1], segs[s, 2], segs[s, 3])
    for p in range(circ_start[k], circ_start[k + 1]):
        c = circ_items[p]
        dx = x - static_xy[c, 0]
        dy = y - static_xy[c, 1]
        lim = r + static_r[c]
        d2 = dx * dx + dy * dy
        if d2 < lim * lim:
            d = math.sqrt(d2)
            if d < 1e-9:
                x += lim
            else:
                x += dx * (lim - d) / d
                y += dy * (lim - d) / d
    # The border last: whatever else pushed, the robot stays in the arena.
    x = min(max(x, r), width - r)
    y = min(max(y, r), height - r)
    return x, y


# The row of layers_work that _layers_into leaves the order of the pairs in.
LAYER_ORDER = 8


@njit(cache=_CACHE)
def layers_work(pairs):  # pragma: no cover
    """The work rows of :func:`_layers_into` for up to ``pairs`` pairs."""
    return np.empty((9, 2 * pairs + 3), dtype=np.int64)


@njit(cache=_CACHE, **_UNCOUNTED)
def _layers_into(pairs, near, held, m, n, px, py, radius, layer, work):  # pragma: no cover
    """The order to solve the pairs in: from the walls outward, layer by layer.

    Layer 0: the robots an obstacle has just pushed out (``held``, of the ``m``
    in ``near``); layer k + 1: those touching one of layer k (breadth first
    over the contact pairs); robots pressed against no wall through others are
    in no layer (a large number). A pressing crowd's push then travels back
    from the wall through its rows within a sweep. Measured, 100 robots flat
    out into a corner for 2 s, worst overlap of two discs: 5.1 mm in this
    order, 8.9 mm in the cells' order. (Letting the lower layer never give way,
    shock propagation proper, made the sweeps diverge in that crowd: two robots
    ended on top of each other.)

    ``work``: :func:`layers_work` for at least these pairs; the order is left
    in its row LAYER_ORDER (the first ``len(pairs)``).
    """
    # Only the discs in pairs, numbered in the order the pairs name them (``layer``
    # holds a disc's number meanwhile): a sparse swarm's few hundred pairs, not
    # its 10,000 discs (allocating and walking per-disc arrays here was 0.1 ms of
    # a 2 ms tick at 10,000 robots and 5,000 balls).
    count = pairs.shape[0]
    free = n + 1
    disc = work[0]
    for q in range(count):
        layer[pairs[q, 0]] = -1
        layer[pairs[q, 1]] = -1
    nl = 0
    for q in range(count):
        for e in range(2):
            a = pairs[q, e]
            if layer[a] == -1:
                layer[a] = nl
                disc[nl] = a
                nl += 1
    start = work[1]
    for i in range(nl + 1):
        start[i] = 0
    for q in range(count):
        start[layer[pairs[q, 0]] + 1] += 1
        start[layer[pairs[q, 1]] + 1] += 1
    for i in range(nl):
        start[i + 1] += start[i]
    fill = work[2]
    for i in range(nl):
        fill[i] = start[i]
    adjacent = work[3]
    for q in range(count):
        i = layer[pairs[q, 0]]
        j = layer[pairs[q, 1]]
        adjacent[fill[i]] = j
        fill[i] += 1
        adjacent[fill[j]] = i
        fill[j] += 1
    depth = work[4]
    for i in range(nl):
        depth[i] = free
    queue = work[5]
    tail = 0
    for q in range(m):
        if held[q]:
            i = layer[near[q]]  # a disc in no pair has a stale number, or none
            if 0 <= i < nl and disc[i] == near[q] and depth[i] != 0:
                depth[i] = 0
                queue[tail] = i
                tail += 1
    # Breadth first: a disc's layer is its distance in touching pairs from the
    # nearest held one, whatever the order it is reached in.
    head = 0
    top = 0
    while head < tail:
        i = queue[head]
        head += 1
        a = disc[i]
        for p in range(start[i], start[i + 1]):
            j = adjacent[p]
            if depth[j] != free:
                continue
            b = disc[j]
            lim = radius[a] + radius[b] + TOLERANCE_MM
            dx = px[b] - px[a]
            dy = py[b] - py[a]
            if dx * dx + dy * dy < lim * lim:
                depth[j] = depth[i] + 1
                top = depth[j]
                queue[tail] = j
                tail += 1
    # A stable counting sort by the pair's lower layer (no layer last): the
    # order of a stable sort of the keys.
    key = work[6]
    runs = work[7]
    for k in range(top + 3):
        runs[k] = 0
    for q in range(count):
        k = min(depth[layer[pairs[q, 0]]], depth[layer[pairs[q, 1]]])
        key[q] = top + 1 if k == free else k
        runs[key[q] + 1] += 1
    for k in range(top + 2):
        runs[k + 1] += runs[k]
    order = work[LAYER_ORDER]
    for q in range(count):
        order[runs[key[q]]] = q
        runs[key[q]] += 1


@njit(cache=_CACHE, inline="always")
def sweeps(pairs, work, m, discs, walls, flags):  # pragma: no cover
    """A substep's pair sweeps, after its obstacle phase: walls' normals, layers, sweeps.

    ``m``: the obstacle phase's count of discs near an obstacle; ``discs``
    (px, py, radius, mass); ``walls`` (width, height, scene, circles);
    ``flags`` (near, is_near, pushed, moved, count, held, layer, normals), the
    drive's work arrays; ``work``: :func:`layers_work` for at least these pairs.
    """
    px, py, radius, mass = discs
    width, height, scene, circles = walls
    near, is_near, pushed, moved, count, held, layer, normals = flags
    _wall_normals(near, m, px, py, radius, width, height, scene, circles, normals, count)
    _layers_into(pairs, near, held, m, px.shape[0], px, py, radius, layer, work)
    order = work[LAYER_ORDER, : pairs.shape[0]]
    _solve_contacts(
        pairs, order, px, py, radius, mass, width, height, scene, circles, near, m, is_near,
        pushed, moved, normals, count,
    )  # fmt: skip


@njit(cache=_CACHE, **_UNCOUNTED)
def _wall_normals(
    near, m, px, py, radius, width, height, scene, circles, normals, count
):  # pragma: no cover
    """Up to two outward normals (``normals`` (N, 2, 2), ``count`` (N,)) of what each robot touches.

    Touching: an obstacle edge, a round obstacle or the border within
    TOLERANCE_MM of the disc. A pair solved later may not push a robot
    against such a normal: walls never give way, so that share goes to the
    other robot of the pair (:func:`_blocked`).
    """
    circ_start, circ_items = circles
    segs, grid_start, grid_items, grid_nx, grid_ny, grid_cell = scene[:6]
    static_xy, static_r = scene[7], scene[8]
    for q in range(m):
        a = near[q]
        x = px[a]
        y = py[a]
        reach = radius[a] + TOLERANCE_MM
        c = 0
        # The border's normals first: a corner gives two.
        if x <= reach:
            normals[a, c, 0], normals[a, c, 1] = 1.0, 0.0
            c += 1
        elif x >= width - reach:
            normals[a, c, 0], normals[a, c, 1] = -1.0, 0.0
            c += 1
        if y <= reach:
            normals[a, c, 0], normals[a, c, 1] = 0.0, 1.0
            c += 1
        elif y >= height - reach:
            normals[a, c, 0], normals[a, c, 1] = 0.0, -1.0
            c += 1
        k = _cell(x, grid_cell, grid_nx) * grid_ny + _cell(y, grid_cell, grid_ny)
        for p in range(grid_start[k], grid_start[k + 1]):
            if c == 2:
                break
            sg = grid_items[p]
            if sg < 4:  # the arena's walls: the border above
                continue
            dx, dy = _from_segment(x, y, segs[sg, 0], segs[sg, 1], segs[sg, 2], segs[sg, 3])
            d2 = dx * dx + dy * dy
            if 1e-18 < d2 < reach * reach:
                d = math.sqrt(d2)
                normals[a, c, 0], normals[a, c, 1] = dx / d, dy / d
                c += 1
        for p in range(circ_start[k], circ_start[k + 1]):
            if c == 2:
                break
            ci = circ_items[p]
            dx = x - static_xy[ci, 0]
            dy = y - static_xy[ci, 1]
            lim = reach + static_r[ci]
            d2 = dx * dx + dy * dy
            if 1e-18 < d2 < lim * lim:
                d = math.sqrt(d2)
                normals[a, c, 0], normals[a, c, 1] = dx / d, dy / d
                c += 1
        count[a] = c


@njit(cache=_CACHE, inline="always")
def _blocked(a, ux, uy, normals, count):  # pragma: no cover
    """Whether moving robot ``a`` along (ux, uy) would drive it into a wall it touches."""
    for c in range(count[a]):  # noqa: SIM110 (numba compiles no generator into any())
        if ux * normals[a, c, 0] + uy * normals[a, c, 1] < -0.1:
            return True
    return False


@njit(cache=_CACHE, **_UNCOUNTED)
def _obstacles_first(
    px, py, radius, margin, width, height, scene, circles, near, is_near, pushed, moved, count, held
):  # pragma: no cover
    """A substep's obstacles: the robots near one listed in ``near``, and pushed out of it.

    Returns how many are near; ``held[q]``: whether ``near[q]`` was pushed. Also
    clears the pair flags (``pushed``, ``moved``) and the wall normals' ``count``.
    Its own kernel, without reference counting (_UNCOUNTED): inlined in
    tick_into, the helpers counted the scene's arrays in and out for every robot.
    """
    circ_start, circ_items = circles
    m = 0
    for a in range(px.shape[0]):
        pushed[a] = False
        moved[a] = False
        count[a] = 0
        is_near[a] = _near_obstacle(
            px[a], py[a], radius[a], margin, width, height, scene, circ_start, circ_items
        )
        if is_near[a]:
            near[m] = a
            m += 1
    # The obstacles first, then what each robot now touches.
    for q in range(m):
        a = near[q]
        x, y = _out_of_obstacles(
            px[a], py[a], radius[a], width, height, scene, circ_start, circ_items
        )
        held[q] = x != px[a] or y != py[a]
        px[a] = x
        py[a] = y
    return m


@njit(cache=_CACHE, **_UNCOUNTED)
def _solve_contacts(
    pairs,
    order,
    px,
    py,
    radius,
    mass,
    width,
    height,
    scene,
    circles,
    near,
    m,
    is_near,
    pushed,
    moved,
    normals,
    count,
):  # pragma: no cover
    """The contact sweeps of a substep over ``pairs`` in ``order`` (see the module's docstring).

    Without reference counting, as :func:`_obstacles_first`.
    """
    circ_start, circ_items = circles
    for _sweep in range(MAX_SWEEPS):
        deepest = 0.0
        for i in range(order.shape[0]):
            q = order[i]
            a = pairs[q, 0]
            b = pairs[q, 1]
            dx = px[b] - px[a]
            dy = py[b] - py[a]
            lim = radius[a] + radius[b]
            d2 = dx * dx + dy * dy
            if d2 >= lim * lim:
                continue
            d = math.sqrt(d2)
            if d < 1e-9:  # on top of each other: apart along x, in slot order
                dx, dy, d = 1.0, 0.0, 1.0
                depth = lim
            else:
                depth = lim - d
            deepest = max(deepest, depth)
            # Who gives way: not a robot the push would drive into a wall it
            # touches (walls never give way); otherwise both, by mass.
            stuck_a = _blocked(a, -dx / d, -dy / d, normals, count)
            stuck_b = _blocked(b, dx / d, dy / d, normals, count)
            if stuck_a and not stuck_b:
                share_a, share_b = 0.0, depth / d
            elif stuck_b and not stuck_a:
                share_a, share_b = depth / d, 0.0
            else:
                ma = mass[a]
                mb = mass[b]
                share_a = depth * mb / (ma + mb) / d
                share_b = depth * ma / (ma + mb) / d
            px[a] -= dx * share_a
            py[a] -= dy * share_a
            px[b] += dx * share_b
            py[b] += dy * share_b
            pushed[a] = True
            pushed[b] = True
            moved[a] = True
            moved[b] = True
        for q in range(m):
            a = near[q]
            if moved[a]:  # only a robot a pair just moved can be in a wall again
                moved[a] = False
                px[a], py[a] = _out_of_obstacles(
                    px[a], py[a], radius[a], width, height, scene, circ_start, circ_items
                )
        if deepest < TOLERANCE_MM:
            break
    # A robot a crowd pushed farther than the margin may have reached an
    # obstacle it was not near: the obstacles have the last word for it too.
    for a in range(px.shape[0]):
        if pushed[a] and not is_near[a]:
            px[a], py[a] = _out_of_obstacles(
                px[a], py[a], radius[a], width, height, scene, circ_start, circ_items
            )


# These kernels inline rays.py's helpers: their edits must reach these caches.
stamp_with_callees(__name__, rays)
