"""Schema and loader of the platform data (``railstop/data/platform.toml``, SPEC §3).

The lamp table must give each of the four (S2, S1) combinations exactly one
lamp; it may not light OK for any combination but (S2, S1) = (1, 0): OK lets
the PSD operate, so the loader refuses a table that would open it anywhere
else.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, field_validator

from railstop.config.base import Model
from railstop.config.loader import data_text, read_toml, validate

DEFAULT_PLATFORM = "platform.toml"

Bit = Literal[0, 1]
Lamp = Literal["F", "OK", "R", "fault"]


class StopSensors(Model):
    spacing_m: Annotated[float, Field(gt=0.0, le=5.0, allow_inf_nan=False)] = 0.75
    kind: Literal["optical", "ultrasonic"] = "optical"
    noise_sd_m: Annotated[float, Field(ge=0.0, le=0.5, allow_inf_nan=False)] = 0.005
    dropout_probability: Annotated[float, Field(ge=0.0, le=0.5, allow_inf_nan=False)] = 0.001
    scan_period_s: Annotated[float, Field(gt=0.0, le=1.0, allow_inf_nan=False)] = 0.05
    debounce_scans: Annotated[int, Field(ge=1, le=100)] = 3


class LampRow(Model):
    s2: Bit
    s1: Bit
    lamp: Lamp


class PlatformFile(Model):
    sensors: StopSensors = Field(default_factory=StopSensors)
    lamp_table: list[LampRow]

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

    def lamps(self) -> dict[tuple[bool, bool], str]:
        return {(bool(r.s2), bool(r.s1)): r.lamp for r in self.lamp_table}


def load_platform(path: str | Path | None = None) -> tuple[PlatformFile, str]:
    """Load a platform data file (``None``: the embedded default); returns it and its source."""
    if path is None:
        source, data = data_text(DEFAULT_PLATFORM)
    else:
        source, data = str(path), read_toml(Path(path))
    return validate(PlatformFile, data, source), source
