"""The brake chain of SPEC §1: brake-line step code, PWM, ECU, actuator dynamics.

Expected values come from the SPEC table (fig. 3), from closed forms of the
first-order lag and from a brute-force sampling of pulse trains, never from
the code under test.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railstop.config import default_vehicle
from railstop.config.schema import BrakeModel
from railstop.physics.brake import (
    STEP_CODE,
    ActuatorState,
    BrakeLine,
    actuator_step,
    braking_decel_mps2,
    decel_to_pwm,
    decode_step,
    ecu_demand_mps2,
    encode_step,
    notch_decel,
    or_pulse_duty,
    pwm_to_decel,
    superimpose_pwm,
)

# SPEC §1 fig. 3, copied from the SPEC: step -> wires (a, b, c); 000 = no service brake.
SPEC_FIG3 = {
    0: (0, 0, 0),
    1: (0, 0, 1),  # B1
    2: (0, 1, 0),  # B2
    3: (0, 1, 1),  # B3
    4: (1, 0, 0),  # B4
    5: (1, 0, 1),  # B5
    6: (1, 1, 0),  # B6
    7: (1, 1, 1),  # B7
}

BRAKE = default_vehicle().brake
FAST = settings(max_examples=60, deadline=None)


def _line(a: int, b: int, c: int, e: int = 0) -> BrakeLine:
    def arr(x: int) -> np.ndarray:
        return np.array([x], dtype=np.int8)

    return BrakeLine(a=arr(a), b=arr(b), c=arr(c), e=arr(e))


# --------------------------------------------------------------------------
# Step code (SPEC §1 fig. 3)


def test_step_code_table_is_spec_fig3() -> None:
    # A wrong wire pattern would make every ECU apply the wrong notch.
    assert STEP_CODE == SPEC_FIG3


def test_encode_step_gives_spec_wires() -> None:
    notches = np.arange(8)
    line = encode_step(notches)
    for n, (a, b, c) in SPEC_FIG3.items():
        assert (line.a[n], line.b[n], line.c[n]) == (a, b, c)
    # No emergency unless asked for.
    assert not line.e.any()


def test_decode_every_wire_pattern() -> None:
    # The ECU side must read every 3-bit pattern as the SPEC step.
    for n, (a, b, c) in SPEC_FIG3.items():
        assert decode_step(_line(a, b, c))[0] == n


@given(st.lists(st.integers(0, 7), min_size=1, max_size=50))
@FAST
def test_encode_decode_round_trip(notches: list[int]) -> None:
    arr = np.array(notches, dtype=np.int64)
    np.testing.assert_array_equal(decode_step(encode_step(arr)), arr)


@pytest.mark.parametrize("bad", [-1, 8, 100])
def test_encode_out_of_range_notch_rejected(bad: int) -> None:
    # Only 8 codes exist on three wires; anything else must not be silently wrapped.
    with pytest.raises(ValueError, match=str(bad)):
        encode_step(np.array([3, bad, 2]))


def test_encode_emergency_sets_wire_e() -> None:
    line = encode_step(np.array([0, 5, 7]), np.array([True, False, True]))
    np.testing.assert_array_equal(line.e, [1, 0, 1])


def test_notch_decel_uses_table() -> None:
    table = [0.0, *BRAKE.notch_decel_mps2]
    np.testing.assert_allclose(notch_decel(np.arange(8), BRAKE), table)


# --------------------------------------------------------------------------
# PWM map


def _rising_part(brake: BrakeModel) -> tuple[float, float, float, float]:
    """(duty_lo, duty_hi, decel_lo, decel_hi) of the map's rising part."""
    duty, dec = brake.pwm_duty, brake.pwm_decel_mps2
    lo = max(i for i, d in enumerate(dec) if d == min(dec))
    hi = min(i for i, d in enumerate(dec) if d == max(dec))
    return duty[lo], duty[hi], dec[lo], dec[hi]


def _interp(x: float, xs: list[float], ys: list[float]) -> float:
    # Independent piecewise-linear evaluation (no numpy) of a map.
    if x <= xs[0]:
        return ys[0]
    for (x0, y0), (x1, y1) in itertools.pairwise(zip(xs, ys, strict=True)):
        if x <= x1:
            return y0 + (y1 - y0) * (x - x0) / (x1 - x0)
    return ys[-1]


