"""The database unit of SPEC §1 claims 8 and 20 as the simulation fills it (issue 13, item 7).

Claim 8: the stopping point, the detector positions and the braking data
(``stations`` rows and each run's parameters); claim 20: the history of every
computed command, with what went on the air (the telegram type and its
decoded fields). Real SQLite files in ``tmp_path``; files of schema version 1
are migrated on opening, files of a newer version refused. The PostgreSQL
tests run on a real server (``conftest.postgres_url``: a throwaway cluster of
the machine's PostgreSQL, or ``RAILSTOP_TEST_POSTGRES_URL``).
"""

from __future__ import annotations

import dataclasses
import json
import sqlite3
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import railstop.store.db as store_db
from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import DisturbanceSet, load_disturbances
from railstop.controllers import TASC_PWM
from railstop.errors import RailstopError, SimulationError
from railstop.link.codec import quantize
from railstop.link.tasc_link import command_records
from railstop.messages import (
    TEL_DELTA,
    TEL_DETECTOR,
    TEL_DISTANCE,
    TEL_EMERGENCY,
    TEL_MEASURED,
    TEL_NOTCH,
    TEL_SIZE,
    TEL_STEP,
)
from railstop.sim.single import run_stop, station_record, stop_record
from railstop.store import SCHEMA_VERSION, SENT_FIELDS, STATION_FIELDS, StopRecord, open_store
from railstop.wayside.tasc_unit import CR_DETECTOR, CR_EMERGENCY, CR_SIZE, SignalForm
from zygote import run_cli

LINE = default_line()
VEHICLE = default_vehicle()
RIVERSIDE = LINE.station("Riverside")

# Schema version 1 exactly as railstop wrote it (SQLite; ``{id}`` is the key's type).
OLD_LAYOUT = """
CREATE TABLE runs (
    id {id} NOT NULL, run_key VARCHAR NOT NULL, station VARCHAR NOT NULL, controller VARCHAR NOT NULL,
    seed BIGINT NOT NULL, line VARCHAR NOT NULL, parameters_json TEXT NOT NULL,
    created_utc VARCHAR(40) NOT NULL,
    PRIMARY KEY (id), CONSTRAINT uq_runs_run_key UNIQUE (run_key)
);
CREATE TABLE campaigns (
    id {id} NOT NULL, campaign_key VARCHAR NOT NULL, station VARCHAR NOT NULL,
    controller VARCHAR NOT NULL, seed BIGINT NOT NULL, runs INTEGER NOT NULL,
    disturbances VARCHAR NOT NULL, runs_file TEXT NOT NULL, manifest_json TEXT NOT NULL,
    summary_json TEXT NOT NULL, created_utc VARCHAR(40) NOT NULL,
    PRIMARY KEY (id), CONSTRAINT uq_campaigns_key UNIQUE (campaign_key)
);
CREATE TABLE dwell_events (
    id {id} NOT NULL, dwell_key VARCHAR NOT NULL, station VARCHAR NOT NULL, seq INTEGER NOT NULL,
    t_s FLOAT NOT NULL, signal VARCHAR NOT NULL, value TEXT NOT NULL,
    PRIMARY KEY (id), CONSTRAINT uq_dwell_events_key_seq UNIQUE (dwell_key, seq)
);
CREATE INDEX ix_dwell_events_dwell_key ON dwell_events (dwell_key);
CREATE TABLE commands (
    id {id} NOT NULL, run_id INTEGER NOT NULL, seq INTEGER NOT NULL, run INTEGER NOT NULL,
    t_s FLOAT NOT NULL, form INTEGER NOT NULL, detector INTEGER NOT NULL, passage_s FLOAT NOT NULL,
    distance_m FLOAT NOT NULL, speed_mps FLOAT NOT NULL, measured_decel_mps2 FLOAT,
    gain FLOAT NOT NULL, required_decel_mps2 FLOAT, command_decel_mps2 FLOAT NOT NULL,
    notch INTEGER NOT NULL, delta INTEGER NOT NULL, effect_s FLOAT NOT NULL,
    PRIMARY KEY (id), CONSTRAINT uq_commands_run_seq UNIQUE (run_id, seq),
    FOREIGN KEY(run_id) REFERENCES runs (id) ON DELETE CASCADE
);
CREATE INDEX ix_commands_run_id ON commands (run_id);
CREATE TABLE stop_results (
    run_id INTEGER NOT NULL, stop_error_m FLOAT NOT NULL, stop_time_s FLOAT,
    max_jerk_mps3 FLOAT NOT NULL, notch_changes INTEGER NOT NULL, commands_received INTEGER NOT NULL,
    commands_sent INTEGER NOT NULL, stopped BOOLEAN NOT NULL,
    PRIMARY KEY (run_id), FOREIGN KEY(run_id) REFERENCES runs (id) ON DELETE CASCADE
);
"""
OLD_ROWS = """
INSERT INTO runs (run_key, station, controller, seed, line, parameters_json, created_utc)
VALUES ('old|stop', 'Riverside', 'tasc-step', 3, 'railstop demo line', '{"load_factor": 0.5}',
        '2024-01-01T00:00:00+00:00');
INSERT INTO commands (run_id, seq, run, t_s, form, detector, passage_s, distance_m, speed_mps,
    measured_decel_mps2, gain, required_decel_mps2, command_decel_mps2, notch, delta, effect_s)
VALUES (1, 0, 0, 1.5, 6, 0, 1.49, 330.0, 16.6, NULL, 1.0, 0.42, 0.42, 3, 0, 2.5);
INSERT INTO stop_results (run_id, stop_error_m, stop_time_s, max_jerk_mps3, notch_changes,
    commands_received, commands_sent, stopped)
VALUES (1, 0.01, 38.0, 0.6, 0, 5, 5, TRUE);
"""
OLD_COMMAND = {
    "run": 0,
    "t_s": 1.5,
    "form": 6,
    "detector": 0,
    "passage_s": 1.49,
    "distance_m": 330.0,
    "speed_mps": 16.6,
    "measured_decel_mps2": None,
    "gain": 1.0,
    "required_decel_mps2": 0.42,
    "command_decel_mps2": 0.42,
    "notch": 3,
    "delta": 0,
    "effect_s": 2.5,
    # Not known for a command written by schema version 1.
    "emergency": None,
    "telegram_type": None,
    "telegram": None,
}


