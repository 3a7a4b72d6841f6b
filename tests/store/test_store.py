"""The event database (SPEC §1 claims 8, 20) on a real SQLite file."""

from __future__ import annotations

import dataclasses
import math
import os
import sqlite3
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from railstop.errors import RailstopError
from railstop.store import COMMAND_FIELDS, RESULT_FIELDS, SENT_FIELDS, StopRecord, open_store


def _command(i: int, **changes: Any) -> dict[str, Any]:
    row: dict[str, Any] = {
        "run": 0,
        "t_s": 1.5 + 4.0 * i,
        "form": 6,
        "detector": i,
        "passage_s": 1.49 + 4.0 * i,
        "distance_m": 220.0 - 50.0 * i,
        "speed_mps": 16.6 - 3.0 * i,
        "measured_decel_mps2": None if i == 0 else 0.68,
        "gain": 1.0 + 0.01 * i,
        "required_decel_mps2": 0.66,
        "command_decel_mps2": 0.665,
        "notch": 5,
        "delta": 0,
        "effect_s": 2.6 + 4.0 * i,
        # What went on the air (claim 20): a form-6 telegram at the wire's resolution.
        "emergency": False,
        "telegram_type": "tasc-required-decel",
        "telegram": {"train_id": 1, "detector": i, "required_mps2": 0.665},
    }
    row.update(changes)
    return row


def _record(**changes: Any) -> StopRecord:
    base = StopRecord(
        run_key="stop|demo|Riverside|tasc-pwm|seed=1",
        station="Riverside",
        controller="tasc-pwm",
        seed=1,
        line="railstop demo line",
        parameters={
            "stop_point_m": 1200.0,
            "detectors_before_stop_m": "220,150,90,40,6",
            "load_factor": 0.0,
            "low_mu_start_m": math.inf,  # "no patch" must survive the JSON
            "note": None,
        },
        commands=[_command(i) for i in range(3)],
        stop_error_m=0.0049,
        stop_time_s=25.4,
        max_jerk_mps3=0.61,
        notch_changes=0,
        commands_received=3,
        commands_sent=3,
        stopped=True,
        created_utc="2024-05-01T10:00:00+00:00",
    )
    return dataclasses.replace(base, **changes)


def _count(db: Path, table: str) -> int:
    with sqlite3.connect(db) as con:
        return int(con.execute(f"SELECT COUNT(*) FROM {table}").fetchone()[0])


def test_save_and_read_back(tmp_path: Path) -> None:
    db = tmp_path / "events.db"
    rec = _record()
    with open_store(db) as store:
        run_id = store.save_stop(rec)
        runs = store.runs()
        assert [r["id"] for r in runs] == [run_id]
        assert runs[0]["run_key"] == rec.run_key
        assert runs[0]["station"] == "Riverside"
        assert runs[0]["controller"] == "tasc-pwm"
        assert runs[0]["seed"] == 1
        assert runs[0]["line"] == "railstop demo line"
        assert runs[0]["created_utc"] == rec.created_utc
        assert runs[0]["parameters"] == rec.parameters
        assert store.commands(run_id) == rec.commands
        assert store.result(run_id) == {name: getattr(rec, name) for name in RESULT_FIELDS}
    # A real file with the three tables of the brief, one row per command.
    assert db.is_file()
    assert (_count(db, "runs"), _count(db, "commands"), _count(db, "stop_results")) == (1, 3, 1)
    with sqlite3.connect(db) as con:
        cols = {row[1] for row in con.execute("PRAGMA table_info(commands)")}
    assert set(COMMAND_FIELDS) <= cols
    assert {"emergency", "telegram_type", "telegram_json"} <= cols
    with open_store(db) as store:
        assert list(store.commands(run_id)[0]) == [*COMMAND_FIELDS, *SENT_FIELDS]


def test_data_survives_reopening(tmp_path: Path) -> None:
    db = tmp_path / "events.db"
    with open_store(db) as store:
        run_id = store.save_stop(_record())
    with open_store(str(db)) as store:
        assert store.commands(run_id) == _record().commands
        assert store.result(run_id) is not None


def test_same_run_key_twice_keeps_one_run_with_latest_rows(tmp_path: Path) -> None:
    db = tmp_path / "events.db"
    first = _record()
    second = _record(
        commands=[_command(i, gain=2.0) for i in range(2)],
        stop_error_m=-0.12,
        commands_sent=2,
        commands_received=2,
        created_utc="2024-05-02T10:00:00+00:00",
    )
    with open_store(db) as store:
        id1 = store.save_stop(first)
        assert store.save_stop(first) == id1  # identical: nothing changes
        assert store.commands(id1) == first.commands
        id2 = store.save_stop(second)
        assert id2 == id1
        assert len(store.runs()) == 1
        assert store.commands(id1) == second.commands
        result = store.result(id1)
        assert result is not None
        assert result["stop_error_m"] == -0.12
        assert result["commands_sent"] == 2
        assert store.runs()[0]["created_utc"] == second.created_utc
    assert (_count(db, "runs"), _count(db, "commands"), _count(db, "stop_results")) == (1, 2, 1)


