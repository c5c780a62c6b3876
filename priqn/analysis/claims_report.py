"""The claims section of a report: its Markdown and ``tables/claims.csv``.

Renders the :class:`priqn.analysis.claims.ClaimResult` list of
:func:`priqn.analysis.claims.evaluate_claims`; the claims' forest plot is
:func:`priqn.analysis.figures.claims_figure`.
"""

from __future__ import annotations

import math
from fractions import Fraction

import pandas as pd

from priqn.analysis import inference
from priqn.analysis.claims import ALPHA, MIN_SEEDS, ClaimResult, Comparison


def _fmt(value: float, metric: str) -> str:
    """Success rates in points (+7.7), returns as they are (+0.42)."""
    if math.isinf(value):
        return "∞"
    if metric == "success":
        return f"{100 * value:+.1f}"
    return f"{value:+.2f}"


def _p(value: Fraction | float | None) -> str:
    return "–" if value is None else f"{float(value):.3g}"


def _where(c: Comparison) -> str:
    at = "endpoint" if c.density is None else f"d {c.density:g}"
    metric = "SR" if c.metric == "success" else c.metric.removeprefix("return_")
    return f"{c.first.render()} − {c.second.render()}, {metric}, {at}"


def to_markdown(results: list[ClaimResult], seed: int) -> str:
    """The claims section of the report: one table of the primary comparisons, one of the
    descriptive per-density differences; claims with rows missing named below."""
    lines = [
        "| claim | paper | comparison (endpoint) | ours: difference [95% CI], seeds | p raw / Holm "
        "(min p) | MDD | seeds for paper's | verdict |",
        "|:--|:--|:--|:--|:--|--:|--:|:--|",
    ]
    for r in results:
        if r.missing:
            continue
        if r.verdict == "pending":
            lines.append(f"| {r.claim.text} | {r.claim.paper} | pending: {r.why} | | | | | |")
            continue
        for i, x in enumerate(r.results):
            c, m = x.comparison, x.comparison.metric
            head = (r.claim.text, r.claim.paper) if i == 0 else ("", "")
            verdict = f"{x.word}" + (f"; claim: **{r.verdict}**" if i == len(r.results) - 1 else "")
            lines.append(
                f"| {head[0]} | {head[1]} | {_where(c)} | {_fmt(x.diff, m)} [{_fmt(x.lo, m)}, "
                f"{_fmt(x.hi, m)}], {x.n_first} vs {x.n_second} | {_p(x.p)} / {_p(x.p_holm)} "
                f"({_p(x.min_p)}) | {_fmt(x.mdd, m) if x.mdd is not None else '–'} | "
                f"{'–' if x.seeds_needed is None else x.seeds_needed} | {verdict} |"
            )
    lines += [
        "",
        "Endpoint: the metric averaged over the evaluation densities, one score per training "
        "seed. Differences in success-rate points (returns in their own units); 95 % Welch t "
        "intervals over training seeds; p: the larger of an exact two-sided permutation test "
        f"over seeds (Monte Carlo above {inference.EXACT_SPLITS:,} splits, "
        f"`numpy.random.default_rng({seed})`) and Welch's t test (tables/claims.csv has both), "
        "Holm-adjusted within its family (the paper's claims; ours); min p: the smallest p "
        "the test can give at these seeds. MDD: the minimum detectable difference at 80 % "
        "power and the comparison's Holm level (∞: the test cannot reach it at these seeds); "
        "seeds for paper's: seeds per row to see the paper's difference at the measured "
        f"spread. Verdicts (`priqn/analysis/inference.py`, α = {ALPHA:g} per family): "
        "reproduced / contradicted = significant after Holm in / against the claimed "
        "direction; paper's effect ruled out = not significant and the one-sided upper bound "
        "at α / m (Bonferroni over the family's m comparisons, so it holds for all of them at "
        "once) below the paper's difference; equivalent = Holm-adjusted TOST within the claim's "
        f"margin; otherwise inconclusive. Pending: a row missing or with fewer than {MIN_SEEDS} "
        "training seeds.",
        "",
    ]
    lines += _density_table(results)
    unchecked = [r.claim.key for r in results if r.missing]
    if unchecked:
        lines += [f"Not checked here (rows not in this report): {', '.join(unchecked)}.", ""]
    return "\n".join(lines)


def _density_table(results: list[ClaimResult]) -> list[str]:
    """Markdown lines: the descriptive per-density differences (no verdicts)."""
    rows = [x for r in results for x in r.by_density]
    if not rows:
        return []
    lines = [
        "Per density, descriptive only (the densities of a training seed move together, "
        "so these are not independent tests and decide nothing):",
        "",
        "| comparison | paper | difference [95% CI] |",
        "|:--|--:|:--|",
    ]
    for x in rows:
        c, m = x.comparison, x.comparison.metric
        paper = "–" if c.paper is None else _fmt(c.paper, m)
        lines.append(
            f"| {_where(c)} | {paper} | {_fmt(x.diff, m)} [{_fmt(x.lo, m)}, {_fmt(x.hi, m)}] |"
        )
    return [*lines, ""]


FRAME_COLUMNS: tuple[str, ...] = (
    "claim",
    "family",
    "verdict",
    "why",
    "role",
    "first",
    "second",
    "metric",
    "density",
    "paper",
    "diff",
    "ci_lo",
    "ci_hi",
    "n_first",
    "n_second",
    "p_permutation",
    "p_welch",
    "p",
    "p_holm",
    "min_p",
    "alpha_holm",
    "hi_family",
    "tost_p_holm",
    "mdd",
    "seeds_needed",
    "word",
)
"""Columns of ``tables/claims.csv``."""


def to_frame(results: list[ClaimResult]) -> pd.DataFrame:
    """One row per comparison: ``role`` primary (decides) or descriptive (per density);
    pending claims: one row with the reason."""
    rows = []
    for r in results:
        base = {
            "claim": r.claim.key,
            "family": r.claim.family,
            "verdict": r.verdict,
            "why": r.why,
        }
        if not r.results:
            rows.append(base)
        for role, items in (("primary", r.results), ("descriptive", r.by_density)):
            for x in items:
                c = x.comparison
                rows.append(
                    {
                        **base,
                        "role": role,
                        "first": c.first.render(),
                        "second": c.second.render(),
                        "metric": c.metric,
                        "density": c.density,
                        "paper": c.paper,
                        "diff": x.diff,
                        "ci_lo": x.lo,
                        "ci_hi": x.hi,
                        "n_first": x.n_first,
                        "n_second": x.n_second,
                        "p_permutation": None if x.p is None else float(x.p_permutation),
                        "p_welch": x.p_welch,
                        "p": None if x.p is None else float(x.p),
                        "p_holm": None if x.p_holm is None else float(x.p_holm),
                        "min_p": None if x.min_p is None else float(x.min_p),
                        "alpha_holm": x.alpha_holm,
                        "hi_family": x.hi_family,
                        "tost_p_holm": x.tost_p_holm,
                        "mdd": x.mdd,
                        "seeds_needed": x.seeds_needed,
                        "word": x.word,
                    }
                )
    frame = pd.DataFrame(rows, columns=list(FRAME_COLUMNS))
    return frame.astype({"seeds_needed": "Int64", "n_first": "Int64", "n_second": "Int64"})
