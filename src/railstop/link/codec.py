"""The telegram codec: every train↔wayside telegram as bytes, its layout kept as data.

Frame (SPEC §5: "~10 bytes, CRC-16" on the loop and the transponder)::

    type (1 B) | payload (fixed size per type) | CRC-16/CCITT-FALSE (2 B, big-endian)

The CRC covers the type byte and the payload; it is ``binascii.crc_hqx(data,
0xFFFF)`` (polynomial 0x1021, initial value 0xFFFF, no reflection, no final
XOR: CRC-16/CCITT-FALSE, check value 0x29B1 over ``b"123456789"``).

Every payload field is a big-endian integer (``struct``) with a declared
resolution, unit and range, listed in :data:`LAYOUTS` (one :class:`Layout`
per message dataclass). :func:`encode`, :func:`decode`, :func:`describe`,
:func:`from_fields`, :func:`quantize` and the documentation
(:func:`layout_markdown`, ``docs/telegrams.md``) are all generated from that
table: one piece of code serves every type.

The type byte is ``P GGG NNNN``: group G (1 TASC, 2 CBTC, 3 position
correction, 4 doors), number N within the group (for TASC, the signal form
of SPEC §1 claim 3) and P an even-parity bit over the other seven. Any two
type codes therefore differ in at least two bits, so a single bit error in
the type byte always gives an unknown type and is never read as another
telegram.

Decoding checks, in this order, and raises :class:`TelegramError` with the
reason code of the first failure:

1. ``malformed`` — the input is not ``bytes`` / ``bytearray`` / ``memoryview``;
2. ``short`` — empty input;
3. ``unknown_type`` — the type byte is not in the table;
4. ``short`` / ``long`` — the length differs from the type's frame length;
5. ``crc`` — the CRC-16 does not match;
6. ``out_of_range`` — a field's value is outside its declared min / max;
   ``bad_value`` — an enumeration code or flag bit that is not defined.

The type is read before the CRC because it gives the frame length: a
truncated telegram is reported as ``short`` (its last two bytes are then no
CRC at all), an overlong one as ``long``. Encoding raises ``out_of_range``
(NaN and infinities included) and ``bad_value`` (wrong Python type, an
undefined enumeration value) the same way, so a telegram that encodes always
decodes.

A value that went through the bytes equals ``quantize(...)`` of the value
sent (same rounding: half to even, ``round(value * counts_per_unit) /
counts_per_unit``), so a simulator can apply the wire's resolution to whole
arrays without encoding every telegram.
"""

from __future__ import annotations

import binascii
import math
import numbers
import struct
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, fields, replace
from dataclasses import field as dataclass_field
from typing import Any, ClassVar, Literal, cast

import numpy as np
from numpy.typing import NDArray

from railstop.errors import TelegramError
from railstop.link.safety import frame_size

__all__ = [
    "LAYOUTS",
    "SPEC_PAYLOAD_BYTES",
    "TASC_FORM_TYPES",
    "TYPES",
    "CbtcCommand",
    "CbtcReport",
    "DoorCommand",
    "Field",
    "Layout",
    "PsdStatus",
    "TascBrakeCommand",
    "TascDecel",
    "TascDistance",
    "TascEmergencyStop",
    "TascIncreaseDecrease",
    "TascInterval",
    "TascPosition",
    "TascRequiredDecel",
    "TascSpeed",
    "Telegram",
    "TrackCircuitOccupancy",
    "WccCommand",
    "ZoneRelease",
    "crc16",
    "decode",
    "describe",
    "encode",
    "from_fields",
    "layout_markdown",
    "layout_of",
    "quantize",
    "quantized",
    "update_doc",
]

CRC_BYTES = 2
FRAME_OVERHEAD_BYTES = 1 + CRC_BYTES  # type byte + CRC-16

# SPEC §5: the two ~10-byte media (the radio has room to spare); their bit rates are
# the presets of railstop/data/media.toml.
SMALL_MEDIA: tuple[str, ...] = ("loop", "transponder")
SPEC_PAYLOAD_BYTES = 10  # SPEC §5: "~10 bytes" of data on the loop and the transponder

Kind = Literal["int", "fixed", "enum", "flags"]

# struct code -> (smallest, largest) integer it holds
_CODE_RANGE = {
    "B": (0, 0xFF),
    "b": (-0x80, 0x7F),
    "H": (0, 0xFFFF),
    "h": (-0x8000, 0x7FFF),
    "I": (0, 0xFFFF_FFFF),
    "i": (-0x8000_0000, 0x7FFF_FFFF),
}
_CODE_NAME = {"B": "uint8", "b": "int8", "H": "uint16", "h": "int16", "I": "uint32", "i": "int32"}


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (SPEC §5 CRC-16); the stdlib's table-driven ``crc_hqx``."""
    return binascii.crc_hqx(data, 0xFFFF)


# --------------------------------------------------------------------------
# The layout as data


