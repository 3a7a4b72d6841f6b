"""The compiled stop kernel: one model for every stop (DESIGN rule 1).

``simulate_block`` simulates runs one after another, each from the start of
the approach to standstill (no lockstep: a run ends at its own stop), every
10 ms (the Doppler sample period of SPEC §1), through the compiled scalar
cores of the physics, brake chain, sensors, wayside unit, link decisions and
onboard control laws. The detailed stop is the same kernel on one run with
recording on; a campaign runs it over blocks of runs on threads (it holds no
GIL) or processes.

One step at time t:
    sensors (Doppler sample at t; passages found during the last step)
    -> wayside TASC unit -> link (loss, corruption, delay, staleness)
    -> onboard receiver (or the onboard ATO) -> brake signal -> ECU (load
    compensation) -> actuator (dead time, jerk limit, lag) -> train dynamics
    t -> t + dt -> wheel sensors (and odometer, transponders, track circuits).

Every random number is drawn from the counter-based streams of
``railstop.streams`` (the same numbers as the array methods): a run's
result does not depend on the block it is simulated in.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railstop.config.driver import LEVEL_PARAMETERS, LV_PARAMS, LV_WIDTH, DriverFile
from railstop.config.platform import LAMP_CODES, PlatformFile
from railstop.config.schema import Station, Track, Vehicle
from railstop.control.brake_ident import AFTER_S as ID_AFTER_S
from railstop.control.brake_ident import BEFORE_S as ID_BEFORE_S
from railstop.control.notch import MOD_SIZE
from railstop.control.tasc import HISTORY, SAMPLES, external_params
from railstop.controllers import DRIVER_ATC1, DRIVER_ATC2, DRIVER_ATS, DRIVER_UNAIDED
from railstop.errors import RailstopError, SimulationError
from railstop.jit import njit, njit_inline, njit_step
from railstop.link.channel import airtime_s, media_preset
from railstop.link.codec import TASC_FORM_TYPES, layout_of
from railstop.onboard.ato import (
    AT_ACTIVE,
    AT_BRAKING,
    AT_SIZE,
    AT_TARGET,
    ato_fix_1,
    ato_init_1,
    ato_odometer_1,
    ato_output_1,
    ato_params,
)
from railstop.onboard.driver import (
    ACT_CREEP_FORWARD,
    ACT_DONE,
    ACT_REVERSE,
    ACT_WAIT,
    DR_LEVEL,
    DR_REACTION,
    DR_SIZE,
    DV_ACTION,
    DV_REQUIRED,
    DV_SIZE,
    RS_EB_RESET,
    RS_JUDGEMENT_FLOOR,
    RS_MAX,
    RS_REVERSE_SETUP,
    creep_position_1,
    creep_time_1,
    driver_draw_1,
    driver_init_1,
    driver_look_1,
    driver_output_1,
    restop_judgement_1,
)
from railstop.onboard.positioning import LOG_ROWS
from railstop.onboard.speed_supervision import SV_ALARM, SV_EB, SV_SIZE, supervise_1, supervision_init_1
from railstop.onboard.tasc_receiver import (
    CFG_PWM,
    CFG_SWITCHED_PWM,
    CONFIG_CODES,
    RP_CONFIG,
    RX_ACTIVE,
    RX_EB,
    RX_EB_T,
    RX_FIRST_RX,
    RX_RECEIVED,
    RX_SIZE,
    RX_TARGET,
    receiver_cycle_1,
    receiver_fix_1,
    receiver_init_1,
    receiver_params,
    receiver_window,
)
from railstop.physics.brake import actuator_step_1, decel_to_pwm_1, line_notch, pwm_to_decel_1
from railstop.physics.train import creep_1, mean_gradient_1, motion_step_1
from railstop.sensors.wayside import crossing_time_1, passage_1
from railstop.sim.corrected_position import (
    FX_SIZE,
    FXI_SIZE,
    FixesLine,
    fixes_init_run,
    fixes_step_run,
)
from railstop.sim.scenario import Scenario
from railstop.sim.tasc_link import CARRIED, frame_bytes
from railstop.streams import Stream, key_normal, key_normal_zig, key_uniform, seed_key, seed_u64, stream_key
from railstop.wayside.tasc_unit import (
    CR_SIZE,
    TEL_DELTA,
    TEL_DETECTOR,
    TEL_EMERGENCY,
    TEL_FIELDS,
    TEL_MEASURED,
    TEL_NOTCH,
    TEL_PASSAGE,
    TEL_SIZE,
    TEL_SPEED,
    WP_BASE_DELAY,
    WP_CONTINUOUS,
    WP_CONTINUOUS_PERIOD,
    WP_DT,
    WP_END_MARGIN,
    WP_FILL,
    WP_FIT_SAMPLES,
    WP_FORM,
    WP_GUARD_LIMIT,
    WP_HAS_DOPPLER,
    WP_ID_AFTER,
    WP_IDENTIFY,
    WP_INITIAL_DECEL,
    WP_INITIAL_DELAY,
    WP_JERK,
    WP_LAG,
    WP_MAX_DECEL,
    WP_MOD_CYCLE,
    WP_MOD_HOLD,
    WP_MODULATE,
    WP_SIZE,
    WP_SPEED_SAMPLES,
    WP_STEP_SPACING,
    WP_STOP,
    WS_DELAY,
    WS_FILLED,
    WS_ID_GAIN,
    WS_LAG,
    WS_SENT,
    WS_SIZE,
    SignalForm,
    wayside_init_1,
    wayside_step_1,
)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

# Controller codes of the kernel: the TASC configurations' codes (CFG_*), then the onboard ATOs,
# then the human drivers of SPEC §3 (ATS, ATC option 1, ATC option 2, no station codes).
CTRL_ATO = 8
CTRL_ATO_CORRECTED = 9
CTRL_DRIVER_ATS = 10
CTRL_DRIVER_ATC1 = 11
CTRL_DRIVER_ATC2 = 12
CTRL_DRIVER_UNAIDED = 13

# The lamps the driver corrects for at a stand (SPEC §3).
LAMP_F = LAMP_CODES["F"]
LAMP_R = LAMP_CODES["R"]

# Scenario columns (one row per run): what the disturbance draw decides.
SC_ENTRY_SPEED = 0
SC_LOAD = 1
SC_WEIGHING_ERROR = 2
SC_BRAKE_GAIN = 3
SC_DEAD_TIME = 4
SC_TAU = 5
SC_WHEEL_D = 6
SC_ODO_ERROR = 7
SC_MU = 8
SC_LOW_MU = 9
SC_LOW_START = 10
SC_LOW_END = 11
SC_LATENCY = 12
SC_LOSS = 13
SC_JITTER = 14
SC_BER = 15
SC_SENSOR_JITTER = 16
SC_MISS = 17
SC_DOPPLER_NOISE = 18
SC_OUTAGE_START = 19  # radio outage: from this long after the first telegram delivered ...
SC_OUTAGE_LEN = 20  # ... for this long every frame is lost (0: no outage)
SC_SIZE = 21
_SCENARIO_FIELDS = (
    "entry_speed_mps",
    "load_factor",
    "load_weighing_error",
    "brake_gain",
    "dead_time_s",
    "time_constant_s",
    "wheel_diameter_m",
    "odometer_diameter_error",
    "adhesion_mu",
    "low_mu",
    "low_mu_start_m",
    "low_mu_end_m",
    "radio_latency_s",
    "radio_loss_probability",
    "radio_jitter_s",
    "radio_bit_error_rate",
    "sensor_jitter_s",
    "sensor_miss_probability",
    "doppler_noise_frac",
    "radio_outage_start_s",
    "radio_outage_duration_s",
)

# Kernel parameters (station, vehicle, controller).
KP_DT = 0
KP_STEPS = 1
KP_CONTROLLER = 2
KP_STOP = 3
KP_TARE = 4
KP_CRUSH = 5
KP_ROTATING = 6
KP_DAVIS_A = 7
KP_DAVIS_B = 8
KP_DAVIS_C = 9
KP_LENGTH = 10
KP_SLIDE_SLIP = 11
KP_JERK = 12
KP_EMERGENCY = 13
KP_HAS_DOPPLER = 14
KP_DOPPLER_REACH = 15
KP_DOPPLER_RANGE = 16
KP_REPEAT = 17
KP_CYCLE = 18
KP_AIRTIME = 19
KP_FRAME_BITS = 20
KP_MAX_AGE = 21
KP_QUANT_AGE = 22  # form 4: counts per second of the passage age
KP_IN_FLIGHT = 23  # frames that can be in the air at once (max age / repeat period + 2)
KP_INITIAL_NOTCH = 24  # TASC trains: the initial brake step of the train's own control (0: none)
# SPEC §3 manual driving (the driver controllers):
KP_HOME = 25  # the home signal's chainage
KP_APPROACH_LIMIT = 26  # m/s, before the first code point
KP_GRACE = 27
KP_ATC = 28  # 1: ATC supervision (indicated / permitted speed), 0: ATS
KP_ATC_MARGIN = 29  # m/s: permitted = indicated + this
KP_INCAPACITATED = 30  # 1: the driver never brakes (the supervision check)
KP_S2 = 31  # the stop sensors' chainages (sensors.stop_sensors sensor_positions) ...
KP_S1 = 32
KP_SENSOR_NOISE = 33  # ... and their noise
KP_START_BEFORE_HOME = 34  # a driver's run starts at least this far before the home signal
KP_SIZE = 35

# Results per run.
RES_ERROR = 0  # front at rest minus stopping point (+ = overrun)
RES_STOP_TIME = 1  # from the first detector to standstill (NaN if not stopped)
RES_MAX_JERK = 2
RES_NOTCH_CHANGES = 3
RES_SENT = 4
RES_RECEIVED = 5
RES_STOPPED = 6
RES_SLID = 7
# The run's Bernoulli draws (what importance sampling needs for exact likelihood ratios):
# detector passages drawn for a miss and the misses; transmission attempts and the losses.
RES_MISS_TRIALS = 8
RES_MISSES = 9
RES_LOSS_TRIALS = 10
RES_LOSSES = 11
RES_EB = 12  # emergency brake cause (control.supervision EB_*; 0: none)
RES_EB_T = 13  # when it was applied (NaN: never)
RES_ID_DELAY = 14  # the brake response the wayside identified: equivalent dead time (NaN: none)
RES_ID_LAG = 15  # ... and build-up lag
RES_FILLED = 16  # detector passages the wayside filled in from its radar
# SPEC §3 manual driving (the other controllers: first = final error, no re-stops, no lamp).
RES_FIRST_ERROR = 17  # the stop error at the first standstill
RES_RESTOPS = 18  # F / R corrections
RES_LAMP = 19  # the lamp at the end (LAMP_*; 0: none)
RES_LEVEL = 20  # the driver's skill level (its row in the driver data; -1: no driver)
RES_SIZE = 21

# Trace columns (recording).
TR_T = 0
TR_X = 1
TR_V = 2
TR_TARGET = 3
TR_DEMAND = 4
TR_BRAKE = 5
TR_ACCEL = 6
TR_NOTCH = 7
TR_DUTY = 8
TR_OWN = 9  # TASC trains: the train's own brake demand (its ATO's; NaN for the ATO controllers)
TR_SWITCH = 10  # config 2: the changeover switches' position (SWITCH_*; NaN otherwise)
# The driver controllers (NaN otherwise): the held limit / indicated speed, the driver's action
# (onboard.driver ACT_*), the supervision (0 quiet, 1 alarm, 2 emergency brake), the lamp at a stand.
TR_LIMIT = 11
TR_ACTION = 12
TR_SUPERVISION = 13
TR_LAMP = 14
# The wheels slide this step (braking beyond the adhesion, the WSP acting: 1, else 0): what the
# train's odometer must know of (SPEC §2 slip/slide; the line's odometer plays it back).
TR_SLIDE = 15
TR_SIZE = 16

# Link attempt log columns (recording): what the byte-level checker replays.
LA_STEP = 0
LA_LOST = 1
LA_CORRUPT = 2
LA_FLIP = 3  # which bit (a uniform in [0, 1)) when corrupted
LA_ARRIVAL = 4
LA_STALE = 5
LA_SIZE = 6

# Counters of the recording arrays.
RC_STEPS = 0
RC_COMMANDS = 1
RC_ATTEMPTS = 2
RC_DELIVERIES = 3
RC_SIZE = 4

_STREAMS = np.array(
    [
        Stream.SENSOR_JITTER,
        Stream.SENSOR_MISS,
        Stream.DOPPLER,
        Stream.RADIO_LOSS,
        Stream.RADIO_LATENCY,
        Stream.RADIO_CYCLE,
        Stream.RADIO_CORRUPT,
        Stream.TC_BOUNDARY,
        Stream.TC_DELAY,
        Stream.DRIVER,
        Stream.STOP_SENSORS,
    ],
    dtype=np.int64,
)
(
    _K_JITTER,
    _K_MISS,
    _K_DOPPLER,
    _K_LOSS,
    _K_LATENCY,
    _K_CYCLE,
    _K_CORRUPT,
    _K_TC_BOUNDARY,
    _K_TC_DELAY,
    _K_DRIVER,
    _K_STOP_SENSORS,
) = range(11)

# SPEC §2 positioning parameters of ``ato-corrected`` (FixesLine as a vector).
FP_DELAY_MEAN = 0
FP_DELAY_SPREAD = 1
FP_FIX_VAR = 2
FP_LEARN = 3
FP_SCALE_PRIOR_VAR = 4
FP_DELAY_PRIOR_VAR = 5
FP_MAX_EXTRAPOLATION = 6
FP_GATE_SIGMA2 = 7
FP_GNSS_COUNTS = 8
FP_SIZE = 9


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
        out[TEL_EMERGENCY] = 1.0
        return
    for j in range(TEL_SIZE):
        if j == TEL_DETECTOR:
            out[j] = tele[j]
        elif j == TEL_EMERGENCY:
            out[j] = 0.0
        elif j in (TEL_NOTCH, TEL_DELTA):
            out[j] = tele[j] if carried[j] > 0 else 0.0
        elif carried[j] == 0:
            out[j] = np.nan
        elif quant[j] > 0.0:
            out[j] = np.rint(tele[j] * quant[j]) / quant[j]
        else:
            out[j] = tele[j]
    if form == 4:
        measured = np.rint(tele[TEL_MEASURED] * quant[TEL_MEASURED]) / quant[TEL_MEASURED]
        # [interpretation] The passage is never after the measurement that reports it: the step's
        # passage is time-stamped within the step (and the sensor's jitter) while the wayside
        # computes at the step's start; the codec's age field is unsigned (tasc_link agrees).
        age = max(0.0, np.rint((tele[TEL_MEASURED] - tele[TEL_PASSAGE]) * quant_age) / quant_age)
        out[TEL_MEASURED] = measured
        out[TEL_SPEED] = np.rint(tele[TEL_SPEED] * quant[TEL_SPEED]) / quant[TEL_SPEED]
        out[TEL_PASSAGE] = measured - age


@njit_inline
def own_command_1(
    notch: int, pwm_train: bool, table: FloatArray, pwm_duty: FloatArray, pwm_decel: FloatArray
) -> tuple[float, float]:
    """The train's own brake command (SPEC §1; tasc.initial_brake_notch) as (duty, deceleration
    demanded): a step, or on a PWM train that step's deceleration as a duty (NaN on a step train).
    It changes only at the zone's transponders, so it is computed when it changes, not every step."""
    if pwm_train:
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
    limit: float,
    lamp: int,
) -> int:
    """Record a correction of the detailed stop: a wait at the stand, then the move at walking pace."""
    total = wait + duration
    n = int(np.ceil(total / dt))
    forward = move > 0.0
    for i in range(1, n + 1):
        if rows >= trace.shape[0]:
            return rows
        tau = min(i * dt, total)
        moving = tau > wait
        gone = creep_position_1(abs(move), rs, tau - wait) if moving else 0.0
        speed = 0.0
        if moving:
            speed = (creep_position_1(abs(move), rs, min(tau - wait + dt, duration)) - gone) / dt
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


