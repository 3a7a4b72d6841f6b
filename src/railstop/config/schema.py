"""Pydantic schemas of the data a railway engineer edits (DESIGN rule 3).

Units are SI except where a field name says km/h or permille (config edge,
DESIGN rule 5). Unknown keys are rejected (DESIGN rule 6).
"""

from __future__ import annotations

import itertools
from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from railstop.config.base import FieldProblem, FiniteFloat, Fraction, NonNegFloat, PositiveFloat, Stretch
from railstop.config.base import Model as _Model
from railstop.config.layout import (
    Cbtc,
    Segment,
    Signalling,
    SpeedLimit,
    check_blocks,
    check_chain,
    check_segments,
    check_speed_limits,
)
from railstop.errors import SimulationError
from railstop.quantities import KMH_PER_MPS

__all__ = ["FieldProblem", "FiniteFloat", "Fraction", "NonNegFloat", "PositiveFloat"]

# The stop model's simulation step (sim.engine.DT_S and live.tasc.TASC_DT_S are this one): the
# Doppler radar samples once a step, so its sample_period_s must be this (model.build refuses another).
SIM_STEP_S = 0.01


class GradientSegment(Stretch):
    """A constant gradient between two chainages; + is uphill in the R direction."""

    # The gradient over the stretch in per mille, + uphill in the R direction: the gravity force on
    # the train (the mean under it); level between segments.
    permille: Annotated[float, Field(ge=-60.0, le=60.0, allow_inf_nan=False)]


class DopplerRadar(_Model):
    """SPEC §1 speed detection unit: a Doppler sensor at the platform end."""

    # Where the radar stands: this far beyond the stopping point (the platform end), looking back
    # at the approaching train; its range is counted from there.
    beyond_stop_m: NonNegFloat = 10.0
    # The radar's sampling period: one sample a simulation step, so it must equal that step, 0.01 s
    # (another is refused at load).
    sample_period_s: Annotated[float, Field(gt=0.0, le=0.1)] = 0.01
    # The radar sees a train only within this distance of itself; outside it the sample reads 0. It
    # must see the whole zone: at least beyond_stop_m + the first detector's distance.
    range_m: PositiveFloat = 400.0
    # The wayside fits the deceleration (the slope of a line through the speed samples) over the
    # radar samples of this window.
    fit_window_s: Annotated[float, Field(gt=0.0, le=10.0)] = 4.0
    # The speed "now" is the mean of the samples of this shorter window, carried forward to the
    # newest sample with the deceleration's slope.
    speed_window_s: Annotated[float, Field(gt=0.0, le=3.0)] = 0.3

    @field_validator("sample_period_s")
    @classmethod
    def _one_sample_a_step(cls, v: float) -> float:
        # The stop model samples the radar once per simulation step (model.build refuses another
        # period when a stop is run): refuse it here, naming the file, not at the first stop.
        if abs(v - SIM_STEP_S) > 1e-12:
            raise ValueError(f"must equal the simulation step {SIM_STEP_S} s (the radar samples once a step)")
        return v


def _detector_list(v: list[float], least: int, too_few: str) -> list[float]:
    """A detector layout: at least ``least`` distances, farthest first, strictly decreasing."""
    if len(v) < least:
        raise ValueError(too_few)
    if any(b >= a for a, b in zip(v, v[1:], strict=False)):
        raise ValueError("detectors must be listed farthest first, strictly decreasing")
    return v


