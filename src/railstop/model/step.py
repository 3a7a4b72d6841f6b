"""The station stop, one 10 ms step at a time: ``stop_init``, ``stop_step``, ``stop_finish`` (DESIGN rule 2).

A run is ``stop_init`` (the train at the start of its approach, every unit
reset), then ``stop_step`` until the train stands or the time is up, then
``stop_finish`` (a driver's corrections at the stand, the run's results);
:func:`railstop.model.run.simulate_run` is that loop. Each function takes the
records of :mod:`railstop.model.records` (parameters, the run's parameters,
state, outputs) and nothing else, so a replay or a live process can drive
the same step.

One step at time t:
    sensors (Doppler sample at t; passages found during the last step)
    -> wayside TASC unit -> link (loss, corruption, delay, staleness)
    -> onboard receiver (or the onboard ATO, or the driver) -> brake signal
    -> ECU (load compensation) -> actuator (dead time, jerk limit, lag)
    -> train dynamics t -> t + dt -> wheel sensors (and odometer,
    transponders, track circuits) -> recording.

Every random number is drawn from the counter-based streams of
``railstop.streams`` (the same numbers as the array methods): a run's
result does not depend on the block it is simulated in.

The step's parts are compiled inline into it (``njit_inline``), and the step
into the run loop: every function on that path is compiled without
reference counting, so taking an array out of a record costs nothing.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from railstop.control.law import reset_law_1
from railstop.control.supervision import EB_CBTC
from railstop.control.tasc import Approach, BrakeCurves
from railstop.jit import ceil_1, njit_inline, njit_step, rint_1
from railstop.messages import (
    TEL_DELTA,
    TEL_DETECTOR,
    TEL_EMERGENCY,
    TEL_MEASURED,
    TEL_NOTCH,
    TEL_PASSAGE,
    TEL_SIZE,
    TEL_SPEED,
    TEL_STEP,
)
from railstop.model.fixes import FixesData, FixesRun, fixes_init_run, fixes_step_run
from railstop.model.records import (
    CTRL_ATO,
    CTRL_ATO_CORRECTED,
    CTRL_DRIVER_ATS,
    FP_DELAY_MEAN,
    FP_DELAY_PRIOR_VAR,
    FP_DELAY_SPREAD,
    FP_DRIVER_FIXES,
    FP_FIX_VAR,
    FP_GATE_SIGMA2,
    FP_GNSS_COUNTS,
    FP_LEARN,
    FP_MAX_EXTRAPOLATION,
    FP_SCALE_PRIOR_VAR,
    K_CORRUPT,
    K_CYCLE,
    K_DOPPLER,
    K_DRIVER,
    K_FAULTS,
    K_JITTER,
    K_LATENCY,
    K_LOSS,
    K_MISS,
    K_STOP_SENSORS,
    K_TC_BOUNDARY,
    K_TC_DELAY,
    KP_AIRTIME,
    KP_APPROACH_LIMIT,
    KP_ATC,
    KP_ATC_MARGIN,
    KP_CONTROLLER,
    KP_CRUSH,
    KP_CYCLE,
    KP_DAVIS_A,
    KP_DAVIS_B,
    KP_DAVIS_C,
    KP_DOPPLER_RANGE,
    KP_DOPPLER_REACH,
    KP_DT,
    KP_EMERGENCY,
    KP_FRAME_BITS,
    KP_GRACE,
    KP_HAS_DOPPLER,
    KP_HOME,
    KP_INCAPACITATED,
    KP_INITIAL_NOTCH,
    KP_JERK,
    KP_LENGTH,
    KP_MAX_AGE,
    KP_PASS,
    KP_QUANT_AGE,
    KP_REORDER_DELAY,
    KP_REPEAT,
    KP_ROTATING,
    KP_S1,
    KP_S2,
    KP_SENSOR_NOISE,
    KP_SLIDE_SLIP,
    KP_START_BEFORE_HOME,
    KP_STOP,
    KP_TARE,
    LA_ARRIVAL,
    LA_CORRUPT,
    LA_FLIP,
    LA_LOST,
    LA_STALE,
    LA_STEP,
    LAMP_F,
    LAMP_R,
    RC_ATTEMPTS,
    RC_COMMANDS,
    RC_DELIVERIES,
    RC_STEPS,
    RES_EB,
    RES_EB_T,
    RES_ERROR,
    RES_FILLED,
    RES_FIRST_ERROR,
    RES_ID_DELAY,
    RES_ID_LAG,
    RES_LAMP,
    RES_LEVEL,
    RES_LOSS_TRIALS,
    RES_LOSSES,
    RES_MAX_JERK,
    RES_MISS_TRIALS,
    RES_MISSES,
    RES_NOTCH_CHANGES,
    RES_RECEIVED,
    RES_RESTOPS,
    RES_SENT,
    RES_SLID,
    RES_STOP_TIME,
    RES_STOPPED,
    SC_BER,
    SC_BRAKE_GAIN,
    SC_BURST_ENTER,
    SC_BURST_EXIT,
    SC_BURST_LOSS,
    SC_DEAD_TIME,
    SC_DOPPLER_NOISE,
    SC_ENTRY_SPEED,
    SC_JITTER,
    SC_LATENCY,
    SC_LOAD,
    SC_LOSS,
    SC_LOW_END,
    SC_LOW_MU,
    SC_LOW_START,
    SC_MISS,
    SC_MU,
    SC_ODO_ERROR,
    SC_OUTAGE_LEN,
    SC_OUTAGE_START,
    SC_REORDER,
    SC_SENSOR_JITTER,
    SC_TAU,
    SC_WEIGHING_ERROR,
    SC_WHEEL_D,
    TR_ACCEL,
    TR_ACTION,
    TR_BRAKE,
    TR_DEMAND,
    TR_DUTY,
    TR_LAMP,
    TR_LIMIT,
    TR_NOTCH,
    TR_OWN,
    TR_SIZE,
    TR_SLIDE,
    TR_SUPERVISION,
    TR_SWITCH,
    TR_T,
    TR_TARGET,
    TR_V,
    TR_X,
    FloatArray,
    RunParams,
    StopOutputs,
    StopParams,
    StopState,
    UintArray,
)
from railstop.onboard.ato import (
    AT_ACTIVE,
    AT_BRAKING,
    AT_TARGET,
    ato_fix_1,
    ato_init_1,
    ato_odometer_1,
    ato_output_1,
)
from railstop.onboard.driver import (
    ACT_CREEP_FORWARD,
    ACT_DONE,
    ACT_REVERSE,
    ACT_WAIT,
    DR_LEVEL,
    DR_MARGIN,
    DR_REACTION,
    DV_ACTION,
    DV_REQUIRED,
    RS_EB_RESET,
    RS_MAX,
    RS_POWER_ACCEL,
    RS_REVERSE_SETUP,
    creep_position_1,
    creep_time_1,
    driver_draw_1,
    driver_init_1,
    driver_look_1,
    driver_output_1,
    move_speed_1,
    restop_judgement_1,
)
from railstop.onboard.speed_supervision import SV_ALARM, SV_EB, supervise_1, supervision_init_1
from railstop.onboard.tasc_receiver import (
    CFG_PWM,
    CFG_SWITCHED_PWM,
    RP_CONFIG,
    RX_ACTIVE,
    RX_EB,
    RX_EB_T,
    RX_FIRST_RX,
    RX_RECEIVED,
    RX_TARGET,
    receiver_cycle_1,
    receiver_fix_1,
    receiver_init_1,
)
from railstop.physics.brake import actuator_step_1, decel_to_pwm_1, line_notch, pwm_to_decel_1
from railstop.physics.train import adhesion_limit_1, creep_1, mean_gradient_1, motion_step_1
from railstop.sensors.wayside import crossing_time_1, passage_1
from railstop.stream_cores import key_normal, key_normal_zig, key_uniform, stream_key
from railstop.wayside.tasc_unit import (
    CR_SIZE,
    WP_FORM,
    WP_INITIAL_DELAY,
    WS_DELAY,
    WS_FILLED,
    WS_ID_GAIN,
    WS_LAG,
    WS_SENT,
    wayside_init_1,
    wayside_step_1,
)


@njit_step
def quantize_telegram_1(
    tele: np.ndarray, out: np.ndarray, quant: np.ndarray, carried: np.ndarray, form: int, quant_age: float
) -> None:
    """What the train can receive: carried fields at the codec's resolution, the rest NaN (0 for
    the notch and delta); form 4 carries the passage as its age at the measurement time. An
    emergency-stop telegram carries the detector and its flag only."""
    if tele[TEL_EMERGENCY] > 0.0:
        for j in range(TEL_SIZE):
            out[j] = np.nan
        out[TEL_DETECTOR] = tele[TEL_DETECTOR]
        out[TEL_NOTCH] = 0.0
        out[TEL_DELTA] = 0.0
        out[TEL_STEP] = 0.0
        out[TEL_EMERGENCY] = 1.0
        return
    for j in range(TEL_SIZE):
        if j == TEL_DETECTOR:
            out[j] = tele[j]
        elif j == TEL_EMERGENCY:
            out[j] = 0.0
        elif j in (TEL_NOTCH, TEL_DELTA, TEL_STEP):
            out[j] = tele[j] if carried[j] > 0 else 0.0
        elif carried[j] == 0:
            out[j] = np.nan
        elif quant[j] > 0.0:
            out[j] = rint_1(tele[j] * quant[j]) / quant[j]
        else:
            out[j] = tele[j]
    if form == 4:
        measured = rint_1(tele[TEL_MEASURED] * quant[TEL_MEASURED]) / quant[TEL_MEASURED]
        # [interpretation] The passage is never after the measurement that reports it: the step's
        # passage is time-stamped within the step (and the sensor's jitter) while the wayside
        # computes at the step's start; the codec's age field is unsigned (tasc_link agrees).
        age = max(0.0, rint_1((tele[TEL_MEASURED] - tele[TEL_PASSAGE]) * quant_age) / quant_age)
        out[TEL_MEASURED] = measured
        out[TEL_SPEED] = rint_1(tele[TEL_SPEED] * quant[TEL_SPEED]) / quant[TEL_SPEED]
        out[TEL_PASSAGE] = measured - age


@njit_inline
def own_command_1(
    notch: int, pwm_train: bool, table: FloatArray, pwm_duty: FloatArray, pwm_decel: FloatArray
) -> tuple[float, float]:
    """The train's own brake command (SPEC §1; tasc.initial_brake_notch) as (duty, deceleration
    demanded): a step, or on a PWM train that step's deceleration as a duty (NaN on a step train).
    It changes only at the zone's transponders and at the hand-over, so it is computed when it
    changes, not every step.

    [interpretation] A PWM brake line in service always carries its carrier: released, the duty
    is the top of the range that brakes nothing (10 % on the embedded EMU), never 0 % (a dead
    line). Configuration 3's zero-crossing detector locks to that carrier (SPEC §1 claims 15, 25)."""
    if pwm_train:
        if notch == 0:
            duty = 0.0
            for j in range(pwm_duty.size):
                if pwm_decel[j] <= 0.0:
                    duty = pwm_duty[j]
                else:
                    break
        else:
            duty = decel_to_pwm_1(table[notch], pwm_duty, pwm_decel)
        return duty, pwm_to_decel_1(duty, pwm_duty, pwm_decel)
    return np.nan, table[line_notch(notch)]


