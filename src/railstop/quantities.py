"""Speeds at the edges (DESIGN rule 8): the model works in m/s; km/h appears only where a person
reads or writes a speed (data files, the CLI, reports), through these helpers.

A foundation module: it imports nothing of railstop. The constants are plain floats, so compiled
(numba) code may use them as globals.
"""

from __future__ import annotations

#: km/h in one m/s (exact: 3600 s / 1000 m).
KMH_PER_MPS = 3.6
#: m/s in one km/h.
MPS_PER_KMH = 1.0 / KMH_PER_MPS


def kmh_to_mps(speed_kmh: float) -> float:
    """A speed in km/h as m/s."""
    return speed_kmh / KMH_PER_MPS


def mps_to_kmh(speed_mps: float) -> float:
    """A speed in m/s as km/h."""
    return speed_mps * KMH_PER_MPS
