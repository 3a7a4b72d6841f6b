"""Track-circuit occupancy detection of SPEC §2: compiled per-run cores and the array wrapper.

SPEC §2 S10: the wayside track-circuit device emits occupancy information
when a train occupies a track circuit. A circuit becomes occupied when the
train's first axle shunts it, i.e. when the train front (the leading axle's
known, constant offset from the front is taken as folded into the surveyed
chainage) crosses the circuit's electrical boundary; the device declares it a
detection delay later. Both are uncertain (values in line data,
``TrackCircuitDetection``; reasons in docs/position.md):

- boundary: the electrical boundary of run r and circuit c lies at
  ``start_c + sd_kind · z`` (z standard normal, ``Stream.TC_BOUNDARY``
  counter c): the tuned zone of a jointless circuit spreads it over metres,
  an insulated joint hardly at all;
- delay: ``max(0, mean + spread · z)`` (``Stream.TC_DELAY`` counter c).

Only *entries* into a circuit the train did not occupy when the run started
make events (the train moves in the +chainage direction only).

One implementation (DESIGN rule 1, ``railstop.jit``): the state of one run is
its boundaries ``boundary_m`` (C,), its delays ``delay_s`` (C,) and the index
of the next circuit it will enter. :func:`tc_draw_run` fills the first two at
create time, :func:`tc_first_index` gives the third, :func:`tc_next_entry`
finds the next entry during a step. :class:`TrackCircuitDetector` holds the
same state for n runs, shape (n, C), and loops over the runs in compiled code.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import TrackCircuit, TrackCircuitDetection
from railstop.jit import njit, njit_inline, njit_step
from railstop.sensors.wayside import crossing_time_1
from railstop.stream_cores import key_normal, seed_key, stream_key
from railstop.streams import RunStreams, Stream, seed_u64

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

_TC_BOUNDARY = int(Stream.TC_BOUNDARY)
_TC_DELAY = int(Stream.TC_DELAY)


# --------------------------------------------------------------------------
# Compiled per-run cores


@njit_step
def tc_draw_run(
    starts_m: FloatArray,
    boundary_sd_m: FloatArray,
    delay_mean_s: float,
    delay_spread_s: float,
    boundary_key: np.uint64,
    delay_key: np.uint64,
    boundary_m: FloatArray,
    delay_s: FloatArray,
) -> None:
    """Create-time draws of one run: its electrical boundaries and detection delays (SPEC §2 S10).

    ``starts_m``, ``boundary_sd_m``: (C,) surveyed starts and boundary
    uncertainty of each circuit (line order); ``boundary_key``/``delay_key``:
    the run's keys of ``Stream.TC_BOUNDARY``/``Stream.TC_DELAY``
    (``stream_key(seed_key(seed, stream), run)``). Fills ``boundary_m`` and
    ``delay_s`` (C,), the numbers ``RunStreams`` gives that run.
    """
    for j in range(starts_m.size):
        c = np.int64(j)  # the counter is the circuit index
        boundary_m[j] = starts_m[j] + boundary_sd_m[j] * key_normal(boundary_key, c)
        d = delay_mean_s + delay_spread_s * key_normal(delay_key, c)
        delay_s[j] = 0.0 if d <= 0.0 else d  # np.maximum(0, d): NaN stays NaN
    return


@njit_step
def tc_first_index(starts_m: FloatArray, x0_m: float) -> int:
    """The first circuit a run starting at x0 will enter: it occupies every one starting at or before it."""
    return int(np.searchsorted(starts_m, x0_m, side="right"))


@njit_inline
def tc_next_entry(
    boundary_m: FloatArray,
    delay_s: FloatArray,
    next_index: int,
    x0_m: float,
    v0_mps: float,
    accel_mps2: float,
    x1_m: float,
    t0_s: float,
) -> tuple[bool, float, float]:
    """SPEC §2 S10 for one run: did it enter circuit ``next_index`` during the step from t0 (front
    at x0) to the next (x1)? Returns (entered, true entry time, time the device declares it occupied).

    A step may enter several circuits: the caller advances ``next_index`` and asks again.
    """
    if next_index >= boundary_m.size:
        return False, np.nan, np.nan
    target = boundary_m[next_index]
    if not x1_m >= target:
        return False, np.nan, np.nan
    # An electrical boundary drawn behind the front's position at the step's start is entered then.
    aim = target if (target >= x0_m or target != target) else x0_m
    entry = t0_s + crossing_time_1(x0_m, v0_mps, accel_mps2, aim)
    return True, entry, entry + delay_s[next_index]


# --------------------------------------------------------------------------
# The same for n runs, one compiled loop per call


@njit
def _draw_runs(
    starts_m: FloatArray,
    boundary_sd_m: FloatArray,
    delay_mean_s: float,
    delay_spread_s: float,
    seed: np.uint64,
    run_index: IntArray,
    x0_m: FloatArray,
    boundary_m: FloatArray,
    delay_s: FloatArray,
    next_index: IntArray,
) -> None:
    b_key = seed_key(seed, np.int64(_TC_BOUNDARY))
    d_key = seed_key(seed, np.int64(_TC_DELAY))
    for i in range(run_index.size):
        run = run_index[i]
        tc_draw_run(
            starts_m,
            boundary_sd_m,
            delay_mean_s,
            delay_spread_s,
            stream_key(b_key, run),
            stream_key(d_key, run),
            boundary_m[i],
            delay_s[i],
        )
        next_index[i] = tc_first_index(starts_m, x0_m[i])
    return


@njit
def detect_runs(
    boundary_m: FloatArray,
    delay_s: FloatArray,
    next_index: IntArray,
    x0_m: FloatArray,
    v0_mps: FloatArray,
    accel_mps2: FloatArray,
    x1_m: FloatArray,
    t0_s: float,
) -> tuple[IntArray, IntArray, FloatArray, FloatArray, IntArray]:
    """Every run's entries during the step, run by run: (run, circuit, entry, occupied, pass)."""
    n = next_index.size
    count = 0
    for i in range(n):
        j = next_index[i]
        while True:
            found = tc_next_entry(
                boundary_m[i], delay_s[i], j, x0_m[i], v0_mps[i], accel_mps2[i], x1_m[i], t0_s
            )
            if not found[0]:
                break
            j += 1
            count += 1
    run = np.empty(count, dtype=np.int64)
    idx = np.empty(count, dtype=np.int64)
    entry = np.empty(count)
    occupied = np.empty(count)
    pas = np.empty(count, dtype=np.int64)
    k = 0
    for i in range(n):
        p = 0
        while True:
            j = next_index[i]
            hit, te, to = tc_next_entry(
                boundary_m[i], delay_s[i], j, x0_m[i], v0_mps[i], accel_mps2[i], x1_m[i], t0_s
            )
            if not hit:
                break
            run[k] = i
            idx[k] = j
            entry[k] = te
            occupied[k] = to
            pas[k] = p
            k += 1
            p += 1
            next_index[i] = j + 1
    return run, idx, entry, occupied, pas


