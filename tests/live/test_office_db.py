"""The management office survives its database (SPEC §1 claims 7, 20; DESIGN rule 10).

A report acknowledged is a report stored: the office acknowledges only what is
committed, holds the rest unacknowledged (its senders send it again) and
retries the database with a bounded back-off. Tested with the real databases
and real processes: ``railstop office serve`` as a subprocess on a loopback UDP
port, a real :class:`~railstop.live.office.OfficeClient` sending to it, and

* a SQLite write lock held from another connection past the office's busy
  time-out;
* the throwaway PostgreSQL cluster stopped and started again while reports
  arrive;
* a SQLite file damaged before the start (refused, untouched) and while the
  office runs (nothing more acknowledged, the office stops);
* the office's process out of file descriptors (its ``RLIMIT_NOFILE`` lowered
  from outside with ``prlimit``).
"""

from __future__ import annotations

import asyncio
import json
import os
import resource
import signal
import sqlite3
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from railstop.link.office_link import LinkTimes
from railstop.link.udp import EpochClock
from railstop.live.office import OFFICE_BUSY_TIMEOUT_S, Backoff, OfficeClient
from railstop.store import StoreCorrupt, StoreError, StoreUnavailable, open_store

KEY = bytes(range(32))
SENDER = 7


# ------------------------------------------------------------------ helpers


class Office:
    """``railstop office serve`` as a subprocess; its stderr lines collected as they come."""

    def __init__(self, db: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "railstop.cli", "office", "serve", "--db", db, "--port", "0",
             "--senders", "1-20"],
            env={**os.environ, "RAILSTOP_OFFICE_KEY": KEY.hex()},
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        self.lines: list[str] = []
        self._ready = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        if not self._ready.wait(60.0):
            self.proc.kill()
            raise AssertionError(f"the office did not start: {self.lines}")
        listening = next((x for x in self.lines if x.startswith("office listening on 127.0.0.1:")), None)
        if listening is None:
            self.proc.wait(timeout=30)
            self._reader.join(timeout=5)
            raise AssertionError(f"the office did not start: {self.lines}")
        self.port = int(listening.split("127.0.0.1:")[1].split()[0])

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line.rstrip("\n"))
            if line.startswith("office listening"):
                self._ready.set()
        self._ready.set()

    def said(self, text: str) -> list[str]:
        return [x for x in self.lines if text in x]

    def stop(self) -> dict[str, Any]:
        """SIGTERM; the counts it prints (its exit status must be 0)."""
        self.proc.send_signal(signal.SIGTERM)
        assert self.proc.stdout is not None
        out = self.proc.stdout.read()
        self.proc.wait(timeout=30)
        self._reader.join(timeout=5)
        assert self.proc.returncode == 0, (self.proc.returncode, self.lines)
        return dict(json.loads(out.strip().splitlines()[-1]))

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)


@pytest.fixture
def office_factory() -> Iterator[Callable[[str], Office]]:
    started: list[Office] = []

    def start(db: str) -> Office:
        office = Office(db)
        started.append(office)
        return office

    yield start
    for office in started:
        office.kill()


def client(port: int) -> OfficeClient:
    return OfficeClient(
        own_id=SENDER,
        office=("127.0.0.1", port),
        master_key=KEY,
        clock=EpochClock(0.0),
        times=LinkTimes(resend_s=0.3),
    )


async def send(office: OfficeClient, first: int, n: int, gap_s: float = 0.005) -> None:
    for i in range(first, first + n):
        office.report("stop-result", {"i": i, "station": "Riverside", "error_m": 0.001 * i})
        await asyncio.sleep(gap_s)


def stored_numbers(db: str) -> list[int]:
    with open_store(db) as store:
        return sorted(int(r["data"]["i"]) for r in store.office_reports())


def damage_office_table(path: Path) -> None:
    """Overwrite the root pages of ``office_reports`` and its indexes with garbage and bump the
    file change counter, as a faulty writer of the file would (the header, page 1, stays whole)."""
    with sqlite3.connect(path) as con:
        roots = [
            r[0]
            for r in con.execute(
                "SELECT rootpage FROM sqlite_master WHERE tbl_name = 'office_reports' AND rootpage > 0"
            )
        ]
        page = con.execute("PRAGMA page_size").fetchone()[0]
    con.close()
    assert roots
    with path.open("r+b") as f:
        for root in roots:
            f.seek((root - 1) * page)
            f.write(bytes((i * 37 + 11) % 251 for i in range(page)))
        f.seek(24)
        (changes,) = struct.unpack(">I", f.read(4))
        f.seek(24)
        f.write(struct.pack(">I", changes + 1))


