"""`railstop zones verify`: the exhaustive search proves the real zone controller (SPEC §4) and
refutes broken ones."""

from __future__ import annotations

import copy
import json
import math
import random
import subprocess
from pathlib import Path

import pytest
from typer.testing import CliRunner

from railstop.config.layout import Cbtc
from railstop.control.supervision import EbCause
from railstop.messages import MovementCommand, PositionReport
from railstop.onboard.cbtc import OnboardCbtc
from railstop.verify import zones as zones_verify
from railstop.verify.zones import (
    INVARIANTS,
    Invariant,
    TrainAction,
    VerifyResult,
    World,
    ZoneModel,
    initial_world,
    verify,
)
from railstop.wayside.zone_controller import TrainStatus, ZoneController, ZoneMode, _Train
from zygote import run_cli

MODEL = ZoneModel()  # 3 trains, 6 segments of 100 m, up to 3 reports lost in a row


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=cwd)  # forked from a warm zygote (tests/zygote.py)


# ---------------------------------------------------------------------- the real controller


@pytest.mark.parametrize("mode", list(ZoneMode), ids=lambda m: m.value)
def test_real_controller_has_no_violation(mode: ZoneMode) -> None:
    """The search of the default model through the real units finds no violation, and is not a
    vacuous proof. (One test per mode, each searching once: the suite's workers may run them
    apart, and a fixture shared by several tests would be searched again on each worker.)"""
    r = verify(MODEL, mode=mode)
    assert r.violations == 0, r.examples
    assert set(r.counts) == {inv.name for inv in INVARIANTS} and len(INVARIANTS) == 5
    assert r.mode == mode and r.model == MODEL
    assert r.states > 1000 and r.transitions > 5 * r.states  # several choices per state
    # Not vacuous: trains are lost (zones set), re-detected inside (automatic release) and
    # outside after moving while lost (flagged), released by the operator, braked by the onboard
    # unit after missed commands, and held by a zone set around them.
    cov = r.coverage
    for key in (
        "lost",
        "auto-release",
        "flagged",
        "manual-release",
        "moved-while-lost",
        "emergency-brake",
        "held-inside-zone",
    ):
        assert cov.get(key, 0) > 0, (key, cov)
    for status in (TrainStatus.TRACKED, TrainStatus.LOST, TrainStatus.FLAGGED):
        assert cov[f"status-{status.value}"] > 0, (status, cov)


@pytest.mark.parametrize("mode", list(ZoneMode), ids=lambda m: m.value)
def test_real_controller_with_a_margin_and_a_processing_delay(mode: ZoneMode) -> None:
    # A safety margin and Δt > 0 (the trains stand at their reports, so Pc = Pp): still safe.
    params = Cbtc(
        report_period_s=1.0,
        processing_delay_s=0.3,
        missed_reports_lost=2,
        missed_commands_eb=2,
        safety_margin_m=20.0,
        rollback_m=0.0,
    )
    # No uncertainty nor rollback here: the conventional zone with a margin must leave room on
    # the short line for a lost train to be found outside it.
    r = verify(ZoneModel(trains=2, segments=5, max_losses=3, uncertainty_m=0.0, params=params), mode=mode)
    assert r.violations == 0, r.examples
    assert r.coverage.get("flagged", 0) > 0 and r.coverage.get("auto-release", 0) > 0


def test_no_losses_no_faults() -> None:
    # With a perfect radio nothing is ever lost: the model's fault events need the losses.
    r = verify(ZoneModel(max_losses=1), mode=ZoneMode.MINIMAL)
    assert r.violations == 0
    assert r.coverage.get("lost", 0) == 0 and r.coverage["status-lost"] == 0
    assert r.coverage.get("emergency-brake", 0) == 0


# ---------------------------------------------------------------------- broken units


class ReleasesEveryRedetection(ZoneController):
    """Releases the zone of every re-detected train, also outside its zone (SPEC §4 step 5 broken)."""

    def _redetect(self, t: _Train, r: PositionReport) -> None:
        super()._redetect(t, r)
        if t.status == TrainStatus.FLAGGED:
            t.zone = None
            t.status = TrainStatus.TRACKED


