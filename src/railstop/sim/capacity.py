"""A CBTC line's minimum headway, computed from its data: what one platform can pass per hour.

Under SPEC §4's moving block a follower's authority ends behind the train ahead (its reported
rear, less the rollback allowance, both trains' location uncertainty and the safety margin).
On this line a train is handed to the station stop (SPEC §1 ground TASC) only when its
authority reaches the stopping point, so one platform serves one train per cycle of

1. **dwell**: the leader's standstill to its start enable (the SPEC §5 door units: stop
   confirmation, doors and PSD open, the operation's dwell, closing and locking);
2. **clearing**: start enable to the leader's front having run the train's length, the
   rollback allowance, both uncertainties and the safety margin, so that the follower's
   authority reaches the stopping point (the plant from standstill: the traction curve, the
   running resistance and the track's gradient, under the line's speed limits); with the
   line's opt-in predictive hand-over, until the authority, advancing at the leader's speed,
   keeps ahead of the follower's whole approach (``handover="predictive"``, HZ-CBTC-19);
3. **system**: the follower hears of it: the leader's next report (a report period at worst),
   the zone controller's processing and the radio's latency, and the line's step;
4. **approach**: the follower, at the hand-over point at the station's TASC entry speed at
   that instant, to its standstill at the stopping point (the station's nominal stop, the stop
   model's own braking from the hand-over).

The minimum headway of a platform is the sum; the line's is the largest over its stations.
It is a lower bound: it assumes a follower that reaches the hand-over at full speed exactly when
its authority reaches the stopping point. A real follower cannot know when that will be: its
ATO brakes towards its hold-back point before the hand-over while the platform is not clear,
and a follower queued there starts again from a stand. [interpretation] SPEC §4 gives no
headway; the terms are those of a moving-block station headway (IEEE 1474.1's safe separation
behind the train ahead, plus the time the platform is occupied), taken from this line's data.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.config.doors import DoorsConfig, load_doors
from railstop.config.operation import Operation
from railstop.config.schema import Line, Station, Vehicle
from railstop.control.line_ato import handover_m, profile_at, static_profile
from railstop.errors import SimulationError
from railstop.link.channel import media_preset
from railstop.onboard.cbtc import approach_within_authority
from railstop.physics.plant import PlantParams, PlantState, plant_step, track_gradient, traction_mps2
from railstop.quantities import MPS_PER_KMH
from railstop.sim.dwell import run_dwell
from railstop.sim.line import ENTRY_MARGIN_M, HANDOVERS
from railstop.sim.single import run_stop

FloatArray = NDArray[np.float64]

#: The load of the trains whose headway is computed (half the crush payload, the nominal stop's).
LOAD_FACTOR = 0.5
#: The clearing's integration step (s) and the longest it may take before it is an error.
CLEAR_STEP_S = 0.01
CLEAR_LIMIT_S = 600.0


@dataclass(frozen=True, slots=True, kw_only=True)
class PlatformHeadway:
    """One platform's minimum headway and its four terms (s), with the distances behind them."""

    station: str
    dwell_s: float
    clear_s: float
    system_s: float
    approach_s: float
    clear_m: float  # how far the leader's front runs before the follower's authority reaches the stop
    entry_speed_kmh: float  # the follower's speed at the hand-over

    @property
    def headway_s(self) -> float:
        return self.dwell_s + self.clear_s + self.system_s + self.approach_s

    @property
    def trains_per_hour(self) -> float:
        return 3600.0 / self.headway_s

    def as_dict(self) -> dict[str, float | str]:
        return {
            "station": self.station,
            "headway_s": round(self.headway_s, 2),
            "trains_per_hour": round(self.trains_per_hour, 2),
            "dwell_s": round(self.dwell_s, 2),
            "clear_s": round(self.clear_s, 2),
            "system_s": round(self.system_s, 3),
            "approach_s": round(self.approach_s, 2),
            "clear_m": round(self.clear_m, 2),
            "entry_speed_kmh": round(self.entry_speed_kmh, 2),
        }


