"""The management office on wall-clock time (SPEC §1 claims 7, 20): a UDP service and its client.

:func:`serve_office` binds a UDP port, accepts the wayside's reports through
:class:`~railstop.link.office_link.OfficeInbox` (EN 50159 category 3), keeps
each in the event database (``railstop.store``: SQLite by default, PostgreSQL
by URL) and only then acknowledges it: a report acknowledged is a report
stored. :class:`OfficeClient` is the wayside's end: it queues reports in an
:class:`~railstop.link.office_link.OfficeOutbox`, sends them, sends again what
is not acknowledged, and takes the acknowledgements. Killing the office loses
nothing: the clients keep sending until a restarted office stores and
acknowledges, and the store keeps a report once however often it arrives.

The office survives its database (DESIGN rule 10: what is not stored is not
acknowledged). Receiving and storing run apart: the receiver holds each new
report (once per sender, session and number, at most ``max_held``) and a
storer writes what is held in one transaction, then acknowledges it. A
failure that may pass (``StoreUnavailable``: a SQLite lock held past the busy
time-out, PostgreSQL restarting, no file descriptor left) is retried with a
bounded exponential back-off while the receiver goes on; the clients resend
meanwhile, and nothing is acknowledged until it is committed. The office says
on stderr, one line each, when the database went away and when it came back.
A damaged SQLite file is refused at start (``PRAGMA quick_check``); a damaged
file or any other database failure while running stops the office: nothing
more is acknowledged, and ``serve_office`` raises it.

These are drivers (DESIGN: ``live/``): they own the sockets and the clock; the
link ends they drive are pure.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import secrets
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from railstop.errors import RailstopError
from railstop.link.office_link import LinkTimes, OfficeInbox, OfficeOutbox, Report
from railstop.link.udp import Address, EpochClock, UdpEndpoint, local_for, open_endpoint
from railstop.store import Store, StoreUnavailable, office_report_values, open_store

OFFICE_ID = 900  # the office's id on the safety layer

#: [interpretation] The office's SQLite busy time-out. The office retries on its own (``Backoff``),
#: so a statement need not wait long for another connection's lock: after a second the office says
#: the database is held, and goes on trying.
OFFICE_BUSY_TIMEOUT_S = 1.0
#: At most this many reports are held for storing (about 4 KiB each at most); more are refused
#: unacknowledged (``held_full``) and their senders send them again.
MAX_HELD = 8192
#: At most this many held reports are written in one transaction.
STORE_BATCH = 256


def new_session() -> int:
    """A sender's or the office's session number: random, drawn once per process start."""
    return secrets.randbits(62) + 1


@dataclass(frozen=True, slots=True, kw_only=True)
class Backoff:
    """Bounded exponential back-off of the office's database retries: ``first_s``, then times
    ``factor`` after each failure, never more than ``max_s``.

    [interpretation] 50 ms doubling to 2 s: a lock that passes quickly costs little, and a
    database back after a long outage is noticed within ``max_s`` (the clients resend every
    second meanwhile, so nothing waits on the office's retries but the storing itself).
    """

    first_s: float = 0.05
    factor: float = 2.0
    max_s: float = 2.0

    def __post_init__(self) -> None:
        if not (0.0 < self.first_s <= self.max_s and self.factor >= 1.0):
            raise RailstopError(
                f"back-off: needs 0 < first_s <= max_s and factor >= 1 "
                f"(got first_s={self.first_s!r}, max_s={self.max_s!r}, factor={self.factor!r})"
            )

    def delay_s(self, failures: int) -> float:
        """The wait after the ``failures``-th failure in a row (1, 2, ...)."""
        return min(self.max_s, self.first_s * self.factor ** min(max(failures - 1, 0), 64))


@dataclass
class OfficeStats:
    stored: int = 0
    duplicates: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    retries: int = 0  # database attempts that failed with a failure that may pass
    outages: int = 0  # times the database went away
    unavailable_s: float = 0.0  # wall-clock time the database was away, in all

    def as_dict(self) -> dict[str, object]:
        return {
            "stored": self.stored,
            "duplicates": self.duplicates,
            "rejected": dict(self.rejected),
            "db_retries": self.retries,
            "db_outages": self.outages,
            "db_unavailable_s": round(self.unavailable_s, 3),
        }

    def refuse(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1


def _stderr_line(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


@dataclass
class _Held:
    """A report received and not yet stored, and where its acknowledgement goes (the latest
    address it came from)."""

    report: Report
    addr: Address


def _row(report: Report) -> dict[str, Any]:
    return {
        "sender_id": report.sender_id,
        "session": report.session,
        "seq": report.seq,
        "kind": report.kind,
        "sent_s": report.sent_s,
        "data": dict(report.data),
    }


class _Outage:
    """The database's state as the office says it: one line when it goes away, one when it is
    back; the retries and the time away counted in the stats."""

    def __init__(self, stats: OfficeStats, say: Callable[[str], None], backoff: Backoff) -> None:
        self.stats, self.say, self.backoff = stats, say, backoff
        self.since: float | None = None
        self.failures = 0

    def failed(self, exc: StoreUnavailable, doing: str) -> float:
        """Count one failure; the delay before the next try."""
        self.stats.retries += 1
        self.failures += 1
        if self.since is None:
            self.since = asyncio.get_running_loop().time()
            self.stats.outages += 1
            self.say(f"office: the database is unavailable ({exc}); {doing}")
        return self.backoff.delay_s(self.failures)

    def succeeded(self, done: str) -> None:
        if self.since is not None:
            away_s = asyncio.get_running_loop().time() - self.since
            self.stats.unavailable_s += away_s
            self.say(
                f"office: the database is available again after {away_s:.1f} s "
                f"({self.failures} failed attempt(s)); {done}"
            )
        self.since, self.failures = None, 0

    def end(self) -> None:
        if self.since is not None:
            self.stats.unavailable_s += asyncio.get_running_loop().time() - self.since
            self.since = None


async def _wait(event: asyncio.Event, timeout_s: float) -> None:
    """Wait until ``event`` is set or ``timeout_s`` passed."""
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(event.wait(), timeout_s)


async def _open(db: str, busy_timeout_s: float, outage: _Outage, stop: asyncio.Event) -> Store | None:
    """Open the database (a damaged SQLite file refused, DESIGN rule 10), waiting while it is
    unavailable; None if ``stop`` was set first."""
    while True:
        try:
            store = await asyncio.to_thread(
                open_store, db, check_integrity=True, busy_timeout_s=busy_timeout_s
            )
        except StoreUnavailable as exc:
            delay_s = outage.failed(exc, "waiting for it before listening")
            await _wait(stop, delay_s)
            if stop.is_set():
                outage.end()
                return None
            continue
        outage.succeeded("listening")
        return store


async def serve_office(
    *,
    db: str,
    local: Address,
    master_key: bytes,
    senders: tuple[int, ...],
    clock: EpochClock,
    stop: asyncio.Event,
    on_ready: Callable[[Address], None] | None = None,
    on_report: Callable[[dict[str, Any]], None] | None = None,
    on_store: Callable[[Any], None] | None = None,
    office_id: int = OFFICE_ID,
    times: LinkTimes | None = None,
    backoff: Backoff | None = None,
    busy_timeout_s: float = OFFICE_BUSY_TIMEOUT_S,
    max_held: int = MAX_HELD,
    log: Callable[[str], None] | None = None,
) -> OfficeStats:
    """Receive, store and acknowledge reports until ``stop`` is set; return the counts.

    ``on_report(row)`` is called with each report newly stored (as ``Store.office_reports``
    gives it), e.g. to push it to the control-room page; ``on_store(store)`` once the database
    is open (the page reads its history from it). ``log(line)`` says the database's state
    changes (default: stderr). A damaged database, or a database failure that does not pass,
    raises its ``RailstopError`` (one line): from then on nothing is acknowledged.
    """
    started_s = clock.now_s()  # nothing sent before this office started is taken (a replay)
    say = log or _stderr_line
    stats = OfficeStats()
    outage = _Outage(stats, say, backoff or Backoff())
    store = await _open(db, busy_timeout_s, outage, stop)
    if store is None:
        return stats
    inbox = OfficeInbox(
        own_id=office_id,
        master_key=master_key,
        senders=senders,
        session=new_session(),
        times=times or LinkTimes(),
        started_s=started_s,
    )
    held: dict[tuple[int, int, int], _Held] = {}
    wake = asyncio.Event()  # something is held
    closing = asyncio.Event()

    async def store_held(ep: UdpEndpoint) -> None:
        """Write what is held, then acknowledge it (SPEC §1 claims 7, 20: stored first)."""
        while not closing.is_set():
            if not held:
                wake.clear()
                await wake.wait()
                continue
            batch = [h.report for h in itertools.islice(held.values(), STORE_BATCH)]
            try:
                rows = await asyncio.to_thread(store.save_office_reports, [_row(r) for r in batch])
            except StoreUnavailable as exc:
                # Nothing of the batch was kept: it stays held, unacknowledged, and is tried again.
                delay_s = outage.failed(exc, "holding the reports unacknowledged and retrying")
                await _wait(closing, delay_s)
                continue
            outage.succeeded(f"{len(batch)} held report(s) stored")
            now_s = clock.now_s()
            for report, row in zip(batch, rows, strict=True):
                latest = held.pop((report.sender_id, report.session, report.seq))
                ep.send(inbox.ack(report, now_s), latest.addr)  # committed: acknowledge
                if row is None:
                    stats.duplicates += 1
                    continue
                stats.stored += 1
                if on_report is not None:
                    on_report(row)

    try:
        if on_store is not None:
            on_store(store)
        async with await open_endpoint(local) as ep:
            if on_ready is not None:
                on_ready(ep.local_address)
            storer = asyncio.create_task(store_held(ep))
            try:
                while not stop.is_set() and not storer.done():
                    got = await ep.recv(timeout_s=0.2)
                    if got is None:
                        continue
                    frame, addr = got
                    report, reason = inbox.accept(frame, clock.now_s())
                    if report is None:
                        stats.refuse(reason or "malformed")
                        continue
                    key = (report.sender_id, report.session, report.seq)
                    if key in held:
                        held[key].addr = addr  # sent again while held: answer where it came from
                        continue
                    if len(held) >= max_held:
                        stats.refuse("held_full")  # not acknowledged: its sender sends it again
                        continue
                    try:
                        office_report_values(**_row(report))
                    except RailstopError:
                        stats.refuse("invalid")  # could never be stored: never acknowledged
                        continue
                    held[key] = _Held(report, addr)
                    wake.set()
            finally:
                closing.set()
                wake.set()
                await asyncio.wait({storer})
            storer.result()  # a failure that does not pass (a damaged file): raised, one line
    finally:
        outage.end()
        store.close()
    return stats


class OfficeClient:
    """A wayside unit's link to the office: ``report(kind, data)`` and forget; nothing is lost."""

    def __init__(
        self,
        *,
        own_id: int,
        office: Address,
        master_key: bytes,
        clock: EpochClock,
        office_id: int = OFFICE_ID,
        times: LinkTimes | None = None,
        tick_s: float = 0.05,
    ) -> None:
        self.office = office
        self.clock = clock
        self.tick_s = tick_s
        self.outbox = OfficeOutbox(
            own_id=own_id,
            office_id=office_id,
            master_key=master_key,
            session=new_session(),
            times=times or LinkTimes(),
        )
        self._ep: UdpEndpoint | None = None
        self._task: asyncio.Task[None] | None = None
        self._closing = False

    async def __aenter__(self) -> OfficeClient:
        self._ep = await open_endpoint(local_for(self.office))
        self._task = asyncio.create_task(self._run())
        return self

    async def __aexit__(self, *exc: object) -> None:
        # The loop ends on the flag (and the closed endpoint) as well as on the cancellation: a
        # cancellation that meets a wait_for just completing can be lost, and the task must end.
        self._closing = True
        if self._ep is not None:
            self._ep.close()
        if self._task is not None:
            self._task.cancel()
            await asyncio.wait({self._task}, timeout=2.0)

    def report(self, kind: str, data: Mapping[str, Any]) -> int:
        """Queue one report and send it at once; its sequence number."""
        seq, frame = self.outbox.submit(kind, data, self.clock.now_s())
        if self._ep is not None:
            self._ep.send(frame, self.office)
        return seq

    @property
    def pending(self) -> int:
        return len(self.outbox.pending)

    async def drain(self, timeout_s: float) -> bool:
        """Wait until every report is acknowledged (True) or ``timeout_s`` passed (False)."""
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout_s
        while self.outbox.pending and loop.time() < end:
            await asyncio.sleep(self.tick_s)
        return not self.outbox.pending

    async def _run(self) -> None:
        assert self._ep is not None
        ep = self._ep
        while not self._closing and not ep.closed:
            got = await ep.recv(timeout_s=self.tick_s)
            if self._closing:
                break
            now = self.clock.now_s()
            if got is not None:
                self.outbox.on_frame(got[0], now)
            for frame in self.outbox.due(now):
                ep.send(frame, self.office)
