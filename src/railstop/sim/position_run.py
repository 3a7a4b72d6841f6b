"""Driver: one train (or n runs) over the whole line with SPEC §2 position correction.

Wires the pure units together, step by step (``dt_s``, 50 ms):

    run profile ─> traction / brake ─> motion_step (true motion)
        │                                  │
        │            tachometer (wheel diameter, slip, slide) ─> odometer log ─┐
        │                                                                      │
    track-circuit devices (boundary, delay) ─> wayside time-stamping unit      │
        (its GNSS clock; free-running in an unrepeated tunnel)                 │
            ─> telegram (circuit ID, GNSS time) ─> link (latency; codec)       │
                ─> onboard positioning unit (its GNSS clock) <─────────────────┘
                     ─> corrected position (SPEC §2 S40), calibrated position (learner)

and records, against the true chainage, the error of the raw odometer, of
the document's correction and of the correction with the learned calibration.

Disturbances of a run: the odometer's assumed wheel diameter is off by
``diameter_error_pct`` (assumed = actual × (1 + error)); low-adhesion patches
(adhesion ``low_mu``) lie in some *braking zones* (60-300 m before a stopping
point: the service brake demand exceeds adhesion, the train slides under
wheel-slide protection) and some *traction zones* (5-125 m after a departure:
the wheels slip under anti-slip control). ``slides`` / ``slips`` choose that
many zones per run at random (a zone holds one patch: more than the line's
zones is refused); ``slide_probability`` / ``slip_probability``
instead give each zone a patch with that chance (how a disturbance set's
``low_adhesion_probability`` is used). Where the patches go is drawn from
``Stream.ADHESION``: zone z (braking zones 0..S-1 of the S stops, then
traction zones S..2S-1) uses counters 4z (which zones), 4z + 1 (start) and
4z + 2 (length).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railstop.config.disturbances import DisturbanceSet, draw_scenario
from railstop.config.schema import Line, Vehicle
from railstop.control.run_profile import RunProfile, RunProfileSettings
from railstop.errors import SimulationError
from railstop.onboard.positioning import FixOutcome, PositioningUnit
from railstop.physics.traction import traction_step
from railstop.physics.train import (
    G_MPS2,
    GradientProfile,
    MotionState,
    TrainMass,
    davis_resistance_n,
    motion_step,
)
from railstop.sensors.odometer import Tachometer, accelerometer_bias_mps2, creep_factor
from railstop.sim.occupancy_chain import ChainSettings, OccupancyChain
from railstop.streams import RUN_LIMIT as STREAM_LIMIT
from railstop.streams import SEED_RANGE, RunStreams, Stream, seed_in_range

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

KMH = 1.0 / 3.6
DT_S = 0.05
MAX_TIME_S = 3600.0
PATCH_COUNTERS = 4
BRAKING_ZONE_M = (60.0, 300.0)  # patch starts this far before a stopping point
TRACTION_ZONE_M = (5.0, 125.0)  # patch starts this far after a departure
CHAINAGE_STEP_M = 1.0  # grid of the error-against-chainage statistics


class SettingError(SimulationError):
    """A position-run setting out of its range: ``setting`` (field name), ``detail`` (why), ``value``.

    ``str(error)`` is ``setting: detail (got value)``; the CLI puts the option and the value as
    typed instead (``railstop.cli_position``).
    """

    def __init__(self, setting: str, detail: str, value: object) -> None:
        self.setting = setting
        self.detail = detail
        self.value = value
        super().__init__(f"{setting}: {detail} (got {value!r})")


@dataclass(frozen=True, slots=True)
class Limit:
    """The finite interval a numeric setting must lie in (None = unbounded on that side), with its unit."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    unit: str = ""

    def problem(self, x: float, *, scale: float = 1.0, unit: str | None = None) -> str | None:
        """Why ``x`` (in the setting's unit) is refused, None if it is not. NaN is "not a number",
        ±inf "not finite"; the bounds of the rule are quoted divided by ``scale`` in ``unit`` (the
        unit of an option that gives the setting as ``value × scale``)."""
        if isinstance(x, float) and math.isnan(x):
            return "not a number"
        if isinstance(x, float) and math.isinf(x):
            return "not finite"
        above = self.lo is None or (x > self.lo if self.lo_open else x >= self.lo)
        below = self.hi is None or (x < self.hi if self.hi_open else x <= self.hi)
        if above and below:
            return None
        return f"must be {self.rule(scale=scale, unit=self.unit if unit is None else unit)}"

    def rule(self, *, scale: float = 1.0, unit: str = "") -> str:
        """``between 0 h and 8888.89 h``, ``greater than 0 and at most 0.5``, ``at least 0``..."""
        u = f" {unit}" if unit else ""
        lo = None if self.lo is None else f"{self.lo / scale:g}{u}"
        hi = None if self.hi is None else f"{self.hi / scale:g}{u}"
        low = None if lo is None else (f"greater than {lo}" if self.lo_open else f"at least {lo}")
        high = None if hi is None else (f"less than {hi}" if self.hi_open else f"at most {hi}")
        if low is not None and high is not None:
            return f"between {lo} and {hi}" if not (self.lo_open or self.hi_open) else f"{low} and {high}"
        return low or high or "finite"


