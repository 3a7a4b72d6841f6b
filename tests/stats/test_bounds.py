"""Rare-event bounds: exact values, validity (coverage) and the properties the methods exist for.

Coverage is checked two ways where it can be: exactly, by summing binomial
probabilities over every outcome, and by simulation with a seeded Generator.
A simulated coverage of a 95 % bound is itself random; each simulated check
uses a case whose true coverage is far enough above 95 % (given in the test)
that the ≥ 95 % assertion is not a coin toss on the seed.
"""

from __future__ import annotations

import math
from functools import reduce

import numpy as np
import pytest
from scipy.stats import binom, binomtest, norm

from railstop.errors import RailstopError
from railstop.report import campaign_report
from railstop.stats import bounds, summary
from railstop.stats.bounds import (
    BoundsError,
    betting_upper,
    clopper_pearson,
    clopper_pearson_upper,
    empirical_bernstein_upper,
    importance_sampling_bound,
    neyman_allocation,
    stratified_bound,
)

DELTA = 0.05


def _cp_coverage_exact(n: int, p: float, confidence: float = 0.95) -> float:
    """P(p ≤ CP_upper(K, n)) for K ~ Bin(n, p), summed exactly over K.

    The bound grows with K, so it covers p exactly when K ≥ k*, the first k whose bound reaches p
    (found by bisection).
    """
    lo, hi = 0, n  # CP_upper(n, n) = 1 ≥ p
    while lo < hi:
        mid = (lo + hi) // 2
        if clopper_pearson_upper(mid, n, confidence) >= p:
            hi = mid
        else:
            lo = mid + 1
    return float(binom.sf(lo - 1, n, p))  # P(K ≥ k*)


# --------------------------------------------------------------------------- Clopper–Pearson


def test_cp_zero_hits_is_the_closed_form() -> None:
    # P(Bin(n, p) = 0) = (1 − p)^n = δ  <=>  p = 1 − δ^(1/n).
    assert clopper_pearson_upper(0, 3000) == pytest.approx(1.0 - 0.05 ** (1.0 / 3000), rel=1e-12)
    assert clopper_pearson_upper(0, 3000) == pytest.approx(9.98079e-4, rel=1e-5)
    lo, hi = clopper_pearson(0, 3000)
    assert lo == 0.0
    assert hi == pytest.approx(1.0 - 0.025 ** (1.0 / 3000), rel=1e-12)
    # All hits: the mirror image.
    lo, hi = clopper_pearson(40, 40, 0.99)
    assert hi == 1.0
    assert lo == pytest.approx(0.005 ** (1.0 / 40), rel=1e-12)
    assert clopper_pearson_upper(40, 40) == 1.0


@pytest.mark.parametrize(
    ("k", "n"),
    [
        (0, 1),
        (1, 1),
        (0, 10),
        (3, 10),
        (10, 10),
        (1, 50),
        (7, 300),
        (0, 3000),
        (2, 3000),
        (25, 3000),
        (0, 1_000_000),
        (3, 1_000_000),
        (5000, 10_000),
    ],
)
@pytest.mark.parametrize("confidence", [0.9, 0.95, 0.999])
def test_cp_matches_scipy_binomtest(k: int, n: int, confidence: float) -> None:
    """scipy's binomtest finds the exact limits by root-finding on the binomial CDF: an independent route.

    Its root-finder stops at an absolute 2e-12, hence abs=1e-11; the defining equations
    P(Bin(n, U) ≤ k) = δ and P(Bin(n, L) ≥ k) = δ/2 are checked to 1e-8 relative as well.
    """
    delta = 1.0 - confidence
    upper = clopper_pearson_upper(k, n, confidence)
    one_sided = binomtest(k, n, alternative="less").proportion_ci(confidence, method="exact")
    assert one_sided.low == 0.0
    assert upper == pytest.approx(one_sided.high, rel=1e-7, abs=1e-11)
    two_sided = binomtest(k, n).proportion_ci(confidence, method="exact")
    lo, hi = clopper_pearson(k, n, confidence)
    assert lo == pytest.approx(two_sided.low, rel=1e-7, abs=1e-11)
    assert hi == pytest.approx(two_sided.high, rel=1e-7, abs=1e-11)
    if k < n:
        assert binom.cdf(k, n, upper) == pytest.approx(delta, rel=1e-8)
        assert binom.cdf(k, n, hi) == pytest.approx(delta / 2, rel=1e-8)
    if k > 0:
        assert binom.sf(k - 1, n, lo) == pytest.approx(delta / 2, rel=1e-8)
    assert lo <= k / n <= hi
    # The two-sided upper limit spends δ/2 on its side, the one-sided all of δ.
    assert hi >= clopper_pearson_upper(k, n, confidence)


