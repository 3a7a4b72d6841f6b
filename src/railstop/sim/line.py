"""The line with many trains on one clock (issue 14, first increment).

A driver (DESIGN: drivers wire units, units decide): ``SimClock`` advances
the plant every ``step_s`` and delivers the units' messages. What runs:

- **the plant** (this module): every train's true motion between stations
  (the train's own ATO, ``control.line_ato``, demands; ``physics.plant``, the
  one train plant of the line and the live plant, moves it: traction, the
  brake chain of the stop model with its dead time, jerk limit and lag,
  running resistance, the track's gradients, adhesion), and the track
  circuits' occupancy from the trains' extents, reported on every change
  (``CircuitOccupancy``);
- **the fixed-block interlocking** (``wayside.interlocking``), a unit: the
  reports in, the signal aspects out (broadcast); each train's ATP takes them
  (``TrainAspects``, a unit per train) and its ATO brakes for the first signal
  at stop ahead;
- **the station stop by ground TASC**: at the hand-over point before a
  station's first detector, when the train's authority reaches the stopping
  point (the approach signal's proceed aspect promises the approach and
  platform blocks clear), the stop model stops the train, from the train's
  own speed there and a disturbance draw of its own: the line steps the
  stop model's own step (``model.run.SteppedStop``, the compiled steps of
  every campaign: wayside TASC unit, link, onboard unit, brake chain,
  motion) on its clock, the 10 ms steps due by each tick of it, and the
  train is where the stop model's state puts it, so the circuits it clears
  free the blocks behind it at the right time. Its result equals the
  campaign's for the same draw, bit for bit (the draw's wheel being the
  train's own: one wheel and one tachometer per train for its whole trip).
  An ``ato-corrected`` stop runs no SPEC §2 chain of its own: the line's
  chain positions it (``_fix_stops``);
- **the dwell** by the door units of SPEC §5 (``sim.dwell.run_dwell``: stop
  confirmation and PSC, the correction creep of an out-of-tolerance stop,
  CPCS/WPCS, train doors and PSD, start enable), the doors standing open
  for the operation's dwell time; departure at start enable and on the next
  proceed aspect. The train and the platform talk over the door link of
  SPEC §5 (``link.door_link``: door-command and psd-status telegrams in
  EN 50159 safety frames over the transponder medium), one link per train
  and platform with its own random stream. A dwell that ends in the SPEC §5
  fault path (no PSC, or the link lost with PSC high: no start enable) keeps
  the train at the platform, and the line behind it waits (DESIGN rule 10).

- **the onboard position** of every train (SPEC §2, ``onboard.positioning``):
  its odometer (the assumed wheel diameter, so off by the drawn diameter
  error; slides and slips on low-adhesion patches), corrected at every track
  circuit it enters from the wayside's occupancy telegram
  (``nodes.occupancy_chain``: the detection delay and the electrical boundary
  drawn per train and circuit, the wayside's GNSS clocks shared by every
  train and free-running in a tunnel without a repeater, the radio's latency,
  the codec), with the learned scale; the train's ATO brakes for the signals
  and limits by that position, and its error against the truth is sampled
  every step. The station stop is taken over where the train physically is
  (the wayside's detectors see it). ``railstop position-run`` is this line
  with one train, its positioning recorded (``PositionSettings.record``).
  Once every train has left the line and the chain has nothing under way, the
  odometers and positioning units are no longer stepped (nothing reads them).

The slides of a station stop (the stop model's state says when its wheels
slide) reach the train's odometer and its positioning unit's WSP input as the
line's own slides do.

The track circuits' reports reach the interlocking, and its aspects the trains, as messages
with no medium between them [interpretation]: they stand for wired circuits and lineside
signals, not for a radio.
"""

from __future__ import annotations

import json
import math
import time
from bisect import bisect_left, bisect_right
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from railstop.clock import SimClock
from railstop.config.disturbances import (
    RUNS_PER_TRAIN,
    DisturbanceSet,
    draw_scenario,
    draw_track_stop,
    load_disturbances,
    track_stop_run,
)
from railstop.config.doors import DoorsConfig, load_doors
from railstop.config.faults import RandomOutages
from railstop.config.loader import default_line, default_vehicle
from railstop.config.media import ChannelParams
from railstop.config.operation import Operation, load_operation
from railstop.config.schema import Line, Station, Vehicle
from railstop.control.line_ato import (
    HOLD_BACK_M,
    LOOKAHEAD_S,
    authority_before_m,
    ceiling_mps,
    demand_mps2,
    handover_m,
    static_profile,
    stop_signal_m,
)
from railstop.control.supervision import EbCause, eb_cause_name
from railstop.controllers import is_corrected
from railstop.errors import SimulationError
from railstop.link.channel import media_preset
from railstop.link.door_link import DoorLinkCounts
from railstop.messages import CircuitOccupancy, ControllerRestart, Message, Output, SignalAspects, TrainLeft
from railstop.model.build import DRIVER_MODES, KernelModel
from railstop.model.records import RES_EB, RES_ERROR, RES_RESTOPS, RES_STOPPED, TR_T, TR_V, TR_X
from railstop.model.run import SteppedStop
from railstop.nodes.chain_step import CompiledChainStep
from railstop.nodes.dwell import creep_rng
from railstop.nodes.occupancy_chain import (
    Arrivals,
    ChainSettings,
    FixRecord,
    OccupancyChain,
    fix_records,
)
from railstop.onboard.cbtc import approach_within_authority
from railstop.onboard.positioning import FixReport, PositioningUnit
from railstop.onboard.restricted_mode import SIGHT_M, RestrictedDrive
from railstop.physics.plant import PlantParams, PlantState, plant_step, track_gradient, traction_mps2
from railstop.quantities import MPS_PER_KMH
from railstop.sensors.odometer import Tachometer, accelerometer_bias_mps2
from railstop.sim.dwell import make_door_link, run_dwell
from railstop.sim.engine import DT_S, MAX_TIME_S
from railstop.sim.line_cbtc import SIGNALLING_MODES, CbtcSignalling, ZoneRecord, outage_windows
from railstop.streams import RUN_LIMIT, RunStreams, Stream
from railstop.units import Unit
from railstop.wayside.interlocking import FixedBlockInterlocking
from railstop.wayside.zone_controller import ZoneMode

#: The line's model version, in a line campaign's identity: 7 since a train has one wheel and one
#: SPEC §2 position chain for its whole trip: its station stops count with the line's tachometer
#: (not a wheel drawn per stop) and an ``ato-corrected`` stop takes the fixes of the line's chain
#: (not a chain of its own). (6: the occupancy telegrams of
#: SPEC §2 go over the train radio, a ``link.channel.SimChannel`` per train; 5: the door link and
#: the CBTC radio draw from counter-based streams, ``link.channel.LinkStreams``; 4: a CBTC train whose
#: radio is dead is moved by its driver in restricted mode; 3: each CBTC train reports its positioning
#: unit's own location uncertainty and the unit weighs each fix by the time error of the clocks
#: that stamped it; 2: the line steps the stop model on its clock; 1 replayed the stop's recorded
#: trajectory).
LINE_MODEL_VERSION = 7
#: The train's own ATO plans its braking curves at this share of full service.
PLANNING_SHARE = 0.7
#: CBTC entry: the authority must reach this far beyond the braking distance from the entry speed.
ENTRY_MARGIN_M = 10.0
#: The phases of a train on the line (it occupies track).
ON_LINE = ("running", "stopping", "dwelling", "held")
#: The run of the random streams the line's wayside (its GNSS clocks) draws from: the last one,
#: far from any train's.
WAYSIDE_RUN = RUN_LIMIT - 1
#: After a dwell's SPEC §5 fault the train stands this long (its emergency brake applied) before
#: the staff have reset its ATC and the confirmation starts again ([interpretation], as the live
#: plant's DWELL_FAULT_HOLD_S: SPEC §5 says nothing of the recovery).
FAULT_HOLD_S = 60.0
#: A train held short of the platform is driven onto it at this speed (on sight, by the staff).
RECOVERY_MPS = 10.0 * MPS_PER_KMH
RECOVERY_ACCEL_MPS2 = 0.3
#: HZ-CBTC-20: the staff drive on sight, so they start the move onto the platform only once the
#: train ahead's rear is this far beyond the stopping point (restricted mode's sight distance), and
#: look again every RECOVERY_RECHECK_S until it is.
RECOVERY_SIGHT_M = SIGHT_M
RECOVERY_RECHECK_S = 1.0
#: Adhesion on a low-adhesion patch between stations (wet leaves, as position-run's).
LOW_MU = 0.05
#: What one trip leaves of the learned scale and delay (standard deviations): a train in service
#: enters with them (``calibration="carried"``). position-run's trips learn the scale to about
#: 1e-4 and the delay to a few hundredths of a second.
CARRIED_SCALE_SD = 2e-4
CARRIED_DELAY_SD_S = 0.03
#: A train whose own ATO stops it at a station (a missed hand-over) stands this close before the
#: stopping point by its onboard position (the ATO's curve ends there at a crawl): its stop.
ATO_STAND_M = 1.0
#: Steps of sliding less than this apart are one slide event (the WSP releases and reapplies).
SLIDE_GAP_S = 2.0
#: A run ``until_gone`` looks whether every train has left the line this often (s).
GONE_CHECK_S = 10.0
#: How a train's onboard positioning starts: with the calibration of its earlier trips, or cold.
CALIBRATIONS = ("carried", "cold")
#: When a CBTC train is handed to the station stop: once its authority reaches the stopping point
#: (the platform is clear), or also once its authority, advancing at the rate it has over the last
#: AUTH_RATE_WINDOW_S, keeps ahead of the stop's approach by the safe braking distance (the train
#: ahead is leaving; ``onboard.cbtc.approach_within_authority``).
HANDOVERS = ("platform-clear", "predictive")
AUTH_RATE_WINDOW_S = 2.0
#: The line's opt-in train regulation (``LineSettings.regulation``): a hold shorter than this is
#: not made, and none is longer than REGULATION_MAX_S (the plan is looked at again when it ends).
REGULATION_MIN_S = 0.5
REGULATION_MAX_S = 120.0


