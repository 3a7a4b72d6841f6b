"""A simple, deterministic run profile between stations, over arrays of runs (DESIGN rule 1).

To drive a train over a whole line (SPEC §2 position correction is about the
runs *between* the stations) this driver repeats, station after station:

1. **accelerate** at the traction's aim until ``speed_limit - cruise_margin``;
2. **cruise** at that speed (traction balances resistance and gradient);
3. **coast** from ``coast_time_s`` of travel before the braking point;
4. **brake** once the deceleration needed to stop at the station's stopping
   point, ``v² / (2 · distance to go)``, reaches ``service_decel_mps2``
   (SPEC "typical values": a TASC-like target of 0.7 m/s²); the brake demand
   is then that needed deceleration less resistance and gradient, up to full
   service: a closed loop that lands on the stopping point;
5. **dwell** ``dwell_s`` at the station, then depart for the next one.

It steers by the *true* position: it stands for a competent driver or ATO
with perfect position so that the odometer study is not mixed with a
stopping-accuracy study **[interpretation]** (the campaign's controllers do
the latter). Brake and traction act at once (no dead time): their dynamics
matter for stopping accuracy, not for how an odometer drifts.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

KMH = 1.0 / 3.6


class Phase(IntEnum):
    DWELL = 0
    ACCEL = 1
    CRUISE = 2
    COAST = 3
    BRAKE = 4
    DONE = 5


@dataclass(frozen=True, slots=True, kw_only=True)
class RunProfileSettings:
    speed_limit_mps: float
    cruise_margin_mps: float = 2.0 * KMH  # cruise this far below the limit (overspeed margin)
    service_decel_mps2: float = 0.7  # SPEC typical values: TASC target ~0.7 m/s²
    full_service_mps2: float = 1.0
    coast_time_s: float = 6.0
    dwell_s: float = 25.0
    cruise_gain_per_s: float = 0.5  # speed-error feedback while cruising

    def __post_init__(self) -> None:
        if self.speed_limit_mps <= self.cruise_margin_mps:
            raise ValueError(f"speed_limit_mps must exceed the cruise margin, got {self.speed_limit_mps}")
        if not 0.0 < self.service_decel_mps2 <= self.full_service_mps2:
            raise ValueError(
                f"service_decel_mps2 must be in (0, full_service_mps2], got {self.service_decel_mps2}"
            )
        if self.dwell_s < 0.0 or self.coast_time_s < 0.0:
            raise ValueError("dwell_s and coast_time_s must not be negative")


@dataclass(frozen=True, slots=True, kw_only=True)
class ProfileCommand:
    """What the driver asks for in one step (n runs)."""

    traction_mps2: FloatArray  # demanded traction acceleration (>= 0)
    brake_mps2: FloatArray  # demanded braking deceleration (>= 0)
    depart: BoolArray  # runs that leave a station (or start) in this step: release the holding brake


class RunProfile:
    """Accelerate / cruise / coast / brake to each stopping point in turn, for n runs."""

    def __init__(
        self, settings: RunProfileSettings, stops_m: FloatArray, n: int, start_position_m: FloatArray
    ) -> None:
        stops = np.asarray(stops_m, dtype=np.float64)
        if stops.ndim != 1 or stops.size == 0 or np.any(np.diff(stops) <= 0.0):
            raise ValueError("stops_m must be a non-empty, strictly increasing list of stopping points")
        x0 = np.broadcast_to(np.asarray(start_position_m, dtype=np.float64), (n,))
        self.settings = settings
        self.stops_m = stops
        self.target = np.searchsorted(stops, x0 + 1.0).astype(np.int64)  # next stop ahead
        self.phase = np.where(self.target < stops.size, Phase.DWELL, Phase.DONE).astype(np.int64)
        self.dwell_until_s = np.zeros(n)  # the first departure is at t = 0
        self.arrival_s = np.full((n, stops.size), np.nan)

    @property
    def done(self) -> BoolArray:
        return self.phase == Phase.DONE

    def command(
        self,
        *,
        t_s: float,
        position_m: FloatArray,
        speed_mps: FloatArray,
        stopped: BoolArray,
        resist_mps2: FloatArray,
    ) -> ProfileCommand:
        """The demand for the step starting at ``t_s``; ``resist_mps2`` = (resistance + gradient) / m_eff."""
        cfg = self.settings
        v = np.asarray(speed_mps, dtype=np.float64)
        ph = self.phase
        n_stops = self.stops_m.size

        # Arrival: a braking run that has come to rest dwells.
        arrived = (ph == Phase.BRAKE) & stopped
        if arrived.any():
            rows = np.flatnonzero(arrived)
            self.arrival_s[rows, self.target[rows]] = t_s
        ph = np.where(arrived, Phase.DWELL, ph)
        self.dwell_until_s = np.where(arrived, t_s + cfg.dwell_s, self.dwell_until_s)
        self.target = np.where(arrived, self.target + 1, self.target)
        ph = np.where(arrived & (self.target >= n_stops), Phase.DONE, ph)

        depart = (ph == Phase.DWELL) & (t_s >= self.dwell_until_s)
        ph = np.where(depart, Phase.ACCEL, ph)

        tgt = np.minimum(self.target, n_stops - 1)
        to_go = self.stops_m[tgt] - np.asarray(position_m, dtype=np.float64)
        needed = np.where(to_go > 0.0, v * v / (2.0 * np.maximum(to_go, 1e-3)), np.inf)
        running = (ph == Phase.ACCEL) | (ph == Phase.CRUISE) | (ph == Phase.COAST)
        # Brake when stopping at the service rate needs it (v² / 2 d >= b_service).
        ph = np.where(running & (needed >= cfg.service_decel_mps2), Phase.BRAKE, ph)
        coast_from = v * v / (2.0 * cfg.service_decel_mps2) + v * cfg.coast_time_s
        powered = (ph == Phase.ACCEL) | (ph == Phase.CRUISE)
        ph = np.where(powered & (to_go <= coast_from), Phase.COAST, ph)
        cruise_v = cfg.speed_limit_mps - cfg.cruise_margin_mps
        ph = np.where((ph == Phase.ACCEL) & (v >= cruise_v), Phase.CRUISE, ph)
        self.phase = ph.astype(np.int64)

        traction = np.where(
            ph == Phase.ACCEL,
            np.inf,  # the traction model caps it at its aim and its curve
            np.where(
                ph == Phase.CRUISE,
                np.maximum(0.0, resist_mps2 + cfg.cruise_gain_per_s * (cruise_v - v)),
                0.0,
            ),
        )
        brake_needed = np.where(np.isfinite(needed), needed - resist_mps2, cfg.full_service_mps2)
        # Cruising or coasting downhill: hold the cruise speed (cruising) or the limit (coasting).
        hold_v = np.where(ph == Phase.CRUISE, cruise_v, cfg.speed_limit_mps)
        hold = np.maximum(0.0, -resist_mps2 - cfg.cruise_gain_per_s * (hold_v - v))
        brake = np.where(
            ph == Phase.BRAKE,
            np.clip(brake_needed, 0.0, cfg.full_service_mps2),
            np.where(
                (ph == Phase.CRUISE) | (ph == Phase.COAST), np.minimum(hold, cfg.full_service_mps2), 0.0
            ),
        )
        # A train at rest (dwelling or done) is held by its brake.
        brake = np.where((ph == Phase.DWELL) | (ph == Phase.DONE), cfg.full_service_mps2, brake)
        return ProfileCommand(traction_mps2=traction, brake_mps2=brake, depart=depart)
