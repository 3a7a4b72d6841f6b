"""The onboard signal control unit of SPEC §1 in its three configurations, compiled, one run at a time.

- ``tasc-brake-controller`` (config 1, claims 9-11): the command goes to the
  train's own brake controller, whose logic picks the notch every control
  cycle (alternating the two notches around a continuous target, with a
  minimum hold) and drives the encoder -> 3-wire step code. Until the first
  braking telegram the brake controller follows the train's own ATO.
- ``tasc-step`` (config 2, claims 12-14, step variant): the onboard controller
  turns the required deceleration into the B1..B7 step code itself; the
  switching unit (switching controller 250, changeover switches SW1-SW3 of
  unit 240) changes the ECU's input over from the train's own wires a, b, c
  to the onboard output once the onboard unit has a command
  (``receiver_switch_1``), every simulation step after that.
- ``tasc-switched-pwm`` (config 2, claim 14, PWM variant): the same on a PWM
  train, with the two switches SW11, SW12 on the PWM line; the onboard PWM
  then runs on its own carrier clock.
- ``tasc-pwm`` (config 3, claims 15, 25): a PWM duty synchronised to the zero
  crossing of the existing PWM brake signal (the train's own ATO's) and
  superimposed on it: the ECU sees the larger duty, latched once per carrier
  period (``railstop.onboard.pwm_wave`` shows it at waveform level).

For signal forms 1-5 the receiver computes the required deceleration itself
(SPEC §1) with the same control law as the wayside, from the telegram's
measurement completed by its own tachometer and station data.
"""

from __future__ import annotations

import math
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import Station, Vehicle
from railstop.control.notch import (
    modulator_init_1,
    modulator_restart_1,
    modulator_update_1,
)
from railstop.control.supervision import (
    EB_ONBOARD_GUARD,
    EB_TIMEOUT,
    EB_WAYSIDE_GUARD,
    overrun_guard_1,
)
from railstop.control.tasc import (
    FIT_SUMS,
    REG_WEIGHTS,
    Approach,
    BrakeCurves,
    brake_need_1,
    clip_1,
    fit_ring_1,
    gain_update_1,
    gain_value_1,
    guard_limit_on_path_1,
    history_push_1,
    interval_fit_add_1,
    interval_fit_decel_1,
    interval_fit_reset_1,
    modelled_means_1,
    plan_command_1,
    regression_taus_1,
    start_floor_mps2,
)
from railstop.controllers import TASC_BRAKE_CONTROLLER, TASC_PWM, TASC_STEP, TASC_SWITCHED_PWM
from railstop.jit import njit_inline, njit_step
from railstop.messages import (
    TEL_DECEL,
    TEL_DELTA,
    TEL_DETECTOR,
    TEL_DISTANCE,
    TEL_DUTY,
    TEL_EMERGENCY,
    TEL_INTERVAL,
    TEL_MEASURED,
    TEL_NOTCH,
    TEL_PASSAGE,
    TEL_REQUIRED,
    TEL_SPEED,
    TEL_STEP,
)
from railstop.physics.brake import decel_to_pwm_1

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


class OnboardConfig(StrEnum):
    BRAKE_CONTROLLER = TASC_BRAKE_CONTROLLER
    STEP = TASC_STEP
    SWITCHED_PWM = TASC_SWITCHED_PWM
    PWM = TASC_PWM


# --------------------------------------------------------------------------
# Compiled scalar core (railstop.jit): the onboard receiver of one run.

CONFIG_CODES: dict[str, int] = {
    OnboardConfig.BRAKE_CONTROLLER.value: 1,
    OnboardConfig.STEP.value: 2,
    OnboardConfig.PWM.value: 3,
    OnboardConfig.SWITCHED_PWM.value: 4,
}
CFG_BRAKE_CONTROLLER = 1
CFG_STEP = 2
CFG_PWM = 3
CFG_SWITCHED_PWM = 4

# Positions of config 2's changeover switches (SW1-SW3, SW11/SW12), as recorded in the trace.
SWITCH_TRAIN = 0  # the ECU reads the train's own brake command
SWITCH_TRANSFER = 1  # contacts moving (break before make): the ECU input is open
SWITCH_ONBOARD = 2  # the ECU reads the onboard unit's output

RP_CONFIG = 0  # CFG_*: 1 brake controller, 2 step (switching unit), 3 PWM superposition, 4 switched PWM
RP_FORM = 1
RP_CYCLE_STEPS = 2  # the notch modulator's cycle: the brake controller's (config 1), the unit's (config 2)
RP_PWM_STEPS = 3  # steps per PWM carrier period (config 3)
RP_MIN_HOLD = 4
RP_RESPONSE = 5  # dead time + lag: the brake response (forms 1-5 planner, overrun guard)
RP_DT = 6
RP_MAX_DECEL = 7
RP_LAG = 8
RP_JERK = 9
RP_STOP = 10
RP_SPEED_SAMPLES = 11
RP_TIMEOUT = 12  # supervision: longest gap between braking telegrams inside the zone
RP_GUARD_LIMIT = 13  # overrun guard: the deceleration beyond which the service brake cannot do
RP_END = 14  # the platform end (chainage)
RP_ODO_UNC = 15  # the odometer's possible error, fraction of the distance since the last reset
RP_POS_MARGIN = 16  # ... plus this (m)
RP_ZONE_START = 17  # the first transponder (chainage): the train knows it is in the TASC zone
RP_FIRST_BY = 18  # the detector (chainage) by which the first telegram must have come
RP_TRANSFER_STEPS = 19  # config 2: steps the changeover switches take (break before make)
RP_DEAD = 20  # the brakes' dead time (the modulator's model: this, then the lag RP_LAG)
RP_START_FLOOR = 21  # forms 1-5: the first braking waits while the command is under this
RP_EMERGENCY = 22  # the train's nominal emergency deceleration (its guard's limit, guard_limit_1)
RP_GUARD_ALPHA = 23  # the guard's deceleration filter: dt / (GUARD_DECEL_TAU_S + dt)
RP_SIZE = 24