# ------------------------------------------------------------------ the pieces


@given(
    first_s=st.floats(0.001, 1.0),
    factor=st.floats(1.0, 4.0),
    extra_s=st.floats(0.0, 10.0),
    failures=st.lists(st.integers(1, 10_000), min_size=2, max_size=20),
)
def test_the_back_off_grows_and_stays_bounded(
    first_s: float, factor: float, extra_s: float, failures: list[int]
) -> None:
    b = Backoff(first_s=first_s, factor=factor, max_s=first_s + extra_s)
    assert b.delay_s(1) == pytest.approx(first_s)
    delays = [b.delay_s(n) for n in sorted(failures)]
    assert all(first_s <= d <= b.max_s for d in delays)
    assert delays == sorted(delays)


def test_a_back_off_that_would_not_back_off_is_refused() -> None:
    from railstop.errors import RailstopError

    for bad in ({"first_s": 0.0}, {"first_s": 3.0, "max_s": 2.0}, {"factor": 0.5}):
        with pytest.raises(RailstopError, match="back-off"):
            Backoff(**bad)


def test_a_held_lock_is_unavailable_and_keeps_nothing_of_the_batch(tmp_path: Path) -> None:
    """The store's side of the office's rule: a batch that meets another connection's write lock
    past the busy time-out raises ``StoreUnavailable`` (to retry) and keeps none of its reports."""
    db = tmp_path / "office.db"
    rows = [
        {"sender_id": 7, "session": 1, "seq": i, "kind": "stop-result", "sent_s": 0.0, "data": {"i": i}}
        for i in range(1, 4)
    ]
    with open_store(db, busy_timeout_s=0.1) as store:
        holder = sqlite3.connect(db, isolation_level=None)
        holder.execute("BEGIN IMMEDIATE")
        try:
            with pytest.raises(StoreUnavailable, match="database is locked") as info:
                store.save_office_reports(rows)
            assert str(db) in str(info.value) and "\n" not in str(info.value)
        finally:
            holder.execute("ROLLBACK")
            holder.close()
        assert store.office_report_count() == 0
        saved = store.save_office_reports([*rows, rows[0]])  # again, and one twice in the list
        assert [r is not None for r in saved] == [True, True, True, False]
        assert store.save_office_reports(rows) == [None, None, None]
        assert store.office_report_count() == 3


def test_commits_are_durable_on_sqlite(tmp_path: Path) -> None:
    with open_store(tmp_path / "office.db") as store:
        d = store.durability()
    assert d["synchronous"] == "2"  # FULL: a commit is on the disk when it returns
    assert d["journal_mode"] == "delete"


def test_commits_are_durable_on_postgresql_whatever_the_server_default(restartable_postgres: Any) -> None:
    """The throwaway cluster's default is ``synchronous_commit=off``; the store's connections ask
    for ``on``: a commit returns once it is on the server's disk."""
    from sqlalchemy import create_engine, text

    plain = create_engine(restartable_postgres.url.replace("postgresql://", "postgresql+psycopg://", 1))
    with plain.connect() as con:
        assert con.execute(text("SHOW synchronous_commit")).scalar() == "off"
    plain.dispose()
    with open_store(restartable_postgres.url) as store:
        assert store.durability()["synchronous_commit"] == "on"


