"""The pieces of the TASC law and the notch modulator, each against a closed form or a fine integration.

They call the compiled scalar cores the stop kernel runs (numba dispatchers are callable from
Python), with their state arrays set up as the kernel sets them up.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railstop.control.notch import (
    MOD_APPLIED,
    MOD_E1,
    MOD_E2,
    MOD_HELD,
    MOD_NOTCH,
    MOD_NOW,
    MOD_RING_SIZE,
    MOD_SIZE,
    MOD_TARGET,
    modulator_aim_1,
    modulator_init_1,
    modulator_pipeline_1,
    modulator_restart_1,
    modulator_update_1,
    stopping_distance_under_lag_1,
)
from railstop.control.tasc import (
    HISTORY,
    fit_ring_1,
    gain_update_1,
    gain_value_1,
    history_push_1,
    history_response_at_1,
    line_fit_1,
)


def _integrate_stop(v0: float, a0: float, c: float, tau: float, dt: float = 1e-4) -> float:
    """Stopping distance by explicit integration with a tiny step (the reference)."""
    v, a, x = v0, a0, 0.0
    while v > 0.0:
        a += (c - a) * (1.0 - np.exp(-dt / tau))
        step_v = min(v, a * dt)
        x += (v - 0.5 * step_v) * dt if step_v < v else v * v / (2.0 * a)
        v -= step_v
    return x


@settings(max_examples=25, deadline=None)
@given(
    v0=st.floats(0.2, 4.0),
    a0=st.floats(0.0, 1.0),
    c=st.floats(0.1, 1.0),
    tau=st.floats(0.2, 1.2),
)
def test_stopping_distance_under_lag_matches_integration(v0: float, a0: float, c: float, tau: float) -> None:
    got = stopping_distance_under_lag_1(v0, a0, c, tau)
    ref = _integrate_stop(v0, a0, c, tau)
    assert abs(got - ref) <= 1e-3 + 1e-3 * ref


def test_stopping_distance_without_transient_is_v2_over_2a() -> None:
    for v, a in ((1.0, 0.3), (2.5, 0.5), (3.0, 0.8)):
        got = stopping_distance_under_lag_1(v, a, a, 0.7)
        np.testing.assert_allclose(got, v * v / (2 * a), rtol=1e-9)


def _gain(windows: list[tuple[float, float, float]]) -> float:
    """The loop gain after the measurement windows (measured, commanded, external) of one run."""
    num = den = 0.0
    for measured, commanded, external in windows:
        num, den = gain_update_1(num, den, measured, commanded, external)
    return gain_value_1(num, den)


def test_gain_estimate_is_least_squares_over_windows() -> None:
    # SPEC §1 loop closure (claims 2, 19). Brake gain 0.85 and 1.1; external decel 0.05; two windows each.
    for true_gain in (0.85, 1.1):
        g = _gain([(true_gain * c + 0.05, c, 0.05) for c in (0.6, 0.45)])
        np.testing.assert_allclose(g, true_gain, rtol=1e-12)
    # A ripple that alternates sign between windows averages out, where the
    # last window alone would be 4 % off.
    g = _gain([(0.6 * (1.0 + ripple), 0.6, 0.0) for ripple in (+0.04, -0.04, +0.04, -0.04)])
    assert abs(g - 1.0) < 1e-12
    # Windows with too small a command (before braking) do not count.
    assert _gain([(0.05, 0.01, 0.0)]) == 1.0


def test_command_response_is_a_first_order_lag_around_the_effect_time() -> None:
    values = np.zeros(HISTORY)  # an empty command history, as the kernel initialises it
    effects = np.full(HISTORY, np.inf)
    history_push_1(values, effects, 0.6, 5.0)
    lag = 0.45
    t = np.array([4.0, 5.0 - lag, 5.0, 6.0])
    got = np.array([history_response_at_1(values, effects, ti, lag) for ti in t])
    expected = 0.6 * (1.0 - np.exp(-np.maximum(t - (5.0 - lag), 0.0) / lag))
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    # The mean delay equals the effect time: the integral of (step - response) is 0.
    ts = np.linspace(0.0, 20.0, 200001)
    step = np.where(ts >= 5.0, 0.6, 0.0)
    response = np.array([history_response_at_1(values, effects, ti, lag) for ti in ts])
    area = np.trapezoid(step - response, ts)
    assert abs(area) < 1e-3


def test_short_speed_window_follows_a_rippling_deceleration() -> None:
    """The speed now from the newest samples; a long line misses the last ripple. The short
    window's mean is exact at its middle (the ripple's last half-period is longer than the
    window); carried forward with the long slope it misses only the difference between the
    deceleration now and the long mean over half the window (stop model 11)."""
    dt = 0.01
    t = np.arange(400) * dt
    decel = 0.5 + 0.07 * np.sign(np.sin(2 * np.pi * t / 2.0))  # notch alternation, 2 s period
    v = 3.0 - np.cumsum(decel) * dt
    # A ring buffer holding the 400 samples, the newest in its last slot; a speed
    # window as long as the ring is the one long line.
    v_long, a_long = fit_ring_1(v, 399, 400, dt, 400)
    v_short, a_same = fit_ring_1(v, 399, 400, dt, 30)
    assert a_same == a_long  # the deceleration still comes from the whole window
    assert v_short - v[-1] == pytest.approx((decel[-1] - a_same) * 29 * dt / 2.0, rel=1e-9, abs=1e-12)
    assert abs(v_short - v[-1]) < 0.3 * abs(v_long - v[-1])
    # Where the newest sample sits in the ring does not matter (the oldest follows it cyclically).
    ring = np.roll(v, -150)
    assert fit_ring_1(ring, 249, 400, dt, 30) == (v_short, a_same)


def test_speed_now_has_the_short_window_means_variance() -> None:
    """Stop model 11: the speed now is the short window's mean carried forward with the long
    slope. On a ramp with white noise its error has the variance of a mean of the short window
    (sigma^2 / m), a quarter of that of a line fitted through the short window alone (its end
    has variance 4 sigma^2 / m for large m)."""
    dt, n, m, sigma = 0.01, 150, 30, 0.02
    rng = np.random.default_rng(11)
    truth = 15.0 - 0.7 * np.arange(n) * dt
    errors, line_errors = [], []
    for _ in range(4000):
        v = truth + rng.normal(0.0, sigma, n)
        speed, _ = fit_ring_1(v, n - 1, n, dt, m)
        errors.append(speed - truth[-1])
        line_errors.append(line_fit_1(v[-m:], m - 1, m, dt)[0] - truth[-1])
    std = float(np.std(errors))
    # The long slope's own error, carried over half the short window, adds a little.
    assert sigma / np.sqrt(m) * 0.9 < std < sigma / np.sqrt(m) * 1.2
    assert std < 0.6 * float(np.std(line_errors))
    assert abs(float(np.mean(errors))) < 3.0 * std / np.sqrt(4000)  # unbiased


def test_form_8_end_phase_may_step_below_the_targets_lower_notch() -> None:
    """Stop model 20: with one notch per hold (form 8, ramp > 0) the end phase chooses among the
    notches one step from the current one, so a train on the target's lower notch that would stop
    short (behind the target's trajectory: e2 < 0) steps below it; one ahead steps up."""
    table = np.array([0.0, 0.143, 0.286, 0.429, 0.571, 0.714, 0.857, 1.0])
    hold, dead, lag, ramp = 0.3, 0.35, 0.45, 0.143 / 0.3
    target = 0.5  # between notches 3 and 4
    chosen = {}
    for e2 in (-0.3, 0.3):
        mod = np.empty(MOD_SIZE)
        modulator_init_1(mod)
        for _ in range(50):  # settle on the target far from the stop
            modulator_update_1(mod, table, hold, dead, lag, target, True, 0.1, 0.0, False, ramp)
        for _ in range(10):  # then on notch 3, the target's lower notch
            modulator_update_1(mod, table, hold, dead, lag, 0.43, True, 0.1, 0.0, False, ramp)
        assert mod[MOD_NOTCH] == 3
        mod[MOD_HELD] = 10.0
        mod[MOD_E2] = e2
        chosen[e2] = modulator_update_1(mod, table, hold, dead, lag, target, True, 0.1, 0.6, True, ramp)
    assert chosen[-0.3] == 2  # below the lower notch: the train would stop short
    assert chosen[0.3] == 4


def test_end_phase_picks_the_notch_that_stops_nearest() -> None:
    """Near standstill the modulator judges notches by the predicted stopping point, one dead time
    ahead, where the notch chosen now starts to act."""
    table = np.array([0.0, 0.143, 0.286, 0.429, 0.571, 0.714, 0.857, 1.0])  # notch 0 released
    hold, dead, lag = 0.5, 0.35, 0.45
    mod = np.empty(MOD_SIZE)
    modulator_init_1(mod)
    target = 0.5
    # Settle on the target far from the stop (no speed: plain sigma-delta).
    for _ in range(50):
        modulator_update_1(mod, table, hold, dead, lag, target, True, 0.1, 0.0, False, 0.0)
    # Now 0.6 m/s from standstill: the end phase decides; its choice must be
    # the notch whose plan stops nearer the target trajectory's stop.
    mod[MOD_HELD] = 10.0
    speed = 0.6
    before = mod.copy()
    chosen = modulator_update_1(mod, table, hold, dead, lag, target, True, 0.1, speed, True, 0.0)
    assert chosen in (3, 4)
    # The state the choice was made on: this cycle's update without the choice.
    seen = before.copy()
    modulator_update_1(seen, table, hold, dead, lag, target, True, 0.1, 0.0, False, 0.0)
    v_dead = modulator_pipeline_1(seen, speed, 0.0, 1)[0]
    goal = stopping_distance_under_lag_1(v_dead - seen[MOD_E1], seen[MOD_TARGET], target, lag) - seen[MOD_E2]
    miss = {
        n: abs(stopping_distance_under_lag_1(v_dead, seen[MOD_APPLIED], table[n], lag) - goal) for n in (3, 4)
    }
    # Holding the chosen notch to standstill is never the clearly worse of the two.
    other = 7 - chosen
    assert miss[chosen] <= miss[other] + 0.05


def _brake_chain(notch_decels: np.ndarray, cycle: float, dead: float, lag: float, fine: float) -> np.ndarray:
    """The brakes as the plant has them, integrated finely: the notch held over each cycle, seen
    one dead time later, through a first-order lag (the reference for the modulator's model)."""
    t = np.arange(0.0, notch_decels.size * cycle, fine)
    held = notch_decels[np.clip(np.floor((t - dead) / cycle + 1e-9).astype(int), -1, None)]
    held[t < dead] = 0.0
    a = np.zeros_like(t)
    for i in range(1, t.size):
        a[i] = held[i - 1] + (a[i - 1] - held[i - 1]) * np.exp(-fine / lag)
    return a


def _drive(mod: np.ndarray, table: np.ndarray, targets: list[float], dead: float, lag: float) -> list[int]:
    return [modulator_update_1(mod, table, 0.3, dead, lag, tg, True, 0.1, 0.0, False, 0.0) for tg in targets]


TABLE = np.array([0.0, 0.143, 0.286, 0.429, 0.571, 0.714, 0.857, 1.0])


@settings(max_examples=25, deadline=None)
@given(dead=st.floats(0.0, 1.5), lag=st.floats(0.1, 1.0), seed=st.integers(0, 2**31 - 1))
def test_the_modulators_brake_model_is_dead_time_then_lag(dead: float, lag: float, seed: int) -> None:
    """The response the modulator models now, and the speed it predicts one dead time ahead, are
    those of the plant's brakes (a dead time, then a first-order lag) fed its own notches."""
    rng = np.random.default_rng(seed)
    mod = np.empty(MOD_SIZE)
    modulator_init_1(mod)
    targets = list(rng.uniform(0.0, 1.0, 40))
    notches = _drive(mod, TABLE, targets, dead, lag)
    cycle, fine = 0.1, 1e-4
    chain = _brake_chain(TABLE[notches], cycle, dead, lag, fine)
    # MOD_NOW is the response at the start of the last cycle (the last call's own time).
    assert abs(mod[MOD_NOW] - chain[round((len(notches) - 1) * cycle / fine)]) < 2e-3
    # The pipeline: from then to one dead time later, the speed lost is the response's integral.
    more = _brake_chain(TABLE[notches + [notches[-1]] * 40], cycle, dead, lag, fine)
    start = round((len(notches) - 1) * cycle / fine)
    span = round(dead / fine)
    lost = float(np.sum(more[start : start + span]) * fine)
    v_end, e1, e2 = modulator_pipeline_1(mod, 10.0, 0.0, 1)
    assert abs((10.0 - v_end) - lost) < 2e-3
    assert abs(e1 - (v_end - 10.0)) < 1e-12  # against no braking, the speed lost is all of e1
    assert e2 <= 1e-12  # braking can only put the train behind a plan of none


def test_a_new_target_starts_from_the_braking_not_yet_felt() -> None:
    """A release just before a new target arrives is still in the dead time when it comes: the
    sender, who measured the train before it acted, planned with the braking going on. The
    restart carries that shortfall (the train will be faster and ahead of the plan), and a
    restart with nothing in flight against the plan carries none."""
    dead, lag = 0.35, 0.45
    mod = np.empty(MOD_SIZE)
    modulator_init_1(mod)
    _drive(mod, TABLE, [0.429] * 60, dead, lag)  # notch 3 held: the target is notch 3 exactly
    modulator_restart_1(mod)
    assert abs(mod[MOD_E1]) < 1e-5 and abs(mod[MOD_E2]) < 1e-5  # both settled on notch 3
    for _ in range(3):  # three cycles of notch 2 (the sigma-delta's release), then notch 3 again
        mod[MOD_HELD] = 10.0
        modulator_update_1(mod, TABLE, 0.3, dead, lag, 0.2, True, 0.1, 0.0, False, 0.0)
    mod[MOD_TARGET] = 0.429
    modulator_restart_1(mod)
    assert mod[MOD_E1] > 0.01 and mod[MOD_E2] > 0.0


def test_form_8_moves_one_notch_per_hold_along_the_planned_ramp() -> None:
    """SPEC §1 form 8 (one notch up or down per telegram): with a ramp rate the modulator moves the
    notch at most one step per minimum hold, and its integrators compare the notches with the target
    followed as a ramp of that rate (the build-up the wayside plans with), so the climb itself leaves
    no error to pay back: after it the notches alternate about the target (each window of the
    settled alternation averages to it), never above the notch above it. Without a ramp the same
    step in the target is taken at once."""
    dead, lag, hold = 0.35, 0.45, 0.3
    ramp = (TABLE[-1] / 7) / hold  # one notch per hold
    target = 0.5  # between notches 3 and 4
    stepped = np.empty(MOD_SIZE)
    modulator_init_1(stepped)
    notches = [
        modulator_update_1(stepped, TABLE, hold, dead, lag, target, True, 0.1, 0.0, False, ramp)
        for _ in range(200)
    ]
    changes = [(i, b - a) for i, (a, b) in enumerate(zip([0, *notches], notches, strict=False)) if b != a]
    assert all(abs(d) == 1 for _, d in changes)
    assert all(j - i >= 3 for (i, _), (j, _) in zip(changes, changes[1:], strict=False))  # 3 cycles = 0.3 s
    assert notches[:12] == [1, 1, 1, 2, 2, 2, 3, 3, 3, 4, 4, 4]  # the climb: a notch per hold
    assert max(notches) <= 4 and min(notches[12:]) >= 3
    settled = TABLE[notches[100:]]
    assert abs(float(settled.mean()) - target) < 0.02
    # The ramp is followed, not a step: the error integrals stay small through the climb.
    assert abs(stepped[MOD_E2]) < 0.05
    at_once = np.empty(MOD_SIZE)
    modulator_init_1(at_once)
    first = modulator_update_1(at_once, TABLE, hold, dead, lag, target, True, 0.1, 0.0, False, 0.0)
    assert first in (3, 4)


def test_a_dead_time_beyond_the_ring_is_added_to_the_lag() -> None:
    """The ring holds MOD_RING_SIZE - 2 cycles; a longer dead time keeps that many and adds the rest
    to the lag, so the modelled response still converges to the notch held."""
    mod = np.empty(MOD_SIZE)
    modulator_init_1(mod)
    dead = (MOD_RING_SIZE + 5) * 0.1
    notches = _drive(mod, TABLE, [0.5] * 400, dead, 0.4)
    assert abs(mod[MOD_NOW] - np.mean(TABLE[notches[-100:]])) < 0.1


def _settled_ahead_of_the_target() -> np.ndarray:
    """A modulator settled on a target of 0.5 m/s^2 (between notches 3 and 4), free to change, whose
    train is 0.3 m ahead of the target trajectory (that judgement brakes more: notch 4)."""
    table = np.array([0.0, 0.143, 0.286, 0.429, 0.571, 0.714, 0.857, 1.0])
    mod = np.empty(MOD_SIZE)
    modulator_init_1(mod)
    for _ in range(50):
        modulator_update_1(mod, table, 0.3, 0.35, 0.45, 0.5, True, 0.1, 0.0, False, 0.0)
    mod[MOD_HELD] = 10.0
    mod[MOD_E2] = 0.3
    return mod


def _end_choice(left_m: float, external_mps2: float = 0.0, gain: float = 1.0) -> int:
    table = np.array([0.0, 0.143, 0.286, 0.429, 0.571, 0.714, 0.857, 1.0])
    mod = _settled_ahead_of_the_target()
    modulator_aim_1(mod, left_m, external_mps2, gain)
    return int(modulator_update_1(mod, table, 0.3, 0.35, 0.45, 0.5, True, 0.1, 0.6, True, 0.0))


def test_aimed_end_phase_judges_the_notches_against_the_measured_stopping_point() -> None:
    """Stop model 23: told the distance to the stopping point (the wayside of forms 7 and 8 measures
    it with its radar), the end phase picks the notch whose plan stops nearest that point, with
    the braking as the caller knows it, whatever the target trajectory says; told none (NaN) it
    judges against the target trajectory as before. At 0.6 m/s, between notches 3 and 4:"""
    assert _end_choice(np.nan) == 4  # the target trajectory: ahead of it, brake more
    assert _end_choice(1.0) == 3  # the point far: the lower notch, though ahead of the target
    assert _end_choice(0.3) == 4  # the point near: the higher
    assert _end_choice(0.3, external_mps2=0.3) == 3  # uphill helps: the lower reaches it
    assert _end_choice(0.5) == 3
    assert _end_choice(0.5, external_mps2=-0.2) == 4  # downhill: the higher
    assert _end_choice(0.45) == 3
    assert _end_choice(0.45, gain=0.7) == 4  # brakes 30 % weak: the higher
    assert _end_choice(0.3, gain=1.3) == 3  # brakes 30 % strong: the lower
