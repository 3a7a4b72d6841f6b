"""SPEC §4 CBTC units: the zone controller (compensation, authority, uncertainties and rollback, lost
trains, protection zones, re-detection) and the onboard unit (reports, the authority anchored to the
report it answers, missed commands, the safe braking model's supervision)."""

from __future__ import annotations

import heapq
import math
from importlib import resources
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railstop.clock import SimClock
from railstop.config import load_line
from railstop.config.layout import Cbtc
from railstop.control.supervision import EbCause
from railstop.errors import ConfigError
from railstop.link.codec import LAYOUTS, CbtcCommand, CbtcReport
from railstop.messages import (
    CBTC_COUNTS_PER_UNIT,
    ManualRelease,
    Message,
    MovementCommand,
    OnboardPosition,
    Output,
    PositionReport,
)
from railstop.onboard.cbtc import (
    OnboardCbtc,
    intervention_speed_mps,
    permitted_speed_mps,
    safe_braking_distance_m,
)
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


def report(train: int, x: float, v: float, t: float, direction: str = "R", u: float = 0.0) -> PositionReport:
    return PositionReport(
        train_id=train, position_m=x, speed_mps=v, direction=direction, time_s=t, uncertainty_m=u
    )


def command_for(
    unit: ZoneController, train: int, x: float, v: float, t: float, direction: str = "R", u: float = 0.0
) -> MovementCommand:
    """Report at t; the command comes out Δt later."""
    assert unit.handle(report(train, x, v, t, direction, u), t) == []
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
    # The exit: a train's length and a margin beyond the line's end (less the margin).
    end = 6000.0 + LENGTH + 21.0 if direction == "R" else -LENGTH - 21.0
    sign = 1.0 if direction == "R" else -1.0
    assert c_on.authority_m == pytest.approx(sign * (end - (x + sign * 0.2 * v)), abs=1e-3)
    assert c_off.authority_m == pytest.approx(sign * (end - x), abs=1e-3)
    assert c_off.authority_m - c_on.authority_m == pytest.approx(0.2 * v, abs=2e-3)  # tighter by Δt·Vp
    assert c_on.report_time_s == 10.0
    assert c_on.delay_s == pytest.approx(0.2) and c_off.delay_s == 0.0  # the Δt compensated with
    # On the telegrams' grid, rounded down: the wire never lengthens it.
    assert c_on.authority_m * CBTC_COUNTS_PER_UNIT == pytest.approx(
        round(c_on.authority_m * CBTC_COUNTS_PER_UNIT)
    )
    assert c_on.authority_m <= sign * (end - (x + sign * c_on.delay_s * v))


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
    assert c.authority_m == pytest.approx(2000.0 - LENGTH - P.rollback_m - 20.0 - pc, abs=1e-3)


@pytest.mark.parametrize("direction", ["R", "L"])
def test_authority_leaves_both_uncertainties_and_the_rollback(direction: str) -> None:
    """IEEE 1474.1: the train ahead's rear less its uncertainty and the rollback, less the margin,
    for the follower's front plus its own uncertainty."""
    sign = 1.0 if direction == "R" else -1.0
    ends = {}
    for u_ahead, u_own in ((0.0, 0.0), (6.0, 0.0), (0.0, 4.0), (6.0, 4.0)):
        unit = zc(Cbtc(report_period_s=0.5, processing_delay_s=0.2, safety_margin_m=20.0, rollback_m=3.0))
        command_for(unit, 2, 3000.0 + sign * 1000.0, 0.0, 0.0, direction, u_ahead)  # the leader, standing
        c = command_for(unit, 1, 3000.0, 10.0, 0.1, direction, u_own)
        pc = 3000.0 + sign * 0.2 * 10.0
        ends[u_ahead, u_own] = pc + sign * c.authority_m
        rear = 3000.0 + sign * (1000.0 - LENGTH)
        assert sign * ends[u_ahead, u_own] == pytest.approx(
            sign * rear - u_ahead - 3.0 - 20.0 - u_own, abs=1e-3
        )
        assert sign * ends[u_ahead, u_own] <= sign * rear - u_ahead - 3.0 - 20.0 - u_own  # rounded down
    assert sign * (ends[0.0, 0.0] - ends[6.0, 4.0]) == pytest.approx(10.0, abs=2e-3)


