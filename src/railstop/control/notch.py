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

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.control.tasc import clip_1
from railstop.jit import njit_step

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def _motion_under_lag(
    v0_mps: FloatArray, a0_mps2: FloatArray, c_mps2: FloatArray, tau_s: float, t_s: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Speed, distance and deceleration after ``t`` with deceleration a(t) = c + (a0 - c)e^(-t/τ)."""
    decay = np.exp(-t_s / tau_s)
    gap = a0_mps2 - c_mps2
    v = v0_mps - c_mps2 * t_s - gap * tau_s * (1.0 - decay)
    x = v0_mps * t_s - 0.5 * c_mps2 * t_s * t_s - gap * tau_s * (t_s - tau_s * (1.0 - decay))
    return v, x, c_mps2 + gap * decay


def stopping_distance_under_lag(
    v0_mps: FloatArray, a0_mps2: FloatArray, c_mps2: FloatArray, tau_s: float
) -> FloatArray:
    """Distance to standstill when the deceleration relaxes from a0 to c (> 0) with time constant τ.

    The stop time solves v(t) = 0 by Newton's method (v decreases
    monotonically while the deceleration stays positive).
    """
    c = np.maximum(c_mps2, 1e-3)
    a0 = np.maximum(a0_mps2, 0.0)
    v0 = np.maximum(v0_mps, 0.0)
    t = v0 / np.maximum(0.5 * (a0 + c), 1e-3)
    for _ in range(8):
        v, _, a = _motion_under_lag(v0, a0, c, tau_s, t)
        t = np.maximum(t + v / np.maximum(a, 1e-3), 0.0)
    return _motion_under_lag(v0, a0, c, tau_s, t)[1]


def nearest_notch(decel_mps2: FloatArray, notch_decel_mps2: FloatArray) -> IntArray:
    """Notch 0..7 whose deceleration is nearest to the target (0 = released)."""
    table = np.concatenate(([0.0], notch_decel_mps2))
    return np.abs(np.asarray(decel_mps2)[:, None] - table[None, :]).argmin(axis=1)


@dataclass(slots=True, kw_only=True)
class NotchModulator:
    """Second-order sigma-delta between the two notches around the target.

    What matters for the stopping point is the position error, the double
    integral of (target - applied) deceleration, so the modulator keeps that
    double integral near zero (a first-order modulator only bounds the speed
    error). "Applied" is the notch deceleration passed through a first-order
    model of the brake response (time constant = dead time + lag), so the
    alternation is timed against what the brakes will really do. The
    integrators restart whenever a new target arrives: the wayside computed it
    from the train's measured state, which already contains the past error.
    """

    table_mps2: FloatArray  # (8,) with 0 for notch 0
    min_hold_s: float
    response_s: float
    notch: IntArray
    applied_mps2: FloatArray  # modelled brake response to the notches
    target_mps2: FloatArray  # modelled response to the target
    e1_mps: FloatArray
    e2_m: FloatArray
    held_s: FloatArray
    changes: IntArray

    @classmethod
    def create(
        cls, n: int, notch_decel_mps2: list[float], min_hold_s: float, response_s: float
    ) -> NotchModulator:
        return cls(
            table_mps2=np.concatenate(([0.0], np.asarray(notch_decel_mps2, dtype=np.float64))),
            min_hold_s=min_hold_s,
            response_s=response_s,
            notch=np.zeros(n, dtype=np.int64),
            applied_mps2=np.zeros(n),
            target_mps2=np.zeros(n),
            e1_mps=np.zeros(n),
            e2_m=np.zeros(n),
            held_s=np.full(n, np.inf),
            changes=np.zeros(n, dtype=np.int64),
        )

    def restart(self, mask: NDArray[np.bool_]) -> None:
        """A new target arrived for the runs in ``mask``."""
        self.e1_mps = np.where(mask, 0.0, self.e1_mps)
        self.e2_m = np.where(mask, 0.0, self.e2_m)

    def update(
        self,
        target_mps2: FloatArray,
        active: NDArray[np.bool_],
        dt_s: float,
        speed_mps: FloatArray | None = None,
    ) -> IntArray:
        """Advance by ``dt_s`` (the controller's cycle) and return the notch to apply.

        With ``speed_mps`` (the train's measured speed) the end phase is
        planned against the predicted stopping point; without it the
        modulator runs on the target alone.
        """
        table = self.table_mps2
        target = np.clip(target_mps2, 0.0, table[-1])
        alpha = 1.0 - np.exp(-dt_s / self.response_s)
        self.applied_mps2 += (table[self.notch] - self.applied_mps2) * alpha
        self.target_mps2 += (target - self.target_mps2) * alpha
        self.e1_mps += (self.target_mps2 - self.applied_mps2) * dt_s
        self.e2_m += self.e1_mps * dt_s
        lo = np.clip(np.searchsorted(table, target, side="right") - 1, 0, 7)
        hi = np.minimum(lo + 1, 7)
        # Look ahead one response time: brake more when the position error
        # (train ahead of the plan: e2 > 0) would otherwise still grow.
        horizon = self.response_s + self.min_hold_s
        want = np.where(self.e2_m + self.e1_mps * horizon > 0.0, hi, lo)
        can_change = self.held_s + 1e-9 >= self.min_hold_s
        if speed_mps is not None:
            end = np.flatnonzero(self._end_phase(speed_mps, target) & can_change & active)
            if end.size:
                want[end] = self._end_choice(end, speed_mps[end], target[end], lo[end], hi[end])
        want = np.where(table[lo] == target, lo, want)
        outside = (self.notch < lo) | (self.notch > hi)
        new = np.where(outside | can_change, want, self.notch)
        new = np.where(active, new, 0)
        changed = new != self.notch
        self.changes += changed & active
        self.held_s = np.where(changed, dt_s, self.held_s + dt_s)
        self.notch = new
        return new

    def _end_phase(self, speed_mps: FloatArray, target: FloatArray) -> NDArray[np.bool_]:
        """Runs within two look-ahead horizons of standstill."""
        remaining_s = speed_mps / np.maximum(target, 0.05)
        return (target > 0.0) & (remaining_s <= 2.0 * (self.min_hold_s + self.response_s))

    def _end_choice(
        self, rows: IntArray, speed_mps: FloatArray, target: FloatArray, lo: IntArray, hi: IntArray
    ) -> IntArray:
        """For ``rows``: the first move of the best two-move plan, judged by the predicted stop."""
        table = self.table_mps2
        tau = self.response_s
        applied = self.applied_mps2[rows]
        # Where the target trajectory stops, relative to the train now: the
        # train is e2 ahead of it and e1 faster (see the integrators).
        goal = (
            stopping_distance_under_lag(speed_mps - self.e1_mps[rows], self.target_mps2[rows], target, tau)
            - self.e2_m[rows]
        )
        hold = np.full(speed_mps.shape, self.min_hold_s)
        best = np.full(speed_mps.shape, np.inf)
        choice = lo.copy()
        for first in (lo, hi):
            v1, x1, a1 = _motion_under_lag(speed_mps, applied, table[first], tau, hold)
            for second in (lo, hi):
                tail = stopping_distance_under_lag(np.maximum(v1, 0.0), a1, table[second], tau)
                # A plan that stops inside the first hold stops where the first notch alone stops it.
                whole = np.where(
                    v1 > 0.0,
                    x1 + tail,
                    stopping_distance_under_lag(speed_mps, applied, table[first], tau),
                )
                miss = np.abs(whole - goal)
                better = miss < best - 1e-12
                best = np.where(better, miss, best)
                choice = np.where(better, first, choice)
        return choice


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
MOD_SIZE = 7


@njit_step
def modulator_init_1(state: FloatArray) -> None:
    state[:] = 0.0
    state[MOD_HELD] = np.inf


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
    decay = np.exp(-t_s / tau_s)
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
        t = max(t + v / max(a, 1e-3), 0.0)
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

    Second-order sigma-delta between the two notches around the target, timed
    against a first-order model of the brake response; with ``use_speed`` the
    end phase is planned against the predicted stopping point (see the class).
    """
    target = clip_1(target_mps2, 0.0, table[table.size - 1])
    alpha = 1.0 - np.exp(-dt_s / response_s)
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
