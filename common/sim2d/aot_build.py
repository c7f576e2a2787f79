"""Build the kernels ahead of time into a Python extension (numba's pycc): see common/sim2d/aot.py.

    python -m common.sim2d.aot_build [--force] [--quiet]

What is compiled: the discs drive's whole path, the engine's default drive
(fused.py's new_state and tick, discs.bin_circles), and the wheel commands
(clamp_speeds, braitenberg_speeds). The chipmunk drives' kernels, the
profiled general path and the sensing pass on threads stay numba's, imported
when first used (compiled.py): pycc compiles no ``parallel`` kernel (its
thread pool is numba's runtime), and those drives are not the default.

The fused state is a numba structref, which only numba's runtime can box:
here new_state returns its address instead (a counted reference, released
by free_state) and tick takes it back, so the extension's callers hold a
plain integer (compiled.py wraps it).

Code is compiled for this machine's CPU, as numba's own is (for a generic
x86-64 the bench's 10-robot world ran up to 5 % slower: docs/BENCHMARKS.md);
the module's name carries the CPU (aot.cpu), so a checkout moved to another
machine runs numba's kernels until it is built there.

The module is written to _aot_<hash of the sources>.<ext> in this directory (a
temporary name first, then renamed: an engine never imports half a file), and
older modules are removed. Two builds at once wait for each other (a lock).

A copy goes to a cache of the user's (``$WART_AOT_CACHE``, default
``~/.cache/wart/aot/<numba>-<numpy>/``; keyed like the module by sources and CPU,
and by the versions it was compiled with), and a build that finds its module
there copies it instead of compiling: a fresh clone or a second worktree of the
same sources costs a copy, not half a minute of a core per core.
"""

from __future__ import annotations

import argparse
import fcntl
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numba
import numpy
from numba import typeof, types
from numba.core import cgutils, codegen
from numba.extending import intrinsic
from numba.pycc import CC

from common.sim2d import aot, discs, fused, physics

_STATE: types.Type | None = None


@intrinsic
def _to_address(typingctx, state):
    """A structref's meminfo address, with a reference counted for it (freed by _release)."""
    sig = types.uint64(state)

    def codegen(context, builder, signature, args):
        ref = cgutils.create_struct_proxy(signature.args[0])(context, builder, value=args[0])
        context.nrt.incref(builder, signature.args[0], args[0])
        return builder.ptrtoint(ref.meminfo, context.get_value_type(types.uint64))

    return sig, codegen


@intrinsic
def _from_address(typingctx, address, typ):
    """The structref of type ``typ`` at ``address`` (a new reference to it)."""
    state_type = typ.instance_type
    sig = state_type(address, typ)

    def codegen(context, builder, signature, args):
        ref = cgutils.create_struct_proxy(state_type)(context, builder)
        ref.meminfo = builder.inttoptr(args[0], ref.meminfo.type)
        value = ref._getvalue()
        context.nrt.incref(builder, state_type, value)
        return value

    return sig, codegen


@intrinsic
def _release(typingctx, address, typ):
    """Drop the reference _to_address counted: the state and its arrays go with the last one."""
    state_type = typ.instance_type
    sig = types.void(address, typ)

    def codegen(context, builder, signature, args):
        ref = cgutils.create_struct_proxy(state_type)(context, builder)
        ref.meminfo = builder.inttoptr(args[0], ref.meminfo.type)
        context.nrt.decref(builder, state_type, ref._getvalue())
        return context.get_dummy_value()

    return sig, codegen


def state_type() -> types.Type:
    """fused.TickState's numba type for aot.state_sample's types."""
    global _STATE
    if _STATE is None:
        _STATE = typeof(fused.new_state(aot.state_sample()))
    return _STATE


