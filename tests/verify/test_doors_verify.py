"""`railstop doors verify`: the exhaustive search proves the real tables and refutes broken ones."""

from __future__ import annotations

import dataclasses
import json
import subprocess
from pathlib import Path
from types import MappingProxyType

import pytest

from railstop.config.doors import Action, ActionRow, load_doors
from railstop.control.doors import (
    CLOSED_STATES,
    DOOR_TRANSITIONS,
    DoorInput,
    DoorState,
    Interlocks,
)
from railstop.nodes.doors import DoorModel
from railstop.onboard.stop_confirm import STOP_TRANSITIONS, StopInput, StopPhase
from railstop.verify.doors import INVARIANTS, all_controls, verify
from zygote import run_cli

CFG = load_doors()
MODEL = DoorModel(actions=CFG.actions, max_psc_attempts=CFG.stop_confirm.max_psc_attempts)
DS = DoorState


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=cwd)  # forked from a warm zygote (tests/zygote.py)


@pytest.fixture(scope="module")
def real_result():  # type: ignore[no-untyped-def]
    return verify(MODEL, doors_per_side=1)


def test_real_tables_have_no_violation(real_result) -> None:  # type: ignore[no-untyped-def]
    r = real_result
    assert r.violations == 0, r.examples
    assert set(r.counts) == {inv.name for inv in INVARIANTS} and len(INVARIANTS) == 8
    # Every input combination under every event of every state: 64 x 2 x 5 per event.
    assert r.controls == 640 == len(set(all_controls()))
    assert r.transitions % 640 == 0 and r.transitions >= 640 * r.states
    assert r.states == 402  # the model's size; a change here is a change of the model


def test_search_reaches_the_interesting_states(real_result) -> None:  # type: ignore[no-untyped-def]
    # Not a vacuous proof: the search opens and closes, obstructs, jams and isolates doors
    # (train doors and PSD), corrects, faults and departs.
    cov = real_result.coverage
    every = tuple(sorted(s.value for s in DoorState))
    assert cov["train_door"] == every and cov["psd"] == every
    assert cov["stop"] == tuple(sorted(p.value for p in StopPhase))
    assert set(cov["moving"]) == {StopPhase.RUNNING.value, StopPhase.CORRECTING.value}


# One broken model per invariant: what a plausible mistake would look like.
def _stop_with(extra: dict[tuple[StopPhase, StopInput], StopPhase]) -> MappingProxyType:  # type: ignore[type-arg]
    return MappingProxyType({**STOP_TRANSITIONS, **extra})


BROKEN: dict[str, DoorModel] = {
    # The ATC restarts the position correction after PSC is lost (a spurious time-out in CONFIRMED):
    # the train creeps with the PSD still open.
    "closed-while-moving": dataclasses.replace(
        MODEL, stop=_stop_with({(StopPhase.CONFIRMED, StopInput.PSC_TIMEOUT): StopPhase.CORRECTING})
    ),
    # The source's garbled row: the PSD (and the doors) opening for (DOA, DMC, DOC, DCC) = (0, 1, 1, 0).
    "dmc-doa-authority": dataclasses.replace(
        MODEL,
        actions=CFG.actions.replace_row(
            ActionRow(doa=0, dmc=1, doc=1, dcc=0, closed=Action.OPEN, open=Action.KEEP_OPEN)
        ),
    ),
    # A "faster" CPCS that opens the train doors as soon as the PSD starts to open.
    "psd-opens-first": dataclasses.replace(
        MODEL, interlocks=Interlocks(train_opens_when_psd=frozenset({DS.OPENING, DS.OPEN}))
    ),
    # A WPCS that closes the PSD without waiting for the train doors.
    "train-closes-first": dataclasses.replace(
        MODEL, interlocks=Interlocks(psd_closes_when_train=frozenset(DoorState))
    ),
    # Start enable on "closed" without the lock.
    "start-enable-safe": dataclasses.replace(
        MODEL, interlocks=Interlocks(locked=frozenset({DS.CLOSED_LOCKED, DS.CLOSED, DS.ISOLATED}))
    ),
    # A stop confirmation that never gives up (the train shuttling for 10 minutes of SPEC §1).
    "psc-attempts-brake": dataclasses.replace(
        MODEL, stop=_stop_with({(StopPhase.PSC_WAIT, StopInput.PSC_TIMEOUT_LAST): StopPhase.CORRECTING})
    ),
    # An ATC that shrugs off a silent link: PSC stays high on a PSD state nobody reports.
    "link-lost-brake": dataclasses.replace(
        MODEL, stop=_stop_with({(StopPhase.CONFIRMED, StopInput.LINK_LOST): StopPhase.CONFIRMED})
    ),
    # A door table without "close an open door": the controller's command is refused.
    "no-interlock-error": dataclasses.replace(
        MODEL,
        doors=MappingProxyType(
            {k: v for k, v in DOOR_TRANSITIONS.items() if k != (DS.OPEN, DoorInput.CLOSE)}
        ),
    ),
}