RX_ACTIVE = 0
RX_TARGET = 1
RX_FIXED_NOTCH = 2  # form 7, step trains (-1: none)
RX_FIXED_DUTY = 3  # form 7, PWM trains (NaN: none)
RX_RECEIVED = 4
RX_LATCHED = 5  # the duty the ECU sees, latched at each zero crossing
RX_NOTCH = 6
RX_TCOL = 7  # newest tachometer slot
RX_TCOUNT = 8
RX_GAIN_NUM = 9
RX_GAIN_DEN = 10
RX_FIRST_RX = 11  # the train holds its speed until told to brake
RX_EXISTING = 12  # the train's own PWM brake signal (released: 0)
RX_ONBOARD_DUTY = 13  # config 3: the onboard PWM duty of the current target
RX_LAST_RX = 14  # time of the last braking telegram delivered (new or a cyclic repeat)
RX_IN_ZONE = 15  # 1 once the train's own position says it is in the TASC zone
RX_FIX_POS = 16  # the train's own position at its last transponder reset (chainage; NaN: none)
RX_SINCE_FIX = 17  # odometer distance since that reset
RX_EB = 18  # emergency brake cause (control.supervision EB_*; 0: none), latched
RX_EB_T = 19  # when it was applied
RX_TACH_PREV = 20  # the tachometer speed of the last step (NaN: none yet)
RX_TACH_DECEL = 21  # the tachometer's deceleration, smoothed over GUARD_DECEL_TAU_S
RX_SWITCH = 22  # config 2: the changeover switches' position (SWITCH_*)
RX_SWITCH_LEFT = 23  # ... steps of the transfer still to go
RX_PREV_V = 24  # form 4: the speed the last used telegram gave (NaN: none yet)
RX_PREV_REF = 25  # form 4: its distance to the stopping point
RX_PREV_DET = 26  # forms 1-3: the detector of the last passage the unit took (-1: none)
RX_COMB_DECEL = 27  # form 4: the deceleration the combination gave (NaN: none yet)
RX_PULSES = 28  # the odometer's count since the start (m, its own scale; forms 1-5 calibrate on it)
RX_PREV_ODO = 29  # forms 1-3: ... at the last passage taken (NaN: none)
RX_SCALE = 30  # forms 1-5: true over tachometer distance, from the wayside's measurements
RX_WIN_START = 31  # forms 1-5: the start of the measurement interval (the last command's effect)
RX_SUMS = 32  # ... the running line fit of the tachometer's speed over it (control.tasc)
RX_DEGRADED = RX_SUMS + FIT_SUMS  # 1: the telegrams stopped after a command; the unit finishes the stop
RX_ODO_SCALE = RX_DEGRADED + 1  # true over odometer distance between the last two transponders (1: none)
RX_WSP_T = RX_ODO_SCALE + 1  # the last step in which the wheel-slide protection acted (-inf: never)
RX_PREV_T = RX_WSP_T + 1  # forms 1-5: when the calibration's last reference was taken (NaN: none)
RX_FIX_T = RX_PREV_T + 1  # when the train passed its last transponder (NaN: none)
RX_CAL_ODO = RX_FIX_T + 1  # forms 4, 5: the odometer's count at the calibration's reference (NaN: none)
RX_CAL_REF = RX_CAL_ODO + 1  # ... and the wayside's distance to the stopping point there
RX_STEP = RX_CAL_REF + 1  # form 8: the number of the last step taken (0: none yet)
RX_STEP_LOST = RX_STEP + 1  # form 8: 1 once a step was missed (latched: degraded mode for good)
RX_GUARD_LIMIT = RX_STEP_LOST + 1  # the overrun guard's limit on the path left (guard_limit_1)
RX_SIZE = RX_GUARD_LIMIT + 1

_SCALE_MIN_M = 50.0  # the odometer's scale is taken only over at least this between transponders
GUARD_DECEL_TAU_S = 0.3  # smoothing of the onboard guard's deceleration from the tachometer