@njit_step
def _simulate_run(
    row: int,
    run: int,
    keys0: np.ndarray,
    kp: np.ndarray,
    sc: np.ndarray,
    bp: np.ndarray,
    gv: np.ndarray,
    ge: np.ndarray,
    table: np.ndarray,
    pwm_duty: np.ndarray,
    pwm_decel: np.ndarray,
    det_pos: np.ndarray,
    det_to_stop: np.ndarray,
    transponders: np.ndarray,
    wp: np.ndarray,
    rp: np.ndarray,
    ap: np.ndarray,
    ext: np.ndarray,
    quant: np.ndarray,
    carried: np.ndarray,
    fp: np.ndarray,
    tc_ids: np.ndarray,
    tc_starts: np.ndarray,
    tc_sd: np.ndarray,
    db_ids: np.ndarray,
    db_starts: np.ndarray,
    db_sd: np.ndarray,
    fx: np.ndarray,
    fxi: np.ndarray,
    flog: np.ndarray,
    fbound: np.ndarray,
    fdelay: np.ndarray,
    levels: np.ndarray,
    rs: np.ndarray,
    code_pos: np.ndarray,
    code_lim: np.ndarray,
    lamp_table: np.ndarray,
    dr: np.ndarray,
    dv: np.ndarray,
    sv: np.ndarray,
    ring: np.ndarray,
    dbuf: np.ndarray,
    tach: np.ndarray,
    pass_t: np.ndarray,
    pass_x: np.ndarray,
    wh_v: np.ndarray,
    wh_e: np.ndarray,
    rh_v: np.ndarray,
    rh_e: np.ndarray,
    taus: np.ndarray,
    weights: np.ndarray,
    mod: np.ndarray,
    ws: np.ndarray,
    rx: np.ndarray,
    at: np.ndarray,
    tele: np.ndarray,
    pending: np.ndarray,
    fl_arr: np.ndarray,
    fl_seq: np.ndarray,
    crow: np.ndarray,
    res: np.ndarray,
    passages: np.ndarray,
    record: bool,
    trace: np.ndarray,
    cmds: np.ndarray,
    sends: np.ndarray,
    attempts: np.ndarray,
    deliveries: np.ndarray,
    counters: np.ndarray,
) -> None:
    dt = kp[KP_DT]
    steps = int(kp[KP_STEPS])
    controller = int(kp[KP_CONTROLLER])
    is_driver = controller >= CTRL_DRIVER_ATS
    is_ato = controller >= CTRL_ATO and not is_driver
    onboard_only = is_ato or is_driver  # no wayside unit, no link
    stop_point = kp[KP_STOP]
    grad = (bp, gv, ge)
    k_jitter = stream_key(keys0[_K_JITTER], run)
    k_miss = stream_key(keys0[_K_MISS], run)
    k_doppler = stream_key(keys0[_K_DOPPLER], run)
    k_loss = stream_key(keys0[_K_LOSS], run)
    k_latency = stream_key(keys0[_K_LATENCY], run)
    k_cycle = stream_key(keys0[_K_CYCLE], run)
    k_corrupt = stream_key(keys0[_K_CORRUPT], run)

    # Masses: actual static and effective mass, and the effective mass the ECU believes (load weighing).
    static = kp[KP_TARE] + sc[SC_LOAD] * kp[KP_CRUSH]
    rotating = kp[KP_TARE] * kp[KP_ROTATING]
    effective = static + rotating
    believed = static * (1.0 + sc[SC_WEIGHING_ERROR]) + rotating
    entry = sc[SC_ENTRY_SPEED]
    x = det_pos[0] - max(20.0, entry * 1.5)
    if is_driver:
        # [interpretation] a driver's run starts far enough before the home signal to meet its codes.
        x = min(x, kp[KP_HOME] - kp[KP_START_BEFORE_HOME])
    v = entry
    accel = 0.0
    stopped = False
    stop_time = np.nan
    sliding = False
    # The odometer assumes the actual diameter with its error (assumed = actual x (1 + error)).
    wheel = sc[SC_WHEEL_D]
    assumed = wheel * (1.0 + sc[SC_ODO_ERROR])
    tach_scale = assumed / wheel
    ssr = kp[KP_SLIDE_SLIP]

    # Actuator: dead time (whole steps), jerk limiter, first-order lag.
    delay_steps = int(np.rint(sc[SC_DEAD_TIME] / dt))
    for j in range(ring.size):
        ring[j] = 0.0
    limited = 0.0
    output = 0.0
    lag_alpha = 1.0 - np.exp(-dt / sc[SC_TAU])
    jerk_step = kp[KP_JERK] * dt

    # The units of this controller: the ATO, or the wayside unit and the receiver (both own the
    # one modulator state).
    k_driver = stream_key(keys0[_K_DRIVER], run)
    atc = kp[KP_ATC] > 0.0
    incapacitated = kp[KP_INCAPACITATED] > 0.0
    eb_cause = 0.0
    eb_t = np.nan
    limit_now = kp[KP_APPROACH_LIMIT]
    code_next = 0
    if is_ato:
        ato_init_1(at, mod)
    elif is_driver:
        # SPEC §3: the run's driver and the train's ATS / ATC supervision.
        driver_draw_1(dr, levels, k_driver)
        driver_init_1(dv)
        supervision_init_1(sv)
    else:
        wayside_init_1(ws, wp, wh_v, wh_e, pass_t, pass_x)
        receiver_init_1(rx, mod, rh_v, rh_e)
    # The train's own control around TASC (station.tasc.initial_brake_notch): its initial brake
    # step from the zone's first transponder on (0 before it, and with none).
    own_notch = 0
    corrected_positioning = controller == CTRL_ATO_CORRECTED
    config = int(rp[RP_CONFIG])
    pwm_train = config in (CFG_PWM, CFG_SWITCHED_PWM)
    own_duty = np.nan
    own_demand = np.nan
    own_for = -1  # the own notch own_duty and own_demand were computed for (-1: none yet)
    switch_pos = -1
    if corrected_positioning:
        # SPEC §2: no transponders; the position comes from track-circuit corrections. Before the
        # simulated approach the train was corrected at the last circuit boundary behind it.
        belief = fixes_init_run(
            fx,
            fxi,
            flog,
            fbound,
            fdelay,
            tc_starts,
            tc_sd,
            fp[FP_DELAY_MEAN],
            fp[FP_DELAY_SPREAD],
            stream_key(keys0[_K_TC_BOUNDARY], run),
            stream_key(keys0[_K_TC_DELAY], run),
            x,
            entry,
            tach_scale,
            fp[FP_FIX_VAR],
            fp[FP_LEARN] > 0.0,
            fp[FP_SCALE_PRIOR_VAR],
            fp[FP_DELAY_PRIOR_VAR],
        )
        ato_fix_1(at, stop_point - belief)
    # The link (SPEC §5 media, EN 50159 layer): the latest command is sent cyclically, a copy
    # every repeat period, until the train stands (the train discards copies it already has; a
    # copy is its life sign). Frames in the air: arrival times and attempt numbers (the safety
    # layer's sequence order); a newer command supersedes the copies of the old one in the air.
    pending_id = 0  # the command the pending telegram carries (1, 2, ...)
    applied_id = 0  # the newest command the receiver has taken
    n_fl = 0
    last_seq = -1  # the newest attempt delivered (the safety layer delivers only newer ones)
    next_try_s = np.inf
    first_rx_s = np.inf
    outage_len = sc[SC_OUTAGE_LEN]
    attempt = 0
    losses = 0
    miss_trials = 0
    misses = 0
    loss_p = sc[SC_LOSS]
    ber = sc[SC_BER]
    corrupt_p = -np.expm1(kp[KP_FRAME_BITS] * np.log1p(-ber)) if ber > 0.0 else 0.0
    latency = sc[SC_LATENCY]
    jitter = sc[SC_JITTER]
    cycle = kp[KP_CYCLE]

    has_doppler = kp[KP_HAS_DOPPLER] > 0.0 and not onboard_only
    noise = sc[SC_DOPPLER_NOISE]
    reach = kp[KP_DOPPLER_REACH]
    radar_range = kp[KP_DOPPLER_RANGE]
    n_det = det_pos.size
    for j in range(n_det):
        passages[j] = np.nan

    odo_step = 0.0
    eb = False
    max_jerk = 0.0
    slid = False
    prev_accel = 0.0
    prev_counted = False
    notch_changes = 0
    prev_notch = 0
    passed = False
    det_idx = 0
    pass_s = 0.0
    sensor_next = 0
    truth_next = 0
    transponder_next = 0
    n_cmd = 0
    n_att = 0
    n_del = 0
    k = 0
    for k in range(steps):
        t = k * dt
        # Sensors: a Doppler sample now (the radar sees trains within its range).
        doppler = np.nan
        if has_doppler:
            # Keyed by the step, so a sample outside the radar's range need not be drawn.
            in_range = (reach - x) <= radar_range
            doppler = 0.0
            if in_range:
                doppler = v * (1.0 + noise * key_normal_zig(k_doppler, k)) if noise > 0.0 else v
        # The tachometer's speed: wheel speed (slower when sliding) with the assumed diameter.
        tach_v = v * creep_1(sliding, ssr) * tach_scale
        if is_ato:
            notch = ato_output_1(at, ap, mod, table, ext, grad, k, tach_v)
            duty = np.nan
            braking = at[AT_BRAKING] > 0.0
        elif is_driver:
            # SPEC §3: the code held since the last point (ATS) / picked up here (ATC).
            while code_next < code_pos.size and x >= code_pos[code_next]:
                limit_now = code_lim[code_next]
                code_next += 1
            # The supervision judges the speedometer's speed (the tachometer's).
            supervise_1(sv, atc, kp[KP_GRACE], kp[KP_ATC_MARGIN], tach_v, limit_now, t)
            eb = sv[SV_EB] > 0.0
            if eb and eb_cause == 0.0:
                eb_cause = sv[SV_EB]
                eb_t = t
            driver_look_1(
                dv,
                dr,
                table,
                k_driver,
                t,
                x,
                tach_v,
                accel,
                stop_point,
                rs[RS_JUDGEMENT_FLOOR],
                code_pos,
                code_lim,
                limit_now,
                incapacitated,
                wp[WP_INITIAL_DELAY],
            )
            notch, holding = driver_output_1(dv, t)
            duty = np.nan
            braking = not holding or eb
        else:
            # Wayside unit -> link -> onboard receiver.
            due = wayside_step_1(
                ws, wp, dbuf, pass_t, pass_x, det_pos, wh_v, wh_e, taus, weights, det_to_stop, table,
                pwm_duty, pwm_decel, ext, grad, t, passed, det_idx, pass_s, doppler, tele, crow,
            )  # fmt: skip
            if due:
                # A newer telegram replaces the one not yet delivered (the wayside sends only its latest).
                quantize_telegram_1(tele, pending, quant, carried, int(wp[WP_FORM]), kp[KP_QUANT_AGE])
                pending_id += 1
                n_fl = 0
                next_try_s = -np.inf
                if record:
                    for j in range(CR_SIZE):
                        cmds[n_cmd, j] = crow[j]
                    cmds[n_cmd, CR_SIZE] = k
                    for j in range(TEL_SIZE):
                        sends[n_cmd, j] = pending[j]
                    n_cmd += 1
            if next_try_s <= t + 1e-9:
                # A transmission attempt (SPEC §5 media; the run's streams decide, counter = attempt).
                c = attempt
                attempt += 1
                lost = key_uniform(k_loss, c) < loss_p
                losses += lost
                # A radio outage (a fault of the data: SC_OUTAGE_*) loses every frame sent in it.
                rel = t - first_rx_s - sc[SC_OUTAGE_START]
                lost = lost or (outage_len > 0.0 and rel >= -1e-9 and rel < outage_len)
                corrupt = False
                if ber > 0.0 and not lost:
                    corrupt = key_uniform(k_corrupt, 2 * c) < corrupt_p
                u = key_uniform(k_cycle, c) if cycle > 0.0 else 0.0
                z = key_normal(k_latency, c) if jitter > 0.0 else 0.0
                arrival = t + (u * cycle + kp[KP_AIRTIME] + max(0.0, latency + jitter * z))
                # The step that receives the frame, and the safety layer's age check there (ms).
                receive_s = np.ceil((arrival - 1e-9) / dt) * dt
                stale = np.rint(receive_s * 1000.0) - np.rint(t * 1000.0) > kp[KP_MAX_AGE] * 1000.0
                if not (lost or corrupt or stale) and n_fl < fl_arr.size:
                    fl_arr[n_fl] = arrival
                    fl_seq[n_fl] = c
                    n_fl += 1
                next_try_s = t + kp[KP_REPEAT]
                if record:
                    attempts[n_att, LA_STEP] = k
                    attempts[n_att, LA_LOST] = lost
                    attempts[n_att, LA_CORRUPT] = corrupt
                    attempts[n_att, LA_FLIP] = key_uniform(k_corrupt, 2 * c + 1) if corrupt else np.nan
                    attempts[n_att, LA_ARRIVAL] = arrival
                    attempts[n_att, LA_STALE] = stale
                    n_att += 1
            # Frames arrived by now, in sending order: the safety layer delivers a frame only if
            # it is newer than the last one delivered (an overtaken frame is out of order).
            delivered = False
            m = 0
            for j in range(n_fl):
                if fl_arr[j] <= t + 1e-9:
                    if fl_seq[j] > last_seq:
                        last_seq = fl_seq[j]
                        delivered = True
                        if record:  # one entry per frame delivered
                            deliveries[n_del] = k
                            n_del += 1
                else:
                    fl_arr[m] = fl_arr[j]
                    fl_seq[m] = fl_seq[j]
                    m += 1
            n_fl = m
            copy = delivered and applied_id == pending_id  # a copy of the command the train has
            new = delivered and not copy
            if new:
                applied_id = pending_id
                first_rx_s = min(first_rx_s, t)
            if own_notch != own_for:
                own_duty, own_demand = own_command_1(own_notch, pwm_train, table, pwm_duty, pwm_decel)
                own_for = own_notch
            notch, duty, eb, switch_pos = receiver_cycle_1(
                rx, rp, mod, tach, rh_v, rh_e, taus, table, pwm_duty, pwm_decel, det_to_stop, ext, grad,
                pending, t, k, new, copy, tach_v, odo_step, own_notch, own_duty,
            )  # fmt: skip
            braking = np.isfinite(rx[RX_FIRST_RX]) or eb or own_notch > 0
        # Onboard -> ECU (step code through the brake line, or PWM) -> actuator -> brakes.
        if notch >= 0:
            ecu_notch = line_notch(notch)
            demand = table[ecu_notch]
            if ecu_notch != prev_notch and not stopped:
                notch_changes += 1
            prev_notch = ecu_notch
        else:
            ecu_notch = -1
            demand = pwm_to_decel_1(duty, pwm_duty, pwm_decel)
        if eb:
            demand = kp[KP_EMERGENCY]  # wire e: the emergency brake, whatever the service command
        limited, output = actuator_step_1(
            ring, k, delay_steps, demand, limited, output, lag_alpha, jerk_step, kp[KP_EMERGENCY]
        )
        # Load compensation: the ECU sets the force for the mass it believes; the real mass and
        # the brake's real effectiveness decide what that force does.
        brake_decel = output * sc[SC_BRAKE_GAIN] * believed / effective
        in_patch = x >= sc[SC_LOW_START] and x < sc[SC_LOW_END]
        mu = sc[SC_LOW_MU] if in_patch else sc[SC_MU]
        x0 = x
        v0 = v
        hold = not braking
        x, v, accel, now_stopped, st, sliding = motion_step_1(
            x,
            v,
            stopped,
            brake_decel,
            mean_gradient_1(x, kp[KP_LENGTH], bp, gv, ge),
            mu,
            hold,
            static,
            effective,
            kp[KP_DAVIS_A],
            kp[KP_DAVIS_B],
            kp[KP_DAVIS_C],
            t,
            dt,
        )
        if now_stopped and not stopped:
            stop_time = st
        stopped = now_stopped
        if sliding and not stopped:
            slid = True
        # Jerk while moving under braking (not across the traction cut-off or the standstill step).
        counted = not hold and not stopped
        jerk = abs(accel - prev_accel) / dt
        if counted and prev_counted:
            max_jerk = max(max_jerk, jerk)
        prev_accel = accel
        prev_counted = counted
        # True passages (for the record) and the detectors' reports (for the wayside).
        if passage_1(det_pos, truth_next, x0, x):
            passages[truth_next] = t + crossing_time_1(x0, v0, accel, det_pos[truth_next])
            truth_next += 1
        # Odometer: wheel revolutions x pi x assumed diameter (SPEC §2).
        revs = (x - x0) * creep_1(sliding, ssr) / (np.pi * wheel)
        odometer = revs * np.pi * assumed
        odo_step = odometer
        if is_ato:
            ato_odometer_1(at, odometer)
            if corrected_positioning:
                corrected, calibrated = fixes_step_run(
                    fx,
                    fxi,
                    flog,
                    fbound,
                    fdelay,
                    tc_ids,
                    db_ids,
                    db_starts,
                    db_sd,
                    fp[FP_DELAY_SPREAD],
                    fp[FP_LEARN] > 0.0,
                    fp[FP_MAX_EXTRAPOLATION],
                    fp[FP_GATE_SIGMA2],
                    fp[FP_GNSS_COUNTS],
                    t,
                    dt,
                    x0,
                    v0,
                    accel,
                    x,
                    odometer,
                    v * creep_1(sliding, ssr) * tach_scale,
                    sliding,
                    sc[SC_LATENCY],
                )
                if corrected:
                    ato_fix_1(at, stop_point - calibrated)
            elif passage_1(transponders, transponder_next, x0, x):
                ato_fix_1(at, stop_point - transponders[transponder_next])
                transponder_next += 1
        elif not is_driver:  # a driver judges by eye (driver_look_1); his speedometer is the tachometer
            # The train's own ATP resets its odometer at the transponders; at the first one (the
            # zone's start) its brake controller applies the initial brake step.
            if passage_1(transponders, transponder_next, x0, x):
                receiver_fix_1(rx, rp, transponders[transponder_next])
                transponder_next += 1
                own_notch = int(kp[KP_INITIAL_NOTCH])
            passed = False
            if passage_1(det_pos, sensor_next, x0, x):
                det_idx = sensor_next
                pass_s = (
                    t
                    + crossing_time_1(x0, v0, accel, det_pos[det_idx])
                    + sc[SC_SENSOR_JITTER] * key_normal(k_jitter, det_idx)
                )
                passed = key_uniform(k_miss, det_idx) >= sc[SC_MISS]
                miss_trials += 1
                misses += not passed
                sensor_next += 1
        if record:
            trace[k, TR_T] = t + dt
            trace[k, TR_X] = x
            trace[k, TR_V] = v
            if is_ato:
                trace[k, TR_TARGET] = at[AT_TARGET] if at[AT_ACTIVE] > 0.0 else np.nan
            elif is_driver:
                trace[k, TR_TARGET] = dv[DV_REQUIRED]
            else:
                trace[k, TR_TARGET] = rx[RX_TARGET] if rx[RX_ACTIVE] > 0.0 else np.nan
            trace[k, TR_DEMAND] = demand
            trace[k, TR_BRAKE] = 0.0 if stopped else brake_decel
            trace[k, TR_ACCEL] = accel
            trace[k, TR_NOTCH] = ecu_notch
            trace[k, TR_DUTY] = duty
            trace[k, TR_OWN] = own_demand
            trace[k, TR_SWITCH] = switch_pos if switch_pos >= 0 else np.nan
            trace[k, TR_SLIDE] = 1.0 if sliding and not stopped else 0.0
            if is_driver:
                trace[k, TR_LIMIT] = limit_now
                trace[k, TR_ACTION] = dv[DV_ACTION]
                trace[k, TR_SUPERVISION] = 2.0 if eb else sv[SV_ALARM]
                trace[k, TR_LAMP] = 0.0
            else:
                for j in (TR_LIMIT, TR_ACTION, TR_SUPERVISION, TR_LAMP):
                    trace[k, j] = np.nan
        if stopped:
            break
    rows = k + 1
    first_error = x - stop_point
    restops = 0
    lamp = 0
    if is_driver and stopped:
        # SPEC §3 lamps at the stand, and the driver's corrections (F: forward, R: reverse).
        k_sensors = stream_key(keys0[_K_STOP_SENSORS], run)
        lamp = _stand_lamp_1(x, kp, lamp_table, k_sensors, 0)
        t_end = stop_time
        setup = rs[RS_EB_RESET] if eb_cause > 0.0 else 0.0
        while lamp in (LAMP_F, LAMP_R) and restops < int(rs[RS_MAX]) and not incapacitated:
            wait = dr[DR_REACTION] + setup + (rs[RS_REVERSE_SETUP] if lamp == LAMP_R else 0.0)
            setup = 0.0
            judged = abs(restop_judgement_1(rs, k_driver, restops, stop_point - x))
            move = judged if lamp == LAMP_F else -judged
            duration = creep_time_1(judged, rs)
            if record:
                rows = _record_move(
                    trace,
                    rows,
                    dt,
                    t_end,
                    x,
                    move,
                    wait,
                    duration,
                    rs,
                    limit_now,
                    lamp,
                )
            x += move
            t_end += wait + duration
            restops += 1
            lamp = _stand_lamp_1(x, kp, lamp_table, k_sensors, restops)
        stop_time = t_end
        if record and rows < trace.shape[0]:
            for j in range(TR_SIZE):
                trace[rows, j] = trace[rows - 1, j]
            trace[rows, TR_T] = t_end
            trace[rows, TR_X] = x
            trace[rows, TR_ACTION] = ACT_DONE
            trace[rows, TR_LAMP] = lamp
            rows += 1
    res[RES_ERROR] = x - stop_point
    res[RES_STOP_TIME] = stop_time - passages[0] if stopped else np.nan
    res[RES_MAX_JERK] = max_jerk
    res[RES_NOTCH_CHANGES] = notch_changes
    res[RES_SENT] = 0.0 if onboard_only else ws[WS_SENT]
    res[RES_RECEIVED] = 0.0 if onboard_only else rx[RX_RECEIVED]
    res[RES_STOPPED] = stopped
    res[RES_SLID] = slid
    res[RES_MISS_TRIALS] = miss_trials
    res[RES_MISSES] = misses
    res[RES_LOSS_TRIALS] = attempt
    res[RES_LOSSES] = losses
    if is_driver:
        res[RES_EB] = eb_cause
        res[RES_EB_T] = eb_t - passages[0]
    else:
        res[RES_EB] = 0.0 if is_ato else rx[RX_EB]
        res[RES_EB_T] = np.nan if is_ato else rx[RX_EB_T] - passages[0]
    identified = not onboard_only and np.isfinite(ws[WS_ID_GAIN])
    res[RES_ID_DELAY] = ws[WS_DELAY] if identified else np.nan
    res[RES_ID_LAG] = ws[WS_LAG] if identified else np.nan
    res[RES_FILLED] = 0.0 if onboard_only else ws[WS_FILLED]
    res[RES_FIRST_ERROR] = first_error
    res[RES_RESTOPS] = restops
    res[RES_LAMP] = lamp
    res[RES_LEVEL] = dr[DR_LEVEL] if is_driver else -1.0
    if record:
        counters[RC_STEPS] = rows
        counters[RC_COMMANDS] = n_cmd
        counters[RC_ATTEMPTS] = n_att
        counters[RC_DELIVERIES] = n_del


