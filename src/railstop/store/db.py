"""The event database (SPEC §1 claims 8 and 20), SQLAlchemy 2.0, SQLite by default.

Claim 8: the database unit keeps the stopping point, the detector positions
and the braking data. Claim 20: it keeps the history of every computed
command. Here one stop is up to four kinds of rows:

* ``stations``: the station the stop was made at, one row per (line name,
  station name): its stopping point, detector positions (chainages and
  distances before the stop), Doppler radar position, signal form, platform
  and its whole TASC zone as JSON (claim 8); shared by every stop there;
* ``runs``: what was simulated (station, controller, seed, line and every
  parameter that decides the stop, as JSON: the stopping point, the detector
  positions, the vehicle's braking data, load and brake gain, and the
  station row's natural key), identified by a natural key ``run_key``;
* ``commands``: every command the wayside unit computed for that stop, one
  column per field of a command record (claim 20): the ``CR_*`` columns of
  ``railstop.wayside.tasc_unit`` as the detailed stop turns them into dicts
  (``railstop.sim.engine._commands``), whether it was an emergency stop, and
  what went on the air: the telegram's codec type and its decoded fields;
* ``stop_results``: how the stop ended.

Saving the same ``run_key`` again never duplicates a stop: identical data is
left untouched, different data replaces the old rows in the same
transaction, so a re-run campaign converges on one row set per stop. The
station row is upserted in that transaction: identical data is left as it
is, changed data updates it (and its ``updated_utc``).

``schema_info`` records the schema version. ``open_store`` brings a file of
an older version up to date (new tables, new nullable columns; old rows keep
NULL there) and refuses one written by a newer railstop.

Database failures come out as one-line errors of two kinds besides the plain
``RailstopError`` (DESIGN rule 9): :class:`StoreUnavailable`, a failure that
may pass (a SQLite lock held past the busy time-out, a lost or refused
PostgreSQL connection, too many open files, a full disk), which a service
retries; and :class:`StoreCorrupt`, a database file SQLite reports damaged,
which nobody retries. ``open_store(..., check_integrity=True)`` runs SQLite's
``PRAGMA quick_check`` before touching a file and refuses a damaged one
untouched. A commit is durable when it returns (SQLite ``synchronous=FULL``,
PostgreSQL ``synchronous_commit=on``, both set on every connection).
"""

from __future__ import annotations

import json
import math
import numbers
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from sqlalchemy import (
    BigInteger,
    Boolean,
    Connection,
    Float,
    ForeignKey,
    Integer,
    String,
    Text,
    UniqueConstraint,
    create_engine,
    delete,
    event,
    func,
    insert,
    inspect,
    select,
    text,
)
from sqlalchemy.engine import URL, Engine, make_url
from sqlalchemy.exc import ArgumentError, DBAPIError, IntegrityError, SQLAlchemyError
from sqlalchemy.exc import DisconnectionError as SaDisconnectionError
from sqlalchemy.exc import TimeoutError as SaPoolTimeout
from sqlalchemy.orm import DeclarativeBase, Mapped, Session, mapped_column, sessionmaker

from railstop.errors import RailstopError


class StoreError(RailstopError):
    """The event database failed (not the data given to it)."""


class StoreUnavailable(StoreError):
    """A database failure that may pass: retry later (nothing was written)."""


class StoreCorrupt(StoreError):
    """The database file is damaged: refused, never retried, never written over."""


# SQLite's primary result codes (the low byte of the extended code, ``sqlite3.Error.sqlite_errorcode``)
# of failures that pass: BUSY / LOCKED (another connection holds the lock past the busy time-out),
# NOMEM, READONLY (a file or file system made read-only, or moved, under the running process),
# IOERR (a failing read or write, e.g. a network file system), FULL (the disk), CANTOPEN (no file
# descriptor left: the journal cannot be opened), PROTOCOL (a lock race). [interpretation] A
# failing disk may never come back: retrying it is still safe, since what is not stored is not
# acknowledged, and the service says on stderr that the database is away.
_SQLITE_TRANSIENT = frozenset({5, 6, 7, 8, 10, 13, 14, 15})
_SQLITE_CORRUPT = frozenset({11, 26})  # SQLITE_CORRUPT, SQLITE_NOTADB
# PostgreSQL SQLSTATEs of failures that pass: class 08 (connection), 53 (insufficient resources:
# too many connections, out of memory or disk), 57P01-57P03 (the server shutting down or
# starting), 57014 (a statement cancelled), 58 (system error: I/O), 40001 / 40P01
# (serialization failure, deadlock), 55P03 (lock not available), 25006 (a read-only transaction:
# a standby not yet promoted).
_PG_TRANSIENT_CLASSES = ("08", "53", "58")
_PG_TRANSIENT = frozenset({"57P01", "57P02", "57P03", "57014", "40001", "40P01", "55P03", "25006"})
_PG_CORRUPT = frozenset({"XX001", "XX002"})  # data_corrupted, index_corrupted


def _kind_of(exc: BaseException) -> type[RailstopError]:
    """Which error a database failure is: ``StoreUnavailable``, ``StoreCorrupt`` or ``StoreError``."""
    if isinstance(exc, SaDisconnectionError | SaPoolTimeout):
        return StoreUnavailable
    if isinstance(exc, DBAPIError) and exc.connection_invalidated:
        return StoreUnavailable  # SQLAlchemy saw the connection die (and dropped the pool's)
    inner = getattr(exc, "orig", None) or exc
    code = getattr(inner, "sqlite_errorcode", None)
    if isinstance(code, int):
        if code & 0xFF in _SQLITE_CORRUPT:
            return StoreCorrupt
        return StoreUnavailable if code & 0xFF in _SQLITE_TRANSIENT else StoreError
    state = getattr(inner, "sqlstate", None)
    if isinstance(state, str):
        if state in _PG_CORRUPT:
            return StoreCorrupt
        if state in _PG_TRANSIENT or state.startswith(_PG_TRANSIENT_CLASSES):
            return StoreUnavailable
        return StoreError
    # No code: psycopg's OperationalError / InterfaceError without a SQLSTATE is a connection that
    # could not be made or was lost (refused, reset, timed out, no file descriptor).
    if isinstance(exc, DBAPIError) and type(inner).__name__ in ("OperationalError", "InterfaceError"):
        return StoreUnavailable
    if isinstance(inner, OSError):
        return StoreUnavailable  # e.g. EMFILE, ECONNREFUSED raised below the driver
    return StoreError


def _db_error(label: str, what: str, exc: BaseException) -> RailstopError:
    """One line naming the database and what failed, of the kind ``_kind_of`` says."""
    kind = _kind_of(exc)
    detail = _one_line(exc)
    if kind is StoreCorrupt:
        detail += " (the file is damaged or not a database: refused, left as it is)"
    return kind(f"{label}: {what}: {detail}")


