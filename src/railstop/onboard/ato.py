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
- control: the best published onboard stop law we know (magicant's
  bve-autopilot TASC, its ``algorithm.md``), re-expressed: a
  constant-deceleration pattern to its odometric stopping point, drawn anew
  through the train's state at every transponder fix, and every controller
  cycle the deceleration that rejoins the pattern in ``ATO_REJOIN_S``
  (pattern deceleration × speed / pattern speed - (pattern speed - speed) /
  ``ATO_REJOIN_S``): it approaches the pattern gradually instead of at once,
  so a late or early brake response does not make it hunt. Near the stop,
  where ``ATO_REJOIN_S`` is longer than the time left, two bounds keep it
  continuous (max / min, no switch): above the pattern it asks at least the
  deceleration that rejoins the pattern halfway to the stop; below it, at most
  the constant deceleration that stops exactly there. It demands that less
  the gradient and resistance of its line data (brakes assumed nominal), the
  pattern read a little ahead of the train (``ATO_LEAD_FRACTION`` of the
  brake's equivalent dead time). The feedback corrects a weak or strong brake
  as the speed departs from the pattern, but nothing measures the train from
  outside;
- brakes: the train's own brake controller realises the demand with the
  B1..B7 notches (minimum hold, end-phase choice by the predicted stop),
  exactly as in ``tasc-brake-controller``.
**[interpretation]** SPEC §1 describes the ATO only by its weakness; the
transponder layout and the law are railstop's choice of a fair baseline.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import Vehicle
from railstop.control.law import control_law, controller_cycle_steps, safe_demand_1
from railstop.control.notch import modulator_init_1, modulator_update_1
from railstop.control.tasc import external_decel_1
from railstop.jit import njit_inline, njit_step

FloatArray = NDArray[np.float64]

ATO_REJOIN_S = 2.0  # the pattern is rejoined in this long (bve-autopilot's "2 seconds")
ATO_LEAD_FRACTION = 0.15  # of the brake's equivalent dead time: how far ahead the pattern is read


# --------------------------------------------------------------------------
# Compiled scalar core (railstop.jit): the onboard ATO of one run.

AP_CYCLE_STEPS = 0
AP_MIN_HOLD = 1
AP_DT = 2
AP_MAX_DECEL = 3
AP_STOP = 4
AP_DEAD = 5  # the brakes' dead time and lag (the modulator's brake model)
AP_LAG = 6
AP_SIZE = 7

AT_ACTIVE = 0
AT_DISTANCE = 1  # odometric distance to the stopping point
AT_TARGET = 2
AT_NOTCH = 3
AT_BRAKING = 4  # until then the train holds its speed
AT_FIXES = 5
AT_PLANS = 6
AT_SIZE = 7


def ato_params(vehicle: Vehicle, stop_point_m: float, dt_s: float) -> FloatArray:
    brake = vehicle.brake
    ap = np.zeros(AP_SIZE)
    ap[AP_CYCLE_STEPS] = controller_cycle_steps(vehicle, dt_s)
    ap[AP_MIN_HOLD] = brake.controller_min_hold_s
    ap[AP_DT] = dt_s
    ap[AP_MAX_DECEL] = brake.full_service_mps2
    ap[AP_STOP] = stop_point_m
    ap[AP_DEAD] = brake.dead_time_s
    ap[AP_LAG] = brake.time_constant_s
    return ap


@njit_step
def ato_init_1(at: FloatArray, mod: FloatArray) -> None:
    at[:] = 0.0
    at[AT_DISTANCE] = np.inf
    modulator_init_1(mod)


@njit_inline
def ato_fix_1(at: FloatArray, distance_m: float) -> None:
    """A position fix: the distance to the stopping point is now ``distance_m``; a new pattern."""
    at[AT_DISTANCE] = distance_m
    at[AT_ACTIVE] = 1.0
    at[AT_FIXES] += 1.0  # the law sees a new fix: a new reference


@njit_inline
def ato_odometer_1(at: FloatArray, increment_m: float) -> None:
    """Distance the odometer counted during the last step."""
    if at[AT_ACTIVE] > 0.0:
        at[AT_DISTANCE] -= increment_m


@njit_inline
def ato_output_1(
    at: FloatArray,
    ap: FloatArray,
    mod: FloatArray,
    table: FloatArray,
    ext: FloatArray,
    grad: tuple[FloatArray, FloatArray, FloatArray],
    k: int,
    speed_mps: float,
    law: Any,
    meas: NDArray[np.void],
    law_state: FloatArray,
    lp: NDArray[np.void],
) -> int:
    """The notch of step ``k`` (``speed_mps``: the tachometer's speed): every controller cycle
    with a position, the ``law``'s demand (``railstop.control.law``), realised with the notches
    by the train's brake controller.

    Inlined into the step (issue 37): called out of line every step, it made the compiler keep
    the caller's state in memory around the call; inlined, ``ato`` ran 141.6 -> 101.1 µs of
    thread CPU time per run (1,000 standard runs at Riverside, every result the same bit)."""
    cycle = int(ap[AP_CYCLE_STEPS])
    active = at[AT_ACTIVE] > 0.0
    if k % cycle == 0:
        if active:
            distance = at[AT_DISTANCE]
            m = meas[0]
            m.t_s = k * ap[AP_DT]
            m.distance_m = distance
            m.speed_mps = speed_mps
            m.external_mps2 = external_decel_1(ext, grad, distance, speed_mps)
            m.fixes = int(at[AT_FIXES])
            m.braking = at[AT_BRAKING] > 0.0
            at[AT_TARGET] = safe_demand_1(law(meas, law_state, lp), ap[AP_MAX_DECEL])
            if at[AT_TARGET] > 0.0:
                at[AT_BRAKING] = 1.0  # from now on the traction is off
            at[AT_PLANS] += 1.0
        at[AT_NOTCH] = modulator_update_1(
            mod,
            table,
            ap[AP_MIN_HOLD],
            ap[AP_DEAD],
            ap[AP_LAG],
            at[AT_TARGET],
            active,
            cycle * ap[AP_DT],
            speed_mps,
            True,
            0.0,
        )
    return int(at[AT_NOTCH])


# --------------------------------------------------------------------------
# The ATO's law, written against railstop.control.law (the example of a law).

# The law's own state (railstop.control.law: zeroed at the start of a run).
ATO_CURVE = 0  # the pattern's deceleration (0: draw a new one at the next plan)
ATO_FIXES_SEEN = 1  # the fixes the pattern was drawn after


def ato_law_function(meas: NDArray[np.void], state: FloatArray, params: NDArray[np.void]) -> float:
    """The brake deceleration the ATO asks for (see the module docstring)."""
    m, p = meas[0], params[0]
    full = p.full_service_mps2
    speed = m.speed_mps
    distance = m.distance_m
    # The pattern is compared a little ahead of the train: a lead that keeps the loop from lagging
    # it by the brake's delay.
    lead_s = ATO_LEAD_FRACTION * p.response_s
    ahead = max(distance - speed * lead_s, 0.0)
    if m.fixes != state[ATO_FIXES_SEEN]:
        # A new fix: the pattern (train deceleration) through the state at this fix; before the
        # brakes are on, through the point where they will have responded, so that the train
        # meets the pattern instead of starting behind it.
        start = ahead if m.braking else distance - speed * p.response_s
        state[ATO_CURVE] = min(max(speed**2 / (2.0 * max(start, 1.0)), 0.05), full)
        state[ATO_FIXES_SEEN] = m.fixes
    curve = state[ATO_CURVE]
    if distance <= 0.0:  # at or past its stopping point with speed left: full service
        return full
    v = speed
    v_pattern = math.sqrt(2.0 * curve * ahead)
    ratio = v / v_pattern if v_pattern > 0.0 else 1.0
    train = curve * ratio - (v_pattern - v) / ATO_REJOIN_S
    if v > v_pattern:
        # Above the pattern: at least rejoin it halfway to the stop.
        half = ahead / 2.0
        train = max(train, (v * v - 2.0 * curve * half) / (2.0 * half)) if half > 1e-3 else full
    elif ahead > 1e-3:
        # Below it: no more than stopping exactly at the stopping point.
        train = min(train, v * v / (2.0 * ahead))
    # Less what the line data's gradient and resistance give at the train.
    return min(max(train - m.external_mps2, 0.0), full)


#: The onboard ATO (positioned at the transponders) and ato-corrected (by SPEC §2 corrections).
ATO_LAW = control_law(name="ato")(ato_law_function)
ATO_CORRECTED_LAW = control_law(name="ato-corrected", positioning="corrected")(ato_law_function)