class TascZone(_Model):
    """SPEC §1 train detection unit and wayside controller settings for one station.

    Detector positions are distances before the stopping point (metres), first
    (farthest) first; the embodiment of the patent uses five wheel sensors.
    """

    # The nominal speed at which a train enters the TASC zone (the disturbance sets' nominal
    # entry_speed_kmh); on the line, the speed ceiling at the station stop's hand-over point.
    entry_speed_kmh: Annotated[float, Field(gt=0.0, le=120.0)] = 60.0
    # SPEC §1: the train detectors' distances before the stopping point, farthest first, strictly
    # decreasing: at least 2 with a Doppler radar, at least 3 without one (variant 2).
    detectors_before_stop_m: list[PositiveFloat]
    # SPEC §1 claim 6, the detectors-only variant of this zone: the detectors it would have without
    # its Doppler radar (Station.detectors_only; None: the same detectors). Laid out as data
    # because the variant needs its own layout: its first command needs two passages, so the
    # first two detectors must lie before the braking point at the entry speed, and after its
    # last detector the stop is open loop, so the last ones must lie close to the stopping point
    # (docs/tasc.md, the detectors-only variant). At least 3, farthest first, strictly decreasing.
    detectors_only_before_stop_m: list[PositiveFloat] | None = None
    # The detectors-only variant's transponders (the station's ato_transponders_before_stop_m in
    # Station.detectors_only; None: the station's own). [interpretation] Without a radar the
    # onboard overrun guard counts its odometer's declared error from the last transponder, over
    # the variant's longer zone (400 m): a transponder halfway keeps that error from braking
    # trains that are on their plan (docs/tasc.md, the detectors-only variant).
    detectors_only_transponders_before_stop_m: list[PositiveFloat] | None = None
    # SPEC §1: the kind of train detector; checked against the list, not read by the simulation
    # (every kind gives the same passage times).
    detector_kind: Literal["wheel-sensor", "ultrasonic", "optical", "magnetic", "proximity"] = "wheel-sensor"
    # SPEC §1 speed detection unit at the platform end (None: no radar, SPEC §1 variant 2: speed
    # and deceleration from the detectors' passage times).
    doppler: DopplerRadar | None = None
    # When the wayside computes a new command: "detectors" at each detector passage (SPEC §1);
    # "continuous" also every continuous_period_s between them (needs the Doppler radar).
    update: Literal["detectors", "continuous"] = "detectors"
    # With update = "continuous": the period of the wayside's commands between detector passages.
    continuous_period_s: Annotated[float, Field(gt=0.0, le=5.0)] = 0.5
    # SPEC §1 claim 3: the form of the braking control signal, 1-8 (1 position, 2 distance, 3 time
    # between detectors, 4 speed, 5 deceleration, 6 required deceleration, 7 brake command,
    # 8 increase / decrease braking); --form overrides it.
    signal_form: Annotated[int, Field(ge=1, le=8)] = 6
    # The radio latency the wayside allows for: added to the brake's dead time and lag as the delay
    # until a new command acts, in its planning and in its overrun guard.
    assumed_link_latency_s: Annotated[float, Field(ge=0.0, le=1.0)] = 0.0
    # Identify the brake response (dead time, lag) online from the Doppler radar once the
    # first braking command has acted, and plan with it (beyond SPEC §1: control.brake_ident).
    identify_brake_response: bool = True
    # Fill in a missed detector's passage from the Doppler-integrated travel (beyond SPEC §1:
    # wayside.tasc_unit.wayside_passage_1).
    fill_missed_detectors: bool = True
    # Cyclic transmission: the latest telegram is repeated at this period
    # (the train discards repeats it already has), so one lost copy costs a
    # period, not the command.
    repeat_period_s: Annotated[float, Field(gt=0.0, le=2.0)] = 0.1
    # The medium of the braking telegrams: a preset of railstop/data/media.toml
    # (SPEC §1 embodiment: RF; SPEC §5: loop, transponder or radio), and the
    # EN 50159 safety layer around them: category 3 (open radio, keyed MAC)
    # unless the medium is a closed system. A telegram older than
    # max_telegram_age_s on arrival is refused as stale.
    medium: str = "radio"
    # EN 50159 category of the braking telegrams' safety layer: 1 or 2 close each frame with a
    # CRC-32, 3 with a keyed MAC (a longer frame, more airtime on the medium).
    safety_category: Literal[1, 2, 3] = 3
    # A telegram older than this on arrival is refused as stale (EN 50159 delay); it also bounds
    # the frames the link keeps in flight.
    max_telegram_age_s: Annotated[float, Field(gt=0.0, le=5.0)] = 0.5
    # Supervision (DESIGN rule 10): once the train has a braking telegram, a telegram (new or a
    # cyclic repeat) must arrive at least this often, else the onboard unit applies the
    # emergency brake through wire e. The first one must have come this long after the train
    # is surely past the second detector (the third without a Doppler radar).
    supervision_timeout_s: Annotated[float, Field(gt=0.0, le=10.0)] = 1.0
    # The wayside's overrun guard (DESIGN rule 10): an emergency-stop telegram when stopping
    # before the platform end would need more than this fraction of the vehicle's full service
    # after the response time (assumed latency + brake dead time + lag).
    overrun_guard_decel_fraction: Annotated[float, Field(gt=0.0, le=5.0)] = 1.0
    # The train's own control around TASC (SPEC §1: "before the TASC zone and alongside it the
    # train runs under its own brake controller"): it keeps its speed up to the zone and, from
    # the zone's first transponder (the first detector), its brake controller applies this
    # initial brake step, B1..B7 (a PWM train: that step's deceleration as a duty). TASC takes
    # over as its configuration says: config 1 gives the brake controller the onboard command,
    # config 2 switches the ECU's input over; config 3 superimposes, so the train's step stays
    # a floor TASC cannot go below to standstill (the OR of the two pulses). 0 (default): no
    # initial brake, the train holds its speed until its first braking telegram (the
    # supervision brakes it if none comes). [interpretation] SPEC §1 names the train's own
    # control but not its law; an initial brake step before the automatic stop is common
    # practice. The wayside's model of the train brakes with it from the first detector on.
    initial_brake_notch: Annotated[int, Field(ge=0, le=7)] = 0

    @field_validator("detectors_before_stop_m")
    @classmethod
    def _detectors(cls, v: list[float]) -> list[float]:
        # SPEC §1: at least two detectors at set intervals approaching the platform.
        return _detector_list(v, 2, "at least 2 detectors are needed (SPEC §1)")

    @field_validator("detectors_only_before_stop_m")
    @classmethod
    def _variant_detectors(cls, v: list[float] | None) -> list[float] | None:
        # SPEC §1 variant 2: at least 3 detectors (speed and deceleration from passage times).
        if v is None:
            return v
        return _detector_list(
            v, 3, "the detectors-only variant needs at least 3 detectors (SPEC §1 variant 2)"
        )

    @model_validator(mode="after")
    def _variant(self) -> TascZone:
        # SPEC §1 variant 2: without a Doppler sensor, >= 3 detectors give speed
        # and deceleration from passage times.
        if self.doppler is None and len(self.detectors_before_stop_m) < 3:
            raise FieldProblem(
                "detectors_before_stop_m",
                "without a doppler radar at least 3 detectors are needed (SPEC §1 variant 2; a zone "
                "gives its detectors-only layout as detectors_only_before_stop_m)",
            )
        if self.update == "continuous" and self.doppler is None:
            raise FieldProblem("update", "update = 'continuous' needs a doppler radar")
        radar = self.doppler
        if radar is not None:
            # The radar reads 0 for a train farther than range_m from it (model.step: in range while
            # radar position - front <= range_m, the radar beyond_stop_m past the stopping point):
            # it must see the train over the whole zone, from the first detector on.
            reach = radar.beyond_stop_m + self.detectors_before_stop_m[0]
            if reach > radar.range_m:
                raise FieldProblem(
                    "doppler.range_m",
                    f"the radar ({radar.beyond_stop_m:g} m past the stop) must see the first detector "
                    f"({self.detectors_before_stop_m[0]:g} m before the stop), {reach:g} m away: "
                    f"range_m must be at least {reach:g} m",
                )
        return self


