"""Rare-event certification: P(stop error > threshold) by importance sampling, with a valid bound.

A PSD design must keep the overrun probability of its stops near 1e-6. Plain
Monte Carlo sees one such stop in a million; :func:`certify` instead draws the
runs from a *proposal* that makes the dangerous combinations common, weights
every run by its exact likelihood ratio, and bounds the probability with a
confidence bound that is valid with few hits (:mod:`railstop.stats.bounds`).

The random inputs of a run
--------------------------
A run of the compiled model is decided by two kinds of random input:

* the **scenario** (the disturbance set's draws: entry speed, load, brake,
  gradients, wheel, the low-adhesion patch and its place, radio latency, ...).
  Here each varying quantity is one coordinate u_j of the unit cube, mapped to
  its value by the distribution's inverse CDF: ``uniform`` lo + (hi − lo)·u,
  ``normal`` clip(mean + sd·Φ⁻¹(u)), ``choice`` the ⌊k·u⌋-th value, the patch
  u < p. Under the disturbance set every u_j is uniform, so its density is 1;
  the clipping point masses of a clipped normal are the u beyond Φ((clip −
  mean)/sd) and need no special case.
* the **per-event Bernoulli draws inside the run**: a wheel detector missing
  its passage (``sensor_miss_probability`` per passage) and a telegram lost
  (``radio_loss_probability`` per transmission attempt). The kernel counts
  the trials and the successes of both (``RES_MISS_TRIALS`` ...); run with
  a tilted probability q instead of p, the ratio of one run's draws is
  (q/p)^m·((1 − q)/(1 − p))^(T − m), exact even though the number of trials T
  depends on earlier outcomes (it is the likelihood of the realised sequence).

Every other draw inside the run (sensor timing jitter, Doppler noise, latency
jitter, bit errors, ...) keeps its distribution: its likelihood ratio is
exactly 1.

The proposal
------------
g = α·f + (1 − α)·h: with probability α (``defensive``) the run is drawn from
the disturbance set itself (f), otherwise from h, a product of one
piecewise-constant density per coordinate (equal-width bins; the patch
coordinate has its two bins [0, p) and [p, 1)) and the two tilted Bernoulli
probabilities. The likelihood ratio of a run x is::

    w(x) = f(x)/g(x) = 1/(α + (1 − α)·r(x)),  r(x) = h(x)/f(x)

whichever component drew it, so every weight is ≤ 1/α: that is the a-priori
range B the bound needs (Hesterberg 1995; Owen & Zhou 2000).

Tuning and estimation
---------------------
h is tuned by the multilevel cross-entropy method (Rubinstein & Kroese 2004)
on *tuning runs* whose random numbers are disjoint from the estimation runs'
(run indices from 2^40 on): each level draws ``tuning_runs`` runs from the
current g, takes the runs whose score reaches γ = min(threshold, the (1 − ρ)
quantile of the scores) and refits each coordinate's bin probabilities and
each Bernoulli probability to them, weighted by their likelihood ratios,
smoothed with the previous h and floored so that no bin dies. The *estimation
runs* (indices 0 .. N − 1) are then drawn from the final g and never used for
tuning, so the estimate is unbiased and the bound valid whatever the tuning
did: p̂ = mean(w·hit), and the upper bound on E[w·hit] over [0, 1/α] is the
betting bound of Waudby-Smith & Ramdas (no normal approximation).

A run that does not come to a stand within the simulated time counts as a hit
**[interpretation]**: its stopping position is unknown, and a certificate
must not assume it is good (fail safe).

Randomness: the coordinates come from ``Stream.CERTIFY`` (counter 0 the
mixture component, counter 1 + j coordinate j) of the run's index under the
seed; the in-run draws are the kernel's own streams of that index. The result
is a pure function of (seed, runs, settings): the same on threads, processes
or a Dask cluster, whatever the block size.
"""

from __future__ import annotations

