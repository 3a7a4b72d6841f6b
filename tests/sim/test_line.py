"""The line with many trains (issue 14): the scheduler, the fixed-block interlocking, the
train's own ATO between stations, and whole runs of the line through the CLI."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from railstop.clock import SimClock
from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import DisturbanceSet, draw_scenario, load_disturbances
from railstop.config.operation import Operation, load_operation
from railstop.config.scenario import station_gradient
from railstop.control.line_ato import (
    SIGNAL_MARGIN_M,
    authority_end_m,
    ceiling_mps,
    demand_mps2,
    handover_m,
    static_profile,
)
from railstop.control.supervision import eb_cause_name
from railstop.errors import InterlockError, SimulationError
from railstop.messages import BROADCAST, CircuitOccupancy, Message, Output, SignalAspects
from railstop.model.build import KernelModel
from railstop.model.records import RES_EB, RES_ERROR
from railstop.model.run import run_stepped
from railstop.sim.campaign import MODEL_VERSION
from railstop.sim.engine import DT_S, MAX_TIME_S, run_batch
from railstop.sim.line import LineSimulation, PositionSettings
from railstop.streams import RunStreams
from railstop.wayside.interlocking import FixedBlockInterlocking
from zygote import run_cli

LINE = default_line()
VEHICLE = default_vehicle()
KMH = 1.0 / 3.6


# ---------------------------------------------------------------- the scheduler


class _Ticker:
    """A unit with a cycle: it wakes every ``period_s`` and says so to ``to``."""

    accepts: tuple[type, ...] = (SignalAspects,)

    def __init__(self, name: str, period_s: float, to: str) -> None:
        self.name = name
        self.period_s = period_s
        self.to = to
        self.next_s = period_s
        self.woken: list[float] = []
        self.heard: list[tuple[float, Message]] = []

    def handle(self, message: Message, now_s: float) -> list[Output]:
        self.heard.append((now_s, message))
        return []

    def next_deadline_s(self) -> float | None:
        return self.next_s

    def on_timer(self, now_s: float) -> list[Output]:
        self.woken.append(now_s)
        self.next_s = now_s + self.period_s
        return [Output(to=self.to, message=SignalAspects(proceed=(True,)))]


def test_deadlines_fire_at_their_own_time_between_plant_steps() -> None:
    a = _Ticker("a", 0.25, "b")
    b = _Ticker("b", 0.4, "a")
    steps: list[float] = []

    def plant(now_s: float, step_s: float) -> list[Output]:
        steps.append(now_s)
        return []

    clock = SimClock([a, b], step_s=0.1)
    clock.run(1.0, plant)
    assert a.woken == pytest.approx([0.25, 0.5, 0.75, 1.0])
    assert b.woken == pytest.approx([0.4, 0.8])
    assert [t for t, _ in b.heard] == pytest.approx(a.woken)  # delivered when sent
    assert steps == pytest.approx([0.1 * k for k in range(1, 11)])


def test_a_broadcast_reaches_the_units_that_accept_its_type() -> None:
    a = _Ticker("a", 10.0, "b")
    inter = FixedBlockInterlocking(LINE, clear_at_start=True)
    clock = SimClock([a, inter], step_s=0.1)
    clock.deliver([Output(to=BROADCAST, message=SignalAspects(proceed=(False,)))])
    assert len(a.heard) == 1  # the interlocking does not take aspects: not delivered to it


def test_a_message_for_no_unit_and_a_loop_are_errors() -> None:
    class _Echo(_Ticker):
        def handle(self, message: Message, now_s: float) -> list[Output]:
            return [Output(to=self.name, message=message)]

    clock = SimClock([_Echo("e", 10.0, "e")], step_s=0.1)
    with pytest.raises(SimulationError, match="not a unit"):
        clock.deliver([Output(to="nobody", message=SignalAspects(proceed=()))])
    with pytest.raises(SimulationError, match="a loop"):
        clock.deliver([Output(to="e", message=SignalAspects(proceed=()))])


# ---------------------------------------------------------------- the interlocking


def _occupy(inter: FixedBlockInterlocking, circuit: int, occupied: bool = True) -> list[Output]:
    return inter.handle(CircuitOccupancy(circuit_id=circuit, occupied=occupied), 0.0)


def test_a_signal_shows_stop_for_its_block_and_the_overlap() -> None:
    inter = FixedBlockInterlocking(LINE, clear_at_start=True)
    assert all(inter.aspects)
    s03 = inter.signal_names.index("S03")  # Riverside approach: circuits 105, 106
    out = _occupy(inter, 106)
    assert len(out) == 1 and isinstance(out[0].message, SignalAspects)
    assert not inter.aspects[s03]
    # The signal before it: its own block (103, 104) is clear, but 105 lies in its 50 m overlap.
    s02 = inter.signal_names.index("S02")
    assert inter.aspects[s02]
    _occupy(inter, 106, False)
    _occupy(inter, 105)
    assert not inter.aspects[s02] and not inter.aspects[s03]
    _occupy(inter, 105, False)
    assert all(inter.aspects)
    assert _occupy(inter, 105, False) == []  # no change, no message


def test_an_unreported_circuit_is_occupied() -> None:
    """DESIGN rule 10: a live interlocking that has not heard of a circuit shows stop over it."""
    inter = FixedBlockInterlocking(LINE)
    assert not any(inter.aspects)
    for c in LINE.track.circuits:
        _occupy(inter, c.id, False)
    assert all(inter.aspects)


def test_the_interlocking_refuses_what_is_not_its_input() -> None:
    inter = FixedBlockInterlocking(LINE, clear_at_start=True)
    with pytest.raises(InterlockError, match="in no block"):
        _occupy(inter, 999)
    with pytest.raises(InterlockError, match="track-circuit reports"):
        inter.handle(SignalAspects(proceed=()), 0.0)
    bare = LINE.model_copy(update={"signalling": None})
    with pytest.raises(InterlockError, match="no \\[signalling\\]"):
        FixedBlockInterlocking(bare)


# ---------------------------------------------------------------- the train's own ATO


def test_the_static_profile_keeps_every_limit_and_brakes_into_it() -> None:
    decel = 0.7
    profile = static_profile(LINE, 5800.0, decel)
    assert profile.max() == pytest.approx(80.0 * KMH)
    curve = LINE.speed_limits[0]
    inside = profile[int(curve.start_m) : int(curve.end_m)]
    assert inside.max() <= curve.limit_kmh * KMH + 1e-9
    for st in LINE.stations:
        entry = st.tasc.entry_speed_kmh * KMH
        k = round(handover_m(st.detector_positions_m()[0], entry))
        assert profile[k] <= entry + 1e-9
    # Never faster than a braking curve at the planning deceleration allows.
    dv2 = profile[:-1] ** 2 - profile[1:] ** 2
    assert dv2.max() <= 2.0 * decel * 1.0 + 1e-9


def test_the_authority_ends_before_the_first_signal_at_stop() -> None:
    signals = [0.0, 400.0, 800.0]
    assert authority_end_m(100.0, signals, (True, True, False)) == 800.0 - SIGNAL_MARGIN_M
    assert authority_end_m(100.0, signals, (False, False, True)) == 400.0 - SIGNAL_MARGIN_M
    assert authority_end_m(900.0, signals, (False, False, False)) == np.inf
    profile = static_profile(LINE, 5800.0, 0.7)
    assert ceiling_mps(profile, 500.0, 10.0, 500.0, 0.7) == 0.0
    assert demand_mps2(10.0, 0.0, 1.0, 1.0) == -1.0  # at most full service
    assert demand_mps2(0.0, 20.0, 0.8, 1.0) == 0.8  # at most what traction gives


# ---------------------------------------------------------------- whole runs


@pytest.fixture(scope="module")
def default_run() -> dict[str, object]:
    sim = LineSimulation(line=LINE, vehicle=VEHICLE, operation=load_operation(None, LINE))
    return sim.run(3600.0).summary()


def test_twelve_trains_stop_at_every_station_within_the_tolerance(default_run: dict[str, object]) -> None:
    """The issue's target: 12 trains, 120 s headway, an hour, the nominal draw: every stop of
    every train within ±0.35 m."""
    s = default_run
    assert s["entered"] == s["exited"] == 12
    assert s["stops"] == s["stops_within_tolerance"] == 48 and s["skipped_stops"] == 0
    assert s["signals_passed_at_danger"] == 0
    assert isinstance(s["stop_error_p99_m"], float) and s["stop_error_p99_m"] <= 0.35
    assert s["emergency_brakes"] == 0 and s["dwell_faults"] == 0
    # The dwell runs the door units: doors open 30 s (40 at Hillcrest) plus the sequence around.
    assert isinstance(s["mean_dwell_s"], float) and 32.5 < s["mean_dwell_s"] < 60.0
    assert isinstance(s["trains_per_hour"], float) and abs(s["trains_per_hour"] - 30.0) < 0.5
    # SPEC §2's occupancy telegrams on the train radio, counted: every frame sent is taken by its
    # train or lost (the default radio flips no bits and makes no copies); one per circuit a
    # train's front entered, tens per train over the line.
    occ = s["occupancy_link"]
    assert isinstance(occ, dict) and occ["frames"] > 12 * 20
    assert occ["frames"] == occ["delivered"] + occ["lost"] and occ["rejected"] == occ["duplicates"] == 0


def test_a_headway_too_short_for_the_blocks_queues_trains_without_collision() -> None:
    """Entries every 45 s on a fixed-block line that holds about 28 trains an hour: trains wait
    at the entry and at red signals, none comes closer than a block's worth, every stop holds."""
    sim = LineSimulation(
        line=LINE,
        vehicle=VEHICLE,
        operation=Operation(trains=10, headway_s=45.0),
        disturbances=load_disturbances("standard"),
    )
    s = sim.run(3600.0).summary()
    assert s["exited"] == 10
    assert isinstance(s["min_separation_m"], float) and s["min_separation_m"] > 50.0
    assert isinstance(s["mean_delay_s"], float) and s["mean_delay_s"] > 60.0  # they queued
    assert isinstance(s["trains_per_hour"], float) and s["trains_per_hour"] < 3600.0 / 45.0
    assert s["stops_within_tolerance"] == s["stops"] == 40


