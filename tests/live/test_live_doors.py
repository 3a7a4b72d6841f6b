"""The station dwell live (SPEC §5): the WPCS's end and the train's end of the door link, wired in
one process, against the dwell simulation and through their fail-safe paths."""

from __future__ import annotations

import math
from typing import Any

import pytest

from railstop.config.doors import load_doors
from railstop.control.doors import LOCKED_STATES, DoorState, Side
from railstop.link.channel import media_preset
from railstop.link.codec import decode, encode
from railstop.live.doors import pack_stop_sensed, unpack_stop_sensed
from railstop.nodes.dwell import DWELL_STEP_S, PlatformDoors, TrainDoors, model_for, run_wired, wired_dwell
from railstop.sim.dwell import make_door_link, run_dwell

DOORS = load_doors()
CYCLE = DOORS.link.exchange_cycle_s


#: A medium that loses nothing and takes no time: each telegram is delivered at the next step, as
#: the wired ends' are.
IDEAL = media_preset(DOORS.link.medium).replace(
    cycle_s=0.0, latency_s=0.0, jitter_s=0.0, loss_probability=0.0, bit_error_rate=0.0, bit_rate_bps=1e12
)

CASES = [
    (0.0, {}),
    (0.3, {}),
    (-0.34, {}),
    (0.8, {}),
    (-1.2, {}),
    (0.0, {"psd_fail": 3}),
    (0.0, {"obstruct_door": 2}),
    (0.0, {"mode": "manual"}),
    (0.8, {"mode": "manual"}),
]


def _wired(error_m: float, kw: dict[str, Any]) -> tuple[TrainDoors, PlatformDoors]:
    return wired_dwell(
        DOORS, error_m=error_m, step_s=DWELL_STEP_S, psd_jam=kw.get("psd_fail"),
        obstruct=kw.get("obstruct_door"), manual=kw.get("mode") == "manual",
    )  # fmt: skip


@pytest.mark.parametrize(("error_m", "kw"), CASES)
def test_the_simulated_dwell_over_an_ideal_link_is_the_wired_dwell(
    error_m: float, kw: dict[str, Any]
) -> None:
    """DESIGN rule 1 parity (a dwell's events): the dwell simulation (``run_dwell``, the line's
    dwell) and the live processes' ends wired directly in one process run the same units on the
    same step: over a medium that loses nothing and takes no time, the same PSC requests, the same
    corrections to the same final stop, the platform's events at the same times, start enable at
    the same instant."""
    train, platform = _wired(error_m, kw)
    sim = run_dwell(
        doors=DOORS, station="P", platform_side="R", stop_error_m=error_m,
        link=make_door_link(DOORS, train_id=train.train, medium=IDEAL), **kw,
    )  # fmt: skip
    assert sim.outcome == train.result()["outcome"] == "start-enable"
    assert (sim.psc_attempts, sim.corrections) == (train.psc_requests, train.corrections)
    assert sim.final_stop_error_m == round(train.error_m, 6)
    assert train.start_enable_s is not None and sim.start_enable_s == round(train.start_enable_s, 3)
    assert sim.link is not None and sim.link.lost == 0 and not sim.link.rejected
    # The platform's events, as the live stations process reports them to the office.
    sim_opened = [e.t_s for e in sim.timeline if e.signal == "PSD" and e.value == "open"]
    wired_opened = [e["t_s"] for e in platform.events if e["ev"] == "psd-open"]
    assert sim_opened == wired_opened and len(wired_opened) == 1
    print(f"{error_m:+.2f} m {kw}: start enable {sim.start_enable_s:.2f} s in both")


@pytest.mark.parametrize(("error_m", "kw"), CASES)
def test_the_door_datas_medium_delays_the_wired_dwell_by_its_hops_only(
    error_m: float, kw: dict[str, Any]
) -> None:
    """Over the door data's medium (a transponder: a poll cycle, latency, rare losses) the dwell
    ends as the wired one does, later at most by what its hops and a lost frame's exchange cycle
    take."""
    train, _ = _wired(error_m, kw)
    sim = run_dwell(doors=DOORS, station="P", platform_side="R", stop_error_m=error_m, seed=3, **kw)
    assert sim.outcome == "start-enable"
    assert sim.start_enable_s is not None and train.start_enable_s is not None
    assert sim.corrections == train.corrections
    assert train.start_enable_s <= sim.start_enable_s <= train.start_enable_s + 4 * CYCLE


def test_train_out_of_reach_is_never_answered_and_brakes() -> None:
    """SPEC §5: no PSC reply after the last attempt: fault and emergency brake."""
    train, platform = wired_dwell(DOORS, error_m=30.0)
    assert train.fault is not None and train.emergency_brake
    assert train.psc_requests == DOORS.stop_confirm.max_psc_attempts
    assert train.corrections == DOORS.stop_confirm.max_psc_attempts - 1
    assert platform.counts["psc_answered"] == 0 and platform.counts["psc_refused"] > 0
    assert all(u == DoorState.CLOSED_LOCKED for u in platform.state.units)


