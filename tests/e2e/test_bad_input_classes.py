"""Classes of bad input closed once, each by one rule (issue 38), through the real command.

- A data file that is not a regular file of bounded size (a folder, ``/dev/zero``, a named pipe
  nobody writes, a file larger than any data file) is refused before it is read
  (``railstop.config.files.read_text_file``): no hang, no memory exhaustion.
- TOML nested deeper than the parser can follow is a syntax error, not a RecursionError.
- An empty value for any option or argument is refused before the command runs (``--out ""``
  would otherwise be the current folder).
Each: one ``error:`` line naming the file or option, exit code 2, nothing written.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from railstop.config.files import MAX_DATA_FILE_BYTES

EXE = [sys.executable, "-m", "railstop.cli"]


def run(
    *args: str, cwd: Path, timeout: float = 60.0, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*EXE, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout, check=False, env=env
    )


def one_error(r: subprocess.CompletedProcess[str], *needles: str) -> None:
    assert r.returncode == 2, (r.returncode, r.stderr)
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    assert "Traceback" not in r.stderr
    for n in needles:
        assert n in lines[0], (n, lines[0])


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="no /dev/zero")
def test_a_device_is_refused_before_it_is_read(tmp_path: Path) -> None:
    one_error(
        run("check", "--line", "/dev/zero", cwd=tmp_path, timeout=30), "/dev/zero", "not a regular file"
    )


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes")
def test_a_named_pipe_nobody_writes_does_not_hang(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "line.toml")
    one_error(
        run("check", "--line", "line.toml", cwd=tmp_path, timeout=30), "line.toml", "not a regular file"
    )
    os.mkfifo(tmp_path / "ops.toml")
    env = {**os.environ, "RAILSTOP_OFFICE_KEY": os.urandom(32).hex()}
    r = run(
        "office", "serve", "--db", "o.db", "--operators", "ops.toml", "--port", "0", "--http-port", "0",
        cwd=tmp_path, timeout=30, env=env,
    )  # fmt: skip
    one_error(r, "ops.toml", "not a regular file")


def test_a_folder_and_a_file_too_large_are_refused(tmp_path: Path) -> None:
    (tmp_path / "adir").mkdir()
    one_error(run("check", "--vehicle", "adir", cwd=tmp_path), "adir", "a folder")
    big = tmp_path / "big.toml"
    with big.open("wb") as fh:
        fh.truncate(MAX_DATA_FILE_BYTES + 1)  # sparse: no disk used
    one_error(run("check", "--line", "big.toml", cwd=tmp_path), "big.toml", "too large")


def test_toml_nested_too_deeply_is_a_syntax_error(tmp_path: Path) -> None:
    (tmp_path / "deep.toml").write_text("a = " + "[" * 50_000 + "]" * 50_000 + "\n", encoding="utf-8")
    one_error(run("check", "--line", "deep.toml", cwd=tmp_path), "deep.toml", "nested too deeply")
    one_error(run("campaign", "--disturbances", "deep.toml", "--runs", "5", cwd=tmp_path), "deep.toml")


@pytest.mark.parametrize(
    "args, named",
    [
        (("campaign", "--runs", "5", "--out", ""), "--out"),
        (("campaign", "--runs", "5", "--out="), "--out"),
        (("compare", "--runs", "5", "--out", " "), "--out"),
        (("report", ""), "argument 2"),
        (("check", "--line", ""), "--line"),
    ],
    ids=["out-empty", "out-equals", "out-blank", "report-empty", "line-empty"],
)
def test_an_empty_value_is_refused_and_nothing_is_written(
    tmp_path: Path, args: tuple[str, ...], named: str
) -> None:
    one_error(run(*args, cwd=tmp_path), named, "empty value")
    assert list(tmp_path.iterdir()) == []  # not the current folder either


def test_a_page_port_in_use_is_one_line_not_a_traceback(tmp_path: Path) -> None:
    import socket

    env = {**os.environ, "RAILSTOP_OFFICE_KEY": os.urandom(32).hex()}
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = str(taken.getsockname()[1])
        r = run("office", "serve", "--db", "o.db", "--port", "0", "--http-port", port, cwd=tmp_path, env=env)
    one_error(r, "--http-port", port, "in use")


def test_an_unusable_cache_folder_is_refused_not_replaced_by_one_in_the_sources(tmp_path: Path) -> None:
    """RAILSTOP_CACHE_DIR that cannot be written (here a folder under a file: not even root can
    make it): one line naming it, exit 2; numba's own fallback (a cache beside the package's
    sources) is never taken."""
    import railstop

    package = Path(railstop.__file__).parent
    before = sorted(package.rglob("*.nbi"))
    blocker = tmp_path / "afile"
    blocker.write_text("x", encoding="utf-8")
    env = {**os.environ, "RAILSTOP_CACHE_DIR": str(blocker / "cache")}
    r = run("stop", "--json", "--no-db", cwd=tmp_path, env=env)
    one_error(r, "RAILSTOP_CACHE_DIR", str(blocker / "cache"), "cannot write")
    assert sorted(package.rglob("*.nbi")) == before


def _numbers(data: object, path: tuple[object, ...] = ()) -> list[tuple[tuple[object, ...], object]]:
    """Every number (not a bool) in parsed TOML, with its path; the first of each list only."""
    if isinstance(data, dict):
        return [n for k, v in data.items() for n in _numbers(v, (*path, k))]
    if isinstance(data, list):
        return _numbers(data[0], (*path, 0)) if data else []
    if isinstance(data, int | float) and not isinstance(data, bool):
        return [(path, data)]
    return []


def _quoted(data: object, path: tuple[object, ...]) -> object:
    """A deep copy of ``data`` with the number at ``path`` written as a string."""
    import copy

    out = copy.deepcopy(data)
    cur = out
    for part in path[:-1]:
        cur = cur[part]  # type: ignore[index]
    cur[path[-1]] = str(cur[path[-1]])  # type: ignore[index]
    return out


def test_a_number_written_as_a_string_is_refused_in_every_data_file() -> None:
    """The schemas are strict: "1200" where 1200 belongs is an error naming the key, never converted
    (a quoted number is a typing error, and the data must say what it means). Every number of
    every embedded data file, quoted one at a time."""
    import tomllib
    from importlib import resources

    from railstop.config.loader import format_loc, validate
    from railstop.errors import ConfigError
    from railstop.report.file_formats import file_formats

    checked = 0
    for fmt in file_formats():
        if not fmt.embedded or fmt.root:
            continue
        name = fmt.embedded.removeprefix("railstop/data/")
        data = tomllib.loads(resources.files("railstop.data").joinpath(name).read_text(encoding="utf-8"))
        validate(fmt.model, data, fmt.embedded)  # the file as it is: valid
        for path, value in _numbers(data):
            with pytest.raises(ConfigError) as e:
                validate(fmt.model, _quoted(data, path), fmt.embedded)  # type: ignore[arg-type]
            where = format_loc(tuple(p for p in path))  # type: ignore[arg-type]
            assert where in str(e.value) and repr(str(value)) in str(e.value), (where, str(e.value))
            checked += 1
    assert checked > 100, checked


def test_a_terminal_that_cannot_show_a_character_gets_a_replacement_not_a_traceback(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONIOENCODING": "ascii", "LC_ALL": "C"}
    r = run("stop", "--no-db", cwd=tmp_path, env=env, timeout=120)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert "within the PSD tolerance ?0.35 m" in r.stdout  # the ± replaced
    r = run("formats", "line", cwd=tmp_path, env=env)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr


def test_another_programs_database_is_refused_untouched(tmp_path: Path) -> None:
    import sqlite3

    db = tmp_path / "theirs.db"
    with sqlite3.connect(db) as con:
        con.execute("create table customers (id integer primary key, name text)")
        con.execute("insert into customers values (1, 'x')")
    before = db.read_bytes()
    one_error(
        run("stop", "--db", "theirs.db", cwd=tmp_path), "theirs.db", "not a railstop database", "customers"
    )
    assert db.read_bytes() == before
