"""The paper's claims as data, and a verdict rule fixed before the grid's numbers are in.

Each :class:`Claim` is a set of directed comparisons between Table II rows ("row A has
a higher success rate than row B at density d") or of equivalences ("A and B are within
±δ"). For each comparison the report gives the difference of the two policies' means
with a 95 % bootstrap CI; the claim's verdict follows from the CIs by one rule
(:func:`verdict`), written down here before the Table II grid finished, so the numbers
cannot choose the rule:

- a comparison **holds** when its CI lies entirely on the claimed side of 0 (for an
  equivalence: inside ±δ); it is **contradicted** when its CI lies entirely on the other
  side of 0, or — for a "better" claim — straddles 0 inside ±δ (no practically relevant
  difference either way; for an equivalence: when its CI excludes 0); otherwise it is
  **unclear**;
- a claim is *reproduced* when every comparison holds, *not reproduced* when any is
  contradicted, and *inconclusive at this budget* otherwise;
- *pending* while a row is missing or has fewer than 2 training seeds (one seed gives no
  CI worth the name).

The CI is a two-level bootstrap per policy — resample training seeds, then evaluation
runs within each drawn seed — of the mean over (net, episode) at the claim's density
(or over all densities): training seeds are the independent repetitions, and the
evaluation runs of one seed share its network. The two policies are resampled
independently (their training seeds are unrelated). Resampling uses
``numpy.random.default_rng(seed)``; the seed is recorded in the report.

**A second look, not the rule.** With 3 training seeds a percentile bootstrap over seeds
is too narrow: it can draw only 10 distinct seed multisets, and the variance it gives a
mean is (S − 1)/S of the usual s²/S. So every comparison also gets a Welch t-interval over
the training seeds alone (one number per seed: its mean over evaluation runs) and the
outcome the same rule would give on that interval, and — where the paper gives a
difference — how many training seeds per row would see the paper's difference with
80 % power at our seed-to-seed spread (:func:`seeds_needed`). The verdict stays the
rule's; the report says where the second look disagrees.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import numpy as np
import pandas as pd
from scipy import stats as scipy_stats

from priqn.errors import PriqnError
from priqn.labels import PolicyLabel, near_greedy

EQUIVALENCE_MARGIN: dict[str, float] = {"success": 0.05}
"""δ per metric: a success-rate difference inside ±5 points is no practical difference.
Metrics without a margin (objective returns) are judged on the sign of the CI alone."""
MIN_SEEDS = 2
"""Training seeds every row of a claim needs before its verdict is computed."""
POWER = 0.8
"""Power the seed estimate of :func:`seeds_needed` asks for (two-sided 5 % test)."""
DENSITIES_ALL: float | None = None
"""``Comparison.density`` value meaning "mean over every evaluated density"."""

IQN = PolicyLabel("iqn")
ENSEMBLE = PolicyLabel("ensemble-iqn")
MA_IQN = PolicyLabel("ma-iqn")


def pr_iqn(
    comparator: str = "qd",
    train_preorder: bool = True,
    eps: float = 0.2,
    partial_order: bool = False,
    extra: tuple[str, ...] = (),
) -> PolicyLabel:
    """A Pr-IQN row; the defaults are the paper's best configuration, Pr-IQN*."""
    return PolicyLabel("pr-iqn", comparator, train_preorder, eps, partial_order, extra)


PR_IQN_STAR = pr_iqn()


@dataclasses.dataclass(frozen=True)
class Comparison:
    """One directed comparison: ``first`` vs ``second`` on ``metric`` at ``density``."""

    first: PolicyLabel
    """The row the claim favours (or either row of an equivalence)."""
    second: PolicyLabel
    """The row it is compared with."""
    metric: str = "success"
    """Episode column compared (``success``, ``return_safety``, ...); higher is better."""
    density: float | None = DENSITIES_ALL
    """Traffic density the comparison is made at; None: the mean over all densities."""
    paper: float | None = None
    """The paper's difference (first − second), in the metric's units, where it gives one."""


