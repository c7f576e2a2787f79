"""The kernels compiled ahead of time: which module, built from which sources, and loading it.

Why: an engine that loads its kernels from numba's on-disk cache carries numba's
runtime (LLVM and numba itself), needed only to load the cached machine code:
185 MiB at 10 robots, against 63 on this module (docs/BENCHMARKS.md, "Memory").
The ahead-of-time module (common/sim2d/aot_build.py builds it with numba's
pycc) is a plain Python extension: importing it loads no numba and no LLVM.

A module is named after a hash of the kernels' sources (:data:`SOURCES`), so a
module built from other sources is never imported: it would run old code on
new layouts (jitcache.py tells of the one crash of that kind). The hash takes
in the CPU too (:func:`cpu`): the module is compiled for this machine's, as
numba compiles (code for a generic x86-64 was up to 5 % slower at 10 robots,
docs/BENCHMARKS.md), and a checkout moved to another machine must not run
instructions its CPU lacks. This module imports no numba (nor numpy, until
asked to describe or sample arguments); common/sim2d/compiled.py chooses
between the module's kernels and numba's.

``WART_KERNELS``: ``auto`` (the default: the module if it is built for these
sources, else numba's), ``jit`` (numba's always) or ``aot`` (the module, an
error if it is missing or stale).
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.machinery
import os
import platform
from pathlib import Path
from types import ModuleType
from typing import Any

HERE = Path(__file__).resolve().parent
PREFIX = "_aot_"

# Every file whose contents reach the compiled code: the kernels, the layouts and
# constants they read, the intrinsics, and the build itself (its signatures).
# tests/unit/common/sim2d/test_aot.py checks that every file defining a kernel is here.
SOURCES = (
    "aot.py",
    "aot_build.py",
    "chipmunk_calls.py",
    "contacts.py",
    "discs.py",
    "discs_split.py",  # not in the module (threads are numba's), but kernels.py warms it up
    "fused.py",
    "kernels.py",
    "noise.py",
    "packs.py",
    "pairs.py",
    "physics.py",
    "pucks.py",
    "pucks_tables.py",
    "rays.py",
    "sense_pass.py",
)

MODES = ("auto", "jit", "aot")


# The lines of /proc/cpuinfo that say which instructions the CPU has (x86, then ARM).
_CPU_KEYS = (
    *("vendor_id", "cpu family", "model", "model name", "flags"),
    *("CPU implementer", "CPU architecture", "CPU variant", "CPU part", "Features"),
)


def cpu() -> str:
    """This machine's CPU as the module's code depends on it: model and instruction sets."""
    try:
        first = Path("/proc/cpuinfo").read_text().split("\n\n")[0]
    except OSError:
        return platform.machine()
    lines = (line.partition(":") for line in first.splitlines())
    return "\n".join(
        [platform.machine()]
        + [f"{k.strip()}:{v.strip()}" for k, _, v in lines if k.strip() in _CPU_KEYS]
    )


def stamp() -> str:
    """A hash of the CPU and :data:`SOURCES`' contents: the module built from them has it."""
    digest = hashlib.sha256(cpu().encode())
    for name in SOURCES:
        digest.update(name.encode() + b"\0")
        digest.update((HERE / name).read_bytes())
    return digest.hexdigest()[:16]


def module_name(hash_: str | None = None) -> str:
    return PREFIX + (hash_ or stamp())


def module_path(hash_: str | None = None) -> Path:
    """Where the module for these sources is (or would be) built, for this Python."""
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
    return HERE / (module_name(hash_) + suffix)


def mode() -> str:
    value = os.environ.get("WART_KERNELS", "auto") or "auto"
    if value not in MODES:
        raise ValueError(f"WART_KERNELS is {value!r}: expected one of {', '.join(MODES)}")
    return value


class Unavailable(Exception):
    """No ahead-of-time module for these sources (the message says why)."""


def load() -> ModuleType:
    """The ahead-of-time module built from these sources; :class:`Unavailable` if there is none."""
    hash_ = stamp()
    path = module_path(hash_)
    if not path.exists():
        built = sorted(p.name for p in HERE.glob(PREFIX + "*"))
        why = "not built" if not built else f"stale (built from other sources: {built[0]})"
        raise Unavailable(f"{path.name} {why}: python -m common.sim2d.aot_build builds it")
    try:
        return importlib.import_module(f"common.sim2d.{module_name(hash_)}")
    except ImportError as exc:  # a broken build (python -m common.sim2d.aot_build --force)
        raise Unavailable(f"{path.name} does not load ({exc})") from exc


