"""The station stop's records (DESIGN rule 2): its parameters, state and outputs as a few named records.

The stop step (:mod:`railstop.model.step`) takes four records, each a
``NamedTuple`` whose fields a reader (and numba) sees by name:

- :class:`StopParams`, the station/line parameters shared by every run of a
  block (:class:`~railstop.model.build.KernelModel` as arrays);
- :class:`RunParams`, one run's parameters: its disturbance draw, its
  gradient, and :data:`RUN_DTYPE`, what follows from them (masses, random
  stream keys, the actuator's and link's constants, the controller's kind);
- :class:`StopState`, the run's state: the train, its onboard control, the
  link, the sensors and the tallies of the results as named scalar records
  (:data:`TRAIN_DTYPE`, :data:`ONBOARD_DTYPE`, :data:`LINK_DTYPE`,
  :data:`SENSE_DTYPE`, :data:`TALLY_DTYPE`), and the arrays of the units
  (wayside unit, receiver, ATO, driver, positioning), whose layouts their
  own modules define (``WS_*``, ``RX_*``, ``AT_*``, ...);
- :class:`StopOutputs`, the run's results (``RES_*``), true passage times and
  the :class:`Recording` buffers of the detailed stop (``TR_*``, ``LA_*``).

The mechanism, chosen by measurement **[interpretation]** (the issue left the
choice open between structured records, namedtuples of arrays and packed
buffers): parameter tables stay packed float64 buffers with named offsets
(``KP_*``, ``SC_*``, and the units' ``WP_*``, ``RP_*``, ...), the scalars of the
state are numpy structured records read and written by field name
(``tr.speed_mps``), and both travel grouped in ``NamedTuple`` records. Each scalar
record is a one-element structured array, indexed ``[0]`` where it is used:
numba passes the record as one pointer into the array, which the tuple keeps
alive (a record taken from an array that is then dropped would dangle), and
``cuda.local.array(1, TRAIN_DTYPE)`` can stand in for it, as a local array of
constant shape can for every array here; no ``structref``, no ``jitclass``,
nothing numba-cuda cannot compile. The step allocates nothing.

Measured on this project's machine (2 cores shared with other work, numba
0.68, best of 7): a latency-bound toy step with 12 scalars of state took
14.2 ns with the state in locals of one loop (the old kernel's shape), 16.5 ns
in a structured record, 16.7 ns in a packed float64 buffer: records cost what
buffers cost, and keep the types (int, bool, float) a buffer blurs. In the
stop model itself the state's round trip through memory is hidden by the
step's work, once the step hands the position, speed and emergency brake on
as values within the step: the figures before and after the split are in
:mod:`railstop.model.run`. Two traps, measured, that decide how the step is
compiled:

- a call passes every array of every record (seven machine words each), so
  ``stop_step`` and its parts are inlined (``njit_inline``): called instead,
  a ``driver-ats`` run took 800 µs instead of 164;
- a function inlined into a caller compiled with numba's reference counting
  (NRT) increfs and decrefs each array it takes out of a tuple, an atomic
  operation each (a toy step: 295-501 ns instead of 30-44): the run loop is
  compiled without NRT (``njit_step``), and the state is allocated once per
  block, by :func:`new_state`.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from railstop.config.platform import LAMP_CODES
from railstop.control.law import LAW_PARAMS_DTYPE, LAW_STATE_SIZE, MEASUREMENTS_DTYPE
from railstop.control.notch import MOD_SIZE
from railstop.control.tasc import HISTORY, SAMPLES
from railstop.jit import as_python
from railstop.messages import TEL_SIZE
from railstop.model.fixes import FX_SIZE, FXI_SIZE
from railstop.onboard.ato import AT_SIZE
from railstop.onboard.driver import DR_SIZE, DV_SIZE
from railstop.onboard.positioning import LOG_ROWS
from railstop.onboard.speed_supervision import SV_SIZE
from railstop.onboard.tasc_receiver import RX_SIZE
from railstop.streams import Stream
from railstop.wayside.tasc_unit import CR_SIZE, WS_SIZE

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
UintArray = NDArray[np.uint64]
#: A one-element structured array: the record is its element [0].
RecordArray = NDArray[np.void]

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
# The medium's bursts (Gilbert-Elliott, link.channel) and reordering, per braking frame:
SC_BURST_ENTER = 21  # good -> bad (0: no bursts)
SC_BURST_EXIT = 22  # bad -> good
SC_BURST_LOSS = 23  # a frame sent in the bad state is lost
SC_REORDER = 24  # a frame is held back by the medium's reorder delay (KP_REORDER_DELAY)
SC_SIZE = 25
SCENARIO_FIELDS = (
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
    "radio_burst_enter_probability",
    "radio_burst_exit_probability",
    "radio_burst_loss_probability",
    "radio_reorder_probability",
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
KP_S2 = 31  # the stop sensors' chainages (config.platform sensor_positions) ...
KP_S1 = 32
KP_SENSOR_NOISE = 33  # ... and their noise
KP_START_BEFORE_HOME = 34  # a driver's run starts at least this far before the home signal
KP_PASS = 35  # SPEC §3 signal-open switch: the run ends when the front passes here (0: a stop)
KP_REORDER_DELAY = 36  # the medium's hold-back of a reordered frame (station.tasc.medium)
KP_SIZE = 37

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

STREAMS = np.array(
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
        Stream.LINK_FAULTS,
    ],
    dtype=np.int64,
)
(
    K_JITTER,
    K_MISS,
    K_DOPPLER,
    K_LOSS,
    K_LATENCY,
    K_CYCLE,
    K_CORRUPT,
    K_TC_BOUNDARY,
    K_TC_DELAY,
    K_DRIVER,
    K_STOP_SENSORS,
    K_FAULTS,
) = range(STREAMS.size)

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
# 1: the run's driver is the line, whose SPEC §2 chain positions the train and hands the stop its
# fixes (``model.run.SteppedStop.fix``); the stop then runs no chain of its own (0: it does).
FP_DRIVER_FIXES = 9
FP_SIZE = 10


# --------------------------------------------------------------------------
# The records.


class StopParams(NamedTuple):
    """The station/line parameters shared by every run of a block (``KernelModel.params``)."""

    kp: FloatArray  # station, vehicle, controller (KP_*)
    table: FloatArray  # deceleration per notch (0 first)
    pwm_duty: FloatArray  # the PWM curve: duty ...
    pwm_decel: FloatArray  # ... and its deceleration
    det_pos: FloatArray  # the wayside detectors' chainages
    det_to_stop: FloatArray  # ... and their distances to the stopping point
    transponders: FloatArray  # the ATP / ATO transponders' chainages
    bp: FloatArray  # the gradient's breakpoints (the values are the run's)
    wp: FloatArray  # wayside unit (tasc_unit WP_*)
    rp: FloatArray  # onboard receiver (tasc_receiver RP_*)
    ap: FloatArray  # onboard ATO (ato AP_*)
    ext: FloatArray  # the external forces' parameters (control.tasc external_params)
    quant: FloatArray  # counts per unit of each telegram field on the wire (0: not fixed-point)
    carried: FloatArray  # 1 where the signal form carries the telegram field
    # SPEC §2 positioning of ato-corrected (FP_*; one empty circuit for the other controllers).
    fp: FloatArray
    tc_ids: IntArray
    tc_starts: FloatArray
    tc_sd: FloatArray
    db_ids: IntArray
    db_starts: FloatArray
    db_sd: FloatArray
    # SPEC §3 manual driving (one-row placeholders for the other controllers).
    levels: FloatArray  # the driver levels' parameters (config.driver driver_arrays)
    rs: FloatArray  # re-stop parameters (onboard.driver RS_*)
    code_pos: FloatArray  # the station's code points ...
    code_lim: FloatArray  # ... and their speed limits (m/s)
    lamp_table: FloatArray  # the lamp per (S2, S1) reading
    # The parameters record of the onboard stop-control law (railstop.control.law). The law itself
    # (a numba first-class function: one compiled model serves every law) is an argument of its
    # own (``stop_step``, ``simulate_block``): inside this record it would make numba type the whole
    # record in Python at every call from Python (about 0.4 ms against 4 us without it).
    lp: RecordArray


# The run's parameters that follow from its draw (stop_init writes them; constant over the run).
RUN_DTYPE = np.dtype(
    [
        ("run", np.int64),  # the run's index (its random streams' counter)
        # The run's random stream keys (railstop.streams).
        ("k_jitter", np.uint64),
        ("k_miss", np.uint64),
        ("k_doppler", np.uint64),
        ("k_loss", np.uint64),
        ("k_latency", np.uint64),
        ("k_cycle", np.uint64),
        ("k_corrupt", np.uint64),
        ("k_faults", np.uint64),  # the medium's bursts and reordering (link.channel LinkStreams.faults)
        ("k_driver", np.uint64),
        ("k_stop_sensors", np.uint64),
        # The controller's kind.
        ("is_ato", np.bool_),
        ("is_driver", np.bool_),
        ("onboard_only", np.bool_),  # no wayside unit, no link
        ("corrected", np.bool_),  # ato-corrected: SPEC §2 track-circuit corrections
        ("own_fixes", np.bool_),  # ... from its own chain (model.fixes), not its driver's
        ("pwm_train", np.bool_),  # config 2 / 3 on a PWM train
        ("atc", np.bool_),  # the driver's supervision: ATC (else ATS)
        ("incapacitated", np.bool_),  # the driver never brakes
        ("has_doppler", np.bool_),  # a wayside radar that the controller uses
        # Masses: actual static and effective mass, and the effective mass the ECU believes.
        ("static_kg", np.float64),
        ("effective_kg", np.float64),
        ("believed_kg", np.float64),
        ("brake_effect", np.float64),  # brakes' deceleration per ECU demand: gain x believed / effective
        # The adhesion's braking limits (physics.train.adhesion_limit_1): dry rail, the patch.
        ("adhesion_limit_mps2", np.float64),
        ("patch_limit_mps2", np.float64),
        # Wheels and odometer: actual and assumed diameter, tachometer scale, slide creep.
        ("wheel_m", np.float64),
        ("assumed_m", np.float64),
        ("tach_scale", np.float64),
        ("slide_slip", np.float64),
        # Actuator: dead time (whole steps), lag and jerk limit per step.
        ("delay_steps", np.int64),
        ("lag_alpha", np.float64),
        ("jerk_step_mps2", np.float64),
        ("corrupt_p", np.float64),  # a frame's probability to be corrupted (bit error rate)
    ],
    align=True,
)


class RunParams(NamedTuple):
    """One run's parameters: its draw, its gradient, and what follows from them."""

    sc: FloatArray  # the run's draw (SC_* columns of scenario_arrays)
    grad: tuple[FloatArray, FloatArray, FloatArray]  # breakpoints, gradient values, elevations
    derived: RecordArray  # RUN_DTYPE


