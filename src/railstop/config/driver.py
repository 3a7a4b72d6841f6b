"""Schema and loader of the human driver's data (``railstop/data/driver.toml``, SPEC §3).

A run draws the driver's skill level with the levels' shares, then each
parameter from that level's distribution (``{normal = [mean, sd], clip = [lo,
hi]}`` or ``{fixed = x}``, the disturbance sets' syntax). The shares must add
up to 1. The arrays the compiled driver reads are made here
(:func:`driver_arrays`), so the kernel never sees a name.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Annotated

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, field_validator, model_validator

from railstop.config.base import FieldProblem, Model
from railstop.config.disturbances import Distribution
from railstop.config.loader import data_text, read_toml, validate
from railstop.quantities import kmh_to_mps

DEFAULT_DRIVER = "driver.toml"

#: The parameters of a level, in the order of the compiled driver's draws (onboard.driver DR_*).
LEVEL_PARAMETERS: tuple[str, ...] = (
    "reaction_s",
    "look_interval_s",
    "distance_bias_pct",
    "distance_noise_pct",
    "speed_read_sd_kmh",
    "planned_decel_mps2",
    "brake_start_fraction",
    "code_margin_kmh",
)
MAX_LEVELS = 8
# Per parameter: a lower bound every draw must respect (the driver must act, look, brake).
_FLOOR = {
    "reaction_s": 0.0,
    "look_interval_s": 0.05,
    "distance_noise_pct": 0.0,
    "speed_read_sd_kmh": 0.0,
    "planned_decel_mps2": 0.05,
    "brake_start_fraction": 0.05,
    "code_margin_kmh": 0.0,
}


def _normal_or_fixed(d: Distribution) -> Distribution:
    if d.kind not in ("normal", "fixed"):
        raise ValueError(
            f"a driver parameter is {{normal = [mean, sd], clip = [lo, hi]}} or {{fixed = x}}, not {d.kind}"
        )
    return d


class Level(Model):
    # The share of runs whose driver has this level of skill; the levels' shares add up to 1.
    share: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]
    # Perception-reaction time: what a look decides acts this long later; also the wait before a
    # re-stop.
    reaction_s: Distribution
    # Time between the driver's looks at speed, distance and marks.
    look_interval_s: Distribution
    # The run's systematic misjudgement of the distance left, a share of it (Weber's law).
    distance_bias_pct: Distribution
    # The look-to-look scatter of the judged distance on top of the bias, a share of it.
    distance_noise_pct: Distribution
    # The scatter (standard deviation) of one reading of the speedometer.
    speed_read_sd_kmh: Distribution
    # The deceleration the driver plans the stop with.
    planned_decel_mps2: Distribution
    # Braking starts when the deceleration needed to stop at the mark reaches this share of
    # planned_decel_mps2 (before it, traction holds the speed).
    brake_start_fraction: Distribution
    # How far below a speed code the driver aims to pass its point.
    code_margin_kmh: Distribution

    @field_validator(*LEVEL_PARAMETERS)
    @classmethod
    def _kind(cls, d: Distribution) -> Distribution:
        return _normal_or_fixed(d)

    @model_validator(mode="after")
    def _floors(self) -> Level:
        for name, floor in _FLOOR.items():
            lo, _ = bounds(getattr(self, name))
            if lo < floor:
                raise FieldProblem(
                    name, f"{name} must not be drawn below {floor:g} (its lowest value is {lo:g}; clip it)"
                )
        return self


class Restop(Model):
    # SPEC §3 re-stop after the F or R lamp: the driver moves the train at this walking pace.
    creep_speed_kmh: Annotated[float, Field(gt=0.0, le=15.0, allow_inf_nan=False)] = 3.0
    # The acceleration up to the creep speed.
    creep_accel_mps2: Annotated[float, Field(gt=0.0, le=1.5, allow_inf_nan=False)] = 0.3
    # The deceleration from the creep speed to a stand.
    creep_decel_mps2: Annotated[float, Field(gt=0.0, le=1.5, allow_inf_nan=False)] = 0.5
    # The distance the driver moves, judged from the platform marks, is off by this share of the
    # true distance (standard deviation), per correction.
    judgement_sd_pct: Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)] = 15.0
    # A further error of the judged distance (standard deviation) on top of judgement_sd_pct.
    judgement_floor_sd_m: Annotated[float, Field(ge=0.0, le=5.0, allow_inf_nan=False)] = 0.08
    # Before reversing (the R lamp): the time to set the reverser and get the control room's
    # permission.
    reverse_setup_s: Annotated[float, Field(ge=0.0, le=600.0, allow_inf_nan=False)] = 8.0
    # After an emergency brake: the time the driver takes to reset it before moving again.
    eb_reset_s: Annotated[float, Field(ge=0.0, le=600.0, allow_inf_nan=False)] = 20.0
    # After this many corrections without OK the driver gives up: the PSD stays closed (the train
    # is counted as not aligned).
    max_restops: Annotated[int, Field(ge=0, le=10)] = 3
    # [interpretation] A forward correction longer than this (a train stopped far short, e.g. by
    # an emergency brake) is driven at the held code less the driver's margin, not at walking pace.
    drive_beyond_m: Annotated[float, Field(gt=0.0, le=1000.0, allow_inf_nan=False)] = 20.0


class Running(Model):
    # [interpretation] A train too slow for the distance left to the stopping point (braked early,
    # below a speed code) is powered up again: the driver takes power at this acceleration (a low
    # notch, well under the vehicle's full traction) ...
    power_accel_mps2: Annotated[float, Field(gt=0.0, le=1.5, allow_inf_nan=False)] = 0.4
    # ... when the speed reads more than this below the speed he aims at: the lowest of the held
    # code, the next code point's and the speed from which a light brake stops at the mark.
    power_band_kmh: Annotated[float, Field(gt=0.0, le=20.0, allow_inf_nan=False)] = 2.0


class DriverFile(Model):
    # The levels of skill by name (at most 8); a run draws one with their shares.
    levels: dict[str, Level]
    # How the driver re-stops after the F or R lamp (all levels alike).
    restop: Restop = Field(default_factory=Restop)
    # How the driver keeps the train moving in the approach (all levels alike).
    running: Running = Field(default_factory=Running)

    @field_validator("levels")
    @classmethod
    def _shares(cls, levels: dict[str, Level]) -> dict[str, Level]:
        if not levels:
            raise ValueError("at least one skill level is needed")
        if len(levels) > MAX_LEVELS:
            raise ValueError(f"at most {MAX_LEVELS} skill levels")
        total = sum(lv.share for lv in levels.values())
        if not math.isclose(total, 1.0, abs_tol=1e-9):
            raise ValueError(f"the levels' shares must add up to 1 (they add up to {total:g})")
        return levels


def bounds(d: Distribution) -> tuple[float, float]:
    """The range of a draw (a normal without clip is unbounded)."""
    if d.fixed is not None:
        return d.fixed, d.fixed
    if d.clip is not None:
        return d.clip
    return -math.inf, math.inf


def load_driver(path: str | Path | None = None) -> tuple[DriverFile, str]:
    """Load a driver data file (``None``: the embedded default); returns it and its source."""
    if path is None:
        source, data = data_text(DEFAULT_DRIVER)
    else:
        source, data = str(path), read_toml(Path(path))
    return validate(DriverFile, data, source), source


@functools.cache
def default_driver() -> DriverFile:
    return load_driver()[0]


# Columns of a level's row in the compiled driver's level table: the cumulative share, then per
# parameter (mean, sd, lo, hi) in LEVEL_PARAMETERS order.
LV_CUMULATIVE = 0
LV_PARAMS = 1
LV_WIDTH = 4


def driver_arrays(driver: DriverFile) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(level table, re-stop and running vector) for the compiled driver (onboard.driver RS_*)."""
    table = np.zeros((len(driver.levels), LV_PARAMS + LV_WIDTH * len(LEVEL_PARAMETERS)))
    cumulative = 0.0
    for i, level in enumerate(driver.levels.values()):
        cumulative += level.share
        table[i, LV_CUMULATIVE] = cumulative
        for j, name in enumerate(LEVEL_PARAMETERS):
            d: Distribution = getattr(level, name)
            lo, hi = bounds(d)
            mean, sd = (d.fixed, 0.0) if d.fixed is not None else d.normal  # type: ignore[misc]
            table[i, LV_PARAMS + LV_WIDTH * j : LV_PARAMS + LV_WIDTH * (j + 1)] = (mean, sd, lo, hi)
    table[-1, LV_CUMULATIVE] = 1.0  # the last level takes what rounding leaves
    r = driver.restop
    restop = np.array(
        [
            kmh_to_mps(r.creep_speed_kmh),
            r.creep_accel_mps2,
            r.creep_decel_mps2,
            r.judgement_sd_pct / 100.0,
            r.judgement_floor_sd_m,
            r.reverse_setup_s,
            float(r.max_restops),
            r.eb_reset_s,
            driver.running.power_accel_mps2,
            kmh_to_mps(driver.running.power_band_kmh),
            r.drive_beyond_m,
        ]
    )
    return table, restop


__all__ = ["DriverFile", "Level", "Restop", "Running", "default_driver", "driver_arrays", "load_driver"]
