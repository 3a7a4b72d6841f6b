"""Disturbance sets: TOML data -> per-run :class:`~railstop.config.scenario.Scenario` (DESIGN rules 3, 6, 7).

A disturbance file maps parameter names to distributions::

    description = "what this set is for"          # optional
    entry_speed_kmh = {uniform = [45.0, 65.0]}
    brake_gain = {normal = [1.0, 0.07], clip = [0.8, 1.2]}
    wheel_diameter_mm = {choice = [780.0, 820.0, 860.0]}
    sensor_jitter_ms = {fixed = 1.0}
    radio_loss_probability = 0.02                 # *_probability: a plain number in [0, 1]

The parameters, their units, physical ranges and nominal values follow SPEC §1
(the disturbances a ground-based TASC stop must tolerate) and the issue's
parameter table; see :data:`PARAMETERS` and ``_SPECS`` below. A parameter the
file does not name takes its nominal value, the one
``Scenario.nominal(station, vehicle)`` uses, so a file with no parameter at
all (``nominal``) gives exactly the nominal scenario.

Distributions
-------------
``fixed``   every run gets x.
``uniform`` lo + (hi - lo) * u with u uniform in [0, 1).
``normal``  mean + sd * z, z standard normal; with ``clip = [lo, hi]`` the value is
            *clipped* to [lo, hi] (not resampled), so a little probability mass
            sits exactly on the bounds (e.g. 0.4 % for brake_gain 1.0 ± 0.07 clipped
            to 0.8..1.2). Every supported parameter has a physical range, so a
            normal without ``clip`` is rejected: it could produce any value.
``choice``  one of the listed values, each with the same probability.

Validation checks the structure, lo <= hi, sd >= 0, a non-empty choice and that
*every value the distribution can produce* lies within the parameter's physical
range (uniform bounds, clip bounds, the fixed value, each choice).

Randomness (DESIGN rule 7)
--------------------------
Every draw is a pure function of (seed, run index, parameter): parameter p
uses only ``Stream.DISTURBANCE`` with uniform counters in its own block
``[16 * b, 16 * b + 16)``, b = ``COUNTER_BLOCKS[p]``. A uniform or a choice uses
counter ``16 b``; a normal uses ``streams.normal(DISTURBANCE, 16 b + 1)`` (one
64-bit draw at that counter, split in two halves for Box–Muller). The block numbers are fixed
here, not derived from the order of :data:`PARAMETERS`, so adding a parameter
(with a new block) never changes the draws of the others, and run i gets the
same values whatever the chunk it is drawn in.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, create_model, model_validator

from railstop.config.gradient import GradientProfile
from railstop.config.loader import format_loc, read_toml, validate
from railstop.config.scenario import Scenario, station_gradient
from railstop.config.schema import FieldProblem, Station, Vehicle
from railstop.errors import ConfigError
from railstop.quantities import MPS_PER_KMH
from railstop.streams import RunStreams, Stream

FloatArray = NDArray[np.float64]

BUILTIN_PACKAGE = "railstop.data.disturbances"

# Length of the approach zone before the first TASC detector that the
# approach gradient covers: a 120 m train entering at the first detector
# has its tail this far out (plus a margin for the run-in before it).
APPROACH_BEFORE_FIRST_DETECTOR_M = 150.0
# The low-adhesion patch starts between the first detector and this far
# before the stopping point.
PATCH_LAST_START_BEFORE_STOP_M = 10.0


# --------------------------------------------------------------------------
# Parameter table (SPEC §1 disturbances, issue table). Ranges are physical
# limits (what the simulator can meaningfully run), not typical values.


@dataclass(frozen=True, slots=True)
class _Range:
    lo: float
    hi: float
    lo_open: bool = False
    hi_open: bool = False

    def contains(self, x: float) -> bool:
        above = x > self.lo if self.lo_open else x >= self.lo
        below = x < self.hi if self.hi_open else x <= self.hi
        return above and below and math.isfinite(x)

    def text(self, name: str) -> str:
        lo = f"{_num(self.lo)} {'<' if self.lo_open else '<='} "
        hi = f" {'<' if self.hi_open else '<='} {_num(self.hi)}"
        return f"{lo}{name}{hi}"


def _num(x: float) -> str:
    return f"{x:g}"


@dataclass(frozen=True, slots=True)
class _Spec:
    unit: str
    range: _Range
    block: int  # counter block, see the module docstring; never reuse or renumber
    meaning: str  # what the parameter is in the stop simulation (one sentence)


_PROB = _Range(0.0, 1.0)

_SPECS: dict[str, _Spec] = {
    "entry_speed_kmh": _Spec(
        "km/h",
        _Range(0.0, 120.0, lo_open=True),
        0,
        meaning="The train's speed at the run's start, 1.5 s (at least 20 m) before the first detector.",
    ),
    "load_factor": _Spec(
        "0 empty .. 1 crush",
        _Range(0.0, 1.0),
        1,
        meaning="The passenger load: the train's mass is tare + load_factor x the crush payload.",
    ),
    "load_weighing_error_pct": _Spec(
        "%",
        _Range(-50.0, 50.0),
        2,
        meaning="The load-weighing error: the brake ECU sets its force for a mass of actual x (1 + error).",
    ),
    "brake_gain": _Spec(
        "actual / nominal",
        _Range(0.0, 3.0, lo_open=True),
        3,
        meaning="The brakes' actual over nominal effectiveness: it scales every deceleration they deliver.",
    ),
    "brake_dead_time_s": _Spec(
        "s",
        _Range(0.0, 2.0),
        4,
        meaning="The brake's dead time from a new demand to the first response (nominal: the vehicle's).",
    ),
    "brake_time_constant_s": _Spec(
        "s",
        _Range(0.0, 3.0, lo_open=True),
        5,
        meaning="The first-order lag of the brake's build-up (nominal: the vehicle's time_constant_s).",
    ),
    "platform_gradient_permille": _Spec(
        "permille, + uphill",
        _Range(-60.0, 60.0),
        6,
        meaning="The gradient from the platform's start to its end (nominal: the station's mean there).",
    ),
    "approach_gradient_permille": _Spec(
        "permille, + uphill",
        _Range(-60.0, 60.0),
        7,
        meaning=(
            "The gradient from 150 m before the first detector to the platform's start "
            "(nominal: the station's mean there)."
        ),
    ),
    "wheel_diameter_mm": _Spec(
        "mm",
        _Range(500.0, 1200.0, lo_open=True, hi_open=True),
        8,
        meaning="The actual wheel diameter: the tachometer counts its revolutions (nominal: the vehicle's).",
    ),
    "odometer_diameter_error_pct": _Spec(
        "%",
        _Range(-20.0, 20.0),
        9,
        meaning=(
            "The error of the diameter the odometer assumes, actual x (1 + error): its distances and "
            "speeds are off by that factor."
        ),
    ),
    "low_adhesion_probability": _Spec(
        "per run",
        _PROB,
        10,
        meaning=(
            "The chance that a run meets a low-adhesion patch, which starts uniformly between the first "
            "detector and 10 m before the stopping point."
        ),
    ),
    "low_adhesion_mu": _Spec(
        "adhesion coefficient",
        _Range(0.0, 0.5, lo_open=True),
        11,
        meaning="The adhesion coefficient in the low-adhesion patch (the vehicle's adhesion_mu elsewhere).",
    ),
    "low_adhesion_length_m": _Spec(
        "m",
        _Range(0.0, 1000.0, lo_open=True),
        12,
        meaning="The length of the low-adhesion patch (uniform in 30-80 m when not given).",
    ),
    "radio_latency_ms": _Spec(
        "ms",
        _Range(0.0, 2000.0),
        14,
        meaning=(
            "The radio's latency, added to each braking telegram's delivery and to the track-circuit "
            "telegrams of the position correction."
        ),
    ),
    "radio_loss_probability": _Spec(
        "per telegram",
        _PROB,
        15,
        meaning="The chance that a braking telegram's transmission (a cyclic repeat too) is lost.",
    ),
    "sensor_jitter_ms": _Spec(
        "ms, standard deviation",
        _Range(0.0, 100.0),
        16,
        meaning="The standard deviation of a detector's passage time around the true crossing.",
    ),
    "sensor_miss_probability": _Spec(
        "per detector passage",
        _PROB,
        17,
        meaning="The chance that a TASC detector misses the train's passage, per detector.",
    ),
    "doppler_noise_pct": _Spec(
        "%, standard deviation",
        _Range(0.0, 50.0),
        18,
        meaning="The radar's relative speed noise: each sample is v x (1 + noise z), z standard normal.",
    ),
    # The link's per-frame randomness (the medium's structure, bit rate and
    # cycle, is station data: tasc.medium).
    "radio_jitter_ms": _Spec(
        "ms, standard deviation per frame",
        _Range(0.0, 1000.0),
        19,
        meaning="The standard deviation of a braking frame's latency around radio_latency_ms (clipped at 0).",
    ),
    "radio_bit_error_rate": _Spec(
        "per bit",
        _Range(0.0, 0.01),
        20,
        meaning="The chance of each bit of a braking frame flipping; the receiver refuses a corrupted frame.",
    ),
    # A radio outage (a fault, DESIGN rule 10): every braking frame sent from this long after
    # the first telegram the train received, for the duration, is lost (0: no outage). With
    # start 0 and a long duration: every telegram after the first is lost.
    "radio_outage_start_s": _Spec(
        "s after the first telegram received",
        _Range(0.0, 1000.0),
        21,
        meaning="When a radio outage starts: this long after the first braking telegram the train received.",
    ),
    "radio_outage_duration_s": _Spec(
        "s (0: no outage)",
        _Range(0.0, 1e6),
        22,
        meaning="How long the outage lasts: every braking frame sent in it is lost (0: no outage).",
    ),
    # The medium's bursts and reordering (link.channel's model, on the braking frames): a
    # Gilbert-Elliott chain advanced once per frame, good -> bad and bad -> good, a frame sent in
    # the bad state lost with the burst's loss probability; a frame held back by the medium's
    # reorder delay (station.tasc.medium) arrives after later ones, which the receiver then
    # drops as out of order.
    "radio_burst_enter_probability": _Spec(
        "per braking frame",
        _PROB,
        23,
        meaning="The chance that the radio falls into a burst (the bad state) at a frame (0: no bursts).",
    ),
    "radio_burst_exit_probability": _Spec(
        "per braking frame",
        _PROB,
        24,
        meaning="The chance that a burst ends at a frame (1 when not given: a burst lasts one frame).",
    ),
    "radio_burst_loss_probability": _Spec(
        "per braking frame in a burst",
        _PROB,
        25,
        meaning="The chance that a braking frame sent in a burst is lost.",
    ),
    "radio_reorder_probability": _Spec(
        "per braking frame",
        _PROB,
        26,
        meaning="The chance that a braking frame is held back by the medium's reorder delay.",
    ),
}

#: Every supported parameter name, in a fixed order (the Parquet column order).
PARAMETERS: tuple[str, ...] = tuple(_SPECS)


def parameter_specs() -> list[tuple[str, str, str, str]]:
    """Every parameter as (name, unit, physical range, meaning): the file's reference."""
    return [(name, spec.unit, spec.range.text("x"), spec.meaning) for name, spec in _SPECS.items()]