@dataclasses.dataclass(frozen=True)
class Claim:
    """One claim of the paper (or a question of ours) as comparisons between rows."""

    key: str
    """Short identifier (``claims.csv``)."""
    text: str
    """The claim in words."""
    paper: str
    """What the paper reports."""
    kind: Literal["better", "equivalent"]
    """``better``: every ``first`` beats its ``second``; ``equivalent``: within ±δ."""
    comparisons: tuple[Comparison, ...]
    """All must hold for the claim to be reproduced."""


def _at_densities(
    first: PolicyLabel, second: PolicyLabel, paper: tuple[float | None, ...] = (None,) * 3
) -> tuple[Comparison, ...]:
    return tuple(
        Comparison(first, second, "success", d, p)
        for d, p in zip((0.5, 0.75, 1.0), paper, strict=True)
    )


def _acting_control(key: str, how: str, eps: float) -> Claim:
    """Ours: Pr-IQN* against IQN and Ensemble-IQN acting near-greedily at ``eps``."""
    return Claim(
        key,
        f"Ours: Pr-IQN* still beats IQN and Ensemble-IQN when they, too, {how}",
        "— (the paper's baselines act greedily)",
        "better",
        _at_densities(PR_IQN_STAR, near_greedy(IQN, eps))
        + _at_densities(PR_IQN_STAR, near_greedy(ENSEMBLE, eps)),
    )


PAPER_ROWS: tuple[PolicyLabel, ...] = (
    IQN,
    ENSEMBLE,
    MA_IQN,
    pr_iqn("mv", True, 0.4),
    pr_iqn("cvar", True, 0.4),
    pr_iqn("qd", False, 0.4),
    pr_iqn("qd", True, 0.4),
    pr_iqn("qd", False, 0.2),
    PR_IQN_STAR,
    pr_iqn("qd", False, 0.2, True),
    pr_iqn("qd", True, 0.2, True),
)
"""The paper's 11 Table II rows."""