def test_a_lost_trains_zone_takes_in_its_uncertainty_and_the_rollback() -> None:
    unit = zc(Cbtc(report_period_s=0.5, processing_delay_s=0.2, safety_margin_m=20.0, rollback_m=3.0))
    command_for(unit, 2, 2125.0, 0.0, 0.0, u=3.0)  # rear at 2005: 2002 with the uncertainty, 1999 rolled back
    unit.on_timer(2.0)
    (zone,) = unit.zones()
    assert zone.start_m == 1900.0  # not 2000: the rear may be in segment 1900-2000


def test_two_missed_reports_make_a_lost_train_with_a_minimal_zone() -> None:
    unit = zc()
    v = 15.0
    c = command_for(unit, 2, 2000.0, v, 0.0)
    leader_end = 2000.0 + 0.2 * v + c.authority_m  # the forward stop point it was given
    command_for(unit, 1, 1000.0, 10.0, 0.1)
    # One missed report: still tracked.
    unit.on_timer(1.0 + 1e-6)
    assert unit.trains[2].status == TrainStatus.TRACKED and unit.trains[2].watchdog.missed == 1
    # The second: lost, zone set, from the segment of its rear to the segment of its end.
    unit.on_timer(1.25)
    assert unit.trains[2].status == TrainStatus.LOST and unit.counts.lost >= 1
    (zone,) = [z for z in unit.zones() if z.train_id == 2]
    assert zone.start_m == 1800.0  # rear 1880 m (1878 m rolled back) lies in segment 1800-1900
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
        PositionReport(
            train_id=1, position_m=100.0, speed_mps=1.0, direction="X", time_s=0.0, uncertainty_m=0.0
        ),
        report(1, 100.0, 1.0, 0.0, u=math.nan),  # a missing uncertainty
        report(1, 100.0, 1.0, 0.0, u=-0.5),
        report(1, 100.0, 1.0, 0.0, u=math.inf),
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


def position(x: float, v: float = 0.0, u: float = 0.0) -> OnboardPosition:
    return OnboardPosition(position_m=x, speed_mps=v, uncertainty_m=u)


def cmd(
    authority: float, report_time_s: float, limit: float = 22.0, delay_s: float = 0.0, gradient: float = 0.0
) -> MovementCommand:
    return MovementCommand(
        train_id=1,
        authority_m=authority,
        gradient_permille=gradient,
        speed_limit_mps=limit,
        report_time_s=report_time_s,
        delay_s=delay_s,
    )


def sent(u: OnboardCbtc, now_s: float) -> PositionReport:
    (out,) = u.on_timer(now_s)
    assert isinstance(out.message, PositionReport)
    return out.message


def test_onboard_reports_every_cycle_from_its_position() -> None:
    u = onboard()
    assert u.on_timer(0.0) == []  # no position yet
    u.handle(position(500.0, 10.0, 2.5), 0.4)
    (out,) = u.on_timer(0.5)
    assert out.to == "zc" and out.message == report(1, 500.0, 10.0, 0.5, u=2.5)
    assert u.next_deadline_s() == 1.0
    # On the telegrams' grid: the uncertainty widened by what the rounding moved the position, up.
    u.handle(position(500.0004, 10.0, 2.5), 0.9)
    (out,) = u.on_timer(1.0)
    assert out.message == report(1, 500.0, 10.0, 1.0, u=2.501)


