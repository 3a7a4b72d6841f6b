"""Confidence bounds for rare-event certification: P(overrun) bounded near 1e-6, validly.

Three estimators of a small probability p = P(hit) (a hit is, for instance, a
stop error above +0.35 m), each with an upper confidence bound that holds at
the stated confidence for every sample size and every p -- no normal
approximation anywhere:

* plain Monte Carlo: k hits in n independent runs, the exact Clopper–Pearson
  bound (:func:`clopper_pearson`, :func:`clopper_pearson_upper`);
* stratified Monte Carlo with known stratum probabilities (e.g. "low-adhesion
  patch or not" × "detector missed or not"): one Clopper–Pearson bound per
  stratum, the error probability split between strata by a union bound
  (:func:`stratified_bound`; :func:`neyman_allocation` spreads a run budget);
* importance sampling with bounded likelihood ratios (a defensive mixture
  proposal): a bound on the mean of X = w·h in [0, B], by betting
  (Waudby-Smith & Ramdas) or by the empirical-Bernstein inequality
  (Maurer & Pontil) (:func:`importance_sampling_bound`, :func:`betting_upper`,
  :func:`empirical_bernstein_upper`).

All functions are pure; scipy is imported only inside the functions that need
it, and only ``scipy.special`` (``scipy.stats`` takes over a second to import).

References
----------
* C. J. Clopper, E. S. Pearson (1934), "The use of confidence or fiducial limits
  illustrated in the case of the binomial", Biometrika 26(4), 404–413.
* J. Neyman (1934), "On the two different aspects of the representative
  method", J. R. Stat. Soc. 97(4), 558–625; W. G. Cochran (1977), Sampling
  Techniques, 3rd ed., ch. 5 (stratified sampling, optimum allocation).
* T. Hesterberg (1995), "Weighted average importance sampling and defensive
  mixture distributions", Technometrics 37(2), 185–194; A. B. Owen, Y. Zhou
  (2000), "Safe and effective importance sampling", JASA 95(449), 135–143.
* I. Waudby-Smith, A. Ramdas (2023), "Estimating means of bounded random
  variables by betting", J. R. Stat. Soc. B 86(1), 1–27 (2024), arXiv:2010.09686.
* A. Maurer, M. Pontil (2009), "Empirical Bernstein bounds and sample variance
  penalization", COLT 2009, Theorem 4, arXiv:0907.3740.
* J. Ville (1939), Étude critique de la notion de collectif (Ville's inequality).
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, SupportsIndex

import numpy as np
from numpy.typing import ArrayLike

from railstop.errors import RailstopError

__all__ = [
    "BoundsError",
    "ImportanceSamplingBound",
    "StratifiedBound",
    "betting_upper",
    "chi2_quantile",
    "clopper_pearson",
    "clopper_pearson_upper",
    "empirical_bernstein_upper",
    "importance_sampling_bound",
    "neyman_allocation",
    "stratified_bound",
]

# Stratum probabilities must sum to 1 within this (they are often products of rounded inputs).
_SUM_TOLERANCE = 1e-9
# Relative precision of the betting bound's root; the returned value is always on the safe side.
_BETTING_RTOL = 1e-6


class BoundsError(RailstopError, ValueError):
    """An argument of a bound is invalid (the message names it and the bad value)."""


# --------------------------------------------------------------------------- argument checks


def _confidence(confidence: float) -> float:
    c = float(confidence)
    if not 0.0 < c < 1.0:
        raise BoundsError(f"confidence: must be strictly between 0 and 1 (got {confidence!r})")
    return c


def _count(name: str, value: SupportsIndex) -> int:
    try:
        v = operator.index(value)
    except TypeError:
        raise BoundsError(f"{name}: must be an integer (got {value!r})") from None
    if v < 0:
        raise BoundsError(f"{name}: must be at least 0 (got {v})")
    return int(v)


def _hits_runs(k: SupportsIndex, n: SupportsIndex) -> tuple[int, int]:
    k, n = _count("k", k), _count("n", n)
    if k > n:
        raise BoundsError(f"k: more hits than runs (got k={k}, n={n})")
    return k, n


def _vector(name: str, values: ArrayLike) -> np.ndarray:
    a = np.asarray(values, dtype=np.float64)
    if a.ndim != 1:
        raise BoundsError(f"{name}: must be one-dimensional (got shape {a.shape})")
    if not np.all(np.isfinite(a)):
        raise BoundsError(f"{name}: must be finite (got {a[~np.isfinite(a)][0]!r})")
    return a


def _bounded_sample(x: ArrayLike, bound: float) -> np.ndarray:
    b = float(bound)
    if not (math.isfinite(b) and b > 0.0):
        raise BoundsError(f"bound: must be a finite number > 0 (got {bound!r})")
    a = _vector("x", x)
    if a.size and (a.min() < 0.0 or a.max() > b):
        bad = a.min() if a.min() < 0.0 else a.max()
        raise BoundsError(f"x: every value must lie in [0, bound={b:g}] (got {bad!r})")
    return a


# --------------------------------------------------------------------------- Clopper–Pearson


def clopper_pearson(k: SupportsIndex, n: SupportsIndex, confidence: float = 0.95) -> tuple[float, float]:
    """The two-sided exact (Clopper–Pearson) interval for a probability seen k times in n trials.

    With δ = 1 − confidence and Beta(q; a, b) the q-quantile of the beta
    distribution::

        lower = Beta(δ/2; k, n − k + 1)       (0 if k = 0)
        upper = Beta(1 − δ/2; k + 1, n − k)   (1 if k = n)

    i.e. the p at which P(Bin(n, p) ≥ k) = δ/2, resp. P(Bin(n, p) ≤ k) = δ/2.
    Coverage is at least ``confidence`` for every p and n (Clopper & Pearson
    1934). No trials (n = 0) give (0, 1).
    """
    k, n = _hits_runs(k, n)
    delta = 1.0 - _confidence(confidence)
    if n == 0:
        return 0.0, 1.0
    lower = 0.0 if k == 0 else _beta_quantile(delta / 2.0, k, n - k + 1)
    upper = 1.0 if k == n else _beta_quantile(1.0 - delta / 2.0, k + 1, n - k)
    return lower, upper


def clopper_pearson_upper(k: SupportsIndex, n: SupportsIndex, confidence: float = 0.95) -> float:
    """The one-sided exact (Clopper–Pearson) upper bound on a probability seen k times in n trials.

    ``upper = Beta(confidence; k + 1, n − k)``, the p at which
    P(Bin(n, p) ≤ k) = 1 − confidence; 1 if k = n (and so for n = 0). For
    k = 0 it is 1 − δ^(1/n) ≈ ln(1/δ)/n ("rule of three" at 95 %). Coverage
    P(p ≤ upper) ≥ confidence for every p and n (Clopper & Pearson 1934).
    """
    k, n = _hits_runs(k, n)
    confidence = _confidence(confidence)
    if k >= n:
        return 1.0
    return _beta_quantile(confidence, k + 1, n - k)


def _beta_quantile(q: float, a: float, b: float) -> float:
    """The q-quantile of Beta(a, b): the inverse of the regularized incomplete beta function,
    which is what ``scipy.stats.beta.ppf`` computes (the same numbers: the tests compare them),
    without loading ``scipy.stats`` (about 1.4 s of every campaign's start-up on the 2-core
    machine, against 0.4 s for ``scipy.special``, which numba loads anyway)."""
    from scipy.special import betaincinv  # lazy (start-up)

    return float(betaincinv(a, b, q))


def chi2_quantile(q: float, df: int) -> float:
    """The q-quantile of the chi-square law of ``df`` degrees of freedom: 2 P^-1(df/2, q), P the
    regularized lower incomplete gamma function (what ``scipy.stats.chi2.ppf`` computes; the tests
    compare them), from ``scipy.special`` for the reason :func:`_beta_quantile` gives."""
    from scipy.special import gammaincinv  # lazy (start-up)

    return 2.0 * float(gammaincinv(df / 2.0, q))


# --------------------------------------------------------------------------- stratified sampling

Split = Literal["weighted", "bonferroni"]


@dataclass(frozen=True)
class StratifiedBound:
    """The result of :func:`stratified_bound`; the per-stratum tuples follow the input order.

    ``estimate`` = Σ π_s k_s/n_s over the sampled strata (strata with n_s = 0
    are left out of it and their total probability is ``unsampled_probability``;
    ``upper`` counts them in full). ``stratum_delta[s]`` is the error
    probability spent on stratum s (0 where none is spent) and
    ``stratum_upper[s]`` the bound on its conditional hit rate p_s (1 for an
    unsampled stratum, NaN for a stratum of probability 0).
    """

    estimate: float
    upper: float
    confidence: float
    split: Split
    stratum_delta: tuple[float, ...]
    stratum_upper: tuple[float, ...]
    unsampled_probability: float


def _strata(probabilities: ArrayLike) -> np.ndarray:
    pi = _vector("probabilities", probabilities)
    if pi.size == 0:
        raise BoundsError("probabilities: at least one stratum is needed (got none)")
    if pi.min() < 0.0:
        raise BoundsError(f"probabilities: must be ≥ 0 (got {pi.min()!r})")
    total = float(pi.sum())
    if abs(total - 1.0) > _SUM_TOLERANCE:
        raise BoundsError(f"probabilities: must sum to 1 (got a sum of {total!r})")
    return pi


def _counts(name: str, values: ArrayLike, size: int) -> np.ndarray:
    a = np.asarray(values)
    if a.shape != (size,):
        raise BoundsError(f"{name}: expected {size} values, one per stratum (got shape {a.shape})")
    if a.size and not (np.issubdtype(a.dtype, np.integer) or np.all(a == np.round(a))):
        raise BoundsError(f"{name}: must be whole numbers (got {a.tolist()!r})")
    out = a.astype(np.int64)
    if out.size and out.min() < 0:
        raise BoundsError(f"{name}: must be ≥ 0 (got {int(out.min())})")
    return out


def stratified_bound(
    probabilities: ArrayLike,
    hits: ArrayLike,
    runs: ArrayLike,
    confidence: float = 0.95,
    *,
    split: Split = "weighted",
) -> StratifiedBound:
    """Estimate and upper bound of p = Σ_s π_s p_s from stratified runs.

    Stratum s has known probability π_s (Σ π_s = 1); its n_s = ``runs[s]``
    runs are drawn from the conditional distribution of stratum s and
    k_s = ``hits[s]`` of them hit. The estimate is p̂ = Σ π_s k_s/n_s and the
    upper bound at confidence 1 − δ is::

        U = Σ_{n_s > 0} π_s · CP_upper(k_s, n_s; 1 − δ_s)  +  Σ_{n_s = 0} π_s,
        Σ δ_s = δ,

    with CP_upper the one-sided Clopper–Pearson bound. Validity is the union
    bound (Bonferroni): each stratum's bound fails with probability ≤ δ_s, so
    all hold at once with probability ≥ 1 − δ, and then p ≤ U. Strata with
    π_s = 0 are skipped; a stratum with no runs contributes its worst case π_s
    and spends no δ.

    The split of δ (``split``) must not depend on the hits, only on the design
    (π, n); both choices here do:

    * ``"bonferroni"``: δ_s = δ/S over the S sampled strata of positive π_s;
    * ``"weighted"`` (default): δ_s ∝ π_s/n_s. In the certification regime most
      strata have k_s = 0, where CP_upper ≈ ln(1/δ_s)/n_s; minimising
      Σ π_s ln(1/δ_s)/n_s subject to Σ δ_s = δ gives exactly δ_s ∝ π_s/n_s
      (Lagrange). It spends little δ on strata that hardly weigh in U.

    The run counts n_s must be fixed before the runs are looked at (e.g. from a
    separate pilot, see :func:`neyman_allocation`); choosing them, or stopping
    a stratum, from the hits of the same runs voids the bound.

    Limits: the union bound is conservative (actual coverage is typically far
    above the nominal). With no hits in any stratum U ≈ Σ π_s·ln(1/δ_s)/n_s ≥
    ln(1/δ)·(Σ √π_s)²/N (Cauchy–Schwarz, N = Σ n_s), i.e. never below plain
    Monte Carlo's ≈ ln(1/δ)/N with the same N runs: stratification sharpens
    the estimate, and the bound when the rare strata carry the hits.
    """
    pi = _strata(probabilities)
    k = _counts("hits", hits, pi.size)
    n = _counts("runs", runs, pi.size)
    if np.any(k > n):
        s = int(np.argmax(k > n))
        raise BoundsError(f"hits: stratum {s} has more hits than runs (got {int(k[s])} > {int(n[s])})")
    confidence = _confidence(confidence)
    if split not in ("weighted", "bonferroni"):
        raise BoundsError(f"split: must be 'weighted' or 'bonferroni' (got {split!r})")
    delta = 1.0 - confidence

    active = (pi > 0.0) & (n > 0)
    unsampled = (pi > 0.0) & (n == 0)
    share = np.zeros(pi.size)
    if split == "bonferroni":
        share[active] = 1.0
    else:
        share[active] = pi[active] / n[active]
    total_share = float(share.sum())
    deltas = delta * share / total_share if total_share > 0.0 else share

    stratum_upper = np.full(pi.size, math.nan)
    stratum_upper[unsampled] = 1.0
    estimate = 0.0
    upper = float(pi[unsampled].sum())
    for i in np.flatnonzero(active).tolist():
        # 1 − δ_s may round to 1.0 for an absurdly small δ_s: then the bound is the trivial 1.
        conf_s = 1.0 - float(deltas[i])
        u = clopper_pearson_upper(int(k[i]), int(n[i]), conf_s) if conf_s < 1.0 else 1.0
        stratum_upper[i] = u
        estimate += float(pi[i]) * int(k[i]) / int(n[i])
        upper += float(pi[i]) * u
    return StratifiedBound(
        estimate=estimate,
        upper=min(upper, 1.0),
        confidence=confidence,
        split=split,
        stratum_delta=tuple(float(d) for d in deltas),
        stratum_upper=tuple(float(u) for u in stratum_upper),
        unsampled_probability=float(pi[unsampled].sum()),
    )


def neyman_allocation(
    probabilities: ArrayLike,
    pilot_rates: ArrayLike,
    budget: SupportsIndex,
    *,
    min_runs: SupportsIndex = 1,
) -> np.ndarray:
    """Split ``budget`` runs between strata by Neyman allocation with a floor; int64 array.

    n_s ∝ π_s·sqrt(p_s(1 − p_s)) (Neyman 1934; Cochran 1977 §5.5), the
    allocation that minimises the variance of p̂ = Σ π_s k_s/n_s, with p_s the
    pilot estimate of the stratum's hit rate. Every stratum with π_s > 0 gets
    at least ``min_runs`` runs (those whose share falls below the floor are
    fixed at it and the rest re-shared, until no share is below it); strata
    with π_s = 0 get none. The counts are whole and sum to ``budget``
    (largest-remainder rounding). If every pilot rate is 0 or 1 the
    allocation is proportional, n_s ∝ π_s.

    Notes: a pilot rate of exactly 0 gets a stratum only the floor, so pass a
    shrunk rate such as (k + ½)/(m + 1) from m pilot runs with k hits. Neyman
    minimises the variance of the estimate, not the upper bound: a stratum
    expected to see no hits contributes ≈ π_s·ln(1/δ_s)/n_s to the bound of
    :func:`stratified_bound`, which is small only if n_s is not too small, so
    keep ``min_runs`` generous for heavy strata. Use fresh runs for the bound,
    not the pilot runs that chose the allocation.
    """
    pi = _strata(probabilities)
    p = _vector("pilot_rates", pilot_rates)
    if p.shape != pi.shape:
        raise BoundsError(f"pilot_rates: expected {pi.size} values, one per stratum (got {p.size})")
    if p.size and (p.min() < 0.0 or p.max() > 1.0):
        raise BoundsError(f"pilot_rates: must lie in [0, 1] (got {p.tolist()!r})")
    total = _count("budget", budget)
    floor = _count("min_runs", min_runs)
    active = pi > 0.0
    need = floor * int(np.count_nonzero(active))
    if total < need:
        raise BoundsError(
            f"budget: {total} runs cannot give {floor} to each of the "
            f"{int(np.count_nonzero(active))} strata of positive probability (need {need})"
        )

    weight = np.where(active, pi * np.sqrt(p * (1.0 - p)), 0.0)
    if not np.any(weight > 0.0):
        weight = np.where(active, pi, 0.0)
    fixed = np.zeros(pi.size, dtype=bool)
    while True:
        free = active & ~fixed
        remaining = total - floor * int(np.count_nonzero(fixed))
        w_free = float(weight[free].sum())
        share = np.zeros(pi.size)
        share[fixed] = float(floor)
        if w_free > 0.0:
            share[free] = remaining * weight[free] / w_free
        low = free & (share < floor)
        if not np.any(low):
            break
        fixed |= low
    # Whole runs: round down (a share of 39.9999999 is 40), then the runs left over go to the
    # largest fractional parts; every stratum keeps at least the floor.
    runs = np.floor(share + 1e-9).astype(np.int64)
    left = total - int(runs.sum())
    if left > 0:
        order = np.argsort(-(share - runs), kind="stable")
        order = order[active[order]]
        runs[order[:left]] += 1
    return runs


# --------------------------------------------------------------------------- importance sampling

Method = Literal["betting", "empirical-bernstein"]


@dataclass(frozen=True)
class ImportanceSamplingBound:
    """The result of :func:`importance_sampling_bound`.

    ``n`` runs, ``hits`` of them hits; ``estimate`` = mean(w·h);
    ``ess`` = (Σw)²/Σw² over all runs and ``ess_hits`` = (Σwh)²/Σ(wh)² over
    the hits (0 when the sums are 0); ``max_weight_share`` = max(wh)/Σwh, the
    share of the estimate carried by the heaviest hit (NaN without a weighted
    hit); ``upper`` the upper bound on P(hit) at ``confidence`` by ``method``
    for X = w·h in [0, ``bound``].
    """

    n: int
    hits: int
    estimate: float
    ess: float
    ess_hits: float
    max_weight_share: float
    upper: float
    method: Method
    confidence: float
    bound: float


def empirical_bernstein_upper(x: ArrayLike, bound: float, confidence: float = 0.95) -> float:
    """Empirical-Bernstein upper confidence bound on E[X] for i.i.d. X_i in [0, B], B = ``bound``.

    Maurer & Pontil (2009), Theorem 4, applied to Y = X/B in [0, 1]: with
    δ = 1 − confidence, sample mean Ȳ and sample variance V (n − 1 in the
    denominator), with probability ≥ 1 − δ::

        E[Y] ≤ Ȳ + sqrt(2·V·ln(2/δ)/n) + 7·ln(2/δ)/(3·(n − 1))

    and the bound on E[X] is B times that, capped at B. Fewer than two values
    give the trivial bound B. The last term is the price of the range: it is
    ≈ 2.3·B·ln(2/δ)/n, so with few hits this bound is looser than
    :func:`betting_upper`.
    """
    a = _bounded_sample(x, bound)
    b = float(bound)
    delta = 1.0 - _confidence(confidence)
    n = a.size
    if n < 2:
        return b
    y = a / b
    log_term = math.log(2.0 / delta)
    variance = float(np.var(y, ddof=1))
    u = float(np.mean(y)) + math.sqrt(2.0 * variance * log_term / n) + 7.0 * log_term / (3.0 * (n - 1))
    return min(u, 1.0) * b


def _plug_in_bets(y: np.ndarray, log_inv_delta: float) -> np.ndarray:
    """Predictable plug-in bets λ̇_t of Waudby-Smith & Ramdas for a fixed sample size n.

    μ̂_t = (½ + Σ_{i≤t} y_i)/(t + 1), σ̂²_t = (¼ + Σ_{i≤t} (y_i − μ̂_i)²)/(t + 1),
    λ̇_t = sqrt(2·ln(1/δ)/(n·σ̂²_{t−1})) with σ̂²_0 = ¼: each bet uses only the
    runs before it.
    """
    n = y.size
    t_plus_1 = np.arange(2.0, n + 2.0)
    mu = (0.5 + np.cumsum(y)) / t_plus_1
    sigma2_before = np.empty(n)
    sigma2_before[0] = 0.25
    sigma2_before[1:] = ((0.25 + np.cumsum(np.square(y - mu))) / t_plus_1)[:-1]
    return np.sqrt((2.0 * log_inv_delta / n) / sigma2_before)


def _max_log_capital(y: np.ndarray, bets: np.ndarray, max_bet: float) -> Callable[[float], float]:
    """m -> max_t ln K_t⁻(m), the running maximum of the log capital of the "mean is below m" bettor."""

    largest_bet = float(bets.max())
    capped = np.empty_like(y)
    work = np.empty_like(y)

    def log_capital(m: float) -> float:
        cap = max_bet / (1.0 - m) if m < 1.0 else math.inf
        lam = bets if cap >= largest_bet else np.minimum(bets, cap, out=capped)
        # ln(1 − λ(y − m)); the factor is ≥ 1 − max_bet > 0 since λ ≤ c/(1 − m) and y ≤ 1.
        np.subtract(m, y, out=work)
        np.multiply(lam, work, out=work)
        np.log1p(work, out=work)
        np.cumsum(work, out=work)
        return float(work.max())

    return log_capital


def betting_upper(x: ArrayLike, bound: float, confidence: float = 0.95, *, max_bet: float = 0.75) -> float:
    """Betting upper confidence bound on E[X] for X_1, X_2, … in [0, B], B = ``bound``.

    Waudby-Smith & Ramdas (2023), hedged capital process with predictable
    plug-in bets, in its one-sided form. With Y_t = X_t/B in [0, 1] and a
    candidate mean m, a bettor who stakes a fraction λ_t of their capital on
    "the mean is below m" has capital::

        K_t⁻(m) = Π_{i≤t} (1 − λ_i(m)·(Y_i − m)),
        λ_i(m) = min(λ̇_i, c/(1 − m)),
        λ̇_i = sqrt(2·ln(1/δ)/(n·σ̂²_{i−1}))     (predictable plug-in, fixed n)

    where σ̂²_{i−1} is the regularised variance of Y_1..Y_{i−1} (σ̂²_0 = ¼) and
    c = ``max_bet`` < 1 the truncation. At the true mean K_t⁻ is a
    non-negative martingale with K_0 = 1, so by Ville's inequality
    P(sup_t K_t⁻(μ) ≥ 1/δ) ≤ δ; the bound is::

        U = B · sup{m in [0, 1] : max_{t≤n} K_t⁻(m) < 1/δ}

    K_t⁻(m) is non-decreasing in m (every factor is), so the set is an
    interval and U is found by root-finding, rounded upwards. This is the
    hedged process K^± = max(θK⁺, (1 − θ)K⁻) with θ = 0, i.e. all of δ spent on
    the upper side. The bound is valid for any n, any distribution on [0, B]
    and even under optional stopping (it is time-uniform); the order of the
    values must not depend on their values (do not sort them).

    The range limit: when the sample holds no value near B, no valid bound can
    be below about mean + B·ln(1/δ)/n, for a distribution with an extra mass
    ε = 1 − δ^(1/n) ≈ ln(1/δ)/n at B would produce such a sample with
    probability > δ. This bound reaches ≈ mean + B·ln(1/δ)/(c·n) there
    (when the bets are truncated); a larger ``max_bet`` c gets closer to the
    limit but loses more capital on a value near B. The paper suggests c = ½
    or ¾; ¾ is the default here because rare-event samples sit at that limit
    (with c = ½ the bound with B = 5, n = 2000 and few hits is ~40 % higher).
    """
    a = _bounded_sample(x, bound)
    b = float(bound)
    delta = 1.0 - _confidence(confidence)
    c = float(max_bet)
    if not 0.0 < c < 1.0:
        raise BoundsError(f"max_bet: must be strictly between 0 and 1 (got {max_bet!r})")
    if a.size == 0:
        return b
    y = a / b
    threshold = math.log(1.0 / delta)
    g = _max_log_capital(y, _plug_in_bets(y, threshold), c)

    def f(m: float) -> float:
        return g(m) - threshold  # ≥ 0: m is rejected

    # Bracket the root (lo accepted, hi rejected) from the shape of the bound, a variance term
    # plus the range term: U − mean is 0.6–1.0 times that scale, so probing 0.75 and then 1, 2,
    # 4, … times it usually brackets tightly. Each evaluation is a pass over all n values.
    n = y.size
    mean = float(np.mean(y))
    scale = math.sqrt(2.0 * float(np.var(y)) * threshold / n) + threshold / (c * n)
    lo, f_lo, hi, f_hi = 0.0, math.nan, 1.0, math.nan
    m, factor = mean + 0.75 * scale, 1.0
    while m < 1.0:
        f_m = f(m)
        if f_m >= 0.0:
            hi, f_hi = m, f_m
            break
        lo, f_lo = m, f_m
        m, factor = mean + factor * scale, 2.0 * factor
    if math.isnan(f_lo) and mean > 0.0:  # the first probe was rejected: try the mean below it
        f_m = f(mean)
        if f_m < 0.0:
            lo, f_lo = mean, f_m
        else:
            hi, f_hi = mean, f_m
    if math.isnan(f_hi):
        f_hi = f(1.0)
        if f_hi < 0.0:
            return b  # not even m = 1 is rejected
    if math.isnan(f_lo):
        f_lo = f(0.0)  # ≤ −ln(1/δ): at m = 0 every factor is 1 − λy ≤ 1
    return _root_from_above(f, lo, f_lo, hi, f_hi, _BETTING_RTOL) * b


def _root_from_above(
    f: Callable[[float], float], lo: float, f_lo: float, hi: float, f_hi: float, rtol: float
) -> float:
    """The upper end of a bracket [lo, hi] of the root of a non-decreasing f, once hi − lo ≤ rtol·hi.

    f(lo) < 0 ≤ f(hi) throughout, so the result is never below the root: a bound computed
    with it errs on the safe side. Regula falsi with the Illinois modification (each end
    moves), and a bisection step whenever two steps have not halved the bracket.
    """
    side = 0
    width_before = [math.inf, math.inf]  # the bracket width one and two steps ago
    while hi - lo > rtol * hi:
        if hi - lo > 0.5 * width_before[0]:
            m, side = 0.5 * (lo + hi), 0
        else:
            # Not closer than a quarter of the tolerance to either end, so the bracket closes.
            margin = 0.25 * rtol * hi
            m = hi - f_hi * (hi - lo) / (f_hi - f_lo)
            m = min(max(m, lo + margin), hi - margin)
        width_before = [width_before[1], hi - lo]
        f_m = f(m)
        if f_m >= 0.0:
            hi, f_hi = m, f_m
            if side == 1:
                f_lo *= 0.5
            side = 1
        else:
            lo, f_lo = m, f_m
            if side == -1:
                f_hi *= 0.5
            side = -1
    return hi


def importance_sampling_bound(
    weights: ArrayLike,
    hits: ArrayLike,
    bound: float,
    confidence: float = 0.95,
    *,
    method: Method = "betting",
    max_bet: float = 0.75,
) -> ImportanceSamplingBound:
    """Importance-sampling estimate of P_p(hit) with a valid upper confidence bound.

    The runs x_i are drawn i.i.d. from a proposal q; ``weights`` are the exact
    likelihood ratios w_i = p(x_i)/q(x_i) ≥ 0 and ``hits`` the indicators
    h_i. X_i = w_i·h_i has E_q[X] = P_p(hit), so::

        p̂ = (1/n)·Σ w_i·h_i
        ess = (Σ w_i)²/Σ w_i²,   ess_hits = (Σ w_i h_i)²/Σ (w_i h_i)²
        max_weight_share = max_i(w_i h_i)/Σ w_i h_i

    and the upper bound is a bound on the mean of X_i in [0, B] with
    B = ``bound``: :func:`betting_upper` (``method="betting"``, Waudby-Smith &
    Ramdas 2023) or :func:`empirical_bernstein_upper`
    (``"empirical-bernstein"``, Maurer & Pontil 2009), capped at 1.

    B must be known before the runs, never taken from them (not the largest
    weight seen). With a defensive mixture q = α·p + (1 − α)·g every weight is
    ≤ 1/α, so B = 1/α is always valid; if w is known to be ≤ B_hit on the
    whole hit region (the proposal density is at least p/B_hit everywhere a hit
    can occur, which must be argued from the model, not seen in the runs),
    X ≤ B_hit and B = B_hit is valid and much tighter.

    The fundamental limit: for X in [0, B] no valid bound can go below about
    mean + B·ln(1/δ)/n (a mass ln(1/δ)/n at B is invisible in n runs with
    probability δ). Plain Monte Carlo with no hits reaches ≈ ln(1/δ)/n, so
    importance sampling gives a tighter *certificate* only if B < 1: with
    B = 1/α = 5 and δ = 0.05, a bound of 1e-6 needs n ≳ 1.5e7 runs (≈ 2e7
    with the betting bound's c = ¾) where plain Monte Carlo with zero hits
    needs 3.0e6. The point estimate and its variance can still be far better
    than plain Monte Carlo's; the certificate needs a small bound on the
    weights of the hits.
    """
    w = _vector("weights", weights)
    h = np.asarray(hits)
    if h.shape != w.shape:
        raise BoundsError(f"hits: expected {w.size} indicators, one per weight (got shape {h.shape})")
    if h.size and not np.all((h == 0) | (h == 1)):
        raise BoundsError("hits: must be booleans or 0/1")
    h = h.astype(bool)
    if w.size and w.min() < 0.0:
        raise BoundsError(f"weights: must be ≥ 0 (got {w.min()!r})")
    b = float(bound)
    if not (math.isfinite(b) and b > 0.0):
        raise BoundsError(f"bound: must be a finite number > 0 (got {bound!r})")
    confidence = _confidence(confidence)
    x = np.where(h, w, 0.0)
    if x.size and x.max() > b:
        raise BoundsError(f"weights: a hit has weight {x.max()!r} above bound={b:g}; the bound is wrong")
    if method == "betting":
        upper = betting_upper(x, b, confidence, max_bet=max_bet)
    elif method == "empirical-bernstein":
        upper = empirical_bernstein_upper(x, b, confidence)
    else:
        raise BoundsError(f"method: must be 'betting' or 'empirical-bernstein' (got {method!r})")

    n = int(w.size)
    sum_w, sum_w2 = float(w.sum()), float(np.dot(w, w))
    sum_x, sum_x2 = float(x.sum()), float(np.dot(x, x))
    return ImportanceSamplingBound(
        n=n,
        hits=int(np.count_nonzero(h)),
        estimate=sum_x / n if n else math.nan,
        ess=sum_w**2 / sum_w2 if sum_w2 > 0.0 else 0.0,
        ess_hits=sum_x**2 / sum_x2 if sum_x2 > 0.0 else 0.0,
        max_weight_share=float(x.max()) / sum_x if sum_x > 0.0 else math.nan,
        upper=min(upper, 1.0),
        method=method,
        confidence=confidence,
        bound=b,
    )