@pytest.mark.parametrize("error_pct", [2.0, -2.0])
def test_trains_drive_from_their_onboard_position(error_pct: float) -> None:
    """SPEC §2 in the loop: every train's odometer 2 % off, corrected at every track circuit
    it enters (detection delay, electrical boundary) with the learned scale; its ATO brakes by
    that position. Every stop is still made (the wayside's detectors take the train where it
    is), the position error is sampled, and the learned scale finds the diameter error (a cold
    start: the trains know nothing of it when they enter)."""
    sim = LineSimulation(
        line=LINE,
        vehicle=VEHICLE,
        operation=Operation(trains=3),
        odometer_error_pct=error_pct,
        calibration="cold",
    )
    s = sim.run(1500.0).summary()
    assert s["stops"] == s["stops_within_tolerance"] == 12 and s["skipped_stops"] == 0
    p99 = s["position_error_p99_m"]
    assert isinstance(p99, float) and 0.0 < p99 < 10.0
    scale = sim.positioning.scale_estimate
    assert np.all(np.abs(scale - (1.0 + error_pct / 100.0)) < 0.005)


def test_slides_between_stations_are_bridged_by_the_accelerometer() -> None:
    """A low-adhesion patch where every train brakes for every station: the wheels slide (the
    WSP holds the braking at the adhesion, the odometer falls short by the creep); the
    positioning bridges each slide with its accelerometer, so the onboard position stays within
    a metre (p99) with a 2 % diameter error. Without the patches the same trains do not slide."""
    op = Operation(trains=2, headway_s=150.0)
    sim = LineSimulation(
        line=LINE, vehicle=VEHICLE, operation=op, odometer_error_pct=2.0, slide_probability=1.0
    )
    s = sim.run(900.0).summary()
    assert s["slide_events"] >= 4 and s["stops"] == s["stops_within_tolerance"] >= 4
    assert isinstance(s["position_error_p99_m"], float) and s["position_error_p99_m"] < 1.0
    # The odometer really fell short: the raw odometer's scale is below the diameter's.
    assert np.all(sim.tacho.odometer_m() < 1.02 * np.array([t.x_m for t in sim.trains]) - 1.0)
    smooth = LineSimulation(line=LINE, vehicle=VEHICLE, operation=op, odometer_error_pct=2.0)
    assert smooth.run(900.0).summary()["slide_events"] == 0


