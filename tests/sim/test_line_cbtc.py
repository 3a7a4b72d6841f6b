"""The line under SPEC §4 CBTC: moving block through the zone controller and the radio, lost
trains and their protection zones, re-detection, the conventional baseline, faults as data."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from railstop.clock import SimClock
from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import load_disturbances
from railstop.config.faults import RandomOutages
from railstop.config.operation import Operation
from railstop.control.line_ato import HOLD_BACK_M, handover_m
from railstop.errors import SimulationError
from railstop.link.cbtc_radio import TRAIN_BASE, ZC_ADDRESS, CbtcEndpoint, CbtcRadio
from railstop.link.channel import media_preset
from railstop.messages import MovementCommand, OnboardPosition, Output, PositionReport
from railstop.nodes.train import make_onboard_cbtc
from railstop.nodes.zone import make_zone_controller
from railstop.onboard.restricted_mode import (
    RESTRICTED_AFTER_S,
    RESTRICTED_M,
    RESTRICTED_MPS,
    SIGHT_M,
    RestrictedMode,
)
from railstop.sim.line import LineSimulation
from railstop.wayside.zone_controller import ZoneMode
from zygote import run_cli

LINE = default_line()
VEHICLE = default_vehicle()


def run(
    signalling: str, trains: int = 4, duration_s: float = 1300.0, **kw: object
) -> tuple[LineSimulation, dict]:  # type: ignore[type-arg]
    sim = LineSimulation(
        line=LINE,
        vehicle=VEHICLE,
        operation=Operation(trains=trains, headway_s=120.0),
        signalling=signalling,
        **kw,  # type: ignore[arg-type]
    )
    return sim, sim.run(duration_s).summary()


def test_cbtc_runs_the_trains_through_with_nothing_unsafe_counted() -> None:
    sim, s = run("cbtc")
    assert s["signalling"] == "cbtc" and s["exited"] == 4 and s["stops"] == s["stops_within_tolerance"] == 16
    c = s["cbtc"]
    assert c["reports"] > 1000 and c["commands"] > 1000
    assert c["authority_overlaps"] == 0 and c["collisions"] == 0 and c["lost_trains"] == 0
    assert s["signals_passed_at_danger"] == 0 and s["skipped_stops"] == 0
    # Every train left the zone controller's care at the line's end.
    assert sim.cbtc is not None and sim.cbtc.zc.trains == {}


def test_a_radio_outage_makes_a_lost_train_whose_zone_is_released_when_it_reports_inside() -> None:
    """SPEC §4: 2 missed reports -> lost, zone; 2 missed commands -> the onboard unit brakes; the
    radio back, the train reports inside its zone -> released automatically; the train goes on."""
    sim, s = run("cbtc", outages=[(1, 400.0, 20.0)])
    c = s["cbtc"]
    assert c["lost_trains"] == 1 and c["auto_releases"] == 1 and c["flagged"] == 0
    assert c["onboard_emergency_brakes"] >= 1 and c["authority_overlaps"] == 0 and c["collisions"] == 0
    (z,) = sim.cbtc.zones if sim.cbtc is not None else []
    assert z.train == 1 and 400.0 < z.set_s < 402.0 and 420.0 <= z.released_s < 425.0
    # The zone covers the train where it stopped: from its rear's segment to its authority's end.
    assert z.start_m % 100.0 == 0.0 and z.end_m % 100.0 == 0.0 and z.end_m - z.start_m >= 200.0
    assert s["exited"] == 4
    # The delay split: the lost train's own delay apart from the others' (journey against the
    # quickest of the run); the lost train, braked and held, is the most delayed.
    journeys = [t.exited_s - t.request_s for t in sim.trains]
    delays = [j - min(journeys) for j in journeys]
    assert c["mean_delay_lost_trains_s"] == pytest.approx(delays[1], abs=0.01)
    others = [d for k, d in enumerate(delays) if k != 1]
    assert c["mean_delay_other_trains_s"] == pytest.approx(sum(others) / 3, abs=0.01)
    assert delays[1] > max(others)
    assert s["mean_delay_s"] == pytest.approx(sum(delays) / 4, abs=0.01)


def test_the_conventional_zone_is_whole_blocks_and_never_smaller() -> None:
    zones = {}
    for mode in ("cbtc", "cbtc-conventional"):
        sim, s = run(mode, trains=2, duration_s=700.0, outages=[(1, 400.0, 20.0)])
        assert s["cbtc"]["authority_overlaps"] == 0 and s["cbtc"]["collisions"] == 0
        assert sim.cbtc is not None
        (zones[mode],) = sim.cbtc.zones
    m, c = zones["cbtc"], zones["cbtc-conventional"]
    assert c.start_m <= m.start_m and c.end_m >= m.end_m and (c.end_m - c.start_m) > (m.end_m - m.start_m)
    block_ends = {circ.end_m for circ in LINE.track.circuits}
    assert c.end_m in block_ends


def test_random_outages_are_a_function_of_the_seed() -> None:
    spec = RandomOutages(probability=0.5, min_s=5.0, max_s=10.0)
    a, _ = run("cbtc", trains=6, duration_s=10.0, random_outages=spec)
    b, _ = run("cbtc", trains=6, duration_s=10.0, random_outages=spec)
    assert a.drawn_outages == b.drawn_outages and 0 < len(a.drawn_outages) < 6
    for _, start, duration in a.drawn_outages:
        assert 5.0 <= duration <= 10.0 and start >= 60.0


@pytest.mark.parametrize(
    ("kw", "needle"),
    [
        ({"signalling": "moving"}, "signalling"),
        ({"signalling": "cbtc", "outages": [(1, -5.0, 10.0)]}, "outages[0]"),
        ({"signalling": "cbtc", "outages": [(1, 5.0, 0.0)]}, "outages[0]"),
    ],
)
def test_bad_settings_raise_naming_the_field(kw: dict[str, object], needle: str) -> None:
    with pytest.raises(SimulationError, match=needle.replace("[", r"\[")):
        LineSimulation(line=LINE, vehicle=VEHICLE, operation=Operation(trains=1), **kw)  # type: ignore[arg-type]


def test_cli_line_run_cbtc_with_a_faults_file(tmp_path: Path) -> None:
    faults = tmp_path / "faults.toml"
    faults.write_text("[[radio_outage]]\ntrain = 0\nstart_s = 200.0\nduration_s = 15.0\n", encoding="utf-8")
    p = run_cli(
        "line",
        "run",
        "--trains",
        "2",
        "--duration-s",
        "600",
        "--signalling",
        "cbtc",
        "--faults",
        str(faults),
        "--json",
        cwd=tmp_path,
        timeout=300,
    )
    assert p.returncode == 0, p.stderr
    s = json.loads(p.stdout)
    assert (
        s["signalling"] == "cbtc" and s["cbtc"]["lost_trains"] == 1 and s["cbtc"]["authority_overlaps"] == 0
    )


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[[radio_outage]]\ntrain = 0\nstart_s = 1.0\nduration_s = 0.0\n", "radio_outage[0].duration_s"),
        ("[[radio_outage]]\ntrain = 0\nstart_s = 1.0\nduration_s = 1.0\nwhen = 3\n", "radio_outage[0].when"),
        ("[random_outages]\nprobability = 0.5\nmin_s = 30.0\nmax_s = 5.0\n", "random_outages.max_s"),
    ],
)
def test_cli_bad_faults_file_one_line_exit_2(text: str, needle: str, tmp_path: Path) -> None:
    faults = tmp_path / "faults.toml"
    faults.write_text(text, encoding="utf-8")
    p = run_cli(
        "line",
        "run",
        "--trains",
        "1",
        "--duration-s",
        "10",
        "--signalling",
        "cbtc",
        "--faults",
        str(faults),
        cwd=tmp_path,
        timeout=300,
    )
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 2 and len(lines) == 1 and needle in p.stderr and str(faults) in p.stderr, p.stderr


def test_a_train_found_outside_its_zone_waits_for_the_operators_authenticated_release() -> None:
    """SPEC §4 step 5 in the line's wiring: flagged -> held; the operator's release (category 3
    frame through the gate) after operator_release_s -> tracked again."""
    from railstop.link.channel import media_preset
    from railstop.messages import ManualRelease, PositionReport
    from railstop.sim.line_cbtc import CbtcSignalling
    from railstop.wayside.zone_controller import TrainStatus, ZoneMode

    sig = CbtcSignalling(
        line=LINE,
        vehicle=VEHICLE,
        mode=ZoneMode.MINIMAL,
        trains=2,
        radio_params=media_preset("cbtc-radio"),
        seed=1,
    )
    zc = sig.zc
    zc.handle(
        PositionReport(
            train_id=0, position_m=2000.0, speed_mps=0.0, direction="R", time_s=0.0, uncertainty_m=8.0
        ),
        0.0,
    )
    zc.on_timer(0.2)
    zc.on_timer(1.5)  # two reports missed: lost
    assert zc.trains[0].status == TrainStatus.LOST
    # It reports again behind its zone (the zone runs ahead to its authority's end): it moved while lost.
    zc.handle(
        PositionReport(
            train_id=0, position_m=1500.0, speed_mps=0.0, direction="R", time_s=2.0, uncertainty_m=8.0
        ),
        2.0,
    )
    assert zc.trains[0].status == TrainStatus.FLAGGED
    wait = LINE.cbtc.operator_release_s
    assert sig.operator(10.0) == [] and sig.operator(10.0 + wait - 1.0) == []
    (out,) = sig.operator(10.0 + wait)
    assert out.to == "zc" and out.message == ManualRelease(train_id=0) and sig.gate.accepted == 1
    zc.handle(out.message, 10.0 + wait)
    assert zc.trains[0].status == TrainStatus.TRACKED and zc.trains[0].zone is None


def test_a_zone_controller_restart_loses_every_train_and_redetects_them() -> None:
    """[interpretation] of SPEC §4 for a restart: every train the controller knew is lost at once
    (zones from its kept last reports) and re-detected by its next report."""
    sim, s = run("cbtc", trains=4, duration_s=900.0, zc_restarts=[500.0])
    c = s["cbtc"]
    on_line = 4  # at 500 s every train has entered (one every 120 s) and none has left yet
    assert c["restarts"] == 1 and c["lost_trains"] == on_line == c["auto_releases"]
    assert c["flagged"] == 0 and c["authority_overlaps"] == 0 and c["collisions"] == 0
    assert sim.cbtc is not None
    assert all(500.0 <= z.set_s < 500.2 and z.released_s < 502.0 for z in sim.cbtc.zones)


def test_faults_file_with_a_restart(tmp_path: Path) -> None:
    from railstop.config.faults import load_faults

    f = tmp_path / "f.toml"
    f.write_text("[[zc_restart]]\nat_s = 900.0\n[[zc_restart]]\nat_s = 100.0\n", encoding="utf-8")
    assert load_faults(f).restarts() == [100.0, 900.0]
    with pytest.raises(SimulationError, match=r"zc_restarts\[0\]"):
        LineSimulation(line=LINE, vehicle=VEHICLE, operation=Operation(trains=1), zc_restarts=[float("nan")])


def test_radio_bursts_from_the_faults_data_make_lost_trains_and_nothing_unsafe() -> None:
    """Gilbert-Elliott bursts on every train's radio: reports lost in runs, trains lost and
    re-detected, never an authority overlap or a collision."""
    bursts = {"burst_enter_probability": 0.003, "burst_exit_probability": 0.3, "burst_loss_probability": 1.0}
    _, s = run("cbtc", trains=3, duration_s=1200.0, radio_changes=bursts)
    c = s["cbtc"]
    assert c["radio_lost"] > 50 and c["lost_trains"] > 0 and c["auto_releases"] > 0
    assert c["authority_overlaps"] == 0 and c["collisions"] == 0 and s["exited"] >= 1
    with pytest.raises(Exception, match="burst_exit_probability"):
        run("cbtc", trains=1, duration_s=1.0, radio_changes={"burst_exit_probability": 2.0})


def test_a_radio_outage_in_a_station_stop_brakes_the_stop_by_the_cbtc_unit() -> None:
    """The line steps the station stop on its clock, so the onboard CBTC unit can act in it (SPEC
    §4: missed commands -> emergency brake): an outage beginning during the first train's first
    stop brakes that stop; its record names the CBTC unit as the cause and the stop ends short."""
    sim0, _ = run("cbtc", trains=1, duration_s=400.0)
    stop0 = sim0.stops[0]
    assert stop0.emergency_brake is None
    # The radio goes 12 s before the stand: the stop is well under way (below the zone's entry
    # speed, TASC braking), and two commands missed come long before the stand.
    sim, s = run("cbtc", trains=1, duration_s=400.0, outages=[(0, stop0.arrive_s - 12.0, 30.0)])
    stop = sim.stops[0]
    assert stop.station == stop0.station
    assert stop.emergency_brake == "cbtc"
    assert stop.error_m < stop0.error_m - 1.0 and not stop.within_tolerance
    assert s["cbtc"]["onboard_emergency_brakes"] >= 1 and s["cbtc"]["collisions"] == 0


def test_a_train_past_its_first_detector_when_the_platform_clears_is_stopped_not_run_through() -> None:
    """A zone set ahead (train 1's radio lost) shortens train 2's authority while it runs at speed
    towards Riverside: it cannot stand before the station's first detector, so the TASC hand-over
    is missed. When the zone is released the platform is clear, and the train, inside the zone,
    must still stop there: its own ATO stops it at the stopping point and it dwells (it ran through
    the platform before, counted as a skipped stop)."""
    sim = LineSimulation(
        line=LINE,
        vehicle=VEHICLE,
        operation=Operation(trains=3, headway_s=120.0),
        disturbances=load_disturbances("standard"),
        seed=8,
        signalling="cbtc-conventional",
        outages=[(1, 274.43, 11.1)],
    )
    result = sim.run(420.0)
    s = result.summary()
    assert s["skipped_stops"] == 0 and s["stops_by_ato"] == 1
    (stop,) = [x for x in result.stops if x.by_ato]
    assert stop.train == 2 and stop.station == LINE.stations[0].name and stop.emergency_brake is None
    # By its onboard position, within a metre and a half of the stopping point; the dwell judged it.
    assert abs(stop.error_m) < 1.5
    assert any(d.train == 2 and d.station == stop.station for d in result.dwells)


class _LiveCarrier:
    """The radio as live operation carries it, without the sockets: the zone controller's and the
    trains' ends built as the live processes build them (their own key, the operation's trains
    only, a start time), each frame taken by the peer's end at once."""

    name = "air"
    accepts = (PositionReport, MovementCommand)

    def __init__(self, trains: int) -> None:
        key = bytes(range(32))
        self.zc = CbtcEndpoint.zone_controller(key, trains=trains, started_s=0.0)
        self.ends = {k: CbtcEndpoint.train(k, key, name=f"radio-{k}", started_s=0.0) for k in range(trains)}

    def handle(self, message: object, now_s: float) -> list[Output]:
        if isinstance(message, PositionReport):
            end = self.ends[message.train_id]
        elif isinstance(message, MovementCommand):
            end = self.zc
        else:
            return []
        end.handle(message, now_s)
        out: list[Output] = []
        for frame, peer in end.outgoing:
            if peer == ZC_ADDRESS:
                out += self.zc.ingest(frame, now_s, to=lambda _k: "zc")
            else:
                k = peer - TRAIN_BASE
                out += self.ends[k].ingest(frame, now_s, to=lambda _k, k=k: f"cbtc-{k}")  # type: ignore[misc]
        end.outgoing.clear()
        return out

    def next_deadline_s(self) -> float | None:
        return None

    def on_timer(self, now_s: float) -> list[Output]:
        return []


