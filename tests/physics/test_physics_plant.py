"""One train plant for the line and the live plant (issue 35 item 1, ``physics.plant``): closed-form
checks of its brake chain, traction and motion, and parity with the stop model's compiled cores.

The braking checks rest on one identity. Let the brakes' deceleration rise from 0 to ``a`` as
y(t) = a·F(t), F a distribution function of mean μ and variance σ² (dead time, jerk ramp, lag:
their means and variances add, as for a sum of independent delays). Then after the response has
settled v(t) = v0 − a·(t − μ), and a train on level track without resistance stops after
t_s = v0 / a + μ, having run x = ∫ s·y(s) ds = v0² / (2a) + v0·μ − a·σ² / 2. A constant extra
deceleration g_i (the gradient) acts at once: a·(t_s − μ) + g_i·t_s = v0 and
x = a·(t_s² − μ² − σ²) / 2 + g_i·t_s² / 2.

For the plant's discrete chain (step dt, D whole steps of dead time, the ramp m = a / (J·dt) steps,
the lag y_k = y_(k-1) + α·(l_k − y_(k-1))), summing a − y_k over the steps gives the exact mean
μ = dt·(D + (m − 1) / 2 + (1 − α) / α); the continuous σ² = T_r² / 12 + τ² (a uniform ramp of
T_r = a / J, an exponential lag of τ) is off by O(dt²): a deceleration held constant over each
step widens the response by a step's width, a·dt² / 12 of distance. The tests allow a·dt² / 6.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from railstop.config import default_line, default_vehicle
from railstop.config.gradient import GradientProfile
from railstop.errors import SimulationError
from railstop.physics.brake import actuator_step_1
from railstop.physics.plant import (
    PlantParams,
    PlantState,
    gradient_profile,
    plant_step,
    set_direction,
    track_gradient,
    traction_adhesion_mps2,
    traction_mps2,
)
from railstop.physics.train import G_MPS2, adhesion_limit_1, mean_gradient_1, motion_step_1

VEHICLE = default_vehicle()
# No running resistance: the closed forms hold exactly.
FRICTIONLESS = VEHICLE.model_copy(
    update={"davis_a_n": 0.0, "davis_b_n_per_mps": 0.0, "davis_c_n_per_mps2": 0.0}
)


def _level(permille: float = 0.0) -> GradientProfile:
    """A constant gradient everywhere (no breakpoints): the mean under the train is that gradient."""
    return GradientProfile.create(np.zeros(0), np.array([[permille]]))


def _brake_to_a_stand(params: PlantParams, v0: float, decel: float) -> tuple[PlantState, list[float]]:
    """A constant braking demand from ``v0`` until the train stands: the state and the speeds."""
    state = PlantState.create(params, x_m=1000.0, v_mps=v0)
    speeds = []
    k = 0
    while not state.stopped:
        plant_step(state, params, demand_mps2=-decel, t_s=k * params.dt_s)
        speeds.append(state.v_mps)
        k += 1
        if k > 100_000:
            raise AssertionError("the train never stopped")
    return state, speeds


def _response(params: PlantParams, decel: float) -> tuple[float, float]:
    """(μ, σ²) of the brake chain's response to a step of ``decel`` (see the module's notes)."""
    dt = params.dt_s
    ramp_steps = decel / params.jerk_step_mps2
    alpha = params.lag_alpha
    mean = dt * (params.delay_steps + (ramp_steps - 1.0) / 2.0 + (1.0 - alpha) / alpha)
    brake = VEHICLE.brake
    variance = (decel / brake.jerk_limit_mps3) ** 2 / 12.0 + brake.time_constant_s**2
    return mean, variance


@pytest.mark.parametrize("dt_s", [0.01, 0.1])
def test_a_constant_braking_demand_on_the_level_follows_the_closed_form(dt_s: float) -> None:
    """v = v0 − a·(t − μ) once the dead time, the jerk ramp and the lag have settled; the train
    stands at t_s = v0 / a + μ after v0² / (2a) + v0·μ − a·σ² / 2."""
    params = PlantParams.create(FRICTIONLESS, load_factor=0.5, dt_s=dt_s, gradient=_level())
    v0, a = 10.0, 0.5
    mean, variance = _response(params, a)
    state, speeds = _brake_to_a_stand(params, v0, a)
    # After 10 s the lag's transient is e^(-10 / 0.45) of a: nothing.
    k = round(10.0 / dt_s)
    assert speeds[k - 1] == pytest.approx(v0 - a * (k * dt_s - mean), abs=1e-9)
    assert state.stop_time_s == pytest.approx(v0 / a + mean, abs=1e-9)
    expected = v0 * v0 / (2.0 * a) + v0 * mean - a * variance / 2.0
    assert abs((state.x_m - 1000.0) - expected) <= a * dt_s**2 / 6.0
    # The dead time alone costs v0 · D · dt of distance beyond the instant brake's v0² / 2a.
    assert state.x_m - 1000.0 > v0 * v0 / (2.0 * a) + v0 * params.delay_steps * dt_s


def test_an_uphill_gradient_shortens_braking_by_g_i_m_over_m_eff() -> None:
    """10 ‰ uphill adds g·i·m / m_eff to the deceleration at every step (the acceleration differs by
    exactly that from the level run's), and the stop follows the closed form with g_i."""
    dt, v0, a, permille = 0.01, 10.0, 0.5, 10.0
    level = PlantParams.create(FRICTIONLESS, load_factor=0.5, dt_s=dt, gradient=_level())
    uphill = PlantParams.create(FRICTIONLESS, load_factor=0.5, dt_s=dt, gradient=_level(permille))
    g_i = G_MPS2 * permille * 1e-3 * uphill.static_kg / uphill.effective_kg
    flat_state = PlantState.create(level, x_m=0.0, v_mps=v0)
    hill_state = PlantState.create(uphill, x_m=0.0, v_mps=v0)
    for k in range(500):  # 5 s: both still running
        plant_step(flat_state, level, demand_mps2=-a, t_s=k * dt)
        plant_step(hill_state, uphill, demand_mps2=-a, t_s=k * dt)
        assert hill_state.accel_mps2 - flat_state.accel_mps2 == pytest.approx(-g_i, abs=1e-12)
    flat, _ = _brake_to_a_stand(level, v0, a)
    hill, _ = _brake_to_a_stand(uphill, v0, a)
    mean, variance = _response(uphill, a)
    t_s = (v0 + a * mean) / (a + g_i)
    assert hill.stop_time_s == pytest.approx(t_s, abs=1e-9)
    expected = a * (t_s**2 - mean**2 - variance) / 2.0 + g_i * t_s**2 / 2.0
    assert abs((hill.x_m - 1000.0) - expected) <= a * dt**2 / 6.0
    assert hill.x_m < flat.x_m - 10.0  # 17 m shorter here


def test_the_emergency_brake_bypasses_the_jerk_limit_but_not_the_dead_time_and_lag() -> None:
    """After the dead time the emergency demand reaches the lag in one step (the service demand
    climbs by the jerk step); the brakes' deceleration then builds up as 1 − (1 − α)^n."""
    params = PlantParams.create(VEHICLE, load_factor=0.5, dt_s=0.01, gradient=_level())
    eb = PlantState.create(params, x_m=0.0, v_mps=20.0)
    service = PlantState.create(params, x_m=0.0, v_mps=20.0)
    full = params.full_service_mps2
    for k in range(params.delay_steps + 3):
        plant_step(eb, params, demand_mps2=0.0, t_s=k * 0.01, eb=True)
        plant_step(service, params, demand_mps2=-full, t_s=k * 0.01)
        if k < params.delay_steps:
            assert eb.output_mps2 == service.output_mps2 == 0.0  # the dead time
        else:
            n = k - params.delay_steps + 1
            assert eb.limited_mps2 == params.emergency_mps2
            built = 1.0 - (1.0 - params.lag_alpha) ** n
            assert eb.output_mps2 == pytest.approx(params.emergency_mps2 * built)
            assert service.limited_mps2 == pytest.approx(n * params.jerk_step_mps2)
    # A service demand beyond full service is full service (the ECU's range), the EB is not.
    big = PlantState.create(params, x_m=0.0, v_mps=20.0)
    for k in range(400):
        plant_step(big, params, demand_mps2=-5.0, t_s=k * 0.01)
    assert big.limited_mps2 == pytest.approx(full)


def test_traction_follows_its_curve_and_slips_beyond_the_adhesion() -> None:
    """Dry rail: the traction control's aim below the base speed, constant power above it. On a
    μ 0.05 patch the demand exceeds what the motored axles transmit: the wheels slip and the
    train accelerates at the adhesion, μ·g·m·motored / m_eff."""
    params = PlantParams.create(FRICTIONLESS, load_factor=1.0, dt_s=0.1, gradient=_level())
    traction = VEHICLE.traction
    assert traction is not None
    power = traction.max_force_n * traction.base_speed_kmh / 3.6
    for v0, expected in ((5.0, min(traction.max_accel_mps2, traction.max_force_n / params.effective_kg)),
                         (20.0, power / 20.0 / params.effective_kg)):  # fmt: skip
        state = PlantState.create(params, x_m=0.0, v_mps=v0)
        plant_step(state, params, demand_mps2=2.0, t_s=0.0)
        assert not state.slipping
        assert state.accel_mps2 == pytest.approx(expected, rel=1e-12)
        assert traction_mps2(params, v0) == pytest.approx(expected, rel=1e-12)
    grip = 0.05 * G_MPS2 * params.static_kg * traction.motored_axle_fraction / params.effective_kg
    assert traction_adhesion_mps2(params, 0.05) == pytest.approx(grip)
    state = PlantState.create(params, x_m=0.0, v_mps=5.0)
    plant_step(state, params, demand_mps2=1.0, t_s=0.0, adhesion_mu=0.05)
    assert state.slipping and state.accel_mps2 == pytest.approx(grip, rel=1e-12)
    # A demand the adhesion gives does not slip; the emergency brake cuts traction.
    plant_step(state, params, demand_mps2=0.5 * grip, t_s=0.1, adhesion_mu=0.05)
    assert not state.slipping and state.accel_mps2 == pytest.approx(0.5 * grip, rel=1e-12)
    plant_step(state, params, demand_mps2=1.0, t_s=0.2, eb=True)
    assert not state.slipping and state.accel_mps2 == 0.0  # no traction; the EB still in its dead time


def test_braking_beyond_the_adhesion_slides_at_the_adhesion() -> None:
    params = PlantParams.create(FRICTIONLESS, load_factor=0.5, dt_s=0.1, gradient=_level())
    state = PlantState.create(params, x_m=0.0, v_mps=15.0)
    for k in range(40):  # 4 s of full service on μ 0.05: the brakes have built up past 0.46
        plant_step(state, params, demand_mps2=-1.0, t_s=k * 0.1, adhesion_mu=0.05)
    limit = 0.05 * G_MPS2 * params.static_kg / params.effective_kg
    assert state.sliding and state.output_mps2 > limit
    assert state.accel_mps2 == pytest.approx(-limit, rel=1e-12)


def test_the_plant_moves_the_train_as_the_stop_model_does_for_the_same_braking() -> None:
    """Parity with the stop kernel: the brakes' deceleration of every step, fed to the kernel's own
    ``motion_step_1`` with its ``actuator_step_1``, gives the plant's positions to the bit (the
    line's gradient profile, resistance, a varying demand and the emergency brake at the end)."""
    line = default_line()
    gradient = track_gradient(line)
    params = PlantParams.create(VEHICLE, load_factor=0.3, dt_s=0.01, gradient=gradient)
    x0, v0 = 2300.0, 18.0  # Hillcrest's -15 ‰ approach
    state = PlantState.create(params, x_m=x0, v_mps=v0)
    ring = np.zeros(params.delay_steps + 1)
    limited = output = 0.0
    x, v, stopped = x0, v0, False
    demands = [-0.2 - 0.6 * (k // 300 % 2) for k in range(6000)]
    for k, demand in enumerate(demands):
        eb = k >= 2000
        t = k * params.dt_s
        plant_step(state, params, demand_mps2=demand, t_s=t, eb=eb)
        limited, output = actuator_step_1(
            ring, k, params.delay_steps, params.emergency_mps2 if eb else -demand, limited, output,
            params.lag_alpha, params.jerk_step_mps2, params.emergency_mps2,
        )  # fmt: skip
        grade = mean_gradient_1(
            x, VEHICLE.length_m, gradient.breakpoints_m, gradient.values_permille[0], gradient._elev_at_bp[0]
        )
        limit = adhesion_limit_1(VEHICLE.adhesion_mu, params.static_kg, params.effective_kg)
        x, v, _, stopped, _, _ = motion_step_1(
            x, v, stopped, output, grade, limit, False, params.static_kg, params.effective_kg,
            VEHICLE.davis_a_n, VEHICLE.davis_b_n_per_mps, VEHICLE.davis_c_n_per_mps2, t, params.dt_s,
        )  # fmt: skip
        assert state.output_mps2 == output
        assert (state.x_m, state.v_mps, state.stopped) == (x, v, stopped)
        if stopped:
            break
    assert stopped and state.stopped and state.x_m > x0 + 100.0


def test_a_standing_train_is_held_moves_off_under_traction_and_reverses_only_at_a_stand() -> None:
    params = PlantParams.create(VEHICLE, load_factor=0.5, dt_s=0.1, gradient=_level(-20.0))
    state = PlantState.create(params, x_m=500.0)
    for k in range(20):  # downhill, no demand: held by its brake
        plant_step(state, params, demand_mps2=0.0, t_s=k * 0.1)
    assert state.stopped and state.x_m == 500.0
    plant_step(state, params, demand_mps2=1.0, t_s=2.0)
    assert not state.stopped and state.v_mps > 0.0 and state.x_m > 500.0
    with pytest.raises(SimulationError, match="direction"):
        set_direction(state, -1)
    state = PlantState.create(params, x_m=500.0)
    set_direction(state, -1)
    for k in range(20):  # backwards: uphill now, traction still moves it (1 m/s² > 0.2 m/s²)
        plant_step(state, params, demand_mps2=1.0, t_s=k * 0.1)
    assert state.x_m < 499.0 and state.direction == -1
    assert state.accel_mps2 < params.max_accel_mps2  # the gradient works against it


def test_a_speed_hold_keeps_the_speed_only_with_the_brakes_released() -> None:
    """The stop kernel's hold (traction holds the approach speed): exact, on a gradient, with
    resistance; while the brakes still act it does not hold."""
    params = PlantParams.create(VEHICLE, load_factor=0.5, dt_s=0.1, gradient=_level(-15.0))
    state = PlantState.create(params, x_m=0.0, v_mps=15.0)
    for k in range(10):
        plant_step(state, params, demand_mps2=0.0, t_s=k * 0.1, speed_hold=True)
    assert state.v_mps == 15.0 and state.x_m == pytest.approx(15.0, abs=1e-9)
    for k in range(10):
        plant_step(state, params, demand_mps2=-1.0, t_s=1.0 + k * 0.1)
    braked = state.v_mps
    plant_step(state, params, demand_mps2=0.0, t_s=2.0, speed_hold=True)
    assert state.output_mps2 > 0.1 and state.v_mps < braked  # the brakes still act


def test_the_track_gradient_is_every_station_s_segments_and_bad_inputs_are_refused() -> None:
    line = default_line()
    profile = track_gradient(line)
    for st in line.stations:
        for seg in st.gradient:
            mid = 0.5 * (seg.start_m + seg.end_m)
            rise = profile.elevation_m(np.array([mid + 1.0]))[0] - profile.elevation_m(np.array([mid]))[0]
            assert rise == pytest.approx(seg.permille * 1e-3)
    segs = line.stations[1].gradient
    with pytest.raises(SimulationError, match="overlap"):
        gradient_profile([segs[0], segs[0]])
    with pytest.raises(SimulationError, match="load_factor"):
        PlantParams.create(VEHICLE, load_factor=1.5, dt_s=0.1)
    with pytest.raises(SimulationError, match="dt_s"):
        PlantParams.create(VEHICLE, load_factor=0.5, dt_s=math.nan)
    with pytest.raises(SimulationError, match="traction"):
        PlantParams.create(VEHICLE.model_copy(update={"traction": None}), load_factor=0.5, dt_s=0.1)
    params = PlantParams.create(VEHICLE, load_factor=0.5, dt_s=0.1)
    with pytest.raises(SimulationError, match="v_mps"):
        PlantState.create(params, x_m=0.0, v_mps=-1.0)
