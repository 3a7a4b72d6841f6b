"""The telegram codec (railstop.link.codec): reference bytes, round trips, every way a frame can be bad."""

from __future__ import annotations

import array
import binascii
import re
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railstop.errors import RailstopError, TelegramError
from railstop.link.codec import (
    LAYOUTS,
    SPEC_PAYLOAD_BYTES,
    TASC_FORM_TYPES,
    TYPES,
    CbtcCommand,
    CbtcReport,
    DoorCommand,
    Field,
    Layout,
    PsdStatus,
    TascBrakeCommand,
    TascDecel,
    TascDistance,
    TascIncreaseDecrease,
    TascInterval,
    TascPosition,
    TascRequiredDecel,
    TascSpeed,
    Telegram,
    TrackCircuitOccupancy,
    WccCommand,
    ZoneRelease,
    crc16,
    decode,
    describe,
    encode,
    from_fields,
    layout_markdown,
    layout_of,
    quantize,
    quantized,
)

ALL = list(LAYOUTS.values())
IDS = [layout.name for layout in ALL]
REASONS = {"short", "long", "unknown_type", "crc", "out_of_range", "bad_value", "malformed"}


def reason(data: Any) -> str:
    with pytest.raises(TelegramError) as info:
        decode(data)
    return info.value.reason


def encode_reason(msg: Telegram) -> tuple[str, str]:
    with pytest.raises(TelegramError) as info:
        encode(msg)
    return info.value.reason, str(info.value)


def with_crc(body: bytes) -> bytes:
    """A frame from a hand-built body; the CRC by the stdlib, whose check value is tested below."""
    return body + binascii.crc_hqx(body, 0xFFFF).to_bytes(2, "big")


# --------------------------------------------------------------------------
# Strategies from the layout table


def _field_strategies(f: Field) -> dict[str, st.SearchStrategy[Any]]:
    if f.kind == "flags":
        return {bit: st.booleans() for bit in f.bits}
    if f.kind == "enum":
        return {f.name: st.sampled_from([v for v, _ in (f.choices or {}).values()])}
    if f.kind == "int":
        return {f.name: st.integers(f.raw_min, f.raw_max)}
    cpu = f.counts_per_unit
    value = st.one_of(
        st.floats(f.min, f.max, allow_nan=False),
        st.integers(f.raw_min, f.raw_max).map(lambda r: r / cpu),  # extremes and exact wire values
        st.integers(f.raw_min, f.raw_max).map(lambda r: (r + 0.5) / cpu).filter(lambda v: v <= f.max),
    )
    return {f.name: st.one_of(st.none(), value) if f.absent is not None else value}


def messages(layout: Layout) -> st.SearchStrategy[Telegram]:
    parts: dict[str, st.SearchStrategy[Any]] = {}
    for f in layout.fields:
        parts.update(_field_strategies(f))
    return st.fixed_dictionaries(parts).map(lambda kw: layout.cls(**kw))