def _exchange(radio: object, uplink: str, trains: int = 3) -> list[tuple[float, ...]]:
    """Three trains running at 15 m/s, 700 m apart, for 60 s under one zone controller and their
    onboard units over ``radio``; every 0.1 s each train's authority end, permitted speed and
    emergency brake, and the controller's counts at the end."""
    zc = make_zone_controller(LINE, VEHICLE, ZoneMode.MINIMAL)
    zc.downlink = radio.name  # type: ignore[attr-defined]
    onboard = [make_onboard_cbtc(LINE, VEHICLE, k, uplink=uplink) for k in range(trains)]
    for unit in onboard:
        unit.active = True
    clock = SimClock([zc, radio, *onboard], step_s=0.1)  # type: ignore[list-item]
    seen: list[tuple[float, ...]] = []

    def plant(now_s: float, step_s: float) -> list[Output]:
        for unit in onboard:
            seen.append((now_s, unit.authority_end_m, unit.permitted_mps(), float(unit.emergency_brake)))
        pos = [
            OnboardPosition(position_m=1900.0 - 700.0 * k + 15.0 * now_s, speed_mps=15.0, uncertainty_m=2.0)
            for k in range(trains)
        ]
        return [Output(to=u.name, message=p) for u, p in zip(onboard, pos, strict=True)]

    clock.run(60.0, plant)
    c = zc.counts
    seen.append((c.reports, c.commands, c.lost))
    return seen


