"""The train's units that the line simulation and live operation both build (SPEC §4): its
onboard CBTC unit, from the line and vehicle data, the same in both."""

from __future__ import annotations

from railstop.config.schema import Line, Vehicle
from railstop.onboard.cbtc import OnboardCbtc


def make_onboard_cbtc(line: Line, vehicle: Vehicle, train_id: int, *, uplink: str) -> OnboardCbtc:
    """Train ``train_id``'s onboard CBTC unit (SPEC §4): the line's CBTC data, the braking curve at
    the vehicle's full service rate, its reports to the radio unit ``uplink``; inactive until the
    train is next to enter the line."""
    return OnboardCbtc(
        train_id=train_id,
        direction="R",
        params=line.cbtc,
        curve_decel_mps2=vehicle.brake.full_service_mps2,
        uplink=uplink,
        active=False,
    )
