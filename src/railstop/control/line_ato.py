"""The train's own ATO between stations on the line with many trains (pure functions).

Between the station stops (where the ground TASC takes the train, SPEC §1)
the train runs under its own onboard control: it keeps below a speed
ceiling made of

- the **static profile**: the line's limit and the civil limits, each
  approached on a braking curve at the planning deceleration, and at every
  station the TASC zone's entry speed at the hand-over point (the train
  enters the zone at the speed the wayside's database expects);
- the **movement authority**: a braking curve to a few metres before the
  first signal ahead that shows stop (the fixed block's ATP).

Its demand is a speed-error law clipped between the planning deceleration
and what traction gives. **[interpretation]** SPEC §1 says only that the
train runs under its own control before the zone; this is the simplest
such law that respects the limits and the signals. The demand goes to the
train's plant (``physics.plant``): braking through the brakes' dead time,
jerk limit and lag, so the train runs up to a second behind its curve; the
curves at 70 % of full service (``sim.line.PLANNING_SHARE``) leave the rest
to catch up, and ``SIGNAL_MARGIN_M`` is far more than what it runs on.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import Line
from railstop.quantities import MPS_PER_KMH

FloatArray = NDArray[np.float64]

#: Resolution of the static profile (m).
PROFILE_DX_M = 1.0
#: A train the station cannot take yet (platform not clear) waits this far before the hand-over
#: point, so that it is back at speed when the stop takes it. [interpretation] a driver or ATO
#: would stop at the approach signal; here the signal stands at the first detector.
HOLD_BACK_M = 60.0
#: The ATO stops this far before a signal at stop, by its onboard position: more than that
#: position's error (SPEC §2 corrections through jointless circuits: p99 about 4 m, worst about
#: 7 m on the default line) so that the true front stays behind the signal. A front past it
#: would occupy the block the signal protects, keep the signal at stop and wait for ever.
SIGNAL_MARGIN_M = 15.0
#: Speed-error gain of the ATO's demand (1/s).
SPEED_GAIN_PER_S = 1.5
#: The ceiling is read this far ahead of the train (s at its speed): a speed-error law lags
#: its target by about the deceleration / gain, so without it the train would run that much
#: over a braking curve.
LOOKAHEAD_S = 1.0 / SPEED_GAIN_PER_S


def handover_m(first_detector_m: float, speed_mps: float) -> float:
    """Where the station stop takes the train over: 1.5 s (at least 20 m) before the first
    detector, as the stop model starts its runs (``railstop.model``)."""
    return first_detector_m - max(20.0, 1.5 * speed_mps)


def static_profile(line: Line, end_m: float, decel_mps2: float) -> FloatArray:
    """The speed ceiling (m/s) every ``PROFILE_DX_M`` from 0 to ``end_m``: the lower of the line's
    limit and the civil limits, with the stations' zone entry speeds at their hand-over points,
    each lower value approached on a braking curve at ``decel_mps2`` (a backward pass)."""
    n = int(np.ceil(end_m / PROFILE_DX_M)) + 1
    x = np.arange(n) * PROFILE_DX_M
    v = np.full(n, line.line.speed_limit_kmh * MPS_PER_KMH)
    for lim in line.speed_limits:
        # The front must be below the limit from its start; the rear until it has passed the
        # end is the train's business at the stop (the limits here are curves, not turnouts).
        inside = (x >= lim.start_m) & (x < lim.end_m)
        v[inside] = np.minimum(v[inside], lim.limit_kmh * MPS_PER_KMH)
    for st in line.stations:
        entry = st.tasc.entry_speed_kmh * MPS_PER_KMH
        k = round(handover_m(st.detector_positions_m()[0], entry) / PROFILE_DX_M)
        if 0 <= k < n:
            v[k] = min(v[k], entry)
    # Backward pass: v[i]^2 <= v[i+1]^2 + 2 a dx.
    v2 = v * v
    for i in range(n - 2, -1, -1):
        v2[i] = min(v2[i], v2[i + 1] + 2.0 * decel_mps2 * PROFILE_DX_M)
    return np.sqrt(v2)


def profile_at(profile: FloatArray, x_m: float) -> float:
    k = int(x_m / PROFILE_DX_M)
    return float(profile[min(max(k, 0), profile.size - 1)])


def stop_signal_m(front_m: float, signal_m: Sequence[float], proceed: Sequence[bool]) -> float:
    """Where the first signal ahead of ``front_m`` that shows stop stands (inf: none)."""
    for pos, ok in zip(signal_m, proceed, strict=True):
        if pos > front_m and not ok:
            return pos
    return np.inf


def authority_end_m(front_m: float, signal_m: Sequence[float], proceed: Sequence[bool]) -> float:
    """``SIGNAL_MARGIN_M`` before the first signal ahead of ``front_m`` that shows stop (inf: none)."""
    return authority_before_m(stop_signal_m(front_m, signal_m, proceed))


def authority_before_m(stop_signal_at_m: float) -> float:
    """The authority's end before a signal at stop at ``stop_signal_at_m`` (``SIGNAL_MARGIN_M``
    short of it; inf: none): :func:`authority_end_m` of a signal already found."""
    return stop_signal_at_m - SIGNAL_MARGIN_M


def ceiling_mps(
    profile: FloatArray, front_m: float, speed_mps: float, authority_m: float, decel_mps2: float
) -> float:
    """The speed the train may have now: its static ceiling and the braking curve to the
    authority's end, both read ``LOOKAHEAD_S`` ahead."""
    ahead = front_m + speed_mps * LOOKAHEAD_S
    static_mps = min(profile_at(profile, front_m), profile_at(profile, ahead))
    to_go = authority_m - ahead
    if to_go <= 0.0:
        return 0.0
    return min(static_mps, math.sqrt(2.0 * decel_mps2 * to_go))


def demand_mps2(speed_mps: float, ceiling: float, traction_mps2: float, brake_mps2: float) -> float:
    """The ATO's acceleration demand: towards the ceiling, at most what traction gives, at least
    -``brake_mps2`` (full service: the ceiling is planned at less, so the curve can be held).
    Aiming 0.5 km/h under the ceiling keeps it from riding the limit."""
    target = ceiling - 0.5 * MPS_PER_KMH
    return min(max(SPEED_GAIN_PER_S * (target - speed_mps), -brake_mps2), traction_mps2)
