"""SPEC §4 CBTC units: the zone controller (compensation, authority, lost trains, protection zones,
re-detection) and the onboard unit (reports, missed commands, supervision)."""

from __future__ import annotations

import math

import pytest

from railstop.config.layout import Cbtc
from railstop.messages import ManualRelease, MovementCommand, OnboardPosition, PositionReport
from railstop.onboard.cbtc import EB_MISSED_COMMANDS, EB_OVERSPEED, OnboardCbtc, permitted_speed_mps
from railstop.wayside.zone_controller import TrainStatus, ZoneController, ZoneMode

P = Cbtc(report_period_s=0.5, processing_delay_s=0.2, safety_margin_m=20.0)
SEGMENTS = [(100.0 * k, 100.0 * (k + 1)) for k in range(60)]  # 0 .. 6000 m
BLOCKS = [(300.0 * k, 300.0 * (k + 1)) for k in range(20)]
LENGTH = 120.0


def zc(params: Cbtc = P, mode: ZoneMode = ZoneMode.MINIMAL) -> ZoneController:
    return ZoneController(
        params=params,
        segments=SEGMENTS,
        blocks=BLOCKS,
        overlap_m=50.0,
        train_length_m=LENGTH,
        line_end_m=6000.0,
        limit_at=lambda x: 60.0 / 3.6 if 3000.0 <= x < 3400.0 else 80.0 / 3.6,
        gradient_at=lambda x: 5.0 if x >= 2000.0 else 0.0,
        mode=mode,
    )


def report(train: int, x: float, v: float, t: float, direction: str = "R") -> PositionReport:
    return PositionReport(train_id=train, position_m=x, speed_mps=v, direction=direction, time_s=t)


def command_for(
    unit: ZoneController, train: int, x: float, v: float, t: float, direction: str = "R"
) -> MovementCommand:
    """Report at t; the command comes out Δt later."""
    assert unit.handle(report(train, x, v, t, direction), t) == []
    assert unit.next_deadline_s() == pytest.approx(t + P.processing_delay_s)
    outs = unit.on_timer(t + P.processing_delay_s)
    (out,) = [o for o in outs if isinstance(o.message, MovementCommand) and o.message.train_id == train]
    assert out.to == f"cbtc-{train}"
    return out.message  # type: ignore[return-value]


@pytest.mark.parametrize("direction", ["R", "L"])
def test_compensated_position_is_pp_plus_or_minus_dt_vp(direction: str) -> None:
    """SPEC §4: Pc = Pp ± Δt·Vp; the authority is the distance from Pc to its end."""
    v = 80.0 / 3.6
    on = zc()
    off = zc(Cbtc(report_period_s=0.5, processing_delay_s=0.2, safety_margin_m=20.0, compensate=False))
    x = 2500.0
    c_on, c_off = command_for(on, 1, x, v, 10.0, direction), command_for(off, 1, x, v, 10.0, direction)
    end = 6000.0 + LENGTH + 1.0 if direction == "R" else -LENGTH - 1.0  # a train's length beyond the end
    sign = 1.0 if direction == "R" else -1.0
    assert c_on.authority_m == pytest.approx(sign * (end - (x + sign * 0.2 * v)))
    assert c_off.authority_m == pytest.approx(sign * (end - x))
    assert c_off.authority_m - c_on.authority_m == pytest.approx(0.2 * v)  # tighter by Δt·Vp
    assert c_on.report_time_s == 10.0


def test_speed_limit_and_gradient_are_taken_at_pc() -> None:
    # Pp just short of the 60 km/h stretch at 3000 m; Pc 4.4 m inside it.
    v = 22.0
    c = command_for(zc(), 1, 2999.0, v, 0.0)
    assert c.speed_limit_mps == pytest.approx(60.0 / 3.6)
    c = command_for(zc(Cbtc(processing_delay_s=0.2, compensate=False)), 1, 2999.0, v, 0.0)
    assert c.speed_limit_mps == pytest.approx(80.0 / 3.6)


def test_authority_ends_behind_the_train_ahead() -> None:
    unit = zc()
    command_for(unit, 2, 2000.0, 0.0, 0.0)  # the leader, standing, front at 2000 m
    c = command_for(unit, 1, 1000.0, 10.0, 0.1)
    pc = 1000.0 + 0.2 * 10.0
    assert c.authority_m == pytest.approx(2000.0 - LENGTH - 20.0 - pc)


