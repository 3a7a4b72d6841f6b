"""Wayside measurements of SPEC §1: wheel-sensor passages and Doppler radar samples."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.jit import njit_inline
from railstop.streams import RunStreams, Stream

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


def crossing_time_s(
    x0_m: FloatArray, v0_mps: FloatArray, accel_mps2: FloatArray, target_m: FloatArray
) -> FloatArray:
    """Time after the start of a step at which x0 + v0 t + a t²/2 reaches the target.

    Exact for the constant acceleration of one step. ``accel`` is signed
    (negative when braking).
    """
    d = target_m - x0_m
    a = accel_mps2
    disc = np.maximum(v0_mps * v0_mps + 2.0 * a * d, 0.0)
    # Root of a/2 t² + v0 t - d = 0, written to stay accurate as a -> 0.
    denom = v0_mps + np.sqrt(disc)
    return np.where(denom > 0.0, 2.0 * d / np.where(denom > 0.0, denom, 1.0), 0.0)


@dataclass(slots=True, kw_only=True)
class WheelSensors:
    """SPEC §1 train detection unit: detectors at fixed chainages, first (farthest) first.

    A detector reports the passage of the train front (its first axle) with a
    timing jitter; with ``miss_probability`` it misses the train entirely.
    """

    positions_m: FloatArray  # (D,)
    jitter_s: FloatArray  # (n,) standard deviation
    miss_probability: FloatArray  # (n,)
    next_index: IntArray  # (n,) next detector each run will reach

    @classmethod
    def create(
        cls, positions_m: FloatArray, jitter_s: FloatArray, miss_probability: FloatArray
    ) -> WheelSensors:
        n = np.asarray(jitter_s).size
        return cls(
            positions_m=np.asarray(positions_m, dtype=np.float64),
            jitter_s=np.asarray(jitter_s, dtype=np.float64),
            miss_probability=np.asarray(miss_probability, dtype=np.float64),
            next_index=np.zeros(n, dtype=np.int64),
        )

    def detect(
        self,
        *,
        x0_m: FloatArray,
        v0_mps: FloatArray,
        accel_mps2: FloatArray,
        x1_m: FloatArray,
        t0_s: float,
        streams: RunStreams,
    ) -> tuple[BoolArray, IntArray, FloatArray]:
        """Passages during the step from t0 (position x0) to the next step (x1).

        Returns (reported mask, detector index, reported passage time). At most
        one detector is crossed per step (detectors are metres apart, a step
        covers centimetres).
        """
        n_det = self.positions_m.size
        has_next = self.next_index < n_det
        idx = np.minimum(self.next_index, n_det - 1)
        target = self.positions_m[idx]
        crossed = has_next & (x0_m < target) & (x1_m >= target)
        if not crossed.any():
            return crossed, idx, np.zeros_like(x0_m)
        # Only the crossing runs draw (the draws are per run and counter, so
        # this changes no run's numbers).
        rows = np.flatnonzero(crossed)
        sub = streams.subset(rows)
        t_report = np.zeros_like(x0_m)
        t_report[rows] = (
            t0_s
            + crossing_time_s(x0_m[rows], v0_mps[rows], accel_mps2[rows], target[rows])
            + self.jitter_s[rows] * sub.normal(Stream.SENSOR_JITTER, idx[rows])
        )
        reported = crossed.copy()
        reported[rows] = sub.uniform(Stream.SENSOR_MISS, idx[rows]) >= self.miss_probability[rows]
        self.next_index[rows] += 1
        return reported, idx, t_report


def doppler_sample(
    speed_mps: FloatArray, noise_frac: FloatArray, streams: RunStreams, sample_index: int
) -> FloatArray:
    """SPEC §1 speed detection unit: one Doppler speed sample with relative noise."""
    noise = streams.normal(Stream.DOPPLER, sample_index)
    return speed_mps * (1.0 + noise_frac * noise)


# --------------------------------------------------------------------------
# Compiled scalar cores (railstop.jit): the one implementation the stop kernel runs.


@njit_inline
def crossing_time_1(x0_m: float, v0_mps: float, accel_mps2: float, target_m: float) -> float:
    """:func:`crossing_time_s` of one run: when x0 + v0 t + a t²/2 reaches ``target_m``."""
    d = target_m - x0_m
    disc = max(v0_mps * v0_mps + 2.0 * accel_mps2 * d, 0.0)
    denom = v0_mps + np.sqrt(disc)
    return 2.0 * d / denom if denom > 0.0 else 0.0


@njit_inline
def passage_1(positions_m: FloatArray, next_index: int, x0_m: float, x1_m: float) -> bool:
    """Does the step from x0 to x1 cross the next detector (at most one per step)?"""
    return (
        next_index < positions_m.size and x0_m < positions_m[next_index] and x1_m >= positions_m[next_index]
    )