# The train and its brakes.
TRAIN_DTYPE = np.dtype(
    [
        ("position_m", np.float64),  # the front's chainage
        ("speed_mps", np.float64),
        ("accel_mps2", np.float64),
        ("stopped", np.bool_),
        ("stop_time_s", np.float64),  # when it came to a stand (NaN: not yet)
        ("sliding", np.bool_),  # the wheels slide (the WSP acting)
        ("limited_mps2", np.float64),  # the actuator's jerk limiter ...
        ("output_mps2", np.float64),  # ... and its lagged output
        ("odometer_step_m", np.float64),  # what the odometer counted in the last step
    ],
    align=True,
)

# The train's control: its own command around TASC, the driver's code and the emergency brake.
ONBOARD_DTYPE = np.dtype(
    [
        ("eb", np.bool_),  # the emergency brake is applied
        ("eb_cause", np.float64),  # the driver's supervision: its cause (control.supervision EB_*) ...
        ("eb_t_s", np.float64),  # ... and when (NaN: never)
        ("limit_mps", np.float64),  # SPEC §3: the code held / indicated
        ("code_next", np.int64),  # the next code point
        ("own_notch", np.int64),  # the train's own brake step (station.tasc.initial_brake_notch)
        ("own_for", np.int64),  # the own notch own_duty and own_demand are for (-1: none yet)
        ("own_duty", np.float64),
        ("own_demand_mps2", np.float64),
        ("switch_pos", np.int64),  # config 2's changeover switch (-1: none)
        # An emergency brake from outside the stop's units (the line's CBTC onboard unit, SPEC §4),
        # applied by the driver that steps the stop: from when (NaN: never). It holds to the stand.
        ("external_eb_t_s", np.float64),
    ],
    align=True,
)