#: The range of every numeric setting (``patch_length_m``, a pair, is checked on its own).
SETTING_LIMITS: dict[str, Limit] = {
    "diameter_error_pct": Limit(-20.0, 20.0, unit="%"),
    "wheel_diameter_m": Limit(0.5, 1.2, lo_open=True, hi_open=True, unit="m"),
    "slides": Limit(0),
    "slips": Limit(0),
    "slide_probability": Limit(0.0, 1.0),
    "slip_probability": Limit(0.0, 1.0),
    "low_mu": Limit(0.0, 0.5, lo_open=True),
    "holdover_s": Limit(0.0, 3.2e7, unit="s"),  # as the line data's track.clocks.holdover_s
    "load_factor": Limit(0.0, 1.0),
    "telegram_latency_s": Limit(0.0, 2.0, unit="s"),
    "dwell_s": Limit(0.0, 600.0, unit="s"),
    "dt_s": Limit(0.0, 0.2, lo_open=True, unit="s"),
}


def check_streams(seed: int, run: int, n: int = 1) -> None:
    """``seed`` and runs ``run .. run + n - 1`` are in the random streams' signed 64-bit range."""
    if not seed_in_range(seed):
        raise SettingError("seed", SEED_RANGE, seed)
    if not 0 <= run < STREAM_LIMIT:
        raise SettingError("run", "must be between 0 and 2^63 - 1", run)
    if run + n > STREAM_LIMIT:
        raise SettingError("run", f"runs {run} .. {run + n - 1} go beyond 2^63 - 1", run)


@dataclass(frozen=True, slots=True, kw_only=True)
class PositionRunSettings:
    """What a position run varies. Defaults: the issue's run (2 % diameter error, slides and slips)."""

    seed: int = 1
    run: int = 0  # first run index of the random streams
    diameter_error_pct: float = 2.0  # odometer's assumed diameter = actual × (1 + error)
    wheel_diameter_m: float | None = None  # actual; None = the vehicle's
    slides: int = 3  # braking zones with a low-adhesion patch, per run
    slips: int = 2  # traction zones with a low-adhesion patch, per run
    slide_probability: float | None = None  # instead of ``slides``: chance per braking zone
    slip_probability: float | None = None  # instead of ``slips``: chance per traction zone
    low_mu: float = 0.05  # adhesion in a patch (wet leaves)
    patch_length_m: tuple[float, float] = (30.0, 80.0)  # uniform range of patch lengths
    gnss: bool = True  # SPEC §2 GNSS time at all (False: every clock free-runs)
    repeaters: bool = True  # SPEC §2 satellite-signal repeaters where the line data has them
    learn: bool = True  # the onboard learner (beyond SPEC §2)
    accelerometer: bool = True  # the slide compensation's accelerometer (beyond SPEC §2)
    holdover_s: float | None = None  # age of a clock with no time source; None = the line's data
    load_factor: float = 0.0
    telegram_latency_s: float = 0.05  # SPEC typical values: radio latency tens of ms
    dwell_s: float = 25.0
    dt_s: float = DT_S

    def __post_init__(self) -> None:
        check_streams(self.seed, self.run)
        for name, limit in SETTING_LIMITS.items():
            value = getattr(self, name)
            problem = None if value is None else limit.problem(value)
            if problem is not None:
                raise SettingError(name, problem, value)
        lo, hi = self.patch_length_m
        if math.isnan(lo) or math.isnan(hi):
            raise SettingError("patch_length_m", "not a number", self.patch_length_m)
        if math.isinf(lo) or math.isinf(hi):
            raise SettingError("patch_length_m", "not finite", self.patch_length_m)
        if not 0.0 < lo <= hi <= 1000.0:
            raise SettingError("patch_length_m", "must satisfy 0 m < lo <= hi <= 1000 m", self.patch_length_m)