def test_every_invariant_has_a_broken_variant() -> None:
    assert set(BROKEN) == {inv.name for inv in INVARIANTS}


@pytest.mark.parametrize("invariant", INVARIANTS, ids=lambda inv: inv.name)
def test_each_invariant_catches_its_broken_table(invariant, real_result) -> None:  # type: ignore[no-untyped-def]
    # The real model satisfies the invariant everywhere ...
    assert real_result.counts[invariant.name] == 0
    # ... and the broken one violates it somewhere reachable (search stops at the first).
    broken = verify(BROKEN[invariant.name], invariants=[invariant], stop_on_violation=True)
    assert broken.counts[invariant.name] >= 1
    (example,) = broken.examples
    assert example.invariant == invariant.name and example.message
    assert example.trace[0].startswith("moving") and example.trace[-1].startswith("->")


@pytest.mark.parametrize("doors_per_side", [1, 2])
def test_a_psd_that_closes_on_shut_but_unlocked_train_doors_is_caught(doors_per_side: int) -> None:
    """SPEC §5 order: "closed" is not enough; the PSD waits for the train doors' lock."""
    (inv,) = [i for i in INVARIANTS if i.name == "train-closes-first"]
    loose = dataclasses.replace(MODEL, interlocks=Interlocks(psd_closes_when_train=CLOSED_STATES))
    r = verify(loose, doors_per_side=doors_per_side, invariants=[inv], stop_on_violation=True)
    assert r.counts[inv.name] >= 1
    assert r.examples[0].message.endswith("is closed")  # shut, the lock not yet made


def test_broken_source_row_fails_in_full_search() -> None:
    # Without stopping early: the garbled source row breaks DMC priority and nothing else.
    r = verify(BROKEN["dmc-doa-authority"])
    assert r.counts["dmc-doa-authority"] > 0
    assert r.counts["closed-while-moving"] == 0 and r.counts["start-enable-safe"] == 0


# -- the command ---------------------------------------------------------------------------


def test_cli_doors_verify_exit_0(tmp_path: Path) -> None:
    p = run("doors", "verify", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert "states: 402" in p.stdout and "violations: 0" in p.stdout
    assert "transitions: " in p.stdout
    for inv in INVARIANTS:
        assert inv.name in p.stdout


def test_cli_doors_verify_broken_file_exit_1(tmp_path: Path) -> None:
    src = (Path(__file__).parents[2] / "src/railstop/data/doors.toml").read_text(encoding="utf-8")
    row = '{ doa = 0, dmc = 1, doc = 1, dcc = 0, closed = "keep-closed", open = "keep-open" }'
    assert row in src
    bad = tmp_path / "doors.toml"
    bad.write_text(src.replace(row, row.replace('"keep-closed"', '"open"')))
    p = run("doors", "verify", "--doors", str(bad), "--json", cwd=tmp_path)
    assert p.returncode == 1, p.stderr
    data = json.loads(p.stdout)
    assert data["violations"] > 0 and data["invariants"]["dmc-doa-authority"] > 0
    assert data["examples"][0]["invariant"] == "dmc-doa-authority"


def test_cli_doors_table(tmp_path: Path) -> None:
    p = run("doors", "table", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    rows = [ln for ln in p.stdout.splitlines() if ln.count("│") >= 6 and ln.strip("│ ")[:1] in "01"]
    assert len(rows) == 16
    assert "close in manual mode" in p.stdout and "[interpretation]" in p.stdout
    j = run("doors", "table", "--json", cwd=tmp_path)
    table = json.loads(j.stdout)
    assert len(table) == 16
    assert {"doa": 0, "dmc": 0, "doc": 0, "dcc": 1, "closed": "keep-closed", "open": "keep-open"}.items() <= (
        next(r for r in table if (r["doa"], r["dmc"], r["doc"], r["dcc"]) == (0, 0, 0, 1)).items()
    )


def test_cli_doors_bad_file_one_line_exit_2(tmp_path: Path) -> None:
    bad = tmp_path / "doors.toml"
    bad.write_text("action_table = []\n")
    p = run("doors", "table", "--doors", str(bad), cwd=tmp_path)
    assert p.returncode == 2
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