@dataclass(frozen=True, slots=True, kw_only=True)
class Field:
    """One payload field: a big-endian integer on the wire, a value in ``unit`` in the dataclass.

    - ``int``: an integer count (ids, indices); the value is the wire integer.
    - ``fixed``: a real number; wire integer = ``round(value * counts_per_unit)``
      (``counts_per_unit = 1000`` puts a value in metres on the wire in millimetres).
    - ``enum``: ``choices`` maps each defined wire code to (value, meaning).
    - ``flags``: bit ``i`` of the wire integer is the boolean attribute ``bits[i]``;
      the other bits must be 0.

    ``min`` / ``max`` are the declared range in ``unit`` (for flags and enums:
    of the wire integer). ``absent`` (optional) is a reserved wire code
    meaning "not available", carried as ``None``.
    """

    name: str
    code: str
    kind: Kind = "fixed"
    unit: str = ""
    counts_per_unit: int = 1
    min: float
    max: float
    description: str
    absent: int | None = None
    choices: Mapping[int, tuple[Any, str]] | None = None
    bits: tuple[str, ...] = ()
    # The declared range as wire integers (derived; kept as attributes for speed).
    raw_min: int = dataclass_field(init=False, repr=False, compare=False)
    raw_max: int = dataclass_field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "raw_min", round(self.min * self.counts_per_unit))
        object.__setattr__(self, "raw_max", round(self.max * self.counts_per_unit))

    @property
    def size(self) -> int:
        return struct.calcsize(">" + self.code)

    @property
    def attributes(self) -> tuple[str, ...]:
        """The dataclass attributes this field carries (one, or one per flag bit)."""
        return self.bits if self.kind == "flags" else (self.name,)

    @property
    def resolution(self) -> str:
        if self.kind != "fixed":
            return "1"
        return f"{1 / self.counts_per_unit:g}"

    @property
    def decimals(self) -> int:
        return max(0, math.ceil(math.log10(self.counts_per_unit))) if self.kind == "fixed" else 0

    @property
    def wire_type(self) -> str:
        return _CODE_NAME[self.code]

    def bounds(self) -> tuple[str, str]:
        """The declared (min, max) as text, at the field's resolution."""
        return (f"{self.min:.{self.decimals}f}", f"{self.max:.{self.decimals}f}")


class Telegram:
    """Base of every message dataclass; ``TYPE`` is its name in :data:`TYPES`."""

    __slots__ = ()
    TYPE: ClassVar[str]


@dataclass(frozen=True, slots=True, kw_only=True)
class Layout:
    """One telegram type: its name, type byte, dataclass and payload fields (in wire order)."""

    name: str
    code: int
    cls: type[Telegram]
    fields: tuple[Field, ...]
    medium: str
    description: str
    note: str = ""
    packer: struct.Struct = dataclass_field(init=False, repr=False, compare=False)  # from ``fields``

    def __post_init__(self) -> None:
        object.__setattr__(self, "packer", struct.Struct(">" + "".join(f.code for f in self.fields)))

    @property
    def payload_size(self) -> int:
        return self.packer.size

    @property
    def frame_size(self) -> int:
        return self.packer.size + FRAME_OVERHEAD_BYTES


# --------------------------------------------------------------------------
# The messages (SPEC §1 claim 3 forms 1-8, SPEC §4 CBTC, SPEC §2, SPEC §5 doors)


# Forms 1-5 carry the combinations of SPEC §1 para 92 (claim 3 with para 67: "one or more of the
# signals, combined as needed"), from which the onboard unit computes the required deceleration
# (claim 10): forms 1-3 the time between the last two detectors, the position and the distance
# (the train computes its speed and deceleration); form 4 the speed and the distance (it computes
# the deceleration); form 5 the deceleration and the distance. [interpretation] Para 92 gives the
# combinations, not which form carries which: each form carries the one that contains its own
# quantity, so forms 1-3 carry the same three, in their own order.


@dataclass(frozen=True, slots=True, kw_only=True)
class TascPosition(Telegram):
    """SPEC §1 claim 3 form 1: the train position the wayside detected, at ``measured_s``, with the
    distance to the stopping point and the time between the last two detectors (para 92)."""

    TYPE: ClassVar[str] = "tasc-position"
    train_id: int
    detector: int
    position_m: float
    distance_m: float
    interval_s: float | None
    passage_s: float
    measured_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class TascDistance(Telegram):
    """SPEC §1 claim 3 form 2: distance from the train to the stopping point, at ``measured_s``,
    with the position and the time between the last two detectors (para 92)."""

    TYPE: ClassVar[str] = "tasc-distance"
    train_id: int
    detector: int
    distance_m: float
    position_m: float
    interval_s: float | None
    passage_s: float
    measured_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class TascInterval(Telegram):
    """SPEC §1 claim 3 form 3: time between the last two detectors (None after the first one), with
    the position and the distance at ``measured_s`` (para 92)."""

    TYPE: ClassVar[str] = "tasc-interval"
    train_id: int
    detector: int
    interval_s: float | None
    passage_s: float
    position_m: float
    distance_m: float
    measured_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class TascSpeed(Telegram):
    """SPEC §1 claim 3 form 4: speed and distance to the stopping point (para 92) at
    ``measured_s``; the last passage was ``passage_age_s`` before."""

    TYPE: ClassVar[str] = "tasc-speed"
    train_id: int
    detector: int
    speed_mps: float
    distance_m: float
    measured_s: float
    passage_age_s: float

    @property
    def passage_s(self) -> float:
        return self.measured_s - self.passage_age_s


@dataclass(frozen=True, slots=True, kw_only=True)
class TascDecel(Telegram):
    """SPEC §1 claim 3 form 5: measured deceleration (None before it can be measured) and the
    distance to the stopping point at ``measured_s`` (para 92)."""

    TYPE: ClassVar[str] = "tasc-decel"
    train_id: int
    detector: int
    decel_mps2: float | None
    distance_m: float
    passage_s: float
    measured_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class TascRequiredDecel(Telegram):
    """SPEC §1 claim 3 form 6: the braking deceleration required to stop at the stopping point."""

    TYPE: ClassVar[str] = "tasc-required-decel"
    train_id: int
    detector: int
    required_mps2: float


@dataclass(frozen=True, slots=True, kw_only=True)
class TascBrakeCommand(Telegram):
    """SPEC §1 claim 3 form 7: brake notch B0..B7 and / or PWM duty (None: step-only train)."""

    TYPE: ClassVar[str] = "tasc-brake-command"
    train_id: int
    detector: int
    notch: int
    duty: float | None


@dataclass(frozen=True, slots=True, kw_only=True)
class TascIncreaseDecrease(Telegram):
    """SPEC §1 claim 3 form 8: increase (+1) / hold (0) / decrease (-1) the braking by one notch."""

    TYPE: ClassVar[str] = "tasc-increase-decrease"
    train_id: int
    detector: int
    delta: int
    step: int