def test_slides_inside_the_station_stops_reach_the_odometer(tmp_path: Path) -> None:
    """Every station stop meets a low-adhesion patch (μ 0.05) and no patch lies between stations:
    the slides come from the stop model's steps alone. They reach the line's odometer (the
    slide events count them) and the positioning's WSP input, whose accelerometer bridges them.
    Each slide lasts the whole patch (some 10 s at μ 0.05), so the bridge's bias tells: the onboard
    position's p99 error with a 2 % diameter error stays under 2 m (1.365 m when last measured), where
    an unbridged slide would leave the wheel 15 % short over the 80 m patch (12 m)."""
    wet = tmp_path / "wet-stops.toml"
    wet.write_text(
        'description = "every stop on a wet patch"\n'
        "low_adhesion_probability = 1.0\n"
        "low_adhesion_mu = { fixed = 0.05 }\n"
        "low_adhesion_length_m = { fixed = 80.0 }\n"
    )
    op = Operation(trains=2, headway_s=150.0)
    sim = LineSimulation(
        line=LINE, vehicle=VEHICLE, operation=op, disturbances=load_disturbances(wet), odometer_error_pct=2.0
    )
    s = sim.run(900.0).summary()
    assert s["stops"] >= 4
    assert s["slide_events"] >= 2  # none between stations: from the stops
    assert isinstance(s["position_error_p99_m"], float) and s["position_error_p99_m"] < 2.0
    dry = LineSimulation(line=LINE, vehicle=VEHICLE, operation=op, odometer_error_pct=2.0)
    assert dry.run(900.0).summary()["slide_events"] == 0