@njit
def simulate_block(
    seed: np.uint64,
    first_run: int,
    kp: np.ndarray,
    sc: np.ndarray,
    bp: np.ndarray,
    gv: np.ndarray,
    ge: np.ndarray,
    table: np.ndarray,
    pwm_duty: np.ndarray,
    pwm_decel: np.ndarray,
    det_pos: np.ndarray,
    det_to_stop: np.ndarray,
    transponders: np.ndarray,
    wp: np.ndarray,
    rp: np.ndarray,
    ap: np.ndarray,
    ext: np.ndarray,
    quant: np.ndarray,
    carried: np.ndarray,
    fp: np.ndarray,
    tc_ids: np.ndarray,
    tc_starts: np.ndarray,
    tc_sd: np.ndarray,
    db_ids: np.ndarray,
    db_starts: np.ndarray,
    db_sd: np.ndarray,
    levels: np.ndarray,
    rs: np.ndarray,
    code_pos: np.ndarray,
    code_lim: np.ndarray,
    lamp_table: np.ndarray,
    log_len: int,
    window: int,
    tach_window: int,
    ring_size: int,
    res: np.ndarray,
    passages: np.ndarray,
    record: bool,
    trace: np.ndarray,
    cmds: np.ndarray,
    sends: np.ndarray,
    attempts: np.ndarray,
    deliveries: np.ndarray,
    counters: np.ndarray,
) -> None:
    """Simulate runs ``first_run .. first_run + n - 1`` (rows of ``sc``), one after another."""
    keys0 = np.empty(_STREAMS.size, dtype=np.uint64)
    for i in range(_STREAMS.size):
        keys0[i] = seed_key(seed, _STREAMS[i])
    ring = np.zeros(ring_size)
    dbuf = np.zeros(window)
    tach = np.zeros(tach_window)
    pass_t = np.empty(3)
    pass_x = np.empty(3)
    wh_v = np.empty(HISTORY)
    wh_e = np.empty(HISTORY)
    rh_v = np.empty(HISTORY)
    rh_e = np.empty(HISTORY)
    taus = np.empty(SAMPLES)
    weights = np.empty(SAMPLES)
    mod = np.empty(MOD_SIZE)
    ws = np.empty(WS_SIZE)
    rx = np.empty(RX_SIZE)
    at = np.empty(AT_SIZE)
    tele = np.empty(TEL_SIZE)
    pending = np.full(TEL_SIZE, np.nan)
    fl_arr = np.empty(max(int(kp[KP_IN_FLIGHT]), 1))
    fl_seq = np.empty(max(int(kp[KP_IN_FLIGHT]), 1), dtype=np.int64)
    crow = np.empty(CR_SIZE)
    fx = np.empty(FX_SIZE)
    fxi = np.empty(FXI_SIZE, dtype=np.int64)
    flog = np.empty((LOG_ROWS, log_len))
    fbound = np.empty(tc_starts.size)
    fdelay = np.empty(tc_starts.size)
    dr = np.empty(DR_SIZE)
    dv = np.empty(DV_SIZE)
    sv = np.empty(SV_SIZE)
    for r in range(sc.shape[0]):
        rec = record and r == 0
        _simulate_run(
            r,
            first_run + r,
            keys0,
            kp,
            sc[r],
            bp,
            gv[r],
            ge[r],
            table,
            pwm_duty,
            pwm_decel,
            det_pos,
            det_to_stop,
            transponders,
            wp,
            rp,
            ap,
            ext,
            quant,
            carried,
            fp,
            tc_ids,
            tc_starts,
            tc_sd,
            db_ids,
            db_starts,
            db_sd,
            fx,
            fxi,
            flog,
            fbound,
            fdelay,
            levels,
            rs,
            code_pos,
            code_lim,
            lamp_table,
            dr,
            dv,
            sv,
            ring,
            dbuf,
            tach,
            pass_t,
            pass_x,
            wh_v,
            wh_e,
            rh_v,
            rh_e,
            taus,
            weights,
            mod,
            ws,
            rx,
            at,
            tele,
            pending,
            fl_arr,
            fl_seq,
            crow,
            res[r],
            passages[r],
            rec,
            trace,
            cmds,
            sends,
            attempts,
            deliveries,
            counters,
        )