def test_a_refused_postgresql_connection_is_unavailable_not_fatal() -> None:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # nobody listens there once closed
    with pytest.raises(StoreUnavailable, match="cannot open the event database") as info:
        open_store(f"postgresql://railstop@127.0.0.1:{port}/postgres")
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("name", "kind"),
    [
        ("AdminShutdown", StoreUnavailable),  # 57P01: the server shutting down (a restart)
        ("CannotConnectNow", StoreUnavailable),  # 57P03: the server starting
        ("ConnectionFailure", StoreUnavailable),  # 08006
        ("TooManyConnections", StoreUnavailable),  # 53300
        ("DiskFull", StoreUnavailable),  # 53100
        ("SerializationFailure", StoreUnavailable),  # 40001
        ("ReadOnlySqlTransaction", StoreUnavailable),  # 25006: a standby not yet promoted
        ("DataCorrupted", StoreCorrupt),  # XX001
        ("IndexCorrupted", StoreCorrupt),  # XX002
        ("UndefinedTable", StoreError),  # 42P01: does not pass by waiting
        ("UniqueViolation", StoreError),
    ],
)
def test_postgresql_failures_are_told_apart_by_their_sqlstate(name: str, kind: type) -> None:
    """The errors psycopg raises for each SQLSTATE, as SQLAlchemy wraps them: a failure that passes
    is ``StoreUnavailable`` (the office retries), data corruption ``StoreCorrupt``, anything else a
    plain ``StoreError`` (the office stops); never the wrong one of the three."""
    import psycopg.errors
    from sqlalchemy.exc import DBAPIError

    from railstop.store.db import _db_error

    orig = getattr(psycopg.errors, name)("server said no")
    wrapped = DBAPIError.instance("INSERT ...", {}, orig, psycopg.Error)
    err = _db_error("postgresql://railstop@db/office", "cannot save 1 office report(s)", wrapped)
    assert type(err) is kind
    assert str(err).startswith("postgresql://railstop@db/office: cannot save") and "\n" not in str(err)


def test_a_damaged_file_is_told_apart_and_left_as_it_is(tmp_path: Path) -> None:
    db = tmp_path / "office.db"
    with open_store(db) as store:
        store.save_office_report(sender_id=7, session=1, seq=1, kind="stop-result", sent_s=0.0, data={})
    damage_office_table(db)
    before = db.read_bytes()
    # Opening without the check reads only the schema: the damage shows only with the check.
    open_store(db).close()
    with pytest.raises(StoreCorrupt, match="quick_check") as info:
        open_store(db, check_integrity=True)
    assert str(db) in str(info.value) and "\n" not in str(info.value)
    assert db.read_bytes() == before


# ------------------------------------------------------------------ end to end


def test_a_sqlite_lock_held_past_the_busy_timeout_holds_the_acknowledgements(
    tmp_path: Path, office_factory: Callable[[str], Office]
) -> None:
    """Another connection holds the office file's write lock for 3 s (the office's busy time-out is
    1 s) while 30 reports arrive: none is acknowledged while it is held; once it is released every
    report is stored once and acknowledged; the office said so in two lines, not one per retry."""
    db = str(tmp_path / "office.db")
    office = office_factory(db)
    hold_s = 3.0
    assert hold_s > 2 * OFFICE_BUSY_TIMEOUT_S

    async def run() -> tuple[int, int, bool]:
        async with client(office.port) as c:
            await send(c, 0, 10)
            assert await c.drain(timeout_s=20.0)
            holder = sqlite3.connect(db, isolation_level=None)
            holder.execute("BEGIN IMMEDIATE")  # the write lock, as another writer takes it
            try:
                acked_before = c.outbox.counts["acknowledged"]
                await send(c, 10, 30)
                await asyncio.sleep(hold_s)
                acked_while_held = c.outbox.counts["acknowledged"] - acked_before
                # Nothing was stored meanwhile: acknowledged and stored are the same reports.
                assert stored_numbers(db) == list(range(10))
            finally:
                holder.execute("ROLLBACK")
                holder.close()
            drained = await c.drain(timeout_s=20.0)
            return acked_before, acked_while_held, drained

    acked_before, acked_while_held, drained = asyncio.run(run())
    assert acked_before == 10 and acked_while_held == 0 and drained
    assert stored_numbers(db) == list(range(40))
    assert len(office.said("the database is unavailable")) == 1, office.lines
    assert "database is locked" in office.said("the database is unavailable")[0]
    assert len(office.said("the database is available again")) == 1, office.lines
    counts = office.stop()
    assert counts["stored"] == 40 and counts["db_outages"] == 1
    assert counts["db_retries"] >= 2 and counts["db_unavailable_s"] >= OFFICE_BUSY_TIMEOUT_S


