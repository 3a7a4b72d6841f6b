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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.streams import RunStreams, Stream

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def creep_factor(
    sliding: BoolArray, slipping: BoolArray, *, slide_slip_ratio: float, traction_slip_ratio: float
) -> FloatArray:
    """Wheel circumferential speed / train speed: < 1 sliding, > 1 slipping, 1 rolling."""
    return np.where(sliding, 1.0 - slide_slip_ratio, np.where(slipping, 1.0 + traction_slip_ratio, 1.0))


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
        """The train moved ``distance_m`` (true) with wheel creep factor ``creep``."""
        self.revolutions = self.revolutions + distance_m * creep / (np.pi * self.actual_diameter_m)

    def odometer_m(self) -> FloatArray:
        """Odometer distance: whole pulses x pi D_assumed / pulses per revolution."""
        pulses = np.floor(self.revolutions * self.pulses_per_rev + 1e-9)
        return pulses * np.pi * self.assumed_diameter_m / self.pulses_per_rev

    def speed_mps(self, true_speed_mps: FloatArray, creep: FloatArray) -> FloatArray:
        """Tachometer speed: wheel speed with the assumed diameter."""
        return true_speed_mps * creep * self.scale


def accelerometer_bias_mps2(streams: RunStreams, bias_sd_mps2: float) -> FloatArray:
    """Each run's accelerometer bias (m/s²): normal, standard deviation ``bias_sd_mps2``."""
    return bias_sd_mps2 * streams.normal(Stream.ACCELEROMETER, 0)
