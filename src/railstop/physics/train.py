"""Longitudinal train dynamics over arrays of runs (DESIGN rule 1).

m_eff · dv/dt = -(F_brake + R(v) + m · g · i)

with m_eff = tare · (1 + rotating_mass_factor) + payload, R(v) = A + B v + C v²
(Davis), i the mean gradient under the train (+ uphill) and the braking force
limited by adhesion (a slide when the demand exceeds it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import Vehicle
from railstop.jit import njit_inline

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


G_MPS2 = 9.80665


@dataclass(frozen=True, slots=True, kw_only=True)
class TrainMass:
    """Masses of n runs: actual static mass, actual effective mass, ECU-believed effective mass."""

    static_kg: FloatArray
    effective_kg: FloatArray
    believed_effective_kg: FloatArray

    @classmethod
    def create(cls, vehicle: Vehicle, load_factor: FloatArray, weighing_error: FloatArray) -> TrainMass:
        """``load_factor`` 0 = empty (AW0) .. 1 = crush (AW3); ``weighing_error`` fraction."""
        lf = np.asarray(load_factor, dtype=np.float64)
        static = vehicle.tare_mass_kg + lf * vehicle.crush_payload_kg
        rotating = vehicle.tare_mass_kg * vehicle.rotating_mass_factor
        believed_static = static * (1.0 + np.asarray(weighing_error, dtype=np.float64))
        return cls(
            static_kg=static,
            effective_kg=static + rotating,
            believed_effective_kg=believed_static + rotating,
        )


@dataclass(slots=True, kw_only=True)
class MotionState:
    """True motion of n runs."""

    position_m: FloatArray  # train front chainage
    speed_mps: FloatArray
    accel_mps2: FloatArray  # last step's acceleration (negative when braking)
    stopped: BoolArray
    stop_time_s: FloatArray
    sliding: BoolArray


def davis_resistance_n(vehicle: Vehicle, speed_mps: FloatArray) -> FloatArray:
    v = np.abs(speed_mps)
    return vehicle.davis_a_n + vehicle.davis_b_n_per_mps * v + vehicle.davis_c_n_per_mps2 * v * v


def adhesion_limit_mps2(mu: FloatArray, mass: TrainMass) -> FloatArray:
    """Largest braking deceleration adhesion allows: mu · g · m / m_eff (all axles braked)."""
    return mu * G_MPS2 * mass.static_kg / mass.effective_kg


def motion_step(
    state: MotionState,
    *,
    vehicle: Vehicle,
    mass: TrainMass,
    brake_decel_mps2: FloatArray,
    mean_gradient: FloatArray,
    adhesion_mu: FloatArray,
    speed_hold: BoolArray,
    t_s: float,
    dt_s: float,
) -> None:
    """Advance the true motion by one step of ``dt_s`` (in place).

    Constant acceleration within the step (exact for v²/2a checks). A run whose
    speed would cross zero stops exactly within the step; a stopped train is
    held by its brake. Runs in ``speed_hold`` keep their speed (traction holds
    the approach speed until the TASC first brakes).
    """
    limit = adhesion_limit_mps2(adhesion_mu, mass)
    state.sliding = brake_decel_mps2 > limit
    brake = np.minimum(brake_decel_mps2, limit)
    resist = davis_resistance_n(vehicle, state.speed_mps) / mass.effective_kg
    grade = G_MPS2 * mean_gradient * mass.static_kg / mass.effective_kg
    decel = brake + resist + grade
    decel = np.where(speed_hold, 0.0, decel)
    moving = ~state.stopped
    v = state.speed_mps
    v_new = v - decel * dt_s
    stops = moving & (decel > 0.0) & (v_new <= 0.0)
    safe_decel = np.where(stops, decel, 1.0)
    x_step = np.where(stops, v * v / (2.0 * safe_decel), v * dt_s - 0.5 * decel * dt_s * dt_s)
    state.position_m = np.where(moving, state.position_m + x_step, state.position_m)
    state.speed_mps = np.where(moving & ~stops, v_new, np.where(moving, 0.0, v))
    state.stop_time_s = np.where(stops, t_s + v / safe_decel, state.stop_time_s)
    state.accel_mps2 = np.where(moving, -decel, 0.0)
    state.stopped = state.stopped | stops


def odometer_increment_m(
    distance_m: FloatArray,
    sliding: BoolArray,
    *,
    actual_diameter_m: FloatArray,
    assumed_diameter_m: FloatArray,
    slide_slip_ratio: float,
) -> FloatArray:
    """Tachometer: wheel revolutions x pi x assumed diameter (SPEC §2).

    The wheel turns distance / (pi D_actual) times, less while sliding; the
    odometer multiplies the revolutions by pi D_assumed.
    """
    revs = distance_m * np.where(sliding, 1.0 - slide_slip_ratio, 1.0) / (np.pi * actual_diameter_m)
    return revs * np.pi * assumed_diameter_m


# --------------------------------------------------------------------------
# Compiled scalar cores (railstop.jit): the one implementation the stop kernel runs.


@njit_inline
def elevation_1(
    x_m: float, breakpoints_m: FloatArray, values_permille: FloatArray, elev_at_bp: FloatArray
) -> float:
    """Elevation (m) at chainage x of one run's piecewise-constant gradient (GradientProfile)."""
    n = breakpoints_m.size
    if n == 0:
        return values_permille[0] * 1e-3 * x_m
    idx = 0  # np.searchsorted(breakpoints, x): breakpoints below x (a profile has a handful)
    while idx < n and breakpoints_m[idx] < x_m:
        idx += 1
    base = max(idx - 1, 0)
    return elev_at_bp[base] + values_permille[idx] * 1e-3 * (x_m - breakpoints_m[base])