# The longest platform a station may have (m): the longest metro platforms are ~ 300 m; a longer
# value is a length typed in mm (140000.0 for 140 m).
MAX_PLATFORM_M = 1000.0


class Station(_Model):
    # The station's name, unique on the line (any case): --station and the operation file name it.
    name: Annotated[str, Field(min_length=1, max_length=64)]
    # The stopping point (a chainage): where the train's front should stop; the detectors and the
    # ATO transponders are placed before it, the stations listed in increasing stop_point_m.
    stop_point_m: FiniteFloat
    # The platform's length; the platform runs back this far from its end (platform_end_m).
    platform_length_m: Annotated[float, Field(gt=0.0, le=MAX_PLATFORM_M, allow_inf_nan=False)]
    # The side of the platform in the running direction, "L" or "R": the side whose doors and
    # platform screen doors open at the dwell.
    platform_side: Literal["L", "R"]
    # Chainage of the platform's end (None: 5 m beyond the stopping point); the overrun guards stop
    # the train before it.
    platform_end_m: FiniteFloat | None = None
    # The gradient around the station: segments of constant gradient, not overlapping (the gaps
    # between them are level); the stop model's track profile.
    gradient: list[GradientSegment] = Field(default_factory=list)
    # How far from the stopping point a stop still lets the platform screen doors open: SPEC §1
    # gives ±35 cm for the Korean metro with PSD, SPEC §3 ±500 mm for manually driven lines.
    psd_tolerance_m: Annotated[float, Field(gt=0.0, le=2.0, allow_inf_nan=False)] = 0.35
    # SPEC §1: the station's TASC zone: detectors, Doppler radar, the wayside's settings and the
    # telegram link.
    tasc: TascZone
    # Position references of the conventional onboard ATO (the baseline TASC
    # replaces): transponders that reset its odometry, metres before the
    # stopping point, farthest first. Default: one at the first TASC detector
    # and a precise-stop transponder 25 m before the stop.
    ato_transponders_before_stop_m: list[PositiveFloat] | None = None

    @model_validator(mode="after")
    def _geometry(self) -> Station:
        end = self.platform_end
        if end < self.stop_point_m:
            raise FieldProblem(
                "platform_end_m", f"platform_end_m must not be before stop_point_m ({self.stop_point_m})"
            )
        # A stop within the PSD tolerance is a good stop: the farthest one (stop_point_m +
        # psd_tolerance_m) must not pass the platform's end, where the overrun guards stop the
        # train (a platform end at the stopping point makes a nominal stop an emergency brake).
        # Only a given platform_end_m can be too near (the default is 5 m past the stop).
        # (1e-9 m: the chainages' rounding, so 1200.35 is 0.35 m past 1200.)
        if self.platform_end_m is not None and end - self.stop_point_m < self.psd_tolerance_m - 1e-9:
            raise FieldProblem(
                "platform_end_m",
                f"{end - self.stop_point_m:g} m past stop_point_m ({self.stop_point_m:g} m): the platform "
                f"must end at least psd_tolerance_m ({self.psd_tolerance_m:g} m) past the stopping point",
            )
        # The stopping point lies on the platform: a train stopped before its start (platform_end
        # - platform_length_m) has its doors at no platform.
        if self.stop_point_m < self.platform_start:
            raise FieldProblem(
                "stop_point_m",
                f"before the platform's start at {self.platform_start:g} m (its end {end:g} m less "
                f"platform_length_m {self.platform_length_m:g} m): the stopping point must be on the "
                "platform",
            )
        segs = sorted(self.gradient, key=lambda s: s.start_m)
        for a, b in zip(segs, segs[1:], strict=False):
            if b.start_m < a.end_m:
                raise FieldProblem("gradient", f"gradient segments overlap at {b.start_m} m")
        return self

    @property
    def platform_end(self) -> float:
        return self.stop_point_m + 5.0 if self.platform_end_m is None else self.platform_end_m

    def detectors_only(self) -> Station:
        """This station without its Doppler radar (SPEC §1 claim 6, the detectors-only variant), its
        detectors those of ``tasc.detectors_only_before_stop_m`` where the zone gives them.

        Validated as a station file is: a zone of fewer than 3 detectors and no variant layout
        raises :class:`~railstop.errors.FieldProblem` (``pydantic.ValidationError``;
        ``config.loader.with_detectors_only`` reports it as a file's problem)."""
        return Station.model_validate(self.detectors_only_data())

    def detectors_only_data(self) -> dict[str, object]:
        """The data of :meth:`detectors_only`, not yet validated."""
        tasc = self.tasc.model_dump()
        tasc["doppler"] = None
        tasc["update"] = "detectors"
        if self.tasc.detectors_only_before_stop_m is not None:
            tasc["detectors_before_stop_m"] = list(self.tasc.detectors_only_before_stop_m)
        data = {**self.model_dump(), "tasc": tasc}
        if self.tasc.detectors_only_transponders_before_stop_m is not None:
            data["ato_transponders_before_stop_m"] = list(self.tasc.detectors_only_transponders_before_stop_m)
        return data

    @property
    def platform_start(self) -> float:
        return self.platform_end - self.platform_length_m

    def ato_transponders_m(self) -> list[float]:
        """Chainages of the ATO transponders, farthest first."""
        before = self.ato_transponders_before_stop_m
        if before is None:
            before = [self.tasc.detectors_before_stop_m[0], 25.0]
        return [self.stop_point_m - d for d in sorted(before, reverse=True)]

    def detector_positions_m(self) -> list[float]:
        return [self.stop_point_m - d for d in self.tasc.detectors_before_stop_m]


