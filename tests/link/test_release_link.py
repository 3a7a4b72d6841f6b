"""SPEC §4 step 5: the operator's manual release travels only in a keyed (category 3) safety frame."""

from __future__ import annotations

import hashlib

from railstop.link.codec import WccCommand
from railstop.link.release_link import (
    WCC_ADDRESS,
    OperatorConsole,
    ReleaseGate,
    WccGate,
    release_key,
    wcc_key,
)
from railstop.messages import ManualRelease


def test_a_genuine_release_is_delivered_once() -> None:
    console, gate = OperatorConsole(operator_id=4), ReleaseGate()
    frame = console.release(7, 100.0)
    assert gate.accept(frame, 100.2) == ManualRelease(train_id=7)
    # The same frame again (a replay) is refused and counted.
    assert gate.accept(frame, 100.4) is None
    assert gate.rejected == {"repeated": 1} and gate.accepted == 1


def test_a_release_with_another_key_is_refused() -> None:
    forger = OperatorConsole(key=release_key(hashlib.sha256(b"not the key").digest()))
    gate = ReleaseGate()
    assert gate.accept(forger.release(7, 10.0), 10.0) is None
    assert gate.rejected == {"bad_mac": 1} and gate.accepted == 0


def test_a_stale_or_damaged_release_is_refused() -> None:
    console, gate = OperatorConsole(), ReleaseGate(max_age_s=5.0)
    old = console.release(3, 0.0)
    assert gate.accept(old, 60.0) is None  # a minute old
    damaged = bytearray(console.release(3, 61.0))
    damaged[15] ^= 0x01
    assert gate.accept(bytes(damaged), 61.0) is None
    assert gate.rejected == {"stale": 1, "bad_mac": 1}
    assert gate.accept(console.release(3, 62.0), 62.0) == ManualRelease(train_id=3)


def _wcc_console(master: bytes | None = None) -> OperatorConsole:
    return OperatorConsole(key=wcc_key() if master is None else wcc_key(master), to=WCC_ADDRESS)


def test_a_genuine_wcc_command_is_delivered_once() -> None:
    console, gate = _wcc_console(), WccGate()
    frame = console.wcc(2, manual=True, panel_open=False, panel_close=True, now_s=5.0)
    got = gate.accept(frame, 5.1)
    assert got == WccCommand(station=2, manual=True, panel_open=False, panel_close=True, operator_id=1)
    assert gate.accept(frame, 5.2) is None  # a replay
    assert gate.rejected == {"repeated": 1} and gate.accepted == 1


def test_a_forged_or_misdirected_wcc_command_is_refused() -> None:
    gate = WccGate()
    forged = _wcc_console(hashlib.sha256(b"not the key").digest())
    assert gate.accept(forged.wcc(0, manual=True, panel_open=True, panel_close=False, now_s=1.0), 1.0) is None
    # A zone release sent to the stations' input: the release link's key, not the WCC's.
    assert gate.accept(OperatorConsole().release(3, 2.0), 2.0) is None
    assert gate.accepted == 0 and sum(gate.rejected.values()) == 2


def test_a_wcc_command_that_makes_no_sense_changes_nothing() -> None:
    """Fail safe: a panel button outside manual mode, or both buttons at once, is refused."""
    console, gate = _wcc_console(), WccGate()
    assert (
        gate.accept(console.wcc(1, manual=False, panel_open=True, panel_close=False, now_s=1.0), 1.0) is None
    )
    assert gate.accept(console.wcc(1, manual=True, panel_open=True, panel_close=True, now_s=2.0), 2.0) is None
    assert gate.rejected == {"inconsistent": 2} and gate.accepted == 0


def test_the_release_names_the_operator_who_sent_it() -> None:
    """Each release telegram carries the sending operator's id (the control room's login), and the
    zone controller's end records who released: not one fixed id for everyone."""
    console, gate = OperatorConsole(), ReleaseGate()
    for now_s, who in ((1.0, 7), (2.0, 12), (3.0, 7)):
        assert gate.accept(console.release(4, now_s, operator_id=who), now_s) == ManualRelease(train_id=4)
    assert gate.released_by == {7: 2, 12: 1}
    wcc_console, wcc_gate = _wcc_console(), WccGate()
    got = wcc_gate.accept(
        wcc_console.wcc(1, manual=True, panel_open=False, panel_close=False, now_s=1.0, operator_id=9), 1.0
    )
    assert got is not None and got.operator_id == 9 and wcc_gate.commanded_by == {9: 1}


def test_a_command_that_names_no_operator_is_refused() -> None:
    """Fail safe: operator id 0 (a login that may only view) never releases or switches anything."""
    console, gate = OperatorConsole(), ReleaseGate()
    assert gate.accept(console.release(4, 1.0, operator_id=0), 1.0) is None
    wcc_gate = WccGate()
    frame = _wcc_console().wcc(1, manual=True, panel_open=False, panel_close=False, now_s=1.0, operator_id=0)
    assert wcc_gate.accept(frame, 1.0) is None
    assert (
        gate.rejected == {"no-operator": 1} == wcc_gate.rejected and gate.accepted == wcc_gate.accepted == 0
    )
