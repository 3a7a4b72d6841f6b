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
from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from railstop.config.base import FieldProblem, Model
from railstop.config.loader import data_text, read_toml, validate

DEFAULT_PLATFORM = "platform.toml"

Bit = Literal[0, 1]
Lamp = Literal["F", "OK", "R", "fault"]
#: The lamps as numbers (the stop kernel's LAMP_*; 0: no lamp, 5: S).
LAMP_CODES: dict[str, int] = {"F": 1, "OK": 2, "R": 3, "fault": 4, "S": 5}
LAMP_NAMES: dict[int, str] = {v: k for k, v in LAMP_CODES.items()}


class StopSensors(Model):
    spacing_m: Annotated[float, Field(gt=0.0, le=5.0, allow_inf_nan=False)] = 0.75
    kind: Literal["optical", "ultrasonic"] = "optical"
    noise_sd_m: Annotated[float, Field(ge=0.0, le=0.5, allow_inf_nan=False)] = 0.005
    dropout_probability: Annotated[float, Field(ge=0.0, le=0.5, allow_inf_nan=False)] = 0.001
    scan_period_s: Annotated[float, Field(gt=0.0, le=1.0, allow_inf_nan=False)] = 0.05
    debounce_scans: Annotated[int, Field(ge=1, le=100)] = 3


def sensor_positions(stop_point_m: float, spacing_m: float) -> tuple[float, float]:
    """(S2, S1) chainages of the stop sensors (SPEC §3) for a train running in +chainage: S2 first,
    S1 ``spacing_m`` on.
    [interpretation] symmetric about the stopping point (see ``platform.toml``)."""
    return stop_point_m - 0.5 * spacing_m, stop_point_m + 0.5 * spacing_m


class DoorCamera(Model):
    """SPEC §3: the CCD camera that shows the PSD control the train doors' shape (open / closed)."""

    frame_period_s: Annotated[float, Field(gt=0.0, le=2.0, allow_inf_nan=False)] = 0.1
    processing_delay_s: Annotated[float, Field(ge=0.0, le=5.0, allow_inf_nan=False)] = 0.3
    open_fraction: Annotated[float, Field(gt=0.0, lt=1.0, allow_inf_nan=False)] = 0.3
    misread_probability: Annotated[float, Field(ge=0.0, lt=0.5, allow_inf_nan=False)] = 0.01
    lost_frame_probability: Annotated[float, Field(ge=0.0, lt=1.0, allow_inf_nan=False)] = 0.001
    confirm_frames: Annotated[int, Field(ge=1, le=100)] = 3
    lost_limit_frames: Annotated[int, Field(ge=1, le=1000)] = 10
    # SPEC §3 / §5 order (train doors closed and locked, then the PSD): the camera cannot see the
    # locks, so "closed" frames must go on this long before the doors count as locked.
    lock_confirm_s: Annotated[float, Field(ge=0.0, le=10.0, allow_inf_nan=False)] = 0.5

    @property
    def lock_frames(self) -> int:
        """Frames that span ``lock_confirm_s`` (rounded up: never shorter than the time)."""
        return math.ceil(self.lock_confirm_s / self.frame_period_s - 1e-9)


class LampRow(Model):
    s2: Bit
    s1: Bit
    lamp: Lamp


class ApproachCode(Model):
    """A speed code from a point on, held until the next one (SPEC §3)."""

    after_home_m: Annotated[float, Field(ge=0.0, le=2000.0, allow_inf_nan=False)]
    limit_kmh: Annotated[float, Field(gt=0.0, le=200.0, allow_inf_nan=False)]


class ApproachMode(Model):
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

    home_to_s2_m: Annotated[float, Field(gt=0.0, le=2000.0, allow_inf_nan=False)] = 204.25
    approach_limit_kmh: Annotated[float, Field(gt=0.0, le=200.0, allow_inf_nan=False)] = 70.0
    atc_permitted_margin_kmh: Annotated[float, Field(ge=0.0, le=50.0, allow_inf_nan=False)] = 5.0
    grace_s: Annotated[float, Field(ge=0.0, le=30.0, allow_inf_nan=False)] = 3.0
    ats: ApproachMode = Field(default_factory=ApproachMode)
    atc1: ApproachMode = Field(default_factory=ApproachMode)
    atc2: ApproachMode = Field(default_factory=ApproachMode)
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


class PlatformFile(Model):
    sensors: StopSensors = Field(default_factory=StopSensors)
    camera: DoorCamera = Field(default_factory=DoorCamera)
    lamp_table: list[LampRow]
    approach: Approach = Field(default_factory=Approach)

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