class IgnoresZones(ZoneController):
    """Computes the authority as if there were no protection zones."""

    def _obstacle_ahead(self, me: _Train, front_m: float, direction: str) -> float:
        zones = {i: t.zone for i, t in self.trains.items()}
        for t in self.trains.values():
            t.zone = None
        try:
            return super()._obstacle_ahead(me, front_m, direction)
        finally:
            for i, z in zones.items():
                self.trains[i].zone = z


class NeverLoses(ZoneController):
    """Counts the missed reports but never declares a train lost (no zone)."""

    def _lose(self, t: _Train) -> None:
        pass


class NeverBrakes(OnboardCbtc):
    """An onboard unit whose emergency brake never applies."""

    def _brake(self, cause: EbCause) -> None:
        pass


class KeepsTheLongestAuthority(OnboardCbtc):
    """An onboard unit that never lets a command shorten the authority it holds."""

    def _on_command(self, message: MovementCommand, now_s: float) -> None:
        held = self.authority_end_m
        super()._on_command(message, now_s)
        if not math.isnan(held):
            self.authority_end_m = max(held, self.authority_end_m)


BROKEN: dict[str, dict[str, object]] = {
    "authority-clear": {"controller_factory": IgnoresZones},
    "no-auto-release-outside": {"controller_factory": ReleasesEveryRedetection},
    "missed-commands-brake": {"onboard_factory": NeverBrakes},
    "lost-train-zone": {"controller_factory": NeverLoses},
    "authority-end": {"onboard_factory": KeepsTheLongestAuthority},
}


def test_every_invariant_has_a_broken_variant() -> None:
    assert set(BROKEN) == {inv.name for inv in INVARIANTS}


@pytest.mark.parametrize("invariant", INVARIANTS, ids=lambda inv: inv.name)
@pytest.mark.parametrize("mode", list(ZoneMode), ids=lambda m: m.value)
def test_each_invariant_catches_its_broken_unit(invariant: Invariant, mode: ZoneMode) -> None:
    # The real units satisfy every invariant everywhere (test_real_controller_has_no_violation);
    # the broken one violates its invariant somewhere reachable (the search stops at the first).
    broken = verify(
        MODEL,
        mode=mode,
        invariants=[invariant],
        stop_on_violation=True,
        **BROKEN[invariant.name],  # type: ignore[arg-type]
    )
    assert broken.counts[invariant.name] == 1
    (example,) = broken.examples
    assert example.invariant == invariant.name and example.message
    # The trace: the initial state, then a cycle line and a state line per cycle, ending in "->".
    assert example.trace[0].startswith("T1 150 m tracked") and example.trace[-1].startswith("-> ")
    assert all(line.startswith("t=") for line in example.trace[1:-1:2])


def test_a_broken_rule_breaks_its_invariant_and_nothing_else() -> None:
    r = verify(ZoneModel(trains=2, segments=4), controller_factory=ReleasesEveryRedetection)
    assert r.counts["no-auto-release-outside"] > 0
    assert (
        r.counts["authority-clear"]
        == r.counts["missed-commands-brake"]
        == r.counts["lost-train-zone"]
        == r.counts["authority-end"]
        == 0
    )


def test_trace_of_a_broken_controller_reads_as_the_papers_story() -> None:
    r = verify(
        MODEL,
        invariants=[INVARIANTS[1]],
        stop_on_violation=True,
        controller_factory=ReleasesEveryRedetection,
    )
    (v,) = r.examples
    text = "\n".join(v.trace)
    # Lost (2 reports lost), moved while lost, re-detected outside: released without the operator.
    assert "report LOST" in text and "moves while lost" in text and " lost zone " in text
    assert "released at" in v.message and "no manual release" in v.message


# ---------------------------------------------------------------------- the model's mechanics