@njit_inline
def mean_gradient_1(
    front_m: float,
    length_m: float,
    breakpoints_m: FloatArray,
    values_permille: FloatArray,
    elev_at_bp: FloatArray,
) -> float:
    """Mean gradient (fraction, + uphill) under a train of ``length_m`` whose front is at x."""
    return (
        elevation_1(front_m, breakpoints_m, values_permille, elev_at_bp)
        - elevation_1(front_m - length_m, breakpoints_m, values_permille, elev_at_bp)
    ) / length_m


@njit_inline
def motion_step_1(
    position_m: float,
    speed_mps: float,
    stopped: bool,
    brake_decel_mps2: float,
    mean_gradient: float,
    adhesion_limit_mps2: float,
    speed_hold: bool,
    static_kg: float,
    effective_kg: float,
    davis_a_n: float,
    davis_b_n_per_mps: float,
    davis_c_n_per_mps2: float,
    t_s: float,
    dt_s: float,
) -> tuple[float, float, float, bool, float, bool]:
    """One step of the true motion: (position, speed, accel, stopped, stop time or NaN, sliding).

    m_eff dv/dt = -(F_brake + R(v) + m g i): constant acceleration within the
    step (exact for v²/2a checks); a run whose speed would cross zero stops
    exactly within the step; a stopped train is held by its brake. With
    ``speed_hold`` the train keeps its speed (traction holds the approach
    speed until the TASC first brakes). The braking deceleration is limited
    by adhesion, mu g m / m_eff (all axles braked, ``adhesion_limit_mps2``:
    :func:`adhesion_limit_1` of the rail here, which the callers keep per run): above it the
    wheels slide.
    """
    limit = adhesion_limit_mps2
    sliding = brake_decel_mps2 > limit
    if speed_hold:
        decel = 0.0  # (resistance and gradient are not computed: the traction holds the speed)
    else:
        brake = min(brake_decel_mps2, limit)
        v_abs = abs(speed_mps)
        resist = (davis_a_n + davis_b_n_per_mps * v_abs + davis_c_n_per_mps2 * v_abs * v_abs) / effective_kg
        grade = G_MPS2 * mean_gradient * static_kg / effective_kg
        decel = brake + resist + grade
    if stopped:
        return position_m, speed_mps, 0.0, True, np.nan, sliding
    v_new = speed_mps - decel * dt_s
    if decel > 0.0 and v_new <= 0.0:
        return (
            position_m + speed_mps * speed_mps / (2.0 * decel),
            0.0,
            -decel,
            True,
            t_s + speed_mps / decel,
            sliding,
        )
    return position_m + (speed_mps * dt_s - 0.5 * decel * dt_s * dt_s), v_new, -decel, False, np.nan, sliding


@njit_inline
def adhesion_limit_1(adhesion_mu: float, static_kg: float, effective_kg: float) -> float:
    """One run's :func:`adhesion_limit_mps2`: above it the wheels slide."""
    return adhesion_mu * G_MPS2 * static_kg / effective_kg


@njit_inline
def creep_1(sliding: bool, slide_slip_ratio: float) -> float:
    """Wheel speed / train speed under braking: short while sliding (SPEC §2 slip/slide)."""
    return 1.0 - slide_slip_ratio if sliding else 1.0
