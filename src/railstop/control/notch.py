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
either notch until standstill). A caller that measures the distance to the
stopping point (the wayside of forms 7 and 8, with its Doppler radar: stop
model 23) has the plans judged against that point, with the braking as it
knows it, instead of against where the target would stop the train
(modulator_aim_1).
**[interpretation]** SPEC §1 leaves the brake controller's own logic open;
this is railstop's model of a competent one.

The modulator's model of the brakes is the plant's own: a dead time, then a
first-order lag. A notch chosen now acts only after the dead time, so the
modulator works on the braking as it will be one dead time from now: its
error integrators compare the lagged notches with the lagged target in that
frame, and it keeps the notches still in the dead time (a ring, one entry
per cycle) to know the braking between now and then. When a new target
arrives, the part of the error the sender could not have measured, the
braking already commanded and not yet felt against the previous target,
starts the integrators (**[interpretation]**: the sender measured the train
before those notches acted). An earlier model folded the dead time into the
lag (one lag of dead time + lag), which times the alternation and the end
phase a dead time early: at Riverside, nominal, a short release just before
the last command ended that stop +0.147 m.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from railstop.control.tasc import clip_1
from railstop.jit import njit_inline, njit_step

FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------
# Compiled scalar cores (railstop.jit): the one implementation of the modulator.
#
# The state of one modulator is a float vector (MOD_*); ``table`` holds the
# deceleration of notches 0..7 (0 for notch 0).

MOD_NOTCH = 0
MOD_APPLIED = 1  # modelled brake response to the notches one dead time from now (m/s²)
MOD_TARGET = 2  # modelled response to the target, in the same frame (m/s²)
MOD_E1 = 3  # speed error integral (m/s)
MOD_E2 = 4  # position error integral (m)
MOD_HELD = 5  # time the notch has been held (s)
MOD_CHANGES = 6
# The response's constants, computed when the cycle, the dead time or the lag change (the wayside's
# identification changes them), not every controller cycle: the smoothing factor of one cycle
# 1 - exp(-dt/τ), the decays over the dead time's fraction of a cycle f and over the rest of the
# cycle, and the (dt, dead time, lag) they were computed for.
MOD_ALPHA = 7
MOD_ALPHA_DT = 8
MOD_ALPHA_TAU = 9  # the lag they were computed for
MOD_ALPHA_DEAD = 10  # the dead time they were computed for
MOD_TAU = 11  # the lag of the model: the brakes' lag, plus any dead time beyond the ring
MOD_CYCLES = 12  # m: whole cycles of dead time (at most MOD_RING_SIZE - 2)
MOD_FRAC = 13  # f: the dead time's rest (s)
MOD_DECAY_F = 14  # exp(-f/τ)
MOD_DECAY_REST = 15  # exp(-(dt - f)/τ)
MOD_DECAY_CYCLE = 16  # exp(-dt/τ)
MOD_NOW = 17  # modelled brake response now (m/s²)
MOD_HEAD = 18  # the ring's entry of the notch held over the last cycle
MOD_RAMP = 19  # the target as the modulator follows it: ramped where the notches are rate-limited
# Stop model 23: where the caller measures the train's distance to the stopping point (the
# wayside of forms 7 and 8: its last detector and its radar's travel since), the end phase aims
# at that point (modulator_aim_1): the distance (NaN: not measured, the end phase aims where the
# target would stop the train), the external deceleration there (gradient and resistance) and
# the loop gain (the brakes' measured over nominal effect) it predicts with.
MOD_LEFT = 20
MOD_EXT = 21
MOD_GAIN = 22
MOD_RING = 23  # the notches' decelerations, one entry per cycle, newest at MOD_HEAD
MOD_RING_SIZE = 64  # 6.2 s of dead time at the default 0.1 s cycle
MOD_SIZE = MOD_RING + MOD_RING_SIZE


@njit_step
def modulator_init_1(state: FloatArray) -> None:
    state[:] = 0.0
    state[MOD_HELD] = np.inf
    state[MOD_ALPHA_TAU] = np.nan  # no constants yet (NaN equals no lag)
    state[MOD_LEFT] = np.nan
    state[MOD_GAIN] = 1.0


@njit_step
def modulator_aim_1(state: FloatArray, left_m: float, external_mps2: float, gain: float) -> None:
    """The end phase aims at the stopping point ``left_m`` ahead (NaN: where the target would stop
    the train), predicting with the external deceleration ``external_mps2`` (+ = helps braking)
    and the brakes' effect ``gain`` times the nominal (stop model 23)."""
    state[MOD_LEFT] = left_m
    state[MOD_EXT] = external_mps2
    state[MOD_GAIN] = gain


