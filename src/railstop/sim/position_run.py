"""``railstop position-run``: one train over the whole line with SPEC §2 position correction, a
one-train preset of the line (``sim.line``).

The run is a line run of one train (the line's clock, its ATO driving by the onboard position,
a ground-TASC stop and a dwell at every station, out at the line's end) whose positioning is
recorded every step: the true front, the raw odometer (entry + the tachometer's count), the
document's correction (SPEC §2 S40) and the correction with the learned calibration, and every
telegram it received (``nodes.occupancy_chain``: the devices, the time-stamping unit's GNSS
clocks, the radio, the codec). The train starts cold: it has learned nothing of its wheel yet.

Disturbances of a run: the odometer's assumed wheel diameter is off by
``diameter_error_pct`` (assumed = actual × (1 + error)); low-adhesion patches (adhesion
``low_mu``) lie where the ATO brakes for a station, before the hand-over to the station's
TASC (the wheels slide under wheel-slide protection), and after a departure from one (the
wheels slip under anti-slip control). ``slides`` / ``slips`` choose that many stations per run
(a zone holds one patch: more than the line's stations is refused); ``slide_probability`` /
``slip_probability`` instead give each zone a patch with that chance (how a disturbance set's
``low_adhesion_probability`` is used). Where the patches go is drawn by the line
(``LineSimulation._place_patches``). Run r of seed S is the line run of seed S + r (as run r of
``railstop line campaign``); a disturbance set's draws for the station stops are the line's.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railstop.config.disturbances import DisturbanceSet, draw_scenario
from railstop.config.operation import Operation, load_operation
from railstop.config.schema import Line, Vehicle
from railstop.errors import SimulationError
from railstop.nodes.occupancy_chain import ChainSettings, FixRecord, occupancy_medium
from railstop.onboard.positioning import FixOutcome
from railstop.sim.line import LineSettings, LineSimulation, PositionSettings
from railstop.streams import RUN_LIMIT as STREAM_LIMIT
from railstop.streams import SEED_RANGE, RunStreams, seed_in_range

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

MAX_TIME_S = 3600.0  # a run that has not left the line by then is an error
CHAINAGE_STEP_M = 1.0  # grid of the error-against-chainage statistics
#: A week: the holdover of a clock set long ago (the stale case of SPEC §2's free-running clocks).
WEEK_S = 7 * 86400.0

#: ``same_path``: the chain settings a run compares on its own path (SPEC §2: what GNSS time and
#: the repeaters in the tunnels buy), each with the line data's holdover or a week's.
SAME_PATH_CHAINS: dict[str, dict[str, Any]] = {
    "GNSS time, repeaters": {},
    "no repeaters": {"repeaters": False},
    "no GNSS": {"gnss": False},
    "no repeaters, week holdover": {"repeaters": False, "holdover_s": WEEK_S},
    "no GNSS, week holdover": {"gnss": False, "holdover_s": WEEK_S},
}


class SettingError(SimulationError):
    """A position-run setting out of its range: ``setting`` (field name), ``detail`` (why), ``value``.

    ``str(error)`` is ``setting: detail (got value)``; the CLI puts the option and the value as
    typed instead (``railstop.cli.position``).
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
    "telegram_latency_s": Limit(0.0, 2.0, unit="s"),
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
    telegram_latency_s: float = 0.05  # the telegrams' radio's mean latency (SPEC: tens of ms)
    # Also run every chain of SAME_PATH_CHAINS on this run's own path (they never drive the train).
    same_path: bool = False

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
class PositionRunResult:
    """Traces (T samples × n runs) and what happened; ``summary(run)`` is the JSON of one run."""

    settings: PositionRunSettings
    line_name: str
    start_m: FloatArray  # (n,)
    t_s: FloatArray  # (T,) the line's clock, from the train's entry
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
    # SAME_PATH_CHAINS on the run's path: (K, T, n) corrected and calibrated, K = the settings.
    same_path_names: list[str] = field(default_factory=list)
    same_path_corrected_m: FloatArray = field(default_factory=lambda: np.zeros((0, 0, 0)))
    same_path_calibrated_m: FloatArray = field(default_factory=lambda: np.zeros((0, 0, 0)))

    @property
    def n(self) -> int:
        return int(self.true_m.shape[1])

    def errors_vs_chainage(self, run: int = 0) -> dict[str, FloatArray]:
        """Errors (estimate - true) on a 1 m grid of true chainage, from the start to the end of the run."""
        return self.on_grid(
            run, {"raw": self.raw_m, "corrected": self.corrected_m, "calibrated": self.calibrated_m}
        )

    def on_grid(self, run: int, estimates: dict[str, FloatArray]) -> dict[str, FloatArray]:
        """``estimates`` (each (T, n)) less the truth, on a 1 m grid of the run's true chainage."""
        x = self.true_m[:, run]
        xs, first = np.unique(x, return_index=True)  # the position only grows; standstills collapse
        grid = np.arange(xs[0], xs[-1] + 1e-9, CHAINAGE_STEP_M)
        out = {"chainage_m": grid}
        for key, est in estimates.items():
            out[key] = np.interp(grid, xs, est[first, run] - xs)
        return out

    def _accuracy(self, run: int, corrected: FloatArray, calibrated: FloatArray) -> dict[str, float | None]:
        """p99 (over the chainage grid) and max (over every sample) of the corrected and calibrated
        errors; the calibrated p99 once the train has left its first station."""
        x = self.true_m[:, run]
        grid = self.on_grid(run, {"corrected": corrected, "calibrated": calibrated})
        warm = grid["chainage_m"] > (self.stops_m[0] if self.stops_m.size else np.inf)

        def r(v: float) -> float:
            return round(float(v), 3)

        return {
            "corrected_p99_abs_m": r(np.percentile(np.abs(grid["corrected"]), 99)),
            "corrected_max_abs_m": r(np.max(np.abs(corrected[:, run] - x))),
            "calibrated_p99_abs_m": r(np.percentile(np.abs(grid["calibrated"]), 99)),
            "calibrated_max_abs_m": r(np.max(np.abs(calibrated[:, run] - x))),
            # Once the train has left its first station: what a train that has learned keeps.
            "calibrated_p99_abs_after_first_stop_m": r(np.percentile(np.abs(grid["calibrated"][warm]), 99))
            if warm.any()
            else None,
        }

    def summary(self, run: int = 0) -> dict[str, Any]:
        if not 0 <= run < self.n:
            raise SimulationError(f"run: no run {run} in a result of {self.n} runs")
        x = self.true_m[:, run]
        raw_err = self.raw_m[:, run] - x
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
            "duration_s": r(self.t_s[-1] - self.t_s[0], 1),
            "diameter_error_pct": self.settings.diameter_error_pct,
            "true_scale_error_pct": r((self.true_scale[run] - 1.0) * 100.0, 4),
            "gnss": self.settings.gnss,
            "repeaters": self.settings.repeaters,
            "learn": self.settings.learn,
            "slide_patches": int(np.sum(has_patch & braking)),
            "slip_patches": int(np.sum(has_patch & ~braking)),
            "slide_distance_m": r(self.slide_distance_m[run], 1),
            "slip_distance_m": r(self.slip_distance_m[run], 1),
            "raw_final_m": r(raw_err[-1]),
            "raw_max_abs_m": r(np.max(np.abs(raw_err))),
            **self._accuracy(run, self.corrected_m, self.calibrated_m),
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
            # SPEC §2 settings compared on this run's own path (only with ``same_path``).
            **(
                {
                    "same_path": [
                        {"setting": name, **self._accuracy(run, cor, cal)}
                        for name, cor, cal in zip(
                            self.same_path_names,
                            self.same_path_corrected_m,
                            self.same_path_calibrated_m,
                            strict=True,
                        )
                    ]
                }
                if self.same_path_names
                else {}
            ),
        }

    def settings_dict(self) -> dict[str, Any]:
        return asdict(self.settings)