def test_the_line_and_live_radios_carry_the_same_exchange() -> None:
    """DESIGN rule 1 parity (a CBTC report/command exchange): the zone controller and the onboard
    units of the line and of live operation (``nodes.zone``, ``nodes.train``), their telegrams
    through the same endpoint (``link.cbtc_radio.CbtcEndpoint``): over the line's simulated radio
    with a medium that loses nothing and takes no time, and with the frames carried as live
    carries them (the live processes' ends, their own key), every train's authority, permitted
    speed and emergency brake are the same at every step, and so are the controller's counts."""
    ideal = media_preset("cbtc-radio").replace(
        cycle_s=0.0, latency_s=0.0, jitter_s=0.0, loss_probability=0.0, bit_error_rate=0.0,
        burst_enter_probability=0.0, bit_rate_bps=1e300,
    )  # fmt: skip
    line = _exchange(CbtcRadio(params=ideal, seed=0), uplink="radio")
    live = _exchange(_LiveCarrier(3), uplink="air")
    assert [tuple(map(repr, row)) for row in live] == [tuple(map(repr, row)) for row in line]  # NaN too
    reports, commands, lost = line[-1]
    assert reports > 3 * 60 / LINE.cbtc.report_period_s - 10 and commands >= reports - 3 and lost == 0
    assert all(math.isfinite(row[1]) for row in line[-100:-1])  # every train holds an authority