def _stop(form: int | None = None, **changes: Any) -> tuple[StopRecord, Any]:
    result, batch = run_stop(
        line=LINE,
        station=RIVERSIDE,
        vehicle=VEHICLE,
        controller=TASC_PWM,
        seed=1,
        form=None if form is None else SignalForm(form),
        **changes,
    )
    return stop_record(result, line=LINE, station=RIVERSIDE, vehicle=VEHICLE), batch


def _saved_commands(record: StopRecord, db: Path | str) -> list[dict[str, Any]]:
    with open_store(db) as store:
        return store.commands(store.save_stop(record))


# ------------------------------------------------------------------ claim 8: stations, parameters


def test_station_row_written_once_and_updated_on_change(tmp_path: Path, monkeypatch: Any) -> None:
    db = tmp_path / "events.db"
    record, _ = _stop()
    with open_store(db) as store:
        times = iter(["2030-01-01T00:00:00+00:00", "2030-01-02T00:00:00+00:00", "2030-01-03T00:00:00+00:00"])
        monkeypatch.setattr(store_db, "_utc_now", lambda: next(times))
        store.save_stop(record)
        (first,) = store.stations()
        assert first["created_utc"] == first["updated_utc"] == "2030-01-01T00:00:00+00:00"
        # SPEC §1 claim 8: the stopping point and the detector positions, as the line data says.
        assert (first["line"], first["name"]) == (LINE.line.name, "Riverside")
        assert first["stop_point_m"] == RIVERSIDE.stop_point_m
        assert first["platform_length_m"] == RIVERSIDE.platform_length_m
        assert first["psd_tolerance_m"] == RIVERSIDE.psd_tolerance_m
        assert first["signal_form"] == RIVERSIDE.tasc.signal_form
        assert first["detector_positions_m"] == RIVERSIDE.detector_positions_m()
        assert first["detectors_before_stop_m"] == RIVERSIDE.tasc.detectors_before_stop_m
        assert RIVERSIDE.tasc.doppler is not None
        assert first["doppler_position_m"] == RIVERSIDE.stop_point_m + RIVERSIDE.tasc.doppler.beyond_stop_m
        assert first["tasc"] == RIVERSIDE.tasc.model_dump(mode="json")
        assert set(STATION_FIELDS) <= set(first)
        # Another stop at the same station, identical data: the row is left untouched.
        other, _ = _stop(form=2)
        store.save_stop(other)
        assert store.stations() == [first]
        # The station's data changed (a detector moved): the one row is updated.
        moved = RIVERSIDE.model_copy(
            update={
                "tasc": RIVERSIDE.tasc.model_copy(
                    update={"detectors_before_stop_m": [330.0, 230.0, 140.0, 60.0, 8.0]}
                )
            }
        )
        store.save_stop(dataclasses.replace(record, station_data=station_record(LINE, moved)))
        (second,) = store.stations()
        assert second["id"] == first["id"]
        assert second["created_utc"] == first["created_utc"]
        assert second["updated_utc"] == "2030-01-02T00:00:00+00:00"
        assert second["detector_positions_m"][-1] == RIVERSIDE.stop_point_m - 8.0
        assert second["tasc"]["detectors_before_stop_m"][-1] == 8.0
        assert store.station(LINE.line.name, "Riverside") == second
        assert store.station(LINE.line.name, "Nowhere") is None
    with sqlite3.connect(db) as con:
        assert con.execute("SELECT COUNT(*) FROM stations").fetchone()[0] == 1


