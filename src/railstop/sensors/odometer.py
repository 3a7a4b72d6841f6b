"""The onboard tachometer and odometer of SPEC §2, over arrays of runs.

SPEC §2: the onboard position comes from a tachometer counting wheel
revolutions; slip/slide and wheel wear make its error accumulate. Here:

- the wheel turns ``distance / (pi D_actual)`` times, times a creep factor:
  ``1 - slide_slip_ratio`` while sliding under braking (wheel-slide protection
  holds the deficit), ``1 + slip_ratio`` while slipping under traction
  (anti-slip control holds the excess), 1 otherwise;
- the tachometer gives ``pulses_per_rev`` pulses per revolution; the odometer
  counts whole pulses and converts them with the *assumed* diameter:
  ``odometer = pulses · pi D_assumed / pulses_per_rev``;
- the tachometer speed is the wheel's circumferential speed with the assumed
  diameter (no pulse quantisation: it is a filtered rate).

The accelerometer (beyond SPEC §2, the slide compensation of
``onboard.positioning``) reads the train's acceleration plus a bias of its
own, constant over a run (drawn once: ``accelerometer_bias_sd_mps2`` of the
vehicle's positioning; the gravity of the gradient is taken out with the line
data, what remains of it is in the bias).

Without creep and quantisation this is :func:`railstop.physics.train.odometer_increment_m`
summed; a test checks that.

One implementation (DESIGN rule 1, ``railstop.jit``): each formula is a compiled scalar core
(``creep_1``, ``revolutions_1``, ``odometer_1``, ``tacho_speed_1``); :class:`Tachometer`'s
methods run them over the runs in one compiled loop, and the line's position step
(``nodes.chain_step``) calls them inside its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.jit import floor_1, njit, njit_inline
from railstop.streams import RunStreams, Stream

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@njit_inline
def creep_1(sliding: bool, slipping: bool, slide_slip_ratio: float, traction_slip_ratio: float) -> float:
    """Wheel circumferential speed / train speed of one run: < 1 sliding, > 1 slipping, 1 rolling."""
    if sliding:
        return 1.0 - slide_slip_ratio
    if slipping:
        return 1.0 + traction_slip_ratio
    return 1.0


@njit_inline
def revolutions_1(revolutions: float, distance_m: float, creep: float, actual_diameter_m: float) -> float:
    """The wheel's revolutions after the train moved ``distance_m`` (true) with ``creep``."""
    return revolutions + distance_m * creep / (math.pi * actual_diameter_m)


@njit_inline
def odometer_1(revolutions: float, pulses_per_rev: int, assumed_diameter_m: float) -> float:
    """Odometer distance: whole pulses x pi D_assumed / pulses per revolution."""
    pulses = floor_1(revolutions * pulses_per_rev + 1e-9)
    return pulses * math.pi * assumed_diameter_m / pulses_per_rev


@njit_inline
def tacho_speed_1(
    true_speed_mps: float, creep: float, assumed_diameter_m: float, actual_diameter_m: float
) -> float:
    """Tachometer speed: wheel speed with the assumed diameter (scale D_assumed / D_actual)."""
    return true_speed_mps * creep * (assumed_diameter_m / actual_diameter_m)


@njit
def _creep_runs(
    sliding: BoolArray, slipping: BoolArray, slide_slip_ratio: float, traction_slip_ratio: float
) -> FloatArray:
    out = np.empty(sliding.size)
    for i in range(sliding.size):
        out[i] = creep_1(sliding[i], slipping[i], slide_slip_ratio, traction_slip_ratio)
    return out


@njit
def _advance_runs(
    revolutions: FloatArray, distance_m: FloatArray, creep: FloatArray, actual_diameter_m: FloatArray
) -> None:
    for i in range(revolutions.size):
        revolutions[i] = revolutions_1(revolutions[i], distance_m[i], creep[i], actual_diameter_m[i])


@njit
def _odometer_runs(
    revolutions: FloatArray, pulses_per_rev: int, assumed_diameter_m: FloatArray
) -> FloatArray:
    out = np.empty(revolutions.size)
    for i in range(revolutions.size):
        out[i] = odometer_1(revolutions[i], pulses_per_rev, assumed_diameter_m[i])
    return out


