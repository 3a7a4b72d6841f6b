"""What ``railstop`` imports and writes on its light paths (the CLI start-up issue).

``stop --json --no-db`` must not load SQLAlchemy, matplotlib or pyarrow, and must
not create a database; ``stop --json`` without ``--no-db`` still writes one (SPEC:
every command goes to the database). Behaviour only: nothing here is timed.
"""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

HEAVY = ("sqlalchemy", "matplotlib", "pyarrow")
MARK = "MODULES:"

# Runs railstop.cli:main with the given argv, then prints which watched modules got imported.
_PROBE = textwrap.dedent(
    """
    import json, sys
    from railstop.cli import main

    watched = json.loads(sys.argv[1])
    sys.argv = ["railstop", *sys.argv[2:]]
    try:
        main()
    finally:
        print("MODULES:" + json.dumps(sorted(m for m in watched if m in sys.modules)), flush=True)
    """
)


def probe(*args: str, cwd: Path, watched: tuple[str, ...] = HEAVY) -> tuple[int, str, list[str], str]:
    """(exit code, stdout without the probe line, watched modules that were imported, stderr)."""
    p = subprocess.run(
        [sys.executable, "-c", _PROBE, json.dumps(watched), *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    lines = p.stdout.splitlines()
    assert lines and lines[-1].startswith(MARK), p.stdout + p.stderr
    return p.returncode, "\n".join(lines[:-1]), json.loads(lines[-1][len(MARK) :]), p.stderr


def test_stop_json_no_db_imports_nothing_heavy_and_writes_no_db(tmp_path: Path) -> None:
    code, out, imported, err = probe(
        "stop", "--json", "--no-db", cwd=tmp_path, watched=(*HEAVY, "railstop.sim.position_run")
    )
    assert code == 0, err
    assert json.loads(out)["station"] == "Riverside"
    assert imported == [], f"stop --json --no-db imported {imported}"
    assert not (tmp_path / "railstop.db").exists()
    assert list(tmp_path.iterdir()) == []


def test_stop_json_writes_the_default_db(tmp_path: Path) -> None:
    code, out, imported, err = probe("stop", "--json", cwd=tmp_path)
    assert code == 0, err
    data = json.loads(out)
    db = tmp_path / "railstop.db"
    assert db.is_file()
    with sqlite3.connect(db) as con:
        assert con.execute("select count(*) from runs").fetchone()[0] == 1
        assert con.execute("select count(*) from commands").fetchone()[0] == data["commands"]
    # Writing the database needs SQLAlchemy, but still neither matplotlib nor pyarrow.
    assert imported == ["sqlalchemy"]


def test_db_and_no_db_exclude_each_other(tmp_path: Path) -> None:
    code, out, _, err = probe("stop", "--json", "--no-db", "--db", str(tmp_path / "x.db"), cwd=tmp_path)
    assert code == 2
    assert out == ""
    assert "--db and --no-db exclude each other" in err.replace("\n", "")
    assert "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_campaign_code_does_not_load_matplotlib(tmp_path: Path) -> None:
    """The campaign engine imports the report's statistics; the plots load matplotlib themselves."""
    p = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys, railstop.sim.campaign, railstop.report.campaign_report; "
            "print(sorted(m for m in ('matplotlib', 'sqlalchemy') if m in sys.modules))",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "[]"


def test_help_still_lists_every_command_in_order(tmp_path: Path) -> None:
    """``position-run`` is built lazily; the listing, its help and typo suggestions are unchanged."""
    exe = [sys.executable, "-m", "railstop.cli"]

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [*exe, *args], cwd=tmp_path, capture_output=True, text=True, timeout=300, check=False
        )

    p = run("--help")
    assert p.returncode == 0, p.stderr
    names = ["dwell", "position-run", "check", "stop", "demo", "campaign", "compare", "report", "doors"]
    where = [p.stdout.find(f"\n  {name} ") for name in names]
    assert all(i >= 0 for i in where), p.stdout
    assert where == sorted(where), p.stdout
    p = run("position-run", "--help")
    assert p.returncode == 0, p.stderr
    assert "--diameter-error-pct" in p.stdout and "--no-gnss" in p.stdout
    p = run("positon-run")
    assert p.returncode == 2
    assert "Did you mean 'position-run'?" in p.stderr
    p = run("stop", "--help")
    assert p.returncode == 0 and "--no-db" in p.stdout


def test_help_lists_position_run_without_building_it(tmp_path: Path) -> None:
    """The group's help shows ``position-run``'s line from a placeholder: the line model it would
    import is not loaded; the placeholder's line is the command's own docstring."""
    import inspect

    from railstop.cli import POSITION_RUN_HELP
    from railstop.cli.position import position_run

    code, text, loaded, _ = probe(
        "--help", cwd=tmp_path, watched=("railstop.sim.position_run", "railstop.sim.line")
    )
    assert code == 0 and "position-run" in text
    assert loaded == []
    assert " ".join((inspect.getdoc(position_run) or "").split()) == POSITION_RUN_HELP


def test_help_loads_no_data_model_nor_the_simulation(tmp_path: Path) -> None:
    """`railstop --help` and `railstop telegram --help` build the command line only: not the data
    schemas, the media models, the codec, numpy, the event loop, the compiler or the simulation
    (issue 37: start-up). (Typer itself looks at pydantic when it builds a sub-command's
    parameters.)"""
    ours = (
        *HEAVY,
        "railstop.config",
        "railstop.link.channel",
        "railstop.link.codec",
        "numba",
        "numpy",
        "asyncio",
        "railstop.sim.engine",
    )
    for args, watched in ((("--help",), (*ours, "pydantic")), (("telegram", "--help"), ours)):
        code, out, imported, err = probe(*args, cwd=tmp_path, watched=watched)
        assert code == 0, err
        assert "Usage: railstop" in out
        assert imported == [], f"{' '.join(args)} imported {imported}"


def test_the_telegram_help_names_the_codecs_types() -> None:
    """``railstop telegram --help`` lists the types from a constant (no codec, no numpy at start-up):
    the codec's own types, in its order."""
    from railstop.cli.telegram import TYPE_NAMES
    from railstop.link.codec import TYPES

    assert tuple(TYPES) == TYPE_NAMES


def test_reading_data_loads_no_compiler(tmp_path: Path) -> None:
    """``check`` (with a disturbance set too), the reference of the files and a dwell read data and
    run Python units only: numba (about 0.2 s to import) stays out; the random streams' compiled
    cores live apart (``railstop.stream_cores``)."""
    for args in (
        ("check", "--disturbances", "standard"),
        ("formats",),
        ("dwell", "--stop-error-m", "0.8"),
        ("telegram", "decode", "9600070202de3ec9"),
    ):
        code, out, imported, err = probe(*args, cwd=tmp_path, watched=("numba", "railstop.stream_cores"))
        assert code == 0, (args, err)
        assert out, args
        assert imported == [], f"railstop {' '.join(args)} imported {imported}"
