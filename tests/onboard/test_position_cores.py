"""The SPEC §2 position-correction chain's compiled per-run cores, driven directly.

The array classes (``TrackCircuitDetector``, ``PositioningUnit``,
``TrackCircuitFixes``) are loops over runs of these cores; here one run's
state is allocated and advanced by hand, as the stop kernel does, and must
give exactly (bit for bit) what the array wrapper gives that run.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

from railstop.config import default_line, default_vehicle
from railstop.config.schema import Positioning, TrackCircuit, TrackCircuitDetection
from railstop.model.fixes import (
    FX_START,
    FXI_NEXT,
    FixesData,
    FixesLine,
    FixesRun,
    TrackCircuitFixes,
    fixes_init_run,
    fixes_state_arrays,
    fixes_step_run,
)
from railstop.onboard.positioning import (
    U_A,
    UI_CORRECTIONS,
    UI_REJECTED,
    FixOutcome,
    PositioningUnit,
    log_length,
    settings_squares,
    unit_calibrated_m,
    unit_corrected_m,
    unit_handle_run,
    unit_init_run,
    unit_log_run,
    unit_state_arrays,
)
from railstop.sensors.track_circuit import TrackCircuitDetector, tc_draw_run, tc_first_index, tc_next_entry
from railstop.stream_cores import seed_key, stream_key
from railstop.streams import RunStreams, Stream, seed_u64

LINE = default_line()
VEHICLE = default_vehicle()
DT = 0.01


def _keys(seed: int, run: int) -> tuple[np.uint64, np.uint64]:
    """The run's keys of the boundary and delay streams."""
    s = seed_u64(seed)
    return (
        np.uint64(stream_key(np.uint64(seed_key(s, np.int64(Stream.TC_BOUNDARY))), np.int64(run))),
        np.uint64(stream_key(np.uint64(seed_key(s, np.int64(Stream.TC_DELAY))), np.int64(run))),
    )


def _same(a: object, b: object) -> bool:
    return bool(np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True))


# --------------------------------------------------------------------------
# Detector


def test_detector_core_is_the_wrapper_run_by_run() -> None:
    circuits = [
        TrackCircuit(id=7, start_m=0.0, end_m=3.0),
        TrackCircuit(id=8, start_m=3.0, end_m=4.0, kind="insulated"),
        TrackCircuit(id=9, start_m=4.0, end_m=60.0),
        TrackCircuit(id=10, start_m=60.0, end_m=90.0),
    ]
    det = TrackCircuitDetection(
        delay_mean_s=0.3, delay_spread_s=0.1, boundary_sd_jointless_m=1.5, boundary_sd_insulated_m=0.2
    )
    n, seed, first = 6, 11, 500
    x0 = np.linspace(-5.0, 2.0, n)
    wrapper = TrackCircuitDetector.create(
        circuits, det, RunStreams.for_runs(seed, first, n), start_position_m=x0
    )
    starts = np.array([c.start_m for c in circuits])
    sds = np.array([det.boundary_sd_m(c.kind) for c in circuits])
    v = np.linspace(8.0, 20.0, n)
    events: list[tuple[int, int, float, float]] = []
    per_run: list[tuple[int, int, float, float]] = []
    boundary = np.empty((n, starts.size))
    delay = np.empty((n, starts.size))
    nxt = np.empty(n, dtype=np.int64)
    for r in range(n):
        bk, dk = _keys(seed, first + r)
        tc_draw_run(starts, sds, det.delay_mean_s, det.delay_spread_s, bk, dk, boundary[r], delay[r])
        nxt[r] = tc_first_index(starts, x0[r])
    assert np.array_equal(boundary, wrapper.boundary_m) and np.array_equal(delay, wrapper.delay_s)
    assert np.array_equal(nxt, wrapper.next_index)
    x = x0.copy()
    several = False
    for k in range(60):
        dt = 0.5  # long steps: several circuits entered in one step
        a = np.full(n, -0.1)
        x1 = x + v * dt + 0.5 * a * dt * dt
        ev = wrapper.detect(x0_m=x, v0_mps=v, accel_mps2=a, x1_m=x1, t0_s=k * dt)
        several |= ev.size > np.unique(ev.run).size
        events += list(
            zip(
                ev.run.tolist(),
                ev.circuit_index.tolist(),
                ev.entry_time_s.tolist(),
                ev.occupied_time_s.tolist(),
                strict=True,
            )
        )
        for r in range(n):
            while True:
                hit, entry, occupied = tc_next_entry(
                    boundary[r], delay[r], int(nxt[r]), x[r], v[r], a[r], x1[r], k * dt
                )
                if not hit:
                    break
                per_run.append((r, int(nxt[r]), entry, occupied))
                nxt[r] += 1
        x, v = x1, v + a * dt
    assert several and len(events) > n
    assert sorted(events) == sorted(per_run)
    assert np.array_equal(nxt, wrapper.next_index)


