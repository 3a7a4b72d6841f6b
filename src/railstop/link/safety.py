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
repetition      sequence number: only a number above the last delivered     ``repeated``,
                one is delivered; a window remembers delivered numbers;     ``old_session``
                across a restart of either end: the timestamp (below)
deletion        sequence number (gap counted in ``Delivered.gap``,          gap / ``deletions``,
                ``deletions``) and time-out (:meth:`timed_out`)             ``timed_out()``
insertion       safety code (cat 3: MAC, no valid frame without the key),   ``corrupt`` / ``bad_mac`` /
                source and destination ids, sequence number                 ``wrong_source`` / ...
re-sequencing   sequence number: a frame older than the last delivered      ``out_of_order``,
                one is never delivered; timestamp: nor one sent before      ``old_session``
                the last delivered one was sent
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
3. ``malformed`` — version / category not the receiver's, the length byte
   disagrees with the frame length, or sequence number 0 (none is sent);
4. ``wrong_source`` — source id is not the peer's;
5. ``wrong_destination`` — destination id is not the receiver's own;
6. ``repeated`` — sequence number equal to the last delivered, or lower
   and delivered before (within the last :data:`SEQ_WINDOW` numbers);
   ``out_of_order`` — lower than the last delivered and not known to be
   delivered (a frame that was overtaken, or one older than the window);
7. ``stale`` — the timestamp is more than ``max_age_s`` before the
   receiver's time, or more than ``future_tolerance_s`` after it;
8. ``old_session`` — sent (timestamp) before the last delivered frame was
   sent, or before the receiver started (``not_before_s``).

Sequence before time: a replayed old frame is reported as the replay it is.

Restarts of either end (EN 50159 repetition and re-sequencing across
sessions). **A receiver never delivers again a frame it delivered before a
restart of either end.** The rule that makes it so is the timestamp: within
a session the sender's timestamps never decrease (its clock is monotonic),
so the timestamps of the delivered frames must never decrease either; a
frame sent before the last delivered one was sent is refused as
``old_session`` whatever its sequence number.

* A restarted sender begins again at sequence number 1. A frame with a lower
  sequence number than the last delivered but a *later* timestamp, fresh and
  with a valid safety code, can only come from a new session of the peer (a
  replay keeps its old timestamp): the receiver follows it from there
  (``restarts`` counts them) instead of refusing the restarted peer until its
  numbers pass the old ones. Frames of the old session that arrive afterwards,
  whatever their numbers, were sent before the new session's and are refused
  (``old_session``; or ``stale`` once older than ``max_age_s``).
* A restarted receiver (a new process, a new :class:`SafeReceiver`) knows
  nothing of what its previous incarnation delivered. It is given the time it
  started as ``not_before_s`` (an argument: units read no clock) and refuses
  every frame sent before it (``old_session``): whatever the previous
  incarnation delivered was sent before the new one started. The cost is the
  frames in flight at the start, refused once. Without ``not_before_s`` (the
  simulations, whose receivers never restart) there is no such floor;
  :class:`SafePeers`, used by the live processes, takes ``started_s``.

Assumptions (documented, not checked): the sender's and the receiver's
clocks are synchronised (GNSS time, SPEC §2) to well within
``future_tolerance_s``; a restart takes longer than 1 ms (the timestamp's
resolution); the timestamp is the sender's time in ms modulo
2**32 and the receiver takes the age modulo 2**32 as a signed number, so
wrap-around is harmless as long as the true age is below 2**31 ms (24.8
days; the counter itself repeats every 49.7 days). The sequence number does
not wrap: a sender refuses to send after 2**32 - 1 frames (497 days at one
frame per 10 ms); the link is re-keyed and restarted before that.

Keys: category 3 keys come from a master key shared by the parties
(:func:`link_key`). The simulations use built-in demonstration master keys
(:func:`demo_master_key`, public by construction); :class:`SafePeers`, the
live processes' links, refuses them and any key shorter than
:data:`MIN_KEY_BYTES` (:func:`check_master_key`).
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
    "DEMO_KEY_PURPOSES",
    "HEADER_BYTES",
    "MAC_BYTES",
    "MAX_PEERS",
    "MIN_KEY_BYTES",
    "PEER_REASONS",
    "REASONS",
    "SEQ_WINDOW",
    "VERSION",
    "Delivered",
    "LinkConfigError",
    "Rejected",
    "SafePeers",
    "SafeReceiver",
    "SafeSender",
    "check_master_key",
    "demo_master_key",
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
    "old_session",
)