@njit_inline
def _stand_lamp_1(x: float, kp: np.ndarray, lamp_table: np.ndarray, key: np.uint64, stand: int) -> int:
    """SPEC §3: the lamp for a train front at rest at ``x``: S2 and S1 (sensors.stop_sensors)
    each see the front, off by the sensor's noise; the platform data's lamp table decides
    (wayside.platform; its debounce settles on this reading).
    [interpretation] a scan's dropout is left to the platform verification: over a stand of
    seconds the debounced reading is the settled one."""
    noise = kp[KP_SENSOR_NOISE]
    s2 = x + noise * key_normal(key, 2 * stand) >= kp[KP_S2]
    s1 = x + noise * key_normal(key, 2 * stand + 1) >= kp[KP_S1]
    return int(lamp_table[2 * int(s2) + int(s1)])


@njit_step
def _record_move(
    trace: np.ndarray,
    rows: int,
    dt: float,
    t0: float,
    x0: float,
    move: float,
    wait: float,
    duration: float,
    rs: np.ndarray,
    top: float,
    limit: float,
    lamp: int,
) -> int:
    """Record a correction of the detailed stop: a wait at the stand, then the move at up to ``top``."""
    total = wait + duration
    n = int(ceil_1(total / dt))
    forward = move > 0.0
    for i in range(1, n + 1):
        if rows >= trace.shape[0]:
            return rows
        tau = min(i * dt, total)
        moving = tau > wait
        gone = creep_position_1(abs(move), rs, tau - wait, top) if moving else 0.0
        speed = 0.0
        if moving:
            speed = (creep_position_1(abs(move), rs, min(tau - wait + dt, duration), top) - gone) / dt
        for j in range(TR_SIZE):
            trace[rows, j] = np.nan
        trace[rows, TR_T] = t0 + tau
        trace[rows, TR_X] = x0 + (gone if forward else -gone)
        trace[rows, TR_V] = speed if forward else -speed
        trace[rows, TR_NOTCH] = 0.0
        trace[rows, TR_SLIDE] = 0.0
        trace[rows, TR_LIMIT] = limit
        trace[rows, TR_ACTION] = (ACT_CREEP_FORWARD if forward else ACT_REVERSE) if moving else ACT_WAIT
        trace[rows, TR_SUPERVISION] = 0.0
        trace[rows, TR_LAMP] = lamp if not moving else 0.0
        rows += 1
    return rows