@dataclass(frozen=True, slots=True, kw_only=True)
class TascEmergencyStop(Telegram):
    """The wayside's overrun guard (DESIGN rule 10): apply the emergency brake (wire e) now."""

    TYPE: ClassVar[str] = "tasc-emergency-stop"
    train_id: int
    detector: int


@dataclass(frozen=True, slots=True, kw_only=True)
class CbtcReport(Telegram):
    """SPEC §4: the onboard unit's periodic position / speed report."""

    TYPE: ClassVar[str] = "cbtc-report"
    train_id: int
    position_m: float
    speed_mps: float
    direction: str
    time_s: float
    # The location uncertainty (IEEE 1474.1); no default value: one left out does not encode.
    uncertainty_m: float = math.nan


@dataclass(frozen=True, slots=True, kw_only=True)
class CbtcCommand(Telegram):
    """SPEC §4: the wayside command computed from the compensated position Pc = Pp ± Δt·Vp."""

    TYPE: ClassVar[str] = "cbtc-command"
    train_id: int
    authority_m: float
    gradient_permille: float
    speed_limit_mps: float
    report_time_s: float
    delay_s: float = math.nan  # Δt; no default value: one left out does not encode


@dataclass(frozen=True, slots=True, kw_only=True)
class ZoneRelease(Telegram):
    """SPEC §4 step 5: the operator releases a lost train's protection zone after visual confirmation."""

    TYPE: ClassVar[str] = "zone-release"
    train_id: int
    operator_id: int


@dataclass(frozen=True, slots=True, kw_only=True)
class WccCommand(Telegram):
    """SPEC §5: the WCC switches a station's WPCS to manual (and presses the platform panel's open
    or close button) or back to automatic."""

    TYPE: ClassVar[str] = "wcc-command"
    station: int
    manual: bool
    panel_open: bool
    panel_close: bool
    operator_id: int


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackCircuitOccupancy(Telegram):
    """SPEC §2 S20: occupied track-circuit ID and the occupancy instant in GNSS time."""

    TYPE: ClassVar[str] = "tc-occupancy"
    circuit_id: int
    gnss_time_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class DoorCommand(Telegram):
    """SPEC §5: train (ATC / CPCS) -> platform (WPCS): the door signals, PSC request, driving mode."""

    TYPE: ClassVar[str] = "door-command"
    train_id: int
    doa_l: bool
    doa_r: bool
    dmc_l: bool
    dmc_r: bool
    doc: bool
    dcc: bool
    psc: bool
    automatic: bool
    doors_locked: int  # bit i: train door i + 1 facing the platform (front first) closed and locked


@dataclass(frozen=True, slots=True, kw_only=True)
class PsdStatus(Telegram):
    """SPEC §5: platform (WPCS) -> train: PSC reply, PSD closed and locked, start enable, and which
    PSD units are fully open (a train door opens only opposite one)."""

    TYPE: ClassVar[str] = "psd-status"
    train_id: int
    psc: bool
    psd_closed_locked: bool
    start_enable: bool
    manual: bool
    fault: bool
    psd_open: int  # bit i: PSD unit i + 1 (front first) fully open


# Fields shared by several types.
_TRAIN_ID = Field(name="train_id", code="H", kind="int", min=0, max=0xFFFF, description="train number")
_DETECTOR = Field(
    name="detector",
    code="B",
    kind="int",
    min=0,
    max=63,
    description="index of the last detector passed, 0 = first (SPEC §1 embodiment: 5)",
)
_MS_MAX = 0xFFFF_FFFF / 1000  # u32 milliseconds: 49.7 days of sender time


#: Doors a mask of the door link can name: one bit per door facing the platform, front first.
MAX_DOOR_UNITS = 24


def _door_mask(name: str, what: str, state: str) -> Field:
    # SPEC §5: the WPCS receives the state of the train doors facing the platform; the train
    # trusts the PSD state only from the link (while PSC is high). [interpretation] The paper
    # gives no layout: one bit per door, 24 doors a side (a 6-car train, 4 doors a car).
    return Field(
        name=name,
        code="I",
        kind="int",
        min=0,
        max=(1 << MAX_DOOR_UNITS) - 1,
        description=f"bit i: {what} i + 1 facing the platform (front first) {state}",
    )


def _time_ms(name: str, description: str) -> Field:
    return Field(
        name=name, code="I", unit="s", counts_per_unit=1000, min=0.0, max=_MS_MAX, description=description
    )


_LOOP = "loop / transponder"
_POSITION = Field(
    name="position_m",
    code="I",
    unit="m",
    counts_per_unit=1000,
    min=0.0,
    max=0xFFFF_FFFF / 1000,
    description="front of the train, chainage",
)
_DISTANCE = Field(
    name="distance_m",
    code="i",
    unit="m",
    counts_per_unit=1000,
    min=-100_000.0,
    max=100_000.0,
    description="to the stopping point (negative: past it)",
)
_INTERVAL = Field(
    name="interval_s",
    code="H",
    unit="s",
    counts_per_unit=1000,
    min=0.0,
    max=65.534,
    absent=0xFFFF,
    description="from detector-1 to detector (0xFFFF: none yet)",
)
# Para 92's payloads are longer than SPEC §5's ~10 bytes: the same note for forms 1-5.
_COMBINATION_NOTE = (
    "Longer than SPEC §5's ~10-byte payload: it carries a combination of SPEC §1 para 92 "
    "(an absolute chainage or distance at 1 mm and an absolute time at 1 ms need 4 bytes each)."
)

