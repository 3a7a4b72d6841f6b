"""What the trains process asks of a train's plant (``live.plant``): a drive, and the constants the
trains' units share with the plant. Light on purpose: the zone controller and the trains' CBTC
logic import it without loading the plant's compiled stop model."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from railstop.config.schema import Vehicle

__all__ = ["HOLD", "STOP_SENSOR_SPAN_M", "Drive", "emergency_drive"]

#: The platform's stop sensors see a train whose front stands within this of the stopping point
#: [interpretation]: they span the precise-stop zone and a correction's reach beyond it; SPEC §5
#: needs only that a train outside the tolerance is seen as not in position.
STOP_SENSOR_SPAN_M = 5.0


@dataclass(frozen=True, slots=True)
class Drive:
    """What the ATO and the CBTC unit ask of a train's traction and brakes: reach ``target_mps``
    (signed: a correction may back, from a stand) with at most ``accel_mps2`` of traction from
    below or ``decel_mps2`` of braking from above (inf: as hard as the train can, full service at
    most); ``emergency``: the emergency brake (the plant's emergency path); ``relocate_m``: the
    train leaves service and comes back there (the line has one direction), NaN otherwise."""

    target_mps: float
    accel_mps2: float
    decel_mps2: float
    relocate_m: float = math.nan
    emergency: bool = False


HOLD = Drive(0.0, 0.0, math.inf)  # standing (the holding brake)


def emergency_drive(vehicle: Vehicle) -> Drive:
    """The emergency brake as a drive: to a stand through the plant's emergency brake."""
    return Drive(0.0, 0.0, vehicle.brake.emergency_decel_mps2, emergency=True)