def test_authority_end_is_the_intended_end() -> None:
    """SPEC §4: the distance is from Pc = Pp + Δt·Vp of the report the command answers; the end is
    that point, not the distance added to where the train is when the command arrives."""
    u = onboard()
    u.handle(position(500.0, 10.0), 0.0)
    r = sent(u, 0.5)
    u.handle(position(503.5, 10.0), 0.85)  # the command arrives 0.35 s after the report
    u.handle(cmd(300.0, r.time_s, delay_s=0.2), 0.85)
    assert u.authority_end_m == pytest.approx(500.0 + 0.2 * 10.0 + 300.0)  # 802, not 803.5
    assert u.distance_to_end_m() == pytest.approx(802.0 - 503.5)


def test_a_command_for_a_report_not_held_is_no_authority_and_counts_missed() -> None:
    u = onboard()
    u.handle(position(500.0), 0.0)
    r0 = sent(u, 0.0)
    u.handle(cmd(300.0, r0.time_s), 0.2)
    assert u.authority_end_m == 800.0
    # Never sent: refused, the authority held stays, and the cycles count missed up to the brake.
    for t in (0.5, 1.0):
        sent(u, t)
        u.handle(cmd(900.0, 0.75), t + 0.2)
    assert u.refused_commands == 2 and u.authority_end_m == 800.0
    sent(u, 1.5)
    assert u.emergency_brake and u.eb_cause == EbCause.MISSED_COMMANDS


def test_an_out_of_order_or_too_old_command_is_no_authority() -> None:
    u = onboard()
    u.handle(position(500.0), 0.0)
    r0, r1 = sent(u, 0.0), sent(u, 0.5)
    u.handle(cmd(100.0, r1.time_s), 0.6)  # the newer report's command first: a shorter authority
    u.handle(cmd(900.0, r0.time_s), 0.7)  # the older one late: it must not lengthen it again
    assert u.authority_end_m == 600.0 and u.refused_commands == 1
    # The unit keeps the last missed_commands_eb (2) reports: an answer to an older one is too old.
    r2 = sent(u, 1.0)
    sent(u, 1.5)
    sent(u, 2.0)
    u.handle(cmd(50.0, r2.time_s), 2.1)
    assert u.refused_commands == 2 and u.authority_end_m == 600.0


@pytest.mark.parametrize(
    "bad",
    [
        {"authority": math.nan},
        {"authority": -1.0},
        {"delay_s": math.nan},
        {"delay_s": -0.1},
        {"limit": math.inf},
    ],
)
def test_an_invalid_command_is_no_authority(bad: dict[str, float]) -> None:
    u = onboard()
    u.handle(position(500.0), 0.0)
    r = sent(u, 0.0)
    kw: dict[str, float] = {"authority": 300.0, "report_time_s": r.time_s, **bad}
    u.handle(cmd(**kw), 0.2)
    assert u.refused_commands == 1 and math.isnan(u.authority_end_m) and u.commands == 0


@pytest.mark.parametrize("bad_u", [math.nan, -1.0, math.inf])
def test_an_invalid_onboard_position_brakes_and_stops_the_reports(bad_u: float) -> None:
    u = onboard()
    u.handle(position(500.0), 0.0)
    assert sent(u, 0.0).uncertainty_m == 0.0
    u.handle(position(510.0, 5.0, bad_u), 0.3)
    assert u.emergency_brake and u.eb_cause == EbCause.POSITION_INVALID
    assert u.on_timer(0.5) == []  # no report: the zone controller loses the train (SPEC §4)