@given(st.floats(0.0, 1.0))
@FAST
def test_pwm_to_decel_is_the_map(duty: float) -> None:
    got = pwm_to_decel(np.array([duty]), BRAKE)[0]
    assert got == pytest.approx(_interp(duty, BRAKE.pwm_duty, BRAKE.pwm_decel_mps2), abs=1e-12)


@given(st.floats(0.0, 1.0))
@FAST
def test_pwm_round_trip_duty(frac: float) -> None:
    # On the rising part the map is one-to-one: duty -> decel -> duty.
    u_lo, u_hi, _, _ = _rising_part(BRAKE)
    u = u_lo + frac * (u_hi - u_lo)
    back = decel_to_pwm(pwm_to_decel(np.array([u]), BRAKE), BRAKE)[0]
    assert back == pytest.approx(u, abs=1e-9)


@given(st.floats(0.0, 1.0))
@FAST
def test_pwm_round_trip_decel(frac: float) -> None:
    # Any service deceleration the map can give is reproduced by its duty.
    _, _, d_lo, d_hi = _rising_part(BRAKE)
    d = d_lo + frac * (d_hi - d_lo)
    duty = decel_to_pwm(np.array([d]), BRAKE)
    assert pwm_to_decel(duty, BRAKE)[0] == pytest.approx(d, abs=1e-9)


def test_pwm_inverse_with_plateau_in_map() -> None:
    # The schema allows a non-decreasing map (pwm_decel_mps2 "must not
    # decrease"), so a plateau in the middle is valid data. The inverse must
    # still give a duty whose deceleration is the one asked for.
    brake = BRAKE.model_copy(
        update={
            "pwm_duty": [0.0, 0.1, 0.4, 0.6, 0.9, 1.0],
            "pwm_decel_mps2": [0.0, 0.0, 0.5, 0.5, 1.0, 1.0],
        }
    )
    d = np.linspace(0.0, 1.0, 21)
    np.testing.assert_allclose(pwm_to_decel(decel_to_pwm(d, brake), brake), d, atol=1e-9)


# --------------------------------------------------------------------------
# PWM superposition (SPEC §1 config 3)


def test_superimpose_spec_example() -> None:
    # SPEC §1: existing 50 % + onboard 70 % -> the ECU sees 70 %.
    assert superimpose_pwm(np.array([0.5]), np.array([0.7]))[0] == pytest.approx(0.7)
    assert superimpose_pwm(np.array([0.7]), np.array([0.5]))[0] == pytest.approx(0.7)


def _sampled_or(d1: float, d2: float, phase: float, n: int = 10_000) -> float:
    # Brute force: sample one period at n midpoints; pulse 1 is high on
    # [0, d1), pulse 2 on [phase, phase + d2) modulo one period.
    t = (np.arange(n) + 0.5) / n
    high1 = t < d1
    high2 = np.mod(t - phase, 1.0) < d2
    return float(np.mean(high1 | high2))


duties = st.floats(0.0, 1.0)


@given(duties, duties)
@FAST
def test_or_pulse_phase_zero_is_max(d1: float, d2: float) -> None:
    # Synchronised at the zero crossing, OR of two pulses = the longer pulse.
    got = or_pulse_duty(np.array([d1]), np.array([d2]), np.array([0.0]))[0]
    assert got == pytest.approx(max(d1, d2), abs=1e-12)
    assert superimpose_pwm(np.array([d1]), np.array([d2]))[0] == pytest.approx(got, abs=1e-12)


@given(duties, duties, st.floats(-2.0, 2.0))
@FAST
def test_or_pulse_matches_sampled_union(d1: float, d2: float, phase: float) -> None:
    # Why SPEC §1 config 3 synchronises: an unsynchronised OR is longer than
    # either pulse, i.e. the ECU would brake harder than both commands.
    got = or_pulse_duty(np.array([d1]), np.array([d2]), np.array([phase]))[0]
    assert got >= max(d1, d2) - 1e-12
    assert got <= min(d1 + d2, 1.0) + 1e-12
    assert got == pytest.approx(_sampled_or(d1, d2, phase), abs=1e-3)


# --------------------------------------------------------------------------
# Actuator: dead time, jerk limiter, first-order lag

EMERGENCY = 1.3


