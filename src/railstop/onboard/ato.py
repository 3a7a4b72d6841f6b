"""The conventional onboard ATO stop: the baseline the ground TASC replaces (SPEC §1 "Problem").

SPEC §1: the onboard ATO "computes the brake demand from its own odometry and
an estimate of train load"; wheel wear changes the diameter the odometry
assumes, and the brakes do not act as the load estimate says. This unit is a
competent version of that scheme, not a straw man:

- position: odometry (tachometer revolutions × the assumed wheel diameter,
  short while the wheels slide), reset exactly at each station transponder
  (``Station.ato_transponders_m``; by default one at the first TASC detector
  and a precise-stop transponder 25 m before the stop);
- speed: the tachometer (so it carries the same diameter error);
- control: a constant-deceleration brake curve to its odometric stopping
  point, drawn anew at every transponder fix; every controller cycle it demands
  the curve's deceleration less the gradient and resistance of its line data
  (brakes assumed nominal), plus a speed feedback ``ATO_SPEED_GAIN_PER_S`` ×
  (tachometer speed - curve speed), the curve read a little ahead of the
  train (``ATO_LEAD_FRACTION`` of the brake's equivalent dead time; gain and
  lead tuned so that ±15 % brake effectiveness costs under 0.2 m). The
  feedback corrects a weak or strong brake as the speed departs from the
  curve, but nothing measures the train from outside;
- brakes: the train's own brake controller realises the demand with the
  B1..B7 notches (minimum hold, end-phase choice by the predicted stop),
  exactly as in ``tasc-brake-controller``.
**[interpretation]** SPEC §1 describes the ATO only by its weakness; the
transponder layout and the re-planning law are railstop's choice of a fair
baseline.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import Vehicle
from railstop.control.notch import modulator_init_1, modulator_update_1
from railstop.control.tasc import clip_1, external_decel_1
from railstop.jit import njit_inline, njit_step

FloatArray = NDArray[np.float64]

ATO_SPEED_GAIN_PER_S = 1.2  # speed-error feedback (1/s)
ATO_LEAD_FRACTION = 0.15  # of the brake's equivalent dead time: how far ahead the curve is read


# --------------------------------------------------------------------------
# Compiled scalar core (railstop.jit): the onboard ATO of one run.

AP_CYCLE_STEPS = 0
AP_MIN_HOLD = 1
AP_RESPONSE = 2  # dead time + lag (the modulator's brake model and the curve's lead)
AP_DT = 3
AP_MAX_DECEL = 4
AP_STOP = 5
AP_SIZE = 6

AT_ACTIVE = 0
AT_DISTANCE = 1  # odometric distance to the stopping point
AT_TARGET = 2
AT_NOTCH = 3
AT_BRAKING = 4  # until then the train holds its speed
AT_CURVE = 5  # the brake curve's deceleration (NaN: draw a new one at the next plan)
AT_FIXES = 6
AT_PLANS = 7
AT_SIZE = 8


def ato_params(vehicle: Vehicle, stop_point_m: float, dt_s: float) -> FloatArray:
    brake = vehicle.brake
    ap = np.zeros(AP_SIZE)
    ap[AP_CYCLE_STEPS] = max(1, round(brake.controller_cycle_s / dt_s))
    ap[AP_MIN_HOLD] = brake.controller_min_hold_s
    ap[AP_RESPONSE] = brake.dead_time_s + brake.time_constant_s
    ap[AP_DT] = dt_s
    ap[AP_MAX_DECEL] = brake.full_service_mps2
    ap[AP_STOP] = stop_point_m
    return ap


@njit_step
def ato_init_1(at: FloatArray, mod: FloatArray) -> None:
    at[:] = 0.0
    at[AT_DISTANCE] = np.inf
    at[AT_CURVE] = np.nan
    modulator_init_1(mod)


@njit_inline
def ato_fix_1(at: FloatArray, distance_m: float) -> None:
    """A position fix: the distance to the stopping point is now ``distance_m``; a new brake curve."""
    at[AT_DISTANCE] = distance_m
    at[AT_ACTIVE] = 1.0
    at[AT_FIXES] += 1.0
    at[AT_CURVE] = np.nan


@njit_inline
def ato_odometer_1(at: FloatArray, increment_m: float) -> None:
    """Distance the odometer counted during the last step."""
    if at[AT_ACTIVE] > 0.0:
        at[AT_DISTANCE] -= increment_m


@njit_step
def ato_output_1(
    at: FloatArray,
    ap: FloatArray,
    mod: FloatArray,
    table: FloatArray,
    ext: FloatArray,
    grad: tuple[FloatArray, FloatArray, FloatArray],
    k: int,
    speed_mps: float,
) -> int:
    """The notch of step ``k`` (``speed_mps``: the tachometer's speed); see the module docstring."""
    cycle = int(ap[AP_CYCLE_STEPS])
    active = at[AT_ACTIVE] > 0.0
    if k % cycle == 0:
        if active:
            full = ap[AP_MAX_DECEL]
            # The curve is compared a little ahead of the train: a lead that keeps
            # the loop from lagging the curve by the brake's delay.
            lead_s = ATO_LEAD_FRACTION * ap[AP_RESPONSE]
            distance = at[AT_DISTANCE]
            ahead = max(distance - speed_mps * lead_s, 0.0)
            if np.isnan(at[AT_CURVE]):
                # The brake curve (train deceleration) through the state at the latest fix.
                at[AT_CURVE] = clip_1(speed_mps**2 / (2.0 * max(ahead, 1.0)), 0.05, full)
            curve = at[AT_CURVE]
            v_ref = np.sqrt(2.0 * curve * ahead)
            ext_now = external_decel_1(ext, grad, distance, speed_mps)
            command = curve - ext_now + ATO_SPEED_GAIN_PER_S * (speed_mps - v_ref)
            if distance <= 0.0:  # at or past its stopping point with speed left: full service
                command = full
            at[AT_TARGET] = clip_1(command, 0.0, full)
            if at[AT_TARGET] > 0.0:
                at[AT_BRAKING] = 1.0
            at[AT_PLANS] += 1.0
        at[AT_NOTCH] = modulator_update_1(
            mod,
            table,
            ap[AP_MIN_HOLD],
            ap[AP_RESPONSE],
            at[AT_TARGET],
            active,
            cycle * ap[AP_DT],
            speed_mps,
            True,
        )
    return int(at[AT_NOTCH])
