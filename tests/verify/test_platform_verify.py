"""The exhaustive check of the SPEC §3 platform interlock: the real platform unit and PSD control,
every event, and each invariant shown catching a broken unit or control."""

from __future__ import annotations

import pytest

from railstop.config.platform import load_platform
from railstop.messages import PlatformLamps, PsdCommand
from railstop.verify.platform import CAMERA, INVARIANTS, verify
from railstop.wayside.platform import PlatformUnit, PsdFollower

DATA, _ = load_platform()
K = DATA.sensors.debounce_scans
C = DATA.camera.confirm_frames
L = DATA.camera.lock_frames
# The search grows with the frames that make a camera lost; the tests take 2 (the count only
# matters at its limit), `railstop platform verify` the data's.
LOST = 2


def real() -> PlatformUnit:
    return PlatformUnit(lamp_table=DATA.lamps(), debounce_scans=K)


def control() -> PsdFollower:
    return PsdFollower(confirm_frames=C, lost_limit_frames=LOST, lock_frames=L)


def test_the_real_unit_and_control_hold_every_invariant_with_fewer_misses_than_they_confirm() -> None:
    r = verify(real, follower_factory=control, max_dropouts=K - 1)
    assert r.violations == 0, r.examples
    assert r.lamps_seen == ("F", "OK", "R", "S")  # the search reaches every lamp
    assert r.unit_states > 500 and r.control_states > 2_000 and r.transitions > 4 * r.states


def test_as_many_misses_as_the_debounce_can_light_ok_for_an_overrun() -> None:
    """The bound is real: k misses of S1 in a row make an overrun look like a train in the window."""
    (inv,) = [i for i in INVARIANTS if i.name == "relay-only-on-ok"]
    r = verify(real, follower_factory=control, max_dropouts=K, invariants=[inv], stop_when_all_violated=True)
    assert r.counts["relay-only-on-ok"] > 0
    (example,) = r.examples
    assert example.trace[-K:] == ("scan (S1 missed)",) * K


def test_as_many_misreads_as_the_control_confirms_can_shut_the_psd_on_doors_not_locked() -> None:
    """The camera's bound is real too: `confirm_frames` misread "closed" frames in a row at an
    end of the run the control counts let it close the PSD before the doors are locked."""
    (inv,) = [i for i in INVARIANTS if i.name == "psd-closes-after-train-locked"]
    r = verify(real, follower_factory=control, max_misreads=C, invariants=[inv], stop_when_all_violated=True)
    assert r.counts[inv.name] > 0
    (example,) = r.examples
    assert "camera frame: closed (misread)" in example.trace
    assert "locked" not in example.message.split("doors ")[-1]


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


class _ClosesOnClosedShape(PsdFollower):
    """The PSD control as it was: closes once the doors are confirmed "closed", without waiting
    for the lock."""

    def decide(self) -> PsdCommand:
        if self.relay and self.camera_ok() and self.shape == "closed":
            return PsdCommand(open=False, camera_ok=True)
        return super().decide()


class _ClosesWhenRelayDrops(PsdFollower):
    """Shuts the PSD as soon as OK goes dark, whatever the train doors."""

    def decide(self) -> PsdCommand:
        if not self.relay:
            return PsdCommand(open=False, camera_ok=self.camera_ok())
        return super().decide()


BROKEN_UNITS = {
    "departure-psd-closed": _DepartsAnyway,
    "no-lamp-while-moving": _LampWhileMoving,
    "relay-only-on-ok": _RelayOnRDataclass,
}
BROKEN_CONTROLS = {
    "psd-command-only-on-ok": _IgnoresRelay,
    "psd-closes-after-train-locked": _ClosesWhenLost,
}
#: More ways to break the closing order, each caught by psd-closes-after-train-locked.
CLOSING_BROKEN = (_ClosesWhenLost, _ClosesOnClosedShape, _ClosesWhenRelayDrops)


def test_every_invariant_has_a_broken_unit_or_control() -> None:
    assert set(BROKEN_UNITS) | set(BROKEN_CONTROLS) == {inv.name for inv in INVARIANTS}


