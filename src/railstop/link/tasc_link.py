"""The wayside -> train braking telegrams as bytes (SPEC §1 claim 3 forms, SPEC §5 media).

The wayside TASC unit produces its telegrams as arrays over runs
(:class:`~railstop.wayside.tasc_unit.TascTelegrams`). On the air each one is
a codec telegram (:mod:`railstop.link.codec`: type, fixed-point payload,
CRC-16) inside an EN 50159 safety frame (:mod:`railstop.link.safety`:
ids, sequence number, timestamp, MAC), carried by a medium
(:mod:`railstop.link.channel`).

Two drivers, one result (DESIGN rule 1):

* every driver quantises the telegrams exactly as the codec does
  (:func:`quantize_telegrams`), so a value that went through bytes equals
  the value the campaign uses;
* the detailed stop (n = 1) really encodes, wraps, corrupts (when the draw
  says so), checks and decodes every frame (:class:`ByteLink`); the campaign
  takes the same per-frame decisions (loss, corruption, delay, staleness)
  from the same random streams and channel functions without building bytes.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railstop.errors import SimulationError
from railstop.link.codec import (
    TASC_FORM_TYPES,
    TascBrakeCommand,
    TascDecel,
    TascDistance,
    TascEmergencyStop,
    TascIncreaseDecrease,
    TascInterval,
    TascPosition,
    TascRequiredDecel,
    TascSpeed,
    Telegram,
    decode,
    encode,
    layout_of,
    quantize,
)
from railstop.link.safety import Delivered, SafeReceiver, SafeSender, frame_size, link_key
from railstop.messages import TEL_FIELDS
from railstop.wayside.tasc_unit import (
    CR_COMMAND,
    CR_DECEL,
    CR_DELTA,
    CR_DETECTOR,
    CR_DISTANCE,
    CR_EFFECT,
    CR_EMERGENCY,
    CR_GAIN,
    CR_NOTCH,
    CR_PASSAGE,
    CR_REQUIRED,
    CR_SPEED,
    CR_T,
    SignalForm,
    TascTelegrams,
    finite_or_none,
)

FloatArray = NDArray[np.float64]

WAYSIDE_ID = 0x0100  # the station's wayside TASC unit
TRAIN_ID = 0x0001  # the train (one per run in a campaign: its own link)
# Demonstration master key. A deployment loads its link keys from its key
# management; a simulation only needs every run to use the same one.
_DEMO_MASTER = hashlib.sha256(b"railstop demonstration TASC link master key").digest()

# SPEC §1 claim 3: the array fields each form puts on the air (the rest is NaN); forms 1-5 carry
# the combinations of para 92 (railstop.link.codec).
_COMBINATION_1 = ("position_m", "distance_m", "interval_s", "passage_s", "measured_s")
CARRIED: dict[SignalForm, tuple[str, ...]] = {
    SignalForm.POSITION: _COMBINATION_1,
    SignalForm.DISTANCE: _COMBINATION_1,
    SignalForm.INTERVAL_TIME: _COMBINATION_1,
    SignalForm.SPEED: ("speed_mps", "distance_m", "measured_s", "passage_s"),
    SignalForm.DECELERATION: ("decel_mps2", "distance_m", "passage_s", "measured_s"),
    SignalForm.REQUIRED_DECELERATION: ("required_mps2",),
    SignalForm.BRAKE_COMMAND: ("notch", "duty"),
    SignalForm.INCREASE_DECREASE: ("delta", "step"),
}
# The telegram's float fields (the others are integers: the detector, the notch, the step, the
# emergency flag), in the telegram vector's order.
_INT_FIELDS = ("detector", "notch", "delta", "emergency", "step")
# ... of which a form carries these or not (0 where it does not; an emergency stop carries none).
_FORM_INT_FIELDS = ("notch", "delta", "step")
_FLOAT_FIELDS = tuple(f for f in TEL_FIELDS if f not in _INT_FIELDS)


def frame_bytes(form: SignalForm, category: int) -> int:
    """Bytes on the medium of one braking telegram of ``form`` (codec frame in a safety frame)."""
    return frame_size(layout_of(TASC_FORM_TYPES[int(form)]).frame_size, category)


def quantize_telegrams(tele: TascTelegrams) -> TascTelegrams:
    """What the train can receive: carried fields rounded to the codec's resolution, the rest NaN.

    Equal, field by field, to :func:`from_message` of the decoded bytes (a
    test proves it), so the campaign and the detailed stop see the same numbers.
    """
    form = SignalForm(tele.form)
    kind = TASC_FORM_TYPES[int(form)]
    carried = CARRIED[form]
    changes: dict[str, object] = {}
    for name in _FLOAT_FIELDS:
        if name not in carried:
            changes[name] = np.full(tele.mask.shape, np.nan)
    for name in _FORM_INT_FIELDS:
        if name not in carried:
            changes[name] = np.zeros(tele.mask.shape, dtype=np.int64)
    if form == SignalForm.SPEED:
        # Form 4 carries the passage as its age at the measurement time.
        measured = quantize(kind, "measured_s", tele.measured_s)
        # Never negative (the kernel's quantize_telegram_1 gives the reason): the age is unsigned.
        age = np.maximum(quantize(kind, "passage_age_s", tele.measured_s - tele.passage_s), 0.0)
        changes["measured_s"] = measured
        changes["speed_mps"] = quantize(kind, "speed_mps", tele.speed_mps)
        changes["distance_m"] = quantize(kind, "distance_m", tele.distance_m)
        changes["passage_s"] = measured - age
    else:
        for name in carried:
            if name in _FLOAT_FIELDS:
                changes[name] = quantize(kind, name, getattr(tele, name))
    out = replace(tele, **changes)  # type: ignore[arg-type]
    eb = np.asarray(tele.emergency) != 0
    if eb.any():  # an emergency-stop telegram carries the detector only
        blank: dict[str, object] = {n: np.where(eb, np.nan, getattr(out, n)) for n in _FLOAT_FIELDS}
        for name in _FORM_INT_FIELDS:
            blank[name] = np.where(eb, 0, getattr(out, name))
        out = replace(out, **blank)  # type: ignore[arg-type]
    return out


def to_message(tele: TascTelegrams, row: int, train_id: int = TRAIN_ID) -> Telegram:
    """The codec message of run ``row`` of a (quantised) telegram."""
    form = SignalForm(tele.form)
    det = int(tele.detector[row])
    if int(tele.emergency[row]):
        return TascEmergencyStop(train_id=train_id, detector=det)
    if form in (SignalForm.POSITION, SignalForm.DISTANCE, SignalForm.INTERVAL_TIME):
        combination = {
            "train_id": train_id,
            "detector": det,
            "position_m": float(tele.position_m[row]),
            "distance_m": float(tele.distance_m[row]),
            "interval_s": finite_or_none(tele.interval_s[row]),
            "passage_s": float(tele.passage_s[row]),
            "measured_s": float(tele.measured_s[row]),
        }
        if form == SignalForm.POSITION:
            return TascPosition(**combination)  # type: ignore[arg-type]
        if form == SignalForm.DISTANCE:
            return TascDistance(**combination)  # type: ignore[arg-type]
        return TascInterval(**combination)  # type: ignore[arg-type]
    if form == SignalForm.SPEED:
        measured = float(tele.measured_s[row])
        return TascSpeed(
            train_id=train_id,
            detector=det,
            speed_mps=float(tele.speed_mps[row]),
            distance_m=float(tele.distance_m[row]),
            measured_s=measured,
            passage_age_s=measured - float(tele.passage_s[row]),
        )
    if form == SignalForm.DECELERATION:
        return TascDecel(
            train_id=train_id,
            detector=det,
            decel_mps2=finite_or_none(tele.decel_mps2[row]),
            distance_m=float(tele.distance_m[row]),
            passage_s=float(tele.passage_s[row]),
            measured_s=float(tele.measured_s[row]),
        )
    if form == SignalForm.REQUIRED_DECELERATION:
        return TascRequiredDecel(
            train_id=train_id, detector=det, required_mps2=float(tele.required_mps2[row])
        )
    if form == SignalForm.BRAKE_COMMAND:
        return TascBrakeCommand(
            train_id=train_id, detector=det, notch=int(tele.notch[row]), duty=finite_or_none(tele.duty[row])
        )
    return TascIncreaseDecrease(
        train_id=train_id, detector=det, delta=int(tele.delta[row]), step=int(tele.step[row])
    )


def from_message(msg: Telegram, form: SignalForm) -> TascTelegrams:
    """A one-run telegram array from a decoded message (fields the form does not carry are NaN)."""
    nan = np.full(1, np.nan)

    def val(name: str) -> FloatArray:
        v = getattr(msg, name, None)
        return np.full(1, np.nan if v is None else float(v))

    passage = val("passage_s")
    emergency = isinstance(msg, TascEmergencyStop)
    if form == SignalForm.SPEED and not emergency:
        passage = np.full(1, msg.passage_s)  # type: ignore[attr-defined]
    return TascTelegrams(
        form=form,
        mask=np.ones(1, dtype=bool),
        detector=np.full(1, int(msg.detector), dtype=np.int64),  # type: ignore[attr-defined]
        passage_s=passage,
        measured_s=val("measured_s"),
        position_m=val("position_m"),
        distance_m=val("distance_m"),
        interval_s=val("interval_s"),
        speed_mps=val("speed_mps"),
        decel_mps2=val("decel_mps2"),
        required_mps2=val("required_mps2"),
        notch=np.full(1, int(getattr(msg, "notch", 0)), dtype=np.int64),  # 0 when not carried
        duty=val("duty") if form == SignalForm.BRAKE_COMMAND else nan,
        delta=np.full(1, int(getattr(msg, "delta", 0)), dtype=np.int64),
        emergency=np.full(1, int(emergency), dtype=np.int64),
        step=np.full(1, int(getattr(msg, "step", 0)), dtype=np.int64),
    )


@dataclass(slots=True)
class ByteLink:
    """The braking telegrams of one run as real frames: codec + EN 50159 safety layer.

    ``transmit`` wraps a codec frame in the safety frame of an attempt (flipping
    one bit when the attempt's draw says it is corrupted); ``arrive`` hands
    frames that have arrived to the safety receiver and returns the decoded
    telegrams it delivered. Rejections are counted by reason (``receiver.counts``).
    """

    category: int
    max_age_s: float
    sender: SafeSender = field(init=False)
    receiver: SafeReceiver = field(init=False)
    in_flight: list[tuple[float, bytes, bool]] = field(default_factory=list)  # (arrival, frame, genuine)
    frames_sent: int = 0
    # The codec's decoding of each payload delivered so far: the cyclic repeats carry the same
    # payload in new safety frames, and decoding is a pure function of the bytes.
    decoded: dict[bytes, Telegram] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # Category 3: the key of the wayside -> train direction, known to both ends.
        key = link_key(_DEMO_MASTER, WAYSIDE_ID, TRAIN_ID) if self.category == 3 else None
        self.sender = SafeSender(WAYSIDE_ID, TRAIN_ID, key=key, category=self.category)
        self.receiver = SafeReceiver(
            TRAIN_ID,
            WAYSIDE_ID,
            key=key,
            category=self.category,
            max_age_s=self.max_age_s,
            timeout_s=1e9,  # the TASC zone's supervision is the onboard unit's, not modelled here
        )

    def transmit(self, payload: bytes, now_s: float, arrival_s: float, corrupt_bit: float | None) -> None:
        """One attempt of the codec frame ``payload`` sent at ``now_s`` (a cyclic repeat sends the
        same payload in a new safety frame); ``corrupt_bit`` in [0, 1) picks the flipped bit
        (None: intact)."""
        frame = bytearray(self.sender.wrap(payload, now_s))
        self.frames_sent += 1
        if corrupt_bit is not None:
            bit = min(int(corrupt_bit * 8 * len(frame)), 8 * len(frame) - 1)
            frame[bit // 8] ^= 1 << (bit % 8)
        self.in_flight.append((arrival_s, bytes(frame), corrupt_bit is None))

    def drop_genuine(self) -> None:
        """A newer telegram supersedes the one in flight: the wayside sends only its latest."""
        self.in_flight = [f for f in self.in_flight if not f[2]]

    def arrive(self, now_s: float) -> list[Telegram]:
        """Frames arrived by ``now_s`` go through the safety receiver; the decoded telegrams of
        those it delivered, in order."""
        got: list[Telegram] = []
        keep: list[tuple[float, bytes, bool]] = []
        for arrival, frame, genuine in self.in_flight:
            if arrival > now_s + 1e-9:
                keep.append((arrival, frame, genuine))
                continue
            verdict = self.receiver.accept(frame, now_s)
            if isinstance(verdict, Delivered):
                msg = self.decoded.get(verdict.payload)
                if msg is None:
                    msg = self.decoded[verdict.payload] = decode(verdict.payload)
                got.append(msg)
        self.in_flight = keep
        return got


# --------------------------------------------------------------------------
# The command records (SPEC §1 claims 8, 20): the database's and the office's, from the stop model's
# rows, for the simulators and the live stations alike.


def command_records(rows: FloatArray, form: SignalForm, sends: FloatArray) -> list[dict[str, Any]]:
    """The command records of the detailed stop (SPEC §1 claims 8, 20), as the database stores them.

    ``rows`` are the wayside unit's command records (``CR_*``, and the step each was sent in),
    ``sends`` the telegram vector the kernel put on the air for each (``TEL_*``, one row per
    record). Claim 20 keeps the history of every computed command; besides its inputs and
    what the unit computed, each record carries what actually went on the air: the codec
    type (``telegram_type``) and the decoded message's fields (``telegram``), encoded and
    decoded as ``check_byte_link`` does, so at the wire's resolution. Signal forms 1-5 carry
    measurements only: their computed notch never went to the train, their telegram says so.
    The ATO controllers send nothing and have no records.
    """
    if len(rows) != len(sends):
        raise SimulationError(f"{len(rows)} command records but {len(sends)} telegrams recorded")
    out = []
    for r, sent in zip(rows, sends, strict=True):
        air = encode(to_message(telegram_of(sent, form), 0))
        message = decode(air)  # at the wire's resolution
        out.append(
            {
                "run": 0,
                "t_s": float(r[CR_T]),
                "form": int(form),
                "detector": int(r[CR_DETECTOR]),
                "passage_s": float(r[CR_PASSAGE]),
                "distance_m": float(r[CR_DISTANCE]),
                "speed_mps": float(r[CR_SPEED]),
                "measured_decel_mps2": finite_or_none(r[CR_DECEL]),
                "gain": float(r[CR_GAIN]),
                "required_decel_mps2": finite_or_none(r[CR_REQUIRED]),
                "command_decel_mps2": float(r[CR_COMMAND]),
                "notch": int(r[CR_NOTCH]),
                "delta": int(r[CR_DELTA]),
                "effect_s": float(r[CR_EFFECT]),
                # DESIGN rule 10: the wayside's overrun guard made this an emergency-stop telegram.
                "emergency": bool(r[CR_EMERGENCY]),
                # SPEC §1 claim 20: what went on the air for this command.
                "telegram_type": message.TYPE,
                "telegram": {
                    attr: getattr(message, attr) for f in layout_of(message).fields for attr in f.attributes
                },
                "air": air.hex(),  # the codec frame itself
            }
        )
    return out


#: A command's fields in the office's record (SPEC §1 claims 7, 20; short names: a report is at
#: most 255 bytes on the link) and the command record's names: when it was computed, from which
#: detector's passage (``age``: how long before), the distance to the stop, the radar's speed, the
#: measured and required deceleration, the correction gain, the command, its notch / step, when it
#: takes effect (``eff``: how long after), the emergency-stop flag.
OFFICE_COMMAND_FIELDS: dict[str, str] = {
    "t": "t_s",
    "det": "detector",
    "age": "passage_s",
    "dist": "distance_m",
    "v": "speed_mps",
    "a_meas": "measured_decel_mps2",
    "a_req": "required_decel_mps2",
    "gain": "gain",
    "a_cmd": "command_decel_mps2",
    "notch": "notch",
    "delta": "delta",
    "eff": "effect_s",
    "eb": "emergency",
}


def office_command(station: str, train: int, rec: Mapping[str, Any]) -> dict[str, Any]:
    """A command record (:func:`command_records`) as the office stores it (SPEC §1 claims 7, 20):
    the station (``st``) and train (``tr``), the command's inputs and what the unit computed
    (:data:`OFFICE_COMMAND_FIELDS`, at millimetre / millisecond resolution; the passage as its age
    at the command, the effect as its delay after it) and the telegram as it went on the air
    (``air``: the codec frame in hex). The live stations and the simulators send the same."""
    out: dict[str, Any] = {"st": station, "tr": train}
    values = dict(rec)
    values["passage_s"] = values["t_s"] - values["passage_s"]
    values["effect_s"] = values["effect_s"] - values["t_s"]
    for short, name in OFFICE_COMMAND_FIELDS.items():
        v = values[name]
        if isinstance(v, float):
            v = round(v, 3) if math.isfinite(v) else None
        out[short] = v
    out["air"] = values["air"]
    return out


def telegram_of(row: FloatArray, form: SignalForm) -> TascTelegrams:
    """One kernel telegram vector as a one-run telegram array (the codec's input)."""
    values: dict[str, Any] = {}
    for j, name in enumerate(TEL_FIELDS):
        if name in _INT_FIELDS:
            values[name] = np.full(1, int(row[j]), dtype=np.int64)
        else:
            values[name] = np.full(1, row[j])
    return TascTelegrams(form=form, mask=np.ones(1, dtype=bool), **values)