@dataclass(frozen=True, slots=True, kw_only=True)
class PositionSettings:
    """What a line run varies in its trains' SPEC §2 positioning, beyond the odometer error and
    the slide chance of :class:`LineSettings` (``railstop position-run`` sets them; the defaults
    are the line's own).

    ``wheel_diameter_m``: the actual wheel (None: the vehicle's). ``slides`` / ``slips``: that many
    stations per train get a low-adhesion patch where the ATO brakes for them (a slide) / where
    it starts from them (a slip), chosen per train (None: ``slide_probability`` of the line
    settings / ``slip_probability`` per station). ``low_mu``: the adhesion on a patch;
    ``patch_length_m``: the range of the patches' lengths. ``chain``: GNSS time, repeaters, the
    clocks' holdover and the radio's latency (``nodes.occupancy_chain``). ``learn`` /
    ``accelerometer``: the onboard learner and the accelerometer's bridge over slides (beyond
    SPEC §2). ``record``: keep every train's true, raw, corrected and calibrated position every
    step and every fix (for ``position-run``). ``same_path``: other settings of the chain, each
    fed the same path as the train's own (its devices, clocks and radio drawn from the same
    streams, its positioning unit logging the same odometer); they never drive the train, so
    their recorded positions show what the setting alone changes (SPEC §2's repeaters and GNSS
    time compared on identical paths).
    """

    wheel_diameter_m: float | None = None
    slides: int | None = None
    slips: int | None = None
    slip_probability: float = 0.0
    low_mu: float = LOW_MU
    patch_length_m: tuple[float, float] = (30.0, 80.0)
    chain: ChainSettings = field(default_factory=ChainSettings)
    learn: bool = True
    accelerometer: bool = True
    record: bool = False
    same_path: tuple[ChainSettings, ...] = ()

    def __post_init__(self) -> None:
        if self.same_path and not self.record:
            raise SimulationError("same_path: the other chains' positions are kept only when recorded")
        if not 0.0 <= self.slip_probability <= 1.0:
            raise SimulationError(f"slip_probability: a probability in [0, 1] (got {self.slip_probability})")
        for name in ("slides", "slips"):
            k = getattr(self, name)
            if k is not None and k < 0:
                raise SimulationError(f"{name}: at least 0 (got {k})")
        if not 0.0 < self.low_mu <= 0.5:
            raise SimulationError(f"low_mu: greater than 0 and at most 0.5 (got {self.low_mu})")
        lo, hi = self.patch_length_m
        if not 0.0 < lo <= hi <= 1000.0:
            raise SimulationError(f"patch_length_m: 0 m < lo <= hi <= 1000 m (got {self.patch_length_m})")


@dataclass(frozen=True, slots=True, kw_only=True)
class LineSettings:
    """The line run's own settings, checked once here (a SimulationError naming the field and
    value), for a run and for a campaign's spec alike.

    ``odometer_error_pct``: every train's odometer diameter error (default: each train's own
    draw of the disturbance set's ``odometer_diameter_error_pct``). ``door_link_loss``: the door
    link's loss per frame, both ways (default: the medium's own, ``[link]`` of the door data); 1
    is a dead platform link (SPEC §5 fault path). ``slide_probability``: the chance, per train and
    station, of a low-adhesion patch where the ATO brakes for the station. ``calibration``:
    "carried" (the odometer scale and delay learned on earlier trips) or "cold" (the learner's
    prior). ``signalling``: "fixed-block" (the blocks and signals of the line data), "cbtc"
    (SPEC §4 moving block with the minimal protection zone) or "cbtc-conventional" (the same with
    the conventional zone: whole blocks and the overlap). ``outages``: (train, start_s,
    duration_s): that train's CBTC radio is dead then (a fault); ``random_outages``: more, drawn
    per train from the seed; ``zc_restarts``: times the zone controller restarts;
    ``radio_medium`` / ``radio_changes``: the CBTC radio's medium and its values changed (loss,
    bursts; a fault). ``handover``: when a CBTC train is handed to the station stop
    (:data:`HANDOVERS`; "predictive" is a capacity option beyond SPEC §4, HZ-CBTC-19).
    ``regulation``: the ATS holds a train at its platform (or at the entry) rather than let it
    stand before the next platform while that is occupied (CBTC only; beyond SPEC §4,
    ``LineSimulation._regulation_hold``).
    """

    odometer_error_pct: float | None = None
    door_link_loss: float | None = None
    slide_probability: float = 0.0
    calibration: str = "carried"
    signalling: str = "fixed-block"
    outages: tuple[tuple[int, float, float], ...] = ()
    random_outages: RandomOutages | None = None
    zc_restarts: tuple[float, ...] = ()
    radio_medium: str = "cbtc-radio"
    radio_changes: Mapping[str, float] = field(default_factory=dict)
    position: PositionSettings = field(default_factory=PositionSettings)
    handover: str = "platform-clear"
    regulation: bool = False

    def __post_init__(self) -> None:
        # Sequences given as lists are kept as tuples (the settings are a value).
        object.__setattr__(self, "outages", tuple(tuple(o) for o in self.outages))
        object.__setattr__(self, "zc_restarts", tuple(self.zc_restarts))
        object.__setattr__(self, "radio_changes", dict(self.radio_changes))
        if self.signalling not in SIGNALLING_MODES:
            raise SimulationError(
                f"signalling: one of {', '.join(SIGNALLING_MODES)} (got {self.signalling!r})"
            )
        for i, (train, start, duration) in enumerate(self.outages):
            if (
                train < 0
                or not (math.isfinite(start) and start >= 0.0)
                or not (math.isfinite(duration) and duration > 0.0)
            ):
                got = f"{train}, {start}, {duration}"
                raise SimulationError(f"outages[{i}]: train >= 0, start_s >= 0, duration_s > 0 (got {got})")
        for i, at in enumerate(self.zc_restarts):
            if not (math.isfinite(at) and at >= 0.0):
                raise SimulationError(f"zc_restarts[{i}]: a time >= 0 s (got {at})")
        for name, prob in (
            ("door_link_loss", 0.0 if self.door_link_loss is None else self.door_link_loss),
            ("slide_probability", self.slide_probability),
        ):
            if not 0.0 <= prob <= 1.0:
                raise SimulationError(f"{name}: a probability in [0, 1] (got {prob})")
        if self.calibration not in CALIBRATIONS:
            raise SimulationError(f"calibration: one of {', '.join(CALIBRATIONS)} (got {self.calibration!r})")
        if self.handover not in HANDOVERS:
            raise SimulationError(f"handover: one of {', '.join(HANDOVERS)} (got {self.handover!r})")
        if self.handover != "platform-clear" and not self.signalling.startswith("cbtc"):
            got = f"{self.handover!r} with {self.signalling!r}"
            raise SimulationError(f"handover: predictive needs CBTC signalling (got {got})")
        if self.regulation and not self.signalling.startswith("cbtc"):
            raise SimulationError(f"regulation: needs CBTC signalling (got {self.signalling!r})")
        self.radio_params()  # an unknown medium or a bad change is refused now, not in a worker

    def radio_params(self) -> ChannelParams:
        """The CBTC radio's medium with the changes of the faults."""
        return media_preset(self.radio_medium).replace(**self.radio_changes)

    def identity(self) -> dict[str, Any]:
        """JSON-ready, for a campaign's identity (checked on --resume)."""
        return {
            "door_link_loss": self.door_link_loss,
            "odometer_error_pct": self.odometer_error_pct,
            "slide_probability": self.slide_probability,
            "calibration": self.calibration,
            "signalling": self.signalling,
            "outages": [list(o) for o in self.outages],
            "random_outages": None if self.random_outages is None else self.random_outages.model_dump(),
            "zc_restarts": list(self.zc_restarts),
            "radio_medium": self.radio_medium,
            "radio_changes": dict(self.radio_changes),
            # Only when changed: a campaign's identity stays that of the line's own positioning.
            **({} if self.position == PositionSettings() else {"position": repr(self.position)}),
            **({} if self.handover == "platform-clear" else {"handover": self.handover}),
            **({"regulation": True} if self.regulation else {}),
        }


def _door_link_totals(dwells: list[DwellRecord]) -> dict[str, int]:
    """The door links of every dwell: frames sent, lost by the medium, refused by the receivers."""
    links = [d.link for d in dwells if d.link is not None]
    return {
        "frames": sum(c.commands_sent + c.status_sent for c in links),
        "lost": sum(c.lost for c in links),
        "rejected": sum(sum(c.rejected.values()) for c in links),
    }


class TrainAspects:
    """A train's ATP receiver of the signal aspects (a unit): it keeps the latest it was told.
    Until the first, every signal is at stop (DESIGN rule 10)."""

    accepts: tuple[type, ...] = (SignalAspects,)

    def __init__(self, name: str, signals: int) -> None:
        self.name = name
        self.proceed: tuple[bool, ...] = (False,) * signals

    def handle(self, message: Message, now_s: float) -> list[Output]:
        if isinstance(message, SignalAspects):
            self.proceed = message.proceed
        return []

    def next_deadline_s(self) -> float | None:
        return None

    def on_timer(self, now_s: float) -> list[Output]:
        return []


