"""Online identification of the brake response from the Doppler radar, compiled.

SPEC §1 plans each command "allowing for the brake's dead time and lag" but
gives no way to know them; the wayside's database holds the nominal values of
the stock. An older or tired train (dead time to 0.8 s, build-up lag to
0.9 s, a slower radio) then brakes later than the plan assumes, the loop gain
absorbs the late build-up as weak brakes, and the train stops short (the
median stop of the wide disturbance set was 0.28 m short for dead times over
0.67 s, 0.38 m for lags over 0.77 s). **[interpretation]** beyond the
document (issue 13 item 6): the wayside identifies the response from the
speed it measures once the first braking command has acted, and plans the
rest of the stop with it.

The model is the one the planner uses: every change of command relaxes as a
first-order lag ``lag`` that starts ``delay - lag`` after the command was sent
(``delay`` = radio latency + dead time + lag, the equivalent dead time), plus
half the jerk-limited ramp. Integrated once, the speed is

    v(t) = v0 - e·(t - t_brake)⁺ - g · Σ_j Δc_j · F(t - t0_j; lag),
    F(u; λ) = u - λ (1 - exp(-u/λ)) for u > 0,

with ``e`` the modelled gradient and running resistance from the first
braking command on (the train held its speed with traction before), ``Δc_j``
the commanded steps and ``g`` the loop gain. For a candidate (delay, lag) the
model is linear in (v0, g): the candidate's residual sum of squares over the
radar's samples is a closed form of six running sums. The estimate is a
maximum a posteriori one: that residual over the radar's noise variance
(taken from the samples' second differences) plus a Gaussian prior around
the nominal response, which keeps noisy records from wandering along the
valley where a later onset trades against a shorter lag. The search is a
coarse grid over (onset, lag) on every tenth sample, a 3 x 3 fine grid
around its best point on every second one, and a parabola through the fine
grid's best point and its neighbours along each axis. The Doppler samples of
a few seconds around the first step are enough: a 0.1 s error of the delay
moves the speed after the build-up by about 0.07 m/s at 0.7 m/s², against
0.5 % radar noise averaged over a few hundred samples. The exponentials are
carried from sample to sample by one multiplication, and nothing is
allocated, so one identification costs about 20 µs.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from railstop.control.tasc import GAIN_MAX, GAIN_MIN, HISTORY
from railstop.jit import njit_step

FloatArray = NDArray[np.float64]

#: The coarse grid of the delay before the build-up starts (radio latency + dead time, s) and of
#: the build-up lag (s), wider than the wide disturbance set; the fine grid around its best
#: point has this step, two either side.
ONSET_COARSE = np.arange(0.0, 1.5, 0.2)
LAG_COARSE = np.arange(0.2, 1.3, 0.2)
FINE_STEP_S = 0.1
#: Every this many radar samples is used on the coarse grid and on the fine one (a 10 ms
#: radar: one sample per 100 ms, then per 20 ms).
COARSE_STRIDE = 10
FINE_STRIDE = 2
#: The identification needs a command that steps the braking by this much (m/s²).
MIN_STEP_MPS2 = 0.1
#: It runs this long after that command (the build-up of the slowest brakes is then in the
#: samples) over the radar's samples from this long before it.
AFTER_S = 5.0
BEFORE_S = 0.5
#: The prior on the response: the nominal one, with these standard deviations (s). A window
#: of noisy samples tells the onset and the lag apart less well than their sum; the prior
#: keeps an estimate from wandering along that valley to the grid's edge.
ONSET_PRIOR_SD_S = 0.4
LAG_PRIOR_SD_S = 0.25
#: Where the fine grid's criteria go in the scratch array (after the running exponentials of
#: the commands and the noise variance and prior).
FINE = HISTORY + 3


@njit_step
def noise_variance_1(ring: FloatArray, newest: int, count: int) -> float:
    """The radar's noise variance per sample, from second differences of the newest ``count``
    samples (white noise of variance σ² gives second differences of variance 6σ²; the train's
    own change of speed over two sample periods is negligible beside it)."""
    size = ring.size
    total = 0.0
    n = 0
    at = newest
    y0 = ring[at]
    at = at - 1 if at > 0 else size - 1
    y1 = ring[at]
    for _ in range(count - 2):
        at = at - 1 if at > 0 else size - 1
        y2 = ring[at]
        if y0 > 0.0 and y1 > 0.0 and y2 > 0.0:
            d = y0 - 2.0 * y1 + y2
            total += d * d
            n += 1
        y0 = y1
        y1 = y2
    return total / (6.0 * n) if n > 0 else np.nan


@njit_step
def response_misfit_1(
    ring: FloatArray,
    newest: int,
    count: int,
    dt_s: float,
    now_s: float,
    braking_from_s: float,
    external_mps2: float,
    values: FloatArray,
    effects: FloatArray,
    shift_s: float,
    lag_s: float,
    stride: int,
    scratch: FloatArray,
) -> tuple[float, float]:
    """(residual sum of squares, loop gain) of every ``stride``-th of the newest ``count`` radar
    samples in ``ring``
    against the commands ``values`` whose effect times ``effects`` are moved by ``shift_s`` and
    whose build-up has the time constant ``lag_s``. A gain outside the loop's bounds, or too few
    samples, gives an infinite residual. Samples of 0 (the train outside the radar's range) do
    not count. ``scratch`` (at least HISTORY long) holds each step's exp(-u/lag), carried from
    sample to sample by one multiplication (the samples are equally spaced)."""
    size = ring.size
    steps = 0
    for j in range(HISTORY):
        if not math.isfinite(effects[j]):
            break
        scratch[j] = np.nan
        steps += 1
    decay = math.exp(-stride * dt_s / lag_s)
    n = 0.0
    sx = 0.0
    sxx = 0.0
    sz = 0.0
    szz = 0.0
    sxz = 0.0
    oldest = ((count - 1) // stride) * stride
    for a in range(oldest, -1, -stride):  # oldest to newest
        t = now_s - a * dt_s
        q = 0.0
        prev = 0.0
        for j in range(steps):
            u = t - (effects[j] + shift_s - lag_s)
            if u > 0.0:
                e = scratch[j]
                e = math.exp(-u / lag_s) if math.isnan(e) else e * decay
                scratch[j] = e
                q += (values[j] - prev) * (u - lag_s * (1.0 - e))
            prev = values[j]
        at = newest - a
        y = ring[at if at >= 0 else at + size]
        if y <= 0.0:
            continue
        z = y + external_mps2 * max(t - braking_from_s, 0.0)
        x = -q
        n += 1.0
        sx += x
        sxx += x * x
        sz += z
        szz += z * z
        sxz += x * z
    if n < 10.0:
        return np.inf, np.nan
    cxx = sxx - sx * sx / n
    cxz = sxz - sx * sz / n
    czz = szz - sz * sz / n
    if cxx <= 1e-9:
        return np.inf, np.nan
    gain = cxz / cxx
    if gain < GAIN_MIN or gain > GAIN_MAX:
        return np.inf, gain
    return max(czz - cxz * cxz / cxx, 0.0), gain


@njit_step
def _misfit_at_1(
    ring: FloatArray,
    newest: int,
    count: int,
    dt_s: float,
    now_s: float,
    braking_from_s: float,
    external_mps2: float,
    values: FloatArray,
    effects: FloatArray,
    delay_s: float,
    onset_s: float,
    lag_s: float,
    stride: int,
    scratch: FloatArray,
) -> tuple[float, float]:
    """The criterion of the candidate (onset, lag) for commands planned with ``delay_s``: the
    residual in units of the noise variance ``scratch[HISTORY]`` plus the prior's penalty around
    the nominal (onset, lag) in ``scratch[HISTORY + 1 : HISTORY + 3]``; and its loop gain."""
    f, g = response_misfit_1(
        ring, newest, count, dt_s, now_s, braking_from_s, external_mps2,
        values, effects, onset_s + lag_s - delay_s, lag_s, stride, scratch,
    )  # fmt: skip
    d_on = (onset_s - scratch[HISTORY + 1]) / ONSET_PRIOR_SD_S
    d_lag = (lag_s - scratch[HISTORY + 2]) / LAG_PRIOR_SD_S
    # The residual of every stride-th sample, in units of the noise variance per sample.
    return f / scratch[HISTORY] + d_on * d_on + d_lag * d_lag, g


@njit_step
def _fine_1(
    ring: FloatArray,
    newest: int,
    count: int,
    dt_s: float,
    now_s: float,
    braking_from_s: float,
    external_mps2: float,
    values: FloatArray,
    effects: FloatArray,
    delay_s: float,
    c_on: float,
    c_lag: float,
    i: int,
    j: int,
    scratch: FloatArray,
) -> tuple[float, float]:
    """Criterion and gain at the point (i, j) of the fine grid around the coarse best (c_on,
    c_lag), index 1 its centre; infinite outside the allowed candidates (onset < 0, lag < 0.1)."""
    onset = c_on + (i - 1) * FINE_STEP_S
    lag = c_lag + (j - 1) * FINE_STEP_S
    if onset < 0.0 or lag < 0.1:
        return np.inf, np.nan
    return _misfit_at_1(ring, newest, count, dt_s, now_s, braking_from_s, external_mps2,
                        values, effects, delay_s, onset, lag, FINE_STRIDE, scratch)  # fmt: skip


@njit_step
def _neighbour_1(
    ring: FloatArray,
    newest: int,
    count: int,
    dt_s: float,
    now_s: float,
    braking_from_s: float,
    external_mps2: float,
    values: FloatArray,
    effects: FloatArray,
    delay_s: float,
    c_on: float,
    c_lag: float,
    i: int,
    j: int,
    scratch: FloatArray,
) -> float:
    """The criterion at fine-grid point (i, j): kept in ``scratch`` inside the 3 x 3 grid, else
    computed (:func:`_fine_1`)."""
    if 0 <= i <= 2 and 0 <= j <= 2:
        return float(scratch[FINE + 3 * i + j])
    f, _ = _fine_1(ring, newest, count, dt_s, now_s, braking_from_s, external_mps2,
                   values, effects, delay_s, c_on, c_lag, i, j, scratch)  # fmt: skip
    return f


@njit_step
def _parabola_min_1(x1: float, step: float, f0: float, f1: float, f2: float) -> float:
    """Abscissa of the minimum of the parabola through (x1 - step, f0), (x1, f1), (x1 + step, f2)
    (x1 if the three do not bracket a minimum)."""
    if not (math.isfinite(f0) and math.isfinite(f1) and math.isfinite(f2)):
        return x1
    curv = f0 - 2.0 * f1 + f2
    if curv <= 0.0 or f1 > f0 or f1 > f2:
        return x1
    return x1 + 0.5 * step * (f0 - f2) / curv


@njit_step
def identify_response_1(
    ring: FloatArray,
    newest: int,
    count: int,
    dt_s: float,
    now_s: float,
    braking_from_s: float,
    external_mps2: float,
    values: FloatArray,
    effects: FloatArray,
    delay_s: float,
    nominal_delay_s: float,
    nominal_lag_s: float,
    scratch: FloatArray,
) -> tuple[float, float, float]:
    """The brake response that best explains the radar's samples: (delay, lag, gain).

    ``effects`` are the command effect times the wayside planned with the equivalent dead time
    ``delay_s``; a candidate (onset, lag) moves them by ``onset + lag - delay_s``. The criterion
    is the residual over the noise variance plus a Gaussian prior around the nominal response
    (a maximum a posteriori estimate). The search is a coarse grid over (onset, lag), a fine
    grid around its best point, then a parabola through the fine grid's best point and its
    neighbours along each axis. NaNs when the samples say nothing (no noise estimate) or no
    candidate explains them with a gain inside the loop's bounds: the caller keeps what it
    assumed. ``scratch`` needs FINE + 9 places."""
    var = noise_variance_1(ring, newest, count)
    if not (var > 0.0):
        return np.nan, np.nan, np.nan
    scratch[HISTORY] = var
    scratch[HISTORY + 1] = nominal_delay_s - nominal_lag_s
    scratch[HISTORY + 2] = nominal_lag_s
    best = np.inf
    c_on = np.nan
    c_lag = np.nan
    for onset in ONSET_COARSE:
        for lag in LAG_COARSE:
            f, _ = _misfit_at_1(ring, newest, count, dt_s, now_s, braking_from_s, external_mps2,
                                values, effects, delay_s, onset, lag, COARSE_STRIDE, scratch)  # fmt: skip
            if f < best:
                best, c_on, c_lag = f, onset, lag
    if not math.isfinite(best):
        return np.nan, np.nan, np.nan
    # The fine grid: 3 x 3 around the coarse best at FINE_STEP_S, its criteria kept in
    # scratch[FINE + 3 i + j] for the parabolas.
    best = np.inf
    bi = 1
    bj = 1
    gain = np.nan
    for i in range(3):
        for j in range(3):
            f, g = _fine_1(ring, newest, count, dt_s, now_s, braking_from_s, external_mps2,
                           values, effects, delay_s, c_on, c_lag, i, j, scratch)  # fmt: skip
            scratch[FINE + 3 * i + j] = f
            if f < best:
                best, bi, bj, gain = f, i, j, g
    if not math.isfinite(best):
        return np.nan, np.nan, np.nan
    # A parabola along each axis through the best point and its neighbours (from the fine grid,
    # or one more candidate where the best point is on its edge).
    on_lo = _neighbour_1(ring, newest, count, dt_s, now_s, braking_from_s, external_mps2,
                         values, effects, delay_s, c_on, c_lag, bi - 1, bj, scratch)  # fmt: skip
    on_hi = _neighbour_1(ring, newest, count, dt_s, now_s, braking_from_s, external_mps2,
                         values, effects, delay_s, c_on, c_lag, bi + 1, bj, scratch)  # fmt: skip
    lag_lo = _neighbour_1(ring, newest, count, dt_s, now_s, braking_from_s, external_mps2,
                          values, effects, delay_s, c_on, c_lag, bi, bj - 1, scratch)  # fmt: skip
    lag_hi = _neighbour_1(ring, newest, count, dt_s, now_s, braking_from_s, external_mps2,
                          values, effects, delay_s, c_on, c_lag, bi, bj + 1, scratch)  # fmt: skip
    onset_fit = _parabola_min_1(c_on + (bi - 1) * FINE_STEP_S, FINE_STEP_S, on_lo, best, on_hi)
    lag_fit = _parabola_min_1(c_lag + (bj - 1) * FINE_STEP_S, FINE_STEP_S, lag_lo, best, lag_hi)
    return onset_fit + lag_fit, lag_fit, gain
