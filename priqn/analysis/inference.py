"""Inference over training seeds: intervals, tests, multiplicity, power and verdict words.

Training seeds are the replicates (docs/statistics.md): every function here takes one
score per training seed and row (``scores_a_S``: S_a seeds of row a), never episodes or
evaluation runs, which share a seed's network. All functions are pure; the permutation
test's Monte-Carlo branch takes an explicit ``numpy.random.Generator``.

- :func:`welch_interval` — the default interval of a difference of means (Welch t).
- :func:`seed_test` — the default test: an exact permutation test over every split of the
  pooled seeds (Monte-Carlo above :data:`EXACT_SPLITS`) *and* Welch's t test, two-sided;
  the larger p counts (p-values are exact fractions).
- :func:`holm` — Holm's step-down adjustment within a family (exact fractions in, out).
- :func:`tost_p` — two one-sided Welch tests for "equivalent within ±margin".
- :func:`min_detectable_difference`, :func:`seeds_needed` — power at the current seeds.
- :func:`verdict_word` — one word per comparison from the above (rule in its docstring).
"""

from __future__ import annotations

import itertools
import math
from fractions import Fraction

import numpy as np
from scipy import stats as scipy_stats

EXACT_SPLITS = 10_000
"""Above this many splits of the pooled seeds the permutation test draws random splits."""
MONTE_CARLO_SPLITS = 9_999
"""Random splits of the Monte-Carlo branch (p = (1 + hits) / (1 + splits))."""
TIE_TOLERANCE = 1e-9
"""A split's statistic within this of the observed one counts as at least as extreme, and no
bound within this of its threshold decides a comparison (floating-point ties, e.g. an
interval ending at 1.1e-16 instead of 0)."""
POWER = 0.8
"""Power asked of :func:`min_detectable_difference` and :func:`seeds_needed`."""

VERDICTS: tuple[str, ...] = (
    "reproduced",
    "contradicted",
    "paper's effect ruled out",
    "equivalent",
    "inconclusive",
)
"""The words :func:`verdict_word` can give."""


def _seed_stats(scores_S: np.ndarray) -> tuple[float, float, int]:
    """Mean, variance of the mean (s² / n) and n of one row's per-seed scores."""
    x = np.asarray(scores_S, dtype=np.float64).reshape(-1)
    if x.size < 2:
        raise ValueError(f"need at least 2 training seeds per row, got {x.size}")
    return float(x.mean()), float(x.var(ddof=1) / x.size), int(x.size)


def welch_se_dof(scores_a_S: np.ndarray, scores_b_S: np.ndarray) -> tuple[float, float, float]:
    """``(mean(a) − mean(b), standard error, Welch-Satterthwaite degrees of freedom)``.

    Seeds that agree exactly in both rows give a zero standard error and infinite dof.
    """
    mean_a, v_a, n_a = _seed_stats(scores_a_S)
    mean_b, v_b, n_b = _seed_stats(scores_b_S)
    se2 = v_a + v_b
    if se2 == 0:
        return mean_a - mean_b, 0.0, math.inf
    dof = se2**2 / (v_a**2 / (n_a - 1) + v_b**2 / (n_b - 1))
    return mean_a - mean_b, math.sqrt(se2), dof


def welch_interval(
    scores_a_S: np.ndarray, scores_b_S: np.ndarray, level: float = 0.95
) -> tuple[float, float]:
    """Two-sided Welch t interval of mean(a) − mean(b) over training seeds at ``level``."""
    diff, se, dof = welch_se_dof(scores_a_S, scores_b_S)
    if se == 0:
        return diff, diff
    half = float(scipy_stats.t.ppf(0.5 + level / 2, dof)) * se
    return diff - half, diff + half


