"""The hazard log (DESIGN rule 10): every hazard has a rule, a unit that exists and tests that exist.

The log is data (``src/railstop/data/hazards/*.toml``); these tests tie it to
the code: a hazard with no test, a test that is not in the suite, a unit that
does not import, or a rendered log that is out of date fails here.
"""

from __future__ import annotations

import ast
import importlib
import subprocess
import sys
from functools import cache
from pathlib import Path

import pytest

from railstop.config.hazards import HazardEntry, load_hazard_file, load_hazard_log
from railstop.errors import ConfigError
from railstop.report.hazard_log import render_markdown

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "safety" / "hazard-log.md"
ENTRIES = load_hazard_log()


@cache
def _test_names(path: Path) -> frozenset[str]:
    """``name`` and ``Class::name`` of every test function the file defines."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.name.startswith("test"):
            names.add(node.name)
        elif isinstance(node, ast.ClassDef):
            for sub in node.body:
                if isinstance(sub, ast.FunctionDef | ast.AsyncFunctionDef) and sub.name.startswith("test"):
                    names.add(f"{node.name}::{sub.name}")
    return frozenset(names)


def missing_tests(entries: list[HazardEntry], root: Path = ROOT) -> list[str]:
    """``id: node`` for every named test that is not a test function of the suite."""
    missing = []
    for e in entries:
        for node in e.hazard.tests:
            file, _, name = node.partition("::")
            path = root / file
            if not path.is_file() or name not in _test_names(path):
                missing.append(f"{e.hazard.id}: {node}")
    return missing


def resolve_unit(dotted: str) -> object:
    """The object a dotted path names: the longest importable module, then attributes."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj: object = importlib.import_module(".".join(parts[:i]))
        except ModuleNotFoundError:
            continue
        for attr in parts[i:]:
            obj = getattr(obj, attr)
        return obj
    raise ModuleNotFoundError(dotted)


def test_the_log_is_not_empty_and_ids_are_unique() -> None:
    ids = [e.hazard.id for e in ENTRIES]
    assert len(ids) >= 10
    assert len(ids) == len(set(ids))


def test_every_hazard_names_tests_that_exist() -> None:
    assert missing_tests(ENTRIES) == []


@pytest.mark.parametrize("entry", ENTRIES, ids=lambda e: e.hazard.id)
def test_every_hazard_names_a_unit_that_exists(entry: HazardEntry) -> None:
    assert resolve_unit(entry.hazard.unit) is not None


def test_the_checks_catch_a_missing_test_and_a_missing_unit() -> None:
    """The two checks above can fail: a renamed test and a renamed unit are caught."""
    e = ENTRIES[0]
    renamed = e.hazard.model_copy(update={"tests": [e.hazard.tests[0] + "_renamed"]})
    assert missing_tests([HazardEntry(source=e.source, hazard=renamed)]) == [
        f"{e.hazard.id}: {e.hazard.tests[0]}_renamed"
    ]
    with pytest.raises(AttributeError):
        resolve_unit(e.hazard.unit + "_renamed")


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "h.toml"
    path.write_text(text, encoding="utf-8")
    return path


GOOD = """
[[hazard]]
id = "HZ-X-01"
title = "A hazard"
origin = "review"
cause = "Something goes wrong."
rule = "Something stops it."
unit = "railstop.errors.RailstopError"
safe_state = "stopped"
tests = ["tests/config/test_hazard_log.py::test_every_hazard_names_tests_that_exist"]
"""


def test_a_hazard_without_a_test_is_refused(tmp_path: Path) -> None:
    assert load_hazard_file(_write(tmp_path, GOOD))[0].id == "HZ-X-01"
    bad = GOOD.replace(
        'tests = ["tests/config/test_hazard_log.py::test_every_hazard_names_tests_that_exist"]', "tests = []"
    )
    with pytest.raises(ConfigError, match=r"h\.toml: hazard\[0\]\.tests: List should have at least 1 item"):
        load_hazard_file(_write(tmp_path, bad))
    no_key = GOOD.replace('safe_state = "stopped"\n', "")
    with pytest.raises(ConfigError, match=r"hazard\[0\]\.safe_state: Field required"):
        load_hazard_file(_write(tmp_path, no_key))


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ('id = "HZ-X-01"', 'id = "H-1"', "id"),
        ('unit = "railstop.errors.RailstopError"', 'unit = "os.system"', "unit"),
        ('test_every_hazard_names_tests_that_exist"]', 'test_x", "not a node"]', "tests.1"),
    ],
)
def test_malformed_entries_name_the_field(tmp_path: Path, old: str, new: str, field: str) -> None:
    with pytest.raises(ConfigError, match=rf"hazard\[0\]\.{field}"):
        load_hazard_file(_write(tmp_path, GOOD.replace(old, new)))


def test_duplicate_ids_and_mixed_areas_are_refused(tmp_path: Path) -> None:
    (tmp_path / "a.toml").write_text(GOOD, encoding="utf-8")
    (tmp_path / "b.toml").write_text(GOOD, encoding="utf-8")
    with pytest.raises(ConfigError, match="already used in"):
        load_hazard_log(tmp_path)
    (tmp_path / "b.toml").write_text(GOOD + GOOD.replace("HZ-X-01", "HZ-Y-02"), encoding="utf-8")
    with pytest.raises(ConfigError, match="one area per file"):
        load_hazard_log(tmp_path)


def test_the_rendered_log_in_the_docs_is_up_to_date() -> None:
    """``railstop hazards --markdown docs/safety/hazard-log.md`` rewrites it."""
    assert DOC.read_text(encoding="utf-8") == render_markdown(ENTRIES) + "\n"


def test_cli_prints_the_log_and_refuses_a_bad_folder_in_one_line(tmp_path: Path) -> None:
    exe = [sys.executable, "-m", "railstop.cli", "hazards"]
    ok = subprocess.run(exe, capture_output=True, text=True, env={"COLUMNS": "200", "PATH": ""}, check=False)
    assert ok.returncode == 0, ok.stderr
    assert ENTRIES[0].hazard.id in ok.stdout
    (tmp_path / "bad.toml").write_text("[[hazard]]\nid = 1\n", encoding="utf-8")
    bad = subprocess.run([*exe, "--dir", str(tmp_path)], capture_output=True, text=True, check=False)
    assert bad.returncode == 2
    assert bad.stderr.strip().count("\n") == 0 and "bad.toml: hazard[0].id" in bad.stderr