class TrackCircuit(Stretch):
    """SPEC §2: a track circuit; the onboard track-circuit DB maps its ID to the chainage of its start.

    ``kind``: "jointless" (audio-frequency, the electrical boundary is a tuned
    zone some metres long) or "insulated" (insulated rail joints: a sharp
    boundary). The kind decides the boundary uncertainty (``TrackCircuitDetection``).
    """

    id: Annotated[int, Field(ge=1, le=65535)]  # fits the 16 bits of an occupancy telegram
    # "jointless" (audio-frequency, a tuned zone as boundary) or "insulated" (insulated rail joints):
    # picks the boundary's uncertainty from the track's detection settings (boundary_sd_*_m).
    kind: Literal["jointless", "insulated"] = "jointless"


class Tunnel(Stretch):
    """A GNSS shadow (SPEC §2); ``repeater`` = a satellite-signal repeater covers the whole section."""

    # A name for the shadow (optional): for the reader of the data, the simulation does not use it.
    name: Annotated[str, Field(min_length=1, max_length=64)] | None = None
    # True: a satellite-signal repeater covers the whole section, so it is no GNSS shadow and the
    # clocks in it stay disciplined (SPEC §2).
    repeater: bool = False


class TrackCircuitDetection(_Model):
    """SPEC §2 wayside track-circuit device: when and where it declares a circuit occupied.

    The delay (receiver filter, relay or input scan) is drawn per passage as
    normal(mean, spread) clipped at 0; the boundary where the first axle is
    detected differs from the surveyed start by normal(0, sd of the kind).
    Values and reasons: docs/position.md.
    """

    # Mean of the delay from the first axle crossing the boundary to the device declaring the
    # circuit occupied; the onboard learner's nominal detection delay too.
    delay_mean_s: Annotated[float, Field(ge=0.0, le=5.0, allow_inf_nan=False)] = 0.30
    # Standard deviation of that delay, drawn per passage as normal(mean, spread) clipped at 0.
    delay_spread_s: Annotated[float, Field(ge=0.0, le=2.0, allow_inf_nan=False)] = 0.05
    # Standard deviation of where the first axle is detected against the surveyed start, for a
    # jointless circuit (its tuned zone is some metres long).
    boundary_sd_jointless_m: Annotated[float, Field(ge=0.0, le=50.0, allow_inf_nan=False)] = 1.5
    # The same for an insulated circuit (a sharp boundary at the rail joints).
    boundary_sd_insulated_m: Annotated[float, Field(ge=0.0, le=50.0, allow_inf_nan=False)] = 0.2

    def boundary_sd_m(self, kind: str) -> float:
        return self.boundary_sd_insulated_m if kind == "insulated" else self.boundary_sd_jointless_m


class GnssClocks(_Model):
    """SPEC §2 GNSS-disciplined clocks of the wayside units and the train.

    Disciplined: the clock is within ``disciplined_error_s`` (standard
    deviation) of GNSS time. In a shadow without a repeater it free-runs: its
    error grows at its frequency offset, drawn per clock as normal(0,
    ``free_run_drift_ppm``). A clock with no time source at all (a wayside unit
    in an unrepeated tunnel, or every clock when GNSS is off) was last set
    ``holdover_s`` before the run.
    """

    # Standard deviation of a GNSS-disciplined clock's error against GNSS time.
    disciplined_error_s: Annotated[float, Field(ge=0.0, le=1e-3, allow_inf_nan=False)] = 1e-7
    # Standard deviation of a free-running clock's frequency offset, drawn per clock: its error
    # grows at this rate in a shadow without a repeater.
    free_run_drift_ppm: Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)] = 1.0
    # How long before the run a clock with no time source at all was last set: its error at the
    # start is its drift times this.
    holdover_s: Annotated[float, Field(ge=0.0, le=3.2e7, allow_inf_nan=False)] = 86400.0


class Track(_Model):
    """SPEC §2 line data: track circuits (contiguous from 0), GNSS shadows, detection and clocks."""

    # SPEC §2 track circuits in running order, contiguous from chainage 0 with unique IDs; the
    # onboard track-circuit DB holds each ID with the chainage of its start.
    circuits: list[TrackCircuit] = Field(default_factory=list)
    # SPEC §2 GNSS shadows (tunnels, cut-and-cover sections), not overlapping and on the line.
    tunnels: list[Tunnel] = Field(default_factory=list)
    # SPEC §2 wayside track-circuit device: its detection delay and boundary uncertainty.
    detection: TrackCircuitDetection = Field(default_factory=TrackCircuitDetection)
    # SPEC §2 GNSS-disciplined clocks of the wayside units and the trains.
    clocks: GnssClocks = Field(default_factory=GnssClocks)

    @model_validator(mode="after")
    def _layout(self) -> Track:
        check_chain(self.circuits, "circuits", "track circuit", "circuit")
        tunnels = sorted(enumerate(self.tunnels), key=lambda it: it[1].start_m)
        for (_, a), (j, b) in zip(tunnels, tunnels[1:], strict=False):
            if b.start_m < a.end_m:
                raise FieldProblem(
                    f"tunnels[{j}].start_m",
                    f"tunnels overlap: {b.start_m} m is before the end of another at {a.end_m} m",
                )
        return self

    @property
    def end_m(self) -> float | None:
        return self.circuits[-1].end_m if self.circuits else None