@dataclass(frozen=True, slots=True, kw_only=True)
class FixRecord:
    """One telegram the train received (SPEC §2 S30/S40) and what it did."""

    run: int
    t_s: float  # true time it was handled
    circuit_id: int
    circuit_start_m: float
    gnss_time_s: float
    outcome: str
    corrected_jump_m: float
    calibrated_jump_m: float
    learned: bool
    gated: bool
    scale_estimate: float
    delay_estimate_s: float
    clock_offset_s: float  # wayside clock error at the occupancy - onboard clock error at the fix


@dataclass(frozen=True, slots=True, kw_only=True)
class PositionRunResult:
    """Traces (T samples × n runs) and what happened; ``summary(run)`` is the JSON of one run."""

    settings: PositionRunSettings
    line_name: str
    start_m: FloatArray  # (n,)
    t_s: FloatArray  # (T,)
    true_m: FloatArray  # (T, n) train front chainage
    speed_mps: FloatArray  # (T, n)
    raw_m: FloatArray  # (T, n) start + odometer
    corrected_m: FloatArray  # (T, n) SPEC §2 document method
    calibrated_m: FloatArray  # (T, n) + learned scale and delay
    fixes: list[FixRecord]
    patch_start_m: FloatArray  # (n, Z) inf = no patch in zone z
    patch_end_m: FloatArray
    patch_is_braking: BoolArray  # (Z,)
    slide_distance_m: FloatArray  # (n,) true distance travelled while sliding
    slip_distance_m: FloatArray
    true_scale: FloatArray  # (n,) D_assumed / D_actual
    learned_scale: FloatArray  # (n,)
    learned_delay_s: FloatArray  # (n,)
    detection_delay_mean_s: float
    telegram_via_codec: bool
    circuits_m: FloatArray = field(default_factory=lambda: np.zeros(0))  # (C + 1,) boundaries
    tunnels: list[tuple[float, float, bool]] = field(default_factory=list)  # (start, end, repeater)
    stops_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    station_names: list[str] = field(default_factory=list)

    @property
    def n(self) -> int:
        return int(self.true_m.shape[1])

    def errors_vs_chainage(self, run: int = 0) -> dict[str, FloatArray]:
        """Errors (estimate - true) on a 1 m grid of true chainage, from the start to the end of the run."""
        x = self.true_m[:, run]
        xs, first = np.unique(x, return_index=True)  # the position only grows; standstills collapse
        grid = np.arange(xs[0], xs[-1] + 1e-9, CHAINAGE_STEP_M)
        out = {"chainage_m": grid}
        for key, est in (
            ("raw", self.raw_m),
            ("corrected", self.corrected_m),
            ("calibrated", self.calibrated_m),
        ):
            err = est[first, run] - xs
            out[key] = np.interp(grid, xs, err)
        return out

    def summary(self, run: int = 0) -> dict[str, Any]:
        if not 0 <= run < self.n:
            raise SimulationError(f"run: no run {run} in a result of {self.n} runs")
        x = self.true_m[:, run]
        err = {k: getattr(self, f"{k}_m")[:, run] - x for k in ("raw", "corrected", "calibrated")}
        grid = self.errors_vs_chainage(run)
        mine = [f for f in self.fixes if f.run == run]
        accepted = [f for f in mine if f.outcome == FixOutcome.ACCEPTED.name.lower()]
        braking = self.patch_is_braking
        has_patch = np.isfinite(self.patch_start_m[run])

        def r(v: float, nd: int = 3) -> float:
            return round(float(v), nd)

        return {
            "line": self.line_name,
            "seed": self.settings.seed,
            "run": self.settings.run + run,
            "distance_m": r(x[-1] - x[0], 1),
            "duration_s": r(self.t_s[-1], 1),
            "diameter_error_pct": self.settings.diameter_error_pct,
            "true_scale_error_pct": r((self.true_scale[run] - 1.0) * 100.0, 4),
            "gnss": self.settings.gnss,
            "repeaters": self.settings.repeaters,
            "learn": self.settings.learn,
            "slide_patches": int(np.sum(has_patch & braking)),
            "slip_patches": int(np.sum(has_patch & ~braking)),
            "slide_distance_m": r(self.slide_distance_m[run], 1),
            "slip_distance_m": r(self.slip_distance_m[run], 1),
            "raw_final_m": r(err["raw"][-1]),
            "raw_max_abs_m": r(np.max(np.abs(err["raw"]))),
            "corrected_p99_abs_m": r(np.percentile(np.abs(grid["corrected"]), 99)),
            "corrected_max_abs_m": r(np.max(np.abs(err["corrected"]))),
            "calibrated_p99_abs_m": r(np.percentile(np.abs(grid["calibrated"]), 99)),
            "calibrated_max_abs_m": r(np.max(np.abs(err["calibrated"]))),
            "corrections": len(accepted),
            "rejected": len(mine) - len(accepted),
            "learned_intervals": sum(f.learned for f in mine),
            "gated_intervals": sum(f.gated for f in mine),
            "learned_scale_error_pct": r((self.learned_scale[run] - 1.0) * 100.0, 4),
            "learned_delay_s": r(self.learned_delay_s[run], 4),
            "clock_offset_max_abs_ms": r(
                max((abs(f.clock_offset_s) for f in accepted), default=0.0) * 1e3, 4
            ),
            "detection_delay_mean_s": self.detection_delay_mean_s,
            "telegram_via_codec": self.telegram_via_codec,
        }

    def settings_dict(self) -> dict[str, Any]:
        return asdict(self.settings)


