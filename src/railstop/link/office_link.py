"""The link from the wayside to the management office (SPEC §1 claims 7, 20), pure.

SPEC §1: the wayside sends what it computed (each TASC command with its inputs,
each stop's result) to the management office "over a dedicated line or the
internet". Over the internet the link is an open transmission system: EN 50159
category 3, every frame wrapped by the safety layer (``link.safety``: sequence
number, timestamp, HMAC with a key per direction) in both directions.

Nothing may be lost when the office is down or restarts:

* the sender (:class:`OfficeOutbox`) numbers its reports (``seq`` within its
  *session*, a random number drawn when the process starts) and keeps each
  one until the office acknowledges it, sending it again every
  ``resend_s`` (each send is a new safety frame: a new safety sequence number
  and timestamp, so a resend is not a replay);
* the office (:class:`OfficeInbox`) acknowledges every report it accepts,
  including one it already has (its acknowledgement may have been lost); the
  store keeps a report once per (sender, session, seq) whatever arrives twice.

A restarted peer starts its safety sequence numbers at 1 again. The receiving
side then rejects its frames as ``repeated`` / ``out_of_order``; a frame that
a fresh receiver accepts (valid MAC, fresh timestamp) and that names another
session than the current one starts a new receiver for that session. A replay
of an old session's frame cannot do this: its timestamp is older than
``max_age_s`` ([interpretation]: the EN 50159 time-stamp defence carries over
to restarts; the peers' clocks are synchronised, as the safety layer assumes).

Report payload: compact JSON ``{"e": session, "q": seq, "k": kind, "t": sent_s,
"d": {...}}``; acknowledgement ``{"e": office session, "s": sender session,
"q": seq}``; both deflated (raw DEFLATE). The safety layer carries at most 255
payload bytes: a report that does not fit deflated is refused when it is
submitted (:class:`OfficeLinkError`), never cut; a payload that does not
inflate to JSON (or inflates beyond 4 KiB) is refused as ``malformed``. No clock
is read and no socket opened here (DESIGN rule 2): times are arguments, the
drivers (``railstop.live.office``) do the I/O.
"""

from __future__ import annotations

import json
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from railstop.errors import RailstopError
from railstop.link.safety import (
    MAX_PAYLOAD_BYTES,
    Delivered,
    Rejected,
    SafeReceiver,
    SafeSender,
    frame_ids,
    link_key,
)

#: What the wayside reports (SPEC §1 claims 7, 20; SPEC §4, §5 events for the control room).
KINDS = (
    "tasc-command",
    "stop-result",
    "campaign-result",  # a campaign's summary (the simulators, SPEC §1 claim 7)
    "dwell-event",
    "dwell-result",
    "zone-event",
    "operator-action",
    "train-state",
)
CATEGORY = 3  # the internet: an open transmission system (EN 50159)


