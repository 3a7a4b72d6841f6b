"""Data schemas and loaders (DESIGN rule 3): line, stations, vehicle."""

from __future__ import annotations

from railstop.config.loader import (
    default_line,
    default_vehicle,
    load_line,
    load_vehicle,
)
from railstop.config.schema import (
    BrakeModel,
    DopplerRadar,
    GradientSegment,
    Line,
    Station,
    TascZone,
    Vehicle,
)

__all__ = [
    "BrakeModel",
    "DopplerRadar",
    "GradientSegment",
    "Line",
    "Station",
    "TascZone",
    "Vehicle",
    "default_line",
    "default_vehicle",
    "load_line",
    "load_vehicle",
]
