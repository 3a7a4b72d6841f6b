"""Configuration 3 at waveform level (SPEC §1 claims 15, 25; patent fig. 9).

The train's brake system drives the ECU with a PWM brake signal (lines e, f).
The onboard signal control unit does not cut that line: a zero-crossing
detector (260) finds the instants the train's signal rises, the onboard
controller (220) starts its own pulses at those instants, and the brake
signal output (230) puts them on the same input, so the ECU sees the OR of
the two. Pulses that start together overlap, and the ECU sees the larger duty
("existing 50 % + onboard 70 % -> 70 %"); pulses out of phase would add up to
more than either.

This module is the reference at sample level, pure numpy: a waveform is a
boolean array over a time grid. The stop kernel uses the equivalent scalar
rule (``receiver_pwm_output_1``: the larger duty, latched once per carrier
period); a test checks one against the other.

**[interpretation]** SPEC §1 says "zero crossing" of the PWM signal; for a
unipolar PWM line that is the edge where the signal leaves zero, the start of
each pulse. With no train pulses (duty 0) there is nothing to lock to: the
onboard unit then runs on its own carrier clock from its last lock.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def time_grid(carrier_hz: float, periods: int, samples_per_period: int = 1000) -> FloatArray:
    """Sample instants covering ``periods`` carrier periods."""
    if carrier_hz <= 0.0 or periods < 1 or samples_per_period < 2:
        raise ValueError("time_grid needs carrier_hz > 0, periods >= 1 and samples_per_period >= 2")
    n = periods * samples_per_period
    return np.arange(n, dtype=np.float64) / (carrier_hz * samples_per_period)


def pwm_wave(duty: float, carrier_hz: float, t: FloatArray, phase_s: float = 0.0) -> BoolArray:
    """A PWM signal of ``duty`` (0..1) whose pulses start at ``phase_s`` + k periods."""
    if not 0.0 <= duty <= 1.0:
        raise ValueError(f"duty {duty} is outside 0..1")
    period = 1.0 / carrier_hz
    into = np.mod(t - phase_s, period)
    # A sample belongs to the pulse when it is less than duty x period into its period (a
    # tolerance of a millionth of a period absorbs the grid's rounding).
    return into < duty * period - 1e-6 * period


def zero_crossings(wave: BoolArray, t: FloatArray) -> FloatArray:
    """The zero-crossing detector: the instants the signal leaves zero (rising edges). A signal
    already high when the record starts has no edge there: the detector sees transitions only."""
    rising = np.flatnonzero(~wave[:-1] & wave[1:]) + 1
    return t[rising]


def synchronised_wave(duty: float, carrier_hz: float, t: FloatArray, edges: FloatArray) -> BoolArray:
    """The onboard pulses: each starts at a detected edge of the train's signal; where a
    period passes without one, the onboard clock goes on from the last lock (the module
    docstring)."""
    if not 0.0 <= duty <= 1.0:
        raise ValueError(f"duty {duty} is outside 0..1")
    period = 1.0 / carrier_hz
    starts: list[float] = []
    clock = float(t[0]) if edges.size == 0 else float(edges[0])
    if edges.size:
        # Before the first lock the onboard clock runs back from it, period by period.
        k = np.floor((clock - t[0]) / period)
        clock -= k * period
    j = 0
    end = float(t[-1]) + period
    while clock < end:
        # Lock to the train's next edge when one comes within this period (with a tolerance of
        # half a period: the detector's edge is the reference).
        while j < edges.size and edges[j] < clock - 0.5 * period:
            j += 1
        if j < edges.size and abs(edges[j] - clock) <= 0.5 * period:
            clock = float(edges[j])
            j += 1
        starts.append(clock)
        clock += period
    s = np.asarray(starts)
    idx = np.searchsorted(s, t, side="right") - 1
    into = np.where(idx >= 0, t - s[np.maximum(idx, 0)], np.inf)
    return into < duty * period - 1e-6 * period


def superimpose(existing: BoolArray, onboard: BoolArray) -> BoolArray:
    """What the ECU input sees: the OR of the two pulse trains (SPEC §1 claim 25)."""
    return existing | onboard


def duty_per_period(wave: BoolArray, carrier_hz: float, t: FloatArray) -> FloatArray:
    """The duty the ECU measures in each whole carrier period of the grid."""
    period = 1.0 / carrier_hz
    index = np.floor((t - t[0]) / period + 1e-9).astype(np.int64)
    n = int(index[-1])  # the last (possibly partial) period is left out
    keep = index < n
    high = np.bincount(index[keep], weights=wave[keep].astype(np.float64), minlength=n)
    count = np.bincount(index[keep], minlength=n)
    return high / np.maximum(count, 1)
