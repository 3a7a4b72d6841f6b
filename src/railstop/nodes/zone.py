"""The zone controller node (SPEC §4): one ZoneController built from the line data (its
segments, its fixed blocks for the conventional zones, civil limits and gradients), the same in
the line simulation and live."""

from __future__ import annotations

from railstop.config.schema import Line, Vehicle
from railstop.quantities import kmh_to_mps
from railstop.wayside.zone_controller import ZoneController, ZoneMode


def civil_limit_mps(line: Line, x_m: float) -> float:
    """The line's own speed limit, or a lower civil limit over ``x_m``."""
    limit = line.line.speed_limit_kmh
    for s in line.speed_limits:
        if s.start_m <= x_m < s.end_m:
            limit = min(limit, s.limit_kmh)
    return kmh_to_mps(limit)


def gradient_permille(line: Line, x_m: float) -> float:
    """The gradient at ``x_m`` (+ uphill in R) where the stations' data give one, else 0 (the
    line's data carry gradients only in the station zones)."""
    for st in line.stations:
        for g in st.gradient:
            if g.start_m <= x_m < g.end_m:
                return float(g.permille)
    return 0.0


def make_zone_controller(line: Line, vehicle: Vehicle, mode: ZoneMode) -> ZoneController:
    """The line's zone controller (SPEC §4): its segments, its fixed blocks (for the conventional
    zones), civil limits and gradients from the line data; the same in the line simulation and live."""
    sig = line.signalling
    circuits = {c.id: c for c in line.track.circuits}
    blocks = (
        [(circuits[b.circuits[0]].start_m, circuits[b.circuits[-1]].end_m) for b in sig.blocks]
        if sig is not None
        else [(s.start_m, s.end_m) for s in line.segments]
    )
    end_m = line.line.length_m if line.line.length_m is not None else float(line.track.end_m or 0.0)
    return ZoneController(
        params=line.cbtc,
        segments=[(s.start_m, s.end_m) for s in line.segments],
        blocks=blocks,
        overlap_m=sig.overlap_m if sig is not None else 0.0,
        train_length_m=vehicle.length_m,
        line_end_m=end_m,
        limit_at=lambda x: civil_limit_mps(line, x),
        gradient_at=lambda x: gradient_permille(line, x),
        mode=mode,
    )
