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
  or whose time lies outside its log (DESIGN rule 7: no correction is safer
  than a wrong one; the rejection is counted).

Beyond SPEC §2, a **learner** estimates from the history of fixes the
odometer's scale ``a = D_assumed / D_actual`` and the constant part ``d`` of
the delay between the first axle's entry and the time in the telegram
(detection delay plus any constant clock offset). Between two fixes i-1, i
(surveyed starts x, odometer readings o, tachometer speeds v at the telegram
times) the train moved ``x_i - x_{i-1} + d (v_i - v_{i-1}) / a`` true metres
(it was ``d · v / a`` past the start when the odometer was read), so::

    o_i - o_{i-1} = a (x_i - x_{i-1}) + d (v_i - v_{i-1}) + noise

linear in theta = (a, d). A Kalman filter over the fixes of each run (a
recursive least squares with prior ``a ~ N(1, scale_prior)``, ``d ~ N(d0,
delay_prior)``, d0 the nominal detection delay of the line data, 0 when not
given) estimates theta. The noise of one fix is the boundary
uncertainty of its circuit (from the DB: the line data gives it per kind;
``fix_sd_m`` when not given) and the delay spread times the speed. Intervals
in which the wheel-slide / anti-slip protection acted (``wsp_active`` in the
log) are not learned from (the odometer was off by the creep), and an
interval whose innovation exceeds ``gate_sigma`` standard deviations is
rejected as an outlier.

The calibrated position does not simply jump to each fix: the fix
``z = start + d · v_occ / a`` (the position when the odometer was read) is
weighed against the calibrated dead reckoning since the previous fix,
``p = p_prev + (o_i - o_{i-1}) / a``, by their variances (a scalar Kalman
update): once the scale is known, dead reckoning over a few hundred metres
is better than one fix through a jointless circuit's tuned zone. After a
slide or slip the dead reckoning is not trusted (the fix is taken as it is).
Between fixes::

    calibrated(t) = p_i + (odo(t) - o_i) / a

The scale error shows in proportion to the distance since the last fix, the
delay in proportion to the speed at the fix: that is what separates them. At
constant speed ``d`` is not observable (every fix shifts by the same ``d·v``)
and the learner keeps its prior there; speed changes between fixes (leaving
and approaching stations) reveal it.

One implementation (DESIGN rule 1, ``railstop.jit``): the state of one run
lives in three small arrays a caller allocates (:func:`unit_state_arrays`)
and passes to compiled scalar functions:

- ``state``: float64 (U_SIZE,), indices ``U_*`` below (newest odometer and
  speed, the references of both positions, theta, its covariance, the
  previous fix, whether WSP acted since it);
- ``istate``: int64 (UI_SIZE,), indices ``UI_*`` (ring head, samples, and the
  corrections / rejections / learned / gated counters);
- ``log``: float64 (LOG_ROWS, L), rows ``LOG_T``, ``LOG_ODO``, ``LOG_V``: the
  ring buffer, L = :func:`log_length` (window, cycle).

A caller may pass longer ``state``/``istate`` vectors: these functions use
their first U_SIZE / UI_SIZE entries only (``sim/corrected_position.py``
appends its own). :func:`unit_init_run` sets a run up, :func:`unit_log_run`
logs one sample, :func:`unit_handle_run` applies one telegram (S30 look-up,
odometer at the telegram's time, S40 correction, learner, calibrated
position). :class:`PositioningUnit` holds the same arrays for n runs, shape
(n, ·), and loops over the runs in compiled code.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
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
# An interval shorter than this (surveyed metres) carries no scale information worth learning.
MIN_LEARN_DISTANCE_M = 20.0
# Dead-reckoning error the learned scale does not explain (fraction of the distance, standard
# deviation): pulse quantisation, wheel diameter differences between axles, curves.
ODOMETRY_NOISE_FRAC = 1e-3

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
U_REF_ODO = 2  # odometer reading of the last fix: the reference of both positions ...
U_DOC_REF = 3  # ... the SPEC §2 corrected position there (the circuit's start)
U_CAL_REF = 4  # ... the calibrated position there
U_CAL_VAR = 5  # variance of the calibrated position there (m²)
U_A = 6  # learner theta: odometer scale a = D_assumed / D_actual
U_D = 7  # learner theta: constant delay d (s)
U_P00 = 8  # learner covariance P, row-major
U_P01 = 9
U_P10 = 10
U_P11 = 11
U_PREV_X = 12  # previous fix: circuit start (NaN before the first fix)
U_PREV_ODO = 13  # ... odometer reading
U_PREV_V = 14  # ... tachometer speed
U_PREV_VAR = 15  # ... fix variance
U_WSP = 16  # 1.0 when the wheel-slide / anti-slip protection acted since the previous fix
U_SIZE = 17
# Per-run state, int64 vector ``istate``:
UI_HEAD = 0  # index of the newest log sample (-1: none yet)
UI_SAMPLES = 1  # samples logged
UI_CORRECTIONS = 2
UI_REJECTED = 3
UI_LEARNED = 4
UI_GATED = 5
UI_SIZE = 6
# Rows of the log ring ``log`` (LOG_ROWS, L):
LOG_T = 0  # the unit's own GNSS clock time of the sample (-inf: never written)
LOG_ODO = 1
LOG_V = 2
LOG_ROWS = 3