def test_different_run_keys_are_different_runs(tmp_path: Path) -> None:
    with open_store(tmp_path / "events.db") as store:
        a = store.save_stop(_record())
        b = store.save_stop(_record(run_key="other", seed=2))
        assert a != b
        assert [r["run_key"] for r in store.runs()] == [_record().run_key, "other"]
        assert store.commands(b) == _record().commands


def test_none_values_round_trip(tmp_path: Path) -> None:
    rec = _record(
        stop_time_s=None,
        stopped=False,
        commands=[_command(0, measured_decel_mps2=None, required_decel_mps2=None)],
    )
    with open_store(tmp_path / "events.db") as store:
        run_id = store.save_stop(rec)
        (cmd,) = store.commands(run_id)
        assert cmd["measured_decel_mps2"] is None
        assert cmd["required_decel_mps2"] is None
        result = store.result(run_id)
        assert result is not None
        assert result["stop_time_s"] is None
        assert result["stopped"] is False
        assert store.runs()[0]["parameters"]["note"] is None


def test_nan_means_none_where_allowed_and_numpy_scalars_are_accepted(tmp_path: Path) -> None:
    # The engine marks "unknown" with NaN and hands out numpy scalars.
    rec = _record(
        seed=np.int64(7),
        stop_time_s=float("nan"),
        max_jerk_mps3=np.float64(0.5),
        stopped=np.bool_(True),
        commands=[_command(0, measured_decel_mps2=float("nan"), notch=np.int64(4))],
    )
    with open_store(tmp_path / "events.db") as store:
        run_id = store.save_stop(rec)
        assert store.commands(run_id)[0]["measured_decel_mps2"] is None
        assert store.commands(run_id)[0]["notch"] == 4
        result = store.result(run_id)
        assert result is not None
        assert result["stop_time_s"] is None
        assert result["stopped"] is True


def test_nan_where_a_value_is_required_is_refused(tmp_path: Path) -> None:
    with open_store(tmp_path / "events.db") as store:
        with pytest.raises(RailstopError, match=r"commands\[1\]\.distance_m"):
            store.save_stop(_record(commands=[_command(0), _command(1, distance_m=math.nan)]))
        with pytest.raises(RailstopError, match=r"commands\[0\]\.gain: missing"):
            row = _command(0)
            del row["gain"]
            store.save_stop(_record(commands=[row]))
        # What went on the air is part of the record (claim 20): required, and checked.
        for name in SENT_FIELDS:
            row = _command(0)
            del row[name]
            with pytest.raises(RailstopError, match=rf"commands\[0\]\.{name}: missing"):
                store.save_stop(_record(commands=[row]))
        with pytest.raises(RailstopError, match=r"commands\[0\]\.emergency: expected true or false"):
            store.save_stop(_record(commands=[_command(0, emergency=1)]))
        with pytest.raises(RailstopError, match=r"commands\[0\]\.telegram: must be a dict"):
            store.save_stop(_record(commands=[_command(0, telegram="required 0.665")]))
        with pytest.raises(RailstopError, match=r"commands\[0\]\.telegram\.x: expected a number"):
            store.save_stop(_record(commands=[_command(0, telegram={"x": object()})]))
        # Nothing half-written.
        assert store.runs() == []


def test_unknown_read_ids(tmp_path: Path) -> None:
    with open_store(tmp_path / "events.db") as store:
        assert store.runs() == []
        assert store.commands(42) == []
        assert store.result(42) is None


def test_missing_directory_is_a_one_line_railstop_error(tmp_path: Path) -> None:
    bad = tmp_path / "no" / "such" / "dir" / "events.db"
    with pytest.raises(RailstopError) as info:
        open_store(bad)
    message = str(info.value)
    assert str(bad) in message
    assert "\n" not in message
    assert info.value.__cause__ is None  # no SQLAlchemy traceback chained on
    assert info.value.__suppress_context__ or info.value.__context__ is None
    assert not bad.parent.exists()


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root may write anywhere")
def test_read_only_directory_is_a_railstop_error(tmp_path: Path) -> None:
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(RailstopError, match="not writable") as info:
            open_store(ro / "events.db")
        assert str(ro / "events.db") in str(info.value)
    finally:
        ro.chmod(0o700)


def test_directory_as_database_file_is_refused(tmp_path: Path) -> None:
    with pytest.raises(RailstopError, match="directory"):
        open_store(tmp_path)


def test_file_that_is_not_a_database(tmp_path: Path) -> None:
    junk = tmp_path / "junk.db"
    junk.write_bytes(b"this is not sqlite " * 100)
    with pytest.raises(RailstopError) as info:
        open_store(junk)
    assert str(junk) in str(info.value)
    assert "\n" not in str(info.value)


def test_sqlite_url_is_accepted(tmp_path: Path) -> None:
    db = tmp_path / "url.db"
    with open_store(f"sqlite:///{db}") as store:
        run_id = store.save_stop(_record())
        assert store.result(run_id) is not None
    assert db.is_file()


def test_closed_store_refuses_work(tmp_path: Path) -> None:
    store = open_store(tmp_path / "events.db")
    store.close()
    store.close()  # twice is harmless
    with pytest.raises(RailstopError, match="closed"):
        store.runs()