def test_slips_after_departures_push_the_odometer_ahead_and_are_bridged() -> None:
    """A low-adhesion patch past every stopping point: starting from the station the traction
    asks more than the adhesion gives, the wheels slip (the anti-slip control holds the traction
    at the adhesion) and turn ahead of the train, so the odometer over-reads with an exact wheel;
    the positioning bridges each slip with its accelerometer. A slip from standstill lasts long
    (some 20 s over an 80 m patch at the adhesion's 0.3 m/s²), so the bridge's bias tells
    (0.02 m/s² sd x 20² s² / 2 = 4 m): it keeps the onboard position within 2 m (p99), half of
    what the odometer alone leaves."""
    op = Operation(trains=1)

    def run(accelerometer: bool) -> tuple[LineSimulation, dict[str, object]]:
        sim = LineSimulation(
            line=LINE,
            vehicle=VEHICLE,
            operation=op,
            odometer_error_pct=0.0,
            position=PositionSettings(slides=0, slips=len(LINE.stations), accelerometer=accelerometer),
        )
        return sim, sim.run(900.0).summary()

    sim, s = run(True)
    train = sim.trains[0]
    assert train.phase == "gone" and s["slide_events"] == 0
    # The summary counts them (one slip per departure onto a patch; none of them a slide).
    assert s["slip_events"] >= 3
    # Each patch is 30-80 m; the train slips over most of the first three (the last station's
    # patch too: it starts from it).
    assert train.slip_m > 90.0
    # The wheel turned ahead: the odometer reads more than the train ran (5 % creep at least).
    run_m = train.x_m - op.entry_m
    assert float(sim.tacho.odometer_m()[0]) > run_m + 0.05 * 0.5 * train.slip_m
    bridged, alone = s["position_error_p99_m"], run(False)[1]["position_error_p99_m"]
    assert isinstance(bridged, float) and isinstance(alone, float)
    assert bridged < 2.0 and bridged < 0.5 * alone
    dry = LineSimulation(line=LINE, vehicle=VEHICLE, operation=op, odometer_error_pct=0.0)
    assert dry.run(900.0).summary()["slip_events"] == 0
    assert dry.trains[0].slip_m == 0.0


def test_carried_calibration_beats_a_cold_start() -> None:
    """A train that enters with the scale and delay of its earlier trips is within a metre from
    the start; a cold one (the learner's 5 % prior) is metres off until it has learned."""
    op = Operation(trains=2, headway_s=150.0)
    p99 = {}
    for calibration in ("carried", "cold"):
        sim = LineSimulation(
            line=LINE, vehicle=VEHICLE, operation=op, odometer_error_pct=2.0, calibration=calibration
        )
        p99[calibration] = sim.run(600.0).summary()["position_error_p99_m"]
    assert p99["carried"] < 1.0 < 2.0 * p99["carried"] < p99["cold"]


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"slide_probability": 1.5}, "slide_probability"),
        ({"slide_probability": -0.1}, "slide_probability"),
        ({"calibration": "warm"}, "calibration"),
        ({"position": PositionSettings(slides=len(LINE.stations) + 1)}, "slides: at most 4 on this line"),
        ({"position": PositionSettings(slips=len(LINE.stations) + 1)}, "slips: at most 4 on this line"),
    ],
)
def test_bad_line_settings_are_refused(kwargs: dict[str, object], field: str) -> None:
    with pytest.raises(SimulationError, match=field):
        LineSimulation(line=LINE, vehicle=VEHICLE, operation=Operation(trains=1), **kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"low_mu": 0.0}, "low_mu"),
        ({"slip_probability": 1.5}, "slip_probability"),
        ({"slides": -1}, "slides"),
        ({"patch_length_m": (80.0, 30.0)}, "patch_length_m"),
    ],
)
def test_bad_position_settings_are_refused(kwargs: dict[str, object], field: str) -> None:
    with pytest.raises(SimulationError, match=field):
        PositionSettings(**kwargs)  # type: ignore[arg-type]


