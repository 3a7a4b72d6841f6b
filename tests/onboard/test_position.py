"""SPEC §2 position correction: the onboard positioning unit, the wayside time-stamping unit, clocks,
the whole-line driver and the ``position-run`` command.

The closed forms checked here:

- with zero delay and perfect clocks the correction is exact: the position at
  the occupancy instant becomes the circuit's start, so afterwards only the
  odometer's scale error (k × distance since the fix) remains;
- an unmodelled delay δ between the entry and the time in the telegram costs
  ``-v · δ`` (the odometer is read δ late);
- a clock offset costs ``v · offset``: a wayside clock ahead by δ reads like a
  delay (-v δ), an onboard clock ahead by δ like a negative one (+v δ);
- the learner's scale converges to D_assumed / D_actual: within **0.1 %**
  (absolute, on a scale of 1.02) after 60 fixes with 1.5 m boundary noise,
  and its delay within 0.1 s of the true 0.3 s (0.02 s on average over runs).
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from railstop.config import default_line, default_vehicle
from railstop.config.media import ChannelParams
from railstop.config.operation import load_operation
from railstop.config.schema import GnssClocks, Line, Positioning, TrackCircuit, TrackCircuitDetection
from railstop.errors import SimulationError
from railstop.link.channel import media_preset
from railstop.nodes.occupancy_chain import ChainSettings, OccupancyChain
from railstop.onboard.positioning import FixOutcome, PositioningUnit
from railstop.sensors.gnss_clock import GnssClock, in_sections
from railstop.sim.line import PositionSettings
from railstop.sim.position_run import PositionRunResult, PositionRunSettings, run_position
from railstop.streams import RunStreams
from railstop.wayside.tc_timestamp import Indication, OccupancyTelegram, TimestampUnit
from zygote import run_cli

DT = 0.05
LINE = default_line()
VEHICLE = default_vehicle()
SETTINGS = Positioning()


def _circuits(starts: list[float]) -> list[TrackCircuit]:
    ends = [*starts[1:], starts[-1] + 200.0]
    return [
        TrackCircuit(id=i + 1, start_m=s, end_m=e) for i, (s, e) in enumerate(zip(starts, ends, strict=True))
    ]


def _constant_speed_unit(
    *, speed: float, scale: float, t_end: float, onboard_offset_s: float = 0.0, accel: float = 0.0
) -> tuple[PositioningUnit, np.ndarray, np.ndarray]:
    """A unit that logged a train from x = 0 at ``speed`` (+ ``accel``) until t_end (n = 1)."""
    unit = PositioningUnit(
        circuits=_circuits([0.0, 300.0, 600.0]),
        settings=Positioning(log_window_s=60.0, learn=False),
        n=1,
        cycle_s=DT,
        start_position_m=np.zeros(1),
    )
    t = np.arange(0.0, t_end + 1e-9, DT)
    x = speed * t + 0.5 * accel * t * t
    for tk, xk in zip(t, x, strict=True):
        unit.log(
            clock_time_s=np.array([tk + onboard_offset_s]),
            odometer_m=np.array([scale * xk]),
            speed_mps=np.array([scale * (speed + accel * tk)]),
        )
    return unit, t, x


# --------------------------------------------------------------------------
# The onboard positioning unit (pure, array-first)


@pytest.mark.parametrize("speed", [5.0, 12.5, 22.0])
def test_correction_exact_with_zero_delay_and_perfect_clocks(speed: float) -> None:
    # SPEC §2 S40 without scale error: after the fix the position is exact.
    t_entry = 300.0 / speed
    unit, _, x = _constant_speed_unit(speed=speed, scale=1.0, t_end=t_entry + 2.0)
    rep = unit.handle(run=np.array([0]), circuit_id=np.array([2]), gnss_time_s=np.array([t_entry]))
    assert rep.outcome[0] == FixOutcome.ACCEPTED
    assert unit.corrected_m()[0] == pytest.approx(x[-1], abs=1e-9)


def test_correction_leaves_only_scale_error_since_the_fix() -> None:
    # With a 2 % scale error the position at the fix is exact, then it drifts by 2 % of the distance.
    speed, t_entry = 20.0, 15.0
    unit, _, x = _constant_speed_unit(speed=speed, scale=1.02, t_end=t_entry + 4.0)
    unit.handle(run=np.array([0]), circuit_id=np.array([2]), gnss_time_s=np.array([t_entry]))
    since = x[-1] - 300.0
    assert unit.corrected_m()[0] - x[-1] == pytest.approx(0.02 * since, abs=1e-9)
    # Raw: 2 % of everything.
    assert unit.odometer_m[0] - x[-1] == pytest.approx(0.02 * x[-1], abs=1e-9)


def test_correction_exact_while_accelerating_up_to_interpolation() -> None:
    # Linear interpolation of the log: error <= a dt² / 8.
    accel = 1.0
    t_entry = float(np.sqrt(2.0 * 300.0 / accel))
    unit, _, x = _constant_speed_unit(speed=0.0, accel=accel, scale=1.0, t_end=t_entry + 1.0)
    unit.handle(run=np.array([0]), circuit_id=np.array([2]), gnss_time_s=np.array([t_entry]))
    assert abs(unit.corrected_m()[0] - x[-1]) <= accel * DT * DT / 8.0 + 1e-9


@pytest.mark.parametrize(("speed", "delay"), [(22.0, 0.3), (13.0, 0.3), (22.0, 0.05), (8.0, 0.6)])
def test_error_equals_speed_times_unmodelled_delay(speed: float, delay: float) -> None:
    t_entry = 300.0 / speed
    unit, _, x = _constant_speed_unit(speed=speed, scale=1.0, t_end=t_entry + 3.0)
    unit.handle(run=np.array([0]), circuit_id=np.array([2]), gnss_time_s=np.array([t_entry + delay]))
    assert unit.corrected_m()[0] - x[-1] == pytest.approx(-speed * delay, abs=1e-9)


@pytest.mark.parametrize("offset", [-0.2, -0.01, 0.05, 0.5])
def test_clock_offset_effect_is_speed_times_offset(offset: float) -> None:
    speed = 20.0
    t_entry = 300.0 / speed
    # Wayside clock ahead by `offset`: the telegram's time is late, like a delay.
    unit, _, x = _constant_speed_unit(speed=speed, scale=1.0, t_end=t_entry + 3.0)
    unit.handle(run=np.array([0]), circuit_id=np.array([2]), gnss_time_s=np.array([t_entry + offset]))
    assert unit.corrected_m()[0] - x[-1] == pytest.approx(-speed * offset, abs=1e-9)
    # Onboard clock ahead by `offset`: its log is read too early, the opposite sign.
    unit, _, x = _constant_speed_unit(speed=speed, scale=1.0, t_end=t_entry + 3.0, onboard_offset_s=offset)
    unit.handle(run=np.array([0]), circuit_id=np.array([2]), gnss_time_s=np.array([t_entry]))
    assert unit.corrected_m()[0] - x[-1] == pytest.approx(speed * offset, abs=1e-9)


def test_unknown_circuit_stale_and_future_telegrams_are_rejected() -> None:
    unit, _, _ = _constant_speed_unit(speed=20.0, scale=1.02, t_end=20.0)
    before = unit.corrected_m().copy()
    # t = -5 is before the log, t = 25 beyond its newest sample (20) + the 1 s extrapolation.
    rep = unit.handle(
        run=np.array([0, 0, 0]), circuit_id=np.array([99, 2, 2]), gnss_time_s=np.array([15.0, -5.0, 25.0])
    )
    assert rep.outcome.tolist() == [FixOutcome.UNKNOWN_CIRCUIT, FixOutcome.STALE, FixOutcome.FUTURE]
    assert not rep.accepted.any()
    assert unit.corrected_m()[0] == before[0]
    assert unit.rejected[0] == 3 and unit.corrections[0] == 0


def test_telegram_a_little_past_the_log_is_extrapolated() -> None:
    speed = 20.0
    unit, _, _ = _constant_speed_unit(speed=speed, scale=1.0, t_end=16.0)
    # A wayside clock 0.2 s ahead of the onboard log's newest sample: extrapolated with the last speed.
    unit.handle(run=np.array([0]), circuit_id=np.array([3]), gnss_time_s=np.array([16.2]))
    assert unit.corrected_m()[0] == pytest.approx(600.0 - speed * 0.2, abs=1e-9)


def test_unit_is_array_first_with_corrections_at_different_times() -> None:
    # Three runs, one call with telegrams of two of them, another later for the third.
    n, speed = 3, 20.0
    unit = PositioningUnit(
        circuits=_circuits([0.0, 300.0, 600.0]),
        settings=Positioning(learn=False),
        n=n,
        cycle_s=DT,
        start_position_m=np.zeros(n),
    )
    x0 = np.array([0.0, 10.0, 20.0])  # true positions at t = 0
    for k in range(int(16.0 / DT) + 1):
        t = k * DT
        x = x0 + speed * t
        unit.log(clock_time_s=np.full(n, t), odometer_m=1.01 * (x - 0.0), speed_mps=np.full(n, speed * 1.01))
        if k == int(15.5 / DT):
            t_entry = (300.0 - x0[:2]) / speed
            unit.handle(run=np.array([1, 0]), circuit_id=np.array([2, 2]), gnss_time_s=t_entry[[1, 0]])
    x_end = x0 + speed * 16.0
    corr = unit.corrected_m()
    for r in (0, 1):
        assert corr[r] - x_end[r] == pytest.approx(0.01 * (x_end[r] - 300.0), abs=1e-9)
    assert unit.corrections.tolist() == [1, 1, 0]
    assert corr[2] == pytest.approx(1.01 * x_end[2], abs=1e-9)


def _learning_run(
    n: int, seed: int, *, nominal_delay_s: float = 0.0, delay_prior_s: float = 1.0
) -> tuple[PositioningUnit, float, float]:
    """n runs over ~11 km of synthetic track: speed 6..22 m/s, circuits every 130..240 m,
    boundary noise 1.5 m, delay 0.3 s, odometer scale 1.02. Returns the unit, scale, delay."""
    rng = np.random.default_rng(seed)
    scale, delay, boundary_sd, latency = 1.02, 0.3, 1.5, 0.05
    starts = np.cumsum(rng.uniform(130.0, 240.0, size=60))
    circuits = _circuits([0.0, *starts.tolist()])
    unit = PositioningUnit(
        circuits=circuits,
        settings=Positioning(delay_prior_s=delay_prior_s),
        n=n,
        cycle_s=DT,
        start_position_m=np.zeros(n),
        boundary_sd_m=[boundary_sd] * len(circuits),
        delay_spread_s=0.0,
        nominal_delay_s=nominal_delay_s,
    )
    t_end = 1300.0
    t = np.arange(0.0, t_end, DT)
    x = np.zeros_like(t)
    v = np.zeros_like(t)
    for k in range(1, t.size):
        v[k - 1] = 14.0 + 8.0 * np.sin(2.0 * np.pi * x[k - 1] / 1700.0)
        x[k] = x[k - 1] + v[k - 1] * DT
    v[-1] = v[-2]
    ids = np.array([c.id for c in circuits[1:]])
    bound = np.array([c.start_m for c in circuits[1:]])[None, :] + boundary_sd * rng.standard_normal(
        (n, ids.size)
    )
    t_occ = np.interp(bound, x, t) + delay
    runs = np.repeat(np.arange(n), ids.size)
    cids = np.tile(ids, n)
    tw = t_occ.ravel()
    order = np.argsort(tw)
    runs, cids, tw = runs[order], cids[order], tw[order]
    j = 0
    for k in range(t.size):
        unit.log(
            clock_time_s=np.full(n, t[k]),
            odometer_m=np.full(n, scale * x[k]),
            speed_mps=np.full(n, scale * v[k]),
        )
        m = j
        while m < tw.size and tw[m] + latency <= t[k]:
            m += 1
        if m > j:
            unit.handle(run=runs[j:m], circuit_id=cids[j:m], gnss_time_s=tw[j:m])
            j = m
    assert j == tw.size  # every telegram was delivered
    return unit, scale, delay


def test_learned_scale_converges_to_the_true_one() -> None:
    # From scratch: no nominal delay, an uninformative prior on it (1 s).
    unit, scale, delay = _learning_run(n=20, seed=7)
    assert unit.corrections.min() == 60
    # The stated tolerance: 0.1 % on the scale for every run. The delay rests on the speed
    # changes between fixes only: within 0.1 s for every run, unbiased to 0.02 s on average.
    assert np.max(np.abs(unit.scale_estimate - scale)) < 1e-3
    assert np.max(np.abs(unit.delay_estimate_s - delay)) < 0.1
    assert abs(np.mean(unit.delay_estimate_s) - delay) < 0.02


def test_learner_corrects_a_wrong_nominal_delay() -> None:
    # The line data says 0.1 s, the devices take 0.3 s: the default prior (0.2 s) lets it learn.
    unit, scale, delay = _learning_run(n=20, seed=8, nominal_delay_s=0.1, delay_prior_s=0.2)
    assert np.max(np.abs(unit.scale_estimate - scale)) < 1e-3
    assert np.max(np.abs(unit.delay_estimate_s - delay)) < 0.1
    assert np.mean(unit.delay_estimate_s) > 0.22


# --------------------------------------------------------------------------
# Clocks and the wayside unit


def _sliding_unit(accel_bias: float | None) -> tuple[PositioningUnit, float]:
    """A train braking at 0.8 m/s² from 20 m/s that slides for 5 s (wheel 20 % short, WSP
    acting), odometer 2 % long; its accelerometer reads the deceleration + ``accel_bias``
    (None: it has none). Returns the unit and the true distance."""
    unit = PositioningUnit(
        circuits=_circuits([0.0, 240.0]),
        settings=SETTINGS,
        n=1,
        cycle_s=DT,
        start_position_m=np.zeros(1),
    )
    unit.carry_calibration(scale=np.array([1.02]), scale_sd=1e-4, delay_s=np.zeros(1), delay_sd_s=0.01)
    x, v, odo = 0.0, 20.0, 0.0
    for k in range(1, 500):
        sliding = 100 <= k < 200
        creep = 0.8 if sliding else 1.0
        v1 = max(v - 0.8 * DT, 0.0)
        dx = 0.5 * (v + v1) * DT
        x, v, odo = x + dx, v1, odo + 1.02 * creep * dx
        unit.log(
            clock_time_s=np.array([k * DT]),
            odometer_m=np.array([odo]),
            speed_mps=np.array([1.02 * creep * v]),
            wsp_active=np.array([sliding]),
            accel_mps2=None if accel_bias is None else np.array([-0.8 + accel_bias]),
        )
    return unit, x


@pytest.mark.parametrize("bias", [0.0, 0.02, -0.05])
def test_a_slide_is_bridged_by_the_accelerometer(bias: float) -> None:
    """Beyond SPEC §2: while the WSP acts the wheel does not count the distance (here 20 %
    short over 5 s, about 13 m of odometer lost); the accelerometer's integral bridges it, off
    by the bias x T²/2 and the interpolation only."""
    unit, x = _sliding_unit(bias)
    lost = x - unit.odometer_m[0] / 1.02
    assert lost > 10.0
    assert abs(unit.calibrated_m()[0] - x) < abs(bias) * 5.0**2 / 2.0 + 0.1


def test_an_unbridged_slide_is_not_trusted() -> None:
    """Without an accelerometer the slide's interval is counted as the wheel saw it and marked
    untrusted: the next fix is taken as it is (gain 1) and nothing is learned from it."""
    unit, x = _sliding_unit(None)
    assert unit.calibrated_m()[0] < x - 10.0  # the wheel's shortfall stays until a fix
    assert unit.wsp_since_fix[0]
    # The front entered circuit 2 (start 240 m) at t = 20 s (20 t - 0.4 t² = 240; delay 0).
    rep = unit.handle(run=np.array([0]), circuit_id=np.array([2]), gnss_time_s=np.array([20.0]))
    assert rep.accepted[0]
    since = (unit.compensated_odometer_m[0] - rep.odometer_at_fix_m[0]) / unit.scale_estimate[0]
    assert abs(unit.calibrated_m()[0] - (240.0 + since)) < 1e-3
    assert abs(unit.calibrated_m()[0] - x) < 0.05
    assert abs(unit.scale_estimate[0] - 1.02) < 1e-7 and not unit.wsp_since_fix[0]


def test_gnss_clock_disciplined_free_running_and_holdover() -> None:
    data = GnssClocks(disciplined_error_s=1e-7, free_run_drift_ppm=2.0, holdover_s=3600.0)
    streams = RunStreams.for_runs(5, 0, 400)
    clock = GnssClock.create(data, streams, clock_index=np.array([0, 1]), disciplined=np.array([True, False]))
    # Disciplined: the small residual; no time source: drift x holdover.
    assert np.allclose(clock.error_s[:, 0], clock.residual_s[:, 0])
    assert np.std(clock.residual_s) == pytest.approx(1e-7, rel=0.15)
    assert np.allclose(clock.error_s[:, 1], clock.drift[:, 1] * 3600.0)
    assert np.std(clock.drift) == pytest.approx(2e-6, rel=0.15)
    # 100 s in a shadow: the first clock drifts from its residual; then GNSS returns.
    e0 = clock.error_s.copy()
    for _ in range(1000):
        clock.advance(0.1, np.array([False, False]))
    assert np.allclose(clock.error_s, e0 + clock.drift * 100.0)
    clock.advance(0.1, np.array([True, True]))
    assert np.allclose(clock.error_s, clock.residual_s)
    assert np.allclose(clock.read(10.0), 10.0 + clock.residual_s)


def test_in_sections() -> None:
    sections = [(100.0, 200.0), (500.0, 600.0)]  # [start, end) each
    x = np.array([50.0, 100.0, 199.9, 200.0, 550.0, 600.0, -np.inf])
    assert in_sections(x, sections).tolist() == [False, True, True, False, True, False, False]
    assert not in_sections(np.array([1.0]), []).any()
    assert not in_sections(x, []).any()


def test_timestamp_unit_telegram_on_occupancy_only() -> None:
    unit = TimestampUnit([101, 102, 103], n=2)
    tel = unit.handle(
        run=np.array([0, 1]),
        circuit_index=np.array([1, 2]),
        indication=Indication.OCCUPIED,
        clock_time_s=[5.0, 6.0],
    )
    assert tel.size == 2
    assert tel.telegram(0) == OccupancyTelegram(circuit_id=102, gnss_time_s=5.0)
    assert tel.telegram(1) == OccupancyTelegram(circuit_id=103, gnss_time_s=6.0)
    # A repeated "occupied" is no new occupancy; after "clear" it is.
    again = unit.handle(
        run=np.array([0]), circuit_index=np.array([1]), indication=Indication.OCCUPIED, clock_time_s=7.0
    )
    assert again.size == 0
    unit.handle(run=np.array([0]), circuit_index=np.array([1]), indication=Indication.CLEAR, clock_time_s=8.0)
    third = unit.handle(
        run=np.array([0]), circuit_index=np.array([1]), indication=Indication.OCCUPIED, clock_time_s=9.0
    )
    assert third.size == 1 and third.gnss_time_s[0] == 9.0
    assert unit.sent.tolist() == [2, 1]
    with pytest.raises(SimulationError, match="no circuit index"):
        unit.handle(
            run=np.array([0]), circuit_index=np.array([3]), indication=Indication.OCCUPIED, clock_time_s=1.0
        )


def _drive_chain(medium: ChannelParams) -> tuple[OccupancyChain, list[tuple[int, int, float, float]]]:
    """Three trains 500 m apart at 15 m/s over 4 km of the default line, their occupancy telegrams
    on ``medium``: the chain and what reached the trains (train, circuit, GNSS time, step end)."""
    chain = OccupancyChain(
        LINE,
        train_streams=RunStreams.for_runs(1, 0, 3),
        wayside_streams=RunStreams.for_runs(1, 99, 1),
        start_position_m=np.array([1000.0, 500.0, 0.0]),
        settings=ChainSettings(medium=medium),
    )
    x = np.array([1000.0, 500.0, 0.0]) + 0.5
    v, dt = np.full(3, 15.0), 0.1
    got: list[tuple[int, int, float, float]] = []
    for k in range(2700):
        x1 = x + v * dt
        chain.advance(t0_s=k * dt, dt_s=dt, x0_m=x, v0_mps=v, accel_mps2=np.zeros(3), x1_m=x1)
        a = chain.arrivals((k + 1) * dt)
        rows = zip(a.run, a.circuit_id, a.gnss_time_s, strict=True)
        got += [(int(r), int(c), float(g), (k + 1) * dt) for r, c, g in rows]
        x = x1
    return chain, got


def test_the_chain_sends_by_the_one_link_model() -> None:
    """SPEC §2 S20-S30 over the train radio (issue 35: one medium model for every link): the
    telegrams go through the codec onto a SimChannel per train; what the medium loses never
    arrives, a duplicate copy gives no second fix, a frame whose bits flipped is refused by the
    CRC, and the wayside's stamps do not depend on the radio."""
    clean = media_preset("cbtc-radio").replace(loss_probability=0.0, jitter_s=0.0)
    ideal, every = _drive_chain(clean)
    assert ideal.counts.frames == len(every) == ideal.counts.delivered > 50
    assert ideal.counts.lost == ideal.counts.rejected == ideal.counts.duplicates == 0
    # One telegram per circuit a train entered, none before the radio's latency after its front
    # entered the circuit (the trains run at 15 m/s from 0.5 m past their starts).
    assert len({(r, c) for r, c, _, _ in every}) == len(every)
    start = {c.id: c.start_m for c in LINE.track_circuits}
    entered = {(r, cid): (start[cid] - (1000.5 - 500.0 * r)) / 15.0 for r, cid, _, _ in every}
    assert all(step_end >= entered[(r, cid)] + clean.latency_s for r, cid, _, step_end in every)
    bad = clean.replace(loss_probability=0.2, duplicate_probability=0.3, bit_error_rate=2e-3)
    chain, got = _drive_chain(bad)
    c = chain.counts
    assert c.frames == ideal.counts.frames
    assert c.lost > 0 and c.duplicates > 0 and c.rejected > 0
    assert c.delivered == len(got) < c.frames
    stamped = {(r, cid): g for r, cid, g, _ in every}
    assert len({(r, cid) for r, cid, _, _ in got}) == len(got)  # each telegram taken once
    assert all(stamped[(r, cid)] == g for r, cid, g, _ in got)  # the same stamps, the wire's resolution