#: Extra columns of the drawn values: does the run meet a patch, and where it starts (inf = none).
LOW_ADHESION = "low_adhesion"
LOW_ADHESION_START = "low_adhesion_start_m"

COUNTER_STRIDE = 16
#: Counter block per random quantity; block b owns uniform counters [16 b, 16 b + 16).
COUNTER_BLOCKS: Mapping[str, int] = {
    **{name: spec.block for name, spec in _SPECS.items()},
    LOW_ADHESION_START: 13,  # where the patch starts (not a file parameter)
}


def counter_base(name: str) -> int:
    """First uniform counter of ``name``'s block on ``Stream.DISTURBANCE``."""
    return COUNTER_BLOCKS[name] * COUNTER_STRIDE


def _is_probability(name: str) -> bool:
    return name.endswith("_probability")


# --------------------------------------------------------------------------
# Schema (pydantic, extra="forbid" like config/schema.py)

KINDS = ("fixed", "uniform", "normal", "choice")

Finite = Annotated[float, Field(strict=True, allow_inf_nan=False)]


def _pair(what: str) -> Any:
    def check(v: Any) -> Any:
        if not isinstance(v, list | tuple) or len(v) != 2:
            raise ValueError(f"needs two numbers {what}")
        return v

    return BeforeValidator(check)


