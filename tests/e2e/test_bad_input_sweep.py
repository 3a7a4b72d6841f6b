"""Every command answers bad input with one ``error:`` line on stderr, exit code 2, never a traceback.

The cases are in ``tests/bad_inputs.py`` (shared with ``benchmarks/bad_input_sweep.py``); each runs
the real command in a process of its own in its own folder, forked from a warm zygote
(``tests/zygote.py``) so that 270 commands do not pay 270 interpreter start-ups; one case per
command group also runs in a fresh interpreter (``python -m``).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bad_inputs import CASES, CLI, ERROR_PREFIX, UDP, Case, Outcome, environment, run_case
from zygote import shared


def _first_of_each_command() -> list[Case]:
    seen: set[tuple[str, ...]] = set()
    firsts = []
    for c in CASES:
        key = (c.module, *c.argv[:1])
        if key not in seen:
            seen.add(key)
            firsts.append(c)
    return firsts


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input_is_one_error_line(case: Case, tmp_path: Path) -> None:
    _check(case, run_case(case, tmp_path, zygote=shared(environment())))


@pytest.mark.parametrize("case", _first_of_each_command(), ids=lambda c: c.id)
def test_bad_input_is_one_error_line_in_a_fresh_interpreter(case: Case, tmp_path: Path) -> None:
    _check(case, run_case(case, tmp_path))


def _check(case: Case, outcome: Outcome) -> None:
    shown = f"$ {case.shell()}\nstdout: {outcome.stdout[-2000:]!r}\nstderr: {outcome.stderr[-4000:]!r}"
    assert outcome.returncode is not None, f"timed out\n{shown}"
    assert not outcome.traceback, f"traceback\n{shown}"
    assert outcome.returncode == 2, f"exit code {outcome.returncode}\n{shown}"
    lines = outcome.lines
    assert len(lines) == 1, f"{len(lines)} lines on stderr\n{shown}"
    assert lines[0].startswith(ERROR_PREFIX), shown
    for needle in case.needles:
        assert needle in lines[0], f"{needle!r} not in the error line\n{shown}"


def test_the_sweep_covers_every_command() -> None:
    """At least 200 cases, and every command and sub-command has some."""
    assert len(CASES) >= 200
    firsts = {c.argv[0] for c in CASES if c.module == CLI and c.argv}
    for command in (
        "check",
        "stop",
        "compile",
        "demo",
        "campaign",
        "compare",
        "certify",
        "report",
        "position-run",
        "dwell",
        "doors",
        "telegram",
    ):
        assert command in firsts, command
    pairs = {c.argv[:2] for c in CASES if c.argv[:1] in (("doors",), ("telegram",))}
    for pair in (
        ("doors", "table"),
        ("doors", "verify"),
        ("telegram", "decode"),
        ("telegram", "encode"),
        ("telegram", "types"),
    ):
        assert pair in pairs, pair
    udp = {c.argv[0] for c in CASES if c.module == UDP and c.argv}
    assert {"send", "receive"} <= udp