def receiver_params(config: str, form: int, vehicle: Vehicle, station: Station, dt_s: float) -> FloatArray:
    """The RP_* vector of a receiver (see the RP_* constants)."""
    brake = vehicle.brake
    stop_point_m = station.stop_point_m
    rp = np.zeros(RP_SIZE)
    rp[RP_CONFIG] = CONFIG_CODES[config]
    rp[RP_FORM] = form
    cfg1 = config == OnboardConfig.BRAKE_CONTROLLER
    # Stop model 22 [interpretation]: config 2's onboard unit chooses its notch on its own cycle
    # (tasc_cycle_s), as the train's brake controller does on its (config 1); up to model 21 it
    # chose one every simulation step (10 ms), which no onboard computer's output stage does and
    # which cost 40 % of the stop kernel's time in the end phase's look-ahead.
    rp[RP_CYCLE_STEPS] = max(1, round((brake.controller_cycle_s if cfg1 else brake.tasc_cycle_s) / dt_s))
    rp[RP_PWM_STEPS] = max(1, round(1.0 / (brake.pwm_carrier_hz * dt_s)))
    rp[RP_MIN_HOLD] = brake.controller_min_hold_s if cfg1 else brake.tasc_min_hold_s
    rp[RP_RESPONSE] = brake.dead_time_s + brake.time_constant_s
    rp[RP_DEAD] = brake.dead_time_s
    rp[RP_DT] = dt_s
    rp[RP_MAX_DECEL] = brake.full_service_mps2
    rp[RP_LAG] = brake.time_constant_s
    rp[RP_JERK] = brake.jerk_limit_mps3
    rp[RP_STOP] = stop_point_m
    rp[RP_SPEED_SAMPLES] = max(2, round(0.3 / dt_s))  # as the wayside's Doppler speed window
    rp[RP_TIMEOUT] = station.tasc.supervision_timeout_s
    rp[RP_GUARD_LIMIT] = vehicle.atp.guard_decel_fraction * brake.full_service_mps2
    rp[RP_END] = station.platform_end
    rp[RP_ODO_UNC] = vehicle.atp.odometer_uncertainty_pct / 100.0
    rp[RP_POS_MARGIN] = vehicle.atp.position_margin_m
    rp[RP_ZONE_START] = station.ato_transponders_m()[0]
    # The wayside's first command comes at the first detector (at the second without a Doppler
    # radar, SPEC §1 variant 2); one missed detector is tolerated: the wayside then speaks at the
    # next one. Past that detector the supervision clock runs. [interpretation]
    first = 1 if station.tasc.doppler is not None else 2
    detectors = station.detector_positions_m()
    rp[RP_FIRST_BY] = detectors[min(first, len(detectors) - 1)]
    rp[RP_TRANSFER_STEPS] = round(brake.switch_transfer_s / dt_s)
    rp[RP_START_FLOOR] = start_floor_mps2(brake.full_service_mps2, form, station.tasc.doppler is not None)
    rp[RP_EMERGENCY] = brake.emergency_decel_mps2
    rp[RP_GUARD_ALPHA] = dt_s / (GUARD_DECEL_TAU_S + dt_s)
    return rp


def receiver_window(dt_s: float) -> int:
    """Tachometer samples the forms 1-5 planner fits its deceleration over (1 s)."""
    return max(2, round(1.0 / dt_s))


@njit_step
def receiver_init_1(rx: FloatArray, mod: FloatArray, hist_v: FloatArray, hist_e: FloatArray) -> None:
    rx[:] = 0.0
    rx[RX_FIXED_NOTCH] = -1.0
    rx[RX_FIXED_DUTY] = np.nan
    rx[RX_TCOL] = -1.0
    rx[RX_FIRST_RX] = np.inf
    rx[RX_LAST_RX] = -np.inf
    rx[RX_FIX_POS] = np.nan
    rx[RX_EB_T] = np.nan
    rx[RX_TACH_PREV] = np.nan
    rx[RX_PREV_V] = np.nan
    rx[RX_PREV_REF] = np.nan
    rx[RX_PREV_DET] = -1.0
    rx[RX_ODO_SCALE] = 1.0
    rx[RX_COMB_DECEL] = np.nan
    rx[RX_GUARD_LIMIT] = np.inf  # the configured limit until the first telegram
    rx[RX_PREV_ODO] = np.nan
    rx[RX_SCALE] = 1.0
    rx[RX_WIN_START] = np.inf
    rx[RX_WSP_T] = -np.inf
    rx[RX_PREV_T] = np.nan
    rx[RX_FIX_T] = np.nan
    rx[RX_CAL_ODO] = np.nan
    rx[RX_CAL_REF] = np.nan
    modulator_init_1(mod)
    hist_v[:] = 0.0
    hist_e[:] = np.inf


@njit_inline
def receiver_observe_1(
    rx: FloatArray, rp: FloatArray, tach: FloatArray, speed_mps: float, wsp: bool, now_s: float
) -> None:
    """Onboard speed from the tachometer (only the forms 1-5 planner uses it); ``wsp``: the
    wheel-slide protection acts (the tachometer reads the sliding wheel, not the train)."""
    if wsp:
        rx[RX_WSP_T] = now_s
    if rp[RP_FORM] > 5:
        return
    if now_s >= rx[RX_WIN_START]:
        interval_fit_add_1(rx, RX_SUMS, now_s - rx[RX_WIN_START], speed_mps)
    col = (int(rx[RX_TCOL]) + 1) % tach.size
    rx[RX_TCOL] = col
    tach[col] = speed_mps
    rx[RX_TCOUNT] = min(rx[RX_TCOUNT] + 1.0, float(tach.size))


