"""SPEC §4 step 5: the operator's manual release travels only in a keyed (category 3) safety frame."""

from __future__ import annotations

import hashlib

from railstop.link.release_link import OperatorConsole, ReleaseGate, release_key
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
