"""The tests mirror the source tree (docs/architecture.md, "Test layout").

A test module sits in ``tests/<package>/`` for a package of ``src/railstop/``, in
``tests/foundations/`` for the top-level modules of ``src/railstop/`` (``streams.py``,
``quantities.py``, ...), or in ``tests/e2e/`` when it drives the whole system; ``tests/``
itself keeps only the shared helpers (``conftest.py``, ``zygote.py``, ``bad_inputs.py``,
``busy.py``, ``bench_loader.py``) and ``tests/data/``. Test modules are imported by their basename (pytest's
``prepend`` import mode, no ``__init__.py``), so no two may share one. The paths that name test
modules outside them (the Makefile's wall-clock modules, the suite's order in ``conftest.py``)
must name modules that exist.
"""

from __future__ import annotations

import re
from pathlib import Path

import conftest

ROOT = Path(__file__).resolve().parents[2]
TESTS = ROOT / "tests"
PACKAGE = ROOT / "src" / "railstop"

#: Folders of tests/ that mirror no package: the top-level modules of src/railstop and the
#: end-to-end tests.
EXTRA_FOLDERS = frozenset({"foundations", "e2e"})
#: Not a folder of tests even though ``railstop.data`` is a package: tests/data holds test data.
NOT_TEST_FOLDERS = frozenset({"data"})


def _is_test_module(path: Path) -> bool:
    """What pytest collects as a test module (its default ``python_files``)."""
    return path.suffix == ".py" and (path.name.startswith("test_") or path.stem.endswith("_test"))


def allowed_folders(package: Path = PACKAGE) -> frozenset[str]:
    """The folders of tests/ that may hold test modules: one per package of ``package``, and
    :data:`EXTRA_FOLDERS`."""
    packages = {p.parent.name for p in package.glob("*/__init__.py")}
    return frozenset(packages - NOT_TEST_FOLDERS) | EXTRA_FOLDERS


def misplaced(tests: Path, folders: frozenset[str]) -> list[str]:
    """Each test module under ``tests`` that is not directly in one of ``folders``, and each
    basename that two test modules share."""
    found = []
    seen: dict[str, str] = {}
    for path in sorted(tests.rglob("*.py")):
        rel = path.relative_to(tests)
        if "__pycache__" in rel.parts or not _is_test_module(path):
            continue
        if len(rel.parts) != 2 or rel.parts[0] not in folders:
            found.append(f"{rel.as_posix()}: not in tests/<package>/, tests/foundations/ or tests/e2e/")
        if path.name in seen:
            found.append(f"{rel.as_posix()}: the same basename as {seen[path.name]}")
        seen.setdefault(path.name, rel.as_posix())
    return found


def test_every_test_module_sits_beside_its_package_or_in_e2e() -> None:
    assert not misplaced(TESTS, allowed_folders()), "\n".join(misplaced(TESTS, allowed_folders()))


def test_the_folders_are_the_packages_of_the_source() -> None:
    folders = allowed_folders()
    assert {"cli", "config", "link", "sim", "wayside", "e2e", "foundations"} <= folders
    assert "data" not in folders and "__pycache__" not in folders


def test_the_check_catches_a_stray_module(tmp_path: Path) -> None:
    (tmp_path / "sim").mkdir()
    (tmp_path / "sim" / "test_good.py").write_text("", encoding="utf-8")
    (tmp_path / "test_at_the_root.py").write_text("", encoding="utf-8")
    (tmp_path / "misc").mkdir()
    (tmp_path / "misc" / "test_elsewhere.py").write_text("", encoding="utf-8")
    (tmp_path / "e2e" / "deeper").mkdir(parents=True)
    (tmp_path / "e2e" / "deeper" / "test_deep.py").write_text("", encoding="utf-8")
    (tmp_path / "e2e" / "test_good.py").write_text("", encoding="utf-8")
    (tmp_path / "helper.py").write_text("", encoding="utf-8")  # a helper at the root is fine
    found = misplaced(tmp_path, frozenset({"sim", "e2e"}))
    assert [line.split(":")[0] for line in found] == [
        "e2e/deeper/test_deep.py",
        "misc/test_elsewhere.py",
        "sim/test_good.py",
        "test_at_the_root.py",
    ]
    assert "the same basename as e2e/test_good.py" in found[2]


def test_the_makefiles_wall_clock_modules_exist() -> None:
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    (line,) = re.findall(r"^WALL_CLOCK_TESTS\s*=(.*)$", makefile, re.M)
    names = line.split()
    assert names, "WALL_CLOCK_TESTS names no module"
    missing = [name for name in names if not (ROOT / name).is_file()]
    assert not missing, f"the Makefile's WALL_CLOCK_TESTS name no such file: {missing}"


def test_the_slow_modules_conftest_runs_first_exist() -> None:
    missing = [name for name in conftest._SLOW_FIRST if not (TESTS / name).is_file()]
    assert not missing, f"conftest._SLOW_FIRST names no such module under tests/: {missing}"