# --------------------------------------------------------------------------
# The Python side: pack data into arrays, call the kernel, unpack.

CONTROLLER_CODES: dict[str, int] = {
    **CONFIG_CODES,
    "ato": CTRL_ATO,
    "ato-corrected": CTRL_ATO_CORRECTED,
    DRIVER_ATS: CTRL_DRIVER_ATS,
    DRIVER_ATC1: CTRL_DRIVER_ATC1,
    DRIVER_ATC2: CTRL_DRIVER_ATC2,
    DRIVER_UNAIDED: CTRL_DRIVER_UNAIDED,
}
# Each driver controller's approach (config.platform Approach) and supervision (True: ATC).
_DRIVER_MODES: dict[str, tuple[str, bool]] = {
    DRIVER_ATS: ("ats", False),
    DRIVER_ATC1: ("atc1", True),
    DRIVER_ATC2: ("atc2", True),
    DRIVER_UNAIDED: ("unaided", False),
}
START_BEFORE_HOME_M = 300.0


@dataclass(frozen=True, slots=True)
class KernelModel:
    """Everything the kernel needs of a station, vehicle, controller and form, as arrays."""

    kp: FloatArray
    table: FloatArray
    pwm_duty: FloatArray
    pwm_decel: FloatArray
    det_pos: FloatArray
    det_to_stop: FloatArray
    transponders: FloatArray
    wp: FloatArray
    rp: FloatArray
    ap: FloatArray
    ext: FloatArray
    quant: FloatArray
    carried: FloatArray
    window: int
    tach_window: int
    form: SignalForm
    controller: str
    # SPEC §2 positioning of ato-corrected (one empty circuit for the other controllers).
    fp: FloatArray
    tc_ids: IntArray
    tc_starts: FloatArray
    tc_sd: FloatArray
    db_ids: IntArray
    db_starts: FloatArray
    db_sd: FloatArray
    log_len: int
    # SPEC §3 manual driving (one-row placeholders for the other controllers).
    levels: FloatArray
    rs: FloatArray
    code_pos: FloatArray
    code_lim: FloatArray
    lamp_table: FloatArray

    @classmethod
    def create(
        cls,
        *,
        station: Station,
        vehicle: Vehicle,
        controller: str,
        form: SignalForm | None,
        dt_s: float,
        max_time_s: float,
        track: Track | None = None,
        driver: DriverFile | None = None,
        platform: PlatformFile | None = None,
        incapacitated: bool = False,
    ) -> KernelModel:
        """``driver``, ``platform``: the driver controllers' data (None: the embedded defaults);
        ``incapacitated``: their driver never brakes (the supervision check of SPEC §3)."""
        if controller not in CONTROLLER_CODES:
            raise SimulationError(
                f"unknown controller {controller!r}; choose one of: {', '.join(CONTROLLER_CODES)}"
            )
        tasc = station.tasc
        form = SignalForm(tasc.signal_form if form is None else form)
        radar = tasc.doppler
        if radar is not None and abs(radar.sample_period_s - dt_s) > 1e-12:
            raise SimulationError(
                f"station {station.name}: tasc.doppler.sample_period_s = "
                f"{radar.sample_period_s} must equal the simulation step {dt_s} s"
            )
        try:
            medium = media_preset(tasc.medium)
        except RailstopError as exc:
            raise SimulationError(f"station {station.name}: tasc.medium: {exc}") from None
        brake = vehicle.brake
        n_bytes = frame_bytes(form, tasc.safety_category)
        kp = np.zeros(KP_SIZE)
        kp[KP_DT] = dt_s
        kp[KP_STEPS] = round(max_time_s / dt_s)
        kp[KP_CONTROLLER] = CONTROLLER_CODES[controller]
        kp[KP_STOP] = station.stop_point_m
        kp[KP_TARE] = vehicle.tare_mass_kg
        kp[KP_CRUSH] = vehicle.crush_payload_kg
        kp[KP_ROTATING] = vehicle.rotating_mass_factor
        kp[KP_DAVIS_A] = vehicle.davis_a_n
        kp[KP_DAVIS_B] = vehicle.davis_b_n_per_mps
        kp[KP_DAVIS_C] = vehicle.davis_c_n_per_mps2
        kp[KP_LENGTH] = vehicle.length_m
        kp[KP_SLIDE_SLIP] = vehicle.slide_slip_ratio
        kp[KP_JERK] = brake.jerk_limit_mps3
        kp[KP_EMERGENCY] = brake.emergency_decel_mps2
        kp[KP_HAS_DOPPLER] = radar is not None
        kp[KP_DOPPLER_REACH] = station.stop_point_m + (radar.beyond_stop_m if radar is not None else 0.0)
        kp[KP_DOPPLER_RANGE] = radar.range_m if radar is not None else 0.0
        kp[KP_REPEAT] = tasc.repeat_period_s
        kp[KP_CYCLE] = medium.cycle_s
        kp[KP_AIRTIME] = float(airtime_s(medium, n_bytes))
        kp[KP_FRAME_BITS] = 8.0 * n_bytes
        kp[KP_MAX_AGE] = tasc.max_telegram_age_s
        # A frame older than the maximum age is refused, so no more than this many are in the air.
        kp[KP_IN_FLIGHT] = int(np.ceil(tasc.max_telegram_age_s / tasc.repeat_period_s)) + 2
        quant, carried, quant_age = _quantization(form)
        kp[KP_QUANT_AGE] = quant_age
        kp[KP_INITIAL_NOTCH] = tasc.initial_brake_notch
        det_to_stop = np.asarray(tasc.detectors_before_stop_m, dtype=np.float64)
        wp = np.zeros(WP_SIZE)
        wp[WP_FORM] = int(form)
        wp[WP_HAS_DOPPLER] = radar is not None
        wp[WP_CONTINUOUS] = tasc.update == "continuous"
        wp[WP_CONTINUOUS_PERIOD] = tasc.continuous_period_s
        wp[WP_DT] = dt_s
        wp[WP_SPEED_SAMPLES] = max(round(radar.speed_window_s / dt_s), 2) if radar is not None else 2
        # Equivalent dead time until a new command acts (SPEC §1: "allowing for the brake's
        # dead time and lag"): radio latency + dead time + tau.
        wp[WP_BASE_DELAY] = tasc.assumed_link_latency_s + brake.dead_time_s + brake.time_constant_s
        wp[WP_JERK] = brake.jerk_limit_mps3
        wp[WP_MAX_DECEL] = brake.full_service_mps2
        wp[WP_LAG] = brake.time_constant_s
        # Issue 13 item 6 (beyond SPEC §1): identify the brake response from the radar, a little
        # less than the radar buffer's length after the first braking command.
        # Form 6 only: with forms 1-5 the train plans its own commands (the wayside's history is
        # not what the brakes were asked for), with forms 7 and 8 the brakes follow the wayside's
        # notch modulation, whose steps the response model does not hold.
        wp[WP_IDENTIFY] = (
            radar is not None and tasc.identify_brake_response and form == SignalForm.REQUIRED_DECELERATION
        )
        wp[WP_ID_AFTER] = ID_AFTER_S
        wp[WP_FILL] = radar is not None and tasc.fill_missed_detectors
        wp[WP_FIT_SAMPLES] = max(round(radar.fit_window_s / dt_s), 2) if radar is not None else 2
        wp[WP_STOP] = station.stop_point_m
        wp[WP_END_MARGIN] = station.platform_end - station.stop_point_m
        wp[WP_GUARD_LIMIT] = tasc.overrun_guard_decel_fraction * brake.full_service_mps2
        # Forms 7, 8: the wayside modulates the notches as the train's brake controller would
        # (its cycle and minimum hold, brake data of the wayside's database, SPEC §1 claim 8).
        wp[WP_MODULATE] = form in (SignalForm.BRAKE_COMMAND, SignalForm.INCREASE_DECREASE)
        wp[WP_MOD_CYCLE] = brake.controller_cycle_s
        wp[WP_MOD_HOLD] = brake.controller_min_hold_s
        wp[WP_INITIAL_DECEL] = ([0.0, *brake.notch_decel_mps2])[tasc.initial_brake_notch]
        wp[WP_INITIAL_DELAY] = brake.dead_time_s + brake.time_constant_s
        wp[WP_STEP_SPACING] = brake.controller_min_hold_s
        if form == SignalForm.INCREASE_DECREASE:
            # One notch per step telegram: the braking builds up no faster than a notch's
            # deceleration per step spacing, which the plan treats as a jerk limit.
            notch_step = brake.full_service_mps2 / len(brake.notch_decel_mps2)
            wp[WP_JERK] = min(brake.jerk_limit_mps3, notch_step / wp[WP_STEP_SPACING])
        # The radar buffer holds the deceleration fit's samples, and those of the identification.
        window = int(wp[WP_FIT_SAMPLES])
        if wp[WP_IDENTIFY] > 0.0:
            window = max(window, round((ID_AFTER_S + ID_BEFORE_S) / dt_s) + 1)
        rcfg = controller if controller in CONFIG_CODES else "tasc-brake-controller"
        fp = np.zeros(FP_SIZE)
        no_ints = np.zeros(1, dtype=np.int64)
        no_floats = np.zeros(1)
        positioning: dict[str, Any] = {
            "tc_ids": no_ints,
            "tc_starts": no_floats,
            "tc_sd": no_floats,
            "db_ids": no_ints,
            "db_starts": no_floats,
            "db_sd": no_floats,
            "log_len": 1,
        }
        if controller == "ato-corrected":
            fl = FixesLine.create(track=track, vehicle=vehicle, dt_s=dt_s)
            fp[FP_DELAY_MEAN] = fl.delay_mean_s
            fp[FP_DELAY_SPREAD] = fl.delay_spread_s
            fp[FP_FIX_VAR] = fl.fix_var_m2
            fp[FP_LEARN] = fl.learn
            fp[FP_SCALE_PRIOR_VAR] = fl.scale_prior_var
            fp[FP_DELAY_PRIOR_VAR] = fl.delay_prior_var_s2
            fp[FP_MAX_EXTRAPOLATION] = fl.max_extrapolation_s
            fp[FP_GATE_SIGMA2] = fl.gate_sigma2
            fp[FP_GNSS_COUNTS] = fl.gnss_counts_per_s
            positioning = {
                "tc_ids": fl.tc_ids,
                "tc_starts": fl.tc_starts_m,
                "tc_sd": fl.tc_sd_m,
                "db_ids": fl.db_ids,
                "db_starts": fl.db_starts_m,
                "db_sd": fl.db_sd_m,
                "log_len": fl.log_len,
            }
        manual: dict[str, Any] = _manual_arrays(kp, controller, station, driver, platform, incapacitated)
        return cls(
            **manual,
            kp=kp,
            table=np.concatenate(([0.0], np.asarray(brake.notch_decel_mps2, dtype=np.float64))),
            pwm_duty=np.asarray(brake.pwm_duty, dtype=np.float64),
            pwm_decel=np.asarray(brake.pwm_decel_mps2, dtype=np.float64),
            det_pos=station.stop_point_m - det_to_stop,
            det_to_stop=det_to_stop,
            transponders=np.asarray(station.ato_transponders_m(), dtype=np.float64),
            wp=wp,
            rp=receiver_params(rcfg, int(form), vehicle, station, dt_s),
            ap=ato_params(vehicle, station.stop_point_m, dt_s),
            ext=external_params(vehicle, station.stop_point_m),
            quant=quant,
            carried=carried,
            window=window,
            tach_window=receiver_window(dt_s),
            form=form,
            controller=controller,
            fp=fp,
            **positioning,
        )


