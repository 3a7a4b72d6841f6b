"""Schema and loader of the platform data (``railstop/data/platform.toml``, SPEC §3).

The lamp table must give each of the four (S2, S1) combinations exactly one
lamp; it may not light OK for any combination but (S2, S1) = (1, 0): OK lets
the PSD operate, so the loader refuses a table that would open it anywhere
else.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import Field, field_validator, model_validator

from railstop.config.base import FieldProblem, Model
from railstop.config.loader import data_text, read_toml, validate
from railstop.controllers import DRIVER_CONTROLLERS

if TYPE_CHECKING:
    from railstop.config.schema import Station

DEFAULT_PLATFORM = "platform.toml"

Bit = Literal[0, 1]
Lamp = Literal["F", "OK", "R", "fault"]
#: The lamps as numbers (the stop kernel's LAMP_*; 0: no lamp, 5: S).
LAMP_CODES: dict[str, int] = {"F": 1, "OK": 2, "R": 3, "fault": 4, "S": 5}
LAMP_NAMES: dict[int, str] = {v: k for k, v in LAMP_CODES.items()}


class StopSensors(Model):
    # SPEC §3: the distance from stop sensor S2 to S1, placed symmetrically about the stopping point
    # (S2 first in the running direction).
    spacing_m: Annotated[float, Field(gt=0.0, le=5.0, allow_inf_nan=False)] = 0.75
    # SPEC §3: optical or ultrasonic time of flight against a reflector; checked against the list,
    # not read by the simulation (noise_sd_m sets the sensors' accuracy).
    kind: Literal["optical", "ultrasonic"] = "optical"
    # Where a sensor sees the train's front: off the truth by this (standard deviation), per scan.
    noise_sd_m: Annotated[float, Field(ge=0.0, le=0.5, allow_inf_nan=False)] = 0.005
    # The chance that a scan misses a train in front of the sensor (it reads "no train").
    dropout_probability: Annotated[float, Field(ge=0.0, le=0.5, allow_inf_nan=False)] = 0.001
    # The sensors are scanned once per this period.
    scan_period_s: Annotated[float, Field(gt=0.0, le=1.0, allow_inf_nan=False)] = 0.05
    # A sensor's state changes only after this many equal scans in a row.
    debounce_scans: Annotated[int, Field(ge=1, le=100)] = 3


def sensor_positions(stop_point_m: float, spacing_m: float) -> tuple[float, float]:
    """(S2, S1) chainages of the stop sensors (SPEC §3) for a train running in +chainage: S2 first,
    S1 ``spacing_m`` on.
    [interpretation] symmetric about the stopping point (see ``platform.toml``)."""
    return stop_point_m - 0.5 * spacing_m, stop_point_m + 0.5 * spacing_m


class DoorCamera(Model):
    """SPEC §3: the CCD camera that shows the PSD control the train doors' shape (open / closed)."""

    # SPEC §3 CCD camera: it delivers a frame once per this period.
    frame_period_s: Annotated[float, Field(gt=0.0, le=2.0, allow_inf_nan=False)] = 0.1
    # Each frame shows the doors as they were this long before it is delivered (grab and compare
    # with the stored shapes: the camera's detection delay).
    processing_delay_s: Annotated[float, Field(ge=0.0, le=5.0, allow_inf_nan=False)] = 0.3
    # A frame shows "open" once the leaves are at least this fraction of the way open ("moving"
    # between shut and this, "closed" only fully shut).
    open_fraction: Annotated[float, Field(gt=0.0, lt=1.0, allow_inf_nan=False)] = 0.3
    # The chance that a frame is classified as one of the other two shapes (each equally likely).
    misread_probability: Annotated[float, Field(ge=0.0, lt=0.5, allow_inf_nan=False)] = 0.01
    # The chance that a frame is unreadable or not delivered.
    lost_frame_probability: Annotated[float, Field(ge=0.0, lt=1.0, allow_inf_nan=False)] = 0.001
    # The PSD control takes a new shape only after this many equal frames in a row.
    confirm_frames: Annotated[int, Field(ge=1, le=100)] = 3
    # This many unreadable frames in a row is a lost camera: the PSD is held where it is and the
    # train is not given departure while it is open (DESIGN rule 10).
    lost_limit_frames: Annotated[int, Field(ge=1, le=1000)] = 10
    # SPEC §3 / §5 order (train doors closed and locked, then the PSD): the camera cannot see the
    # locks, so "closed" frames must go on this long before the doors count as locked.
    lock_confirm_s: Annotated[float, Field(ge=0.0, le=10.0, allow_inf_nan=False)] = 0.5

    @property
    def lock_frames(self) -> int:
        """Frames that span ``lock_confirm_s`` (rounded up: never shorter than the time)."""
        return math.ceil(self.lock_confirm_s / self.frame_period_s - 1e-9)