def _probability_number(v: Any) -> Any:
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ValueError("a probability is a plain number between 0 and 1, e.g. 0.02")
    # NaN and infinity are named as such (the range check would call them too small or too big).
    if math.isnan(v):
        raise ValueError("not a number")
    if math.isinf(v):
        raise ValueError("not finite")
    return v


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Distribution(_Model):
    """One parameter's distribution: exactly one of fixed, uniform, normal (+ clip), choice."""

    # {fixed = x}: every run gets x.
    fixed: Finite | None = None
    # {uniform = [lo, hi]}: lo + (hi - lo) u, u uniform in [0, 1).
    uniform: Annotated[tuple[Finite, Finite], _pair("[lo, hi]")] | None = None
    # {normal = [mean, sd]}: mean + sd z, z standard normal (sd >= 0); a disturbance parameter also
    # needs clip.
    normal: Annotated[tuple[Finite, Finite], _pair("[mean, sd]")] | None = None
    # With normal only: the drawn value is clipped to [lo, hi] (not resampled).
    clip: Annotated[tuple[Finite, Finite], _pair("[lo, hi]")] | None = None
    # {choice = [a, b, ...]}: one of the listed values, each with the same probability.
    choice: list[Finite] | None = None

    @model_validator(mode="before")
    @classmethod
    def _table(cls, data: Any) -> Any:
        if isinstance(data, Distribution):
            return data
        if not isinstance(data, dict):
            raise ValueError(
                "a distribution is a table: {fixed = x}, {uniform = [lo, hi]}, "
                "{normal = [mean, sd], clip = [lo, hi]} or {choice = [a, b, ...]}"
            )
        return data

    @model_validator(mode="after")
    def _consistent(self) -> Distribution:
        given = [k for k in KINDS if getattr(self, k) is not None]
        if not given:
            raise ValueError("a distribution needs exactly one of fixed, uniform, normal, choice")
        if len(given) > 1:
            raise FieldProblem(given[1], f"give only one of fixed, uniform, normal, choice (also {given[0]})")
        if self.uniform is not None and self.uniform[0] > self.uniform[1]:
            raise FieldProblem("uniform", "lo must not be greater than hi in [lo, hi]")
        if self.normal is not None and self.normal[1] < 0.0:
            raise FieldProblem("normal", "the standard deviation sd in [mean, sd] must be >= 0")
        if self.clip is not None:
            if self.normal is None:
                raise FieldProblem("clip", "clip only goes with normal")
            if self.clip[0] > self.clip[1]:
                raise FieldProblem("clip", "lo must not be greater than hi in clip = [lo, hi]")
        if self.choice is not None and not self.choice:
            raise FieldProblem("choice", "choice needs at least one value")
        return self

    @property
    def kind(self) -> str:
        return next(k for k in KINDS if getattr(self, k) is not None)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for key in (*KINDS, "clip"):
            value = getattr(self, key)
            if value is not None:
                out[key] = list(value) if isinstance(value, tuple | list) else value
        return out

    def produced_bounds(self) -> list[tuple[str, list[float]]]:
        """The values whose range decides the range of every draw, per field; empty = unbounded."""
        if self.fixed is not None:
            return [("fixed", [self.fixed])]
        if self.uniform is not None:
            return [("uniform", list(self.uniform))]
        if self.choice is not None:
            return [("choice", list(self.choice))]
        if self.clip is not None:
            return [("clip", list(self.clip))]
        return []