def test_platform_dead_before_the_stop_brakes_the_train() -> None:
    train, _ = wired_dwell(DOORS, error_m=0.0, platform_silent_after_s=0.0)
    assert train.fault is not None and train.emergency_brake
    assert train.psc_requests == DOORS.stop_confirm.max_psc_attempts


def test_platform_dead_with_doors_open_is_a_lost_link() -> None:
    """PSC high, the status frames stop: the train's supervision reports the fault and brakes
    within ``supervision_timeout_s`` plus a step; no start enable on a PSD it cannot see."""
    train, platform = wired_dwell(DOORS, error_m=0.0, platform_silent_after_s=10.0, step_s=0.01)
    assert train.fault is not None and "link-lost" in train.fault
    assert train.start_enable_s is None and train.emergency_brake
    t_fault = next(t for t, what in train.events if what == "fault")
    assert 10.0 < t_fault <= 10.0 + DOORS.link.supervision_timeout_s + 0.02
    print(f"platform dead at 10 s with the doors open: fault and emergency brake at {t_fault:.2f} s")
    assert platform.train == 1  # the dead platform never let go (it ran no more)


def test_train_silent_platform_drops_it_and_holds_the_psd() -> None:
    model = model_for(DOORS)
    platform = PlatformDoors(index=0, name="P", side=Side.R, doors=DOORS, model=model)
    train = TrainDoors(
        train=4, station=0, station_name="P", side=Side.R, error_m=0.0, doors=DOORS, model=model, t0_s=0.0
    )
    t = 0.0
    while t < 8.0:  # until the doors are open
        train.step(t, 0.01)
        platform.sense(4, 0.0, t)
        for cmd in train.due:
            platform.receive(cmd, t)
        train.due.clear()
        platform.tick(t)
        for _, status in platform.due:
            train.receive(status, t)
        platform.due.clear()
        t = round(t + 0.01, 9)
    assert all(u == DoorState.OPEN for u in platform.state.units)
    while t < 10.0:  # the train's process is gone: only the platform runs
        platform.tick(t)
        t = round(t + 0.01, 9)
    assert platform.train is None and platform.counts["links_lost"] == 1
    assert platform.events[-1]["ev"] == "link-lost"
    # No exchange, no command (SPEC §5): the PSD is held as it is, for the staff.
    assert all(u == DoorState.OPEN for u in platform.state.units)


def test_wcc_manual_holds_the_psd_until_the_panel_opens_it() -> None:
    """SPEC §5: the WCC switches the WPCS to manual; the ATC's DOC no longer opens the PSD, the
    panel's open button does; the PSD closes on the panel's close button only."""
    held, _ = wired_dwell(DOORS, error_m=0.0, wcc=((0.0, True, False, False),), until_s=60.0)
    assert held.start_enable_s is None and held.fault is None  # standing, doors closed
    assert all(u in LOCKED_STATES for u in held.cpcs.side(Side.R))
    train, platform = wired_dwell(
        DOORS,
        error_m=0.0,
        wcc=((0.0, True, False, False), (10.0, True, True, False), (40.0, True, False, True)),
    )
    assert train.start_enable_s is not None and train.start_enable_s > 40.0
    events = [e["ev"] for e in platform.events]
    assert events[:3] == ["wcc-manual", "psc", "psd-open"]
    assert platform.events[0]["wcc"] == "manual"
    assert "psd-locked" in events


def test_wcc_back_to_automatic() -> None:
    train, platform = wired_dwell(
        DOORS, error_m=0.0, wcc=((0.0, True, False, False), (5.0, False, False, False))
    )
    assert train.start_enable_s is not None
    assert [e["ev"] for e in platform.events][:2] == ["wcc-manual", "psc"]
    assert "wcc-auto" in [e["ev"] for e in platform.events]


def test_status_and_command_travel_through_the_codec() -> None:
    train, platform = wired_dwell(DOORS, error_m=0.0)
    cmd = train.command()
    assert decode(encode(cmd)) == cmd
    status = platform.status()
    assert decode(encode(status)) == status
    assert unpack_stop_sensed(pack_stop_sensed(3, 2, -0.125)) == (3, 2, -0.125)
    with pytest.raises(ValueError):
        unpack_stop_sensed(b"\x00" * 3)
    assert math.isnan(unpack_stop_sensed(pack_stop_sensed(3, 2, math.nan))[2])


