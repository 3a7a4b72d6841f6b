"""Faults as data (SPEC §4 communication loss): a TOML file for ``railstop line run --faults FILE``.

::

    # The CBTC radio of train 3 (0 = the first train to enter) is dead for 20 s.
    [[radio_outage]]
    train = 3
    start_s = 900.0
    duration_s = 20.0

    # Every train's radio: fades in bursts (Gilbert-Elliott: enter, leave, loss while bad).
    [radio]
    burst_enter_probability = 0.01
    burst_exit_probability = 0.3
    burst_loss_probability = 0.8

    # The zone controller restarts at 1200 s (every train it knew is lost at once).
    [[zc_restart]]
    at_s = 1200.0

    # Outages drawn at random: each train, with this chance, loses its radio once, for a
    # duration uniform in [min_s, max_s], at a time uniform in its first ``within_s`` on the line.
    [random_outages]
    probability = 0.1
    min_s = 5.0
    max_s = 30.0

Unknown keys are refused; a problem names the file, the field and the value.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import Field, model_validator

from railstop.config.base import FieldProblem, Model
from railstop.config.loader import read_toml, validate


class RadioOutage(Model):
    # The train whose CBTC radio is dead, by its index (0 = the first train to enter).
    train: Annotated[int, Field(ge=0, le=199)]
    # When the outage starts, in the line run's time.
    start_s: Annotated[float, Field(ge=0.0, le=1e6, allow_inf_nan=False)]
    # How long the radio is dead from then.
    duration_s: Annotated[float, Field(gt=0.0, le=1e5, allow_inf_nan=False)]


class RadioFaults(Model):
    """Changes to the CBTC radio medium of every train (``cbtc-radio`` of media.toml): loss per
    frame and Gilbert-Elliott bursts (railstop.link.channel)."""

    # Replaces the medium's independent loss per frame (None: the medium's own value).
    loss_probability: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] | None = None
    # Replaces the Gilbert-Elliott chance per frame of going from good to bad (None: the medium's).
    burst_enter_probability: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] | None = None
    # Replaces the chance per frame of going from bad back to good (None: the medium's).
    burst_exit_probability: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] | None = None
    # Replaces the loss of a frame sent in the bad state (None: the medium's).
    burst_loss_probability: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] | None = None

    def changes(self) -> dict[str, float]:
        return {k: v for k, v in self.model_dump().items() if v is not None}


class ControllerRestartFault(Model):
    # When the zone controller restarts (line run time): every train it tracked is lost at once and
    # re-detected by its next report (SPEC §4).
    at_s: Annotated[float, Field(ge=0.0, le=1e6, allow_inf_nan=False)]


class RandomOutages(Model):
    # The chance of each train losing its CBTC radio once, drawn per train from the seed (0: none).
    probability: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = 0.0
    # The shortest outage: its duration is uniform in [min_s, max_s].
    min_s: Annotated[float, Field(gt=0.0, le=3600.0, allow_inf_nan=False)] = 5.0
    # The longest outage, at least min_s.
    max_s: Annotated[float, Field(gt=0.0, le=3600.0, allow_inf_nan=False)] = 30.0
    # When, after the train asks to enter: uniform in [60 s, 60 s + within_s] (on the line).
    within_s: Annotated[float, Field(gt=0.0, le=86400.0, allow_inf_nan=False)] = 480.0

    @model_validator(mode="after")
    def _order(self) -> RandomOutages:
        if self.max_s < self.min_s:
            raise FieldProblem("max_s", f"must not be less than min_s ({self.min_s})")
        return self


class Faults(Model):
    # Outages of given trains' CBTC radio (SPEC §4 communication loss).
    radio_outage: list[RadioOutage] = Field(default_factory=list)
    # Outages drawn at random, at most one per train.
    random_outages: RandomOutages = Field(default_factory=RandomOutages)
    # Restarts of the zone controller.
    zc_restart: list[ControllerRestartFault] = Field(default_factory=list)
    # Changes to the CBTC radio medium (cbtc-radio of media.toml) of every train: loss and bursts.
    radio: RadioFaults = Field(default_factory=RadioFaults)

    def restarts(self) -> list[float]:
        return sorted(r.at_s for r in self.zc_restart)

    def outages(self) -> list[tuple[int, float, float]]:
        return [(o.train, o.start_s, o.duration_s) for o in self.radio_outage]


def load_faults(path: str | Path | None) -> Faults:
    """A faults file (``None``: no faults)."""
    if path is None:
        return Faults()
    return validate(Faults, read_toml(Path(path)), str(path))