# --------------------------------------------------------------------------
# The whole-line driver


#: The operation with a train that enters knowing exactly where it is.
EXACT_ENTRY = load_operation(None, LINE).model_copy(update={"entry_position_sd_m": 0.0})


def _ideal_line(delay_s: float) -> Line:
    """The default line with a fixed detection delay, sharp boundaries and perfect clocks."""
    track = LINE.track.model_copy(
        update={
            "detection": TrackCircuitDetection(
                delay_mean_s=delay_s,
                delay_spread_s=0.0,
                boundary_sd_jointless_m=0.0,
                boundary_sd_insulated_m=0.0,
            ),
            "clocks": GnssClocks(disciplined_error_s=0.0, free_run_drift_ppm=0.0),
        }
    )
    return LINE.model_copy(update={"track": track})


def _after_fix_errors(res: PositionRunResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(corrected error just after each fix, true distance between occupancy and telegram time, speed)."""
    errs, moved, speeds = [], [], []
    delay = res.detection_delay_mean_s
    for f in res.fixes:
        k = int(np.searchsorted(res.t_s, f.t_s - 1e-9))
        errs.append(res.corrected_m[k, 0] - res.true_m[k, 0])
        x_w = np.interp(f.gnss_time_s, res.t_s, res.true_m[:, 0])
        x_e = np.interp(f.gnss_time_s - delay, res.t_s, res.true_m[:, 0])
        moved.append(x_w - x_e)
        speeds.append(np.interp(f.gnss_time_s - delay, res.t_s, res.speed_mps[:, 0]))
    return np.array(errs), np.array(moved), np.array(speeds)


def test_whole_line_zero_delay_perfect_clocks_is_exact_up_to_pulses() -> None:
    res = run_position(
        _ideal_line(0.0),
        VEHICLE,
        PositionRunSettings(diameter_error_pct=0.0, slides=0, slips=0),
        operation=EXACT_ENTRY,
    )
    s = res.summary()
    # Every circuit entered between the line's entry and its end gives one correction.
    starts = np.array([c.start_m for c in LINE.track_circuits])
    assert s["corrections"] == np.sum(starts > res.start_m[0])
    # One odometer pulse, plus the telegram's 0.1 ms (2 mm at 80 km/h) and the summary's rounding.
    pulse_m = np.pi * VEHICLE.wheel_diameter_m / VEHICLE.positioning.tachometer_pulses_per_rev + 3e-3
    assert s["corrected_max_abs_m"] <= pulse_m + 1e-6
    errs, _, _ = _after_fix_errors(res)
    assert np.max(np.abs(errs)) <= pulse_m + 1e-6


def test_whole_line_error_is_speed_times_unmodelled_delay() -> None:
    delay = 0.3
    res = run_position(
        _ideal_line(delay),
        VEHICLE,
        PositionRunSettings(diameter_error_pct=0.0, slides=0, slips=0, learn=False),
        operation=EXACT_ENTRY,
    )
    errs, moved, speeds = _after_fix_errors(res)
    # One odometer pulse, plus the telegram's 0.1 ms (2 mm at 80 km/h) and the summary's rounding.
    pulse_m = np.pi * VEHICLE.wheel_diameter_m / VEHICLE.positioning.tachometer_pulses_per_rev + 3e-3
    # Exactly the distance run during the delay (up to one pulse) ...
    assert np.allclose(errs, -moved, atol=pulse_m + 1e-6)
    # ... which is v·δ up to the acceleration's a δ²/2 (|a| <= 1 m/s²).
    assert np.allclose(errs, -speeds * delay, atol=pulse_m + 0.5 * 1.0 * delay**2 + 1e-6)
    assert np.min(errs) < -6.0  # at 78 km/h: -6.5 m


@pytest.fixture(scope="module")
def note_run() -> PositionRunResult:
    """The issue's run: 2 % wheel-diameter error, 3 slide and 2 slip patches, default line data."""
    return run_position(LINE, VEHICLE, PositionRunSettings())


def test_note_run_raw_grows_corrected_and_calibrated_stay_bounded(note_run: PositionRunResult) -> None:
    s = note_run.summary()
    grid = note_run.errors_vs_chainage()
    x, raw = grid["chainage_m"], grid["raw"]
    assert s["distance_m"] > 5400.0 and s["slide_patches"] == 3 and s["slip_patches"] == 2
    assert note_run.slide_distance_m[0] > 0.0 and note_run.slip_distance_m[0] > 0.0
    # Raw: about 2 % of the distance (slides take some back, slips add some).
    half = x.size // 2
    assert np.mean(raw[half:]) > 1.5 * np.mean(raw[:half]) > 0.0
    assert s["raw_max_abs_m"] > 90.0
    # Corrected and calibrated: bounded, nowhere near the raw error, and the calibration helps.
    # The document's correction leaves the distance run during the unmodelled delay (6.6 m at
    # 80 km/h), the diameter error over a circuit (2 % of up to 250 m) and a slide's shortfall.
    assert s["corrected_max_abs_m"] < 20.0
    assert s["calibrated_p99_abs_m"] < s["corrected_p99_abs_m"]
    half_err = {k: np.percentile(np.abs(grid[k][half:]), 95) for k in ("corrected", "calibrated")}
    assert half_err["calibrated"] < 0.7 * half_err["corrected"]
    # The learned scale on the line: within 0.15 percentage points of 2 %.
    assert abs(s["learned_scale_error_pct"] - s["true_scale_error_pct"]) < 0.15
    assert 0.2 < s["learned_delay_s"] < 0.45


def test_same_seed_same_run(note_run: PositionRunResult) -> None:
    again = run_position(LINE, VEHICLE, PositionRunSettings())
    assert again.summary() == note_run.summary()
    assert np.array_equal(again.calibrated_m, note_run.calibrated_m)


@pytest.fixture(scope="module")
def same_path_run() -> PositionRunResult:
    """The note's run with every SPEC §2 chain setting fed its path."""
    return run_position(LINE, VEHICLE, PositionRunSettings(same_path=True))


def test_same_path_chains_never_drive_and_share_the_draws(
    note_run: PositionRunResult, same_path_run: PositionRunResult
) -> None:
    res = same_path_run
    # The other chains never touch the train: its path and its own positions are the note run's.
    assert np.array_equal(res.true_m, note_run.true_m)
    assert np.array_equal(res.calibrated_m, note_run.calibrated_m)
    assert res.same_path_names[0] == "GNSS time, repeaters"
    # The chain of the train's own setting, fed the same path, repeats it bit for bit: the same
    # devices, clocks and radio draws, so the rows differ only by their setting.
    assert np.array_equal(res.same_path_corrected_m[0], note_run.corrected_m)
    assert np.array_equal(res.same_path_calibrated_m[0], note_run.calibrated_m)
    rows = res.summary()["same_path"]
    assert [r["setting"] for r in rows] == res.same_path_names
    for key in ("corrected_p99_abs_m", "calibrated_p99_abs_m", "calibrated_max_abs_m"):
        assert rows[0][key] == note_run.summary()[key]


def test_same_path_settings_act_only_where_the_document_says(same_path_run: PositionRunResult) -> None:
    res = same_path_run
    names = res.same_path_names
    x = res.true_m[:, 0]
    tunnel_start = min(a for a, _, repeater in res.tunnels if repeater)  # the Hillcrest tunnel
    before = x < tunnel_start - 300.0  # a fix's telegram arrives after the train passed the boundary
    base = res.same_path_corrected_m[names.index("GNSS time, repeaters")]
    # Without repeaters: the same positions until the first tunnel with a repeater (every clock
    # disciplined there either way), different after it (that tunnel is a shadow now).
    for name in ("no repeaters", "no repeaters, week holdover"):
        other = res.same_path_corrected_m[names.index(name)]
        assert np.array_equal(other[before, 0], base[before, 0])
        assert not np.array_equal(other[~before, 0], base[~before, 0])
    # Without GNSS every clock free-runs from the start: positions differ from the first fix.
    no_gnss = res.same_path_corrected_m[names.index("no GNSS")]
    assert not np.array_equal(no_gnss[before, 0], base[before, 0])
    # A clock set a week ago drifts seven times as far as one set a day ago (SPEC §2 free-running):
    # on the same path its corrected positions are worse.
    rows = {r["setting"]: r for r in res.summary()["same_path"]}
    for day, week in (("no repeaters", "no repeaters, week holdover"), ("no GNSS", "no GNSS, week holdover")):
        assert rows[week]["corrected_p99_abs_m"] > rows[day]["corrected_p99_abs_m"]


def test_same_path_needs_the_recording() -> None:
    with pytest.raises(SimulationError, match="same_path"):
        PositionSettings(same_path=(ChainSettings(),))


def test_no_learning_gives_the_document_method() -> None:
    res = run_position(LINE, VEHICLE, PositionRunSettings(learn=False, slides=0, slips=0))
    assert np.allclose(res.calibrated_m, res.corrected_m)


def test_settings_and_line_checks() -> None:
    with pytest.raises(SimulationError, match="slides"):
        PositionRunSettings(slides=-1)
    with pytest.raises(SimulationError, match="low_mu"):
        PositionRunSettings(low_mu=0.0)
    bare = LINE.model_copy(update={"track": LINE.track.model_copy(update={"circuits": []})})
    with pytest.raises(SimulationError, match=r"track\.circuits"):
        run_position(bare, VEHICLE)
    with pytest.raises(SimulationError, match=r"vehicle\.traction"):
        run_position(LINE, VEHICLE.model_copy(update={"traction": None}))


# --------------------------------------------------------------------------
# The command, end to end through a subprocess


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=cwd)  # forked from a warm zygote (tests/zygote.py)