LAYOUTS: dict[type[Telegram], Layout] = {
    layout.cls: layout
    for layout in (
        Layout(
            name="tasc-position",
            code=0x11,
            cls=TascPosition,
            medium=_LOOP,
            description="SPEC §1 form 1: train position detected by the wayside, with the distance "
            "and the time between two detectors (para 92)",
            note=_COMBINATION_NOTE,
            fields=(
                _TRAIN_ID,
                _DETECTOR,
                _POSITION,
                _DISTANCE,
                _INTERVAL,
                _time_ms("passage_s", "passage time at detector"),
                _time_ms("measured_s", "time position and distance refer to (sender clock)"),
            ),
        ),
        Layout(
            name="tasc-distance",
            code=0x12,
            cls=TascDistance,
            medium=_LOOP,
            description="SPEC §1 form 2: distance between the train and the stopping point, with the "
            "position and the time between two detectors (para 92)",
            note=_COMBINATION_NOTE + " A station zone is longer than the 327 m an int16 of cm holds.",
            fields=(
                _TRAIN_ID,
                _DETECTOR,
                _DISTANCE,
                _POSITION,
                _INTERVAL,
                _time_ms("passage_s", "passage time at detector"),
                _time_ms("measured_s", "time distance and position refer to (sender clock)"),
            ),
        ),
        Layout(
            name="tasc-interval",
            code=0x93,
            cls=TascInterval,
            medium=_LOOP,
            description="SPEC §1 form 3: time taken between two detectors, with the position and the "
            "distance (para 92)",
            note=_COMBINATION_NOTE,
            fields=(
                _TRAIN_ID,
                _DETECTOR,
                _INTERVAL,
                _time_ms("passage_s", "passage time at detector"),
                _POSITION,
                _DISTANCE,
                _time_ms("measured_s", "time position and distance refer to (sender clock)"),
            ),
        ),
        Layout(
            name="tasc-speed",
            code=0x14,
            cls=TascSpeed,
            medium=_LOOP,
            description="SPEC §1 form 4: speed, with the distance (para 92)",
            note=_COMBINATION_NOTE + " The last passage is carried as its age (2 bytes).",
            fields=(
                _TRAIN_ID,
                _DETECTOR,
                Field(
                    name="speed_mps",
                    code="h",
                    unit="m/s",
                    counts_per_unit=1000,
                    min=-32.767,
                    max=32.767,
                    description="measured speed (signed: a noisy fit near standstill may dip below 0)",
                ),
                _DISTANCE,
                _time_ms("measured_s", "time speed and distance refer to (sender clock)"),
                Field(
                    name="passage_age_s",
                    code="H",
                    unit="s",
                    counts_per_unit=1000,
                    min=0.0,
                    max=65.535,
                    description="measured_s minus the passage time at detector",
                ),
            ),
        ),
        Layout(
            name="tasc-decel",
            code=0x95,
            cls=TascDecel,
            medium=_LOOP,
            description="SPEC §1 form 5: measured deceleration, with the distance (para 92)",
            note=_COMBINATION_NOTE,
            fields=(
                _TRAIN_ID,
                _DETECTOR,
                Field(
                    name="decel_mps2",
                    code="h",
                    unit="m/s²",
                    counts_per_unit=1000,
                    min=-20.0,
                    max=20.0,
                    absent=-0x8000,
                    description="measured deceleration, + = slowing (-32768: not measured yet)",
                ),
                _DISTANCE,
                _time_ms("passage_s", "passage time at detector"),
                _time_ms("measured_s", "time the distance refers to (sender clock)"),
            ),
        ),
        Layout(
            name="tasc-required-decel",
            code=0x96,
            cls=TascRequiredDecel,
            medium=_LOOP,
            description="SPEC §1 form 6: required braking deceleration",
            fields=(
                _TRAIN_ID,
                _DETECTOR,
                Field(
                    name="required_mps2",
                    code="H",
                    unit="m/s²",
                    counts_per_unit=1000,
                    min=0.0,
                    max=10.0,
                    description="braking deceleration required to stop at the stopping point",
                ),
            ),
        ),
        Layout(
            name="tasc-brake-command",
            code=0x17,
            cls=TascBrakeCommand,
            medium=_LOOP,
            description="SPEC §1 form 7: brake-system control command",
            fields=(
                _TRAIN_ID,
                _DETECTOR,
                Field(
                    name="notch",
                    code="B",
                    kind="int",
                    min=0,
                    max=7,
                    description="service brake step B0..B7 (0 = no service brake)",
                ),
                Field(
                    name="duty",
                    code="H",
                    unit="1",
                    counts_per_unit=10_000,
                    min=0.0,
                    max=1.0,
                    absent=0xFFFF,
                    description="PWM duty ratio (0xFFFF: none, step-controlled train)",
                ),
            ),
        ),
        Layout(
            name="tasc-increase-decrease",
            code=0x18,
            cls=TascIncreaseDecrease,
            medium=_LOOP,
            description="SPEC §1 form 8: increase / decrease the current braking deceleration",
            fields=(
                _TRAIN_ID,
                _DETECTOR,
                Field(
                    name="delta",
                    code="b",
                    kind="enum",
                    min=-1,
                    max=1,
                    choices={-1: (-1, "decrease"), 0: (0, "hold"), 1: (1, "increase")},
                    description="one notch step down / none / up",
                ),
                Field(
                    name="step",
                    code="B",
                    kind="int",
                    min=0,
                    max=255,
                    description="the step's number (1, 2, ... modulo 256): a train that sees one "
                    "skipped knows it missed a step (not in SPEC §1; stop model 14)",
                ),
            ),
        ),
        Layout(
            name="tasc-emergency-stop",
            code=0x9F,
            cls=TascEmergencyStop,
            medium=_LOOP,
            description="the wayside's overrun guard: emergency brake (wire e), any signal form "
            "(not in SPEC §1: DESIGN rule 10 needs the wayside to be able to stop a train it measures "
            "running past the platform end; number 15 of the TASC group)",
            fields=(_TRAIN_ID, _DETECTOR),
        ),
        Layout(
            name="cbtc-report",
            code=0x21,
            cls=CbtcReport,
            medium="radio",
            description="SPEC §4: onboard -> wayside position report",
            fields=(
                _TRAIN_ID,
                Field(
                    name="position_m",
                    code="I",
                    unit="m",
                    counts_per_unit=1000,
                    min=0.0,
                    max=0xFFFF_FFFF / 1000,
                    description="Pp, chainage of the train front",
                ),
                Field(
                    name="speed_mps",
                    code="H",
                    unit="m/s",
                    counts_per_unit=1000,
                    min=0.0,
                    max=65.535,
                    description="Vp, speed (the sign is in direction)",
                ),
                Field(
                    name="direction",
                    code="B",
                    kind="enum",
                    min=0,
                    max=1,
                    choices={0: ("R", "+chainage, up"), 1: ("L", "-chainage, down")},
                    description="travel direction",
                ),
                _time_ms("time_s", "time of the report (onboard clock)"),
                Field(
                    name="uncertainty_m",
                    code="I",
                    unit="m",
                    counts_per_unit=1000,
                    min=0.0,
                    max=0xFFFF_FFFF / 1000,
                    description="location uncertainty: the true front is within position_m ± this",
                ),
            ),
        ),
        Layout(
            name="cbtc-command",
            code=0x22,
            cls=CbtcCommand,
            medium="radio",
            description="SPEC §4: wayside -> onboard command",
            fields=(
                _TRAIN_ID,
                Field(
                    name="authority_m",
                    code="I",
                    unit="m",
                    counts_per_unit=1000,
                    min=0.0,
                    max=0xFFFF_FFFF / 1000,
                    description="movement authority: distance to the ATC stopping point from Pc",
                ),
                Field(
                    name="gradient_permille",
                    code="h",
                    unit="‰",
                    counts_per_unit=10,
                    min=-100.0,
                    max=100.0,
                    description="gradient at Pc (+ = uphill in the direction of travel)",
                ),
                Field(
                    name="speed_limit_mps",
                    code="H",
                    unit="m/s",
                    counts_per_unit=1000,
                    min=0.0,
                    max=65.535,
                    description="speed limit at Pc",
                ),
                _time_ms("report_time_s", "time_s of the report this command answers"),
                Field(
                    name="delay_s",
                    code="H",
                    unit="s",
                    counts_per_unit=1000,
                    min=0.0,
                    max=65.535,
                    description="Δt of Pc = Pp ± Δt·Vp (the onboard unit rebuilds Pc from its report)",
                ),
            ),
        ),
        Layout(
            name="zone-release",
            code=0xA3,
            cls=ZoneRelease,
            medium="radio",
            description="SPEC §4 step 5: operator -> zone controller, manual release of a lost train's "
            "protection zone after visual confirmation (always in a category 3 safety frame with the "
            "operator's own key)",
            fields=(
                _TRAIN_ID,
                Field(name="operator_id", code="H", kind="int", min=0, max=0xFFFF, description="operator"),
            ),
        ),
        Layout(
            name="tc-occupancy",
            code=0xB1,
            cls=TrackCircuitOccupancy,
            medium="radio",
            description="SPEC §2 S20: track-circuit occupancy",
            fields=(
                Field(
                    name="circuit_id",
                    code="I",
                    kind="int",
                    min=0,
                    max=0xFFFF_FFFF,
                    description="occupied track circuit",
                ),
                Field(
                    name="gnss_time_s",
                    code="i",
                    unit="s",
                    counts_per_unit=10_000,
                    min=-0x8000_0000 / 10_000,
                    max=0x7FFF_FFFF / 10_000,
                    description="occupancy instant, GNSS time from 00:00 of the service day "
                    "(0.1 ms = 2.5 mm at 90 km/h; ±59.6 h)",
                ),
            ),
        ),
        Layout(
            name="door-command",
            code=0x41,
            cls=DoorCommand,
            medium=_LOOP,
            description="SPEC §5: train -> platform door signals",
            fields=(
                _TRAIN_ID,
                Field(
                    name="signals",
                    code="B",
                    kind="flags",
                    min=0,
                    max=0xFF,
                    bits=("doa_l", "doa_r", "dmc_l", "dmc_r", "doc", "dcc", "psc", "automatic"),
                    description="bit 0 DOA-L, 1 DOA-R, 2 DMC-L, 3 DMC-R, 4 DOC, 5 DCC, "
                    "6 PSC request, 7 driving mode (1 automatic, 0 manual)",
                ),
                _door_mask("doors_locked", "train door", "closed and locked"),
            ),
        ),
        Layout(
            name="wcc-command",
            code=0xC3,
            cls=WccCommand,
            medium="radio",
            description="SPEC §5: WCC (control room) -> a station's WPCS, manual mode and the platform "
            "panel's buttons (always in a category 3 safety frame with the operator's own key)",
            fields=(
                Field(
                    name="station",
                    code="H",
                    kind="int",
                    min=0,
                    max=0xFFFF,
                    description="the station's number on the line (0 = first in the line data)",
                ),
                Field(
                    name="mode",
                    code="B",
                    kind="flags",
                    min=0,
                    max=0x07,
                    bits=("manual", "panel_open", "panel_close"),
                    description="bit 0 WPCS in manual, 1 panel open button, 2 panel close button "
                    "(1 and 2 only with 0, never both); bits 3-7 must be 0",
                ),
                Field(name="operator_id", code="H", kind="int", min=0, max=0xFFFF, description="operator"),
            ),
        ),
        Layout(
            name="psd-status",
            code=0x42,
            cls=PsdStatus,
            medium=_LOOP,
            description="SPEC §5: platform -> train PSD status",
            fields=(
                _TRAIN_ID,
                Field(
                    name="status",
                    code="B",
                    kind="flags",
                    min=0,
                    max=0x1F,
                    bits=("psc", "psd_closed_locked", "start_enable", "manual", "fault"),
                    description="bit 0 PSC reply, 1 PSD closed and locked, 2 start enable, "
                    "3 WPCS in manual (WCC), 4 PSD fault; bits 5-7 must be 0",
                ),
                _door_mask("psd_open", "PSD unit", "fully open"),
            ),
        ),
    )
}

