"""link.endpoint.Endpoint: telegrams to safety frames and back, every category, any bytes survived."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railstop.link.codec import CbtcCommand, DoorCommand, PsdStatus, encode
from railstop.link.endpoint import Endpoint
from railstop.link.safety import LinkConfigError, SafePeers

A, B = 0x1001, 0x0200
KEY = bytes(range(32))
STATUS = PsdStatus(
    train_id=1, psc=True, psd_closed_locked=True, start_enable=True, manual=False, fault=False, psd_open=0
)


def pair(category: int) -> tuple[Endpoint, Endpoint]:
    key = KEY if category == 3 else None
    a = Endpoint(
        A, peers=lambda p: p == B, max_age_s=0.3, category=category, master_key=key, expects=(PsdStatus,)
    )
    b = Endpoint(B, peers=lambda p: p == A, max_age_s=0.3, category=category, master_key=key)
    return a, b


@pytest.mark.parametrize("category", [1, 2, 3])
def test_a_telegram_goes_through_as_itself_once(category: int) -> None:
    a, b = pair(category)
    frame = b.frame(STATUS, A, 1.0)
    assert frame is not None
    assert a.receive(frame, 1.05) == (B, STATUS)
    assert a.receive(frame, 1.06) is None and a.rejected == {"repeated": 1}  # a replay
    assert (b.sent, a.delivered) == (1, 1)


@pytest.mark.parametrize(("category", "reason"), [(1, "corrupt"), (3, "bad_mac")])
def test_a_damaged_frame_is_refused_by_its_safety_code(category: int, reason: str) -> None:
    a, b = pair(category)
    frame = bytearray(b.frame(STATUS, A, 1.0) or b"")
    frame[-6] ^= 0x10  # a payload bit
    assert a.receive(bytes(frame), 1.0) is None
    assert a.rejected == {reason: 1}


def test_what_the_codec_or_the_end_refuses_is_counted_by_reason() -> None:
    a, b = pair(3)
    # A value the telegram cannot carry: nothing is sent.
    big = DoorCommand(
        train_id=70000, doa_l=False, doa_r=False, dmc_l=False, dmc_r=False, doc=False, dcc=False,
        psc=False, automatic=True, doors_locked=0,
    )  # fmt: skip
    assert b.frame(big, A, 1.0) is None and b.sent == 0
    assert len(b.rejected) == 1 and next(iter(b.rejected)).startswith("encode-")
    # A valid safety frame around bytes that are no telegram.
    assert a.receive(b.links.wrap(b"\xff\x00", A, 1.1), 1.1) is None
    assert any(r.startswith("codec-") for r in a.rejected)
    # A telegram this end does not take (a train end takes psd-status only).
    cmd = CbtcCommand(
        train_id=1,
        authority_m=100.0,
        gradient_permille=0.0,
        speed_limit_mps=10.0,
        report_time_s=1.0,
        delay_s=0.1,
    )
    assert a.receive(b.links.wrap(encode(cmd), A, 1.2), 1.2) is None
    assert a.rejected.get("unexpected-type") == 1


def test_a_key_is_for_category_3_only() -> None:
    with pytest.raises(LinkConfigError, match="CRC-32"):
        SafePeers(A, KEY, max_age_s=0.3, peers=lambda p: True, category=1)
    with pytest.raises(LinkConfigError, match="at least 16 bytes"):
        SafePeers(A, None, max_age_s=0.3, peers=lambda p: True, category=3)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=80), st.sampled_from([1, 2, 3]))
def test_any_bytes_are_refused_or_taken_never_raised(data: bytes, category: int) -> None:
    a, _ = pair(category)
    got = a.receive(data, 1.0)
    assert got is None or isinstance(got[1], PsdStatus)
    assert sum(a.rejected.values()) + a.delivered == 1