@njit_step
def receiver_receive_1(
    rx: FloatArray,
    rp: FloatArray,
    mod: FloatArray,
    tach: FloatArray,
    hist_v: FloatArray,
    hist_e: FloatArray,
    taus: FloatArray,
    brake: BrakeCurves,
    approach: Approach,
    tele: FloatArray,
    now_s: float,
) -> None:
    """Take the telegram delivered now (SPEC §1: forms 6-8 as such; forms 1-5 planned onboard)."""
    table, pwm_duty, pwm_decel = brake.table, brake.pwm_duty, brake.pwm_decel
    det_to_stop, ext, grad = approach.det_to_stop, approach.ext, approach.grad
    rx[RX_LAST_RX] = now_s
    if tele[TEL_EMERGENCY] > 0.0:
        # The wayside's overrun guard (DESIGN rule 10): emergency brake through wire e.
        _apply_eb_1(rx, EB_WAYSIDE_GUARD, now_s)
        rx[RX_RECEIVED] += 1.0
        return
    rx[RX_ACTIVE] = 1.0
    rx[RX_RECEIVED] += 1.0
    # Stop model 18: the overrun guard's limit as this train's emergency brake keeps it on the
    # path left, the train where its odometry puts it (NaN before a transponder fix), with the
    # forms 1-5 loop gain (1 for forms 6-8, which measure none onboard).
    rx[RX_GUARD_LIMIT] = guard_limit_on_path_1(
        rp[RP_GUARD_LIMIT], rp[RP_EMERGENCY], gain_value_1(rx[RX_GAIN_NUM], rx[RX_GAIN_DEN]), ext, grad,
        rp[RP_STOP] - rx[RX_FIX_POS] - rx[RX_SINCE_FIX], rp[RP_END] - rp[RP_STOP],
    )  # fmt: skip
    modulator_restart_1(mod)
    form = int(rp[RP_FORM])
    if form == 6:
        rx[RX_TARGET] = tele[TEL_REQUIRED]
    elif form == 7:
        rx[RX_FIXED_NOTCH] = tele[TEL_NOTCH]
        rx[RX_FIXED_DUTY] = tele[TEL_DUTY]
        rx[RX_TARGET] = table[max(int(tele[TEL_NOTCH]), 0)]
    elif form == 8:
        # SPEC §1 claim 11, paras 93-94: increase / decrease the current braking, passed to the
        # brake controller as such: one notch up or down per telegram (a PWM train: that notch's
        # deceleration as a duty).
        step = tele[TEL_STEP]
        if rx[RX_STEP_LOST] == 0.0 and step == (rx[RX_STEP] + 1.0) % 256.0:
            notch = min(max(max(rx[RX_FIXED_NOTCH], 0.0) + tele[TEL_DELTA], 0.0), float(table.size - 1))
            rx[RX_FIXED_NOTCH] = notch
            rx[RX_TARGET] = table[int(notch)]
        elif rx[RX_STEP_LOST] == 0.0 and step == rx[RX_STEP] and tele[TEL_DELTA] == 0.0:
            pass  # no step: the wayside's first telegram while the braking waits (a hold)
        elif rx[RX_STEP_LOST] == 0.0:
            # Stop model 14 [interpretation]: a step number skipped, so a step never reached the
            # train (all its transmissions lost), and every later "one more" / "one less" would
            # leave it a notch off what the wayside believes for the rest of the stop (measured on
            # model 13: 2.06 m past the stop, 31.09 m short). It no longer takes the steps and
            # finishes the stop in degraded mode, as after a lost link (receiver_degraded_1, the
            # overrun guard watching); without a transponder fix, the emergency brake.
            rx[RX_STEP_LOST] = 1.0
            if math.isfinite(rx[RX_FIX_POS]):
                rx[RX_DEGRADED] = 1.0
            else:
                _apply_eb_1(rx, EB_TIMEOUT, now_s)
        rx[RX_STEP] = step
    else:
        _receiver_plan_1(rx, rp, tach, hist_v, hist_e, taus, det_to_stop, ext, grad, tele, now_s)
    if rx[RX_TARGET] > 0.0:
        rx[RX_FIRST_RX] = min(rx[RX_FIRST_RX], now_s)
    if int(rp[RP_CONFIG]) in (CFG_PWM, CFG_SWITCHED_PWM):
        duty = rx[RX_FIXED_DUTY]
        rx[RX_ONBOARD_DUTY] = (
            duty if math.isfinite(duty) else decel_to_pwm_1(rx[RX_TARGET], pwm_duty, pwm_decel)
        )