@dataclass(slots=True)
class Train:
    index: int
    request_s: float  # when it asks to enter
    phase: str = "waiting"  # waiting, running, stopping, dwelling, held (dwell fault), gone
    x_m: float = 0.0  # front
    v_mps: float = 0.0
    next_station: int = 0
    entered_s: float = np.nan
    exited_s: float = np.nan
    until_s: float = np.nan  # dwelling: when the doors have closed
    plan_depart_s: float = np.nan  # the regulation's plan of its start from the platform it is at
    # stopping: the station stop's model, stepped on the line's clock from t0 (the hand-over) ...
    stop: SteppedStop | None = None
    stop_t0_s: float = np.nan
    # An ato-corrected stop is positioned by the line's SPEC §2 chain: it has had its first fix.
    stop_positioned: bool = False
    # ... or a move on the line's clock (times, positions, speeds): a driver's corrections at the
    # stand (SPEC §3), a recovery onto the platform on sight.
    play_t: Any = None
    play_x: Any = None
    play_v: Any = None
    load_factor: float = 0.5
    # Between stations: its true motion (``physics.plant``: traction, the brake chain, resistance,
    # gradient, adhesion), created as it enters and as it departs, for its load then.
    plant: PlantState | None = None
    plant_params: PlantParams | None = None
    # Low adhesion: (start, end, zone); zone k < S: where the ATO brakes for station k, S + k:
    # where it starts from station k (S stations).
    patches: list[tuple[float, float, int]] = field(default_factory=list)
    sliding: bool = False  # braking beyond the adhesion: the WSP acts this step
    slipping: bool = False  # traction beyond the adhesion: the anti-slip control acts this step
    slide_m: float = 0.0  # true distance run while sliding / slipping
    slip_m: float = 0.0
    trace: list[tuple[float, float, float, float, float, float]] = field(default_factory=list)
    # The same path's corrected and calibrated position by each ``PositionSettings.same_path`` chain.
    same_path_trace: list[tuple[float, ...]] = field(default_factory=list)
    slides: int = 0  # slide events: slides that started
    last_slide_s: float = -np.inf  # the last step it slid
    slips: int = 0  # slip events: wheel slips (traction beyond the adhesion) that started
    last_slip_s: float = -np.inf  # the last step it slipped
    x_onboard_m: float = 0.0  # where the train believes its front is (SPEC §2 positioning)
    samples_t: list[float] = field(default_factory=list)
    samples_x: list[float] = field(default_factory=list)
    dwells_here: int = 0  # dwells begun at its current station (a dwell fault's retries)
    auth_log: list[tuple[float, float]] = field(default_factory=list)  # (time, authority end), CBTC