TYPES: dict[str, type[Telegram]] = {layout.name: cls for cls, layout in LAYOUTS.items()}
_BY_CODE: dict[int, Layout] = {layout.code: layout for layout in LAYOUTS.values()}

# SPEC §1 claim 3: the message type of each signal form (a SignalForm is an int).
TASC_FORM_TYPES: dict[int, type[Telegram]] = {
    1: TascPosition,
    2: TascDistance,
    3: TascInterval,
    4: TascSpeed,
    5: TascDecel,
    6: TascRequiredDecel,
    7: TascBrakeCommand,
    8: TascIncreaseDecrease,
}


def _check_layouts() -> None:
    """The table is self-consistent (run at import: a broken table must not ship)."""
    for cls, layout in LAYOUTS.items():
        if layout.cls is not cls or layout.name != cls.TYPE:
            raise RuntimeError(f"{layout.name}: class / name mismatch")
        if bin(layout.code).count("1") % 2:
            raise RuntimeError(f"{layout.name}: type code 0x{layout.code:02x} has odd parity")
        attrs = [a for f in layout.fields for a in f.attributes]
        if attrs != [f.name for f in fields(cast(Any, cls))]:
            raise RuntimeError(f"{layout.name}: layout {attrs} != dataclass fields")
        for f in layout.fields:
            lo, hi = _CODE_RANGE[f.code]
            if not lo <= f.raw_min <= f.raw_max <= hi:
                raise RuntimeError(f"{layout.name}.{f.name}: declared range does not fit {f.code}")
            if f.absent is not None and (f.raw_min <= f.absent <= f.raw_max or not lo <= f.absent <= hi):
                raise RuntimeError(f"{layout.name}.{f.name}: absent code inside the range")
            if f.kind == "enum" and (not f.choices or not all(lo <= c <= hi for c in f.choices)):
                raise RuntimeError(f"{layout.name}.{f.name}: bad choices")
            if f.kind == "flags" and (f.raw_max != (1 << len(f.bits)) - 1 or f.raw_min != 0):
                raise RuntimeError(f"{layout.name}.{f.name}: flags range must be the defined bits")
    if len(_BY_CODE) != len(LAYOUTS) or len(TYPES) != len(LAYOUTS):
        raise RuntimeError("duplicate type code or name")


