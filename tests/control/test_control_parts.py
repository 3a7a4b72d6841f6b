"""The pieces of the TASC law and the notch modulator, each against a closed form or a fine integration.

They call the compiled scalar cores the stop kernel runs (numba dispatchers are callable from
Python), with their state arrays set up as the kernel sets them up.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from railstop.control.notch import (
    MOD_APPLIED,
    MOD_E1,
    MOD_E2,
    MOD_HELD,
    MOD_SIZE,
    MOD_TARGET,
    modulator_init_1,
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
    """The speed now from the newest samples; a long line misses the last ripple."""
    dt = 0.01
    t = np.arange(400) * dt
    decel = 0.5 + 0.07 * np.sign(np.sin(2 * np.pi * t / 2.0))  # notch alternation, 2 s period
    v = 3.0 - np.cumsum(decel) * dt
    # A ring buffer holding the 400 samples, the newest in its last slot; a speed
    # window as long as the ring is the one long line.
    v_long, a_long = fit_ring_1(v, 399, 400, dt, 400)
    v_short, a_same = fit_ring_1(v, 399, 400, dt, 30)
    assert a_same == a_long  # the deceleration still comes from the whole window
    assert abs(v_short - v[-1]) < 0.2 * abs(v_long - v[-1])
    assert abs(v_short - v[-1]) < 0.005
    # Where the newest sample sits in the ring does not matter (the oldest follows it cyclically).
    ring = np.roll(v, -150)
    assert fit_ring_1(ring, 249, 400, dt, 30) == (v_short, a_same)


def test_end_phase_picks_the_notch_that_stops_nearest() -> None:
    """Near standstill the modulator judges notches by the predicted stopping point."""
    table = np.array([0.0, 0.143, 0.286, 0.429, 0.571, 0.714, 0.857, 1.0])  # notch 0 released
    hold, response = 0.5, 0.8
    mod = np.empty(MOD_SIZE)
    modulator_init_1(mod)
    target = 0.5
    # Settle on the target far from the stop (no speed: plain sigma-delta).
    for _ in range(50):
        modulator_update_1(mod, table, hold, response, target, True, 0.1, 0.0, False)
    # Now 0.6 m/s from standstill: the end phase decides; its choice must be
    # the notch whose plan stops nearer the target trajectory's stop.
    mod[MOD_HELD] = 10.0
    speed = 0.6
    chosen = modulator_update_1(mod, table, hold, response, target, True, 0.1, speed, True)
    assert chosen in (3, 4)
    goal = stopping_distance_under_lag_1(speed - mod[MOD_E1], mod[MOD_TARGET], target, 0.8) - mod[MOD_E2]
    miss = {
        n: abs(stopping_distance_under_lag_1(speed, mod[MOD_APPLIED], table[n], 0.8) - goal) for n in (3, 4)
    }
    # Holding the chosen notch to standstill is never the clearly worse of the two.
    other = 7 - chosen
    assert miss[chosen] <= miss[other] + 0.05
