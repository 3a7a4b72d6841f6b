"""The CBTC line's analytic minimum headway (``railstop.sim.capacity``) against its data and the line,
and the predictive hand-over that lets a follower start its station stop behind a leaving train.

- the clearing distance is the train's length, the rollback allowance, the safety margin and
  both trains' uncertainty (the zone controller's authority rule); the clearing time is no less
  than that distance at the traction's acceleration limit from a stand allows;
- the dwell term is the line's own nominal dwell (the same door units) and adds one for one;
- the follower's release state lies on its ATO's approach to its waiting point (it can still stop
  there), and the bound is more than a clairvoyant follower's;
- the minimum is a lower bound: trains entering faster than it are served no faster than it at
  the busiest platform.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from railstop.config import default_line, default_vehicle
from railstop.config.operation import StationDwell, load_operation
from railstop.control.line_ato import HOLD_BACK_M, ceiling_mps, handover_m, static_profile
from railstop.errors import SimulationError
from railstop.onboard.cbtc import approach_within_authority
from railstop.quantities import MPS_PER_KMH
from railstop.sim import line as line_module
from railstop.sim.capacity import PlatformHeadway, minimum_headways
from railstop.sim.line import LineSettings, LineSimulation

LINE = default_line()
VEHICLE = default_vehicle()
OPERATION = load_operation(None, LINE)
CBTC = LineSettings(signalling="cbtc")


@pytest.fixture(scope="module")
def headways() -> list[PlatformHeadway]:
    return minimum_headways(LINE, VEHICLE, OPERATION)


@pytest.fixture(scope="module")
def predictive_headways() -> list[PlatformHeadway]:
    return minimum_headways(LINE, VEHICLE, OPERATION, handover="predictive")


def test_terms_follow_the_data(headways: list[PlatformHeadway]) -> None:
    cbtc = LINE.cbtc
    assert [h.station for h in headways] == [s.name for s in LINE.stations]
    for h in headways:
        assert h.clear_m == pytest.approx(
            VEHICLE.length_m + cbtc.rollback_m + cbtc.safety_margin_m + 2.0 * cbtc.position_uncertainty_m
        )
        # From a stand at most the traction's acceleration limit: no quicker than this.
        assert VEHICLE.traction is not None
        assert h.clear_s >= math.sqrt(2.0 * h.clear_m / VEHICLE.traction.max_accel_mps2)
        assert h.clear_s < 2.0 * math.sqrt(2.0 * h.clear_m / VEHICLE.traction.max_accel_mps2)
        assert h.system_s == pytest.approx(cbtc.report_period_s + cbtc.processing_delay_s + 0.05 + 0.1)
        assert h.headway_s == pytest.approx(h.dwell_s + h.clear_s + h.system_s + h.run_in_s + h.approach_s)
        assert h.follow_s == pytest.approx(h.headway_s - h.dwell_s)
        assert h.trains_per_hour == pytest.approx(3600.0 / h.headway_s)
    # A smaller uncertainty clears sooner.
    small = minimum_headways(LINE, VEHICLE, OPERATION, uncertainty_m=1.0)
    assert all(a.clear_s < b.clear_s for a, b in zip(small, headways, strict=True))


def test_the_follower_is_released_where_it_can_still_stop_at_its_waiting_point(
    headways: list[PlatformHeadway],
) -> None:
    """Until its authority reaches the stopping point a follower must be able to stop at its
    waiting point (HOLD_BACK_M before the hand-over): the release state the bound takes is on the
    ATO's approach to it, within its braking curve (the plant a little above it while the brakes
    build up) and short of the waiting point, and the bound is the clairvoyant one (at the
    hand-over at the entry speed when released) plus what that braking costs."""
    plan = line_module.PLANNING_SHARE * VEHICLE.brake.full_service_mps2
    profile = static_profile(LINE, LINE.end_m, plan)
    for h, station in zip(headways, LINE.stations, strict=True):
        first = station.detector_positions_m()[0]
        entry = station.tasc.entry_speed_kmh * MPS_PER_KMH
        wait = handover_m(first, entry) - HOLD_BACK_M
        x = handover_m(first, h.entry_speed_kmh * MPS_PER_KMH) - h.release_m
        v = h.release_kmh * MPS_PER_KMH
        assert x <= wait and v >= 0.0
        # It can still stop at the waiting point braking at full service.
        assert v * v <= 2.0 * VEHICLE.brake.full_service_mps2 * (wait - x)
        assert v <= ceiling_mps(profile, x, v, wait, plan) + 0.5
        # The follower cannot stop at its waiting point and be at the hand-over at the entry
        # speed when released: the bound is the clairvoyant one and more.
        assert h.run_in_s > 0.0 and h.headway_s > h.ideal_headway_s + 5.0
        # Running in from its release it reaches the hand-over at about the zone's entry speed.
        assert h.entry_speed_kmh == pytest.approx(station.tasc.entry_speed_kmh, abs=2.0)


def test_dwell_is_the_lines_nominal_dwell_and_adds_one_for_one(headways: list[PlatformHeadway]) -> None:
    # One train through the line, nominal: each dwell as the line's door units run it.
    op = OPERATION.model_copy(update={"trains": 1})
    sim = LineSimulation(
        line=LINE, vehicle=VEHICLE, operation=op, seed=1, settings=LineSettings(signalling="cbtc")
    )
    sim.run(1800.0, until_gone=True)
    line_dwell = {d.station: d.dwell_s for d in sim.dwells}
    for h in headways:
        assert line_dwell[h.station] == pytest.approx(h.dwell_s, abs=0.02)
    longer = OPERATION.model_copy(
        update={
            "dwell_s": OPERATION.dwell_s + 10.0,
            "stations": [StationDwell(name=s.name, dwell_s=s.dwell_s + 10.0) for s in OPERATION.stations],
        }
    )
    for a, b in zip(minimum_headways(LINE, VEHICLE, longer), headways, strict=True):
        assert a.headway_s - b.headway_s == pytest.approx(10.0, abs=0.02)
        assert a.approach_s == b.approach_s and a.clear_s == b.clear_s


def test_the_minimum_is_a_lower_bound_of_the_simulated_line(headways: list[PlatformHeadway]) -> None:
    least = max(h.headway_s for h in headways)
    op = OPERATION.model_copy(update={"trains": 7, "headway_s": 0.8 * least})
    sim = LineSimulation(
        line=LINE, vehicle=VEHICLE, operation=op, seed=1, settings=LineSettings(signalling="cbtc")
    )
    sim.run(1500.0)
    intervals = []
    for station in LINE.stations:
        arrivals = sorted(s.arrive_s for s in sim.stops if s.station == station.name)
        if len(arrivals) >= 4:
            intervals.append(float(np.median(np.diff(arrivals))))
    assert intervals
    # Entries faster than any platform serves: the busiest is no quicker than its minimum.
    assert max(intervals) >= 0.99 * least


# --------------------------------------------------------------------------
# The predictive hand-over (LineSettings.handover = "predictive", HZ-CBTC-19)


def _approach(authority_m: float, advance_mps: float, speed_mps: float = 16.0) -> bool:
    return approach_within_authority(
        front_m=0.0,
        speed_mps=speed_mps,
        hold_to_m=20.0,
        stop_m=350.0,
        authority_m=authority_m,
        advance_mps=advance_mps,
        params=LINE.cbtc,
        margin_m=10.0,
    )


def test_an_authority_that_stands_short_of_the_stop_never_hands_over() -> None:
    # The train ahead dwells: its authority does not advance, whatever its end now.
    for end in (100.0, 200.0, 300.0, 349.0, 355.0):
        assert not _approach(end, 0.0)
    assert not _approach(float("nan"), 5.0) and not _approach(200.0, float("inf"))
    # Far beyond the stop, standing or not: the approach fits.
    assert _approach(350.0 + 400.0, 0.0)


@given(
    end=st.floats(150.0, 500.0),
    rate=st.floats(0.0, 25.0),
    more=st.floats(0.0, 10.0),
    speed=st.floats(5.0, 20.0),
)
def test_a_faster_or_longer_authority_never_hands_over_later(
    end: float, rate: float, more: float, speed: float
) -> None:
    if _approach(end, rate, speed):
        assert _approach(end + more, rate, speed)
        assert _approach(end, rate + more, speed)


def _predictive_line(headway_s: float) -> tuple[LineSimulation, dict[str, Any]]:
    op = OPERATION.model_copy(update={"trains": 7, "headway_s": headway_s})
    settings = LineSettings(signalling="cbtc", handover="predictive")
    sim = LineSimulation(line=LINE, vehicle=VEHICLE, operation=op, seed=1, settings=settings)
    return sim, sim.run(1500.0).summary()


def test_a_predictive_line_serves_trains_closer_than_the_platform_clear_rule_can(
    headways: list[PlatformHeadway], predictive_headways: list[PlatformHeadway]
) -> None:
    clear_min = max(h.headway_s for h in headways)
    assert max(h.headway_s for h in predictive_headways) < clear_min - 5.0
    sim, s = _predictive_line(100.0)  # below the platform-clear minimum (111.4 s), above the predictive
    c = s["cbtc"]
    assert c["authority_overlaps"] == 0 and c["collisions"] == 0 and c["onboard_emergency_brakes"] == 0
    assert s["stops"] == s["stops_within_tolerance"] == 28 and s["skipped_stops"] == 0
    for station in LINE.stations:
        arrivals = sorted(r.arrive_s for r in sim.stops if r.station == station.name)
        # Every pair of trains after the first ones closer than the platform-clear rule's lower
        # bound: no follower waited for the platform to clear.
        assert float(np.max(np.diff(arrivals)[2:])) < clear_min


def test_a_failed_prediction_is_braked_by_the_onboard_unit(
    predictive_headways: list[PlatformHeadway],
) -> None:
    """HZ-CBTC-19: fed faster than it can serve, the leaving trains are soon queued themselves, an
    authority stops advancing as predicted, and the onboard unit brakes the follower's stop: never
    an overlap or a collision, and every stop outside the tolerance ended by that brake."""
    sim, s = _predictive_line(0.8 * max(h.headway_s for h in predictive_headways))
    c = s["cbtc"]
    assert c["authority_overlaps"] == 0 and c["collisions"] == 0 and s["skipped_stops"] == 0
    missed = [r for r in sim.stops if not r.within_tolerance]
    assert missed and c["onboard_emergency_brakes"] >= len(missed)
    assert all(r.emergency_brake is not None for r in missed)


def test_a_train_held_short_is_not_driven_onto_an_occupied_platform() -> None:
    """HZ-CBTC-20 on the line: 20 trains entering every 96 s under the predictive hand-over (the
    case the capacity benchmark found): failed predictions brake followers' stops short and fault
    their dwells, and the staff's recoveries on sight drive nobody into a train still standing at
    the platform: no collision, a positive least separation. (The run that found the collision,
    line model 4's draws, drove a recovery into the train ahead; with line model 5's draws this
    run's recoveries meet a clear platform, so the rule's firing is shown by the test below.)"""
    op = OPERATION.model_copy(update={"trains": 20, "headway_s": 96.0})
    settings = LineSettings(signalling="cbtc", handover="predictive")
    sim = LineSimulation(line=LINE, vehicle=VEHICLE, operation=op, seed=1, settings=settings)
    s = sim.run(1600.0).summary()
    assert s["dwell_faults"] >= 1 and s["cbtc"]["collisions"] == 0 and s["min_separation_m"] > 0.0


def test_the_recovery_on_sight_waits_while_the_platform_is_occupied(monkeypatch: pytest.MonkeyPatch) -> None:
    """HZ-CBTC-20, the rule alone: a follower held short of Riverside (a dwell fault) while the
    train ahead still stands at the platform is not driven on; it is rechecked every
    ``RECOVERY_RECHECK_S`` and driven onto the stopping point once the train ahead's rear is
    ``RECOVERY_SIGHT_M`` beyond it. With the rule off the move it plans ends inside the train
    ahead."""
    op = OPERATION.model_copy(update={"trains": 2})
    sim = LineSimulation(
        line=LINE,
        vehicle=VEHICLE,
        operation=op,
        seed=1,
        settings=LineSettings(signalling="cbtc", handover="predictive"),
    )
    stop = LINE.stations[0].stop_point_m
    leader, follower = sim.trains
    length = VEHICLE.length_m

    def held_short() -> None:
        leader.phase, leader.x_m = "dwelling", stop  # standing at the platform
        follower.phase, follower.x_m, follower.next_station = "held", stop - 30.0, 1

    held_short()
    sim._recover(follower, 500.0)
    assert follower.phase == "held" and follower.next_station == 1
    assert follower.until_s == 500.0 + line_module.RECOVERY_RECHECK_S
    leader.phase, leader.x_m = "running", stop + length + line_module.RECOVERY_SIGHT_M - 1.0  # not yet
    sim._recover(follower, 501.0)
    assert follower.phase == "held"
    leader.x_m = stop + length + line_module.RECOVERY_SIGHT_M + 1.0  # its rear out of sight's reach
    sim._recover(follower, 502.0)
    assert follower.phase == "stopping" and follower.next_station == 0
    assert follower.play_x[-1] == stop and follower.play_v[-1] == 0.0
    # The rule off: the same held train is driven at once, to a front inside the train ahead.
    held_short()
    monkeypatch.setattr(line_module, "RECOVERY_SIGHT_M", -math.inf)
    sim._recover(follower, 500.0)
    assert follower.phase == "stopping" and follower.play_x[-1] > leader.x_m - length


def test_the_predictive_hand_over_needs_cbtc() -> None:
    with pytest.raises(SimulationError, match="handover"):
        LineSettings(handover="predictive")
    with pytest.raises(SimulationError, match="handover"):
        LineSettings(signalling="cbtc", handover="soon")


# --------------------------------------------------------------------------
# The ATS's train regulation (LineSettings.regulation)


def _stands_between_platforms(sim: LineSimulation) -> int:
    """How many times a train stood for 2 s or more away from every stopping point (5 m): held
    before a platform (the trains waiting at the entry are not on the line)."""
    stops = [st.stop_point_m for st in LINE.stations]
    count = 0
    for train in sim.trains:
        t, x = np.asarray(train.samples_t), np.asarray(train.samples_x)
        still = np.flatnonzero(np.abs(np.diff(x)) < 1e-9)
        if not still.size:
            continue
        # Runs of consecutive standing steps.
        breaks = np.flatnonzero(np.diff(still) > 1) + 1
        for run in np.split(still, breaks):
            if t[run[-1] + 1] - t[run[0]] >= 2.0 and min(abs(x[run[0]] - s) for s in stops) > 5.0:
                count += 1
    return count


def _queued_line(regulation: bool, least: float) -> tuple[LineSimulation, dict[str, Any], float]:
    op = OPERATION.model_copy(update={"trains": 7, "headway_s": 0.8 * least})
    settings = LineSettings(signalling="cbtc", regulation=regulation)
    sim = LineSimulation(line=LINE, vehicle=VEHICLE, operation=op, seed=1, settings=settings)
    s = sim.run(1500.0).summary()
    busiest = 0.0
    for station in LINE.stations:
        arrivals = sorted(r.arrive_s for r in sim.stops if r.station == station.name)
        if len(arrivals) >= 4:
            busiest = max(busiest, float(np.median(np.diff(arrivals))))
    return sim, s, busiest


def test_a_regulated_line_holds_its_trains_at_platforms_and_serves_at_its_minimum(
    headways: list[PlatformHeadway],
) -> None:
    """Fed faster than it can serve, the line's followers stand before the platforms and restart
    from a stand: its busiest platform serves one train per standing cycle, well over the
    minimum. With the regulation the ATS holds each at the platform (or the entry) before, to
    reach its best release state as the platform clears: no train stands between platforms, and
    the busiest platform serves at the minimum; never an overlap or a collision."""
    least = max(h.headway_s for h in headways)
    plain, s_plain, busiest_plain = _queued_line(False, least)
    regulated, s_reg, busiest_reg = _queued_line(True, least)
    assert _stands_between_platforms(plain) >= 3 and busiest_plain > 1.05 * least
    assert "regulation_holds" not in s_plain["cbtc"]
    assert _stands_between_platforms(regulated) == 0
    assert s_reg["cbtc"]["regulation_holds"] >= 5 and s_reg["cbtc"]["regulation_hold_s"] > 60.0
    assert 0.99 * least <= busiest_reg <= 1.02 * least
    for s in (s_plain, s_reg):
        assert s["cbtc"]["authority_overlaps"] == 0 and s["cbtc"]["collisions"] == 0
        assert s["stops"] == s["stops_within_tolerance"] and s["skipped_stops"] == 0


def test_the_regulation_needs_cbtc_and_is_part_of_a_campaigns_identity() -> None:
    with pytest.raises(SimulationError, match="regulation"):
        LineSettings(regulation=True)
    assert LineSettings(signalling="cbtc", regulation=True).identity()["regulation"] is True
    assert "regulation" not in LineSettings(signalling="cbtc").identity()


def test_the_regulation_holds_a_train_at_its_platform_until_it_would_meet_the_release() -> None:
    """The rule alone, at a platform (most holds of a queued line are at the entry): a train ready
    to leave Riverside while the train ahead dwells at Hillcrest is held so that it reaches its
    best release state as that train's planned start plus the clearing and the system's delays
    release it; looked at again when the hold ends, it leaves. A train ahead still braking into
    Hillcrest starts a nominal dwell after its nominal stop ends; one that has left, or is held
    by a dwell fault, holds nobody."""
    op = OPERATION.model_copy(update={"trains": 2})
    settings = LineSettings(signalling="cbtc", regulation=True)
    sim = LineSimulation(line=LINE, vehicle=VEHICLE, operation=op, seed=1, settings=settings)
    reg = sim._regulation[1]
    assert reg is not None and reg.station == "Hillcrest"
    leader, follower = sim.trains[1], sim.trains[0]
    riverside, hillcrest = (st.stop_point_m for st in LINE.stations[:2])
    now = 500.0

    def ready() -> None:
        leader.phase, leader.x_m, leader.next_station = "dwelling", hillcrest, 2
        leader.plan_depart_s = now + 60.0  # it leaves in 60 s by the plan
        follower.phase, follower.x_m, follower.next_station = "dwelling", riverside, 1
        follower.until_s = now

    ready()
    hold = 60.0 + reg.release_after_s - reg.run_to_release_s
    assert hold > 1.0 and sim._regulation_hold(follower, now, 1)
    assert follower.until_s == pytest.approx(now + hold) and follower.plan_depart_s == follower.until_s
    assert sim.regulation_holds == 1 and sim.regulation_hold_s == pytest.approx(hold)
    # Looked at again when the hold ends: no hold left, it leaves.
    assert not sim._regulation_hold(follower, follower.until_s, 1)
    # Still braking in, 10 s into its stop: it arrives when its nominal stop ends, then dwells.
    ready()
    leader.phase, leader.x_m, leader.next_station, leader.stop_t0_s = (
        "stopping",
        hillcrest - 100.0,
        1,
        now - 10.0,
    )
    assert sim._regulation_hold(follower, now, 1)
    start = now - 10.0 + reg.approach_s + reg.start_enable_s
    assert follower.until_s == pytest.approx(start + reg.release_after_s - reg.run_to_release_s)
    # Gone from the platform, or held there by a dwell fault: no plan, no hold.
    for phase, x in (("running", hillcrest + 50.0), ("held", hillcrest)):
        ready()
        leader.phase, leader.x_m = phase, x
        assert not sim._regulation_hold(follower, now, 1)