def test_cli_position_run_json_and_plot(tmp_path: Path) -> None:
    png = tmp_path / "pos.png"
    p = _cli("position-run", "--seed", "1", "--json", "--plot", str(png), cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    for key in (
        "distance_m",
        "raw_max_abs_m",
        "corrected_p99_abs_m",
        "corrected_max_abs_m",
        "calibrated_p99_abs_m",
        "corrections",
    ):
        assert key in data
    assert data["diameter_error_pct"] == 2.0 and data["gnss"] and data["repeaters"]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size > 20_000


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("--slides", "-1"), "--slides: must be at least 0 (got -1)"),
        (("--diameter-error-pct", "30"), "--diameter-error-pct: must be between -20 % and 20 % (got 30)"),
        (("--disturbances", "nonsense"), "no such file"),
    ],
)
def test_cli_position_run_bad_input_one_line_exit_2(
    tmp_path: Path, args: tuple[str, ...], needle: str
) -> None:
    p = _cli("position-run", *args, cwd=tmp_path)
    assert p.returncode == 2
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, p.stderr
    assert needle in p.stderr
    assert "Traceback" not in p.stderr


def test_cli_position_run_bad_line_file_names_field(tmp_path: Path) -> None:
    text = (Path(__file__).parents[2] / "src/railstop/data/line.toml").read_text(encoding="utf-8")
    bad = tmp_path / "line.toml"
    bad.write_text(
        text.replace("{ id = 105, start_m = 870.0,", "{ id = 105, start_m = 875.0,"), encoding="utf-8"
    )
    p = _cli("position-run", "--line", str(bad), cwd=tmp_path)
    assert p.returncode == 2
    assert len([ln for ln in p.stderr.splitlines() if ln.strip()]) == 1, p.stderr
    assert "track.circuits[4].start_m" in p.stderr and "875.0" in p.stderr