@njit_inline
def _held_1(state: FloatArray, ago: int) -> float:
    """The deceleration of the notch held ``ago`` cycles before the last one (0: the last)."""
    j = int(state[MOD_HEAD]) - ago
    if j < 0:
        j += MOD_RING_SIZE
    return state[MOD_RING + j]


@njit_inline
def _lag_segment_1(
    v: float, x: float, a: float, c: float, t: float, decay: float, tau: float
) -> tuple[float, float, float]:
    """Speed, distance and deceleration after ``t`` under a(t) = c + (a - c)e^(-t/τ) (``decay`` =
    e^(-t/τ)), from speed ``v`` and distance ``x``."""
    gap = a - c
    v_end = v - c * t - gap * tau * (1.0 - decay)
    x_end = x + v * t - 0.5 * c * t * t - gap * tau * (t - tau * (1.0 - decay))
    return v_end, x_end, c + gap * decay


@njit_step
def modulator_pipeline_1(
    state: FloatArray, speed_mps: float, assumed_mps2: float, pushed: int
) -> tuple[float, float, float]:
    """The braking already commanded and not yet felt: from the last cycle to one dead time
    after it, the train's speed at its end (from ``speed_mps``), and the speed and distance it
    gains against a deceleration of ``assumed_mps2`` held throughout (e1, e2 of that interval).
    ``pushed``: 1 once the last cycle's own notch is in the ring, 0 while it is being chosen."""
    v, x = _in_flight_1(state, speed_mps, 1.0, 0.0, pushed)
    span = int(state[MOD_CYCLES]) * state[MOD_ALPHA_DT] + state[MOD_FRAC]
    v_plan = speed_mps - assumed_mps2 * span
    x_plan = speed_mps * span - 0.5 * assumed_mps2 * span * span
    return v, v - v_plan, x - x_plan


@njit_inline
def _in_flight_1(
    state: FloatArray, speed_mps: float, gain: float, ext: float, pushed: int
) -> tuple[float, float]:
    """The train's speed one dead time after the last cycle and the distance it covers until then,
    from ``speed_mps``, under the notches already commanded, each giving ``gain`` times its
    nominal deceleration, plus ``ext`` (1 and 0: the modulator's own model). ``pushed`` as in
    :func:`modulator_pipeline_1`."""
    tau = state[MOD_TAU]
    dt = state[MOD_ALPHA_DT]
    m = int(state[MOD_CYCLES])
    v, x, a = _lag_segment_1(
        speed_mps, 0.0, gain * state[MOD_NOW] + ext, gain * _held_1(state, m + pushed) + ext,
        state[MOD_FRAC], state[MOD_DECAY_F], tau,
    )  # fmt: skip
    for ago in range(m - 1, -1, -1):
        decel = gain * _held_1(state, ago + pushed) + ext
        v, x, a = _lag_segment_1(v, x, a, decel, dt, state[MOD_DECAY_CYCLE], tau)
    return v, x


@njit_step
def modulator_restart_1(state: FloatArray) -> None:
    """A new target arrived: the integrators restart (the target already contains the error the
    sender measured) from the error of the braking already commanded and not yet felt, against
    the previous target that the sender assumed would go on."""
    state[MOD_E1] = 0.0
    state[MOD_E2] = 0.0
    if state[MOD_ALPHA_TAU] == state[MOD_ALPHA_TAU]:  # the model has run a cycle: it has a ring
        _, e1, e2 = modulator_pipeline_1(state, 0.0, state[MOD_TARGET], 1)
        state[MOD_E1] = e1
        state[MOD_E2] = e2


@njit_step
def motion_under_lag_1(
    v0_mps: float, a0_mps2: float, c_mps2: float, tau_s: float, t_s: float
) -> tuple[float, float, float]:
    """Speed, distance and deceleration after t with deceleration a(t) = c + (a0 - c)e^(-t/τ)."""
    return _lag_segment_1(v0_mps, 0.0, a0_mps2, c_mps2, t_s, math.exp(-t_s / tau_s), tau_s)