_check_layouts()


# --------------------------------------------------------------------------
# Field <-> wire integer


def _where(layout: Layout, f: Field) -> str:
    return f"{layout.name}.{f.name}"


def _range_text(f: Field) -> str:
    lo, hi = f.bounds()
    unit = f" {f.unit}" if f.kind == "fixed" and f.unit not in ("", "1") else ""
    return f"[{lo}, {hi}]{unit}"


_BOOLS = (bool, np.bool_)


def _to_raw(layout: Layout, f: Field, msg: Telegram) -> int:
    if f.kind == "flags":
        raw = 0
        for i, attr in enumerate(f.bits):
            bit = getattr(msg, attr)
            if type(bit) is not bool and not isinstance(bit, _BOOLS):
                raise TelegramError("bad_value", f"{layout.name}.{attr}={bit!r}: not a bool")
            if bit:
                raw |= 1 << i
        return raw
    value = getattr(msg, f.name)
    kind = f.kind
    tv = type(value)
    # Fast paths for plain Python numbers (the common case); numpy scalars and the
    # like go through the numbers ABCs below.
    if kind == "fixed" and (tv is float or tv is int):
        scaled = value * f.counts_per_unit
        if scaled - scaled != 0.0:  # NaN or an infinity
            raise TelegramError("out_of_range", f"{_where(layout, f)}={value!r} outside {_range_text(f)}")
        raw = round(scaled)
    elif kind == "int" and tv is int:
        raw = value
    else:
        raw = _to_raw_slow(layout, f, value)
        if kind == "enum" or value is None:
            return raw
    if not f.raw_min <= raw <= f.raw_max:
        raise TelegramError("out_of_range", f"{_where(layout, f)}={value!r} outside {_range_text(f)}")
    return raw


def _to_raw_slow(layout: Layout, f: Field, value: Any) -> int:
    where = _where(layout, f)
    if f.kind == "enum":
        key: int | str | None = None
        if isinstance(value, numbers.Integral) and not isinstance(value, _BOOLS):
            key = int(value)
        elif isinstance(value, str):
            key = value
        for code, (choice, _) in (f.choices or {}).items():
            if key is not None and type(choice) is type(key) and choice == key:
                return code
        choices = [c for c, _ in (f.choices or {}).values()]
        raise TelegramError("bad_value", f"{where}={value!r}: not one of {choices}")
    if value is None:
        if f.absent is None:
            raise TelegramError("bad_value", f"{where}=None: the field cannot be absent")
        return f.absent
    if isinstance(value, _BOOLS):
        raise TelegramError("bad_value", f"{where}={value!r}: a bool is not a number")
    if f.kind == "int":
        if not isinstance(value, numbers.Integral):
            raise TelegramError("bad_value", f"{where}={value!r}: not an integer")
        return int(value)
    if not isinstance(value, numbers.Real):
        raise TelegramError("bad_value", f"{where}={value!r}: not a number")
    scaled = float(value) * f.counts_per_unit
    if not math.isfinite(scaled):
        raise TelegramError("out_of_range", f"{where}={float(value)!r} outside {_range_text(f)}")
    return round(scaled)


def _from_raw(layout: Layout, f: Field, raw: int) -> Any:
    """The value of a non-flag field."""
    if f.kind == "enum":
        choices = f.choices or {}
        if raw not in choices:
            raise TelegramError("bad_value", f"{_where(layout, f)}: code {raw} is not defined")
        return choices[raw][0]
    if raw == f.absent:
        return None
    if not f.raw_min <= raw <= f.raw_max:
        shown = raw if f.kind == "int" else f"{raw / f.counts_per_unit:.{f.decimals}f}"
        raise TelegramError("out_of_range", f"{_where(layout, f)}={shown} outside {_range_text(f)}")
    return raw if f.kind == "int" else raw / f.counts_per_unit