def describe(value: Any) -> object:
    """What a compiled function's argument must match: dtype, dimensions and layout, recursively.

    The module's functions do not check their arguments' types (numba's
    dispatcher did): an array of other dimensions or layout would be read
    wrongly. Its callers compare what they pass, where they can afford it,
    with what it was compiled for (compiled.py).
    """
    import numpy as np  # here: ./dev asks whether the module is built without numpy

    if isinstance(value, np.ndarray):
        return (value.dtype.name, value.ndim, bool(value.flags.c_contiguous))
    if isinstance(value, tuple):
        return tuple(describe(v) for v in value)
    if isinstance(value, bool | np.bool_):
        return "bool"
    if isinstance(value, int):
        return "int64"  # how numba types a Python int
    if isinstance(value, np.integer | np.floating):
        return value.dtype.name
    if isinstance(value, float):
        return "float64"
    return type(value).__name__


def state_sample() -> tuple[Any, ...]:
    """fused.new_state's argument as the World passes it (world_tick._new_fused_state), smallest.

    The build compiles new_state for its types and compiled.py
    checks each call's against them: one sample, so the two cannot disagree.
    """
    # here, not at the top: ./dev asks whether the module is built without numpy
    import numpy as np

    from common.sim2d.packs import N_AGENT_F, N_AGENT_I  # with numpy, as above
    from common.sim2d.pucks_tables import objects_table

    one = np.ones(1)
    i64 = np.zeros(2, dtype=np.int64)
    return (
        np.full((1, 3), 50.0),  # pose
        np.zeros((1, 3)),  # vel
        np.zeros((1, 2)),  # cmd
        np.zeros((1, 2)),  # counters
        np.zeros(1),  # arm
        np.zeros(1, dtype=np.bool_),  # holding
        (one, one, one, one, one),  # drive
        (i64, np.zeros(0, dtype=np.int64)),  # circles (discs.bin_circles)
        (  # tables
            np.zeros((1, 1, 5)),
            1,
            1,
            np.zeros((1, N_AGENT_F)),
            np.zeros((1, N_AGENT_I), dtype=np.int64),
            np.array([[0.0, 1.0]]),
            np.array([[1.0, 0.0]]),
            np.array([2], dtype=np.int64),
            np.zeros((1, 1, 5)),
            np.ones((1, 1), dtype=np.bool_),
            np.ones((1, 1)),  # each IR sensor's gain
            np.zeros((1, 1)),  # each IR sensor's additive noise
        ),
        scene_sample(),  # scene
        objects_table(0, 1),  # pucks
        (  # objects (pucks_tables.scene_buffers)
            np.zeros((0, 2)),
            np.zeros(0),
            np.zeros(0, dtype=np.int64),
            np.zeros(0, dtype=np.bool_),
            np.zeros((0, 4)),
        ),
        (  # readings
            np.zeros((1, 1), dtype=np.int32),
            np.zeros((1, 1), dtype=np.int32),
            np.zeros(1, dtype=np.int32),
        ),
        (100.0, 100.0, 0.01),  # geometry
        1,  # substeps
    )


def scene_sample() -> tuple[Any, ...]:
    """A static scene (packs.StaticScene's layout, a plain tuple): a 100 mm arena of one cell
    without obstacles, the smallest the kernels take."""
    import numpy as np  # here, not at the top: as state_sample's

    return (
        np.zeros((0, 4)),
        np.zeros(2, dtype=np.int64),
        np.zeros(0, dtype=np.int64),
        1,
        1,
        100.0,
        np.zeros((0, 4)),
        np.zeros((0, 2)),
        np.zeros(0),
    )


def circles_sample() -> tuple[Any, ...]:
    """discs.bin_circles' arguments as world_tick passes them (static geometry's circles)."""
    import numpy as np  # here, not at the top: as state_sample's

    return (np.zeros((0, 2)), np.zeros(0), 1, 1, 100.0)
