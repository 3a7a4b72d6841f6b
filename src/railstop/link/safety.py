"""The safety layer of EN 50159 (safety-related communication in transmission systems), pure.

SPEC §5 puts door, PSD and braking telegrams on the wayside loop, the
transponder or short-range radio; SPEC §5 also notes that radio "needs
security". This layer wraps any payload (a codec frame, railstop.link.codec)
in a safety frame that lets the receiver detect the seven threats of
EN 50159. It does no I/O and reads no clock: the sender's and the receiver's
time are arguments (DESIGN rule 2).

Safety frame (big-endian)::

    offset size field
    0      1    version (high nibble, 1) | category (low nibble: 1, 2 or 3)
    1      2    source id (uint16)
    3      2    destination id (uint16)
    5      4    sequence number (uint32; the first frame is 1, +1 per frame)
    9      4    timestamp (uint32, ms of the sender's clock, modulo 2**32)
    13     1    payload length n (0..255)
    14     n    payload
    14+n   4|8  safety code: CRC-32 (categories 1, 2) or HMAC-SHA256 truncated to 8 bytes (category 3)

The safety code covers every byte before it. EN 50159 categories:
1 = closed transmission system (fixed, known users), 2 = open system where
unauthorised access can be excluded, 3 = open system where it cannot (radio).
Categories 1 and 2 use a non-cryptographic safety code, CRC-32 (zlib), which
is independent of the transmission system's own CRC-16 (SPEC §5) as EN 50159
asks; category 3 uses a keyed MAC, HMAC-SHA256 with a per-direction key
(:func:`link_key`), truncated to :data:`MAC_BYTES`.

Threats and defences (EN 50159 §7; the reason the receiver reports):

==============  ==========================================================  ============================
threat          defence                                                     reported as
==============  ==========================================================  ============================
repetition      sequence number: only a number above the last delivered     ``repeated``
                one is delivered; a window remembers delivered numbers
deletion        sequence number (gap counted in ``Delivered.gap``,          gap / ``deletions``,
                ``deletions``) and time-out (:meth:`timed_out`)             ``timed_out()``
insertion       safety code (cat 3: MAC, no valid frame without the key),   ``corrupt`` / ``bad_mac`` /
                source and destination ids, sequence number                 ``wrong_source`` / ...
re-sequencing   sequence number: a frame older than the last delivered      ``out_of_order``
                one is never delivered
corruption      safety code: CRC-32 (cat 1, 2) / HMAC-SHA256 (cat 3)        ``corrupt`` / ``bad_mac``
delay           timestamp: older than ``max_age_s`` (or ahead of the        ``stale``, ``timed_out()``
                receiver's clock) is refused; time-out
masquerade      cat 3: MAC with a key per link and direction; source and    ``bad_mac`` /
                destination ids (cat 1, 2: against unintended               ``wrong_source`` /
                masquerade only: no attacker can reach a closed system)     ``wrong_destination``
==============  ==========================================================  ============================

Order of the receiver's checks (the first failure is the reason reported;
a rejected frame never changes the receiver's state, only its counters):

1. ``malformed`` — not bytes, or shorter than header + safety code;
2. ``corrupt`` (cat 1, 2) / ``bad_mac`` (cat 3) — the safety code, before
   any header field is trusted (MAC compared with ``hmac.compare_digest``);
3. ``malformed`` — version / category not the receiver's, or the length
   byte disagrees with the frame length;
4. ``wrong_source`` — source id is not the peer's;
5. ``wrong_destination`` — destination id is not the receiver's own;
6. ``repeated`` — sequence number equal to the last delivered, or lower
   and delivered before (within the last :data:`SEQ_WINDOW` numbers);
   ``out_of_order`` — lower than the last delivered and not known to be
   delivered (a frame that was overtaken, or one older than the window);
7. ``stale`` — the timestamp is more than ``max_age_s`` before the
   receiver's time, or more than ``future_tolerance_s`` after it.

Sequence before time: a replayed old frame is reported as the replay it is.

A restarted sender begins again at sequence number 1. A frame with a lower
sequence number than the last delivered but a *later* timestamp, fresh and
with a valid safety code, can only come from a new session of the peer
(within a session sequence and timestamp rise together; a replay keeps its
old timestamp): the receiver follows it from there (``restarts`` counts
them) instead of refusing the restarted peer until its numbers pass the old
ones.

Assumptions (documented, not checked): the sender's and the receiver's
clocks are synchronised (GNSS time, SPEC §2) to well within
``future_tolerance_s``; the timestamp is the sender's time in ms modulo
2**32 and the receiver takes the age modulo 2**32 as a signed number, so
wrap-around is harmless as long as the true age is below 2**31 ms (24.8
days; the counter itself repeats every 49.7 days). The sequence number does
not wrap: a sender refuses to send after 2**32 - 1 frames (497 days at one
frame per 10 ms); the link is re-keyed and restarted before that.
"""