import contextlib
import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railstop.config.disturbances import (
    DEFAULT_LOW_ADHESION_LENGTH_M,
    LOW_ADHESION,
    LOW_ADHESION_START,
    Distribution,
    DisturbanceSet,
    nominal_values,
    patch_start_range,
    probability,
    quantile,
    scenario_from_values,
)
from railstop.config.schema import Line, Vehicle
from railstop.errors import RailstopError
from railstop.model.build import KernelModel
from railstop.model.records import (
    RES_ERROR,
    RES_LOSS_TRIALS,
    RES_LOSSES,
    RES_MISS_TRIALS,
    RES_MISSES,
    RES_STOPPED,
)
from railstop.model.run import run_kernel
from railstop.sim.engine import DT_S, MAX_TIME_S
from railstop.sim.executor import blocks, execute
from railstop.stats.bounds import betting_upper, chi2_quantile, clopper_pearson, clopper_pearson_upper
from railstop.streams import RUN_LIMIT, SEED_RANGE, RunStreams, Stream, seed_in_range
from railstop.wayside.tasc_unit import SignalForm

FloatArray = NDArray[np.float64]

__all__ = [
    "CertifyError",
    "CertifyResult",
    "CertifySpec",
    "Proposal",
    "certify",
    "initial_proposal",
    "sample_block",
]

#: Tuning runs use run indices from here on; estimation runs use 0 .. N - 1.
TUNING_FIRST_RUN = 1 << 40
#: Equal-width bins of a continuous coordinate's proposal density.
BINS = 5
#: Each bin keeps at least this share of its disturbance-set probability (no bin dies in tuning).
BIN_FLOOR = 0.05
#: A tilted Bernoulli probability stays in [p, this].
MAX_TILT = 0.5
#: Significance level of the test that decides whether a coordinate is tilted at all.
TILT_TEST_LEVEL = 0.01
#: Runs beyond the threshold that suffice to fit the proposal to them directly.
MIN_ELITE = 10
#: The tuning's start: share of runs with a patch, and factor on the in-run Bernoulli probabilities.
BOOST_PATCH = 0.25
BOOST_TILT = 10.0
#: Block size of the executor (runs).
BLOCK_RUNS = 5_000


class CertifyError(RailstopError, ValueError):
    """A certification setting is invalid: ``setting`` names it, the message also gives the value."""

    def __init__(self, setting: str, message: str) -> None:
        super().__init__(f"{setting}: {message}")
        self.setting = setting
        self.detail = message


# --------------------------------------------------------------------------- the coordinates


@dataclass(frozen=True, slots=True)
class Coordinate:
    """One varying scenario quantity: its name and the bin edges of its proposal density in [0, 1]."""

    name: str  # a disturbance parameter, LOW_ADHESION (the patch, u < p) or LOW_ADHESION_START
    edges: tuple[float, ...]


@dataclass(frozen=True, slots=True)
class Tilt:
    """A Bernoulli draw inside the run that the proposal may make more frequent."""

    name: str  # "sensor_miss_probability" or "radio_loss_probability"
    p: float  # the disturbance set's probability


def _varies(dist: Distribution) -> bool:
    if dist.uniform is not None:
        return dist.uniform[1] > dist.uniform[0]
    if dist.normal is not None:
        return dist.normal[1] > 0.0
    if dist.choice is not None:
        return len(set(dist.choice)) > 1
    return False


def _patch_params(dist: DisturbanceSet) -> dict[str, Distribution]:
    """The patch's distributions: its adhesion (if the set names it; else the dry rail's, as in a
    campaign) and its length (the set's or the default)."""
    out = {"low_adhesion_length_m": dist.params.get("low_adhesion_length_m", DEFAULT_LOW_ADHESION_LENGTH_M)}
    if "low_adhesion_mu" in dist.params:
        out["low_adhesion_mu"] = dist.params["low_adhesion_mu"]
    return out


def coordinates(dist: DisturbanceSet) -> tuple[tuple[Coordinate, ...], tuple[Tilt, ...]]:
    """The cube's coordinates and the tiltable in-run Bernoulli draws of a disturbance set."""
    even = tuple(np.linspace(0.0, 1.0, BINS + 1).tolist())
    coords: list[Coordinate] = []
    patch_p = probability(dist, "low_adhesion_probability")
    patch_names = ("low_adhesion_mu", "low_adhesion_length_m")
    for name, d in dist.params.items():
        if name.endswith("_probability") or name in patch_names:
            continue
        if _varies(d):
            coords.append(Coordinate(name, even))
    if patch_p > 0.0:
        if patch_p < 1.0:
            coords.append(Coordinate(LOW_ADHESION, (0.0, patch_p, 1.0)))
        coords.append(Coordinate(LOW_ADHESION_START, even))
        for name, d in _patch_params(dist).items():
            if _varies(d):
                coords.append(Coordinate(name, even))
    tilts: list[Tilt] = []
    for name in ("sensor_miss_probability", "radio_loss_probability"):
        p = probability(dist, name)
        if 0.0 < p < 1.0:
            tilts.append(Tilt(name, p))
    return tuple(coords), tuple(tilts)


