"""The compiled kernels the World calls: ahead of time where built, else numba's.

At import this picks the path (common/sim2d/aot.py, ``WART_KERNELS``): the
ahead-of-time module when it is built from these sources, numba's kernels
(common/sim2d/kernels.py, compiled or loaded from numba's cache) otherwise.
:data:`PATH` and :data:`WHY` say which and why; the engine logs them.

On the ahead-of-time path, kernels the module does not have (the chipmunk
drives', the profiled path's, the sensing pass on threads: aot_build.py says
why) are numba's, imported at their first use: a world on the default drive
never loads numba, one on another drive loads it when it first ticks.

Both paths run the same code on the same arguments: trajectories and
readings are the same bits (tests/unit/common/sim2d/test_aot.py).
"""

from __future__ import annotations

import contextlib
import logging
import sys
import time
from collections.abc import Callable
from types import ModuleType
from typing import Any

import numpy as np

from common.sim2d import aot

log = logging.getLogger(__name__)

_module: ModuleType | None = None
_mode = aot.mode()
if _mode == "jit":
    WHY = "numba's (WART_KERNELS=jit)"
else:
    try:
        _module = aot.load()
    except aot.Unavailable as exc:
        if _mode == "aot":
            raise ImportError(f"WART_KERNELS=aot: {exc}") from exc
        WHY = f"numba's: the ahead-of-time module is {exc}"
    else:
        WHY = f"ahead of time ({_module.__name__.rsplit('.', 1)[-1]})"

PATH = "jit" if _module is None else "aot"

# The kernels with an ahead-of-time version (aot_build._exports), as the World calls them.
clamp_speeds: Callable[[np.ndarray, np.ndarray, np.ndarray], None]
braitenberg_speeds: Callable[[np.ndarray, np.ndarray, float, np.ndarray, np.ndarray], None]


def _jit() -> ModuleType:
    """numba's kernels (kernels.py), imported at the first call that needs them."""
    if "common.sim2d.kernels" not in sys.modules and PATH == "aot":
        log.info("kernels: loading numba's for what the ahead-of-time module lacks")
    from common.sim2d import kernels  # numba: loaded only when a kernel needs it

    return kernels


class _Address(int):
    """A fused state in the ahead-of-time module: its address, released when this goes."""

    __slots__ = ()

    def __del__(self) -> None:
        # NameError or TypeError: the interpreter is exiting, and frees it all.
        with contextlib.suppress(NameError, TypeError):
            _free(self)


_state_kinds: object = None


def new_tick(
    given: tuple[Any, ...],
) -> tuple[object, Callable[[Any, bool, np.uint64, np.ndarray], None]]:
    """(state, tick) for fused.new_state's ``given``: ``tick(state, sense, key, lights)``.

    ``lights`` must be a C-contiguous (L, 4) float64 array (SensorSuite.lit's):
    the ahead-of-time tick does not check it. The other arguments are checked
    against the types the module was built for; where they differ (a world
    built otherwise than world_tick builds it), numba's kernels run it.
    """
    global _state_kinds
    if _module is not None:
        *rest, geometry, substeps = given
        given = (*rest, tuple(float(g) for g in geometry), int(substeps))
        if _state_kinds is None:
            _state_kinds = aot.describe(aot.state_sample())
        if aot.describe(given) == _state_kinds:
            return _Address(_module.new_state(given)), _module.tick
        log.warning("kernels: a fused state of other types than built for: numba's runs it")
    from common.sim2d import fused  # numba: only when the module cannot run this state

    state = fused.new_state(given)
    return state, fused.entry(state)


_circle_kinds: object = None


def bin_circles(*args: Any) -> tuple[np.ndarray, np.ndarray]:
    """discs.bin_circles (the round obstacles binned in the sensing grid)."""
    global _circle_kinds
    if _module is not None:
        if _circle_kinds is None:
            _circle_kinds = aot.describe(aot.circles_sample())
        if aot.describe(args) == _circle_kinds:
            return _module.bin_circles(*args)
    from common.sim2d import discs  # numba: only when the module cannot bin these

    return discs.bin_circles(*args)


def discs_tick(*args: Any) -> tuple[np.ndarray, np.ndarray]:
    """discs.tick (the discs drive's general path: a profiled world): numba's."""
    from common.sim2d import discs  # numba: a profiled world only

    return discs.tick(*args)


def scene_into(*args: Any) -> tuple[int, int]:
    """pucks.scene_into (before a sensing pass on threads): numba's."""
    from common.sim2d import pucks  # numba: a pass on threads only

    return pucks.scene_into(*args)


def warm_up() -> float:
    """Load (or compile) the kernels this path runs; returns the seconds it took."""
    if _module is None:
        return _jit().warm_up()
    t0 = time.perf_counter()
    state, tick = new_tick(aot.state_sample())
    tick(state, False, np.uint64(1), np.zeros((0, 4)))
    return time.perf_counter() - t0


if _module is not None:
    clamp_speeds = _module.clamp_speeds
    braitenberg_speeds = _module.braitenberg_speeds
    _free = _module.free_state
else:
    clamp_speeds = _jit().clamp_speeds
    braitenberg_speeds = _jit().braitenberg_speeds


def __getattr__(name: str) -> Any:
    """The kernels with no ahead-of-time version (kernels.NAME): numba's, at first use."""
    if name.startswith("__"):
        raise AttributeError(name)
    value = getattr(_jit(), name)
    globals()[name] = value  # found here from now on, without this call
    return value