def test_a_postgresql_restart_is_survived(
    restartable_postgres: Any, office_factory: Callable[[str], Office]
) -> None:
    """The cluster is stopped (fast shutdown) while reports arrive and started again 1.5 s later:
    the office keeps running, reconnects, and every report is stored once."""
    from sqlalchemy import create_engine, text

    from railstop.store.db import _Base

    url = restartable_postgres.url
    engine = create_engine(url.replace("postgresql://", "postgresql+psycopg://", 1))
    with engine.begin() as con:  # a database without the store's tables
        for table in _Base.metadata.tables:
            con.execute(text(f"DROP TABLE IF EXISTS {table} CASCADE"))
    engine.dispose()
    office = office_factory(url)
    n = 120

    async def run() -> tuple[int, bool]:
        async with client(office.port) as c:
            await send(c, 0, 40)
            assert await c.drain(timeout_s=20.0)
            await asyncio.to_thread(restartable_postgres.stop)
            try:
                await send(c, 40, 40)
                await asyncio.sleep(1.5)
                acked_while_down = c.outbox.counts["acknowledged"] - 40
            finally:
                await asyncio.to_thread(restartable_postgres.start)
            await send(c, 80, n - 80)
            return acked_while_down, await c.drain(timeout_s=30.0)

    acked_while_down, drained = asyncio.run(run())
    assert acked_while_down == 0 and drained, office.lines
    assert office.proc.poll() is None  # it survived
    assert stored_numbers(url) == list(range(n))
    with open_store(url) as store:
        rows = store.office_reports()
    assert len({(r["session"], r["seq"]) for r in rows}) == n == len(rows)
    assert len(office.said("the database is unavailable")) == 1, office.lines
    assert len(office.said("the database is available again")) == 1, office.lines
    counts = office.stop()
    assert counts["stored"] == n and counts["db_outages"] == 1 and counts["db_retries"] >= 1


def test_a_damaged_sqlite_file_is_refused_at_start_untouched(tmp_path: Path) -> None:
    """A file whose office table is damaged (the schema still reads) and a file that is not a
    database: ``railstop office serve`` refuses each in one line naming it, exit status 2, and
    leaves it byte for byte as it was."""
    damaged = tmp_path / "damaged.db"
    with open_store(damaged) as store:
        for seq in range(1, 50):
            store.save_office_report(
                sender_id=7, session=1, seq=seq, kind="stop-result", sent_s=0.0, data={"i": seq}
            )
    damage_office_table(damaged)
    junk = tmp_path / "junk.db"
    junk.write_bytes(b"not a database " * 300)
    for db in (damaged, junk):
        before = db.read_bytes()
        p = subprocess.run(
            [sys.executable, "-m", "railstop.cli", "office", "serve", "--db", str(db), "--port", "0"],
            env={**os.environ, "RAILSTOP_OFFICE_KEY": KEY.hex()}, capture_output=True, text=True, timeout=30,
        )  # fmt: skip
        assert p.returncode == 2, p.stderr
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1 and str(db) in lines[0] and "damaged" in lines[0], p.stderr
        assert "listening" not in p.stderr and "Traceback" not in p.stderr
        assert db.read_bytes() == before
        assert not Path(f"{db}-journal").exists()


def test_a_file_damaged_while_running_stops_the_acknowledgements(
    tmp_path: Path, office_factory: Callable[[str], Office]
) -> None:
    """20 reports stored and acknowledged; then the office table's pages are overwritten while the
    office runs and 10 more reports arrive: none of them is acknowledged, the office stops with one
    line naming the file (exit status 2) and the sender still holds all 10."""
    db = tmp_path / "office.db"
    office = office_factory(str(db))

    async def run() -> tuple[int, int]:
        async with client(office.port) as c:
            await send(c, 0, 20)
            assert await c.drain(timeout_s=20.0)
            assert stored_numbers(str(db)) == list(range(20))
            damage_office_table(db)
            await send(c, 20, 10)
            end = time.monotonic() + 20.0
            while office.proc.poll() is None and time.monotonic() < end:
                await asyncio.sleep(0.05)
            await asyncio.sleep(0.5)  # an acknowledgement in flight would have arrived
            return c.outbox.counts["acknowledged"], c.pending

    acknowledged, pending = asyncio.run(run())
    assert office.proc.wait(timeout=10) == 2, office.lines
    office._reader.join(timeout=5)
    assert acknowledged == 20 and pending == 10
    error = [x for x in office.lines if x.startswith("error:")]
    assert len(error) == 1 and str(db) in error[0] and "malformed" in error[0], office.lines
    assert "Traceback" not in "\n".join(office.lines)


