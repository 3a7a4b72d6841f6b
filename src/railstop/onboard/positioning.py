"""The onboard position-correction device of SPEC §2: compiled per-run cores and the array wrapper.

SPEC §2: the onboard device keeps a track-circuit DB (ID -> absolute chainage
of the circuit's start), receives (circuit ID, occupancy instant in GNSS time)
from the wayside, and its position module compares the tachometer position
*at the occupancy instant* with the circuit start and corrects the accumulated
error; corrected position and speed go to the train control. This unit:

- keeps a log of (its own GNSS clock time, odometer distance, tachometer
  speed), one sample per call of :meth:`PositioningUnit.log`, over
  ``log_window_s`` (a ring buffer of L samples per run);
- on a telegram (:meth:`PositioningUnit.handle`): S30 looks the circuit up in
  the DB; finds the odometer reading at the telegram's GNSS time by linear
  interpolation in the log (a telegram time a little past the newest sample,
  possible with clock offsets, is extrapolated with the last speed up to
  ``max_extrapolation_s``); S40 sets the position at that instant to the
  circuit's start: ``corrected(t) = start + odo(t) - odo(t_occ)``;
- rejects (does not correct from) a telegram whose circuit is not in the DB
  or whose time lies outside its log (DESIGN rule 10: no correction is safer
  than a wrong one; the rejection is counted).

Beyond SPEC §2, one **extended Kalman filter** per run over the state
``s = (p, a, d)``: the position ``p`` when the odometer was read at the last
fix, the odometer's scale ``a = D_assumed / D_actual`` and the constant part
``d`` of the delay between the first axle's entry and the time in the
telegram (detection delay plus any constant clock offset). Between fixes the
position is dead-reckoned, ``p' = p + m / a`` with ``m`` the odometer's count
since the last fix (process noise ``ODOMETRY_NOISE_FRAC`` of the distance, and
the bridged slides' error below). A fix of circuit start ``x`` at tachometer
speed ``v`` measures ``x = p - d v / a`` (the train was ``d · v_true`` past the
start when the odometer was read) with the noise of the circuit's boundary
(from the DB: the line data gives it per kind; ``fix_sd_m`` when not given)
and of the delay's spread times the speed. The prior: the start position
(``fix_sd_m``, or what the caller knows of it), ``a ~ N(1, scale_prior)``,
``d ~ N(d0, delay_prior)`` with d0 the line's nominal detection delay, or a
calibration carried from earlier trips (:meth:`PositioningUnit.carry_calibration`).
The scale is learned over the whole distance between fixes (not interval by
interval), so a few kilometres find it to about 1e-4 and the dead reckoning
then averages many fixes through jointless circuits' tuned zones. A fix
further than ``gate_sigma`` standard deviations from the prediction
contradicts the dead reckoning (an undetected slide): the position restarts
from it, the scale and delay keep what they learned (counted as gated).

**Slide compensation** (beyond SPEC §2): while the wheel-slide / anti-slip
protection acts (``wsp_active`` in the log) the wheel does not roll with the
train. With an accelerometer (``accel_mps2``) the unit bridges the interval:
its compensated odometer integrates the last tachometer speed before the WSP
acted, moved on by the accelerometer, and the filter adds the bridge's error
(the bias, ``accelerometer_bias_sd_mps2``, times T²/2; the start speed's
``BRIDGE_SPEED_SD_MPS`` times T). Without one, the interval is not trusted:
the next fix is taken as it is and nothing is learned from it. The SPEC §2
document position always uses the raw odometer. Between fixes::

    calibrated(t) = p + (compensated odometer(t) - its value at the fix) / a

At constant speed ``d`` is not observable (every fix shifts by the same
``d·v``) and the filter keeps its prior there; speed changes between fixes
(leaving and approaching stations) reveal it.

One implementation (DESIGN rule 1, ``railstop.jit``): the state of one run
lives in three small arrays a caller allocates (:func:`unit_state_arrays`)
and passes to compiled scalar functions:

- ``state``: float64 (U_SIZE,), indices ``U_*`` below (newest odometer and
  speed, the references of both positions, the filter's state and
  covariance, the compensated odometer and the bridges since the last fix);
- ``istate``: int64 (UI_SIZE,), indices ``UI_*`` (ring head, samples, and the
  corrections / rejections / learned / gated counters);
- ``log``: float64 (LOG_ROWS, L), rows ``LOG_T``, ``LOG_ODO``, ``LOG_V``, ``LOG_COMP``: the
  ring buffer, L = :func:`log_length` (window, cycle).

A caller may pass longer ``state``/``istate`` vectors: these functions use
their first U_SIZE / UI_SIZE entries only (``model/fixes.py``
appends its own). :func:`unit_init_run` sets a run up, :func:`unit_log_run`
logs one sample, :func:`unit_handle_run` applies one telegram (S30 look-up,
odometer at the telegram's time, S40 correction, learner, calibrated
position). :class:`PositioningUnit` holds the same arrays for n runs, shape
(n, ·), and loops over the runs in compiled code.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import Positioning, TrackCircuit
from railstop.jit import njit, njit_inline, njit_step

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

# Process noise added to the learner per fix (standard deviations): the wheel
# diameter and the delay are constant within a run, a little process noise
# keeps the filter able to follow a slow change (wear, a clock in holdover).
SCALE_PROCESS_SD = 1e-5
DELAY_PROCESS_SD_S = 1e-3
# Dead-reckoning error the learned scale does not explain (fraction of the distance, standard
# deviation): pulse quantisation, wheel diameter differences between axles, curves.
ODOMETRY_NOISE_FRAC = 1e-3
# A bridged slide starts from the last tachometer speed before the WSP acted: its error
# (standard deviation, m/s) grows the bridged distance's error with the bridge's length.
BRIDGE_SPEED_SD_MPS = 0.05
# The position's variance after a slide no accelerometer bridged: the dead reckoning is not
# trusted, the next fix is taken as it is (the filter's gain 1).
UNTRUSTED_VAR_M2 = 1e8

_SCALE_PROCESS_VAR = SCALE_PROCESS_SD**2
_DELAY_PROCESS_VAR_S2 = DELAY_PROCESS_SD_S**2


class FixOutcome(IntEnum):
    ACCEPTED = 0
    UNKNOWN_CIRCUIT = 1  # the ID is not in the track-circuit DB
    STALE = 2  # older than the log window
    FUTURE = 3  # later than the newest log sample + max_extrapolation_s


_ACCEPTED = int(FixOutcome.ACCEPTED)
_UNKNOWN_CIRCUIT = int(FixOutcome.UNKNOWN_CIRCUIT)
_STALE = int(FixOutcome.STALE)
_FUTURE = int(FixOutcome.FUTURE)

# Per-run state, float64 vector ``state``:
U_ODO = 0  # newest odometer reading (m)
U_SPEED = 1  # newest tachometer speed (m/s)
U_REF_ODO = 2  # odometer reading of the last fix: the reference of the SPEC §2 position ...
U_DOC_REF = 3  # ... the SPEC §2 corrected position there (the circuit's start)
U_CAL_REF = 4  # filter state p: the calibrated position at the last fix
U_CAL_VAR = 5  # its variance P_pp (m²)
U_A = 6  # filter state a: odometer scale D_assumed / D_actual
U_D = 7  # filter state d: constant delay (s)
U_P00 = 8  # covariance of (a, d), row-major: P_aa
U_P01 = 9  # P_ad
U_P10 = 10  # P_da (= P_ad)
U_P11 = 11  # P_dd
U_PPA = 12  # covariance P_pa
U_PPD = 13  # covariance P_pd
U_WSP = 14  # 1.0 when WSP acted since the last fix without an accelerometer to bridge it
U_COMP = 15  # newest slide-compensated odometer reading (m, odometer units)
U_REF_COMP = 16  # the compensated odometer at the last fix: the calibrated position's reference
U_VREF = 17  # the bridged wheel speed while WSP acts (m/s, odometer units)
U_LAST_T = 18  # clock time of the newest log sample (-inf before the first)
U_BRIDGE_CUR = 19  # length of the bridge in progress (s)
U_BRIDGE_T = 20  # seconds bridged since the last fix
U_BRIDGE_H = 21  # sum over the bridges since the last fix of (length² / 2) (s²)
U_ACC_VAR = 22  # the accelerometer's bias variance (m²/s⁴), from the settings
U_HOLD_V = 23  # the tachometer speed before the WSP acted unbridged (m/s, odometer units)
U_SLIDE_M = 24  # bound on the error of the unbridged WSP intervals since the last fix (odometer m)
U_NOM_D = 25  # the line's nominal detection delay (s), whether learned from or not
U_FIX_BIAS_M = 26  # the last fix's error its variance does not hold: without the learner, v x delay
U_SIZE = 27
# Per-run state, int64 vector ``istate``:
UI_HEAD = 0  # index of the newest log sample (-1: none yet)
UI_SAMPLES = 1  # samples logged
UI_CORRECTIONS = 2
UI_REJECTED = 3
UI_LEARNED = 4  # fixes the filter took
UI_GATED = 5  # fixes inconsistent with the dead reckoning: the position restarted from them
UI_SIZE = 6
# Rows of the log ring ``log`` (LOG_ROWS, L):
LOG_T = 0  # the unit's own GNSS clock time of the sample (-inf: never written)
LOG_ODO = 1
LOG_V = 2
LOG_COMP = 3  # the slide-compensated odometer
LOG_ROWS = 4


def log_length(log_window_s: float, cycle_s: float) -> int:
    """Samples of the log ring: ``log_window_s`` at one sample per ``cycle_s``, plus one."""
    return int(np.ceil(log_window_s / cycle_s)) + 1


class SettingsSquares(NamedTuple):
    """The squares of the positioning settings the compiled cores take."""

    fix_var_m2: float  # fix_sd_m²: the start position's variance
    scale_prior_var: float  # (scale_prior_pct / 100)²
    delay_prior_var_s2: float  # delay_prior_s²
    gate_sigma2: float  # gate_sigma²
    accel_bias_var: float  # accelerometer_bias_sd_mps2²


def settings_squares(settings: Positioning) -> SettingsSquares:
    """The settings squared in Python (C ``pow``), as the array code always did: ``x ** 2`` of a
    Python float can differ from ``x * x`` in the last bit, and the compiled code must not."""
    return SettingsSquares(
        fix_var_m2=float(settings.fix_sd_m) ** 2,
        scale_prior_var=(float(settings.scale_prior_pct) * 1e-2) ** 2,
        delay_prior_var_s2=float(settings.delay_prior_s) ** 2,
        gate_sigma2=float(settings.gate_sigma) ** 2,
        accel_bias_var=float(settings.accelerometer_bias_sd_mps2) ** 2,
    )


def unit_state_arrays(log_len: int) -> tuple[FloatArray, IntArray, FloatArray]:
    """Uninitialised (state, istate, log) of one run (fill them with :func:`unit_init_run`)."""
    return np.empty(U_SIZE), np.empty(UI_SIZE, dtype=np.int64), np.empty((LOG_ROWS, log_len))


# --------------------------------------------------------------------------
# Compiled per-run cores


@njit_step
def unit_init_run(
    state: FloatArray,
    istate: IntArray,
    log: FloatArray,
    start_position_m: float,
    fix_var_m2: float,
    learn: bool,
    nominal_delay_s: float,
    scale_prior_var: float,
    delay_prior_var_s2: float,
    accel_bias_var: float,
) -> None:
    """One run's unit at its start: empty log, positions at ``start_position_m``, the filter's prior.

    The start is known like a fix (variance ``fix_var_m2``). Without learning
    the calibrated position is the document's: no scale, no delay (d = 0).
    The variances are the settings squared by :func:`settings_squares`.
    """
    log[LOG_T, :] = -np.inf
    log[LOG_ODO, :] = 0.0
    log[LOG_V, :] = 0.0
    log[LOG_COMP, :] = 0.0
    for k in range(UI_SIZE):
        istate[k] = 0
    istate[UI_HEAD] = -1
    for k in range(U_SIZE):
        state[k] = 0.0
    state[U_DOC_REF] = start_position_m
    state[U_CAL_REF] = start_position_m
    state[U_CAL_VAR] = fix_var_m2
    state[U_A] = 1.0
    state[U_D] = nominal_delay_s if learn else 0.0
    state[U_P00] = scale_prior_var
    state[U_P11] = delay_prior_var_s2
    state[U_LAST_T] = -np.inf
    state[U_ACC_VAR] = accel_bias_var
    state[U_NOM_D] = nominal_delay_s
    return


@njit_inline
def unit_log_run(
    state: FloatArray,
    istate: IntArray,
    log: FloatArray,
    clock_time_s: float,
    odometer_m: float,
    speed_mps: float,
    wsp_active: bool,
    accel_mps2: float,
) -> None:
    """One cycle's sample of one run: its clock reading, odometer, tachometer speed, whether the
    wheel-slide / anti-slip protection acts, and the accelerometer (m/s², gravity on the gradient
    taken out; NaN: none).

    Beyond SPEC §2 (slide compensation): while the WSP acts the wheel does not roll with the
    train, so the compensated odometer does not count the wheel; it integrates a bridged speed
    instead, the last tachometer speed before the WSP acted moved on by the accelerometer. Without
    an accelerometer the wheel is counted and the interval is marked untrusted (as SPEC §2 alone).
    """
    head = (istate[UI_HEAD] + 1) % log.shape[1]
    istate[UI_HEAD] = head
    istate[UI_SAMPLES] += 1
    dt = clock_time_s - state[U_LAST_T] if math.isfinite(state[U_LAST_T]) else 0.0
    dt = max(dt, 0.0)
    bridge = wsp_active and math.isfinite(accel_mps2) and istate[UI_SAMPLES] > 1
    if bridge:
        v0 = state[U_VREF]
        v1 = max(v0 + state[U_A] * accel_mps2 * dt, 0.0)  # odometer units: a x true
        state[U_COMP] += 0.5 * (v0 + v1) * dt
        state[U_VREF] = v1
        state[U_BRIDGE_CUR] += dt
        state[U_BRIDGE_T] += dt
        state[U_BRIDGE_H] += state[U_BRIDGE_CUR] * dt  # the integral of the bridge's age: T²/2
    else:
        state[U_COMP] += odometer_m - state[U_ODO]
        state[U_VREF] = speed_mps
        state[U_BRIDGE_CUR] = 0.0
        if wsp_active:
            state[U_WSP] = 1.0
            # The bounded slide ([interpretation], for the location uncertainty): while the
            # wheel slides the train runs between the wheel's speed and the speed before the WSP
            # acted (it brakes, it does not gain speed); while it slips, between standstill and
            # the wheel's speed. The wheel's count is off by at most the larger gap.
            state[U_SLIDE_M] += max(state[U_HOLD_V] - speed_mps, speed_mps) * dt
        else:
            state[U_HOLD_V] = speed_mps
    log[LOG_T, head] = clock_time_s
    log[LOG_ODO, head] = odometer_m
    log[LOG_V, head] = state[U_VREF]
    log[LOG_COMP, head] = state[U_COMP]
    state[U_ODO] = odometer_m
    state[U_SPEED] = speed_mps
    state[U_LAST_T] = clock_time_s
    return


@njit_inline
def unit_lookup(
    db_ids: IntArray, db_starts_m: FloatArray, db_sd_m: FloatArray, circuit_id: int
) -> tuple[bool, float, float]:
    """SPEC §2 S30: (known, start chainage, boundary uncertainty) of a circuit ID in the DB (sorted by ID)."""
    if db_ids.size == 0:
        return False, np.nan, np.nan
    pos = min(int(np.searchsorted(db_ids, circuit_id)), db_ids.size - 1)
    if db_ids[pos] == circuit_id:
        return True, db_starts_m[pos], db_sd_m[pos]
    return False, np.nan, np.nan


@njit_step
def unit_odometer_at_run(
    istate: IntArray, log: FloatArray, clock_time_s: float, max_extrapolation_s: float
) -> tuple[int, float, float, float]:
    """(outcome, odometer, speed, compensated odometer) of one run at its clock time ``clock_time_s``.

    Linear interpolation between the log samples around the time; past the
    newest sample, extrapolation with the last speed up to
    ``max_extrapolation_s`` (FUTURE beyond); before the oldest one, STALE.
    """
    length = log.shape[1]
    first = istate[UI_HEAD] + 1  # ring slot of the oldest sample: slot (first + i) % L is the i-th
    count = 0
    for i in range(length):
        if log[LOG_T, (first + i) % length] <= clock_time_s:
            count += 1
    i = count - 1  # last sample at or before t; -1 = before the log
    if not math.isfinite(log[LOG_T, (first + max(i, 0)) % length]):  # slots never written: -inf
        i = -1
    if i < 0:
        return _STALE, np.nan, np.nan, np.nan
    if i == length - 1:
        newest = (first + i) % length
        dt_new = clock_time_s - log[LOG_T, newest]
        if dt_new <= max_extrapolation_s:
            ahead = log[LOG_V, newest] * dt_new
            return _ACCEPTED, log[LOG_ODO, newest] + ahead, log[LOG_V, newest], log[LOG_COMP, newest] + ahead
        return _FUTURE, np.nan, np.nan, np.nan
    s0 = (first + i) % length
    s1 = (first + i + 1) % length
    t0 = log[LOG_T, s0]
    w = (clock_time_s - t0) / (log[LOG_T, s1] - t0)
    odo = log[LOG_ODO, s0] + w * (log[LOG_ODO, s1] - log[LOG_ODO, s0])
    v = log[LOG_V, s0] + w * (log[LOG_V, s1] - log[LOG_V, s0])
    comp = log[LOG_COMP, s0] + w * (log[LOG_COMP, s1] - log[LOG_COMP, s0])
    return _ACCEPTED, odo, v, comp


@njit_step
def unit_handle_run(
    state: FloatArray,
    istate: IntArray,
    log: FloatArray,
    db_ids: IntArray,
    db_starts_m: FloatArray,
    db_sd_m: FloatArray,
    delay_spread_s: float,
    learn: bool,
    max_extrapolation_s: float,
    gate_sigma2: float,
    circuit_id: int,
    gnss_time_s: float,
) -> tuple[int, float, float, float, float, float, bool, bool]:
    """One telegram (circuit ID, GNSS occupancy time) received by one run; SPEC §2 S30, S40.

    Returns (outcome, circuit start, odometer at the fix, speed at the fix,
    SPEC §2 corrected jump, calibrated jump, learned, gated): the row of a
    :class:`FixReport` (start NaN when unknown, odometer and speed NaN and
    jumps 0 when rejected). ``gate_sigma2``: ``gate_sigma²`` (:func:`settings_squares`).
    """
    known, x, sd = unit_lookup(db_ids, db_starts_m, db_sd_m, circuit_id)  # SPEC §2 S30: the DB
    # SPEC §2 S30: passing time -> odometer then.
    outcome, o, vv, oc = unit_odometer_at_run(istate, log, gnss_time_s, max_extrapolation_s)
    if not known:
        outcome = _UNKNOWN_CIRCUIT
    if outcome != _ACCEPTED:
        istate[UI_REJECTED] += 1
        return outcome, x, np.nan, np.nan, 0.0, 0.0, False, False
    q = vv * delay_spread_s
    fix_var = sd * sd + q * q

    # SPEC §2 S40: the odometer position at the occupancy instant becomes the circuit start.
    doc_before = state[U_DOC_REF] + (o - state[U_REF_ODO])
    state[U_REF_ODO] = o
    state[U_DOC_REF] = x
    istate[UI_CORRECTIONS] += 1

    # Beyond SPEC §2: one extended Kalman filter over s = (p, a, d), p the position when the
    # odometer was read at the telegram's time. Prediction: the compensated odometer since the
    # last fix over the scale, p' = p + m / a.
    a = state[U_A]
    d = state[U_D]
    m = oc - state[U_REF_COMP]
    p = state[U_CAL_REF] + m / a
    cal_before = p
    state[U_REF_COMP] = oc
    untrusted = state[U_WSP] != 0.0
    bridged = BRIDGE_SPEED_SD_MPS * state[U_BRIDGE_T]
    drift = state[U_BRIDGE_H]  # x the bias: the bridges' error
    state[U_WSP] = 0.0
    state[U_BRIDGE_T] = 0.0
    state[U_BRIDGE_H] = 0.0
    state[U_SLIDE_M] = 0.0
    if not learn:  # the document's position: the fix as it is
        state[U_CAL_REF] = x
        # SPEC §2 takes the circuit's start as the position at the occupancy time: the train was
        # the detection delay x its speed past it (docs/position.md), an error with a sign. Its
        # mean is the line's nominal delay (the bias), its spread the prior's (the variance).
        sv = vv / state[U_A]
        state[U_CAL_VAR] = fix_var + sv * sv * state[U_P11]
        state[U_FIX_BIAS_M] = abs(sv) * state[U_NOM_D]
        return outcome, x, o, vv, doc_before - x, cal_before - x, False, False
    j = -m / (a * a)  # dp'/da
    paa = state[U_P00] + _SCALE_PROCESS_VAR
    pad = state[U_P01]
    pdd = state[U_P11] + _DELAY_PROCESS_VAR_S2
    ppp = unit_predicted_var(state, m, a, bridged, drift)
    ppa = state[U_PPA] + j * state[U_P00]
    ppd = state[U_PPD] + j * state[U_P01]
    if untrusted:
        # A slide or slip no accelerometer bridged: the dead reckoning since the last fix is
        # not trusted, nor learned from (the position's prior is wide and uncorrelated).
        ppp = UNTRUSTED_VAR_M2
        ppa = 0.0
        ppd = 0.0
    # Measurement: the surveyed start x = p - d v / a (the train was d·v_true past the start
    # when the odometer was read) + the boundary's and the delay spread's noise.
    h0 = 1.0
    h1 = d * vv / (a * a)
    h2 = -vv / a
    innov = x - (p - d * vv / a)
    # P H'
    g0 = ppp * h0 + ppa * h1 + ppd * h2
    g1 = ppa * h0 + paa * h1 + pad * h2
    g2 = ppd * h0 + pad * h1 + pdd * h2
    s_var = h0 * g0 + h1 * g1 + h2 * g2 + fix_var
    gated = innov * innov > gate_sigma2 * s_var
    if gated:
        # The fix contradicts the dead reckoning (an undetected slide, a wrong circuit start):
        # the position restarts from the fix, the scale and delay keep what they learned.
        istate[UI_GATED] += 1
        p = x + d * vv / a
        state[U_CAL_REF] = p
        state[U_CAL_VAR] = fix_var + (vv / a) ** 2 * pdd
        state[U_PPA] = 0.0
        state[U_PPD] = 0.0
        state[U_P00] = paa
        state[U_P01] = pad
        state[U_P10] = pad
        state[U_P11] = pdd
        return outcome, x, o, vv, doc_before - x, cal_before - p, False, True
    k0 = g0 / s_var
    k1 = g1 / s_var
    k2 = g2 / s_var
    p = p + k0 * innov
    state[U_CAL_REF] = p
    state[U_A] = a + k1 * innov
    state[U_D] = d + k2 * innov
    # P - K (H P) = P - K g' (P symmetric)
    state[U_CAL_VAR] = ppp - k0 * g0
    state[U_PPA] = ppa - k0 * g1
    state[U_PPD] = ppd - k0 * g2
    state[U_P00] = paa - k1 * g1
    state[U_P01] = pad - k1 * g2
    state[U_P10] = state[U_P01]
    state[U_P11] = pdd - k2 * g2
    istate[UI_LEARNED] += 1
    return outcome, x, o, vv, doc_before - x, cal_before - p, True, False


@njit_inline
def unit_predicted_var(state: FloatArray, m: float, a: float, bridged: float, drift: float) -> float:
    """The variance of the dead-reckoned position ``m`` odometer metres past the last fix (scale
    ``a``): the fix's variance, the scale's error over the distance, the odometry noise and the
    bridges' errors (``bridged``: the start speeds' error x the seconds bridged; ``drift``: the
    bridges' T²/2, x the accelerometer's bias)."""
    j = -m / (a * a)  # dp'/da
    noise = ODOMETRY_NOISE_FRAC * m / a
    q_p = noise * noise + bridged * bridged + drift * drift * state[U_ACC_VAR]
    return state[U_CAL_VAR] + 2.0 * j * state[U_PPA] + j * j * state[U_P00] + q_p


@njit_inline
def unit_uncertainty_m(state: FloatArray, sigmas: float) -> float:
    """The location uncertainty of the calibrated position now (IEEE 1474.1: the true front lies
    within ± this): ``sigmas`` standard deviations of the dead reckoning since the last fix, plus
    the bound of the unbridged slides since then (their error is bounded, not random:
    ``unit_log_run``) and, without the learner, the detection delay the fix leaves in.
    [interpretation] The errors the filter models are taken as Gaussian; a contradiction the
    filter cannot see (a slide the WSP did not act on, a wrong circuit start) is caught by the
    gate at the next fix, not by this bound."""
    a = state[U_A]
    m = state[U_COMP] - state[U_REF_COMP]
    bridged = BRIDGE_SPEED_SD_MPS * state[U_BRIDGE_T]
    var = unit_predicted_var(state, m, a, bridged, state[U_BRIDGE_H])
    return sigmas * math.sqrt(max(var, 0.0)) + state[U_SLIDE_M] / a + state[U_FIX_BIAS_M]


@njit_inline
def unit_corrected_m(state: FloatArray) -> float:
    """SPEC §2 corrected position (document method) of one run at its newest log sample."""
    return state[U_DOC_REF] + (state[U_ODO] - state[U_REF_ODO])


@njit_inline
def unit_calibrated_m(state: FloatArray) -> float:
    """Corrected position of one run with the learned scale and delay (beyond SPEC §2)."""
    return state[U_CAL_REF] + (state[U_COMP] - state[U_REF_COMP]) / state[U_A]


# --------------------------------------------------------------------------
# The same for n runs, one compiled loop per call


@njit
def _init_runs(
    state: FloatArray,
    istate: IntArray,
    log: FloatArray,
    start_position_m: FloatArray,
    fix_var_m2: float,
    learn: bool,
    nominal_delay_s: float,
    scale_prior_var: float,
    delay_prior_var_s2: float,
    accel_bias_var: float,
) -> None:
    for i in range(start_position_m.size):
        unit_init_run(
            state[i],
            istate[i],
            log[i],
            start_position_m[i],
            fix_var_m2,
            learn,
            nominal_delay_s,
            scale_prior_var,
            delay_prior_var_s2,
            accel_bias_var,
        )
    return


@njit
def _log_runs(
    state: FloatArray,
    istate: IntArray,
    log: FloatArray,
    clock_time_s: FloatArray,
    odometer_m: FloatArray,
    speed_mps: FloatArray,
    wsp_active: BoolArray,
    accel_mps2: FloatArray,
) -> None:
    for i in range(clock_time_s.size):
        unit_log_run(
            state[i],
            istate[i],
            log[i],
            clock_time_s[i],
            odometer_m[i],
            speed_mps[i],
            wsp_active[i],
            accel_mps2[i],
        )
    return


@njit
def _handle_runs(
    state: FloatArray,
    istate: IntArray,
    log: FloatArray,
    db_ids: IntArray,
    db_starts_m: FloatArray,
    db_sd_m: FloatArray,
    delay_spread_s: float,
    learn: bool,
    max_extrapolation_s: float,
    gate_sigma2: float,
    run: IntArray,
    circuit_id: IntArray,
    gnss_time_s: FloatArray,
    outcome: IntArray,
    out_f: FloatArray,
    out_b: BoolArray,
    db_time_sd_s: FloatArray,
) -> None:
    """Telegrams in their order (those of one run applied one after the other). ``db_time_sd_s``:
    per circuit of the DB, the error of the clocks that time its telegrams (empty: none beyond
    the detection delay's spread); it adds to the spread."""
    for k in range(run.size):
        r = run[k]
        spread = delay_spread_s
        if db_time_sd_s.size:
            i = np.searchsorted(db_ids, circuit_id[k])
            if i < db_ids.size and db_ids[i] == circuit_id[k] and db_time_sd_s[i] > 0.0:
                spread = math.sqrt(delay_spread_s * delay_spread_s + db_time_sd_s[i] * db_time_sd_s[i])
        res = unit_handle_run(
            state[r],
            istate[r],
            log[r],
            db_ids,
            db_starts_m,
            db_sd_m,
            spread,
            learn,
            max_extrapolation_s,
            gate_sigma2,
            circuit_id[k],
            gnss_time_s[k],
        )
        outcome[k] = res[0]
        out_f[0, k] = res[1]
        out_f[1, k] = res[2]
        out_f[2, k] = res[3]
        out_f[3, k] = res[4]
        out_f[4, k] = res[5]
        out_b[0, k] = res[6]
        out_b[1, k] = res[7]
    return


@njit
def _uncertainty_runs(state: FloatArray, sigmas: float, out: FloatArray) -> None:
    for k in range(out.size):
        out[k] = unit_uncertainty_m(state[k], sigmas)
    return


@njit
def _odometer_at_runs(
    istate: IntArray,
    log: FloatArray,
    run: IntArray,
    clock_time_s: FloatArray,
    max_extrapolation_s: float,
    outcome: IntArray,
    odo: FloatArray,
    v: FloatArray,
) -> None:
    for k in range(run.size):
        outcome[k], odo[k], v[k], _ = unit_odometer_at_run(
            istate[run[k]], log[run[k]], clock_time_s[k], max_extrapolation_s
        )
    return


@njit
def _lookup_many(
    db_ids: IntArray,
    db_starts_m: FloatArray,
    db_sd_m: FloatArray,
    circuit_id: IntArray,
    known: BoolArray,
    start_m: FloatArray,
    sd_m: FloatArray,
) -> None:
    for k in range(circuit_id.size):
        known[k], start_m[k], sd_m[k] = unit_lookup(db_ids, db_starts_m, db_sd_m, circuit_id[k])
    return


# --------------------------------------------------------------------------
# Array wrapper


@dataclass(frozen=True, slots=True, kw_only=True)
class FixReport:
    """What :meth:`PositioningUnit.handle` did with k telegrams (one row each)."""

    run: IntArray
    circuit_id: IntArray
    outcome: IntArray  # FixOutcome
    circuit_start_m: FloatArray  # NaN when unknown
    odometer_at_fix_m: FloatArray  # NaN when rejected
    speed_at_fix_mps: FloatArray
    corrected_jump_m: FloatArray  # SPEC §2 S40 correction: document position before - after (0 if rejected)
    calibrated_jump_m: FloatArray
    learned: BoolArray  # the interval ending at this fix updated the learner
    gated: BoolArray  # the interval was an outlier and was not learned from

    @property
    def accepted(self) -> BoolArray:
        return self.outcome == FixOutcome.ACCEPTED


@dataclass(frozen=True, slots=True, kw_only=True)
class CircuitDb:
    """SPEC §2 track-circuit DB: ID -> start chainage and its uncertainty as a fix, sorted by ID."""

    ids: IntArray  # (C,) sorted
    starts_m: FloatArray  # (C,)
    sd_m: FloatArray  # (C,)
    # (C,) or (0,): the error of the clocks that time each circuit's telegrams (s, standard deviation)
    time_sd_s: FloatArray = field(default_factory=lambda: np.empty(0))

    @classmethod
    def create(
        cls,
        circuits: Sequence[TrackCircuit],
        boundary_sd_m: Sequence[float] | None,
        default_sd_m: float,
        time_sd_s: Sequence[float] | FloatArray | None = None,
    ) -> CircuitDb:
        """``boundary_sd_m``: per circuit (in the order of ``circuits``); ``default_sd_m`` when None.
        ``time_sd_s``: per circuit, its time-stamping clocks' error (None: none to add)."""
        ids = np.array([c.id for c in circuits], dtype=np.int64)
        starts = np.array([c.start_m for c in circuits], dtype=np.float64)
        sds = np.full(ids.size, default_sd_m) if boundary_sd_m is None else np.asarray(boundary_sd_m)
        if sds.shape != ids.shape or np.any(sds < 0.0):
            raise ValueError("boundary_sd_m needs one non-negative value per circuit")
        times = np.empty(0) if time_sd_s is None else np.asarray(time_sd_s, dtype=np.float64)
        if time_sd_s is not None and (times.shape != ids.shape or not np.all(times >= 0.0)):
            raise ValueError("time_sd_s needs one non-negative value per circuit")
        order = np.argsort(ids)
        return cls(
            ids=np.ascontiguousarray(ids[order]),
            starts_m=np.ascontiguousarray(starts[order]),
            sd_m=np.ascontiguousarray(sds[order], dtype=np.float64),
            time_sd_s=np.ascontiguousarray(times[order] if times.size else times),
        )


def _f64_runs(values: object, n: int) -> FloatArray:
    """One value per run, contiguous float64 (no copy when it already is)."""
    arr = np.asarray(values, dtype=np.float64)
    return np.ascontiguousarray(arr if arr.shape == (n,) else np.broadcast_to(arr, (n,)).copy())


def _bool_runs(values: object, n: int) -> BoolArray:
    arr = np.asarray(values, dtype=np.bool_)
    return np.ascontiguousarray(arr if arr.shape == (n,) else np.broadcast_to(arr, (n,)).copy())


class PositioningUnit:
    """SPEC §2 onboard position-correction device for n runs (DESIGN rules 1, 2).

    The per-run state of n runs: ``state`` (n, ≥ U_SIZE), ``istate``
    (n, ≥ UI_SIZE), ``log`` (n, LOG_ROWS, L); every method is one compiled
    loop over runs of the per-run cores above.
    """

    def __init__(
        self,
        *,
        circuits: Sequence[TrackCircuit],
        settings: Positioning,
        n: int,
        cycle_s: float,
        start_position_m: FloatArray,
        boundary_sd_m: Sequence[float] | None = None,
        delay_spread_s: float = 0.0,
        nominal_delay_s: float = 0.0,
        start_sd_m: float | None = None,
        time_sd_s: Sequence[float] | FloatArray | None = None,
    ) -> None:
        """``boundary_sd_m``: per circuit (in the order of ``circuits``), the uncertainty of its
        start as a fix; ``delay_spread_s``, ``nominal_delay_s``: the detection delay's spread and
        mean (all line data); the nominal delay is the learner's prior, it learns the actual one.
        ``start_sd_m``: how well the start position is known (None: ``fix_sd_m``, like a fix).
        ``time_sd_s``: per circuit, the error of the clocks that time its telegrams (None: GNSS
        time, nothing beyond the delay's spread)."""
        if cycle_s <= 0.0:
            raise ValueError(f"cycle_s must be positive, got {cycle_s}")
        if delay_spread_s < 0.0:
            raise ValueError(f"delay_spread_s must not be negative, got {delay_spread_s}")
        db = CircuitDb.create(circuits, boundary_sd_m, settings.fix_sd_m, time_sd_s)
        length = log_length(settings.log_window_s, cycle_s)
        state = np.empty((n, U_SIZE))
        istate = np.empty((n, UI_SIZE), dtype=np.int64)
        log = np.empty((n, LOG_ROWS, length))
        sq = settings_squares(settings)
        if start_sd_m is not None and not (start_sd_m >= 0.0 and np.isfinite(start_sd_m)):
            raise ValueError(f"start_sd_m must be finite and not negative, got {start_sd_m}")
        _init_runs(
            state,
            istate,
            log,
            _f64_runs(start_position_m, n),
            sq.fix_var_m2 if start_sd_m is None else float(start_sd_m) ** 2,
            bool(settings.learn),
            float(nominal_delay_s),
            sq.scale_prior_var,
            sq.delay_prior_var_s2,
            sq.accel_bias_var,
        )
        self._bind(
            db=db, settings=settings, delay_spread_s=delay_spread_s, state=state, istate=istate, log=log
        )

    @classmethod
    def over(
        cls,
        *,
        db: CircuitDb,
        settings: Positioning,
        delay_spread_s: float,
        state: FloatArray,
        istate: IntArray,
        log: FloatArray,
    ) -> PositioningUnit:
        """A unit over per-run state a driver has initialised (:func:`unit_init_run`); rows may be longer."""
        unit = cls.__new__(cls)
        unit._bind(
            db=db, settings=settings, delay_spread_s=delay_spread_s, state=state, istate=istate, log=log
        )
        return unit

    def _bind(
        self,
        *,
        db: CircuitDb,
        settings: Positioning,
        delay_spread_s: float,
        state: FloatArray,
        istate: IntArray,
        log: FloatArray,
    ) -> None:
        self.db = db
        self.db_ids = db.ids  # SPEC §2 track-circuit DB: ID -> start chainage
        self.db_starts_m = db.starts_m
        self.db_sd_m = db.sd_m
        self.db_time_sd_s = db.time_sd_s
        self.delay_spread_s = float(delay_spread_s)
        self.settings = settings
        self.n = int(state.shape[0])
        self.state = state
        self.istate = istate
        self.log_ring = log

    # ------------------------------------------------------------------ inputs

    def log(
        self,
        *,
        clock_time_s: FloatArray,
        odometer_m: FloatArray,
        speed_mps: FloatArray,
        wsp_active: BoolArray | None = None,
        accel_mps2: FloatArray | None = None,
    ) -> None:
        """One cycle's sample of every run: its clock reading, odometer, tachometer speed, whether
        the WSP acts and the accelerometer (None: the train has none, see :func:`unit_log_run`)."""
        n = self.n
        _log_runs(
            self.state,
            self.istate,
            self.log_ring,
            _f64_runs(clock_time_s, n),
            _f64_runs(odometer_m, n),
            _f64_runs(speed_mps, n),
            _bool_runs(False if wsp_active is None else wsp_active, n),
            _f64_runs(np.nan if accel_mps2 is None else accel_mps2, n),
        )

    def handle(self, *, run: IntArray, circuit_id: IntArray, gnss_time_s: FloatArray) -> FixReport:
        """Telegrams (circuit ID, GNSS occupancy time) received by runs ``run``; SPEC §2 S30, S40.

        Telegrams of one run are applied in their order.
        """
        run = np.array(run, dtype=np.int64, ndmin=1)
        cid = np.array(circuit_id, dtype=np.int64, ndmin=1)
        tg = np.array(gnss_time_s, dtype=np.float64, ndmin=1)
        k = run.size
        outcome = np.empty(k, dtype=np.int64)
        out_f = np.empty((5, k))
        out_b = np.empty((2, k), dtype=np.bool_)
        cfg = self.settings
        _handle_runs(
            self.state,
            self.istate,
            self.log_ring,
            self.db_ids,
            self.db_starts_m,
            self.db_sd_m,
            self.delay_spread_s,
            bool(cfg.learn),
            float(cfg.max_extrapolation_s),
            settings_squares(cfg).gate_sigma2,
            run,
            cid,
            tg,
            outcome,
            out_f,
            out_b,
            self.db_time_sd_s,
        )
        return FixReport(
            run=run,
            circuit_id=cid,
            outcome=outcome,
            circuit_start_m=out_f[0],
            odometer_at_fix_m=out_f[1],
            speed_at_fix_mps=out_f[2],
            corrected_jump_m=out_f[3],
            calibrated_jump_m=out_f[4],
            learned=out_b[0],
            gated=out_b[1],
        )

    def carry_calibration(
        self, *, scale: FloatArray, scale_sd: float, delay_s: FloatArray, delay_sd_s: float
    ) -> None:
        """Start every run's filter from a calibration kept from earlier trips (beyond SPEC §2):
        the scale and delay with their standard deviations, in place of the settings' prior."""
        if scale_sd < 0.0 or delay_sd_s < 0.0:
            raise ValueError("standard deviations must not be negative")
        self.state[:, U_A] = _f64_runs(scale, self.n)
        self.state[:, U_D] = _f64_runs(delay_s, self.n)
        self.state[:, U_P00] = scale_sd * scale_sd
        self.state[:, U_P01] = 0.0
        self.state[:, U_P10] = 0.0
        self.state[:, U_P11] = delay_sd_s * delay_sd_s

    # ----------------------------------------------------------------- outputs

    def corrected_m(self) -> FloatArray:
        """SPEC §2 corrected position (document method) at the newest log sample."""
        return self.doc_ref_m + (self.odometer_m - self.ref_odo_m)

    def calibrated_m(self) -> FloatArray:
        """Corrected position with the learned scale and delay (beyond SPEC §2)."""
        return self.cal_ref_m + (self.state[:, U_COMP] - self.state[:, U_REF_COMP]) / self.scale_estimate

    def uncertainty_m(self, sigmas: float) -> FloatArray:
        """Location uncertainty of each run's calibrated position now (``unit_uncertainty_m``):
        ``sigmas`` standard deviations of its dead reckoning plus its unbridged slides' bound."""
        out = np.empty(self.n)
        _uncertainty_runs(self.state, float(sigmas), out)
        return out

    def corrected_speed_mps(self) -> FloatArray:
        """Tachometer speed (bridged while the WSP acts) with the learned scale."""
        return self.state[:, U_VREF] / self.scale_estimate

    @property
    def scale_estimate(self) -> FloatArray:
        """Learned odometer scale a = D_assumed / D_actual (1 = no error)."""
        return self.state[:, U_A]

    @property
    def delay_estimate_s(self) -> FloatArray:
        """Learned constant delay d (s) between the entry into a circuit and the telegram's time."""
        return self.state[:, U_D]

    # Views of the per-run state (n,) under the names of the array code.
    @property
    def odometer_m(self) -> FloatArray:
        return self.state[:, U_ODO]

    @property
    def speed_mps(self) -> FloatArray:
        return self.state[:, U_SPEED]

    @property
    def ref_odo_m(self) -> FloatArray:
        return self.state[:, U_REF_ODO]

    @property
    def doc_ref_m(self) -> FloatArray:
        return self.state[:, U_DOC_REF]

    @property
    def cal_ref_m(self) -> FloatArray:
        return self.state[:, U_CAL_REF]

    @property
    def cal_var_m2(self) -> FloatArray:
        return self.state[:, U_CAL_VAR]

    @property
    def theta(self) -> FloatArray:
        """(n, 2): a, d."""
        return self.state[:, U_A : U_D + 1]

    @property
    def cov(self) -> FloatArray:
        """(n, 2, 2): the learner's covariance."""
        return self.state[:, U_P00 : U_P11 + 1].reshape(self.n, 2, 2)

    @property
    def wsp_since_fix(self) -> BoolArray:
        return self.state[:, U_WSP] != 0.0

    @property
    def corrections(self) -> IntArray:
        return self.istate[:, UI_CORRECTIONS]

    @property
    def rejected(self) -> IntArray:
        return self.istate[:, UI_REJECTED]

    @property
    def learned(self) -> IntArray:
        return self.istate[:, UI_LEARNED]

    @property
    def gated(self) -> IntArray:
        return self.istate[:, UI_GATED]

    @property
    def head(self) -> int:
        """Ring slot of the newest sample (common to all runs: every run logs every cycle)."""
        return int(self.istate[0, UI_HEAD]) if self.n else -1

    @property
    def samples(self) -> int:
        return int(self.istate[0, UI_SAMPLES]) if self.n else 0

    @property
    def log_t_s(self) -> FloatArray:
        """(n, L) the ring buffer's clock times (slot order, newest at ``istate[:, UI_HEAD]``)."""
        return self.log_ring[:, LOG_T, :]

    @property
    def log_odo_m(self) -> FloatArray:
        return self.log_ring[:, LOG_ODO, :]

    @property
    def log_v_mps(self) -> FloatArray:
        return self.log_ring[:, LOG_V, :]

    @property
    def compensated_odometer_m(self) -> FloatArray:
        """The newest slide-compensated odometer reading (beyond SPEC §2)."""
        return self.state[:, U_COMP]

    # ---------------------------------------------------------------- look-ups

    def lookup_start_m(self, circuit_id: IntArray) -> tuple[BoolArray, FloatArray]:
        """SPEC §2 S30: (known, start chainage) of each circuit ID in the track-circuit DB."""
        cid = np.array(circuit_id, dtype=np.int64, ndmin=1)
        known = np.empty(cid.size, dtype=np.bool_)
        start = np.empty(cid.size)
        sd = np.empty(cid.size)
        _lookup_many(self.db_ids, self.db_starts_m, self.db_sd_m, cid, known, start, sd)
        return known, start

    def odometer_at(self, run: IntArray, clock_time_s: FloatArray) -> tuple[IntArray, FloatArray, FloatArray]:
        """(outcome, odometer, tachometer speed) of runs ``run`` at their clock time ``clock_time_s``."""
        rr = np.array(run, dtype=np.int64, ndmin=1)
        t = np.array(np.broadcast_to(np.asarray(clock_time_s, dtype=np.float64), rr.shape))
        outcome = np.empty(rr.size, dtype=np.int64)
        odo = np.empty(rr.size)
        v = np.empty(rr.size)
        _odometer_at_runs(
            self.istate, self.log_ring, rr, t, float(self.settings.max_extrapolation_s), outcome, odo, v
        )
        return outcome, odo, v
