"""Position fixes of the ``ato-corrected`` baseline: SPEC §2 corrections from track circuits.

The conventional onboard ATO (``railstop.onboard.ato``) stops from its own
odometry. ``ato-corrected`` is the same ATO whose position is corrected by
the method of SPEC §2 instead of station transponders: the wayside
time-stamps each track-circuit occupancy with GNSS time, the train corrects
its odometer position against the circuit's surveyed start
(:class:`~railstop.onboard.positioning.PositioningUnit`). A competent ATO
knows the line's nominal detection delay: it uses the unit's calibrated
position, which adds delay × speed to each fix (the document method alone
leaves the train that far behind its true position, metres at approach
speeds) and learns scale and delay over the few fixes of the approach.

Assumptions of this driver (documented, not drawn): GNSS-disciplined clocks
on both sides (offsets of ~100 ns, negligible); the occupancy telegram goes
on the radio with the run's latency (the positioning unit uses the time in
the telegram, so the latency only delays the fix); its GNSS time has the
codec's 0.1 ms resolution. Before the simulated approach the train was
corrected at the last circuit boundary behind it, so it starts with that
fix's error (detection delay × speed, boundary uncertainty) plus its
odometer's scale error over the distance since.

One implementation (DESIGN rule 1, ``railstop.jit``): the driver of one run
is :func:`fixes_init_run` and :func:`fixes_step_run`, compiled scalar code
over the run's state (:func:`fixes_state_arrays`): the positioning unit's
(``onboard/positioning.py``) with the driver's own entries appended (indices
``FX_*``, ``FXI_*``) and the detector's (``sensors/track_circuit.py``).
:class:`FixesLine` gives everything else they need as plain arrays and
scalars; :class:`TrackCircuitFixes` runs n runs in one compiled loop per call.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import Track, Vehicle
from railstop.errors import SimulationError
from railstop.jit import njit, njit_inline, njit_step, rint_1
from railstop.link.codec import TrackCircuitOccupancy, layout_of
from railstop.onboard.positioning import (
    LOG_ROWS,
    U_CAL_VAR,
    U_ODO,
    U_SIZE,
    UI_SIZE,
    UNTRUSTED_VAR_M2,
    CircuitDb,
    FixOutcome,
    PositioningUnit,
    log_length,
    settings_squares,
    unit_calibrated_m,
    unit_handle_run,
    unit_init_run,
    unit_log_run,
)
from railstop.sensors.track_circuit import (
    TrackCircuitDetector,
    circuit_arrays,
    tc_draw_run,
    tc_first_index,
    tc_next_entry,
)
from railstop.stream_cores import seed_key, stream_key
from railstop.streams import RunStreams, Stream, seed_u64

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

LOG_WINDOW_S = 2.0  # covers the detection delay and the radio latency of a telegram

_ACCEPTED = int(FixOutcome.ACCEPTED)
_TC_BOUNDARY = int(Stream.TC_BOUNDARY)
_TC_DELAY = int(Stream.TC_DELAY)

# The driver's entries after the unit's in the per-run float64 state vector ...
FX_PENDING_TIME = U_SIZE + 0  # GNSS time of the telegram on its way (inf: none)
FX_PENDING_ARRIVAL = U_SIZE + 1  # when it reaches the train
FX_START = U_SIZE + 2  # the corrected position at the start of the simulation
FX_SIZE = U_SIZE + 3
# ... and in the int64 one.
FXI_NEXT = UI_SIZE + 0  # next circuit (line order) the run will enter; C = none left
FXI_PENDING_CIRCUIT = UI_SIZE + 1  # circuit id of the telegram on its way (-1: none)
FXI_SIZE = UI_SIZE + 2


class FixesRun(NamedTuple):
    """The state of the fixes chain of one run (or, as 2-D arrays, of n runs): the positioning
    unit's vectors (FX_*, FXI_*) and odometer log, the detector's draws per circuit."""

    state: FloatArray  # (FX_SIZE,)
    istate: IntArray  # (FXI_SIZE,)
    log: FloatArray  # (LOG_ROWS, log_len)
    boundary_m: FloatArray  # (C,) each circuit's electrical boundary
    delay_s: FloatArray  # (C,) ... and detection delay


class FixesData(NamedTuple):
    """What a step of the chain needs of the line and the unit's settings (``FixesLine.data``)."""

    tc_ids: IntArray  # (C,) circuits in line order (the detector's)
    db_ids: IntArray  # (C,) the onboard track-circuit DB, sorted by ID
    db_starts_m: FloatArray
    db_sd_m: FloatArray
    delay_spread_s: float
    learn: bool
    max_extrapolation_s: float
    gate_sigma2: float
    gnss_counts_per_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class FixesLine:
    """What the driver needs of the line, the vehicle and the step, as plain arrays and scalars."""

    tc_ids: IntArray  # (C,) circuits in line order (the detector's)
    tc_starts_m: FloatArray  # (C,) surveyed starts
    tc_sd_m: FloatArray  # (C,) boundary uncertainty of each circuit (its kind)
    db_ids: IntArray  # (C,) the onboard track-circuit DB, sorted by ID
    db_starts_m: FloatArray
    db_sd_m: FloatArray
    delay_mean_s: float  # detection delay: the detector's mean and the unit's nominal delay
    delay_spread_s: float
    # Vehicle positioning settings; the squared ones from ``settings_squares`` (bit-identical
    # to the array code's Python squares).
    fix_var_m2: float
    learn: bool
    scale_prior_var: float
    delay_prior_var_s2: float
    max_extrapolation_s: float
    gate_sigma2: float
    gnss_counts_per_s: float  # the telegram's GNSS-time resolution (codec): 1e4 = 0.1 ms
    log_len: int  # log ring samples: LOG_WINDOW_S at one sample per step

    @classmethod
    def create(cls, *, track: Track | None, vehicle: Vehicle, dt_s: float) -> FixesLine:
        if track is None or not track.circuits:
            raise SimulationError("ato-corrected needs the line's track circuits ([track] circuits)")
        if dt_s <= 0.0:
            raise ValueError(f"dt_s must be positive, got {dt_s}")
        det = track.detection
        if det.delay_spread_s < 0.0:
            raise ValueError(f"delay_spread_s must not be negative, got {det.delay_spread_s}")
        ids, starts, sds = circuit_arrays(track.circuits, det)
        db = CircuitDb.create(track.circuits, sds.tolist(), vehicle.positioning.fix_sd_m)
        gnss = next(f for f in layout_of(TrackCircuitOccupancy).fields if f.name == "gnss_time_s")
        pos = vehicle.positioning
        sq = settings_squares(pos)
        return cls(
            tc_ids=ids,
            tc_starts_m=starts,
            tc_sd_m=sds,
            db_ids=db.ids,
            db_starts_m=db.starts_m,
            db_sd_m=db.sd_m,
            delay_mean_s=float(det.delay_mean_s),
            delay_spread_s=float(det.delay_spread_s),
            fix_var_m2=sq.fix_var_m2,
            learn=bool(pos.learn),
            scale_prior_var=sq.scale_prior_var,
            delay_prior_var_s2=sq.delay_prior_var_s2,
            max_extrapolation_s=float(pos.max_extrapolation_s),
            gate_sigma2=sq.gate_sigma2,
            gnss_counts_per_s=float(gnss.counts_per_unit),
            log_len=log_length(LOG_WINDOW_S, dt_s),
        )

    @property
    def n_circuits(self) -> int:
        return int(self.tc_ids.size)

    def data(self) -> FixesData:
        """The record :func:`fixes_step_run` takes."""
        return FixesData(
            self.tc_ids, self.db_ids, self.db_starts_m, self.db_sd_m, self.delay_spread_s, self.learn,
            self.max_extrapolation_s, self.gate_sigma2, self.gnss_counts_per_s,
        )  # fmt: skip


