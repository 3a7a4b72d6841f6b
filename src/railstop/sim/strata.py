"""Certification by strata: the discrete cause whose probability is exact, bounded stratum by stratum.

Why: with the standard set, every overrun comes from a slide on a
low-adhesion patch, and the set draws a patch with a *known* probability p (5 %).
The importance sampler of :mod:`railstop.sim.certify` has to learn that from
its runs, and its bound, over weights up to 1/α, is no lower than plain Monte
Carlo's. Stratifying on the patch takes the known part out of the estimate:

    P(hit) = (1 − p) · P(hit | no patch) + p · P(hit | patch)

Each stratum is plain Monte Carlo from the disturbance set with the patch
forced off or on. Every other quantity keeps its distribution, and the in-run
draws (detector misses, lost telegrams) stay the kernel's own. Each
conditional probability gets its exact Clopper–Pearson upper bound at
confidence 1 − δ/k (k strata, Bonferroni). The weighted sum of those bounds
is then an upper bound on P(hit) at confidence ≥ 1 − δ. The estimate is the
weighted sum of the strata's hit rates.

Allocation: the runs are split n_i ∝ √w_i. This minimises the bound when
no stratum has a hit, since each bound is then about ln(k/δ)/n_i, and the
sum Σ w_i/n_i is smallest at n_i ∝ √w_i. **[interpretation]** The issue names
three discrete causes (a patch, a missed detector, a lost-telegram pattern).
Only the patch is drawn before the run; the misses and losses are drawn
inside the kernel, step by step, and stay in the runs. A set without a patch
(p = 0) is one stratum, which is plain Monte Carlo.

The hazard: ``overrun`` (stop error > the threshold, the PSD tolerance by
default) or ``platform-end``. The latter is the front past the platform's
end, the hazard that matters to an operator: a stop error greater than the
platform end's distance beyond the stopping point. A run that never comes to
a stand counts as a hit (fail safe, as in :mod:`railstop.sim.certify`).

Runs: the no-patch stratum is runs 0 .. n₀ − 1 of the seed. The patch stratum
is runs from :data:`PATCH_FIRST_RUN` on, disjoint from those and from the
importance sampler's tuning runs. A stratum's runs are pure functions of
(seed, run index), so threads, processes, a Dask cluster or a GPU
(``device``) give the same numbers; a GPU's equal the CPU's within
:mod:`railstop.model.gpu`'s bound.
"""

from __future__ import annotations

import contextlib
import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from railstop.config.disturbances import probability
from railstop.sim.campaign import check_device, simulate_runs
from railstop.sim.certify import CertifySpec, check_question, check_setting, hazard_score
from railstop.sim.executor import blocks, execute
from railstop.stats.bounds import clopper_pearson_upper

#: The patch stratum's runs start here (the no-patch stratum's at 0; the importance sampler's
#: tuning runs at 2^40).
PATCH_FIRST_RUN = 1 << 41
#: Runs per block on the CPU (one progress step; a GPU takes a whole stratum's block at once).
CPU_BLOCK_RUNS = 5_000
GPU_BLOCK_RUNS = 1_000_000
HAZARDS = ("overrun", "platform-end")


@dataclass(frozen=True, slots=True)
class Stratum:
    """One stratum: its exact probability, its runs and hits, its bound."""

    name: str
    weight: float  # its probability under the disturbance set (exact)
    first_run: int
    runs: int
    hits: int
    not_stopped: int
    upper: float  # P(hit | stratum) <= this, at the stratum's confidence
    max_error_m: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "stratum": self.name,
            "weight": self.weight,
            "first_run": self.first_run,
            "runs": self.runs,
            "hits": self.hits,
            "not_stopped": self.not_stopped,
            "upper_bound": self.upper,
            "max_error_m": self.max_error_m,
        }


@dataclass(frozen=True, slots=True)
class StratifiedResult:
    spec: CertifySpec
    hazard: str
    strata: tuple[Stratum, ...]
    confidence: float
    target: float
    device: str
    elapsed_s: float

    @property
    def estimate(self) -> float:
        return sum(s.weight * s.hits / s.runs for s in self.strata if s.runs)

    @property
    def upper(self) -> float:
        return min(1.0, sum(s.weight * s.upper for s in self.strata))

    @property
    def runs(self) -> int:
        return sum(s.runs for s in self.strata)

    @property
    def certified(self) -> bool:
        return self.upper <= self.target

    def to_dict(self) -> dict[str, Any]:
        return {
            **self.spec.to_dict(),
            "hazard": self.hazard,
            "method": "stratified",
            "device": self.device,
            "runs": self.runs,
            "hits": sum(s.hits for s in self.strata),
            "not_stopped": sum(s.not_stopped for s in self.strata),
            "estimate": self.estimate,
            "upper_bound": self.upper,
            "confidence": self.confidence,
            "target": self.target,
            "certified": self.certified,
            "strata": [s.to_dict() for s in self.strata],
            "elapsed_s": round(self.elapsed_s, 3),
            "runs_per_s": round(self.runs / self.elapsed_s, 1) if self.elapsed_s > 0 else None,
        }