def _manual_arrays(
    kp: FloatArray,
    controller: str,
    station: Station,
    driver: DriverFile | None,
    platform: PlatformFile | None,
    incapacitated: bool,
) -> dict[str, FloatArray]:
    """The driver controllers' arrays (SPEC §3), and their kernel parameters set in ``kp``."""
    if controller not in _DRIVER_MODES:
        return {
            "levels": np.zeros((1, LV_PARAMS + LV_WIDTH * len(LEVEL_PARAMETERS))),
            "rs": np.zeros(RS_EB_RESET + 1),
            "code_pos": np.zeros(0),
            "code_lim": np.zeros(0),
            "lamp_table": np.zeros(4),
        }
    from railstop.config.driver import default_driver, driver_arrays
    from railstop.config.platform import default_platform
    from railstop.sensors.stop_sensors import sensor_positions

    driver = default_driver() if driver is None else driver
    platform = default_platform() if platform is None else platform
    mode, atc = _DRIVER_MODES[controller]
    approach = platform.approach
    home = platform.home_signal_m(station.stop_point_m)
    codes = getattr(approach, mode).codes
    kp[KP_HOME] = home
    kp[KP_APPROACH_LIMIT] = approach.approach_limit_kmh / 3.6
    kp[KP_GRACE] = approach.grace_s
    kp[KP_ATC] = atc
    kp[KP_ATC_MARGIN] = approach.atc_permitted_margin_kmh / 3.6
    kp[KP_INCAPACITATED] = incapacitated
    kp[KP_S2], kp[KP_S1] = sensor_positions(station.stop_point_m, platform.sensors.spacing_m)
    kp[KP_SENSOR_NOISE] = platform.sensors.noise_sd_m
    kp[KP_START_BEFORE_HOME] = START_BEFORE_HOME_M
    levels, rs = driver_arrays(driver)
    lamps = platform.lamps()
    return {
        "levels": levels,
        "rs": rs,
        "code_pos": np.array([home + c.after_home_m for c in codes], dtype=np.float64),
        "code_lim": np.array([c.limit_kmh / 3.6 for c in codes], dtype=np.float64),
        "lamp_table": np.array(
            [LAMP_CODES[lamps[(s2, s1)]] for s2 in (False, True) for s1 in (False, True)], dtype=np.float64
        ),
    }


