"""The wayside signal control unit of SPEC §1, compiled, one run at a time.

Fed with wheel-sensor passages and Doppler samples, it computes at every
detector (and, with ``update = "continuous"``, every ``continuous_period_s``
between detectors) the braking deceleration required to stop at the stopping
point, and emits a braking control signal in one of the eight forms of
claim 3. Time is an argument; it draws no random numbers and does no I/O
(DESIGN rule 2). Every command and its inputs are returned for the database
(claims 8, 20) as a command record (the CR_* columns).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from railstop.control.brake_ident import MIN_STEP_MPS2, identify_response_1
from railstop.control.notch import (
    MOD_SIZE,
    modulator_aim_1,
    modulator_init_1,
    modulator_restart_1,
    modulator_update_1,
    nearest_notch_1,
)
from railstop.control.supervision import overrun_guard_1
from railstop.control.tasc import (
    MIN_WINDOW_CMD,
    REG_WEIGHTS,
    Approach,
    BrakeCurves,
    external_decel_1,
    fit_passages_1,
    fit_ring_1,
    gain_update_1,
    gain_value_1,
    guard_limit_on_path_1,
    hat_weights_1,
    history_push_1,
    history_response_at_1,
    history_value_at_1,
    interval_fit_add_1,
    interval_fit_decel_1,
    interval_fit_reset_1,
    modelled_means_1,
    plan_command_1,
    regression_taus_1,
)
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
    TEL_POSITION,
    TEL_REQUIRED,
    TEL_SPEED,
    TEL_STEP,
)
from railstop.physics.brake import decel_to_pwm_1

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


class SignalForm(IntEnum):
    """SPEC §1 claim 3: the forms the train braking control signal may take."""

    POSITION = 1
    DISTANCE = 2
    INTERVAL_TIME = 3
    SPEED = 4
    DECELERATION = 5
    REQUIRED_DECELERATION = 6
    BRAKE_COMMAND = 7
    INCREASE_DECREASE = 8


FORM_NAMES = {
    SignalForm.POSITION: "train position",
    SignalForm.DISTANCE: "distance to stopping point",
    SignalForm.INTERVAL_TIME: "time between two detectors",
    SignalForm.SPEED: "speed",
    SignalForm.DECELERATION: "deceleration",
    SignalForm.REQUIRED_DECELERATION: "required braking deceleration",
    SignalForm.BRAKE_COMMAND: "brake-system control command",
    SignalForm.INCREASE_DECREASE: "increase / decrease braking",
}


@dataclass(slots=True, kw_only=True)
class TascTelegrams:
    """Braking control signals sent this step (rows where ``mask`` is set).

    Fields not carried by the form are NaN (forms 1-5 carry measurements,
    SPEC §1: "the onboard unit computes the required deceleration itself").
    """

    form: SignalForm
    mask: BoolArray
    detector: IntArray  # index of the last detector passed (-1 none)
    passage_s: FloatArray  # time of that passage
    measured_s: FloatArray  # time the measurement refers to (= send time)
    position_m: FloatArray
    distance_m: FloatArray
    interval_s: FloatArray
    speed_mps: FloatArray
    decel_mps2: FloatArray
    required_mps2: FloatArray
    notch: IntArray
    duty: FloatArray
    delta: IntArray
    emergency: IntArray  # 1: the wayside's overrun guard fired (the emergency-stop telegram)
    step: IntArray  # form 8: the step's number modulo 256 (0 for the other forms)


def finite_or_none(x: float) -> float | None:
    """A number for a record or a message, None where it is absent (NaN) or infinite."""
    return float(x) if np.isfinite(x) else None


# --------------------------------------------------------------------------
# Compiled scalar core (railstop.jit): the wayside unit of one run.
#
# A braking telegram is a float vector (TEL_*; NaN = not carried). The
# unit's parameters are a float vector (WP_*), its state another (WS_*) plus
# a few arrays: the Doppler ring buffer, the last three passages, the
# command history, two scratch arrays of SAMPLES for the window means.

WP_FORM = 0
WP_HAS_DOPPLER = 1
WP_CONTINUOUS = 2  # update = "continuous"
WP_CONTINUOUS_PERIOD = 3
WP_DT = 4
WP_SPEED_SAMPLES = 5
WP_BASE_DELAY = 6  # assumed link latency + brake dead time + lag time constant
WP_JERK = 7
WP_MAX_DECEL = 8  # full service
WP_LAG = 9  # brake build-up time constant
WP_STOP = 10
WP_END_MARGIN = 11  # platform end beyond the stopping point (the overrun guard's end)
WP_GUARD_LIMIT = 12  # the overrun guard's deceleration limit (full service x guard fraction)
WP_MODULATE = 13  # forms 7, 8: the wayside realises its command with the notches itself
WP_MOD_CYCLE = 14  # ... every this many seconds (the train's brake controller cycle)
WP_MOD_HOLD = 15  # ... holding a notch at least this long (the train's brake controller's)
WP_STEP_SPACING = 16  # form 8: one step telegram at most this often
WP_INITIAL_DECEL = 17  # the train's own initial brake step in the zone (tasc.initial_brake_notch)
WP_INITIAL_DELAY = 18  # ... acts this long after the first detector (dead time + lag, no radio)
WP_IDENTIFY = 19  # identify the brake response online from the Doppler samples (control.brake_ident)
WP_ID_AFTER = 20  # ... this long after the first command that steps the braking enough
WP_FIT_SAMPLES = 21  # Doppler samples of the deceleration fit (the radar buffer may hold more)
WP_FILL = 22  # fill in a missed detector's passage from the Doppler-integrated travel
WP_START_FLOOR = 23  # the first braking waits while the command is under this (control.tasc)
WP_EMERGENCY = 24  # the train's nominal emergency deceleration (the database's braking data)
WP_SIZE = 25

WS_COL = 0  # newest Doppler slot
WS_DCOUNT = 1  # Doppler samples held (<= window)
WS_WIN_START = 2  # start of the measurement interval (the last command's effect time)
WS_SUMS = 3  # 5 running sums of the interval's line fit: count, Σt, Σt², Σv, Σtv
WS_PASS_COUNT = 8
WS_LAST_DET = 9
WS_LAST_PASS = 10
WS_TRAVEL = 11  # Doppler-integrated travel since the last passage
WS_GAIN_NUM = 12
WS_GAIN_DEN = 13
WS_MOD_SENT = 14  # forms 7, 8: the notch last sent (form 8: the train is believed to apply)
WS_SENT = 15
WS_FIRST_SENT = 16  # the train holds its speed until told to brake
WS_NEXT_UPDATE = 17
WS_EMERGENCY = 18  # 1 once the overrun guard fired (latched: every later telegram says so)
WS_DECEL = 19  # the deceleration measured at the last command (the overrun guard's; 0: none)
WS_TARGET = 20  # forms 7, 8: the deceleration the notches realise (the last command; NaN: none)
WS_MOD_NEXT = 21  # forms 7, 8: the next modulator cycle
WS_LAST_STEP = 22  # form 8: when the last step telegram was sent
WS_DELAY = 23  # the equivalent dead time the plan uses (WP_BASE_DELAY until identified)
WS_LAG = 24  # the build-up lag the plan uses (WP_LAG until identified)
WS_ID_AT = 25  # when the brake response is to be identified (inf: not due)
WS_ID_GAIN = 26  # the loop gain the identification found (NaN: not identified)
WS_FILLED = 27  # detector passages filled in from the Doppler (wayside_passage_1)
WS_ID_DONE = 28  # 1 once the identification ran (whatever it found)
WS_STEPS = 29  # form 8: the steps sent so far (the last one's number)
WS_GUARD_LIMIT = 30  # the overrun guard's limit for this train on this path (guard_limit_1)
WS_MOD = 31  # forms 7, 8: the wayside's notch modulator (control.notch MOD_* state)
WS_SIZE = WS_MOD + MOD_SIZE

# Command record columns (SPEC §1 claims 8, 20: every command and its inputs).
CR_T = 0
CR_DETECTOR = 1
CR_PASSAGE = 2
CR_DISTANCE = 3
CR_SPEED = 4
CR_DECEL = 5
CR_GAIN = 6
CR_REQUIRED = 7
CR_COMMAND = 8
CR_NOTCH = 9
CR_DELTA = 10
CR_EFFECT = 11
CR_EMERGENCY = 12  # 1: the overrun guard fired, the telegram is an emergency stop
CR_SIZE = 13

# The measurements forms 1-5 put on the air besides the detector and times: the combinations of
# SPEC §1 para 92 (claim 3, para 67), one row per form, columns _MEASUREMENTS; the
# railstop.link.codec layouts carry the same.
_MEASUREMENTS = np.array([TEL_POSITION, TEL_DISTANCE, TEL_INTERVAL, TEL_SPEED, TEL_DECEL, TEL_REQUIRED])
_COMBINATION_OF_FORM = np.array(
    [
        [0, 0, 0, 0, 0, 0],
        [1, 1, 1, 0, 0, 0],  # form 1: position, with distance and interval
        [1, 1, 1, 0, 0, 0],  # form 2: distance, with position and interval
        [1, 1, 1, 0, 0, 0],  # form 3: interval, with position and distance
        [0, 1, 0, 1, 0, 0],  # form 4: speed and distance
        [0, 1, 0, 0, 1, 0],  # form 5: deceleration and distance
    ]
)
_PASSAGE_FRAC = (np.arange(16) + 0.5) / 16


@njit_step
def wayside_init_1(
    ws: FloatArray,
    wp: FloatArray,
    hist_v: FloatArray,
    hist_e: FloatArray,
    pass_t: FloatArray,
    pass_x: FloatArray,
) -> None:
    ws[:] = 0.0
    ws[WS_DELAY] = wp[WP_BASE_DELAY]
    ws[WS_LAG] = wp[WP_LAG]
    ws[WS_ID_AT] = np.inf
    ws[WS_ID_GAIN] = np.nan
    ws[WS_COL] = -1.0
    ws[WS_LAST_DET] = -1.0
    ws[WS_LAST_PASS] = np.nan
    ws[WS_FIRST_SENT] = np.inf
    ws[WS_NEXT_UPDATE] = np.inf
    ws[WS_TARGET] = np.nan
    ws[WS_MOD_NEXT] = np.inf
    ws[WS_LAST_STEP] = -np.inf
    ws[WS_GUARD_LIMIT] = wp[WP_GUARD_LIMIT]
    modulator_init_1(ws[WS_MOD : WS_MOD + MOD_SIZE])
    hist_v[:] = 0.0
    hist_e[:] = np.inf
    pass_t[:] = np.nan
    pass_x[:] = np.nan


#: A missed detector's passage is filled in once the Doppler-integrated travel is this far
#: beyond it (m): well beyond a passage's report (one 10 ms step, 0.2 m at 70 km/h, plus the
#: sensor's jitter), well short of the next detector.
FILL_MARGIN_M = 0.5


@njit_inline
def wayside_passage_1(
    ws: FloatArray,
    wp: FloatArray,
    pass_x: FloatArray,
    det_pos: FloatArray,
    now_s: float,
    passed: bool,
    detector: int,
    passage_s: float,
    doppler_mps: float,
) -> tuple[bool, int, float]:
    """The detector passage the wayside unit takes this step: (passed, detector, passage time).

    Issue 13 item 6, beyond SPEC §1 (which assumes every detector reports): with a Doppler
    radar the unit knows how far the train has run since the last passage; once that is
    ``FILL_MARGIN_M`` beyond the next detector and no passage came, the detector missed the
    train, and the unit fills in its passage (the time from the travel and the speed) so the
    command of that detector is not lost. A late report of a detector already filled in is
    ignored. Without a radar, or before the first passage, nothing is filled in."""
    last = int(ws[WS_LAST_DET])
    if passed:
        return detector > last, detector, passage_s
    if wp[WP_FILL] == 0.0 or last < 0 or last + 1 >= det_pos.size or not (doppler_mps > 0.0):
        return False, detector, passage_s
    over = ws[WS_TRAVEL] - (det_pos[last + 1] - pass_x[2])
    if over < FILL_MARGIN_M:
        return False, detector, passage_s
    ws[WS_FILLED] += 1.0
    return True, last + 1, now_s - over / doppler_mps


@njit_inline
def wayside_observe_1(
    ws: FloatArray,
    wp: FloatArray,
    dbuf: FloatArray,
    pass_t: FloatArray,
    pass_x: FloatArray,
    det_pos: FloatArray,
    now_s: float,
    passed: bool,
    detector: int,
    passage_s: float,
    doppler_mps: float,
) -> bool:
    """One step of the wayside unit's measurements; True when a command is due now.

    ``doppler_mps`` is NaN when there is no sample this step. When due, the
    caller calls :func:`wayside_command_1` in the same step.
    """
    if wp[WP_HAS_DOPPLER] > 0.0 and math.isfinite(doppler_mps):
        window = dbuf.size
        col = int(ws[WS_COL]) + 1
        if col == window:
            col = 0
        ws[WS_COL] = col
        dbuf[col] = doppler_mps
        t_rel = max(now_s - ws[WS_WIN_START], -1.0)
        if t_rel >= 0.0:
            interval_fit_add_1(ws, WS_SUMS, t_rel, doppler_mps)
        ws[WS_DCOUNT] = min(ws[WS_DCOUNT] + 1.0, float(window))
        ws[WS_TRAVEL] += doppler_mps * wp[WP_DT]
    if (
        wp[WP_HAS_DOPPLER] > 0.0
        and math.isfinite(doppler_mps)
        and ws[WS_EMERGENCY] == 0.0
        and ws[WS_LAST_DET] >= 0.0
        and not passed
        and overrun_guard_1(
            doppler_mps,
            ws[WS_DECEL],
            wp[WP_STOP] + wp[WP_END_MARGIN] - pass_x[2] - ws[WS_TRAVEL],
            max(wp[WP_BASE_DELAY], ws[WS_DELAY]),
            ws[WS_GUARD_LIMIT],
        )
    ):
        # DESIGN rule 10, the wayside's overrun guard on every Doppler sample: an emergency-stop
        # telegram now (wayside_command_1 sends it).
        ws[WS_EMERGENCY] = 1.0
        return True
    if passed:
        for j in range(2):
            pass_t[j] = pass_t[j + 1]
            pass_x[j] = pass_x[j + 1]
        pass_t[2] = passage_s
        pass_x[2] = det_pos[detector]
        ws[WS_PASS_COUNT] += 1.0
        ws[WS_LAST_DET] = detector
        ws[WS_LAST_PASS] = passage_s
    # SPEC §1: control at every detector (variant 2 needs two passages for a speed).
    need = ws[WS_PASS_COUNT] >= (1.0 if wp[WP_HAS_DOPPLER] > 0.0 else 2.0)
    if passed and need:
        return True
    return wp[WP_CONTINUOUS] > 0.0 and need and now_s >= ws[WS_NEXT_UPDATE]


@njit_step
def wayside_identify_1(
    ws: FloatArray,
    wp: FloatArray,
    dbuf: FloatArray,
    hist_v: FloatArray,
    hist_e: FloatArray,
    det_to_stop: FloatArray,
    ext: FloatArray,
    grad: tuple[FloatArray, FloatArray, FloatArray],
    scratch: FloatArray,
    now_s: float,
) -> None:
    """Identify the brake response once, ``WP_ID_AFTER`` after the first braking command
    (control.brake_ident; issue 13 item 6, beyond SPEC §1), when the step was large enough to
    show it. The plan from then on uses the identified equivalent dead time and lag, and the
    effect times of the commands already sent move with it. The overrun guard keeps the larger
    of the nominal and the identified delay (an estimate never makes supervision laxer)."""
    if not (now_s >= ws[WS_ID_AT]):
        return
    ws[WS_ID_AT] = np.inf  # once: not due again
    ws[WS_ID_DONE] = 1.0
    step = 0.0
    for j in range(hist_v.size):
        if math.isfinite(hist_e[j]):
            step = max(step, hist_v[j])
    if step < MIN_STEP_MPS2:
        return
    newest = int(ws[WS_COL])
    speed = dbuf[newest]
    distance = det_to_stop[int(ws[WS_LAST_DET])] - ws[WS_TRAVEL]
    delay, lag, gain = identify_response_1(
        dbuf,
        newest,
        int(ws[WS_DCOUNT]),
        wp[WP_DT],
        now_s,
        ws[WS_FIRST_SENT],
        external_decel_1(ext, grad, distance, speed),
        hist_v,
        hist_e,
        ws[WS_DELAY],
        wp[WP_BASE_DELAY],
        wp[WP_LAG],
        scratch,
    )
    if not math.isfinite(delay):
        return
    shift = delay - ws[WS_DELAY]
    for j in range(hist_e.size):
        if math.isfinite(hist_e[j]):
            hist_e[j] += shift
    ws[WS_DELAY] = delay
    ws[WS_LAG] = lag
    ws[WS_ID_GAIN] = gain


@njit_step
def _passages_fit_1(
    pass_t: FloatArray,
    pass_x: FloatArray,
    hist_v: FloatArray,
    hist_e: FloatArray,
    lag_s: float,
    gain: float,
    braking_from_s: float,
    stop_m: float,
    ext: FloatArray,
    grad: tuple[FloatArray, FloatArray, FloatArray],
) -> tuple[float, float]:
    """SPEC §1 variant 2, three passages: (speed at the newest, deceleration the model misses).

    The train's deceleration over the last three passages is modelled as the brake's modelled
    response to the commands (times the loop gain) plus gradient and resistance where the
    database puts them, plus one unknown constant ``delta`` (an unsurveyed gradient, a brake
    that is not the model's). The two intervals give two equations in the speed at the newest
    passage and ``delta``:  x2 - xi = v2 (t2 - ti) + ∫_{ti}^{t2} (τ - ti) a(τ) dτ  (i = 0, 1).
    Correcting one interval's mean speed with the model alone (the speed estimate before)
    carries the model's error times half the interval into the speed: at 1 m/s over a 14 s
    interval, 0.04 m/s² of unknown gradient is 0.28 m/s, a stop metres short.
    [interpretation] SPEC §1 gives speed and deceleration from passage times and leaves the
    estimator open; this one is exact for any constant error of the model.
    """
    t0, t1, t2 = pass_t[0], pass_t[1], pass_t[2]
    # Where the train was between the passages: the parabola through them.
    v_q, a_q = fit_passages_1(pass_t, pass_x, 3)
    n = _PASSAGE_FRAC.size
    i1 = 0.0  # ∫_{t1}^{t2} (τ - t1) a dτ
    s_b = 0.0  # ∫_{t1}^{t2} a dτ
    a01 = 0.0  # ∫_{t0}^{t1} (τ - t0) a dτ
    for seg in range(2):
        lo = t0 if seg == 0 else t1
        width = (t1 - t0) if seg == 0 else (t2 - t1)
        for j in range(n):
            tau = lo + width * _PASSAGE_FRAC[j]
            a_model = gain * history_response_at_1(hist_v, hist_e, tau, lag_s)
            if tau >= braking_from_s:
                back = t2 - tau
                x_then = pass_x[2] - v_q * back - 0.5 * a_q * back * back
                a_model += external_decel_1(ext, grad, stop_m - x_then, v_q + a_q * back)
            w = width / n
            if seg == 0:
                a01 += (tau - t0) * a_model * w
            else:
                i1 += (tau - t1) * a_model * w
                s_b += a_model * w
    i0 = a01 + i1 + (t1 - t0) * s_b
    d0 = t2 - t0
    d1 = t2 - t1
    r0 = pass_x[2] - pass_x[0] - i0
    r1 = pass_x[2] - pass_x[1] - i1
    det = 0.5 * d0 * d1 * (d1 - d0)
    v2 = (0.5 * r0 * d1 * d1 - 0.5 * r1 * d0 * d0) / det
    delta = (d0 * r1 - d1 * r0) / det
    return v2, delta


@njit_step
def _wayside_measure_1(
    ws: FloatArray,
    wp: FloatArray,
    dbuf: FloatArray,
    pass_t: FloatArray,
    pass_x: FloatArray,
    hist_v: FloatArray,
    hist_e: FloatArray,
    taus: FloatArray,
    weights: FloatArray,
    det_to_stop: FloatArray,
    ext: FloatArray,
    grad: tuple[FloatArray, FloatArray, FloatArray],
    now_s: float,
    new_passage: bool,
) -> tuple[float, float, float, float, float]:
    """Speed now, measured decel, distance to go, and the window's modelled means (commanded
    brake decel, external decel while braking) the measured deceleration is compared with."""
    dt = wp[WP_DT]
    last_det = int(ws[WS_LAST_DET])
    if wp[WP_HAS_DOPPLER] > 0.0:
        count = min(int(ws[WS_DCOUNT]), int(wp[WP_FIT_SAMPLES]))
        speed, decel = fit_ring_1(dbuf, int(ws[WS_COL]), count, dt, int(wp[WP_SPEED_SAMPLES]))
        # Prefer the interval since the last command took effect when it is longer: the
        # deceleration over the whole interval between commands (a brake controller
        # alternating two notches matches the target only on average over its alternation).
        c, interval_decel = interval_fit_decel_1(ws, WS_SUMS)
        if c > count:
            decel = interval_decel
            count = c
        if new_passage:  # at a passage, the travel since it is reconstructed from the fit
            since = now_s - ws[WS_LAST_PASS]
            ws[WS_TRAVEL] = speed * since + 0.5 * decel * since * since
        distance = det_to_stop[last_det] - ws[WS_TRAVEL]
        regression_taus_1(now_s - (count - 1) * dt, now_s, taus)
        cmd_mean, ext_mean = modelled_means_1(
            hist_v,
            hist_e,
            taus,
            REG_WEIGHTS,
            ws[WS_FIRST_SENT],
            ws[WS_LAG],
            ext,
            grad,
            distance,
            speed,
            decel,
            now_s,
        )
        return speed, decel, distance, cmd_mean, ext_mean
    # SPEC §1 variant 2: passage times only. The mean speed over the last
    # interval is corrected to the newest passage with the modelled
    # deceleration; three passages measure the (hat-weighted) deceleration.
    gain = gain_value_1(ws[WS_GAIN_NUM], ws[WS_GAIN_DEN])
    t1 = pass_t[1]
    t2 = pass_t[2]
    first = ws[WS_FIRST_SENT]
    v_mean = (pass_x[2] - pass_x[1]) / (t2 - t1)
    ext_v = external_decel_1(ext, grad, det_to_stop[last_det], v_mean)
    # v(t2) = mean speed - (1/Δ) ∫_{t1}^{t2} (τ - t1) a(τ) dτ
    acc = 0.0
    for j in range(16):
        tau = t1 + (t2 - t1) * _PASSAGE_FRAC[j]
        a_model = gain * history_value_at_1(hist_v, hist_e, tau) + (ext_v if tau >= first else 0.0)
        acc += a_model * _PASSAGE_FRAC[j]
    v_p = v_mean - (t2 - t1) * (acc / 16.0)
    a_now = gain * history_value_at_1(hist_v, hist_e, now_s) + (ext_v if now_s >= first else 0.0)
    since = now_s - t2
    speed = v_p - a_now * since
    distance = det_to_stop[last_det] - (v_p * since - 0.5 * a_now * since**2)
    decel = np.nan
    cmd_mean = 0.0
    ext_mean = 0.0
    count = int(ws[WS_PASS_COUNT])
    if count >= 3:
        v_fit, delta = _passages_fit_1(
            pass_t, pass_x, hist_v, hist_e, ws[WS_LAG], gain, first, wp[WP_STOP], ext, grad
        )
        if math.isfinite(v_fit) and math.isfinite(delta):  # else the one-interval estimate above
            a_now += delta
            speed = v_fit - a_now * since
            distance = det_to_stop[last_det] - (v_fit * since - 0.5 * a_now * since**2)
        _, decel = fit_passages_1(pass_t, pass_x, count)
        hat_weights_1(pass_t[0], t1, t2, taus, weights)
        cmd_mean, ext_mean = modelled_means_1(
            hist_v, hist_e, taus, weights, first, ws[WS_LAG], ext, grad, distance, speed, decel, now_s
        )
    return speed, decel, distance, cmd_mean, ext_mean


@njit_inline
def _modulator_cycle_1(
    ws: FloatArray, wp: FloatArray, table: FloatArray, speed_mps: float, left_m: float, external_mps2: float
) -> int:
    """Forms 7, 8: one cycle of the wayside's notch modulator on its target (``speed_mps`` NaN: no
    speed, the end phase is not planned), timed as the train's brake controller would be.
    Stop model 23 (SPEC §1 claim 3, forms 7 and 8; **[interpretation]**: SPEC §1 leaves the
    wayside's notch modulation to us): with a Doppler radar the end phase aims at the stopping
    point, ``left_m`` ahead as the radar's travel since the last detector puts it, with the
    external deceleration ``external_mps2`` there and the loop gain
    (control.notch.modulator_aim_1); without one, where the target would stop the train (the
    passages alone give no distance between them)."""
    has_speed = math.isfinite(speed_mps)
    mod = ws[WS_MOD : WS_MOD + MOD_SIZE]
    if wp[WP_HAS_DOPPLER] > 0.0 and has_speed and math.isfinite(left_m):
        modulator_aim_1(mod, left_m, external_mps2, gain_value_1(ws[WS_GAIN_NUM], ws[WS_GAIN_DEN]))
    else:
        modulator_aim_1(mod, np.nan, 0.0, 1.0)
    return modulator_update_1(
        mod,
        table,
        wp[WP_MOD_HOLD],
        ws[WS_DELAY] - ws[WS_LAG],  # radio and dead time: the equivalent dead time less the lag
        ws[WS_LAG],
        ws[WS_TARGET],
        True,
        wp[WP_MOD_CYCLE],
        speed_mps if has_speed else 0.0,
        has_speed,
        wp[WP_JERK] if int(wp[WP_FORM]) == 8 else 0.0,
    )


@njit_inline
def _modulated_notch_1(ws: FloatArray, wp: FloatArray, notch: int, now_s: float) -> tuple[int, int]:
    """Forms 7, 8: the notch to send for the modulator's ``notch``, and form 8's step (+1, -1, 0):
    one notch per telegram from the notch the train is believed to apply.

    A step must reach the train: the link carries only the wayside's latest telegram, so a step
    sent before the previous one was delivered would replace it and the train would be a notch
    off for the rest of the stop. Steps are therefore at least ``WP_STEP_SPACING`` apart (the
    brake controller's minimum hold: with the cyclic repeat every 0.1 s, three transmissions of
    each step, all delivered before the next on a link faster than 0.1 s). On a slower link a
    step can still be replaced; spacing by the maximum telegram age (0.5 s) would exclude that
    but made the stops coarser (measured: 210 of 256 forms benchmark stops in band against 229).
    [interpretation] SPEC §1 gives form 8 no protocol."""
    sent = int(ws[WS_MOD_SENT])
    delta = 0
    if int(wp[WP_FORM]) == 8:
        if now_s + 1e-9 >= ws[WS_LAST_STEP] + wp[WP_STEP_SPACING]:
            delta = 1 if notch > sent else (-1 if notch < sent else 0)
        notch = sent + delta
        if delta != 0:
            ws[WS_LAST_STEP] = now_s
            ws[WS_STEPS] += 1.0
    ws[WS_MOD_SENT] = notch
    return notch, delta


@njit_inline
def wayside_modulate_1(
    ws: FloatArray,
    wp: FloatArray,
    table: FloatArray,
    approach: Approach,
    pass_x: FloatArray,
    now_s: float,
    doppler_mps: float,
    tele: FloatArray,
    record: FloatArray,
) -> bool:
    """Forms 7, 8 between commands: one cycle of the wayside's modulator when one is due; True when
    its notch changed, with the new telegram in ``tele`` (the last command's, with the new notch or
    step) and its record in ``record``. Time-driven, so it runs without a Doppler radar too (the
    end phase then has no speed)."""
    if wp[WP_MODULATE] == 0.0 or ws[WS_EMERGENCY] > 0.0 or not math.isfinite(ws[WS_TARGET]):
        return False
    if now_s + 1e-9 < ws[WS_MOD_NEXT]:
        return False
    ws[WS_MOD_NEXT] += wp[WP_MOD_CYCLE]
    left = np.nan
    ext = 0.0
    if ws[WS_LAST_DET] >= 0.0 and math.isfinite(doppler_mps):
        # The stopping point from the last detector's chainage and the radar's travel since.
        left = wp[WP_STOP] - pass_x[2] - ws[WS_TRAVEL]
        ext = external_decel_1(approach.ext, approach.grad, left, doppler_mps)
    cycle = _modulator_cycle_1(ws, wp, table, doppler_mps, left, ext)
    notch, delta = _modulated_notch_1(ws, wp, cycle, now_s)
    if delta == 0 and (int(wp[WP_FORM]) == 8 or notch == int(tele[TEL_NOTCH])):
        return False
    ws[WS_SENT] += 1.0
    tele[TEL_MEASURED] = now_s
    tele[TEL_NOTCH] = notch
    tele[TEL_DELTA] = delta
    tele[TEL_STEP] = ws[WS_STEPS] % 256.0
    record[CR_T] = now_s
    record[CR_NOTCH] = notch
    record[CR_DELTA] = delta
    return True


@njit_inline
def _initial_brake_step_1(
    ws: FloatArray,
    wp: FloatArray,
    pass_t: FloatArray,
    pass_x: FloatArray,
    hist_v: FloatArray,
    hist_e: FloatArray,
    det_to_stop: FloatArray,
) -> None:
    """The train's own initial brake step from the zone's first transponder, at the first
    detector (tasc.initial_brake_notch): the wayside's database knows it, so its model of the
    train brakes from that passage on instead of holding the speed. [interpretation] Configs 1
    and 2 replace it with the first command, as the model's history does. Once, into the empty
    history (a form-8 command that changes no notch is planned, not sent)."""
    if wp[WP_INITIAL_DECEL] > 0.0 and not math.isfinite(hist_e[0]):
        first_x = wp[WP_STOP] - det_to_stop[0]
        for j in range(3):
            if pass_x[j] == first_x and math.isfinite(pass_t[j]):
                history_push_1(hist_v, hist_e, wp[WP_INITIAL_DECEL], pass_t[j] + wp[WP_INITIAL_DELAY])
                ws[WS_FIRST_SENT] = min(ws[WS_FIRST_SENT], pass_t[j])


@njit_inline
def _telegram_and_record_1(
    ws: FloatArray,
    wp: FloatArray,
    brake: BrakeCurves,
    tele: FloatArray,
    record: FloatArray,
    now_s: float,
    distance: float,
    interval: float,
    speed: float,
    decel: float,
    gain: float,
    a_true: float,
    command: float,
    notch: int,
    delta: int,
    effect: float,
) -> None:
    """The command's telegram (TEL_*: in form 1-5 only what the form's combination carries, SPEC §1
    para 92) into ``tele`` and its record (CR_*: SPEC §1 claims 8, 20) into ``record``."""
    form = int(wp[WP_FORM])
    last_det = ws[WS_LAST_DET]
    tele[TEL_DETECTOR] = last_det
    tele[TEL_PASSAGE] = ws[WS_LAST_PASS]
    tele[TEL_MEASURED] = now_s
    tele[TEL_POSITION] = wp[WP_STOP] - distance
    tele[TEL_DISTANCE] = distance
    tele[TEL_INTERVAL] = interval
    tele[TEL_SPEED] = speed
    tele[TEL_DECEL] = decel
    tele[TEL_REQUIRED] = command
    tele[TEL_NOTCH] = notch
    tele[TEL_DUTY] = decel_to_pwm_1(command, brake.pwm_duty, brake.pwm_decel)
    tele[TEL_DELTA] = delta
    tele[TEL_STEP] = ws[WS_STEPS] % 256.0
    tele[TEL_EMERGENCY] = ws[WS_EMERGENCY]
    if form <= 5:  # forms 1-5 carry measurements only, in para 92's combinations (SPEC §1)
        for m in range(_MEASUREMENTS.size):
            if _COMBINATION_OF_FORM[form, m] == 0:
                tele[_MEASUREMENTS[m]] = np.nan
    record[CR_T] = now_s
    record[CR_DETECTOR] = last_det
    record[CR_PASSAGE] = ws[WS_LAST_PASS]
    record[CR_DISTANCE] = distance
    record[CR_SPEED] = speed
    record[CR_DECEL] = decel
    record[CR_GAIN] = gain
    record[CR_REQUIRED] = a_true
    record[CR_COMMAND] = command
    record[CR_NOTCH] = notch
    record[CR_DELTA] = delta
    record[CR_EFFECT] = effect
    record[CR_EMERGENCY] = ws[WS_EMERGENCY]


@njit_step
def wayside_command_1(
    ws: FloatArray,
    wp: FloatArray,
    dbuf: FloatArray,
    pass_t: FloatArray,
    pass_x: FloatArray,
    hist_v: FloatArray,
    hist_e: FloatArray,
    taus: FloatArray,
    weights: FloatArray,
    brake: BrakeCurves,
    approach: Approach,
    now_s: float,
    new_passage: bool,
    tele: FloatArray,
    record: FloatArray,
) -> bool:
    """The command due now: measure, close the loop, plan; the telegram into ``tele``, its
    record (CR_*: SPEC §1 claims 8, 20) into ``record``; True when the telegram is to be sent."""
    table = brake.table
    det_to_stop, ext, grad = approach.det_to_stop, approach.ext, approach.grad
    _initial_brake_step_1(ws, wp, pass_t, pass_x, hist_v, hist_e, det_to_stop)
    speed, decel, distance, cmd_mean, ext_mean = _wayside_measure_1(
        ws,
        wp,
        dbuf,
        pass_t,
        pass_x,
        hist_v,
        hist_e,
        taus,
        weights,
        det_to_stop,
        ext,
        grad,
        now_s,
        new_passage,
    )
    interval = pass_t[2] - pass_t[1]
    ws[WS_DECEL] = decel if math.isfinite(decel) else 0.0
    # Stop model 18: the guard's limit as this train's emergency brake keeps it on the path left,
    # with the loop gain so far.
    ws[WS_GUARD_LIMIT] = guard_limit_on_path_1(
        wp[WP_GUARD_LIMIT], wp[WP_EMERGENCY], gain_value_1(ws[WS_GAIN_NUM], ws[WS_GAIN_DEN]), ext, grad,
        distance, wp[WP_END_MARGIN],
    )  # fmt: skip
    if ws[WS_EMERGENCY] == 0.0 and overrun_guard_1(
        speed,
        ws[WS_DECEL],
        distance + wp[WP_END_MARGIN],
        max(wp[WP_BASE_DELAY], ws[WS_DELAY]),
        ws[WS_GUARD_LIMIT],
    ):
        ws[WS_EMERGENCY] = 1.0  # DESIGN rule 10: the overrun guard at a command (both variants)
    # Loop closure (SPEC §1 claims 2, 19) and the next command.
    num, den = ws[WS_GAIN_NUM], ws[WS_GAIN_DEN]
    if wp[WP_HAS_DOPPLER] == 0.0 and cmd_mean >= MIN_WINDOW_CMD:
        # SPEC §1 variant 2: a window is a whole span of three passages, measured to a few
        # mm/s² (passage times to the ms), and the train's braking after the last passage is
        # the newest window's, not the average since the zone's entry (whose gradient the
        # platform does not share): the gain is the newest window's. [interpretation]
        num, den = 0.0, 0.0
    num, den = gain_update_1(num, den, decel, cmd_mean, ext_mean)
    ws[WS_GAIN_NUM] = num
    ws[WS_GAIN_DEN] = den
    gain = gain_value_1(num, den)
    command, a_true, effect = plan_command_1(
        distance,
        speed,
        now_s,
        hist_v,
        hist_e,
        gain,
        ws[WS_DELAY],
        wp[WP_JERK],
        wp[WP_MAX_DECEL],
        ext,
        grad,
        det_to_stop,
        wp[WP_START_FLOOR],
    )
    form = int(wp[WP_FORM])
    notch = nearest_notch_1(command, table)
    delta = 0
    if wp[WP_MODULATE] > 0.0:
        # Forms 7 and 8 leave the train nothing to compute (SPEC §1 claim 3: a brake-system
        # command; increase / decrease the current braking, paras 93-94), so the wayside realises
        # its continuous command with the notches itself, as a brake controller would: the same
        # modulator (control.notch), run on the wayside's clock against the brake's response
        # including the radio latency, one new telegram whenever its notch changes
        # (wayside_modulate_1). Form 8 moves the train one notch per telegram.
        # [interpretation] SPEC §1 names the forms only; a notch command held from one detector
        # to the next cannot stop a train within a notch's worth of deceleration.
        ws[WS_TARGET] = command
        modulator_restart_1(ws[WS_MOD : WS_MOD + MOD_SIZE])
        ws[WS_MOD_NEXT] = now_s + wp[WP_MOD_CYCLE]
        ext_now = external_decel_1(ext, grad, distance, speed)
        cycle = _modulator_cycle_1(ws, wp, table, speed, distance, ext_now)
        notch, delta = _modulated_notch_1(ws, wp, cycle, now_s)
    if form >= 6 or wp[WP_HAS_DOPPLER] == 0.0:
        # Forms 1-5: the train computes its own command from the measurements. Without a radar
        # the wayside's speed at a passage rests on its model of the braking since the passage
        # before last (_passages_fit_1), so it models the train as braking by the command the
        # same law gives on the same measurements (the onboard unit's differs by its own loop
        # gain, which the fit's constant term takes up). [interpretation] With a radar it
        # measures the speed and models nothing.
        history_push_1(hist_v, hist_e, command, effect)
    # Form 8 says only "more" or "less": a command that changes no notch is not sent (the cyclic
    # repeat of the last telegram keeps the train's supervision alive), except the stop's first,
    # which tells the train that the wayside has it when its braking waits for a later detector
    # (control.tasc.START_FLOOR): without it the train's supervision would time out.
    send = form != 8 or delta != 0 or ws[WS_EMERGENCY] > 0.0 or ws[WS_SENT] == 0.0
    if send:
        ws[WS_SENT] += 1.0
    if command > 0.0:  # the train holds its speed (its own traction control) until told to brake
        ws[WS_FIRST_SENT] = min(ws[WS_FIRST_SENT], now_s)
    if (
        wp[WP_IDENTIFY] > 0.0
        and ws[WS_ID_DONE] == 0.0
        and ws[WS_ID_AT] == np.inf
        and abs(command - history_value_at_1(hist_v, hist_e, now_s)) >= MIN_STEP_MPS2
    ):
        # The first command that steps the braking enough to show the response: identify it
        # once its build-up is in the radar's buffer (wayside_identify_1).
        ws[WS_ID_AT] = now_s + wp[WP_ID_AFTER]
    # The next measurement interval starts when this command takes effect.
    ws[WS_WIN_START] = effect
    interval_fit_reset_1(ws, WS_SUMS)
    if wp[WP_CONTINUOUS] > 0.0:
        ws[WS_NEXT_UPDATE] = now_s + wp[WP_CONTINUOUS_PERIOD]
    _telegram_and_record_1(
        ws, wp, brake, tele, record, now_s, distance, interval, speed, decel, gain, a_true, command,
        notch, delta, effect,
    )  # fmt: skip
    return send


@njit_inline
def wayside_step_1(
    ws: FloatArray,
    wp: FloatArray,
    dbuf: FloatArray,
    pass_t: FloatArray,
    pass_x: FloatArray,
    det_pos: FloatArray,
    hist_v: FloatArray,
    hist_e: FloatArray,
    taus: FloatArray,
    weights: FloatArray,
    brake: BrakeCurves,
    approach: Approach,
    now_s: float,
    passed: bool,
    detector: int,
    passage_s: float,
    doppler_mps: float,
    tele: FloatArray,
    record: FloatArray,
) -> bool:
    """One step of the wayside TASC unit (SPEC §1): the detectors' report of this step
    (``passed``, ``detector``, ``passage_s``) and the radar's sample in, True when a telegram is
    due (in ``tele``, its record in ``record``). The stop model and the live station run this
    same step; only what carries the sensors and the telegram differs."""
    w_passed, w_det, w_pass_s = wayside_passage_1(
        ws, wp, pass_x, det_pos, now_s, passed, detector, passage_s, doppler_mps
    )
    due = wayside_observe_1(
        ws, wp, dbuf, pass_t, pass_x, det_pos, now_s, w_passed, w_det, w_pass_s, doppler_mps
    )
    if now_s >= ws[WS_ID_AT]:  # the brake response, once after the first braking command
        a = approach
        wayside_identify_1(ws, wp, dbuf, hist_v, hist_e, a.det_to_stop, a.ext, a.grad, taus, now_s)
    if due:
        return wayside_command_1(
            ws,
            wp,
            dbuf,
            pass_t,
            pass_x,
            hist_v,
            hist_e,
            taus,
            weights,
            brake,
            approach,
            now_s,
            w_passed,
            tele,
            record,
        )
    # Forms 7, 8: the wayside's own notch modulation between commands.
    return wayside_modulate_1(ws, wp, brake.table, approach, pass_x, now_s, doppler_mps, tele, record)
