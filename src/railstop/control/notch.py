"""Realising a continuous deceleration with the 7 service notches (SPEC §1).

A step-controlled brake has only B1..B7. A brake controller that must follow
a continuous target alternates between the two notches either side of it,
with the time shares that make the mean equal the target: a sigma-delta
modulator, with a minimum hold time so the brake line is not chattered. The
actuator's lag smooths the alternation.

Near standstill the alternation no longer averages out: a notch held through
the last second or two moves the stopping point by (notch step) × t² / 2,
tenths of a metre. In that end phase the modulator knows the train's speed
(every brake controller has it from the tachometer) and picks, among the two
notches, the one whose predicted stop lies nearest to where the target would
stop the train (a two-move look-ahead: this notch for the minimum hold, then
either notch until standstill).
**[interpretation]** SPEC §1 leaves the brake controller's own logic open;
this is railstop's model of a competent one.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from railstop.control.tasc import clip_1
from railstop.jit import njit_step

FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------
# Compiled scalar cores (railstop.jit): the one implementation of the modulator.
#
# The state of one modulator is a float vector (MOD_*); ``table`` holds the
# deceleration of notches 0..7 (0 for notch 0).

MOD_NOTCH = 0
MOD_APPLIED = 1  # modelled brake response to the notches (m/s²)
MOD_TARGET = 2  # modelled response to the target (m/s²)
MOD_E1 = 3  # speed error integral (m/s)
MOD_E2 = 4  # position error integral (m)
MOD_HELD = 5  # time the notch has been held (s)
MOD_CHANGES = 6
# The response's smoothing factor 1 - exp(-dt/τ) and the (dt, τ) it was computed for: the response
# time changes only when the wayside identifies it, so the exponential is computed once per change
# rather than every controller cycle (the same value to the bit).
MOD_ALPHA = 7
MOD_ALPHA_DT = 8
MOD_ALPHA_TAU = 9
MOD_SIZE = 10


@njit_step
def modulator_init_1(state: FloatArray) -> None:
    state[:] = 0.0
    state[MOD_HELD] = np.inf
    state[MOD_ALPHA_TAU] = np.nan  # no factor yet (NaN equals no response time)


@njit_step
def modulator_restart_1(state: FloatArray) -> None:
    """A new target arrived: the integrators restart (the target already contains the past error)."""
    state[MOD_E1] = 0.0
    state[MOD_E2] = 0.0


@njit_step
def motion_under_lag_1(
    v0_mps: float, a0_mps2: float, c_mps2: float, tau_s: float, t_s: float
) -> tuple[float, float, float]:
    """Speed, distance and deceleration after t with deceleration a(t) = c + (a0 - c)e^(-t/τ)."""
    decay = math.exp(-t_s / tau_s)
    gap = a0_mps2 - c_mps2
    v = v0_mps - c_mps2 * t_s - gap * tau_s * (1.0 - decay)
    x = v0_mps * t_s - 0.5 * c_mps2 * t_s * t_s - gap * tau_s * (t_s - tau_s * (1.0 - decay))
    return v, x, c_mps2 + gap * decay


@njit_step
def stopping_distance_under_lag_1(v0_mps: float, a0_mps2: float, c_mps2: float, tau_s: float) -> float:
    """Distance to standstill when the deceleration relaxes from a0 to c (> 0) with time constant τ
    (Newton's method on v(t) = 0; v decreases monotonically while the deceleration stays positive)."""
    c = max(c_mps2, 1e-3)
    a0 = max(a0_mps2, 0.0)
    v0 = max(v0_mps, 0.0)
    t = v0 / max(0.5 * (a0 + c), 1e-3)
    for _ in range(8):
        v, _x, a = motion_under_lag_1(v0, a0, c, tau_s, t)
        t_next = max(t + v / max(a, 1e-3), 0.0)
        if t_next == t:
            # Converged to the bit: every further iteration would return this t again (an exact
            # fixed point of a deterministic step), so stopping here changes no result.
            break
        t = t_next
    return motion_under_lag_1(v0, a0, c, tau_s, t)[1]


@njit_step
def nearest_notch_1(decel_mps2: float, table: FloatArray) -> int:
    """Notch 0..7 whose deceleration is nearest to the target (the first of equals)."""
    best = 0
    gap = abs(decel_mps2 - table[0])
    for j in range(1, table.size):
        g = abs(decel_mps2 - table[j])
        if g < gap:
            best = j
            gap = g
    return best


@njit_step
def _end_choice_1(
    state: FloatArray,
    table: FloatArray,
    min_hold_s: float,
    response_s: float,
    speed_mps: float,
    target: float,
    lo: int,
    hi: int,
) -> int:
    """The first move of the best two-move plan (this notch for the minimum hold, then either
    notch until standstill), judged by the predicted stop against where the target stops the train."""
    tau = response_s
    applied = state[MOD_APPLIED]
    # The train is e2 ahead of the target trajectory and e1 faster.
    goal = (
        stopping_distance_under_lag_1(speed_mps - state[MOD_E1], state[MOD_TARGET], target, tau)
        - state[MOD_E2]
    )
    best = np.inf
    choice = lo
    for first in (lo, hi):
        v1, x1, a1 = motion_under_lag_1(speed_mps, applied, table[first], tau, min_hold_s)
        for second in (lo, hi):
            if v1 > 0.0:
                whole = x1 + stopping_distance_under_lag_1(max(v1, 0.0), a1, table[second], tau)
            else:  # stops inside the first hold: where the first notch alone stops it
                whole = stopping_distance_under_lag_1(speed_mps, applied, table[first], tau)
            miss = abs(whole - goal)
            if miss < best - 1e-12:
                best = miss
                choice = first
    return choice


@njit_step
def modulator_update_1(
    state: FloatArray,
    table: FloatArray,
    min_hold_s: float,
    response_s: float,
    target_mps2: float,
    active: bool,
    dt_s: float,
    speed_mps: float,
    use_speed: bool,
) -> int:
    """Advance one modulator by ``dt_s`` (the controller's cycle) and return the notch to apply.

    A second-order sigma-delta between the two notches around the target. What
    matters for the stopping point is the position error, the double integral
    of (target - applied) deceleration, so the modulator keeps that double
    integral near zero (a first-order modulator only bounds the speed error).
    "Applied" is the notch deceleration passed through a first-order model of
    the brake response (time constant ``response_s`` = dead time + lag), so the
    alternation is timed against what the brakes will really do. The
    integrators restart whenever a new target arrives
    (:func:`modulator_restart_1`): the wayside computed it from the train's
    measured state, which already contains the past error. With ``use_speed``
    (the train's measured speed ``speed_mps``) the end phase is planned against
    the predicted stopping point (see the module docstring); without it the
    modulator runs on the target alone.
    """
    target = clip_1(target_mps2, 0.0, table[table.size - 1])
    if state[MOD_ALPHA_DT] != dt_s or state[MOD_ALPHA_TAU] != response_s:
        state[MOD_ALPHA] = 1.0 - math.exp(-dt_s / response_s)
        state[MOD_ALPHA_DT] = dt_s
        state[MOD_ALPHA_TAU] = response_s
    alpha = state[MOD_ALPHA]
    notch = int(state[MOD_NOTCH])
    state[MOD_APPLIED] += (table[notch] - state[MOD_APPLIED]) * alpha
    state[MOD_TARGET] += (target - state[MOD_TARGET]) * alpha
    state[MOD_E1] += (state[MOD_TARGET] - state[MOD_APPLIED]) * dt_s
    state[MOD_E2] += state[MOD_E1] * dt_s
    lo = min(max(int(np.searchsorted(table, target, side="right")) - 1, 0), 7)
    hi = min(lo + 1, 7)
    # Look ahead one response time: brake more when the position error
    # (train ahead of the plan: e2 > 0) would otherwise still grow.
    horizon = response_s + min_hold_s
    want = hi if state[MOD_E2] + state[MOD_E1] * horizon > 0.0 else lo
    can_change = state[MOD_HELD] + 1e-9 >= min_hold_s
    # End phase: within two look-ahead horizons of standstill.
    end_phase = target > 0.0 and speed_mps / max(target, 0.05) <= 2.0 * (min_hold_s + response_s)
    if use_speed and can_change and active and end_phase:
        want = _end_choice_1(state, table, min_hold_s, response_s, speed_mps, target, lo, hi)
    if table[lo] == target:
        want = lo
    new = want if (notch < lo or notch > hi or can_change) else notch
    if not active:
        new = 0
    if new != notch:
        if active:
            state[MOD_CHANGES] += 1.0
        state[MOD_HELD] = dt_s
    else:
        state[MOD_HELD] += dt_s
    state[MOD_NOTCH] = new
    return new