def sample(layout: Layout) -> Telegram:
    """A valid message of every type with no field at zero (so that a changed byte shows)."""
    kw: dict[str, Any] = {}
    for f in layout.fields:
        if f.kind == "flags":
            kw.update({bit: i % 2 == 0 for i, bit in enumerate(f.bits)})
        elif f.kind == "enum":
            kw[f.name] = next(iter((f.choices or {}).values()))[0]
        elif f.kind == "int":
            kw[f.name] = (f.raw_min + f.raw_max) // 2 or 1
        else:
            kw[f.name] = ((f.raw_min + f.raw_max) // 3 or 7) / f.counts_per_unit
    return layout.cls(**kw)


# --------------------------------------------------------------------------
# CRC and reference frames written out by hand from docs/telegrams.md


def test_crc16_ccitt_false_check_value() -> None:
    assert crc16(b"123456789") == 0x29B1


REFERENCES = [
    # type 96 | train 1234 | detector 02 | 0.700 m/s² = 700 = 02bc | CRC
    (TascRequiredDecel(train_id=0x1234, detector=2, required_mps2=0.7), "96 1234 02 02bc 85c1"),
    # type 21 | train 7 | 1200.500 m = 1200500 mm = 00125174 | 16.667 m/s = 411b | L = 01
    # | 3600.250 s = 3600250 ms = 0036ef7a | uncertainty 2.500 m = 2500 mm = 000009c4 | CRC
    (
        CbtcReport(
            train_id=7, position_m=1200.5, speed_mps=16.667, direction="L", time_s=3600.25, uncertainty_m=2.5
        ),
        "21 0007 00125174 411b 01 0036ef7a 000009c4 4eca",
    ),
    # type 41 | train 0102 | DOA-R (bit 1), DOC (4), PSC (6), automatic (7) = 1101 0010 = d2
    # | train doors 2..24 closed and locked, door 1 not = 00fffffe | CRC
    (
        DoorCommand(
            train_id=0x0102,
            doa_l=False,
            doa_r=True,
            dmc_l=False,
            dmc_r=False,
            doc=True,
            dcc=False,
            psc=True,
            automatic=True,
            doors_locked=0xFFFFFE,
        ),
        "41 0102 d2 00fffffe 0230",
    ),
    # type b1 | circuit 107 = 0000006b | -0.5 s = -5000 x 0.1 ms = ffffec78 | CRC
    (TrackCircuitOccupancy(circuit_id=107, gnss_time_s=-0.5), "b1 0000006b ffffec78 6342"),
    # type 95 | train 1 | detector 0 | decel absent = 8000 | distance 42.195 m = 42195 mm = 0000a4d3
    # | passage 12.345 s = 12345 ms = 00003039 | measured 13.000 s = 13000 ms = 000032c8 | CRC
    (
        TascDecel(
            train_id=1, detector=0, decel_mps2=None, distance_m=42.195, passage_s=12.345, measured_s=13.0
        ),
        "95 0001 00 8000 0000a4d3 00003039 000032c8 f1f7",
    ),
    # type 93 | train 0102 | detector 03 | interval 2.500 s = 2500 ms = 09c4
    # | passage 100.250 s = 100250 ms = 0001879a | position 1234.567 m = 1234567 mm = 0012d687
    # | distance -0.250 m (past the stopping point) = -250 mm = ffffff06
    # | measured 101.000 s = 101000 ms = 00018a88 | CRC
    (
        TascInterval(
            train_id=0x0102,
            detector=3,
            interval_s=2.5,
            passage_s=100.25,
            position_m=1234.567,
            distance_m=-0.25,
            measured_s=101.0,
        ),
        "93 0102 03 09c4 0001879a 0012d687 ffffff06 00018a88 723e",
    ),
    # type 18 | train 9 | detector 4 | decrease = -1 = ff | step 7 | CRC
    (TascIncreaseDecrease(train_id=9, detector=4, delta=-1, step=7), "18 0009 04 ff 07 4579"),
    # type a3 (P = 1: even parity) | train 0012 | operator 0007 | CRC
    (ZoneRelease(train_id=0x12, operator_id=7), "a3 0012 0007 885e"),
    # type c3 (group 4 number 3 = 100 0011, P = 1: even parity) | station 0002
    # | manual (bit 0), panel open (bit 1) = 03 | operator 0007 | CRC
    (
        WccCommand(station=2, manual=True, panel_open=True, panel_close=False, operator_id=7),
        "c3 0002 03 0007 ba1f",
    ),
]


@pytest.mark.parametrize(("msg", "text"), REFERENCES, ids=[m.TYPE for m, _ in REFERENCES])
def test_reference_frames_both_ways(msg: Telegram, text: str) -> None:
    frame = bytes.fromhex(text)
    assert encode(msg) == frame
    assert decode(frame) == msg


def test_type_codes_are_even_parity_and_two_bits_apart() -> None:
    codes = [layout.code for layout in ALL]
    assert len(set(codes)) == len(codes)
    for c in codes:
        assert bin(c).count("1") % 2 == 0
    for a in codes:
        for b in codes:
            if a != b:
                assert bin(a ^ b).count("1") >= 2


def test_tasc_forms_map_to_group_1_by_form_number() -> None:
    from railstop.wayside.tasc_unit import SignalForm

    assert set(TASC_FORM_TYPES) == {int(f) for f in SignalForm}
    for form in SignalForm:
        code = LAYOUTS[TASC_FORM_TYPES[form]].code
        assert code & 0x7F == 0x10 | int(form)


def test_speed_telegram_gives_the_passage_time_back() -> None:
    msg = decode(
        encode(
            TascSpeed(
                train_id=1, detector=3, speed_mps=4.2, distance_m=120.5, measured_s=100.25, passage_age_s=1.5
            )
        )
    )
    assert isinstance(msg, TascSpeed)
    assert msg.passage_s == pytest.approx(98.75)
    assert msg.distance_m == 120.5


# SPEC §1 para 92: the combination each of forms 1-5 carries after the train id and the detector,
# in wire order. Forms 1-3 carry the same three quantities (time between two detectors, position,
# distance), each with its own quantity first; form 4 the speed and the distance; form 5 the
# deceleration and the distance. None carries a required deceleration (the train computes it).
PARA_92 = {
    1: ("position_m", "distance_m", "interval_s", "passage_s", "measured_s"),
    2: ("distance_m", "position_m", "interval_s", "passage_s", "measured_s"),
    3: ("interval_s", "passage_s", "position_m", "distance_m", "measured_s"),
    4: ("speed_mps", "distance_m", "measured_s", "passage_age_s"),
    5: ("decel_mps2", "distance_m", "passage_s", "measured_s"),
}
PARA_92_PAYLOAD_BYTES = {1: 21, 2: 21, 3: 21, 4: 15, 5: 17}


@pytest.mark.parametrize("form", sorted(PARA_92))
def test_forms_1_to_5_carry_the_para_92_combinations(form: int) -> None:
    layout = LAYOUTS[TASC_FORM_TYPES[form]]
    assert tuple(f.name for f in layout.fields) == ("train_id", "detector", *PARA_92[form])
    assert layout.payload_size == PARA_92_PAYLOAD_BYTES[form]
    assert "distance_m" in PARA_92[form]
    assert "required_mps2" not in PARA_92[form]


def test_forms_1_to_3_carry_the_same_fields_in_their_own_order() -> None:
    """Every field has one wire type, resolution, range and absent code in all three forms."""

    def wire(f: Field) -> tuple[Any, ...]:
        return (f.code, f.unit, f.counts_per_unit, f.min, f.max, f.absent)

    by_name = [{f.name: f for f in LAYOUTS[TASC_FORM_TYPES[form]].fields} for form in (1, 2, 3)]
    assert set(by_name[0]) == set(by_name[1]) == set(by_name[2])
    for name in by_name[0]:
        assert wire(by_name[0][name]) == wire(by_name[1][name]) == wire(by_name[2][name]), name
    orders = [tuple(f.name for f in LAYOUTS[TASC_FORM_TYPES[form]].fields) for form in (1, 2, 3)]
    assert len(set(orders)) == 3
    # The distance of forms 4 and 5 is the same field too.
    for form in (4, 5):
        fields_ = {f.name: f for f in LAYOUTS[TASC_FORM_TYPES[form]].fields}
        assert wire(fields_["distance_m"]) == wire(by_name[0]["distance_m"])


# --------------------------------------------------------------------------
# Round trips


@pytest.mark.parametrize("layout", ALL, ids=IDS)
@settings(max_examples=100, deadline=None)
@given(data=st.data())
def test_round_trip_equals_quantised(layout: Layout, data: st.DataObject) -> None:
    msg = data.draw(messages(layout))
    frame = encode(msg)
    assert len(frame) == layout.frame_size == layout.payload_size + 3
    assert frame[0] == layout.code
    got = decode(frame)
    assert got == quantized(msg)
    # The vectorised quantiser gives what the wire carries, field by field.
    for f in layout.fields:
        if f.kind == "fixed":
            sent = getattr(msg, f.name)
            arr = quantize(layout.name, f.name, np.array([np.nan if sent is None else sent]))
            want = getattr(got, f.name)
            if want is None:
                assert np.isnan(arr[0])
            else:
                assert arr[0] == want
                assert quantize(layout.cls, f.name, sent) == want
    # A decoded telegram re-encodes to the same bytes.
    assert encode(got) == frame


@pytest.mark.parametrize("layout", ALL, ids=IDS)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_any_frame_with_valid_crc_decodes_canonically_or_names_a_field(
    layout: Layout, data: st.DataObject
) -> None:
    """Any wire integers at all: either a telegram that re-encodes to the same bytes, or a field error."""
    raws = [data.draw(st.integers(*_code_range(f.code))) for f in layout.fields]
    frame = with_crc(bytes((layout.code,)) + layout.packer.pack(*raws))
    try:
        msg = decode(frame)
    except TelegramError as exc:
        assert exc.reason in ("out_of_range", "bad_value")
        assert any(f"{layout.name}.{f.name}" in str(exc) for f in layout.fields)
        return
    assert encode(msg) == frame


def _code_range(code: str) -> tuple[int, int]:
    bits = struct.calcsize(code) * 8
    return (0, (1 << bits) - 1) if code.isupper() else (-(1 << (bits - 1)), (1 << (bits - 1)) - 1)


def test_quantize_arrays_keep_nan_and_round_half_to_even() -> None:
    got = quantize("tasc-required-decel", "required_mps2", np.array([0.7004, 0.0005, 0.0015, np.nan]))
    np.testing.assert_array_equal(got, [0.7, 0.0, 0.002, np.nan])
    assert quantize("tc-occupancy", "gnss_time_s", 1.23456) == 1.2346
    assert quantize("tasc-brake-command", "notch", 3) == 3  # not fixed-point: unchanged
    with pytest.raises(TelegramError, match="no field 'speed'"):
        quantize("cbtc-report", "speed", 1.0)


# --------------------------------------------------------------------------
# Bad frames


@pytest.mark.parametrize("layout", ALL, ids=IDS)
def test_every_truncation_is_short_and_an_extra_byte_is_long(layout: Layout) -> None:
    frame = encode(sample(layout))
    for k in range(len(frame)):
        assert reason(frame[:k]) == "short", k
    for extra in (b"\x00", b"\xff", frame[-2:]):
        assert reason(frame + extra) == "long"


@pytest.mark.parametrize("layout", ALL, ids=IDS)
def test_every_single_bit_flip_is_rejected_with_its_exact_reason(layout: Layout) -> None:
    """Type byte: even-parity codes make any single flip an unknown type; anywhere else the CRC catches it."""
    frame = encode(sample(layout))
    for bit in range(8 * len(frame)):
        bad = bytearray(frame)
        bad[bit // 8] ^= 0x80 >> (bit % 8)
        assert reason(bytes(bad)) == ("unknown_type" if bit < 8 else "crc"), bit


def test_unknown_type_bytes() -> None:
    known = {layout.code for layout in ALL}
    for b in range(256):
        if b not in known:
            assert reason(bytes((b,)) + bytes(16)) == "unknown_type"
    assert reason(b"\x00") == "unknown_type"
    assert reason(b"") == "short"


@pytest.mark.parametrize(
    ("msg", "field"),
    [
        (TascRequiredDecel(train_id=1, detector=0, required_mps2=10.001), "required_mps2"),
        (TascRequiredDecel(train_id=1, detector=0, required_mps2=-0.001), "required_mps2"),
        (TascRequiredDecel(train_id=1, detector=0, required_mps2=float("nan")), "required_mps2"),
        (TascRequiredDecel(train_id=1, detector=0, required_mps2=float("inf")), "required_mps2"),
        (TascRequiredDecel(train_id=1, detector=64, required_mps2=0.5), "detector"),
        (TascRequiredDecel(train_id=65536, detector=0, required_mps2=0.5), "train_id"),
        (TascRequiredDecel(train_id=-1, detector=0, required_mps2=0.5), "train_id"),
        (TascBrakeCommand(train_id=1, detector=0, notch=8, duty=0.5), "notch"),
        (TascBrakeCommand(train_id=1, detector=0, notch=7, duty=1.00005001), "duty"),
        (
            TascSpeed(
                train_id=1, detector=0, speed_mps=-32.768, distance_m=10.0, measured_s=0.0, passage_age_s=0.0
            ),
            "speed_mps",
        ),
        (
            TascSpeed(
                train_id=1,
                detector=0,
                speed_mps=3.0,
                distance_m=100_000.001,
                measured_s=0.0,
                passage_age_s=0.0,
            ),
            "distance_m",
        ),
        (
            TascPosition(
                train_id=1,
                detector=1,
                position_m=-0.001,
                distance_m=10.0,
                interval_s=None,
                passage_s=1.0,
                measured_s=1.0,
            ),
            "position_m",
        ),
        (
            TascDistance(
                train_id=1,
                detector=1,
                distance_m=-100_000.001,
                position_m=0.0,
                interval_s=2.0,
                passage_s=1.0,
                measured_s=1.0,
            ),
            "distance_m",
        ),
        (
            TascInterval(
                train_id=1,
                detector=1,
                interval_s=65.535,
                passage_s=1.0,
                position_m=0.0,
                distance_m=10.0,
                measured_s=1.0,
            ),
            "interval_s",
        ),
        (
            TascInterval(
                train_id=1,
                detector=1,
                interval_s=1.0,
                passage_s=1.0,
                position_m=0.0,
                distance_m=10.0,
                measured_s=float("nan"),
            ),
            "measured_s",
        ),
        (
            TascDecel(
                train_id=1,
                detector=1,
                decel_mps2=float("-inf"),
                distance_m=10.0,
                passage_s=1.0,
                measured_s=1.0,
            ),
            "decel_mps2",
        ),
        (CbtcReport(train_id=1, position_m=-0.001, speed_mps=0.0, direction="R", time_s=0.0), "position_m"),
        (CbtcReport(train_id=1, position_m=0.0, speed_mps=0.0, direction="R", time_s=4294967.296), "time_s"),
        (
            CbtcCommand(
                train_id=1, authority_m=10.0, gradient_permille=100.06, speed_limit_mps=1.0, report_time_s=0.0
            ),
            "gradient_permille",
        ),
        (TrackCircuitOccupancy(circuit_id=2**32, gnss_time_s=0.0), "circuit_id"),
        (TrackCircuitOccupancy(circuit_id=1, gnss_time_s=1e300), "gnss_time_s"),
        (TascIncreaseDecrease(train_id=1, detector=0, delta=1, step=256), "step"),  # the wayside wraps it
    ],
)
def test_encode_out_of_range_names_field_and_value(msg: Telegram, field: str) -> None:
    why, text = encode_reason(msg)
    assert why == "out_of_range"
    assert f"{msg.TYPE}.{field}=" in text


@pytest.mark.parametrize(
    ("msg", "field"),
    [
        (TascIncreaseDecrease(train_id=1, detector=0, delta=2, step=1), "delta"),
        (TascIncreaseDecrease(train_id=1, detector=0, delta=True, step=1), "delta"),  # a bool is not -1/0/+1
        (TascIncreaseDecrease(train_id=1, detector=0, delta=1.0, step=1), "delta"),  # type: ignore[arg-type]
        (CbtcReport(train_id=1, position_m=0.0, speed_mps=0.0, direction="X", time_s=0.0), "direction"),
        (TascRequiredDecel(train_id=1, detector=0, required_mps2=None), "required_mps2"),  # type: ignore[arg-type]
        (
            TascDecel(train_id=1, detector=1, decel_mps2=0.5, distance_m=None, passage_s=1.0, measured_s=1.0),  # type: ignore[arg-type]
            "distance_m",
        ),  # the distance has no absent code: a form-5 telegram always carries it
        (TascRequiredDecel(train_id=1, detector=0, required_mps2="0.5"), "required_mps2"),  # type: ignore[arg-type]
        (TascRequiredDecel(train_id=1.0, detector=0, required_mps2=0.5), "train_id"),  # type: ignore[arg-type]
        (TascRequiredDecel(train_id=True, detector=0, required_mps2=0.5), "train_id"),
        (
            PsdStatus(
                train_id=1,
                psc=1,
                psd_closed_locked=False,
                start_enable=False,
                manual=False,
                fault=False,
                psd_open=0,
            ),
            "psc",
        ),  # type: ignore[arg-type]
    ],
)
def test_encode_bad_value_names_field(msg: Telegram, field: str) -> None:
    why, text = encode_reason(msg)
    assert why == "bad_value"
    assert f"{msg.TYPE}.{field}" in text


def test_encode_accepts_numpy_scalars() -> None:
    msg = TascRequiredDecel(train_id=np.int64(3), detector=np.int16(1), required_mps2=np.float64(0.25))
    assert decode(encode(msg)) == TascRequiredDecel(train_id=3, detector=1, required_mps2=0.25)


def test_encode_unknown_class() -> None:
    class NotATelegram(Telegram):
        TYPE = "nope"

    with pytest.raises(TelegramError) as info:
        encode(NotATelegram())
    assert info.value.reason == "unknown_type"


@pytest.mark.parametrize(
    ("body", "why", "field"),
    [
        ("96 0001 00 2711", "out_of_range", "required_mps2"),  # 10.001 m/s²
        ("96 0001 40 0001", "out_of_range", "detector"),  # detector 64
        ("17 0001 00 08 ffff", "out_of_range", "notch"),  # B8 does not exist
        ("17 0001 00 07 2711", "out_of_range", "duty"),  # 1.0001
        ("14 0001 00 8000 00000000 00000000 0000", "out_of_range", "speed_mps"),  # -32.768 m/s
        ("12 0001 00 05f5e101 00000000 ffff 00000000 00000000", "out_of_range", "distance_m"),  # 100.001 km
        ("22 0001 00000000 03e9 0000 00000000 0000", "out_of_range", "gradient_permille"),  # 100.1 ‰
        ("18 0001 00 02 01", "bad_value", "delta"),
        ("18 0001 00 80 01", "bad_value", "delta"),
        ("21 0001 00000000 0000 02 00000000 00000000", "bad_value", "direction"),
        ("42 0001 20 00000000", "bad_value", "status"),  # bit 5 undefined
        ("42 0001 00 01000000", "out_of_range", "psd_open"),  # a 25th unit
    ],
)
def test_decode_field_errors(body: str, why: str, field: str) -> None:
    frame = with_crc(bytes.fromhex(body))
    with pytest.raises(TelegramError) as info:
        decode(frame)
    assert info.value.reason == why
    assert field in str(info.value)


def test_decode_absent_values() -> None:
    # form 3 before the second detector: interval absent | passage 0.1 s | 1000 m | 250 m | 0.1 s
    msg = decode(with_crc(bytes.fromhex("93 0002 00 ffff 00000064 000f4240 0003d090 00000064")))
    assert msg == TascInterval(
        train_id=2,
        detector=0,
        interval_s=None,
        passage_s=0.1,
        position_m=1000.0,
        distance_m=250.0,
        measured_s=0.1,
    )
    # form 1, the same: 1000 m | 250 m | interval absent | passage 0.1 s | 0.1 s
    msg = decode(with_crc(bytes.fromhex("11 0002 00 000f4240 0003d090 ffff 00000064 00000064")))
    assert msg == TascPosition(
        train_id=2,
        detector=0,
        position_m=1000.0,
        distance_m=250.0,
        interval_s=None,
        passage_s=0.1,
        measured_s=0.1,
    )
    msg = decode(with_crc(bytes.fromhex("17 0002 01 05 ffff")))
    assert msg == TascBrakeCommand(train_id=2, detector=1, notch=5, duty=None)


def test_input_kinds() -> None:
    frame = encode(sample(LAYOUTS[TascRequiredDecel]))
    want = decode(frame)
    assert decode(bytearray(frame)) == want
    assert decode(memoryview(frame)) == want
    assert decode(memoryview(b"xx" + frame)[2:]) == want
    assert decode(memoryview(array.array("B", frame))) == want
    released = memoryview(frame)
    released.release()
    assert reason(released) == "malformed"
    for bad in (None, frame.hex(), 3, list(frame), [frame]):
        assert reason(bad) == "malformed"


@settings(max_examples=1000, deadline=None)
@given(st.binary(max_size=40))
def test_random_bytes_only_telegram_errors(data: bytes) -> None:
    try:
        msg = decode(data)
    except TelegramError as exc:
        assert exc.reason in REASONS
        assert isinstance(exc, RailstopError)
    else:
        assert encode(msg) == data


@settings(max_examples=500, deadline=None)
@given(
    st.sampled_from(ALL).flatmap(
        lambda lay: st.binary(min_size=0, max_size=lay.frame_size + 2).map(
            lambda rest: bytes((lay.code,)) + rest
        )
    )
)
def test_random_bytes_behind_a_valid_type(data: bytes) -> None:
    try:
        decode(data)
    except TelegramError as exc:
        assert exc.reason in REASONS - {"unknown_type", "malformed"}


# --------------------------------------------------------------------------
# describe, from_fields, documentation


def test_describe_lists_every_field_with_units() -> None:
    rows = dict(
        describe(
            CbtcReport(
                train_id=7, position_m=1200.5, speed_mps=16.667, direction="L", time_s=3.0, uncertainty_m=2.5
            )
        )
    )
    assert rows == {
        "train_id": "7",
        "position_m": "1200.500 m",
        "speed_mps": "16.667 m/s",
        "direction": "L (-chainage, down)",
        "time_s": "3.000 s",
        "uncertainty_m": "2.500 m",
    }
    rows = dict(
        describe(
            TascDecel(
                train_id=1, detector=0, decel_mps2=None, distance_m=-0.25, passage_s=1.0, measured_s=2.0
            )
        )
    )
    assert rows["decel_mps2"] == "absent"
    assert rows["distance_m"] == "-0.250 m"
    assert list(rows) == ["train_id", "detector", "decel_mps2", "distance_m", "passage_s", "measured_s"]
    rows = dict(describe(TascIncreaseDecrease(train_id=1, detector=0, delta=1, step=3)))
    assert rows["delta"] == "+1 (increase)"
    assert rows["step"] == "3"
    door = sample(LAYOUTS[DoorCommand])
    assert [name for name, _ in describe(door)] == [
        "train_id",
        "doa_l",
        "doa_r",
        "dmc_l",
        "dmc_r",
        "doc",
        "dcc",
        "psc",
        "automatic",
        "doors_locked",
    ]


@pytest.mark.parametrize("layout", ALL, ids=IDS)
@settings(max_examples=30, deadline=None)
@given(data=st.data())
def test_from_fields_parses_what_it_is_given(layout: Layout, data: st.DataObject) -> None:
    msg = data.draw(messages(layout))

    def text(v: Any) -> str:
        return "none" if v is None else ("1" if v is True else "0" if v is False else str(v))

    values = {a: text(getattr(msg, a)) for f in layout.fields for a in f.attributes}
    assert from_fields(layout.name, values) == msg


@pytest.mark.parametrize(
    ("type_name", "values", "why", "needle"),
    [
        ("tasc-foo", {}, "unknown_type", "tasc-foo"),
        (
            "tasc-required-decel",
            {"train_id": "1", "detector": "0"},
            "bad_value",
            "missing field 'required_mps2'",
        ),
        (
            "tasc-required-decel",
            {"train_id": "1", "detector": "0", "required_mps2": "0.5", "speed": "3"},
            "bad_value",
            "unknown field 'speed'",
        ),
        (
            "tasc-required-decel",
            {"train_id": "1", "detector": "0", "required_mps2": "fast"},
            "bad_value",
            "required_mps2='fast'",
        ),
        (
            "tasc-required-decel",
            {"train_id": "x", "detector": "0", "required_mps2": "1"},
            "bad_value",
            "train_id='x'",
        ),
        (
            "tasc-required-decel",
            {"train_id": "1", "detector": "0", "required_mps2": "11"},
            "out_of_range",
            "11",
        ),
        (
            "tasc-increase-decrease",
            {"train_id": "1", "detector": "0", "delta": "up", "step": "1"},
            "bad_value",
            "delta='up'",
        ),
        (
            "psd-status",
            {
                "train_id": "1",
                "psc": "maybe",
                "psd_closed_locked": "1",
                "start_enable": "0",
                "manual": "0",
                "fault": "0",
                "psd_open": "0",
            },
            "bad_value",
            "psc='maybe'",
        ),
    ],
)
def test_from_fields_errors(type_name: str, values: dict[str, str], why: str, needle: str) -> None:
    with pytest.raises(TelegramError) as info:
        from_fields(type_name, values)
    assert info.value.reason == why
    assert needle in str(info.value)


def test_types_and_layout_lookup() -> None:
    assert set(TYPES) == {layout.name for layout in ALL}
    assert layout_of("cbtc-command") is LAYOUTS[CbtcCommand]
    assert layout_of(CbtcCommand) is LAYOUTS[CbtcCommand]
    with pytest.raises(TelegramError):
        layout_of("nope")


def test_loop_telegrams_fit_about_ten_bytes() -> None:
    """SPEC §5: ~10 bytes on the loop / transponder. Only forms 1-5 are longer (they carry a
    combination of SPEC §1 para 92), and every longer one says why in its note."""
    combinations = {TASC_FORM_TYPES[form] for form in PARA_92}
    for layout in ALL:
        if layout.medium != "radio":
            assert (layout.payload_size > SPEC_PAYLOAD_BYTES) == bool(layout.note), layout.name
            if layout.cls not in combinations:
                assert layout.payload_size <= SPEC_PAYLOAD_BYTES, layout.name
            else:
                assert "para 92" in layout.note, layout.name


def test_docs_telegrams_md_is_up_to_date() -> None:
    doc = (Path(__file__).resolve().parents[2] / "docs" / "telegrams.md").read_text(encoding="utf-8")
    found = re.search(r"<!-- BEGIN layout_markdown\(\) -->\n(.*)<!-- END layout_markdown\(\) -->", doc, re.S)
    assert found, "docs/telegrams.md lacks the generated block"
    assert found.group(1) == layout_markdown(), "regenerate with railstop.link.codec.update_doc"