# --------------------------------------------------------------------------
# The start of a run.


@njit_inline
def _derive_run(p: StopParams, run: RunParams, seed_keys: UintArray, run_index: int) -> None:
    """The run's parameters that follow from its draw and the station's (``RUN_DTYPE``)."""
    kp, sc, d = p.kp, run.sc, run.derived[0]
    dt = kp[KP_DT]
    controller = int(kp[KP_CONTROLLER])
    d.run = run_index
    d.is_driver = controller >= CTRL_DRIVER_ATS
    d.is_ato = controller >= CTRL_ATO and not d.is_driver
    d.onboard_only = d.is_ato or d.is_driver  # no wayside unit, no link
    d.corrected = controller == CTRL_ATO_CORRECTED
    # SPEC §2: a campaign's run positions itself (model.fixes); a run the line drives takes the
    # fixes of the line's own chain, one chain per train (issue 35; ``SteppedStop.fix``).
    d.own_fixes = d.corrected and p.fp[FP_DRIVER_FIXES] == 0.0
    config = int(p.rp[RP_CONFIG])
    d.pwm_train = config in (CFG_PWM, CFG_SWITCHED_PWM)
    d.atc = kp[KP_ATC] > 0.0
    d.incapacitated = kp[KP_INCAPACITATED] > 0.0
    d.has_doppler = kp[KP_HAS_DOPPLER] > 0.0 and not d.onboard_only
    d.k_jitter = stream_key(seed_keys[K_JITTER], run_index)
    d.k_miss = stream_key(seed_keys[K_MISS], run_index)
    d.k_doppler = stream_key(seed_keys[K_DOPPLER], run_index)
    d.k_loss = stream_key(seed_keys[K_LOSS], run_index)
    d.k_latency = stream_key(seed_keys[K_LATENCY], run_index)
    d.k_cycle = stream_key(seed_keys[K_CYCLE], run_index)
    d.k_corrupt = stream_key(seed_keys[K_CORRUPT], run_index)
    d.k_faults = stream_key(seed_keys[K_FAULTS], run_index)
    d.k_driver = stream_key(seed_keys[K_DRIVER], run_index)
    d.k_stop_sensors = stream_key(seed_keys[K_STOP_SENSORS], run_index)
    # Masses: actual static and effective mass, and the effective mass the ECU believes (load weighing).
    static = kp[KP_TARE] + sc[SC_LOAD] * kp[KP_CRUSH]
    rotating = kp[KP_TARE] * kp[KP_ROTATING]
    d.static_kg = static
    d.effective_kg = static + rotating
    d.believed_kg = static * (1.0 + sc[SC_WEIGHING_ERROR]) + rotating
    d.brake_effect = sc[SC_BRAKE_GAIN] * d.believed_kg / d.effective_kg
    d.adhesion_limit_mps2 = adhesion_limit_1(sc[SC_MU], d.static_kg, d.effective_kg)
    d.patch_limit_mps2 = adhesion_limit_1(sc[SC_LOW_MU], d.static_kg, d.effective_kg)
    # The odometer assumes the actual diameter with its error (assumed = actual x (1 + error)).
    d.wheel_m = sc[SC_WHEEL_D]
    d.assumed_m = d.wheel_m * (1.0 + sc[SC_ODO_ERROR])
    d.tach_scale = d.assumed_m / d.wheel_m
    d.slide_slip = kp[KP_SLIDE_SLIP]
    # Actuator: dead time (whole steps), jerk limiter, first-order lag.
    d.delay_steps = int(rint_1(sc[SC_DEAD_TIME] / dt))
    d.lag_alpha = 1.0 - math.exp(-dt / sc[SC_TAU])
    d.jerk_step_mps2 = kp[KP_JERK] * dt
    ber = sc[SC_BER]
    d.corrupt_p = -math.expm1(kp[KP_FRAME_BITS] * math.log1p(-ber)) if ber > 0.0 else 0.0


@njit_inline
def _reset_state(p: StopParams, s: StopState, start_m: float, entry_mps: float) -> None:
    """Every scalar of the state at the start of the approach."""
    tr, ob, ln, se, ta = s.train[0], s.onboard[0], s.link[0], s.sense[0], s.tally[0]
    tr.position_m = start_m
    tr.speed_mps = entry_mps
    tr.accel_mps2 = 0.0
    tr.stopped = False
    tr.stop_time_s = np.nan
    tr.sliding = False
    tr.limited_mps2 = 0.0
    tr.output_mps2 = 0.0
    tr.odometer_step_m = 0.0
    ob.eb = False
    ob.eb_cause = 0.0
    ob.eb_t_s = np.nan
    ob.external_eb_t_s = np.nan
    ob.limit_mps = p.kp[KP_APPROACH_LIMIT]
    ob.code_next = 0
    # The train's own control around TASC (station.tasc.initial_brake_notch): its initial brake
    # step from the zone's first transponder on (0 before it, and with none).
    ob.own_notch = 0
    ob.own_for = -1
    ob.own_duty = np.nan
    ob.own_demand_mps2 = np.nan
    ob.switch_pos = -1
    # The link (SPEC §5 media, EN 50159 layer): the latest command is sent cyclically, a copy
    # every repeat period, until the train stands (the train discards copies it already has; a
    # copy is its life sign). Frames in the air: arrival times and attempt numbers (the safety
    # layer's sequence order); a newer command supersedes the copies of the old one in the air.
    ln.pending_id = 0
    ln.applied_id = 0
    ln.in_flight = 0
    ln.last_seq = -1
    ln.next_try_s = np.inf
    ln.first_rx_s = np.inf
    ln.attempts = 0
    ln.losses = 0
    ln.bad = False  # the medium starts in the good state
    se.passed = False
    se.det_idx = 0
    se.pass_s = 0.0
    se.sensor_next = 0
    se.truth_next = 0
    se.transponder_next = 0
    se.transponder_m = np.nan
    se.miss_trials = 0
    se.misses = 0
    ta.max_accel_change_mps2 = 0.0
    ta.slid = False
    ta.prev_accel_mps2 = 0.0
    ta.prev_counted = False
    ta.notch_changes = 0
    ta.prev_notch = 0
    ta.commands = 0
    ta.attempts = 0
    ta.deliveries = 0
    for j in range(s.ring.size):
        s.ring[j] = 0.0


