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
    train: Annotated[int, Field(ge=0, le=199)]
    start_s: Annotated[float, Field(ge=0.0, le=1e6, allow_inf_nan=False)]
    duration_s: Annotated[float, Field(gt=0.0, le=1e5, allow_inf_nan=False)]


class RadioFaults(Model):
    """Changes to the CBTC radio medium of every train (``cbtc-radio`` of media.toml): loss per
    frame and Gilbert-Elliott bursts (railstop.link.channel)."""

    loss_probability: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] | None = None
    burst_enter_probability: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] | None = None
    burst_exit_probability: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] | None = None
    burst_loss_probability: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] | None = None

    def changes(self) -> dict[str, float]:
        return {k: v for k, v in self.model_dump().items() if v is not None}


class ControllerRestartFault(Model):
    at_s: Annotated[float, Field(ge=0.0, le=1e6, allow_inf_nan=False)]


class RandomOutages(Model):
    probability: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = 0.0
    min_s: Annotated[float, Field(gt=0.0, le=3600.0, allow_inf_nan=False)] = 5.0
    max_s: Annotated[float, Field(gt=0.0, le=3600.0, allow_inf_nan=False)] = 30.0
    # When, after the train asks to enter: uniform in [60 s, 60 s + within_s] (on the line).
    within_s: Annotated[float, Field(gt=0.0, le=86400.0, allow_inf_nan=False)] = 480.0

    @model_validator(mode="after")
    def _order(self) -> RandomOutages:
        if self.max_s < self.min_s:
            raise FieldProblem("max_s", f"must not be less than min_s ({self.min_s})")
        return self


class Faults(Model):
    radio_outage: list[RadioOutage] = Field(default_factory=list)
    random_outages: RandomOutages = Field(default_factory=RandomOutages)
    zc_restart: list[ControllerRestartFault] = Field(default_factory=list)
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