Probability = Annotated[
    float, BeforeValidator(_probability_number), Field(ge=0.0, le=1.0, allow_inf_nan=False)
]


def _file_model() -> type[BaseModel]:
    fields: dict[str, Any] = {"description": (str | None, None)}
    for name in PARAMETERS:
        fields[name] = (Probability | None, None) if _is_probability(name) else (Distribution | None, None)
    return create_model("DisturbanceFile", __base__=_Model, **fields)


DisturbanceFile = _file_model()


# --------------------------------------------------------------------------
# The set


@dataclass(frozen=True)
class DisturbanceSet:
    """A validated disturbance file. Probabilities are kept as ``Distribution(fixed=p)``."""

    name: str  # "standard", "nominal" or the file path as given
    source: str  # file shown in errors
    params: dict[str, Distribution]
    description: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-able, in the file's own shape: ``from_dict(to_dict())`` gives the same set."""
        out: dict[str, Any] = {}
        if self.description:
            out["description"] = self.description
        for name in PARAMETERS:
            if name in self.params:
                dist = self.params[name]
                out[name] = dist.fixed if _is_probability(name) else dist.to_dict()
        return out

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], *, name: str = "(dict)", source: str = "(dict)"
    ) -> DisturbanceSet:
        """Validate ``data`` (the TOML meaning, or ``to_dict()``) like a file."""
        return _parse(dict(data), name=name, source=source)