# --------------------------------------------------------------------------- the proposal


@dataclass(frozen=True, slots=True)
class Proposal:
    """g = α·f + (1 − α)·h; h: bin probabilities per coordinate and a probability per tilt."""

    coords: tuple[Coordinate, ...]
    probs: tuple[tuple[float, ...], ...]  # per coordinate, one per bin (sum 1)
    tilts: tuple[Tilt, ...]
    q: tuple[float, ...]  # per tilt
    defensive: float  # α

    @property
    def weight_bound(self) -> float:
        return 1.0 / self.defensive

    def to_dict(self) -> dict[str, Any]:
        return {
            "defensive": self.defensive,
            "coordinates": {
                c.name: {"edges": list(c.edges), "probabilities": [round(x, 6) for x in p]}
                for c, p in zip(self.coords, self.probs, strict=True)
            },
            "tilts": {t.name: {"p": t.p, "q": q} for t, q in zip(self.tilts, self.q, strict=True)},
        }


def initial_proposal(dist: DisturbanceSet, defensive: float, *, boost: bool = False) -> Proposal:
    """h = f (every bin its own width, every tilt its set's probability), or with ``boost`` the rare
    discrete causes made common to start the tuning from: a low-adhesion patch in at least
    ``BOOST_PATCH`` of the runs, each in-run Bernoulli draw ``BOOST_TILT`` times as likely (at most
    ``MAX_TILT``). [interpretation] Cross-entropy started from f fits the bulk of the stop errors
    (load, brake lag) and climbs towards a rare threshold very slowly when the overruns come from
    rare discrete causes; any start is valid, the estimation runs are weighted exactly."""
    coords, tilts = coordinates(dist)
    probs = [np.diff(c.edges) for c in coords]
    q = [t.p for t in tilts]
    if boost:
        for j, c in enumerate(coords):
            if c.name == LOW_ADHESION and c.edges[1] < BOOST_PATCH:
                probs[j] = np.array([BOOST_PATCH, 1.0 - BOOST_PATCH])
        q = [min(MAX_TILT, max(t.p, BOOST_TILT * t.p)) for t in tilts]
    return Proposal(coords, tuple(tuple(p.tolist()) for p in probs), tilts, tuple(q), defensive)


def _bins(edges: FloatArray, u: FloatArray) -> NDArray[np.int64]:
    return np.clip(np.searchsorted(edges, u, side="right") - 1, 0, edges.size - 2)


def _from_h(edges: FloatArray, probs: FloatArray, v: FloatArray) -> FloatArray:
    """Inverse CDF of the piecewise-constant density: v uniform in [0, 1) -> u drawn from h."""
    cdf = np.concatenate([[0.0], np.cumsum(probs)])
    cdf[-1] = 1.0
    b = _bins(cdf, v)
    u = edges[b] + (v - cdf[b]) / probs[b] * (edges[b + 1] - edges[b])
    return np.clip(u, edges[b], np.nextafter(edges[b + 1], -np.inf))


def _log_h(edges: FloatArray, probs: FloatArray, u: FloatArray) -> FloatArray:
    b = _bins(edges, u)
    return np.log(probs[b] / (edges[b + 1] - edges[b]))


# --------------------------------------------------------------------------- one block of runs


@dataclass(frozen=True)
class CertifySpec:
    """What a certification is: the model, the event and the proposal's settings."""

    line: Line
    vehicle: Vehicle
    station: str
    controller: str
    disturbances: DisturbanceSet
    threshold_m: float
    seed: int = 1
    form: int | None = None

    def to_dict(self) -> dict[str, Any]:
        """What a certificate reports of its question (its own keys follow)."""
        return {
            "station": self.station,
            "controller": self.controller,
            "disturbances": self.disturbances.name,
            "seed": self.seed,
            "threshold_m": self.threshold_m,
        }


