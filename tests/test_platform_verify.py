"""The exhaustive check of the SPEC §3 platform interlock: the real unit, every event, and each
invariant shown catching a broken unit."""

from __future__ import annotations

import pytest

from railstop.config.platform import load_platform
from railstop.messages import PlatformLamps
from railstop.sim.platform_verify import INVARIANTS, verify
from railstop.wayside.platform import PlatformUnit

DATA, _ = load_platform()
K = DATA.sensors.debounce_scans


def real() -> PlatformUnit:
    return PlatformUnit(lamp_table=DATA.lamps(), debounce_scans=K)


def test_the_real_unit_holds_every_invariant_with_fewer_misses_than_the_debounce() -> None:
    r = verify(real, max_dropouts=K - 1)
    assert r.violations == 0, r.examples
    assert r.lamps_seen == ("F", "OK", "R", "S")  # the search reaches every lamp
    assert r.states > 1000 and r.transitions > 5 * r.states


def test_as_many_misses_as_the_debounce_can_light_ok_for_an_overrun() -> None:
    """The bound is real: k misses of S1 in a row make an overrun look like a train in the window."""
    r = verify(real, max_dropouts=K)
    assert r.counts["relay-only-on-ok"] > 0 and r.counts["departure-psd-closed"] == 0
    (example,) = [e for e in r.examples if e.invariant == "relay-only-on-ok"]
    assert example.trace[-K:] == ("scan (S1 missed)",) * K


class _DepartsAnyway(PlatformUnit):
    def lamps(self) -> PlatformLamps:
        return PlatformLamps(
            lamp=super().lamps().lamp, psd_enable=super().lamps().psd_enable, departure_permitted=True
        )


class _LampWhileMoving(PlatformUnit):
    def lamps(self) -> PlatformLamps:
        got = super().lamps()
        return (
            got
            if self.standstill
            else PlatformLamps(lamp="F", psd_enable=False, departure_permitted=got.departure_permitted)
        )


class _RelayOnRDataclass(PlatformUnit):
    def lamps(self) -> PlatformLamps:
        got = super().lamps()
        if got.lamp == "R":
            return PlatformLamps(lamp="R", psd_enable=True, departure_permitted=got.departure_permitted)
        return got


BROKEN = {
    "departure-psd-closed": _DepartsAnyway,
    "no-lamp-while-moving": _LampWhileMoving,
    "relay-only-on-ok": _RelayOnRDataclass,
}


def test_every_invariant_has_a_broken_unit() -> None:
    assert set(BROKEN) == {inv.name for inv in INVARIANTS}


@pytest.mark.parametrize("name", sorted(BROKEN))
def test_each_invariant_catches_its_broken_unit(name: str) -> None:
    cls = BROKEN[name]
    r = verify(lambda: cls(lamp_table=DATA.lamps(), debounce_scans=K), max_dropouts=K - 1)
    assert r.counts[name] > 0
    (example,) = [e for e in r.examples if e.invariant == name]
    assert example.message and example.trace


def test_cli_platform_verify_exit_0_and_1(tmp_path: object) -> None:
    import subprocess
    import sys

    ok = subprocess.run(
        [sys.executable, "-m", "railstop.cli", "platform", "verify"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert ok.returncode == 0 and "violations: 0" in ok.stdout, ok.stderr
    bad = subprocess.run(
        [sys.executable, "-m", "railstop.cli", "platform", "verify", "--max-dropouts", str(K)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert bad.returncode == 1 and "relay-only-on-ok: PSD relay energised" in bad.stdout