@njit_inline
def _calibrate_tachometer_1(
    rx: FloatArray,
    tele: FloatArray,
    det_to_stop: FloatArray,
    form: int,
    tach_v: float,
    now_s: float,
    lag: float,
) -> None:
    """Forms 1-5: the tachometer's scale (true over tachometer distance, RX_SCALE) from the
    telegram's measurements (:func:`_receiver_plan_1`, items 1-3), never over a stretch in which
    the wheel-slide protection acted."""
    det = int(tele[TEL_DETECTOR])
    if form <= 3:
        if det != int(rx[RX_PREV_DET]):
            # A new passage: the odometer's count at it (back from now at the present speed), as
            # forms 4 and 5 take theirs (stop model 16: the tachometer's speed summed per step is
            # off by a·dt/2v, the count is the odometer's own).
            odo_pass = rx[RX_PULSES] - tach_v * (now_s - tele[TEL_PASSAGE])
            interval = tele[TEL_INTERVAL]
            prev = int(rx[RX_PREV_DET])
            known = math.isfinite(interval) and interval > 0.0 and math.isfinite(rx[RX_PREV_ODO])
            if prev == det - 1 and known:
                tach_mean = (odo_pass - rx[RX_PREV_ODO]) / interval
                true_mean = (det_to_stop[prev] - det_to_stop[det]) / interval
                if tach_mean > 0.5 and rx[RX_WSP_T] < rx[RX_PREV_T]:
                    rx[RX_SCALE] = true_mean / tach_mean
            rx[RX_PREV_ODO] = odo_pass
            rx[RX_PREV_DET] = det
            rx[RX_PREV_T] = tele[TEL_PASSAGE]
    else:
        # Forms 4, 5: two successive distances against the odometer's count between the same
        # instants calibrate the tachometer (the wheel's scale error is the odometer's). The
        # count, not the tachometer's speed summed per step: that sum is off by a · dt / 2v, a
        # few hundredths of a per cent near standstill, which moved nominal stops by centimetres.
        odo_meas = rx[RX_PULSES] - tach_v * lag
        d_m = tele[TEL_DISTANCE]
        calm = rx[RX_WSP_T] < rx[RX_PREV_T]  # no slide since the reference
        if math.isfinite(rx[RX_CAL_ODO]) and odo_meas - rx[RX_CAL_ODO] > 5.0 and calm:
            rx[RX_SCALE] = (rx[RX_CAL_REF] - d_m) / (odo_meas - rx[RX_CAL_ODO])
        if not math.isfinite(rx[RX_CAL_ODO]) or odo_meas - rx[RX_CAL_ODO] > 5.0:
            rx[RX_CAL_ODO] = odo_meas
            rx[RX_CAL_REF] = d_m
            rx[RX_PREV_T] = tele[TEL_MEASURED]


@njit_step
def _receiver_plan_1(
    rx: FloatArray,
    rp: FloatArray,
    tach: FloatArray,
    hist_v: FloatArray,
    hist_e: FloatArray,
    taus: FloatArray,
    det_to_stop: FloatArray,
    ext: FloatArray,
    grad: tuple[FloatArray, FloatArray, FloatArray],
    tele: FloatArray,
    now_s: float,
) -> None:
    """Forms 1-5: the onboard unit computes the required deceleration itself (claim 10) from the
    combination of para 92 the telegram carries, with the same law as the wayside:

    1. forms 1-3, the time between the last two detectors, the position and the distance: the
       mean speed over that interval (detector spacing from the unit's own database over the
       time) against the tachometer's mean over the same interval calibrates the tachometer;
       the speed and deceleration now are the tachometer's, so calibrated;
    2. form 4, the speed and the distance: the deceleration from two successive (speed,
       distance) pairs, (v1² - v2²) / 2 (d1 - d2); two successive distances against the
       odometer's count calibrate the tachometer, as in form 5, whose deceleration closes the
       loop gain (stop model 12: uncalibrated, an odometer's wheel diameter 1.5 % below the
       actual biased the gain by a tenth on a steep uphill approach, where the brake gives a
       third of the deceleration, and such stops ended 0.3-0.4 m short);
    3. form 5, the deceleration and the distance: two successive distances against the
       odometer's count over the same time calibrate the tachometer, which gives the speed; the
       wayside's deceleration only where the tachometer has none yet.

    The distance always comes from the wayside, advanced to now. What a combination does not
    give (anything before a second telegram) comes from the tachometer as it is. No
    calibration and no gain update is taken over a stretch in which the wheel-slide protection
    acted (stop model 12, **[interpretation]**: the sliding wheel's tachometer reads the slide,
    not the wheel's diameter; taken, one slide on a low-adhesion patch set the scale a half too
    high and stopped the train up to 143 m short).
    [interpretation] Para 92 says the train computes speed and deceleration from these, not how;
    a mean speed over an interval of several seconds is no speed at the end of it while the
    braking changes, so the interval calibrates the tachometer instead, which removes the wheel
    diameter error the ground TASC exists to remove. The loop gain is closed on the
    tachometer's deceleration over the interval since the last command took effect, whose
    window the modelled means match."""
    dt = rp[RP_DT]
    count = int(rx[RX_TCOUNT])
    tach_v, tach_a = fit_ring_1(tach, int(rx[RX_TCOL]), count, dt, int(rp[RP_SPEED_SAMPLES]))
    form = int(rp[RP_FORM])
    lag = now_s - tele[TEL_MEASURED]
    a_tach = tach_a if math.isfinite(tach_a) else 0.0
    _calibrate_tachometer_1(rx, tele, det_to_stop, form, tach_v, now_s, lag)
    scale = rx[RX_SCALE]
    speed = tach_v * scale
    a_est = a_tach * scale
    if form == 4:
        v_m = tele[TEL_SPEED]
        d_m = tele[TEL_DISTANCE]
        if math.isfinite(rx[RX_PREV_V]) and rx[RX_PREV_REF] - d_m > 1.0:
            rx[RX_COMB_DECEL] = (rx[RX_PREV_V] ** 2 - v_m**2) / (2.0 * (rx[RX_PREV_REF] - d_m))
            rx[RX_PREV_V] = v_m
            rx[RX_PREV_REF] = d_m
        elif not math.isfinite(rx[RX_PREV_V]):
            rx[RX_PREV_V] = v_m
            rx[RX_PREV_REF] = d_m
        a_est = rx[RX_COMB_DECEL] if math.isfinite(rx[RX_COMB_DECEL]) else a_tach
        speed = v_m - a_est * lag
    elif form == 5 and math.isfinite(tele[TEL_DECEL]) and not math.isfinite(tach_a):
        # The wayside's deceleration stands in only where the tachometer has none: it is the mean
        # over the wayside's own interval, which the onboard unit's model of its commands does
        # not match (measured: with it the form-5 stops ended up to 0.38 m short).
        a_est = tele[TEL_DECEL]
    # The loop gain's measurement: the tachometer's deceleration over the interval since the last
    # command took effect when that is longer than the 1 s ring (as the wayside's Doppler fit).
    window = count
    measured = a_tach * scale
    c, interval_decel = interval_fit_decel_1(rx, RX_SUMS)
    if c > count:
        window = c
        measured = interval_decel * scale
    distance = tele[TEL_DISTANCE] - (speed * lag + 0.5 * a_est * lag * lag)
    regression_taus_1(now_s - (window - 1) * dt, now_s, taus)
    cmd_mean, ext_mean = modelled_means_1(
        hist_v,
        hist_e,
        taus,
        REG_WEIGHTS,
        rx[RX_FIRST_RX],
        rp[RP_LAG],
        ext,
        grad,
        distance,
        speed,
        a_est,
        now_s,
    )
    num, den = rx[RX_GAIN_NUM], rx[RX_GAIN_DEN]
    if rx[RX_WSP_T] < now_s - window * dt:
        # A window in which the wheel-slide protection acted measures the sliding wheel, not the
        # brake: the gain keeps what the calm windows gave.
        num, den = gain_update_1(num, den, measured, cmd_mean, ext_mean)
    rx[RX_GAIN_NUM] = num
    rx[RX_GAIN_DEN] = den
    command, _, effect = plan_command_1(
        distance,
        speed,
        now_s,
        hist_v,
        hist_e,
        gain_value_1(num, den),
        rp[RP_RESPONSE],
        rp[RP_JERK],
        rp[RP_MAX_DECEL],
        ext,
        grad,
        det_to_stop,
        rp[RP_START_FLOOR],
    )
    history_push_1(hist_v, hist_e, command, effect)
    rx[RX_TARGET] = command
    rx[RX_WIN_START] = effect
    interval_fit_reset_1(rx, RX_SUMS)