def fixes_state_arrays(
    n_circuits: int, log_len: int
) -> tuple[FloatArray, IntArray, FloatArray, FloatArray, FloatArray]:
    """Uninitialised state of one run: (state (FX_SIZE,), istate (FXI_SIZE,) int64, log (LOG_ROWS,
    log_len), boundary_m (C,), delay_s (C,)); :func:`fixes_init_run` fills them."""
    return (
        np.empty(FX_SIZE),
        np.empty(FXI_SIZE, dtype=np.int64),
        np.empty((LOG_ROWS, log_len)),
        np.empty(n_circuits),
        np.empty(n_circuits),
    )


# --------------------------------------------------------------------------
# Compiled per-run cores


@njit_step
def fixes_init_run(
    state: FloatArray,
    istate: IntArray,
    log: FloatArray,
    boundary_m: FloatArray,
    delay_s: FloatArray,
    tc_starts_m: FloatArray,
    tc_sd_m: FloatArray,
    delay_mean_s: float,
    delay_spread_s: float,
    boundary_key: np.uint64,
    delay_key: np.uint64,
    start_m: float,
    speed_mps: float,
    tach_scale: float,
    fix_var_m2: float,
    learn: bool,
    scale_prior_var: float,
    delay_prior_var_s2: float,
) -> float:
    """One run at the start of the approach: the detector's draws, the fix behind the train, the unit.

    Returns the corrected position the train starts with (chainage); NaN
    when no circuit starts at or behind ``start_m`` (then ``istate[FXI_NEXT]``
    is 0 and the run cannot be simulated).
    """
    tc_draw_run(
        tc_starts_m, tc_sd_m, delay_mean_s, delay_spread_s, boundary_key, delay_key, boundary_m, delay_s
    )
    nxt = tc_first_index(tc_starts_m, start_m)
    istate[FXI_NEXT] = nxt
    istate[FXI_PENDING_CIRCUIT] = -1
    state[FX_PENDING_TIME] = np.inf
    state[FX_PENDING_ARRIVAL] = np.inf
    last = nxt - 1
    belief = np.nan
    if last >= 0:
        # SPEC §2 S40 at the last boundary behind the train: when the wayside declared
        # the occupancy the front was delay × speed past the electrical boundary; the
        # train put itself at the surveyed start plus the nominal delay × its speed;
        # since then its odometer counted with its scale error.
        at_fix = boundary_m[last] + speed_mps * delay_s[last]
        belief = tc_starts_m[last] + delay_mean_s * speed_mps * tach_scale + (start_m - at_fix) * tach_scale
    # The station-stop kernel's train has no accelerometer: a slide leaves its dead reckoning
    # untrusted until the next fix (SPEC §2 alone), no bridge (accelerometer bias variance 0).
    unit_init_run(
        state, istate, log, belief, fix_var_m2, learn, delay_mean_s, scale_prior_var, delay_prior_var_s2, 0.0
    )
    # The start is the SPEC §2 belief, not a fix the filter may learn the scale against: the
    # first fix in the approach is taken as it is and the learning starts from it.
    state[U_CAL_VAR] = UNTRUSTED_VAR_M2
    state[FX_START] = belief
    return belief