def _quantization(form: SignalForm) -> tuple[FloatArray, FloatArray, float]:
    """Counts per unit of each telegram field on the wire (0: not fixed-point), carried flags, and
    form 4's passage-age resolution: the codec layouts decide (SPEC §5 telegrams)."""
    layout = layout_of(TASC_FORM_TYPES[int(form)])
    cpu = {f.name: float(f.counts_per_unit) for f in layout.fields if f.kind == "fixed"}
    carried_names = set(CARRIED[form])
    quant = np.zeros(TEL_SIZE)
    carried = np.zeros(TEL_SIZE)
    for j, name in enumerate(TEL_FIELDS):
        carried[j] = name in carried_names or name == "detector"
        quant[j] = cpu.get(name, 0.0)
    if form == SignalForm.SPEED:
        carried[TEL_PASSAGE] = 1.0
        quant[TEL_PASSAGE] = 0.0
    return quant, carried, cpu.get("passage_age_s", 1.0)


def scenario_arrays(scenario: Scenario) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """(sc, breakpoints, gradient values, elevations at breakpoints) of a scenario."""
    sc = np.empty((scenario.n, SC_SIZE))
    for j, name in enumerate(_SCENARIO_FIELDS):
        sc[:, j] = getattr(scenario, name)
    g = scenario.gradient
    n = scenario.n
    values = np.ascontiguousarray(np.broadcast_to(g.values_permille, (n, g.values_permille.shape[1])))
    elev = np.ascontiguousarray(np.broadcast_to(g._elev_at_bp, (n, g._elev_at_bp.shape[1])))
    return sc, np.ascontiguousarray(g.breakpoints_m, dtype=np.float64), values, elev