def _parse(data: dict[str, Any], *, name: str, source: str) -> DisturbanceSet:
    for key in data:
        if key != "description" and key not in _SPECS:
            close = difflib.get_close_matches(key, PARAMETERS, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise ConfigError(
                source, format_loc((key,)), f"unknown parameter; {hint}supported: {', '.join(PARAMETERS)}"
            )
    model = validate(DisturbanceFile, data, source)
    params: dict[str, Distribution] = {}
    for pname in PARAMETERS:
        value = getattr(model, pname)
        if value is None:
            continue
        if _is_probability(pname):
            params[pname] = Distribution(fixed=float(value))
            continue
        _check_range(pname, value, data, source)
        params[pname] = value
    return DisturbanceSet(
        name=name, source=source, params=params, description=getattr(model, "description", None) or ""
    )


def _check_range(name: str, dist: Distribution, data: dict[str, Any], source: str) -> None:
    rng = _SPECS[name].range
    bounds = dist.produced_bounds()
    if not bounds:  # a normal without clip
        raise ConfigError(
            source,
            format_loc((name, "normal")),
            f"a normal can produce any value but {rng.text(name)}: add clip = [lo, hi]",
            data[name]["normal"],
        )
    for key, values in bounds:
        bad = [v for v in values if not rng.contains(v)]
        if bad:
            raise ConfigError(
                source,
                format_loc((name, key)),
                f"{_num(bad[0])} is out of range: every value the distribution can produce "
                f"must satisfy {rng.text(name)}",
                data[name][key],
            )


def builtin_sets() -> list[str]:
    """Names of the embedded disturbance sets."""
    files = resources.files(BUILTIN_PACKAGE)
    return sorted(p.name.removesuffix(".toml") for p in files.iterdir() if p.name.endswith(".toml"))


def load_disturbances(spec: str | Path) -> DisturbanceSet:
    """``"standard"``, ``"nominal"`` (embedded sets) or the path of a TOML file."""
    if isinstance(spec, str) and spec in builtin_sets():
        ref = resources.files(BUILTIN_PACKAGE).joinpath(f"{spec}.toml")
        source = f"railstop/data/disturbances/{spec}.toml"
        try:
            data = tomllib.loads(ref.read_text(encoding="utf-8"))
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(source, "(toml syntax)", str(exc)) from None
        return _parse(data, name=spec, source=source)
    path = Path(spec)
    if not path.exists():
        raise ConfigError(
            str(spec), "(file)", f"no such file; the embedded sets are: {', '.join(builtin_sets())}"
        )
    return _parse(read_toml(path), name=str(spec), source=str(spec))


# --------------------------------------------------------------------------
# Drawing

# Absent low_adhesion_length_m: patch lengths uniform in this range (metres).
DEFAULT_LOW_ADHESION_LENGTH_M = Distribution(uniform=(30.0, 80.0))


def quantile(dist: Distribution, u: FloatArray) -> FloatArray:
    """The value of ``dist`` at quantile u (its inverse CDF; u uniform in [0, 1) gives the
    distribution itself). A normal is clipped like a drawn one (:func:`clipped`)."""
    if dist.uniform is not None:
        lo, hi = dist.uniform
        return lo + (hi - lo) * u
    if dist.choice is not None:
        values = np.asarray(dist.choice, dtype=np.float64)
        return values[np.minimum((u * values.size).astype(np.int64), values.size - 1)]
    if dist.normal is not None:
        from scipy.special import ndtri  # lazy (start-up): scipy loads slowly; only a normal needs it

        mean, sd = dist.normal
        with np.errstate(invalid="ignore"):
            return clipped(dist, mean + sd * ndtri(u))  # u = 0 gives -inf: clipped
    assert dist.fixed is not None  # exactly one kind is set (Distribution validates it)
    return np.full(u.shape, float(dist.fixed))


def clipped(dist: Distribution, x: FloatArray) -> FloatArray:
    """``x`` clipped to the distribution's clip bounds, if it has them (clipped, not resampled)."""
    return np.clip(x, dist.clip[0], dist.clip[1]) if dist.clip is not None else x


def probability(dist: DisturbanceSet, name: str) -> float:
    """The set's ``*_probability`` parameter ``name`` (0 when the set does not name it)."""
    given = dist.params.get(name)
    return float(given.fixed or 0.0) if given is not None else 0.0


def _draw(dist: Distribution, streams: RunStreams, name: str) -> FloatArray:
    base = counter_base(name)
    if dist.fixed is not None:
        return np.full(streams.n, float(dist.fixed))
    if dist.normal is None:
        return quantile(dist, streams.uniform(Stream.DISTURBANCE, base))
    mean, sd = dist.normal
    # normal(c) reads uniform counters 2c and 2c + 1: base and base + 1 (base is even).
    return clipped(dist, mean + sd * streams.normal(Stream.DISTURBANCE, base + 1))


def _zone_means_permille(station: Station) -> tuple[float, float]:
    """The station's own mean gradient (permille) over the approach and the platform zones."""
    zones = _zones(station)
    elev = station_gradient(station, 1).elevation_m(np.array([zones]))[0]

    def mean(i: int) -> float:
        length = zones[i + 1] - zones[i]
        return float((elev[i + 1] - elev[i]) / length * 1e3) if length > 0.0 else 0.0

    return mean(0), mean(1)


def _zones(station: Station) -> tuple[float, float, float]:
    """(approach start, platform start, platform end) chainages."""
    first = station.detector_positions_m()[0]
    return first - APPROACH_BEFORE_FIRST_DETECTOR_M, station.platform_start, station.platform_end


def nominal_values(station: Station, vehicle: Vehicle, n: int) -> dict[str, FloatArray]:
    """Every parameter's nominal value in the file's units (what ``Scenario.nominal`` uses)."""
    approach, platform = _zone_means_permille(station)
    nominal = {
        "entry_speed_kmh": station.tasc.entry_speed_kmh,
        "load_factor": 0.0,
        "load_weighing_error_pct": 0.0,
        "brake_gain": 1.0,
        "brake_dead_time_s": vehicle.brake.dead_time_s,
        "brake_time_constant_s": vehicle.brake.time_constant_s,
        "platform_gradient_permille": platform,
        "approach_gradient_permille": approach,
        "wheel_diameter_mm": vehicle.wheel_diameter_m * 1e3,
        "odometer_diameter_error_pct": 0.0,
        "low_adhesion_probability": 0.0,
        "low_adhesion_mu": vehicle.adhesion_mu,
        "radio_latency_ms": 0.0,
        "radio_loss_probability": 0.0,
        "sensor_jitter_ms": 0.0,
        "sensor_miss_probability": 0.0,
        "doppler_noise_pct": 0.0,
        "radio_jitter_ms": 0.0,
        "radio_bit_error_rate": 0.0,
        "radio_outage_start_s": 0.0,
        "radio_outage_duration_s": 0.0,
        "radio_burst_enter_probability": 0.0,
        "radio_burst_exit_probability": 1.0,
        "radio_burst_loss_probability": 0.0,
        "radio_reorder_probability": 0.0,
    }
    return {k: np.full(n, float(v)) for k, v in nominal.items()}


def _gradient(
    station: Station, n: int, approach_permille: FloatArray, platform_permille: FloatArray
) -> GradientProfile:
    """Approach zone [first detector - 150 m, platform start] and platform [start, end]; level elsewhere."""
    a0, p0, p1 = _zones(station)
    zero = np.zeros(n)
    if a0 < p0:
        bps = np.array([a0, p0, p1])
        values = np.column_stack([zero, approach_permille, platform_permille, zero])
    else:  # the TASC zone lies within the platform: no approach zone
        bps = np.array([p0, p1])
        values = np.column_stack([zero, platform_permille, zero])
    return GradientProfile.create(bps, values)


# Parameter -> (Scenario field, factor from the file unit to SI). Absent parameters keep
# the nominal field; gradients and low adhesion are built separately.
_TO_SCENARIO: dict[str, tuple[str, float]] = {
    "entry_speed_kmh": ("entry_speed_mps", MPS_PER_KMH),
    "load_factor": ("load_factor", 1.0),
    "load_weighing_error_pct": ("load_weighing_error", 1e-2),
    "brake_gain": ("brake_gain", 1.0),
    "brake_dead_time_s": ("dead_time_s", 1.0),
    "brake_time_constant_s": ("time_constant_s", 1.0),
    "wheel_diameter_mm": ("wheel_diameter_m", 1e-3),
    "odometer_diameter_error_pct": ("odometer_diameter_error", 1e-2),
    "radio_latency_ms": ("radio_latency_s", 1e-3),
    "radio_loss_probability": ("radio_loss_probability", 1.0),
    "sensor_jitter_ms": ("sensor_jitter_s", 1e-3),
    "sensor_miss_probability": ("sensor_miss_probability", 1.0),
    "doppler_noise_pct": ("doppler_noise_frac", 1e-2),
    "radio_jitter_ms": ("radio_jitter_s", 1e-3),
    "radio_bit_error_rate": ("radio_bit_error_rate", 1.0),
    "radio_outage_start_s": ("radio_outage_start_s", 1.0),
    "radio_outage_duration_s": ("radio_outage_duration_s", 1.0),
    "radio_burst_enter_probability": ("radio_burst_enter_probability", 1.0),
    "radio_burst_exit_probability": ("radio_burst_exit_probability", 1.0),
    "radio_burst_loss_probability": ("radio_burst_loss_probability", 1.0),
    "radio_reorder_probability": ("radio_reorder_probability", 1.0),
}


def draw_scenario(
    dist: DisturbanceSet, station: Station, vehicle: Vehicle, streams: RunStreams, patch: bool | None = None
) -> tuple[Scenario, dict[str, np.ndarray]]:
    """The scenario of ``streams.n`` runs and the drawn values per parameter (file units).

    The values dict has one array of shape (n,) per name of :data:`PARAMETERS`
    (nominal values for parameters the set does not name), plus ``low_adhesion``
    (bool: the run meets a patch) and ``low_adhesion_start_m`` (inf = no patch).
    ``low_adhesion_mu`` and ``low_adhesion_length_m`` hold the drawn values of
    every run, whether or not it meets a patch. ``patch``: True / False forces a patch on every
    run / on none (a certification stratum); None draws it with the set's probability.
    """
    n = streams.n
    p = dist.params
    values: dict[str, Any] = nominal_values(station, vehicle, n)
    for name in PARAMETERS:
        if name in p and name != "low_adhesion_probability":
            values[name] = _draw(p[name], streams, name)
    values["low_adhesion_length_m"] = _draw(
        p.get("low_adhesion_length_m", DEFAULT_LOW_ADHESION_LENGTH_M), streams, "low_adhesion_length_m"
    )
    # Low adhesion: with probability p a run meets a patch of drawn mu and length
    # starting uniformly between the first detector and 10 m before the stop.
    if "low_adhesion_probability" in p:
        prob = probability(dist, "low_adhesion_probability")
        values["low_adhesion_probability"] = np.full(n, prob)
        hit = streams.uniform(Stream.DISTURBANCE, counter_base("low_adhesion_probability")) < prob
    else:
        hit = np.zeros(n, dtype=bool)
    if patch is not None:
        # A stratum of the certification (railstop.sim.strata): every run with a patch, or none;
        # the patch's place, adhesion and length keep their draws.
        hit = np.full(n, patch)
    lo, hi = patch_start_range(station)
    start = lo + (hi - lo) * streams.uniform(Stream.DISTURBANCE, counter_base(LOW_ADHESION_START))
    values[LOW_ADHESION] = hit
    values[LOW_ADHESION_START] = np.where(hit, start, np.inf)
    return scenario_from_values(dist, station, vehicle, values), _ordered(values)


#: The runs of a line's draws per train: a train's stop at its ``visit``-th station (from 0) is run
#: ``train x RUNS_PER_TRAIN + visit`` (``track_stop_run``), in the line simulation and live alike.
RUNS_PER_TRAIN = 100


def track_stop_run(train: int, visit: int) -> int:
    """The run of a train's stop on a line (:data:`RUNS_PER_TRAIN`; visits past it wrap)."""
    return train * RUNS_PER_TRAIN + visit % RUNS_PER_TRAIN


def draw_track_stop(
    dist: DisturbanceSet,
    station: Station,
    vehicle: Vehicle,
    *,
    seed: int,
    run: int,
    entry_speed_mps: float,
    wheel: tuple[float, float] | None = None,
) -> Scenario:
    """Run ``run`` of ``seed`` drawn for a train that arrives on the line: its own speed at the
    hand-over (``entry_speed_mps``) and the station's own gradients (on a line the gradient is the
    track's, not a draw: a campaign draws it to try the station on other tracks). The line
    simulation and live operation draw their stops so.

    ``wheel``: the train's own wheel, (actual diameter in m, its odometer's diameter error as a
    fraction: assumed = actual x (1 + error)), where its driver has one for the whole trip (the
    line's tachometer): the stop's odometer is then that wheel's, not a draw of its own."""
    scenario, _ = draw_scenario(dist, station, vehicle, RunStreams.for_runs(seed, run, 1))
    changes: dict[str, Any] = {}
    if wheel is not None:
        changes["wheel_diameter_m"] = np.array([wheel[0]], dtype=np.float64)
        changes["odometer_diameter_error"] = np.array([wheel[1]], dtype=np.float64)
    return scenario.with_values(
        entry_speed_mps=np.array([entry_speed_mps]), gradient=station_gradient(station, 1), **changes
    )


def patch_start_range(station: Station) -> tuple[float, float]:
    """Where a low-adhesion patch may start: [first detector, stopping point - 10 m] (ordered)."""
    first = station.detector_positions_m()[0]
    last = station.stop_point_m - PATCH_LAST_START_BEFORE_STOP_M
    return min(first, last), max(first, last)


def _ordered(values: dict[str, Any]) -> dict[str, np.ndarray]:
    ordered = {name: values[name] for name in PARAMETERS}
    ordered[LOW_ADHESION] = values[LOW_ADHESION]
    ordered[LOW_ADHESION_START] = values[LOW_ADHESION_START]
    return ordered


def scenario_from_values(
    dist: DisturbanceSet, station: Station, vehicle: Vehicle, values: Mapping[str, np.ndarray]
) -> Scenario:
    """The scenario of drawn ``values`` (the dict :func:`draw_scenario` returns; however drawn).

    Parameters the set does not name keep the nominal scenario's field, whatever
    ``values`` holds for them.
    """
    p = dist.params
    n = int(np.asarray(values[LOW_ADHESION]).size)
    scen = Scenario.nominal(station, vehicle, n=n)
    changes: dict[str, Any] = {}
    for name, (target, factor) in _TO_SCENARIO.items():
        if name in p:
            changes[target] = np.asarray(values[name], dtype=np.float64) * factor

    # Gradients: a per-run profile when the set names either; the absent one keeps
    # the station's own mean gradient over its zone (nominal_values).
    if "approach_gradient_permille" in p or "platform_gradient_permille" in p:
        changes["gradient"] = _gradient(
            station, n, values["approach_gradient_permille"], values["platform_gradient_permille"]
        )
    if "low_adhesion_probability" in p:
        hit = np.asarray(values[LOW_ADHESION], dtype=bool)
        start = np.asarray(values[LOW_ADHESION_START], dtype=np.float64)
        changes["low_mu"] = np.where(hit, values["low_adhesion_mu"], vehicle.adhesion_mu)
        changes["low_mu_start_m"] = np.where(hit, start, np.inf)
        changes["low_mu_end_m"] = np.where(hit, start + values["low_adhesion_length_m"], np.inf)
    return scen.with_values(**changes) if changes else scen


__all__ = [
    "COUNTER_BLOCKS",
    "COUNTER_STRIDE",
    "LOW_ADHESION",
    "LOW_ADHESION_START",
    "PARAMETERS",
    "Distribution",
    "DisturbanceSet",
    "builtin_sets",
    "counter_base",
    "draw_scenario",
    "load_disturbances",
    "nominal_values",
    "patch_start_range",
    "probability",
    "quantile",
    "scenario_from_values",
]