# The link (SPEC §5 media, EN 50159 layer): the pending command, the frames in the air.
LINK_DTYPE = np.dtype(
    [
        ("pending_id", np.int64),  # the command the pending telegram carries (1, 2, ...)
        ("applied_id", np.int64),  # the newest command the receiver has taken
        ("in_flight", np.int64),  # frames in the air (StopState fl_arr, fl_seq)
        ("last_seq", np.int64),  # the newest attempt delivered (-1: none)
        ("next_try_s", np.float64),  # the next transmission attempt
        ("first_rx_s", np.float64),  # the first telegram delivered (inf: none yet)
        ("attempts", np.int64),  # transmission attempts (the streams' counter)
        ("losses", np.int64),  # ... lost to the loss probability
        ("bad", np.bool_),  # the medium's Gilbert-Elliott state (True: in a burst)
    ],
    align=True,
)

# The wayside detectors, the true passages and the transponders.
SENSE_DTYPE = np.dtype(
    [
        ("passed", np.bool_),  # a detector reported a passage in the last step ...
        ("det_idx", np.int64),  # ... which one ...
        ("pass_s", np.float64),  # ... and when
        ("sensor_next", np.int64),  # the next detector to report
        ("truth_next", np.int64),  # the next detector passed (the true passages)
        ("transponder_next", np.int64),
        ("transponder_m", np.float64),  # a transponder the train passed in the last step (NaN: none)
        ("miss_trials", np.int64),  # detector passages drawn for a miss ...
        ("misses", np.int64),  # ... and the misses
    ],
    align=True,
)