@njit_step
def stop_init(
    p: StopParams, run: RunParams, s: StopState, out: StopOutputs, seed_keys: UintArray, run_index: int
) -> None:
    """Start run ``run_index`` (``seed_keys``: the seed's stream keys, ``RunStreams``): the run's
    derived parameters, the train at the start of its approach, every unit of its controller reset."""
    _derive_run(p, run, seed_keys, run_index)
    kp, d = p.kp, run.derived[0]
    entry = run.sc[SC_ENTRY_SPEED]
    x = p.det_pos[0] - max(20.0, entry * 1.5)
    if d.is_driver:
        # [interpretation] a driver's run starts far enough before the home signal to meet its codes.
        x = min(x, kp[KP_HOME] - kp[KP_START_BEFORE_HOME])
        # SPEC §3: the run's driver. [interpretation] He has run under the approach code before:
        # at most its limit less his margin on his speedometer (the drawn entry speed caps it).
        driver_draw_1(s.dr, p.levels, d.k_driver)
        entry = min(entry, (kp[KP_APPROACH_LIMIT] - s.dr[DR_MARGIN]) / d.tach_scale)
    _reset_state(p, s, x, entry)
    if d.is_ato:
        ato_init_1(s.at, s.mod)
        reset_law_1(s.law_state, s.law_params, p.lp)
    elif d.is_driver:
        # SPEC §3: the driver's state and the train's ATS / ATC supervision.
        driver_init_1(s.dv)
        supervision_init_1(s.sv)
    else:
        # The wayside unit and the receiver (both own the one modulator state).
        wayside_init_1(s.ws, p.wp, s.wh_v, s.wh_e, s.pass_t, s.pass_x)
        receiver_init_1(s.rx, s.mod, s.rh_v, s.rh_e)
    if d.own_fixes:
        # SPEC §2: no transponders; the position comes from track-circuit corrections. Before the
        # simulated approach the train was corrected at the last circuit boundary behind it. (A
        # run the line drives gets its first fix, the line chain's position, before its first step.)
        fp = p.fp
        belief = fixes_init_run(
            s.fx, s.fxi, s.flog, s.fbound, s.fdelay, p.tc_starts, p.tc_sd, fp[FP_DELAY_MEAN],
            fp[FP_DELAY_SPREAD], stream_key(seed_keys[K_TC_BOUNDARY], run_index),
            stream_key(seed_keys[K_TC_DELAY], run_index), x, entry, d.tach_scale, fp[FP_FIX_VAR],
            fp[FP_LEARN] > 0.0, fp[FP_SCALE_PRIOR_VAR], fp[FP_DELAY_PRIOR_VAR],
        )  # fmt: skip
        ato_fix_1(s.at, kp[KP_STOP] - belief)
    for j in range(out.passages.size):
        out.passages[j] = np.nan


# --------------------------------------------------------------------------
# One step: the controller's part (TASC: wayside -> link -> receiver; the ATO; the driver).


@njit_inline
def doppler_reading_1(p: StopParams, run: RunParams, s: StopState, k: int) -> float:
    """The wayside radar's sample at step ``k`` of the train as the state has it (NaN: no radar;
    0: out of its range). The plant's side of the sensors: the truth with the radar's noise."""
    kp, d, tr = p.kp, run.derived[0], s.train[0]
    doppler = np.nan
    if d.has_doppler:
        # The radar sees trains within its range; keyed by the step, so a sample outside the
        # radar's range need not be drawn.
        in_range = (kp[KP_DOPPLER_REACH] - tr.position_m) <= kp[KP_DOPPLER_RANGE]
        doppler = 0.0
        if in_range:
            noise = run.sc[SC_DOPPLER_NOISE]
            v = tr.speed_mps
            doppler = v * (1.0 + noise * key_normal_zig(d.k_doppler, k)) if noise > 0.0 else v
    return doppler


@njit_inline
def wayside_command_1(
    p: StopParams, run: RunParams, s: StopState, out: StopOutputs, k: int, t: float, doppler: float,
    passed: bool, det_idx: int, pass_s: float,
) -> bool:  # fmt: skip
    """The wayside unit's step on the sensors' reading at ``t`` (the Doppler sample, the detector
    passage of the last step): True when a new command is due, its telegram quantised for the air
    in ``s.pending`` (a new command replaces the telegram not yet delivered: the wayside sends only
    its latest). The stop model and the live stations process run this same step."""
    ln = s.link[0]
    due = wayside_step_1(
        s.ws, p.wp, s.dbuf, s.pass_t, s.pass_x, p.det_pos, s.wh_v, s.wh_e, s.taus, s.weights,
        BrakeCurves(p.table, p.pwm_duty, p.pwm_decel), Approach(p.det_to_stop, p.ext, run.grad), t, passed,
        det_idx, pass_s, doppler, s.tele, s.crow,
    )  # fmt: skip
    if not due:
        return False
    quantize_telegram_1(s.tele, s.pending, p.quant, p.carried, int(p.wp[WP_FORM]), p.kp[KP_QUANT_AGE])
    ln.pending_id += 1
    ln.in_flight = 0
    ln.next_try_s = -np.inf
    rec = out.rec
    if rec.on:
        ta = s.tally[0]
        n = ta.commands
        for j in range(CR_SIZE):
            rec.commands[n, j] = s.crow[j]
        rec.commands[n, CR_SIZE] = k
        for j in range(TEL_SIZE):
            rec.sends[n, j] = s.pending[j]
        ta.commands = n + 1
    return True


@njit_inline
def _wayside_1(p: StopParams, run: RunParams, s: StopState, out: StopOutputs, k: int, t: float) -> None:
    """The wayside unit's step: a Doppler sample now, the detector passage of the last step."""
    se = s.sense[0]
    wayside_command_1(p, run, s, out, k, t, doppler_reading_1(p, run, s, k), se.passed, se.det_idx, se.pass_s)