CLAIMS: tuple[Claim, ...] = (
    Claim(
        "star-vs-iqn",
        "Pr-IQN* has a higher success rate than IQN at every density",
        "+7.7 / +16.6 / +20.3 points at 0.5 / 0.75 / 1.0",
        "better",
        _at_densities(PR_IQN_STAR, IQN, (0.077, 0.166, 0.203)),
    ),
    Claim(
        "star-vs-ensemble",
        "Pr-IQN* has a higher success rate than Ensemble-IQN at every density",
        "+11.0 / +14.7 / +13.9 points at 0.5 / 0.75 / 1.0",
        "better",
        _at_densities(PR_IQN_STAR, ENSEMBLE, (0.110, 0.147, 0.139)),
    ),
    Claim(
        "ma-iqn-worst",
        "MA-IQN has the lowest success rate of the paper's rows (mean over densities)",
        "lowest row of Table II",
        "better",
        tuple(Comparison(row, MA_IQN) for row in PAPER_ROWS if row != MA_IQN),
    ),
    Claim(
        "qd-mv-cvar",
        "QD > MV > CVaR (training preorder, ε 0.4; mean over densities)",
        "QD best, CVaR worst",
        "better",
        (
            Comparison(pr_iqn("qd", True, 0.4), pr_iqn("mv", True, 0.4)),
            Comparison(pr_iqn("mv", True, 0.4), pr_iqn("cvar", True, 0.4)),
        ),
    ),
    Claim(
        "eps-0.2",
        "ε 0.2 beats ε 0.4 (QD, training preorder off and on; mean over densities)",
        "ε 0.2 better",
        "better",
        (
            Comparison(pr_iqn("qd", False, 0.2), pr_iqn("qd", False, 0.4)),
            Comparison(PR_IQN_STAR, pr_iqn("qd", True, 0.4)),
        ),
    ),
    Claim(
        "training-preorder",
        "The training preorder helps (QD ε 0.2, total order)",
        "+3.3 / +2.5 points at 0.75 / 1.0",
        "better",
        (
            Comparison(PR_IQN_STAR, pr_iqn("qd", False, 0.2), "success", 0.75, 0.033),
            Comparison(PR_IQN_STAR, pr_iqn("qd", False, 0.2), "success", 1.0, 0.025),
        ),
    ),
    Claim(
        "partial-trained",
        "With the training preorder, the partial order is comparable to the total order",
        "comparable",
        "equivalent",
        (Comparison(pr_iqn("qd", True, 0.2, True), PR_IQN_STAR),),
    ),
    Claim(
        "partial-untrained",
        "Without the training preorder, the partial order is worse than the total order",
        "worse",
        "better",
        (Comparison(pr_iqn("qd", False, 0.2), pr_iqn("qd", False, 0.2, True)),),
    ),
    Claim(
        "table1",
        "Table I: Pr-IQN* has higher safety, risk and lane-keeping returns than IQN",
        "gains on all three",
        "better",
        tuple(
            Comparison(PR_IQN_STAR, IQN, f"return_{name}")
            for name in ("safety", "risk", "lane_keeping")
        ),
    ),
    _acting_control(
        "ours-acting-control",
        "act at random among their near-best actions (near-greedy ε 0.2, Pr-IQN*'s tolerance)",
        0.2,
    ),
    _acting_control(
        "ours-acting-control-matched",
        "act as randomly as Pr-IQN* (near-greedy ε 0.005: a mean set of about 1.2 actions, "
        "as Pr-IQN*'s leaf)",
        0.005,
    ),
    Claim(
        "ours-fsd",
        "Ours: the distributional fsd comparator beats QD (Pr-IQN*, mean over densities)",
        "— (not in the paper)",
        "better",
        (Comparison(pr_iqn("fsd"), PR_IQN_STAR),),
    ),
    Claim(
        "ours-scaled",
        "Ours: the scale-aware normalisation beats the paper's (Pr-IQN*, mean over densities)",
        "— (not in the paper)",
        "better",
        (Comparison(pr_iqn(extra=("scaled",)), PR_IQN_STAR),),
    ),
    Claim(
        "ours-untrained-qd-0.2",
        "Ours, exploratory (registered after seeds 0–1, before any seed-2 cell ran): Pr-IQN "
        "QD ε 0.2 without the training preorder has a higher success rate than IQN and "
        "Ensemble-IQN at every density",
        "— (the paper's best row trains with the preorder)",
        "better",
        _at_densities(pr_iqn("qd", False, 0.2), IQN)
        + _at_densities(pr_iqn("qd", False, 0.2), ENSEMBLE),
    ),
)
"""The claims checked by every report that holds their rows (docs/results.md)."""


@dataclasses.dataclass(frozen=True)
class ComparisonResult:
    """One comparison measured: difference of means and its bootstrap CI."""

    comparison: Comparison
    diff: float
    """mean(first) − mean(second)."""
    lo: float
    hi: float
    outcome: str
    """``holds``, ``contradicted`` or ``unclear``."""
    seed_lo: float
    seed_hi: float
    """Welch t 95 % interval of first − second over training seeds only (second look)."""
    seed_outcome: str
    """The rule's outcome on ``[seed_lo, seed_hi]``."""
    seeds_needed: int | None
    """Training seeds per row to see the paper's difference (None: the paper gives none)."""


@dataclasses.dataclass(frozen=True)
class ClaimResult:
    """A claim's verdict and the comparisons behind it (empty while pending)."""

    claim: Claim
    verdict: str
    """``reproduced``, ``not reproduced``, ``inconclusive at this budget`` or ``pending``."""
    why: str
    """For ``pending``: what is missing; otherwise empty."""
    results: tuple[ComparisonResult, ...] = ()
    missing: tuple[str, ...] = ()
    """Rows of the claim with no evaluated runs in the report."""

    @property
    def seed_verdict(self) -> str:
        """The verdict the rule gives on the seeds-only t-intervals (the second look)."""
        if not self.results:
            return self.verdict
        return verdict([r.seed_outcome for r in self.results])