# What the results count, and the recording's rows.
TALLY_DTYPE = np.dtype(
    [
        # the largest change of the acceleration from one counted step to the next (the jerk times
        # the step: the result divides by the step once, at the end)
        ("max_accel_change_mps2", np.float64),
        ("slid", np.bool_),
        ("prev_accel_mps2", np.float64),
        ("prev_counted", np.bool_),  # the last step's jerk counted (braking, moving)
        ("notch_changes", np.int64),
        ("prev_notch", np.int64),
        ("commands", np.int64),  # recording: command rows ...
        ("attempts", np.int64),  # ... transmission attempts ...
        ("deliveries", np.int64),  # ... and deliveries written
    ],
    align=True,
)


class StopState(NamedTuple):
    """One run's state (``new_state``; ``stop_init`` resets it for each run)."""

    train: RecordArray  # TRAIN_DTYPE
    onboard: RecordArray  # ONBOARD_DTYPE
    link: RecordArray  # LINK_DTYPE
    sense: RecordArray  # SENSE_DTYPE
    tally: RecordArray  # TALLY_DTYPE
    ring: FloatArray  # the actuator's dead time (brake.actuator_step_1)
    # The wayside unit (tasc_unit WS_*; radar buffer, speed history, passages, command).
    ws: FloatArray
    dbuf: FloatArray
    wh_v: FloatArray
    wh_e: FloatArray
    pass_t: FloatArray
    pass_x: FloatArray
    tele: FloatArray
    crow: FloatArray
    # The planning samples (control.tasc), shared by the wayside unit and the receiver.
    taus: FloatArray
    weights: FloatArray
    # The link: the telegram on the air, the frames in flight (arrival time, attempt number).
    pending: FloatArray
    fl_arr: FloatArray
    fl_seq: IntArray
    # The onboard receiver (tasc_receiver RX_*), its tachometer and history; the notch modulator
    # (control.notch, also the ATO's); the ATO (ato AT_*).
    rx: FloatArray
    tach: FloatArray
    rh_v: FloatArray
    rh_e: FloatArray
    mod: FloatArray
    at: FloatArray
    meas: RecordArray  # the law's measurements (control.law MEASUREMENTS_DTYPE)
    law_state: FloatArray  # the law's own state (control.law LAW_STATE_SIZE)
    law_params: RecordArray  # the run's copy of the law's parameters (control.law LAW_PARAMS_DTYPE)
    # SPEC §2 positioning of ato-corrected (model.fixes).
    fx: FloatArray
    fxi: IntArray
    flog: FloatArray
    fbound: FloatArray
    fdelay: FloatArray
    # SPEC §3: the driver (onboard.driver DR_*, DV_*) and the speed supervision (SV_*).
    dr: FloatArray
    dv: FloatArray
    sv: FloatArray


class Recording(NamedTuple):
    """The recording buffers of the detailed stop (run 0 of a block, when ``on``)."""

    on: bool
    trace: FloatArray  # (rows, TR_SIZE)
    commands: FloatArray  # (rows, CR_SIZE + 1): the wayside's command records and their step
    sends: FloatArray  # (rows, TEL_SIZE): the telegrams as quantised for the air
    attempts: FloatArray  # (rows, LA_SIZE)
    deliveries: FloatArray  # steps at which a frame was delivered
    counters: IntArray  # rows written (RC_*)


class StopOutputs(NamedTuple):
    """What one run writes: its results, its true passage times and its recording."""

    res: FloatArray  # (RES_SIZE,)
    passages: FloatArray  # (detectors,): when the front passed each (NaN: never)
    rec: Recording


def new_record(dtype: np.dtype[Any], shape: int | tuple[int, ...] = 1) -> RecordArray:
    """A zeroed record of ``dtype`` (a one-element structured array; ``shape``: that many; a
    plain dtype gives a plain zeroed array). With the model run as Python
    (``NUMBA_DISABLE_JIT=1``) a numpy record array, whose elements take their fields as
    attributes as a compiled record does."""
    arr = np.zeros(shape, dtype=dtype)
    return arr.view(np.recarray) if as_python() and dtype.names else arr