def test_a_dwell_fault_holds_the_train_until_the_staff_recover_it() -> None:
    """No braking telegram ever delivered: each stop ends by emergency brake short of the
    stopping point, its dwell in the SPEC §5 fault path (no start enable), so the train stands with
    its doors closed and the trains behind wait at red signals (DESIGN rule 10). After the staff's
    reset (FAULT_HOLD_S) it is driven onto the platform and its second dwell gives start enable."""
    from railstop.sim.line import FAULT_HOLD_S

    sim = LineSimulation(
        line=LINE,
        vehicle=VEHICLE,
        operation=Operation(trains=3, headway_s=120.0),
        disturbances=DisturbanceSet.from_dict(
            {**load_disturbances("outage-after-first").to_dict(), "radio_loss_probability": 1.0},
            name="no-telegram",
            source="test",
        ),
    )
    s = sim.run(1200.0).summary()
    assert s["emergency_brakes"] == s["stops"] == s["dwell_faults"] >= 3
    assert isinstance(s["min_separation_m"], float) and s["min_separation_m"] > 50.0
    first = [d for d in sim.dwells if d.train == 0]
    # At each station: the fault (out of position after the short stop), then start enable.
    assert [d.outcome for d in first[:4]] == ["fault", "start-enable"] * 2
    assert first[0].station == first[1].station == LINE.stations[0].name
    assert first[0].corrections == 2 and first[1].corrections == 0
    # It stood short of its stopping point (held, its emergency brake applied) for the reset's time.
    tr = sim.trains[0]
    longest, since = 0.0, None
    ts, xs = tr.samples_t, tr.samples_x
    for t0, x0, t1, x1 in zip(ts[:-1], xs[:-1], ts[1:], xs[1:], strict=True):
        standing = x1 == x0 and x1 < LINE.stations[0].stop_point_m - 1.0
        since = (t0 if since is None else since) if standing else None
        if since is not None:
            longest = max(longest, t1 - since)
    assert longest >= FAULT_HOLD_S
    assert s["exited"] >= 1


def test_no_train_waits_for_ever_at_a_signal_it_occupies() -> None:
    """20 trains every 60 s on the standard set once ended with a train whose front stood 1.2 m
    past a red signal (its onboard position 1.2 m behind): its own occupancy kept the signal at
    stop, and the line behind it waited for ever. The ATO now stops 15 m before a red signal,
    more than the onboard position's error; every train gets through, none passes a red one."""
    sim = LineSimulation(
        line=LINE,
        vehicle=VEHICLE,
        operation=Operation(trains=20, headway_s=60.0),
        disturbances=load_disturbances("standard"),
    )
    s = sim.run(3600.0).summary()
    assert s["entered"] == s["exited"] == 20
    assert s["signals_passed_at_danger"] == 0 and s["skipped_stops"] == 0
    assert s["stops"] == s["stops_within_tolerance"] == 80


def test_a_faulty_platform_link_never_opens_doors() -> None:
    """A dead platform door link: the first train's dwells end in the SPEC §5 fault path with its
    doors closed (each retry after the staff's reset too) and the line behind it held. A link that
    loses one frame in ten: the exchange rides it out (frames lost, counted) and every train gets
    its start enable."""
    every = LineSimulation(line=LINE, vehicle=VEHICLE, operation=Operation(trains=3), door_link_loss=1.0)
    s = every.run(1200.0).summary()
    # The staff's resets try again every FAULT_HOLD_S: each dwell faults, none opens the doors.
    assert s["stops"] == 1 and s["exited"] == 0
    assert s["dwell_faults"] == len(every.dwells) >= 2
    assert all(d.outcome == "fault" for d in every.dwells)
    assert [t.phase for t in every.trains].count("held") == 1
    assert s["door_link"]["frames"] > 0 and s["door_link"]["lost"] == s["door_link"]["frames"]
    some = LineSimulation(line=LINE, vehicle=VEHICLE, operation=Operation(trains=3), door_link_loss=0.1)
    r = some.run(1500.0).summary()
    assert r["dwell_faults"] == 0 and r["exited"] == 3
    link = r["door_link"]
    assert 0.05 * link["frames"] < link["lost"] < 0.15 * link["frames"]
    with pytest.raises(SimulationError, match="door_link_loss"):
        LineSimulation(line=LINE, vehicle=VEHICLE, operation=Operation(trains=1), door_link_loss=1.5)