@njit_inline
def _transmit_1(p: StopParams, run: RunParams, s: StopState, out: StopOutputs, k: int, t: float) -> None:
    """A transmission attempt when one is due (SPEC §5 media; the run's streams decide, counter =
    attempt): lost, corrupted, or in the air until its arrival, refused there if stale."""
    ln = s.link[0]
    if not ln.next_try_s <= t + 1e-9:
        return
    kp, sc, d = p.kp, run.sc, run.derived[0]
    c = ln.attempts
    ln.attempts = c + 1
    lost = key_uniform(d.k_loss, c) < sc[SC_LOSS]
    ln.losses += lost
    # A radio outage (a fault of the data: SC_OUTAGE_*) loses every frame sent in it.
    rel = t - ln.first_rx_s - sc[SC_OUTAGE_START]
    outage_len = sc[SC_OUTAGE_LEN]
    in_outage = outage_len > 0.0 and rel >= -1e-9 and rel < outage_len
    reordered = False
    if not in_outage and (sc[SC_BURST_ENTER] > 0.0 or ln.bad):
        # The medium's bursts (link.channel.SimChannel, the same draws at the same counters): the
        # Gilbert-Elliott chain advances once per frame sent outside an outage, then judges it.
        u_state = key_uniform(d.k_faults, 4 * c)
        ln.bad = u_state >= sc[SC_BURST_EXIT] if ln.bad else u_state < sc[SC_BURST_ENTER]
        lost = lost or (ln.bad and key_uniform(d.k_faults, 4 * c + 1) < sc[SC_BURST_LOSS])
    if not (in_outage or lost) and sc[SC_REORDER] > 0.0:
        reordered = key_uniform(d.k_faults, 4 * c + 3) < sc[SC_REORDER]
    lost = lost or in_outage
    corrupt = False
    if sc[SC_BER] > 0.0 and not lost:
        corrupt = key_uniform(d.k_corrupt, 2 * c) < d.corrupt_p
    cycle = kp[KP_CYCLE]
    jitter = sc[SC_JITTER]
    u = key_uniform(d.k_cycle, c) if cycle > 0.0 else 0.0
    z = key_normal(d.k_latency, c) if jitter > 0.0 else 0.0
    arrival = t + (u * cycle + kp[KP_AIRTIME] + max(0.0, sc[SC_LATENCY] + jitter * z))
    if reordered:  # held back: later frames overtake it, and the receiver drops it then
        arrival += kp[KP_REORDER_DELAY]
    # The step that receives the frame, and the safety layer's age check there (ms).
    dt = kp[KP_DT]
    receive_s = ceil_1((arrival - 1e-9) / dt) * dt
    stale = rint_1(receive_s * 1000.0) - rint_1(t * 1000.0) > kp[KP_MAX_AGE] * 1000.0
    n_fl = ln.in_flight
    if not (lost or corrupt or stale) and n_fl < s.fl_arr.size:
        s.fl_arr[n_fl] = arrival
        s.fl_seq[n_fl] = c
        ln.in_flight = n_fl + 1
    ln.next_try_s = t + kp[KP_REPEAT]
    rec = out.rec
    if rec.on:
        ta = s.tally[0]
        n = ta.attempts
        rec.attempts[n, LA_STEP] = k
        rec.attempts[n, LA_LOST] = lost
        rec.attempts[n, LA_CORRUPT] = corrupt
        rec.attempts[n, LA_FLIP] = key_uniform(d.k_corrupt, 2 * c + 1) if corrupt else np.nan
        rec.attempts[n, LA_ARRIVAL] = arrival
        rec.attempts[n, LA_STALE] = stale
        ta.attempts = n + 1


@njit_inline
def _deliver_1(s: StopState, out: StopOutputs, k: int, t: float) -> bool:
    """Frames arrived by now, in sending order: the safety layer delivers a frame only if it is
    newer than the last one delivered (an overtaken frame is out of order). Whether any was."""
    ln = s.link[0]
    rec = out.rec
    delivered = False
    m = 0
    for j in range(ln.in_flight):
        if s.fl_arr[j] <= t + 1e-9:
            if s.fl_seq[j] > ln.last_seq:
                ln.last_seq = s.fl_seq[j]
                delivered = True
                if rec.on:  # one entry per frame delivered
                    ta = s.tally[0]
                    rec.deliveries[ta.deliveries] = k
                    ta.deliveries += 1
        else:
            s.fl_arr[m] = s.fl_arr[j]
            s.fl_seq[m] = s.fl_seq[j]
            m += 1
    ln.in_flight = m
    return delivered


@njit_inline
def tasc_onboard_1(
    p: StopParams, run: RunParams, s: StopState, k: int, t: float, tach_v: float, new: bool, copy: bool
) -> tuple[int, float, bool, bool]:
    """The train's TASC side of step ``k`` (SPEC §1): a transponder passed in the last step resets
    its odometer (at the first, its brake controller applies the initial brake step); a new
    telegram (``new``, in ``s.pending``) or a copy of the one it has (``copy``) and its sensing in;
    (notch, duty, braking, emergency brake) out for the ECU. The stop model and the live trains
    process run this same step."""
    ob, d, se = s.onboard[0], run.derived[0], s.sense[0]
    if se.transponder_m == se.transponder_m:  # not NaN: the train's own ATP saw a transponder
        receiver_fix_1(s.rx, p.rp, se.transponder_m, t)
        ob.own_notch = int(p.kp[KP_INITIAL_NOTCH])
        se.transponder_m = np.nan
    if s.rx[RX_ACTIVE] > 0.0:
        # [interpretation] The hand-over: once TASC's first command is in, the train's own
        # controller releases its initial step (its carrier stays, at the released duty). Configs
        # 1 and 2 replace the train's command anyway; config 3's OR could otherwise only add to it,
        # and a step it kept would be a floor the onboard unit cannot go below.
        ob.own_notch = 0
    own_notch = ob.own_notch
    if own_notch != ob.own_for:
        ob.own_duty, ob.own_demand_mps2 = own_command_1(
            own_notch, d.pwm_train, p.table, p.pwm_duty, p.pwm_decel
        )
        ob.own_for = own_notch
    notch, duty, eb, switch_pos = receiver_cycle_1(
        s.rx, p.rp, s.mod, s.tach, s.rh_v, s.rh_e, s.taus, BrakeCurves(p.table, p.pwm_duty, p.pwm_decel),
        Approach(p.det_to_stop, p.ext, run.grad), s.pending, t, k, new, copy, tach_v,
        s.train[0].sliding, s.train[0].odometer_step_m, own_notch, ob.own_duty,
    )  # fmt: skip
    ob.eb = eb
    ob.switch_pos = switch_pos
    braking = math.isfinite(s.rx[RX_FIRST_RX]) or eb or own_notch > 0
    return notch, duty, braking, eb


@njit_inline
def _tasc_control_1(
    p: StopParams, run: RunParams, s: StopState, out: StopOutputs, k: int, t: float, tach_v: float
) -> tuple[int, float, bool, bool]:
    """Wayside unit -> link -> onboard receiver: (notch, duty, braking, emergency brake) for the ECU."""
    _wayside_1(p, run, s, out, k, t)
    _transmit_1(p, run, s, out, k, t)
    delivered = _deliver_1(s, out, k, t)
    ln = s.link[0]
    copy = delivered and ln.applied_id == ln.pending_id  # a copy of the command the train has
    new = delivered and not copy
    if new:
        ln.applied_id = ln.pending_id
        ln.first_rx_s = min(ln.first_rx_s, t)
    return tasc_onboard_1(p, run, s, k, t, tach_v, new, copy)