# --------------------------------------------------------------------------
# Positioning unit


def test_unit_core_is_the_wrapper_run_by_run() -> None:
    circuits = [TrackCircuit(id=i + 1, start_m=200.0 * i, end_m=200.0 * (i + 1)) for i in range(12)]
    settings = Positioning(log_window_s=3.0, gate_sigma=3.0)
    n = 3
    unit = PositioningUnit(
        circuits=circuits,
        settings=settings,
        n=n,
        cycle_s=0.05,
        start_position_m=np.array([0.0, 5.0, 10.0]),
        boundary_sd_m=[1.0] * len(circuits),
        delay_spread_s=0.02,
        nominal_delay_s=0.25,
    )
    db = unit.db
    sq = settings_squares(settings)
    runs = [unit_state_arrays(log_length(settings.log_window_s, 0.05)) for _ in range(n)]
    for r, (st, ist, lg) in enumerate(runs):
        unit_init_run(
            st,
            ist,
            lg,
            [0.0, 5.0, 10.0][r],
            sq.fix_var_m2,
            True,
            0.25,
            sq.scale_prior_var,
            sq.delay_prior_var_s2,
            sq.accel_bias_var,
        )
    speed = np.array([12.0, 15.0, 18.0])
    scale = np.array([1.02, 0.99, 1.0])
    x = np.array([0.0, 5.0, 10.0])
    next_c = np.ones(n, dtype=np.int64)
    outcomes: set[int] = set()
    for k in range(1, 2400):
        t = 0.05 * k
        v = speed * (1.0 + 0.3 * np.sin(t / 9.0))
        x = x + v * 0.05
        wsp = (k % 700) < 3 * (1 + np.arange(n))
        # Runs 0 and 1 have an accelerometer (bridged slides), run 2 has none (untrusted).
        acc = np.where(np.arange(n) < 2, speed * 0.3 * np.cos(t / 9.0) / 9.0 + 0.01, np.nan)
        unit.log(
            clock_time_s=np.full(n, t),
            odometer_m=scale * x,
            speed_mps=scale * v,
            wsp_active=wsp,
            accel_mps2=acc,
        )
        for r, (st, ist, lg) in enumerate(runs):
            unit_log_run(st, ist, lg, t, scale[r] * x[r], scale[r] * v[r], bool(wsp[r]), float(acc[r]))
        # A telegram 0.3 s after each boundary; now and then an unknown circuit or an old time.
        for r in range(n):
            c = int(next_c[r])
            if c < len(circuits) and x[r] >= 200.0 * c + 0.3 * v[r]:
                cid, tg = c + 1, t - 0.3 - 0.01 * r
                if c % 5 == 3:
                    cid = 99
                if c % 7 == 5:
                    tg = t - 10.0
                rep = unit.handle(run=np.array([r]), circuit_id=np.array([cid]), gnss_time_s=np.array([tg]))
                st, ist, lg = runs[r]
                row = unit_handle_run(
                    st,
                    ist,
                    lg,
                    db.ids,
                    db.starts_m,
                    db.sd_m,
                    0.02,
                    True,
                    settings.max_extrapolation_s,
                    sq.gate_sigma2,
                    cid,
                    tg,
                )
                wrapper_row = (
                    rep.outcome[0],
                    rep.circuit_start_m[0],
                    rep.odometer_at_fix_m[0],
                    rep.speed_at_fix_mps[0],
                    rep.corrected_jump_m[0],
                    rep.calibrated_jump_m[0],
                    rep.learned[0],
                    rep.gated[0],
                )
                assert _same(row, wrapper_row)
                outcomes.add(int(row[0]))
                next_c[r] += 1
    assert outcomes == {FixOutcome.ACCEPTED, FixOutcome.UNKNOWN_CIRCUIT, FixOutcome.STALE}
    for r, (st, ist, _) in enumerate(runs):
        assert np.array_equal(st, unit.state[r]) and np.array_equal(ist, unit.istate[r])
        assert unit_calibrated_m(st) == unit.calibrated_m()[r]
        assert unit_corrected_m(st) == unit.corrected_m()[r]
        assert ist[UI_CORRECTIONS] == unit.corrections[r] > 3 and ist[UI_REJECTED] == unit.rejected[r] > 0
        assert st[U_A] == unit.scale_estimate[r] != 1.0


