"""SPEC §1 claims 7, 20: ``railstop stop``, ``campaign`` and ``line run`` send their records to a
running management office too (``--office HOST:PORT``, the key from RAILSTOP_OFFICE_KEY), over the
office's authenticated link, as the live stations do. End to end: ``railstop office serve`` as a
real process, the simulators as real processes, the office's real SQLite file."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from railstop.cli.common import SIMULATOR_OFFICE_ID
from railstop.link.codec import decode
from railstop.store import open_store
from zygote import run_cli

KEY = bytes(range(32))
ENV = {**os.environ, "RAILSTOP_OFFICE_KEY": KEY.hex()}
NO_KEY = {k: v for k, v in os.environ.items() if k != "RAILSTOP_OFFICE_KEY"}


@pytest.fixture
def office(tmp_path: Path) -> Iterator[tuple[str, Path]]:
    """A running office on a free port: (its address, its database)."""
    db = tmp_path / "office.db"
    proc = subprocess.Popen(
        [sys.executable, "-m", "railstop.cli", "office", "serve", "--db", str(db), "--port", "0"],
        env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        assert "office listening on 127.0.0.1:" in line, line
        yield f"127.0.0.1:{line.split('127.0.0.1:')[1].split()[0]}", db
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def _reports(db: Path, kind: str) -> list[dict[str, object]]:
    with open_store(str(db)) as store:
        return list(store.office_reports(kind=kind))


def test_a_stop_sends_its_commands_and_its_result(office: tuple[str, Path], tmp_path: Path) -> None:
    """Every command the wayside computed (with the frame that went on the air) and the stop's
    result reach the office, from the simulators' sender id; the local database has the stop too."""
    address, db = office
    p = run_cli("stop", "--json", "--db", str(tmp_path / "local.db"), "--office", address, env=ENV)
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    commands = _reports(db, "tasc-command")
    results = _reports(db, "stop-result")
    assert len(commands) == out["commands_sent"] > 0 and len(results) == 1
    assert {r["sender_id"] for r in commands + results} == {SIMULATOR_OFFICE_ID}
    result = results[0]["data"]
    assert result["station"] == out["station"] and result["error_m"] == round(out["stop_error_m"], 3)  # type: ignore[index]
    for r in commands:
        data = r["data"]
        assert data["st"] == out["station"]  # type: ignore[index]
        assert decode(bytes.fromhex(data["air"])).TYPE.startswith("tasc")  # type: ignore[index]
    assert out["office_link"]["acknowledged"] == len(commands) + 1
    with open_store(str(tmp_path / "local.db")) as store:
        assert len(store.runs()) == 1


def test_a_campaign_sends_its_summary_and_a_line_run_its_stops_and_dwells(
    office: tuple[str, Path], tmp_path: Path
) -> None:
    address, db = office
    p = run_cli(
        "campaign", "--runs", "50", "--json", "--out", str(tmp_path / "c"), "--db", str(tmp_path / "c.db"),
        "--office", address, env=ENV,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    row = json.loads(p.stdout)
    (summary,) = _reports(db, "campaign-result")
    data = summary["data"]
    assert data["runs"] == 50 and data["p99"] == round(row["p99_abs_m"], 4)  # type: ignore[index]
    p = run_cli("line", "run", "--trains", "2", "--duration-s", "600", "--json", "--office", address, env=ENV)
    assert p.returncode == 0, p.stderr
    line = json.loads(p.stdout)
    assert len(_reports(db, "stop-result")) == line["stops"] > 0
    dwells = _reports(db, "dwell-result")
    assert len(dwells) >= line["stops"] - 2 and {d["data"]["outcome"] for d in dwells} == {"start-enable"}  # type: ignore[index]


def test_without_a_key_or_an_office_one_line_exit_2_and_the_local_record_kept(tmp_path: Path) -> None:
    """No key: refused before any work (one line, exit 2). No office listening: the stop is in
    the local database, and the error says the reports were not acknowledged."""
    p = run_cli("stop", "--no-db", "--office", "127.0.0.1:9", env=NO_KEY)
    assert p.returncode == 2 and "RAILSTOP_OFFICE_KEY" in p.stderr and len(p.stderr.strip().splitlines()) == 1
    p = run_cli("stop", "--no-db", "--office", "nowhere", env=ENV)
    assert p.returncode == 2 and "--office" in p.stderr and "Traceback" not in p.stderr
    local = tmp_path / "local.db"
    p = run_cli("stop", "--db", str(local), "--office", "127.0.0.1:9", env=ENV, timeout=120)
    assert p.returncode == 2, p.stderr
    assert "not acknowledged" in p.stderr and "local records are kept" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1
    with open_store(str(local)) as store:
        assert len(store.runs()) == 1