def test_two_missed_commands_apply_the_emergency_brake_one_does_not() -> None:
    u = onboard()
    u.handle(position(500.0), 0.0)
    r = sent(u, 0.0)
    u.handle(cmd(1000.0, r.time_s), 0.3)
    u.handle(position(500.0, 10.0), 0.4)
    r = sent(u, 0.5)  # answered
    sent(u, 1.0)  # one missed
    assert not u.emergency_brake and u.watchdog.missed == 1
    u.handle(cmd(1000.0, r.time_s), 1.3)
    r = sent(u, 1.5)
    sent(u, 2.0)  # one missed again, not consecutive with the first
    assert not u.emergency_brake
    r = sent(u, 2.5)  # the second in a row
    assert u.emergency_brake and u.eb_cause == EbCause.MISSED_COMMANDS
    assert u.eb_count == 1 and u.eb_causes == {EbCause.MISSED_COMMANDS: 1}
    # Latched while moving, even when commands come back ...
    u.handle(cmd(1000.0, r.time_s), 2.6)
    assert u.emergency_brake
    # ... released at standstill by a fresh command.
    u.handle(position(520.0), 5.0)
    r = sent(u, 5.0)
    u.handle(cmd(1000.0, r.time_s), 5.1)
    assert not u.emergency_brake


def test_safe_braking_model_closed_form() -> None:
    """IEEE 1474.1: reaction (detection + cut-off) at the runaway acceleration, build-up coasting,
    then the guaranteed emergency brake rate; the intervention speed inverts it."""
    p = P
    for v in (0.0, 5.0, 22.0):
        t_r, a, t_b, b = 0.7, 1.0, 1.2, 1.1
        v1 = v + a * t_r
        expect = v * t_r + 0.5 * a * t_r**2 + v1 * t_b + v1**2 / (2 * b)
        assert safe_braking_distance_m(v, p) == pytest.approx(expect)
    for d in (5.0, 50.0, 400.0):
        for grad in (0.0, -30.0):
            v = intervention_speed_mps(d, p, grad)
            assert v > 0.0 and safe_braking_distance_m(v, p, grad) == pytest.approx(d)
    assert intervention_speed_mps(1.0, p) == 0.0  # within the reaction distance from a standstill
    # Downhill the curve is lower; uphill no credit is taken ([interpretation]).
    assert (
        intervention_speed_mps(200.0, p, -30.0)
        < intervention_speed_mps(200.0, p)
        == intervention_speed_mps(200.0, p, 30.0)
    )
    # A downhill the guaranteed rate cannot hold: no speed is safe.
    assert intervention_speed_mps(200.0, p, -120.0) == 0.0 and math.isinf(
        safe_braking_distance_m(1.0, p, -120.0)
    )


def test_overspeed_against_the_intervention_curve_applies_the_emergency_brake() -> None:
    u = onboard()
    u.handle(position(500.0), 0.0)
    r = sent(u, 0.0)
    u.handle(cmd(100.0, r.time_s), 0.1)
    ok = intervention_speed_mps(100.0, P)
    u.handle(position(500.0, ok - 0.01), 0.2)
    assert not u.emergency_brake
    assert u.permitted_mps() <= ok - u.overspeed_tolerance_mps  # the driving curve stays under it
    u.handle(position(500.0, ok + 0.01), 0.3)
    assert u.emergency_brake and u.eb_cause == EbCause.CBTC_OVERSPEED


def test_the_growth_of_the_uncertainty_shortens_the_authority() -> None:
    u = onboard()
    u.handle(position(500.0, 0.0, 2.0), 0.0)
    r = sent(u, 0.0)
    u.handle(cmd(100.0, r.time_s), 0.1)
    assert u.distance_to_end_m() == pytest.approx(100.0)
    u.handle(position(500.0, 0.0, 7.0), 0.2)  # 5 m more uncertain than when reported
    assert u.distance_to_end_m() == pytest.approx(95.0, abs=2e-3)