def test_a_station_without_radar_has_no_doppler_position(tmp_path: Path) -> None:
    no_radar = RIVERSIDE.detectors_only()
    st = station_record(LINE, no_radar)
    assert st.doppler_position_m is None
    record, _ = _stop()
    with open_store(tmp_path / "events.db") as store:
        store.save_stop(dataclasses.replace(record, station_data=st))
        (row,) = store.stations()
        assert row["doppler_position_m"] is None
        assert row["tasc"]["doppler"] is None


def test_parameters_hold_stopping_point_detectors_and_braking_data(tmp_path: Path) -> None:
    record, _ = _stop()
    with open_store(tmp_path / "events.db") as store:
        store.save_stop(record)
        (run,) = store.runs()
        (station,) = store.stations()
    p = run["parameters"]
    # SPEC §1 claim 8: the stopping point, the detector positions ...
    assert p["stop_point_m"] == RIVERSIDE.stop_point_m
    assert p["detector_positions_m"] == RIVERSIDE.detector_positions_m()
    assert p["station_key"] == {"line": station["line"], "name": station["name"]}
    # ... and the braking data that decides the stop.
    brake = VEHICLE.brake
    assert p["vehicle"] == VEHICLE.name
    assert p["brake"]["notch_decel_mps2"] == brake.notch_decel_mps2  # B1..B7
    assert len(p["brake"]["notch_decel_mps2"]) == 7
    assert p["brake"]["full_service_mps2"] == brake.full_service_mps2
    assert p["brake"]["dead_time_s"] == brake.dead_time_s
    assert p["brake"]["time_constant_s"] == brake.time_constant_s
    assert p["brake"]["jerk_limit_mps3"] == brake.jerk_limit_mps3
    # What the CLI stored before stays.
    assert (p["load_factor"], p["brake_gain"], p["form"]) == (0.0, 1.0, RIVERSIDE.tasc.signal_form)
    assert p["inputs_sha256"]


def test_ato_stop_has_no_commands_but_its_station(tmp_path: Path) -> None:
    result, batch = run_stop(line=LINE, station=RIVERSIDE, vehicle=VEHICLE, controller="ato", seed=1)
    assert batch.commands == []
    with open_store(tmp_path / "events.db") as store:
        run_id = store.save_stop(stop_record(result, line=LINE, station=RIVERSIDE, vehicle=VEHICLE))
        assert store.commands(run_id) == []
        assert len(store.stations()) == 1


