"""What every data schema shares: the strict base model, number types, and the field problem."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, model_validator

PositiveFloat = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Fraction = Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]


class Model(BaseModel):
    """Frozen, and unknown keys are rejected (DESIGN rule 6)."""

    model_config = ConfigDict(extra="forbid", frozen=True, str_strip_whitespace=True, strict=True)


class FieldProblem(ValueError):
    """A whole-model check that is about one field: the loader reports that field and its value."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(message)
        self.field = field


class Stretch(Model):
    """A stretch of the line from ``start_m`` to ``end_m`` (chainage, R direction), not empty."""

    # Chainage where the stretch starts (R direction).
    start_m: FiniteFloat
    # Chainage where it ends: greater than start_m.
    end_m: FiniteFloat

    @model_validator(mode="after")
    def _ordered(self) -> Stretch:
        if self.end_m <= self.start_m:
            raise FieldProblem("end_m", f"end_m must be greater than start_m ({self.start_m})")
        return self