def test_no_command_no_authority_and_foreign_commands_are_ignored() -> None:
    u = onboard()
    u.handle(position(500.0), 0.0)
    assert u.distance_to_end_m() == 0.0 and u.permitted_mps() == 0.0
    # Moving without an authority is overspeed (DESIGN rule 10).
    moving = onboard()
    moving.handle(position(500.0, 3.0), 0.0)
    assert moving.emergency_brake and moving.eb_cause == EbCause.CBTC_OVERSPEED
    r = sent(u, 0.0)
    u.handle(
        MovementCommand(
            train_id=9,
            authority_m=900.0,
            gradient_permille=0.0,
            speed_limit_mps=20.0,
            report_time_s=r.time_s,
            delay_s=0.0,
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
        u.handle(position(0.0), 0.0)
        r = sent(u, 0.0)
        u.handle(cmd(200.0, r.time_s, limit=30.0, gradient=grad), 0.1)
    assert down.intervention_mps() == pytest.approx(intervention_speed_mps(200.0, P, -30.0))
    assert down.intervention_mps() < flat.intervention_mps()
    assert down.permitted_mps() < flat.permitted_mps()


# ---------------------------------------------------------------------- wire and data


def test_the_messages_match_the_telegrams() -> None:
    """Both ends compute with the wire's numbers: the telegrams carry every field of the messages,
    distances, speeds and times at the grid the units put them on."""
    for msg, tele in ((PositionReport, CbtcReport), (MovementCommand, CbtcCommand)):
        layout = LAYOUTS[tele]
        assert [f.name for f in layout.fields] == list(msg.__dataclass_fields__)
        for f in layout.fields:
            if f.kind == "fixed" and f.unit in ("m", "m/s", "s"):
                assert f.counts_per_unit == CBTC_COUNTS_PER_UNIT, f.name


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("gebr_mps2", "0.0"),
        ("gebr_mps2", "12.0"),
        ("brake_build_up_s", "-0.5"),
        ("runaway_accel_mps2", "nan"),
        ("rollback_m", "-1.0"),
        ("position_uncertainty_m", "-2.0"),
    ],
)
def test_impossible_braking_data_is_refused_naming_file_field_and_value(
    tmp_path: Path, field: str, value: str
) -> None:
    text = resources.files("railstop.data").joinpath("line.toml").read_text(encoding="utf-8")
    head, cbtc = text.split("\n[cbtc]\n", 1)
    lines = [ln for ln in cbtc.split("\n") if not ln.startswith(f"{field} =")]
    path = tmp_path / "line.toml"
    path.write_text(head + "\n[cbtc]\n" + f"{field} = {value}\n" + "\n".join(lines), encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_line(path)
    text = str(info.value)
    assert "\n" not in text and str(path) in text and f"cbtc.{field}" in text and value in text


# ---------------------------------------------------------------------- the authority end, end to end


class AnchorsAtArrival(OnboardCbtc):
    """The old reading: the commanded distance added to where the train is when it arrives."""

    def _on_command(self, message: MovementCommand, now_s: float) -> None:
        here = self.position_m
        super()._on_command(message, now_s)
        if message.train_id == self.train_id and self.commands and not math.isnan(here):
            self.authority_end_m = here + self.sign * message.authority_m


class _Wire:
    """A radio in both directions with fixed latencies and the given losses (per direction, the
    frames in order: True = lost), delivering in order."""

    name = "radio"
    accepts: tuple[type, ...] = (PositionReport, MovementCommand)

    def __init__(self, up_s: float, down_s: float, lost_up: list[bool], lost_down: list[bool]) -> None:
        self.latency = {"up": up_s, "down": down_s}
        self.lost = {"up": list(lost_up), "down": list(lost_down)}
        self.heap: list[tuple[float, int, Output]] = []
        self.seq = 0

    def handle(self, message: Message, now_s: float) -> list[Output]:
        way = "up" if isinstance(message, PositionReport) else "down"
        if self.lost[way] and self.lost[way].pop(0):
            return []
        to = "zc" if way == "up" else "cbtc-0"
        self.seq += 1
        heapq.heappush(self.heap, (now_s + self.latency[way], self.seq, Output(to=to, message=message)))
        return []

    def next_deadline_s(self) -> float | None:
        return self.heap[0][0] if self.heap else None

    def on_timer(self, now_s: float) -> list[Output]:
        out = []
        while self.heap and self.heap[0][0] <= now_s + 1e-12:
            out.append(heapq.heappop(self.heap)[2])
        return out


def authority_overshoot_m(
    unit_cls: type[OnboardCbtc],
    speed_mps: float,
    delay_s: float,
    up_s: float,
    down_s: float,
    lost_up: list[bool],
    lost_down: list[bool],
) -> float:
    """The most the train's authority end lies beyond the end the zone controller meant (the
    standing train's rear less its uncertainty, the rollback, the margin and the follower's own
    uncertainty), over every instant of a run; -inf when it never held one."""
    u_m = 3.0
    params = Cbtc(report_period_s=0.5, processing_delay_s=delay_s, missed_commands_eb=3)
    zone = ZoneController(
        params=params,
        segments=SEGMENTS,
        blocks=BLOCKS,
        overlap_m=50.0,
        train_length_m=LENGTH,
        line_end_m=6000.0,
        limit_at=lambda x: 30.0,
        gradient_at=lambda x: 0.0,
        downlink="radio",
    )
    train = unit_cls(train_id=0, direction="R", params=params, curve_decel_mps2=1.0, uplink="radio")
    zone.handle(report(1, 5000.0, 0.0, 0.0, u=u_m), 0.0)  # the obstacle, standing, known from the start
    clock = SimClock([zone, _Wire(up_s, down_s, lost_up, lost_down), train], step_s=0.01)
    # Less the uncertainty the train reported in the report its authority answers (its own, on the
    # telegram's grid).
    limit = 5000.0 - LENGTH - u_m - params.rollback_m - params.safety_margin_m
    worst = -math.inf

    def plant(now_s: float, dt: float) -> list[Output]:
        nonlocal worst
        if not math.isnan(train.authority_end_m):
            worst = max(worst, train.authority_end_m - (limit - train.held_uncertainty_m))
        x = 1000.0 + speed_mps * now_s
        return [
            Output(
                to=train.name, message=OnboardPosition(position_m=x, speed_mps=speed_mps, uncertainty_m=u_m)
            )
        ]

    clock.run(4.0, plant)
    if not math.isnan(train.authority_end_m):
        worst = max(worst, train.authority_end_m - (limit - train.held_uncertainty_m))
    return worst


_losses = st.lists(st.booleans(), max_size=10)


@settings(max_examples=40, deadline=None)
@given(
    speed_kmh=st.floats(min_value=0.0, max_value=90.0),
    delay_s=st.floats(min_value=0.0, max_value=1.0),
    up_s=st.floats(min_value=0.0, max_value=0.4),
    down_s=st.floats(min_value=0.0, max_value=0.4),
    lost_up=_losses,
    lost_down=_losses,
)
def test_the_onboard_authority_never_ends_beyond_the_intended_end(
    speed_kmh: float, delay_s: float, up_s: float, down_s: float, lost_up: list[bool], lost_down: list[bool]
) -> None:
    """At any speed 0-90 km/h, processing delay 0-1 s, uplink and downlink latency and loss."""
    worst = authority_overshoot_m(OnboardCbtc, speed_kmh / 3.6, delay_s, up_s, down_s, lost_up, lost_down)
    assert worst <= 1e-9


def test_the_old_reading_ends_beyond_the_intended_end() -> None:
    """The property bites: the distance added where the command arrives overshoots by the distance
    run meanwhile (80 km/h, Δt 0.2 s, 0.1 s each way: 0.4 s, 8.9 m)."""
    worst = authority_overshoot_m(AnchorsAtArrival, 80.0 / 3.6, 0.2, 0.1, 0.1, [], [])
    assert worst > 2.0
    assert authority_overshoot_m(OnboardCbtc, 80.0 / 3.6, 0.2, 0.1, 0.1, [], []) <= 0.0