def _flags_from_raw(layout: Layout, f: Field, raw: int, into: dict[str, Any]) -> None:
    """The flags of a flag field, each put into ``into`` under its attribute."""
    if raw & ~f.raw_max:
        raise TelegramError(
            "bad_value", f"{_where(layout, f)}=0x{raw:02x}: undefined bits 0x{raw & ~f.raw_max:02x} set"
        )
    for i, attr in enumerate(f.bits):
        into[attr] = bool(raw >> i & 1)


# --------------------------------------------------------------------------
# Public API


def layout_of(kind: str | type[Telegram] | Telegram) -> Layout:
    """The layout of a type name (``"cbtc-report"``), a message class or a message."""
    if isinstance(kind, str):
        cls = TYPES.get(kind)
        if cls is None:
            raise TelegramError("unknown_type", f"{kind!r}; known: {', '.join(TYPES)}")
        return LAYOUTS[cls]
    cls = kind if isinstance(kind, type) else type(kind)
    layout = LAYOUTS.get(cls)
    if layout is None:
        raise TelegramError("unknown_type", f"{cls.__name__} is not a telegram")
    return layout


def encode(msg: Telegram) -> bytes:
    """The frame of ``msg``: type | payload | CRC-16. Raises TelegramError (out_of_range, bad_value)."""
    layout = LAYOUTS.get(type(msg)) or layout_of(msg)  # (a message's own class: its layout at once)
    body = bytes((layout.code,)) + layout.packer.pack(*[_to_raw(layout, f, msg) for f in layout.fields])
    return body + crc16(body).to_bytes(CRC_BYTES, "big")


def decode(data: bytes | bytearray | memoryview) -> Telegram:
    """The message in a frame; raises TelegramError with the reason of the first failed check."""
    if type(data) is bytes:
        pass  # the common case: nothing to convert
    elif isinstance(data, memoryview):
        try:
            data = data.tobytes()
        except (ValueError, TypeError) as exc:  # a released or unreadable view
            raise TelegramError("malformed", f"unreadable memoryview: {exc}") from None
    elif isinstance(data, bytes | bytearray):
        data = bytes(data)
    else:
        raise TelegramError("malformed", f"expected bytes, got {type(data).__name__}")
    if not data:
        raise TelegramError("short", "empty input")
    layout = _BY_CODE.get(data[0])
    if layout is None:
        raise TelegramError("unknown_type", f"type byte 0x{data[0]:02x}")
    if len(data) != layout.frame_size:
        reason = "short" if len(data) < layout.frame_size else "long"
        raise TelegramError(reason, f"{layout.name}: {len(data)} bytes, the frame has {layout.frame_size}")
    got = int.from_bytes(data[-CRC_BYTES:], "big")
    want = crc16(data[:-CRC_BYTES])
    if got != want:
        raise TelegramError("crc", f"{layout.name}: CRC 0x{got:04x}, computed 0x{want:04x}")
    kwargs: dict[str, Any] = {}
    for f, raw in zip(layout.fields, layout.packer.unpack_from(data, 1), strict=True):
        if f.kind == "flags":
            _flags_from_raw(layout, f, raw, kwargs)
        else:
            kwargs[f.name] = _from_raw(layout, f, raw)
    return layout.cls(**kwargs)


def quantize(
    kind: str | type[Telegram] | Telegram,
    field: str,
    values: float | NDArray[np.float64] | Iterable[float] | None,
) -> Any:
    """What field ``field`` of telegram type ``kind`` can carry: ``values`` rounded to its resolution.

    Works on a scalar (returns a float) or an array (returns an array, NaN
    kept: NaN stands for an absent value). Equal to the value a receiver
    decodes whenever the value is in range (the range is not checked here).
    Fields other than fixed-point ones are returned unchanged.
    """
    layout = layout_of(kind)
    f = next((f for f in layout.fields if f.name == field), None)
    if f is None:
        raise TelegramError("bad_value", f"{layout.name} has no field {field!r}")
    if f.kind != "fixed" or values is None:
        return values
    cpu = f.counts_per_unit
    if isinstance(values, numbers.Real) and not isinstance(values, np.ndarray):
        v = float(values)
        return round(v * cpu) / cpu if math.isfinite(v * cpu) else v
    arr = np.asarray(values, dtype=np.float64)
    return np.round(arr * cpu) / cpu


def quantized(msg: Telegram) -> Telegram:
    """``msg`` with every fixed-point field rounded to its resolution (what ``decode(encode(msg))`` gives)."""
    layout = layout_of(msg)
    changes = {
        f.name: quantize(layout.name, f.name, getattr(msg, f.name))
        for f in layout.fields
        if f.kind == "fixed" and isinstance(getattr(msg, f.name), numbers.Real)
    }
    return replace(msg, **changes)  # type: ignore[type-var]


def _format(f: Field, value: Any) -> str:
    if value is None:
        return "absent"
    if f.kind == "enum":
        meaning = next((m for v, m in (f.choices or {}).values() if v == value), "?")
        return f"{value:+d} ({meaning})" if isinstance(value, int) else f"{value} ({meaning})"
    if f.kind == "int":
        return str(value)
    unit = "" if f.unit in ("", "1") else f" {f.unit}"
    return f"{value:.{f.decimals}f}{unit}"


def describe(msg: Telegram) -> list[tuple[str, str]]:
    """Every field of ``msg`` as (name, value with unit), in wire order (flag bits one by one)."""
    layout = layout_of(msg)
    rows: list[tuple[str, str]] = []
    for f in layout.fields:
        if f.kind == "flags":
            rows.extend((attr, "1" if getattr(msg, attr) else "0") for attr in f.bits)
        else:
            rows.append((f.name, _format(f, getattr(msg, f.name))))
    return rows


_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}
_ABSENT = {"none", "absent", "-"}