def test_copy_unit_is_a_deep_copy_of_the_units() -> None:
    """The fast copy behaves as copy.deepcopy along random runs, and leaves the original alone."""
    rng = random.Random(15)
    for mode in ZoneMode:
        w = initial_world(MODEL, mode)
        for _ in range(60):
            choices = list(w.choices())
            choice = rng.choice(choices)
            before = w.snapshot()
            fast = w.clone()
            deep = copy.deepcopy(w)
            fast.cycle(choice)
            deep.cycle(choice)
            assert fast.snapshot() == deep.snapshot()
            assert w.snapshot() == before  # the original is untouched
            assert fast.zc.counts == deep.zc.counts
            w = fast


def test_snapshot_ignores_the_time_origin_and_counters() -> None:
    a = initial_world(MODEL, ZoneMode.MINIMAL)
    b = a.clone()
    for _ in range(3):  # three more quiet cycles: the same state, later
        b.close()
    assert b.t_s == a.t_s + 3.0 and b.zc.counts.reports > a.zc.counts.reports
    assert b.snapshot() == a.snapshot()


def test_two_lost_reports_make_a_lost_train_and_two_missed_commands_brake() -> None:
    # SPEC §4 through the model: train 2 (front 250 m) loses two reports.
    w = initial_world(MODEL, ZoneMode.MINIMAL)
    for n in (1, 2):
        step = w.cycle(
            zones_verify.Choice(
                release=None,
                actions=tuple(TrainAction(train=t, to_m=w.fronts[t - 1], deliver=t != 2) for t in (1, 2, 3)),
            )
        )
        assert w.status(2) == (TrainStatus.TRACKED if n == 1 else TrainStatus.LOST)
    zone = w.zone(2)
    assert zone is not None and (zone.start_m, zone.end_m) == (100.0, 300.0)  # rear 170 .. end 270
    # The onboard counts the second missed command when its timer fires next.
    step = w.cycle(zones_verify.Choice(release=None, actions=()))
    (timer,) = [r for r in step.timers if r.train == 2]
    assert timer.commands_missed == 2 and timer.emergency_brake
    assert w.status(2) == TrainStatus.TRACKED and w.zone(2) is None  # re-detected inside: released


def _cycle(w: World, release: int | None = None, **moves: tuple[float, bool]) -> zones_verify.Step:
    """One cycle: ``T2=(to_m, deliver)``; the trains not named stand and report."""
    actions = []
    for t in range(1, w.trains + 1):
        to, deliver = moves.get(f"T{t}", (w.fronts[t - 1], True))
        actions.append(TrainAction(train=t, to_m=to, deliver=deliver))
    return w.cycle(zones_verify.Choice(release=release, actions=tuple(actions)))


def test_flagged_train_gone_silent_has_its_zone_grown_over_its_last_report() -> None:
    """[interpretation] of SPEC §4 step 5: a flagged train whose reports stop again keeps its flag,
    and its zone grows to take in where it last reported (it may stand anywhere it could reach);
    the operator's release of it while it is silent makes it lost again at once."""
    w = initial_world(ZoneModel(trains=3, segments=7), ZoneMode.MINIMAL, fronts=[150.0, 350.0, 450.0])
    _cycle(w, T2=(350.0, False))
    _cycle(w, T2=(350.0, False), T3=(550.0, True))
    zone = w.zone(2)
    assert w.status(2) == TrainStatus.LOST and zone is not None
    assert (zone.start_m, zone.end_m) == (200.0, 400.0)  # rear 270 .. authority end 370 (T3's rear)
    _cycle(w, T2=(350.0, False), T3=(650.0, True))
    # SPEC §4 step 5: it moved while lost and is found outside its zone: flagged, zone kept.
    _cycle(w, T2=(450.0, True))
    assert w.status(2) == TrainStatus.FLAGGED and w.zone(2) == zone
    for _ in range(3):  # ... and then goes silent
        step = _cycle(w, T2=(450.0, False))
    grown = w.zone(2)
    assert w.status(2) == TrainStatus.FLAGGED and grown is not None
    assert grown.start_m <= zone.start_m and grown.end_m >= 450.0  # its last report is covered
    (cmd,) = [c for c in step.commands if c.train == 1]
    assert cmd.end_m <= grown.start_m  # nothing reaches into it
    # The operator releases it while it is silent: lost again at once, zone around its last report.
    _cycle(w, release=2, T2=(450.0, False))
    z2 = w.zone(2)
    assert w.status(2) == TrainStatus.LOST and z2 is not None
    assert z2.start_m <= 370.0 and z2.end_m >= 450.0