# The keys of one command record (``railstop.sim.engine._commands``: the wayside unit's
# ``CR_*`` columns, absent values None by ``finite_or_none``), in column order, with their
# type and whether the value may be missing (claim 20: the command history).
# Only the two decelerations may legitimately be unknown: the measured one
# before three passages / a full Doppler window, the required one when the
# planner has none; a NaN anywhere else is a bug upstream and is refused.
_COMMAND_SPEC: dict[str, tuple[type, bool]] = {
    "run": (int, False),
    "t_s": (float, False),
    "form": (int, False),
    "detector": (int, False),
    "passage_s": (float, False),
    "distance_m": (float, False),
    "speed_mps": (float, False),
    "measured_decel_mps2": (float, True),
    "gain": (float, False),
    "required_decel_mps2": (float, True),
    "command_decel_mps2": (float, False),
    "notch": (int, False),
    "delta": (int, False),
    "effect_s": (float, False),
}
COMMAND_FIELDS: tuple[str, ...] = tuple(_COMMAND_SPEC)

# What went on the air for each command (SPEC §1 claim 20; schema version 2): the emergency-stop
# flag of the record (DESIGN rule 10, the wayside's overrun guard), the telegram's codec type
# (``railstop.link.codec``, e.g. "tasc-distance") and its decoded fields (a dict, stored as
# JSON). Required when saving; NULL (None) in rows written by schema version 1.
SENT_FIELDS: tuple[str, ...] = ("emergency", "telegram_type", "telegram")

# The result of one stop (claim 8: braking data); ``stop_time_s`` is None
# when the train never came to rest.
_RESULT_SPEC: dict[str, tuple[type, bool]] = {
    "stop_error_m": (float, False),
    "stop_time_s": (float, True),
    "max_jerk_mps3": (float, False),
    "notch_changes": (int, False),
    "commands_received": (int, False),
    "commands_sent": (int, False),
    "stopped": (bool, False),
}
RESULT_FIELDS: tuple[str, ...] = tuple(_RESULT_SPEC)

# One station row (SPEC §1 claim 8: the stopping point and the detector positions), natural key
# (line, name); the JSON columns are read back decoded, without their ``_json`` suffix.
STATION_FIELDS: tuple[str, ...] = (
    "line",
    "name",
    "stop_point_m",
    "platform_length_m",
    "psd_tolerance_m",
    "signal_form",
    "detector_positions_m",
    "detectors_before_stop_m",
    "doppler_position_m",
    "tasc",
)
_STATION_JSON = ("detector_positions_m", "detectors_before_stop_m", "tasc")

# 1: runs, commands (the CR_* columns only), stop_results, campaigns, dwell_events; no schema_info.
# 2: stations; commands.emergency, telegram_type, telegram_json; schema_info.
# 3: office_reports (the management office's log of what the wayside sent).
SCHEMA_VERSION = 3

_RUN_FIELDS: tuple[str, ...] = (
    "run_key",
    "station",
    "controller",
    "seed",
    "line",
    "parameters_json",
    "created_utc",
)


def _utc_now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def office_report_values(
    *, sender_id: int, session: int, seq: int, kind: str, sent_s: float, data: Any
) -> dict[str, Any]:
    """The ``office_reports`` columns of one report (all but ``received_utc``), or a
    ``RailstopError`` naming the field: what a report must be to be kept (64-bit numbers, a
    kind, JSON data). The office checks a report with it before it queues it for storing."""
    src = f"office report {sender_id}/{session}/{seq}"
    return {
        "sender_id": _value(src, "sender_id", sender_id, int, False),
        "session": _value(src, "session", session, int, False),
        "seq": _value(src, "seq", seq, int, False),
        "kind": _value(src, "kind", kind, str, False),
        "sent_s": _value(src, "sent_s", sent_s, float, False),
        "data_json": json.dumps(_json_data(src, "data", data), sort_keys=True),
    }


@dataclass(frozen=True, slots=True, kw_only=True)
class StationRecord:
    """One station as the database keeps it (SPEC §1 claim 8: stopping point, detector positions).

    Chainages in metres. ``detector_positions_m`` are the detectors' chainages,
    ``detectors_before_stop_m`` the same as distances before the stopping
    point (farthest first); ``doppler_position_m`` is the Doppler radar's
    chainage (None: no radar); ``tasc`` the station's whole TASC zone as
    JSON data. ``railstop.sim.single.station_record`` builds it from the
    line data.
    """

    line: str
    name: str
    stop_point_m: float
    platform_length_m: float
    psd_tolerance_m: float
    signal_form: int
    detector_positions_m: list[float]
    detectors_before_stop_m: list[float]
    doppler_position_m: float | None
    tasc: dict[str, Any]


@dataclass(frozen=True, slots=True, kw_only=True)
class StopRecord:
    """One stop as it goes into the database (claims 8, 20).

    ``parameters`` holds what decides the stop (stopping point, detector
    positions, braking data, load, brake gain, ...) as JSON data: numbers,
    strings, booleans, None, lists and dicts of them; non-finite floats are
    kept (Python's JSON writes them as ``NaN``/``Infinity``) because ``inf``
    is meaningful, e.g. "no low-adhesion patch". ``commands`` are the command
    records of the detailed stop (``BatchResult.commands``): the keys
    ``COMMAND_FIELDS`` and ``SENT_FIELDS`` are required, others are ignored.
    ``station_data`` (optional) is upserted into ``stations`` with the stop;
    its line and name must be the record's. ``railstop.sim.single.stop_record``
    builds the whole record of a simulated stop.
    """

    run_key: str
    station: str
    controller: str
    seed: int
    line: str
    parameters: dict[str, Any]
    commands: list[dict[str, Any]]
    stop_error_m: float
    stop_time_s: float | None
    max_jerk_mps3: float
    notch_changes: int
    commands_received: int
    commands_sent: int
    stopped: bool
    created_utc: str = field(default_factory=_utc_now)
    station_data: StationRecord | None = None


# -- schema -------------------------------------------------------------------


class _Base(DeclarativeBase):
    pass