@njit_inline
def receiver_pwm_output_1(rx: FloatArray, rp: FloatArray, k: int, existing: float) -> float:
    """The onboard PWM brake signal of step ``k``, latched once per carrier period.

    Config 3: synchronised to the zero crossing of the existing PWM brake signal (duty
    ``existing``, the train's own) and superimposed on it: both pulses start together, so the
    ECU sees their OR, the larger duty (SPEC §1 claims 15, 25). Config 2 (switched PWM): the
    onboard duty alone, on the onboard unit's own carrier clock; the switching unit decides
    whether the ECU sees it.
    """
    if k % int(rp[RP_PWM_STEPS]) == 0:
        rx[RX_EXISTING] = existing
        onboard = rx[RX_ONBOARD_DUTY] if rx[RX_ACTIVE] > 0.0 else 0.0
        rx[RX_LATCHED] = max(existing, onboard) if int(rp[RP_CONFIG]) == CFG_PWM else onboard
    return rx[RX_LATCHED]


@njit_inline
def receiver_switch_1(rx: FloatArray, rp: FloatArray) -> int:
    """Config 2's switching unit, one step: the switching controller changes the ECU's input over
    to the onboard output once the onboard unit has a braking command (SPEC §1 paras 194, 198),
    break before make over ``RP_TRANSFER_STEPS``; it stays over to standstill.
    **[interpretation]** SPEC §1 does not say when the switches go back; not within the stop."""
    pos = int(rx[RX_SWITCH])
    if pos == SWITCH_TRAIN and rx[RX_ACTIVE] > 0.0:
        pos = SWITCH_TRANSFER
        rx[RX_SWITCH_LEFT] = rp[RP_TRANSFER_STEPS]
    if pos == SWITCH_TRANSFER:
        if rx[RX_SWITCH_LEFT] <= 0.0:
            pos = SWITCH_ONBOARD
        rx[RX_SWITCH_LEFT] -= 1.0
    rx[RX_SWITCH] = pos
    return pos


