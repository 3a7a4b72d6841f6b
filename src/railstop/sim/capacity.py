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
4. **run-in**: the follower, released, from where it is to the hand-over point. Until its
   authority reaches the stopping point it must be able to stop at its waiting point
   (``HOLD_BACK_M`` before the hand-over): at best it is on its ATO's approach to that point (the
   line's law, ``control.line_ato``: the braking curve at the planning deceleration read ahead,
   on the plant with its brakes' lag), anywhere from where that curve starts to bind down to a
   stand at the waiting point; from there its ATO runs it up to the hand-over on the plant;
5. **approach**: the follower from the hand-over point, at the speed it reaches it, to its
   standstill at the stopping point (the station's nominal stop from that entry speed, the stop
   model's own braking).

The follower's release state is the one on that approach with the least clear + run-in +
approach (under the predictive rule the release depends on where the follower is). The minimum headway of a
platform is the sum; the line's is the largest over its stations. It is the least cycle of the
line's rule for its declared data: a follower of the line's law that came in slower is slower
still where it is, and the run-in starts with the brakes released; but it takes each train's
location uncertainty at its declared bound (the line's trains report their positioning unit's,
smaller, so their authorities reach the stopping point a little sooner), the wait for the
leader's next report at its worst, and half the payload (``docs/cbtc.md`` gives how close the
simulated line comes). The bound of a clairvoyant follower, at the hand-over
at the zone's entry speed exactly when its authority reaches the stopping point, is kept beside
it (``ideal_headway_s``): the braking distance to the waiting point is the difference, the term
every headway formula carries (the follower's braking distance behind the train ahead).
[interpretation] SPEC §4 gives no headway; the terms are those of a moving-block station
headway (IEEE 1474.1's safe separation behind the train ahead, plus the time the platform is
occupied and the follower's braking to its waiting point), taken from this line's data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railstop.config.doors import DoorsConfig, load_doors
from railstop.config.operation import Operation
from railstop.config.scenario import Scenario
from railstop.config.schema import Line, Station, Track, Vehicle
from railstop.control.line_ato import (
    HOLD_BACK_M,
    ceiling_mps,
    demand_mps2,
    handover_m,
    profile_at,
    static_profile,
)
from railstop.errors import SimulationError
from railstop.link.channel import media_preset
from railstop.onboard.cbtc import approach_within_authority
from railstop.physics.plant import PlantParams, PlantState, plant_step, track_gradient, traction_mps2
from railstop.quantities import MPS_PER_KMH
from railstop.sim.dwell import run_dwell
from railstop.sim.engine import run_batch
from railstop.sim.line import ENTRY_MARGIN_M, HANDOVERS, PLANNING_SHARE
from railstop.streams import RunStreams

FloatArray = NDArray[np.float64]

#: The load of the trains whose headway is computed (half the crush payload, the nominal stop's).
LOAD_FACTOR = 0.5
#: The clearing's integration step (s) and the longest it may take before it is an error.
CLEAR_STEP_S = 0.01
CLEAR_LIMIT_S = 600.0
#: The follower's candidate release states: every this far along its braking curve to its waiting
#: point, at most this far back (m).
RELEASE_DX_M = 5.0
RELEASE_SPAN_M = 1500.0
#: The follower's approach to its waiting point starts this far before its ATO's curve binds;
#: it stands there once this slow within a metre of it (the ATO creeps the last centimetres).
RELEASE_LEAD_M = 50.0
STAND_MPS = 0.05


@dataclass(frozen=True, slots=True, kw_only=True)
class PlatformHeadway:
    """One platform's minimum headway and its five terms (s), with the distances behind them."""

    station: str
    dwell_s: float
    clear_s: float
    system_s: float
    run_in_s: float  # the follower, released, to the hand-over point
    approach_s: float  # the follower from the hand-over point to standstill
    clear_m: float  # how far the leader's front runs before the follower's authority reaches the stop
    release_m: float  # where the follower is at its release: this far before the hand-over point
    release_at_m: float  # the same, as a chainage
    release_kmh: float  # its speed there
    entry_speed_kmh: float  # its speed at the hand-over
    ideal_headway_s: float  # a clairvoyant follower's: at the hand-over at the zone's entry speed
    nominal_approach_s: float  # the approach from the hand-over at the zone's entry speed

    @property
    def headway_s(self) -> float:
        return self.dwell_s + self.clear_s + self.system_s + self.run_in_s + self.approach_s

    @property
    def follow_s(self) -> float:
        """The follower's least time from the leader's start to its own standstill."""
        return self.clear_s + self.system_s + self.run_in_s + self.approach_s

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
            "run_in_s": round(self.run_in_s, 2),
            "approach_s": round(self.approach_s, 2),
            "clear_m": round(self.clear_m, 2),
            "release_m": round(self.release_m, 1),
            "release_kmh": round(self.release_kmh, 1),
            "entry_speed_kmh": round(self.entry_speed_kmh, 2),
            "ideal_headway_s": round(self.ideal_headway_s, 2),
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class _Release:
    """A follower's state at its release (on its braking curve to the waiting point) and its least
    time from there to the hand-over, the speed it reaches it at."""

    x_m: float
    v_mps: float
    run_in_s: float
    entry_mps: float


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
    from where the follower is: ``onboard.cbtc.approach_within_authority``, at the leader's exact
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
    params, ato_profile, plan_mps2 = _follower_model(line, vehicle)
    if handover not in HANDOVERS:
        raise SimulationError(f"handover: one of {', '.join(HANDOVERS)} (got {handover!r})")
    out = []
    for st in line.stations:
        dwell_doors = door_data.with_dwell(operation.dwell_at_s(st.name)).at_station(st, "the line file")
        v_entry = st.tasc.entry_speed_kmh * MPS_PER_KMH
        first = st.detector_positions_m()[0]
        leader = _leader_start(params, profile, st.stop_point_m, clear_m)

        def clear_from(
            front_m: float,
            speed_mps: float,
            st: Station = st,
            d1: float = first,
            leader: list[tuple[float, float, float]] = leader,
        ) -> float:
            """The leader's time from its start until the follower at (front, speed) is released."""
            for t, run_m, leader_mps in leader:
                if run_m >= clear_m:
                    return t
                if handover == "predictive" and approach_within_authority(
                    front_m=front_m,
                    speed_mps=speed_mps,
                    hold_to_m=d1,
                    stop_m=st.stop_point_m,
                    authority_m=st.stop_point_m + run_m - clear_m,
                    advance_mps=leader_mps,
                    params=cbtc,
                    margin_m=ENTRY_MARGIN_M,
                ):
                    return t
            raise SimulationError(  # pragma: no cover - _leader_start runs until clear_m
                f"station {st.name!r}: the follower is not released within {CLEAR_LIMIT_S:.0f} s"
            )

        releases = _releases(params, ato_profile, plan_mps2, first, v_entry)
        approach = _approach_s(
            st, vehicle, operation.controller, [r.entry_mps for r in releases] + [v_entry], line.track
        )
        clears = [clear_from(r.x_m, r.v_mps) for r in releases]
        best = min(range(len(releases)), key=lambda k: clears[k] + releases[k].run_in_s + approach[k])
        r = releases[best]
        dwell_s = _dwell_s(dwell_doors, st)
        ideal = dwell_s + clear_from(handover_m(first, v_entry), v_entry) + system_s + approach[-1]
        out.append(
            PlatformHeadway(
                station=st.name,
                dwell_s=dwell_s,
                clear_s=clears[best],
                system_s=system_s,
                run_in_s=r.run_in_s,
                approach_s=approach[best],
                clear_m=clear_m,
                release_m=handover_m(first, r.entry_mps) - r.x_m,
                release_at_m=r.x_m,
                release_kmh=r.v_mps / MPS_PER_KMH,
                entry_speed_kmh=r.entry_mps / MPS_PER_KMH,
                ideal_headway_s=ideal,
                nominal_approach_s=approach[-1],
            )
        )
    return out


def _follower_model(line: Line, vehicle: Vehicle) -> tuple[PlantParams, FloatArray, float]:
    """A follower of the line's law: the plant (half load, the line's gradients, the clearing's
    step), its ATO's ceiling (the static profile at the planning deceleration) and that
    deceleration."""
    plan_mps2 = PLANNING_SHARE * vehicle.brake.full_service_mps2
    params = PlantParams.create(
        vehicle, load_factor=LOAD_FACTOR, dt_s=CLEAR_STEP_S, gradient=track_gradient(line)
    )
    return params, static_profile(line, line.end_m, plan_mps2), plan_mps2


def _waiting_point_m(first_m: float, v_entry_mps: float) -> float:
    """Where a follower waits while the platform is not clear: ``HOLD_BACK_M`` before the
    hand-over point of a station whose first detector is at ``first_m``."""
    return handover_m(first_m, v_entry_mps) - HOLD_BACK_M


def _dwell_s(doors: DoorsConfig, station: Station) -> float:
    """Standstill to start enable of a nominal dwell (a stop on the mark, a clean link)."""
    res = run_dwell(doors=doors, station=station.name, platform_side=station.platform_side, stop_error_m=0.0)
    if res.start_enable_s is None:  # pragma: no cover - the nominal dwell of valid data ends enabled
        raise SimulationError(f"station {station.name!r}: the nominal dwell gives no start enable")
    return res.start_enable_s


def _leader_start(
    params: PlantParams, profile: FloatArray, stop_m: float, clear_m: float
) -> list[tuple[float, float, float]]:
    """The leader from a stand at ``stop_m`` at full traction (under the static speed limits) until
    its front has run ``clear_m``: (time, distance run, speed) every step."""
    plant = PlantState.create(params, x_m=stop_m)
    t = 0.0
    out = [(t, 0.0, 0.0)]
    while plant.x_m - stop_m < clear_m:
        if t > CLEAR_LIMIT_S:
            raise SimulationError(
                f"the follower is not released within {CLEAR_LIMIT_S:.0f} s of the leader's start"
            )
        limit = profile_at(profile, plant.x_m)
        demand = traction_mps2(params, plant.v_mps) if plant.v_mps < limit else 0.0
        plant_step(plant, params, demand_mps2=demand, t_s=t)
        t += params.dt_s
        out.append((t, plant.x_m - stop_m, plant.v_mps))
    return out


def _releases(
    params: PlantParams, profile: FloatArray, plan_mps2: float, first_m: float, v_entry: float
) -> list[_Release]:
    """The follower's candidate states at its release: its ATO's approach to its waiting point (the
    line's law on the plant, from its static profile well before the curve to that point binds to
    a stand there), every ``RELEASE_DX_M`` run and the stand, each with its ATO's run from there to
    the hand-over point once released. Any follower of the line's law is at best this fast where
    it is: one that came in slower is slower still."""
    wait_m = _waiting_point_m(first_m, v_entry)
    # Back along the curve to where it no longer binds (the ATO's ceiling is the static profile).
    x = wait_m
    while x > wait_m - RELEASE_SPAN_M:
        free = profile_at(profile, x)
        if ceiling_mps(profile, x, free, wait_m, plan_mps2) >= ceiling_mps(
            profile, x, free, math.inf, plan_mps2
        ):
            break
        x -= RELEASE_DX_M
    x0 = max(x - RELEASE_LEAD_M, 0.0)
    plant = PlantState.create(params, x_m=x0, v_mps=profile_at(profile, x0))
    out = []
    t = 0.0
    next_m = x0
    while True:
        x, v = plant.x_m, plant.v_mps
        standing = plant.stopped or (v < STAND_MPS and wait_m - x < 1.0)
        if x >= next_m or standing:
            out.append(_run_in(params, profile, plan_mps2, first_m, x, 0.0 if standing else v))
            next_m = x + RELEASE_DX_M
            if standing:
                return out
        _ato_step(plant, params, profile, plan_mps2, wait_m, t)
        t += params.dt_s
        if t > CLEAR_LIMIT_S:  # pragma: no cover - the ATO stops at its waiting point
            raise SimulationError(
                f"the follower does not stop at its waiting point within {CLEAR_LIMIT_S:.0f} s"
            )


def _ato_step(
    plant: PlantState, params: PlantParams, profile: FloatArray, plan_mps2: float, target_m: float, t_s: float
) -> None:
    """One step of the line's ATO law (``control.line_ato``: its ceiling under the static profile and
    the braking curve to ``target_m``, its speed-error demand) on the plant, as the line runs it."""
    v = plant.v_mps
    ceiling = ceiling_mps(profile, plant.x_m, v, target_m, plan_mps2)
    plant_step(
        plant,
        params,
        demand_mps2=demand_mps2(v, ceiling, traction_mps2(params, v), params.full_service_mps2),
        t_s=t_s,
    )


def _run_in(
    params: PlantParams, profile: FloatArray, plan_mps2: float, first_m: float, x_m: float, v_mps: float
) -> _Release:
    """The follower released at ``x_m`` running at ``v_mps``: its ATO (authority no longer short)
    runs it on the plant to the hand-over point (1.5 s before the first detector at the speed it
    has there, ``handover_m``)."""
    plant = PlantState.create(params, x_m=x_m, v_mps=v_mps)
    t = 0.0
    while True:
        x0, v0 = plant.x_m, plant.v_mps
        _ato_step(plant, params, profile, plan_mps2, math.inf, t)
        h = handover_m(first_m, plant.v_mps)
        if plant.x_m >= h:
            frac = min(max((h - x0) / max(plant.x_m - x0, 1e-9), 0.0), 1.0)
            return _Release(
                x_m=x_m,
                v_mps=v_mps,
                run_in_s=t + frac * params.dt_s,
                entry_mps=v0 + (plant.v_mps - v0) * frac,
            )
        t += params.dt_s
        if t > CLEAR_LIMIT_S:  # pragma: no cover - the ATO runs towards a free hand-over
            raise SimulationError(f"the follower does not reach the hand-over within {CLEAR_LIMIT_S:.0f} s")


def _approach_s(
    station: Station, vehicle: Vehicle, controller: str, entries_mps: list[float], track: Track | None
) -> list[float]:
    """The follower from the hand-over point to standstill at each entry speed: the run from the
    hand-over to the first detector at that speed, then the station's nominal stop from that
    detector (the stop model, one batch)."""
    v = np.asarray(entries_mps, dtype=float)
    scenario = Scenario.nominal(station, vehicle, n=v.size, load_factor=LOAD_FACTOR)
    res = run_batch(
        station=station,
        vehicle=vehicle,
        scenario=scenario.with_values(entry_speed_mps=v),
        controller=controller,
        streams=RunStreams.for_runs(1, 0, v.size),
        track=track,
    )
    if not np.all(res.stopped):  # pragma: no cover - a nominal stop of valid data stands
        raise SimulationError(f"station {station.name!r}: a nominal stop from the hand-over does not stand")
    first = station.detector_positions_m()[0]
    lead = np.array([(first - handover_m(first, float(e))) / max(float(e), 1e-9) for e in v])
    return [float(a) for a in res.stop_time_s + lead]


@dataclass(frozen=True, slots=True, kw_only=True)
class RegulationTimes:
    """What the line's opt-in regulation (``LineSettings.regulation``) plans with at one station:
    the follower should reach its best release state (``PlatformHeadway``) as its authority
    reaches the stopping point, so it is held at the station before for the difference."""

    station: str
    start_enable_s: float  # the nominal dwell: standstill to start enable
    release_after_s: float  # the leader's start enable to the follower's release (clear + system)
    approach_s: float  # the nominal stop: the hand-over at the zone's entry speed to standstill
    run_to_release_s: float  # from a stand at the station before to the best release state here


def regulation_times(
    line: Line,
    vehicle: Vehicle,
    operation: Operation,
    *,
    handover: str = "platform-clear",
    step_s: float = 0.1,
    doors: DoorsConfig | None = None,
) -> list[RegulationTimes | None]:
    """Per station: the nominal dwell, the release after the leader's start and a follower's run
    from a stand at the station before (from the line's entry at the operation's entry speed, for
    the first) to its best release state there on its ATO's approach to its waiting point (the
    line's law on the plant), and the nominal stop from the hand-over at the zone's entry speed;
    None where that state lies behind the start. [interpretation] Beyond SPEC §4: the train
    regulation of an ATS, which holds a train at its platform rather than let it stand before the
    next one."""
    heads = minimum_headways(line, vehicle, operation, step_s=step_s, doors=doors, handover=handover)
    params, profile, plan_mps2 = _follower_model(line, vehicle)
    out: list[RegulationTimes | None] = []
    for k, (st, h) in enumerate(zip(line.stations, heads, strict=True)):
        wait_m = _waiting_point_m(st.detector_positions_m()[0], st.tasc.entry_speed_kmh * MPS_PER_KMH)
        if k == 0:  # from the line's entry, at the operation's entry speed
            x0, v0, came_from = operation.entry_m, operation.entry_speed_kmh * MPS_PER_KMH, "the entry"
        else:  # from a stand at the station before
            x0, v0, came_from = line.stations[k - 1].stop_point_m, 0.0, repr(line.stations[k - 1].name)
        if h.release_at_m <= x0:
            out.append(None)  # released before it could be held: nothing to plan
            continue
        plant = PlantState.create(params, x_m=x0, v_mps=v0)
        t = 0.0
        while plant.x_m < h.release_at_m:
            _ato_step(plant, params, profile, plan_mps2, wait_m, t)
            t += params.dt_s
            if t > CLEAR_LIMIT_S or (plant.stopped and t > 1.0):  # pragma: no cover - valid data
                raise SimulationError(
                    f"station {st.name!r}: a train from {came_from} does not reach its release"
                )
        out.append(
            RegulationTimes(
                station=st.name,
                start_enable_s=h.dwell_s,
                release_after_s=h.clear_s + h.system_s,
                approach_s=h.nominal_approach_s,
                run_to_release_s=t,
            )
        )
    return out