def test_model_refuses_a_line_too_short() -> None:
    with pytest.raises(ValueError, match="segments"):
        ZoneModel(trains=3, segments=3)
    with pytest.raises(ValueError, match="train_length_m"):
        ZoneModel(train_length_m=120.0)


def test_a_world_refuses_two_turns_of_one_train() -> None:
    w: World = initial_world(MODEL, ZoneMode.MINIMAL)
    w.turn(TrainAction(train=1, to_m=150.0, deliver=True))
    with pytest.raises(ValueError, match="already"):
        w.turn(TrainAction(train=1, to_m=150.0, deliver=True))


# ---------------------------------------------------------------------- the command


def test_cli_zones_verify_exit_0(tmp_path: Path) -> None:
    p = run("zones", "verify", "--trains", "2", "--segments", "4", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    last = [ln for ln in p.stdout.splitlines() if ln.startswith("states: ")]
    assert len(last) == 2  # both modes
    assert all("violations: 0" in ln and "transitions: " in ln for ln in last)
    assert p.stdout.rstrip().splitlines()[-1] == last[-1]
    for inv in INVARIANTS:
        assert inv.name in p.stdout
    assert "(minimal)" in p.stdout and "(conventional)" in p.stdout


def test_cli_zones_verify_json_one_mode(tmp_path: Path) -> None:
    p = run(
        "zones",
        "verify",
        "--mode",
        "conventional",
        "--trains",
        "2",
        "--segments",
        "3",
        "--json",
        cwd=tmp_path,
    )
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    (r,) = data["modes"]
    assert r["mode"] == "conventional" and r["violations"] == 0 and r["states"] > 0


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("--mode", "fancy"), "--mode"),
        (("--trains", "9"), "--trains"),
        (("--max-losses", "-1"), "--max-losses"),
        (("--trains", "3", "--segments", "3"), "--segments"),
        (("--segments", "abc"), "--segments"),
    ],
)
def test_cli_zones_verify_bad_option_one_line_exit_2(
    args: tuple[str, ...], needle: str, tmp_path: Path
) -> None:
    p = run("zones", "verify", *args, cwd=tmp_path)
    assert p.returncode == 2, (p.stdout, p.stderr)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert lines[0].startswith("error:") and needle in lines[0]


def test_cli_zones_verify_violation_exit_1_with_trace(monkeypatch: pytest.MonkeyPatch) -> None:
    from railstop.cli import app

    real_verify = zones_verify.verify

    def broken_verify(model: ZoneModel, **kw: object) -> VerifyResult:
        return real_verify(model, controller_factory=IgnoresZones, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(zones_verify, "verify", broken_verify)
    res = CliRunner().invoke(
        app, ["zones", "verify", "--mode", "minimal", "--trains", "2", "--segments", "4"]
    )
    assert res.exit_code == 1, res.output
    assert "authority-clear: " in res.output and "trace:" in res.output
    assert "  -> T1 " in res.output
    assert res.output.rstrip().splitlines()[-1].startswith("states: ")


def test_the_search_reports_its_progress_explored_of_found(monkeypatch: pytest.MonkeyPatch) -> None:
    """``progress(explored, found)`` every PROGRESS_EVERY states: explored grows, never past found
    (the CLI shows it on stderr while the search runs a minute or two)."""
    import railstop.verify.zones as zones

    monkeypatch.setattr(zones, "PROGRESS_EVERY", 50)
    calls: list[tuple[int, int]] = []
    r = verify(ZoneModel(trains=2, segments=5, max_losses=2), progress=lambda e, f: calls.append((e, f)))
    assert r.states >= 200 and len(calls) >= 3  # every state is explored once: about states / 50 calls
    assert [e for e, _ in calls] == [50 * (k + 1) for k in range(len(calls))]
    assert all(e <= f <= r.states for e, f in calls)
