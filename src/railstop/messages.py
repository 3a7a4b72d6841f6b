"""Role-neutral messages between units (DESIGN rule 3): frozen dataclasses, nothing else (but
the grid the CBTC telegrams carry their values on, which both CBTC ends share, and the vector
layout of the compiled TASC telegram, which both TASC ends share).

Units import messages, never each other. A unit returns its outputs as
``Output`` pairs: the name of the unit it is for (or ``BROADCAST``) and the
message; the driver (a scheduler on simulated time, or a live runner) delivers
them, through the link model where a link is between the two.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

BROADCAST = "*"


@dataclass(frozen=True, slots=True, kw_only=True)
class CircuitOccupancy:
    """A wayside track-circuit device reports a circuit's state (SPEC §2: occupied / clear)."""

    circuit_id: int
    occupied: bool


@dataclass(frozen=True, slots=True, kw_only=True)
class SignalAspects:
    """The interlocking's signal aspects, every signal in running order: True = proceed."""

    proceed: tuple[bool, ...]


#: Counts per unit of the CBTC telegrams' distances, speeds and times (``cbtc-report`` and
#: ``cbtc-command`` in link/codec.py: mm, mm/s, ms). The CBTC units put the values they send on
#: this grid themselves, so that both ends compute with the very numbers the other receives.
CBTC_COUNTS_PER_UNIT = 1000


def cbtc_grid(value: float) -> float:
    """``value`` as a CBTC telegram carries it (the codec's ``quantize``: half to even)."""
    return round(value * CBTC_COUNTS_PER_UNIT) / CBTC_COUNTS_PER_UNIT


def cbtc_grid_down(value: float) -> float:
    """The largest value on the CBTC telegrams' grid not above ``value`` (a distance that the
    wire's rounding must never lengthen)."""
    return math.floor(value * CBTC_COUNTS_PER_UNIT) / CBTC_COUNTS_PER_UNIT


def cbtc_grid_up(value: float) -> float:
    """The smallest value on the CBTC telegrams' grid not below ``value`` (an uncertainty)."""
    return math.ceil(value * CBTC_COUNTS_PER_UNIT) / CBTC_COUNTS_PER_UNIT


@dataclass(frozen=True, slots=True, kw_only=True)
class PositionReport:
    """SPEC §4 report a: the onboard CBTC unit's position (train front, Pp), speed (Vp) and the
    location uncertainty of its positioning (IEEE 1474.1: the true front lies within
    ``position_m ± uncertainty_m``; missing, negative or non-finite: the report is invalid)."""

    train_id: int
    position_m: float
    speed_mps: float  # >= 0; the sign is in ``direction``
    direction: str  # "R" (+chainage) or "L"
    time_s: float  # when the onboard unit took the position; the report's identity
    uncertainty_m: float  # >= 0, the positioning's confidence bound on the front


@dataclass(frozen=True, slots=True, kw_only=True)
class MovementCommand:
    """SPEC §4 command b: the movement authority as a distance from the compensated position
    Pc = Pp ± Δt·Vp of the report it answers, the gradient and the speed limit there. The onboard
    unit rebuilds Pc from its own copy of that report and ``delay_s`` (Δt), so that the end is the
    point the zone controller meant."""

    train_id: int
    authority_m: float  # distance from Pc to the end of the authority (>= 0)
    gradient_permille: float
    speed_limit_mps: float
    report_time_s: float  # the report this command answers (its time_s)
    delay_s: float  # Δt of SPEC §4 the controller compensated with (>= 0)


@dataclass(frozen=True, slots=True, kw_only=True)
class ManualRelease:
    """SPEC §4 step 5: the operator releases a lost train's protection zone after visual
    confirmation (it reaches the zone controller only through an authenticated link)."""

    train_id: int


@dataclass(frozen=True, slots=True, kw_only=True)
class TrainLeft:
    """A train has left the zone controller's area (the line's end): it is no longer supervised."""

    train_id: int


@dataclass(frozen=True, slots=True, kw_only=True)
class StopSensorScan:
    """SPEC §3: one scan of the platform's stop sensors S2 and S1, and the train's standstill."""

    s2: bool
    s1: bool
    standstill: bool


@dataclass(frozen=True, slots=True, kw_only=True)
class PsdDoorState:
    """The PSD's doors as the platform sees them: all closed and locked, or not."""

    closed_locked: bool


