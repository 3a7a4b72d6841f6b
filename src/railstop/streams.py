"""Counter-based random streams, one per run (DESIGN rule 7, adapted).

Every random number a run uses is a pure function of (seed, run index,
stream, counter): the i-th Doppler noise sample of run 1234 is the same
whether run 1234 is simulated alone, in a chunk of 10,000 or on another
worker. That is what "same seed -> same numbers whatever the chunk size"
needs, and it stays fully vectorised: drawing from per-run
``numpy.random.Generator`` objects would cost tens of microseconds per run.

The mixing function is the SplitMix64 finaliser applied to a per-run stream
key (seed, stream, run; cached) and then to that key plus the counter;
uniforms take the top 53 bits, normals use Box–Muller on the two 32-bit
halves of one draw.

The compiled model draws the same numbers one at a time with the scalar
functions at the end of this module (:func:`stream_key`, :func:`key_uniform`,
:func:`key_normal`): bit-identical to the array methods (a test proves it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from railstop.jit import njit_inline

#: Run numbers (and seeds) are signed 64-bit integers in the streams and the Parquet rows.
RUN_LIMIT = 2**63
#: What every seed check says (a seed outside the range would silently stand for another one).
SEED_RANGE = "must be between -2^63 and 2^63 - 1, the range of the random streams"


def seed_in_range(seed: int) -> bool:
    return -RUN_LIMIT <= seed < RUN_LIMIT


_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)


class Stream(IntEnum):
    """Independent streams of a run; the counter indexes draws within one."""

    DISTURBANCE = 1
    SENSOR_JITTER = 2
    SENSOR_MISS = 3
    DOPPLER = 4
    RADIO_LOSS = 5
    RADIO_LATENCY = 6
    ADHESION = 7
    TC_BOUNDARY = 8  # SPEC §2 track-circuit electrical boundary, counter = circuit index
    TC_DELAY = 9  # SPEC §2 track-circuit detection delay, counter = circuit index
    CLOCK = 10  # SPEC §2 GNSS clocks: counter 2k drift, 2k + 1 disciplined residual of clock k
    RADIO_CYCLE = 11  # SPEC §5 poll-cycle phase of a telegram attempt, counter = attempt
    RADIO_CORRUPT = 12  # bit errors of an attempt: counter 2k corrupted?, 2k + 1 which bit
    CERTIFY = 13  # rare-event certification: counter 0 mixture component, 1 + j cube coordinate j
    ACCELEROMETER = 14  # the odometry's accelerometer: counter 0 its bias
    DOOR_LINK = 15  # SPEC §5 door link of a dwell: a generator per (seed, train, dwell)
    CBTC_RADIO = 16  # SPEC §4 train radio: a generator per (seed, train, direction); counter 0.. faults
    DRIVER = 17  # SPEC §3 the human driver of a run: counter 0 level, 1.. parameters, looks, re-stops
    STOP_SENSORS = 18  # SPEC §3 platform stop sensors at a stand: counter 2k S2, 2k + 1 S1 of stand k
    PLATFORM_DWELL = 19  # SPEC §3 a manual line's dwell: a generator per (seed, dwell); sensors, camera
    LINK_FAULTS = 20  # SPEC §5 medium, frame c: 4c burst chain, 4c+1 burst loss, 4c+2 dup, 4c+3 reorder
    LINK_FLIPS = 21  # SPEC §5 bit errors of frame c's copy j: a key per 2c + j, counter 0.. (link.channel)
    OCCUPANCY_LINK = 22  # SPEC §2 occupancy telegrams: a radio per (seed, train) (nodes.occupancy_chain)


def _mix(z: NDArray[np.uint64]) -> NDArray[np.uint64]:
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@dataclass(frozen=True, slots=True)
class RunStreams:
    """Random streams for a set of runs of one seed."""

    seed: int
    run_index: NDArray[np.int64]
    _keys: dict[int, NDArray[np.uint64]] = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def for_runs(cls, seed: int, first_run: int, n: int) -> RunStreams:
        return cls(seed=int(seed), run_index=np.arange(first_run, first_run + n, dtype=np.int64))

    @property
    def n(self) -> int:
        return int(self.run_index.size)

    def subset(self, rows: NDArray[np.bool_] | NDArray[np.int64]) -> RunStreams:
        """The streams of some runs (a mask or row indices); their numbers do not change."""
        return RunStreams(seed=self.seed, run_index=self.run_index[rows])

    def _key(self, stream: int) -> NDArray[np.uint64]:
        """The per-run key of one stream (a pure function of seed, stream and run index)."""
        z = self._keys.get(stream)
        if z is None:
            with np.errstate(over="ignore"):
                key = _mix(
                    np.asarray(np.uint64(self.seed & 0xFFFFFFFFFFFFFFFF) * _GOLDEN + np.uint64(stream))
                )
                z = _mix(key ^ (self.run_index.astype(np.uint64) * _GOLDEN))
            self._keys[stream] = z
        return z

    def _bits(self, stream: int, counter: int | NDArray[np.int64]) -> NDArray[np.uint64]:
        z = self._key(stream)
        with np.errstate(over="ignore"):
            c = np.asarray(counter, dtype=np.int64).astype(np.uint64)
            return _mix(z + (c + np.uint64(1)) * _GOLDEN)

    def uniform(self, stream: int, counter: int | NDArray[np.int64]) -> NDArray[np.float64]:
        """Uniform in [0, 1), one per run."""
        bits = self._bits(stream, counter)
        return (bits >> _S11).astype(np.float64) * (1.0 / 9007199254740992.0)

    def normal(self, stream: int, counter: int | NDArray[np.int64]) -> NDArray[np.float64]:
        """Standard normal, one per run: Box–Muller on the two 32-bit halves of draw ``counter``.

        Normals and uniforms of one stream share counters: a stream uses one kind.
        """
        bits = self._bits(stream, counter)
        u1 = ((bits >> np.uint64(32)).astype(np.float64) + 0.5) * (1.0 / 4294967296.0)  # (0, 1)
        u2 = (bits & np.uint64(0xFFFFFFFF)).astype(np.float64) * (1.0 / 4294967296.0)
        # The C library's log and cos, as the interpreter's draws (py_key_normal: link.channel) and
        # the compiled model's take them: numpy's vectorised loops may round the last bit otherwise
        # (seed 4542, run 4542, DOOR_LINK, counter 25439: -0.07626570307426442 against ...443).
        two_pi = 2.0 * math.pi
        pairs = zip(u1.ravel().tolist(), u2.ravel().tolist(), strict=True)
        out = np.fromiter(
            (math.sqrt(-2.0 * math.log(a)) * math.cos(two_pi * b) for a, b in pairs),
            dtype=np.float64,
            count=u1.size,
        )
        return out.reshape(u1.shape)


# --------------------------------------------------------------------------
# The same numbers, one at a time, for the compiled model (railstop.jit).

_U_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_U_M1 = np.uint64(0xBF58476D1CE4E5B9)
_U_M2 = np.uint64(0x94D049BB133111EB)
_U_MASK = np.uint64(0xFFFFFFFFFFFFFFFF)
_U_LOW32 = np.uint64(0xFFFFFFFF)


@njit_inline
def mix64(z: np.uint64) -> np.uint64:
    """The SplitMix64 finaliser (:func:`_mix` on one number)."""
    z = (z ^ (z >> np.uint64(30))) * _U_M1
    z = (z ^ (z >> np.uint64(27))) * _U_M2
    return z ^ (z >> np.uint64(31))


@njit_inline
def seed_key(seed: np.uint64, stream: int | np.integer) -> np.uint64:
    """The key of (seed, stream), common to every run; ``seed`` already reduced to 64 bits."""
    return mix64(seed * _U_GOLDEN + np.uint64(stream))


@njit_inline
def stream_key(seed_stream_key: np.uint64, run: int | np.integer) -> np.uint64:
    """Run ``run``'s key of a stream (``RunStreams._key``)."""
    return mix64(seed_stream_key ^ (np.uint64(run) * _U_GOLDEN))