# --------------------------------------------------------------------------
# Set-up helpers


def _check_patch_counts(settings: PositionRunSettings, stop_count: int) -> None:
    """``slides`` / ``slips`` (when no per-zone chance replaces them) fit the line's zones.

    A zone holds at most one patch: there is one braking zone before every station (where the
    ATO brakes for it) and one traction zone after every station (where it starts from it), so
    at most ``stop_count`` of each. More is refused rather than capped.
    """
    for name, count, prob, patch, zone, what in (
        ("slides", settings.slides, settings.slide_probability, "slide", "braking", "stations to stop at"),
        ("slips", settings.slips, settings.slip_probability, "slip", "traction", "stations to start from"),
    ):
        if prob is None and count > stop_count:
            raise SettingError(
                name,
                f"at most {stop_count} on this line: one {patch} patch per {zone} zone, "
                f"and the line has {stop_count} {what}",
                count,
            )


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
    line: Line,
    vehicle: Vehicle,
    settings: PositionRunSettings | None = None,
    *,
    n: int = 1,
    operation: Operation | None = None,
    disturbances: DisturbanceSet | None = None,
) -> PositionRunResult:
    """``n`` runs of one train over the whole line (line runs of seeds seed + run .. + n - 1).

    ``operation``: the trains' operation (default: the embedded one; its first train, its
    dwells); ``disturbances``: the set the station stops draw from (default: nominal).
    """
    cfg = settings or PositionRunSettings()
    if n < 1:
        raise SimulationError(f"n: at least one run is needed (got {n})")
    if not line.track_circuits:
        raise SimulationError("track.circuits: the line has no track circuits; position-run needs them")
    if vehicle.traction is None:
        raise SimulationError(
            "vehicle.traction: the vehicle has no tractive-effort curve; position-run needs it"
        )
    check_streams(cfg.seed, cfg.run, n)
    if not seed_in_range(cfg.seed + cfg.run + n - 1):
        raise SettingError("run", f"seed + run goes beyond the seeds' range ({SEED_RANGE})", cfg.run)
    _check_patch_counts(cfg, len(line.stations))
    op = (operation or load_operation(None, line)).model_copy(update={"trains": 1, "entries_s": None})
    runs = []
    for r in range(n):
        sim = LineSimulation(
            line=line,
            vehicle=vehicle,
            operation=op,
            disturbances=disturbances,
            seed=cfg.seed + cfg.run + r,
            settings=line_settings(cfg),
        )
        sim.run(MAX_TIME_S, until_gone=True)
        train = sim.trains[0]
        if train.phase != "gone":
            raise SimulationError(
                f"run {cfg.run + r}: the train did not leave the line within {MAX_TIME_S:.0f} s"
            )
        runs.append(sim)
    return _result(line, cfg, runs)