def test_cli_position_run_takes_the_operation_of_a_line_of_ones_own(tmp_path: Path) -> None:
    """A line whose stations are not the embedded line's: the embedded operation names other
    stations, so position-run takes the line's own with --operation (as ``line run``)."""
    text = (Path(__file__).parents[2] / "src/railstop/data/line.toml").read_text(encoding="utf-8")
    own = tmp_path / "line.toml"
    own.write_text(
        text.replace('"Hillcrest"', '"Hilltop"').replace('"Museum"', '"Gallery"'), encoding="utf-8"
    )
    refused = _cli("position-run", "--line", str(own), "--json", cwd=tmp_path)
    assert refused.returncode == 2 and "give --operation FILE" in refused.stderr, refused.stderr
    op = tmp_path / "op.toml"
    op.write_text('stations = [{ name = "Hilltop", dwell_s = 40.0 }]\n', encoding="utf-8")
    args = ("--line", str(own), "--operation", str(op), "--slides", "0", "--slips", "0", "--json")
    p = _cli("position-run", *args, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["corrections"] > 0
    # A bad operation file is one line naming the option, the file, the field and the value.
    op.write_text('stations = [{ name = "Hillcrest", dwell_s = 40.0 }]\n', encoding="utf-8")
    bad = _cli("position-run", *args, cwd=tmp_path)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert len([ln for ln in bad.stderr.splitlines() if ln.strip()]) == 1, bad.stderr
    assert f"--operation: {op}: stations[0].name: no such station" in bad.stderr
    assert "'Hillcrest'" in bad.stderr
