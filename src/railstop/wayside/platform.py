"""The platform unit of SPEC §3: stop sensors -> lamps -> PSD relay (fig. 4), a pure unit.

Each scan of the stop sensors S2, S1 (debounced, see ``PlatformUnit``) and the train's
standstill give the lamp from the **lamp table** of the platform data:

* **F**: stopped short of the sensors (move forward);
* **OK**: S2 sees the train and S1 does not: the **PSD may operate** (the
  PSD relay is energised only while OK is lit);
* **R**: passed both (reverse);
* **S**: once the PSD has operated with OK and is closed and locked again:
  departure ready.

No lamp while the train moves. The PSD is the **master**, the train the
**slave** (SPEC §3 interlock principles): departure is permitted only with
the PSD closed and locked. The **signal-open switch** lets a train pass the
station: no lamp, the PSD held closed. A sensor combination that cannot be
a train front at rest (S1 without S2) lights no lamp and holds the PSD
closed (DESIGN rule 10), as does any state the unit cannot tell.

Time is not needed (scans come at the sensors' period); nothing is read from
a clock (DESIGN rule 2).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from railstop.errors import InterlockError
from railstop.messages import (
    BROADCAST,
    DoorCameraFrame,
    Message,
    Output,
    PlatformLamps,
    PsdCommand,
    PsdDoorState,
    SignalOpenSwitch,
    StopSensorScan,
)
from railstop.sensors.door_camera import CLOSED, OPEN, SHAPES


@dataclass(slots=True)
class _Debounce:
    """A sensor at a stand: unsettled (None) from the stop until ``need`` equal readings in a row,
    then that reading, which changes only after ``need`` opposite readings in a row."""

    need: int
    state: bool | None = None
    trues: int = 0
    falses: int = 0

    def feed(self, raw: bool) -> None:
        if raw:
            self.trues, self.falses = self.trues + 1, 0
            if self.trues >= self.need:
                self.state = True
        else:
            self.trues, self.falses = 0, self.falses + 1
            if self.falses >= self.need:
                self.state = False

    def reset(self) -> None:
        self.state, self.trues, self.falses = None, 0, 0


@dataclass(slots=True)
class PlatformUnit:
    """``lamp_table``: (s2, s1) -> "F" | "OK" | "R" | "fault" (the platform data's)."""

    lamp_table: Mapping[tuple[bool, bool], str]
    debounce_scans: int = 3
    name: str = "platform"
    accepts: tuple[type, ...] = (StopSensorScan, PsdDoorState, SignalOpenSwitch)
    s2: _Debounce = field(init=False)
    s1: _Debounce = field(init=False)
    standstill: bool = False
    psd_closed: bool = True
    psd_operated: bool = False  # the PSD has opened under OK at this stop
    signal_open: bool = False
    last: PlatformLamps | None = None

    def __post_init__(self) -> None:
        if sorted(self.lamp_table) != [(False, False), (False, True), (True, False), (True, True)]:
            raise InterlockError("platform: the lamp table needs each (s2, s1) combination once")
        if any(lamp == "OK" and key != (True, False) for key, lamp in self.lamp_table.items()):
            raise InterlockError("platform: only (s2, s1) = (1, 0) may light OK")
        # [interpretation] A missed scan reads "no train", so an overrun train whose S1 misses
        # would look like one in the window. A sensor's reading counts only once it has read
        # the same ``debounce_scans`` times in a row since the train stopped: fewer misses in a
        # row than that cannot light OK (``verify.platform`` checks it); until both sensors
        # have settled, no lamp and no PSD.
        self.s2 = _Debounce(self.debounce_scans)
        self.s1 = _Debounce(self.debounce_scans)

    # ------------------------------------------------------------------ the rule

    def lamps(self) -> PlatformLamps:
        """What the platform shows now (a pure function of the unit's state)."""
        departure = self.psd_closed  # SPEC §3: departure only with the PSD closed (PSD master)
        if self.signal_open:
            return PlatformLamps(lamp=None, psd_enable=False, departure_permitted=departure)
        if not self.standstill:
            return PlatformLamps(lamp=None, psd_enable=False, departure_permitted=departure)
        s2, s1 = self.s2.state, self.s1.state
        if s2 is None or s1 is None:  # not settled since the stop: nothing yet
            return PlatformLamps(lamp=None, psd_enable=False, departure_permitted=departure)
        lamp = self.lamp_table[(s2, s1)]
        if lamp == "OK" and self.psd_operated and self.psd_closed:
            return PlatformLamps(lamp="S", psd_enable=False, departure_permitted=departure)
        if lamp == "fault":
            return PlatformLamps(lamp=None, psd_enable=False, departure_permitted=departure)
        return PlatformLamps(lamp=lamp, psd_enable=lamp == "OK", departure_permitted=departure)

    # ------------------------------------------------------------------ the contract

    def handle(self, message: Message, now_s: float) -> list[Output]:
        if isinstance(message, StopSensorScan):
            if message.standstill:
                # [interpretation] A train at a stand does not move: once both sensors have settled
                # after the stop, the lamp holds until the train moves again. Later readings at the
                # stand are noise or dropouts (a front standing within a sensor's noise of it would
                # otherwise flip OK and F / R, drop the relay and shut the PSD in front of open
                # train doors).
                if self.s2.state is None or self.s1.state is None:
                    self.s2.feed(message.s2)
                    self.s1.feed(message.s1)
            else:
                # Moving: a new stop (or a correction) starts afresh.
                self.s2.reset()
                self.s1.reset()
                self.psd_operated = False
            self.standstill = message.standstill
        elif isinstance(message, PsdDoorState):
            if not message.closed_locked and self.last is not None and self.last.psd_enable:
                self.psd_operated = True
            self.psd_closed = message.closed_locked
        elif isinstance(message, SignalOpenSwitch):
            self.signal_open = message.on
        else:
            raise InterlockError(f"platform: cannot take a {type(message).__name__}")
        now = self.lamps()
        if now == self.last:
            return []
        self.last = now
        return [Output(to=BROADCAST, message=now)]

    def next_deadline_s(self) -> float | None:
        return None

    def on_timer(self, now_s: float) -> list[Output]:
        return []


@dataclass(slots=True)
class PsdFollower:
    """SPEC §3 fig. 4: the PSD control. The PSD follows the train doors as the CCD camera sees
    them (``sensors.door_camera``: "open", "moving", "closed" = fully shut, or unreadable).

    * A shape counts once ``confirm_frames`` readable frames in a row show it, so a misread frame
      cannot move the PSD; unreadable frames neither confirm nor break a run.
    * **Opening** (SPEC §3: only while OK is lit): the PSD is told to open only with the relay
      energised and the doors confirmed open.
    * **Closing** (SPEC §5 order, train doors first, then the PSD; [interpretation] for SPEC §3,
      where no data link tells the platform that the train doors are locked): the PSD is told to
      close only once the doors count as **closed and locked**: a run of readable "closed"
      frames (an unreadable frame or any other shape starts it again) long enough that, with
      up to ``confirm_frames - 1`` misread frames at either end of it, it still holds
      ``lock_frames + 1`` true ones: the doors have stood shut for the lock time of the door
      data (the camera cannot see the locks). Until then a PSD that is open stays open: while
      the doors move ("moving"), while they are shut but not yet counted locked, and also when
      the relay drops
      ([interpretation] DESIGN rule 10, most restrictive for people on the platform: a PSD never
      closes on a train door that is not closed and locked; departure needs the PSD closed, so
      the train waits). Nothing opens without the relay.
    * ``lost_limit_frames`` unreadable frames in a row: the camera is lost and the doors' shape
      unknown. [interpretation] (DESIGN rule 10) the PSD is held where it is: a closed PSD stays
      closed, an open one open (closing it could shut passengers between the PSD and an open
      train door); the train is held until the camera sees again or staff close the PSD by hand.
    """

    confirm_frames: int = 3
    lost_limit_frames: int = 10
    lock_frames: int = 5
    name: str = "psd-control"
    accepts: tuple[type, ...] = (PlatformLamps, DoorCameraFrame)
    relay: bool = False
    shape: str | None = None  # the confirmed shape: "open", "moving", "closed"; None not known
    run_shape: str | None = None  # the shape of the current run of equal frames
    run: int = 0
    lost: int = 0
    closed_run: int = 0  # readable "closed" frames in a row, nothing else between
    command: PsdCommand = field(default_factory=lambda: PsdCommand(open=False, camera_ok=True))

    def __post_init__(self) -> None:
        if self.confirm_frames < 1 or self.lost_limit_frames < 1 or self.lock_frames < 0:
            raise InterlockError(
                "psd-control: confirm_frames and lost_limit_frames must be at least 1, lock_frames at least 0"
            )

    def camera_ok(self) -> bool:
        return self.lost < self.lost_limit_frames

    def locked_after_frames(self) -> int:
        """The "closed" frames in a row after which the doors count as closed and locked."""
        return 2 * (self.confirm_frames - 1) + self.lock_frames + 1

    def doors_locked(self) -> bool:
        """The train doors count as closed and locked (SPEC §3 / §5: what the PSD closes after)."""
        return self.closed_run >= self.locked_after_frames()

    def decide(self) -> PsdCommand:
        """The command now (a pure function of the state)."""
        ok = self.camera_ok()
        if self.doors_locked():
            return PsdCommand(open=False, camera_ok=ok)  # SPEC §5 order: train doors locked, then the PSD
        if self.relay and ok and self.shape == OPEN:
            return PsdCommand(open=True, camera_ok=ok)  # SPEC §3: follows the doors while OK is lit
        # Doors moving, shut but not yet counted locked, not known, or the relay off: nothing opens
        # and an open PSD stays open.
        return PsdCommand(open=self.command.open, camera_ok=ok)

    def handle(self, message: Message, now_s: float) -> list[Output]:
        bad: str | None = None
        if isinstance(message, PlatformLamps):
            self.relay = message.psd_enable
        elif isinstance(message, DoorCameraFrame):
            seen = message.shape
            if seen is not None and seen not in SHAPES:
                bad, seen = f"psd-control: a camera frame of unknown shape {seen!r}", None
            if seen is None:
                # Unreadable (or unknown: DESIGN rule 10, counted as unreadable).
                self.lost += 1
                self.closed_run = 0
                if not self.camera_ok():
                    self.shape, self.run_shape, self.run = None, None, 0
            else:
                self.lost = 0
                self.run = self.run + 1 if seen == self.run_shape else 1
                self.run_shape = seen
                if self.run >= self.confirm_frames:
                    self.shape = seen
                self.closed_run = self.closed_run + 1 if seen == CLOSED else 0
        else:
            raise InterlockError(f"psd-control: cannot take a {type(message).__name__}")
        now = self.decide()
        out: list[Output] = []
        if now != self.command:
            self.command = now
            out = [Output(to=BROADCAST, message=now)]
        if bad is not None:
            raise InterlockError(bad)  # the safe state (the frame counted unreadable) first
        return out

    def next_deadline_s(self) -> float | None:
        return None

    def on_timer(self, now_s: float) -> list[Output]:
        return []
