"""Keep the memory a world's ticks free for the next tick instead of giving it back.

Why: a swarm's tick allocates and frees arrays of a few hundred kilobytes
(numpy's temporaries, the sensing pass's grids), and glibc's malloc by default
serves such blocks with mmap or trims them off the heap's top when they are
freed. Either way the next tick gets fresh pages from the kernel, each one a
page fault. Measured at 10,000 robots (docs/BENCHMARKS.md,
2026-11-26): 412 page faults and 1.8 ms of a 3.4 ms drive tick; the whole
simulated second went from 770 to 560 ms of wall time with the two settings
below. The cost is that a process keeps, as free heap, the most it ever held
at once: for a world, its largest tick's working set.

Only glibc has mallopt; elsewhere (musl, macOS) this does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging

log = logging.getLogger(__name__)

# glibc's malloc.h: mallopt's parameter numbers.
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
# Blocks below this come from the heap, not from mmap: glibc's largest
# (HEAP_MAX_SIZE / 2 on 64-bit), the ceiling its own dynamic threshold rises to.
MMAP_THRESHOLD = 32 * 1024 * 1024
# The heap's free top is given back only past this much.
TRIM_THRESHOLD = 256 * 1024 * 1024

_done: bool | None = None


def keep_freed_memory() -> bool:
    """Set malloc's thresholds for this process once; True if they are set (glibc)."""
    global _done
    if _done is not None:
        return _done
    _done = False
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError, TypeError):
        log.debug("no mallopt in %s: freed memory goes back to the system", name)
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    # mallopt returns 1 on success.
    _done = bool(
        mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD) and mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    )
    return _done