@njit_step
def stopping_distance_under_lag_1(v0_mps: float, a0_mps2: float, c_mps2: float, tau_s: float) -> float:
    """Distance to standstill when the deceleration relaxes from a0 to c (> 0) with time constant τ
    (Newton's method on v(t) = 0; v decreases monotonically while the deceleration stays positive)."""
    c = max(c_mps2, 1e-3)
    a0 = max(a0_mps2, 0.0)
    v0 = max(v0_mps, 0.0)
    t = v0 / max(0.5 * (a0 + c), 1e-3)
    for _ in range(8):
        v, x, a = motion_under_lag_1(v0, a0, c, tau_s, t)
        t_next = max(t + v / max(a, 1e-3), 0.0)
        if t_next == t:
            # Converged to the bit: every further iteration would return this t again (an exact
            # fixed point of a deterministic step), so stopping here changes no result; x is the
            # distance at this very t.
            return x
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
    speed_mps: float,
    target: float,
    lo: int,
    hi: int,
    first_lo: int,
    first_hi: int,
) -> int:
    """The first move of the best two-move plan (a notch of ``first_lo`` .. ``first_hi`` for the
    minimum hold, then lo or hi until standstill), judged by the predicted stop against where
    the target stops the train. Both are judged one dead time from now, where the notch chosen
    now starts to act: the train's speed there follows from the notches already commanded.
    The first move's notches are lo and hi where the notch may jump, the notches one step
    from the current one where it moves one notch per hold (form 8)."""
    tau = state[MOD_TAU]
    left = state[MOD_LEFT]
    aimed = left == left
    # Stop model 23 [interpretation]: a caller that measures the distance to the stopping point
    # has the plans judged against that point, with the braking as it knows it (gain x the
    # notches' nominal deceleration, plus gradient and resistance): the target set at the last
    # command, followed open-loop since, no longer decides where the train stops (measured on
    # model 22: form 8 trains with slow brakes stepped a notch up 1.1 m before the stop, 0.3 m/s^2
    # needed, and stopped 0.36 m short). Otherwise gain 1 and no external deceleration, the
    # modulator's own model (x 1 + 0 changes no deceleration: they are all >= 0).
    gain = state[MOD_GAIN] if aimed else 1.0
    ext = state[MOD_EXT] if aimed else 0.0
    v_dead, x_dead = _in_flight_1(state, speed_mps, gain, ext, 0)
    if v_dead <= 0.0:  # the train stands before this choice acts
        return int(state[MOD_NOTCH])
    if aimed:
        goal = left - x_dead
    else:
        # The train is e2 ahead of the target trajectory and e1 faster (one dead time from now).
        goal = (
            stopping_distance_under_lag_1(v_dead - state[MOD_E1], state[MOD_TARGET], target, tau)
            - state[MOD_E2]
        )
    applied = gain * state[MOD_APPLIED] + ext
    best = np.inf
    choice = lo
    hold_decay = math.exp(-min_hold_s / tau)
    for first in range(first_lo, first_hi + 1):
        c1 = gain * table[first] + ext
        v1, x1, a1 = _lag_segment_1(v_dead, 0.0, applied, c1, min_hold_s, hold_decay, tau)
        if v1 <= 0.0:  # stops inside the first hold: where the first notch alone stops it
            alone = stopping_distance_under_lag_1(v_dead, applied, c1, tau)
        for second in (lo, hi):
            if v1 > 0.0:
                whole = x1 + stopping_distance_under_lag_1(max(v1, 0.0), a1, gain * table[second] + ext, tau)
            else:
                whole = alone
            miss = abs(whole - goal)
            if miss < best - 1e-12:
                best = miss
                choice = first
    return choice


@njit_inline
def _response_constants_1(state: FloatArray, dt_s: float, dead_s: float, lag_s: float) -> None:
    """The model's constants for this cycle, dead time and lag. A dead time longer than the ring
    holds (MOD_RING_SIZE - 2 cycles) is modelled as that many cycles and the rest added to the
    lag (**[interpretation]**: the earlier model's approximation, for that rest only)."""
    cycles = math.floor(dead_s / dt_s)
    frac = dead_s - cycles * dt_s
    tau = lag_s
    if cycles > MOD_RING_SIZE - 2:
        tau += (cycles - (MOD_RING_SIZE - 2)) * dt_s + frac
        cycles = MOD_RING_SIZE - 2
        frac = 0.0
    state[MOD_TAU] = tau
    state[MOD_CYCLES] = cycles
    state[MOD_FRAC] = frac
    state[MOD_DECAY_CYCLE] = math.exp(-dt_s / tau)
    state[MOD_ALPHA] = 1.0 - state[MOD_DECAY_CYCLE]
    state[MOD_DECAY_F] = math.exp(-frac / tau)
    state[MOD_DECAY_REST] = math.exp(-(dt_s - frac) / tau)
    state[MOD_ALPHA_DT] = dt_s
    state[MOD_ALPHA_DEAD] = dead_s
    state[MOD_ALPHA_TAU] = lag_s