# --------------------------------------------------------------------------
# Set-up helpers


def line_gradient(line: Line, n: int) -> GradientProfile:
    """The whole line's gradient from every station's segments (gaps are level)."""
    segs = sorted((g for s in line.stations for g in s.gradient), key=lambda g: g.start_m)
    bps: list[float] = []
    vals: list[float] = [0.0]
    for seg in segs:
        if bps and seg.start_m < bps[-1] - 1e-9:
            raise SimulationError(f"gradient segments of different stations overlap at {seg.start_m} m")
        if bps and abs(bps[-1] - seg.start_m) < 1e-9:
            vals[-1] = seg.permille
        else:
            bps.append(seg.start_m)
            vals.append(seg.permille)
        bps.append(seg.end_m)
        vals.append(0.0)
    return GradientProfile.create(np.asarray(bps), np.tile(np.asarray(vals), (n, 1)))


def _check_patch_counts(settings: PositionRunSettings, stop_count: int) -> None:
    """``slides`` / ``slips`` (when no per-zone chance replaces them) fit the line's zones.

    A zone holds at most one patch: there is one braking zone per stopping point and one
    traction zone per departure (the start, then every stop but the last), so at most
    ``stop_count`` of each. More is refused rather than capped.
    """
    for name, count, prob, patch, zone, what in (
        ("slides", settings.slides, settings.slide_probability, "slide", "braking", "stopping points"),
        ("slips", settings.slips, settings.slip_probability, "slip", "traction", "departures"),
    ):
        if prob is None and count > stop_count:
            raise SettingError(
                name,
                f"at most {stop_count} on this line: one {patch} patch per {zone} zone, "
                f"and the line has {stop_count} {what}",
                count,
            )