@dataclass(frozen=True)
class BlockResult:
    """Runs ``first .. first + n - 1`` drawn from a proposal."""

    first: int
    score: FloatArray  # stop error (m, + = overrun); +inf for a run that never stood still
    log_ratio: FloatArray  # ln r(x) = ln h(x)/f(x)
    weight: FloatArray  # f/g = 1/(α + (1 − α) r)
    from_h: NDArray[np.bool_]
    u: FloatArray | None = None  # (n, coordinates), kept for tuning
    trials: FloatArray | None = None  # (n, tilts)
    successes: FloatArray | None = None  # (n, tilts)
    counts: dict[str, int] = field(default_factory=dict)


def sample_block(
    spec: CertifySpec, proposal: Proposal, block: tuple[int, int], keep: bool = False
) -> BlockResult:
    """Draw runs ``block = (first, end)`` from ``proposal`` and simulate them (a pure function)."""

    first, end = block
    n = end - first
    station = spec.line.station(spec.station)
    streams = RunStreams.for_runs(spec.seed, first, n)
    from_h = streams.uniform(Stream.CERTIFY, 0) >= proposal.defensive
    d = len(proposal.coords)
    u = np.empty((n, d))
    log_r = np.zeros(n)
    for j, (c, p) in enumerate(zip(proposal.coords, proposal.probs, strict=True)):
        edges, probs = np.asarray(c.edges), np.asarray(p)
        v = streams.uniform(Stream.CERTIFY, 1 + j)
        u[:, j] = np.where(from_h, _from_h(edges, probs, v), v)
        log_r += _log_h(edges, probs, u[:, j])

    # Values: nominal, then the set's constants (a fixed or degenerate distribution), then the cube.
    values = nominal_values(station, spec.vehicle, n)
    params = spec.disturbances.params
    patch = _patch_params(spec.disturbances)
    middle = np.full(n, 0.5)
    for name, dist in {**params, **patch}.items():
        if not name.endswith("_probability"):
            values[name] = quantile(dist, middle)
    patch_p = probability(spec.disturbances, "low_adhesion_probability")
    hit = np.full(n, patch_p >= 1.0)
    start = np.full(n, math.nan)
    lo, hi = patch_start_range(station)
    for j, c in enumerate(proposal.coords):
        if c.name == LOW_ADHESION:
            hit = u[:, j] < patch_p
        elif c.name == LOW_ADHESION_START:
            start = lo + (hi - lo) * u[:, j]
        else:
            dist = patch[c.name] if c.name in patch else params[c.name]
            values[c.name] = quantile(dist, u[:, j])
    values[LOW_ADHESION] = hit
    values[LOW_ADHESION_START] = np.where(hit, start, np.inf)
    if "low_adhesion_probability" in params:
        values["low_adhesion_probability"] = np.full(n, patch_p)
    for t, q in zip(proposal.tilts, proposal.q, strict=True):
        values[t.name] = np.where(from_h, q, t.p)  # the kernel draws with the component's probability

    scenario = scenario_from_values(spec.disturbances, station, spec.vehicle, values)
    model = KernelModel.create(
        station=station,
        vehicle=spec.vehicle,
        controller=spec.controller,
        form=None if spec.form is None else SignalForm(spec.form),
        dt_s=DT_S,
        max_time_s=MAX_TIME_S,
        track=spec.line.track,
    )
    res, _, _ = run_kernel(model, scenario, seed=spec.seed, first_run=first)
    columns = {
        "sensor_miss_probability": (RES_MISS_TRIALS, RES_MISSES),
        "radio_loss_probability": (RES_LOSS_TRIALS, RES_LOSSES),
    }
    trials = np.zeros((n, len(proposal.tilts)))
    successes = np.zeros((n, len(proposal.tilts)))
    for i, (t, q) in enumerate(zip(proposal.tilts, proposal.q, strict=True)):
        tc, sc = columns[t.name]
        trials[:, i], successes[:, i] = res[:, tc], res[:, sc]
        log_r += successes[:, i] * math.log(q / t.p) + (trials[:, i] - successes[:, i]) * math.log(
            (1.0 - q) / (1.0 - t.p)
        )
    stopped = res[:, RES_STOPPED] > 0.0
    score = hazard_score(stopped, res[:, RES_ERROR])
    alpha = proposal.defensive
    with np.errstate(over="ignore"):
        weight = 1.0 / (alpha + (1.0 - alpha) * np.exp(log_r))
    return BlockResult(
        first=first,
        score=score,
        log_ratio=log_r,
        weight=weight,
        from_h=from_h,
        u=u if keep else None,
        trials=trials if keep else None,
        successes=successes if keep else None,
        counts={"not_stopped": int(np.sum(~stopped))},
    )