class OfficeLinkError(RailstopError):
    """A report the link cannot carry (unknown kind, too large, not JSON)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Report:
    """One report as the office receives it."""

    sender_id: int
    session: int
    seq: int
    kind: str
    sent_s: float
    data: Mapping[str, Any]


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkTimes:
    resend_s: float = 1.0  # a report not acknowledged is sent again after this
    max_age_s: float = 5.0  # safety layer: a frame older than this is refused (stale)
    future_tolerance_s: float = 0.5
    #: At most this many reports are sent again at once (the oldest first): a sender that has
    #: gathered thousands while the office was down does not burst them all every resend_s.
    resend_window: int = 64


#: A payload inflates to at most this many bytes (a frame that would inflate further is refused).
MAX_INFLATED_BYTES = 4096


def _is_count(v: Any, low: int) -> bool:
    """An integer (not a bool) from ``low`` to 2**63 - 1: a session or sequence number."""
    return isinstance(v, int) and not isinstance(v, bool) and low <= v < 2**63


def _dumps(obj: Mapping[str, Any]) -> bytes:
    """Compact JSON, deflated (raw DEFLATE, RFC 1951): a report with a TASC command's inputs is about
    280 bytes of JSON, 190 deflated, and the safety layer carries at most 255."""
    text = json.dumps(obj, separators=(",", ":"), sort_keys=True, allow_nan=False).encode()
    packer = zlib.compressobj(9, zlib.DEFLATED, -15)
    return packer.compress(text) + packer.flush()


def _loads(payload: bytes) -> dict[str, Any] | None:
    try:
        inflater = zlib.decompressobj(-15)
        text = inflater.decompress(payload, MAX_INFLATED_BYTES)
        if inflater.unconsumed_tail or not inflater.eof:
            return None  # too large, or cut short
        obj = json.loads(text.decode())
    except (zlib.error, UnicodeDecodeError, ValueError):
        return None
    return obj if isinstance(obj, dict) else None


class _SessionReceiver:
    """A safety-layer receiver that follows the peer across restarts (see the module docstring)."""

    def __init__(
        self, own_id: int, peer_id: int, *, key: bytes, times: LinkTimes, not_before_s: float | None = None
    ) -> None:
        """``not_before_s``: when this end (its process) started; nothing sent before it is
        delivered, whatever session it belongs to (EN 50159 repetition across a restart of this
        end: its previous incarnation may have delivered it, ``railstop.link.safety``)."""
        self.own_id, self.peer_id, self.key, self.times = own_id, peer_id, key, times
        self.not_before_s = not_before_s
        self.session: int | None = None
        self.receiver = self._fresh(0.0)
        self.restarts = 0

    def _fresh(self, now_s: float, not_before_s: float | None = None) -> SafeReceiver:
        floors = [f for f in (not_before_s, self.not_before_s) if f is not None]
        return SafeReceiver(
            self.own_id,
            self.peer_id,
            key=self.key,
            category=CATEGORY,
            max_age_s=self.times.max_age_s,
            timeout_s=3600.0,  # the office link is watched by the outbox's resends, not a time-out
            start_s=now_s,
            future_tolerance_s=self.times.future_tolerance_s,
            not_before_s=max(floors) if floors else None,
        )

    def accept(self, frame: bytes, now_s: float) -> tuple[dict[str, Any] | None, str | None]:
        """(the payload object, None) or (None, the reason it was refused)."""
        got = self.receiver.accept(frame, now_s)
        if isinstance(got, Rejected) and got.reason in ("repeated", "out_of_order"):
            # Only a frame sent after the last one delivered can open a new session: a fresh
            # frame of an older session (sent before it) is not followed back (EN 50159
            # repetition across restarts, railstop.link.safety).
            fresh = self._fresh(now_s, not_before_s=self.receiver.last_sent_s)
            again = fresh.accept(frame, now_s)
            if isinstance(again, Delivered):
                obj = _loads(again.payload)
                if obj is not None and obj.get("e") != self.session:
                    # The peer restarted: a valid, fresh frame of a new session.
                    self.receiver, got = fresh, again
                    self.restarts += 1
        if isinstance(got, Rejected):
            return None, got.reason
        obj = _loads(got.payload)
        if obj is None or not isinstance(obj.get("e"), int):
            return None, "malformed"
        self.session = obj["e"]
        return obj, None


@dataclass
class OfficeOutbox:
    """The sending end at a wayside unit: reports kept until acknowledged, sent again until then."""

    own_id: int
    office_id: int
    master_key: bytes
    session: int
    times: LinkTimes = field(default_factory=LinkTimes)
    next_seq: int = 1
    pending: dict[int, tuple[bytes, float]] = field(default_factory=dict)  # seq -> (payload, last sent)
    counts: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._sender = SafeSender(
            self.own_id,
            self.office_id,
            key=link_key(self.master_key, self.own_id, self.office_id),
            category=3,
        )
        self._acks = _SessionReceiver(
            self.own_id,
            self.office_id,
            key=link_key(self.master_key, self.office_id, self.own_id),
            times=self.times,
        )
        self.counts = {"submitted": 0, "sent": 0, "resent": 0, "acknowledged": 0, "ack_rejected": 0}

    def submit(self, kind: str, data: Mapping[str, Any], now_s: float) -> tuple[int, bytes]:
        """Queue a report; return its sequence number and its first frame (to send now)."""
        if kind not in KINDS:
            raise OfficeLinkError(f"office report kind: one of {', '.join(KINDS)} (got {kind!r})")
        seq = self.next_seq
        try:
            payload = _dumps({"e": self.session, "q": seq, "k": kind, "t": round(now_s, 3), "d": dict(data)})
        except (TypeError, ValueError) as exc:
            raise OfficeLinkError(f"office report {kind}: the data is not plain JSON ({exc})") from None
        if len(payload) > MAX_PAYLOAD_BYTES:
            raise OfficeLinkError(
                f"office report {kind}: {len(payload)} bytes, the link carries at most {MAX_PAYLOAD_BYTES}"
            )
        self.next_seq += 1
        self.pending[seq] = (payload, now_s)
        self.counts["submitted"] += 1
        self.counts["sent"] += 1
        return seq, self._sender.wrap(payload, now_s)

    def due(self, now_s: float) -> list[bytes]:
        """The frames of the reports to send again now: the oldest due, at most ``resend_window``."""
        out: list[bytes] = []
        for seq, (payload, last) in self.pending.items():  # inserted in sequence order
            if len(out) >= self.times.resend_window:
                break
            if now_s - last >= self.times.resend_s:
                self.pending[seq] = (payload, now_s)
                out.append(self._sender.wrap(payload, now_s))
                self.counts["resent"] += 1
        return out

    def on_frame(self, frame: bytes, now_s: float) -> int | None:
        """An acknowledgement from the office: the report it names is done (its seq), or None."""
        obj, _ = self._acks.accept(frame, now_s)
        if obj is None or obj.get("s") != self.session or not isinstance(obj.get("q"), int):
            self.counts["ack_rejected"] += 1
            return None
        seq = int(obj["q"])
        if self.pending.pop(seq, None) is not None:
            self.counts["acknowledged"] += 1
        return seq


@dataclass
class OfficeInbox:
    """The receiving end at the office: one session-following receiver per known sender."""

    own_id: int
    master_key: bytes
    senders: tuple[int, ...]
    session: int
    times: LinkTimes = field(default_factory=LinkTimes)
    counts: dict[str, int] = field(default_factory=dict)
    #: When the office (its process) started, on the link's clock: reports sent before it are
    #: refused (``old_session``), so a restarted office never takes a replay of what its previous
    #: incarnation took. None: no such floor (an office that never restarts, as in the tests).
    started_s: float | None = None

    def __post_init__(self) -> None:
        self._rx = {
            s: _SessionReceiver(
                self.own_id,
                s,
                key=link_key(self.master_key, s, self.own_id),
                times=self.times,
                not_before_s=self.started_s,
            )
            for s in self.senders
        }
        self._tx = {
            s: SafeSender(self.own_id, s, key=link_key(self.master_key, self.own_id, s), category=3)
            for s in self.senders
        }
        self.counts = {"accepted": 0, "unknown_sender": 0}

    def on_frame(self, frame: bytes, now_s: float) -> tuple[Report | None, bytes | None, str | None]:
        """(the report, the acknowledgement frame to send back, None) or (None, None, the reason).

        ``accept`` then ``ack`` at once: for a receiver that keeps the report before it answers
        (the office: stored first, acknowledged after), call the two apart.
        """
        report, reason = self.accept(frame, now_s)
        if report is None:
            return None, None, reason
        return report, self.ack(report, now_s), None

    def accept(self, frame: bytes, now_s: float) -> tuple[Report | None, str | None]:
        """(the report, None) or (None, the reason it was refused); nothing is acknowledged yet."""
        ids = frame_ids(frame)
        src = -1 if ids is None else ids[0]
        rx = self._rx.get(src)
        if rx is None:
            self.counts["unknown_sender"] += 1
            return None, "unknown_sender"
        obj, reason = rx.accept(frame, now_s)
        if obj is None:
            self._count(reason or "malformed")
            return None, reason
        kind, sent, data = obj.get("k"), obj.get("t"), obj.get("d")
        session: Any = obj.get("e")
        seq: Any = obj.get("q")
        # The numbering must fit the database's 64-bit columns (and a bool is not a number): a
        # report that could never be stored is refused here, never queued for storing.
        if (
            kind not in KINDS
            or not _is_count(session, 0)
            or not _is_count(seq, 1)
            or isinstance(sent, bool)
            or not isinstance(sent, int | float)
            or not isinstance(data, dict)
        ):
            self._count("malformed")
            return None, "malformed"
        self.counts["accepted"] += 1
        report = Report(sender_id=src, session=session, seq=seq, kind=kind, sent_s=float(sent), data=data)
        return report, None

    def ack(self, report: Report, now_s: float) -> bytes:
        """The acknowledgement of ``report`` as a new safety frame stamped ``now_s``: made when it
        is sent, so that acknowledgements held back (while the report was being stored) still go
        out in sequence and fresh."""
        return self._tx[report.sender_id].wrap(
            _dumps({"e": self.session, "s": report.session, "q": report.seq}), now_s
        )

    def _count(self, reason: str) -> None:
        self.counts[reason] = self.counts.get(reason, 0) + 1