@njit_step
def receiver_step_output_1(
    rx: FloatArray, rp: FloatArray, mod: FloatArray, table: FloatArray, k: int, speed_mps: float
) -> int:
    """Configs 1, 2: the notch of step ``k``. The brake controller (config 1) or the onboard
    unit's own modulator (config 2) sets it once per its cycle; forms 7 and 8 fix it (config 2
    relays the wayside's notch to the switching unit in the step it has it); wire e passes
    through from the train."""
    cycle = int(rp[RP_CYCLE_STEPS])
    if k % cycle != 0:
        if rx[RX_FIXED_NOTCH] >= 0.0 and int(rp[RP_CONFIG]) == CFG_STEP:
            rx[RX_NOTCH] = rx[RX_FIXED_NOTCH]
    else:
        notch = modulator_update_1(
            mod,
            table,
            rp[RP_MIN_HOLD],
            rp[RP_DEAD],
            rp[RP_LAG],
            rx[RX_TARGET],
            rx[RX_ACTIVE] > 0.0,
            cycle * rp[RP_DT],
            speed_mps,
            True,
            0.0,
        )
        rx[RX_NOTCH] = rx[RX_FIXED_NOTCH] if rx[RX_FIXED_NOTCH] >= 0.0 else notch
    return int(rx[RX_NOTCH])


# --------------------------------------------------------------------------
# Supervision (DESIGN rules 4, 10; control.supervision): the train's own position, the
# telegram time-out inside the zone and the overrun guard. The emergency brake is latched.


@njit_inline
def _apply_eb_1(rx: FloatArray, cause: int, now_s: float) -> None:
    if rx[RX_EB] == 0.0:
        rx[RX_EB] = cause
        rx[RX_EB_T] = now_s


@njit_inline
def receiver_alive_1(rx: FloatArray, now_s: float) -> None:
    """A cyclic repeat of the telegram the unit already has: a life sign, nothing else."""
    rx[RX_LAST_RX] = now_s


@njit_inline
def receiver_fix_1(rx: FloatArray, rp: FloatArray, position_m: float, now_s: float) -> None:
    """The train's own ATP reset its odometer at a transponder at ``position_m`` (passed in the
    step before ``now_s``). At the first one (the zone's start, SPEC §1: the first detector) it
    knows it is in the TASC zone and the telegram supervision starts."""
    if math.isfinite(rx[RX_FIX_POS]) and rx[RX_SINCE_FIX] > _SCALE_MIN_M and rx[RX_WSP_T] < rx[RX_FIX_T]:
        # Two transponders at known chainages: the odometer's scale over the stretch between
        # them (SPEC §2: the wheel's diameter is what the odometer gets wrong), for degraded mode;
        # not over a stretch in which the wheel-slide protection acted (SPEC §2: a slide is the
        # other thing it gets wrong, and it would not recur).
        rx[RX_ODO_SCALE] = (position_m - rx[RX_FIX_POS]) / rx[RX_SINCE_FIX]
    rx[RX_FIX_POS] = position_m
    rx[RX_FIX_T] = now_s - rp[RP_DT]
    rx[RX_SINCE_FIX] = 0.0
    if position_m >= rp[RP_ZONE_START] - 1e-9:
        rx[RX_IN_ZONE] = 1.0


@njit_inline
def receiver_supervise_1(
    rx: FloatArray, rp: FloatArray, now_s: float, odometer_m: float, speed_mps: float
) -> bool:
    """One step of the onboard supervision; True while the emergency brake is applied.

    ``odometer_m``: the distance the odometer counted in the last step; ``speed_mps``: the
    tachometer's speed (both carry the odometer's diameter error).
    """
    if math.isfinite(rx[RX_FIX_POS]):
        rx[RX_SINCE_FIX] += odometer_m
    if math.isfinite(rx[RX_TACH_PREV]):
        decel = (rx[RX_TACH_PREV] - speed_mps) / rp[RP_DT]
        rx[RX_TACH_DECEL] += rp[RP_GUARD_ALPHA] * (decel - rx[RX_TACH_DECEL])
    rx[RX_TACH_PREV] = speed_mps
    if rx[RX_EB] > 0.0:
        return True
    since = rx[RX_SINCE_FIX]
    unc = rp[RP_ODO_UNC] * abs(since) + rp[RP_POS_MARGIN]
    # No telegram yet: the clock starts once the train is surely past the detector by which the
    # wayside must have spoken (its possible odometer error counted for the wayside).
    if rx[RX_IN_ZONE] > 0.0 and rx[RX_LAST_RX] == -np.inf and rx[RX_FIX_POS] + since - unc >= rp[RP_FIRST_BY]:
        rx[RX_LAST_RX] = now_s
    if rx[RX_IN_ZONE] > 0.0 and rx[RX_LAST_RX] > -np.inf and now_s - rx[RX_LAST_RX] > rp[RP_TIMEOUT] + 1e-9:
        # DESIGN rule 10: braking telegrams stopped arriving inside the zone. [interpretation]
        # (degraded mode) A train that has had a braking command and knows its position from a
        # transponder finishes the stop on its own odometry (receiver_degraded_1), the overrun
        # guard below still watching it; one the wayside never spoke to brakes at once.
        if rx[RX_ACTIVE] > 0.0 and math.isfinite(rx[RX_FIX_POS]):
            rx[RX_DEGRADED] = 1.0
        else:
            _apply_eb_1(rx, EB_TIMEOUT, now_s)
            return True
    if math.isfinite(rx[RX_FIX_POS]):
        # The overrun guard on the train's own odometry, its possible error counted against it
        # (the train may be further on than the odometer says).
        position = rx[RX_FIX_POS] + since + unc
        if overrun_guard_1(
            speed_mps * (1.0 + rp[RP_ODO_UNC]),
            rx[RX_TACH_DECEL] * (1.0 - rp[RP_ODO_UNC]),
            rp[RP_END] - position,
            rp[RP_RESPONSE],
            min(rp[RP_GUARD_LIMIT], rx[RX_GUARD_LIMIT]),
        ):
            _apply_eb_1(rx, EB_ONBOARD_GUARD, now_s)
            return True
    return False