def _blocks(first: int, n: int, workers: int) -> list[tuple[int, int]]:
    return list(blocks(first, first + n, workers, BLOCK_RUNS))


def _sample(
    spec: CertifySpec,
    proposal: Proposal,
    first: int,
    n: int,
    *,
    keep: bool,
    workers: int,
    scheduler: str | None,
    progress: Callable[[int], None] | None,
) -> list[BlockResult]:
    """Runs first .. first + n - 1 from ``proposal``, in run order, wherever the executor puts them."""
    fn = functools.partial(sample_block, spec, proposal, keep=keep)
    out: dict[int, BlockResult] = {}
    with contextlib.closing(
        execute(fn, _blocks(first, n, workers), workers=workers, scheduler=scheduler)
    ) as it:
        for (a, b), result in it:
            out[a] = result
            if progress:
                progress(b - a)
    return [out[a] for a in sorted(out)]


# --------------------------------------------------------------------------- tuning


def _refit(proposal: Proposal, blocks: list[BlockResult], level: float, smoothing: float) -> Proposal:
    """One cross-entropy step: the proposal fitted to the runs with score >= level, weighted by f/g."""
    score = np.concatenate([b.score for b in blocks])
    elite = score >= level
    w = np.concatenate([b.weight for b in blocks])[elite]
    total = float(np.sum(w))
    if total <= 0.0:
        return proposal
    u = np.concatenate([b.u for b in blocks if b.u is not None])[elite]
    # A coordinate is tilted only where the elite runs differ from the disturbance set beyond
    # chance: a chi-square test at 1 % on the elite's effective size (Kish), else it keeps f.
    # [interpretation] Fitting every coordinate to a few dozen elite runs tilts the ones that do
    # not matter by noise, which only spreads the weights.
    n_eff = total**2 / float(np.sum(w**2))
    probs: list[tuple[float, ...]] = []
    for j, (c, old) in enumerate(zip(proposal.coords, proposal.probs, strict=True)):
        edges = np.asarray(c.edges)
        width = np.diff(edges)
        fitted = np.bincount(_bins(edges, u[:, j]), weights=w, minlength=width.size) / total
        statistic = n_eff * float(np.sum((fitted - width) ** 2 / width))
        if statistic < chi2_quantile(1.0 - TILT_TEST_LEVEL, width.size - 1):
            fitted = width
        new = (1.0 - smoothing) * np.asarray(old) + smoothing * fitted
        new = np.maximum(new, BIN_FLOOR * width)
        probs.append(tuple((new / new.sum()).tolist()))
    q: list[float] = []
    if proposal.tilts:
        trials = np.concatenate([b.trials for b in blocks if b.trials is not None])[elite]
        successes = np.concatenate([b.successes for b in blocks if b.successes is not None])[elite]
        for i, (t, old_q) in enumerate(zip(proposal.tilts, proposal.q, strict=True)):
            drawn = float(np.sum(w * trials[:, i]))
            fitted_q = float(np.sum(w * successes[:, i])) / drawn if drawn > 0.0 else old_q
            q.append(min(MAX_TILT, max(t.p, (1.0 - smoothing) * old_q + smoothing * fitted_q)))
    return replace(proposal, probs=tuple(probs), q=tuple(q))


@dataclass(frozen=True)
class TuningLevel:
    runs: int
    level_m: float  # γ of this level
    elite: int  # runs at or above γ