from __future__ import annotations

import hashlib
import hmac
import math
import struct
import zlib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

from railstop.errors import RailstopError

__all__ = [
    "CRC_BYTES",
    "HEADER_BYTES",
    "MAC_BYTES",
    "MIN_KEY_BYTES",
    "REASONS",
    "SEQ_WINDOW",
    "VERSION",
    "Delivered",
    "LinkConfigError",
    "Rejected",
    "SafeReceiver",
    "SafeSender",
    "frame_ids",
    "frame_size",
    "hkdf_sha256",
    "link_key",
]

VERSION = 1
HEADER = struct.Struct(">BHHIIB")  # version|category, src, dst, seq, timestamp ms, payload length
HEADER_BYTES = HEADER.size  # 14
CRC_BYTES = 4  # CRC-32, categories 1 and 2
MAC_BYTES = 8  # HMAC-SHA256 truncated to 64 bits, category 3 (EN 50159 leaves the length to the design)
MIN_KEY_BYTES = 16  # 128-bit keys at least
MAX_PAYLOAD_BYTES = 0xFF  # the length byte; SPEC §5 telegrams are ~10 bytes
SEQ_WINDOW = 64  # delivered sequence numbers remembered below the last one (to tell "repeated")
_TS_MOD = 1 << 32
_SEQ_MAX = (1 << 32) - 1

REASONS = (
    "corrupt",
    "malformed",
    "wrong_source",
    "wrong_destination",
    "repeated",
    "out_of_order",
    "stale",
    "bad_mac",
)

_KDF_SALT = b"railstop EN 50159 link key v1"