@njit_inline
def receiver_degraded_1(
    rx: FloatArray, rp: FloatArray, brake: BrakeCurves, approach: Approach, speed_mps: float, now_s: float
) -> None:
    """Degraded mode (the telegrams stopped after a command): the unit's own target by the
    wayside's law (SPEC §1: v² / 2s less what gradient and resistance give over the path) from
    where its odometry puts the train (the last transponder and the odometer since, at the scale
    the last two transponders gave), as the train's ATO would; the overrun guard, which counts the
    odometry's possible error against the train, brakes harder when it must."""
    scale = rx[RX_ODO_SCALE]
    left = rp[RP_STOP] - (rx[RX_FIX_POS] + scale * rx[RX_SINCE_FIX])
    v = scale * speed_mps
    if left > 0.05:
        target = clip_1(brake_need_1(approach.ext, approach.grad, left, v), 0.0, rp[RP_MAX_DECEL])
    else:
        target = rp[RP_MAX_DECEL] if v > 0.0 else 0.0
    rx[RX_TARGET] = target
    if target > 0.0:
        # A train whose only telegram said "hold" (its braking waited for a later detector,
        # control.tasc.START_FLOOR) stops holding its speed once its own plan brakes.
        rx[RX_FIRST_RX] = min(rx[RX_FIRST_RX], now_s)
    rx[RX_FIXED_NOTCH] = -1.0  # forms 7, 8: the unit's own target now, not the wayside's notch
    rx[RX_FIXED_DUTY] = np.nan
    rx[RX_ONBOARD_DUTY] = decel_to_pwm_1(target, brake.pwm_duty, brake.pwm_decel)


@njit_inline
def receiver_cycle_1(
    rx: FloatArray,
    rp: FloatArray,
    mod: FloatArray,
    tach: FloatArray,
    hist_v: FloatArray,
    hist_e: FloatArray,
    taus: FloatArray,
    brake: BrakeCurves,
    approach: Approach,
    telegram: FloatArray,
    now_s: float,
    k: int,
    new: bool,
    copy: bool,
    speed_mps: float,
    wsp: bool,
    odometer_m: float,
    own_notch: int,
    own_duty: float,
) -> tuple[int, float, bool, int]:
    """One step of the onboard unit (SPEC §1 configurations): a new telegram (``new``, in
    ``telegram``) or a copy of the one it has (``copy``, a life sign), the tachometer's speed and
    whether the wheel-slide protection acts (``wsp``) and the odometer's last step in; (notch,
    duty, emergency brake, switch position) out for the
    brake ECU. Notch -1: a PWM train (the duty holds the command); duty NaN: a step train; switch
    -1: no switching unit. The train's own command (``own_notch``, ``own_duty``) passes as its
    configuration says. The stop model and the live train run this same step."""
    rx[RX_PULSES] += odometer_m
    if copy:
        receiver_alive_1(rx, now_s)
    elif new:
        if rx[RX_STEP_LOST] == 0.0:
            rx[RX_DEGRADED] = 0.0  # the wayside speaks again: its commands rule (not after a lost step)
        receiver_receive_1(
            rx, rp, mod, tach, hist_v, hist_e, taus, brake, approach, telegram, now_s,
        )  # fmt: skip
    receiver_observe_1(rx, rp, tach, speed_mps, wsp, now_s)
    # The onboard supervision (DESIGN rule 10): telegram time-out, overrun guard.
    eb = receiver_supervise_1(rx, rp, now_s, odometer_m, speed_mps)
    if rx[RX_DEGRADED] > 0.0 and not eb:
        receiver_degraded_1(rx, rp, brake, approach, speed_mps, now_s)
    config = int(rp[RP_CONFIG])
    switch_pos = receiver_switch_1(rx, rp) if config in (CFG_STEP, CFG_SWITCHED_PWM) else -1
    if config in (CFG_PWM, CFG_SWITCHED_PWM):
        # Config 3 superimposes on the train's duty; config 2 switches between the two.
        onboard = receiver_pwm_output_1(rx, rp, k, own_duty)
        if config == CFG_PWM or switch_pos == SWITCH_ONBOARD:
            return -1, onboard, eb, switch_pos
        if switch_pos == SWITCH_TRAIN:
            return -1, own_duty, eb, switch_pos
        return -1, 0.0, eb, switch_pos  # contacts in transfer: the ECU input is open
    onboard_notch = receiver_step_output_1(rx, rp, mod, brake.table, k, speed_mps)
    if config == CFG_BRAKE_CONTROLLER:
        # Config 1: the brake controller follows the onboard unit once it has a command.
        return (onboard_notch if rx[RX_ACTIVE] > 0.0 else own_notch), np.nan, eb, switch_pos
    if switch_pos == SWITCH_ONBOARD:
        return onboard_notch, np.nan, eb, switch_pos
    if switch_pos == SWITCH_TRAIN:
        return own_notch, np.nan, eb, switch_pos
    return 0, np.nan, eb, switch_pos  # contacts in transfer: wires a, b, c open (000)