def tune(
    spec: CertifySpec,
    *,
    defensive: float,
    runs_per_level: int,
    max_levels: int,
    rho: float = 0.02,
    smoothing: float = 0.5,
    workers: int = 1,
    scheduler: str | None = None,
    progress: Callable[[int], None] | None = None,
) -> tuple[Proposal, list[TuningLevel]]:
    """The multilevel cross-entropy tuning (see the module docstring); tuning runs only."""
    proposal = initial_proposal(spec.disturbances, defensive, boost=True)
    levels: list[TuningLevel] = []
    pool: list[BlockResult] = []  # every tuning run so far, weighted against its own proposal
    first = TUNING_FIRST_RUN
    for _ in range(max_levels):
        blocks = _sample(
            spec,
            proposal,
            first,
            runs_per_level,
            keep=True,
            workers=workers,
            scheduler=scheduler,
            progress=progress,
        )
        first += runs_per_level
        pool.extend(blocks)
        # The level: the threshold once the pool holds enough runs beyond it (fit to them
        # directly), else the (1 - rho) quantile of this level's scores.
        hits = int(sum(np.sum(b.score > spec.threshold_m) for b in pool))
        if hits >= MIN_ELITE:
            level, fit = spec.threshold_m, pool
        else:
            score = np.concatenate([b.score for b in blocks])
            level, fit = min(spec.threshold_m, float(np.quantile(score, 1.0 - rho))), blocks
        elite = int(sum(np.sum(b.score >= level) for b in fit))
        levels.append(TuningLevel(runs=runs_per_level, level_m=level, elite=elite))
        proposal = _refit(proposal, fit, level, smoothing)
    return proposal, levels


# --------------------------------------------------------------------------- estimation


@dataclass(frozen=True)
class CertifyResult:
    spec: CertifySpec
    proposal: Proposal
    levels: list[TuningLevel]
    runs: int
    tuning_runs: int
    hits: int
    hits_from_h: int
    estimate: float
    lower: float  # two-sided interval at the confidence
    upper_two_sided: float
    upper: float  # one-sided upper bound at the confidence: the certificate
    confidence: float
    target: float
    ess_hits: float
    max_weight_share: float
    mean_weight: float  # E_g[w] = 1 exactly: a check of the likelihood ratios
    not_stopped: int
    elapsed_s: float
    method: str

    @property
    def certified(self) -> bool:
        return self.upper <= self.target

    def to_dict(self) -> dict[str, Any]:
        return {
            **self.spec.to_dict(),
            "method": self.method,
            "runs": self.runs,
            "tuning_runs": self.tuning_runs,
            "hits": self.hits,
            "hits_from_proposal": self.hits_from_h,
            "estimate": self.estimate,
            "interval": [self.lower, self.upper_two_sided],
            "upper_bound": self.upper,
            "confidence": self.confidence,
            "target": self.target,
            "certified": self.certified,
            "ess_hits": self.ess_hits,
            "max_weight_share": self.max_weight_share,
            "weight_bound": self.proposal.weight_bound,
            "mean_weight": self.mean_weight,
            "not_stopped": self.not_stopped,
            "tuning_levels_m": [lv.level_m for lv in self.levels],
            "proposal": self.proposal.to_dict(),
            "elapsed_s": round(self.elapsed_s, 3),
            "runs_per_s": round((self.runs + self.tuning_runs) / self.elapsed_s, 1)
            if self.elapsed_s > 0
            else None,
        }


def check_setting(name: str, value: object, ok: bool, what: str) -> None:
    """A certification setting that is not ``ok``: a CertifyError naming it and its value."""
    if not ok:
        raise CertifyError(name, f"{what} (got {value!r})")


def check_question(spec: CertifySpec, target: float, confidence: float) -> None:
    """The settings every certification method shares: the target, the confidence, the
    threshold and the seed."""
    check_setting("target", target, 0.0 < target < 1.0, "must be strictly between 0 and 1")
    check_setting("confidence", confidence, 0.0 < confidence < 1.0, "must be strictly between 0 and 1")
    check_setting("threshold_m", spec.threshold_m, math.isfinite(spec.threshold_m), "must be a finite number")
    check_setting("seed", spec.seed, seed_in_range(spec.seed), SEED_RANGE)