@njit_inline
def _driver_control_1(
    p: StopParams, run: RunParams, s: StopState, t: float, tach_v: float
) -> tuple[int, bool, bool, float]:
    """SPEC §3 manual driving: the codes, the ATS / ATC supervision, the driver: (notch, braking,
    emergency brake, the traction the driver takes in m/s²)."""
    kp, d, tr, ob = p.kp, run.derived[0], s.train[0], s.onboard[0]
    # The code held since the last point (ATS) / picked up here (ATC).
    code_next = ob.code_next
    while code_next < p.code_pos.size and tr.position_m >= p.code_pos[code_next]:
        ob.limit_mps = p.code_lim[code_next]
        code_next += 1
    ob.code_next = code_next
    limit = ob.limit_mps
    # The supervision judges the speedometer's speed (the tachometer's).
    supervise_1(s.sv, d.atc, kp[KP_GRACE], kp[KP_ATC_MARGIN], tach_v, limit, t)
    eb = s.sv[SV_EB] > 0.0
    ob.eb = eb
    if eb and ob.eb_cause == 0.0:
        ob.eb_cause = s.sv[SV_EB]
        ob.eb_t_s = t
    # SPEC §3 signal-open switch (KP_PASS): the driver runs through, no stop ahead.
    stop_point = kp[KP_STOP] if kp[KP_PASS] <= 0.0 else np.inf
    driver_look_1(
        s.dv, s.dr, p.table, d.k_driver, t, tr.position_m, tach_v, tr.accel_mps2, stop_point,
        p.code_pos, p.code_lim, limit, d.incapacitated, p.wp[WP_INITIAL_DELAY], p.rs,
    )  # fmt: skip
    notch, holding, power = driver_output_1(s.dv, t)
    # Power (config.driver Running): the brakes released, traction at the driver's notch; the
    # emergency brake cuts it.
    traction = p.rs[RS_POWER_ACCEL] if power and not eb else 0.0
    return notch, not holding or eb, eb, traction


# --------------------------------------------------------------------------
# One step: the brake chain, the train's motion, the sensors after the move, the recording.


@njit_inline
def ecu_1(p: StopParams, s: StopState, notch: int, duty: float, eb: bool) -> tuple[float, int]:
    """Onboard -> ECU: the brake demand of a step code through the brake line, or of a PWM duty
    (``eb``: the emergency brake, wire e): (demand, the ECU's notch (-1: PWM))."""
    kp, tr, ta = p.kp, s.train[0], s.tally[0]
    if notch >= 0:
        ecu_notch = line_notch(notch)
        demand = p.table[ecu_notch]
        if ecu_notch != ta.prev_notch and not tr.stopped:
            ta.notch_changes += 1
        ta.prev_notch = ecu_notch
    else:
        ecu_notch = -1
        demand = pwm_to_decel_1(duty, p.pwm_duty, p.pwm_decel)
    if eb:
        demand = kp[KP_EMERGENCY]  # wire e: the emergency brake, whatever the service command
    return demand, ecu_notch


@njit_inline
def actuator_1(p: StopParams, run: RunParams, s: StopState, k: int, demand: float) -> float:
    """The ECU's demand -> actuator (dead time, jerk limit, lag) -> brakes: the brakes' deceleration.
    Load compensation: the ECU sets the force for the mass it believes; the real mass and the
    brake's real effectiveness decide what that force does."""
    kp, d, tr = p.kp, run.derived[0], s.train[0]
    tr.limited_mps2, tr.output_mps2 = actuator_step_1(
        s.ring, k, d.delay_steps, demand, tr.limited_mps2, tr.output_mps2, d.lag_alpha, d.jerk_step_mps2,
        kp[KP_EMERGENCY],
    )  # fmt: skip
    return tr.output_mps2 * d.brake_effect


@njit_inline
def move_1(
    p: StopParams,
    run: RunParams,
    s: StopState,
    t: float,
    x: float,
    v: float,
    brake_decel: float,
    hold: bool,
    traction: float = 0.0,
) -> tuple[float, float, bool, bool]:
    """The train's dynamics t -> t + dt from ``x``, ``v``, its standstill, and the jerk while
    braking: (position, acceleration, sliding, stopped) after the step. ``traction`` (m/s², a
    driver's power): it moves a standing train and is capped at the adhesion."""
    kp, sc, d, tr, ta = p.kp, run.sc, run.derived[0], s.train[0], s.tally[0]
    dt = kp[KP_DT]
    in_patch = x >= sc[SC_LOW_START] and x < sc[SC_LOW_END]
    # The adhesion's limit here (the run's two, derived once: _derive_run).
    limit = d.patch_limit_mps2 if in_patch else d.adhesion_limit_mps2
    bp, gv, ge = run.grad
    stopped = tr.stopped
    if traction > 0.0:
        # [interpretation] the traction a driver takes is far below the adhesion on dry rail; on a
        # low-adhesion patch it is held to it (the anti-slip control), and it releases the brakes.
        traction = min(traction, limit)
        brake_decel -= traction
        stopped = stopped and brake_decel >= 0.0
    x, v, accel, now_stopped, st, sliding = motion_step_1(
        x, v, stopped, brake_decel, mean_gradient_1(x, kp[KP_LENGTH], bp, gv, ge), limit, hold,
        d.static_kg, d.effective_kg, kp[KP_DAVIS_A], kp[KP_DAVIS_B], kp[KP_DAVIS_C], t, dt,
    )  # fmt: skip
    tr.position_m = x
    tr.speed_mps = v
    tr.accel_mps2 = accel
    tr.sliding = sliding
    if now_stopped and not stopped:
        tr.stop_time_s = st
    tr.stopped = now_stopped
    if sliding and not now_stopped:
        ta.slid = True
    # Jerk while moving under braking (not across the traction cut-off or the standstill step).
    counted = not hold and traction <= 0.0 and not now_stopped
    # The largest |change| of the acceleration; the jerk is that over the step, divided once at the
    # end of the run (stop_finish: dividing by the same positive step rounds monotonically, so the
    # maximum of the quotients is the quotient of the maximum, to the bit).
    change = abs(accel - ta.prev_accel_mps2)
    if counted and ta.prev_counted:
        ta.max_accel_change_mps2 = max(ta.max_accel_change_mps2, change)
    ta.prev_accel_mps2 = accel
    ta.prev_counted = counted
    return x, accel, sliding, now_stopped