def log_length(log_window_s: float, cycle_s: float) -> int:
    """Samples of the log ring: ``log_window_s`` at one sample per ``cycle_s``, plus one."""
    return int(np.ceil(log_window_s / cycle_s)) + 1


class SettingsSquares(NamedTuple):
    """The squares of the positioning settings the compiled cores take."""

    fix_var_m2: float  # fix_sd_m²: the start position's variance
    scale_prior_var: float  # (scale_prior_pct / 100)²
    delay_prior_var_s2: float  # delay_prior_s²
    gate_sigma2: float  # gate_sigma²


def settings_squares(settings: Positioning) -> SettingsSquares:
    """The settings squared in Python (C ``pow``), as the array code always did: ``x ** 2`` of a
    Python float can differ from ``x * x`` in the last bit, and the compiled code must not."""
    return SettingsSquares(
        fix_var_m2=float(settings.fix_sd_m) ** 2,
        scale_prior_var=(float(settings.scale_prior_pct) * 1e-2) ** 2,
        delay_prior_var_s2=float(settings.delay_prior_s) ** 2,
        gate_sigma2=float(settings.gate_sigma) ** 2,
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
) -> None:
    """One run's unit at its start: empty log, positions at ``start_position_m``, the learner's prior.

    The start is known like a fix (variance ``fix_var_m2``). Without learning
    the calibrated position is the document's: no scale, no delay (d = 0).
    The variances are the settings squared by :func:`settings_squares`.
    """
    log[LOG_T, :] = -np.inf
    log[LOG_ODO, :] = 0.0
    log[LOG_V, :] = 0.0
    for k in range(UI_SIZE):
        istate[k] = 0
    istate[UI_HEAD] = -1
    state[U_ODO] = 0.0
    state[U_SPEED] = 0.0
    state[U_REF_ODO] = 0.0
    state[U_DOC_REF] = start_position_m
    state[U_CAL_REF] = start_position_m
    state[U_CAL_VAR] = fix_var_m2
    state[U_A] = 1.0
    state[U_D] = nominal_delay_s if learn else 0.0
    state[U_P00] = scale_prior_var
    state[U_P01] = 0.0
    state[U_P10] = 0.0
    state[U_P11] = delay_prior_var_s2
    state[U_PREV_X] = np.nan
    state[U_PREV_ODO] = np.nan
    state[U_PREV_V] = np.nan
    state[U_PREV_VAR] = np.nan
    state[U_WSP] = 0.0
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
) -> None:
    """One cycle's sample of one run: its clock reading, odometer and tachometer speed."""
    head = (istate[UI_HEAD] + 1) % log.shape[1]
    istate[UI_HEAD] = head
    istate[UI_SAMPLES] += 1
    log[LOG_T, head] = clock_time_s
    log[LOG_ODO, head] = odometer_m
    log[LOG_V, head] = speed_mps
    state[U_ODO] = odometer_m
    state[U_SPEED] = speed_mps
    if wsp_active:
        state[U_WSP] = 1.0
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
) -> tuple[int, float, float]:
    """(outcome, odometer, tachometer speed) of one run at its clock time ``clock_time_s``.

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
    if not np.isfinite(log[LOG_T, (first + max(i, 0)) % length]):  # slots never written: -inf
        i = -1
    if i < 0:
        return _STALE, np.nan, np.nan
    if i == length - 1:
        newest = (first + i) % length
        dt_new = clock_time_s - log[LOG_T, newest]
        if dt_new <= max_extrapolation_s:
            return _ACCEPTED, log[LOG_ODO, newest] + log[LOG_V, newest] * dt_new, log[LOG_V, newest]
        return _FUTURE, np.nan, np.nan
    s0 = (first + i) % length
    s1 = (first + i + 1) % length
    t0 = log[LOG_T, s0]
    w = (clock_time_s - t0) / (log[LOG_T, s1] - t0)
    odo = log[LOG_ODO, s0] + w * (log[LOG_ODO, s1] - log[LOG_ODO, s0])
    v = log[LOG_V, s0] + w * (log[LOG_V, s1] - log[LOG_V, s0])
    return _ACCEPTED, odo, v


@njit_inline
def _unit_learn_run(
    state: FloatArray,
    istate: IntArray,
    x_m: float,
    odo_m: float,
    v_mps: float,
    fix_var_m2: float,
    learn: bool,
    gate_sigma2: float,
) -> tuple[bool, bool]:
    """Kalman update of theta = (a, d) with the interval since the run's previous fix: (learned, gated)."""
    dx = x_m - state[U_PREV_X]
    learned = False
    gated = False
    if learn and np.isfinite(dx) and dx >= MIN_LEARN_DISTANCE_M and state[U_WSP] == 0.0:
        phi0 = dx
        phi1 = v_mps - state[U_PREV_V]
        y = odo_m - state[U_PREV_ODO]
        a = state[U_A]
        d = state[U_D]
        c00 = state[U_P00] + _SCALE_PROCESS_VAR
        c01 = state[U_P01] + 0.0
        c10 = state[U_P10] + 0.0
        c11 = state[U_P11] + _DELAY_PROCESS_VAR_S2
        p0 = c00 * phi0 + c01 * phi1  # P phi
        p1 = c10 * phi0 + c11 * phi1
        # The interval's noise: that of its two fixes.
        s_var = (phi0 * p0 + phi1 * p1) + fix_var_m2 + state[U_PREV_VAR]
        innov = y - (phi0 * a + phi1 * d)
        g0 = p0 / s_var
        g1 = p1 / s_var
        if innov * innov <= gate_sigma2 * s_var:
            state[U_A] = a + g0 * innov
            state[U_D] = d + g1 * innov
            state[U_P00] = c00 - g0 * p0
            state[U_P01] = c01 - g0 * p1
            state[U_P10] = c10 - g1 * p0
            state[U_P11] = c11 - g1 * p1
            learned = True
            istate[UI_LEARNED] += 1
        else:  # an outlier: not learned from (the process noise stays added)
            state[U_P00] = c00
            state[U_P01] = c01
            state[U_P10] = c10
            state[U_P11] = c11
            gated = True
            istate[UI_GATED] += 1
    state[U_PREV_X] = x_m
    state[U_PREV_ODO] = odo_m
    state[U_PREV_V] = v_mps
    state[U_PREV_VAR] = fix_var_m2
    state[U_WSP] = 0.0
    return learned, gated


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
    outcome, o, vv = unit_odometer_at_run(istate, log, gnss_time_s, max_extrapolation_s)
    if not known:
        outcome = _UNKNOWN_CIRCUIT
    if outcome != _ACCEPTED:
        istate[UI_REJECTED] += 1
        return outcome, x, np.nan, np.nan, 0.0, 0.0, False, False
    q = vv * delay_spread_s
    fix_var = sd * sd + q * q

    # SPEC §2 S40: the odometer position at the occupancy instant becomes the circuit start.
    moved = o - state[U_REF_ODO]
    doc_before = state[U_DOC_REF] + moved
    # Beyond SPEC §2: calibrated dead reckoning since the last fix, and its variance.
    a0 = state[U_A]
    cal_before = state[U_CAL_REF] + moved / a0
    r1 = moved / (a0 * a0)
    r2 = ODOMETRY_NOISE_FRAC * moved / a0
    pred_var = state[U_CAL_VAR] + r1 * r1 * state[U_P00] + r2 * r2
    if state[U_WSP] != 0.0 or not learn:
        pred_var = np.inf

    learned, gated = _unit_learn_run(state, istate, x, o, vv, fix_var, learn, gate_sigma2)

    a = state[U_A]
    d = state[U_D]
    state[U_REF_ODO] = o
    state[U_DOC_REF] = x
    # Beyond SPEC §2: the train was d·v_true past the start when the odometer was read ...
    z = x + d * vv / a
    r3 = vv / a
    z_var = fix_var + r3 * r3 * state[U_P11]
    # ... and that fix is weighed against the dead reckoning (K = 1 after a slide or slip).
    if np.isinf(pred_var):
        gain = 1.0
        state[U_CAL_VAR] = z_var
    else:
        gain = pred_var / (pred_var + z_var)
        state[U_CAL_VAR] = (1.0 - gain) * pred_var
    cal = cal_before + gain * (z - cal_before)
    state[U_CAL_REF] = cal
    istate[UI_CORRECTIONS] += 1
    return outcome, x, o, vv, doc_before - x, cal_before - cal, learned, gated