def _run(
    demands: np.ndarray,
    *,
    dt: float,
    dead: float | np.ndarray,
    tau: float = 0.45,
    jerk: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Feed ``demands`` (steps x n) through an actuator; return (limited, output) histories."""
    demands = np.atleast_2d(np.asarray(demands, dtype=np.float64).T).T
    steps, n = demands.shape
    state = ActuatorState.create(
        n=n,
        dt_s=dt,
        dead_time_s=np.broadcast_to(np.asarray(dead, dtype=np.float64), (n,)).copy(),
        time_constant_s=np.full(n, tau),
        jerk_limit_mps3=jerk,
        emergency_mps2=EMERGENCY,
    )
    lim = np.empty((steps, n))
    out = np.empty((steps, n))
    for k in range(steps):
        out[k] = actuator_step(state, demands[k])
        lim[k] = state.limited_mps2
    return lim, out


@pytest.mark.parametrize(("tau", "dt"), [(0.3, 0.01), (0.45, 0.01), (0.6, 0.02)])
def test_first_order_lag_time_constant(tau: float, dt: float) -> None:
    # Closed form of a first-order lag to a step u: y(t) = u (1 - e^(-t/tau));
    # after one time constant 63.2 %. Zero dead time and a jerk limit large
    # enough that the limiter passes the step at once.
    u = 1.0
    steps = round(3 * tau / dt)
    _, out = _run(np.full(steps, u), dt=dt, dead=0.0, tau=tau, jerk=1e6)
    n_tau = round(tau / dt)
    assert out[n_tau - 1, 0] / u == pytest.approx(1.0 - math.exp(-1.0), abs=0.01)
    assert out[n_tau - 1, 0] / u == pytest.approx(0.632, abs=0.01)
    # And the whole response follows the closed form (output k is after k+1 steps).
    t = (np.arange(steps) + 1) * dt
    np.testing.assert_allclose(out[:, 0], u * (1.0 - np.exp(-t / tau)), atol=1e-9)


@given(
    st.lists(st.integers(0, 40), min_size=1, max_size=4),
    st.floats(-0.3, 0.3),
    st.lists(st.floats(0.0, 1.25), min_size=5, max_size=60),
)
@FAST
def test_dead_time_delays_by_rounded_steps(
    delay_steps: list[int], offset: float, demand_values: list[float]
) -> None:
    # A pure delay of round(dead/dt) steps: the delayed response is the
    # undelayed one shifted, and nothing happens before. Several runs with
    # different dead times in one state check that each run has its own delay.
    dt = 0.01
    # |offset| <= 0.3 step, so round(dead / dt) is the integer k of each run.
    dead = np.array([max(k + offset, 0.0) * dt for k in delay_steps])
    expected_shift = delay_steps
    steps = len(demand_values) + 50
    demand = np.zeros(steps)
    demand[: len(demand_values)] = demand_values
    n = len(delay_steps)
    lim_d, out_d = _run(np.tile(demand[:, None], (1, n)), dt=dt, dead=dead)
    lim_0, out_0 = _run(demand, dt=dt, dead=0.0)
    for j, k in enumerate(expected_shift):
        assert np.all(out_d[:k, j] == 0.0)
        np.testing.assert_allclose(out_d[k:, j], out_0[: steps - k, 0], atol=1e-12)
        np.testing.assert_allclose(lim_d[k:, j], lim_0[: steps - k, 0], atol=1e-12)


@given(
    st.lists(st.floats(0.0, 1.25), min_size=2, max_size=80),
    st.floats(0.1, 5.0),
    st.sampled_from([0.005, 0.01, 0.02]),
)
@FAST
def test_jerk_limiter_bounds_rate(values: list[float], jerk: float, dt: float) -> None:
    # Comfort (SPEC §1 "non-safe braking"): below the emergency level the
    # limited demand never changes by more than jerk * dt per step.
    demand = np.repeat(np.array(values), 5)
    lim, out = _run(demand, dt=dt, dead=0.0, jerk=jerk)
    steps = np.diff(np.concatenate(([0.0], lim[:, 0])))
    assert np.all(np.abs(steps) <= jerk * dt * (1 + 1e-9) + 1e-15)
    # The lag output never leaves the range the limited demand spans.
    assert np.all(out[:, 0] >= -1e-12)
    assert np.all(out[:, 0] <= max(values) + 1e-12)


def test_jerk_limiter_reaches_held_demand() -> None:
    # A held demand is reached after demand / (jerk dt) steps, not before.
    dt, jerk, u = 0.01, 1.0, 0.8
    lim, _ = _run(np.full(200, u), dt=dt, dead=0.0, jerk=jerk)
    ramp = np.minimum((np.arange(200) + 1) * jerk * dt, u)
    np.testing.assert_allclose(lim[:, 0], ramp, atol=1e-12)


@pytest.mark.parametrize("dead_steps", [0, 7])
def test_emergency_bypasses_jerk_limiter(dead_steps: int) -> None:
    # Fail safe (DESIGN rule 7): the emergency brake is not softened by the
    # comfort limiter; it only waits for the dead time.
    dt = 0.01
    lim, _ = _run(np.full(20, EMERGENCY), dt=dt, dead=dead_steps * dt, jerk=1.0)
    assert np.all(lim[:dead_steps, 0] == 0.0)
    assert lim[dead_steps, 0] == pytest.approx(EMERGENCY)
    # A service demand just below emergency is rate limited (contrast).
    lim_s, _ = _run(np.full(20, EMERGENCY - 0.05), dt=dt, dead=0.0, jerk=1.0)
    assert lim_s[0, 0] == pytest.approx(1.0 * dt)


# --------------------------------------------------------------------------
# Brake ECU and the force it produces


def test_ecu_step_demand_uses_notch_table() -> None:
    notches = np.arange(8)
    demand = ecu_demand_mps2(line=encode_step(notches), duty=None, emergency=np.zeros(8, bool), brake=BRAKE)
    expected = [0.0, *BRAKE.notch_decel_mps2]
    np.testing.assert_allclose(demand, expected)


def test_ecu_wire_e_gives_emergency() -> None:
    # Wire e overrides the service command whatever the notch (SPEC §1 fig. 2).
    notches = np.arange(8)
    line = encode_step(notches, np.ones(8, bool))
    demand = ecu_demand_mps2(line=line, duty=None, emergency=np.zeros(8, bool), brake=BRAKE)
    np.testing.assert_allclose(demand, BRAKE.emergency_decel_mps2)
    # The separate emergency input does the same for a line without wire e.
    demand = ecu_demand_mps2(line=encode_step(notches), duty=None, emergency=np.ones(8, bool), brake=BRAKE)
    np.testing.assert_allclose(demand, BRAKE.emergency_decel_mps2)


@given(st.lists(duties, min_size=1, max_size=10))
@FAST
def test_ecu_pwm_demand_uses_map(values: list[float]) -> None:
    duty = np.array(values)
    demand = ecu_demand_mps2(line=None, duty=duty, emergency=np.zeros(duty.size, bool), brake=BRAKE)
    expected = [_interp(d, BRAKE.pwm_duty, BRAKE.pwm_decel_mps2) for d in values]
    np.testing.assert_allclose(demand, expected, atol=1e-12)
    emerg = ecu_demand_mps2(line=None, duty=duty, emergency=np.ones(duty.size, bool), brake=BRAKE)
    np.testing.assert_allclose(emerg, BRAKE.emergency_decel_mps2)


def test_ecu_needs_an_input() -> None:
    with pytest.raises(ValueError):
        ecu_demand_mps2(line=None, duty=None, emergency=np.zeros(1, bool), brake=BRAKE)


pos = st.floats(1e3, 1e6)


@given(st.floats(0.0, 1.5), st.floats(0.5, 1.5), pos, pos)
@FAST
def test_braking_decel_load_compensation(demand: float, gain: float, believed: float, actual: float) -> None:
    # The ECU sets force F = demand x believed mass x gain; the train decelerates at F / m.
    got = braking_decel_mps2(
        np.array([demand]),
        brake_gain=np.array([gain]),
        believed_effective_kg=np.array([believed]),
        effective_kg=np.array([actual]),
    )[0]
    force = demand * believed * gain
    assert got == pytest.approx(force / actual, rel=1e-12, abs=1e-15)
    # With perfect weighing and a nominal brake the train gets exactly the demand.
    exact = braking_decel_mps2(
        np.array([demand]),
        brake_gain=np.array([1.0]),
        believed_effective_kg=np.array([actual]),
        effective_kg=np.array([actual]),
    )[0]
    assert exact == pytest.approx(demand, rel=1e-12, abs=1e-15)