@njit_inline
def sensors_1(
    p: StopParams, run: RunParams, s: StopState, out: StopOutputs, t: float, x0: float, v0: float,
    x: float, accel: float, sliding: bool,
) -> None:  # fmt: skip
    """After the move from ``x0``, ``v0`` to ``x`` (``accel``, ``sliding``): the true passages, the
    odometer, the positioning (transponders, track circuits) and the wayside detectors' reports."""
    kp, sc, d, tr, se = p.kp, run.sc, run.derived[0], s.train[0], s.sense[0]
    # True passages (for the record) and the detectors' reports (for the wayside).
    if passage_1(p.det_pos, se.truth_next, x0, x):
        out.passages[se.truth_next] = t + crossing_time_1(x0, v0, accel, p.det_pos[se.truth_next])
        se.truth_next += 1
    # Odometer: wheel revolutions x pi x assumed diameter (SPEC §2), i.e. the distance x creep x
    # D_assumed / D_actual (the tachometer's scale, one factor per run: stop model 21).
    odometer = (x - x0) * creep_1(sliding, d.slide_slip) * d.tach_scale
    tr.odometer_step_m = odometer
    if d.is_ato:
        ato_odometer_1(s.at, odometer)
        if d.own_fixes:  # (driven by the line: its chain's fixes come through SteppedStop.fix)
            fp = p.fp
            data = FixesData(
                p.tc_ids,
                p.db_ids,
                p.db_starts,
                p.db_sd,
                fp[FP_DELAY_SPREAD],
                fp[FP_LEARN] > 0.0,
                fp[FP_MAX_EXTRAPOLATION],
                fp[FP_GATE_SIGMA2],
                fp[FP_GNSS_COUNTS],
            )
            corrected, calibrated = fixes_step_run(
                FixesRun(s.fx, s.fxi, s.flog, s.fbound, s.fdelay), data, t, kp[KP_DT], x0, v0, accel, x,
                odometer, tr.speed_mps * creep_1(sliding, d.slide_slip) * d.tach_scale, sliding,
                sc[SC_LATENCY],
            )  # fmt: skip
            if corrected:
                ato_fix_1(s.at, kp[KP_STOP] - calibrated)
        elif not d.corrected and passage_1(p.transponders, se.transponder_next, x0, x):
            ato_fix_1(s.at, kp[KP_STOP] - p.transponders[se.transponder_next])
            se.transponder_next += 1
    elif not d.is_driver:  # a driver judges by eye (driver_look_1); his speedometer is the tachometer
        # The train's own ATP resets its odometer at the transponders; at the first one (the
        # zone's start) its brake controller applies the initial brake step.
        # (The train takes the passage in its next step: ``tasc_onboard_1``.)
        if passage_1(p.transponders, se.transponder_next, x0, x):
            se.transponder_m = p.transponders[se.transponder_next]
            se.transponder_next += 1
        se.passed = False
        if passage_1(p.det_pos, se.sensor_next, x0, x):
            det_idx = se.sensor_next
            se.det_idx = det_idx
            se.pass_s = (
                t
                + crossing_time_1(x0, v0, accel, p.det_pos[det_idx])
                + sc[SC_SENSOR_JITTER] * key_normal(d.k_jitter, det_idx)
            )
            passed = key_uniform(d.k_miss, det_idx) >= sc[SC_MISS]
            se.passed = passed
            se.miss_trials += 1
            se.misses += not passed
            se.sensor_next += 1


@njit_inline
def _record_step_1(
    run: RunParams,
    s: StopState,
    out: StopOutputs,
    k: int,
    t: float,
    dt: float,
    demand: float,
    brake_decel: float,
    ecu_notch: int,
    duty: float,
) -> None:
    """The trace row of step ``k`` (the detailed stop)."""
    d, tr, ob = run.derived[0], s.train[0], s.onboard[0]
    trace = out.rec.trace
    trace[k, TR_T] = t + dt
    trace[k, TR_X] = tr.position_m
    trace[k, TR_V] = tr.speed_mps
    if d.is_ato:
        trace[k, TR_TARGET] = s.at[AT_TARGET] if s.at[AT_ACTIVE] > 0.0 else np.nan
    elif d.is_driver:
        trace[k, TR_TARGET] = s.dv[DV_REQUIRED]
    else:
        trace[k, TR_TARGET] = s.rx[RX_TARGET] if s.rx[RX_ACTIVE] > 0.0 else np.nan
    trace[k, TR_DEMAND] = demand
    trace[k, TR_BRAKE] = 0.0 if tr.stopped else brake_decel
    trace[k, TR_ACCEL] = tr.accel_mps2
    trace[k, TR_NOTCH] = ecu_notch
    trace[k, TR_DUTY] = duty
    trace[k, TR_OWN] = ob.own_demand_mps2
    trace[k, TR_SWITCH] = ob.switch_pos if ob.switch_pos >= 0 else np.nan
    trace[k, TR_SLIDE] = 1.0 if tr.sliding and not tr.stopped else 0.0
    if d.is_driver:
        trace[k, TR_LIMIT] = ob.limit_mps
        trace[k, TR_ACTION] = s.dv[DV_ACTION]
        trace[k, TR_SUPERVISION] = 2.0 if ob.eb else s.sv[SV_ALARM]
        trace[k, TR_LAMP] = 0.0
    else:
        for j in (TR_LIMIT, TR_ACTION, TR_SUPERVISION, TR_LAMP):
            trace[k, j] = np.nan


@njit_inline
def tach_speed_1(run: RunParams, s: StopState) -> float:
    """The tachometer's speed: the wheel's (slower when sliding) with the assumed diameter."""
    d, tr = run.derived[0], s.train[0]
    return tr.speed_mps * creep_1(tr.sliding, d.slide_slip) * d.tach_scale


@njit_inline
def external_eb_1(s: StopState, t: float) -> bool:
    """Whether an emergency brake from outside the stop's units (the CBTC onboard unit) is applied
    by ``t`` (``external_eb_t_s`` NaN: never)."""
    return s.onboard[0].external_eb_t_s <= t