@njit
def _speed_runs(
    true_speed_mps: FloatArray,
    creep: FloatArray,
    assumed_diameter_m: FloatArray,
    actual_diameter_m: FloatArray,
) -> FloatArray:
    out = np.empty(true_speed_mps.size)
    for i in range(true_speed_mps.size):
        out[i] = tacho_speed_1(true_speed_mps[i], creep[i], assumed_diameter_m[i], actual_diameter_m[i])
    return out


def _runs(values: object, n: int, dtype: type = np.float64) -> NDArray:
    """One contiguous value per run (a scalar is broadcast)."""
    return np.ascontiguousarray(np.broadcast_to(np.asarray(values, dtype=dtype), (n,)))


def creep_factor(
    sliding: BoolArray, slipping: BoolArray, *, slide_slip_ratio: float, traction_slip_ratio: float
) -> FloatArray:
    """Wheel circumferential speed / train speed: < 1 sliding, > 1 slipping, 1 rolling."""
    sl, sp = np.broadcast_arrays(np.asarray(sliding, dtype=np.bool_), np.asarray(slipping, dtype=np.bool_))
    out = _creep_runs(
        np.ascontiguousarray(sl).ravel(),
        np.ascontiguousarray(sp).ravel(),
        slide_slip_ratio,
        traction_slip_ratio,
    )
    return out.reshape(sl.shape)


@dataclass(slots=True, kw_only=True)
class Tachometer:
    """Wheel revolutions, pulses and the odometer of n runs (in place)."""

    actual_diameter_m: FloatArray  # (n,)
    assumed_diameter_m: FloatArray  # (n,)
    pulses_per_rev: int
    revolutions: FloatArray  # (n,) since the start of the run

    @classmethod
    def create(
        cls, *, actual_diameter_m: FloatArray, assumed_diameter_m: FloatArray, pulses_per_rev: int
    ) -> Tachometer:
        actual = np.asarray(actual_diameter_m, dtype=np.float64)
        assumed = np.broadcast_to(np.asarray(assumed_diameter_m, dtype=np.float64), actual.shape).copy()
        if np.any(actual <= 0.0) or np.any(assumed <= 0.0):
            raise ValueError("wheel diameters must be positive")
        if pulses_per_rev < 1:
            raise ValueError(f"pulses_per_rev must be at least 1, got {pulses_per_rev}")
        return cls(
            actual_diameter_m=actual,
            assumed_diameter_m=assumed,
            pulses_per_rev=int(pulses_per_rev),
            revolutions=np.zeros_like(actual),
        )

    @property
    def scale(self) -> FloatArray:
        """Odometer metres per true metre while rolling: D_assumed / D_actual."""
        return self.assumed_diameter_m / self.actual_diameter_m

    def advance(self, distance_m: FloatArray, creep: FloatArray) -> None:
        """The train moved ``distance_m`` (true) with wheel creep factor ``creep`` (in place)."""
        n = self.revolutions.size
        _advance_runs(self.revolutions, _runs(distance_m, n), _runs(creep, n), self.actual_diameter_m)

    def odometer_m(self) -> FloatArray:
        """Odometer distance: whole pulses x pi D_assumed / pulses per revolution."""
        return _odometer_runs(self.revolutions, self.pulses_per_rev, self.assumed_diameter_m)

    def speed_mps(self, true_speed_mps: FloatArray, creep: FloatArray) -> FloatArray:
        """Tachometer speed: wheel speed with the assumed diameter."""
        n = self.revolutions.size
        return _speed_runs(
            _runs(true_speed_mps, n), _runs(creep, n), self.assumed_diameter_m, self.actual_diameter_m
        )


def accelerometer_bias_mps2(streams: RunStreams, bias_sd_mps2: float) -> FloatArray:
    """Each run's accelerometer bias (m/s²): normal, standard deviation ``bias_sd_mps2``."""
    return bias_sd_mps2 * streams.normal(Stream.ACCELEROMETER, 0)