def test_the_restricted_mode_rule_step_by_step() -> None:
    """SPEC §4 restricted mode (``onboard.restricted_mode``, the one rule of the line's and the live
    trains): the emergency brake first, a stand of 20 s, on sight at 15 km/h at most, standing while
    the train ahead's rear is within 150 m or the place to stop is reached, at most 400 m; the radio
    back, the driver stops at the service rate and leaves the train to its ATP."""
    rule = RestrictedMode(brake_mps2=1.0)
    state = {"now_s": 0.0, "step_s": 0.1, "position_m": 1000.0, "speed_mps": 0.0}
    step = lambda **kw: rule.step(**{**state, "radio_dead": True, "emergency_brake": True, **kw})  # noqa: E731
    assert rule.step(**state, radio_dead=False, emergency_brake=False) is None  # the ATP drives
    assert step(emergency_brake=False) is None  # the commands not yet missed twice: not braked
    assert step(speed_mps=5.0) is None  # still braking under the emergency brake
    wait = step()  # at a stand: he asks for leave
    assert wait is not None and wait.stand and wait.decel_mps2 == 1.0
    assert step(now_s=RESTRICTED_AFTER_S - 0.1) == wait
    go = step(now_s=RESTRICTED_AFTER_S)
    assert go is not None and go.target_mps == pytest.approx(RESTRICTED_MPS) and go.accel_mps2 > 0.0
    # The train ahead's rear within the sight distance, or the place to stop reached: he stands.
    assert step(now_s=30.0, ahead_m=1000.0 + SIGHT_M).stand  # type: ignore[union-attr]
    assert step(now_s=30.0, stop_m=1000.0).stand  # type: ignore[union-attr]
    near = step(now_s=30.0, ahead_m=1000.0 + SIGHT_M + 5.0)
    assert near is not None and 0.0 < near.target_mps < RESTRICTED_MPS  # braking on his curve
    # 400 m at most (counted from the speed each step).
    moving = RestrictedMode(brake_mps2=1.0)
    moving.step(**{**state, "radio_dead": True, "emergency_brake": True})
    n = 0
    while not (d := moving.step(**{**state, "now_s": 21.0 + n * 0.1, "speed_mps": RESTRICTED_MPS,
                                   "radio_dead": True, "emergency_brake": True})).stand:  # fmt: skip
        n += 1
    assert moving.run_m == pytest.approx(RESTRICTED_M, abs=RESTRICTED_MPS * 0.1) and moving.moves == 1
    # The radio back while moving: he stops at the service rate; at a stand the ATP has it again.
    back = moving.step(**{**state, "speed_mps": 2.0, "radio_dead": False, "emergency_brake": True})
    assert back is not None and back.stand and d.decel_mps2 == back.decel_mps2 == 1.0
    assert moving.step(**state, radio_dead=False, emergency_brake=True) is None
    assert moving.left_m == RESTRICTED_M and moving.leave_at_s is None