class LineInfo(_Model):
    # The line's name, shown in reports and messages.
    name: Annotated[str, Field(min_length=1)]
    # The line's own speed limit: the trains' ceiling where no civil limit is lower; entry speeds
    # above it are refused.
    speed_limit_kmh: Annotated[float, Field(gt=0.0, le=200.0)] = 80.0
    # Chainage of the end of the line (optional): the track circuits must end exactly there.
    length_m: PositiveFloat | None = None


class Line(_Model):
    # The line's name, speed limit and length.
    line: LineInfo
    # The stations in increasing stop_point_m, with unique names; the first is the default station.
    stations: list[Station] = Field(min_length=1)
    # SPEC §2 track circuits, GNSS shadows, detection and clocks (empty: no position correction data).
    track: Track = Field(default_factory=Track)
    # The line with many trains (config.layout): segments with IDs (SPEC §4), fixed-block
    # signalling over the track circuits, civil speed limits. Empty / None: a line of single stops.
    segments: list[Segment] = Field(default_factory=list)
    # Fixed-block signalling over the track circuits (None: no blocks; a line run needs them).
    signalling: Signalling | None = None
    # Civil speed limits over stretches of the line, not overlapping; the line's own limit elsewhere.
    speed_limits: list[SpeedLimit] = Field(default_factory=list)
    # SPEC §4 moving-block CBTC over the segments (None: the defaults of config.layout.Cbtc).
    cbtc: Cbtc = Field(default_factory=Cbtc)

    @model_validator(mode="after")
    def _unique(self) -> Line:
        names = [s.name for s in self.stations]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise FieldProblem("stations", f"station names must be unique, repeated: {sorted(dup)}")
        for i, (prev, st) in enumerate(itertools.pairwise(self.stations), start=1):
            if st.stop_point_m < prev.stop_point_m:
                raise FieldProblem(
                    f"stations[{i}].stop_point_m",
                    f"stations must be listed in increasing stop_point_m: station {st.name!r} stops at "
                    f"{st.stop_point_m:g} m, before the previous station {prev.name!r} "
                    f"(stations[{i - 1}].stop_point_m = {prev.stop_point_m:g} m)",
                )
        return self

    @model_validator(mode="after")
    def _gradients_apart(self) -> Line:
        # One track has one gradient at each chainage: the stations' segments together make the
        # line's profile (physics.plant.track_gradient, a line run), so the segments of two
        # stations must not overlap either (each station's own are checked in Station).
        segs = sorted(
            (
                (seg.start_m, i, k, seg)
                for i, st in enumerate(self.stations)
                for k, seg in enumerate(st.gradient)
            ),
            key=lambda it: it[0],
        )
        for (_, i, _, a), (_, j, k, b) in zip(segs, segs[1:], strict=False):
            if b.start_m < a.end_m:
                raise FieldProblem(
                    f"stations[{j}].gradient[{k}].start_m",
                    f"the gradient segment {b.start_m:g} .. {b.end_m:g} m of station "
                    f"{self.stations[j].name!r} overlaps the segment {a.start_m:g} .. {a.end_m:g} m of "
                    f"station {self.stations[i].name!r} over {b.start_m:g} .. {min(a.end_m, b.end_m):g} m",
                )
        return self

    @model_validator(mode="after")
    def _track_covers_line(self) -> Line:
        # SPEC §2: every position on the line lies in exactly one track circuit
        # (contiguity is checked in Track); here: the circuits reach the line's
        # end and cover every platform, and the tunnels lie on the line.
        end = self.track.end_m
        if end is None:
            return self
        if self.line.length_m is not None and end != self.line.length_m:
            raise FieldProblem(
                f"track.circuits[{len(self.track.circuits) - 1}].end_m",
                f"the last track circuit must end at line.length_m ({self.line.length_m:g} m)",
            )
        # The station's own field is blamed (a stop point off the line, a platform typed in mm),
        # never the whole list of circuits.
        on_line = f"the line (its track circuits) runs 0 .. {end:g} m"
        for i, s in enumerate(self.stations):
            where = f"station {s.name!r}'s platform {s.platform_start:g} .. {s.platform_end:g} m"
            if not 0.0 <= s.stop_point_m <= end:
                raise FieldProblem(
                    f"stations[{i}].stop_point_m",
                    f"the stopping point of station {s.name!r} is off the line: {on_line}",
                )
            if s.platform_end > end:
                field = "platform_end_m" if s.platform_end_m is not None else "stop_point_m"
                raise FieldProblem(f"stations[{i}].{field}", f"{where} ends past the line's end: {on_line}")
            if s.platform_start < 0.0:
                raise FieldProblem(
                    f"stations[{i}].platform_length_m",
                    f"{where} starts before the line's start: {on_line}",
                )
        for i, t in enumerate(self.track.tunnels):
            if t.start_m < 0.0 or t.end_m > end:
                raise FieldProblem(
                    f"track.tunnels[{i}]",
                    f"tunnel {t.start_m} .. {t.end_m} m is not on the line (0 .. {end} m)",
                )
        return self

    @model_validator(mode="after")
    def _layout(self) -> Line:
        end = self.line.length_m if self.line.length_m is not None else self.track.end_m
        check_segments(self.segments, end)
        if self.signalling is not None:
            check_blocks(self.signalling.blocks, [c.id for c in self.track.circuits])
        check_speed_limits(self.speed_limits, end)
        return self

    @property
    def track_circuits(self) -> list[TrackCircuit]:
        return self.track.circuits

    @property
    def end_m(self) -> float:
        """Where the line ends: its length, else the end of its track circuits (0 without either)."""
        return self.line.length_m if self.line.length_m is not None else float(self.track.end_m or 0.0)

    @property
    def tunnels(self) -> list[Tunnel]:
        return self.track.tunnels

    def station(self, name: str | None) -> Station:
        if name is None:
            return self.stations[0]
        for s in self.stations:
            if s.name.lower() == name.lower():
                return s
        raise SimulationError(
            f"unknown station {name!r}; this line has: {', '.join(s.name for s in self.stations)}"
        )


