"""Track-circuit occupancy detection of SPEC §2, over arrays of runs.

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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import TrackCircuit, TrackCircuitDetection
from railstop.sensors.wayside import crossing_time_s
from railstop.streams import RunStreams, Stream

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


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
    """The wayside track-circuit devices of a line, for n runs."""

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
        n, c_count = streams.n, len(circuits)
        starts = np.array([c.start_m for c in circuits], dtype=np.float64)
        boundary = np.empty((n, c_count))
        delay = np.empty((n, c_count))
        for j, circ in enumerate(circuits):
            sd = detection.boundary_sd_m(circ.kind)
            boundary[:, j] = circ.start_m + sd * streams.normal(Stream.TC_BOUNDARY, j)
            z = streams.normal(Stream.TC_DELAY, j)
            delay[:, j] = np.maximum(0.0, detection.delay_mean_s + detection.delay_spread_s * z)
        x0 = np.broadcast_to(np.asarray(start_position_m, dtype=np.float64), (n,))
        # The train already occupies every circuit that starts at or before its front.
        first = np.searchsorted(starts, x0, side="right").astype(np.int64)
        return cls(
            ids=np.array([c.id for c in circuits], dtype=np.int64),
            starts_m=starts,
            boundary_m=boundary,
            delay_s=delay,
            next_index=first,
        )

    def detect(
        self, *, x0_m: FloatArray, v0_mps: FloatArray, accel_mps2: FloatArray, x1_m: FloatArray, t0_s: float
    ) -> OccupancyEvents:
        """SPEC §2 S10: circuits entered during the step from t0 (front at x0) to the next (x1)."""
        n, c_count = self.boundary_m.shape
        rows_all = np.arange(n)
        runs: list[IntArray] = []
        idxs: list[IntArray] = []
        times: list[FloatArray] = []
        while True:
            has = self.next_index < c_count
            j = np.minimum(self.next_index, c_count - 1)
            target = self.boundary_m[rows_all, j]
            crossed = has & (x1_m >= target)
            if not crossed.any():
                break
            r = np.flatnonzero(crossed)
            jj = j[r]
            dt = crossing_time_s(x0_m[r], v0_mps[r], accel_mps2[r], np.maximum(target[r], x0_m[r]))
            runs.append(r)
            idxs.append(jj)
            times.append(t0_s + dt)
            self.next_index = np.where(crossed, self.next_index + 1, self.next_index)
        if not runs:
            empty_i = np.zeros(0, dtype=np.int64)
            empty_f = np.zeros(0)
            return OccupancyEvents(
                run=empty_i, circuit_index=empty_i, entry_time_s=empty_f, occupied_time_s=empty_f
            )
        run = np.concatenate(runs)
        idx = np.concatenate(idxs)
        entry = np.concatenate(times)
        return OccupancyEvents(
            run=run,
            circuit_index=idx,
            entry_time_s=entry,
            occupied_time_s=entry + self.delay_s[run, idx],
        )