# ------------------------------------------------------------------ claim 20: what went on the air


def test_form_2_rows_show_the_distance_telegram(tmp_path: Path) -> None:
    record, batch = _stop(form=2)
    rows = _saved_commands(record, tmp_path / "events.db")
    assert len(rows) == len(batch.commands) > 0
    for row in rows:
        assert row["telegram_type"] == "tasc-distance"
        assert row["emergency"] is False
        tel = row["telegram"]
        # Form 2 carries the distance the wayside measured, at the wire's resolution ...
        assert tel["distance_m"] == quantize("tasc-distance", "distance_m", row["distance_m"])
        assert tel["detector"] == row["detector"]
        # ... and no deceleration nor notch: the computed ones never went to the train.
        assert not {"required_mps2", "notch", "delta", "decel_mps2"} & set(tel)


def test_form_6_telegram_carries_the_commanded_deceleration(tmp_path: Path) -> None:
    record, _ = _stop(form=6)
    rows = _saved_commands(record, tmp_path / "events.db")
    assert rows
    for row in rows:
        assert row["telegram_type"] == "tasc-required-decel"
        expected = quantize("tasc-required-decel", "required_mps2", row["command_decel_mps2"])
        assert row["telegram"]["required_mps2"] == expected


def test_wayside_emergency_stop_is_stored(tmp_path: Path) -> None:
    """A station whose only detectors are 220 m out and brakes 25 % weak, the train's own guard
    blind: the wayside's overrun guard sends an emergency-stop telegram (DESIGN rule 10)."""
    zone = RIVERSIDE.tasc.model_copy(update={"detectors_before_stop_m": [220.0, 219.0]})
    station = RIVERSIDE.model_copy(update={"tasc": zone})
    vehicle = VEHICLE.model_copy(update={"atp": VEHICLE.atp.model_copy(update={"guard_decel_fraction": 5.0})})
    d = load_disturbances("nominal").to_dict()
    d["brake_gain"] = {"fixed": 0.75}
    result, _ = run_stop(
        line=LINE,
        station=station,
        vehicle=vehicle,
        controller=TASC_PWM,
        seed=1,
        disturbances=DisturbanceSet.from_dict(d, name="nominal+weak", source="test"),
    )
    assert result.emergency_brake == "wayside-overrun-guard"
    rows = _saved_commands(
        stop_record(result, line=LINE, station=station, vehicle=vehicle), tmp_path / "events.db"
    )
    assert rows[-1]["emergency"] is True
    assert rows[-1]["telegram_type"] == "tasc-emergency-stop"
    assert set(rows[-1]["telegram"]) == {"train_id", "detector"}
    assert not any(r["emergency"] for r in rows[:-1])
    assert all(r["telegram_type"] == "tasc-required-decel" for r in rows[:-1])


def test_commands_map_the_emergency_flag_and_the_telegram() -> None:
    """``engine._commands`` on a synthetic kernel record: one ordinary command, one emergency stop."""
    rows = np.zeros((2, CR_SIZE + 1))
    rows[:, CR_DETECTOR] = [0, 1]
    rows[1, CR_EMERGENCY] = 1.0
    # Every telegram field finite and in range, so the test holds whatever form 2 carries besides
    # its distance; the notch, delta and step are 0 and the emergency-stop row carries its flag only,
    # as the kernel records them.
    sends = np.full((2, TEL_SIZE), 1.0)
    sends[:, TEL_DETECTOR] = [0, 1]
    sends[:, TEL_EMERGENCY] = [0.0, 1.0]
    sends[:, [TEL_NOTCH, TEL_DELTA, TEL_STEP]] = 0.0
    sends[0, TEL_DISTANCE] = 123.4567
    sends[0, TEL_MEASURED] = 2.0
    sends[
        1,
        [
            j
            for j in range(TEL_SIZE)
            if j not in (TEL_DETECTOR, TEL_EMERGENCY, TEL_NOTCH, TEL_DELTA, TEL_STEP)
        ],
    ] = np.nan
    out = command_records(rows, SignalForm.DISTANCE, sends)
    assert [c["emergency"] for c in out] == [False, True]
    assert [c["telegram_type"] for c in out] == ["tasc-distance", "tasc-emergency-stop"]
    assert out[0]["telegram"]["distance_m"] == 123.457  # the wire's resolution: 1 mm
    assert out[0]["telegram"]["detector"] == 0
    assert "required_mps2" not in out[0]["telegram"]
    assert out[1]["telegram"] == {"train_id": 1, "detector": 1}
    assert set(SENT_FIELDS) <= set(out[0])
    with pytest.raises(SimulationError, match="2 command records but 1 telegrams"):
        command_records(rows, SignalForm.DISTANCE, sends[:1])