class LampRow(Model):
    # SPEC §3 lamp table: whether sensor S2 sees the train, 0 or 1.
    s2: Bit
    # Whether sensor S1 sees the train, 0 or 1.
    s1: Bit
    # The lamp for this (S2, S1) at standstill: "F" move forward, "OK" in position (the PSD may
    # operate; only for S2 = 1, S1 = 0), "R" reverse, "fault" none and the PSD held closed.
    lamp: Lamp


#: A driver's run starts this far before the home signal ([interpretation]: far enough to meet the
#: codes of the block before it and to settle at the approach limit); no code point may lie before.
START_BEFORE_HOME_M = 300.0


class ApproachCode(Model):
    """A speed code from a point on, held until the next one (SPEC §3)."""

    # Where the code starts: this far beyond the home signal (negative: before it, in the block
    # that leads to it), before the stop sensors and after the start of a driver's run (300 m
    # before the home signal).
    after_home_m: Annotated[float, Field(gt=-START_BEFORE_HOME_M, le=2000.0, allow_inf_nan=False)]
    # The code's speed limit, held until the next code's point.
    limit_kmh: Annotated[float, Field(gt=0.0, le=200.0, allow_inf_nan=False)]


class ApproachMode(Model):
    # The mode's speed codes in running order, one per point (empty: no station codes).
    codes: list[ApproachCode] = Field(default_factory=list)

    @field_validator("codes")
    @classmethod
    def _ordered(cls, codes: list[ApproachCode]) -> list[ApproachCode]:
        points = [c.after_home_m for c in codes]
        if points != sorted(points) or len(set(points)) != len(points):
            raise ValueError(f"codes must be in running order, one per point (after_home_m {points})")
        return codes


class Approach(Model):
    """The approach of a manually driven train (SPEC §3 figs. 3 and 5), from the home signal."""

    # SPEC §3 fig. 3: the stop sensor S2 stands this far beyond the home signal (the station-entry
    # signal); the codes' points are measured from the home signal.
    home_to_s2_m: Annotated[float, Field(gt=0.0, le=2000.0, allow_inf_nan=False)] = 204.25
    # The speed limit before the first code (from the block before the home signal; SPEC §3: "60 ->
    # 45 km/h" at Code 45); the driver aims to run at it less his margin. A run's drawn entry speed
    # is capped there.
    approach_limit_kmh: Annotated[float, Field(gt=0.0, le=200.0, allow_inf_nan=False)] = 60.0
    # ATC modes: the permitted speed is the indicated speed plus this; above it the emergency brake
    # applies at once.
    atc_permitted_margin_kmh: Annotated[float, Field(ge=0.0, le=50.0, allow_inf_nan=False)] = 5.0
    # SPEC §3: a train over the limit (ATS) or above the indicated speed (ATC) for this long gets the
    # emergency brake.
    grace_s: Annotated[float, Field(ge=0.0, le=30.0, allow_inf_nan=False)] = 3.0
    # SPEC §3 fig. 3: the codes of the ATS accurate stop (controller driver-ats).
    ats: ApproachMode = Field(default_factory=ApproachMode)
    # SPEC §3 fig. 5, ATC option 1 (controller driver-atc1).
    atc1: ApproachMode = Field(default_factory=ApproachMode)
    # SPEC §3 fig. 5, ATC option 2 (controller driver-atc2).
    atc2: ApproachMode = Field(default_factory=ApproachMode)
    # No station codes: the driver stops by the platform marks alone (controller driver-unaided).
    unaided: ApproachMode = Field(default_factory=ApproachMode)

    @model_validator(mode="after")
    def _before_sensors(self) -> Approach:
        for mode in ("ats", "atc1", "atc2", "unaided"):
            for code in getattr(self, mode).codes:
                if code.after_home_m >= self.home_to_s2_m:
                    raise FieldProblem(
                        mode,
                        f"a code point at {code.after_home_m:g} m is not before the stop sensors "
                        f"({self.home_to_s2_m:g} m from the home signal)",
                    )
        return self