def test_the_run_is_a_function_of_the_seed() -> None:
    def summary(seed: int) -> dict[str, object]:
        op = Operation(trains=3, headway_s=120.0)
        sim = LineSimulation(
            line=LINE, vehicle=VEHICLE, operation=op, disturbances=load_disturbances("standard"), seed=seed
        )
        out = sim.run(1200.0).summary()
        for k in ("wall_s", "sim_to_wall"):
            out.pop(k)
        return out

    assert summary(5) == summary(5)
    assert summary(5) != summary(6)


def test_line_run_through_the_cli(tmp_path: Path) -> None:
    png = tmp_path / "line.png"
    p = run_cli("line", "run", "--trains", "3", "--duration-s", "900", "--json", "--plot", str(png))
    assert p.returncode == 0, p.stderr
    s = json.loads(p.stdout)
    for key in (
        "trains",
        "stops",
        "stop_error_p99_m",
        "trains_per_hour",
        "mean_delay_s",
        "emergency_brakes",
        "position_error_p99_m",
    ):
        assert key in s
    assert s["trains"] == 3 and s["stops"] == 12
    assert png.stat().st_size > 10_000


def test_line_run_refuses_bad_input_in_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "op.toml"
    bad.write_text('controller = "magic"\n', encoding="utf-8")
    p = run_cli("line", "run", "--operation", str(bad))
    assert p.returncode == 2
    lines = (p.stdout + p.stderr).strip().splitlines()
    assert len(lines) == 1 and f"{bad}: controller:" in lines[0] and "Traceback" not in p.stderr


@pytest.mark.parametrize("command", ["run", "campaign"])
def test_a_line_without_signalling_is_refused_naming_its_file(tmp_path: Path, command: str) -> None:
    """A line file with stations but no [signalling] passes ``check`` (a station stop needs no
    blocks) but cannot carry a line's trains: ``line run`` and ``line campaign`` refuse it in one
    line naming the file and the table (before, the simulation's refusal named no file)."""
    text = (Path(__file__).parents[2] / "src/railstop/data/line.toml").read_text(encoding="utf-8")
    no_blocks = tmp_path / "line.toml"
    no_blocks.write_text(text[: text.index("[signalling]")] + text[text.index("[cbtc]") :], encoding="utf-8")
    assert run_cli("check", "--line", str(no_blocks)).returncode == 0
    extra = ["--out", str(tmp_path / "c")] if command == "campaign" else []
    p = run_cli("line", command, "--line", str(no_blocks), *extra)
    assert p.returncode == 2
    lines = (p.stdout + p.stderr).strip().splitlines()
    assert len(lines) == 1 and f"{no_blocks}: signalling: the line has no [signalling]" in lines[0], lines
    assert not (tmp_path / "c").exists()


# ---------------------------------------------------------------- line campaigns


