"""Chipmunk's C functions called from numba kernels: the intrinsics (common/sim2d/chipmunk.py).

Each takes the function's address (an entry of chipmunk.FUNCTIONS) and the
body's or space's address as integers, and emits the call through a function
pointer: the machine code holds no address of a particular process, so it can
be cached on disk and compiled ahead of time (common/sim2d/aot_build.py).
Kept apart from chipmunk.py so that module needs no numba: an engine on the
ahead-of-time kernels reads the addresses there without loading numba's runtime.
"""

from __future__ import annotations

from typing import Any

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

# cpVect is a struct of two doubles: returned in two floating-point registers
# and passed by value as two floating-point arguments on x86-64 (System V) and
# AArch64, which is how clang lowers it and how it is declared here.
_DOUBLE = ir.DoubleType()
_VECT = ir.LiteralStructType([_DOUBLE, _DOUBLE])
_PTR = ir.IntType(8).as_pointer()


def _function(builder: ir.IRBuilder, address: ir.Value, ret: ir.Type, args: list[ir.Type]) -> Any:
    return builder.inttoptr(address, ir.FunctionType(ret, args).as_pointer())


@intrinsic
def get_vect(typingctx, fn, obj):
    """(x, y) = fn(obj) for a ``cpVect fn(cpBody *)``; both arguments are addresses."""
    sig = types.UniTuple(types.float64, 2)(types.uint64, types.uint64)

    def codegen(context, builder, signature, args):
        f = _function(builder, args[0], _VECT, [_PTR])
        out = builder.call(f, [builder.inttoptr(args[1], _PTR)])
        parts = [builder.extract_value(out, 0), builder.extract_value(out, 1)]
        return context.make_tuple(builder, signature.return_type, parts)

    return sig, codegen


@intrinsic
def get_double(typingctx, fn, obj):
    """fn(obj) for a ``double fn(cpBody *)``."""
    sig = types.float64(types.uint64, types.uint64)

    def codegen(context, builder, signature, args):
        f = _function(builder, args[0], _DOUBLE, [_PTR])
        return builder.call(f, [builder.inttoptr(args[1], _PTR)])

    return sig, codegen


@intrinsic
def set_vect(typingctx, fn, obj, x, y):
    """fn(obj, (x, y)) for a ``void fn(cpBody *, cpVect)``."""
    sig = types.void(types.uint64, types.uint64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        f = _function(builder, args[0], ir.VoidType(), [_PTR, _DOUBLE, _DOUBLE])
        builder.call(f, [builder.inttoptr(args[1], _PTR), args[2], args[3]])
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def set_double(typingctx, fn, obj, value):
    """fn(obj, value) for a ``void fn(cpBody *, double)`` or ``void fn(cpSpace *, double)``."""
    sig = types.void(types.uint64, types.uint64, types.float64)

    def codegen(context, builder, signature, args):
        f = _function(builder, args[0], ir.VoidType(), [_PTR, _DOUBLE])
        builder.call(f, [builder.inttoptr(args[1], _PTR), args[2]])
        return context.get_dummy_value()

    return sig, codegen