@dataclass(frozen=True, slots=True)
class KernelRecord:
    """What the kernel recorded of run 0 (the detailed stop)."""

    trace: FloatArray  # (steps, TR_SIZE)
    commands: FloatArray  # (k, CR_SIZE + 1): command records and the step they were sent in
    sends: FloatArray  # (k, TEL_SIZE): the telegrams as quantised for the air
    attempts: FloatArray  # (m, LA_SIZE)
    deliveries: NDArray[np.int64]  # steps at which the pending telegram was delivered


def run_kernel(
    model: KernelModel,
    scenario: Scenario,
    *,
    seed: int,
    first_run: int,
    record: bool = False,
) -> tuple[FloatArray, FloatArray, KernelRecord | None]:
    """Simulate ``scenario.n`` runs: (results (n, RES_SIZE), true passage times (n, D), record of run 0)."""
    sc, bp, gv, ge = scenario_arrays(scenario)
    if model.controller == "ato-corrected" and scenario.n:
        # The train was corrected at the last circuit boundary behind its start (SPEC §2).
        start = model.det_pos[0] - np.maximum(20.0, 1.5 * sc[:, SC_ENTRY_SPEED])
        if np.any(start < model.tc_starts[0]):
            raise SimulationError("ato-corrected: the approach starts before the first track circuit")
    n = scenario.n
    steps = int(model.kp[KP_STEPS])
    rows = steps if record else 1
    if record and model.controller in _DRIVER_MODES:
        rows *= 2  # room for the re-stops after the first standstill
    trace = np.full((rows, TR_SIZE), np.nan)
    cmds = np.zeros((rows, CR_SIZE + 1))
    sends = np.zeros((rows, TEL_SIZE))
    attempts = np.zeros((rows, LA_SIZE))
    deliveries = np.zeros(rows)
    counters = np.zeros(RC_SIZE, dtype=np.int64)
    res = np.empty((n, RES_SIZE))
    passages = np.empty((n, model.det_pos.size))
    ring_size = int(np.rint(np.max(sc[:, SC_DEAD_TIME]) / model.kp[KP_DT])) + 1 if n else 1
    simulate_block(
        seed_u64(seed),
        first_run,
        model.kp,
        sc,
        bp,
        gv,
        ge,
        model.table,
        model.pwm_duty,
        model.pwm_decel,
        model.det_pos,
        model.det_to_stop,
        model.transponders,
        model.wp,
        model.rp,
        model.ap,
        model.ext,
        model.quant,
        model.carried,
        model.fp,
        model.tc_ids,
        model.tc_starts,
        model.tc_sd,
        model.db_ids,
        model.db_starts,
        model.db_sd,
        model.levels,
        model.rs,
        model.code_pos,
        model.code_lim,
        model.lamp_table,
        model.log_len,
        model.window,
        model.tach_window,
        ring_size,
        res,
        passages,
        record,
        trace,
        cmds,
        sends,
        attempts,
        deliveries,
        counters,
    )
    rec = None
    if record:
        rec = KernelRecord(
            trace=trace[: counters[RC_STEPS]],
            commands=cmds[: counters[RC_COMMANDS]],
            sends=sends[: counters[RC_COMMANDS]],
            attempts=attempts[: counters[RC_ATTEMPTS]],
            deliveries=deliveries[: counters[RC_DELIVERIES]].astype(np.int64),
        )
    return res, passages, rec


def warm_up() -> dict[str, object]:
    """Compile the kernel (or load it from the on-disk cache) by running one short stop without and
    with recording: one compiled signature serves every controller, form and station.

    Returns what happened: whether anything was compiled, and the cache folder.
    """
    from railstop.config import default_line, default_vehicle
    from railstop.jit import cache_dir

    line, vehicle = default_line(), default_vehicle()
    station = line.stations[0]
    scenario = Scenario.nominal(station, vehicle)
    stats: Any = simulate_block.stats  # type: ignore[attr-defined]
    misses_before = sum(stats.cache_misses.values())
    model = KernelModel.create(
        station=station, vehicle=vehicle, controller="tasc-pwm", form=None, dt_s=0.01, max_time_s=150.0
    )
    for record in (False, True):
        run_kernel(model, scenario, seed=0, first_run=0, record=record)
    compiled = sum(stats.cache_misses.values()) > misses_before
    return {"compiled": compiled, "cache_dir": str(cache_dir())}