def test_running_out_of_file_descriptors_is_survived(
    tmp_path: Path, office_factory: Callable[[str], Office]
) -> None:
    """The office's process may open no more files (its soft ``RLIMIT_NOFILE`` lowered to 3 from
    outside): SQLite cannot open its journal, so 20 reports are held unacknowledged; with the limit
    restored every report is stored once, and the office never stopped."""
    db = str(tmp_path / "office.db")
    office = office_factory(db)
    pid = office.proc.pid
    soft, hard = resource.prlimit(pid, resource.RLIMIT_NOFILE)

    async def run() -> tuple[int, bool]:
        async with client(office.port) as c:
            await send(c, 0, 10)
            assert await c.drain(timeout_s=20.0)
            resource.prlimit(pid, resource.RLIMIT_NOFILE, (3, hard))
            try:
                await send(c, 10, 20)
                end = time.monotonic() + 10.0
                while not office.said("the database is unavailable") and time.monotonic() < end:
                    await asyncio.sleep(0.05)
                await asyncio.sleep(1.0)
                acked_while_starved = c.outbox.counts["acknowledged"] - 10
            finally:
                resource.prlimit(pid, resource.RLIMIT_NOFILE, (soft, hard))
            return acked_while_starved, await c.drain(timeout_s=20.0)

    acked_while_starved, drained = asyncio.run(run())
    assert acked_while_starved == 0 and drained, (acked_while_starved, drained, office.lines)
    unavailable = office.said("the database is unavailable")
    assert len(unavailable) == 1 and "unable to open database file" in unavailable[0], office.lines
    assert len(office.said("the database is available again")) == 1, office.lines
    assert stored_numbers(db) == list(range(30))
    counts = office.stop()
    assert counts["stored"] == 30 and counts["db_outages"] == 1, (counts, office.lines)


def test_the_reports_held_are_bounded_and_the_rest_sent_again(tmp_path: Path) -> None:
    """``serve_office`` in this process with room for 5 held reports; another connection holds the
    file's write lock while 20 reports arrive: none is acknowledged, all but 5 are refused
    (``held_full``: their sender sends them again); once the lock goes every report is stored
    once, and the office said two lines."""
    from railstop.live.office import serve_office

    db = str(tmp_path / "office.db")
    open_store(db).close()
    lines: list[str] = []

    async def run() -> tuple[int, bool, Any]:
        stop = asyncio.Event()
        ready: asyncio.Future[tuple[str, int]] = asyncio.get_running_loop().create_future()
        task = asyncio.create_task(
            serve_office(db=db, local=("127.0.0.1", 0), master_key=KEY, senders=(SENDER,),
                         clock=EpochClock(0.0), stop=stop, on_ready=ready.set_result, busy_timeout_s=0.1,
                         max_held=5, log=lines.append)
        )  # fmt: skip
        port = (await asyncio.wait_for(ready, 30.0))[1]
        holder = sqlite3.connect(db, isolation_level=None)
        holder.execute("BEGIN IMMEDIATE")
        try:
            async with client(port) as c:
                await send(c, 0, 20)
                await asyncio.sleep(1.0)
                acked_while_held = c.outbox.counts["acknowledged"]
                holder.execute("ROLLBACK")
                drained = await c.drain(timeout_s=20.0)
        finally:
            holder.close()
            stop.set()
        return acked_while_held, drained, await task

    acked_while_held, drained, stats = asyncio.run(run())
    assert acked_while_held == 0 and drained
    assert stats.rejected.get("held_full", 0) >= 15 and stats.stored == 20
    assert stored_numbers(db) == list(range(20))
    assert len(lines) == 2 and "unavailable" in lines[0] and "available again" in lines[1], lines
    assert stats.outages == 1 and stats.retries >= 2 and stats.unavailable_s > 0.5