@dataclass(frozen=True, slots=True, kw_only=True)
class SignalOpenSwitch:
    """SPEC §3: the signal-open switch that lets a train pass the station (skip, out of service)."""

    on: bool


@dataclass(frozen=True, slots=True, kw_only=True)
class PlatformLamps:
    """SPEC §3: the lamp lit (F, OK, R, S; None: none), whether the PSD may operate, and whether
    the PSD state permits departure."""

    lamp: str | None
    psd_enable: bool
    departure_permitted: bool


@dataclass(frozen=True, slots=True, kw_only=True)
class DoorCameraFrame:
    """SPEC §3: one frame of the platform's CCD camera, as its image processing classified the
    train doors' shape: "open", "moving" (between open and shut), "closed" (the leaves fully
    shut), or None (unreadable / lost)."""

    shape: str | None


@dataclass(frozen=True, slots=True, kw_only=True)
class PsdCommand:
    """SPEC §3: what the PSD control tells the PSD doors (open or close) and whether it still
    knows the train doors' shape (``camera_ok`` False: the camera is lost, the PSD is held)."""

    open: bool
    camera_ok: bool


@dataclass(frozen=True, slots=True, kw_only=True)
class SpeedCode:
    """SPEC §3: the speed limit an ATS point gives (held until the next point) or the ATC speed
    code the pick-up coil receives (the ADU's indicated speed)."""

    limit_mps: float


@dataclass(frozen=True, slots=True, kw_only=True)
class TrainSpeed:
    """The train's speed as its own speedometer measures it."""

    speed_mps: float


@dataclass(frozen=True, slots=True, kw_only=True)
class SupervisionState:
    """SPEC §3 speed supervision: the overspeed alarm, the emergency brake and its cause."""

    alarm: bool
    emergency_brake: bool
    cause: str | None


@dataclass(frozen=True, slots=True, kw_only=True)
class ControllerRestart:
    """Fault injection: the zone controller restarts (its volatile state is gone)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class OnboardPosition:
    """The onboard positioning's estimate (SPEC §2) for the train's own units."""

    position_m: float
    speed_mps: float
    uncertainty_m: float  # the positioning's confidence bound on the front (>= 0; else invalid)


#: Every message a unit takes or sends.
Message = (
    CircuitOccupancy
    | SignalAspects
    | PositionReport
    | MovementCommand
    | ManualRelease
    | TrainLeft
    | ControllerRestart
    | SpeedCode
    | TrainSpeed
    | SupervisionState
    | StopSensorScan
    | PsdDoorState
    | SignalOpenSwitch
    | PlatformLamps
    | DoorCameraFrame
    | PsdCommand
    | OnboardPosition
)


@dataclass(frozen=True, slots=True, kw_only=True)
class Output:
    """A message for the unit named ``to`` (``BROADCAST``: every unit that takes its type)."""

    to: str
    message: Message


# The ground TASC braking telegram (SPEC §1) as the compiled units exchange it: one float
# vector per telegram, indexed by TEL_*; NaN marks a field the signal form does not carry.
# Both ends (wayside/tasc_unit.py, onboard/tasc_receiver.py) share this layout.
TEL_DETECTOR = 0
TEL_PASSAGE = 1
TEL_MEASURED = 2
TEL_POSITION = 3
TEL_DISTANCE = 4
TEL_INTERVAL = 5
TEL_SPEED = 6
TEL_DECEL = 7
TEL_REQUIRED = 8
TEL_NOTCH = 9
TEL_DUTY = 10
TEL_DELTA = 11
TEL_EMERGENCY = 12  # 1: an emergency-stop telegram (the wayside's overrun guard), every form
TEL_STEP = 13  # form 8: the step's number (1, 2, ... modulo 256): a train learns of a step it missed
TEL_SIZE = 14
#: Telegram vector index -> TascTelegrams field (the array form of the same telegram).
TEL_FIELDS: tuple[str, ...] = (
    "detector",
    "passage_s",
    "measured_s",
    "position_m",
    "distance_m",
    "interval_s",
    "speed_mps",
    "decel_mps2",
    "required_mps2",
    "notch",
    "duty",
    "delta",
    "emergency",
    "step",
)