def _patches(
    settings: PositionRunSettings, streams: RunStreams, stops_m: FloatArray, start_m: FloatArray
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Low-adhesion patches per run and zone: (start, end) with inf = none, and which zones brake."""
    n, s_count = streams.n, stops_m.size
    z_count = 2 * s_count
    prio = np.empty((n, z_count))
    u_start = np.empty((n, z_count))
    u_len = np.empty((n, z_count))
    for z in range(z_count):
        prio[:, z] = streams.uniform(Stream.ADHESION, PATCH_COUNTERS * z)
        u_start[:, z] = streams.uniform(Stream.ADHESION, PATCH_COUNTERS * z + 1)
        u_len[:, z] = streams.uniform(Stream.ADHESION, PATCH_COUNTERS * z + 2)
    braking = np.arange(z_count) < s_count
    has = np.zeros((n, z_count), dtype=bool)
    for zone_mask, count, prob in (
        (braking, settings.slides, settings.slide_probability),
        (~braking, settings.slips, settings.slip_probability),
    ):
        cols = np.flatnonzero(zone_mask)
        if prob is not None:
            has[:, cols] = prio[:, cols] < prob
        else:
            rank = np.argsort(np.argsort(prio[:, cols], axis=1), axis=1)
            has[:, cols] = rank < count  # count <= cols.size: _check_patch_counts
    lo, hi = settings.patch_length_m
    length = lo + (hi - lo) * u_len
    before = BRAKING_ZONE_M[0] + (BRAKING_ZONE_M[1] - BRAKING_ZONE_M[0]) * u_start
    after = TRACTION_ZONE_M[0] + (TRACTION_ZONE_M[1] - TRACTION_ZONE_M[0]) * u_start
    # Traction zone j follows departure j: the start position, then stops 0 .. S-2.
    departures = (
        np.column_stack([start_m, np.tile(stops_m[:-1], (n, 1))]) if s_count > 1 else start_m[:, None]
    )
    starts = np.where(braking, np.tile(stops_m, 2)[None, :] - before, 0.0)
    starts[:, ~braking] = departures + after[:, ~braking]
    starts = np.where(has, starts, np.inf)
    ends = np.where(has, starts + length, np.inf)
    return starts, ends, braking


def disturbance_overrides(
    dist: DisturbanceSet, line: Line, vehicle: Vehicle, *, seed: int, run: int
) -> dict[str, Any]:
    """Position-run settings from a disturbance set, for run ``run`` (names it does not give are absent).

    Reused parameters: ``wheel_diameter_mm`` (actual), ``odometer_diameter_error_pct``,
    ``low_adhesion_probability`` (chance of a patch per braking and per traction
    zone), ``low_adhesion_mu`` and ``low_adhesion_length_m``. The draw is that of
    campaign run ``run`` at the line's first station.
    """
    streams = RunStreams.for_runs(seed, run, 1)
    _, values = draw_scenario(dist, line.stations[0], vehicle, streams)
    p = dist.params
    out: dict[str, Any] = {}
    if "wheel_diameter_mm" in p:
        out["wheel_diameter_m"] = float(values["wheel_diameter_mm"][0]) * 1e-3
    if "odometer_diameter_error_pct" in p:
        out["diameter_error_pct"] = float(values["odometer_diameter_error_pct"][0])
    if "low_adhesion_probability" in p:
        prob = float(p["low_adhesion_probability"].fixed or 0.0)
        out["slide_probability"] = prob
        out["slip_probability"] = prob
    if "low_adhesion_mu" in p:
        out["low_mu"] = float(values["low_adhesion_mu"][0])
    if "low_adhesion_length_m" in p:
        length = float(values["low_adhesion_length_m"][0])
        out["patch_length_m"] = (length, length)
    return out


# --------------------------------------------------------------------------
# The run


def run_position(
    line: Line, vehicle: Vehicle, settings: PositionRunSettings | None = None, *, n: int = 1
) -> PositionRunResult:
    """Drive ``n`` runs of one train over the whole line; see the module docstring."""
    cfg = settings or PositionRunSettings()
    if n < 1:
        raise SimulationError(f"n: at least one run is needed (got {n})")
    circuits = line.track_circuits
    if not circuits:
        raise SimulationError("track.circuits: the line has no track circuits; position-run needs them")
    if vehicle.traction is None:
        raise SimulationError(
            "vehicle.traction: the vehicle has no tractive-effort curve; position-run needs it"
        )
    check_streams(cfg.seed, cfg.run, n)
    traction = vehicle.traction
    track = line.track
    dt = cfg.dt_s
    streams = RunStreams.for_runs(cfg.seed, cfg.run, n)

    stops = np.array([s.stop_point_m for s in line.stations], dtype=np.float64)
    _check_patch_counts(cfg, stops.size)
    start = np.full(n, vehicle.length_m + 10.0)  # the whole train on the line, at rest
    if stops[0] <= start[0] + 50.0:
        raise SimulationError(
            f"stations: the first stop ({stops[0]} m) is too close to the start ({start[0]} m)"
        )
    mass = TrainMass.create(vehicle, np.full(n, cfg.load_factor), np.zeros(n))
    gradient = line_gradient(line, n)
    profile = RunProfile(
        RunProfileSettings(
            speed_limit_mps=line.line.speed_limit_kmh * KMH,
            full_service_mps2=vehicle.brake.full_service_mps2,
            dwell_s=cfg.dwell_s,
        ),
        stops,
        n,
        start,
    )
    motion = MotionState(
        position_m=start.copy(),
        speed_mps=np.zeros(n),
        accel_mps2=np.zeros(n),
        stopped=np.ones(n, dtype=bool),
        stop_time_s=np.full(n, np.nan),
        sliding=np.zeros(n, dtype=bool),
    )
    actual_d = np.full(n, vehicle.wheel_diameter_m if cfg.wheel_diameter_m is None else cfg.wheel_diameter_m)
    tacho = Tachometer.create(
        actual_diameter_m=actual_d,
        assumed_diameter_m=actual_d * (1.0 + cfg.diameter_error_pct * 1e-2),
        pulses_per_rev=vehicle.positioning.tachometer_pulses_per_rev,
    )
    p_start, p_end, p_braking = _patches(cfg, streams, stops, start)
    accel_bias = accelerometer_bias_mps2(streams, vehicle.positioning.accelerometer_bias_sd_mps2)

    # SPEC §2 S10-S30: the devices, the time-stamping unit, the clocks and the radio; each run
    # its own world (its own wayside clocks).
    chain = OccupancyChain(
        line,
        train_streams=streams,
        wayside_streams=streams,
        start_position_m=start,
        settings=ChainSettings(
            gnss=cfg.gnss,
            repeaters=cfg.repeaters,
            holdover_s=cfg.holdover_s,
            latency_s=cfg.telegram_latency_s,
        ),
    )
    pos_settings = vehicle.positioning.model_copy(update={"learn": vehicle.positioning.learn and cfg.learn})
    unit = PositioningUnit(
        circuits=circuits,
        settings=pos_settings,
        n=n,
        cycle_s=dt,
        start_position_m=start,
        # The DB knows each circuit's kind, hence how sharp its boundary is, and the delay spread.
        boundary_sd_m=[track.detection.boundary_sd_m(c.kind) for c in circuits],
        delay_spread_s=track.detection.delay_spread_s,
        nominal_delay_s=track.detection.delay_mean_s,
    )

    fixes: list[FixRecord] = []
    slide_dist = np.zeros(n)
    slip_dist = np.zeros(n)
    rec: dict[str, list[FloatArray]] = {k: [] for k in ("t", "x", "v", "raw", "cor", "cal")}

    def record(t: float) -> None:
        rec["t"].append(np.array(t))
        rec["x"].append(motion.position_m.copy())
        rec["v"].append(motion.speed_mps.copy())
        rec["raw"].append(start + tacho.odometer_m())
        rec["cor"].append(unit.corrected_m())
        rec["cal"].append(unit.calibrated_m())

    unit.log(clock_time_s=chain.onboard_time_s(0.0), odometer_m=tacho.odometer_m(), speed_mps=np.zeros(n))
    record(0.0)
    steps = round(MAX_TIME_S / dt)
    for k in range(steps):
        t = k * dt
        t1 = t + dt
        x = motion.position_m
        in_patch = np.any((x[:, None] >= p_start) & (x[:, None] < p_end), axis=1)
        mu = np.where(in_patch, cfg.low_mu, vehicle.adhesion_mu)
        grade = gradient.mean_gradient(x, vehicle.length_m)
        resist = davis_resistance_n(vehicle, motion.speed_mps) / mass.effective_kg
        resist = resist + G_MPS2 * grade * mass.static_kg / mass.effective_kg
        cmd = profile.command(
            t_s=t, position_m=x, speed_mps=motion.speed_mps, stopped=motion.stopped, resist_mps2=resist
        )
        if profile.done.all():
            break
        motion.stopped = motion.stopped & ~cmd.depart
        trac = traction_step(
            traction,
            demand_accel_mps2=cmd.traction_mps2,
            speed_mps=motion.speed_mps,
            mass=mass,
            adhesion_mu=mu,
        )
        braking = cmd.brake_mps2 > 0.0
        x0, v0 = motion.position_m.copy(), motion.speed_mps.copy()
        was_moving = ~motion.stopped
        # Traction enters the one equation of motion as a negative braking deceleration.
        motion_step(
            motion,
            vehicle=vehicle,
            mass=mass,
            brake_decel_mps2=np.where(braking, cmd.brake_mps2, -trac.accel_mps2),
            mean_gradient=grade,
            adhesion_mu=mu,
            speed_hold=np.zeros(n, dtype=bool),
            t_s=t,
            dt_s=dt,
        )
        dist = motion.position_m - x0
        sliding = motion.sliding & was_moving & braking
        slipping = trac.slipping & was_moving & ~braking
        creep = creep_factor(
            sliding,
            slipping,
            slide_slip_ratio=vehicle.slide_slip_ratio,
            traction_slip_ratio=traction.slip_ratio,
        )
        tacho.advance(dist, creep)
        slide_dist += np.where(sliding, dist, 0.0)
        slip_dist += np.where(slipping, dist, 0.0)

        # SPEC §2 S10-S20: clocks, detection, time-stamping.
        chain.advance(
            t0_s=t, dt_s=dt, x0_m=x0, v0_mps=v0, accel_mps2=motion.accel_mps2, x1_m=motion.position_m
        )

        # Onboard: the cycle's log sample, then the telegrams that have arrived.
        unit.log(
            clock_time_s=chain.onboard_time_s(t1),
            odometer_m=tacho.odometer_m(),
            speed_mps=tacho.speed_mps(motion.speed_mps, creep),
            wsp_active=sliding | slipping,
            # The accelerometer's bridge belongs to the calibration: without the learner the
            # calibrated position is the document's (no bridge either).
            accel_mps2=motion.accel_mps2 + accel_bias if cfg.accelerometer and cfg.learn else None,
        )
        got = chain.arrivals(t1)
        if got.size:
            rep = unit.handle(run=got.run, circuit_id=got.circuit_id, gnss_time_s=got.gnss_time_s)
            for j in range(rep.run.size):
                rr = int(rep.run[j])
                fixes.append(
                    FixRecord(
                        run=rr,
                        t_s=t1,
                        circuit_id=int(rep.circuit_id[j]),
                        circuit_start_m=float(rep.circuit_start_m[j]),
                        gnss_time_s=float(got.gnss_time_s[j]),
                        outcome=FixOutcome(int(rep.outcome[j])).name.lower(),
                        corrected_jump_m=float(rep.corrected_jump_m[j]),
                        calibrated_jump_m=float(rep.calibrated_jump_m[j]),
                        learned=bool(rep.learned[j]),
                        gated=bool(rep.gated[j]),
                        scale_estimate=float(unit.scale_estimate[rr]),
                        delay_estimate_s=float(unit.delay_estimate_s[rr]),
                        clock_offset_s=float(got.clock_offset_s[j]),
                    )
                )
        record(t1)
    else:
        raise SimulationError(f"the runs did not reach the last station within {MAX_TIME_S:.0f} s")

    return PositionRunResult(
        settings=cfg,
        line_name=line.line.name,
        start_m=start,
        t_s=np.asarray(rec["t"]),
        true_m=np.asarray(rec["x"]),
        speed_mps=np.asarray(rec["v"]),
        raw_m=np.asarray(rec["raw"]),
        corrected_m=np.asarray(rec["cor"]),
        calibrated_m=np.asarray(rec["cal"]),
        fixes=fixes,
        patch_start_m=p_start,
        patch_end_m=p_end,
        patch_is_braking=p_braking,
        slide_distance_m=slide_dist,
        slip_distance_m=slip_dist,
        true_scale=tacho.scale.copy(),
        learned_scale=unit.scale_estimate.copy(),
        learned_delay_s=unit.delay_estimate_s.copy(),
        detection_delay_mean_s=track.detection.delay_mean_s,
        telegram_via_codec=chain.used_codec,
        circuits_m=np.array([c.start_m for c in circuits] + [circuits[-1].end_m]),
        tunnels=[(t.start_m, t.end_m, t.repeater and cfg.repeaters) for t in track.tunnels],
        stops_m=stops,
        station_names=[s.name for s in line.stations],
    )
