"""One train's plant (DESIGN rule 1, issue 35 item 1): traction, the brake chain and the motion of the
stop model, one step at a time, for the drivers that move a train outside a station stop (the line
between stations, ``sim.line``; the live plant under the ATO and the CBTC unit, ``live.plant``).

A step, in order:

1. **the brake chain**: a braking demand (a negative ``demand_mps2``, clipped to full service: the
   ECU's service range) or the emergency brake goes through
   :func:`railstop.physics.brake.actuator_step_1`, the stop kernel's own actuator: dead time (whole
   steps), the ECU's jerk limit (bypassed by the emergency brake), the build-up lag;
2. **traction**: a positive demand, limited by the traction control's aim (``max_accel_mps2``), the
   tractive-effort curve (constant force, then constant power: :mod:`railstop.physics.traction`) and
   the adhesion of the motored axles; above that the wheels slip and the anti-slip control holds the
   force at the adhesion. The emergency brake cuts traction;
3. **the motion**: :func:`railstop.physics.train.motion_step_1`, the stop kernel's own equation of
   motion, with the brakes' deceleration less the traction acceleration (``traction.py``: one copy of
   the equation of motion), the running resistance, the mean gradient under the train
   (:func:`railstop.physics.train.mean_gradient_1` over the track's profile) and the adhesion in
   braking (a slide above it); a train whose speed would cross zero stops exactly within the step
   and is held by its brake until traction moves it again.

The compiled scalar cores are called from Python, one call each per step: measured on this
project's machine 1.2 µs (actuator), 1.4 µs (motion) and 0.8 µs (mean gradient) per call, against
2.2, 2.7 and 1.6 µs for their ``.py_func`` (plain Python over the same source; the compiled call
is the faster, so the plant uses it). The line steps a running train every 0.1 s, the live plant
every 10 ms.

**[interpretation]** The ECU's load weighing is exact here (the station stop draws its error): the
brakes give the deceleration demanded. Traction acts at once (its current control is fast beside
the brakes' pneumatics); a traction demand releases the brakes, which decay through the chain, so
both act while the brakes release.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.config.gradient import GradientProfile
from railstop.config.schema import GradientSegment, Line, Vehicle
from railstop.errors import SimulationError
from railstop.physics.brake import actuator_step_1
from railstop.physics.train import G_MPS2, adhesion_limit_1, mean_gradient_1, motion_step_1
from railstop.quantities import kmh_to_mps

FloatArray = NDArray[np.float64]

#: The brakes count as released below this deceleration (m/s²): a speed hold acts only then.
RELEASED_MPS2 = 1e-3


def gradient_profile(segments: Sequence[GradientSegment], *, field: str = "gradient") -> GradientProfile:
    """The piecewise-constant profile of ``segments`` (chainages, + uphill), level between them; a
    :class:`SimulationError` naming ``field`` when two overlap."""
    try:
        return GradientProfile.from_segments(segments)
    except ValueError as exc:
        raise SimulationError(f"{field}: {exc}") from None


def track_gradient(line: Line) -> GradientProfile:
    """The line's gradient profile: every station's gradient segments (they are chainages of the
    line, ``config.schema.Station.gradient``), level track between them."""
    return gradient_profile([seg for st in line.stations for seg in st.gradient], field="stations.gradient")


@dataclass(frozen=True, slots=True, kw_only=True)
class PlantParams:
    """What one train's plant needs, in SI units (:meth:`create` from the vehicle data)."""

    dt_s: float
    static_kg: float
    effective_kg: float
    davis_a_n: float
    davis_b_n_per_mps: float
    davis_c_n_per_mps2: float
    max_force_n: float  # traction: constant force up to base_speed_mps, constant power above
    base_speed_mps: float
    max_accel_mps2: float
    motored_axle_fraction: float
    full_service_mps2: float
    emergency_mps2: float
    delay_steps: int  # the brakes' dead time in whole steps
    jerk_step_mps2: float  # the ECU's jerk limit, per step
    lag_alpha: float  # the build-up lag per step, 1 - exp(-dt / tau)
    adhesion_mu: float
    length_m: float
    breakpoints_m: FloatArray  # the track's gradient (GradientProfile, one run)
    gradient_permille: FloatArray
    elevation_m: FloatArray

    @classmethod
    def create(
        cls, vehicle: Vehicle, *, load_factor: float, dt_s: float, gradient: GradientProfile | None = None
    ) -> PlantParams:
        """``load_factor``: 0 empty (AW0) .. 1 crush (AW3); ``gradient``: the track's profile (its
        first run; None: level track)."""
        if not 0.0 <= load_factor <= 1.0:
            raise SimulationError(f"load_factor: 0 (empty) .. 1 (crush) (got {load_factor})")
        if not (math.isfinite(dt_s) and 0.0 < dt_s <= 1.0):
            raise SimulationError(f"dt_s: a step of more than 0 s and at most 1 s (got {dt_s})")
        traction = vehicle.traction
        if traction is None:
            raise SimulationError(f"vehicle {vehicle.name!r} has no [vehicle.traction]: the trains must run")
        if gradient is None:
            gradient = GradientProfile.create(np.zeros(0), np.zeros((1, 1)))
        brake = vehicle.brake
        static = vehicle.tare_mass_kg + load_factor * vehicle.crush_payload_kg
        return cls(
            dt_s=dt_s,
            static_kg=static,
            effective_kg=static + vehicle.tare_mass_kg * vehicle.rotating_mass_factor,
            davis_a_n=vehicle.davis_a_n,
            davis_b_n_per_mps=vehicle.davis_b_n_per_mps,
            davis_c_n_per_mps2=vehicle.davis_c_n_per_mps2,
            max_force_n=traction.max_force_n,
            base_speed_mps=kmh_to_mps(traction.base_speed_kmh),
            max_accel_mps2=traction.max_accel_mps2,
            motored_axle_fraction=traction.motored_axle_fraction,
            full_service_mps2=brake.full_service_mps2,
            emergency_mps2=brake.emergency_decel_mps2,
            # As the stop kernel rounds them (``railstop.model.build``): whole steps of dead time.
            # [interpretation] At the line's 0.1 s step the 0.35 s dead time becomes 0.3 s, within
            # half a step of the stop model's (10 ms); the plant is the simulated truth, not a
            # safety margin, so the nearest whole step, as in the stop model, not a rounding up.
            delay_steps=int(np.rint(brake.dead_time_s / dt_s)),
            jerk_step_mps2=brake.jerk_limit_mps3 * dt_s,
            lag_alpha=1.0 - math.exp(-dt_s / brake.time_constant_s),
            adhesion_mu=vehicle.adhesion_mu,
            length_m=vehicle.length_m,
            breakpoints_m=np.ascontiguousarray(gradient.breakpoints_m, dtype=np.float64),
            gradient_permille=np.ascontiguousarray(gradient.values_permille[0], dtype=np.float64),
            elevation_m=np.ascontiguousarray(gradient._elev_at_bp[0], dtype=np.float64),
        )

    def mean_gradient(self, front_m: float) -> float:
        """The mean gradient (fraction, + uphill towards higher chainage) under the train whose front
        (the end towards higher chainage) is at ``front_m``."""
        return float(
            mean_gradient_1(
                front_m, self.length_m, self.breakpoints_m, self.gradient_permille, self.elevation_m
            )
        )


