"""The EN 50159 safety layer (railstop.link.safety): the seven threats, every reason, an adversary."""

from __future__ import annotations

import struct
import zlib
from typing import ClassVar

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, precondition, rule

from railstop.errors import RailstopError
from railstop.link.codec import TascRequiredDecel, encode
from railstop.link.safety import (
    DEMO_KEY_PURPOSES,
    HEADER_BYTES,
    MAC_BYTES,
    PEER_REASONS,
    REASONS,
    SEQ_WINDOW,
    Delivered,
    LinkConfigError,
    Rejected,
    SafePeers,
    SafeReceiver,
    SafeSender,
    check_master_key,
    demo_master_key,
    frame_size,
    hkdf_sha256,
    link_key,
)

MASTER = bytes(range(100, 132))
A, B = 1, 2  # sender id, receiver id
MAX_AGE_S = 0.5
TIMEOUT_S = 1.0
PAYLOAD = encode(TascRequiredDecel(train_id=0x1234, detector=2, required_mps2=0.7))  # 9612340202bc85c1


def key_for(category: int, src: int = A, dst: int = B) -> bytes | None:
    return link_key(MASTER, src, dst) if category == 3 else None


def make_pair(category: int, **rx: float) -> tuple[SafeSender, SafeReceiver]:
    sender = SafeSender(A, B, key=key_for(category), category=category)
    receiver = SafeReceiver(
        B,
        A,
        key=key_for(category),
        category=category,
        max_age_s=rx.pop("max_age_s", MAX_AGE_S),
        timeout_s=rx.pop("timeout_s", TIMEOUT_S),
        **rx,
    )
    return sender, receiver


def code_reason(category: int) -> str:
    return "bad_mac" if category == 3 else "corrupt"


def resign(category: int, body: bytes) -> bytes:
    """Re-compute the safety code of a hand-edited body (as a sender with the right key would)."""
    import hashlib
    import hmac

    if category == 3:
        key = key_for(category)
        assert key is not None
        return body + hmac.new(key, body, hashlib.sha256).digest()[:8]
    return body + zlib.crc32(body).to_bytes(4, "big")


CATS = pytest.mark.parametrize("category", [1, 2, 3])


# --------------------------------------------------------------------------
# The frame, byte for byte


def test_reference_frame_category_1() -> None:
    """Written out from docs/telegrams.md; the CRC-32 was computed with a bitwise reference CRC."""
    frame = SafeSender(1, 2, category=1).wrap(PAYLOAD, 12.345)
    # 11 = version 1 | cat 1; src 0001; dst 0002; seq 00000001; 12345 ms = 00003039; length 08
    assert frame.hex() == "11000100020000000100003039089612340202bc85c1dc4119b9"


def test_reference_frame_category_3() -> None:
    """MAC computed by hand from the HMAC definition (ipad / opad) with key 00 01 .. 1f."""
    frame = SafeSender(1, 2, key=bytes(range(32)), category=3).wrap(PAYLOAD, 12.345)
    assert frame.hex() == "13000100020000000100003039089612340202bc85c1ec7c02f9e0dcfe25"


@CATS
def test_frame_size_and_sequence(category: int) -> None:
    sender, receiver = make_pair(category)
    for i in range(1, 4):
        frame = sender.wrap(b"x" * i, 0.0)
        assert len(frame) == frame_size(i, category) == HEADER_BYTES + i + (8 if category == 3 else 4)
        assert struct.unpack_from(">I", frame, 5)[0] == i
        got = receiver.accept(frame, 0.0)
        assert got == Delivered(payload=b"x" * i, seq=i, sent_s=0.0, gap=0)
    assert sender.wrap(b"", 0.0)[-(8 if category == 3 else 4) - 1] == 0  # empty payload allowed


def test_hkdf_rfc5869_test_case_1() -> None:
    okm = hkdf_sha256(bytes([0x0B]) * 22, salt=bytes(range(13)), info=bytes(range(0xF0, 0xFA)), length=42)
    assert okm.hex() == (
        "3cb25f25faacd57a90434f64d0362f2a2d2d0a90cf1a5a4c5db02d56ecc4c5bf34007208d5b887185865"
    )


def test_link_keys_differ_per_direction_and_link() -> None:
    keys = {
        link_key(MASTER, 1, 2),
        link_key(MASTER, 2, 1),
        link_key(MASTER, 1, 3),
        link_key(MASTER[::-1], 1, 2),
    }
    assert len(keys) == 4
    assert all(len(k) == 32 for k in keys)
    assert link_key(MASTER, 1, 2) == link_key(bytearray(MASTER), 1, 2)


# --------------------------------------------------------------------------
# The seven EN 50159 threats


@CATS
def test_threat_repetition(category: int) -> None:
    sender, receiver = make_pair(category)
    f1 = sender.wrap(b"one", 0.0)
    f2 = sender.wrap(b"two", 0.01)
    assert isinstance(receiver.accept(f1, 0.02), Delivered)
    assert receiver.accept(f1, 0.03) == Rejected(reason="repeated")
    assert isinstance(receiver.accept(f2, 0.04), Delivered)
    assert receiver.accept(f2, 0.05) == Rejected(reason="repeated")
    assert receiver.accept(f1, 0.06) == Rejected(reason="repeated")  # still remembered as delivered
    assert receiver.counts["delivered"] == 2 and receiver.counts["repeated"] == 3