def test_two_missed_reports_make_a_lost_train_with_a_minimal_zone() -> None:
    unit = zc()
    v = 15.0
    c = command_for(unit, 2, 2000.0, v, 0.0)
    leader_end = 2000.0 + 0.2 * v + c.authority_m  # the forward stop point it was given
    command_for(unit, 1, 1000.0, 10.0, 0.1)
    # One missed report: still tracked.
    unit.on_timer(1.0 + 1e-6)
    assert unit.trains[2].status == TrainStatus.TRACKED and unit.trains[2].missed == 1
    # The second: lost, zone set, from the segment of its rear to the segment of its end.
    unit.on_timer(1.25)
    assert unit.trains[2].status == TrainStatus.LOST and unit.counts.lost >= 1
    (zone,) = [z for z in unit.zones() if z.train_id == 2]
    assert zone.start_m == 1800.0  # rear 1880 m lies in segment 1800-1900
    assert zone.end_m == math.ceil(leader_end / 100.0) * 100.0 or zone.end_m == 6000.0
    # The follower's authority stops short of the zone.
    c1 = command_for(unit, 1, 1010.0, 10.0, 1.3)
    assert 1010.0 + 0.2 * 10.0 + c1.authority_m <= zone.start_m - 20.0 + 1e-9


def test_conventional_zone_is_whole_blocks_and_the_overlap_and_never_smaller() -> None:
    zones = {}
    for mode in ZoneMode:
        unit = zc(mode=mode)
        command_for(unit, 2, 2000.0, 0.0, 0.0)
        command_for(unit, 3, 1650.0, 0.0, 0.0)  # its authority ends behind train 2
        unit.on_timer(2.0)
        zones[mode] = next(z for z in unit.zones() if z.train_id == 3)
    m, c = zones[ZoneMode.MINIMAL], zones[ZoneMode.CONVENTIONAL]
    # Train 3: rear 1530, authority end 2000 - 120 - 20 = 1860.
    assert (m.start_m, m.end_m) == (1500.0, 1900.0)
    assert (c.start_m, c.end_m) == (1200.0, 2100.0)  # blocks 1200-1500 (overlap) .. 1800-2100
    assert c.start_m <= m.start_m and c.end_m >= m.end_m


def test_redetection_inside_releases_outside_flags_until_manual_release() -> None:
    for x_back, inside in ((1850.0, True), (2500.0, False)):
        unit = zc()
        command_for(unit, 2, 2000.0, 0.0, 0.0)  # authority to the line's end
        command_for(unit, 1, 1600.0, 0.0, 0.0)
        unit.handle(report(2, 2000.0, 0.0, 0.5), 0.5)  # the follower does not report again
        unit.on_timer(3.0)
        t2 = unit.trains[2]
        # Train 1 is lost (it stopped reporting); train 2 too, at 3 s.
        t1 = unit.trains[1]
        assert t1.status == TrainStatus.LOST and t1.zone is not None
        zone = t1.zone
        assert (zone.start_m, zone.end_m) == (1400.0, 1900.0)  # rear 1480 .. end 2000 - 140 = 1860
        unit.handle(report(1, x_back, 0.0, 3.2), 3.2)
        if inside:
            assert t1.status == TrainStatus.TRACKED and t1.zone is None and unit.counts.auto_releases == 1
            continue
        assert t1.status == TrainStatus.FLAGGED and t1.zone == zone and unit.counts.flagged == 1
        # Held: a flagged train's authority is 0.
        outs = unit.on_timer(3.4)
        (c,) = [o.message for o in outs if isinstance(o.message, MovementCommand)]
        assert c.authority_m == 0.0
        # A report inside the zone later does not release it: only the operator does.
        unit.handle(report(1, 1850.0, 0.0, 3.6), 3.6)
        assert t1.status == TrainStatus.FLAGGED
        unit.handle(ManualRelease(train_id=1), 4.0)
        assert t1.status == TrainStatus.TRACKED and t1.zone is None and unit.counts.manual_releases == 1
        unit.handle(ManualRelease(train_id=1), 4.1)
        assert unit.counts.ignored_releases == 1
        assert t2 is unit.trains[2]


@pytest.mark.parametrize(
    "bad",
    [
        report(1, math.nan, 1.0, 0.0),
        report(1, 100.0, -1.0, 0.0),
        PositionReport(train_id=1, position_m=100.0, speed_mps=1.0, direction="X", time_s=0.0),
    ],
)
def test_an_invalid_report_is_refused_counted_and_counts_as_missed(bad: PositionReport) -> None:
    unit = zc()
    command_for(unit, 1, 1000.0, 0.0, 0.0)
    assert unit.handle(bad, 0.5) == []
    assert unit.counts.rejected_reports == 1
    unit.on_timer(1.25)
    assert unit.trains[1].status == TrainStatus.LOST  # as with the report missing


# ---------------------------------------------------------------------- the onboard unit


def onboard(**kw: object) -> OnboardCbtc:
    return OnboardCbtc(train_id=1, direction="R", params=P, curve_decel_mps2=0.7, **kw)  # type: ignore[arg-type]


