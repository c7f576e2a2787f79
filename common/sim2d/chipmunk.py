"""Chipmunk's body accessors and space step, callable from compiled kernels.

A tick at 10 robots spends as long in the Python glue around chipmunk (pymunk's
batch buffers, descriptors, numpy views, one kernel call to lay the velocities
out and one to gather the poses back) as chipmunk spends stepping the space.
Here the kernels call chipmunk's own C functions instead: the drive kernel sets
each control body's velocity, steps the space and reads every robot's and
object's pose in one compiled call (kernels.physics_tick).

Function addresses are looked up in pymunk's C extension at run time and
passed to the kernels as a table of integers (``FUNCTIONS``), so the kernels'
on-disk cache holds no address of a particular process. Bodies and spaces are
passed as their ``cpBody *`` / ``cpSpace *`` addresses (``body_address``,
``space_address``); the caller keeps the pymunk objects alive for as long as a
kernel may use them.

This reaches one step below pymunk's public API (``Body._body``,
``Space._space``, the C library in ``pymunk._chipmunk``), in pymunk 7
(pyproject pins ``pymunk < 8``). ``check_signatures`` verifies at import that
every function still has the C signature the code generation below assumes;
tests/unit/common/sim2d/test_chipmunk.py checks values against pymunk's own
accessors and a whole trajectory against ``Space.step``.

The kernels' side of the calls (numba intrinsics) is in chipmunk_calls.py: this
module imports no numba, so an engine on the ahead-of-time kernels
(common/sim2d/aot.py) reads the addresses without loading numba's runtime.
"""

from __future__ import annotations

import numpy as np
import pymunk
from pymunk._chipmunk import ffi, lib

# Indices into FUNCTIONS.
GET_POSITION = 0
GET_ANGLE = 1
GET_VELOCITY = 2
GET_ANGULAR_VELOCITY = 3
SET_VELOCITY = 4
SET_ANGULAR_VELOCITY = 5
SPACE_STEP = 6
HASTY_SPACE_STEP = 7  # the threaded space's step (pymunk.Space(threaded=True))
SET_FORCE = 8  # the velocity drive's servo (kernels.physics_tick_servo)
SET_TORQUE = 9

# Name and the C signature the intrinsics below are generated for.
_SIGNATURES = (
    ("cpBodyGetPosition", "cpVect(*)(cpBody *)"),
    ("cpBodyGetAngle", "double(*)(cpBody *)"),
    ("cpBodyGetVelocity", "cpVect(*)(cpBody *)"),
    ("cpBodyGetAngularVelocity", "double(*)(cpBody *)"),
    ("cpBodySetVelocity", "void(*)(cpBody *, cpVect)"),
    ("cpBodySetAngularVelocity", "void(*)(cpBody *, double)"),
    ("cpSpaceStep", "void(*)(cpSpace *, double)"),
    ("cpHastySpaceStep", "void(*)(cpSpace *, double)"),
    ("cpBodySetForce", "void(*)(cpBody *, cpVect)"),
    ("cpBodySetTorque", "void(*)(cpBody *, double)"),
)


def check_signatures() -> None:
    """Fail loudly if pymunk's chipmunk no longer matches the generated calls."""
    if ffi.sizeof("cpFloat") != 8 or ffi.sizeof("cpVect") != 16:
        raise ImportError("pymunk's chipmunk is not built with double-precision cpFloat")
    for name, expected in _SIGNATURES:
        found = ffi.typeof(ffi.addressof(lib, name)).cname.replace("struct ", "")
        if found.replace("cpFloat", "double") != expected:
            raise ImportError(f"pymunk's {name} is {found}, expected {expected}")


check_signatures()
FUNCTIONS = np.array(
    [int(ffi.cast("uintptr_t", ffi.addressof(lib, name))) for name, _ in _SIGNATURES],
    dtype=np.uint64,
)


def body_address(body: pymunk.Body) -> int:
    return int(ffi.cast("uintptr_t", body._body))


def space_address(space: pymunk.Space) -> int:
    return int(ffi.cast("uintptr_t", space._space))


def addresses(bodies: list[pymunk.Body]) -> np.ndarray:
    return np.array([body_address(b) for b in bodies], dtype=np.uint64)


def space_step_pending(space: pymunk.Space) -> bool:
    """True if pymunk's own ``Space.step`` has work besides chipmunk's step.

    After shapes or bodies are added or removed, pymunk checks new bodies'
    masses and releases removed shapes in its step; callbacks may have queued
    additions, removals or post-step callbacks. The engine steps through pymunk
    then, and straight through chipmunk otherwise.
    """
    return bool(
        space._bodies_to_check
        or space._removed_shapes
        or space._add_later
        or space._remove_later
        or space._post_step_callbacks
    )
