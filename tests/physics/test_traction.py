"""Traction and the run profile: what lets a train drive a whole line (SPEC §2 position runs).

Closed forms: the tractive effort is F_max up to the base speed and P / v
above it (P = F_max · v_base, continuous at v_base); traction is capped by
the control's aim, the curve and the motored axles' adhesion (a slip above
it); the odometer's wheel turns distance · creep / (pi D) times. A run from
standstill reaches the cruise speed (line limit less 2 km/h) and stops at
every station's stopping point within 5 cm.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railstop.config import default_line, default_vehicle
from railstop.physics.traction import traction_adhesion_limit_mps2, traction_step, tractive_effort_n
from railstop.physics.train import G_MPS2, TrainMass, odometer_increment_m
from railstop.quantities import MPS_PER_KMH
from railstop.sensors.odometer import Tachometer, creep_factor
from railstop.sim.position_run import PositionRunResult, PositionRunSettings, run_position

VEHICLE = default_vehicle()
LINE = default_line()
assert VEHICLE.traction is not None
TRACTION = VEHICLE.traction
EMPTY = TrainMass.create(VEHICLE, np.zeros(1), np.zeros(1))


def test_default_traction_is_a_metro_emu() -> None:
    # ~1.0 m/s² starting acceleration aim; the curve could give more to an empty train.
    assert TRACTION.max_accel_mps2 == pytest.approx(1.0)
    assert TRACTION.max_force_n / EMPTY.effective_kg[0] > 1.0
    assert TRACTION.max_power_w == pytest.approx(TRACTION.max_force_n * TRACTION.base_speed_kmh * MPS_PER_KMH)


@settings(max_examples=60, deadline=None)
@given(st.floats(min_value=0.0, max_value=40.0))
def test_tractive_effort_constant_force_then_constant_power(v: float) -> None:
    f = float(tractive_effort_n(TRACTION, np.array([v]))[0])
    base = TRACTION.base_speed_kmh * MPS_PER_KMH
    if v <= base:
        assert f == pytest.approx(TRACTION.max_force_n)
    else:
        assert f * v == pytest.approx(TRACTION.max_power_w)
        assert f < TRACTION.max_force_n


def test_tractive_effort_continuous_and_falling() -> None:
    base = TRACTION.base_speed_kmh * MPS_PER_KMH
    v = np.linspace(0.0, 30.0, 3001)
    f = tractive_effort_n(TRACTION, v)
    assert np.all(np.diff(f) <= 1e-6)
    left, right = tractive_effort_n(TRACTION, np.array([base - 1e-9, base + 1e-9]))
    assert left == pytest.approx(right, rel=1e-6)


def test_traction_step_caps_by_aim_curve_and_adhesion() -> None:
    v = np.array([2.0, 22.0, 2.0, 2.0])
    mu = np.array([0.2, 0.2, 0.05, 0.2])
    mass = TrainMass.create(VEHICLE, np.zeros(4), np.zeros(4))
    out = traction_step(
        TRACTION, demand_accel_mps2=np.array([5.0, 5.0, 5.0, 0.3]), speed_mps=v, mass=mass, adhesion_mu=mu
    )
    curve_22 = TRACTION.max_power_w / 22.0 / mass.effective_kg[1]
    limit_low = mu[2] * G_MPS2 * mass.static_kg[2] * TRACTION.motored_axle_fraction / mass.effective_kg[2]
    assert out.accel_mps2[0] == pytest.approx(TRACTION.max_accel_mps2)  # the aim
    assert out.accel_mps2[1] == pytest.approx(curve_22)  # constant power at 80 km/h
    assert out.accel_mps2[2] == pytest.approx(limit_low)  # adhesion on a wet patch ...
    assert out.slipping.tolist() == [False, False, True, False]  # ... is a slip
    assert out.accel_mps2[3] == pytest.approx(0.3)
    assert traction_adhesion_limit_mps2(mu, mass, TRACTION)[2] == pytest.approx(limit_low)


def test_tachometer_matches_odometer_increment_and_creep() -> None:
    d = np.array([0.80, 0.80, 0.80])
    tach = Tachometer.create(actual_diameter_m=d, assumed_diameter_m=d * 1.02, pulses_per_rev=100_000)
    sliding = np.array([False, True, False])
    slipping = np.array([False, False, True])
    creep = creep_factor(sliding, slipping, slide_slip_ratio=0.15, traction_slip_ratio=0.10)
    assert creep.tolist() == [1.0, 0.85, 1.10]
    tach.advance(np.full(3, 100.0), creep)
    ref = odometer_increment_m(
        np.full(3, 100.0), sliding, actual_diameter_m=d, assumed_diameter_m=d * 1.02, slide_slip_ratio=0.15
    )
    got = tach.odometer_m()
    # Whole pulses of 2.6e-5 m: the same as the spine's tachometer, and a slip runs ahead by 10 %.
    assert got[:2] == pytest.approx(ref[:2], abs=3e-5)
    assert got[2] == pytest.approx(100.0 * 1.02 * 1.10, abs=3e-5)
    assert tach.speed_mps(np.full(3, 10.0), creep) == pytest.approx([10.2, 10.2 * 0.85, 10.2 * 1.1])


def test_tachometer_counts_whole_pulses() -> None:
    tach = Tachometer.create(
        actual_diameter_m=np.array([0.8]), assumed_diameter_m=np.array([0.8]), pulses_per_rev=4
    )
    per_pulse = np.pi * 0.8 / 4
    tach.advance(np.array([2.5 * per_pulse]), np.ones(1))
    assert tach.odometer_m()[0] == pytest.approx(2 * per_pulse)
    with pytest.raises(ValueError, match="pulses_per_rev"):
        Tachometer.create(actual_diameter_m=np.ones(1), assumed_diameter_m=np.ones(1), pulses_per_rev=0)


@pytest.fixture(scope="module")
def plain_run() -> PositionRunResult:
    return run_position(LINE, VEHICLE, PositionRunSettings(slides=0, slips=0))


def test_run_keeps_the_limits_and_stops_at_every_station(plain_run: PositionRunResult) -> None:
    res = plain_run
    x, v, t = res.true_m[:, 0], res.speed_mps[:, 0], res.t_s
    assert np.max(v) <= LINE.line.speed_limit_kmh * MPS_PER_KMH + 1e-6  # never above the line's limit
    assert np.max(v) >= (LINE.line.speed_limit_kmh - 2.0) * MPS_PER_KMH  # and up to it somewhere
    for station in LINE.stations:
        at_rest = (v == 0.0) & (np.abs(x - station.stop_point_m) < 30.0)
        assert at_rest.any(), f"no stop at {station.name}"
        # The station's TASC stop, within its PSD tolerance.
        assert np.max(np.abs(x[at_rest] - station.stop_point_m)) <= station.psd_tolerance_m
    # Starting from the first station: traction up to the vehicle's 1.0 m/s² aim, less the
    # resistance, on a train with its load.
    leave = int(np.flatnonzero((v == 0.0) & (np.abs(x - LINE.stations[0].stop_point_m) < 30.0))[-1])
    k = leave + round(2.0 / (t[1] - t[0]))
    assert 0.6 < (v[k] - v[leave]) / (t[k] - t[leave]) <= 1.0