# Physical bounds of a train on steel rail ([interpretation]: the data must describe a train, not
# any number; each bound is several times what a metro has). Braking: wheel on rail gives at most
# about 0.3 g (3 m/s², as the CBTC guaranteed rate's bound); a larger rate is a typing error.
MAX_BRAKE_MPS2 = 3.0
BrakeRate = Annotated[float, Field(gt=0.0, le=MAX_BRAKE_MPS2, allow_inf_nan=False)]
# A car is 5 to 40 m long and weighs (empty) 5 to 100 t: a vehicle outside is not a train.
CAR_LENGTH_M = (5.0, 40.0)
CAR_TARE_KG = (5_000.0, 100_000.0)
# [interpretation] A crush-loaded metro car carries 15-25 t: 40 t a car is the most a car's payload is.
CAR_PAYLOAD_KG = 40_000.0


# How far (a share of full service) the PWM map's largest deceleration may fall short of B7.
PWM_REACH_TOLERANCE = 0.02


class BrakeModel(_Model):
    """SPEC §1 brake chain: notch table, emergency, PWM map, ECU + actuator dynamics."""

    # SPEC §1 fig. 3: the deceleration of each service notch B1..B7, exactly 7, increasing; B7 is full
    # service.
    notch_decel_mps2: list[BrakeRate]
    # The emergency brake's deceleration (wire e), at least the B7 deceleration.
    emergency_decel_mps2: BrakeRate
    # The PWM brake command's duty ratios (increasing, at least 2): with pwm_decel_mps2 the map from
    # duty to service deceleration, interpolated.
    pwm_duty: list[Fraction]
    # The service deceleration at each duty of pwm_duty (same length, not decreasing).
    pwm_decel_mps2: list[Annotated[float, Field(ge=0.0, le=MAX_BRAKE_MPS2, allow_inf_nan=False)]]
    # The PWM carrier frequency: the onboard unit's PWM output (tasc-pwm, tasc-switched-pwm) takes
    # a new duty once per carrier period.
    pwm_carrier_hz: Annotated[float, Field(gt=0.0, le=2000.0)] = 50.0
    # The brake's dead time: from a new demand to the first response (whole simulation steps; the
    # disturbance sets' nominal brake_dead_time_s).
    dead_time_s: Annotated[float, Field(ge=0.0, le=2.0)]
    # The first-order lag of the brake's build-up (the disturbance sets' nominal
    # brake_time_constant_s).
    time_constant_s: Annotated[float, Field(gt=0.0, le=3.0)]
    # The ECU's jerk limiter: the deceleration demand changes at most this fast. [interpretation]
    # At least 0.1 m/s³: slower, full service takes 10 s and more to build up (metros limit jerk
    # for comfort to about 0.5-1.5 m/s³); a smaller value is a typing error.
    jerk_limit_mps3: Annotated[float, Field(ge=0.1, le=20.0, allow_inf_nan=False)]
    # The train's own brake controller (config 1, the ATO, the wayside's notch modulation of forms 7
    # and 8): it updates its notch once per this cycle.
    controller_cycle_s: Annotated[float, Field(gt=0.0, le=1.0)] = 0.1
    # The train's brake controller holds a notch at least this long before it changes it.
    controller_min_hold_s: Annotated[float, Field(ge=0.0, le=3.0)] = 0.3
    # The onboard TASC unit's step output (config 2, tasc-step, through the switching unit) holds a
    # notch at least this long (config 1 holds controller_min_hold_s).
    tasc_min_hold_s: Annotated[float, Field(ge=0.0, le=3.0)] = 0.2
    # The onboard TASC unit's own modulator (config 2, tasc-step) chooses its notch once per this
    # cycle; a notch the wayside sends (forms 7, 8) is relayed at once.
    tasc_cycle_s: Annotated[float, Field(gt=0.0, le=1.0)] = 0.05
    # Config 2's switching unit (SPEC §1 claims 12-14): the changeover switches' transfer time,
    # break before make: for this long the ECU input is open (000: no service brake).
    switch_transfer_s: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = 0.02

    @field_validator("notch_decel_mps2")
    @classmethod
    def _notches(cls, v: list[float]) -> list[float]:
        # SPEC §1 fig. 3: 3 service wires a, b, c carry exactly 7 steps B1..B7.
        if len(v) != 7:
            raise ValueError(f"exactly 7 notches B1..B7 are needed, got {len(v)}")
        if any(b <= a for a, b in zip(v, v[1:], strict=False)):
            raise ValueError("notch decelerations must increase from B1 to B7")
        return v

    @model_validator(mode="after")
    def _pwm(self) -> BrakeModel:
        if len(self.pwm_duty) != len(self.pwm_decel_mps2) or len(self.pwm_duty) < 2:
            raise FieldProblem(
                "pwm_decel_mps2", "pwm_duty and pwm_decel_mps2 need the same length, at least 2"
            )
        if any(b <= a for a, b in zip(self.pwm_duty, self.pwm_duty[1:], strict=False)):
            raise FieldProblem("pwm_duty", "pwm_duty must increase strictly")
        dec = self.pwm_decel_mps2
        if any(b < a for a, b in zip(dec, dec[1:], strict=False)):
            raise FieldProblem(
                "pwm_decel_mps2", "pwm_decel_mps2 must not decrease (larger duty = more braking)"
            )
        if self.emergency_decel_mps2 < self.notch_decel_mps2[-1]:
            raise FieldProblem(
                "emergency_decel_mps2", "emergency_decel_mps2 must be at least the B7 deceleration"
            )
        # [interpretation] The PWM command reaches full service: a map whose largest deceleration
        # falls short of B7 (by more than PWM_REACH_TOLERANCE of it) makes the PWM configurations
        # brake weaker than the notch table says the train can, silently.
        full, reach = self.notch_decel_mps2[-1], max(dec)
        if reach < full * (1.0 - PWM_REACH_TOLERANCE):
            raise FieldProblem(
                "pwm_decel_mps2",
                f"the PWM map's largest deceleration {reach:g} m/s² falls short of full service "
                f"(notch_decel_mps2 B7 = {full:g} m/s²): the PWM command must reach it "
                f"(within {PWM_REACH_TOLERANCE:.0%})",
            )
        return self

    @property
    def full_service_mps2(self) -> float:
        return self.notch_decel_mps2[-1]