def _exports() -> list[tuple[str, Any, Callable[..., Any]]]:
    """(name, signature, Python function compiled under that name) for every export."""
    state = state_type()
    given_type = typeof(aot.state_sample())

    def new_state(given):  # pragma: no cover (compiled)
        return _to_address(fused.new_state(given))  # type: ignore[call-arg]  # numba's typing: (context, ...)

    def tick(address, sense, key, lights):  # pragma: no cover
        fused.tick(_from_address(address, state), sense, key, lights)  # type: ignore[call-arg]

    def free_state(address):  # pragma: no cover
        _release(address, state)  # type: ignore[call-arg]

    circles_args = tuple(typeof(a) for a in aot.circles_sample())
    discs.bin_circles.compile(circles_args)  # for its return type
    circles = discs.bin_circles.overloads[circles_args].signature  # type: ignore[attr-defined]
    any2 = types.Array(types.float64, 2, "A")
    c1 = types.Array(types.float64, 1, "C")
    c2 = types.Array(types.float64, 2, "C")
    return [
        ("new_state", types.uint64(given_type), new_state),
        ("tick", types.void(types.uint64, *fused._REST), tick),
        ("free_state", types.void(types.uint64), free_state),
        ("bin_circles", circles, discs.bin_circles.py_func),
        # The speeds a caller gives may be a view (World.set_speeds_all): any layout.
        ("clamp_speeds", types.void(any2, c1, c2), physics.clamp_speeds.py_func),
        (
            "braitenberg_speeds",
            types.void(types.Array(types.int32, 2, "A"), any2, types.float64, c1, c2),
            physics.braitenberg_speeds.py_func,
        ),
    ]


def _host_features() -> None:
    """Compile for the instruction sets this CPU has, as numba's JIT does, not its model's.

    pycc gives LLVM the CPU's name alone, and LLVM then assumes every
    instruction set of that model: a virtual machine may hide some (numba's
    JIT passes the ones the CPU reports). numba's internals: without them,
    the CPU's name alone.
    """
    aot_codegen = getattr(codegen, "AOTCPUCodegen", None)
    host = getattr(codegen, "get_host_cpu_features", None)
    if aot_codegen is not None and host is not None:
        aot_codegen._customize_tm_features = lambda self: host()


def build(force: bool = False, quiet: bool = False) -> Path:
    """Compile the module for the current sources unless it exists; returns its path."""
    target = aot.module_path()
    say: Callable[[str], None] = (
        (lambda _: None) if quiet else (lambda m: print(m, file=sys.stderr))
    )
    with open(aot.HERE / ".aot-build.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # another build's module is this one's, if current
        if target.exists() and not force:
            say(f"aot: {target.name} is up to date")
            return target
        cached = cache_dir() / target.name
        if cached.exists() and not force:
            _copy_then_rename(cached, target)
            _drop_others(target)
            say(f"aot: {target.name} from the cache ({cached.parent})")
            return target
        t0 = time.perf_counter()
        _host_features()
        name = aot.module_name()
        with tempfile.TemporaryDirectory(dir=aot.HERE, prefix=".aot-build-") as tmp:
            cc = CC(name)
            cc.target_cpu = "host"
            cc.output_dir = tmp
            cc.verbose = False
            for export, signature, func in _exports():
                cc.export(export, signature)(func)
            cc.compile()
            (built,) = Path(tmp).glob(name + "*")
            built.replace(target)
        _drop_others(target)
        say(f"aot: built {target.name} in {time.perf_counter() - t0:.0f} s")
        _keep(target)
        return target


def cache_dir() -> Path:
    """Where built modules are kept for other checkouts (WART_AOT_CACHE, else ~/.cache)."""
    given = os.environ.get("WART_AOT_CACHE")
    base = Path(given) if given else Path.home() / ".cache" / "wart" / "aot"
    return base / f"numba{numba.__version__}-numpy{numpy.__version__}"


def _copy_then_rename(source: Path, target: Path) -> None:
    """Copy to a temporary name beside ``target``, then rename: no reader (an engine, a
    build in another checkout) ever finds half a file."""
    partial = target.with_name(f".{target.name}.{os.getpid()}")
    shutil.copyfile(source, partial)
    partial.replace(target)


def _drop_others(target: Path) -> None:
    """Remove the modules of other sources from this directory: only ``target`` loads."""
    for old in aot.HERE.glob(aot.PREFIX + "*"):
        if old != target:
            old.unlink(missing_ok=True)


def _keep(built: Path, most: int = 4) -> None:
    """A copy in the cache, the ``most`` newest kept; a cache that cannot be written is
    skipped (a read-only home: the build itself succeeded)."""
    try:
        where = cache_dir()
        where.mkdir(parents=True, exist_ok=True)
        _copy_then_rename(built, where / built.name)
        kept = sorted(where.glob(aot.PREFIX + "*"), key=lambda p: p.stat().st_mtime)
        for old in kept[:-most]:
            old.unlink(missing_ok=True)
    except OSError as exc:
        print(f"aot: not kept in the cache ({exc})", file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--force", action="store_true", help="build even if up to date")
    parser.add_argument("--quiet", action="store_true", help="say nothing when all went well")
    args = parser.parse_args(argv)
    build(force=args.force, quiet=args.quiet)
    return 0


if __name__ == "__main__":
    sys.exit(main())
