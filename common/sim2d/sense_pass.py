"""The sensing pass: circles binned in the grid, then every agent's readings, serial or threaded."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from common.sim2d import noise, packs, rays
from common.sim2d.jitcache import stamp_with_callees
from common.sim2d.noise import normal
from common.sim2d.packs import (
    _CACHE,
    _COUNTED,
    _UNCOUNTED,
    F_AMB_COS_HALF,
    F_AMB_DARK,
    F_AMB_DROP,
    F_AMB_FLOOR,
    F_AMB_NOISE_FRACTION,
    F_ARM_LOWERED_ABOVE,
    F_GRIP_HALF_WIDTH,
    F_GRIP_X0,
    F_GRIP_X1,
    F_HAS_GRIP,
    F_PROX_MAX,
    F_PROX_NOISE_FRACTION,
    F_RADIUS,
    F_REACH,
    I_AMB_SENSORS,
    I_PROX_SENSORS,
    I_TYPE,
)
from common.sim2d.rays import (
    _cell,
    _directions,
    _in_light,
    _interp,
    _occluded,
    _occluded_grid,
    _point_segment_d2,
    _ray_circle,
    _ray_segment,
    _shadow_table,
    ambient_gain,
    place_by_cell,
)


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
    them from tick to tick (rays.place_by_cell places them).
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
    place_by_cell(ccell, nc, ncell, count, citems)  # a cell's circles in increasing order
    for p in range(nc):
        c = citems[p]
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
    """One worker's scratch arrays: ray directions, nearest hits, candidates; no shadow bins.

    The last, (0, 0), is the shadow table of a pass that bins none (:func:`sense_unbinned`).
    """
    nrays = tables[0].shape[1]
    return (
        np.empty(nrays),
        np.empty(nrays),
        np.empty(tables[1]),
        np.empty(tables[8].shape[1]),
        np.empty(nc, dtype=np.int64),
        np.empty(moving[4].shape[0], dtype=np.int64),
        np.empty(scene[0].shape[0], dtype=np.int64),
        np.empty((0, 0)),
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
        prox_gain,
        prox_counts,
    ) = tables
    segs, grid_start, grid_items, grid_nx, grid_ny, cell, occ_segs, static_xy, static_r = scene
    edges, lights = moving[4], moving[5]
    key = np.uint64(moving[6])  # a plain int key would turn the words' arithmetic to floats
    prox_out, amb_out, presence_out = out
    cx, cy, cr, cown, cobj, count = circles[:6]
    dx, dy, per_sensor, total, cand, ecand, scand = scratch[:7]
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
            if _point_segment_d2(x, y, segs[sg]) < lim * lim:
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
        top = agent_f[a, F_PROX_MAX]
        for j in range(n_prox):
            if j >= agent_i[a, I_PROX_SENSORS]:
                prox_out[a, j] = 0
                continue
            # The sensor's gain: 1 on a datasheet robot (the same bits: v * 1.0 is v).
            v = _interp(per_sensor[j], curve_x[g], curve_y[g], ng) * prox_gain[g, j]
            ncounts = prox_counts[g, j]
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
            if shadows.shape[0] != 0 and _in_light(shadows[li], ddx, ddy):
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


@njit(cache=_CACHE, **_COUNTED)
def sense_into(robots, tables, scene, moving, out, buffers, scratch):  # pragma: no cover
    """:func:`sense` in the caller's ``buffers`` (:func:`circle_buffers`) and ``scratch``.

    For common/sim2d/fused.py, whose state keeps them from tick to tick: the
    same readings, without a pass's allocations.
    """
    _circles_into(robots, tables, scene, moving, buffers)
    shadows = _shadow_table(robots, scene, moving)
    n = robots[0].shape[0]
    _sense_range(0, n, robots, tables, scene, moving, out, buffers, shadows, scratch)


@njit(cache=_CACHE, inline="always", **_UNCOUNTED)  # in the fused tick: discs._contacts says why
def sense_unbinned(robots, tables, scene, moving, out, buffers, scratch):  # pragma: no cover
    """:func:`sense_into` for a pass that bins no shadows (not :func:`rays.bins_shadows`).

    Uncounted (it allocates nothing): common/sim2d/fused.py's tick calls it for
    every small world's pass, where counting each array of these tuples in and
    out was a tenth of the step. Same readings: with no bins every robot walks.
    """
    _circles_into(robots, tables, scene, moving, buffers)
    n = robots[0].shape[0]
    _sense_range(0, n, robots, tables, scene, moving, out, buffers, scratch[7], scratch)


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


# sense calls kernels of these files: their edits must reach its cache too.
stamp_with_callees(__name__, packs, noise, rays)