def mean_interval(scores_S: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """Two-sided t interval of one row's mean over training seeds at ``level``; (NaN, NaN)
    below 2 seeds (descriptive: the report's per-row intervals)."""
    x = np.asarray(scores_S, dtype=np.float64).reshape(-1)
    if x.size < 2:
        return float("nan"), float("nan")
    half = float(scipy_stats.t.ppf(0.5 + level / 2, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size))
    return float(x.mean()) - half, float(x.mean()) + half


def upper_bound(scores_a_S: np.ndarray, scores_b_S: np.ndarray, alpha: float) -> float:
    """One-sided Welch upper confidence bound of mean(a) − mean(b) at level 1 − ``alpha``.

    With ``alpha`` = α / m over a family of m comparisons (Bonferroni) the bounds hold
    simultaneously, so "the paper's effect is ruled out" is as error-controlled as the
    family's other verdicts; α / m with m = 2 is the upper end of a 95 % two-sided interval.
    """
    diff, se, dof = welch_se_dof(scores_a_S, scores_b_S)
    if se == 0:
        return diff
    return diff + float(scipy_stats.t.ppf(1 - alpha, dof)) * se


def splits(n_a: int, n_b: int) -> int:
    """Ways to split ``n_a + n_b`` pooled seeds into groups of ``n_a`` and ``n_b``."""
    return math.comb(n_a + n_b, n_a)


def min_attainable_p(n_a: int, n_b: int) -> Fraction:
    """The smallest two-sided p :func:`permutation_test` can give at these seed counts.

    Exact test: the observed split is the most extreme one; with equal group sizes its
    mirror image is as extreme, so 2 / splits (3 vs 3 seeds: 2/20 = 0.10), else 1 / splits.
    Monte-Carlo: 1 / (1 + MONTE_CARLO_SPLITS).
    """
    total = splits(n_a, n_b)
    if total > EXACT_SPLITS:
        return Fraction(1, 1 + MONTE_CARLO_SPLITS)
    return Fraction(2 if n_a == n_b else 1, total)


def _welch_t(a_KA: np.ndarray, b_KB: np.ndarray) -> np.ndarray:
    """``[K]`` |Welch t| of each row pair (0 where both groups are constant and equal;
    a large finite value where they are constant and differ)."""
    diff_K = a_KA.mean(axis=1) - b_KB.mean(axis=1)
    se2_K = a_KA.var(axis=1, ddof=1) / a_KA.shape[1] + b_KB.var(axis=1, ddof=1) / b_KB.shape[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_K = np.abs(diff_K) / np.sqrt(se2_K)
    t_K[se2_K == 0] = np.where(np.abs(diff_K[se2_K == 0]) > TIE_TOLERANCE, 1e12, 0.0)
    return t_K


def _welch_t_split(pooled_N: np.ndarray, in_a_KN: np.ndarray, n_a: int) -> np.ndarray:
    """``[K]`` |Welch t| of every split (``in_a_KN``: True for group a) of the pooled seeds."""
    K, n = in_a_KN.shape
    x_KN = np.broadcast_to(pooled_N, (K, n))
    return _welch_t(x_KN[in_a_KN].reshape(K, n_a), x_KN[~in_a_KN].reshape(K, n - n_a))


def permutation_test(
    scores_a_S: np.ndarray, scores_b_S: np.ndarray, rng: np.random.Generator | None = None
) -> Fraction:
    """Two-sided permutation p of mean(a) − mean(b) over training seeds (an exact fraction).

    The statistic is the studentized difference |Welch t|. With equal seed counts it orders
    the splits exactly as the raw difference of means does (same p); with unequal counts
    it keeps the test's level when the rows' seed spreads differ, where the raw difference
    does not (Janssen 1997; Chung & Romano 2013). Exact when the pooled seeds have at most
    :data:`EXACT_SPLITS` splits: the fraction of all splits whose |t| is at least the
    observed one (within :data:`TIE_TOLERANCE`). Otherwise :data:`MONTE_CARLO_SPLITS` random
    splits drawn from ``rng`` (required then), p = (1 + hits) / (1 + splits), never 0.

    It tests "the two rows' seed scores are exchangeable"; at very unequal seed spreads and
    few seeds it may reject a little more often than α (tests/test_claims.py calibrates it
    at this grid's spreads).
    """
    a = np.asarray(scores_a_S, dtype=np.float64).reshape(-1)
    b = np.asarray(scores_b_S, dtype=np.float64).reshape(-1)
    pooled = np.concatenate([a, b])
    n_a, n = a.size, a.size + b.size
    total = splits(a.size, b.size)
    if total <= EXACT_SPLITS:
        groups_KA = np.array(list(itertools.combinations(range(n), n_a)), dtype=np.intp)
    else:
        if rng is None:
            raise ValueError(f"{total} splits: a Monte-Carlo permutation test needs an rng")
        groups_KA = np.argsort(rng.random((MONTE_CARLO_SPLITS, n)), axis=1)[:, :n_a]
    in_a_KN = np.zeros((len(groups_KA), n), dtype=bool)
    np.put_along_axis(in_a_KN, groups_KA, True, axis=1)
    observed = _welch_t(a[None, :], b[None, :])[0]
    t_K = _welch_t_split(pooled, in_a_KN, n_a)
    hits = int(np.count_nonzero(t_K >= observed - TIE_TOLERANCE))
    if total <= EXACT_SPLITS:
        return Fraction(hits, total)
    return Fraction(1 + hits, 1 + MONTE_CARLO_SPLITS)


def welch_p(scores_a_S: np.ndarray, scores_b_S: np.ndarray) -> float:
    """Two-sided p of Welch's t test of mean(a) = mean(b) over training seeds."""
    diff, se, dof = welch_se_dof(scores_a_S, scores_b_S)
    if se == 0:
        return 1.0 if abs(diff) <= TIE_TOLERANCE else 0.0
    return float(2 * scipy_stats.t.sf(abs(diff) / se, dof))


def seed_test(
    scores_a_S: np.ndarray, scores_b_S: np.ndarray, rng: np.random.Generator | None = None
) -> tuple[Fraction, Fraction, float]:
    """``(p, p_permutation, p_welch)``: the default test of a difference over seeds.

    p is the larger of the permutation p (:func:`permutation_test`: no normality
    assumption, but it tests exchangeability, so at few seeds and very unequal spreads it
    rejects too often: 5.7 % family-wise at 5 seeds at this grid's spreads) and Welch's
    (:func:`welch_p`: equal means with unequal spreads, but assumes normal seed means):
    a difference counts only when both tests see it. Calibrated in tests/test_claims.py.
    """
    p_perm = permutation_test(scores_a_S, scores_b_S, rng)
    p_welch = welch_p(scores_a_S, scores_b_S)
    return max(p_perm, Fraction(p_welch)), p_perm, p_welch


def holm(p_values: list[Fraction]) -> list[Fraction]:
    """Holm step-down adjusted p-values (same order as given; exact fractions).

    Sorted ascending, the i-th smallest (1-based) becomes max over j <= i of
    min(1, (m − j + 1) p_(j)); a comparison is significant at family-wise level α iff its
    adjusted p <= α.
    """
    m = len(p_values)
    order = sorted(range(m), key=lambda i: p_values[i])
    adjusted: list[Fraction] = [Fraction(0)] * m
    running = Fraction(0)
    for rank, i in enumerate(order):
        running = max(running, min(Fraction(1), (m - rank) * Fraction(p_values[i])))
        adjusted[i] = running
    return adjusted


def holm_levels(p_values: list[Fraction], alpha: float) -> list[float]:
    """Each comparison's own Holm threshold α / (m − rank + 1) (rank by raw p, 1-based)."""
    m = len(p_values)
    order = sorted(range(m), key=lambda i: p_values[i])
    levels = [alpha] * m
    for rank, i in enumerate(order):
        levels[i] = alpha / (m - rank)
    return levels


def tost_p(scores_a_S: np.ndarray, scores_b_S: np.ndarray, margin: float) -> float:
    """p of "|mean(a) − mean(b)| < margin" by two one-sided Welch t tests (the larger p)."""
    diff, se, dof = welch_se_dof(scores_a_S, scores_b_S)
    if se == 0:
        return 0.0 if abs(diff) < margin else 1.0
    p_lower = float(scipy_stats.t.sf((diff + margin) / se, dof))  # H0: diff <= -margin
    p_upper = float(scipy_stats.t.cdf((diff - margin) / se, dof))  # H0: diff >= +margin
    return max(p_lower, p_upper)


def min_detectable_difference(
    scores_a_S: np.ndarray, scores_b_S: np.ndarray, alpha: float, power: float = POWER
) -> float:
    """Smallest |difference| a two-sided Welch test at ``alpha`` sees with ``power``, at the
    current seeds and their spread: (t₁₋α/₂ + t_power) × SE. Infinite when the
    permutation test cannot reach ``alpha`` at these seed counts at all."""
    n_a, n_b = np.asarray(scores_a_S).size, np.asarray(scores_b_S).size
    if float(min_attainable_p(n_a, n_b)) > alpha:
        return math.inf
    _, se, dof = welch_se_dof(scores_a_S, scores_b_S)
    if se == 0:
        return 0.0
    t = scipy_stats.t
    return float((t.ppf(1 - alpha / 2, dof) + t.ppf(power, dof)) * se)


def seeds_needed(
    scores_a_S: np.ndarray,
    scores_b_S: np.ndarray,
    effect: float,
    alpha: float,
    power: float = POWER,
) -> int:
    """Training seeds per row for a two-sided test at ``alpha`` to see ``effect`` with
    ``power`` at the measured seed spread (normal approximation:
    n = ⌈(z₁₋α/₂ + z_power)² (s_a² + s_b²) / effect²⌉), and at least enough seeds for the
    permutation test to reach ``alpha``. From few seeds the spread itself is uncertain."""
    a = np.asarray(scores_a_S, dtype=np.float64).reshape(-1)
    b = np.asarray(scores_b_S, dtype=np.float64).reshape(-1)
    spread = a.var(ddof=1) + b.var(ddof=1)
    z = scipy_stats.norm.ppf(1 - alpha / 2) + scipy_stats.norm.ppf(power)
    n = 2 if effect == 0 else max(2, math.ceil(z**2 * spread / effect**2))
    while float(min_attainable_p(n, n)) > alpha:
        n += 1
    return n


def verdict_word(
    kind: str,
    diff: float,
    hi: float,
    p_adjusted: Fraction,
    alpha: float,
    paper: float | None = None,
    tost_p_adjusted: float | None = None,
) -> str:
    """One word for one comparison of ``a − b`` (``diff``, its family-wise upper bound
    ``hi`` (:func:`upper_bound` at α / m), its Holm-adjusted permutation p).

    - ``reproduced``: significant (adjusted p <= α) in the claimed direction (a > b);
    - ``contradicted``: significant in the opposite direction (for ``kind = "equivalent"``:
      significantly different at all);
    - ``paper's effect ruled out`` (``better`` claims with a paper difference): not
      significant, and the family-wise upper bound ``hi`` lies below the paper's
      difference by more than :data:`TIE_TOLERANCE`;
    - ``equivalent`` (``kind = "equivalent"`` only): the Holm-adjusted TOST p <= α;
    - ``inconclusive`` otherwise.

    p-values are exact fractions (permutation counts), so "p <= α" is decided exactly; a
    bound within :data:`TIE_TOLERANCE` of the paper's difference decides nothing.
    """
    if kind not in ("better", "equivalent"):
        raise ValueError(f"kind: expected 'better' or 'equivalent', got {kind!r}")
    significant = p_adjusted <= Fraction(alpha).limit_denominator(10**12)
    if kind == "equivalent":
        if tost_p_adjusted is not None and tost_p_adjusted <= alpha:
            return "equivalent"
        return "contradicted" if significant else "inconclusive"
    if significant and diff > 0:
        return "reproduced"
    if significant and diff < 0:
        return "contradicted"
    if paper is not None and hi < paper - TIE_TOLERANCE:
        return "paper's effect ruled out"
    return "inconclusive"


def claim_verdict(words: list[str]) -> str:
    """A claim's verdict from its comparisons' words: contradicted if any is; else ruled
    out if any is; else reproduced / equivalent if all are; else inconclusive."""
    for word in ("contradicted", "paper's effect ruled out"):
        if word in words:
            return word
    for word in ("reproduced", "equivalent"):
        if words and all(w == word for w in words):
            return word
    return "inconclusive"