@CATS
def test_threat_deletion(category: int) -> None:
    sender, receiver = make_pair(category)
    frames = [sender.wrap(bytes([i]), 0.1 * i) for i in range(6)]
    assert receiver.accept(frames[0], 0.0) == Delivered(payload=b"\x00", seq=1, sent_s=0.0, gap=0)
    # frames 1, 2 and 3 are lost
    got = receiver.accept(frames[4], 0.4)
    assert isinstance(got, Delivered) and got.gap == 3 and got.seq == 5
    assert receiver.deletions == 3
    # everything after is lost: the time-out reports it
    assert not receiver.timed_out(0.4 + TIMEOUT_S)
    assert receiver.timed_out(0.4 + TIMEOUT_S + 0.001)


@CATS
def test_threat_insertion(category: int) -> None:
    sender, receiver = make_pair(category)
    assert isinstance(receiver.accept(sender.wrap(b"a", 0.0), 0.0), Delivered)
    # A frame made up with the next sequence number, but no valid safety code ...
    body = struct.pack(">BHHIIB", 0x10 | category, A, B, 2, 10, 3) + b"evil"[:3]
    assert receiver.accept(body + bytes(8 if category == 3 else 4), 0.01) == Rejected(
        reason=code_reason(category)
    )
    # ... from a station that is not the peer (in category 1/2 it can compute the CRC-32) ...
    intruder = SafeSender(7, B, key=key_for(category, 7, B), category=category)
    got = receiver.accept(intruder.wrap(b"evil", 0.01), 0.01)
    assert got == Rejected(reason="bad_mac" if category == 3 else "wrong_source")
    # ... or random noise: nothing is delivered and the genuine stream goes on without a gap.
    assert isinstance(receiver.accept(bytes(range(40)), 0.01), Rejected)
    got = receiver.accept(sender.wrap(b"b", 0.02), 0.02)
    assert got == Delivered(payload=b"b", seq=2, sent_s=0.02, gap=0)


@CATS
def test_threat_resequencing(category: int) -> None:
    sender, receiver = make_pair(category)
    f1, f2, f3 = (sender.wrap(bytes([i]), 0.0) for i in range(3))
    assert isinstance(receiver.accept(f1, 0.0), Delivered)
    got = receiver.accept(f3, 0.0)
    assert isinstance(got, Delivered) and got.gap == 1
    assert receiver.accept(f2, 0.0) == Rejected(reason="out_of_order")
    assert receiver.deletions == 1