def minimum_headways(
    line: Line,
    vehicle: Vehicle,
    operation: Operation,
    *,
    uncertainty_m: float | None = None,
    step_s: float = 0.1,
    doors: DoorsConfig | None = None,
    handover: str = "platform-clear",
) -> list[PlatformHeadway]:
    """Every station's minimum headway under the line's CBTC (in the line's order).

    ``handover``: the line's rule (``LineSettings.handover``): "platform-clear" (the clearing
    ends when the follower's authority reaches the stopping point) or "predictive" (it ends when
    the authority, advancing at the leader's speed, keeps ahead of the follower's whole approach
    from the hand-over point: ``onboard.cbtc.approach_within_authority``, at the leader's exact
    speed where the line estimates it over the last two seconds, so still a lower bound).

    ``uncertainty_m``: the location uncertainty each train reports (None: the line data's declared
    bound, ``cbtc.position_uncertainty_m``; a line train reports its positioning unit's, smaller);
    ``step_s``: the line's step (a message waits up to one for the next); ``doors``: the door data
    (None: the embedded one)."""
    cbtc = line.cbtc
    u = cbtc.position_uncertainty_m if uncertainty_m is None else uncertainty_m
    # SPEC §4 / IEEE 1474.1: the follower's authority ends the safety margin and its own
    # uncertainty behind the leader's rear, which is widened by the leader's uncertainty and the
    # rollback allowance (wayside.zone_controller); it reaches the stopping point once the
    # leader's front has run this far from it.
    clear_m = vehicle.length_m + cbtc.rollback_m + cbtc.safety_margin_m + 2.0 * u
    radio = media_preset("cbtc-radio")
    # The leader's next report (a period at worst), the controller's processing, the radio, the
    # line's step at which the follower reads its new authority.
    system_s = cbtc.report_period_s + cbtc.processing_delay_s + radio.latency_s + step_s
    door_data = doors if doors is not None else load_doors(None)
    profile = static_profile(line, line.end_m, vehicle.brake.full_service_mps2)
    gradient = track_gradient(line)
    params = PlantParams.create(vehicle, load_factor=LOAD_FACTOR, dt_s=CLEAR_STEP_S, gradient=gradient)
    if handover not in HANDOVERS:
        raise SimulationError(f"handover: one of {', '.join(HANDOVERS)} (got {handover!r})")
    out = []
    for st in line.stations:
        dwell_doors = door_data.with_dwell(operation.dwell_at_s(st.name)).at_station(st, "the line file")
        v_entry = st.tasc.entry_speed_kmh * MPS_PER_KMH
        first = st.detector_positions_m()[0]

        def released(
            run_m: float, leader_mps: float, st: Station = st, v: float = v_entry, d1: float = first
        ) -> bool:
            if run_m >= clear_m:
                return True
            if handover == "platform-clear":
                return False
            return approach_within_authority(
                front_m=handover_m(d1, v),
                speed_mps=v,
                hold_to_m=d1,
                stop_m=st.stop_point_m,
                authority_m=st.stop_point_m + run_m - clear_m,
                advance_mps=leader_mps,
                params=cbtc,
                margin_m=ENTRY_MARGIN_M,
            )

        out.append(
            PlatformHeadway(
                station=st.name,
                dwell_s=_dwell_s(dwell_doors, st),
                clear_s=_clear_s(params, profile, st.stop_point_m, released),
                system_s=system_s,
                approach_s=_approach_s(line, st, vehicle, operation.controller),
                clear_m=clear_m,
                entry_speed_kmh=st.tasc.entry_speed_kmh,
            )
        )
    return out


def _dwell_s(doors: DoorsConfig, station: Station) -> float:
    """Standstill to start enable of a nominal dwell (a stop on the mark, a clean link)."""
    res = run_dwell(doors=doors, station=station.name, platform_side=station.platform_side, stop_error_m=0.0)
    if res.start_enable_s is None:  # pragma: no cover - the nominal dwell of valid data ends enabled
        raise SimulationError(f"station {station.name!r}: the nominal dwell gives no start enable")
    return res.start_enable_s


def _clear_s(
    params: PlantParams, profile: FloatArray, stop_m: float, released: Callable[[float, float], bool]
) -> float:
    """The leader from a stand at ``stop_m`` at full traction (under the static speed limits) until
    ``released(distance its front has run, its speed)`` (the follower may be handed over)."""
    plant = PlantState.create(params, x_m=stop_m)
    t = 0.0
    while not released(plant.x_m - stop_m, plant.v_mps):
        if t > CLEAR_LIMIT_S:
            raise SimulationError(
                f"the follower is not released within {CLEAR_LIMIT_S:.0f} s of the leader's start"
            )
        limit = profile_at(profile, plant.x_m)
        demand = traction_mps2(params, plant.v_mps) if plant.v_mps < limit else 0.0
        plant_step(plant, params, demand_mps2=demand, t_s=t)
        t += params.dt_s
    return t


def _approach_s(line: Line, station: Station, vehicle: Vehicle, controller: str) -> float:
    """The follower from the hand-over point to standstill: the run from the hand-over to the first
    detector at the entry speed, then the station's nominal stop (from that detector)."""
    res, _ = run_stop(
        line=line, station=station, vehicle=vehicle, controller=controller, seed=1, load_factor=LOAD_FACTOR
    )
    if res.stop_time_s is None:  # pragma: no cover - a nominal stop of valid data stands
        raise SimulationError(f"station {station.name!r}: the nominal stop does not stand")
    v = station.tasc.entry_speed_kmh * MPS_PER_KMH
    first = station.detector_positions_m()[0]
    return float(res.stop_time_s) + (first - handover_m(first, v)) / v