@njit_inline
def stop_step(p: StopParams, run: RunParams, s: StopState, out: StopOutputs, k: int, law: Any) -> bool:
    """Step ``k`` of the station stop, t = k dt -> t + dt (see the module docstring). True when
    the train stands at its end (the run's end). ``law``: the onboard stop-control law
    (``model.build.compiled_law``; the ATO's unless a law was loaded)."""
    d, tr = run.derived[0], s.train[0]
    dt = p.kp[KP_DT]
    t = k * dt
    x0 = tr.position_m
    v0 = tr.speed_mps
    tach_v = tach_speed_1(run, s)
    traction = 0.0
    if d.is_ato:
        notch = ato_output_1(
            s.at, p.ap, s.mod, p.table, p.ext, run.grad, k, tach_v, law, s.meas, s.law_state, s.law_params
        )
        duty = np.nan
        braking = s.at[AT_BRAKING] > 0.0
        eb = False
    elif d.is_driver:
        notch, braking, eb, traction = _driver_control_1(p, run, s, t, tach_v)
        duty = np.nan
    else:
        notch, duty, braking, eb = _tasc_control_1(p, run, s, out, k, t, tach_v)
    if external_eb_1(s, t):
        eb = braking = True
        traction = 0.0
    demand, ecu_notch = ecu_1(p, s, notch, duty, eb)
    brake_decel = actuator_1(p, run, s, k, demand)
    x, accel, sliding, stopped = move_1(p, run, s, t, x0, v0, brake_decel, not braking, traction)
    sensors_1(p, run, s, out, t, x0, v0, x, accel, sliding)
    if out.rec.on:
        _record_step_1(run, s, out, k, t, dt, demand, brake_decel, ecu_notch, duty)
    # The run ends at the stand, or (signal-open switch) once the train has passed the platform.
    return stopped or 0.0 < p.kp[KP_PASS] <= x


# --------------------------------------------------------------------------
# The end of a run.


@njit_inline
def _restops_1(
    p: StopParams, run: RunParams, s: StopState, out: StopOutputs, rows: int
) -> tuple[int, int, int]:
    """SPEC §3 lamps at the stand, and the driver's corrections (F: forward, R: reverse), each
    recorded as a wait and a creep: (lamp at the end, corrections, trace rows)."""
    kp, rs, d, tr, ob = p.kp, p.rs, run.derived[0], s.train[0], s.onboard[0]
    rec = out.rec
    dt = kp[KP_DT]
    stop_point = kp[KP_STOP]
    x = tr.position_m
    lamp = _stand_lamp_1(x, kp, p.lamp_table, d.k_stop_sensors, 0)
    t_end = tr.stop_time_s
    setup = rs[RS_EB_RESET] if ob.eb_cause > 0.0 else 0.0
    restops = 0
    while lamp in (LAMP_F, LAMP_R) and restops < int(rs[RS_MAX]) and not d.incapacitated:
        wait = s.dr[DR_REACTION] + setup + (rs[RS_REVERSE_SETUP] if lamp == LAMP_R else 0.0)
        setup = 0.0
        judged = abs(restop_judgement_1(rs, d.k_driver, restops, stop_point - x))
        move = judged if lamp == LAMP_F else -judged
        top = move_speed_1(rs, judged, lamp == LAMP_F, ob.limit_mps - s.dr[DR_MARGIN])
        duration = creep_time_1(judged, rs, top)
        if rec.on:
            rows = _record_move(
                rec.trace, rows, dt, t_end, x, move, wait, duration, rs, top, ob.limit_mps, lamp
            )
        x += move
        t_end += wait + duration
        restops += 1
        lamp = _stand_lamp_1(x, kp, p.lamp_table, d.k_stop_sensors, restops)
    tr.position_m = x
    tr.stop_time_s = t_end
    trace = rec.trace
    if rec.on and rows < trace.shape[0]:
        for j in range(TR_SIZE):
            trace[rows, j] = trace[rows - 1, j]
        trace[rows, TR_T] = t_end
        trace[rows, TR_X] = x
        trace[rows, TR_ACTION] = ACT_DONE
        trace[rows, TR_LAMP] = lamp
        rows += 1
    return lamp, restops, rows


@njit_step
def stop_finish(p: StopParams, run: RunParams, s: StopState, out: StopOutputs, rows: int) -> None:
    """The end of the run (the train stands, or the time is up; ``rows`` steps done): a driver's
    corrections at the stand, and the run's results (``RES_*``) and recording counters."""
    d, tr, ob, ln, se, ta = run.derived[0], s.train[0], s.onboard[0], s.link[0], s.sense[0], s.tally[0]
    stop_point = p.kp[KP_STOP]
    first_error = tr.position_m - stop_point
    restops = 0
    lamp = 0
    if d.is_driver and tr.stopped:
        lamp, restops, rows = _restops_1(p, run, s, out, rows)
    res, passages = out.res, out.passages
    onboard_only = d.onboard_only
    res[RES_ERROR] = tr.position_m - stop_point
    res[RES_STOP_TIME] = tr.stop_time_s - passages[0] if tr.stopped else np.nan
    res[RES_MAX_JERK] = ta.max_accel_change_mps2 / p.kp[KP_DT]
    res[RES_NOTCH_CHANGES] = ta.notch_changes
    res[RES_SENT] = 0.0 if onboard_only else s.ws[WS_SENT]
    res[RES_RECEIVED] = 0.0 if onboard_only else s.rx[RX_RECEIVED]
    res[RES_STOPPED] = tr.stopped
    res[RES_SLID] = ta.slid
    res[RES_MISS_TRIALS] = se.miss_trials
    res[RES_MISSES] = se.misses
    res[RES_LOSS_TRIALS] = ln.attempts
    res[RES_LOSSES] = ln.losses
    if d.is_driver:
        res[RES_EB] = ob.eb_cause
        res[RES_EB_T] = ob.eb_t_s - passages[0]
    else:
        res[RES_EB] = 0.0 if d.is_ato else s.rx[RX_EB]
        res[RES_EB_T] = np.nan if d.is_ato else s.rx[RX_EB_T] - passages[0]
    if res[RES_EB] == 0.0 and math.isfinite(ob.external_eb_t_s):
        # Braked from outside only: the cause is the CBTC unit's (the stop's own units did not).
        res[RES_EB] = EB_CBTC
        res[RES_EB_T] = ob.external_eb_t_s - passages[0]
    identified = not onboard_only and math.isfinite(s.ws[WS_ID_GAIN])
    res[RES_ID_DELAY] = s.ws[WS_DELAY] if identified else np.nan
    res[RES_ID_LAG] = s.ws[WS_LAG] if identified else np.nan
    res[RES_FILLED] = 0.0 if onboard_only else s.ws[WS_FILLED]
    res[RES_FIRST_ERROR] = first_error
    res[RES_RESTOPS] = restops
    res[RES_LAMP] = lamp
    res[RES_LEVEL] = s.dr[DR_LEVEL] if d.is_driver else -1.0
    rec = out.rec
    if rec.on:
        rec.counters[RC_STEPS] = rows
        rec.counters[RC_COMMANDS] = ta.commands
        rec.counters[RC_ATTEMPTS] = ta.attempts
        rec.counters[RC_DELIVERIES] = ta.deliveries
