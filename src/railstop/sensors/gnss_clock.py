"""GNSS-disciplined clocks of SPEC §2, over arrays of clocks.

SPEC §2: "GNSS is used only for time". Both the wayside position-correction
device and the onboard device have a GNSS receiver that disciplines their
clock; satellite-signal repeaters in GNSS shadows (tunnels) keep it
synchronised. The model of one clock:

- disciplined (GNSS visible, or a repeater covers the shadow): the error
  (reading - true time) is a small residual, drawn per clock as
  normal(0, ``disciplined_error_s``) (~100 ns: negligible for positioning);
- free-running (a shadow without a repeater, or GNSS switched off): the error
  grows at the clock's frequency offset ``drift`` (s/s), drawn per clock as
  normal(0, ``free_run_drift_ppm`` · 1e-6): ``e(t) = e(t_loss) + drift · (t - t_loss)``;
- a clock that had no time source when the run started (a wayside unit
  inside an unrepeated tunnel, every clock with GNSS off) was last set
  ``holdover_s`` earlier: its error at t = 0 is ``drift · holdover_s``;
- when GNSS returns the clock is disciplined again at once
  **[interpretation]**: a real receiver slews over seconds, but the error it
  removes is then microseconds, below anything this model resolves.

Every array may have any shape: (n,) for the onboard clock of n runs, (n, C)
for the wayside clocks of C track circuits. Randomness comes from
``RunStreams`` (DESIGN rule 7): ``Stream.CLOCK`` counter ``2 k`` gives clock
k's drift, ``2 k + 1`` its disciplined residual.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import GnssClocks
from railstop.streams import RunStreams, Stream

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

PPM = 1e-6


@dataclass(slots=True, kw_only=True)
class GnssClock:
    """Clocks that are disciplined or free-running, advanced in place with the simulation."""

    residual_s: FloatArray  # error while disciplined
    drift: FloatArray  # frequency offset while free-running (s/s)
    error_s: FloatArray  # current error: reading - true time
    disciplined: BoolArray  # current state

    @classmethod
    def create(
        cls,
        data: GnssClocks,
        streams: RunStreams,
        *,
        clock_index: NDArray[np.int64],
        disciplined: BoolArray,
        t0_s: float = 0.0,
    ) -> GnssClock:
        """Clocks number ``clock_index`` (shape (k,)) of every run: arrays of shape (n, k).

        ``disciplined`` (broadcast to (n, k)) is the state at ``t0_s``; a clock
        that is not disciplined then had no time source for ``holdover_s``.
        """
        idx = np.asarray(clock_index, dtype=np.int64)
        n, k = streams.n, idx.size
        drift = np.empty((n, k))
        resid = np.empty((n, k))
        for j, c in enumerate(idx):  # k is small (a few dozen clocks)
            drift[:, j] = data.free_run_drift_ppm * PPM * streams.normal(Stream.CLOCK, 2 * int(c))
            resid[:, j] = data.disciplined_error_s * streams.normal(Stream.CLOCK, 2 * int(c) + 1)
        disc = np.broadcast_to(np.asarray(disciplined, dtype=bool), (n, k)).copy()
        # SPEC §2: without a time source the clock free-runs; it was last set holdover_s ago.
        error = np.where(disc, resid, drift * (data.holdover_s + t0_s))
        return cls(residual_s=resid, drift=drift, error_s=error, disciplined=disc)

    def advance(self, dt_s: float, disciplined: BoolArray) -> None:
        """Move on by ``dt_s``; ``disciplined`` says which clocks have GNSS time during the step."""
        disc = np.asarray(disciplined, dtype=bool)
        if disc.shape != self.error_s.shape:
            disc = np.broadcast_to(disc, self.error_s.shape)
        # SPEC §2: in a shadow without a repeater the clock free-runs and drifts.
        self.error_s = np.where(disc, self.residual_s, self.error_s + self.drift * dt_s)
        self.disciplined = np.array(disc)

    def read(self, true_time_s: float | FloatArray) -> FloatArray:
        """The clocks' readings at ``true_time_s`` (their current error)."""
        return np.asarray(true_time_s, dtype=np.float64) + self.error_s


def in_sections(x_m: FloatArray, sections: list[tuple[float, float]]) -> BoolArray:
    """Which positions ``x_m`` (float64) lie in one of the ``sections``, each a (start, end) pair
    of [start, end) (e.g. tunnels without repeaters: the GNSS shadows)."""
    out = np.zeros(x_m.shape, dtype=bool)
    for start, end in sections:
        out |= (x_m >= start) & (x_m < end)  # a line has a few tunnels: one pass each
    return out