def allocation(weights: list[float], runs: int) -> list[int]:
    """``runs`` split over strata of these probabilities, n_i ∝ √w_i (at least 1 each)."""
    roots = [math.sqrt(w) for w in weights]
    total = sum(roots)
    n = [max(1, round(runs * r / total)) for r in roots]
    n[0] += runs - sum(n)  # the rounding's remainder to the first (runs >= len(weights))
    return n


def _block(
    spec: CertifySpec, patch: bool | None, device: str, block: tuple[int, int]
) -> tuple[int, int, float]:
    """Runs ``block`` of a stratum: (hits, runs that never stood, largest stop error)."""
    first, end = block
    result, _ = simulate_runs(
        station=spec.line.station(spec.station),
        vehicle=spec.vehicle,
        controller=spec.controller,
        disturbances=spec.disturbances,
        seed=spec.seed,
        first_run=first,
        n=end - first,
        form=spec.form,
        track=spec.line.track,
        device=device,
        patch=patch,
    )
    score = hazard_score(result.stopped, result.stop_error_m)
    stood = np.isfinite(score)
    errors = score[stood]
    hits = int(np.sum(score > spec.threshold_m))
    return hits, int(np.sum(~stood)), float(np.max(errors)) if errors.size else math.nan


def stratified_certify(
    spec: CertifySpec,
    *,
    runs: int,
    target: float,
    hazard: str = "overrun",
    confidence: float = 0.95,
    device: str = "cpu",
    workers: int = 1,
    scheduler: str | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> StratifiedResult:
    """Bound P(hit) stratum by stratum (see the module docstring); ``spec.threshold_m`` is the
    hazard's threshold (the caller sets it for ``platform-end``)."""
    check_setting("runs", runs, 1 <= runs <= PATCH_FIRST_RUN, "must be between 1 and 2^41")
    check_question(spec, target, confidence)
    check_setting("hazard", hazard, hazard in HAZARDS, f"must be one of {', '.join(HAZARDS)}")
    check_device(device)
    t0 = time.perf_counter()
    p = probability(spec.disturbances, "low_adhesion_probability")
    layout: list[tuple[str, float, bool | None, int]]
    if 0.0 < p < 1.0:
        layout = [("no patch", 1.0 - p, False, 0), ("low-adhesion patch", p, True, PATCH_FIRST_RUN)]
    else:
        layout = [("patch" if p >= 1.0 else "no patch", 1.0, None, 0)]
    check_setting("runs", runs, runs >= len(layout), f"at least one per stratum, {len(layout)}")
    sizes = allocation([w for _, w, _, _ in layout], runs)
    level = 1.0 - (1.0 - confidence) / len(layout)  # Bonferroni: each stratum at 1 - δ/k
    most = GPU_BLOCK_RUNS if device == "gpu" else CPU_BLOCK_RUNS
    n_workers = 1 if device == "gpu" and scheduler is None else workers
    strata: list[Stratum] = []
    for (name, weight, patch, first), n in zip(layout, sizes, strict=True):
        done = 0
        if progress is not None:
            progress(name, 0, n)
        hits = not_stopped = 0
        worst = -math.inf
        fn = functools.partial(_block, spec, patch, device)
        items = blocks(first, first + n, n_workers, most)
        with contextlib.closing(execute(fn, items, workers=n_workers, scheduler=scheduler)) as it:
            for (a, b), (h, ns, mx) in it:
                hits += h
                not_stopped += ns
                worst = max(worst, mx) if math.isfinite(mx) else worst
                done += b - a
                if progress is not None:
                    progress(name, done, n)
        strata.append(
            Stratum(
                name=name,
                weight=weight,
                first_run=first,
                runs=n,
                hits=hits,
                not_stopped=not_stopped,
                upper=clopper_pearson_upper(hits, n, level),
                max_error_m=worst if math.isfinite(worst) else math.nan,
            )
        )
    return StratifiedResult(
        spec=spec,
        hazard=hazard,
        strata=tuple(strata),
        confidence=confidence,
        target=target,
        device=device,
        elapsed_s=time.perf_counter() - t0,
    )