@njit_inline
def key_bits(key: np.uint64, counter: int | np.integer) -> np.uint64:
    return mix64(key + (np.uint64(counter) + np.uint64(1)) * _U_GOLDEN)


@njit_inline
def key_uniform(key: np.uint64, counter: int | np.integer) -> float:
    """Uniform in [0, 1): ``RunStreams.uniform`` of one run."""
    return float(key_bits(key, counter) >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit_inline
def key_normal(key: np.uint64, counter: int | np.integer) -> float:
    """Standard normal: ``RunStreams.normal`` of one run (Box–Muller on the two halves)."""
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


# --------------------------------------------------------------------------
# The same numbers once more, as plain Python integers, for the units that run in the interpreter
# (the simulated media of link.channel): a numba function called from Python costs microseconds
# and a compilation, an integer mix a few hundred nanoseconds. Bit-identical to the above (a test).

_P_MASK = 0xFFFFFFFFFFFFFFFF
_P_GOLDEN = 0x9E3779B97F4A7C15
_P_M1 = 0xBF58476D1CE4E5B9
_P_M2 = 0x94D049BB133111EB


def py_mix64(z: int) -> int:
    """:func:`mix64` on a Python integer in [0, 2^64)."""
    z = ((z ^ (z >> 30)) * _P_M1) & _P_MASK
    z = ((z ^ (z >> 27)) * _P_M2) & _P_MASK
    return z ^ (z >> 31)


def py_seed_key(seed: int, stream: int) -> int:
    """:func:`seed_key` of ``seed`` (any int, reduced to 64 bits as :func:`seed_u64`)."""
    return py_mix64(((seed & _P_MASK) * _P_GOLDEN + stream) & _P_MASK)


def py_stream_key(seed_stream_key: int, run: int) -> int:
    """:func:`stream_key`: run ``run``'s key of a stream (``run`` any int, taken mod 2^64)."""
    return py_mix64(seed_stream_key ^ (((run & _P_MASK) * _P_GOLDEN) & _P_MASK))


def py_fold(first: int, *more: int) -> int:
    """Integers folded into one well-mixed 64-bit number (e.g. a link's owner stream and identity,
    ``link.channel.LinkStreams.for_link``)."""
    h = py_mix64((first + 1) * _P_GOLDEN & _P_MASK)
    for x in more:
        h = py_mix64((h ^ (x & _P_MASK)) * _P_M1 & _P_MASK)
    return h


def py_key_bits(key: int, counter: int) -> int:
    """:func:`key_bits`: the 64 bits of draw ``counter``."""
    return py_mix64((key + (counter + 1) * _P_GOLDEN) & _P_MASK)


def py_key_uniform(key: int, counter: int) -> float:
    """:func:`key_uniform`: uniform in [0, 1)."""
    return (py_key_bits(key, counter) >> 11) * (1.0 / 9007199254740992.0)


def py_key_normal(key: int, counter: int) -> float:
    """:func:`key_normal`: standard normal (Box–Muller on the two halves of one draw)."""
    bits = py_key_bits(key, counter)
    u1 = ((bits >> 32) + 0.5) * (1.0 / 4294967296.0)
    u2 = (bits & 0xFFFFFFFF) * (1.0 / 4294967296.0)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


def seed_u64(seed: int) -> np.uint64:
    """The seed as the 64-bit number the streams use."""
    return np.uint64(int(seed) & 0xFFFFFFFFFFFFFFFF)