def test_cp_no_trials_and_bad_arguments() -> None:
    assert clopper_pearson(0, 0) == (0.0, 1.0)
    assert clopper_pearson_upper(0, 0) == 1.0
    assert clopper_pearson_upper(np.int64(2), np.int64(10)) == pytest.approx(
        float(clopper_pearson_upper(2, 10))
    )
    for args in [(3, 2), (-1, 5), (1.5, 10)]:
        with pytest.raises(BoundsError):
            clopper_pearson_upper(*args)  # type: ignore[arg-type]
    for confidence in (0.0, 1.0, 1.5, math.nan):
        with pytest.raises(BoundsError, match="confidence"):
            clopper_pearson(1, 10, confidence)
    # One error type for callers: railstop's own and a ValueError.
    assert issubclass(BoundsError, RailstopError) and issubclass(BoundsError, ValueError)


@pytest.mark.parametrize("p", [1e-6, 1e-4, 1e-3, 1e-2, 0.3])
@pytest.mark.parametrize("n", [1, 20, 700, 3000, 4000])
def test_cp_exact_coverage_at_least_nominal(n: int, p: float) -> None:
    """Coverage summed over every outcome, including near-exact cases (n = 3000, p = 1e-3: 0.9503)."""
    assert _cp_coverage_exact(n, p) >= 0.95
    assert _cp_coverage_exact(n, p, 0.99) >= 0.99


@pytest.mark.parametrize(("p", "n"), [(1e-3, 4000), (1e-2, 1000)])
def test_cp_simulated_coverage(p: float, n: int) -> None:
    # True coverage 0.982 and 0.971: ≥ 3.5 standard errors of 2000 repetitions above 0.95.
    exact = _cp_coverage_exact(n, p)
    assert exact > 0.965
    hits = np.random.default_rng(20240611).binomial(n, p, size=2000)
    upper = {int(k): clopper_pearson_upper(int(k), n) for k in np.unique(hits)}
    covered = np.mean([upper[int(k)] >= p for k in hits])
    assert covered >= 0.95
    assert abs(covered - exact) < 4.0 * math.sqrt(exact * (1.0 - exact) / hits.size)


def test_the_campaign_summary_uses_this_implementation() -> None:
    assert summary.clopper_pearson_upper is bounds.clopper_pearson_upper
    assert campaign_report.summary_stats is summary.summary_stats
    assert not hasattr(summary, "_clopper_pearson_upper")


# --------------------------------------------------------------------------- stratified

# "Low-adhesion patch or not" × "detector missed or not", with a rare worst corner.
PI = np.array([0.88, 0.09, 0.025, 0.005])
RATE = np.array([5e-4, 4e-3, 1e-2, 0.08])
RUNS = np.array([6000, 1000, 400, 150])
P_TRUE = float(PI @ RATE)