def cmd(authority: float, limit: float = 22.0) -> MovementCommand:
    return MovementCommand(
        train_id=1, authority_m=authority, gradient_permille=0.0, speed_limit_mps=limit, report_time_s=0.0
    )


def test_onboard_reports_every_cycle_from_its_position() -> None:
    u = onboard()
    assert u.on_timer(0.0) == []  # no position yet
    u.handle(OnboardPosition(position_m=500.0, speed_mps=10.0), 0.4)
    (out,) = u.on_timer(0.5)
    assert out.to == "zc" and out.message == report(1, 500.0, 10.0, 0.5)
    assert u.next_deadline_s() == 1.0


def test_two_missed_commands_apply_the_emergency_brake_one_does_not() -> None:
    u = onboard()
    u.handle(OnboardPosition(position_m=500.0, speed_mps=0.0), 0.0)
    u.on_timer(0.0)
    u.handle(cmd(1000.0), 0.3)
    u.handle(OnboardPosition(position_m=500.0, speed_mps=10.0), 0.4)
    u.on_timer(0.5)  # answered
    u.on_timer(1.0)  # one missed
    assert not u.emergency_brake and u.missed == 1
    u.handle(cmd(1000.0), 1.3)
    u.on_timer(1.5)
    u.on_timer(2.0)  # one missed again, not consecutive with the first
    assert not u.emergency_brake
    u.on_timer(2.5)  # the second in a row
    assert u.emergency_brake and u.eb_cause == EB_MISSED_COMMANDS
    assert u.eb_count == 1 and u.eb_causes == {EB_MISSED_COMMANDS: 1}
    # Latched while moving, even when commands come back ...
    u.handle(cmd(1000.0), 2.6)
    assert u.emergency_brake
    # ... released at standstill by a fresh command.
    u.handle(OnboardPosition(position_m=520.0, speed_mps=0.0), 5.0)
    u.handle(cmd(1000.0), 5.1)
    assert not u.emergency_brake


def test_authority_end_is_the_distance_from_where_the_command_arrives() -> None:
    u = onboard()
    u.handle(OnboardPosition(position_m=500.0, speed_mps=0.0), 0.0)
    u.handle(cmd(300.0), 0.2)
    assert u.authority_end_m == 800.0 and u.distance_to_end_m() == 300.0


def test_overspeed_against_the_braking_curve_applies_the_emergency_brake() -> None:
    u = onboard()
    u.handle(OnboardPosition(position_m=500.0, speed_mps=0.0), 0.0)
    u.handle(cmd(100.0), 0.1)
    ok = permitted_speed_mps(100.0, 0.7, 1.0)
    u.handle(OnboardPosition(position_m=500.0, speed_mps=ok), 0.2)
    assert not u.emergency_brake
    u.handle(OnboardPosition(position_m=500.0, speed_mps=ok + u.overspeed_tolerance_mps + 0.1), 0.3)
    assert u.emergency_brake and u.eb_cause == EB_OVERSPEED


def test_no_command_no_authority_and_foreign_commands_are_ignored() -> None:
    u = onboard()
    u.handle(OnboardPosition(position_m=500.0, speed_mps=0.0), 0.0)
    assert u.distance_to_end_m() == 0.0 and u.permitted_mps() == 0.0
    # Moving without an authority is overspeed (DESIGN rule 10).
    moving = onboard()
    moving.handle(OnboardPosition(position_m=500.0, speed_mps=3.0), 0.0)
    assert moving.emergency_brake and moving.eb_cause == EB_OVERSPEED
    u.handle(
        MovementCommand(
            train_id=9, authority_m=900.0, gradient_permille=0.0, speed_limit_mps=20.0, report_time_s=0.0
        ),
        0.1,
    )
    assert u.foreign_commands == 1 and u.distance_to_end_m() == 0.0


def test_permitted_speed_stops_within_the_distance() -> None:
    for d in (1.0, 50.0, 400.0):
        v = permitted_speed_mps(d, 0.7, 1.0)
        assert v * 1.0 + v * v / (2 * 0.7) == pytest.approx(d)
    assert permitted_speed_mps(0.0, 0.7, 1.0) == 0.0


def test_the_commands_gradient_enters_the_braking_curve() -> None:
    """SPEC §4: the gradient at Pc is part of the command; downhill the train may run slower."""
    flat, down = onboard(), onboard()
    for u, grad in ((flat, 0.0), (down, -30.0)):
        u.handle(OnboardPosition(position_m=0.0, speed_mps=0.0), 0.0)
        u.handle(
            MovementCommand(
                train_id=1, authority_m=200.0, gradient_permille=grad, speed_limit_mps=30.0, report_time_s=0.0
            ),
            0.1,
        )
    assert down.permitted_mps() == pytest.approx(permitted_speed_mps(200.0, 0.7 - 9.81 * 0.03, 1.0))
    assert down.permitted_mps() < flat.permitted_mps()
