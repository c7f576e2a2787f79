"""The discs drive's tick with its per-disc work split over numba's threads: the same bits.

Why: at 10,000 robots the drive was the serial part of a tick whose sensing
pass already ran on two threads (docs/BENCHMARKS.md): about 2 ms a
tick with 5,000 balls, most of it work done disc by disc. That work is shared
here between the threads; what has an order stays on the calling thread.

On the threads (chunks of discs, each thread writing only its discs' slots):

- each robot's wheels (its speeds, its counters: the first substep) and its
  arc, its cell in the pair grid, and the obstacle phase's test and push out
  (:func:`_robots_range`). The push is kept aside (``qx``, ``qy``) until the
  pairs are found, as the serial tick finds them before it pushes;
- the objects' cells and obstacle phase, after their substep's start
  (pucks.start_substep, serial: a held object rides its holder's new pose);
- the counting sort of the discs by cell (:func:`_sort_range`): each thread
  places the discs of its share of the cells;
- the pair scan (:func:`_scan_range`): each chunk of the sorted discs scans
  its neighbours into its own list, with the gripper's exception
  (pucks.keeps) applied as it goes; the lists are joined in chunk order,
  which is the serial scan's order.

On the calling thread: the fastest wheel and largest disc (the grid's cell),
the joining of the pairs and of the obstacle phase's list (in slot order, as
the serial tick builds it), the walls' normals, the layers, the Gauss-Seidel
sweeps (about 5 % of the serial tick, and an order), the objects' substep
ends and the poses written out: discs.tick_into's calls, unchanged.

Every disc's arithmetic is the serial tick's, on the same inputs, in the same
order: the trajectories, contacts and readings are the same bits whatever the
thread count (tests/unit/common/sim2d/test_discs_split.py).

Not overlapped with the sensing pass instead: a pass reads the poses this
tick's drive gives, and the next tick's drive reads the speeds the
controllers set from that pass's readings; neither can start before the
other ends.

Python calls this directly (World._step_fused, after or instead of the fused
call): a cached function calling a parallel one loaded broken code in the
next process (common/sim2d/fused.py, tick).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, prange

from common.sim2d import aot, contacts, discs, packs, pairs, pucks, rays
from common.sim2d.contacts import (
    _UNCOUNTED,
    _near_obstacle,
    _out_of_obstacles,
    layers_work,
    sweeps,
)
from common.sim2d.discs import _arc, _objects_in, _poses_out, _reach, _wheels
from common.sim2d.jitcache import stamp_with_callees
from common.sim2d.pairs import _cell, _neighbours, _pairs

_CACHE = True

# Discs (robots and objects) from which a world with threads splits its drive.
# Each split substep hands work to the threads three times (four with
# objects); a handoff to numba's sleeping workers (OMP_WAIT_POLICY=PASSIVE,
# packs.py) costs tens of microseconds, and a disc's share of the split work
# about 0.1 us: below a few thousand discs the serial tick is as fast
# (docs/history/).
SPLIT_MIN_DISCS = 4000

# Chunks of discs per parallel loop: a few per thread, handed out one at a
# time (sensing.sense_on_threads sets the chunk size), so that a worker the
# shared machine descheduled leaves its share to the others. Fixed for the
# process, so that the work arrays are sized once.
CHUNKS = 8 * packs.MAX_THREADS

# Pairs a chunk's list holds per disc of the chunk before the tick falls back
# to the serial scan (a crowd pressed together: the same pairs, found serially).
PAIRS_PER_DISC = 8


def split_buffers(discs_: int) -> tuple[np.ndarray, ...]:
    """:func:`tick_into_split`'s work arrays beside discs.drive_buffers, for ``discs_`` discs."""
    cap = PAIRS_PER_DISC * (discs_ // CHUNKS + 1)
    return (
        np.empty(discs_),  # qx, qy: where the obstacle phase pushes a near disc
        np.empty(discs_),
        np.empty((CHUNKS, cap, 2), dtype=np.int64),  # each chunk's pairs
        np.zeros(CHUNKS, dtype=np.int64),  # and how many
        # Each chunk's discs by the share of the cells their cell is in, in slot
        # order, in the chunk's own slots of the row (_robots_range, _sort_range),
        np.empty((packs.MAX_THREADS, discs_), dtype=np.int64),
        # and how many: the robots' chunks, then the objects'.
        np.zeros((2 * CHUNKS, packs.MAX_THREADS), dtype=np.int64),
        np.zeros(packs.MAX_THREADS + 1, dtype=np.int64),  # each share's first cell
    )


@njit(cache=_CACHE, **_UNCOUNTED)
def _robots_range(
    lo, hi, first, robots, drive, buffers, grid, scene, circles, split, seg, ranges
):  # pragma: no cover
    """Robots ``lo`` to ``hi - 1``: wheels (``first`` substep), arc, pair cell, obstacle test.

    ``robots``, ``drive``: discs.tick_into's. ``grid``: (substep s, margin,
    width, height, cell, gx, gy). As
    discs.tick_into and pairs._pairs and _obstacles_first do it, robot by
    robot, except that a near robot's push out is written to ``qx``, ``qy``
    (``split``'s first two), and each robot is listed under the share of the
    cells its cell is in (``seg``: this chunk's row of counts; ``ranges``
    shares).
    """
    h = grid[0]
    pose, cmd, counters, _ = robots
    mm_s_per_unit, wheel_base, pulses_per_tick, radius, _ = drive
    px, py, th, v, w = buffers[0], buffers[1], buffers[2], buffers[3], buffers[4]
    for r in range(ranges):
        split[5][seg, r] = 0
    for a in range(lo, hi):
        if first:
            _wheels(
                a, pose, cmd, mm_s_per_unit, wheel_base, counters, pulses_per_tick, px, py, th, v, w
            )
        px[a], py[a], th[a] = _arc(px[a], py[a], th[a], v[a], w[a], h)
        _disc_phase(a, lo, seg, ranges, radius, buffers, grid, scene, circles, split)


@njit(cache=_CACHE, inline="always")
def _disc_phase(
    a, lo, seg, ranges, radius, buffers, grid, scene, circles, split
):  # pragma: no cover
    """Disc ``a``'s pair cell and share, flags cleared, obstacle test, push out (``qx``, ``qy``)."""
    _, margin, width, height, cell, gx, gy = grid
    circ_start, circ_items = circles
    qx, qy, rlist, rcount, bounds = split[0], split[1], split[4], split[5], split[6]
    px, py = buffers[0], buffers[1]
    x = px[a]
    y = py[a]
    kc = _cell(x, cell, gx) * gy + _cell(y, cell, gy)
    buffers[13][a] = kc  # home
    # The share of the cells kc is in, without a division (a tenth of this
    # loop's time) or a branch (which share a disc is in is a coin toss).
    r = 0
    for b in range(1, ranges):
        r += int(kc >= bounds[b])
    rlist[r, lo + rcount[seg, r]] = a
    rcount[seg, r] += 1
    buffers[7][a] = False  # pushed
    buffers[8][a] = False  # moved
    buffers[12][a] = 0  # the walls' normals' count
    near = _near_obstacle(x, y, radius[a], margin, width, height, scene, circ_start, circ_items)
    buffers[6][a] = near  # is_near
    if near:
        qx[a], qy[a] = _out_of_obstacles(
            x, y, radius[a], width, height, scene, circ_start, circ_items
        )


@njit(cache=_CACHE, **_UNCOUNTED)
def _objects_range(
    lo, hi, radius, buffers, grid, scene, circles, split, seg, ranges
):  # pragma: no cover
    """Discs ``lo`` to ``hi - 1`` (objects, after their substep's start): :func:`_disc_phase`."""
    for r in range(ranges):
        split[5][seg, r] = 0
    for a in range(lo, hi):
        _disc_phase(a, lo, seg, ranges, radius, buffers, grid, scene, circles, split)


@njit(cache=_CACHE, inline="always")
def _segment(s, n, k, chunks):  # pragma: no cover
    """The first slot of chunk row ``s``: the robots' chunks, then the objects'."""
    if s < chunks:
        return n * s // chunks
    return n + k * (s - chunks) // chunks


@njit(cache=_CACHE, **_UNCOUNTED)
def _sort_range(r, ranges, n, k, ncell, radius, buffers, start, split):  # pragma: no cover
    """pairs._pairs' counting sort for the ``r``-th of ``ranges`` shares of the cells.

    Its discs are the chunks' lists for this share (in slot order); those of
    the shares below are counted, not placed, so each share's runs start where
    the serial sort starts them: ``start``, ``slot`` and the sorted copies
    come out the same whatever the shares.
    """
    px, py, home, slot, sk = buffers[0], buffers[1], buffers[13], buffers[14], buffers[15]
    sx, sy, sr = buffers[16], buffers[17], buffers[18]
    rlist, rcount = split[4], split[5]
    c0 = ncell * r // ranges
    c1 = ncell * (r + 1) // ranges
    rows = rcount.shape[0]
    chunks = rows // 2
    for kc in range(c0, c1):
        start[kc] = 0
    end = 0
    for s in range(rows):
        for below in range(r):
            end += rcount[s, below]
        lo = _segment(s, n, k, chunks)
        for j in range(rcount[s, r]):
            start[home[rlist[r, lo + j]]] += 1
    for kc in range(c0, c1):
        end += start[kc]
        start[kc] = end
    for s in range(rows - 1, -1, -1):
        lo = _segment(s, n, k, chunks)
        for j in range(rcount[s, r] - 1, -1, -1):
            a = rlist[r, lo + j]
            kc = home[a]
            start[kc] -= 1
            p = start[kc]
            slot[p] = a
            sk[p] = kc
            sx[p] = px[a]
            sy[p] = py[a]
            sr[p] = radius[a]


@njit(cache=_CACHE, **_UNCOUNTED)
def _scan_range(
    p0, p1, start, buffers, gx, gy, margin, out, n, k, objects, arm
):  # pragma: no cover
    """pairs._pairs' scan of sorted discs ``p0`` to ``p1 - 1``, into ``out``: returns how many.

    The pairs pucks.drop_pairs would drop are left out here (with ``k``
    objects). Past ``out``'s length it counts without writing: the caller
    then scans serially.
    """
    holder, grip, fingers = objects[3], objects[5], objects[6]
    px, py, th, slot, sk = buffers[0], buffers[1], buffers[2], buffers[14], buffers[15]
    sx, sy, sr = buffers[16], buffers[17], buffers[18]
    cap = out.shape[0]
    m = 0
    for p in range(p0, p1):
        kc = sk[p]
        ix = kc // gy
        iy = kc - ix * gy
        x = sx[p]
        y = sy[p]
        r = sr[p] + margin
        for nb in range(5):
            lo, hi = _neighbours(nb, p, kc, ix, iy, gx, gy, start)
            for q in range(lo, hi):
                dx = sx[q] - x
                dy = sy[q] - y
                lim = r + sr[q]
                if dx * dx + dy * dy < lim * lim:
                    a = slot[p]
                    b = slot[q]
                    lo_ab = min(a, b)
                    hi_ab = max(a, b)
                    if k and not pucks.keeps(
                        lo_ab, hi_ab, n, holder, grip, fingers, arm, px, py, th
                    ):
                        continue
                    if m < cap:
                        out[m, 0] = lo_ab
                        out[m, 1] = hi_ab
                    m += 1
    return m


@njit(cache=_CACHE, parallel=True)
def tick_into_split(
    robots, drive, scene, circles, geometry, substeps, objects, into, buffers, split, threads
):  # pragma: no cover
    """discs.tick_into with its per-disc loops on numba's threads (the module's docstring).

    The same arguments, and ``split``: :func:`split_buffers` for these discs.
    The caller sets numba's thread count to ``threads`` (:func:`on_threads`;
    numba.get_num_threads in here would keep the kernel out of the cache).
    """
    pose, cmd, _, arm = robots
    mm_s_per_unit, _, _, radius, mass = drive
    width, height, substep_s = geometry
    out, vel = into
    n = pose.shape[0]
    k = objects[0].shape[0]
    nd = n + k
    px, py, th, v, w, near, is_near, pushed, moved, held, layer, normals, count = buffers[:13]
    start, pair_out = buffers[19], buffers[20]  # the rest of _pairs' buffers: the kernels
    start_x, start_y = buffers[21], buffers[22]  # the objects' (discs.tick_into's sx, sy)
    qx, qy, chunk_pairs, chunk_count, _, rcount, bounds = split
    chunks = chunk_count.shape[0]
    if not k:  # no objects' chunks this tick: their rows list nothing
        for row in range(chunks, 2 * chunks):
            for share in range(rcount.shape[1]):
                rcount[row, share] = 0
    # The fastest wheel and the largest disc, as discs.tick_into finds them
    # (a maximum is the same whatever the order); the objects' start here.
    top_speed = 0.0
    top_radius = 0.0
    for a in range(n):
        w0 = cmd[a, 0] * mm_s_per_unit[a]
        w1 = cmd[a, 1] * mm_s_per_unit[a]
        top_speed = max(top_speed, max(abs(w0), abs(w1)))
        top_radius = max(top_radius, radius[a])
    robot_speed = top_speed
    top_speed, top_radius = _objects_in(n, objects, radius, px, py, th, v, w, top_speed, top_radius)
    margin, cell = _reach(top_speed, top_radius, substep_s)
    gx = (math.floor(width / cell)) + 1
    gy = (math.floor(height / cell)) + 1
    ncell = gx * gy
    if start.shape[0] < ncell + 1:
        start = np.empty(ncell + 1, dtype=np.int64)
    grid = (substep_s, margin, width, height, cell, gx, gy)
    # Shares of the grid's cells for the sort, one a thread: each disc is
    # listed under its share as its cell is found (_disc_phase).
    ranges = threads
    for b in range(ranges + 1):
        bounds[b] = ncell * b // ranges  # as _sort_range splits them
    for s in range(substeps):
        first = s == 0
        for c in prange(chunks):
            lo, hi = n * c // chunks, n * (c + 1) // chunks
            _robots_range(
                lo, hi, first, robots, drive, buffers, grid, scene, circles, split, c, ranges
            )
        if k:
            pucks.start_substep(n, objects, arm, px, py, th, v, w, start_x, start_y, substep_s)
            for c in prange(chunks):
                _objects_range(
                    n + k * c // chunks,
                    n + k * (c + 1) // chunks,
                    radius,
                    buffers,
                    grid,
                    scene,
                    circles,
                    split,
                    chunks + c,
                    ranges,
                )
        # pairs._pairs' counting sort, on the cells found above: each thread
        # sorts the discs of its share of the cells (_sort_range).
        for r in prange(ranges):
            _sort_range(r, ranges, n, k, ncell, radius, buffers, start, split)
        start[ncell] = nd
        for c in prange(chunks):
            chunk_count[c] = _scan_range(
                nd * c // chunks,
                nd * (c + 1) // chunks,
                start,
                buffers,
                gx,
                gy,
                margin,
                chunk_pairs[c],
                n,
                k,
                objects,
                arm,
            )
        total = 0
        overflow = False
        for c in range(chunks):
            total += chunk_count[c]
            overflow = overflow or chunk_count[c] > chunk_pairs.shape[1]
        if overflow:
            # A crowd: the serial scan (the same pairs), then the same drops.
            pairs = _pairs(px, py, radius, width, height, cell, margin, buffers[13:21])
            if k:
                pairs = pairs[: pucks.drop_pairs(pairs, n, objects, arm, px, py, th)]
        else:
            pairs = pair_out if pair_out.shape[0] >= total else np.empty((total, 2), np.int64)
            m = 0
            for c in range(chunks):
                for q in range(chunk_count[c]):
                    pairs[m, 0] = chunk_pairs[c, q, 0]
                    pairs[m, 1] = chunk_pairs[c, q, 1]
                    m += 1
            pairs = pairs[:total]
        # The obstacle phase's list in slot order, and its pushes (_obstacles_first).
        m = 0
        for a in range(nd):
            if is_near[a]:
                near[m] = a
                held[m] = qx[a] != px[a] or qy[a] != py[a]
                px[a] = qx[a]
                py[a] = qy[a]
                m += 1
        if pairs.shape[0] != 0:
            flags = (near, is_near, pushed, moved, count, held, layer, normals)
            work = layers_work(pairs.shape[0])
            sweeps(pairs, work, m, (px, py, radius, mass), (width, height, scene, circles), flags)
        if k:
            pucks.end_substep(
                n, objects, arm, px, py, th, v, w, start_x, start_y, substep_s, robot_speed
            )
    _poses_out(pose, substep_s * substeps, px, py, th, v, w, out, vel, objects)


def on_threads(args: tuple[object, ...], threads: int) -> None:
    """:func:`tick_into_split` on ``threads`` threads, set as sensing.sense_on_threads sets them."""
    numba.set_num_threads(threads)
    chunk = numba.set_parallel_chunksize(1)
    try:
        tick_into_split(*args, threads)  # type: ignore[call-arg]  # numba types it, not mypy
    finally:
        numba.set_parallel_chunksize(chunk)


def tick(
    robots: tuple[np.ndarray, ...],
    drive: tuple[np.ndarray, ...],
    scene: tuple[object, ...],
    circles: tuple[np.ndarray, np.ndarray],
    geometry: tuple[float, float, float],
    substeps: int,
    objects: tuple[np.ndarray, ...],
    threads: int,
    split: tuple[np.ndarray, ...],
) -> tuple[np.ndarray, np.ndarray]:
    """discs.tick on ``threads`` threads: (pose, vel), new arrays; ``split``: the caller's buffers.

    Kept by the caller: allocated each tick, their 2 MB (10,000 robots and
    5,000 balls) cost a seventh of the tick's CPU.
    """
    n = robots[0].shape[0]
    width, height, _ = geometry
    into = (np.empty((n, 3)), np.empty((n, 3)))
    buffers = discs.drive_buffers(n, objects[0].shape[0], width, height, drive[3])
    on_threads(
        (robots, drive, scene, circles, geometry, substeps, objects, into, buffers, split), threads
    )
    return into


def warm_up() -> None:
    """Compile (or load from the on-disk cache) the split tick: kernels.warm_up calls it."""
    one = np.ones(1)
    robots = (np.full((1, 3), 50.0), np.zeros((1, 2)), np.zeros((1, 2)), np.zeros(1))
    circles = contacts.bin_circles(*aot.circles_sample())
    geometry = (100.0, 100.0, 0.01)
    objects = pucks.objects_table(0, 1)
    drive = (one, one, one, one, one)
    tick(robots, drive, aot.scene_sample(), circles, geometry, 1, objects, 1, split_buffers(1))


# The split tick calls the drive's and the contacts' kernels: their edits must reach its cache.
stamp_with_callees(__name__, discs, contacts, pairs, pucks, rays)