# --------------------------------------------------------------------------
# Array wrapper


def circuit_arrays(
    circuits: list[TrackCircuit] | tuple[TrackCircuit, ...], detection: TrackCircuitDetection
) -> tuple[IntArray, FloatArray, FloatArray]:
    """(ids, surveyed starts, boundary uncertainty) of the line's circuits, in line order."""
    ids = np.array([c.id for c in circuits], dtype=np.int64)
    starts = np.array([c.start_m for c in circuits], dtype=np.float64)
    sds = np.array([detection.boundary_sd_m(c.kind) for c in circuits], dtype=np.float64)
    return ids, starts, sds


@dataclass(frozen=True, slots=True, kw_only=True)
class OccupancyEvents:
    """Circuits that became occupied during one step: one row per event (k events)."""

    run: IntArray  # (k,) row of the run in the batch
    circuit_index: IntArray  # (k,) index into the line's circuit list
    entry_time_s: FloatArray  # (k,) true time the first axle crossed the electrical boundary
    occupied_time_s: FloatArray  # (k,) true time the device declares the circuit occupied

    @property
    def size(self) -> int:
        return int(self.run.size)


@dataclass(slots=True, kw_only=True)
class TrackCircuitDetector:
    """The wayside track-circuit devices of a line, for n runs (the per-run state of n runs)."""

    ids: IntArray  # (C,)
    starts_m: FloatArray  # (C,) surveyed starts
    boundary_m: FloatArray  # (n, C) electrical boundaries of each run
    delay_s: FloatArray  # (n, C) detection delay of each run's passage
    next_index: IntArray  # (n,) next circuit each run will enter (C = none left)

    @classmethod
    def create(
        cls,
        circuits: list[TrackCircuit],
        detection: TrackCircuitDetection,
        streams: RunStreams,
        *,
        start_position_m: FloatArray,
    ) -> TrackCircuitDetector:
        if not circuits:
            raise ValueError("no track circuits: the line has no [track] circuits")
        n = streams.n
        ids, starts, sds = circuit_arrays(circuits, detection)
        boundary = np.empty((n, starts.size))
        delay = np.empty((n, starts.size))
        first = np.empty(n, dtype=np.int64)
        x0 = np.array(np.broadcast_to(np.asarray(start_position_m, dtype=np.float64), (n,)))
        _draw_runs(
            starts,
            sds,
            float(detection.delay_mean_s),
            float(detection.delay_spread_s),
            seed_u64(streams.seed),
            np.ascontiguousarray(streams.run_index, dtype=np.int64),
            x0,
            boundary,
            delay,
            first,
        )
        return cls(ids=ids, starts_m=starts, boundary_m=boundary, delay_s=delay, next_index=first)

    def detect(
        self, *, x0_m: FloatArray, v0_mps: FloatArray, accel_mps2: FloatArray, x1_m: FloatArray, t0_s: float
    ) -> OccupancyEvents:
        """SPEC §2 S10: circuits entered during the step from t0 (front at x0) to the next (x1).

        Events come pass by pass (every run's first entry of the step, then
        every second one, ...), runs in order within a pass.
        """

        def f(a: FloatArray) -> FloatArray:
            return np.ascontiguousarray(a, dtype=np.float64)

        run, idx, entry, occupied, pas = detect_runs(
            self.boundary_m,
            self.delay_s,
            self.next_index,
            f(x0_m),
            f(v0_mps),
            f(accel_mps2),
            f(x1_m),
            float(t0_s),
        )
        return events_of(run, idx, entry, occupied, pas)


def events_of(
    run: IntArray, idx: IntArray, entry: FloatArray, occupied: FloatArray, pas: IntArray
) -> OccupancyEvents:
    """The events of one step as the compiled detection found them (run by run), pass by pass."""
    if pas.size and pas.max() > 0:
        order = np.argsort(pas, kind="stable")
        run, idx, entry, occupied = run[order], idx[order], entry[order], occupied[order]
    return OccupancyEvents(run=run, circuit_index=idx, entry_time_s=entry, occupied_time_s=occupied)
