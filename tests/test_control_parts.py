"""The pieces of the TASC law and the notch modulator, each against a closed form or a fine integration."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from railstop.control.notch import NotchModulator, stopping_distance_under_lag
from railstop.control.tasc import CommandHistory, GainEstimate, fit_doppler


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
    got = stopping_distance_under_lag(np.array([v0]), np.array([a0]), np.array([c]), tau)[0]
    ref = _integrate_stop(v0, a0, c, tau)
    assert abs(got - ref) <= 1e-3 + 1e-3 * ref


def test_stopping_distance_without_transient_is_v2_over_2a() -> None:
    v = np.array([1.0, 2.5, 3.0])
    a = np.array([0.3, 0.5, 0.8])
    got = stopping_distance_under_lag(v, a, a, 0.7)
    np.testing.assert_allclose(got, v * v / (2 * a), rtol=1e-9)


def test_gain_estimate_is_least_squares_over_windows() -> None:
    est = GainEstimate.create(2)
    rows = np.array([0, 1])
    # Run 0: brake gain 0.85, run 1: 1.1; external decel 0.05; two windows each.
    for c in (0.6, 0.45):
        commanded = np.array([c, c])
        measured = np.array([0.85, 1.1]) * commanded + 0.05
        g = est.update(rows, measured, commanded, np.full(2, 0.05))
    np.testing.assert_allclose(g, [0.85, 1.1], rtol=1e-12)
    # A ripple that alternates sign between windows averages out, where the
    # last window alone would be 4 % off.
    est = GainEstimate.create(1)
    r = np.array([0])
    for ripple in (+0.04, -0.04, +0.04, -0.04):
        g = est.update(r, np.array([0.6 * (1.0 + ripple)]), np.array([0.6]), np.zeros(1))
    assert abs(g[0] - 1.0) < 1e-12
    # Windows with too small a command (before braking) do not count.
    est = GainEstimate.create(1)
    g = est.update(r, np.array([0.05]), np.array([0.01]), np.zeros(1))
    assert g[0] == 1.0


def test_command_response_is_a_first_order_lag_around_the_effect_time() -> None:
    hist = CommandHistory.create(1)
    mask = np.array([True])
    hist.push(mask, np.array([0.6]), np.array([5.0]))
    lag = 0.45
    t = np.array([[4.0, 5.0 - lag, 5.0, 6.0]])
    got = hist.response_at(t, lag)[0]
    expected = 0.6 * (1.0 - np.exp(-np.maximum(t[0] - (5.0 - lag), 0.0) / lag))
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    # The mean delay equals the effect time: the integral of (step - response) is 0.
    ts = np.linspace(0.0, 20.0, 200001)[None, :]
    step = np.where(ts >= 5.0, 0.6, 0.0)
    area = np.trapezoid(step - hist.response_at(ts, lag), ts, axis=1)[0]
    assert abs(area) < 1e-3


def test_short_speed_window_follows_a_rippling_deceleration() -> None:
    """The speed now from the newest samples; a long line misses the last ripple."""
    dt = 0.01
    t = np.arange(400) * dt
    decel = 0.5 + 0.07 * np.sign(np.sin(2 * np.pi * t / 2.0))  # notch alternation, 2 s period
    v = 3.0 - np.cumsum(decel) * dt
    samples = v[None, :]
    count = np.array([400])
    v_long, a_long = fit_doppler(samples, dt, count)
    v_short, a_same = fit_doppler(samples, dt, count, speed_samples=30)
    assert a_same[0] == a_long[0]  # the deceleration still comes from the whole window
    assert abs(v_short[0] - v[-1]) < 0.2 * abs(v_long[0] - v[-1])
    assert abs(v_short[0] - v[-1]) < 0.005


def test_end_phase_picks_the_notch_that_stops_nearest() -> None:
    """Near standstill the modulator judges notches by the predicted stopping point."""
    table = [0.143, 0.286, 0.429, 0.571, 0.714, 0.857, 1.0]
    mod = NotchModulator.create(1, table, min_hold_s=0.5, response_s=0.8)
    active = np.array([True])
    target = np.array([0.5])
    # Settle on the target far from the stop (no speed: plain sigma-delta).
    for _ in range(50):
        mod.update(target, active, 0.1)
    # Now 0.6 m/s from standstill: the end phase decides; its choice must be
    # the notch whose plan stops nearer the target trajectory's stop.
    mod.held_s[:] = 10.0
    speed = np.array([0.6])
    chosen = mod.update(target, active, 0.1, speed)[0]
    assert chosen in (3, 4)
    goal = stopping_distance_under_lag(speed - mod.e1_mps, mod.target_mps2, target, 0.8) - mod.e2_m
    miss = {
        n: abs(stopping_distance_under_lag(speed, mod.applied_mps2, np.array([table[n - 1]]), 0.8) - goal)[0]
        for n in (3, 4)
    }
    # Holding the chosen notch to standstill is never the clearly worse of the two.
    other = 7 - chosen
    assert miss[chosen] <= miss[other] + 0.05