def traction_mps2(params: PlantParams, speed_mps: float) -> float:
    """The most traction gives at ``speed_mps`` (m/s², before adhesion): the control's aim and the
    tractive-effort curve, F(v) = F_max up to the base speed, F_max · v_base / v above."""
    v = abs(speed_mps)
    force = params.max_force_n
    if v > params.base_speed_mps:
        force *= params.base_speed_mps / v
    return min(params.max_accel_mps2, force / params.effective_kg)


def traction_adhesion_mps2(params: PlantParams, adhesion_mu: float) -> float:
    """The most traction adhesion lets the motored axles transmit: mu · g · m · motored / m_eff
    (``physics.traction.traction_adhesion_limit_mps2``)."""
    return adhesion_mu * G_MPS2 * params.static_kg * params.motored_axle_fraction / params.effective_kg


@dataclass(slots=True, kw_only=True)
class PlantState:
    """One train's true state (:func:`plant_step` moves it). ``v_mps`` is the speed (>= 0) in the
    running ``direction`` (+1 towards higher chainage, -1 back; changed at a stand by
    :func:`set_direction`); ``ring``, ``k``, ``limited_mps2`` and ``output_mps2`` are the brake
    chain's (``actuator_step_1``): ``output_mps2`` is the brakes' deceleration now."""

    x_m: float
    v_mps: float
    ring: FloatArray
    direction: int = 1
    stopped: bool = False
    k: int = 0
    limited_mps2: float = 0.0
    output_mps2: float = 0.0
    accel_mps2: float = 0.0  # the last step's acceleration in the running direction
    sliding: bool = False  # braking beyond the adhesion in the last step (the WSP acting)
    slipping: bool = False  # traction beyond the adhesion in the last step (the anti-slip control)
    stop_time_s: float = math.nan  # when it last came to a stand

    @classmethod
    def create(cls, params: PlantParams, *, x_m: float, v_mps: float = 0.0, direction: int = 1) -> PlantState:
        """A train at ``x_m`` running at ``v_mps`` (>= 0) in ``direction``, its brakes released (at
        ``v_mps`` 0 it stands, held)."""
        if not (math.isfinite(v_mps) and v_mps >= 0.0):
            raise SimulationError(f"v_mps: a finite speed >= 0 in the running direction (got {v_mps})")
        if direction not in (1, -1):
            raise SimulationError(f"direction: +1 or -1 (got {direction})")
        return cls(
            x_m=float(x_m),
            v_mps=float(v_mps),
            ring=np.zeros(params.delay_steps + 1),
            direction=direction,
            stopped=v_mps == 0.0,
        )


