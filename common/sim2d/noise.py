"""Gaussian sensor noise drawn in the kernels, counter-based (see the comment below)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from common.sim2d import jitcache  # noqa: F401 (where numba caches the kernels below)
from common.sim2d.packs import _CACHE

# --- Gaussian noise, counter-based -----------------------------------------------------
# Every sensor's noise of a pass is a function of (the pass's key, the agent's slot,
# the sensor): a key is one 64-bit draw from the world's seeded generator per pass
# (sensing.NoiseKeys), and the kernel derives the normals itself. So the noise costs
# no numpy call and no buffer (at 10,000 robots numpy's draw of 240,000 normals a pass
# was about 4 ms, a quarter of the pass), a chunk of robots on any thread draws
# exactly what one thread would, and the same seed still gives the same readings.
#
# Words: SplitMix64 (Steele, Lea, Flood 2014), word j of sensor stream i being the
# generator's output at counter i * 2**16 + j from the key: consecutive counters are
# consecutive SplitMix64 outputs, a generator that passes BigCrush. Normals: the
# Marsaglia-Tsang ziggurat with 256 layers, as numpy's ``standard_normal`` does it
# (same tables' construction, same 52-bit layout of a word, same tail and wedges):
# one word and no transcendental call about 99 % of the time.
_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_U30, _U27, _U31 = np.uint64(30), np.uint64(27), np.uint64(31)
_U1, _U8, _U11, _U16 = np.uint64(1), np.uint64(8), np.uint64(11), np.uint64(16)
_BYTE = np.uint64(0xFF)
_MANTISSA = np.uint64(0x000FFFFFFFFFFFFF)
_ZIG_R = 3.6541528853610088  # start of the tail
_ZIG_V = 0.00492867323399  # area of each layer


def _ziggurat_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ki, wi, fi) for 256 layers, built as Marsaglia and Tsang (2000) and numpy do."""
    m1 = 2.0**52
    ki = np.zeros(256, dtype=np.int64)  # below 2**52: compared with a word's 52 bits
    wi = np.zeros(256)
    fi = np.zeros(256)
    dn = tn = _ZIG_R
    q = _ZIG_V / math.exp(-0.5 * dn * dn)
    ki[0] = int((dn / q) * m1)
    wi[0] = q / m1
    wi[255] = dn / m1
    fi[0] = 1.0
    fi[255] = math.exp(-0.5 * dn * dn)
    for i in range(254, 0, -1):
        dn = math.sqrt(-2.0 * math.log(_ZIG_V / dn + math.exp(-0.5 * dn * dn)))
        ki[i + 1] = int((dn / tn) * m1)
        tn = dn
        fi[i] = math.exp(-0.5 * dn * dn)
        wi[i] = dn / m1
    return ki, wi, fi


_ZIG_KI, _ZIG_WI, _ZIG_FI = _ziggurat_tables()


@njit(cache=_CACHE, inline="always")
def _word(key, stream, j):  # pragma: no cover
    """The ``j``-th 64-bit word of noise stream ``stream`` under ``key`` (SplitMix64)."""
    z = key + ((np.uint64(stream) << _U16) + np.uint64(j)) * _GAMMA
    z = (z ^ (z >> _U30)) * _M1
    z = (z ^ (z >> _U27)) * _M2
    return z ^ (z >> _U31)


@njit(cache=_CACHE, inline="always")
def _unit(word):  # pragma: no cover
    """A double in [0, 1) from the top 53 bits of a word."""
    return float(word >> _U11) * (1.0 / 9007199254740992.0)


@njit(cache=_CACHE, inline="always")
def normal(key, stream):  # pragma: no cover
    """One standard normal value: stream ``stream`` of ``key`` (numpy's ziggurat on its words).

    Inlined, and the sign applied without a branch: a call per value and a
    mispredicted branch on a random bit cost more than the rest (14 against 5 ns).
    """
    j = 0
    while True:
        r = _word(key, stream, j)
        j += 1
        idx = np.int64(r & _BYTE)
        r = r >> _U8
        rabs = np.int64((r >> _U1) & _MANTISSA)
        x = float(rabs) * _ZIG_WI[idx] * (1.0 - 2.0 * float(r & _U1))
        if rabs < _ZIG_KI[idx]:
            return x  # inside the layer's rectangle: about 99 % of draws
        if idx == 0:  # the tail beyond R (Marsaglia's method)
            while True:
                xx = -(1.0 / _ZIG_R) * math.log1p(-_unit(_word(key, stream, j)))
                yy = -math.log1p(-_unit(_word(key, stream, j + 1)))
                j += 2
                if yy + yy > xx * xx:
                    return -(_ZIG_R + xx) if (rabs >> 8) & 1 else _ZIG_R + xx
        f0 = _ZIG_FI[idx - 1]
        f1 = _ZIG_FI[idx]
        u = _unit(_word(key, stream, j))
        j += 1
        if (f0 - f1) * u + f1 < math.exp(-0.5 * x * x):
            return x  # under the curve in the layer's wedge


@njit(cache=_CACHE)
def normals(key, first, count):  # pragma: no cover
    """Streams ``first`` to ``first + count - 1`` of ``key``, one normal each (for tests)."""
    out = np.empty(count)
    k = np.uint64(key)
    for i in range(count):
        out[i] = normal(k, first + i)
    return out