@CATS
def test_threat_corruption_every_single_bit(category: int) -> None:
    sender, receiver = make_pair(category)
    frame = sender.wrap(PAYLOAD, 1.0)
    for bit in range(8 * len(frame)):
        bad = bytearray(frame)
        bad[bit // 8] ^= 1 << (bit % 8)
        assert receiver.accept(bytes(bad), 1.0) == Rejected(reason=code_reason(category)), bit
    assert receiver.counts[code_reason(category)] == 8 * len(frame)
    assert isinstance(receiver.accept(frame, 1.0), Delivered)


@CATS
def test_threat_delay(category: int) -> None:
    sender, receiver = make_pair(category)
    late = sender.wrap(b"late", 1.0)
    on_time = sender.wrap(b"on time", 1.0)
    assert receiver.accept(late, 1.0 + MAX_AGE_S + 0.001) == Rejected(reason="stale")
    got = receiver.accept(on_time, 1.0 + MAX_AGE_S)  # exactly max_age_s old: still good
    assert isinstance(got, Delivered) and got.sent_s == 1.0 and got.gap == 1
    # A timestamp from the future (beyond the clock tolerance) is as suspect as an old one.
    ahead = sender.wrap(b"ahead", 5.0)
    assert receiver.accept(ahead, 5.0 - 0.051) == Rejected(reason="stale")
    assert isinstance(receiver.accept(sender.wrap(b"ok", 5.05), 5.0), Delivered)


@CATS
def test_threat_masquerade(category: int) -> None:
    sender, receiver = make_pair(category)
    # Someone else claiming to be A: in category 3 without A's key for this direction.
    if category == 3:
        for key in (link_key(MASTER, A, 9), link_key(MASTER, B, A), bytes(32)):
            impostor = SafeSender(A, B, key=key, category=3)
            assert receiver.accept(impostor.wrap(b"open doors", 0.0), 0.0) == Rejected(reason="bad_mac")
    # Reflection: B's own frames to A played back to B.
    own = SafeSender(B, A, key=key_for(category, B, A), category=category)
    got = receiver.accept(own.wrap(b"mirror", 0.0), 0.0)
    assert got == Rejected(reason="bad_mac" if category == 3 else "wrong_source")
    # A frame from A to another station is not for B.
    other = SafeSender(A, 5, key=key_for(category, A, 5), category=category)
    got = receiver.accept(other.wrap(b"not yours", 0.0), 0.0)
    assert got == Rejected(reason="bad_mac" if category == 3 else "wrong_destination")
    assert receiver.counts["delivered"] == 0
    assert isinstance(receiver.accept(sender.wrap(b"genuine", 0.0), 0.0), Delivered)


# --------------------------------------------------------------------------
# One test per rejection reason (with a valid safety code where the reason needs one)


@CATS
def test_reason_malformed(category: int) -> None:
    sender, receiver = make_pair(category)
    frame = sender.wrap(b"abc", 0.0)
    code = 8 if category == 3 else 4
    for bad in (b"", frame[: HEADER_BYTES + code - 1], None, "text", 12):
        assert receiver.accept(bad, 0.0) == Rejected(reason="malformed")  # type: ignore[arg-type]
    body = bytearray(frame[:-code])
    for i, value in ((0, 0x20 | category), (0, 0x10 | (category % 3 + 1)), (13, 2), (13, 4)):
        edited = bytearray(body)
        edited[i] = value  # wrong version / wrong category / length byte too small / too large
        assert receiver.accept(resign(category, bytes(edited)), 0.0) == Rejected(reason="malformed"), i
    assert receiver.counts["malformed"] == 9
    assert isinstance(receiver.accept(frame, 0.0), Delivered)


def test_reason_corrupt_and_bad_mac() -> None:
    for category in (1, 2, 3):
        sender, receiver = make_pair(category)
        frame = bytearray(sender.wrap(b"abc", 0.0))
        frame[-1] ^= 0xFF
        assert receiver.accept(bytes(frame), 0.0) == Rejected(reason=code_reason(category))
    # A category 3 receiver never reports "corrupt", a category 1 receiver never "bad_mac".
    _, r1 = make_pair(1)
    s3, r3 = make_pair(3)
    assert r1.accept(s3.wrap(b"abc", 0.0), 0.0) == Rejected(reason="corrupt")
    s1, _ = make_pair(1)
    assert r3.accept(s1.wrap(b"abcdefgh", 0.0), 0.0) == Rejected(reason="bad_mac")


@CATS
def test_reason_wrong_source_and_destination(category: int) -> None:
    sender, receiver = make_pair(category)
    body = bytearray(sender.wrap(b"abc", 0.0)[: -(8 if category == 3 else 4)])
    src = bytearray(body)
    src[1:3] = (9).to_bytes(2, "big")
    assert receiver.accept(resign(category, bytes(src)), 0.0) == Rejected(reason="wrong_source")
    dst = bytearray(body)
    dst[3:5] = (9).to_bytes(2, "big")
    assert receiver.accept(resign(category, bytes(dst)), 0.0) == Rejected(reason="wrong_destination")


@CATS
def test_reason_repeated_and_out_of_order(category: int) -> None:
    sender, receiver = make_pair(category)
    frames = [sender.wrap(bytes([i % 256]), 0.0) for i in range(SEQ_WINDOW + 3)]
    assert isinstance(receiver.accept(frames[0], 0.0), Delivered)
    assert isinstance(receiver.accept(frames[2], 0.0), Delivered)
    assert receiver.accept(frames[2], 0.0) == Rejected(reason="repeated")  # == last
    assert receiver.accept(frames[0], 0.0) == Rejected(reason="repeated")  # delivered before
    assert receiver.accept(frames[1], 0.0) == Rejected(reason="out_of_order")  # never delivered
    # Once a delivered frame is more than SEQ_WINDOW behind, it is reported as out of order.
    assert isinstance(receiver.accept(frames[SEQ_WINDOW + 1], 0.0), Delivered)  # seq 66
    assert receiver.accept(frames[2], 0.0) == Rejected(reason="repeated")  # 63 behind: remembered
    assert receiver.accept(frames[0], 0.0) == Rejected(reason="out_of_order")  # 65 behind: forgotten


@CATS
def test_a_restarted_sender_is_followed_and_a_replay_still_refused(category: int) -> None:
    """A restarted sender begins again at sequence number 1, later in time: the receiver follows the
    new session at once (not after the new numbers pass the old ones). Frames of the old session
    replayed afterwards keep their old timestamps and stay refused."""
    sender, receiver = make_pair(category)
    old = [sender.wrap(bytes([i]), 10.0 + 0.1 * i) for i in range(100)]
    for i, frame in enumerate(old):
        assert isinstance(receiver.accept(frame, 10.0 + 0.1 * i), Delivered)
    again = SafeSender(A, B, key=key_for(category), category=category)  # the restarted sender
    first = receiver.accept(again.wrap(b"new", 25.0), 25.0)
    assert isinstance(first, Delivered) and first.seq == 1 and first.payload == b"new"
    assert receiver.restarts == 1
    assert isinstance(receiver.accept(again.wrap(b"next", 25.1), 25.1), Delivered)
    # A replay of the old session (valid code, its old timestamp) is refused, whatever its number.
    assert receiver.accept(old[99], 25.2) == Rejected(reason="stale")  # seq 100, above the new 2
    assert receiver.accept(old[0], 25.2) == Rejected(reason="repeated")  # seq 1: delivered (new session)
    # Within a session a frame overtaken by a later one stays out of order (its time is earlier).
    late = again.wrap(b"late", 25.2)
    assert isinstance(receiver.accept(again.wrap(b"on time", 25.3), 25.3), Delivered)
    assert receiver.accept(late, 25.3) == Rejected(reason="out_of_order")
    assert receiver.restarts == 1


@CATS
def test_reason_stale(category: int) -> None:
    sender, receiver = make_pair(category, max_age_s=0.2)
    assert receiver.accept(sender.wrap(b"a", 10.0), 10.201) == Rejected(reason="stale")
    assert receiver.accept(sender.wrap(b"b", 10.0), 9.9) == Rejected(reason="stale")
    assert isinstance(receiver.accept(sender.wrap(b"c", 10.0), 10.2), Delivered)


def test_timestamp_wrap_is_harmless() -> None:
    sender, receiver = make_pair(1)
    t = 4294967.290  # 6 ms before the uint32 ms counter wraps
    frame = sender.wrap(b"wrap", t)
    assert struct.unpack_from(">I", frame, 9)[0] == 4294967290
    got = receiver.accept(frame, t + 0.010)  # the receiver's counter has wrapped
    assert isinstance(got, Delivered) and got.sent_s == pytest.approx(t)
    after = sender.wrap(b"after", t + 0.010)
    assert struct.unpack_from(">I", after, 9)[0] == 4
    assert receiver.accept(after, t + 0.010 + MAX_AGE_S + 0.001) == Rejected(reason="stale")


# --------------------------------------------------------------------------
# Time-out, counters, inputs, configuration


def test_timed_out_from_start_and_from_last_delivery() -> None:
    sender, receiver = make_pair(1, start_s=100.0)
    assert not receiver.timed_out(100.0 + TIMEOUT_S)
    assert receiver.timed_out(100.0 + TIMEOUT_S + 0.001)
    assert isinstance(receiver.accept(sender.wrap(b"a", 101.5), 101.5), Delivered)
    assert not receiver.timed_out(102.0)
    # Rejected frames do not keep the link alive.
    for t in (102.0, 102.3, 102.6):
        assert isinstance(receiver.accept(b"\x00" * 30, t), Rejected)
    assert receiver.timed_out(102.6)


def test_counts_add_up() -> None:
    sender, receiver = make_pair(3)
    frames = [sender.wrap(bytes([i]), 0.0) for i in range(5)]
    outcomes = [receiver.accept(f, 0.0) for f in (frames[0], frames[0], frames[2], frames[1], b"", frames[4])]
    outcomes.append(receiver.accept(frames[3][:-1] + bytes([frames[3][-1] ^ 1]), 0.0))
    assert [getattr(o, "reason", "delivered") for o in outcomes] == [
        "delivered",
        "repeated",
        "delivered",
        "out_of_order",
        "malformed",
        "delivered",
        "bad_mac",
    ]
    assert receiver.counts == {
        **dict.fromkeys(REASONS, 0),
        "delivered": 3,
        "repeated": 1,
        "out_of_order": 1,
        "malformed": 1,
        "bad_mac": 1,
    }
    assert receiver.deletions == 2


def test_bytes_like_inputs() -> None:
    sender, receiver = make_pair(1)
    assert isinstance(receiver.accept(bytearray(sender.wrap(b"a", 0.0)), 0.0), Delivered)
    assert isinstance(receiver.accept(memoryview(sender.wrap(b"b", 0.0)), 0.0), Delivered)
    assert isinstance(receiver.accept(sender.wrap(memoryview(b"c"), 0.0), 0.0), Delivered)
    view = memoryview(sender.wrap(b"d", 0.0))
    view.release()
    assert receiver.accept(view, 0.0) == Rejected(reason="malformed")


@pytest.mark.parametrize(
    "make",
    [
        lambda: SafeSender(1, 2, category=3),  # no key
        lambda: SafeSender(1, 2, key=bytes(15), category=3),  # short key
        lambda: SafeSender(1, 2, key=bytes(16), category=1),  # a key does nothing in category 1
        lambda: SafeSender(1, 2, category=4),
        lambda: SafeSender(1, 2, category=True),
        lambda: SafeSender(1, 1, category=1),
        lambda: SafeSender(-1, 2, category=1),
        lambda: SafeSender(1, 65536, category=1),
        lambda: SafeReceiver(2, 1, category=1, max_age_s=-1.0, timeout_s=1.0),
        lambda: SafeReceiver(2, 1, category=1, max_age_s=float("nan"), timeout_s=1.0),
        lambda: SafeReceiver(2, 2, category=1, max_age_s=1.0, timeout_s=1.0),
        lambda: SafeReceiver(2, 1, category=3, max_age_s=1.0, timeout_s=1.0),
        lambda: SafeSender(1, 2, category=1).wrap(bytes(256), 0.0),
        lambda: SafeSender(1, 2, category=1).wrap("text", 0.0),  # type: ignore[arg-type]
        lambda: SafeSender(1, 2, category=1).wrap(b"", float("inf")),
        lambda: SafeReceiver(2, 1, category=1, max_age_s=1.0, timeout_s=1.0).accept(b"", float("nan")),
        lambda: link_key(bytes(15), 1, 2),
    ],
)
def test_configuration_errors(make: object) -> None:
    with pytest.raises(LinkConfigError) as info:
        make()  # type: ignore[operator]
    assert isinstance(info.value, RailstopError) and isinstance(info.value, ValueError)


def test_sequence_numbers_do_not_wrap() -> None:
    sender = SafeSender(1, 2, category=1)
    sender.next_seq = 2**32 - 1
    assert struct.unpack_from(">I", sender.wrap(b"", 0.0), 5)[0] == 2**32 - 1
    with pytest.raises(LinkConfigError, match="exhausted"):
        sender.wrap(b"", 0.0)


# --------------------------------------------------------------------------
# An adversary on the medium (hypothesis stateful)

MAX_AGE_MS = round(MAX_AGE_S * 1000)
FUTURE_MS = 50


class Adversary(RuleBasedStateMachine):
    """The adversary sees every genuine frame and may drop, replay, reorder, delay, corrupt, forge, inject.

    Time runs on a 1 ms grid so that the age limit can be checked exactly.
    After every frame: a delivered payload is genuine, its sequence number is
    above every one delivered before (so each genuine frame is delivered at
    most once), it is at most max_age_s old, and a genuine, intact, fresh,
    in-order frame IS delivered. Every call adds one to exactly one counter.
    """

    category: ClassVar[int] = 1

    @initialize()
    def setup(self) -> None:
        self.now_ms = 0
        self.sender, self.rx = make_pair(self.category)
        self.genuine: dict[int, tuple[bytes, int, bytes]] = {}  # seq -> (payload, sent ms, frame)
        self.delivered: list[int] = []
        self.last_delivery_ms = 0
        self.calls = 0
        self.gaps = 0

    # -- the model of a genuine, intact frame
    def expected(self, seq: int) -> str:
        last = self.delivered[-1] if self.delivered else 0
        if seq == last:
            return "repeated"
        if seq < last:
            return "repeated" if seq in self.delivered and last - seq < SEQ_WINDOW else "out_of_order"
        age = self.now_ms - self.genuine[seq][1]
        return "stale" if age > MAX_AGE_MS or -age > FUTURE_MS else "delivered"

    def deliver(self, frame: bytes, expect: str | None = None) -> None:
        before = dict(self.rx.counts)
        got = self.rx.accept(frame, self.now_ms / 1000)
        self.calls += 1
        diff = {k: v - before[k] for k, v in self.rx.counts.items()}
        assert sorted(diff.values()) == [0] * (len(diff) - 1) + [1]
        if isinstance(got, Delivered):
            assert diff["delivered"] == 1
            assert got.seq in self.genuine, "delivered a frame nobody sent"
            payload, sent_ms, _ = self.genuine[got.seq]
            assert got.payload == payload
            assert not self.delivered or got.seq > self.delivered[-1]
            assert self.now_ms - sent_ms <= MAX_AGE_MS
            assert got.sent_s == sent_ms / 1000
            assert got.gap == got.seq - (self.delivered[-1] if self.delivered else 0) - 1
            self.delivered.append(got.seq)
            self.last_delivery_ms = self.now_ms
            self.gaps += got.gap
            outcome = "delivered"
        else:
            assert got.reason in REASONS and diff[got.reason] == 1
            outcome = got.reason
        if expect is not None:
            assert outcome == expect, (outcome, expect)

    # -- genuine traffic
    @rule(payload=st.binary(max_size=12), deliver=st.booleans())
    def send(self, payload: bytes, deliver: bool) -> None:
        seq = self.sender.next_seq
        frame = self.sender.wrap(payload, self.now_ms / 1000)
        self.genuine[seq] = (payload, self.now_ms, frame)
        if deliver:
            self.deliver(frame, self.expected(seq))
        # else: dropped (deletion); the adversary keeps a copy

    @precondition(lambda self: self.genuine)
    @rule(pick=st.integers(min_value=0))
    def replay(self, pick: int) -> None:
        """Deliver any genuine frame again or late: repetition, re-sequencing, delayed delivery."""
        seq = sorted(self.genuine)[pick % len(self.genuine)]
        self.deliver(self.genuine[seq][2], self.expected(seq))

    @rule(
        dt_ms=st.one_of(
            st.integers(0, 60), st.integers(0, 3 * MAX_AGE_MS), st.sampled_from([MAX_AGE_MS, MAX_AGE_MS + 1])
        )
    )
    def advance(self, dt_ms: int) -> None:
        self.now_ms += dt_ms

    # -- hostile or broken frames
    @precondition(lambda self: self.genuine)
    @rule(pick=st.integers(min_value=0), bit=st.integers(min_value=0))
    def flip_one_bit(self, pick: int, bit: int) -> None:
        frame = bytearray(self.genuine[sorted(self.genuine)[pick % len(self.genuine)]][2])
        bit %= 8 * len(frame)
        frame[bit // 8] ^= 1 << (bit % 8)
        self.deliver(bytes(frame), code_reason(self.category))

    @precondition(lambda self: self.genuine)
    @rule(
        pick=st.integers(min_value=0),
        edits=st.lists(st.tuples(st.integers(0), st.integers(1, 255)), min_size=1),
    )
    def mangle(self, pick: int, edits: list[tuple[int, int]]) -> None:
        frame = bytearray(self.genuine[sorted(self.genuine)[pick % len(self.genuine)]][2])
        for pos, mask in edits:
            frame[pos % len(frame)] ^= mask
        self.deliver(bytes(frame))

    @precondition(lambda self: self.genuine)
    @rule(pick=st.integers(min_value=0), cut=st.integers(1, 40), tail=st.binary(max_size=8))
    def truncate_or_extend(self, pick: int, cut: int, tail: bytes) -> None:
        frame = self.genuine[sorted(self.genuine)[pick % len(self.genuine)]][2]
        self.deliver(frame[: max(0, len(frame) - cut)] + tail)

    @rule(payload=st.binary(max_size=12), who=st.sampled_from(["key", "source", "destination"]))
    def forge(self, payload: bytes, who: str) -> None:
        """A frame with the next sequence number and a fresh timestamp, but not from A to B with A's key."""
        cat = self.category
        if who == "key" and cat == 3:
            forger = SafeSender(A, B, key=link_key(b"not the master key", A, B), category=3)
        elif who == "destination":
            forger = SafeSender(A, 5, key=key_for(cat, A, 5), category=cat)
        else:
            forger = SafeSender(6, B, key=key_for(cat, 6, B), category=cat)
        forger.next_seq = self.sender.next_seq
        frame = forger.wrap(payload, self.now_ms / 1000)
        expect = {"key": "wrong_source", "source": "wrong_source", "destination": "wrong_destination"}[who]
        self.deliver(frame, "bad_mac" if cat == 3 else expect)

    @rule(noise=st.binary(max_size=64))
    def inject(self, noise: bytes) -> None:
        self.deliver(noise)

    # -- what must hold after every step
    @invariant()
    def counters_add_up(self) -> None:
        assert sum(self.rx.counts.values()) == self.calls
        assert self.rx.counts["delivered"] == len(self.delivered)
        assert self.rx.deletions == self.gaps
        assert self.rx.timed_out(self.now_ms / 1000) == (
            self.now_ms - self.last_delivery_ms > TIMEOUT_S * 1000
        )


class AdversaryCategory1(Adversary):
    category = 1


class AdversaryCategory3(Adversary):
    category = 3


_STATEFUL = settings(
    max_examples=100, stateful_step_count=40, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
TestAdversaryCategory1 = AdversaryCategory1.TestCase
TestAdversaryCategory1.settings = _STATEFUL
TestAdversaryCategory3 = AdversaryCategory3.TestCase
TestAdversaryCategory3.settings = _STATEFUL


def test_time_out_is_decided_in_whole_milliseconds() -> None:
    """Found by the stateful adversary: a delivery at 0.951 s and a check at 1.951 s is exactly the
    1 s time-out, not past it (in seconds, 1.951 - 0.951 > 1.0 in floating point)."""
    sender, receiver = make_pair(3)
    assert isinstance(receiver.accept(sender.wrap(b"a", 0.951), 0.951), Delivered)
    assert not receiver.timed_out(1.951)
    assert receiver.timed_out(1.952)


def test_sequence_number_zero_is_malformed() -> None:
    """No sender sends sequence number 0 (the first is 1): a frame with it, even with a valid safety
    code, is refused and cannot pass for a restart of the peer."""
    _, receiver = make_pair(1)
    body = struct.pack(">BHHIIB", 0x11, A, B, 0, 0, 1) + b"z"
    assert receiver.accept(resign(1, body), 0.0) == Rejected(reason="malformed")
    assert receiver.last_seq == 0 and receiver.restarts == 0


# --------------------------------------------------------------------------
# Restarts of either end: a frame delivered once is never delivered again


@CATS
def test_old_session_frames_are_not_delivered_after_a_sender_restart(category: int) -> None:
    """Once the receiver follows a restarted sender, frames of the old session with higher sequence
    numbers (still fresh) are refused; alternating old and new frames delivers each new one once
    and no old one again."""
    sender, receiver = make_pair(category, max_age_s=5.0)
    old = [sender.wrap(bytes([i]), 10.0 + 0.01 * i) for i in range(50)]
    for i, frame in enumerate(old[:40]):
        assert isinstance(receiver.accept(frame, 10.0 + 0.01 * i), Delivered)
    again = SafeSender(A, B, key=key_for(category), category=category)  # restarted at 10.5 s
    new = [again.wrap(bytes([100 + i]), 10.5 + 0.01 * i) for i in range(10)]
    assert isinstance(receiver.accept(new[0], 10.5), Delivered) and receiver.restarts == 1
    delivered = []
    for i in range(1, 10):
        t = 10.5 + 0.01 * i
        for frame in (old[40 + i], new[i], old[i], old[39]):  # old ones sent before, some never delivered
            got = receiver.accept(frame, t)
            if isinstance(got, Delivered):
                delivered.append(got.payload[0])
    assert delivered == list(range(101, 110))
    assert receiver.counts["old_session"] > 0 and receiver.restarts == 1


@CATS
def test_a_restarted_receiver_refuses_what_was_sent_before_it_started(category: int) -> None:
    """A receiver process started again (a new SafeReceiver) is given its start: the frames its
    predecessor delivered, still younger than max_age_s, are refused; frames sent after it started
    are delivered."""
    sender, first = make_pair(category, max_age_s=5.0)
    frames = [sender.wrap(bytes([i]), 1.0 + 0.1 * i) for i in range(10)]
    for i, frame in enumerate(frames):
        assert isinstance(first.accept(frame, 1.0 + 0.1 * i), Delivered)
    # Without its start the new incarnation would deliver them again (the hazard) ...
    _, blind = make_pair(category, max_age_s=5.0)
    assert isinstance(blind.accept(frames[9], 2.5), Delivered)
    # ... with it, refused; the sender's next frame is delivered.
    _, second = make_pair(category, max_age_s=5.0, not_before_s=2.0)
    assert [second.accept(f, 2.5) for f in frames] == [Rejected(reason="old_session")] * 10
    assert isinstance(second.accept(sender.wrap(b"next", 2.6), 2.6), Delivered)
    assert second.counts["old_session"] == 10


class _Run:
    """Genuine frames of successive sender sessions, an adversary delivering any of them in any
    order, any number of times, to successive receiver incarnations."""

    def __init__(self, category: int) -> None:
        self.category = category
        self.now_ms = 0
        self.frames: list[tuple[bytes, tuple[int, int]]] = []  # (frame, (session, seq))
        self.session = 0
        self.sender = SafeSender(A, B, key=key_for(category), category=category)
        self.receiver = self.new_receiver(None)
        self.delivered: list[tuple[int, int]] = []
        self.by_payload: dict[bytes, tuple[int, int]] = {}

    def new_receiver(self, start_s: float | None) -> SafeReceiver:
        return SafeReceiver(
            B, A, key=key_for(self.category), category=self.category, max_age_s=MAX_AGE_S,
            timeout_s=TIMEOUT_S, not_before_s=start_s,
        )  # fmt: skip

    def deliver(self, frame: bytes) -> None:
        got = self.receiver.accept(frame, self.now_ms / 1000)
        if isinstance(got, Delivered):
            ident = self.by_payload[got.payload]
            assert ident not in self.delivered, f"{ident} delivered twice"
            self.delivered.append(ident)


@pytest.mark.parametrize("category", [1, 3])
@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_no_frame_is_delivered_twice_across_restarts_of_either_end(
    category: int, data: st.DataObject
) -> None:
    """The rule of the module docstring as a property: whatever the adversary replays, however the
    sender and the receiver restart (each restart takes at least 1 ms), no genuine frame is
    delivered twice, and every frame delivered is genuine."""
    run = _Run(category)
    for _ in range(data.draw(st.integers(1, 40))):
        action = data.draw(st.sampled_from(["send", "send", "advance", "replay", "sender", "receiver"]))
        if action == "send":
            seq = run.sender.next_seq
            payload = struct.pack(">HI", run.session, seq)
            frame = run.sender.wrap(payload, run.now_ms / 1000)
            run.by_payload[payload] = (run.session, seq)
            run.frames.append((frame, (run.session, seq)))
            if data.draw(st.booleans()):
                run.deliver(frame)
        elif action == "advance":
            run.now_ms += data.draw(st.integers(0, 3 * MAX_AGE_MS))
        elif action == "replay" and run.frames:
            run.deliver(data.draw(st.sampled_from(run.frames))[0])
        elif action == "sender":
            run.now_ms += data.draw(st.integers(1, 50))
            run.session += 1
            run.sender = SafeSender(A, B, key=key_for(category), category=category)
        elif action == "receiver":
            run.now_ms += data.draw(st.integers(1, 50))
            run.receiver = run.new_receiver(run.now_ms / 1000)


# --------------------------------------------------------------------------
# SafePeers: one party, many peers, any bytes from anyone

OWN, PEER = 0x0300, 0x2001  # the zone controller and a train radio, as in the live CBTC line


def zc_peers(**kw: object) -> SafePeers:
    return SafePeers(OWN, MASTER, max_age_s=1.0, peers=lambda p: p == OWN or 0x2000 <= p < 0x3000, **kw)  # type: ignore[arg-type]


def forged(src: int, dst: int, *, seq: int = 1, ts_ms: int = 0, payload: bytes = b"x") -> bytes:
    """A category-3 frame with any header and a MAC made without the key."""
    return struct.pack(">BHHIIB", 0x13, src, dst, seq, ts_ms, len(payload)) + payload + bytes(MAC_BYTES)


def test_peers_survive_a_frame_naming_the_receiver_as_its_source() -> None:
    """A frame whose header names the receiving party as its source (reflection; random junk does it
    about once in 65,536 datagrams) is refused and counted; it used to end the process."""
    links = zc_peers()
    assert links.accept(forged(OWN, OWN), 0.0) is None
    assert links.accept(forged(OWN, 0x1234), 0.0) is None
    genuine = SafePeers(PEER, MASTER, max_age_s=1.0, peers=lambda p: p == OWN).wrap(b"report", OWN, 0.0)
    got = links.accept(genuine, 0.0)
    assert got is not None and got[0] == PEER and got[1].payload == b"report"
    assert links.rejected == {"wrong_source": 2} and links.delivered == 1


@settings(max_examples=300, deadline=None)
@given(
    frame=st.one_of(
        st.binary(max_size=64),
        st.builds(
            forged,
            st.integers(0, 0xFFFF),
            st.sampled_from([OWN, 0, 0xFFFF, PEER]),
            seq=st.integers(0, 2**32 - 1),
            ts_ms=st.integers(0, 2**32 - 1),
            payload=st.binary(max_size=20),
        ),
    ),
    now_s=st.floats(-1e6, 1e6),
)
def test_peers_accept_any_bytes_without_raising_or_keeping_state(frame: bytes, now_s: float) -> None:
    """Any bytes, any header: refused (no key), counted once, no receiver created."""
    links = zc_peers()
    assert links.accept(frame, now_s) is None
    assert sum(links.rejected.values()) == 1 and set(links.rejected) <= set(PEER_REASONS)
    assert links.peers_held == 0


def test_peers_keep_no_state_for_forged_sources_and_a_bounded_number_of_real_ones() -> None:
    """Frames naming every possible source id make no receiver (the MAC is checked first); peers that
    verify are held up to max_peers, one more is refused as too_many_peers and stays unheard."""
    links = zc_peers(max_peers=3)
    for src in range(0x2000, 0x3000):  # every id the predicate allows, forged
        assert links.accept(forged(src, OWN), 0.0) is None
    assert links.peers_held == 0 and links.rejected == {"bad_mac": 0x1000}
    trains = [SafePeers(0x2000 + k, MASTER, max_age_s=1.0, peers=lambda p: True) for k in range(5)]
    got = [links.accept(t.wrap(b"r", OWN, 0.0), 0.0) for t in trains]
    assert [g is not None for g in got] == [True, True, True, False, False]
    assert links.peers_held == 3 and links.rejected["too_many_peers"] == 2
    # The peers held are still heard.
    assert links.accept(trains[0].wrap(b"r2", OWN, 0.1), 0.1) is not None


def test_peers_refuse_cheaply_what_cannot_be_a_peer() -> None:
    links = zc_peers()
    assert links.accept(forged(0x1000, OWN), 0.0) is None  # not a possible peer
    assert links.accept(forged(PEER, 0x0301), 0.0) is None  # for another party
    assert links.accept(b"\x13" + bytes(20), 0.0) is None  # too short for category 3
    assert links.accept(forged(PEER, OWN)[:-1], 0.0) is None  # length byte disagrees
    assert links.accept("text", 0.0) is None  # type: ignore[arg-type]
    assert links.rejected == {"unknown_peer": 1, "wrong_destination": 1, "malformed": 3}


def test_peers_count_an_error_of_the_peer_predicate_and_go_on() -> None:
    """An unexpected error while checking a frame (here the caller's predicate fails) is counted as
    ``error`` and survived; a bad receiver time is the caller's error and raises."""

    def broken(p: int) -> bool:
        raise KeyError(p)

    links = SafePeers(OWN, MASTER, max_age_s=1.0, peers=broken)
    assert links.accept(forged(PEER, OWN), 0.0) is None
    assert links.rejected == {"error": 1}
    with pytest.raises(LinkConfigError):
        links.accept(forged(PEER, OWN), float("nan"))


def test_peers_started_refuse_frames_sent_before_the_process_started() -> None:
    """A party started again (SafePeers with started_s) refuses what its predecessor may have
    delivered; what the peer sends afterwards gets through."""
    train = SafePeers(PEER, MASTER, max_age_s=1.0, peers=lambda p: p == OWN)
    frames = [train.wrap(bytes([i]), OWN, 5.0 + 0.1 * i) for i in range(5)]
    before = zc_peers()
    assert all(before.accept(f, 5.0 + 0.1 * i) is not None for i, f in enumerate(frames))
    again = zc_peers(started_s=5.45)
    assert [again.accept(f, 5.5) for f in frames] == [None] * 5
    assert again.rejected == {"old_session": 5} and again.peers_held == 0
    assert again.accept(train.wrap(b"new", OWN, 5.5), 5.5) is not None


@pytest.mark.parametrize("purpose", DEMO_KEY_PURPOSES)
def test_live_links_refuse_the_built_in_demonstration_keys(purpose: str) -> None:
    """The simulations' master keys are public (their derivation is in the source): a live link
    (SafePeers) refuses them, and short or missing keys, with one line."""
    with pytest.raises(LinkConfigError, match="demonstration key") as info:
        SafePeers(OWN, demo_master_key(purpose), max_age_s=1.0, peers=lambda p: True)
    assert "\n" not in str(info.value)
    for bad in (b"", bytes(15), None, "0011" * 8):
        with pytest.raises(LinkConfigError, match="at least 16 bytes"):
            SafePeers(OWN, bad, max_age_s=1.0, peers=lambda p: True)  # type: ignore[arg-type]
    assert check_master_key(bytearray(MASTER)) == MASTER


def test_only_the_simulated_radio_may_run_on_a_demonstration_key() -> None:
    """The CBTC radio's endpoint is one for the line and live (``CbtcEndpoint``): built as live
    builds it, it refuses the demonstration key; only a simulation's end says ``simulated`` (the
    line's ``CbtcRadio``), and no module of the live processes or the command line ever does."""
    from pathlib import Path

    import railstop
    from railstop.link import cbtc_radio

    with pytest.raises(LinkConfigError, match="demonstration key"):
        cbtc_radio.CbtcEndpoint.zone_controller(cbtc_radio._DEMO_MASTER, trains=3)
    with pytest.raises(LinkConfigError, match="demonstration key"):
        cbtc_radio.CbtcEndpoint.train(0, cbtc_radio._DEMO_MASTER)
    root = Path(railstop.__file__).parent
    sources = [*(root / "live").glob("*.py"), *(root / "cli").glob("*.py")]
    assert sources and not [p.name for p in sources if "simulated=True" in p.read_text()]
    assert "simulated=True" in (root / "link" / "cbtc_radio.py").read_text()


def test_simulated_links_keep_their_demonstration_keys() -> None:
    """The simulations go on with their built-in keys (the same bytes as before they were named)."""
    import hashlib

    from railstop.link import cbtc_radio, door_link

    assert hashlib.sha256(b"railstop demonstration CBTC radio master key").digest() == cbtc_radio._DEMO_MASTER
    assert hashlib.sha256(b"railstop demonstration door link master key").digest() == door_link._DEMO_MASTER
