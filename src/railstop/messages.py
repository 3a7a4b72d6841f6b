"""Role-neutral messages between units (DESIGN rule 3): frozen dataclasses, nothing else.

Units import messages, never each other. A unit returns its outputs as
``Output`` pairs: the name of the unit it is for (or ``BROADCAST``) and the
message; the driver (a scheduler on simulated time, or a live runner) delivers
them, through the link model where a link is between the two.
"""

from __future__ import annotations

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


@dataclass(frozen=True, slots=True, kw_only=True)
class PositionReport:
    """SPEC §4 report a: the onboard CBTC unit's position (train front, Pp) and speed (Vp)."""

    train_id: int
    position_m: float
    speed_mps: float  # >= 0; the sign is in ``direction``
    direction: str  # "R" (+chainage) or "L"
    time_s: float  # when the onboard unit took the position


@dataclass(frozen=True, slots=True, kw_only=True)
class MovementCommand:
    """SPEC §4 command b: the movement authority as a distance from the compensated position Pc,
    the gradient and the speed limit there."""

    train_id: int
    authority_m: float  # distance from Pc to the end of the authority (>= 0)
    gradient_permille: float
    speed_limit_mps: float
    report_time_s: float  # the report this command answers


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
    train doors' shape: open (True), closed (False), or unreadable / lost (None)."""

    doors_open: bool | None


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