def hazard_score(stopped: NDArray[np.bool_], error_m: FloatArray) -> FloatArray:
    """The score a hit is judged by: the stop error, +inf for a run that never stood still (or
    whose error is not a number): [interpretation] its stopping point is unknown, so it counts
    against the design whatever the threshold (fail safe)."""
    return np.where(stopped & np.isfinite(error_m), error_m, np.inf)


def certify(
    spec: CertifySpec,
    *,
    runs: int,
    target: float,
    confidence: float = 0.95,
    method: str = "is",
    defensive: float = 0.5,
    tuning_runs: int = 4_000,
    max_levels: int = 6,
    workers: int = 1,
    scheduler: str | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> CertifyResult:
    """Estimate and bound P(stop error > threshold) (see the module docstring).

    ``method``: ``"is"`` (importance sampling, the default) or ``"mc"`` (plain
    Monte Carlo from the disturbance set, exact Clopper–Pearson bound);
    ``tuning_runs`` per cross-entropy level; ``progress(stage, done, total)``.
    """
    # Estimation runs are numbered 0 .. runs - 1 and tuning runs from TUNING_FIRST_RUN on, within
    # the random streams' 64-bit range: the two must not overlap, nor run past 2^63.
    check_setting("runs", runs, 1 <= runs <= TUNING_FIRST_RUN, "must be between 1 and 2^40")
    check_question(spec, target, confidence)
    check_setting("method", method, method in ("is", "mc"), "must be is or mc")
    check_setting("defensive", defensive, 0.0 < defensive <= 1.0, "must be in (0, 1]")
    most = (RUN_LIMIT - TUNING_FIRST_RUN) // max_levels  # every level's runs get their own numbers
    check_setting("tuning_runs", tuning_runs, 100 <= tuning_runs <= most, f"must be between 100 and {most}")
    t0 = time.perf_counter()

    def stage(name: str, total: int) -> Callable[[int], None] | None:
        if progress is None:
            return None
        done = [0]
        progress(name, 0, total)

        def step(k: int) -> None:
            done[0] += k
            progress(name, done[0], total)

        return step

    levels: list[TuningLevel] = []
    if method == "mc":
        proposal = initial_proposal(spec.disturbances, 1.0)
    else:
        proposal, levels = tune(
            spec,
            defensive=defensive,
            runs_per_level=tuning_runs,
            max_levels=max_levels,
            workers=workers,
            scheduler=scheduler,
            progress=stage("tuning", tuning_runs * max_levels),
        )
        if progress is not None:
            progress("tuning", tuning_runs * max_levels, tuning_runs * max_levels)
    blocks = _sample(
        spec,
        proposal,
        0,
        runs,
        keep=False,
        workers=workers,
        scheduler=scheduler,
        progress=stage("estimation", runs),
    )
    score = np.concatenate([b.score for b in blocks])
    weight = np.concatenate([b.weight for b in blocks])
    from_h = np.concatenate([b.from_h for b in blocks])
    hit = score > spec.threshold_m
    x = np.where(hit, weight, 0.0)
    hits = int(np.sum(hit))
    two_sided = 0.5 * (1.0 + confidence)
    if method == "mc":
        upper = clopper_pearson_upper(hits, runs, confidence)
        lower, upper2 = clopper_pearson(hits, runs, confidence)
    else:
        b = proposal.weight_bound
        upper = min(1.0, betting_upper(x, b, confidence))
        upper2 = min(1.0, betting_upper(x, b, two_sided))
        lower = max(0.0, b - betting_upper(b - x, b, two_sided))
    hw = x[hit]
    total = float(np.sum(hw))
    return CertifyResult(
        spec=spec,
        proposal=proposal,
        levels=levels,
        runs=runs,
        tuning_runs=sum(lv.runs for lv in levels),
        hits=hits,
        hits_from_h=int(np.sum(hit & from_h)),
        estimate=float(np.mean(x)),
        lower=lower,
        upper_two_sided=upper2,
        upper=upper,
        confidence=confidence,
        target=target,
        ess_hits=total**2 / float(np.sum(hw**2)) if total > 0.0 else 0.0,
        max_weight_share=float(np.max(hw)) / total if total > 0.0 else math.nan,
        mean_weight=float(np.mean(weight)),
        not_stopped=sum(b.counts["not_stopped"] for b in blocks),
        elapsed_s=time.perf_counter() - t0,
        method=method,
    )