# --------------------------------------------------------------------------
# The ato-corrected driver: what the stop kernel calls


def _approach(n: int) -> dict[str, np.ndarray]:
    """Start positions, speeds, odometer scales and latencies of n runs near the first station."""
    stop = LINE.stations[0].stop_point_m
    return {
        "start_m": stop - np.linspace(180.0, 320.0, n),
        "speed_mps": np.linspace(14.0, 22.0, n),
        "tach_scale": np.linspace(0.985, 1.02, n),
        "latency_s": np.linspace(0.02, 0.4, n),
    }


def _step_inputs(
    k: int, x: np.ndarray, v: np.ndarray, tach_scale: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Braking at 0.6 m/s² to standstill, sliding now and then: (accel, x1, odometer step, tach speed,
    sliding)."""
    a = np.where(v > 0.0, -0.6, 0.0)
    v1 = np.maximum(v + a * DT, 0.0)
    x1 = x + 0.5 * (v + v1) * DT
    sliding = ((k // 50) % 9 == 4) & (v > 1.0)
    odo = (x1 - x) * tach_scale * np.where(sliding, 0.85, 1.0)
    tach_v = v * tach_scale * np.where(sliding, 0.85, 1.0)
    return a, x1, odo, tach_v, sliding


def test_fixes_per_run_core_gives_the_wrapper_corrections() -> None:
    n, seed, first = 5, 3, 40
    ap = _approach(n)
    streams = RunStreams.for_runs(seed, first, n)
    fixes = TrackCircuitFixes.create(
        track=LINE.track,
        vehicle=VEHICLE,
        streams=streams,
        start_m=ap["start_m"],
        speed_mps=ap["speed_mps"],
        tach_scale=ap["tach_scale"],
        dt_s=DT,
    )
    line = FixesLine.create(track=LINE.track, vehicle=VEHICLE, dt_s=DT)
    runs = []
    for r in range(n):
        arrays = fixes_state_arrays(line.n_circuits, line.log_len)
        bk, dk = _keys(seed, first + r)
        belief = fixes_init_run(
            *arrays,
            line.tc_starts_m,
            line.tc_sd_m,
            line.delay_mean_s,
            line.delay_spread_s,
            bk,
            dk,
            ap["start_m"][r],
            ap["speed_mps"][r],
            ap["tach_scale"][r],
            line.fix_var_m2,
            line.learn,
            line.scale_prior_var,
            line.delay_prior_var_s2,
        )
        assert belief == fixes.start_position_m[r] == arrays[0][FX_START]
        assert arrays[1][FXI_NEXT] == fixes.detector.next_index[r] > 0
        runs.append(arrays)
    x, v = ap["start_m"].copy(), ap["speed_mps"].copy()
    corrections = 0
    for k in range(3000):
        a, x1, odo, tach_v, sliding = _step_inputs(k, x, v, ap["tach_scale"])
        rows, cal = fixes.step(
            t0_s=k * DT,
            dt_s=DT,
            x0_m=x,
            v0_mps=v,
            accel_mps2=a,
            x1_m=x1,
            odometer_increment_m=odo,
            tach_speed_mps=tach_v,
            sliding=sliding,
            latency_s=ap["latency_s"],
        )
        wrapper = dict(zip(rows.tolist(), cal.tolist(), strict=True))
        for r, (st, ist, lg, bnd, dly) in enumerate(runs):
            corrected, calibrated = fixes_step_run(
                FixesRun(st, ist, lg, bnd, dly),
                line.data(),
                k * DT,
                DT,
                x[r],
                v[r],
                a[r],
                x1[r],
                odo[r],
                tach_v[r],
                bool(sliding[r]),
                ap["latency_s"][r],
            )
            assert corrected == (r in wrapper)
            if corrected:
                assert calibrated == wrapper[r]
                corrections += 1
            assert calibrated == fixes.unit.calibrated_m()[r]
        x, v = x1, np.maximum(v + a * DT, 0.0)
    assert corrections > n
    for r, (st, ist, lg, bnd, dly) in enumerate(runs):
        assert np.array_equal(st, fixes.unit.state[r]) and np.array_equal(ist, fixes.unit.istate[r])
        assert np.array_equal(lg, fixes.unit.log_ring[r])
        assert np.array_equal(bnd, fixes.detector.boundary_m[r])
        assert np.array_equal(dly, fixes.detector.delay_s[r])


@numba.njit(_nrt=False)  # as the kernel's per-step code: no array reference counting, no allocation
def _one_run_in_compiled_code(
    st: np.ndarray,
    ist: np.ndarray,
    lg: np.ndarray,
    bnd: np.ndarray,
    dly: np.ndarray,
    tc_ids: np.ndarray,
    tc_starts_m: np.ndarray,
    tc_sd_m: np.ndarray,
    db_ids: np.ndarray,
    db_starts_m: np.ndarray,
    db_sd_m: np.ndarray,
    scalars: np.ndarray,
    learn: bool,
    boundary_key: np.uint64,
    delay_key: np.uint64,
    start_m: float,
    speed_mps: float,
    tach_scale: float,
    latency_s: float,
    corrected: np.ndarray,
    calibrated: np.ndarray,
) -> float:
    """How a compiled stop kernel drives one run: init the state it allocated, then step
    (braking at 0.6 m/s² to standstill, sliding now and then)."""
    delay_mean, delay_spread, fix_var, scale_var = scalars[0], scalars[1], scalars[2], scalars[3]
    delay_var, max_extra, gate2, counts = scalars[4], scalars[5], scalars[6], scalars[7]
    belief = fixes_init_run(
        st,
        ist,
        lg,
        bnd,
        dly,
        tc_starts_m,
        tc_sd_m,
        delay_mean,
        delay_spread,
        boundary_key,
        delay_key,
        start_m,
        speed_mps,
        tach_scale,
        fix_var,
        learn,
        scale_var,
        delay_var,
    )
    x, v = start_m, speed_mps
    for k in range(corrected.size):
        a = -0.6 if v > 0.0 else 0.0
        v1 = max(v + a * 0.01, 0.0)
        x1 = x + 0.5 * (v + v1) * 0.01
        sliding = ((k // 50) % 9 == 4) and v > 1.0
        slip = 0.85 if sliding else 1.0
        corrected[k], calibrated[k] = fixes_step_run(
            FixesRun(st, ist, lg, bnd, dly),
            FixesData(tc_ids, db_ids, db_starts_m, db_sd_m, delay_spread, learn, max_extra, gate2, counts),
            k * 0.01,
            0.01,
            x,
            v,
            a,
            x1,
            (x1 - x) * tach_scale * slip,
            v * tach_scale * slip,
            sliding,
            latency_s,
        )
        x, v = x1, max(v + a * 0.01, 0.0)
    return belief


def test_fixes_core_runs_inside_compiled_code_like_the_kernel() -> None:
    n, seed, first = 4, 9, 0
    ap = _approach(n)
    line = FixesLine.create(track=LINE.track, vehicle=VEHICLE, dt_s=DT)
    fixes = TrackCircuitFixes.create(
        track=LINE.track,
        vehicle=VEHICLE,
        streams=RunStreams.for_runs(seed, first, n),
        start_m=ap["start_m"],
        speed_mps=ap["speed_mps"],
        tach_scale=ap["tach_scale"],
        dt_s=DT,
    )
    steps = 2500
    got_corrected = np.zeros((steps, n), dtype=bool)
    got_cal = np.full((steps, n), np.nan)
    x, v = ap["start_m"].copy(), ap["speed_mps"].copy()
    for k in range(steps):
        a, x1, odo, tach_v, sliding = _step_inputs(k, x, v, ap["tach_scale"])
        rows, cal = fixes.step(
            t0_s=k * 0.01,
            dt_s=0.01,
            x0_m=x,
            v0_mps=v,
            accel_mps2=a,
            x1_m=x1,
            odometer_increment_m=odo,
            tach_speed_mps=tach_v,
            sliding=sliding,
            latency_s=ap["latency_s"],
        )
        got_corrected[k, rows] = True
        got_cal[k, rows] = cal
        x, v = x1, np.maximum(v + a * DT, 0.0)
    scalars = np.array(
        [
            line.delay_mean_s,
            line.delay_spread_s,
            line.fix_var_m2,
            line.scale_prior_var,
            line.delay_prior_var_s2,
            line.max_extrapolation_s,
            line.gate_sigma2,
            line.gnss_counts_per_s,
        ]
    )
    for r in range(n):
        bk, dk = _keys(seed, first + r)
        # Any state length >= FX_SIZE / FXI_SIZE will do.
        st, ist, lg, bnd, dly = (
            np.empty(64),
            np.empty(16, dtype=np.int64),
            *fixes_state_arrays(line.n_circuits, line.log_len)[2:],
        )
        corrected = np.zeros(steps, dtype=np.bool_)
        calibrated = np.empty(steps)
        belief = _one_run_in_compiled_code(
            st,
            ist,
            lg,
            bnd,
            dly,
            line.tc_ids,
            line.tc_starts_m,
            line.tc_sd_m,
            line.db_ids,
            line.db_starts_m,
            line.db_sd_m,
            scalars,
            line.learn,
            bk,
            dk,
            ap["start_m"][r],
            ap["speed_mps"][r],
            ap["tach_scale"][r],
            ap["latency_s"][r],
            corrected,
            calibrated,
        )
        assert belief == fixes.start_position_m[r]
        assert np.array_equal(corrected, got_corrected[:, r])
        assert corrected.sum() >= 1
        assert np.array_equal(calibrated[corrected], got_cal[corrected, r])


def test_fixes_init_run_has_no_start_before_the_first_circuit() -> None:
    line = FixesLine.create(track=LINE.track, vehicle=VEHICLE, dt_s=DT)
    arrays = fixes_state_arrays(line.n_circuits, line.log_len)
    bk, dk = _keys(1, 0)
    belief = fixes_init_run(
        *arrays,
        line.tc_starts_m,
        line.tc_sd_m,
        line.delay_mean_s,
        line.delay_spread_s,
        bk,
        dk,
        line.tc_starts_m[0] - 10.0,
        15.0,
        1.0,
        line.fix_var_m2,
        line.learn,
        line.scale_prior_var,
        line.delay_prior_var_s2,
    )
    assert np.isnan(belief) and arrays[1][FXI_NEXT] == 0


def test_settings_squares_are_the_python_squares() -> None:
    # x ** 2 of a Python float (C pow) and x * x differ in the last bit for some x; the
    # cores take the Python squares so that they stay bit-identical to the array code.
    s = Positioning(fix_sd_m=0.3, scale_prior_pct=3.43, delay_prior_s=0.17, gate_sigma=2.9)
    sq = settings_squares(s)
    assert sq.fix_var_m2 == 0.3**2 and sq.scale_prior_var == (3.43 * 1e-2) ** 2
    assert sq.delay_prior_var_s2 == 0.17**2 and sq.gate_sigma2 == 2.9**2
    unit = PositioningUnit(
        circuits=[TrackCircuit(id=1, start_m=0.0, end_m=10.0)],
        settings=s,
        n=1,
        cycle_s=DT,
        start_position_m=np.zeros(1),
    )
    assert unit.cal_var_m2[0] == sq.fix_var_m2 and unit.cov[0, 0, 0] == sq.scale_prior_var


@pytest.mark.parametrize("n", [1, 7])
def test_wrapper_views_follow_the_per_run_state(n: int) -> None:
    ap = {k: v[:n] for k, v in _approach(max(n, 2)).items()}
    fixes = TrackCircuitFixes.create(
        track=LINE.track,
        vehicle=VEHICLE,
        streams=RunStreams.for_runs(5, 0, n),
        start_m=ap["start_m"],
        speed_mps=ap["speed_mps"],
        tach_scale=ap["tach_scale"],
        dt_s=DT,
    )
    assert np.array_equal(fixes.pending_circuit, np.full(n, -1))
    assert np.all(np.isinf(fixes.pending_arrival_s)) and np.all(fixes.odometer_m == 0.0)
    x, v = ap["start_m"].copy(), ap["speed_mps"].copy()
    for k in range(400):
        a, x1, odo, tach_v, sliding = _step_inputs(k, x, v, ap["tach_scale"])
        fixes.step(
            t0_s=k * DT,
            dt_s=DT,
            x0_m=x,
            v0_mps=v,
            accel_mps2=a,
            x1_m=x1,
            odometer_increment_m=odo,
            tach_speed_mps=tach_v,
            sliding=sliding,
            latency_s=ap["latency_s"],
        )
        x, v = x1, np.maximum(v + a * DT, 0.0)
    # The wrapper's attributes are views of the per-run state the compiled loop advanced.
    assert np.all(fixes.odometer_m > 0.0) and np.array_equal(fixes.odometer_m, fixes.unit.state[:, 0])
    assert np.shares_memory(fixes.detector.next_index, fixes.unit.istate)
    assert np.array_equal(fixes.detector.next_index, fixes.unit.istate[:, FXI_NEXT])
    assert np.all(fixes.detector.next_index > 0)
    per_run = [unit_calibrated_m(fixes.unit.state[r]) for r in range(n)]
    assert np.array_equal(fixes.unit.calibrated_m(), per_run)