def test_stratified_estimate_and_bound_by_hand() -> None:
    res = stratified_bound(PI, [1, 3, 0, 12], RUNS, split="bonferroni")
    assert res.estimate == pytest.approx(0.88 / 6000 + 0.09 * 3 / 1000 + 0.005 * 12 / 150)
    assert res.stratum_delta == pytest.approx((DELTA / 4,) * 4)
    expected = [
        clopper_pearson_upper(k, n, 1.0 - DELTA / 4) for k, n in zip([1, 3, 0, 12], RUNS, strict=True)
    ]
    assert res.stratum_upper == pytest.approx(expected, rel=1e-12)
    assert res.upper == pytest.approx(float(PI @ np.array(expected)), rel=1e-12)
    assert res.unsampled_probability == 0.0

    weighted = stratified_bound(PI, [1, 3, 0, 12], RUNS)
    assert weighted.split == "weighted"
    share = PI / RUNS
    assert weighted.stratum_delta == pytest.approx(tuple(DELTA * share / share.sum()), rel=1e-12)
    assert sum(weighted.stratum_delta) == pytest.approx(DELTA)


def test_one_stratum_is_clopper_pearson() -> None:
    for split in ("weighted", "bonferroni"):
        res = stratified_bound([1.0], [4], [2500], 0.9, split=split)
        assert res.upper == clopper_pearson_upper(4, 2500, 0.9)
        assert res.estimate == 4 / 2500


def test_unsampled_and_impossible_strata() -> None:
    # Stratum 1 has no runs: counted at its worst case, 1 × π; stratum 2 cannot occur: ignored.
    res = stratified_bound([0.7, 0.2, 0.0, 0.1], [0, 0, 3, 0], [1000, 0, 10, 500])
    assert res.unsampled_probability == pytest.approx(0.2)
    assert res.stratum_upper[1] == 1.0 and math.isnan(res.stratum_upper[2])
    assert res.stratum_delta[1] == 0.0 and res.stratum_delta[2] == 0.0
    assert sum(res.stratum_delta) == pytest.approx(DELTA)  # all of δ on the two sampled strata
    assert res.estimate == 0.0  # the hits of the impossible stratum count for nothing
    sampled = 0.7 * res.stratum_upper[0] + 0.1 * res.stratum_upper[3]
    assert res.upper == pytest.approx(0.2 + sampled, rel=1e-12)
    # Nothing sampled at all: the bound is the trivial 1.
    assert stratified_bound([0.5, 0.5], [0, 0], [0, 0]).upper == 1.0


def test_stratified_rejects_bad_input() -> None:
    with pytest.raises(BoundsError, match="sum to 1"):
        stratified_bound([0.5, 0.4], [0, 0], [10, 10])
    with pytest.raises(BoundsError, match="more hits than runs"):
        stratified_bound([0.5, 0.5], [0, 11], [10, 10])
    with pytest.raises(BoundsError, match="one per stratum"):
        stratified_bound([0.5, 0.5], [0, 1, 2], [10, 10])
    with pytest.raises(BoundsError, match="split"):
        stratified_bound([1.0], [0], [10], split="holm")  # type: ignore[arg-type]


def _stratum_uppers(split: str) -> list[np.ndarray]:
    """U_s(k) for every k of non-negligible probability, read off stratified_bound (δ_s: from π, n only)."""
    tables = []
    for s in range(PI.size):
        top = int(binom.isf(1e-12, RUNS[s], RATE[s])) + 1
        table = []
        for k in range(top + 1):
            hits = np.zeros(PI.size, dtype=np.int64)
            hits[s] = k
            table.append(stratified_bound(PI, hits, RUNS, split=split).stratum_upper[s])  # type: ignore[arg-type]
        tables.append(np.array(table))
    return tables


def _outer(op: np.ufunc, per_stratum: list[np.ndarray]) -> np.ndarray:
    """op over the strata on the grid of joint outcomes (k_1, …, k_S)."""
    return reduce(op, np.ix_(*per_stratum))