@pytest.mark.parametrize("name", sorted(BROKEN_UNITS) + sorted(BROKEN_CONTROLS))
def test_each_invariant_catches_its_broken_unit_or_control(name: str) -> None:
    unit_cls = BROKEN_UNITS.get(name, PlatformUnit)
    control_cls = BROKEN_CONTROLS.get(name, PsdFollower)
    (inv,) = [i for i in INVARIANTS if i.name == name]
    r = verify(
        lambda: unit_cls(lamp_table=DATA.lamps(), debounce_scans=K),
        follower_factory=lambda: control_cls(confirm_frames=C, lost_limit_frames=LOST, lock_frames=L),
        max_dropouts=K - 1,
        invariants=[inv],
        stop_when_all_violated=True,
    )
    assert r.counts[name] > 0
    (example,) = r.examples
    assert example.message and example.trace


@pytest.mark.parametrize("broken", CLOSING_BROKEN, ids=lambda c: c.__name__)
def test_the_closing_order_catches_each_broken_control(broken: type[PsdFollower]) -> None:
    (inv,) = [i for i in INVARIANTS if i.name == "psd-closes-after-train-locked"]
    r = verify(
        real,
        follower_factory=lambda: broken(confirm_frames=C, lost_limit_frames=LOST, lock_frames=L),
        invariants=[inv],
        stop_when_all_violated=True,
    )
    assert r.counts[inv.name] > 0
    (example,) = r.examples
    assert example.message.startswith("PSD commanded closed with the train doors")


def test_a_control_that_trusts_one_frame_is_caught_by_a_single_misread() -> None:
    """The data's confirmation matters: confirm_frames = 1 lets one misread shut the PSD."""
    (inv,) = [i for i in INVARIANTS if i.name == "psd-closes-after-train-locked"]
    r = verify(
        real,
        follower_factory=lambda: PsdFollower(confirm_frames=1, lost_limit_frames=LOST, lock_frames=L),
        max_misreads=1,
        lock_frames=L,
        invariants=[inv],
        stop_when_all_violated=True,
    )
    assert r.counts[inv.name] > 0
    assert "camera frame: closed (misread)" in r.examples[0].trace


def test_a_lock_wait_shorter_than_the_doors_lock_is_caught() -> None:
    """The lock confirmation matters: a control that counts one frame fewer than the doors may
    take to lock closes the PSD on shut, unlocked doors."""
    (inv,) = [i for i in INVARIANTS if i.name == "psd-closes-after-train-locked"]
    r = verify(
        real,
        follower_factory=lambda: PsdFollower(confirm_frames=C, lost_limit_frames=LOST, lock_frames=L - 1),
        lock_frames=L,
        invariants=[inv],
        stop_when_all_violated=True,
    )
    assert r.counts[inv.name] > 0
    assert r.examples[0].message.split()[-1] in ("closed", "opening")  # never locked: shut or reopened


def test_a_camera_that_reads_closed_before_the_leaves_shut_is_caught() -> None:
    """The camera's "closed" must mean fully shut: one that reads a closing door as closed (the
    earlier camera: "closed" below 30 % open) lets the real control shut the PSD on it."""
    (inv,) = [i for i in INVARIANTS if i.name == "psd-closes-after-train-locked"]
    early = {**CAMERA, "closing": frozenset({"moving", "closed"})}
    r = verify(real, follower_factory=control, camera=early, invariants=[inv], stop_when_all_violated=True)
    assert r.counts[inv.name] > 0
    assert r.examples[0].message == "PSD commanded closed with the train doors closing"


def test_a_reopen_the_camera_cannot_see_yet_is_the_only_exception() -> None:
    """Without the allowance for doors reopened after their lock within the misreads the camera
    may give, the real control is caught: the exception is needed, and it is all that is."""
    from railstop.verify.invariants import Invariant
    from railstop.verify.platform import LOCKED, ControlState, Step

    def strict(s: Step) -> str | None:
        a = s.after
        if isinstance(a, ControlState) and s.command_before and not s.command_after and a.doors != LOCKED:
            return f"closed with the doors {a.doors}"
        return None

    r = verify(
        real,
        follower_factory=control,
        invariants=[Invariant(name="strict", text="", check=strict)],
        stop_when_all_violated=True,
    )
    assert r.counts["strict"] > 0
    trace = r.examples[0].trace
    assert "train doors open" in trace and trace[-1] == "camera frame: closed (misread)"


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