class Traction(_Model):
    """Tractive-effort curve: constant force up to ``base_speed_kmh``, constant power above.

    ``max_accel_mps2`` is the acceleration the traction control aims at
    (load-weighed), ``motored_axle_fraction`` the share of the train's weight
    on motored axles (4M2T: 4/6), which sets the adhesion limit in traction.
    While traction demands more than adhesion gives, the anti-slip control
    holds the wheels ``slip_ratio`` faster than the train.
    """

    # The tractive effort up to base_speed_kmh; above it the power max_force_n x base speed holds.
    max_force_n: Annotated[float, Field(gt=0.0, le=2e6, allow_inf_nan=False)]
    # The speed where the constant force gives way to constant power.
    base_speed_kmh: Annotated[float, Field(gt=0.0, le=200.0, allow_inf_nan=False)]
    # The acceleration the traction control aims at (load-weighed): the most traction gives.
    max_accel_mps2: Annotated[float, Field(gt=0.0, le=2.0, allow_inf_nan=False)] = 1.0
    # The share of the train's weight on motored axles (4M2T: 4/6): sets the adhesion limit in
    # traction.
    motored_axle_fraction: Annotated[float, Field(gt=0.0, le=1.0, allow_inf_nan=False)] = 1.0
    # While traction demands more than adhesion gives, the anti-slip control holds the wheels this
    # fraction faster than the train (the tachometer over-reads by it).
    slip_ratio: Annotated[float, Field(ge=0.0, lt=1.0, allow_inf_nan=False)] = 0.10

    @property
    def max_power_w(self) -> float:
        return self.max_force_n * self.base_speed_kmh / KMH_PER_MPS  # F x v, v from km/h


class Positioning(_Model):
    """SPEC §2 onboard position-correction device: tachometer, odometer log and the learner.

    The learner (beyond SPEC §2) estimates the odometer's scale and the
    constant part of the detection delay from the history of corrections;
    its prior and noise are set here (see onboard/positioning.py).
    """

    # SPEC §2 tachometer: pulses per wheel revolution; the odometer counts whole pulses.
    tachometer_pulses_per_rev: Annotated[int, Field(ge=1, le=10000)] = 100
    # How long the odometer log (GNSS time, odometer, tachometer speed) reaches back: the occupancy
    # instant of a telegram is looked up in it (the stop kernel keeps its own 2 s).
    log_window_s: Annotated[float, Field(gt=0.0, le=60.0, allow_inf_nan=False)] = 5.0
    # How far past its newest log sample a telegram time may lie (clock offsets) and
    # still be used, extrapolating with the last tachometer speed.
    max_extrapolation_s: Annotated[float, Field(ge=0.0, le=5.0, allow_inf_nan=False)] = 1.0
    # Beyond SPEC §2: learn the odometer's scale and the constant detection delay from the fixes
    # (false: correct the position only).
    learn: bool = True
    # The learner's prior standard deviation of the odometer's scale error.
    scale_prior_pct: Annotated[float, Field(gt=0.0, le=20.0, allow_inf_nan=False)] = 5.0
    # The learner's prior standard deviation of the constant delay, around the line's nominal
    # detection delay.
    delay_prior_s: Annotated[float, Field(gt=0.0, le=5.0, allow_inf_nan=False)] = 0.2
    # Standard deviation of the start position, and of a fix where the line data gives no
    # boundary uncertainty.
    fix_sd_m: Annotated[float, Field(gt=0.0, le=50.0, allow_inf_nan=False)] = 1.5
    # A fix further than this many standard deviations from the prediction is not learned from:
    # the position restarts from it (counted as gated).
    gate_sigma: Annotated[float, Field(gt=0.0, le=100.0, allow_inf_nan=False)] = 4.0
    # Beyond SPEC §2: the accelerometer that bridges the odometer while the WSP acts (slide
    # compensation); the standard deviation of its bias after the gradient's gravity is taken
    # out. [interpretation] a MEMS unit of a train's odometry, with the gradient from the line
    # data: a few hundredths of a m/s².
    accelerometer_bias_sd_mps2: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = 0.02


