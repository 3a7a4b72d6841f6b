"""The README's command examples print what the README says they print.

Every ```console block of README.md is a list of ``$ railstop ...`` commands,
each followed by the lines it prints. A command shown with output is run (in a
temporary folder, as a user would from a fresh checkout) and its output must
match: a ``...`` inside a line stands for any text, a line that is only ``...``
for any number of lines. A command shown without output is not run (a demo or
a 100,000-run campaign); its options are still checked by ``--help`` parsing
(the command and each long option must exist).
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from zygote import run_cli

README = Path(__file__).resolve().parents[1] / "README.md"
EXE = [sys.executable, "-m", "railstop.cli"]


@dataclass(frozen=True)
class Example:
    line: int  # in README.md
    argv: list[str]  # after "railstop"
    expected: list[str]


def examples() -> list[Example]:
    found: list[Example] = []
    in_console = False
    current: Example | None = None
    for number, raw in enumerate(README.read_text(encoding="utf-8").splitlines(), start=1):
        if raw.startswith("```"):
            in_console = raw.strip() == "```console"
            current = None
            continue
        if not in_console:
            continue
        if raw.startswith("$ "):
            words = shlex.split(raw[2:], comments=True)
            if not words or words[0] != "railstop":
                current = None
                continue
            current = Example(number, words[1:], [])
            found.append(current)
        elif current is not None and raw.strip():
            current.expected.append(raw.rstrip())
    return found


def _matches(expected: list[str], actual: list[str]) -> bool:
    """Line by line; ``...`` in a line is any text, a line ``...`` is any run of lines."""
    pattern = []
    for line in expected:
        if line.strip() == "...":
            pattern.append(r"(?:.*\n)*?")
        else:
            parts = [re.escape(p) for p in line.split("...")]
            pattern.append(".*".join(parts) + r"\n")
    return re.fullmatch("".join(pattern), "".join(a + "\n" for a in actual)) is not None


EXAMPLES = examples()
SHOWN = [e for e in EXAMPLES if e.expected]


def test_the_readme_has_examples_with_output() -> None:
    assert len(SHOWN) >= 6, [e.argv for e in SHOWN]


@pytest.mark.parametrize("example", SHOWN, ids=[f"L{e.line}:{' '.join(e.argv)[:50]}" for e in SHOWN])
def test_readme_example_prints_what_the_readme_shows(example: Example, tmp_path: Path) -> None:
    env = {**os.environ, "RAILSTOP_STATUS_S": "0", "COLUMNS": "200"}
    p = run_cli(*example.argv, cwd=tmp_path, env=env)  # forked from a warm zygote (tests/zygote.py)
    actual = [ln.rstrip() for ln in (p.stdout + p.stderr).splitlines() if ln.strip()]
    assert _matches(example.expected, actual), (
        f"README.md line {example.line}: `railstop {' '.join(example.argv)}` printed\n"
        + "\n".join(actual)
        + "\n--- where the README shows ---\n"
        + "\n".join(example.expected)
    )


def _help_options(argv: list[str]) -> tuple[list[str], str]:
    """The sub-command path (words before the first option) and its --help text."""
    path = []
    for word in argv:
        if word.startswith("-"):
            break
        path.append(word)
    while path:
        p = subprocess.run([*EXE, *path, "--help"], capture_output=True, text=True, timeout=120, check=False)
        if p.returncode == 0:
            return path, p.stdout
        path.pop()  # a positional argument, not a command
    raise AssertionError(f"no command in {argv}")


UNSHOWN = [e for e in EXAMPLES if not e.expected]


@pytest.mark.parametrize("example", UNSHOWN, ids=[f"L{e.line}:{' '.join(e.argv)[:50]}" for e in UNSHOWN])
def test_readme_example_without_output_names_real_options(example: Example) -> None:
    path, text = _help_options(example.argv)
    assert path, example
    for word in example.argv:
        if word.startswith("--"):
            option = word.split("=", 1)[0]
            assert re.search(rf"(?<![\w-]){re.escape(option)}(?![\w-])", text), (
                f"README.md line {example.line}: railstop {' '.join(path)} has no option {option}"
            )


def test_the_matcher() -> None:
    assert _matches(["a ... c"], ["a b c"])
    assert not _matches(["a ... c"], ["a b d"])
    assert _matches(["x", "...", "y"], ["x", "1", "2", "y"])
    assert _matches(["x", "...", "y"], ["x", "y"])
    assert not _matches(["x"], ["x", "extra"])
