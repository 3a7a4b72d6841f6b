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
functions of :mod:`railstop.stream_cores` (``stream_key``, ``key_uniform``,
``key_normal``): bit-identical to the array methods (a test proves it). They
live apart so that what only reads data (``railstop check``, the disturbance
sets, the simulated media) imports no compiler.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

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
# The same numbers once more, as plain Python integers, for the units that run in the interpreter
# (the simulated media of link.channel): a numba function called from Python costs microseconds
# and a compilation, an integer mix a few hundred nanoseconds. Bit-identical to the above (a test).

_P_MASK = 0xFFFFFFFFFFFFFFFF
_P_GOLDEN = 0x9E3779B97F4A7C15
_P_M1 = 0xBF58476D1CE4E5B9
_P_M2 = 0x94D049BB133111EB


def py_mix64(z: int) -> int:
    """:func:`~railstop.stream_cores.mix64` on a Python integer in [0, 2^64)."""
    z = ((z ^ (z >> 30)) * _P_M1) & _P_MASK
    z = ((z ^ (z >> 27)) * _P_M2) & _P_MASK
    return z ^ (z >> 31)


def py_seed_key(seed: int, stream: int) -> int:
    """:func:`~railstop.stream_cores.seed_key` of ``seed`` (any int, reduced to 64 bits as
    :func:`seed_u64`)."""
    return py_mix64(((seed & _P_MASK) * _P_GOLDEN + stream) & _P_MASK)


def py_stream_key(seed_stream_key: int, run: int) -> int:
    """:func:`~railstop.stream_cores.stream_key`: run ``run``'s key of a stream (``run`` any int,
    taken mod 2^64)."""
    return py_mix64(seed_stream_key ^ (((run & _P_MASK) * _P_GOLDEN) & _P_MASK))


def py_fold(first: int, *more: int) -> int:
    """Integers folded into one well-mixed 64-bit number (e.g. a link's owner stream and identity,
    ``link.channel.LinkStreams.for_link``)."""
    h = py_mix64((first + 1) * _P_GOLDEN & _P_MASK)
    for x in more:
        h = py_mix64((h ^ (x & _P_MASK)) * _P_M1 & _P_MASK)
    return h


def py_key_bits(key: int, counter: int) -> int:
    """:func:`~railstop.stream_cores.key_bits`: the 64 bits of draw ``counter``."""
    return py_mix64((key + (counter + 1) * _P_GOLDEN) & _P_MASK)


def py_key_uniform(key: int, counter: int) -> float:
    """:func:`~railstop.stream_cores.key_uniform`: uniform in [0, 1)."""
    return (py_key_bits(key, counter) >> 11) * (1.0 / 9007199254740992.0)


def py_key_normal(key: int, counter: int) -> float:
    """:func:`~railstop.stream_cores.key_normal`: standard normal (Box–Muller on the two halves of
    one draw)."""
    bits = py_key_bits(key, counter)
    u1 = ((bits >> 32) + 0.5) * (1.0 / 4294967296.0)
    u2 = (bits & 0xFFFFFFFF) * (1.0 / 4294967296.0)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


def seed_u64(seed: int) -> np.uint64:
    """The seed as the 64-bit number the streams use."""
    return np.uint64(int(seed) & 0xFFFFFFFFFFFFFFFF)