def test_a_lost_train_moves_on_sight_and_is_found_outside_its_zone_held_for_the_operator() -> None:
    """Issue 36, SPEC §4 re-detection outside the zone on the line: train 3 stands queued 35 m
    behind train 2 (waiting before Riverside) when its radio dies for 150 s. Its emergency brake,
    20 s, then its driver moves it in restricted mode (``onboard.restricted_mode``): not while
    train 2's rear is within the sight distance, then on sight at 15 km/h at most, 150 m behind it,
    up to where the trains wait for Riverside's platform, out of its protection zone. The radio
    back, its report falls outside the zone: flagged and held (authority 0) until the operator's
    release 180 s later. Train 4, behind, never enters the zone; nothing overlaps or collides."""
    k, start, end = 3, 235.0, 385.0
    sim = LineSimulation(
        line=LINE,
        vehicle=VEHICLE,
        operation=Operation(trains=5, headway_s=60.0),
        signalling="cbtc",
        outages=[(k, start, end - start)],
    )
    result = sim.run(700.0)
    c = result.summary()["cbtc"]
    assert (
        c["lost_trains"] == 1 and c["flagged"] == 1 and c["auto_releases"] == 0 and c["manual_releases"] == 1
    )
    assert c["restricted_moves"] == 1 and c["authority_overlaps"] == 0 and c["collisions"] == 0
    assert sim.cbtc is not None
    (zone,) = sim.cbtc.zones
    release = LINE.cbtc.operator_release_s
    assert zone.train == k and start < zone.set_s < start + 2.0
    # Flagged at its first report after the outage; the operator's release 180 s later.
    assert end + release <= zone.released_s < end + release + 2.0
    length = VEHICLE.length_m
    t, x = (np.array(a) for a in result.samples[k])

    def front(j: int, at: np.ndarray) -> np.ndarray:
        tj, xj = result.samples[j]
        return np.interp(at, tj, xj, left=np.nan, right=np.inf)

    lost = (t >= start) & (t < end)
    tl, xl = t[lost], x[lost]
    speed = np.diff(xl) / np.diff(tl)
    ahead_rear = front(2, tl) - length
    moving = np.nonzero(speed > 0.0)[0] + 1
    assert moving.size > 100 and xl.max() - xl[0] > 100.0, "it moved while lost"
    assert speed.max() <= RESTRICTED_MPS + 1e-9  # never above 15 km/h
    assert xl.max() - xl[0] <= RESTRICTED_M  # at most 400 m
    assert tl[moving[0]] >= start + RESTRICTED_AFTER_S  # after the wait
    # Never closer than the sight distance to the train ahead's rear while it moved: it stood
    # while train 2 waited 35 m ahead.
    assert (ahead_rear[moving] - xl[moving]).min() >= SIGHT_M - 0.5
    assert (ahead_rear[0] - xl[0]) < SIGHT_M
    # It stopped where the trains wait for Riverside's platform, out of its zone.
    riverside = LINE.stations[0]
    hold = handover_m(riverside.detector_positions_m()[0], riverside.tasc.entry_speed_kmh / 3.6) - HOLD_BACK_M
    assert zone.end_m < xl.max() <= hold + 0.5
    # Held while flagged: it did not move from the radio's return to the operator's release.
    held = (t >= end) & (t < zone.released_s)
    assert np.ptp(x[held]) < 0.01
    # The safety property: train 4, behind the lost train, never entered its zone.
    during = np.arange(zone.set_s, zone.released_s, 0.1)
    follower = front(4, during)
    assert np.nanmax(follower) < zone.start_m
    # And no train ever overlapped the lost train.
    for j in range(5):
        if j != k:
            other = front(j, t)
            sep = np.where(other > x, other - length - x, x - length - other)
            assert np.nanmin(sep) > 0.0


def test_a_lost_train_in_restricted_mode_runs_at_most_400_m() -> None:
    """Train 1's radio dead for 200 s between Hillcrest and Museum with the line ahead free: its
    driver runs the 400 m of restricted mode, then stands; back inside its long zone (its authority
    reached far ahead), the zone is released automatically."""
    sim, s = run("cbtc", trains=3, duration_s=700.0, outages=[(1, 400.0, 200.0)])
    c = s["cbtc"]
    assert c["restricted_moves"] == 1 and RESTRICTED_M - 1.0 < c["restricted_m"] <= RESTRICTED_M + 0.5
    assert c["lost_trains"] == c["auto_releases"] == 1 and c["flagged"] == 0 and c["collisions"] == 0
    t, x = np.array(sim.trains[1].samples_t), np.array(sim.trains[1].samples_x)
    lost = (t >= 400.0) & (t < 600.0)
    xl = x[lost]
    stood = np.nonzero(np.diff(xl) == 0.0)[0][0]  # its emergency brake's stand
    assert RESTRICTED_M - 1.0 < xl.max() - xl[stood] <= RESTRICTED_M + 0.5
    assert np.diff(xl)[stood:].max() / 0.1 <= RESTRICTED_MPS + 1e-9