def run_means(episodes: pd.DataFrame, label: str, metric: str, density: float | None) -> np.ndarray:
    """``scores_SR``: mean of ``metric`` per (training seed, evaluation run) of one policy.

    Rows are the policy's training seeds, columns its evaluation runs (both sorted); the
    mean is over every net and episode at ``density`` (None: every density). A one-line
    PriqnError when the seeds do not all have the same evaluation runs.
    """
    rows = episodes[episodes["label"] == label]
    if density is not None:
        rows = rows[np.isclose(rows["density"].astype(float), density)]
    table = rows.groupby(["train_seed", "eval_run"])[metric].mean().astype(float).unstack()
    if table.isna().any().any():
        raise PriqnError(f"{label}: training seeds were evaluated on different evaluation runs")
    return table.sort_index().sort_index(axis=1).to_numpy()


def bootstrap_means(scores_SR: np.ndarray, reps: int, rng: np.random.Generator) -> np.ndarray:
    """``[reps]`` two-level bootstrap means: draw seeds, then evaluation runs within each."""
    S, R = scores_SR.shape
    seeds_BS = rng.integers(S, size=(reps, S))
    runs_BSR = rng.integers(R, size=(reps, S, R))
    return scores_SR[seeds_BS[:, :, None], runs_BSR].mean(axis=(1, 2))


def seed_interval(first_SR: np.ndarray, second_SR: np.ndarray) -> tuple[float, float]:
    """Welch t 95 % interval of mean(first) − mean(second) over training seeds only.

    Each training seed counts once, as its mean over evaluation runs; the two rows'
    seeds are independent samples with unequal variances (Welch-Satterthwaite degrees of
    freedom). Seeds that agree exactly give a zero-width interval.
    """
    a_S, b_S = first_SR.mean(axis=1), second_SR.mean(axis=1)
    var_a, var_b = a_S.var(ddof=1) / a_S.size, b_S.var(ddof=1) / b_S.size
    diff = float(a_S.mean() - b_S.mean())
    se2 = var_a + var_b
    if se2 == 0:
        return diff, diff
    dof = se2**2 / (var_a**2 / (a_S.size - 1) + var_b**2 / (b_S.size - 1))
    half = float(scipy_stats.t.ppf(0.975, dof)) * math.sqrt(se2)
    return diff - half, diff + half


def seeds_needed(first_SR: np.ndarray, second_SR: np.ndarray, effect: float) -> int:
    """Training seeds per row for a two-sided 5 % test to see ``effect`` with POWER.

    Normal approximation with our seed-to-seed standard deviations ``s`` (of the per-seed
    means): n = ⌈(z₀.₉₇₅ + z_POWER)² (s_first² + s_second²) / effect²⌉, at least MIN_SEEDS.
    With 3 seeds each ``s`` is itself uncertain: an order of magnitude, not a plan.
    """
    spread = first_SR.mean(axis=1).var(ddof=1) + second_SR.mean(axis=1).var(ddof=1)
    z = scipy_stats.norm.ppf(0.975) + scipy_stats.norm.ppf(POWER)
    return max(MIN_SEEDS, math.ceil(z**2 * spread / effect**2))


def outcome(kind: str, lo: float, hi: float, margin: float) -> str:
    """``holds`` / ``contradicted`` / ``unclear`` for a CI [lo, hi] of first − second."""
    if kind == "equivalent":
        if -margin < lo and hi < margin:
            return "holds"
        return "contradicted" if (lo > 0 or hi < 0) else "unclear"
    if lo > 0:
        return "holds"
    if hi < 0 or (-margin < lo and hi < margin):
        return "contradicted"
    return "unclear"


def verdict(outcomes: list[str]) -> str:
    """A claim's verdict from its comparisons' outcomes (rule in the module docstring)."""
    if all(o == "holds" for o in outcomes):
        return "reproduced"
    if any(o == "contradicted" for o in outcomes):
        return "not reproduced"
    return "inconclusive at this budget"