class StationRow(_Base):
    """One station's stop data (SPEC §1 claim 8: the stopping point, the detector positions).

    Natural key (line, name); upserted with every stop made there (schema version 2).
    """

    __tablename__ = "stations"
    __table_args__ = (UniqueConstraint("line", "name", name="uq_stations_line_name"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    line: Mapped[str] = mapped_column(String)
    name: Mapped[str] = mapped_column(String)
    stop_point_m: Mapped[float] = mapped_column(Float)
    platform_length_m: Mapped[float] = mapped_column(Float)
    psd_tolerance_m: Mapped[float] = mapped_column(Float)
    signal_form: Mapped[int] = mapped_column(Integer)
    detector_positions_m_json: Mapped[str] = mapped_column(Text)  # chainages, farthest first
    detectors_before_stop_m_json: Mapped[str] = mapped_column(Text)
    doppler_position_m: Mapped[float | None] = mapped_column(Float, nullable=True)  # None: no radar
    tasc_json: Mapped[str] = mapped_column(Text)  # the whole TascZone
    created_utc: Mapped[str] = mapped_column(String(40))
    updated_utc: Mapped[str] = mapped_column(String(40))


class SchemaInfoRow(_Base):
    """One row per schema version this file was brought to; the newest is the file's version."""

    __tablename__ = "schema_info"

    version: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    applied_utc: Mapped[str] = mapped_column(String(40))
    note: Mapped[str] = mapped_column(Text)


class RunRow(_Base):
    """One simulated stop and what decided it (claim 8: stopping point, detectors, braking data)."""

    __tablename__ = "runs"
    __table_args__ = (UniqueConstraint("run_key", name="uq_runs_run_key"),)

    # Integer (not BigInteger): on SQLite only INTEGER PRIMARY KEY is the rowid.
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_key: Mapped[str] = mapped_column(String)
    station: Mapped[str] = mapped_column(String)
    controller: Mapped[str] = mapped_column(String)
    seed: Mapped[int] = mapped_column(BigInteger)
    line: Mapped[str] = mapped_column(String)
    parameters_json: Mapped[str] = mapped_column(Text)
    created_utc: Mapped[str] = mapped_column(String(40))


class CommandRow(_Base):
    """One computed command and its inputs (claim 20: the command history)."""

    __tablename__ = "commands"
    __table_args__ = (UniqueConstraint("run_id", "seq", name="uq_commands_run_seq"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    seq: Mapped[int] = mapped_column(Integer)  # order within the stop
    run: Mapped[int] = mapped_column(Integer)  # column of the batch it came from
    t_s: Mapped[float] = mapped_column(Float)
    form: Mapped[int] = mapped_column(Integer)
    detector: Mapped[int] = mapped_column(Integer)
    passage_s: Mapped[float] = mapped_column(Float)
    distance_m: Mapped[float] = mapped_column(Float)
    speed_mps: Mapped[float] = mapped_column(Float)
    measured_decel_mps2: Mapped[float | None] = mapped_column(Float, nullable=True)
    gain: Mapped[float] = mapped_column(Float)
    required_decel_mps2: Mapped[float | None] = mapped_column(Float, nullable=True)
    command_decel_mps2: Mapped[float] = mapped_column(Float)
    notch: Mapped[int] = mapped_column(Integer)
    delta: Mapped[int] = mapped_column(Integer)
    effect_s: Mapped[float] = mapped_column(Float)
    # Claim 20, what went on the air (schema version 2: added to older files by open_store,
    # hence nullable; rows written by version 1 keep NULL).
    emergency: Mapped[bool | None] = mapped_column(Boolean, nullable=True)
    telegram_type: Mapped[str | None] = mapped_column(String, nullable=True)
    telegram_json: Mapped[str | None] = mapped_column(Text, nullable=True)


class ResultRow(_Base):
    """How one stop ended (claim 8: braking data)."""

    __tablename__ = "stop_results"

    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), primary_key=True)
    stop_error_m: Mapped[float] = mapped_column(Float)
    stop_time_s: Mapped[float | None] = mapped_column(Float, nullable=True)
    max_jerk_mps3: Mapped[float] = mapped_column(Float)
    notch_changes: Mapped[int] = mapped_column(Integer)
    commands_received: Mapped[int] = mapped_column(Integer)
    commands_sent: Mapped[int] = mapped_column(Integer)
    stopped: Mapped[bool] = mapped_column(Boolean)


class CampaignRow(_Base):
    """The summary of one Monte Carlo campaign (its per-run rows are in its Parquet file)."""

    __tablename__ = "campaigns"
    __table_args__ = (UniqueConstraint("campaign_key", name="uq_campaigns_key"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    campaign_key: Mapped[str] = mapped_column(String)
    station: Mapped[str] = mapped_column(String)
    controller: Mapped[str] = mapped_column(String)
    seed: Mapped[int] = mapped_column(BigInteger)
    runs: Mapped[int] = mapped_column(Integer)
    disturbances: Mapped[str] = mapped_column(String)
    runs_file: Mapped[str] = mapped_column(Text)
    manifest_json: Mapped[str] = mapped_column(Text)
    summary_json: Mapped[str] = mapped_column(Text)
    created_utc: Mapped[str] = mapped_column(String(40))


class DwellEventRow(_Base):
    """One signal change of a station dwell (SPEC §5): the timeline of ``railstop dwell``.

    ``dwell_key`` names the dwell (station, mode, stop error, door data...);
    saving the same key again replaces its rows, never duplicates them.
    ``value`` is the JSON text of the value (0/1, a number or a state name).
    """

    __tablename__ = "dwell_events"
    __table_args__ = (UniqueConstraint("dwell_key", "seq", name="uq_dwell_events_key_seq"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    dwell_key: Mapped[str] = mapped_column(String, index=True)
    station: Mapped[str] = mapped_column(String)
    seq: Mapped[int] = mapped_column(Integer)  # order within the dwell
    t_s: Mapped[float] = mapped_column(Float)
    signal: Mapped[str] = mapped_column(String)
    value: Mapped[str] = mapped_column(Text)


class OfficeReportRow(_Base):
    """One report the management office received from the wayside (SPEC §1 claims 7, 20).

    The key (sender_id, session, seq) is the sender's numbering: a report sent again (its
    acknowledgement lost, the office restarted) is kept once. ``data_json`` is the report's data
    as sent; ``sent_s`` the sender's time, ``received_utc`` the office's.
    """

    __tablename__ = "office_reports"
    __table_args__ = (UniqueConstraint("sender_id", "session", "seq", name="uq_office_reports_sender"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    sender_id: Mapped[int] = mapped_column(Integer, index=True)
    session: Mapped[int] = mapped_column(BigInteger)
    seq: Mapped[int] = mapped_column(BigInteger)
    kind: Mapped[str] = mapped_column(String(40), index=True)
    sent_s: Mapped[float] = mapped_column(Float)
    data_json: Mapped[str] = mapped_column(Text)
    received_utc: Mapped[str] = mapped_column(String(40))


# -- the store ----------------------------------------------------------------


class Store:
    """An open event database; use ``open_store`` to get one."""

    def __init__(self, engine: Engine, label: str) -> None:
        self._engine: Engine | None = engine
        self._label = label
        self._sessions = sessionmaker(engine, expire_on_commit=False)

    def __repr__(self) -> str:
        state = "closed" if self._engine is None else "open"
        return f"Store({self._label!r}, {state})"

    def __enter__(self) -> Store:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        """Release the connections; closing twice is harmless."""
        if self._engine is not None:
            self._engine.dispose()
            self._engine = None

    @property
    def label(self) -> str:
        """The database as messages name it (a file, or a URL without its password)."""
        return self._label

    @property
    def dialect(self) -> str:
        """``sqlite`` or ``postgresql``."""
        if self._engine is None:
            raise RailstopError(f"{self._label}: the event database is closed")
        return str(self._engine.dialect.name)

    def durability(self) -> dict[str, str]:
        """What a commit's durability rests on, as the database reports it for a new connection:
        SQLite ``journal_mode`` and ``synchronous`` (0 OFF, 1 NORMAL, 2 FULL, 3 EXTRA),
        PostgreSQL ``synchronous_commit`` and ``fsync``."""
        if self._engine is None:
            raise RailstopError(f"{self._label}: the event database is closed")
        sqlite = self.dialect == "sqlite"
        names = ("journal_mode", "synchronous") if sqlite else ("synchronous_commit", "fsync")
        verb = "PRAGMA" if sqlite else "SHOW"
        try:
            with self._engine.connect() as conn:
                return {n: str(conn.exec_driver_sql(f"{verb} {n}").scalar()) for n in names}
        except SQLAlchemyError as exc:
            raise _db_error(self._label, "cannot read its settings", exc) from None

    def _session(self) -> Session:
        if self._engine is None:
            raise RailstopError(f"{self._label}: the event database is closed")
        return self._sessions()

    # -- writing ------------------------------------------------------------
    def save_stop(self, run: StopRecord) -> int:
        """Write ``run`` (station, run row, commands, result) in one transaction; return its id.

        A ``run_key`` already stored keeps its id: identical data is left as
        it is, otherwise the run row is updated and its commands and result
        replaced by the new ones. The station row (``run.station_data``) is
        inserted, left as it is when identical, or updated.
        """
        values, commands, result, station = _normalise(run)
        # Two writers may both find the key missing and both insert it; the
        # unique constraint stops the second, which then retries as an update.
        for attempt in range(2):
            try:
                with self._session() as session, session.begin():
                    if station is not None:
                        _upsert_station(session, station)  # SPEC §1 claim 8, same transaction
                    return _upsert(session, values, commands, result)
            except IntegrityError as exc:
                if attempt == 1:
                    raise RailstopError(
                        f"{self._label}: cannot save run {run.run_key!r}: {_one_line(exc)}"
                    ) from None
            except SQLAlchemyError as exc:
                raise _db_error(self._label, f"cannot save run {run.run_key!r}", exc) from None
        raise AssertionError("unreachable")  # pragma: no cover

    def save_campaign(
        self, *, key: str, manifest: Mapping[str, Any], summary: Mapping[str, Any], runs_file: str
    ) -> int:
        """Write (or replace) the summary of the campaign ``key``; return its id."""
        values = {
            "campaign_key": key,
            "station": str(manifest["station"]),
            "controller": str(manifest["controller"]),
            "seed": int(manifest["seed"]),
            "runs": int(manifest["runs"]),
            "disturbances": str(manifest["disturbances"]["name"]),
            "runs_file": runs_file,
            "manifest_json": json.dumps(manifest, sort_keys=True),
            "summary_json": json.dumps(summary, sort_keys=True),
            "created_utc": _utc_now(),
        }
        try:
            with self._session() as session, session.begin():
                row = session.scalars(select(CampaignRow).where(CampaignRow.campaign_key == key)).first()
                if row is None:
                    row = CampaignRow(**values)
                    session.add(row)
                else:
                    for name, value in values.items():
                        setattr(row, name, value)
                session.flush()
                return int(row.id)
        except SQLAlchemyError as exc:
            raise _db_error(self._label, f"cannot save campaign {key!r}", exc) from None

    def campaigns(self) -> list[dict[str, Any]]:
        """Every stored campaign summary, oldest first."""
        with self._reading() as session:
            rows = session.scalars(select(CampaignRow).order_by(CampaignRow.id)).all()
            return [
                {
                    "id": r.id,
                    "campaign_key": r.campaign_key,
                    "station": r.station,
                    "controller": r.controller,
                    "seed": r.seed,
                    "runs": r.runs,
                    "disturbances": r.disturbances,
                    "runs_file": r.runs_file,
                    "manifest": json.loads(r.manifest_json),
                    "summary": json.loads(r.summary_json),
                    "created_utc": r.created_utc,
                }
                for r in rows
            ]

    def save_dwell(self, *, key: str, station: str, events: Sequence[Any]) -> int:
        """Write one dwell timeline (objects with ``t_s``, ``signal``, ``value``); return its row count.

        The same ``key`` again: identical rows are left untouched, different
        rows replace the old ones in one transaction (never duplicated).
        """
        if not isinstance(key, str) or not key:
            raise RailstopError(f"dwell key: must be a non-empty string (got {key!r})")
        station = _value(f"dwell {key!r}", "station", station, str, False)
        rows = [_dwell_row(key, station, i, e) for i, e in enumerate(events)]
        fields = ("station", "t_s", "signal", "value")
        new = [{f: r[f] for f in fields} for r in rows]
        for attempt in range(2):
            try:
                with self._session() as session, session.begin():
                    if _dwell_dicts(session, key) == new:
                        return len(new)
                    # Explicit delete first: the ORM would flush the inserts before the delete.
                    session.execute(delete(DwellEventRow).where(DwellEventRow.dwell_key == key))
                    session.add_all(DwellEventRow(**r) for r in rows)
                    return len(rows)
            except IntegrityError as exc:
                if attempt == 1:
                    raise RailstopError(
                        f"{self._label}: cannot save dwell {key!r}: {_one_line(exc)}"
                    ) from None
            except SQLAlchemyError as exc:
                raise _db_error(self._label, f"cannot save dwell {key!r}", exc) from None
        raise AssertionError("unreachable")  # pragma: no cover

    def dwell_events(self, key: str) -> list[dict[str, Any]]:
        """The timeline of one dwell in order (``value`` decoded from JSON); empty if unknown."""
        with self._reading() as session:
            return [{**d, "value": json.loads(d["value"])} for d in _dwell_dicts(session, key)]

    def dwell_keys(self) -> list[str]:
        """Every stored dwell, in the order first saved."""
        with self._reading() as session:
            rows = session.execute(
                select(DwellEventRow.dwell_key).where(DwellEventRow.seq == 0).order_by(DwellEventRow.id)
            ).all()
            return [r[0] for r in rows]

    def save_office_report(
        self, *, sender_id: int, session: int, seq: int, kind: str, sent_s: float, data: Any
    ) -> dict[str, Any] | None:
        """Keep one report of the management office; return it as ``office_reports`` gives it, or
        None if it was already there (idempotent: the same (sender, session, seq) again changes
        nothing, whoever sent it twice)."""
        report = {"sender_id": sender_id, "session": session, "seq": seq, "kind": kind, "sent_s": sent_s}
        return self.save_office_reports([{**report, "data": data}])[0]

    def save_office_reports(self, reports: Sequence[Mapping[str, Any]]) -> list[dict[str, Any] | None]:
        """Keep several reports of the management office in one transaction (SPEC §1 claims 7, 20).

        Each report is a mapping with the keyword arguments of ``office_report_values``. Returns,
        in order, each report as ``office_reports`` gives it, or None where its (sender, session,
        seq) was kept already (also earlier in the same list). When it returns, the transaction is
        committed and durable (``synchronous=FULL`` / ``synchronous_commit=on``): the office may
        acknowledge them. When it raises, nothing of the list was kept (``StoreUnavailable``: try
        again later; ``StoreCorrupt``: never).
        """
        values = [office_report_values(**r) for r in reports]
        for attempt in range(2):
            received = _utc_now()
            try:
                with self._session() as session_, session_.begin():
                    out: list[dict[str, Any] | None] = []
                    rows: list[tuple[int, OfficeReportRow]] = []
                    seen: set[tuple[int, int, int]] = set()
                    for v in values:
                        key = (v["sender_id"], v["session"], v["seq"])
                        found = session_.scalar(
                            select(OfficeReportRow.id).where(
                                OfficeReportRow.sender_id == key[0],
                                OfficeReportRow.session == key[1],
                                OfficeReportRow.seq == key[2],
                            )
                        )
                        if found is not None or key in seen:
                            out.append(None)
                            continue
                        seen.add(key)
                        row = OfficeReportRow(**v, received_utc=received)
                        session_.add(row)
                        rows.append((len(out), row))
                        out.append(None)
                    session_.flush()  # assigns the ids
                    for i, row in rows:
                        out[i] = _office_dict(row)
                return out  # committed: the ``with`` block ended without an error
            except IntegrityError as exc:  # another writer kept one between our look and our insert
                if attempt == 1:
                    raise _db_error(self._label, f"cannot save {len(values)} office report(s)", exc) from None
            except SQLAlchemyError as exc:
                raise _db_error(self._label, f"cannot save {len(values)} office report(s)", exc) from None
        raise AssertionError("unreachable")  # pragma: no cover

    def office_reports(
        self, *, kind: str | None = None, after_id: int = 0, limit: int = 10_000, latest: bool = False
    ) -> list[dict[str, Any]]:
        """The office's reports in the order received (``id`` > ``after_id``), ``data`` decoded: the
        first ``limit`` of them, or with ``latest`` the last ``limit``."""
        with self._reading() as session:
            q = select(OfficeReportRow).where(OfficeReportRow.id > after_id)
            if kind is not None:
                q = q.where(OfficeReportRow.kind == kind)
            order = OfficeReportRow.id.desc() if latest else OfficeReportRow.id
            rows = [_office_dict(r) for r in session.scalars(q.order_by(order).limit(limit)).all()]
            return rows[::-1] if latest else rows

    def office_report_count(self) -> int:
        with self._reading() as session:
            return int(session.scalar(select(func.count()).select_from(OfficeReportRow)) or 0)

    # -- reading ------------------------------------------------------------
    def runs(self) -> list[dict[str, Any]]:
        """Every stored run, oldest first; ``parameters`` decoded from JSON."""
        cols = [RunRow.id, *(getattr(RunRow, f) for f in _RUN_FIELDS)]
        with self._reading() as session:
            rows = session.execute(select(*cols).order_by(RunRow.id)).all()
        out = []
        for row in rows:
            d = dict(zip(("id", *_RUN_FIELDS), row, strict=True))
            d["parameters"] = json.loads(d.pop("parameters_json"))
            out.append(d)
        return out

    def commands(self, run_id: int) -> list[dict[str, Any]]:
        """The command history of one run in the order computed (claim 20).

        Keys ``COMMAND_FIELDS`` then ``SENT_FIELDS`` (``telegram`` decoded from
        JSON); the ``SENT_FIELDS`` are None in rows written by schema version 1.
        """
        with self._reading() as session:
            return [_decode_command(c) for c in _command_dicts(session, run_id)]

    def stations(self) -> list[dict[str, Any]]:
        """Every stored station (claim 8), in the order first saved.

        Keys ``id``, ``STATION_FIELDS`` (the JSON columns decoded), ``created_utc``, ``updated_utc``.
        """
        with self._reading() as session:
            rows = session.scalars(select(StationRow).order_by(StationRow.id)).all()
            return [_station_dict(r) for r in rows]

    def station(self, line: str, name: str) -> dict[str, Any] | None:
        """The station ``name`` of the line ``line`` (as ``stations()`` gives it), or None."""
        with self._reading() as session:
            row = session.scalars(
                select(StationRow).where(StationRow.line == line, StationRow.name == name)
            ).one_or_none()
            return None if row is None else _station_dict(row)

    def schema_version(self) -> int:
        """The schema version of the open file (``SCHEMA_VERSION`` once opened)."""
        with self._reading() as session:
            return int(session.scalar(select(func.max(SchemaInfoRow.version))) or 0)

    def result(self, run_id: int) -> dict[str, Any] | None:
        """The result of one run (keys ``RESULT_FIELDS``), or None if there is none."""
        with self._reading() as session:
            return _result_dict(session, run_id)

    def _reading(self) -> _ReadSession:
        return _ReadSession(self)


class _ReadSession:
    """A session whose database errors come out as one-line ``RailstopError``s."""

    def __init__(self, store: Store) -> None:
        self._store = store
        self._session: Session | None = None

    def __enter__(self) -> Session:
        self._session = self._store._session()
        return self._session

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        assert self._session is not None
        self._session.close()
        if isinstance(exc, SQLAlchemyError):
            raise _db_error(self._store._label, "cannot read", exc) from None


#: SQLite's busy time-out: how long a statement waits for another connection's lock.
DEFAULT_BUSY_TIMEOUT_S = 5.0
#: How long a PostgreSQL connection may take to be made (libpq's ``connect_timeout``).
PG_CONNECT_TIMEOUT_S = 10


def open_store(
    path: str | Path, *, check_integrity: bool = False, busy_timeout_s: float = DEFAULT_BUSY_TIMEOUT_S
) -> Store:
    """Open (creating if needed) the event database at ``path``.

    ``path`` is a SQLite file, or a full SQLAlchemy URL when it is a string
    starting with ``sqlite:`` or ``postgresql``. Problems (missing or
    read-only directory, not a database, no driver) raise ``RailstopError``
    with a one-line message naming the path: ``StoreUnavailable`` for what may
    pass (a lock, a server not answering), ``StoreCorrupt`` for a damaged file.
    ``check_integrity``: run SQLite's ``PRAGMA quick_check`` first and refuse a
    damaged file before anything is written to it. ``busy_timeout_s``: SQLite's
    busy time-out (how long a statement waits for another connection's lock).
    Connections are checked before each use (``pool_pre_ping``): one a
    restarted PostgreSQL server dropped is replaced, not used.
    """
    if isinstance(path, str) and path.startswith(("sqlite:", "postgresql")):
        try:
            url = make_url(path)
        except ArgumentError:
            raise RailstopError(f"{path}: not a valid database URL") from None
        if url.drivername == "postgresql":
            # The driver railstop installs (psycopg 3), not SQLAlchemy's default (psycopg2).
            url = url.set(drivername="postgresql+psycopg")
        # Never echo a password into logs or terminals.
        label = url.render_as_string(hide_password=True)
        db = url.database
        if url.get_backend_name() == "sqlite" and db and db != ":memory:" and not db.startswith("file:"):
            _check_sqlite_file(Path(db).expanduser(), label)
    else:
        label = str(path)
        file = Path(path).expanduser()
        _check_sqlite_file(file, label)
        # URL.create, not string formatting: a '?' or '#' in a file name stays a file name.
        url = URL.create("sqlite", database=str(file))
    if not (isinstance(busy_timeout_s, int | float) and 0.0 <= busy_timeout_s <= 3600.0):
        raise RailstopError(f"{label}: busy time-out: 0 to 3600 s (got {busy_timeout_s!r})")
    connect_args: dict[str, Any] = {}
    if url.get_backend_name() == "sqlite":
        connect_args["timeout"] = float(busy_timeout_s)
    elif url.get_backend_name() == "postgresql":
        # Bounded: a server that does not answer is a failure that may pass, not a hang.
        if "connect_timeout" not in url.query:
            connect_args["connect_timeout"] = PG_CONNECT_TIMEOUT_S
        # SPEC §1 claims 7, 20 (a report acknowledged is a report stored): a commit returns once
        # it is on the server's disk, whatever the server's default says.
        if "options" not in url.query:
            connect_args["options"] = "-c synchronous_commit=on"
    try:
        engine = create_engine(url, pool_pre_ping=True, connect_args=connect_args)
    except (SQLAlchemyError, ImportError) as exc:
        raise RailstopError(f"{label}: cannot open the event database: {_one_line(exc)}") from None
    if engine.dialect.name == "sqlite":
        # SQLite ignores foreign keys unless asked, per connection; synchronous=FULL: a commit
        # is on the disk when it returns (the durability the office's acknowledgement needs).
        event.listen(engine, "connect", _sqlite_connection_setup)
        if check_integrity:
            try:
                _check_integrity(engine, label)
            except RailstopError:
                engine.dispose()
                raise
    # Two processes opening the same new or old file may both create or migrate it: the
    # second one's statements then fail on what the first did, and a second pass finds
    # the file up to date.
    for attempt in range(2):
        try:
            _prepare_schema(engine, label)
            break
        except RailstopError:
            engine.dispose()
            raise
        except ImportError as exc:
            engine.dispose()
            raise RailstopError(f"{label}: cannot open the event database: {_one_line(exc)}") from None
        except SQLAlchemyError as exc:
            # A damaged file is not the race above: no second pass.
            if attempt == 1 or _kind_of(exc) is StoreCorrupt:
                engine.dispose()
                raise _db_error(label, "cannot open the event database", exc) from None
    return Store(engine, label)


def _check_integrity(engine: Engine, label: str) -> None:
    """Refuse a damaged SQLite file (``PRAGMA quick_check``) before anything is written to it."""
    try:
        with engine.connect() as conn:
            found = [str(r[0]) for r in conn.exec_driver_sql("PRAGMA quick_check").all()]
    except SQLAlchemyError as exc:
        raise _db_error(label, "integrity check (PRAGMA quick_check)", exc) from None
    if found != ["ok"]:
        more = f" (and {len(found) - 1} more)" if len(found) > 1 else ""
        raise StoreCorrupt(
            f"{label}: integrity check (PRAGMA quick_check): {found[0] if found else 'no answer'}{more} "
            "(the file is damaged: refused, left as it is)"
        )


# -- schema versions ----------------------------------------------------------


def _prepare_schema(engine: Engine, label: str) -> None:
    """Create the tables of a new file, bring an older one up to ``SCHEMA_VERSION``; refuse a
    database of another program (tables, none of railstop's) untouched.

    A file without ``schema_info`` whose tables exist is version 1. Every
    column added since is nullable: missing ones are added with ``ALTER
    TABLE ... ADD COLUMN`` (old rows keep NULL, nothing is rewritten), missing
    tables are created. A file of a newer version is refused untouched.
    """
    with engine.begin() as conn:
        names = set(inspect(conn).get_table_names())
        found = _file_version(conn, names)
        if found > SCHEMA_VERSION:
            raise RailstopError(
                f"{label}: written by a newer railstop (database schema version {found}, this "
                f"railstop knows up to {SCHEMA_VERSION}); open it with that version or use another file"
            )
        if found == SCHEMA_VERSION:
            return
        if found == 0 and names:
            # Another program's database (tables, none of ours): refused untouched, not extended
            # with railstop's tables beside its own.
            shown = ", ".join(sorted(names)[:5]) + (", ..." if len(names) > 5 else "")
            raise RailstopError(
                f"{label}: not a railstop database (it holds other tables: {shown}); railstop never "
                "writes into another program's database: give a new file"
            )
        _Base.metadata.create_all(conn)
        added = _add_missing_columns(conn, names, label)
        if found == 0:
            note = "created"
        else:
            new_tables = sorted(set(_Base.metadata.tables) - names)
            note = f"migrated from version {found}: new tables {', '.join(new_tables) or 'none'}; "
            note += f"new columns {', '.join(added) or 'none'}"
        conn.execute(insert(SchemaInfoRow).values(version=SCHEMA_VERSION, applied_utc=_utc_now(), note=note))


def _file_version(conn: Connection, names: set[str]) -> int:
    """The file's schema version: 0 for an empty file, 1 for tables without ``schema_info``."""
    if SchemaInfoRow.__tablename__ in names:
        version = conn.scalar(select(func.max(SchemaInfoRow.version)))
        if version is not None:
            return int(version)
    return 1 if names & set(_Base.metadata.tables) else 0


def _add_missing_columns(conn: Connection, existing: set[str], label: str) -> list[str]:
    """Add to every table the file already had the model's columns it lacks; return ``table.column``s."""
    added = []
    prep = conn.dialect.identifier_preparer
    for table in _Base.metadata.sorted_tables:
        if table.name not in existing:
            continue
        present = {c["name"] for c in inspect(conn).get_columns(table.name)}
        for column in table.columns:
            if column.name in present:
                continue
            if not column.nullable:
                raise RailstopError(
                    f"{label}: table {table.name} lacks column {column.name}, which cannot be added"
                )
            kind = column.type.compile(dialect=conn.dialect)
            conn.execute(
                text(f"ALTER TABLE {prep.format_table(table)} ADD COLUMN {prep.format_column(column)} {kind}")
            )
            added.append(f"{table.name}.{column.name}")
    return added


# -- helpers ------------------------------------------------------------------


def _sqlite_connection_setup(dbapi_connection: Any, _record: Any) -> None:
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA foreign_keys=ON")
    # FULL, whatever the build's default: with the rollback journal the store uses (and in WAL
    # too) a committed transaction survives a power cut.
    cursor.execute("PRAGMA synchronous=FULL")
    cursor.close()


def _check_sqlite_file(file: Path, label: str) -> None:
    """Refuse up front what SQLite would report only as 'unable to open database file'."""
    if file.is_dir():
        raise RailstopError(f"{label}: is a directory, not a database file")
    parent = file.parent
    if not parent.is_dir():
        raise RailstopError(f"{label}: directory {str(parent)!r} does not exist")
    # SQLite writes its journal next to the file, so the directory must be writable too.
    if not os.access(parent, os.W_OK | os.X_OK):
        raise RailstopError(f"{label}: directory {str(parent)!r} is not writable")
    if file.exists() and not os.access(file, os.R_OK | os.W_OK):
        raise RailstopError(f"{label}: file is not readable and writable")


def _one_line(exc: BaseException) -> str:
    """The driver's own message (not SQLAlchemy's multi-line wrapper), first line only."""
    inner = getattr(exc, "orig", None) or exc
    text = str(inner).strip()
    return text.splitlines()[0] if text else type(inner).__name__


def _upsert_station(session: Session, values: dict[str, Any]) -> int:
    """SPEC §1 claim 8: insert the station, leave it when identical, else update it; return its id."""
    row = session.scalars(
        select(StationRow).where(StationRow.line == values["line"], StationRow.name == values["name"])
    ).one_or_none()
    if row is None:
        now = _utc_now()
        row = StationRow(**values, created_utc=now, updated_utc=now)
        session.add(row)
        session.flush()  # assigns row.id; a concurrent insert fails here, and the save is retried
        return row.id
    if any(getattr(row, k) != v for k, v in values.items()):
        for k, v in values.items():
            setattr(row, k, v)
        row.updated_utc = _utc_now()
    return row.id


def _upsert(
    session: Session,
    values: dict[str, Any],
    commands: list[dict[str, Any]],
    result: dict[str, Any],
) -> int:
    row = session.scalars(select(RunRow).where(RunRow.run_key == values["run_key"])).one_or_none()
    if row is None:
        row = RunRow(**values)
        session.add(row)
        session.flush()  # assigns row.id
    else:
        same = (
            all(getattr(row, k) == v for k, v in values.items() if k != "created_utc")
            and _command_dicts(session, row.id) == commands
            and _result_dict(session, row.id) == result
        )
        if same:
            return row.id
        for k, v in values.items():
            setattr(row, k, v)
        # Delete with explicit statements before inserting: the ORM flushes
        # inserts before deletes, which would trip the (run_id, seq) constraint.
        session.execute(delete(CommandRow).where(CommandRow.run_id == row.id))
        session.execute(delete(ResultRow).where(ResultRow.run_id == row.id))
    run_id = row.id
    session.add_all(CommandRow(run_id=run_id, seq=i, **c) for i, c in enumerate(commands))
    session.add(ResultRow(run_id=run_id, **result))
    return run_id


# The command columns as stored: the record, then what went on the air (claim 20).
_COMMAND_COLUMNS: tuple[str, ...] = (*COMMAND_FIELDS, "emergency", "telegram_type", "telegram_json")


def _command_dicts(session: Session, run_id: int) -> list[dict[str, Any]]:
    cols = [getattr(CommandRow, f) for f in _COMMAND_COLUMNS]
    rows = session.execute(select(*cols).where(CommandRow.run_id == run_id).order_by(CommandRow.seq)).all()
    return [dict(zip(_COMMAND_COLUMNS, r, strict=True)) for r in rows]


def _decode_command(row: dict[str, Any]) -> dict[str, Any]:
    out = dict(row)
    raw = out.pop("telegram_json")
    out["telegram"] = None if raw is None else json.loads(raw)
    return out


def _station_dict(row: StationRow) -> dict[str, Any]:
    out: dict[str, Any] = {"id": row.id}
    for name in STATION_FIELDS:
        out[name] = json.loads(getattr(row, f"{name}_json")) if name in _STATION_JSON else getattr(row, name)
    out["created_utc"] = row.created_utc
    out["updated_utc"] = row.updated_utc
    return out


def _result_dict(session: Session, run_id: int) -> dict[str, Any] | None:
    cols = [getattr(ResultRow, f) for f in RESULT_FIELDS]
    row = session.execute(select(*cols).where(ResultRow.run_id == run_id)).one_or_none()
    return None if row is None else dict(zip(RESULT_FIELDS, row, strict=True))


def _dwell_row(key: str, station: str, seq: int, event: Any) -> dict[str, Any]:
    src = f"dwell {key!r}: event {seq}"
    try:
        t_s, signal, value = event.t_s, event.signal, event.value
    except AttributeError:
        raise RailstopError(f"{src}: needs t_s, signal and value (got {event!r})") from None
    if isinstance(value, bool | np.bool_):
        value = int(value)
    if not isinstance(value, str | numbers.Real) or (isinstance(value, float) and not math.isfinite(value)):
        raise RailstopError(f"{src}: value: expected a finite number or a string (got {value!r})")
    return {
        "dwell_key": key,
        "station": station,
        "seq": seq,
        "t_s": _value(src, "t_s", t_s, float, False),
        "signal": _value(src, "signal", signal, str, False),
        "value": json.dumps(value.item() if isinstance(value, np.generic) else value),
    }


def _office_dict(r: OfficeReportRow) -> dict[str, Any]:
    return {
        "id": r.id,
        "sender_id": r.sender_id,
        "session": r.session,
        "seq": r.seq,
        "kind": r.kind,
        "sent_s": r.sent_s,
        "data": json.loads(r.data_json),
        "received_utc": r.received_utc,
    }


def _dwell_dicts(session: Session, key: str) -> list[dict[str, Any]]:
    cols = [DwellEventRow.station, DwellEventRow.t_s, DwellEventRow.signal, DwellEventRow.value]
    rows = session.execute(
        select(*cols).where(DwellEventRow.dwell_key == key).order_by(DwellEventRow.seq)
    ).all()
    return [dict(zip(("station", "t_s", "signal", "value"), r, strict=True)) for r in rows]


def _normalise(
    run: StopRecord,
) -> tuple[dict[str, Any], list[dict[str, Any]], dict[str, Any], dict[str, Any] | None]:
    """Plain Python values for every column, or a ``RailstopError`` naming the field.

    numpy scalars become int/float/bool; NaN becomes None where None is
    allowed (the engine marks "unknown" with NaN) and is refused elsewhere.
    """
    key = run.run_key
    if not isinstance(key, str) or not key:
        raise RailstopError(f"run_key: must be a non-empty string (got {key!r})")
    src = f"run {key!r}"
    values = {
        "run_key": key,
        "station": _value(src, "station", run.station, str, False),
        "controller": _value(src, "controller", run.controller, str, False),
        "seed": _value(src, "seed", run.seed, int, False),
        "line": _value(src, "line", run.line, str, False),
        "parameters_json": _parameters_json(src, run.parameters),
        "created_utc": _value(src, "created_utc", run.created_utc, str, False),
    }
    if isinstance(run.commands, Mapping | str) or not isinstance(run.commands, Sequence):
        raise RailstopError(f"{src}: commands: must be a list of dicts (got {type(run.commands)})")
    commands = []
    for i, cmd in enumerate(run.commands):
        if not isinstance(cmd, Mapping):
            raise RailstopError(f"{src}: commands[{i}]: must be a dict (got {cmd!r})")
        for name in (*_COMMAND_SPEC, *SENT_FIELDS):
            if name not in cmd:
                raise RailstopError(f"{src}: commands[{i}].{name}: missing")
        row = {
            name: _value(src, f"commands[{i}].{name}", cmd[name], kind, nullable)
            for name, (kind, nullable) in _COMMAND_SPEC.items()
        }
        # Claim 20: what went on the air (DESIGN rule 10: an emergency stop or not).
        row["emergency"] = _value(src, f"commands[{i}].emergency", cmd["emergency"], bool, False)
        row["telegram_type"] = _value(src, f"commands[{i}].telegram_type", cmd["telegram_type"], str, False)
        telegram = cmd["telegram"]
        if not isinstance(telegram, Mapping):
            raise RailstopError(f"{src}: commands[{i}].telegram: must be a dict (got {telegram!r})")
        row["telegram_json"] = json.dumps(_json_data(src, f"commands[{i}].telegram", telegram))
        commands.append(row)
    result = {
        name: _value(src, name, getattr(run, name), kind, nullable)
        for name, (kind, nullable) in _RESULT_SPEC.items()
    }
    station = None
    if run.station_data is not None:
        station = _station_values(src, run.station_data)
        if (station["line"], station["name"]) != (values["line"], values["station"]):
            raise RailstopError(
                f"{src}: station_data: is station {station['name']!r} of line {station['line']!r}, "
                f"the run's is {values['station']!r} of line {values['line']!r}"
            )
    return values, commands, result, station


def _station_values(src: str, st: Any) -> dict[str, Any]:
    """The ``stations`` columns of a ``StationRecord`` (SPEC §1 claim 8), or a ``RailstopError``."""
    if not isinstance(st, StationRecord):
        raise RailstopError(f"{src}: station_data: must be a StationRecord (got {type(st).__name__})")
    where = f"{src}: station_data"

    def finite(name: str, v: Any, nullable: bool = False) -> float | None:
        f = _value(where, name, v, float, nullable)
        if f is not None and not math.isfinite(f):
            raise RailstopError(f"{where}: {name}: expected a finite number (got {v!r})")
        return f

    def chainages(name: str, v: Any) -> str:
        if isinstance(v, str | Mapping) or not isinstance(v, Sequence):
            raise RailstopError(f"{where}: {name}: must be a list of numbers (got {v!r})")
        return json.dumps([finite(f"{name}[{i}]", x) for i, x in enumerate(v)])

    if not isinstance(st.tasc, Mapping):
        raise RailstopError(f"{where}: tasc: must be a dict (got {type(st.tasc).__name__})")
    return {
        "line": _value(where, "line", st.line, str, False),
        "name": _value(where, "name", st.name, str, False),
        "stop_point_m": finite("stop_point_m", st.stop_point_m),
        "platform_length_m": finite("platform_length_m", st.platform_length_m),
        "psd_tolerance_m": finite("psd_tolerance_m", st.psd_tolerance_m),
        "signal_form": _value(where, "signal_form", st.signal_form, int, False),
        "detector_positions_m_json": chainages("detector_positions_m", st.detector_positions_m),
        "detectors_before_stop_m_json": chainages("detectors_before_stop_m", st.detectors_before_stop_m),
        "doppler_position_m": finite("doppler_position_m", st.doppler_position_m, nullable=True),
        # Sorted keys: the same zone gives the same text, so an unchanged station compares equal.
        "tasc_json": json.dumps(_json_data(where, "tasc", st.tasc), sort_keys=True),
    }


def _value(src: str, name: str, v: Any, kind: type, nullable: bool) -> Any:
    def bad(message: str) -> RailstopError:
        return RailstopError(f"{src}: {name}: {message} (got {v!r})")

    if v is None:
        if nullable:
            return None
        raise bad("a value is required")
    if kind is str:
        if not isinstance(v, str):
            raise bad("expected a string")
        return v
    if kind is bool:
        if not isinstance(v, bool | np.bool_):
            raise bad("expected true or false")
        return bool(v)
    if kind is int:
        # bool is an int subclass, but True as a notch or a seed is a bug.
        if isinstance(v, bool | np.bool_) or not isinstance(v, numbers.Integral):
            raise bad("expected an integer")
        if not -(2**63) <= int(v) < 2**63:  # SQLite's INTEGER (and BigInteger) is 64-bit
            raise bad("outside the 64-bit integer range of the database")
        return int(v)
    if isinstance(v, bool | np.bool_) or not isinstance(v, numbers.Real):
        raise bad("expected a number")
    f = float(v)
    if math.isnan(f):
        if nullable:
            return None
        raise bad("not a number")
    return f


def _parameters_json(src: str, params: Any) -> str:
    if not isinstance(params, Mapping):
        raise RailstopError(f"{src}: parameters: must be a dict (got {type(params)})")
    # Sorted keys: the same parameters give the same text, so a re-save compares equal.
    return json.dumps(_json_data(src, "parameters", params), sort_keys=True)


def _json_data(src: str, name: str, v: Any) -> Any:
    """``v`` as plain JSON data (numpy scalars and arrays become Python values), or a ``RailstopError``.

    Dicts need string keys; non-finite floats are kept (JSON ``NaN``/``Infinity``).
    """
    if v is None or isinstance(v, str | bool):
        return v
    if isinstance(v, np.bool_):
        return bool(v)
    if isinstance(v, numbers.Integral):
        return int(v)
    if isinstance(v, numbers.Real):
        return float(v)
    if isinstance(v, Mapping):
        out = {}
        for k, x in v.items():
            if not isinstance(k, str):
                raise RailstopError(f"{src}: {name}: keys must be strings (got {k!r})")
            out[k] = _json_data(src, f"{name}.{k}", x)
        return out
    if isinstance(v, Sequence | np.ndarray) and not isinstance(v, bytes | bytearray):
        return [_json_data(src, f"{name}[{i}]", x) for i, x in enumerate(v)]
    raise RailstopError(f"{src}: {name}: expected a number, string, None, list or dict (got {v!r})")