def _parse(layout: Layout, f: Field, attr: str, text: str) -> Any:
    where = f"{layout.name}.{attr}={text!r}"
    s = text.strip()
    if f.kind == "flags":
        if s.lower() in _TRUE:
            return True
        if s.lower() in _FALSE:
            return False
        raise TelegramError("bad_value", f"{where}: not a flag (0/1, true/false)")
    if f.absent is not None and s.lower() in _ABSENT:
        return None
    if f.kind == "enum":
        choices = list((f.choices or {}).values())
        for value, _ in choices:
            if s.lower() == str(value).lower():
                return value
            if isinstance(value, int):
                try:
                    if int(s) == value:
                        return value
                except ValueError:
                    pass
        raise TelegramError("bad_value", f"{where}: one of {[v for v, _ in choices]}")
    if f.kind == "int":
        try:
            return int(s, 0) if s.lower().startswith(("0x", "0b", "0o")) else int(s)
        except ValueError:
            raise TelegramError("bad_value", f"{where}: not an integer") from None
    try:
        return float(s)
    except ValueError:
        raise TelegramError("bad_value", f"{where}: not a number") from None


def from_fields(type_name: str, values: Mapping[str, str]) -> Telegram:
    """Build a message from text (``{"required_mps2": "0.7", ...}``), e.g. from the command line.

    Every field must be given (absent values as ``none``; flags as 0/1).
    Raises TelegramError naming the field and the value: ``unknown_type``,
    ``bad_value`` (unknown, missing or unparsable field) or ``out_of_range``.
    """
    layout = layout_of(type_name)
    expected = {attr: f for f in layout.fields for attr in f.attributes}
    unknown = [k for k in values if k not in expected]
    if unknown:
        raise TelegramError(
            "bad_value", f"{layout.name}: unknown field {unknown[0]!r}; fields: {', '.join(expected)}"
        )
    missing = [k for k in expected if k not in values]
    if missing:
        raise TelegramError("bad_value", f"{layout.name}: missing field {missing[0]!r}")
    msg = layout.cls(**{attr: _parse(layout, f, attr, values[attr]) for attr, f in expected.items()})
    encode(msg)  # range checks now, with the field and value named
    return msg


# --------------------------------------------------------------------------
# Documentation from the table


def layout_markdown() -> str:
    """The byte layout of every telegram and its sizes / airtimes, as Markdown (docs/telegrams.md)."""
    lines: list[str] = []
    lines.append("| type | code | payload B | frame B | cat 1/2 frame B | cat 3 frame B | medium |")
    lines.append("|---|---|---|---|---|---|---|")
    for layout in LAYOUTS.values():
        lines.append(
            f"| `{layout.name}` | 0x{layout.code:02X} | {layout.payload_size} | {layout.frame_size} "
            f"| {frame_size(layout.frame_size, 1)} | {frame_size(layout.frame_size, 3)} | {layout.medium} |"
        )
    lines.append("")
    lines.append("Airtime of the bytes alone (ms; preamble and sync words come on top, see")
    lines.append("`railstop.link.channel`). Codec frame / inside a safety frame of category 1-2 / 3:")
    lines.append("")
    # The bytes alone: the medium without its preamble / sync overhead. (The media's models are
    # imported here, not with the codec: the CLI's help and `telegram` need only the layouts.)
    from railstop.link.channel import airtime_s, media_preset

    media = [(m, media_preset(m).replace(overhead_bits=0)) for m in SMALL_MEDIA]
    head = " | ".join(f"{m} {p.bit_rate_bps / 1000:g} kbit/s" for m, p in media)
    lines.append(f"| type | {head} |")
    lines.append("|---|" + "---|" * len(media))
    for layout in LAYOUTS.values():
        sizes = (layout.frame_size, frame_size(layout.frame_size, 1), frame_size(layout.frame_size, 3))
        cells = " | ".join(" / ".join(f"{1000.0 * airtime_s(p, n):.2f}" for n in sizes) for _, p in media)
        lines.append(f"| `{layout.name}` | {cells} |")
    for layout in LAYOUTS.values():
        lines.append("")
        lines.append(f"### `{layout.name}` — type 0x{layout.code:02X}")
        lines.append("")
        lines.append(
            f"{layout.description}. Class `{layout.cls.__name__}`; {layout.payload_size}-byte payload, "
            f"{layout.frame_size}-byte frame; {layout.medium}."
        )
        if layout.note:
            lines.append(f"{layout.note}")
        lines.append("")
        lines.append("| offset | field | wire type | unit | resolution | min | max | description |")
        lines.append("|---|---|---|---|---|---|---|---|")
        lines.append("| 0 | type | uint8 | | | | | " + f"0x{layout.code:02X} |")
        offset = 1
        for f in layout.fields:
            desc = f.description
            if f.kind == "enum" and f.choices:
                desc += "; " + ", ".join(f"{c} = {v} ({m})" for c, (v, m) in f.choices.items())
            lo, hi = f.bounds()
            lines.append(
                f"| {offset} | `{f.name}` | {f.wire_type} | {f.unit} | {f.resolution} "
                f"| {lo} | {hi} | {desc} |"
            )
            offset += f.size
        lines.append(f"| {offset} | crc | uint16 | | | | | CRC-16/CCITT-FALSE over bytes 0..{offset - 1} |")
    return "\n".join(lines) + "\n"


DOC_BEGIN = "<!-- BEGIN layout_markdown() -->\n"
DOC_END = "<!-- END layout_markdown() -->"


def update_doc(text: str) -> str:
    """``text`` with the block between the markers replaced by :func:`layout_markdown` (docs/telegrams.md)."""
    start = text.find(DOC_BEGIN)
    end = text.find(DOC_END)
    if start < 0 or end < start:
        raise TelegramError("malformed", "the document lacks the layout_markdown() markers")
    return text[: start + len(DOC_BEGIN)] + layout_markdown() + text[end:]