@njit_inline
def unit_corrected_m(state: FloatArray) -> float:
    """SPEC §2 corrected position (document method) of one run at its newest log sample."""
    return state[U_DOC_REF] + (state[U_ODO] - state[U_REF_ODO])


@njit_inline
def unit_calibrated_m(state: FloatArray) -> float:
    """Corrected position of one run with the learned scale and delay (beyond SPEC §2)."""
    return state[U_CAL_REF] + (state[U_ODO] - state[U_REF_ODO]) / state[U_A]


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
) -> None:
    for i in range(clock_time_s.size):
        unit_log_run(state[i], istate[i], log[i], clock_time_s[i], odometer_m[i], speed_mps[i], wsp_active[i])
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
) -> None:
    """Telegrams in their order (those of one run applied one after the other)."""
    for k in range(run.size):
        r = run[k]
        res = unit_handle_run(
            state[r],
            istate[r],
            log[r],
            db_ids,
            db_starts_m,
            db_sd_m,
            delay_spread_s,
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
        outcome[k], odo[k], v[k] = unit_odometer_at_run(
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

    @classmethod
    def create(
        cls, circuits: Sequence[TrackCircuit], boundary_sd_m: Sequence[float] | None, default_sd_m: float
    ) -> CircuitDb:
        """``boundary_sd_m``: per circuit (in the order of ``circuits``); ``default_sd_m`` when None."""
        ids = np.array([c.id for c in circuits], dtype=np.int64)
        starts = np.array([c.start_m for c in circuits], dtype=np.float64)
        sds = np.full(ids.size, default_sd_m) if boundary_sd_m is None else np.asarray(boundary_sd_m)
        if sds.shape != ids.shape or np.any(sds < 0.0):
            raise ValueError("boundary_sd_m needs one non-negative value per circuit")
        order = np.argsort(ids)
        return cls(
            ids=np.ascontiguousarray(ids[order]),
            starts_m=np.ascontiguousarray(starts[order]),
            sd_m=np.ascontiguousarray(sds[order], dtype=np.float64),
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
    ) -> None:
        """``boundary_sd_m``: per circuit (in the order of ``circuits``), the uncertainty of its
        start as a fix; ``delay_spread_s``, ``nominal_delay_s``: the detection delay's spread and
        mean (all line data); the nominal delay is the learner's prior, it learns the actual one."""
        if cycle_s <= 0.0:
            raise ValueError(f"cycle_s must be positive, got {cycle_s}")
        if delay_spread_s < 0.0:
            raise ValueError(f"delay_spread_s must not be negative, got {delay_spread_s}")
        db = CircuitDb.create(circuits, boundary_sd_m, settings.fix_sd_m)
        length = log_length(settings.log_window_s, cycle_s)
        state = np.empty((n, U_SIZE))
        istate = np.empty((n, UI_SIZE), dtype=np.int64)
        log = np.empty((n, LOG_ROWS, length))
        sq = settings_squares(settings)
        _init_runs(
            state,
            istate,
            log,
            _f64_runs(start_position_m, n),
            sq.fix_var_m2,
            bool(settings.learn),
            float(nominal_delay_s),
            sq.scale_prior_var,
            sq.delay_prior_var_s2,
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
    ) -> None:
        """One cycle's sample of every run: its clock reading, odometer and tachometer speed."""
        n = self.n
        _log_runs(
            self.state,
            self.istate,
            self.log_ring,
            _f64_runs(clock_time_s, n),
            _f64_runs(odometer_m, n),
            _f64_runs(speed_mps, n),
            _bool_runs(False if wsp_active is None else wsp_active, n),
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

    # ----------------------------------------------------------------- outputs

    def corrected_m(self) -> FloatArray:
        """SPEC §2 corrected position (document method) at the newest log sample."""
        return self.doc_ref_m + (self.odometer_m - self.ref_odo_m)

    def calibrated_m(self) -> FloatArray:
        """Corrected position with the learned scale and delay (beyond SPEC §2)."""
        return self.cal_ref_m + (self.odometer_m - self.ref_odo_m) / self.scale_estimate

    def corrected_speed_mps(self) -> FloatArray:
        """Tachometer speed with the learned scale."""
        return self.speed_mps / self.scale_estimate

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
    def prev_x_m(self) -> FloatArray:
        return self.state[:, U_PREV_X]

    @property
    def prev_odo_m(self) -> FloatArray:
        return self.state[:, U_PREV_ODO]

    @property
    def prev_v_mps(self) -> FloatArray:
        return self.state[:, U_PREV_V]

    @property
    def prev_var_m2(self) -> FloatArray:
        return self.state[:, U_PREV_VAR]

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