# ------------------------------------------------------------------ bad input: one line each


def test_station_data_must_be_the_runs_station(tmp_path: Path) -> None:
    record, _ = _stop()
    museum = station_record(LINE, LINE.station("Museum"))
    assert record.station_data is not None
    with open_store(tmp_path / "events.db") as store:
        with pytest.raises(RailstopError, match="station_data: is station 'Museum'") as info:
            store.save_stop(dataclasses.replace(record, station_data=museum))
        assert "\n" not in str(info.value)
        bad = dataclasses.replace(record.station_data, stop_point_m=float("inf"))
        with pytest.raises(RailstopError, match="stop_point_m: expected a finite number"):
            store.save_stop(dataclasses.replace(record, station_data=bad))
        bad = dataclasses.replace(record.station_data, detector_positions_m=[870.0, float("nan")])
        with pytest.raises(RailstopError, match=r"detector_positions_m\[1\]"):
            store.save_stop(dataclasses.replace(record, station_data=bad))
        with pytest.raises(RailstopError, match="must be a StationRecord"):
            store.save_stop(dataclasses.replace(record, station_data={"name": "Riverside"}))  # type: ignore[arg-type]
        # Nothing half-written: neither the run nor the station.
        assert store.runs() == []
        assert store.stations() == []


# ------------------------------------------------------------------ schema versions


def _old_file(db: Path) -> None:
    with sqlite3.connect(db) as con:
        con.executescript(OLD_LAYOUT.format(id="INTEGER") + OLD_ROWS)


def test_a_file_of_schema_version_1_is_migrated_and_loses_nothing(tmp_path: Path) -> None:
    db = tmp_path / "old.db"
    _old_file(db)
    record, _ = _stop()
    with open_store(db) as store:
        assert store.schema_version() == SCHEMA_VERSION
        (old,) = store.runs()
        assert old["run_key"] == "old|stop"
        assert old["parameters"] == {"load_factor": 0.5}
        assert store.commands(old["id"]) == [OLD_COMMAND]
        old_result = store.result(old["id"])
        assert old_result is not None and old_result["stop_time_s"] == 38.0
        assert store.stations() == []
        new_id = store.save_stop(record)
    with open_store(db) as store:  # reopened: already up to date
        assert [r["run_key"] for r in store.runs()] == ["old|stop", record.run_key]
        assert store.commands(old["id"]) == [OLD_COMMAND]
        new = store.commands(new_id)
        assert len(new) == len(record.commands)
        assert all(c["telegram_type"] == "tasc-required-decel" for c in new)
        assert [s["name"] for s in store.stations()] == ["Riverside"]
    with sqlite3.connect(db) as con:
        cols = [r[1] for r in con.execute("PRAGMA table_info(commands)")]
        info = con.execute("SELECT version, note FROM schema_info ORDER BY version").fetchall()
    assert cols[-3:] == ["emergency", "telegram_type", "telegram_json"]
    assert len(info) == 1 and info[0][0] == SCHEMA_VERSION
    assert "migrated from version 1" in info[0][1]
    assert "commands.telegram_json" in info[0][1] and "stations" in info[0][1]


def test_a_new_file_records_its_schema_version(tmp_path: Path) -> None:
    db = tmp_path / "new.db"
    with open_store(db) as store:
        assert store.schema_version() == SCHEMA_VERSION
    with open_store(db):
        pass
    with sqlite3.connect(db) as con:
        assert con.execute("SELECT version, note FROM schema_info").fetchall() == [
            (SCHEMA_VERSION, "created")
        ]