def set_direction(state: PlantState, direction: int) -> None:
    """Reverse (or not) a train that stands; a SimulationError for a moving one."""
    if direction not in (1, -1):
        raise SimulationError(f"direction: +1 or -1 (got {direction})")
    if direction != state.direction and not state.stopped:
        raise SimulationError(f"direction: a train reverses only at a stand (it runs at {state.v_mps} m/s)")
    state.direction = direction


def plant_step(
    state: PlantState,
    params: PlantParams,
    *,
    demand_mps2: float,
    t_s: float,
    eb: bool = False,
    speed_hold: bool = False,
    adhesion_mu: float | None = None,
) -> None:
    """One step of ``params.dt_s`` from ``t_s`` (in place; see the module's notes).

    ``demand_mps2``: traction when positive, braking (its magnitude, at most full service) when
    negative; ``eb``: the emergency brake (wire e: past the jerk limit, traction cut);
    ``speed_hold``: traction holds the speed against resistance and gradient (the stop kernel's
    hold before the first brake), only while the brakes are released; ``adhesion_mu``: the rail's
    adhesion here (None: the vehicle's dry rail)."""
    mu = params.adhesion_mu if adhesion_mu is None else adhesion_mu
    service = min(max(-demand_mps2, 0.0), params.full_service_mps2)  # the ECU's service range
    brake_demand = params.emergency_mps2 if eb else service
    limited, output = actuator_step_1(
        state.ring,
        state.k,
        params.delay_steps,
        brake_demand,
        state.limited_mps2,
        state.output_mps2,
        params.lag_alpha,
        params.jerk_step_mps2,
        params.emergency_mps2,
    )
    state.k += 1
    state.limited_mps2, state.output_mps2 = limited, output
    traction = 0.0
    state.slipping = False
    if demand_mps2 > 0.0 and not eb:
        wanted = min(demand_mps2, traction_mps2(params, state.v_mps))
        grip = traction_adhesion_mps2(params, mu)
        state.slipping = wanted > grip
        traction = min(wanted, grip)
        if traction > 0.0:
            state.stopped = False  # motion_step_1 holds it again if the brakes still win
    d = state.direction
    moving = not state.stopped
    x, v, accel, stopped, stop_t, sliding = motion_step_1(
        d * state.x_m,
        state.v_mps,
        state.stopped,
        output - traction,
        d * params.mean_gradient(state.x_m),
        adhesion_limit_1(mu, params.static_kg, params.effective_kg),
        speed_hold and output < RELEASED_MPS2,
        params.static_kg,
        params.effective_kg,
        params.davis_a_n,
        params.davis_b_n_per_mps,
        params.davis_c_n_per_mps2,
        t_s,
        params.dt_s,
    )
    state.x_m, state.v_mps, state.accel_mps2 = d * x, v, accel
    if stopped and moving:
        state.stop_time_s = stop_t
    state.stopped = stopped
    state.sliding = sliding and moving