class LinkConfigError(RailstopError, ValueError):
    """The safety layer was set up or called with an invalid argument (ids, category, key, payload)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Delivered:
    """A frame the receiver accepted; ``gap``: frames skipped since the previous delivery (deletions)."""

    payload: bytes
    seq: int
    sent_s: float
    gap: int


@dataclass(frozen=True, slots=True, kw_only=True)
class Rejected:
    """A frame the receiver refused; ``reason`` is one of :data:`REASONS`."""

    reason: str


def code_bytes(category: int) -> int:
    """Length of the safety code for ``category``."""
    _check_category(category)
    return MAC_BYTES if category == 3 else CRC_BYTES


def frame_size(payload_bytes: int, category: int) -> int:
    """Bytes on the medium for a payload of ``payload_bytes`` in a safety frame of ``category``."""
    return HEADER_BYTES + payload_bytes + code_bytes(category)


def link_key(master: bytes, src_id: int, dst_id: int) -> bytes:
    """The 32-byte key of the direction src -> dst, derived from a master key (HKDF-SHA256, RFC 5869).

    Each direction of each link gets its own key, so a frame can be neither
    reflected back to its sender nor replayed on another link.
    """
    if not isinstance(master, bytes | bytearray) or len(master) < MIN_KEY_BYTES:
        raise LinkConfigError(f"master: a key of at least {MIN_KEY_BYTES} bytes is needed")
    _check_id("src_id", src_id)
    _check_id("dst_id", dst_id)
    return hkdf_sha256(
        bytes(master), salt=_KDF_SALT, info=b"railstop link" + struct.pack(">HH", src_id, dst_id)
    )


def hkdf_sha256(ikm: bytes, *, salt: bytes, info: bytes, length: int = 32) -> bytes:
    """HKDF (RFC 5869) with HMAC-SHA256: extract a pseudo-random key, expand it to ``length`` bytes."""
    if not 0 < length <= 255 * 32:
        raise LinkConfigError(f"length: 1..{255 * 32} bytes (got {length})")
    prk = hmac.new(salt or bytes(32), ikm, hashlib.sha256).digest()
    okm, block = b"", b""
    for i in range(1, -(-length // 32) + 1):
        block = hmac.new(prk, block + info + bytes((i,)), hashlib.sha256).digest()
        okm += block
    return okm[:length]


def _check_id(name: str, value: object) -> None:
    if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= 0xFFFF:
        raise LinkConfigError(f"{name}: a uint16 id is needed (got {value!r})")


def _check_category(category: object) -> None:
    if category not in (1, 2, 3) or isinstance(category, bool):
        raise LinkConfigError(f"category: EN 50159 category 1, 2 or 3 (got {category!r})")


def _check_key(category: int, key: bytes | None) -> bytes | None:
    if category == 3:
        if not isinstance(key, bytes | bytearray) or len(key) < MIN_KEY_BYTES:
            raise LinkConfigError(f"key: category 3 needs a key of at least {MIN_KEY_BYTES} bytes")
        return bytes(key)
    if key is not None:
        raise LinkConfigError(f"key: category {category} uses a CRC-32, not a key (got a key)")
    return None


def _check_time(name: str, value: float) -> float:
    try:
        t = float(value)
    except (TypeError, ValueError):
        raise LinkConfigError(f"{name}: a time in seconds is needed (got {value!r})") from None
    if not math.isfinite(t):
        raise LinkConfigError(f"{name}: must be finite (got {value!r})")
    return t


def _safety_code(category: int, key: bytes | None, data: bytes) -> bytes:
    if category == 3:
        return hmac.new(key or b"", data, hashlib.sha256).digest()[:MAC_BYTES]
    return zlib.crc32(data).to_bytes(CRC_BYTES, "big")


def frame_ids(frame: bytes) -> tuple[int, int] | None:
    """(source id, destination id) as a frame's header states them, None if it is too short to
    hold them. Not checked: only to pick the receiver that will check the frame (its safety code
    first, then these very ids)."""
    if len(frame) < 5:
        return None
    _, src, dst = struct.unpack_from(">BHH", frame)
    return int(src), int(dst)


class SafeSender:
    """One direction of a link, sending side: ``wrap(payload, now_s)`` gives the safety frame."""

    def __init__(self, src_id: int, dst_id: int, *, key: bytes | None = None, category: int) -> None:
        _check_id("src_id", src_id)
        _check_id("dst_id", dst_id)
        if src_id == dst_id:
            raise LinkConfigError(f"dst_id: must differ from src_id (both {src_id}): reflection")
        _check_category(category)
        self.src_id = src_id
        self.dst_id = dst_id
        self.category = category
        self._key = _check_key(category, key)
        self.next_seq = 1

    def wrap(self, payload: bytes, now_s: float) -> bytes:
        """The safety frame of ``payload`` sent at sender time ``now_s``; the sequence number advances."""
        if not isinstance(payload, bytes | bytearray | memoryview):
            raise LinkConfigError(f"payload: bytes are needed (got {type(payload).__name__})")
        data = bytes(payload)
        if len(data) > MAX_PAYLOAD_BYTES:
            raise LinkConfigError(f"payload: at most {MAX_PAYLOAD_BYTES} bytes (got {len(data)})")
        t = _check_time("now_s", now_s)
        if self.next_seq > _SEQ_MAX:
            raise LinkConfigError("sequence numbers exhausted: re-key and restart the link")
        ts_ms = round(t * 1000.0) % _TS_MOD
        head = HEADER.pack(
            VERSION << 4 | self.category, self.src_id, self.dst_id, self.next_seq, ts_ms, len(data)
        )
        self.next_seq += 1
        body = head + data
        return body + _safety_code(self.category, self._key, body)


class SafeReceiver:
    """One direction of a link, receiving side: ``accept(frame, now_s)`` -> Delivered | Rejected.

    ``counts`` holds one counter per reason of :data:`REASONS` plus
    ``delivered``; every call to :meth:`accept` adds one to exactly one of
    them. ``deletions`` is the sum of the gaps of the delivered frames.
    """

    def __init__(
        self,
        own_id: int,
        peer_id: int,
        *,
        key: bytes | None = None,
        category: int,
        max_age_s: float,
        timeout_s: float,
        start_s: float = 0.0,
        future_tolerance_s: float = 0.05,
    ) -> None:
        _check_id("own_id", own_id)
        _check_id("peer_id", peer_id)
        if own_id == peer_id:
            raise LinkConfigError(f"peer_id: must differ from own_id (both {own_id}): reflection")
        _check_category(category)
        for name, value in (
            ("max_age_s", max_age_s),
            ("timeout_s", timeout_s),
            ("future_tolerance_s", future_tolerance_s),
        ):
            if _check_time(name, value) < 0.0:
                raise LinkConfigError(f"{name}: must be >= 0 (got {value!r})")
        self.own_id = own_id
        self.peer_id = peer_id
        self.category = category
        self._key = _check_key(category, key)
        self._code_len = code_bytes(category)
        self.max_age_s = float(max_age_s)
        self.timeout_s = float(timeout_s)
        self.future_tolerance_s = float(future_tolerance_s)
        self._max_age_ms = self.max_age_s * 1000.0
        self._future_ms = self.future_tolerance_s * 1000.0
        self.last_seq = 0  # the sender's first frame is 1
        self._seen = 0  # bit k set: last_seq - k was delivered (k < SEQ_WINDOW)
        self.last_valid_s = _check_time("start_s", start_s)
        self.deletions = 0
        self.restarts = 0  # new sessions of the peer followed (a restarted sender)
        self._last_sent_ms = -math.inf  # the sending time of the last frame delivered
        self.counts: dict[str, int] = dict.fromkeys((*REASONS, "delivered"), 0)

    def _reject(self, reason: str) -> Rejected:
        self.counts[reason] += 1
        return Rejected(reason=reason)

    def accept(self, frame: bytes, now_s: float) -> Delivered | Rejected:
        """Check ``frame`` received at receiver time ``now_s`` (order: see the module docstring)."""
        now = _check_time("now_s", now_s)
        if isinstance(frame, memoryview):
            try:
                frame = frame.tobytes()
            except (ValueError, TypeError):
                return self._reject("malformed")
        elif isinstance(frame, bytes | bytearray):
            frame = bytes(frame)
        else:
            return self._reject("malformed")
        n = len(frame)
        if n < HEADER_BYTES + self._code_len:
            return self._reject("malformed")
        body, code = frame[: n - self._code_len], frame[n - self._code_len :]
        if not hmac.compare_digest(code, _safety_code(self.category, self._key, body)):
            return self._reject("bad_mac" if self.category == 3 else "corrupt")
        vc, src, dst, seq, ts_ms, length = HEADER.unpack_from(body)
        if vc != (VERSION << 4 | self.category) or length != len(body) - HEADER_BYTES:
            return self._reject("malformed")
        if src != self.peer_id:
            return self._reject("wrong_source")
        if dst != self.own_id:
            return self._reject("wrong_destination")
        now_ms = round(now * 1000.0)
        age_ms = (now_ms - ts_ms + (1 << 31)) % _TS_MOD - (1 << 31)  # signed, wrap-safe
        fresh = not (age_ms > self._max_age_ms or -age_ms > self._future_ms)
        if seq <= self.last_seq:
            if fresh and now_ms - age_ms > self._last_sent_ms:
                # The peer restarted: within one session sequence and timestamp rise together, so
                # a lower sequence number with a later timestamp is a new session (a replay keeps
                # its old timestamp: refused below as repeated, or as stale). Followed from here.
                self.restarts += 1
                self.last_seq, self._seen = seq - 1, 0
            else:
                back = self.last_seq - seq
                seen = back < SEQ_WINDOW and self._seen >> back & 1
                return self._reject("repeated" if seen else "out_of_order")
        if not fresh:
            return self._reject("stale")
        gap = seq - self.last_seq - 1
        shift = seq - self.last_seq
        self._seen = ((self._seen << shift) | 1) & ((1 << SEQ_WINDOW) - 1) if shift < SEQ_WINDOW else 1
        self.last_seq = seq
        self.deletions += gap
        self.last_valid_s = now
        self._last_sent_ms = now_ms - age_ms
        self.counts["delivered"] += 1
        return Delivered(payload=body[HEADER_BYTES:], seq=seq, sent_s=(now_ms - age_ms) / 1000.0, gap=gap)

    def timed_out(self, now_s: float) -> bool:
        """No frame delivered for longer than ``timeout_s`` (counting from ``start_s`` before the first).

        In whole milliseconds, like the frames' timestamps and the age check: in
        seconds, 1.951 - 0.951 > 1.0 in floating point, and a link exactly at its
        time-out would count as timed out.
        """
        elapsed_ms = round(_check_time("now_s", now_s) * 1000.0) - round(self.last_valid_s * 1000.0)
        return elapsed_ms > round(self.timeout_s * 1000.0)


def sum_counts(
    counts: Iterable[Mapping[str, int]], *, into: dict[str, int] | None = None, prefix: str = ""
) -> dict[str, int]:
    """Counts by reason (refusals, outcomes) summed over ``counts``, added to ``into`` (a new dict by
    default), each key with ``prefix``."""
    out = {} if into is None else into
    for c in counts:
        for reason, n in c.items():
            key = prefix + reason
            out[key] = out.get(key, 0) + n
    return out


class SafePeers:
    """Category-3 links of one party with any number of peers over a shared transport (one socket):
    ``wrap(payload, peer, now_s)`` gives the frame for ``peer`` (its own sequence and key per
    direction), ``accept(frame, now_s)`` checks a received frame with the receiver of the peer it
    names and gives (peer, payload), or the reason it was refused (counted in ``rejected``).
    ``peers(id)`` says which senders may be heard (any other is refused as ``unknown_peer``)."""

    def __init__(
        self, own_id: int, master_key: bytes, *, max_age_s: float, peers: Callable[[int], bool]
    ) -> None:
        self.own_id = own_id
        self.master_key = master_key
        self.max_age_s = max_age_s
        self.known = peers
        self._tx: dict[int, SafeSender] = {}
        self._rx: dict[int, SafeReceiver] = {}
        self.sent = 0
        self.delivered = 0
        self.rejected: dict[str, int] = {}

    def reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1

    def wrap(self, payload: bytes, peer: int, now_s: float) -> bytes:
        if peer not in self._tx:
            key = link_key(self.master_key, self.own_id, peer)
            self._tx[peer] = SafeSender(self.own_id, peer, key=key, category=3)
        self.sent += 1
        return self._tx[peer].wrap(payload, now_s)

    def accept(self, frame: bytes, now_s: float) -> tuple[int, Delivered] | None:
        ids = frame_ids(frame)
        peer = -1 if ids is None else ids[0]
        if not self.known(peer):
            self.reject("unknown_peer")
            return None
        if peer not in self._rx:
            self._rx[peer] = SafeReceiver(
                self.own_id,
                peer,
                key=link_key(self.master_key, peer, self.own_id),
                category=3,
                max_age_s=self.max_age_s,
                timeout_s=1e9,  # the units above supervise their peers' silence
                start_s=now_s,
                future_tolerance_s=0.2,
            )
        got = self._rx[peer].accept(frame, now_s)
        if not isinstance(got, Delivered):
            self.reject(got.reason)
            return None
        self.delivered += 1
        return peer, got