def test_stratified_exact_coverage_and_expected_bound() -> None:
    """P(p ≤ U) and E[U], summed over every joint outcome (k_1..k_4) of the four binomials."""
    expected = {}
    for split in ("weighted", "bonferroni"):
        tables = _stratum_uppers(split)
        # U is additive over the strata (this is what lets the sum run per stratum).
        rng = np.random.default_rng(3)
        for _ in range(5):
            k = [int(rng.integers(0, t.size)) for t in tables]
            res = stratified_bound(PI, k, RUNS, split=split)
            assert res.upper == pytest.approx(sum(PI[s] * tables[s][k[s]] for s in range(PI.size)), rel=1e-12)
        ks = [np.arange(t.size) for t in tables]
        prob = _outer(np.multiply, [binom.pmf(k, RUNS[s], RATE[s]) for s, k in enumerate(ks)])
        assert prob.sum() == pytest.approx(1.0, abs=1e-9)
        upper = _outer(np.add, [PI[s] * tables[s] for s in range(PI.size)])
        assert float(np.sum(prob * (upper >= P_TRUE))) >= 0.95
        expected[split] = float(np.sum(prob * upper))

    # The same machinery catches an invalid bound: p̂ + 1.645·se (normal approximation) covers ≈ 0.905.
    rate = [k / RUNS[s] for s, k in enumerate(ks)]
    estimate = _outer(np.add, [PI[s] * rate[s] for s in range(PI.size)])
    variance = _outer(np.add, [PI[s] ** 2 * rate[s] * (1 - rate[s]) / RUNS[s] for s in range(PI.size)])
    normal = estimate + norm.ppf(0.95) * np.sqrt(variance)
    assert float(np.sum(prob * (normal >= P_TRUE))) < 0.93
    # δ_s ∝ π_s/n_s gives a lower bound on average than δ/S; both are ≈ 2.6 × p here (rare strata).
    assert expected["weighted"] < expected["bonferroni"] < 3.0 * P_TRUE


def test_stratified_simulated_coverage_and_split_choice() -> None:
    """3 strata, 2000 repetitions; the weighted split is tighter than Bonferroni here."""
    pi = np.array([0.9, 0.09, 0.01])
    rate = np.array([1e-4, 3e-3, 0.05])
    runs = np.array([3000, 1000, 400])
    p_true = float(pi @ rate)
    hits = np.random.default_rng(7).binomial(runs, rate, size=(2000, 3))
    cache: dict[tuple[int, ...], tuple[float, float, float]] = {}
    for k in map(tuple, hits):
        if k not in cache:
            w = stratified_bound(pi, k, runs)
            b = stratified_bound(pi, k, runs, split="bonferroni")
            cache[k] = (w.upper, b.upper, w.estimate)
    result = np.array([cache[k] for k in map(tuple, hits)])
    assert np.mean(result[:, 0] >= p_true) >= 0.95
    assert np.mean(result[:, 1] >= p_true) >= 0.95
    # The estimate is unbiased: within 4 standard errors of the truth.
    se = result[:, 2].std(ddof=1) / math.sqrt(len(result))
    assert abs(result[:, 2].mean() - p_true) < 4.0 * se
    assert np.median(result[:, 0]) < np.median(result[:, 1])


def test_neyman_allocation() -> None:
    pi = np.array([0.6, 0.3, 0.1, 0.0])
    rate = np.array([1e-3, 1e-2, 0.2, 0.5])
    runs = neyman_allocation(pi, rate, 10_000, min_runs=50)
    assert runs.dtype == np.int64 and runs.sum() == 10_000
    assert runs[3] == 0  # π = 0: nothing to learn there
    weight = pi[:3] * np.sqrt(rate[:3] * (1 - rate[:3]))
    assert np.all(np.abs(runs[:3] - 10_000 * weight / weight.sum()) <= 1.0)

    # A stratum with no pilot hits gets the floor, the others share the rest by Neyman.
    runs = neyman_allocation([0.5, 0.3, 0.2], [0.0, 0.01, 0.05], 1000, min_runs=100)
    assert runs[0] == 100 and runs.sum() == 1000
    weight = np.array([0.3, 0.2]) * np.sqrt(np.array([0.01, 0.05]) * np.array([0.99, 0.95]))
    assert np.all(np.abs(runs[1:] - 900 * weight / weight.sum()) <= 1.0)

    # The floor can push several strata up; re-sharing keeps every one at or above it.
    runs = neyman_allocation([0.97, 0.01, 0.01, 0.01], [0.3, 1e-4, 1e-4, 0.02], 500, min_runs=40)
    assert runs.sum() == 500 and runs.min() >= 40 and runs[0] == 500 - 3 * 40

    # No pilot information at all: proportional allocation.
    assert neyman_allocation([0.5, 0.25, 0.25], [0.0, 0.0, 0.0], 1000).tolist() == [500, 250, 250]
    with pytest.raises(BoundsError, match="budget"):
        neyman_allocation([0.5, 0.5], [0.1, 0.1], 15, min_runs=10)
    with pytest.raises(BoundsError, match="pilot_rates"):
        neyman_allocation([0.5, 0.5], [0.1, 1.5], 100)