#: The sizes a state's arrays take from the model and the block (``new_state``'s arguments).
STATE_SIZES = ("ring", "window", "tach_window", "in_flight", "log_len", "circuits")

#: The state's work arrays, in ``StopState``'s order: (field, shape, dtype, initial value). A
#: shape's entry is a number or one of :data:`STATE_SIZES`. The one list of them: the CPU's
#: :func:`new_state` and the GPU kernel's local arrays (railstop.model.gpu) are both made from it.
STATE_FIELDS: tuple[tuple[str, tuple[int | str, ...], np.dtype, float], ...] = tuple(
    (name, shape, np.dtype(dtype), fill)
    for name, shape, dtype, fill in (
        ("train", (1,), TRAIN_DTYPE, 0.0),
        ("onboard", (1,), ONBOARD_DTYPE, 0.0),
        ("link", (1,), LINK_DTYPE, 0.0),
        ("sense", (1,), SENSE_DTYPE, 0.0),
        ("tally", (1,), TALLY_DTYPE, 0.0),
        ("ring", ("ring",), np.float64, 0.0),
        ("ws", (WS_SIZE,), np.float64, 0.0),
        ("dbuf", ("window",), np.float64, 0.0),
        ("wh_v", (HISTORY,), np.float64, 0.0),
        ("wh_e", (HISTORY,), np.float64, 0.0),
        ("pass_t", (3,), np.float64, 0.0),
        ("pass_x", (3,), np.float64, 0.0),
        ("tele", (TEL_SIZE,), np.float64, 0.0),
        ("crow", (CR_SIZE,), np.float64, 0.0),
        ("taus", (SAMPLES,), np.float64, 0.0),
        ("weights", (SAMPLES,), np.float64, 0.0),
        # The telegram on the air: none yet (a run's first command replaces it).
        ("pending", (TEL_SIZE,), np.float64, np.nan),
        ("fl_arr", ("in_flight",), np.float64, 0.0),
        ("fl_seq", ("in_flight",), np.int64, 0.0),
        ("rx", (RX_SIZE,), np.float64, 0.0),
        ("tach", ("tach_window",), np.float64, 0.0),
        ("rh_v", (HISTORY,), np.float64, 0.0),
        ("rh_e", (HISTORY,), np.float64, 0.0),
        ("mod", (MOD_SIZE,), np.float64, 0.0),
        ("at", (AT_SIZE,), np.float64, 0.0),
        ("meas", (1,), MEASUREMENTS_DTYPE, 0.0),
        ("law_state", (LAW_STATE_SIZE,), np.float64, 0.0),
        ("law_params", (1,), LAW_PARAMS_DTYPE, 0.0),
        ("fx", (FX_SIZE,), np.float64, 0.0),
        ("fxi", (FXI_SIZE,), np.int64, 0.0),
        ("flog", (LOG_ROWS, "log_len"), np.float64, 0.0),
        ("fbound", ("circuits",), np.float64, 0.0),
        ("fdelay", ("circuits",), np.float64, 0.0),
        ("dr", (DR_SIZE,), np.float64, 0.0),
        ("dv", (DV_SIZE,), np.float64, 0.0),
        ("sv", (SV_SIZE,), np.float64, 0.0),
    )
)


def state_shape(shape: tuple[int | str, ...], sizes: dict[str, int]) -> tuple[int, ...]:
    """A :data:`STATE_FIELDS` shape with its named sizes filled in from ``sizes``."""
    return tuple(d if isinstance(d, int) else int(sizes[d]) for d in shape)


def constant_shape(shape: tuple[int | str, ...]) -> tuple[int, ...] | None:
    """A :data:`STATE_FIELDS` shape when no size in it is the model's to set, else None."""
    return tuple(int(d) for d in shape) if all(isinstance(d, int) for d in shape) else None


def state_array(dims: tuple[int, ...], dtype: np.dtype[Any], fill: float) -> NDArray[Any]:
    """One work array of the state, as a run starts from it: zeroed, then set to ``fill``."""
    arr: NDArray[Any] = new_record(dtype, dims)
    if fill != 0.0:
        arr[...] = fill
    return arr


def new_state(sizes: dict[str, int]) -> StopState:
    """The state buffers of a block of runs (:data:`STATE_FIELDS`), ``sizes`` naming each of
    :data:`STATE_SIZES`: the dead time's ring in steps, the radar buffer's samples, the
    tachometer's window, the frames in the air, the positioning log's entries, the track
    circuits."""
    return StopState(
        *(state_array(state_shape(shape, sizes), dtype, fill) for _, shape, dtype, fill in STATE_FIELDS)
    )
