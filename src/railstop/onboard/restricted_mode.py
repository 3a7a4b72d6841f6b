"""Restricted mode: how the driver of a lost train moves it (SPEC §4), a pure unit on the train.

A train whose CBTC radio is dead gets no commands: its onboard unit applies the
emergency brake (2 missed commands, SPEC §4) and the zone controller loses it
and sets a protection zone. The train still has a driver. **[interpretation]**
SPEC §4 says only that a lost train may move while lost (so that, re-detected
outside its zone, it is held for the operator's manual release); this is the
usual degraded mode that moves it: at a stand after the emergency brake he waits
``RESTRICTED_AFTER_S`` (he asks the control centre and gets leave), cuts the ATP
out and drives on sight at ``RESTRICTED_MPS`` (15 km/h) for at most
``RESTRICTED_M`` (to the next place where he can call in), stopping ``SIGHT_M``
behind the train ahead (he can see it) and short of the place a driver must
stop at (``stop_m``: where the line's trains wait for a platform; none live);
when the radio comes back he stops, cuts the ATP in again, and the zone
controller re-detects the train (inside its zone: released; outside: flagged
and held until the operator's release).

The same unit drives the live trains (``live.cbtc``) and the line simulation's
(``sim.line``): each asks it every plant step what the driver does.
Nothing here reads a clock (DESIGN rule 2): the time and the train's state are
arguments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from railstop.errors import InterlockError
from railstop.onboard.cbtc import permitted_speed_mps
from railstop.quantities import kmh_to_mps

RESTRICTED_AFTER_S = 20.0  # at a stand with a dead radio, the driver asks and gets leave after this
RESTRICTED_MPS = kmh_to_mps(15.0)  # on sight, ATP cut out
RESTRICTED_M = 400.0  # at most this far (to the next place where he can call in)
SIGHT_M = 150.0  # he stops this far behind the train ahead (he can see it)
RESTRICTED_ACCEL_MPS2 = 0.3  # he takes power gently
#: His curve to where he must stop: this share of the full service rate, after this reaction.
SIGHT_BRAKE_SHARE = 0.5
SIGHT_RESPONSE_S = 0.5


@dataclass(frozen=True, slots=True, kw_only=True)
class RestrictedDrive:
    """What the driver asks of the traction and brakes: reach ``target_mps`` with at most
    ``accel_mps2`` of traction or ``decel_mps2`` of braking (a target of 0: he stands, or stops)."""

    target_mps: float
    accel_mps2: float
    decel_mps2: float

    @property
    def stand(self) -> bool:
        return self.target_mps <= 0.0


@dataclass(slots=True)
class RestrictedMode:
    """One train's driver in restricted mode (the rule above). ``brake_mps2``: the train's full
    service rate, at which he stops and holds it. :meth:`step` every plant step says what he does:
    None while the ATP (the onboard CBTC unit) drives or brakes the train."""

    brake_mps2: float
    leave_at_s: float | None = None  # he may start moving then (None: not yet at a stand, lost)
    left_m: float = RESTRICTED_M  # what is left of the distance he may run
    moving: bool = False  # he has moved the train since the radio went
    moves: int = 0  # restricted movements begun (counted)
    run_m: float = 0.0  # distance run in restricted mode, all of them

    def __post_init__(self) -> None:
        if not self.brake_mps2 > 0.0:
            raise InterlockError(f"restricted mode: brake_mps2 must be > 0 (got {self.brake_mps2})")

    def step(
        self,
        *,
        now_s: float,
        step_s: float,
        position_m: float,
        speed_mps: float,
        radio_dead: bool,
        emergency_brake: bool,
        ahead_m: float = math.inf,
        stop_m: float = math.inf,
    ) -> RestrictedDrive | None:
        """What the driver does this step, from the train's front ``position_m`` and speed, whether
        its radio is dead and its emergency brake applied, the rear of the train ahead
        (``ahead_m``, inf: none) and where he must stop in any case (``stop_m``, inf: nowhere),
        all in the running direction. None: he leaves the train to its ATP."""
        stand = RestrictedDrive(target_mps=0.0, accel_mps2=0.0, decel_mps2=self.brake_mps2)
        if not radio_dead:
            self.leave_at_s, self.left_m = None, RESTRICTED_M
            if speed_mps > 0.0 and self.moving:
                return stand  # the radio is back: he stops, and cuts the ATP in again
            self.moving = False
            return None
        if not emergency_brake:
            return None  # not braked yet (the commands are missed for 2 cycles first)
        if self.leave_at_s is None:
            if speed_mps > 0.0:
                return None  # still braking under the emergency brake
            self.leave_at_s = now_s + RESTRICTED_AFTER_S
        if now_s < self.leave_at_s or self.left_m <= 0.0:
            return stand
        room = min(self.left_m, ahead_m - SIGHT_M - position_m, stop_m - position_m)
        curve = permitted_speed_mps(max(room, 0.0), self.brake_mps2 * SIGHT_BRAKE_SHARE, SIGHT_RESPONSE_S)
        moved = speed_mps * step_s
        if moved > 0.0 and self.left_m == RESTRICTED_M:
            self.moves += 1  # the first metre of this outage's movement
        self.left_m -= moved
        self.run_m += moved
        self.moving = True
        target, accel = min(RESTRICTED_MPS, curve), RESTRICTED_ACCEL_MPS2
        return RestrictedDrive(target_mps=target, accel_mps2=accel, decel_mps2=self.brake_mps2)