_KDF_SALT = b"railstop EN 50159 link key v1"

#: The simulated links with a built-in demonstration master key (:func:`demo_master_key`).
DEMO_KEY_PURPOSES = ("CBTC radio", "door link", "zone release", "TASC link")

#: Receivers one :class:`SafePeers` holds at most (one per peer heard with a valid MAC) unless
#: told otherwise: more than the live line's parties (60 trains at most, a station's plant and
#: trains) and a bound on the state frames can make a process keep.
MAX_PEERS = 256


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


def demo_master_key(purpose: str) -> bytes:
    """The built-in master key of a simulated link (one of :data:`DEMO_KEY_PURPOSES`).

    Public by construction (its derivation is in the source): for simulations only, where no
    attacker exists. :func:`check_master_key` refuses it, so no live link runs on it.
    """
    if purpose not in DEMO_KEY_PURPOSES:
        raise LinkConfigError(f"purpose: one of {', '.join(DEMO_KEY_PURPOSES)} (got {purpose!r})")
    return hashlib.sha256(f"railstop demonstration {purpose} master key".encode()).digest()


_DEMO_KEYS = frozenset(demo_master_key(p) for p in DEMO_KEY_PURPOSES)


def check_master_key(master: object) -> bytes:
    """``master`` as the master key of a live link: bytes, at least :data:`MIN_KEY_BYTES` long and
    not a built-in demonstration key; :class:`LinkConfigError` (one line) otherwise.

    EN 50159 category 3 (masquerade): a key anyone can read in the source authenticates nobody.
    """
    if not isinstance(master, bytes | bytearray) or len(master) < MIN_KEY_BYTES:
        raise LinkConfigError(
            f"master key: at least {MIN_KEY_BYTES} bytes are needed (a key file, the environment, or "
            "one generated for the run)"
        )
    if bytes(master) in _DEMO_KEYS:
        raise LinkConfigError(
            "master key: a built-in demonstration key is public and refused on a live link; "
            "give the run its own key"
        )
    return bytes(master)


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
        if type(payload) is bytes:
            data = payload  # (a bytes object is taken as it is)
        elif isinstance(payload, bytes | bytearray | memoryview):
            data = bytes(payload)
        else:
            raise LinkConfigError(f"payload: bytes are needed (got {type(payload).__name__})")
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
        not_before_s: float | None = None,
    ) -> None:
        """``not_before_s``: when this receiver (its process) started; frames sent before it are
        refused as ``old_session`` (a previous incarnation may have delivered them). None: no
        such floor (a receiver that is never restarted, as in the simulations)."""
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
        # The sending time of the last frame delivered; before the first, the receiver's start
        # (module docstring, restarts: nothing sent earlier is delivered).
        self.not_before_s = None if not_before_s is None else _check_time("not_before_s", not_before_s)
        self._last_sent_ms = -math.inf if not_before_s is None else float(round(not_before_s * 1000.0))
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
        return self._check(frame, now)

    def _check(self, frame: bytes, now: float) -> Delivered | Rejected:
        """:meth:`accept` of a frame already made bytes, at a time already checked."""
        n = len(frame)
        if n < HEADER_BYTES + self._code_len:
            return self._reject("malformed")
        body, code = frame[: n - self._code_len], frame[n - self._code_len :]
        if not hmac.compare_digest(code, _safety_code(self.category, self._key, body)):
            return self._reject("bad_mac" if self.category == 3 else "corrupt")
        vc, src, dst, seq, ts_ms, length = HEADER.unpack_from(body)
        if vc != (VERSION << 4 | self.category) or length != len(body) - HEADER_BYTES or seq == 0:
            return self._reject("malformed")
        if src != self.peer_id:
            return self._reject("wrong_source")
        if dst != self.own_id:
            return self._reject("wrong_destination")
        now_ms = round(now * 1000.0)
        age_ms = (now_ms - ts_ms + (1 << 31)) % _TS_MOD - (1 << 31)  # signed, wrap-safe
        sent_ms = now_ms - age_ms  # the sending time on the receiver's time line
        fresh = not (age_ms > self._max_age_ms or -age_ms > self._future_ms)
        restart = False
        if seq <= self.last_seq:
            # The peer restarted: within one session sequence and timestamp rise together, so a
            # lower sequence number with a later timestamp is a new session (a replay keeps its
            # old timestamp: refused here as repeated, or below as stale / old session).
            restart = fresh and sent_ms > self._last_sent_ms
            if not restart:
                back = self.last_seq - seq
                seen = back < SEQ_WINDOW and self._seen >> back & 1
                return self._reject("repeated" if seen else "out_of_order")
        if not fresh:
            return self._reject("stale")
        if sent_ms < self._last_sent_ms:
            # Sent before the last delivered frame (or before this receiver started): a frame of an
            # earlier session of either end, whatever its sequence number (module docstring).
            return self._reject("old_session")
        if restart:
            self.restarts += 1  # followed from here: the state changes only for a delivery
            self.last_seq, self._seen = seq - 1, 0
        gap = seq - self.last_seq - 1
        shift = seq - self.last_seq
        self._seen = ((self._seen << shift) | 1) & ((1 << SEQ_WINDOW) - 1) if shift < SEQ_WINDOW else 1
        self.last_seq = seq
        self.deletions += gap
        self.last_valid_s = now
        self._last_sent_ms = float(sent_ms)
        self.counts["delivered"] += 1
        return Delivered(payload=body[HEADER_BYTES:], seq=seq, sent_s=sent_ms / 1000.0, gap=gap)

    @property
    def last_sent_s(self) -> float | None:
        """When the last delivered frame was sent (before the first: ``not_before_s``, or None)."""
        return None if math.isinf(self._last_sent_ms) else self._last_sent_ms / 1000.0

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


