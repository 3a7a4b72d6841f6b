"""The exhaustive check of the SPEC §3 platform interlock: the real platform unit and PSD control,
every event, and each invariant shown catching a broken unit or control."""

from __future__ import annotations

import pytest

from railstop.config.platform import load_platform
from railstop.messages import PlatformLamps, PsdCommand
from railstop.sim.platform_verify import INVARIANTS, verify
from railstop.wayside.platform import PlatformUnit, PsdFollower

DATA, _ = load_platform()
K = DATA.sensors.debounce_scans
C = DATA.camera.confirm_frames
# The search grows with the frames that make a camera lost; the tests take 2 (the count only
# matters at its limit), `railstop platform verify` the data's.
LOST = 2


def real() -> PlatformUnit:
    return PlatformUnit(lamp_table=DATA.lamps(), debounce_scans=K)


def control() -> PsdFollower:
    return PsdFollower(confirm_frames=C, lost_limit_frames=LOST)


def test_the_real_unit_and_control_hold_every_invariant_with_fewer_misses_than_they_confirm() -> None:
    r = verify(real, follower_factory=control, max_dropouts=K - 1)
    assert r.violations == 0, r.examples
    assert r.lamps_seen == ("F", "OK", "R", "S")  # the search reaches every lamp
    assert r.states > 10_000 and r.transitions > 5 * r.states


def test_as_many_misses_as_the_debounce_can_light_ok_for_an_overrun() -> None:
    """The bound is real: k misses of S1 in a row make an overrun look like a train in the window."""
    (inv,) = [i for i in INVARIANTS if i.name == "relay-only-on-ok"]
    r = verify(real, follower_factory=control, max_dropouts=K, invariants=[inv], stop_when_all_violated=True)
    assert r.counts["relay-only-on-ok"] > 0
    (example,) = r.examples
    assert example.trace[-K:] == ("scan (S1 missed)",) * K


def test_as_many_misreads_as_the_control_confirms_can_shut_the_psd_on_open_doors() -> None:
    """The camera's bound is real too: `confirm_frames` misread frames in a row confirm a shape
    the doors do not have."""
    (inv,) = [i for i in INVARIANTS if i.name == "psd-not-closed-on-open-doors"]
    r = verify(real, follower_factory=control, max_misreads=C, invariants=[inv], stop_when_all_violated=True)
    assert r.counts[inv.name] > 0
    (example,) = r.examples
    assert example.trace[-C:] == ("camera frame (misread)",) * C


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


class _IgnoresRelay(PsdFollower):
    """Follows the camera whether or not OK is lit."""

    def decide(self) -> PsdCommand:
        if self.shape is None:
            return self.command
        return PsdCommand(open=self.shape, camera_ok=self.camera_ok())


class _ClosesWhenLost(PsdFollower):
    """Shuts the PSD when it no longer sees the doors (instead of holding it)."""

    def decide(self) -> PsdCommand:
        if self.relay and not self.camera_ok():
            return PsdCommand(open=False, camera_ok=False)
        return super().decide()


BROKEN_UNITS = {
    "departure-psd-closed": _DepartsAnyway,
    "no-lamp-while-moving": _LampWhileMoving,
    "relay-only-on-ok": _RelayOnRDataclass,
}
BROKEN_CONTROLS = {
    "psd-command-only-on-ok": _IgnoresRelay,
    "psd-not-closed-on-open-doors": _ClosesWhenLost,
}


def test_every_invariant_has_a_broken_unit_or_control() -> None:
    assert set(BROKEN_UNITS) | set(BROKEN_CONTROLS) == {inv.name for inv in INVARIANTS}


@pytest.mark.parametrize("name", sorted(BROKEN_UNITS) + sorted(BROKEN_CONTROLS))
def test_each_invariant_catches_its_broken_unit_or_control(name: str) -> None:
    unit_cls = BROKEN_UNITS.get(name, PlatformUnit)
    control_cls = BROKEN_CONTROLS.get(name, PsdFollower)
    (inv,) = [i for i in INVARIANTS if i.name == name]
    r = verify(
        lambda: unit_cls(lamp_table=DATA.lamps(), debounce_scans=K),
        follower_factory=lambda: control_cls(confirm_frames=C, lost_limit_frames=LOST),
        max_dropouts=K - 1,
        invariants=[inv],
        stop_when_all_violated=True,
    )
    assert r.counts[name] > 0
    (example,) = r.examples
    assert example.message and example.trace


def test_a_control_that_trusts_one_frame_is_caught_by_a_single_misread() -> None:
    """The data's confirmation matters: confirm_frames = 1 lets one misread shut the PSD."""
    (inv,) = [i for i in INVARIANTS if i.name == "psd-not-closed-on-open-doors"]
    r = verify(
        real,
        follower_factory=lambda: PsdFollower(confirm_frames=1, lost_limit_frames=LOST),
        max_misreads=1,
        invariants=[inv],
        stop_when_all_violated=True,
    )
    assert r.counts[inv.name] > 0
    assert r.examples[0].trace[-1] == "camera frame (misread)"


def test_cli_platform_verify_exit_0_and_1(tmp_path: object) -> None:
    import subprocess
    import sys

    ok = subprocess.run(
        [sys.executable, "-m", "railstop.cli", "platform", "verify", "--lost-limit", str(LOST)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert ok.returncode == 0 and "violations: 0" in ok.stdout, ok.stderr
    bad = subprocess.run(
        [
            sys.executable,
            "-m",
            "railstop.cli",
            "platform",
            "verify",
            "--max-dropouts",
            str(K),
            "--lost-limit",
            "1",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert bad.returncode == 1 and "relay-only-on-ok: PSD relay energised" in bad.stdout