def evaluate_claim(
    claim: Claim, episodes: pd.DataFrame, reps: int = 2000, seed: int = 0
) -> ClaimResult:
    """Measure every comparison of ``claim`` on ``episodes`` and give its verdict."""
    seeds = episodes.groupby("label")["train_seed"].nunique()
    labels = sorted(
        {c.first.render() for c in claim.comparisons}
        | {c.second.render() for c in claim.comparisons}
    )
    missing = tuple(label for label in labels if label not in seeds.index)
    if missing:
        why = f"no evaluated runs of {', '.join(missing)}"
        return ClaimResult(claim, "pending", why, missing=missing)
    few = [f"{label} ({seeds[label]})" for label in labels if seeds[label] < MIN_SEEDS]
    if few:
        return ClaimResult(
            claim, "pending", f"fewer than {MIN_SEEDS} training seeds: {', '.join(few)}"
        )
    matrices = []
    for c in claim.comparisons:
        pair = [
            run_means(episodes, row.render(), c.metric, c.density) for row in (c.first, c.second)
        ]
        if any(m.size == 0 for m in pair):
            return ClaimResult(claim, "pending", f"no episodes at density {c.density:g}")
        matrices.append(pair)
    rng = np.random.default_rng(seed)
    results = []
    for c, (first, second) in zip(claim.comparisons, matrices, strict=True):
        diff_B = bootstrap_means(first, reps, rng) - bootstrap_means(second, reps, rng)
        lo, hi = (float(q) for q in np.percentile(diff_B, [2.5, 97.5]))
        diff = float(first.mean() - second.mean())
        margin = EQUIVALENCE_MARGIN.get(c.metric, 0.0)
        seed_lo, seed_hi = seed_interval(first, second)
        results.append(
            ComparisonResult(
                c,
                diff,
                lo,
                hi,
                outcome(claim.kind, lo, hi, margin),
                seed_lo,
                seed_hi,
                outcome(claim.kind, seed_lo, seed_hi, margin),
                None if c.paper is None else seeds_needed(first, second, c.paper),
            )
        )
    return ClaimResult(claim, verdict([r.outcome for r in results]), "", tuple(results))


def evaluate_claims(
    episodes: pd.DataFrame, reps: int = 2000, seed: int = 0, claims: tuple[Claim, ...] = CLAIMS
) -> list[ClaimResult]:
    """Every claim on ``episodes``, in order (claims whose rows are missing: pending)."""
    return [evaluate_claim(claim, episodes, reps, seed) for claim in claims]


def _fmt(value: float, metric: str) -> str:
    """Success rates in points (+7.7), returns as they are (+0.42)."""
    if metric == "success":
        return f"{100 * value:+.1f}"
    return f"{value:+.2f}"


def _where(c: Comparison) -> str:
    at = "all densities" if c.density is None else f"d {c.density:g}"
    metric = "SR" if c.metric == "success" else c.metric.removeprefix("return_")
    return f"{c.first.render()} − {c.second.render()}, {metric}, {at}"


def to_markdown(results: list[ClaimResult], reps: int, seed: int) -> str:
    """The claims section of the report: a line per claim whose rows are all evaluated.

    Claims with rows missing from the report are named in one sentence below the table.
    """
    lines = [
        "| claim | paper | ours: difference [95% CI] | verdict |",
        "|:--|:--|:--|:--|",
    ]
    for r in results:
        if r.missing:
            continue
        if r.verdict == "pending":
            ours = f"pending: {r.why}"
        else:
            ours = "<br>".join(
                f"{_where(x.comparison)}: {_fmt(x.diff, x.comparison.metric)} "
                f"[{_fmt(x.lo, x.comparison.metric)}, {_fmt(x.hi, x.comparison.metric)}] "
                f"({x.outcome})"
                for x in r.results
            )
        lines.append(f"| {r.claim.text} | {r.claim.paper} | {ours} | **{r.verdict}** |")
    margins = ", ".join(f"{m} ±{100 * d:g} points" for m, d in EQUIVALENCE_MARGIN.items())
    lines += [
        "",
        "Success-rate differences in points, returns in their own units. CIs: two-level "
        f"bootstrap (training seeds, then evaluation runs within a seed), {reps} "
        f"replications, `numpy.random.default_rng({seed})`. Rule (fixed before the data, "
        "`priqn/analysis/claims.py`): a comparison holds when its CI is on the claimed side "
        "of 0, and is contradicted when its CI is on the other side or straddles 0 within ±δ "
        f"({margins}); "
        "reproduced = all hold, not reproduced = any contradicted, otherwise inconclusive at "
        f"this budget; pending while a row is missing or has fewer than {MIN_SEEDS} "
        "training seeds.",
        "",
    ]
    lines += _second_look(results)
    unchecked = [r.claim.key for r in results if r.missing]
    if unchecked:
        lines += [f"Not checked here (rows not in this report): {', '.join(unchecked)}.", ""]
    return "\n".join(lines)