def _run(train: TrainDoors, platform: PlatformDoors, t0: float, until_s: float) -> list[tuple[float, bool]]:
    """Train and platform wired, from ``t0`` to ``until_s`` or the dwell's end; each step's (time,
    moved while a train door was not locked)."""
    out = []

    def observe(t: float, moved: float) -> None:
        unlocked = not all(u in LOCKED_STATES for s in (Side.L, Side.R) for u in train.cpcs.side(s))
        out.append((t, moved != 0.0 and unlocked))

    run_wired(train, platform, t0_s=t0, step_s=0.01, until_s=until_s, observe=observe)
    return out


def test_after_a_fault_with_doors_open_the_next_dwell_closes_them_before_it_creeps() -> None:
    """A dwell ends in the link-lost fault with the train's doors open; the train's next dwell there
    (after the staff's reset) starts from those doors. Out of position, the correction creep waits
    until every train door is closed and locked (the traction interlock), then the train moves."""
    model = model_for(DOORS)
    first, _ = wired_dwell(DOORS, error_m=0.0, platform_silent_after_s=10.0)
    assert first.fault is not None
    assert any(u == DoorState.OPEN for u in first.cpcs.side(Side.R))
    platform = PlatformDoors(index=0, name="P", side=Side.R, doors=DOORS, model=model)
    again = TrainDoors(
        train=1, station=0, station_name="P", side=Side.R, error_m=0.8, doors=DOORS, model=model,
        t0_s=100.0, carried=first.cpcs,
    )  # fmt: skip
    steps = _run(again, platform, 100.0, 300.0)
    assert not any(bad for _, bad in steps), "the train moved with a door open"
    assert again.corrections == 1 and again.start_enable_s is not None
    assert abs(again.error_m) <= DOORS.stop_confirm.tolerance_m


def test_after_a_fault_in_position_the_next_dwell_goes_on_from_open_doors() -> None:
    model = model_for(DOORS)
    first, _ = wired_dwell(DOORS, error_m=0.0, platform_silent_after_s=10.0)
    platform = PlatformDoors(index=0, name="P", side=Side.R, doors=DOORS, model=model)
    # The platform's PSD is open too (it held it as it was).
    platform.state = platform.state._replace(units=(DoorState.OPEN,) * len(platform.state.units))
    again = TrainDoors(
        train=1, station=0, station_name="P", side=Side.R, error_m=0.0, doors=DOORS, model=model,
        t0_s=100.0, carried=first.cpcs,
    )  # fmt: skip
    _run(again, platform, 100.0, 300.0)
    assert again.start_enable_s is not None and again.corrections == 0
    assert all(u in LOCKED_STATES for u in platform.state.units)


def test_a_psd_unit_that_jams_withholds_start_enable_until_the_staff_isolate_it() -> None:
    """Fault injection: PSD unit 3 fails to close. The WPCS reports the PSD not closed and locked,
    so the train gets no start enable (SPEC §5 fig. 7) until the staff isolate the unit."""
    train, platform = wired_dwell(DOORS, error_m=0.0, psd_jam=3, step_s=0.01)
    assert train.start_enable_s is not None
    events = [(e["ev"], e.get("unit")) for e in platform.events]
    assert ("psd-jam", 3) in events and ("psd-isolated", 3) in events
    jammed = next(e["t_s"] for e in platform.events if e["ev"] == "psd-jam")
    assert train.start_enable_s >= jammed + DOORS.timing.staff_isolation_s
    assert platform.state.units[2] == DoorState.ISOLATED
    with pytest.raises(ValueError, match="PSD unit 25"):
        platform.jam(24)


@pytest.mark.parametrize("error_m", [0.0, 0.8])
def test_manual_driving_is_slower_than_the_atc(error_m: float) -> None:
    """The driver's dwell (SPEC §5 manual column: door-side selector, open and close buttons, each a
    moment after its cue): the same corrections as the ATC's, start enable later."""
    train, platform = wired_dwell(DOORS, error_m=error_m, manual=True, step_s=0.01)
    auto, _ = wired_dwell(DOORS, error_m=error_m, step_s=0.01)
    assert train.start_enable_s is not None and auto.start_enable_s is not None
    assert train.corrections == auto.corrections and train.psc_requests == auto.psc_requests
    assert train.start_enable_s > auto.start_enable_s + DOORS.timing.driver_action_s  # the driver is slower
    assert [e["ev"] for e in platform.events] == ["psc", "psd-open", "psd-locked", "psc-off"]


def test_an_obstructed_train_door_withholds_start_enable_until_it_is_cleared() -> None:
    """Fault injection: train door 2 on the platform side meets an obstacle while closing; it
    reopens and holds until the obstacle is cleared, then closes; start enable only then."""
    train, _ = wired_dwell(DOORS, error_m=0.0, obstruct=2, step_s=0.01)
    plain, _ = wired_dwell(DOORS, error_m=0.0, step_s=0.01)
    assert train.start_enable_s is not None and plain.start_enable_s
    assert train.start_enable_s > plain.start_enable_s + DOORS.timing.obstruction_clear_s
    assert any(what == "door 2 obstructed" for _, what in train.events)