#: Sensor noise within this many standard deviations counts when the OK window is checked
#: against the PSD tolerance (``PlatformFile``).
OK_WINDOW_SIGMAS = 3.0


class PlatformFile(Model):
    # SPEC §3: the door / PSD stop tolerance of the manually driven lines (±500 mm). A driver
    # controller's stop is judged by it: the station as fitted for manual driving (its sensors,
    # lamps and PSD); the OK window (half the sensor spacing and 3 sd of their noise) must lie
    # inside it, or OK could light, and the PSD open, with the train outside the tolerance.
    psd_tolerance_m: Annotated[float, Field(gt=0.0, le=2.0, allow_inf_nan=False)] = 0.50
    # SPEC §3: the two platform stop sensors S2 and S1.
    sensors: StopSensors = Field(default_factory=StopSensors)
    # SPEC §3: the CCD camera through which the PSD follows the train doors.
    camera: DoorCamera = Field(default_factory=DoorCamera)
    # SPEC §3: the lamp for each of the four (S2, S1) combinations, once each; only (1, 0) may light OK.
    lamp_table: list[LampRow]
    # SPEC §3: the approach of a manually driven train from the home signal, per driving mode.
    approach: Approach = Field(default_factory=Approach)

    @model_validator(mode="after")
    def _ok_inside_tolerance(self) -> PlatformFile:
        half = 0.5 * self.sensors.spacing_m + OK_WINDOW_SIGMAS * self.sensors.noise_sd_m
        if half > self.psd_tolerance_m + 1e-12:
            raise FieldProblem(
                "sensors.spacing_m",
                f"{self.sensors.spacing_m:g} m apart (noise {self.sensors.noise_sd_m:g} m) the sensors light "
                f"OK up to ±{half:.3f} m from the stopping point, outside psd_tolerance_m "
                f"(±{self.psd_tolerance_m:g} m): the PSD could open with the train out of position",
            )
        return self

    @field_validator("lamp_table")
    @classmethod
    def _four(cls, rows: list[LampRow]) -> list[LampRow]:
        keys = [(r.s2, r.s1) for r in rows]
        if sorted(keys) != [(0, 0), (0, 1), (1, 0), (1, 1)]:
            raise ValueError(f"need each (s2, s1) combination exactly once, got {keys}")
        for r in rows:
            if r.lamp == "OK" and (r.s2, r.s1) != (1, 0):
                raise ValueError(
                    f"OK lets the PSD operate: only (s2, s1) = (1, 0) may light it, not ({r.s2}, {r.s1})"
                )
        return rows

    def home_signal_m(self, stop_point_m: float) -> float:
        """The home signal's chainage for a stopping point: SPEC §3 fig. 3 puts S2
        ``approach.home_to_s2_m`` beyond it (S2 from :func:`sensor_positions`)."""
        s2, _ = sensor_positions(stop_point_m, self.sensors.spacing_m)
        return s2 - self.approach.home_to_s2_m

    def lamps(self) -> dict[tuple[bool, bool], str]:
        return {(bool(r.s2), bool(r.s1)): r.lamp for r in self.lamp_table}


def stop_tolerance(station: Station, controller: str, platform: PlatformFile | None = None) -> float:
    """The PSD tolerance a stop of ``controller`` at ``station`` is judged by: a driver controller's
    platform's (SPEC §3, ``platform`` or the embedded one), any other's the station's (the line
    file's ``psd_tolerance_m``, SPEC §1)."""
    if controller in DRIVER_CONTROLLERS:
        return (platform or default_platform()).psd_tolerance_m
    return station.psd_tolerance_m


@functools.cache
def default_platform() -> PlatformFile:
    return load_platform()[0]


def load_platform(path: str | Path | None = None) -> tuple[PlatformFile, str]:
    """Load a platform data file (``None``: the embedded default); returns it and its source."""
    if path is None:
        source, data = data_text(DEFAULT_PLATFORM)
    else:
        source, data = str(path), read_toml(Path(path))
    return validate(PlatformFile, data, source), source
