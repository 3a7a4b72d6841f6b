"""Longitudinal train dynamics: closed-form checks of physics/train.py.

m_eff dv/dt = -(F_brake + R(v) + m g i). Each test isolates one term and
compares with its closed form: a constant deceleration stops at v²/2a after
v/a, a gradient decelerates at g i m / m_eff, adhesion caps braking at
mu g m / m_eff, the tachometer scales by D_assumed / D_actual.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from railstop.config import default_vehicle
from railstop.config.gradient import GradientProfile
from railstop.config.schema import Vehicle
from railstop.physics.train import (
    G_MPS2,
    MotionState,
    TrainMass,
    adhesion_limit_mps2,
    davis_resistance_n,
    motion_step,
    odometer_increment_m,
)

FAST = settings(max_examples=40, deadline=None)
VEHICLE = default_vehicle()


def _no_resistance() -> Vehicle:
    # Davis terms 0 so that the brake (or the gradient) is the only force.
    return VEHICLE.model_copy(update={"davis_a_n": 0.0, "davis_b_n_per_mps": 0.0, "davis_c_n_per_mps2": 0.0})


def _state(speed: np.ndarray, position: float = 0.0) -> MotionState:
    n = speed.size
    return MotionState(
        position_m=np.full(n, position),
        speed_mps=speed.astype(np.float64).copy(),
        accel_mps2=np.zeros(n),
        stopped=np.zeros(n, bool),
        stop_time_s=np.full(n, np.nan),
        sliding=np.zeros(n, bool),
    )


def _mass(n: int, load: float = 0.5, err: float = 0.0) -> TrainMass:
    return TrainMass.create(VEHICLE, np.full(n, load), np.full(n, err))


def _step(
    state: MotionState,
    vehicle: Vehicle,
    mass: TrainMass,
    brake: np.ndarray,
    *,
    t: float,
    dt: float,
    grad: np.ndarray | None = None,
    mu: float = 0.5,
    hold: np.ndarray | None = None,
) -> None:
    n = state.speed_mps.size
    motion_step(
        state,
        vehicle=vehicle,
        mass=mass,
        brake_decel_mps2=brake,
        mean_gradient=np.zeros(n) if grad is None else grad,
        adhesion_mu=np.full(n, mu),
        speed_hold=np.zeros(n, bool) if hold is None else hold,
        t_s=t,
        dt_s=dt,
    )


# --------------------------------------------------------------------------
# Constant deceleration: stopping distance and time


@given(
    st.lists(st.tuples(st.floats(1.0, 25.0), st.floats(0.3, 1.3)), min_size=1, max_size=8),
    st.sampled_from([0.01, 0.02, 0.05, 0.1]),
)
@FAST
def test_constant_decel_stops_at_v2_over_2a(runs: list[tuple[float, float]], dt: float) -> None:
    # The core accuracy claim of the simulator: a train braking at a constant
    # a from v stops after exactly v²/2a and v/a, whatever the step size;
    # the step that crosses zero must be cut at the true standstill.
    v0 = np.array([r[0] for r in runs])
    a = np.array([r[1] for r in runs])
    veh = _no_resistance()
    mass = _mass(v0.size)
    state = _state(v0, position=100.0)
    k = 0
    while not state.stopped.all():
        _step(state, veh, mass, a, t=k * dt, dt=dt)
        k += 1
        assert k < 10_000
    np.testing.assert_allclose(state.position_m - 100.0, v0**2 / (2 * a), rtol=1e-9)
    np.testing.assert_allclose(state.stop_time_s, v0 / a, rtol=1e-9)
    assert np.all(state.speed_mps == 0.0)
    # Once stopped, the brake holds it: no creeping, no reversing.
    pos = state.position_m.copy()
    for j in range(5):
        _step(state, veh, mass, a, t=(k + j) * dt, dt=dt)
    np.testing.assert_array_equal(state.position_m, pos)
    np.testing.assert_array_equal(state.speed_mps, 0.0)


def test_davis_resistance_adds_to_the_brake() -> None:
    # With the Davis terms on, the step's deceleration is the brake plus
    # R(v)/m_eff with R = A + B v + C v² (the "compute with them and subtract" check).
    v = np.array([5.0, 10.0, 20.0])
    a = np.array([0.5, 0.5, 0.5])
    mass = _mass(3)
    state = _state(v)
    _step(state, VEHICLE, mass, a, t=0.0, dt=0.01)
    resist = VEHICLE.davis_a_n + VEHICLE.davis_b_n_per_mps * v + VEHICLE.davis_c_n_per_mps2 * v * v
    np.testing.assert_allclose(davis_resistance_n(VEHICLE, v), resist)
    np.testing.assert_allclose(-state.accel_mps2 - a, resist / mass.effective_kg, rtol=1e-12)
    np.testing.assert_allclose(state.speed_mps, v - (a + resist / mass.effective_kg) * 0.01)


# --------------------------------------------------------------------------
# Gradient


@pytest.mark.parametrize("load", [0.0, 1.0])
def test_uphill_gradient_decelerates_at_g_i_m_over_meff(load: float) -> None:
    # Gradient force m g i acts on the static mass; the rotating mass adds
    # inertia only, so the deceleration is g i m / m_eff (< g i).
    profile = GradientProfile.create(np.array([]), np.array([[10.0]]))  # 10 permille up
    veh = _no_resistance()
    mass = TrainMass.create(veh, np.array([load]), np.array([0.0]))
    v0, dt, steps = 15.0, 0.05, 100
    state = _state(np.array([v0]), position=500.0)
    for k in range(steps):
        grad = profile.mean_gradient(state.position_m, veh.length_m)
        np.testing.assert_allclose(grad, 0.010, rtol=1e-12)
        _step(state, veh, mass, np.zeros(1), t=k * dt, dt=dt, grad=grad)
    m = veh.tare_mass_kg + load * veh.crush_payload_kg
    m_eff = m + veh.tare_mass_kg * veh.rotating_mass_factor
    expected = G_MPS2 * 0.010 * m / m_eff
    assert -state.accel_mps2[0] == pytest.approx(expected, rel=1e-12)
    assert expected < G_MPS2 * 0.010
    assert state.speed_mps[0] == pytest.approx(v0 - expected * steps * dt, rel=1e-12)
    t = steps * dt
    assert state.position_m[0] - 500.0 == pytest.approx(v0 * t - 0.5 * expected * t * t, rel=1e-9)


def test_downhill_gradient_accelerates() -> None:
    veh = _no_resistance()
    mass = _mass(1)
    state = _state(np.array([10.0]))
    _step(state, veh, mass, np.zeros(1), t=0.0, dt=0.1, grad=np.array([-0.02]))
    expected = G_MPS2 * 0.02 * mass.static_kg[0] / mass.effective_kg[0]
    assert state.accel_mps2[0] == pytest.approx(expected, rel=1e-12)
    assert state.speed_mps[0] > 10.0


def _analytic_mean(bps: list[float], vals: list[float], front: float, length: float) -> float:
    # Mean gradient (fraction) over [front - length, front]: sum of
    # value x overlap over the intervals (-inf, b0), [b0, b1), ..., [b_last, inf).
    edges = [-np.inf, *bps, np.inf]
    lo, hi = front - length, front
    total = 0.0
    for j, v in enumerate(vals):
        overlap = max(0.0, min(hi, edges[j + 1]) - max(lo, edges[j]))
        total += v * 1e-3 * overlap
    return total / length


@given(
    st.floats(0.0, 1.0),
    st.floats(-40.0, 40.0),
    st.floats(-40.0, 40.0),
    st.floats(20.0, 200.0),
)
@FAST
def test_mean_gradient_straddling_one_change(frac: float, g0: float, g1: float, length: float) -> None:
    # A train of length L whose front is s metres past a gradient change
    # feels (g0 (L - s) + g1 s) / L: the force changes continuously as it
    # runs over the change.
    b = 1000.0
    s = frac * length
    profile = GradientProfile.create(np.array([b]), np.array([[g0, g1]]))
    got = profile.mean_gradient(np.array([b + s]), length)[0]
    expected = (g0 * (length - s) + g1 * s) / length * 1e-3
    assert got == pytest.approx(expected, abs=1e-12)


@given(
    st.lists(st.floats(0.0, 1000.0), min_size=1, max_size=5, unique=True),
    st.data(),
    st.lists(st.floats(-1400.0, 1400.0), min_size=1, max_size=10),
    st.floats(20.0, 250.0),
)
@FAST
def test_mean_gradient_matches_analytic_average(
    bps: list[float], data: st.DataObject, fronts: list[float], length: float
) -> None:
    bps = sorted(bps)
    assume(all(b - a > 1e-3 for a, b in itertools.pairwise(bps)))
    vals = data.draw(st.lists(st.floats(-40.0, 40.0), min_size=len(bps) + 1, max_size=len(bps) + 1))
    profile = GradientProfile.create(np.array(bps), np.array([vals]))
    got = profile.mean_gradient(np.array(fronts), length)
    expected = [_analytic_mean(bps, vals, f, length) for f in fronts]
    np.testing.assert_allclose(got, expected, atol=1e-9)


def test_mean_gradient_per_run_values_and_rows() -> None:
    # Each run has its own gradient values (a disturbance draw); a row subset
    # must pick the right runs.
    bps = [100.0, 300.0]
    vals = np.array([[0.0, 10.0, -5.0], [20.0, 0.0, 5.0], [-10.0, -10.0, 30.0]])
    profile = GradientProfile.create(np.array(bps), vals)
    fronts = np.array([150.0, 350.0, 320.0])
    got = profile.mean_gradient(fronts, 100.0)
    expected = [_analytic_mean(bps, list(vals[i]), fronts[i], 100.0) for i in range(3)]
    np.testing.assert_allclose(got, expected, atol=1e-12)
    rows = np.array([2, 0])
    got_rows = profile.mean_gradient(fronts[rows], 100.0, rows)
    np.testing.assert_allclose(got_rows, [expected[2], expected[0]], atol=1e-12)


def test_gradient_profile_rejects_bad_shapes() -> None:
    with pytest.raises(ValueError):
        GradientProfile.create(np.array([1.0, 2.0]), np.array([[0.0, 1.0]]))
    with pytest.raises(ValueError):
        GradientProfile.create(np.array([2.0, 1.0]), np.array([[0.0, 1.0, 2.0]]))


# --------------------------------------------------------------------------
# Adhesion


@pytest.mark.parametrize("mu", [0.05, 0.1, 0.2])
def test_adhesion_caps_braking_and_sets_sliding(mu: float) -> None:
    # Friction force mu m g (static mass on the rail) decelerates the
    # effective mass: the largest braking deceleration is mu g m / m_eff.
    veh = _no_resistance()
    mass = _mass(3, load=0.3)
    limit = mu * G_MPS2 * mass.static_kg / mass.effective_kg
    np.testing.assert_allclose(adhesion_limit_mps2(np.full(3, mu), mass), limit)
    brake = np.array([0.5 * limit[0], 2.0 * limit[1], 1.3])
    state = _state(np.full(3, 20.0))
    _step(state, veh, mass, brake, t=0.0, dt=0.01, mu=mu)
    expected_slide = brake > limit
    np.testing.assert_array_equal(state.sliding, expected_slide)
    np.testing.assert_allclose(-state.accel_mps2, np.minimum(brake, limit), rtol=1e-12)
    assert state.sliding[1] and not state.sliding[0]


def test_speed_hold_keeps_speed() -> None:
    # Traction holds the approach speed until the TASC first brakes.
    state = _state(np.array([16.0, 16.0]))
    _step(
        state,
        VEHICLE,
        _mass(2),
        np.array([0.7, 0.7]),
        t=0.0,
        dt=0.1,
        grad=np.array([0.01, 0.01]),
        hold=np.array([True, False]),
    )
    assert state.speed_mps[0] == 16.0
    assert state.position_m[0] == pytest.approx(1.6)
    assert state.speed_mps[1] < 16.0


# --------------------------------------------------------------------------
# Masses


@given(st.floats(0.0, 1.0), st.floats(-0.2, 0.2))
@FAST
def test_train_mass(load: float, err: float) -> None:
    mass = TrainMass.create(VEHICLE, np.array([load]), np.array([err]))
    static = VEHICLE.tare_mass_kg + load * VEHICLE.crush_payload_kg
    rotating = VEHICLE.tare_mass_kg * VEHICLE.rotating_mass_factor
    assert mass.static_kg[0] == pytest.approx(static, rel=1e-12)
    assert mass.effective_kg[0] == pytest.approx(static + rotating, rel=1e-12)
    # The weighing error is what the ECU believes, not what the train weighs.
    exact = TrainMass.create(VEHICLE, np.array([load]), np.array([0.0]))
    assert mass.static_kg[0] == exact.static_kg[0]
    assert mass.effective_kg[0] == exact.effective_kg[0]
    assert exact.believed_effective_kg[0] == pytest.approx(exact.effective_kg[0], rel=1e-12)
    assert mass.believed_effective_kg[0] - mass.effective_kg[0] == pytest.approx(
        err * static, rel=1e-9, abs=1e-6
    )


def test_crush_load_adds_crush_payload() -> None:
    empty = TrainMass.create(VEHICLE, np.array([0.0]), np.array([0.0]))
    crush = TrainMass.create(VEHICLE, np.array([1.0]), np.array([0.0]))
    assert crush.static_kg[0] - empty.static_kg[0] == pytest.approx(VEHICLE.crush_payload_kg)
    assert crush.effective_kg[0] - empty.effective_kg[0] == pytest.approx(VEHICLE.crush_payload_kg)
    assert empty.static_kg[0] == pytest.approx(VEHICLE.tare_mass_kg)


# --------------------------------------------------------------------------
# Tachometer


@given(
    st.floats(1e-3, 50.0),
    st.floats(0.78, 0.86),
    st.floats(0.78, 0.86),
    st.floats(0.0, 0.5),
)
@FAST
def test_odometer_scales_by_diameter_and_slip(
    dist: float, actual: float, assumed: float, slip: float
) -> None:
    # SPEC §2: the odometer counts revolutions (distance / pi D_actual) and
    # multiplies by pi D_assumed; a worn wheel makes it over-read. A sliding
    # wheel turns (1 - slip) as often.
    args = {
        "actual_diameter_m": np.array([actual, actual]),
        "assumed_diameter_m": np.array([assumed, assumed]),
        "slide_slip_ratio": slip,
    }
    got = odometer_increment_m(np.array([dist, dist]), np.array([False, True]), **args)
    assert got[0] == pytest.approx(dist * assumed / actual, rel=1e-12, abs=1e-15)
    assert got[1] == pytest.approx(dist * assumed / actual * (1 - slip), rel=1e-12, abs=1e-15)
    # A worn wheel over-reads, once the wear is more than the rounding of the increment
    # (hypothesis found a wheel one ulp smaller reading the same metre, and equal diameters
    # reading one ulp short).
    if actual < assumed * (1.0 - 1e-12):
        assert got[0] > dist
