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

One implementation (DESIGN rule 1, ``railstop.jit``): a clock's step and the shadow test are
compiled scalar cores (``clock_error_1``, ``in_sections_1``); :class:`GnssClock` and
:func:`in_sections` run them over their arrays, the line's position step (``nodes.chain_step``)
inside its own loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import GnssClocks
from railstop.jit import njit, njit_inline
from railstop.streams import RunStreams, Stream

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

PPM = 1e-6


@njit_inline
def clock_error_1(error_s: float, residual_s: float, drift: float, disciplined: bool, dt_s: float) -> float:
    """One clock's error after ``dt_s``: its residual while disciplined, else it drifts on."""
    if disciplined:
        return residual_s
    return error_s + drift * dt_s  # SPEC §2: in a shadow without a repeater the clock free-runs


@njit_inline
def in_sections_1(x_m: float, sections: FloatArray) -> bool:
    """Whether ``x_m`` lies in one of the ``sections`` ((k, 2): [start, end) rows)."""
    for j in range(sections.shape[0]):  # noqa: SIM110 (numba compiles no generator)
        if x_m >= sections[j, 0] and x_m < sections[j, 1]:
            return True
    return False


@njit
def _advance_clocks(
    error_s: FloatArray, residual_s: FloatArray, drift: FloatArray, disciplined: BoolArray, dt_s: float
) -> None:
    for i in range(error_s.size):
        error_s[i] = clock_error_1(error_s[i], residual_s[i], drift[i], disciplined[i], dt_s)


@njit
def _in_sections_runs(x_m: FloatArray, sections: FloatArray) -> BoolArray:
    out = np.empty(x_m.size, dtype=np.bool_)
    for i in range(x_m.size):
        out[i] = in_sections_1(x_m[i], sections)
    return out


def sections_array(sections: list[tuple[float, float]]) -> FloatArray:
    """(start, end) pairs as the (k, 2) array the compiled cores take."""
    return np.array(sections, dtype=np.float64).reshape(-1, 2)


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
        error = np.ascontiguousarray(np.where(disc, resid, drift * (data.holdover_s + t0_s)))
        return cls(residual_s=resid, drift=drift, error_s=error, disciplined=disc)

    def advance(self, dt_s: float, disciplined: BoolArray) -> None:
        """Move on by ``dt_s``; ``disciplined`` says which clocks have GNSS time during the step."""
        disc = np.ascontiguousarray(np.broadcast_to(np.asarray(disciplined, dtype=bool), self.error_s.shape))
        _advance_clocks(
            self.error_s.reshape(-1),
            self.residual_s.reshape(-1),
            self.drift.reshape(-1),
            disc.reshape(-1),
            float(dt_s),
        )
        self.disciplined = np.array(disc)

    def read(self, true_time_s: float | FloatArray) -> FloatArray:
        """The clocks' readings at ``true_time_s`` (their current error)."""
        return np.asarray(true_time_s, dtype=np.float64) + self.error_s


def in_sections(x_m: FloatArray, sections: list[tuple[float, float]]) -> BoolArray:
    """Which positions ``x_m`` (float64) lie in one of the ``sections``, each a (start, end) pair
    of [start, end) (e.g. tunnels without repeaters: the GNSS shadows)."""
    x = np.ascontiguousarray(x_m, dtype=np.float64)
    return _in_sections_runs(x.reshape(-1), sections_array(sections)).reshape(x.shape)
