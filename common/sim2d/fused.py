"""The discs drive's whole tick (drive, contacts, every sensor) in one compiled call.

Why: in a small world the tick's cost was not arithmetic but crossing into
numba. Every array handed to a compiled function is unboxed on every call
(about 0.14 us each, a NRT wrapper allocated per array) and typed by the
dispatcher (tuples of arrays about 0.13 us an element more); the discs tick
and the sensing pass took about 46 arguments between them, plus the Python
that packed them. At 10 robots that was most of the step (docs/history/).

So a world on the discs drive keeps its per-tick state in one numba
structref, :class:`TickState`, built when the layout changes: its own pose and
velocity buffers, the world's command, counter and arm arrays (the same
memory: set_speeds and set_counters write them in place, the tick advances the
counters in place as before), the drive's and the sensors' tables, the static
scene and the output readings. A tick is then :func:`tick` with the state, a
flag, the pass's noise key and the lit lights: one structref unboxed and typed,
whatever the number of tables.

The world hands out copies of the buffers (World.agent_pose, proximity...), so
an array a caller holds never changes under it, as when each tick allocated
new ones. Same arithmetic, same order as discs.tick then kernels.sense: the
trajectories and readings are the same bits (tests/unit/common/sim2d/test_fused.py).

Numba caches functions taking a structref on disk like any other (the type is
defined at import, here, and pickled by reference); the proxy's own
constructor is not cached, so the state is built by :func:`new_state`, a
cached function.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numba import njit, typeof, types
from numba.core import cgutils
from numba.core.runtime.nrtdynmod import _meminfo_struct_type
from numba.experimental import structref
from numba.extending import intrinsic

from common.sim2d import aot, contacts, discs, noise, packs, pairs, pucks, rays, sense_pass
from common.sim2d import kernels as K
from common.sim2d.jitcache import stamp_with_callees
from common.sim2d.packs import _UNCOUNTED

_CACHE = True


@structref.register
class TickStateType(types.StructRef):
    def preprocess_fields(
        self, fields: tuple[tuple[str, types.Type], ...]
    ) -> tuple[tuple[str, types.Type], ...]:
        # Literal types (a layout's sensor count, say) would make a new
        # specialisation per value: fields are typed by kind only.
        return tuple((name, types.unliteral(t)) for name, t in fields)


class TickState(structref.StructRefProxy):
    """One discs world's per-tick state (see the module's docstring); built by :func:`new_state`."""


FIELDS = (
    "pose",  # (N, 3) the robots' poses: moved in place by each tick
    "vel",  # (N, 3) the last tick's mean velocities
    "cmd",  # (N, 2) World.cmd itself
    "counters",  # (N, 2) World.counters itself
    "arm",  # (N,) World.arm itself
    "holding",  # (N,) bool: which robots hold an object (world_discs.DiscObjects.holding)
    # (mm_s_per_unit, wheel_base, pulses_per_tick) (N,) each; radius, mass (N + K,):
    # the robots', then the objects' discs (common/sim2d/pucks.py)
    "drive",
    "circles",  # the round obstacles binned in the sensing grid (discs.bin_circles)
    "tables",  # packs.SensorTables as a plain tuple
    "scene",  # packs.StaticScene as a plain tuple
    "pucks",  # the movable objects: pucks.objects_table's layout, moved in place
    "objects",  # MovingScene's circles and edges: pucks.scene_into fills them per pass
    "readings",  # (proximity, ambient, presence) written by a sensing pass
    "geometry",  # (width, height, substep s) of the arena and the tick
    "substeps",
    # Work arrays, kept from tick to tick rather than allocated by each: forty-odd
    # allocations a tick, about 1 us of a 15 us step at 10 robots (BENCHMARKS.md).
    "drive_work",  # discs.drive_buffers
    "circle_work",  # kernels.circle_buffers
    "sense_work",  # kernels.scratch_buffers
)
structref.define_proxy(TickState, TickStateType, list(FIELDS))


@njit(cache=_CACHE)
def new_state(given):  # pragma: no cover
    """A :class:`TickState` of ``given``, the world's part (:data:`FIELDS`' first fifteen, arrays
    by reference, not copied), and its work arrays.

    ``given``'s ``objects``: pucks.scene_buffers for these objects and round obstacles.
    """
    pose = given[0]  # in FIELDS' order
    drive, _, tables, scene, pucks_table, objects, _, geometry, _ = given[6:]
    n = pose.shape[0]
    width, height, _ = geometry
    nc = n + objects[1].shape[0]
    return TickState(
        *given,
        discs.drive_buffers(n, pucks_table[0].shape[0], width, height, drive[3]),
        K.circle_buffers(nc, scene[3] * scene[4]),
        # objects[4] is the movable edges, where a MovingScene has them
        K.scratch_buffers(tables, scene, objects, nc),
    )


@intrinsic
def _borrowed(typingctx, state):  # pragma: no cover
    """Every field of a :class:`TickState`, in :data:`FIELDS`' order, with no reference counted.

    For an uncounted caller only (``_nrt=False``): it holds the state, and the
    state holds the fields. Reading them as attributes would count a reference
    to each array of each tuple in and out again, about two hundred calls of
    numba's runtime a tick (a tenth of a 10-robot step, docs/BENCHMARKS.md);
    and an uncounted function cannot read a structref's attributes at all.
    """
    if not isinstance(state, TickStateType):
        return None
    data_type = state.get_data_type()
    fields = types.Tuple([state.field_dict[name] for name in FIELDS])

    def codegen(context, builder, signature, args):
        ref = cgutils.create_struct_proxy(state)(context, builder, value=args[0])
        meminfo = builder.bitcast(ref.meminfo, _meminfo_struct_type.as_pointer())
        data = builder.load(cgutils.gep(builder, meminfo, 0, 3))  # NRT_MemInfo's data
        model = context.data_model_manager[data_type]
        data = builder.bitcast(data, model.get_value_type().as_pointer())
        payload = cgutils.create_struct_proxy(data_type)(context, builder, ref=data)
        return context.make_tuple(builder, fields, [getattr(payload, n) for n in FIELDS])

    return fields(state), codegen


@njit(cache=_CACHE, **_UNCOUNTED)
def tick(state, sense, key, lights):  # pragma: no cover
    """One tick: the robots move (discs.tick_into); then, if ``sense``, every sensor is read.

    ``key`` is the sensing pass's noise key (drawn by the caller only for a
    pass), ``lights`` the lit lights as SensorSuite's table. Serial: where a
    pass runs on threads, the world calls this with ``sense`` False and then
    the parallel pass itself (World._step_fused). (Calling
    kernels.sense_parallel from here compiled, but the on-disk cache of a
    function calling a parallel one loaded broken code in the next process:
    it crashed. Where the drive runs on threads too, from
    discs_split.SPLIT_MIN_DISCS discs, the world calls discs_split's tick
    instead of this one.) Uncounted: it reads the state's fields borrowed
    (:func:`_borrowed`), allocates nothing and returns no array.
    """
    fields: tuple[Any, ...] = _borrowed(state)  # type: ignore[call-arg]  # numba: (context, state)
    pose, vel, cmd, counters, arm, holding = fields[:6]  # in FIELDS' order
    drive, circles, tables, scene, pucks_table, objects = fields[6:12]
    readings, geometry, substeps, drive_work, circle_work, sense_work = fields[12:]
    robots = (pose, cmd, counters, arm)
    discs.tick_into(
        robots, drive, scene, circles, geometry, substeps, pucks_table, (pose, vel), drive_work
    )
    if sense:
        m, e = pucks.scene_into(pose.shape[0], pucks_table, arm, scene[7], scene[8], objects)
        moving = (objects[0][:m], objects[1][:m], objects[2][:m], objects[3][:m], objects[4][:e])
        robots = (pose, arm, holding)
        if rays.bins_shadows(pose.shape[0], scene):  # a swarm: the bins' allocation is counted
            K.sense_into(
                robots, tables, scene, (*moving, lights, key), readings, circle_work, sense_work
            )
        else:
            sense_pass.sense_unbinned(
                robots, tables, scene, (*moving, lights, key), readings, circle_work, sense_work
            )


# tick and new_state call the drive's and the sensors' kernels, in other files:
# their edits must reach these caches too (it crashed, the one time a cached
# tick called old code with new layouts).
stamp_with_callees(__name__, discs, contacts, pairs, pucks, packs, noise, rays, sense_pass)


# The types of tick's other arguments: a flag, the noise key, the lights' table
# (SensorSuite.lit: a C-contiguous (L, 4) float64 array, NO_LIGHTS when none).
_REST = (types.boolean, types.uint64, types.Array(types.float64, 2, "C"))


def entry(state: TickState) -> Callable[[TickState, bool, np.uint64, np.ndarray], None]:
    """:func:`tick` compiled for this state's type, to be called without the dispatcher.

    The dispatcher types a structref through Python on every call (about 1.7 us,
    a tenth of a 10-robot step); the compiled entry point only unboxes the
    arguments. It trusts them to be of the types it was compiled for: the
    caller passes this ``state`` (its type was looked up here) and arguments of
    the types in ``_REST``. Compiled here if the cache has no such version.
    """
    sig = (typeof(state), *_REST)
    cres = tick.overloads.get(sig)
    if cres is None:
        tick.compile(sig)
        cres = tick.overloads[sig]
    return cres.entry_point  # numba's internal, untyped


def warm_up() -> None:
    """Compile (or load from the on-disk cache) the fused tick: kernels.warm_up calls it.

    For the arguments' types the World passes (aot.state_sample), as compiled.py's warm-up.
    """
    state = new_state(aot.state_sample())
    entry(state)(state, False, np.uint64(1), np.zeros((0, 4)))