@dataclass(frozen=True, slots=True, kw_only=True)
class StopRecord:
    train: int
    station: str
    arrive_s: float  # standstill
    error_m: float
    entry_speed_kmh: float | None  # at the hand-over (None: a stop by the train's own ATO)
    emergency_brake: str | None
    within_tolerance: bool
    # The stop's draw: run ``run`` of the line's seed, at exactly this speed at the hand-over.
    run: int = -1
    entry_speed_mps: float | None = None
    # Made by the train's own ATO after a missed hand-over (``LineSimulation._run``), not by TASC.
    by_ato: bool = False

    @classmethod
    def of(
        cls,
        train: int,
        st: Station,
        *,
        arrive_s: float,
        error_m: float,
        stood: bool,
        eb: str | None,
        **more: Any,
    ) -> StopRecord:
        """A stop at ``st`` as recorded (rounded; within the station's PSD tolerance if it stood)."""
        return cls(
            train=train,
            station=st.name,
            arrive_s=round(arrive_s, 3),
            error_m=round(error_m, 4),
            emergency_brake=eb,
            within_tolerance=stood and abs(error_m) <= st.psd_tolerance_m,
            **more,
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class DwellRecord:
    train: int
    station: str
    outcome: str  # start-enable | fault | stalled (sim.dwell)
    dwell_s: float  # standstill to start enable (or to the fault)
    psc_attempts: int
    corrections: int
    link: DoorLinkCounts | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class LineResult:
    trains: int
    entered: int
    exited: int
    stops: list[StopRecord]
    dwells: list[DwellRecord]
    duration_s: float
    wall_s: float
    entry_s: list[float]
    exit_s: list[float]
    request_s: list[float]
    samples: list[tuple[list[float], list[float]]]  # per train: times, front positions
    signal_m: list[float]
    station_m: list[tuple[str, float]]
    min_separation_m: float
    position_errors: list[float]
    skipped_stops: int
    signals_passed_at_danger: int
    slide_events: int = 0  # slides (the WSP acting on low adhesion), between stations and in stops
    slip_events: int = 0  # wheel slips (the anti-slip control acting), between stations
    calibration: str = "carried"
    signalling: str = "fixed-block"
    cbtc: dict[str, Any] | None = None  # the CBTC summary (SPEC §4), with signalling cbtc*
    zones: list[ZoneRecord] = field(default_factory=list)
    # SPEC §2's occupancy telegrams on the train radio: frames sent, delivered, lost, refused, copies.
    occupancy_link: dict[str, int] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        """The JSON of ``railstop line run``."""
        errors = np.array([abs(s.error_m) for s in self.stops])
        delays = self._delays()
        exits = sorted(x for x in self.exit_s if np.isfinite(x))
        tph = (len(exits) - 1) / (exits[-1] - exits[0]) * 3600.0 if len(exits) >= 2 else None
        return {
            "trains": self.trains,
            "entered": self.entered,
            "exited": self.exited,
            "stops": len(self.stops),
            "stops_within_tolerance": int(sum(s.within_tolerance for s in self.stops)),
            "skipped_stops": self.skipped_stops,
            "stops_by_ato": int(sum(s.by_ato for s in self.stops)),
            "signals_passed_at_danger": self.signals_passed_at_danger,
            "stop_error_p99_m": round(float(np.percentile(errors, 99.0)), 4) if errors.size else None,
            "stop_error_max_m": round(float(errors.max()), 4) if errors.size else None,
            "trains_per_hour": round(tph, 2) if tph is not None else None,
            "mean_delay_s": round(float(np.mean(list(delays.values()))), 2) if delays else None,
            "emergency_brakes": int(sum(s.emergency_brake is not None for s in self.stops)),
            "mean_dwell_s": round(float(np.mean([d.dwell_s for d in self.dwells])), 2)
            if self.dwells
            else None,
            "dwell_faults": int(sum(d.outcome != "start-enable" for d in self.dwells)),
            "psc_retries": int(sum(max(d.psc_attempts - 1, 0) for d in self.dwells)),
            "door_link": _door_link_totals(self.dwells),
            "occupancy_link": dict(self.occupancy_link),
            # Counted, not assumed: the least gap between a train's front and the rear ahead.
            "min_separation_m": round(self.min_separation_m, 2)
            if np.isfinite(self.min_separation_m)
            else None,
            "position_error_p99_m": round(float(np.percentile(np.abs(self.position_errors), 99.0)), 3)
            if self.position_errors
            else None,
            "position_error_max_m": round(float(np.max(np.abs(self.position_errors))), 3)
            if self.position_errors
            else None,
            "position_calibration": self.calibration,
            "slide_events": self.slide_events,
            "slip_events": self.slip_events,
            "signalling": self.signalling,
            "cbtc": self._cbtc_summary(delays),
            "duration_s": self.duration_s,
            "wall_s": round(self.wall_s, 3),
            "sim_to_wall": round(self.duration_s / self.wall_s, 1) if self.wall_s > 0 else None,
        }

    def _delays(self) -> dict[int, float]:
        """Each train that left the line: its delay, its journey (from asking to enter to leaving
        the line) against the quickest journey of the run (the first train's, on an empty line,
        in practice)."""
        pairs = enumerate(zip(self.exit_s, self.request_s, strict=True))
        journeys = {i: x - r for i, (x, r) in pairs if np.isfinite(x)}
        fastest = min(journeys.values(), default=np.nan)
        return {i: j - fastest for i, j in journeys.items()}

    def _cbtc_summary(self, delays: dict[int, float]) -> dict[str, Any] | None:
        """The CBTC summary with the delay split (SPEC §4): the mean delay of the trains that were
        lost (a protection zone was set for them) and of the others, which the zones held up."""
        if self.cbtc is None:
            return None
        lost = {z.train for z in self.zones}

        def mean(rows: list[float]) -> float | None:
            return round(float(np.mean(rows)), 2) if rows else None

        return {
            **self.cbtc,
            "mean_delay_lost_trains_s": mean([d for i, d in delays.items() if i in lost]),
            "mean_delay_other_trains_s": mean([d for i, d in delays.items() if i not in lost]),
        }


def _feed_chain(
    chain: OccupancyChain,
    unit: PositioningUnit,
    now_s: float,
    motion: dict[str, Any],
    log: dict[str, Any],
) -> tuple[FixReport | None, Arrivals]:
    """One step of a SPEC §2 chain and the positioning unit it feeds: the trains' ``motion`` over
    the step (the devices detect, the wayside stamps), the unit's ``log`` at the onboard clock,
    then the telegrams that reached the trains by ``now_s`` (the fixes' report, None if none)."""
    chain.advance(**motion)
    unit.log(clock_time_s=chain.onboard_time_s(now_s), **log)
    return _fixes(chain, unit, now_s)


def _fixes(chain: OccupancyChain, unit: PositioningUnit, now_s: float) -> tuple[FixReport | None, Arrivals]:
    """The telegrams of ``chain`` that reached the trains by ``now_s``, handed to ``unit`` (its
    report, None if none)."""
    got = chain.arrivals(now_s)
    if not got.size:
        return None, got
    return unit.handle(run=got.run, circuit_id=got.circuit_id, gnss_time_s=got.gnss_time_s), got


class LineSimulation:
    def __init__(
        self,
        *,
        line: Line,
        vehicle: Vehicle,
        operation: Operation,
        disturbances: DisturbanceSet | None = None,
        seed: int = 1,
        step_s: float = 0.1,
        settings: LineSettings | None = None,
        **changes: Any,
    ) -> None:
        """``settings``: the run's own settings (:class:`LineSettings`); ``changes``: fields of
        it given directly (``door_link_loss=1.0``), over ``settings``."""
        cfg = replace(settings or LineSettings(), **changes)
        self.settings = cfg
        self._restarts_due = sorted(cfg.zc_restarts)  # the zone-controller restarts still to come
        if line.signalling is None:
            raise SimulationError(f"line {line.line.name!r} has no [signalling]: the trains need blocks")
        if vehicle.traction is None:
            raise SimulationError(f"vehicle {vehicle.name!r} has no [vehicle.traction]: the trains must run")
        self.traction = vehicle.traction
        # The track's gradients (the stations' segments, level between): the trains feel them.
        self.gradient = track_gradient(line)
        self.step_s = step_s
        self.line = line
        self.vehicle = vehicle
        self.operation = operation
        self.dist = disturbances if disturbances is not None else load_disturbances("nominal")
        self.seed = seed
        self.end_m = line.end_m
        brake = vehicle.brake
        self.brake_mps2 = brake.full_service_mps2
        self.plan_mps2 = PLANNING_SHARE * brake.full_service_mps2
        self.profile = static_profile(line, self.end_m, self.plan_mps2)
        self.interlocking = FixedBlockInterlocking(line, clear_at_start=True)
        self.signal_m = self.interlocking.signal_m
        self.first_detector_m = [st.detector_positions_m()[0] for st in line.stations]
        # The signal protecting the block the trains enter into.
        self.entry_signal = max(i for i, s in enumerate(self.signal_m) if s <= operation.entry_m)
        self.circuits = [(c.id, c.start_m, c.end_m) for c in line.track.circuits]
        # The circuits are in running order and contiguous (the line data's check): their starts
        # and their ends ascend, so those under a train are found by bisection.
        self._circuit_starts = [c.start_m for c in line.track.circuits]
        self._circuit_ends = [c.end_m for c in line.track.circuits]
        self.trains = [Train(index=k, request_s=t) for k, t in enumerate(operation.entry_times_s())]
        self.receivers = [TrainAspects(f"train-{t.index}", len(self.signal_m)) for t in self.trains]
        for r in self.receivers:
            r.proceed = self.interlocking.aspects
        self.cbtc: CbtcSignalling | None = None
        self.drawn_outages: list[tuple[int, float, float]] = []
        units: list[Unit] = [self.interlocking, *self.receivers]
        if cfg.signalling != "fixed-block":
            self.cbtc = CbtcSignalling(
                line=line,
                vehicle=vehicle,
                mode=ZoneMode.CONVENTIONAL if cfg.signalling == "cbtc-conventional" else ZoneMode.MINIMAL,
                trains=len(self.trains),
                radio_params=cfg.radio_params(),
                seed=seed,
                outages=outage_windows([*cfg.outages, *self._draw_outages(cfg.random_outages, seed)]),
            )
            units += self.cbtc.units()
        self.clock = SimClock(units, step_s=step_s)
        self._occupied: set[int] = set()
        self.stops: list[StopRecord] = []
        self.dwells: list[DwellRecord] = []
        self.doors = load_doors(None)
        self.doors.check_vehicle(self.vehicle, "the vehicle file")  # its doors, the train's
        self._doors_for: dict[tuple[float, str], DoorsConfig] = {}
        self._stop_models: dict[int, KernelModel] = {}
        # ato-corrected: the line's SPEC §2 chain positions the trains' station stops (_fix_stops).
        self._driver_fixes = is_corrected(operation.controller)
        # ... and what they gave each stop: (train, run, hand-over time, SteppedStop.fixes).
        self.stop_fixes: list[tuple[int, int, float, tuple[tuple[int, float], ...]]] = []
        self.min_separation_m = np.inf  # the least gap between a train's front and the rear ahead
        self.skipped_stops = 0
        self.signals_passed_at_danger = 0
        self.regulation_holds = 0
        self.regulation_hold_s = 0.0
        self._regulation = None
        if cfg.regulation:
            # (The line's door units run the embedded door data, self.doors; so does the plan.)
            self._regulation = _regulation_plan(line, vehicle, operation, cfg.handover, step_s)
        self._init_positioning(cfg.odometer_error_pct)

    # ------------------------------------------------------------------ onboard position (SPEC §2)

    def _init_positioning(self, odometer_error_pct: float | None) -> None:
        n = len(self.trains)
        veh = self.vehicle
        # Each train's own streams (run indices past the stations'): its wheel, its circuits.
        self.train_streams = RunStreams(
            seed=self.seed,
            run_index=np.array([t.index * RUNS_PER_TRAIN + RUNS_PER_TRAIN - 1 for t in self.trains]),
        )
        if odometer_error_pct is None:
            _, values = draw_scenario(self.dist, self.line.stations[0], veh, self.train_streams)
            err = np.asarray(values["odometer_diameter_error_pct"], dtype=np.float64) / 100.0
        else:
            err = np.full(n, odometer_error_pct / 100.0)
        # SPEC §2 tachometer: whole pulses of the wheel, read with the assumed diameter.
        pos = self.settings.position
        actual = np.full(n, veh.wheel_diameter_m if pos.wheel_diameter_m is None else pos.wheel_diameter_m)
        # One wheel per train for its whole trip: its station stops' odometer is this one too.
        self.odometer_error = err
        self.tacho = Tachometer.create(
            actual_diameter_m=actual,
            assumed_diameter_m=actual * (1.0 + err),
            pulses_per_rev=veh.positioning.tachometer_pulses_per_rev,
        )
        self.accel_bias = accelerometer_bias_mps2(
            self.train_streams, veh.positioning.accelerometer_bias_sd_mps2
        )
        self._place_patches()
        det = self.line.track.detection
        self.circuit_sd = [det.boundary_sd_m(c.kind) for c in self.line.track.circuits]
        self.chain, self.positioning = self._chain_and_unit(pos.chain)
        # The other chains on the same path (never driving): the same streams, so the same draws.
        self.same_path = [self._chain_and_unit(c) for c in pos.same_path]
        self._chain_step = CompiledChainStep(
            self.chain,
            self.positioning,
            self.tacho,
            slide_slip_ratio=veh.slide_slip_ratio,
            traction_slip_ratio=self.traction.slip_ratio,
            # It belongs to the calibration: without the learner the calibrated position is the
            # document's (no bridge either).
            accel_bias_mps2=self.accel_bias if pos.accelerometer and pos.learn else None,
        )
        self.position_errors: list[float] = []
        self.fixes: list[FixRecord] = []
        self._empty = False  # every train has left and the chains are idle (_emptied): for good

    def _chain_and_unit(self, settings: ChainSettings) -> tuple[OccupancyChain, PositioningUnit]:
        """The SPEC §2 chain of ``settings`` and the trains' positioning units it feeds."""
        n = len(self.trains)
        veh = self.vehicle
        pos = self.settings.position
        det = self.line.track.detection
        # SPEC §2 S10-S30: every train's passage of the devices (its own boundaries and delays),
        # one wayside (its GNSS clocks shared by every train), the radio and the onboard clocks.
        chain = OccupancyChain(
            self.line,
            train_streams=self.train_streams,
            wayside_streams=RunStreams.for_runs(self.seed, WAYSIDE_RUN, 1),
            start_position_m=np.full(n, self.operation.entry_m),
            settings=settings,
        )
        unit = PositioningUnit(
            circuits=self.line.track.circuits,
            settings=veh.positioning.model_copy(update={"learn": veh.positioning.learn and pos.learn}),
            n=n,
            cycle_s=self.clock.step_s,
            # The train's belief as it enters: the entry, off by what it knows of it.
            start_position_m=self.operation.entry_m
            + self.operation.entry_position_sd_m * self.train_streams.normal(Stream.ACCELEROMETER, 3),
            boundary_sd_m=self.circuit_sd,
            delay_spread_s=det.delay_spread_s,
            nominal_delay_s=det.delay_mean_s,
            start_sd_m=self.operation.entry_position_sd_m,
            time_sd_s=chain.clock_sd_s(),
        )
        if self.settings.calibration == "carried":
            # [interpretation] a train in service keeps the scale and delay it learned on its
            # earlier trips (non-volatile, as wheel-diameter calibration is kept): it enters with
            # them, each off by what one trip leaves (CARRIED_SCALE_SD, CARRIED_DELAY_SD_S).
            st = self.train_streams
            scale = np.asarray(self.tacho.scale) * (
                1.0 + CARRIED_SCALE_SD * st.normal(Stream.ACCELEROMETER, 1)
            )
            delay = det.delay_mean_s + CARRIED_DELAY_SD_S * st.normal(Stream.ACCELEROMETER, 2)
            unit.carry_calibration(
                scale=scale, scale_sd=CARRIED_SCALE_SD, delay_s=delay, delay_sd_s=CARRIED_DELAY_SD_S
            )
        return chain, unit

    def _place_patches(self) -> None:
        """Low-adhesion patches (wet leaves, ``low_mu``), drawn per train (``Stream.ADHESION``,
        counters 3z .. 3z + 2 for zone z): where the ATO brakes for station k (zone k: a patch
        ending 0-100 m before the hand-over point, the ATO's braking down to the TASC entry speed;
        the stop itself has its own adhesion draw) and where it starts from station k (zone S + k:
        a patch starting 5-125 m past the stopping point). A zone gets one with the settings'
        chance, or the ``slides`` / ``slips`` zones of lowest draw get one each."""
        pos = self.settings.position
        stations = self.line.stations
        s_count = len(stations)
        lo, hi = pos.patch_length_m
        for name, count in (("slides", pos.slides), ("slips", pos.slips)):
            if count is not None and count > s_count:
                raise SimulationError(
                    f"{name}: at most {s_count} on this line, one per station (got {count})"
                )
        for t in self.trains:
            st = self.train_streams.subset(np.array([t.index]))
            u = [
                [float(st.uniform(Stream.ADHESION, 3 * z + j)[0]) for j in range(3)]
                for z in range(2 * s_count)
            ]
            for zones, count, prob in (
                (range(s_count), pos.slides, self.settings.slide_probability),
                (range(s_count, 2 * s_count), pos.slips, pos.slip_probability),
            ):
                if count is None:
                    chosen = [z for z in zones if u[z][0] < prob]
                else:
                    chosen = sorted(zones, key=lambda z: u[z][0])[:count]
                for z in sorted(chosen):
                    length = lo + (hi - lo) * u[z][2]
                    if z < s_count:
                        entry = stations[z].tasc.entry_speed_kmh * MPS_PER_KMH
                        end = handover_m(self.first_detector_m[z], entry) - 100.0 * u[z][1]
                        t.patches.append((end - length, end, z))
                    else:
                        start = stations[z - s_count].stop_point_m + 5.0 + 120.0 * u[z][1]
                        t.patches.append((start, start + length, z))

    def _position_step(self, now_s: float, dt: float, before: list[tuple[str, float, float]]) -> None:
        """Odometers, the SPEC §2 chain (the devices detect the fronts entering circuits, the
        wayside stamps the occupancy in GNSS time, the telegram reaches the train a radio latency
        later through the codec), the units' logs and fixes. ``before``: every train's (phase,
        front, speed) at the step's start."""
        pos = self.settings.position
        # One pass over the trains for every per-train input of the step (the arrays below).
        on: list[bool] = []
        x0_l: list[float] = []
        x1_l: list[float] = []
        v0_l: list[float] = []
        v1_l: list[float] = []
        sliding_l: list[bool] = []
        slipping_l: list[bool] = []
        creeping = False  # any train sliding or slipping (its distance run so counted)
        for t, (p, x, v) in zip(self.trains, before, strict=True):
            o = t.phase in ON_LINE
            # A train that entered in this step moved nothing yet; one not on the line enters nothing.
            xn = t.x_m if o else -np.inf
            on.append(o)
            x1_l.append(xn)
            x0_l.append(x if p in ON_LINE else xn)
            v0_l.append(v)
            v1_l.append(t.v_mps)
            sliding_l.append(t.sliding)
            slipping_l.append(t.slipping)
            creeping = creeping or t.sliding or t.slipping
        on_line = np.array(on)
        x0 = np.array(x0_l, dtype=np.float64)
        x1 = np.array(x1_l, dtype=np.float64)
        v0 = np.array(v0_l, dtype=np.float64)
        # The odometers, the onboard clocks, the devices' detection and the units' logs in one
        # compiled loop (nodes.chain_step); the wayside takes the detections.
        got_step = self._chain_step.step(
            now_s=now_s,
            dt_s=dt,
            on_line=on_line,
            x0_m=x0,
            x1_m=x1,
            v0_mps=v0,
            v1_mps=np.array(v1_l, dtype=np.float64),
            sliding=np.array(sliding_l),
            slipping=np.array(slipping_l),
        )
        if creeping:
            moved = got_step.moved_m
            for t in self.trains:
                t.slide_m += float(moved[t.index]) if t.sliding else 0.0
                t.slip_m += float(moved[t.index]) if t.slipping else 0.0
        rep, got = _fixes(self.chain, self.positioning, now_s)
        if rep is not None and pos.record:
            self.fixes += fix_records(rep, got, self.positioning, now_s)
        if self.same_path:
            # The other chains on the same path (recorded runs only): the same motion and samples.
            motion = {
                "t0_s": now_s - dt,
                "dt_s": dt,
                "x0_m": x0,
                "v0_mps": v0,
                "accel_mps2": got_step.accel_mps2.copy(),
                "x1_m": x1,
            }
            log = {
                "odometer_m": got_step.odometer_m.copy(),
                "speed_mps": got_step.speed_mps.copy(),
                "wsp_active": got_step.wsp_active.copy(),
                "accel_mps2": got_step.log_accel_mps2.copy() if self._chain_step.accelerometer else None,
            }
            for chain, unit in self.same_path:
                _feed_chain(chain, unit, now_s, motion, log)
        # The calibrated positions: the step's, or again after a fix.
        est = self.positioning.calibrated_m() if got.size else got_step.calibrated_m
        errors = self.position_errors
        for t, x_onboard, o in zip(self.trains, est.tolist(), on, strict=True):
            t.x_onboard_m = x_onboard
            if o:
                errors.append(x_onboard - t.x_m)
        if self._driver_fixes:
            self._fix_stops(rep)
        if pos.record:
            raw = self.operation.entry_m + self.tacho.odometer_m()
            cor = self.positioning.corrected_m()
            other = [(u.corrected_m(), u.calibrated_m()) for _, u in self.same_path]
            for t in self.trains:
                if t.phase in ON_LINE:
                    i = t.index
                    t.trace.append((now_s, t.x_m, t.v_mps, float(raw[i]), float(cor[i]), float(est[i])))
                    if other:
                        t.same_path_trace.append(tuple(float(a[i]) for pair in other for a in pair))

    def _fix_stops(self, rep: FixReport | None) -> None:
        """SPEC §2, one position chain per train (issue 35): an ``ato-corrected`` train's station
        stop is positioned by the line's chain, which has positioned it all along. Its ATO takes the
        line unit's calibrated position when the stop takes the train (before the stop's first step)
        and again after each fix the unit accepts during the stop; between them it counts its
        odometer (the same wheel). The stop runs no chain of its own (``with_driver_fixes``)."""
        fixed = set(rep.run[rep.accepted].tolist()) if rep is not None else set()
        for t in self.trains:
            stop = t.stop
            if stop is None or stop.done:
                continue
            if not t.stop_positioned or t.index in fixed:
                stop.fix(t.x_onboard_m)
                t.stop_positioned = True

    def _emptied(self) -> bool:
        """Every train has left the line and nothing of the SPEC §2 chain is under way (no
        occupancy to declare, no telegram in flight): no device can detect a train any more and no
        fix can reach one. The trains' odometers and positioning units are then no longer stepped
        (a train that has left is positioned no more; nothing of the run reads them).

        Once true it stays true: a train that has left never comes back, and a chain that is no
        longer stepped takes nothing new on. The trains are looked at last first (they leave in
        the order they entered, so the last is the one most likely still on the line)."""
        if not self._empty:
            self._empty = all(t.phase == "gone" for t in reversed(self.trains)) and all(
                chain.idle for chain in (self.chain, *(c for c, _ in self.same_path))
            )
        return self._empty

    # ------------------------------------------------------------------ the plant

    def _occupancy(self) -> list[Output]:
        occ: set[int] = set()
        length = self.vehicle.length_m
        for t in self.trains:
            if t.phase in ("waiting", "gone"):
                continue
            lo, hi = t.x_m - length, t.x_m
            # The circuits that start before its front and end beyond its rear.
            for k in range(bisect_right(self._circuit_ends, lo), bisect_left(self._circuit_starts, hi)):
                occ.add(self.circuits[k][0])
        out = [
            Output(to="interlocking", message=CircuitOccupancy(circuit_id=c, occupied=c in occ))
            for c in sorted(occ ^ self._occupied)
        ]
        self._occupied = occ
        return out

    def _authority_keeps_ahead(self, train: Train, auth_m: float, now_s: float, st: Station) -> bool:
        """``handover = "predictive"``: the authority's end advances (the train ahead is leaving) fast
        enough that the station stop's approach from here keeps the safe braking distance (and a
        margin) behind it to the end, at the rate it advanced over the last AUTH_RATE_WINDOW_S.
        [interpretation] Beyond SPEC §4, a capacity option: the onboard unit's supervision still
        brakes the stop if the authority stops advancing (HZ-CBTC-19)."""
        log = train.auth_log
        log.append((now_s, auth_m))
        while log and log[0][0] < now_s - AUTH_RATE_WINDOW_S - 1e-9:
            log.pop(0)
        t0, a0 = log[0]
        if now_s - t0 < 0.5 * AUTH_RATE_WINDOW_S or not math.isfinite(auth_m) or not math.isfinite(a0):
            return False
        rate = max((auth_m - a0) / (now_s - t0), 0.0)
        first = self.first_detector_m[train.next_station]
        return approach_within_authority(
            front_m=train.x_onboard_m,
            speed_mps=train.v_mps,
            hold_to_m=first,
            stop_m=st.stop_point_m,
            authority_m=auth_m,
            advance_mps=rate,
            params=self.line.cbtc,
            margin_m=ENTRY_MARGIN_M,
        )

    def _start_plant(self, train: Train, v_mps: float) -> tuple[PlantState, PlantParams]:
        """The train's plant where it is, at ``v_mps``, its brakes released, for its load now (the
        last station stop's draw)."""
        params = PlantParams.create(
            self.vehicle, load_factor=train.load_factor, dt_s=self.step_s, gradient=self.gradient
        )
        plant = PlantState.create(params, x_m=train.x_m, v_mps=v_mps)
        train.plant, train.plant_params = plant, params
        return plant, params

    def _run(self, train: Train, now_s: float, dt: float) -> None:
        # The ATO knows its position from the onboard positioning (SPEC §2), not the truth.
        here = train.x_onboard_m
        proceed = self.receivers[train.index].proceed
        st_next = (
            self.line.stations[train.next_station] if train.next_station < len(self.line.stations) else None
        )
        if self.cbtc is None:
            stop_at = stop_signal_m(here, self.signal_m, proceed)
            auth = authority_before_m(stop_at)
            # The station can take the train when no signal at stop stands before its stopping point.
            platform_clear = st_next is not None and stop_at > st_next.stop_point_m
        else:
            # SPEC §4: the movement authority of the zone controller's last command.
            auth = self.cbtc.authority_end_m(train.index)
            platform_clear = st_next is not None and auth >= st_next.stop_point_m
            if self.settings.handover == "predictive" and st_next is not None:
                platform_clear = platform_clear or self._authority_keeps_ahead(train, auth, now_s, st_next)
        target = auth
        # Past the station's first detector without its stop begun: the hand-over was missed (the
        # platform was not clear when the train passed it, e.g. its authority shrank at a zone
        # ahead and the train could not stand before the zone's start).
        missed = st_next is not None and train.x_m >= self.first_detector_m[train.next_station]
        if st_next is not None and missed and platform_clear:
            # [interpretation] SPEC §1 stops only a train it takes over before its first detector;
            # a train standing (or crawling) inside the zone is stopped at the stopping point by its
            # own ATO, by its onboard position, rather than run through the platform.
            target = min(auth, st_next.stop_point_m)
        elif st_next is not None and not platform_clear:
            # The platform is not clear: the station stop cannot take the train, so its ATO
            # stops it HOLD_BACK_M before the hand-over point, from where it runs up to speed
            # again once the platform clears.
            entry = st_next.tasc.entry_speed_kmh * MPS_PER_KMH
            target = min(auth, handover_m(self.first_detector_m[train.next_station], entry) - HOLD_BACK_M)
        plant, params = train.plant, train.plant_params
        if plant is None or params is None:
            plant, params = self._start_plant(train, train.v_mps)
        v = train.v_mps
        ceiling = ceiling_mps(self.profile, here, v, target, self.plan_mps2)
        a = demand_mps2(v, ceiling, traction_mps2(params, v), self.brake_mps2)
        # The plant (physics.plant, the stop model's brake chain and motion): the braking demand
        # through the brakes' dead time, jerk limit and lag; traction up to the curve and the
        # adhesion; resistance and the track's gradient. On a low-adhesion patch the wheels slide
        # when the braking asks more than the adhesion gives (the wheel-slide protection holds the
        # deceleration at it, the wheel short), and slip when traction does (the anti-slip control
        # holds the traction at it, the wheel ahead of the train).
        low = any(s0 <= train.x_m < s1 for s0, s1, _ in train.patches)
        eb = self.cbtc is not None and self.cbtc.emergency_brake(train.index)  # SPEC §4: onboard EB
        drive = self._restricted(train, now_s, dt)
        if drive is not None:
            # Restricted mode (SPEC §4 lost trains, onboard.restricted_mode): its driver has cut
            # the ATP out and drives on sight; his demand through the same speed law and plant.
            eb = False
            a = (
                -drive.decel_mps2
                if drive.stand
                else demand_mps2(
                    v, drive.target_mps, min(drive.accel_mps2, traction_mps2(params, v)), drive.decel_mps2
                )
            )
        plant_step(
            plant,
            params,
            demand_mps2=a,
            t_s=now_s - dt,
            eb=eb,
            adhesion_mu=self.settings.position.low_mu if low else None,
        )
        train.slipping = plant.slipping
        train.sliding = plant.sliding
        if plant.sliding:
            if now_s - train.last_slide_s > SLIDE_GAP_S:  # a new slide, not the WSP's next cycle
                train.slides += 1
            train.last_slide_s = now_s
        if plant.slipping:
            # Counted as the slides are: the odometer over-reads while the wheels slip (SPEC §2
            # slip/slide), so a run whose trains slip says so in its summary.
            if now_s - train.last_slip_s > SLIDE_GAP_S:
                train.slips += 1
            train.last_slip_s = now_s
        x_new, v_new = plant.x_m, plant.v_mps
        if (
            st_next is not None
            and missed
            and platform_clear
            and plant.stopped
            and st_next.stop_point_m - train.x_onboard_m < ATO_STAND_M
        ):
            train.x_m, train.v_mps = x_new, 0.0
            train.plant = None
            self._stopped_by_ato(train, st_next, now_s)
            return
        if st_next is not None:
            first = self.first_detector_m[train.next_station]
            h = handover_m(first, v_new)
            if x_new >= h and train.x_m < first and platform_clear:
                # Land at the hand-over point, then the station stop takes the train. (The point
                # moves with the speed, 1.5 s before the detector: a front a few centimetres past
                # it is taken there, so that the stop model's run starts where the train is.)
                frac = min(max((h - train.x_m) / max(x_new - train.x_m, 1e-9), 0.0), 1.0)
                train.x_m, train.v_mps = h, v + (v_new - v) * frac
                train.plant = None  # the stop model's plant takes the train
                self._stop(train, st_next, now_s - dt + frac * dt)
                return
        if self.cbtc is None:  # (moving block: the fixed signals are not used)
            # The signals passed in the step: train.x_m < signal <= x_new (their chainages ascend,
            # the blocks being in running order).
            k = bisect_right(self.signal_m, train.x_m)
            while k < len(self.signal_m) and self.signal_m[k] <= x_new:
                if not proceed[k]:
                    # A signal passed at danger: counted (it must not happen) and the train stopped
                    # by its emergency brake there (DESIGN rule 10).
                    self.signals_passed_at_danger += 1
                    v_new = plant.v_mps = 0.0
                    plant.stopped = True
                k += 1
        train.x_m, train.v_mps = x_new, v_new
        if st_next is not None and train.x_m > st_next.platform_end:
            # Past a platform without its stop: counted, never silent (it must not happen).
            self.skipped_stops += 1
            train.next_station += 1
        if train.x_m - self.vehicle.length_m >= self.end_m:
            train.phase = "gone"
            train.exited_s = now_s
            train.plant = None

    def _train_ahead(self, x_m: float) -> Train | None:
        """The nearest train on the line whose true front is beyond ``x_m`` (None: none)."""
        ahead = (t for t in self.trains if t.phase in ON_LINE and t.x_m > x_m)
        return min(ahead, key=lambda t: t.x_m, default=None)

    def _rear_ahead_m(self, train: Train) -> float:
        """The true rear of the nearest train on the line ahead of ``train`` (inf: none), what a
        driver moving on sight sees."""
        leader = self._train_ahead(train.x_m)
        return math.inf if leader is None else leader.x_m - self.vehicle.length_m

    def _restricted(self, train: Train, now_s: float, dt: float) -> RestrictedDrive | None:
        """Restricted mode under CBTC (SPEC §4 lost trains; ``onboard.restricted_mode``, the rule
        live operation's trains follow): what the driver of a train whose radio is dead does this
        step, None when its ATO and onboard unit drive it. He sees the true world: his train's
        front, the rear of the train ahead. [interpretation] He stops short of the next station where
        the ATO waits for a platform (``HOLD_BACK_M`` before its hand-over point): the stop there
        is ground TASC's (SPEC §1), which he leaves to the train once its radio is back."""
        cbtc = self.cbtc
        if cbtc is None:
            return None
        dead = cbtc.radio_dead(train.index, now_s)
        ahead = stop = math.inf
        if dead:  # (only then does he look: the other trains are not looked at every step)
            ahead = self._rear_ahead_m(train)
            if train.next_station < len(self.line.stations):
                entry = self.line.stations[train.next_station].tasc.entry_speed_kmh * MPS_PER_KMH
                stop = handover_m(self.first_detector_m[train.next_station], entry) - HOLD_BACK_M
        return cbtc.restricted[train.index].step(
            now_s=now_s,
            step_s=dt,
            position_m=train.x_m,
            speed_mps=train.v_mps,
            radio_dead=dead,
            emergency_brake=cbtc.emergency_brake(train.index),
            ahead_m=ahead,
            stop_m=stop,
        )

    def _stop_model(self, station_index: int) -> KernelModel:
        """The stop model of a station (built once: a model holds no run's state)."""
        model = self._stop_models.get(station_index)
        if model is None:
            model = KernelModel.create(
                station=self.line.stations[station_index],
                vehicle=self.vehicle,
                controller=self.operation.controller,
                form=None,
                dt_s=DT_S,
                max_time_s=MAX_TIME_S,
                track=self.line.track,
            ).with_driver_fixes()  # ato-corrected: positioned by the line's chain (_fix_stops)
            self._stop_models[station_index] = model
        return model

    def _stop(self, train: Train, st: Station, t0_s: float) -> None:
        """The station stop from the train's state at the hand-over point: its draw, and the stop
        model ready to be stepped on the line's clock from ``t0_s``."""
        station_index = self.line.stations.index(st)
        run = track_stop_run(train.index, station_index)
        # The train's own wheel (the line's tachometer), not one drawn for the stop (line model 7).
        wheel = (float(self.tacho.actual_diameter_m[train.index]), float(self.odometer_error[train.index]))
        scenario = draw_track_stop(
            self.dist, st, self.vehicle, seed=self.seed, run=run, entry_speed_mps=train.v_mps, wheel=wheel
        )
        train.load_factor = float(scenario.load_factor[0])
        model = self._stop_model(station_index)
        # A driver's corrections at the stand (SPEC §3) are worked out at once when the train
        # stands (the wait and the creep, in closed form): recorded, and the line plays them.
        train.stop = SteppedStop(
            model, scenario, seed=self.seed, run=run, record=model.controller in DRIVER_MODES
        )
        train.stop_t0_s = t0_s
        train.stop_positioned = False
        train.phase = "stopping"

    def _stopped_by_ato(self, train: Train, st: Station, now_s: float) -> None:
        """A station stop the train's own ATO made after a missed hand-over: recorded (``by_ato``),
        then the dwell, which judges the stop like any other (SPEC §5: a correction creep, or the
        fault path and the staff's recovery)."""
        eb = self.cbtc is not None and self.cbtc.emergency_brake(train.index)
        error = train.x_m - st.stop_point_m
        cause = EbCause.CBTC.label if eb else None
        self.stops.append(
            StopRecord.of(
                train.index,
                st,
                arrive_s=now_s,
                error_m=error,
                stood=True,
                eb=cause,
                entry_speed_kmh=None,
                by_ato=True,
            )
        )
        train.phase = "stopping"
        self._dwell(train, now_s)

    def _stopping(self, train: Train, now_s: float) -> None:
        stop = train.stop
        if stop is not None:
            # The stop model's 10 ms steps due by now, never ahead of the line's clock: the train
            # is where the model's state is, at most one of its steps (10 ms) behind the clock.
            if self.cbtc is not None and self.cbtc.emergency_brake(train.index):
                # SPEC §4: the onboard CBTC unit's emergency brake acts in a station stop too.
                stop.emergency_brake()
            due = math.floor((now_s - train.stop_t0_s) / stop.dt_s + 1e-9)
            slid = stop.advance(due - stop.steps)
            train.x_m, train.v_mps = stop.position_m, stop.speed_mps
            if not stop.done:
                # The stop model's slides reach the odometer (SPEC §2 slip/slide) as the line's
                # own do: a new slide event unless the WSP's last cycle was just before. Not in
                # the step it comes to a stand: the dwell begins there, and its correction creep
                # must reach the odometer.
                if slid:
                    train.sliding = True
                    if now_s - train.last_slide_s > SLIDE_GAP_S:
                        train.slides += 1
                    train.last_slide_s = now_s
                return
            train.stop = None
            self._stopped(train, stop)
            if train.play_t is None:
                self._dwell(train, train.stop_t0_s + stop.elapsed_s)
            return
        if now_s < train.play_t[-1]:
            # The speed too: the tachometer's log and the occupancy instants need it.
            train.x_m = float(np.interp(now_s, train.play_t, train.play_x))
            train.v_mps = float(np.interp(now_s, train.play_t, train.play_v))
            return
        train.x_m = float(train.play_x[-1])
        train.v_mps = 0.0
        arrive = float(train.play_t[-1])
        train.play_t = train.play_x = train.play_v = None
        self._dwell(train, arrive)

    def _stopped(self, train: Train, stop: SteppedStop) -> None:
        """The stop's end: its record; a driver's corrections at the stand to be played."""
        res, _, rec = stop.finish()
        t0, stand_s = train.stop_t0_s, stop.elapsed_s
        if stop.driver_fixes:
            self.stop_fixes.append((train.index, stop.run, t0, tuple(stop.fixes)))
        st = self.line.stations[train.next_station]
        arrive = t0 + stand_s
        if rec is not None and res[0, RES_RESTOPS] > 0.0:
            moves = rec.trace[stop.steps :]
            moves = moves[(moves[:, TR_T] > stand_s) & np.isfinite(moves[:, TR_X])]
            train.play_t = t0 + np.concatenate(([stand_s], moves[:, TR_T]))
            train.play_x = np.concatenate(([train.x_m], moves[:, TR_X]))
            train.play_v = np.concatenate(([0.0], np.nan_to_num(moves[:, TR_V])))
            train.play_v[-1] = 0.0
            arrive = float(train.play_t[-1])
        self.stops.append(
            StopRecord.of(
                train.index,
                st,
                arrive_s=arrive,
                error_m=float(res[0, RES_ERROR]),
                stood=bool(res[0, RES_STOPPED] > 0.0),
                eb=eb_cause_name(int(res[0, RES_EB])),
                entry_speed_kmh=round(float(stop.entry_speed_mps) / MPS_PER_KMH, 2),
                run=stop.run,
                entry_speed_mps=stop.entry_speed_mps,
            )
        )

    def _dwell(self, train: Train, arrive: float) -> None:
        """The dwell (SPEC §5) of a train standing at its station since ``arrive``."""
        st = self.line.stations[train.next_station]
        doors = self._doors(self.operation.dwell_at_s(st.name), st)
        # A retry after a fault draws its own link and creeps (the first is the station's number).
        counter = train.next_station + 1000 * train.dwells_here
        dwell = run_dwell(
            doors=doors,
            station=st.name,
            platform_side=st.platform_side,
            stop_error_m=train.x_m - st.stop_point_m,
            # SPEC §5: the door telegrams over the train's own link at this platform.
            link=make_door_link(
                doors,
                seed=self.seed,
                train_id=train.index,
                counter=counter,
                loss_probability=self.settings.door_link_loss,
            ),
            creep=creep_rng(self.seed, train_id=train.index, counter=counter),
        )
        train.dwells_here += 1
        self.dwells.append(
            DwellRecord(
                train=train.index,
                station=st.name,
                outcome=dwell.outcome,
                dwell_s=dwell.dwell_total_s,
                psc_attempts=dwell.psc_attempts,
                corrections=dwell.corrections,
                link=dwell.link,
            )
        )
        train.next_station += 1
        train.x_m = st.stop_point_m + dwell.final_stop_error_m  # after any correction creep
        if dwell.start_enable_s is None:
            # SPEC §5 fault path: no start enable, doors held closed, the train stays (the line
            # behind it waits) until the staff's reset (``_recover``).
            train.phase = "held"
            train.until_s = arrive + dwell.dwell_total_s + FAULT_HOLD_S
            return
        train.dwells_here = 0
        train.phase = "dwelling"
        train.until_s = arrive + dwell.start_enable_s
        reg = None if self._regulation is None else self._regulation[train.next_station - 1]
        if reg is not None:
            train.plan_depart_s = arrive + reg.start_enable_s  # the ATS plans the nominal dwell

    def _recover(self, train: Train, now_s: float) -> None:
        """After a dwell fault and the staff's reset ([interpretation], ``FAULT_HOLD_S``): a train
        short of the platform by more than the tolerance is driven onto the stopping point on sight
        (``RECOVERY_MPS``); then its confirmation starts again (a new dwell, its correction creeps
        included). A platform whose link stays dead faults it again: it stays, fail safe.

        HZ-CBTC-20: on sight means the staff stop short of what they see. A train held short of a
        platform that another train still occupies (under the predictive hand-over the follower
        may start its stop while the train ahead stands at the platform; a failed prediction
        brakes it short) stays held until the train ahead's rear is ``RECOVERY_SIGHT_M`` beyond the
        stopping point ([interpretation]: SPEC §5 says nothing of the recovery; the distance is
        restricted mode's, the one rule of this line for moves on sight)."""
        st = self.line.stations[train.next_station - 1]
        if self._rear_ahead_m(train) < st.stop_point_m + RECOVERY_SIGHT_M:
            train.until_s = now_s + RECOVERY_RECHECK_S
            return
        train.next_station -= 1
        gap = st.stop_point_m - train.x_m
        t, x, v = np.array([now_s]), np.array([train.x_m]), np.array([0.0])
        if gap > st.psd_tolerance_m:
            # A trapezoid (or triangle) of speed, RECOVERY_ACCEL_MPS2 up and down.
            a = RECOVERY_ACCEL_MPS2
            top = min(RECOVERY_MPS, math.sqrt(a * gap))
            ramp_s, ramp_m = top / a, top * top / (2.0 * a)
            cruise_s = (gap - 2.0 * ramp_m) / top
            r = np.linspace(0.0, ramp_s, 20)
            t = np.concatenate((now_s + r, now_s + ramp_s + cruise_s + r[1:]))
            x = np.concatenate(
                (train.x_m + 0.5 * a * r * r, train.x_m + gap - ramp_m + top * r[1:] - 0.5 * a * r[1:] ** 2)
            )
            v = np.concatenate((a * r, top - a * r[1:]))
            x[-1], v[-1] = st.stop_point_m, 0.0
        train.play_t, train.play_x, train.play_v = t, x, v  # driven on sight at a crawl: no slide
        train.phase = "stopping"

    def _doors(self, dwell_s: float, station: Station) -> DoorsConfig:
        """The door data with the doors standing open for ``dwell_s``, at ``station`` (its PSD
        tolerance: one per station judges the stop and the dwell)."""
        cfg = self._doors_for.get((dwell_s, station.name))
        if cfg is None:
            where = f"the line file of {self.line.line.name!r}"
            cfg = self.doors.with_dwell(dwell_s).at_station(station, where)
            self._doors_for[(dwell_s, station.name)] = cfg
        return cfg

    def plant(self, now_s: float, dt: float) -> list[Output]:
        if self._empty and self.cbtc is None:
            # Every train has left and the chains are idle (_emptied, for good): no train moves,
            # enters or is positioned any more; what is left of a step is its circuits (free).
            for train in self.trains:
                train.sliding = train.slipping = False
            return self._occupancy()
        entry_proceed = self.interlocking.aspects[self.entry_signal]
        entry_free = True  # CBTC: one train may still enter this step
        before = [(t.phase, t.x_m, t.v_mps) for t in self.trains]
        for train in self.trains:
            train.sliding = train.slipping = False  # set by the running train's brakes below
            if train.phase == "gone":
                continue  # it has left the line for good
            if train.phase == "waiting":
                if self.cbtc is not None:
                    if train.until_s > now_s or self._regulation_hold(train, now_s, 0):
                        entry_free = False  # the head of the queue is held: none enters behind it
                        continue
                    entry_free = self._cbtc_entry(train, now_s, entry_free)
                elif now_s >= train.request_s and entry_proceed and self._entry_clear():
                    self._enter(train, now_s)
                    entry_proceed = False  # one train per step
            elif train.phase == "running":
                self._run(train, now_s, dt)
            elif train.phase == "stopping":
                self._stopping(train, now_s)
            elif (
                train.phase == "dwelling"
                and now_s >= train.until_s
                and not self._regulation_hold(train, now_s, train.next_station)
            ):
                train.phase = "running"
                self._start_plant(train, 0.0)  # it departs from a stand
            elif train.phase == "held" and now_s >= train.until_s:
                self._recover(train, now_s)
            if train.phase in ON_LINE:
                train.samples_t.append(now_s)
                train.samples_x.append(train.x_m)
        if not self._emptied():
            self._position_step(now_s, dt, before)
        on_line = sorted(t.x_m for t in self.trains if t.phase in ON_LINE)
        if len(on_line) > 1:
            length = self.vehicle.length_m
            gap = min(
                leader - length - follower for follower, leader in zip(on_line, on_line[1:], strict=False)
            )
            self.min_separation_m = min(self.min_separation_m, gap)
        out = self._occupancy()
        if self.cbtc is not None:
            out += self._cbtc_observe(now_s)
        return out

    def _cbtc_observe(self, now_s: float) -> list[Output]:
        """Every active onboard unit learns where its train believes it is; a train that has left
        the line leaves the zone controller's care."""
        cbtc = self.cbtc
        if cbtc is None:
            return []
        out: list[Output] = []
        while self._restarts_due and now_s >= self._restarts_due[0]:
            self._restarts_due.pop(0)
            out.append(Output(to=cbtc.zc.name, message=ControllerRestart()))  # a fault (data)
        # IEEE 1474.1: each train reports the location uncertainty of its own positioning.
        bound = self.positioning.uncertainty_m(self.line.cbtc.position_confidence_sigmas)
        for t in self.trains:
            if t.phase == "gone":
                if cbtc.active[t.index]:
                    cbtc.active[t.index] = False
                    cbtc.onboard[t.index].active = False
                    cbtc.on_line[t.index] = False
                    out.append(Output(to=cbtc.zc.name, message=TrainLeft(train_id=t.index)))
                continue
            on = t.phase in ON_LINE
            out += cbtc.observe(
                t.index,
                onboard_m=t.x_onboard_m if on else self.operation.entry_m,
                speed_mps=t.v_mps if on else 0.0,
                true_m=t.x_m,
                on_line=on,
                uncertainty_m=float(bound[t.index]),
            )
        cbtc.check_collisions()
        cbtc.sweep_zones(now_s)
        return out + cbtc.operator(now_s)

    def _draw_outages(self, spec: RandomOutages | None, seed: int) -> list[tuple[int, float, float]]:
        """One outage per train with ``spec.probability``: its duration uniform in [min_s, max_s],
        its start uniform in [60 s, 60 s + within_s] after the train asks to enter (its own stream,
        so a train's outage does not depend on the others')."""
        if spec is None or spec.probability <= 0.0:
            return []
        streams = RunStreams(seed=seed, run_index=np.array([t.index for t in self.trains]))
        u = [streams.uniform(Stream.CBTC_RADIO, c) for c in range(3)]
        out = []
        for t in self.trains:
            k = t.index
            if float(u[0][k]) < spec.probability:
                start = t.request_s + 60.0 + spec.within_s * float(u[1][k])
                out.append((k, start, spec.min_s + (spec.max_s - spec.min_s) * float(u[2][k])))
        self.drawn_outages = out
        return out

    def _regulation_summary(self) -> dict[str, Any]:
        """The regulation's holds, only when it is on (a run without it reads as before)."""
        if self._regulation is None:
            return {}
        return {
            "regulation_holds": self.regulation_holds,
            "regulation_hold_s": round(self.regulation_hold_s, 1),
        }

    def _regulation_hold(self, train: Train, now_s: float, station: int) -> bool:
        """The line's opt-in train regulation (``LineSettings.regulation``): whether the ATS holds
        ``train`` (ready to leave its platform, or the head of the entry queue) a while longer,
        because leaving now it would reach the platform of ``station`` before that platform's
        train has left and have to stand before it. The hold ends where, running on, the train
        reaches its best release state (``sim.capacity``: the run from here, measured once) as
        the train ahead's planned start enable plus the clearing and the system's delays release
        it. The train ahead's start is its plan (the nominal dwell from its arrival, or the hold
        the ATS gave it; not before now); one still braking into the platform arrives when its
        nominal stop from the hand-over ends (not before now), one not yet there as if it were at
        the hand-over now (the least hold; looked at again when it ends). [interpretation] Beyond
        SPEC §4: an ATS function; the train stands at a platform instead of before one, and a
        train held there holds up the trains behind it by the same rule. It moves no train and
        grants no authority: a plan that proves early leaves the train to stand before the
        platform as without it."""
        if self._regulation is None or station >= len(self.line.stations):
            return False
        reg = self._regulation[station]
        if reg is None:
            return False
        if train.phase == "waiting" and (
            now_s < train.request_s
            or any(t.phase == "waiting" and t.index < train.index for t in self.trains)
        ):
            return False  # not asking yet, or not the head of the queue
        leader = self._train_ahead(self.operation.entry_m if train.phase == "waiting" else train.x_m)
        if leader is None:
            return False
        if leader.phase == "dwelling" and leader.next_station == station + 1:
            start = max(leader.plan_depart_s, now_s)  # (a dwell past its plan: not before now)
        elif leader.phase == "stopping" and leader.next_station == station:
            # Braking in: it arrives when its nominal stop from the hand-over ends, now at the earliest.
            start = max(leader.stop_t0_s + reg.approach_s, now_s) + reg.start_enable_s
        elif leader.phase == "running" and leader.next_station == station:
            start = now_s + reg.approach_s + reg.start_enable_s  # not there yet: at the earliest
        else:
            return False  # gone from the platform, held by a fault, or beyond
        hold = start + reg.release_after_s - (now_s + reg.run_to_release_s)
        if not hold >= REGULATION_MIN_S:  # (NaN: no plan, no hold)
            return False
        hold = min(hold, REGULATION_MAX_S)
        train.until_s = now_s + hold
        train.plan_depart_s = train.until_s
        self.regulation_holds += 1
        self.regulation_hold_s += hold
        return True

    def _enter(self, train: Train, now_s: float) -> None:
        train.phase = "running"
        train.x_m = self.operation.entry_m
        train.v_mps = self.operation.entry_speed_kmh * MPS_PER_KMH
        train.entered_s = now_s
        self._start_plant(train, train.v_mps)

    def _cbtc_entry(self, train: Train, now_s: float, free: bool) -> bool:
        """SPEC §4: the train next to enter starts its onboard unit and enters once its authority
        reaches beyond its braking distance from the entry speed. Returns whether another train
        may still enter this step."""
        cbtc = self.cbtc
        if cbtc is None or not free or now_s < train.request_s:
            return free
        if any(t.phase == "waiting" and t.index < train.index for t in self.trains):
            return free  # not the head of the queue
        cbtc.activate(train.index)
        v = self.operation.entry_speed_kmh * MPS_PER_KMH
        need = v * v / (2.0 * self.plan_mps2) + v * LOOKAHEAD_S + ENTRY_MARGIN_M
        if (
            not cbtc.emergency_brake(train.index)
            and cbtc.authority_end_m(train.index) - train.x_onboard_m >= need
            and self._entry_clear()
        ):
            self._enter(train, now_s)
            return False
        return False

    def _entry_clear(self) -> bool:
        # No train's rear still within the train's own length of the entry point.
        length = self.vehicle.length_m
        return all(
            t.phase in ("waiting", "gone") or t.x_m - length > self.operation.entry_m + 1.0
            for t in self.trains
        )

    # ------------------------------------------------------------------ the run

    def run(self, duration_s: float, *, until_gone: bool = False) -> LineResult:
        """Run the line for ``duration_s``; with ``until_gone``, stop at the first whole
        ``GONE_CHECK_S`` after every train has left the line (``duration_s`` is then the end)."""
        t0 = time.perf_counter()
        self.clock.deliver(self._occupancy())
        if until_gone:
            while self.clock.now_s < duration_s - 1e-9 and any(t.phase != "gone" for t in self.trains):
                self.clock.run(min(self.clock.now_s + GONE_CHECK_S, duration_s), self.plant)
            duration_s = self.clock.now_s
        else:
            self.clock.run(duration_s, self.plant)
        if self.cbtc is not None:
            self.cbtc.finish(self.clock.now_s)
        wall = time.perf_counter() - t0
        return LineResult(
            trains=len(self.trains),
            entered=int(sum(bool(np.isfinite(t.entered_s)) for t in self.trains)),
            exited=int(sum(bool(np.isfinite(t.exited_s)) for t in self.trains)),
            stops=list(self.stops),
            dwells=list(self.dwells),
            duration_s=duration_s,
            wall_s=wall,
            entry_s=[t.entered_s for t in self.trains],
            exit_s=[t.exited_s for t in self.trains],
            request_s=[t.request_s for t in self.trains],
            samples=[(t.samples_t, t.samples_x) for t in self.trains],
            signal_m=list(self.signal_m),
            station_m=[(s.name, s.stop_point_m) for s in self.line.stations],
            min_separation_m=float(self.min_separation_m),
            position_errors=self.position_errors,
            skipped_stops=self.skipped_stops,
            signals_passed_at_danger=self.signals_passed_at_danger,
            slide_events=sum(t.slides for t in self.trains),
            slip_events=sum(t.slips for t in self.trains),
            calibration=self.settings.calibration,
            signalling=self.settings.signalling,
            cbtc=None if self.cbtc is None else {**self.cbtc.summary(), **self._regulation_summary()},
            zones=list(self.cbtc.zones) if self.cbtc is not None else [],
            occupancy_link=asdict(self.chain.counts),
        )


#: The regulation's plans computed in this process, by their inputs (a line campaign's worker runs
#: many lines of the same data; a plan takes a second or two to compute).
_REGULATION_PLANS: dict[str, list[Any]] = {}


def _regulation_plan(
    line: Line, vehicle: Vehicle, operation: Operation, handover: str, step_s: float
) -> list[Any]:
    """``sim.capacity.regulation_times`` of these inputs (the embedded door data), computed once per
    process."""
    from railstop.sim.capacity import regulation_times  # (it imports this module)

    key = json.dumps(
        [
            line.model_dump(mode="json"),
            vehicle.model_dump(mode="json"),
            operation.model_dump(mode="json"),
            handover,
            step_s,
        ],
        sort_keys=True,
    )
    plan = _REGULATION_PLANS.get(key)
    if plan is None:
        plan = _REGULATION_PLANS[key] = regulation_times(
            line, vehicle, operation, handover=handover, step_s=step_s
        )
    return plan


def warm_up() -> None:
    """Load the line's own compiled steps from the on-disk cache, compiling them first if they are
    not there (``railstop compile``): the position step (``nodes.chain_step``) and the positioning
    units' fixes, by running the default line's first train over its first circuits."""
    line, vehicle = default_line(), default_vehicle()
    operation = load_operation(None, line)
    operation = operation.model_validate({**operation.model_dump(), "trains": 1})
    LineSimulation(line=line, vehicle=vehicle, operation=operation).run(300.0)
