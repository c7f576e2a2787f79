"""The sensing pass's geometry: rays against circles and edges, occlusion, the lights' shadows."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from common.sim2d import jitcache  # noqa: F401 (where numba caches the kernels below)
from common.sim2d.packs import _CACHE


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
    return clamped_cell(v, cell, n, 1)


@njit(cache=_CACHE, inline="always")
def place_by_cell(cell_of, n, ncell, start, order):  # pragma: no cover
    """A counting sort's second half: items 0 to ``n - 1`` into ``order``, cell after cell.

    ``start[k]`` holds how many items are in cell k (``cell_of[i]``: item i's
    cell); afterwards it is where cell k's run starts in ``order``, and
    ``start[ncell]`` is ``n``. Walking the items backwards, each takes the last
    free place of its cell's run, so a cell's items keep their order and the
    offsets need no copy. The pair grid (pairs._pairs_into) and the sensing
    grid (sense_pass._circles_into) sort their discs so.
    """
    for k in range(1, ncell):
        start[k] += start[k - 1]
    start[ncell] = n
    for i in range(n - 1, -1, -1):
        k = cell_of[i]
        start[k] -= 1
        order[start[k]] = i


@njit(cache=_CACHE, inline="always")
def clamped_cell(v, cell, n, below):  # pragma: no cover
    """The index of the cell of size ``cell`` holding ``v`` in a grid of ``n`` cells, clamped.

    ``below``: how many margin cells the grid has below 0 (the sensing grid's
    one, rays._cell; none for the drive's pair grid).
    """
    i = math.floor(v / cell) + below
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
    if bins_shadows(robots[0].shape[0], scene):
        return _shadows(lights, occ_segs, static_xy, static_r, SHADOW_BINS)
    return np.full((lights.shape[0], 0), np.inf)


@njit(cache=_CACHE, inline="always")
def bins_shadows(n, scene):  # pragma: no cover
    """Whether a pass over ``n`` robots in ``scene`` bins the lights' shadows (_shadow_table)."""
    return scene[6].shape[0] > 64 and n >= SHADOW_MIN_AGENTS
