"""The discs drive's pair grid: which discs may touch within a substep.

Each substep of common/sim2d/discs.py's tick, after the arcs and before the
contacts (common/sim2d/contacts.py): the discs sorted by cell, each cell
scanned against itself and four neighbours.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from common.sim2d import contacts, rays
from common.sim2d.contacts import _COUNTED, _UNCOUNTED
from common.sim2d.jitcache import stamp_with_callees
from common.sim2d.rays import clamped_cell, place_by_cell

_CACHE = True


@njit(cache=_CACHE, inline="always")
def _cell(v, cell, n):  # pragma: no cover
    """The pair grid's cell of a coordinate (no margin cell), clamped to the grid."""
    return clamped_cell(v, cell, n, 0)


@njit(cache=_CACHE, inline="always")
def _neighbours(nb, p, k, ix, iy, gx, gy, start):  # pragma: no cover
    """The run of sorted discs that disc ``p`` (in cell ``k`` = (ix, iy)) is compared with.

    ``nb`` 0: its own cell's later discs; 1 to 4: the cells (ix, iy + 1) and
    the next column's three, an empty run where the cell is off the grid.
    Each pair of neighbouring cells is so compared once.
    """
    if nb == 0:
        return p + 1, start[k + 1]
    jx = ix + (0 if nb == 1 else 1)
    jy = iy + (1 if nb == 1 else nb - 3)
    if jx >= gx or jy < 0 or jy >= gy:
        return 0, 0
    j = jx * gy + jy
    return start[j], start[j + 1]


@njit(cache=_CACHE, **_COUNTED)
def _pairs(px, py, radius, width, height, cell, margin, buffers):  # pragma: no cover
    """:func:`_pairs_into`'s pairs, in new arrays where ``buffers`` are too small for them."""
    start, out = buffers[6], buffers[7]
    m = _pairs_into(px, py, radius, width, height, cell, margin, buffers)
    if 0 <= m <= out.shape[0]:
        return out[:m]
    ncell = (math.floor(width / cell) + 1) * (math.floor(height / cell) + 1)
    if start.shape[0] < ncell + 1:
        start = np.empty(ncell + 1, dtype=np.int64)
    if m < 0:  # the cells' offsets did not fit: the pairs are not counted yet
        m = _pairs_into(px, py, radius, width, height, cell, margin, (*buffers[:6], start, out))
    if m > out.shape[0]:
        out = np.empty((max(m, 2 * out.shape[0]), 2), dtype=np.int64)
        _pairs_into(px, py, radius, width, height, cell, margin, (*buffers[:6], start, out))
    return out[:m]


@njit(cache=_CACHE, **_UNCOUNTED)
def _pairs_into(px, py, radius, width, height, cell, margin, buffers):  # pragma: no cover
    """How many pairs of discs are closer than their radii plus ``margin``; the first in ``out``.

    ``out`` (buffers' last) gets the pairs as (M, 2) slots, as many as it has
    rows; the count returned may be more (then :func:`_pairs` makes room and
    asks again). -1: ``start`` is too short for this grid (nothing counted).

    The discs are sorted by cell (a counting sort) and copied in that order, so
    the scan reads neighbours from contiguous memory rather than from random
    slots; each cell is compared with itself and four of its neighbours (the
    other four compare with it), so each pair is found once. The pairs come
    out in cell order, the same for the same poses. ``buffers`` are
    discs.drive_buffers' eight for it.
    """
    home, slot, sk, sx, sy, sr, start, out = buffers
    n = px.shape[0]
    gx = (math.floor(width / cell)) + 1
    gy = (math.floor(height / cell)) + 1
    ncell = gx * gy
    if start.shape[0] < ncell + 1:
        return -1
    for k in range(ncell + 1):
        start[k] = 0
    for a in range(n):
        k = _cell(px[a], cell, gx) * gy + _cell(py[a], cell, gy)
        home[a] = k
        start[k] += 1
    place_by_cell(home, n, ncell, start, slot)  # a cell's discs in slot order
    for p in range(n):
        a = slot[p]
        sk[p] = home[a]  # each sorted disc's cell, read in order below
        sx[p] = px[a]
        sy[p] = py[a]
        sr[p] = radius[a]
    m = 0
    # The sorted discs in order are the cells in order with their discs: walking
    # the discs visits the same (cell, disc) sequence as walking every cell,
    # without the empty cells (most of them in a small arena; 58,000 cells for
    # 10,000 robots in the bench's swarm). Measured at 10,000: 1.17 ms against
    # 1.32 walking the cells (with home[slot[p]] for the cell: 1.30).
    for p in range(n):
        k = sk[p]
        ix = k // gy
        iy = k - ix * gy
        x = sx[p]
        y = sy[p]
        r = sr[p] + margin
        for nb in range(5):
            lo, hi = _neighbours(nb, p, k, ix, iy, gx, gy, start)
            for q in range(lo, hi):
                dx = sx[q] - x
                dy = sy[q] - y
                lim = r + sr[q]
                if dx * dx + dy * dy < lim * lim:
                    if m < out.shape[0]:
                        a = slot[p]
                        b = slot[q]
                        out[m, 0] = min(a, b)
                        out[m, 1] = max(a, b)
                    m += 1
    return m


# These kernels inline rays.py's helper and take contacts.py's flags: their edits
# must reach these caches.
stamp_with_callees(__name__, contacts, rays)
