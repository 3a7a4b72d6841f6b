"""The command examples of the README and of the docs print what those pages say they print.

Every ```console block of README.md and of each docs/**/*.md page is a list of
``$ railstop ...`` commands, each followed by the lines it prints. A command shown with
output is run (in a temporary folder, as a user would from a fresh checkout) and its output
must match: a ``...`` inside a line stands for any text, a line that is only ``...`` for any
number of lines. A command shown without output is not run (a demo or a 100,000-run
campaign); its options are still checked by ``--help`` parsing (the command and each long
option must exist). A ``$ cp SRC DST`` line of a block (SRC in the repository) puts that
file into the temporary folder of every command after it in the block.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from zygote import run_cli

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").rglob("*.md"))]
EXE = [sys.executable, "-m", "railstop.cli"]


@dataclass(frozen=True)
class Example:
    file: str  # the page, relative to the repository (README.md, docs/...)
    line: int  # in that page
    argv: list[str]  # after "railstop"
    expected: list[str]
    copies: tuple[tuple[str, str], ...] = ()  # (from the repository, to the temporary folder)

    @property
    def where(self) -> str:
        return f"{self.file} line {self.line}"


def examples(page: Path) -> list[Example]:
    found: list[Example] = []
    name = page.relative_to(ROOT).as_posix()
    in_console = False
    current: Example | None = None
    copies: list[tuple[str, str]] = []
    for number, raw in enumerate(page.read_text(encoding="utf-8").splitlines(), start=1):
        if raw.startswith("```"):
            in_console = raw.strip() == "```console"
            current = None
            copies = []
            continue
        if not in_console:
            continue
        if raw.startswith("$ "):
            words = shlex.split(raw[2:], comments=True)
            current = None
            if len(words) == 3 and words[0] == "cp":
                copies.append((words[1], words[2]))
            elif words and words[0] == "railstop":
                current = Example(name, number, words[1:], [], tuple(copies))
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


def _id(example: Example) -> str:
    return f"{example.file}:L{example.line}:{' '.join(example.argv)[:50]}"


EXAMPLES = [e for page in PAGES for e in examples(page)]
SHOWN = [e for e in EXAMPLES if e.expected]


def test_the_readme_has_examples_with_output() -> None:
    in_readme = [e for e in SHOWN if e.file == "README.md"]
    assert len(in_readme) >= 5, [e.argv for e in in_readme]
    assert len(SHOWN) >= 6, [e.argv for e in SHOWN]


@pytest.mark.parametrize("example", SHOWN, ids=[_id(e) for e in SHOWN])
def test_readme_example_prints_what_the_readme_shows(example: Example, tmp_path: Path) -> None:
    for source, target in example.copies:
        shutil.copyfile(ROOT / source, tmp_path / target)
    env = {**os.environ, "RAILSTOP_STATUS_S": "0", "COLUMNS": "200"}
    p = run_cli(*example.argv, cwd=tmp_path, env=env)  # forked from a warm zygote (tests/zygote.py)
    actual = [ln.rstrip() for ln in (p.stdout + p.stderr).splitlines() if ln.strip()]
    assert _matches(example.expected, actual), (
        f"{example.where}: `railstop {' '.join(example.argv)}` printed\n"
        + "\n".join(actual)
        + f"\n--- where {example.file} shows ---\n"
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


@pytest.mark.parametrize("example", UNSHOWN, ids=[_id(e) for e in UNSHOWN])
def test_readme_example_without_output_names_real_options(example: Example) -> None:
    path, text = _help_options(example.argv)
    assert path, example
    for word in example.argv:
        if word.startswith("--"):
            option = word.split("=", 1)[0]
            assert re.search(rf"(?<![\w-]){re.escape(option)}(?![\w-])", text), (
                f"{example.where}: railstop {' '.join(path)} has no option {option}"
            )


def test_the_copied_files_exist() -> None:
    for example in EXAMPLES:
        for source, _ in example.copies:
            assert (ROOT / source).is_file(), f"{example.where}: no {source} in the repository"


def test_the_matcher() -> None:
    assert _matches(["a ... c"], ["a b c"])
    assert not _matches(["a ... c"], ["a b d"])
    assert _matches(["x", "...", "y"], ["x", "1", "2", "y"])
    assert _matches(["x", "...", "y"], ["x", "y"])
    assert not _matches(["x"], ["x", "extra"])