def test_a_file_of_a_newer_schema_is_refused_untouched(tmp_path: Path) -> None:
    db = tmp_path / "future.db"
    with open_store(db):
        pass
    with sqlite3.connect(db) as con:
        con.execute(
            "INSERT INTO schema_info VALUES (?, '2099-01-01T00:00:00+00:00', 'future')", (SCHEMA_VERSION + 1,)
        )
        con.execute("CREATE TABLE future_only (x INTEGER)")
    before = db.read_bytes()
    with pytest.raises(RailstopError) as info:
        open_store(db)
    message = str(info.value)
    assert str(db) in message and "newer railstop" in message and f"version {SCHEMA_VERSION + 1}" in message
    assert "\n" not in message
    assert info.value.__cause__ is None
    assert db.read_bytes() == before


# ------------------------------------------------------------------ the command line


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=cwd)  # forked from a warm zygote (tests/zygote.py)


def test_railstop_stop_writes_the_station_and_the_telegrams(tmp_path: Path) -> None:
    db = tmp_path / "runs.db"
    _old_file(db)  # the command line migrates an old file too
    p = _cli("stop", "--station", "Museum", "--form", "2", "--json", "--db", str(db), cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    museum = LINE.station("Museum")
    with sqlite3.connect(db) as con:
        stations = con.execute(
            "SELECT line, name, stop_point_m, detector_positions_m_json FROM stations"
        ).fetchall()
        (params,) = con.execute("SELECT parameters_json FROM runs WHERE run_key != 'old|stop'").fetchone()
        types = con.execute(
            "SELECT DISTINCT telegram_type FROM commands JOIN runs ON runs.id = commands.run_id "
            "WHERE run_key != 'old|stop'"
        ).fetchall()
        n_cmd = con.execute("SELECT COUNT(*) FROM commands").fetchone()[0]
    assert stations == [
        (LINE.line.name, "Museum", museum.stop_point_m, json.dumps(museum.detector_positions_m()))
    ]
    assert json.loads(params)["station_key"] == {"line": LINE.line.name, "name": "Museum"}
    assert types == [("tasc-distance",)]
    assert n_cmd == data["commands"] + 1  # and the old file's one command


# ------------------------------------------------------------------ PostgreSQL


@pytest.fixture
def pg(empty_postgres: str) -> str:
    """A real PostgreSQL database with no tables (conftest), emptied again afterwards."""
    return empty_postgres


def test_postgresql_station_and_telegrams(pg: str) -> None:
    record, _ = _stop(form=2)
    with open_store(pg) as store:
        assert store.schema_version() == SCHEMA_VERSION
        run_id = store.save_stop(record)
        store.save_stop(record)
        (station,) = store.stations()
        assert station["detector_positions_m"] == RIVERSIDE.detector_positions_m()
        rows = store.commands(run_id)
        assert [r["telegram_type"] for r in rows] == ["tasc-distance"] * len(record.commands)
        assert all(r["emergency"] is False for r in rows)
        assert store.runs()[0]["parameters"]["brake"]["notch_decel_mps2"] == VEHICLE.brake.notch_decel_mps2


def test_postgresql_migration_of_schema_version_1(pg: str) -> None:
    from sqlalchemy import create_engine, text

    engine = create_engine(pg.replace("postgresql://", "postgresql+psycopg://", 1))
    with engine.begin() as con:
        for statement in (OLD_LAYOUT.format(id="SERIAL") + OLD_ROWS).split(";"):
            if statement.strip():
                con.execute(text(statement))
    engine.dispose()
    record, _ = _stop()
    with open_store(pg) as store:
        assert store.schema_version() == SCHEMA_VERSION
        (old,) = store.runs()
        assert store.commands(old["id"]) == [OLD_COMMAND]
        new_id = store.save_stop(record)
        assert len(store.commands(new_id)) == len(record.commands)
        assert len(store.runs()) == 2