def line_settings(cfg: PositionRunSettings) -> LineSettings:
    """The line's settings of a position run: one train starting cold, its positioning recorded."""
    # The telegrams' radio: the chain's default medium at this run's latency.
    medium = occupancy_medium().replace(latency_s=cfg.telegram_latency_s)
    same_path = (
        tuple(ChainSettings(medium=medium, **change) for change in SAME_PATH_CHAINS.values())
        if cfg.same_path
        else ()
    )
    return LineSettings(
        odometer_error_pct=cfg.diameter_error_pct,
        slide_probability=cfg.slide_probability or 0.0,
        calibration="cold",
        position=PositionSettings(
            wheel_diameter_m=cfg.wheel_diameter_m,
            slides=cfg.slides if cfg.slide_probability is None else None,
            slips=cfg.slips if cfg.slip_probability is None else None,
            slip_probability=cfg.slip_probability or 0.0,
            low_mu=cfg.low_mu,
            patch_length_m=cfg.patch_length_m,
            chain=ChainSettings(
                gnss=cfg.gnss,
                repeaters=cfg.repeaters,
                holdover_s=cfg.holdover_s,
                medium=medium,
            ),
            learn=cfg.learn,
            accelerometer=cfg.accelerometer,
            record=True,
            same_path=same_path,
        ),
    )


def _result(line: Line, cfg: PositionRunSettings, runs: list[LineSimulation]) -> PositionRunResult:
    """The runs' traces side by side: (T, n), a run that left the line earlier standing at its
    last sample (its error unchanged) until the longest has ended."""
    n = len(runs)
    traces = [np.asarray(sim.trains[0].trace, dtype=np.float64) for sim in runs]
    longest = max(traces, key=len)
    t_count = len(longest)

    def col(k: int, of: list[FloatArray] = traces) -> FloatArray:
        out = np.empty((t_count, n))
        for r, tr in enumerate(of):
            out[: len(tr), r] = tr[:, k]
            out[len(tr) :, r] = tr[-1, k]
        return out

    names = list(SAME_PATH_CHAINS) if cfg.same_path else []
    others = [np.asarray(sim.trains[0].same_path_trace, dtype=np.float64) for sim in runs] if names else []

    speed = col(2)
    for r, tr in enumerate(traces):
        speed[len(tr) :, r] = 0.0
    s_count = len(line.stations)
    p_start = np.full((n, 2 * s_count), np.inf)
    p_end = np.full((n, 2 * s_count), np.inf)
    fixes = []
    for r, sim in enumerate(runs):
        for a, b, z in sim.trains[0].patches:
            p_start[r, z], p_end[r, z] = a, b
        fixes += [replace(f, run=r) for f in sim.fixes]
    circuits = line.track_circuits
    return PositionRunResult(
        settings=cfg,
        line_name=line.line.name,
        start_m=np.array([sim.operation.entry_m for sim in runs]),
        t_s=longest[:, 0],  # the line's clock, as the fixes' times
        true_m=col(1),
        speed_mps=speed,
        raw_m=col(3),
        corrected_m=col(4),
        calibrated_m=col(5),
        fixes=fixes,
        patch_start_m=p_start,
        patch_end_m=p_end,
        patch_is_braking=np.arange(2 * s_count) < s_count,
        slide_distance_m=np.array([sim.trains[0].slide_m for sim in runs]),
        slip_distance_m=np.array([sim.trains[0].slip_m for sim in runs]),
        true_scale=np.array([float(sim.tacho.scale[0]) for sim in runs]),
        learned_scale=np.array([float(sim.positioning.scale_estimate[0]) for sim in runs]),
        learned_delay_s=np.array([float(sim.positioning.delay_estimate_s[0]) for sim in runs]),
        detection_delay_mean_s=line.track.detection.delay_mean_s,
        telegram_via_codec=all(sim.chain.used_codec for sim in runs),
        circuits_m=np.array([c.start_m for c in circuits] + [circuits[-1].end_m]),
        tunnels=[(t.start_m, t.end_m, t.repeater and cfg.repeaters) for t in line.track.tunnels],
        stops_m=np.array([st.stop_point_m for st in line.stations], dtype=np.float64),
        station_names=[st.name for st in line.stations],
        same_path_names=names,
        same_path_corrected_m=np.array([col(2 * k, others) for k in range(len(names))]),
        same_path_calibrated_m=np.array([col(2 * k + 1, others) for k in range(len(names))]),
    )