def _campaign(tmp: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return run_cli("line", "campaign", "--trains", "2", "--duration-s", "700", "--out", str(tmp), *args)


def test_a_line_campaign_pools_its_runs_and_resumes(tmp_path: Path) -> None:
    out = tmp_path / "camp"
    p = _campaign(out, "--runs", "3", "--workers", "2", "--json")
    assert p.returncode == 0, p.stderr
    s = json.loads(p.stdout)
    assert s["runs"] == 3 and set(s["stations"]) == {st.name for st in LINE.stations}
    assert sum(st["stops"] for st in s["stations"].values()) == 3 * 2 * 4
    rows = [json.loads(line) for line in (out / "runs.jsonl").read_text(encoding="utf-8").splitlines()]
    assert sorted(r["run"] for r in rows) == [0, 1, 2]
    # Run r is the line run of seed S + r, reproduced alone.
    alone = run_cli(
        "line", "run", "--trains", "2", "--duration-s", "700", "--seed", "3", "--json",
        "--disturbances", "standard",
    )  # fmt: skip
    row2 = next(r for r in rows if r["run"] == 2)["summary"]
    again = json.loads(alone.stdout)
    for key in ("stops", "stop_error_p99_m", "trains_per_hour", "position_error_p99_m"):
        assert again[key] == row2[key]
    # Killed mid-write: the cut last line runs again, the others are kept.
    text = (out / "runs.jsonl").read_text(encoding="utf-8").splitlines()
    (out / "runs.jsonl").write_text("\n".join(text[:2]) + "\n" + text[2][:40], encoding="utf-8")
    r = _campaign(out, "--runs", "3", "--resume", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["runs"] == 3
    lines = (out / "runs.jsonl").read_text(encoding="utf-8").splitlines()
    assert len(lines) == 3  # the cut line dropped, its run written again
    assert [json.loads(line) for line in lines[:2]] == rows[:2]
    rerun = json.loads(lines[2])
    assert rerun["stops"] == rows[2]["stops"] and rerun["dwells"] == rows[2]["dwells"]


def test_a_line_campaign_refuses_to_mix_settings(tmp_path: Path) -> None:
    out = tmp_path / "camp"
    assert _campaign(out, "--runs", "1").returncode == 0
    p = _campaign(out, "--runs", "1")
    assert p.returncode == 2 and "already there" in p.stderr + p.stdout
    q = _campaign(out, "--runs", "2", "--resume")
    assert q.returncode == 2 and "other settings" in q.stderr + q.stdout
    # Runs of another stop model (the line steps it in every stop) are not mixed in either.
    spec_file = out / "campaign.json"
    ident = json.loads(spec_file.read_text(encoding="utf-8"))
    assert ident["model_version"] == MODEL_VERSION
    spec_file.write_text(json.dumps({**ident, "model_version": MODEL_VERSION - 1}), encoding="utf-8")
    r = _campaign(out, "--runs", "1", "--resume")
    assert r.returncode == 2 and "other settings" in r.stderr + r.stdout


def test_a_line_campaign_runs_on_a_dask_cluster_with_the_same_rows(tmp_path: Path) -> None:
    """--scheduler: the runs go to a real Dask scheduler over loopback TCP; the rows are the same
    as run here, whoever computed them."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=1,
        threads_per_worker=2,
        processes=False,
        protocol="tcp://",
        host="127.0.0.1",
        dashboard_address=":0",
    ) as cluster:
        dask = _campaign(tmp_path / "dask", "--runs", "2", "--scheduler", cluster.scheduler_address, "--json")
    assert dask.returncode == 0, dask.stderr
    here = _campaign(tmp_path / "here", "--runs", "2", "--json")
    assert here.returncode == 0, here.stderr

    def rows(folder: str) -> list[dict[str, object]]:
        text = (tmp_path / folder / "runs.jsonl").read_text(encoding="utf-8")
        out = sorted((json.loads(line) for line in text.splitlines()), key=lambda r: int(r["run"]))
        for row in out:  # the wall-clock figures are the machine's, not the run's
            row["summary"].pop("wall_s")
            row["summary"].pop("sim_to_wall")
        return out

    assert rows("dask") == rows("here")
    assert json.loads(dask.stdout)["stations"] == json.loads(here.stdout)["stations"]


def test_a_line_campaign_with_no_scheduler_there_fails_cleanly(tmp_path: Path) -> None:
    p = _campaign(tmp_path / "c", "--runs", "1", "--scheduler", "tcp://127.0.0.1:9")
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and "127.0.0.1:9" in p.stderr


def _stop_draw(sim: LineSimulation, dist: DisturbanceSet, rec: Any, streams: RunStreams) -> Any:
    """The draw of train 0's stop ``rec`` made again from its streams, as a campaign draws it: the
    train's speed at the hand-over, the station's gradients, and the train's own wheel for its
    whole trip (the line's tachometer), not the stop's draw."""
    st = LINE.station(rec.station)
    scenario, _ = draw_scenario(dist, st, VEHICLE, streams)
    return scenario.with_values(
        entry_speed_mps=np.array([rec.entry_speed_mps]),
        gradient=station_gradient(st, 1),
        wheel_diameter_m=sim.tacho.actual_diameter_m[:1].copy(),
        odometer_diameter_error=sim.odometer_error[:1].copy(),
    )


def test_a_stop_on_the_line_is_the_campaigns_stop_of_its_draw() -> None:
    """DESIGN rule 1, parity (issue 35 item 8): the line steps the stop model on its own 0.1 s
    clock from a hand-over between two of its ticks; each of its stops (error, emergency brake,
    whether it stood) is the campaign engine's run of the same draw, bit for bit (to the record's
    rounding)."""
    dist = load_disturbances("standard")
    op = Operation(trains=1, headway_s=120.0)
    sim = LineSimulation(line=LINE, vehicle=VEHICLE, operation=op, disturbances=dist, seed=11)
    result = sim.run(900.0)
    assert len(result.stops) == len(LINE.stations)
    for rec in result.stops:
        st = LINE.station(rec.station)
        streams = RunStreams.for_runs(11, rec.run, 1)
        scenario = _stop_draw(sim, dist, rec, streams)
        batch = run_batch(
            station=st, vehicle=VEHICLE, scenario=scenario, controller="tasc-pwm", streams=streams,
            track=LINE.track,
        )  # fmt: skip
        assert rec.error_m == round(float(batch.stop_error_m[0]), 4), rec
        assert rec.emergency_brake == eb_cause_name(int(batch.emergency_brake[0]))
        assert rec.within_tolerance == (bool(batch.stopped[0]) and abs(rec.error_m) <= st.psd_tolerance_m)


def test_a_trains_stops_count_with_its_own_wheel_for_the_whole_trip() -> None:
    """One wheel per train (issue 35 item 4, line model 7): the odometer of each of a train's
    station stops is the line's tachometer of that train (its diameter error), not one drawn for
    the stop. Two trains of different wheels: each stop's draw carries its own train's."""
    dist = load_disturbances("standard")
    sim = LineSimulation(
        line=LINE, vehicle=VEHICLE, operation=Operation(trains=2, headway_s=120.0), disturbances=dist, seed=11
    )
    assert sim.odometer_error[0] != sim.odometer_error[1]  # the set draws each train's wheel
    seen: dict[int, set[float]] = {0: set(), 1: set()}
    original = sim._stop

    def stop_and_look(train: Any, st: Any, t0_s: float) -> None:
        original(train, st, t0_s)
        seen[train.index].add(float(train.stop.records.tach_scale))

    sim._stop = stop_and_look  # type: ignore[method-assign]
    sim.run(900.0)
    for i in (0, 1):
        assert seen[i] == {float(sim.tacho.scale[i])}, (i, seen[i])


def test_an_ato_corrected_stop_is_positioned_by_the_lines_own_chain() -> None:
    """SPEC §2, one position chain per train (issue 35 item 4): an ``ato-corrected`` train's
    station stop runs no chain of its own. Its ATO takes the line positioning unit's calibrated
    position when the stop takes the train and after each fix that unit accepts during the stop;
    the stop is then the stop model driven by exactly those fixes (``run_stepped`` given them
    alone gives the line's result, bit for bit)."""
    dist = load_disturbances("standard")
    op = Operation(trains=1, headway_s=120.0, controller="ato-corrected")
    sim = LineSimulation(
        line=LINE, vehicle=VEHICLE, operation=op, disturbances=dist, seed=11,
        position=PositionSettings(record=True),
    )  # fmt: skip
    result = sim.run(900.0)
    assert len(result.stops) == len(LINE.stations) == len(sim.stop_fixes)
    train = sim.trains[0]
    trace = np.array(train.trace)  # (t, true, speed, raw, corrected, calibrated) every tick
    for rec, (index, run, t0, fixes) in zip(result.stops, sim.stop_fixes, strict=True):
        assert (index, run) == (0, rec.run)
        # The first fix when the stop takes the train, one more per fix the line's unit accepts.
        accepted = [f for f in sim.fixes if f.outcome == "accepted" and t0 < f.t_s <= rec.arrive_s]
        assert fixes[0][0] == 0
        assert len(fixes) == 1 + len(accepted)
        # Each is the line unit's calibrated position at the tick it was given.
        for steps, position in fixes:
            tick = np.flatnonzero(trace[:, 0] >= t0 + steps * DT_S - 1e-9)[0]
            assert position == trace[tick, 5], (steps, position, trace[tick])
        # The stop model driven by those fixes alone is the line's stop.
        st = LINE.station(rec.station)
        scenario = _stop_draw(sim, dist, rec, RunStreams.for_runs(11, run, 1))
        model = KernelModel.create(
            station=st, vehicle=VEHICLE, controller="ato-corrected", form=None, dt_s=DT_S,
            max_time_s=MAX_TIME_S, track=LINE.track,
        ).with_driver_fixes()  # fmt: skip
        res, _, _ = run_stepped(model, scenario, seed=11, run=run, fixes=fixes)
        assert rec.error_m == round(float(res[0, RES_ERROR]), 4), rec
        assert rec.emergency_brake == eb_cause_name(int(res[0, RES_EB]))


def test_a_line_campaign_sums_the_regulations_holds_only_where_it_regulated() -> None:
    from railstop.sim.line_campaign import _cbtc_totals

    def row(**cbtc: float) -> dict[str, Any]:
        return {"summary": {"cbtc": {"lost_trains": 0, "mean_delay_other_trains_s": 1.0, **cbtc}}}

    plain = _cbtc_totals([row(), row()])
    assert plain is not None and "regulation_holds" not in plain
    regulated = _cbtc_totals(
        [row(regulation_holds=3, regulation_hold_s=40.5), row(regulation_holds=2, regulation_hold_s=9.5)]
    )
    assert regulated is not None
    assert regulated["regulation_holds"] == 5 and regulated["regulation_hold_s"] == 50.0