# --------------------------------------------------------------------------- importance sampling

ALPHA = 0.2  # q = 0.2·N(0, 1) + 0.8·N(3, 1), target P(Z > 3) under N(0, 1)
SHIFT = 3.0
N_IS = 2000
P_IS = float(norm.sf(SHIFT))  # 1.3499e-3
B_DEFENSIVE = 1.0 / ALPHA
# w(z) = φ(z)/(αφ(z) + (1 − α)φ(z − 3)) = 1/(α + (1 − α)·exp(3z − 4.5)) falls with z, so on the
# hit region z > 3 every weight is below w(3): a bound known before any run, not read off the data.
B_HIT = 1.0 / (ALPHA + (1.0 - ALPHA) * math.exp(SHIFT * SHIFT - SHIFT * SHIFT / 2.0))


def _weight(z: np.ndarray) -> np.ndarray:
    """p(z)/q(z) = φ(z)/(αφ(z) + (1 − α)φ(z − 3)) in closed form."""
    return 1.0 / (ALPHA + (1.0 - ALPHA) * np.exp(SHIFT * z - SHIFT * SHIFT / 2.0))


def _is_sample(rng: np.random.Generator, shape: int | tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Runs drawn from q: weights and hits (Z > 3)."""
    z = rng.standard_normal(shape) + np.where(rng.random(shape) < ALPHA, 0.0, SHIFT)
    return _weight(z), z > SHIFT


@pytest.fixture(scope="module")
def is_repetitions() -> np.ndarray:
    """1500 repetitions of n = 2000 runs: columns estimate, betting upper, empirical-Bernstein upper."""
    w, h = _is_sample(np.random.default_rng(12345), (1500, N_IS))
    out = np.empty((w.shape[0], 3))
    for r in range(w.shape[0]):
        res = importance_sampling_bound(w[r], h[r], B_HIT)
        out[r] = res.estimate, res.upper, empirical_bernstein_upper(np.where(h[r], w[r], 0.0), B_HIT)
    return out


def test_is_weights_are_exact_and_bounded() -> None:
    assert pytest.approx(1.3499e-3, rel=1e-4) == P_IS
    assert pytest.approx(0.013848, rel=1e-4) == B_HIT
    z = np.linspace(-8.0, 12.0, 2001)
    ratio = norm.pdf(z) / (ALPHA * norm.pdf(z) + (1.0 - ALPHA) * norm.pdf(z - SHIFT))
    assert _weight(z) == pytest.approx(ratio, rel=1e-12)
    w, h = _is_sample(np.random.default_rng(0), 100_000)
    assert w.max() <= B_DEFENSIVE
    assert w[h].max() <= B_HIT
    assert np.mean(w) == pytest.approx(1.0, abs=0.02)  # E_q[w] = 1


def test_is_bounds_cover(is_repetitions: np.ndarray) -> None:
    # The betting bound's true coverage here is ≈ 0.963 (2 × 2000 repetitions with other seeds),
    # 3.4 standard errors of 1500 repetitions above 0.95: tight, so a bound a little too low fails.
    assert np.mean(is_repetitions[:, 1] >= P_IS) >= 0.95
    assert np.mean(is_repetitions[:, 2] >= P_IS) >= 0.95


def test_is_estimate_is_unbiased(is_repetitions: np.ndarray) -> None:
    estimate = is_repetitions[:, 0]
    se = estimate.std(ddof=1) / math.sqrt(estimate.size)
    assert abs(estimate.mean() - P_IS) < 4.0 * se
    # And precise: a relative standard error of ~5 % per campaign, against ~54 % for plain MC.
    assert estimate.std(ddof=1) < 0.1 * P_IS


def test_is_bound_far_tighter_than_plain_monte_carlo(is_repetitions: np.ndarray) -> None:
    """What importance sampling is for: with B known on the hit region the margin shrinks ≥ 10-fold."""
    median_hits = int(binom.median(N_IS, P_IS))  # 3 of 2000; the CP bound grows with the hits
    cp_median = clopper_pearson_upper(median_hits, N_IS)
    betting_margin = float(np.median(is_repetitions[:, 1])) - P_IS
    assert 0.0 < betting_margin < 0.1 * (cp_median - P_IS)
    assert np.quantile(is_repetitions[:, 1], 0.95) < 0.5 * cp_median
    # Betting beats empirical Bernstein here (its range term is 7/3·B·ln(2/δ)/(n − 1)).
    assert np.median(is_repetitions[:, 1]) < np.median(is_repetitions[:, 2])


def test_is_defensive_bound_alone_hits_the_range_floor() -> None:
    """With only B = 1/α known, the bound cannot beat plain MC: the limit B·(1 − δ^(1/n)) binds."""
    w, h = _is_sample(np.random.default_rng(99), (200, N_IS))
    floor = B_DEFENSIVE * (1.0 - DELTA ** (1.0 / N_IS))  # ≈ 7.5e-3
    uppers = [importance_sampling_bound(w[r], h[r], B_DEFENSIVE).upper for r in range(w.shape[0])]
    assert min(uppers) >= floor
    assert floor > clopper_pearson_upper(int(binom.median(N_IS, P_IS)), N_IS)


@pytest.mark.parametrize("method", ["betting", "empirical-bernstein"])
@pytest.mark.parametrize(("bound", "n"), [(1.0, 2000), (50.0, 2000), (5.0, 100_000), (1.0, 1)])
def test_no_hits_never_below_the_range_floor(method: str, bound: float, n: int) -> None:
    # A mass ε < 1 − δ^(1/n) at B shows up in none of n runs with probability > δ: any valid
    # bound on a sample without hits is at least ε·B for all such ε.
    w = np.full(n, 0.5)
    res = importance_sampling_bound(w, np.zeros(n, dtype=bool), bound, method=method)  # type: ignore[arg-type]
    floor = min(1.0, bound * (1.0 - DELTA ** (1.0 / n)))
    assert res.upper >= floor
    assert res.estimate == 0.0 and res.hits == 0
    if method == "betting" and n > 1:
        # ... and not much more: ≈ ln(1/δ)/(c·n) with the bets capped at c = 0.75.
        assert res.upper <= min(1.0, 2.0 * floor / 0.75)


def test_bounds_survive_the_adversary_the_floor_is_about() -> None:
    """X = B with probability ε = 0.6·ln(1/δ)/n, else a small value: the mass at B is often unseen."""
    rng = np.random.default_rng(4242)
    n, b = 2000, 5.0
    eps = 0.6 * math.log(1.0 / DELTA) / n
    mean = eps * b + (1.0 - eps) * 0.01
    naive = betting = bernstein = 0
    reps = 400
    for _ in range(reps):
        x = np.where(rng.random(n) < eps, b, rng.uniform(0.0, 0.02, n))
        se = x.std(ddof=1) / math.sqrt(n)
        naive += x.mean() + norm.ppf(0.95) * se >= mean
        betting += betting_upper(x, b) >= mean
        bernstein += empirical_bernstein_upper(x, b) >= mean
    # The normal approximation fails about once in six (whenever no B is seen): the check bites.
    assert naive / reps < 0.9
    assert betting / reps >= 0.95
    assert bernstein / reps >= 0.95


def _naive_max_log_capital(y: list[float], m: float, delta: float, c: float) -> float:
    """Waudby-Smith & Ramdas' K_t⁻(m) written out step by step, its running maximum (log)."""
    n = len(y)
    log_k, best = 0.0, -math.inf
    total, squares = 0.0, 0.0
    sigma2_before = 0.25
    for t, yt in enumerate(y, start=1):
        bet = min(math.sqrt(2.0 * math.log(1.0 / delta) / (n * sigma2_before)), c / (1.0 - m))
        log_k += math.log(1.0 - bet * (yt - m))
        best = max(best, log_k)
        total += yt
        mu_t = (0.5 + total) / (t + 1)
        squares += (yt - mu_t) ** 2
        sigma2_before = (0.25 + squares) / (t + 1)
    return best


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_betting_bound_is_the_root_of_the_capital_process(seed: int) -> None:
    """An independent, loop-by-loop capital process: it reaches 1/δ at U and not just below U."""
    w, h = _is_sample(np.random.default_rng(seed), 300)
    x = np.where(h, w, 0.0)
    for b, confidence in [(B_HIT, 0.95), (B_DEFENSIVE, 0.99)]:
        u = betting_upper(x, b, confidence)
        y = list(x / b)
        delta = 1.0 - confidence
        assert _naive_max_log_capital(y, u / b, delta, 0.75) >= math.log(1.0 / delta) - 1e-9
        assert _naive_max_log_capital(y, u / b * (1.0 - 1e-5), delta, 0.75) < math.log(1.0 / delta)


def test_empirical_bernstein_formula() -> None:
    x = np.array([0.0, 0.2, 0.0, 0.4, 0.1] * 40)  # n = 200, in [0, B = 2]
    y = x / 2.0
    log_term = math.log(2.0 / 0.1)
    expected = y.mean() + math.sqrt(2 * y.var(ddof=1) * log_term / 200) + 7 * log_term / (3 * 199)
    assert empirical_bernstein_upper(x, 2.0, 0.9) == pytest.approx(2.0 * expected, rel=1e-12)
    assert empirical_bernstein_upper(x[:1], 2.0) == 2.0  # one value: nothing but the range


def test_is_diagnostics_by_hand() -> None:
    w = np.array([0.5, 2.0, 1.0, 0.5, 4.0])
    h = np.array([True, False, True, True, False])
    res = importance_sampling_bound(w, h, 5.0, method="empirical-bernstein")
    assert res.n == 5 and res.hits == 3
    assert res.estimate == pytest.approx((0.5 + 1.0 + 0.5) / 5)
    assert res.ess == pytest.approx(8.0**2 / (0.25 + 4 + 1 + 0.25 + 16))
    assert res.ess_hits == pytest.approx(2.0**2 / (0.25 + 1 + 0.25))
    assert res.max_weight_share == pytest.approx(0.5)
    assert res.method == "empirical-bernstein" and res.bound == 5.0 and res.confidence == 0.95
    assert res.upper <= 1.0  # a probability, though B = 5
    with pytest.raises(AttributeError):
        res.upper = 0.0  # type: ignore[misc]


def test_is_edge_cases() -> None:
    # All weights zero (every run outside the target's support): estimate 0, no usable sample size.
    zero = importance_sampling_bound(np.zeros(500), np.ones(500, dtype=bool), 5.0)
    assert zero.estimate == 0.0 and zero.ess == 0.0 and zero.ess_hits == 0.0
    assert math.isnan(zero.max_weight_share)
    assert zero.upper >= min(1.0, 5.0 * (1.0 - DELTA ** (1.0 / 500)))
    # One run: a hit of weight 0.01 with B = 0.02, and a miss.
    hit = importance_sampling_bound([0.01], [True], 0.02)
    assert hit.estimate == 0.01 and hit.max_weight_share == 1.0 and hit.ess_hits == 1.0
    assert 0.01 <= hit.upper <= 0.02
    miss = importance_sampling_bound([0.3], [False], 0.02)
    assert miss.upper >= 0.02 * 0.95  # one run of X = 0 cannot exclude much
    # No runs: the range is all there is.
    empty = importance_sampling_bound([], [], 0.5)
    assert empty.n == 0 and math.isnan(empty.estimate) and empty.upper == 0.5


def test_is_rejects_bad_input() -> None:
    with pytest.raises(BoundsError, match="above bound"):
        importance_sampling_bound([0.1, 6.0], [False, True], 5.0)
    # A large weight on a miss is no contradiction: X = w·h = 0.
    assert importance_sampling_bound([0.1, 6.0], [True, False], 5.0).hits == 1
    with pytest.raises(BoundsError, match="weights"):
        importance_sampling_bound([-0.1, 1.0], [False, True], 5.0)
    with pytest.raises(BoundsError, match="hits"):
        importance_sampling_bound([0.1, 1.0], [0, 2], 5.0)
    with pytest.raises(BoundsError, match="one per weight"):
        importance_sampling_bound([0.1, 1.0], [True], 5.0)
    with pytest.raises(BoundsError, match="bound"):
        importance_sampling_bound([0.1], [True], math.inf)
    with pytest.raises(BoundsError, match="method"):
        importance_sampling_bound([0.1], [True], 1.0, method="normal")  # type: ignore[arg-type]
    with pytest.raises(BoundsError, match="max_bet"):
        betting_upper([0.1], 1.0, max_bet=1.0)
    with pytest.raises(BoundsError, match="x"):
        betting_upper([0.1, math.nan], 1.0)


def test_betting_bound_is_monotone_in_confidence_and_data() -> None:
    x = np.where(np.arange(1000) % 97 == 0, 0.3, 0.0)
    levels = [betting_upper(x, 1.0, c) for c in (0.5, 0.9, 0.95, 0.99, 0.999)]
    assert levels == sorted(levels) and levels[0] > x.mean()
    # One more hit, everything else equal, cannot lower the bound here.
    more = x.copy()
    more[500] = 0.3
    assert betting_upper(more, 1.0) > betting_upper(x, 1.0)


def test_the_beta_quantile_is_scipy_stats_beta_ppf() -> None:
    """The bounds take Beta(a, b)'s quantile from scipy.special (scipy.stats loads slowly): the
    numbers as scipy.stats' beta.ppf (to 1e-12; equal to the bit with scipy 1.17) over the runs,
    hits and confidences the tool meets."""
    from scipy.stats import beta

    from railstop.stats.bounds import _beta_quantile

    for n in (1, 2, 7, 100, 1_500, 30_000, 1_000_000, 5_000_000):
        for k in sorted({0, 1, 2, 5, n // 3, n - 1, n}):
            for q in (0.005, 0.025, 0.05, 0.95, 0.975, 0.995):
                for a, b in ((k + 1, n - k), (k, n - k + 1)):
                    if a > 0 and b > 0:
                        want = float(beta.ppf(q, a, b))
                        assert _beta_quantile(q, a, b) == pytest.approx(want, rel=1e-12, abs=0.0), (q, a, b)


def test_the_chi_square_quantile_is_scipy_stats_chi2_ppf() -> None:
    """Certify's tilt test takes the chi-square quantile from scipy.special (scipy.stats loads
    slowly): the same as scipy.stats' chi2.ppf (to 1e-12)."""
    from scipy.stats import chi2

    from railstop.sim.certify import TILT_TEST_LEVEL
    from railstop.stats.bounds import chi2_quantile

    for df in range(1, 64):
        for q in (0.9, 0.95, 0.99, 1.0 - TILT_TEST_LEVEL):
            assert chi2_quantile(q, df) == pytest.approx(float(chi2.ppf(q, df)), rel=1e-12, abs=0.0), (df, q)