@njit_inline
def fixes_step_run(
    run: FixesRun,
    data: FixesData,
    t0_s: float,
    dt_s: float,
    x0_m: float,
    v0_mps: float,
    accel_mps2: float,
    x1_m: float,
    odometer_increment_m: float,
    tach_speed_mps: float,
    sliding: bool,
    latency_s: float,
) -> tuple[bool, float]:
    """One step of one run: log the odometer, detect occupancies, take the telegram that arrived.

    Returns (corrected now, calibrated position): the position with the
    line's nominal detection delay taken into account (and whatever the unit
    learned of scale and delay since), chainage, at the end of the step.

    Inlined into the stop step, which calls it every step (issue 37): out of line, the call
    made the compiler keep the caller's state in memory around it and passed nine arrays
    through the stack; inlined, ``ato-corrected`` ran 568.2 -> 350.3 µs of thread CPU time per
    run (1,000 standard runs at Riverside, every result the same bit).
    """
    state, istate, log, boundary_m, delay_s = run.state, run.istate, run.log, run.boundary_m, run.delay_s
    tc_ids, db_ids, db_starts_m, db_sd_m = data.tc_ids, data.db_ids, data.db_starts_m, data.db_sd_m
    gnss_counts_per_s = data.gnss_counts_per_s
    now = t0_s + dt_s
    odometer = state[U_ODO] + odometer_increment_m  # the cumulative reading: the newest logged + this step's
    # GNSS-disciplined onboard clock: its reading is the true time.
    unit_log_run(state, istate, log, now, odometer, tach_speed_mps, sliding, np.nan)
    while True:
        nxt = istate[FXI_NEXT]
        hit, _, occupied = tc_next_entry(boundary_m, delay_s, nxt, x0_m, v0_mps, accel_mps2, x1_m, t0_s)
        if not hit:
            break
        # SPEC §2 S20: (circuit ID, occupancy instant in GNSS time), on the radio with the run's
        # latency; the codec carries the time at its resolution (half to even, as the codec rounds).
        # A newer occupancy replaces a telegram still on its way.
        istate[FXI_PENDING_CIRCUIT] = tc_ids[nxt]
        state[FX_PENDING_TIME] = rint_1(occupied * gnss_counts_per_s) / gnss_counts_per_s
        state[FX_PENDING_ARRIVAL] = occupied + latency_s
        istate[FXI_NEXT] = nxt + 1
    if not state[FX_PENDING_ARRIVAL] <= now + 1e-9:
        return False, unit_calibrated_m(state)
    res = unit_handle_run(
        state,
        istate,
        log,
        db_ids,
        db_starts_m,
        db_sd_m,
        data.delay_spread_s,
        data.learn,
        data.max_extrapolation_s,
        data.gate_sigma2,
        istate[FXI_PENDING_CIRCUIT],
        state[FX_PENDING_TIME],
    )
    istate[FXI_PENDING_CIRCUIT] = -1
    state[FX_PENDING_TIME] = np.inf
    state[FX_PENDING_ARRIVAL] = np.inf
    return res[0] == _ACCEPTED, unit_calibrated_m(state)


