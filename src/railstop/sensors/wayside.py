"""Wayside measurements of SPEC §1: wheel-sensor passages.

SPEC §1 train detection unit: detectors at fixed chainages, first (farthest)
first. A detector reports the passage of the train front (its first axle)
with a timing jitter, and misses the train with some probability; the stop
kernel (``railstop.model``) draws both, and the Doppler radar's speed
samples with their relative noise, from the run's random streams.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from railstop.jit import njit_inline

FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------
# Compiled scalar cores (railstop.jit): the one implementation the stop kernel runs.


@njit_inline
def crossing_time_1(x0_m: float, v0_mps: float, accel_mps2: float, target_m: float) -> float:
    """Time after the start of a step at which x0 + v0 t + a t²/2 reaches ``target_m``.

    Exact for the constant acceleration of one step. ``accel_mps2`` is signed
    (negative when braking).
    """
    d = target_m - x0_m
    disc = max(v0_mps * v0_mps + 2.0 * accel_mps2 * d, 0.0)
    # Root of a/2 t² + v0 t - d = 0, written to stay accurate as a -> 0.
    denom = v0_mps + math.sqrt(disc)
    return 2.0 * d / denom if denom > 0.0 else 0.0


@njit_inline
def passage_1(positions_m: FloatArray, next_index: int, x0_m: float, x1_m: float) -> bool:
    """Does the step from x0 to x1 cross the next detector (at most one per step: detectors are
    metres apart, a step covers centimetres)?"""
    return (
        next_index < positions_m.size and x0_m < positions_m[next_index] and x1_m >= positions_m[next_index]
    )
