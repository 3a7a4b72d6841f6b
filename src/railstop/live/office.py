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

These are drivers (DESIGN: ``live/``): they own the sockets and the clock; the
link ends they drive are pure.
"""

from __future__ import annotations

import asyncio
import secrets
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from railstop.link.office_link import LinkTimes, OfficeInbox, OfficeOutbox
from railstop.link.udp import Address, EpochClock, UdpEndpoint, local_for, open_endpoint
from railstop.store import open_store

OFFICE_ID = 900  # the office's id on the safety layer


def new_session() -> int:
    """A sender's or the office's session number: random, drawn once per process start."""
    return secrets.randbits(62) + 1


@dataclass
class OfficeStats:
    stored: int = 0
    duplicates: int = 0
    rejected: dict[str, int] = field(default_factory=dict)


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
) -> OfficeStats:
    """Receive, store and acknowledge reports until ``stop`` is set; return the counts.

    ``on_report(row)`` is called with each report newly stored (as ``Store.office_reports``
    gives it), e.g. to push it to the control-room page; ``on_store(store)`` once the database
    is open (the page reads its history from it).
    """
    inbox = OfficeInbox(
        own_id=office_id,
        master_key=master_key,
        senders=senders,
        session=new_session(),
        times=times or LinkTimes(),
    )
    stats = OfficeStats()
    with open_store(db) as store:
        if on_store is not None:
            on_store(store)
        async with await open_endpoint(local) as ep:
            if on_ready is not None:
                on_ready(ep.local_address)
            while not stop.is_set():
                got = await ep.recv(timeout_s=0.2)
                if got is None:
                    continue
                frame, addr = got
                report, ack, reason = inbox.on_frame(frame, clock.now_s())
                if report is None or ack is None:
                    if reason is not None:
                        stats.rejected[reason] = stats.rejected.get(reason, 0) + 1
                    continue
                # Stored first, acknowledged after: an acknowledged report is never lost.
                new = await asyncio.to_thread(
                    store.save_office_report,
                    sender_id=report.sender_id,
                    session=report.session,
                    seq=report.seq,
                    kind=report.kind,
                    sent_s=report.sent_s,
                    data=dict(report.data),
                )
                if new is not None:
                    stats.stored += 1
                else:
                    stats.duplicates += 1
                ep.send(ack, addr)
                if new is not None and on_report is not None:
                    on_report(new)
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