# --------------------------------------------------------------------------
# The same for n runs, one compiled loop per call


@njit
def _init_runs(
    state: FloatArray,
    istate: IntArray,
    log: FloatArray,
    boundary_m: FloatArray,
    delay_s: FloatArray,
    tc_starts_m: FloatArray,
    tc_sd_m: FloatArray,
    delay_mean_s: float,
    delay_spread_s: float,
    seed: np.uint64,
    run_index: IntArray,
    start_m: FloatArray,
    speed_mps: FloatArray,
    tach_scale: FloatArray,
    fix_var_m2: float,
    learn: bool,
    scale_prior_var: float,
    delay_prior_var_s2: float,
) -> None:
    b_key = seed_key(seed, np.int64(_TC_BOUNDARY))
    d_key = seed_key(seed, np.int64(_TC_DELAY))
    for i in range(run_index.size):
        fixes_init_run(
            state[i],
            istate[i],
            log[i],
            boundary_m[i],
            delay_s[i],
            tc_starts_m,
            tc_sd_m,
            delay_mean_s,
            delay_spread_s,
            stream_key(b_key, run_index[i]),
            stream_key(d_key, run_index[i]),
            start_m[i],
            speed_mps[i],
            tach_scale[i],
            fix_var_m2,
            learn,
            scale_prior_var,
            delay_prior_var_s2,
        )
    return


@njit
def _step_runs(
    runs: FixesRun,
    data: FixesData,
    t0_s: float,
    dt_s: float,
    x0_m: FloatArray,
    v0_mps: FloatArray,
    accel_mps2: FloatArray,
    x1_m: FloatArray,
    odometer_increment_m: FloatArray,
    tach_speed_mps: FloatArray,
    sliding: BoolArray,
    latency_s: FloatArray,
    corrected: BoolArray,
    calibrated_m: FloatArray,
) -> None:
    for i in range(x0_m.size):
        run = FixesRun(runs.state[i], runs.istate[i], runs.log[i], runs.boundary_m[i], runs.delay_s[i])
        corrected[i], calibrated_m[i] = fixes_step_run(
            run,
            data,
            t0_s,
            dt_s,
            x0_m[i],
            v0_mps[i],
            accel_mps2[i],
            x1_m[i],
            odometer_increment_m[i],
            tach_speed_mps[i],
            sliding[i],
            latency_s[i],
        )
    return


# --------------------------------------------------------------------------
# Array wrapper


def _f64(a: FloatArray | float, n: int) -> FloatArray:
    """One value per run, contiguous float64 (no copy when it already is)."""
    arr = np.asarray(a, dtype=np.float64)
    return np.ascontiguousarray(arr if arr.shape == (n,) else np.broadcast_to(arr, (n,)).copy())


def _bool(a: BoolArray | bool, n: int) -> BoolArray:
    arr = np.asarray(a, dtype=np.bool_)
    return np.ascontiguousarray(arr if arr.shape == (n,) else np.broadcast_to(arr, (n,)).copy())