class Atp(_Model):
    """The train's own protection around TASC (DESIGN rule 10): the overrun guard.

    The guard knows the station's platform end from its line data and the
    train's position from its odometer, reset at the ATO transponders; it
    counts the odometer's possible error (``odometer_uncertainty_pct`` of the
    distance since the last reset plus ``position_margin_m``) against itself,
    and applies the emergency brake when stopping before the platform end
    would need more than ``guard_decel_fraction`` x full service after the
    brake's response time.
    """

    # The odometer error the overrun guard counts against itself: this share of the distance since
    # the last transponder reset.
    odometer_uncertainty_pct: Annotated[float, Field(ge=0.0, le=10.0, allow_inf_nan=False)] = 1.5
    # A fixed position error the overrun guard adds to that.
    position_margin_m: Annotated[float, Field(ge=0.0, le=20.0, allow_inf_nan=False)] = 0.5
    # The guard applies the emergency brake when stopping before the platform end would need more
    # than this fraction of full service after the brake's response time.
    guard_decel_fraction: Annotated[float, Field(gt=0.0, le=2.0, allow_inf_nan=False)] = 1.0


class Vehicle(_Model):
    # The vehicle's name, shown in reports and messages.
    name: Annotated[str, Field(min_length=1)]
    # The number of cars: the length and the tare mass must be a train's for it (5-40 m and
    # 5-100 t a car); the simulation itself runs the whole train as one mass.
    cars: Annotated[int, Field(ge=1, le=20)]
    # The train's length: the gradient force is the mean gradient under it, and on the line its rear
    # occupies the track behind the front.
    length_m: PositiveFloat
    # The empty train's mass (AW0).
    tare_mass_kg: Annotated[float, Field(gt=0.0, le=2e6, allow_inf_nan=False)]
    # The payload of a crush-loaded train (AW0 to AW3): a run's mass is tare + load_factor x this.
    crush_payload_kg: Annotated[float, Field(ge=0.0, le=2e6, allow_inf_nan=False)]
    # The equivalent mass of the rotating parts (wheelsets, motors) as a fraction of tare: added to
    # the mass that is accelerated, not to the weight.
    rotating_mass_factor: Annotated[float, Field(ge=0.0, le=0.5)]
    # Davis running resistance R(v) = A + B v + C v²: the constant term A.
    davis_a_n: Annotated[float, Field(ge=0.0, le=1e5, allow_inf_nan=False)]
    # The term B of R(v), in N per m/s.
    davis_b_n_per_mps: Annotated[float, Field(ge=0.0, le=1e4, allow_inf_nan=False)]
    # The term C of R(v), in N per (m/s)².
    davis_c_n_per_mps2: Annotated[float, Field(ge=0.0, le=1e3, allow_inf_nan=False)]
    # The wheel's diameter: the tachometer's revolutions give the distance with it (the disturbance
    # sets' nominal wheel_diameter_mm; the odometer error is relative to it).
    wheel_diameter_m: Annotated[float, Field(gt=0.5, lt=1.2)]
    # The dry rail's adhesion coefficient: it limits braking and traction; a demand above what it
    # gives slides or slips the wheels (the disturbance sets' nominal low_adhesion_mu).
    # [interpretation] At least 0.1: wet rail gives about 0.1, dry rail 0.2-0.4; a lower value is
    # no dry rail (low-adhesion patches are the disturbance set's low_adhesion_mu).
    adhesion_mu: Annotated[float, Field(ge=0.1, le=0.5)]
    # While the wheels slide under braking, the wheel-slide protection holds them this fraction
    # slower than the train (the tachometer under-reads by it).
    slide_slip_ratio: Annotated[float, Field(ge=0.0, lt=1.0)] = 0.15
    # SPEC §1 brake chain: notch table, emergency, PWM map, ECU and actuator dynamics.
    brake: BrakeModel
    # Needed to drive between stations (position-run); a braking-only vehicle file may omit it.
    traction: Traction | None = None
    # SPEC §2 onboard position-correction device: tachometer, odometer log and the learner.
    positioning: Positioning = Field(default_factory=Positioning)
    # The train's own overrun guard around TASC (DESIGN rule 10).
    atp: Atp = Field(default_factory=Atp)

    @model_validator(mode="after")
    def _a_train(self) -> Vehicle:
        # Physically a train: its cars 5-40 m long and 5-100 t empty each ([interpretation],
        # CAR_LENGTH_M, CAR_TARE_KG), so that a length or a mass off by a factor is caught.
        for name, total, (lo, hi), unit, per in (
            ("length_m", self.length_m, CAR_LENGTH_M, "m", 1.0),
            ("tare_mass_kg", self.tare_mass_kg, CAR_TARE_KG, "t", 1000.0),
        ):
            car = total / self.cars / per
            if not lo / per <= car <= hi / per:
                raise FieldProblem(
                    name,
                    f"{car:g} {unit} per car for {self.cars} cars: "
                    f"a car is {lo / per:g} to {hi / per:g} {unit}",
                )
        # [interpretation] A crush-loaded metro car carries 15-25 t: more than CAR_PAYLOAD_KG (40 t)
        # a car is no passenger load but a typing error.
        payload_t = self.crush_payload_kg / self.cars / 1000.0
        if payload_t > CAR_PAYLOAD_KG / 1000.0:
            raise FieldProblem(
                "crush_payload_kg",
                f"{payload_t:g} t per car for {self.cars} cars: "
                f"a crush-loaded car carries at most {CAR_PAYLOAD_KG / 1000.0:g} t",
            )
        # The train must be able to start: at standstill the tractive effort (max_force_n) must
        # exceed the running resistance's constant term (davis_a_n), else no train ever leaves.
        if self.traction is not None and self.traction.max_force_n <= self.davis_a_n:
            raise FieldProblem(
                "traction.max_force_n",
                f"not above the running resistance at standstill davis_a_n ({self.davis_a_n:g} N): "
                "the train could never start",
            )
        return self


class VehicleFile(_Model):
    # The vehicle: masses, resistance, brake, traction, positioning and protection.
    vehicle: Vehicle
