"""The door units of SPEC §5: action table, door unit, CPCS, WPCS, precise-stop confirmation."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railstop.config.doors import Action, ActionRow, ActionTable, load_doors
from railstop.control.doors import (
    DOOR_TRANSITIONS,
    LOCKED_STATES,
    DoorInput,
    DoorSignals,
    DoorState,
    Interlocks,
    PsdReport,
    Side,
    door_next,
)
from railstop.errors import ConfigError, InterlockError
from railstop.nodes.doors import (
    Controls,
    DoorModel,
    Event,
    EventKind,
    World,
    start_blockers,
    start_enabled,
    step,
)
from railstop.onboard import cpcs
from railstop.onboard.cpcs import Cpcs, CpcsState
from railstop.onboard.stop_confirm import (
    STOP_TRANSITIONS,
    StopConfirm,
    StopConfirmState,
    StopInput,
    StopPhase,
)
from railstop.onboard.stop_confirm import step as stop_step
from railstop.wayside import wpcs
from railstop.wayside.wpcs import TrainReport, Wpcs, WpcsState, answers_psc

DS = DoorState
DI = DoorInput
CFG = load_doors()
ACTIONS = CFG.actions
MODEL = DoorModel(actions=ACTIONS, max_psc_attempts=CFG.stop_confirm.max_psc_attempts)

# SPEC §5 Table 1 as printed in the spec, written out by hand:
# (DOA, DMC, DOC, DCC) -> (door now closed, door now open, door now open in manual mode).
SPEC_TABLE: dict[tuple[int, int, int, int], tuple[str, str, str]] = {
    (1, 1, 1, 1): ("keep-closed", "close", "close"),
    (1, 1, 1, 0): ("keep-closed", "keep-open", "keep-open"),
    (1, 1, 0, 1): ("keep-closed", "close", "close"),
    (1, 1, 0, 0): ("keep-closed", "keep-open", "keep-open"),
    (1, 0, 1, 1): ("open", "keep-open", "keep-open"),
    (1, 0, 1, 0): ("open", "keep-open", "keep-open"),
    (1, 0, 0, 1): ("keep-closed", "keep-open", "keep-open"),
    (1, 0, 0, 0): ("keep-closed", "keep-open", "keep-open"),
    (0, 1, 1, 1): ("keep-closed", "close", "close"),
    (0, 1, 1, 0): ("keep-closed", "keep-open", "keep-open"),
    (0, 1, 0, 1): ("keep-closed", "close", "close"),
    (0, 1, 0, 0): ("keep-closed", "keep-open", "keep-open"),
    (0, 0, 1, 1): ("keep-closed", "keep-open", "keep-open"),
    (0, 0, 1, 0): ("keep-closed", "keep-open", "keep-open"),
    (0, 0, 0, 1): ("keep-closed", "keep-open", "close"),
    (0, 0, 0, 0): ("keep-closed", "keep-open", "keep-open"),
}

ALL_SIGNALS = [DoorSignals(*bits) for bits in itertools.product((False, True), repeat=6)]


def confirmed_world(n: int = 1, side: Side = Side.R) -> World:
    """A train at standstill in position with PSC high, everything closed and locked."""
    w = World.arriving(platform_side=side, doors_per_side=n)
    return w._replace(
        moving=False, in_position=True, stop=StopConfirmState(phase=StopPhase.CONFIRMED, failed=0)
    )


def open_signals(side: Side = Side.R) -> DoorSignals:
    return DoorSignals().with_side(side, doa=True, dmc=False)._replace(doc=True)


def close_signals(side: Side = Side.R) -> DoorSignals:
    return DoorSignals().with_side(side, doa=True, dmc=True)._replace(dcc=True)


# -- the action table as data -----------------------------------------------------


def test_action_table_rows_equal_the_spec_table() -> None:
    got = {r.key: (r.closed.value, r.open.value, (r.open_manual or r.open).value) for r in ACTIONS.rows}
    assert got == SPEC_TABLE
    assert len(ACTIONS.rows) == 16


def test_table_decide_reads_the_rows_as_they_are() -> None:
    for (doa, dmc, doc, dcc), (closed, when_open, when_open_manual) in SPEC_TABLE.items():
        sig = (bool(doa), bool(dmc), bool(doc), bool(dcc))
        assert ACTIONS.decide(*sig, closed=True, manual=False).value == closed
        assert ACTIONS.decide(*sig, closed=True, manual=True).value == closed
        assert ACTIONS.decide(*sig, closed=False, manual=False).value == when_open
        assert ACTIONS.decide(*sig, closed=False, manual=True).value == when_open_manual


def test_interpretation_note_is_kept_in_the_data_file() -> None:
    text = (Path(__file__).parents[2] / "src/railstop/data/doors.toml").read_text(encoding="utf-8")
    assert "[interpretation]" in text
    assert "(0,1,1,0)" in text and "transcription error" in text


def test_a_replaced_row_is_used_as_written() -> None:
    # The table is data: a different row changes what the doors do (the verifier catches it).
    broken = ACTIONS.replace_row(
        ActionRow(doa=0, dmc=1, doc=1, dcc=0, closed=Action.OPEN, open=Action.KEEP_OPEN)
    )
    assert broken.decide(False, True, True, False, closed=True, manual=False) == Action.OPEN
    assert ACTIONS.decide(False, True, True, False, closed=True, manual=False) == Action.KEEP_CLOSED


def test_action_table_object_needs_all_sixteen_rows() -> None:
    with pytest.raises(ConfigError, match="16 combinations"):
        ActionTable(ACTIONS.rows[:15])
    with pytest.raises(ConfigError, match="16 combinations"):
        ActionTable((*ACTIONS.rows[:15], ACTIONS.rows[0]))
    with pytest.raises(ConfigError, match="open"):
        ActionTable(
            tuple(
                ActionRow(doa=r.doa, dmc=r.dmc, doc=r.doc, dcc=r.dcc, closed=Action.CLOSE, open=r.open)
                if r.key == (1, 1, 1, 1)
                else r
                for r in ACTIONS.rows
            )
        )


def test_doors_config_loader_errors_name_file_field_value(tmp_path: Path) -> None:
    src = (Path(__file__).parents[2] / "src/railstop/data/doors.toml").read_text(encoding="utf-8")
    dup = tmp_path / "dup.toml"
    dup.write_text(
        src.replace(
            '{ doa = 0, dmc = 0, doc = 0, dcc = 0, closed = "keep-closed", open = "keep-open" }',
            '{ doa = 1, dmc = 0, doc = 1, dcc = 0, closed = "open", open = "keep-open" }',
        )
    )
    with pytest.raises(ConfigError) as info:
        load_doors(dup)
    assert str(dup) in str(info.value) and "action_table" in str(info.value) and "repeats" in str(info.value)
    slow = tmp_path / "slow.toml"
    slow.write_text(src.replace("psd_open_s = 2.0", "psd_open_s = 3.5"))
    with pytest.raises(ConfigError) as info:
        load_doors(slow)
    assert "timing.psd_open_s" in str(info.value) and "3.5" in str(info.value)
    typo = tmp_path / "typo.toml"
    typo.write_text(src.replace("dwell_s = 20.0", "dwell_s = 20.0\ndwel_s = 20.0"))
    with pytest.raises(ConfigError, match="unknown key"):
        load_doors(typo)
    bad_cell = tmp_path / "cell.toml"
    bad_cell.write_text(
        src.replace('closed = "keep-closed", open = "close" }', 'closed = "close", open = "close" }', 1)
    )
    with pytest.raises(ConfigError, match=r"action_table\[0\]\.closed"):
        load_doors(bad_cell)


def test_tolerance_choice_is_data() -> None:
    sc = CFG.stop_confirm
    assert sc.tolerance == "psd" and sc.tolerance_m == 0.35
    assert sc.manual_line_tolerance_m == 0.50
    assert sc.model_copy(update={"tolerance": "manual-line"}).tolerance_m == 0.50
    assert answers_psc(0.35, 0.35) and answers_psc(-0.35, 0.35)
    assert not answers_psc(0.351, 0.35) and not answers_psc(-0.4, 0.35)


def test_psd_is_faster_than_train_doors() -> None:
    t = CFG.timing
    assert t.psd_open_s < t.train_door_open_s and t.psd_close_s < t.train_door_close_s


# -- the door unit --------------------------------------------------------------------


def test_door_unit_normal_cycle() -> None:
    s = DS.CLOSED_LOCKED
    for inp, expected in (
        (DI.OPEN, DS.OPENING),
        (DI.DONE, DS.OPEN),
        (DI.CLOSE, DS.CLOSING),
        (DI.DONE, DS.CLOSED),
        (DI.DONE, DS.CLOSED_LOCKED),
    ):
        s = door_next(s, inp)
        assert s == expected


def test_door_unit_obstruction_jam_isolation() -> None:
    assert door_next(DS.CLOSING, DI.OBSTRUCT) == DS.OBSTRUCTED
    # Cleared: open again, waiting for the controller's next close command.
    assert door_next(DS.OBSTRUCTED, DI.CLEAR) == DS.OPEN
    assert door_next(DS.OBSTRUCTED, DI.ISOLATE) == DS.ISOLATED
    assert door_next(DS.CLOSING, DI.JAM) == DS.JAMMED
    assert door_next(DS.JAMMED, DI.ISOLATE) == DS.ISOLATED
    with pytest.raises(InterlockError, match="isolate"):
        door_next(DS.OPEN, DI.ISOLATE)  # staff isolate only a failed unit
    with pytest.raises(InterlockError, match="'open'"):
        door_next(DS.ISOLATED, DI.OPEN)


@given(st.sampled_from(list(DoorState)), st.sampled_from(list(DoorInput)))
def test_every_door_state_input_pair(state: DoorState, inp: DoorInput) -> None:
    if (state, inp) in DOOR_TRANSITIONS:
        assert door_next(state, inp) == DOOR_TRANSITIONS[(state, inp)]
    else:
        with pytest.raises(InterlockError, match=state.value):
            door_next(state, inp)


@given(st.sampled_from(list(DoorState)), st.sampled_from(list(DoorInput)), st.integers(0, 2))
def test_every_pair_through_the_cpcs_object(state: DoorState, inp: DoorInput, unit: int) -> None:
    unit_cpcs = Cpcs(doors_per_side=3, actions=ACTIONS)
    units = list(unit_cpcs.state.right)
    units[unit] = state
    unit_cpcs.state = unit_cpcs.state._replace(right=tuple(units))
    if (state, inp) in DOOR_TRANSITIONS:
        after = unit_cpcs.door_event(Side.R, unit, inp)
        assert after.right[unit] == DOOR_TRANSITIONS[(state, inp)] and not after.fault
    else:
        with pytest.raises(InterlockError, match=f"train door R{unit + 1}"):
            unit_cpcs.door_event(Side.R, unit, inp)
        # DESIGN rule 7: the safe state (fault: held closed, no start enable).
        assert unit_cpcs.state.fault
        assert unit_cpcs.state.right[unit] == state  # a door does not jump


@given(st.sampled_from(list(DoorState)), st.sampled_from(list(DoorInput)))
def test_every_pair_through_the_wpcs_object(state: DoorState, inp: DoorInput) -> None:
    unit_wpcs = Wpcs(side=Side.L, units=2, actions=ACTIONS)
    unit_wpcs.state = unit_wpcs.state._replace(units=(DS.CLOSED_LOCKED, state))
    if (state, inp) in DOOR_TRANSITIONS:
        assert unit_wpcs.door_event(1, inp).units[1] == DOOR_TRANSITIONS[(state, inp)]
    else:
        with pytest.raises(InterlockError, match="PSD L2"):
            unit_wpcs.door_event(1, inp)
        assert unit_wpcs.state.fault


# -- CPCS and WPCS rules ---------------------------------------------------------------


@settings(max_examples=300)
@given(
    st.sampled_from(ALL_SIGNALS),
    st.booleans(),
    st.booleans(),
    st.lists(st.sampled_from(list(DoorState)), min_size=2, max_size=2),
    st.lists(st.sampled_from(list(DoorState)), min_size=2, max_size=2),
    st.lists(st.sampled_from(list(DoorState)), min_size=2, max_size=2),
    st.sampled_from([Side.L, Side.R]),
)
def test_cpcs_never_opens_without_authority_psd_or_at_speed(
    signals: DoorSignals,
    manual: bool,
    zero_speed: bool,
    left: list[DoorState],
    right: list[DoorState],
    psd_units: list[DoorState],
    psd_side: Side,
) -> None:
    # Any state, reachable or not: a door that starts opening had DOA=1, DMC=0, zero speed
    # and the PSD opposite it open.
    before = CpcsState(left=tuple(left), right=tuple(right))
    psd = PsdReport(side=psd_side, units=tuple(psd_units))
    try:
        after = cpcs.scan(before, signals, manual=manual, zero_speed=zero_speed, psd=psd, actions=ACTIONS)
    except InterlockError:
        return  # an invalid command is refused (the real table never gives one: see the verifier)
    for side in (Side.L, Side.R):
        for i, (u0, u1) in enumerate(zip(before.side(side), after.side(side), strict=True)):
            if u1 == DS.OPENING and u0 != DS.OPENING:
                assert signals.doa(side) and not signals.dmc(side) and zero_speed
                assert side == psd_side and psd_units[i] == DS.OPEN


@settings(max_examples=300)
@given(
    st.sampled_from(ALL_SIGNALS),
    st.booleans(),
    st.booleans(),
    st.booleans(),
    st.booleans(),
    st.lists(st.sampled_from(list(DoorState)), min_size=2, max_size=2),
    st.lists(st.sampled_from(list(DoorState)), min_size=2, max_size=2),
)
def test_wpcs_never_opens_without_authority_nor_closes_on_open_train_doors(
    signals: DoorSignals,
    manual: bool,
    wcc_manual: bool,
    panel_open: bool,
    panel_close: bool,
    units: list[DoorState],
    train_doors: list[DoorState],
) -> None:
    before = WpcsState(side=Side.L, units=tuple(units))
    report = TrainReport(signals=signals, manual=manual, doors=tuple(train_doors))
    try:
        after = wpcs.scan(
            before,
            report,
            wcc_manual=wcc_manual,
            panel_open=panel_open,
            panel_close=panel_close,
            actions=ACTIONS,
        )
    except InterlockError:
        return
    for u0, u1 in zip(before.units, after.units, strict=True):
        if u1 == DS.OPENING and u0 != DS.OPENING:
            assert signals.doa_l and not signals.dmc_l
        if u1 == DS.CLOSING and u0 != DS.CLOSING:
            assert all(d in LOCKED_STATES for d in train_doors)
    # No PSC, no data exchange: the PSD is held as it is.
    assert (
        wpcs.scan(before, None, wcc_manual=wcc_manual, panel_open=True, panel_close=True, actions=ACTIONS)
        == before
    )


def test_zvr_holds_doors_closed_while_moving() -> None:
    state = CpcsState.closed(2)
    psd = PsdReport(side=Side.R, units=(DS.OPEN, DS.OPEN))
    sig = open_signals()  # DMC-R = 0: the ATC "forgot" DMC; the ZVR contact holds the doors
    moving = cpcs.scan(state, sig, manual=False, zero_speed=False, psd=psd, actions=ACTIONS)
    assert moving.right == (DS.CLOSED_LOCKED, DS.CLOSED_LOCKED)
    standing = cpcs.scan(state, sig, manual=False, zero_speed=True, psd=psd, actions=ACTIONS)
    assert standing.right == (DS.OPENING, DS.OPENING)
    # Without the ZVR wiring the same inputs would open the doors at speed.
    no_zvr = cpcs.scan(
        state, sig, manual=False, zero_speed=False, psd=psd, actions=ACTIONS, interlocks=Interlocks(zvr=False)
    )
    assert no_zvr.right == (DS.OPENING, DS.OPENING)


def test_dmc_overrides_doa_doc_dcc() -> None:
    psd = PsdReport(side=Side.R, units=(DS.OPEN,))
    for sig in ALL_SIGNALS:
        for manual in (False, True):
            after = cpcs.scan(
                CpcsState.closed(1), sig, manual=manual, zero_speed=True, psd=psd, actions=ACTIONS
            )
            opened = after.right[0] == DS.OPENING
            assert opened == (sig.doa_r and not sig.dmc_r and sig.doc)
            assert after.left[0] == DS.CLOSED_LOCKED  # no PSD on the left: never opens


def test_only_the_platform_side_opens() -> None:
    both = DoorSignals(doa_l=True, doa_r=True, dmc_l=False, dmc_r=False, doc=True)
    w = confirmed_world(side=Side.L)
    w, _ = step(w, Controls(signals=both), Event(EventKind.NONE), MODEL)
    w, _ = step(w, Controls(signals=both), Event(EventKind.PSD, Side.L, 0, DI.DONE), MODEL)
    assert w.cpcs.left == (DS.OPENING,)
    assert w.cpcs.right == (DS.CLOSED_LOCKED,)


def test_opening_order_psd_first_then_train_doors() -> None:
    c = Controls(signals=open_signals())
    w, _ = step(confirmed_world(2), c, Event(EventKind.NONE), MODEL)
    assert w.wpcs.units == (DS.OPENING, DS.OPENING)
    assert w.cpcs.right == (DS.CLOSED_LOCKED, DS.CLOSED_LOCKED)  # waits for the PSD
    w, _ = step(w, c, Event(EventKind.PSD, Side.R, 0, DI.DONE), MODEL)
    assert w.cpcs.right == (DS.OPENING, DS.CLOSED_LOCKED)  # door 1 faces an open PSD unit; door 2 not yet
    w, _ = step(w, c, Event(EventKind.PSD, Side.R, 1, DI.DONE), MODEL)
    assert w.cpcs.right == (DS.OPENING, DS.OPENING)


def test_closing_order_train_doors_first_then_psd() -> None:
    w = confirmed_world(1)
    w = w._replace(cpcs=w.cpcs._replace(right=(DS.OPEN,)), wpcs=w.wpcs._replace(units=(DS.OPEN,)))
    c = Controls(signals=close_signals())
    w, _ = step(w, c, Event(EventKind.NONE), MODEL)
    assert w.cpcs.right == (DS.CLOSING,) and w.wpcs.units == (DS.OPEN,)
    w, _ = step(w, c, Event(EventKind.TRAIN_DOOR, Side.R, 0, DI.DONE), MODEL)
    assert w.cpcs.right == (DS.CLOSED,) and w.wpcs.units == (DS.OPEN,)  # closed but not locked yet
    w, _ = step(w, c, Event(EventKind.TRAIN_DOOR, Side.R, 0, DI.DONE), MODEL)
    assert w.cpcs.right == (DS.CLOSED_LOCKED,) and w.wpcs.units == (DS.CLOSING,)
    assert not start_enabled(w, MODEL)
    w, _ = step(w, c, Event(EventKind.PSD, Side.R, 0, DI.DONE), MODEL)
    w, _ = step(w, c, Event(EventKind.PSD, Side.R, 0, DI.DONE), MODEL)
    assert w.wpcs.units == (DS.CLOSED_LOCKED,) and start_enabled(w, MODEL)


def test_manual_close_button_closes_on_its_own() -> None:
    w = confirmed_world(1)
    w = w._replace(cpcs=w.cpcs._replace(right=(DS.OPEN,)), wpcs=w.wpcs._replace(units=(DS.OPEN,)))
    button = DoorSignals(dmc_l=True, dmc_r=False, dcc=True)  # selector off, DMC-R released
    auto, _ = step(w, Controls(signals=button, manual=False), Event(EventKind.NONE), MODEL)
    assert auto.cpcs.right == (DS.OPEN,)
    manual, _ = step(w, Controls(signals=button, manual=True), Event(EventKind.NONE), MODEL)
    assert manual.cpcs.right == (DS.CLOSING,)


def test_wcc_manual_panel_opens_and_closes_the_psd_under_the_interlocks() -> None:
    sig = DoorSignals().with_side(Side.R, doa=True, dmc=False)  # no DOC from the train
    panel_open = Controls(signals=sig, wcc_manual=True, panel_open=True)
    w, _ = step(confirmed_world(1), panel_open, Event(EventKind.NONE), MODEL)
    assert w.wpcs.units == (DS.OPENING,)
    # DMC high from the train: the panel cannot open.
    w2, _ = step(
        confirmed_world(1),
        panel_open._replace(signals=sig.with_side(Side.R, dmc=True)),
        Event(EventKind.NONE),
        MODEL,
    )
    assert w2.wpcs.units == (DS.CLOSED_LOCKED,)


def test_obstruction_withholds_start_enable_and_names_the_door() -> None:
    w = confirmed_world(3)
    w = w._replace(cpcs=w.cpcs._replace(right=(DS.CLOSED_LOCKED, DS.OBSTRUCTED, DS.CLOSED_LOCKED)))
    assert not start_enabled(w, MODEL)
    assert start_blockers(w, MODEL) == ("train door R2 obstructed",)
    # Staff isolation: closed and locked by hand, out of the loop: start enable.
    isolated, _ = step(w, Controls(), Event(EventKind.TRAIN_DOOR, Side.R, 1, DI.ISOLATE), MODEL)
    assert start_enabled(isolated, MODEL) and start_blockers(isolated, MODEL) == ()
    # Cleared instead: the door stands open, closes on the next close command, then locks.
    c = Controls(signals=close_signals())
    cleared, _ = step(w, c, Event(EventKind.TRAIN_DOOR, Side.R, 1, DI.CLEAR), MODEL)
    assert cleared.cpcs.right[1] == DS.CLOSING
    assert start_blockers(cleared, MODEL) == ("train door R2 closing",)


def test_failed_psd_unit_withholds_start_enable_until_isolated() -> None:
    w = confirmed_world(4)
    w = w._replace(
        wpcs=w.wpcs._replace(units=(DS.CLOSED_LOCKED, DS.CLOSED_LOCKED, DS.JAMMED, DS.CLOSED_LOCKED))
    )
    assert start_blockers(w, MODEL) == ("PSD R3 jammed",)
    w, _ = step(w, Controls(), Event(EventKind.PSD, Side.R, 2, DI.ISOLATE), MODEL)
    assert w.wpcs.units[2] == DS.ISOLATED and start_enabled(w, MODEL)
    # The train door facing an isolated PSD unit never opens.
    c = Controls(signals=open_signals())
    w, _ = step(w, c, Event(EventKind.NONE), MODEL)
    for i in (0, 1, 3):
        w, _ = step(w, c, Event(EventKind.PSD, Side.R, i, DI.DONE), MODEL)
    assert w.cpcs.right == (DS.OPENING, DS.OPENING, DS.CLOSED_LOCKED, DS.OPENING)


def test_start_enable_needs_psc() -> None:
    w = confirmed_world(1)
    assert start_enabled(w, MODEL)
    waiting = w._replace(stop=StopConfirmState(phase=StopPhase.PSC_WAIT))
    assert not start_enabled(waiting, MODEL)
    assert any("no PSC" in b for b in start_blockers(waiting, MODEL))


def test_cleared_psd_obstruction_does_not_close_past_an_opening_train_door() -> None:
    # Found by `railstop doors verify --doors-per-side 2`: a PSD unit that resumed closing on its
    # own after an obstruction closed while a train door of its side was opening.
    w = confirmed_world(2, side=Side.L)
    w = w._replace(
        cpcs=w.cpcs._replace(left=(DS.OPENING, DS.CLOSED_LOCKED)),
        wpcs=w.wpcs._replace(units=(DS.OPEN, DS.OBSTRUCTED)),
    )
    sig = DoorSignals().with_side(Side.L, doa=True, dmc=False)._replace(doc=True)
    after, errors = step(w, Controls(signals=sig), Event(EventKind.PSD, Side.L, 1, DI.CLEAR), MODEL)
    assert not errors
    assert after.wpcs.units[1] != DS.CLOSING


# -- precise-stop confirmation ----------------------------------------------------------------


def test_psc_reply_confirms() -> None:
    unit = StopConfirm()
    assert unit.handle(StopInput.STANDSTILL).psc_request
    s = unit.handle(StopInput.PSC_REPLY)
    assert s.psc and s.attempts == 1 and not s.emergency_brake


def test_three_attempts_without_psc_fault_and_emergency_brake() -> None:
    unit = StopConfirm(max_attempts=3)
    unit.handle(StopInput.STANDSTILL)
    for attempt in (1, 2):
        s = unit.handle(StopInput.PSC_TIMEOUT)
        assert s.phase == StopPhase.CORRECTING and s.creep and s.failed == attempt
        s = unit.handle(StopInput.STANDSTILL)
        assert s.psc_request and s.attempts == attempt + 1
    s = unit.handle(StopInput.PSC_TIMEOUT)
    assert s.phase == StopPhase.FAULT and s.emergency_brake and s.attempts == 3


def test_correction_then_reply() -> None:
    unit = StopConfirm()
    for inp in (StopInput.STANDSTILL, StopInput.PSC_TIMEOUT, StopInput.STANDSTILL, StopInput.PSC_REPLY):
        s = unit.handle(inp)
    assert s.psc and s.attempts == 2
    assert unit.handle(StopInput.DEPART) == StopConfirmState()  # the next stop starts afresh


@given(st.sampled_from(list(StopPhase)), st.integers(0, 3), st.sampled_from(list(StopInput)))
def test_every_stop_phase_input_pair(phase: StopPhase, failed: int, inp: StopInput) -> None:
    unit = StopConfirm(max_attempts=3)
    unit.state = StopConfirmState(phase=phase, failed=failed)
    key = StopInput.PSC_TIMEOUT_LAST if inp == StopInput.PSC_TIMEOUT and failed + 1 >= 3 else inp
    if (phase, key) in STOP_TRANSITIONS:
        assert unit.handle(inp).phase == STOP_TRANSITIONS[(phase, key)]
    else:
        with pytest.raises(InterlockError, match=phase.value):
            unit.handle(inp)
        # DESIGN rule 7: the unit's safe state is the fault with emergency brake.
        assert unit.state.phase == StopPhase.FAULT and unit.state.emergency_brake


def test_invalid_input_to_the_cpcs_safe_state_then_nothing_opens() -> None:
    unit = Cpcs(doors_per_side=1, actions=ACTIONS)
    with pytest.raises(InterlockError, match="train door R1"):
        unit.door_event(Side.R, 0, DI.DONE)  # a "done" for a door that is not moving
    assert unit.state.fault
    psd = PsdReport(side=Side.R, units=(DS.OPEN,))
    assert unit.scan(open_signals(), manual=False, zero_speed=True, psd=psd).right == (DS.CLOSED_LOCKED,)
    enable = unit.start_enable(psd, psc=True)
    assert not enable.enabled and "CPCS fault" in enable.blockers
    with pytest.raises(InterlockError, match="doors_per_side"):
        Cpcs(doors_per_side=0, actions=ACTIONS)


def test_invalid_input_to_the_wpcs_safe_state_then_nothing_opens() -> None:
    unit = Wpcs(side=Side.R, units=1, actions=ACTIONS)
    with pytest.raises(InterlockError, match="PSD R1"):
        unit.door_event(0, DI.CLEAR)
    assert unit.state.fault
    report = TrainReport(signals=open_signals(), manual=False, doors=(DS.CLOSED_LOCKED,))
    assert unit.scan(report).units == (DS.CLOSED_LOCKED,)
    assert not cpcs.start_enabled(CpcsState.closed(1), unit.state.report(), psc=True, emergency_brake=False)


def test_invalid_event_in_the_wired_system_goes_safe_and_reports() -> None:
    w = confirmed_world(1)
    after, errors = step(w, Controls(), Event(EventKind.TRAIN_DOOR, Side.R, 0, DI.DONE), MODEL)
    assert errors and "train door R1" in errors[0]
    assert after.cpcs.fault and not start_enabled(after, MODEL)
    after, errors = step(w, Controls(), Event(EventKind.PSC_REPLY), MODEL)  # no request pending
    assert errors and after.stop.phase == StopPhase.FAULT


@settings(max_examples=200)
@given(
    st.lists(st.sampled_from(list(DoorState)), min_size=2, max_size=2),
    st.lists(st.sampled_from(list(DoorState)), min_size=2, max_size=2),
    st.lists(st.sampled_from(list(DoorState)), min_size=2, max_size=2),
    st.sampled_from(list(StopPhase)),
    st.booleans(),
    st.booleans(),
)
def test_start_enabled_agrees_with_its_blockers(
    left: list[DoorState],
    right: list[DoorState],
    psd_units: list[DoorState],
    phase: StopPhase,
    cpcs_fault: bool,
    wpcs_fault: bool,
) -> None:
    w = World(
        moving=False,
        in_position=True,
        stop=StopConfirmState(phase=phase),
        cpcs=CpcsState(left=tuple(left), right=tuple(right), fault=cpcs_fault),
        wpcs=WpcsState(side=Side.R, units=tuple(psd_units), fault=wpcs_fault),
    )
    assert start_enabled(w, MODEL) == (start_blockers(w, MODEL) == ())
    if start_enabled(w, MODEL):
        assert all(u in LOCKED_STATES for u in (*left, *right, *psd_units)) and phase == StopPhase.CONFIRMED


def test_stop_step_rejects_a_nonsense_attempt_count() -> None:
    with pytest.raises(InterlockError, match="max_attempts"):
        stop_step(StopConfirmState(), StopInput.STANDSTILL, max_attempts=0)