#: Why :class:`SafePeers` refused a frame: a receiver's reasons, and ``unknown_peer`` (a source
#: that cannot be a peer), ``too_many_peers`` (a new peer, valid MAC, beyond ``max_peers``),
#: ``error`` (an unexpected error while checking the frame: counted, survived).
PEER_REASONS = (*REASONS, "unknown_peer", "too_many_peers", "error")


class SafePeers:
    """The links of one party with any number of peers over a shared transport (one socket, one
    simulated medium; category 3 unless ``category`` says 1 or 2, a CRC-32 and no key):
    ``wrap(payload, peer, now_s)`` gives the frame for ``peer`` (its own sequence and key per
    direction), ``accept(frame, now_s)`` checks a received frame with the receiver of the peer it
    names and gives (peer, payload), or None: the reason it was refused is counted in
    ``rejected`` (:data:`PEER_REASONS`). ``peers(id)`` says which senders may be heard.

    Any bytes, from anyone (DESIGN rule 9: a process that serves others survives every bad
    frame): :meth:`accept` never raises for a frame, it counts it. Cheap refusals come first and
    touch no state, before any MAC is computed: too short or not this version and category
    (``malformed``), a source that is this party or not a possible peer (``wrong_source`` /
    ``unknown_peer``), a destination not this party (``wrong_destination``). The header is only
    used to refuse here, never to accept. No receiver state exists before a frame's MAC verified
    with the key of the peer it names, and at most ``max_peers`` receivers are held (a new peer
    beyond them is refused, ``too_many_peers``: it stays unheard and its own supervision acts,
    DESIGN rule 10). ``started_s``: when this party (its process) started; its receivers refuse
    frames sent before it (``old_session``: the module docstring's restart rule). None: no such
    floor. The master key must be a live key (:func:`check_master_key`) unless ``simulated`` (a
    link of a simulation over a simulated medium, where a demonstration key is allowed).
    """

    def __init__(
        self,
        own_id: int,
        master_key: bytes | None,
        *,
        max_age_s: float,
        peers: Callable[[int], bool],
        max_peers: int = MAX_PEERS,
        started_s: float | None = None,
        future_tolerance_s: float = 0.2,
        simulated: bool = False,
        category: int = 3,
    ) -> None:
        _check_id("own_id", own_id)
        _check_category(category)
        if not callable(peers):
            raise LinkConfigError("peers: a function of a source id is needed")
        if not isinstance(max_peers, int) or isinstance(max_peers, bool) or max_peers < 1:
            raise LinkConfigError(f"max_peers: a whole number >= 1 is needed (got {max_peers!r})")
        for name, value in (("max_age_s", max_age_s), ("future_tolerance_s", future_tolerance_s)):
            if _check_time(name, value) < 0.0:
                raise LinkConfigError(f"{name}: must be >= 0 (got {value!r})")
        self.own_id = own_id
        self.category = category
        if category != 3:
            # Categories 1 and 2 (a closed transmission system): a CRC-32, no key (_check_key).
            if master_key is not None:
                raise LinkConfigError(f"master_key: category {category} uses a CRC-32, not a key")
            self.master_key = b""
        else:
            # A simulated link (no attacker: the line simulation's radio) may run on a built-in
            # demonstration key; every live link passes the check (``simulated`` is never set there).
            if simulated and isinstance(master_key, bytes | bytearray):
                self.master_key = bytes(master_key)
            else:
                self.master_key = check_master_key(master_key)
        self._code_len = code_bytes(category)
        self.max_age_s = float(max_age_s)
        self.future_tolerance_s = float(future_tolerance_s)
        self.max_peers = max_peers
        self.started_s = None if started_s is None else _check_time("started_s", started_s)
        self.known = peers
        self._tx: dict[int, SafeSender] = {}
        self._rx: dict[int, SafeReceiver] = {}
        self._vc = VERSION << 4 | category
        self.sent = 0
        self.delivered = 0
        self.rejected: dict[str, int] = {}

    @property
    def peers_held(self) -> int:
        """Receivers held: peers heard with a valid MAC (at most ``max_peers``)."""
        return len(self._rx)

    def reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1

    def _key(self, src: int, dst: int) -> bytes | None:
        """The key of the direction ``src`` -> ``dst`` (category 3), or None (a CRC-32)."""
        return link_key(self.master_key, src, dst) if self.category == 3 else None

    def wrap(self, payload: bytes, peer: int, now_s: float) -> bytes:
        if peer not in self._tx:
            key = self._key(self.own_id, peer)
            self._tx[peer] = SafeSender(self.own_id, peer, key=key, category=self.category)
        frame = self._tx[peer].wrap(payload, now_s)
        self.sent += 1
        return frame

    def accept(self, frame: bytes, now_s: float) -> tuple[int, Delivered] | None:
        """(peer, delivery), or None with the reason counted. ``now_s`` is the caller's: a bad one
        raises :class:`LinkConfigError`; nothing about the frame does."""
        now = _check_time("now_s", now_s)
        try:
            return self._accept(frame, now)
        except Exception:  # DESIGN rule 9: counted and survived, never a crash
            self.reject("error")
            return None

    def _accept(self, frame: object, now_s: float) -> tuple[int, Delivered] | None:
        if type(frame) is bytes:
            data = frame  # (a bytes object is taken as it is)
        elif isinstance(frame, bytes | bytearray | memoryview):
            data = bytes(frame)
        else:
            self.reject("malformed")
            return None
        n = len(data)
        code_len = self._code_len
        if n < HEADER_BYTES + code_len:
            self.reject("malformed")
            return None
        vc, src, dst, _seq, _ts, length = HEADER.unpack_from(data)
        if vc != self._vc or length != n - HEADER_BYTES - code_len:
            self.reject("malformed")
            return None
        if src == self.own_id:
            self.reject("wrong_source")  # reflection: no peer sends as this party
            return None
        if not self.known(src):
            self.reject("unknown_peer")
            return None
        if dst != self.own_id:
            self.reject("wrong_destination")
            return None
        rx = self._rx.get(src)
        if rx is None:
            # A peer not heard yet: its MAC (CRC) first, so that no state exists for a forged
            # (corrupted) source.
            key = self._key(src, self.own_id)
            body, code = data[: n - code_len], data[n - code_len :]
            if not hmac.compare_digest(code, _safety_code(self.category, key, body)):
                self.reject("bad_mac" if self.category == 3 else "corrupt")
                return None
            if len(self._rx) >= self.max_peers:
                self.reject("too_many_peers")
                return None
            rx = SafeReceiver(
                self.own_id,
                src,
                key=key,
                category=self.category,
                max_age_s=self.max_age_s,
                timeout_s=1e9,  # the units above supervise their peers' silence
                start_s=now_s,
                future_tolerance_s=self.future_tolerance_s,
                not_before_s=self.started_s,
            )
            got = rx._check(data, now_s)
            if not isinstance(got, Delivered):
                # Authentic but refused (stale, old session...): nothing kept for a frame not delivered.
                self.reject(got.reason)
                return None
            self._rx[src] = rx
        else:
            got = rx._check(data, now_s)  # (``accept`` has checked the time, the frame is bytes)
            if not isinstance(got, Delivered):
                self.reject(got.reason)
                return None
        self.delivered += 1
        return src, got