@dataclass(slots=True)
class TrackCircuitFixes:
    """Track-circuit occupancies -> (circuit, GNSS time) telegrams -> corrected positions, n runs.

    ``detector`` and ``unit`` are views of the per-run state (rows of
    ``unit.state``, ``unit.istate``, ``unit.log_ring``, ``detector.boundary_m``,
    ``detector.delay_s``), which the compiled per-run cores advance.
    """

    line: FixesLine
    detector: TrackCircuitDetector
    unit: PositioningUnit
    start_position_m: FloatArray  # the corrected position at the start of the simulation

    @classmethod
    def create(
        cls,
        *,
        track: Track | None,
        vehicle: Vehicle,
        streams: RunStreams,
        start_m: FloatArray,
        speed_mps: FloatArray,
        tach_scale: FloatArray,
        dt_s: float,
    ) -> TrackCircuitFixes:
        line = FixesLine.create(track=track, vehicle=vehicle, dt_s=dt_s)
        n, c_count = streams.n, line.n_circuits
        state = np.empty((n, FX_SIZE))
        istate = np.empty((n, FXI_SIZE), dtype=np.int64)
        log = np.empty((n, LOG_ROWS, line.log_len))
        boundary = np.empty((n, c_count))
        delay = np.empty((n, c_count))
        _init_runs(
            state,
            istate,
            log,
            boundary,
            delay,
            line.tc_starts_m,
            line.tc_sd_m,
            line.delay_mean_s,
            line.delay_spread_s,
            seed_u64(streams.seed),
            np.ascontiguousarray(streams.run_index, dtype=np.int64),
            _f64(start_m, n),
            _f64(speed_mps, n),
            _f64(tach_scale, n),
            line.fix_var_m2,
            line.learn,
            line.scale_prior_var,
            line.delay_prior_var_s2,
        )
        if np.any(istate[:, FXI_NEXT] == 0):
            raise SimulationError("ato-corrected: the approach starts before the first track circuit")
        detector = TrackCircuitDetector(
            ids=line.tc_ids,
            starts_m=line.tc_starts_m,
            boundary_m=boundary,
            delay_s=delay,
            next_index=istate[:, FXI_NEXT],
        )
        unit = PositioningUnit.over(
            db=CircuitDb(ids=line.db_ids, starts_m=line.db_starts_m, sd_m=line.db_sd_m),
            settings=vehicle.positioning.model_copy(update={"log_window_s": LOG_WINDOW_S}),
            delay_spread_s=line.delay_spread_s,
            state=state,
            istate=istate,
            log=log,
        )
        return cls(line=line, detector=detector, unit=unit, start_position_m=state[:, FX_START].copy())

    @property
    def odometer_m(self) -> FloatArray:
        """Cumulative odometer reading (the unit's newest logged one)."""
        return self.unit.odometer_m

    @property
    def pending_circuit(self) -> IntArray:
        """Circuit id of the telegram on its way (-1: none)."""
        return self.unit.istate[:, FXI_PENDING_CIRCUIT]

    @property
    def pending_time_s(self) -> FloatArray:
        """Its GNSS time."""
        return self.unit.state[:, FX_PENDING_TIME]

    @property
    def pending_arrival_s(self) -> FloatArray:
        """When it reaches the train."""
        return self.unit.state[:, FX_PENDING_ARRIVAL]

    def step(
        self,
        *,
        t0_s: float,
        dt_s: float,
        x0_m: FloatArray,
        v0_mps: FloatArray,
        accel_mps2: FloatArray,
        x1_m: FloatArray,
        odometer_increment_m: FloatArray,
        tach_speed_mps: FloatArray,
        sliding: BoolArray,
        latency_s: FloatArray,
    ) -> tuple[IntArray, FloatArray]:
        """One step: log the odometer, detect occupancies, take telegrams that arrived.

        Returns the runs corrected now and their corrected positions (chainage).
        """
        n = self.unit.n
        line = self.line
        corrected = np.empty(n, dtype=np.bool_)
        calibrated = np.empty(n)
        _step_runs(
            FixesRun(
                self.unit.state,
                self.unit.istate,
                self.unit.log_ring,
                self.detector.boundary_m,
                self.detector.delay_s,
            ),
            line.data(),
            float(t0_s),
            float(dt_s),
            _f64(x0_m, n),
            _f64(v0_mps, n),
            _f64(accel_mps2, n),
            _f64(x1_m, n),
            _f64(odometer_increment_m, n),
            _f64(tach_speed_mps, n),
            _bool(sliding, n),
            _f64(latency_s, n),
            corrected,
            calibrated,
        )
        rows = np.flatnonzero(corrected)
        return rows, calibrated[rows]