@njit_step
def modulator_update_1(
    state: FloatArray,
    table: FloatArray,
    min_hold_s: float,
    dead_s: float,
    lag_s: float,
    target_mps2: float,
    active: bool,
    dt_s: float,
    speed_mps: float,
    use_speed: bool,
    ramp_mps3: float,
) -> int:
    """Advance one modulator by ``dt_s`` (the controller's cycle) and return the notch to apply.

    A second-order sigma-delta between the two notches around the target. What
    matters for the stopping point is the position error, the double integral
    of (target - applied) deceleration, so the modulator keeps that double
    integral near zero (a first-order modulator only bounds the speed error).
    "Applied" is the notch deceleration through the brakes' response, a dead time
    ``dead_s`` and a first-order lag ``lag_s``, so the alternation is timed against
    what the brakes will really do: the integrators work one dead time ahead (see
    the module docstring). The integrators restart whenever a new target arrives
    (:func:`modulator_restart_1`): the wayside computed it from the train's
    measured state, which already contains the past error. With ``use_speed``
    (the train's measured speed ``speed_mps``) the end phase is planned against
    the predicted stopping point (see the module docstring); without it the
    modulator runs on the target alone.

    ``ramp_mps3`` > 0: the notch moves at most one step per minimum hold (SPEC §1 form 8, one
    notch per telegram), and the target is followed as a ramp of that rate, the build-up the
    sender planned with (its jerk limit): the integrators compare the notches with the ramp,
    not with a step the notches cannot make (**[interpretation]**).
    """
    target = clip_1(target_mps2, 0.0, table[table.size - 1])
    dead = max(dead_s, 0.0)
    if state[MOD_ALPHA_DT] != dt_s or state[MOD_ALPHA_DEAD] != dead or state[MOD_ALPHA_TAU] != lag_s:
        _response_constants_1(state, dt_s, dead, lag_s)
    alpha = state[MOD_ALPHA]
    notch = int(state[MOD_NOTCH])
    # The last cycle's notch, one dead time ahead; the response now, from the notches of one dead
    # time ago (the fraction f of the cycle on the older one).
    m = int(state[MOD_CYCLES])
    older = _held_1(state, m + 1)
    newer = _held_1(state, m)
    now = older + (state[MOD_NOW] - older) * state[MOD_DECAY_F]
    state[MOD_NOW] = newer + (now - newer) * state[MOD_DECAY_REST]
    state[MOD_APPLIED] += (table[notch] - state[MOD_APPLIED]) * alpha
    if ramp_mps3 > 0.0:
        step = ramp_mps3 * dt_s
        state[MOD_RAMP] += clip_1(target - state[MOD_RAMP], -step, step)
    else:
        state[MOD_RAMP] = target
    state[MOD_TARGET] += (state[MOD_RAMP] - state[MOD_TARGET]) * alpha
    state[MOD_E1] += (state[MOD_TARGET] - state[MOD_APPLIED]) * dt_s
    state[MOD_E2] += state[MOD_E1] * dt_s
    lo = min(max(int(np.searchsorted(table, target, side="right")) - 1, 0), 7)
    hi = min(lo + 1, 7)
    # Look ahead one lag and a hold: brake more when the position error (train ahead of the
    # plan: e2 > 0) would otherwise still grow.
    horizon = state[MOD_TAU] + min_hold_s
    want = hi if state[MOD_E2] + state[MOD_E1] * horizon > 0.0 else lo
    can_change = state[MOD_HELD] + 1e-9 >= min_hold_s
    # End phase: within two look-ahead horizons of standstill.
    end_phase = target > 0.0 and speed_mps / max(target, 0.05) <= 2.0 * (min_hold_s + dead + lag_s)
    if use_speed and can_change and active and end_phase:
        first_lo, first_hi = lo, hi
        if ramp_mps3 > 0.0:
            # SPEC §1 form 8 moves one notch per hold: the first move is one of the notches one
            # step from this one, below lo too. Judged among lo and hi only, a train whose notch
            # came down from above the target (the braking of the last notches still building
            # up) could not brake less than lo however short it was going to stop (measured,
            # forms_standard --forms 8: most silent misses short by 0.3-0.5 m with slow brakes).
            # [interpretation] the brake controller's own logic is railstop's model.
            first_lo, first_hi = max(notch - 1, 0), min(notch + 1, table.size - 1)
        want = _end_choice_1(state, table, min_hold_s, speed_mps, target, lo, hi, first_lo, first_hi)
    if table[lo] == target:
        want = lo
    if ramp_mps3 > 0.0:
        # One notch per hold, towards the notch wanted.
        new = notch + (1 if want > notch else (-1 if want < notch else 0)) if can_change else notch
    else:
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
    head = int(state[MOD_HEAD]) + 1
    if head >= MOD_RING_SIZE:
        head = 0
    state[MOD_HEAD] = head
    state[MOD_RING + head] = table[new]
    return new
