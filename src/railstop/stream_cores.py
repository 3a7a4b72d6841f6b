"""The counter-based random streams' scalar cores, compiled (:mod:`railstop.streams`, DESIGN rule 7).

The compiled model draws the numbers of :class:`railstop.streams.RunStreams` one at a time: the
same SplitMix64 mix of (seed, stream, run, counter), the same uniforms and Box–Muller normals,
bit-identical to the array methods and to the interpreter's integers (``py_*``; a test proves
it), and the ziggurat normals of the Doppler noise. Apart from :mod:`railstop.streams` so that
what only reads data imports no compiler (issue 37: start-up).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from railstop.jit import njit_inline

_U_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_U_M1 = np.uint64(0xBF58476D1CE4E5B9)
_U_M2 = np.uint64(0x94D049BB133111EB)
_U_MASK = np.uint64(0xFFFFFFFFFFFFFFFF)
_U_LOW32 = np.uint64(0xFFFFFFFF)


@njit_inline
def mix64(z: np.uint64) -> np.uint64:
    """The SplitMix64 finaliser (``railstop.streams._mix`` on one number)."""
    z = (z ^ (z >> np.uint64(30))) * _U_M1
    z = (z ^ (z >> np.uint64(27))) * _U_M2
    return z ^ (z >> np.uint64(31))


@njit_inline
def seed_key(seed: np.uint64, stream: int | np.integer) -> np.uint64:
    """The key of (seed, stream), common to every run; ``seed`` already reduced to 64 bits."""
    return mix64(seed * _U_GOLDEN + np.uint64(stream))


@njit_inline
def stream_key(seed_stream_key: np.uint64, run: int | np.integer) -> np.uint64:
    """Run ``run``'s key of a stream (``railstop.streams.RunStreams._key``)."""
    return mix64(seed_stream_key ^ (np.uint64(run) * _U_GOLDEN))


@njit_inline
def key_bits(key: np.uint64, counter: int | np.integer) -> np.uint64:
    return mix64(key + (np.uint64(counter) + np.uint64(1)) * _U_GOLDEN)


@njit_inline
def key_uniform(key: np.uint64, counter: int | np.integer) -> float:
    """Uniform in [0, 1): ``railstop.streams.RunStreams.uniform`` of one run."""
    return float(key_bits(key, counter) >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit_inline
def key_normal(key: np.uint64, counter: int | np.integer) -> float:
    """Standard normal: ``railstop.streams.RunStreams.normal`` of one run (Box–Muller on the two halves)."""
    bits = key_bits(key, counter)
    u1 = (float(bits >> np.uint64(32)) + 0.5) * (1.0 / 4294967296.0)
    u2 = float(bits & _U_LOW32) * (1.0 / 4294967296.0)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


# The ziggurat of the standard normal (Marsaglia & Tsang 2000, "The ziggurat method for generating
# random variables", J. Stat. Softw. 5(8)), 256 layers of equal area V under f(x) = exp(-x²/2):
# layer 0 is the base strip [0, R] x [0, f(R)] plus the tail beyond R, drawn as a rectangle of
# width V/f(R); layer i >= 1 spans [0, X[i]] x [f(X[i]), f(X[i+1])], X[1] = R, X[256] = 0.
ZIGGURAT_LAYERS = 256
ZIGGURAT_R = 3.6541528853610088
ZIGGURAT_V = 4.92867323399e-3


def _ziggurat_tables() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    x = np.empty(ZIGGURAT_LAYERS + 1)
    x[0] = ZIGGURAT_V / math.exp(-0.5 * ZIGGURAT_R * ZIGGURAT_R)
    x[1] = ZIGGURAT_R
    for i in range(1, ZIGGURAT_LAYERS - 1):
        # f(X[i+1]) = V/X[i] + f(X[i]): the next layer has the same area.
        y = ZIGGURAT_V / x[i] + math.exp(-0.5 * x[i] * x[i])
        x[i + 1] = math.sqrt(-2.0 * math.log(y))
    x[ZIGGURAT_LAYERS] = 0.0
    return x, np.exp(-0.5 * x * x)


_ZIG_X, _ZIG_F = _ziggurat_tables()


@njit_inline
def _next_bits(bits: np.uint64) -> np.uint64:
    """The next 64 bits of a draw that needs more than one (a keyed SplitMix64 step)."""
    return mix64(bits + _U_GOLDEN)


@njit_inline
def key_normal_zig(key: np.uint64, counter: int | np.integer) -> float:
    """Standard normal by the ziggurat (about 99 % of draws: one 64-bit word, a multiply and a
    compare; no log or cos). Stream definition of kernel model version 3 (Doppler noise).

    Bits of a word: 0-7 the layer, 8 the sign, 11-63 the uniform in [0, 1). A draw that leaves
    the layer's inner rectangle continues with further words of the same keyed sequence.
    """
    bits = key_bits(key, counter)
    while True:
        layer = int(bits & np.uint64(0xFF))
        sign = 1.0 if (bits >> np.uint64(8)) & np.uint64(1) else -1.0
        u = float(bits >> np.uint64(11)) * (1.0 / 9007199254740992.0)
        x = u * _ZIG_X[layer]
        if x < _ZIG_X[layer + 1]:
            return sign * x
        bits = _next_bits(bits)
        if layer == 0:
            # The tail beyond R (Marsaglia 1964): x = -ln(u1)/R, y = -ln(u2), accept if 2y > x².
            while True:
                u1 = (float(bits >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)
                bits = _next_bits(bits)
                u2 = (float(bits >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)
                bits = _next_bits(bits)
                t = -math.log(u1) / ZIGGURAT_R
                if -2.0 * math.log(u2) > t * t:
                    return sign * (ZIGGURAT_R + t)
        # The wedge between the layer's inner rectangle and the curve.
        y = _ZIG_F[layer] + float(bits >> np.uint64(11)) * (1.0 / 9007199254740992.0) * (
            _ZIG_F[layer + 1] - _ZIG_F[layer]
        )
        if y < math.exp(-0.5 * x * x):
            return sign * x
        bits = _next_bits(bits)