def _second_look(results: list[ClaimResult]) -> list[str]:
    """Markdown lines: every measured comparison with its seeds-only t-interval."""
    measured = [r for r in results if r.results]
    if not measured:
        return []
    lines = [
        "**A second look, not the rule: training seeds only.** With this few training "
        "seeds the seed bootstrap is too narrow, so each comparison also gets a Welch "
        "t 95 % CI over the per-seed means (evaluation runs averaged) and the rule's "
        f"outcome on it; the last column is the training seeds per row that would see the "
        f"paper's difference with {100 * POWER:g} % power at our seed-to-seed spread (an "
        "order of magnitude: the spread itself comes from few seeds).",
        "",
        "| comparison | difference | bootstrap CI (rule) | t CI, seeds only | outcome, seeds "
        "only | seeds per row for the paper's difference |",
        "|:--|--:|:--|:--|:--|--:|",
    ]
    for r in measured:
        for x in r.results:
            m = x.comparison.metric
            lines.append(
                f"| {_where(x.comparison)} | {_fmt(x.diff, m)} | [{_fmt(x.lo, m)}, "
                f"{_fmt(x.hi, m)}] ({x.outcome}) | [{_fmt(x.seed_lo, m)}, {_fmt(x.seed_hi, m)}] "
                f"| {x.seed_outcome} | {'–' if x.seeds_needed is None else x.seeds_needed} |"
            )
    changed = [
        f"{r.claim.key} ({r.verdict} → {r.seed_verdict})"
        for r in measured
        if r.seed_verdict != r.verdict
    ]
    lines += [
        "",
        "Verdicts the second look would change: "
        + (", ".join(changed) if changed else "none")
        + ".",
        "",
    ]
    return lines


def to_frame(results: list[ClaimResult]) -> pd.DataFrame:
    """One row per comparison (pending claims: one row with the reason)."""
    rows = []
    for r in results:
        base = {"claim": r.claim.key, "verdict": r.verdict, "why": r.why}
        if not r.results:
            rows.append(base)
        for x in r.results:
            c = x.comparison
            rows.append(
                {
                    **base,
                    "first": c.first.render(),
                    "second": c.second.render(),
                    "metric": c.metric,
                    "density": c.density,
                    "paper": c.paper,
                    "diff": x.diff,
                    "ci_lo": x.lo,
                    "ci_hi": x.hi,
                    "outcome": x.outcome,
                    "seed_ci_lo": x.seed_lo,
                    "seed_ci_hi": x.seed_hi,
                    "seed_outcome": x.seed_outcome,
                    "seed_verdict": r.seed_verdict,
                    "seeds_needed": x.seeds_needed,
                }
            )
    columns = ["claim", "verdict", "why", "first", "second", "metric", "density", "paper"]
    measured = ["diff", "ci_lo", "ci_hi", "outcome"]
    second_look = ["seed_ci_lo", "seed_ci_hi", "seed_outcome", "seed_verdict", "seeds_needed"]
    frame = pd.DataFrame(rows, columns=[*columns, *measured, *second_look])
    return frame.astype({"seeds_needed": "Int64"})
