"""The track's gradient as the stop model takes it: piecewise constant, common breakpoints, a row of
values per run (pure numpy, so that the data layer and the CLI need no compiler)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class GradientProfile:
    """Piecewise-constant gradient, common breakpoints, per-run values (permille, + uphill).

    ``values`` has shape (n, len(breakpoints) + 1): column j holds the gradient
    between breakpoint j-1 and j (column 0 before the first breakpoint).
    """

    breakpoints_m: FloatArray
    values_permille: FloatArray
    _elev_at_bp: FloatArray  # (n, B) elevation (m) at each breakpoint, 0 at the first

    @classmethod
    def create(cls, breakpoints_m: FloatArray, values_permille: FloatArray) -> GradientProfile:
        bp = np.asarray(breakpoints_m, dtype=np.float64)
        vals = np.atleast_2d(np.asarray(values_permille, dtype=np.float64))
        if vals.shape[1] != bp.size + 1:
            raise ValueError("gradient values need one column more than breakpoints")
        if bp.size and np.any(np.diff(bp) <= 0):
            raise ValueError("gradient breakpoints must increase")
        rise = vals[:, 1:-1] * 1e-3 * np.diff(bp)[None, :]
        elev = np.concatenate([np.zeros((vals.shape[0], 1)), np.cumsum(rise, axis=1)], axis=1)
        return cls(breakpoints_m=bp, values_permille=vals, _elev_at_bp=elev)

    @classmethod
    def from_segments(cls, segments: Iterable[Any], n: int = 1) -> GradientProfile:
        """The profile of gradient segments (``start_m``, ``end_m``, ``permille``; level between
        them) for ``n`` runs; a ``ValueError`` when two overlap."""
        bps: list[float] = []
        vals: list[float] = [0.0]
        for seg in sorted(segments, key=lambda s: s.start_m):
            if bps and seg.start_m < bps[-1] - 1e-9:
                raise ValueError(f"segments overlap at {seg.start_m} m (one ends at {bps[-1]} m)")
            if bps and abs(bps[-1] - seg.start_m) < 1e-9:
                vals[-1] = seg.permille
            else:
                bps.append(seg.start_m)
                vals.append(seg.permille)
            bps.append(seg.end_m)
            vals.append(0.0)
        values = np.tile(np.asarray(vals, dtype=np.float64), (n, 1))
        return cls.create(np.asarray(bps, dtype=np.float64), values)

    def elevation_m(self, x_m: FloatArray, rows: NDArray[np.int64] | None = None) -> FloatArray:
        """Elevation (m) at chainage ``x_m`` for each run (or the runs ``rows``)."""
        vals = self.values_permille if rows is None else self.values_permille[rows]
        elev = self._elev_at_bp if rows is None else self._elev_at_bp[rows]
        x = np.asarray(x_m, dtype=np.float64)
        r = np.arange(vals.shape[0]).reshape((-1,) + (1,) * (x.ndim - 1))
        bp = self.breakpoints_m
        if bp.size == 0:
            return vals[r, 0] * 1e-3 * x
        idx = np.searchsorted(bp, x)  # 0..B
        base_i = np.maximum(idx - 1, 0)
        grad = vals[r, idx] * 1e-3
        return elev[r, base_i] + grad * (x - bp[base_i])

    def mean_gradient(
        self, front_m: FloatArray, length_m: float, rows: NDArray[np.int64] | None = None
    ) -> FloatArray:
        """Mean gradient (fraction, + uphill) under a train of ``length_m`` whose front is at x.

        Averaging over the train's length is exact for the gradient force on a
        uniformly loaded train and keeps the force continuous at a gradient change.
        """
        return (self.elevation_m(front_m, rows) - self.elevation_m(front_m - length_m, rows)) / length_m
