"""AdaStop taken look by look on a pre-registered design's per-seed scores.

A design (:class:`priqn.experiment.SequentialSpec`: a ``[sequential]`` table or a
``[[question]]``) is read from the experiment file; its cells' scores are collected by
:mod:`priqn.analysis.questions`. This module holds what is left once the scores are in:

1. :func:`take_looks` takes the design and each row's ``scores_S`` and runs **AdaStop**
   look by look: each family gets its own ``adastop.MultipleAgentsComparator`` with the
   design's n, K, B, α, β and seed, and look k is taken once every row still in an open
   comparison has its first k·n seeds — the decisions are a pure function of the
   committed scores, so a report regenerates them exactly;
2. :func:`verdict` gives each comparison its pre-registered **verdict word**.

Arrays: ``scores_S`` is one row's per-seed scores in look order (position 0 first).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from priqn.analysis import inference
from priqn.errors import PriqnError
from priqn.experiment import ComparisonSpec, SequentialSpec

DECISIONS: tuple[str, ...] = ("larger", "smaller", "equal", "continue")
"""AdaStop's decision words for ``a`` vs ``b``: a larger, a smaller, not different (only at
the last look with β = 0), or undecided yet."""


def relative_path(path: Path) -> str:
    """``path`` relative to the working directory when inside it (reports stay portable)."""
    try:
        return str(Path(path).absolute().relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def scores_by_policy(scores: pd.DataFrame, policies: list[str]) -> dict[str, np.ndarray]:
    """Row -> ``scores_S`` of its *contiguous* positions 0, 1, ... (a gap ends the run);
    ``scores``: columns ``policy`` (the row or group) and ``seed`` (the position)."""
    out = {}
    for policy in policies:
        mine = scores[scores["policy"] == policy].set_index("seed")["score"]
        n = 0
        while n in mine.index:
            n += 1
        out[policy] = mine.reindex(range(n)).to_numpy(dtype=float)
    return out


@dataclasses.dataclass(frozen=True)
class ComparisonLook:
    """One comparison at one look."""

    name: str
    family: str
    a: str
    b: str
    n_a: int
    n_b: int
    """Seeds of each row used at this look."""
    diff: float
    """mean(a) − mean(b) over those seeds."""
    lo: float
    hi: float
    """Welch 95 % interval of the difference (descriptive: not adjusted for the looks)."""
    hi_family: float
    """One-sided Welch upper bound at α / m (m: the family's comparisons), which decides
    "paper's effect ruled out" for a comparison AdaStop left undecided at the last look."""
    decision: str
    """AdaStop's decision after this look (:data:`DECISIONS`)."""
    decided_at: int | None
    """The look (1-based) at which it was decided; None while open."""


@dataclasses.dataclass(frozen=True)
class Look:
    """One interim analysis."""

    k: int
    """Look number, 1-based."""
    seeds_per_row: dict[str, int]
    """Seeds each row had in play at this look."""
    comparisons: tuple[ComparisonLook, ...]
    level_spent: dict[str, float]
    """Family -> α spent so far (AdaStop's linear spending: at most α k / K)."""
    needed: dict[str, float]
    """Family -> the |mean difference| (endpoint units) a comparison left open at this look
    had to exceed to be decided here: AdaStop's boundary over the k blocks, divided by k.
    ``inf`` when the look had too few splits to reject anything; absent once the family
    was finished at an earlier look."""


@dataclasses.dataclass(frozen=True)
class Looks:
    """The experiment as far as its committed cells go."""

    looks: tuple[Look, ...]
    """Looks taken, in order."""
    decisions: dict[str, str]
    """Comparison name -> decision after the last look taken."""
    finished: bool
    """Every comparison decided (or the last look taken)."""
    open_rows: tuple[str, ...]
    """Rows that still need seeds (in an open comparison)."""
    next_look: int | None
    """The next look (1-based) that needs cells; None when finished."""


def two_sided_comparator() -> type:
    """``adastop.MultipleAgentsComparator`` with its permutation distribution made two-sided.

    adastop 0.1.3 (and its repository's head, checked 2026-11-25) compares the statistic
    ``max |mean_a - mean_b|`` with the permutation distribution of the *signed* max
    ``max (mean_a - mean_b)``. For one comparison that distribution is symmetric, so the
    boundary sits at its 1 - α quantile where the two-sided test needs 1 - α / 2: every
    look rejects at about twice its level (the headline design's families: 11 % / 12 % of
    400 null data sets at α 0.05, 4.5 % / 4.75 % corrected). Here the distribution the
    boundary is read from is the max of the absolute differences, as in the AdaStop paper;
    the signed sums the later looks add to are kept (docs/statistics.md, "Sequential
    experiments").

    It also mends adastop's tail probabilities after the first look when a look has more
    splits than ``B`` (n ≥ 8 seeds a row a look at B 10,000: C(16, 8) = 12,870): the first
    look draws ``B`` random splits, but the later looks divide their counts by
    ``n_splits ** floor(log B / log n_splits)`` = 1 instead of ``B``. No level is then
    spent after the first look, and the boundary is the largest split sum, which no data
    exceed: the explain design's safety question at 60k (10 seeds a look) could decide
    only at its first look, and its last look would call "equal" whatever the data. Here
    those looks divide by ``B``, the number of random paths (docs/statistics.md). With
    n ≤ 7 (every look of the headline) nothing changes.
    """
    try:
        from adastop import MultipleAgentsComparator
    except ModuleNotFoundError:
        raise PriqnError(
            "the sequential design needs the adastop package: pip install adastop==0.1.3"
        ) from None

    class TwoSidedComparator(MultipleAgentsComparator):
        def compute_mean_diffs(self, k: int, Z: list) -> dict[str, np.ndarray]:  # noqa: N803
            signed = super().compute_mean_diffs(k, Z)  # kept in self.mean_diffs
            a, b = self.current_comparisons[0]  # every row has the same seeds a look
            if math.comb(self.n[a] + self.n[b], self.n[a]) > self.B:  # random from look 1
                self.normalization = self.B
            return {comp: np.abs(np.asarray(d)) for comp, d in signed.items()}

    return TwoSidedComparator


def _family_comparator(
    design: SequentialSpec, comparisons: list[ComparisonSpec]
) -> tuple[Any, list[str]]:
    """A fresh (two-sided) AdaStop comparator of one family and its agent order."""
    MultipleAgentsComparator = two_sided_comparator()  # noqa: N806 - a class
    agents: list[str] = []
    for c in comparisons:
        for row in (c.a, c.b):
            if row not in agents:
                agents.append(row)
    pairs = np.array([(agents.index(c.a), agents.index(c.b)) for c in comparisons])
    comparator = MultipleAgentsComparator(
        n=design.seeds_per_look,
        K=len(design.interims),
        B=design.permutations,
        comparisons=pairs,
        alpha=design.alpha,
        beta=design.beta,
        seed=design.seed,
    )
    return comparator, agents


def take_looks(design: SequentialSpec, scores_S: dict[str, np.ndarray]) -> Looks:
    """AdaStop, look by look, on the committed scores (see the module docstring).

    ``scores_S``: every row (or group) of the design -> its scores in look order, contiguous
    from position 0 (:func:`scores_by_policy`); its keys, in order, are the rows the looks
    report (``Look.seeds_per_row``), and every row a comparison names must be among them."""
    import contextlib
    import io

    n, K = design.seeds_per_look, len(design.interims)
    families = design.families()
    state = {f: _family_comparator(design, cs) for f, cs in families.items()}
    decisions = {c.name: "continue" for c in design.comparisons}
    decided_at: dict[str, int] = {}
    looks: list[Look] = []
    for k in range(K):
        open_rows = _open_rows(design, decisions, list(scores_S))
        if not open_rows or any(len(scores_S[r]) < (k + 1) * n for r in open_rows):
            break
        level: dict[str, float] = {}
        needed: dict[str, float] = {}
        for family, comps in families.items():
            comparator, agents = state[family]
            if comparator.is_finished:
                level[family] = float(comparator.level_spent)
                continue
            values = {a: scores_S[a][: (k + 1) * n] for a in agents}
            with contextlib.redirect_stdout(io.StringIO()):  # adastop prints "Step k"
                comparator.partial_compare(values, verbose=False)
            for c, pair in zip(comps, comparator.comparisons, strict=True):
                word = comparator.decisions[str(pair)]
                if word != "continue" and decisions[c.name] == "continue":
                    decided_at[c.name] = k + 1
                decisions[c.name] = word
            level[family] = float(comparator.level_spent)
            needed[family] = float(comparator.boundary[-1][1]) / (k + 1)
        seeds_now = {r: min(len(x), (k + 1) * n) for r, x in scores_S.items()}
        rows = _look_rows(design, scores_S, seeds_now, decisions, decided_at)
        looks.append(Look(k + 1, seeds_now, rows, level, needed))
    open_rows = _open_rows(design, decisions, list(scores_S))
    finished = not open_rows
    return Looks(
        tuple(looks),
        dict(decisions),
        finished,
        open_rows,
        None if finished else len(looks) + 1,
    )


def _open_rows(
    design: SequentialSpec, decisions: dict[str, str], rows: list[str]
) -> tuple[str, ...]:
    """The rows (in ``rows``' order) still in a comparison AdaStop has not decided."""
    still = {r for c in design.comparisons if decisions[c.name] == "continue" for r in (c.a, c.b)}
    return tuple(r for r in rows if r in still)


def _look_rows(
    design: SequentialSpec,
    scores_S: dict[str, np.ndarray],
    seeds_now: dict[str, int],
    decisions: dict[str, str],
    decided_at: dict[str, int],
) -> tuple[ComparisonLook, ...]:
    out = []
    for c in design.comparisons:
        a, b = scores_S[c.a][: seeds_now[c.a]], scores_S[c.b][: seeds_now[c.b]]
        lo, hi = inference.welch_interval(a, b)
        m = sum(x.family == c.family for x in design.comparisons)
        out.append(
            ComparisonLook(
                c.name,
                c.family,
                c.a,
                c.b,
                a.size,
                b.size,
                float(a.mean() - b.mean()),
                lo,
                hi,
                inference.upper_bound(a, b, design.alpha / m),
                decisions[c.name],
                decided_at.get(c.name),
            )
        )
    return tuple(out)


def verdict(design: SequentialSpec, result: Looks, comparison: ComparisonSpec) -> str:
    """The pre-registered verdict words of one comparison (headline.toml, "verdicts";
    explain.toml, "Questions and verdict words"): ``reproduced`` / ``contradicted`` /
    ``paper's effect ruled out`` / ``inconclusive at N seeds`` where the paper gives a
    difference; otherwise ``a better`` / ``a worse`` / ``no difference found at N seeds``,
    where for a violation rate (lower is better) ``a better`` is ``a violates more`` and
    ``a worse`` ``a violates less``; ``open: look k pending`` while undecided."""
    word = _verdict(result, comparison)
    if design.endpoint != "violation" or comparison.paper_difference is not None:
        return word
    return {"a better": "a violates more", "a worse": "a violates less"}.get(word, word)


def row_verdict(design: SequentialSpec, result: Looks, comparison: ComparisonSpec) -> str:
    """The verdict words (:func:`priqn.analysis.sequential.verdict`) as every report prints
    them: a comparison's first row by its name, not as ``a`` (``iqn better``,
    ``pr-iqn-qd-tp-eps0.2 violates more``)."""
    words = verdict(design, result, comparison)
    return comparison.a + words[1:] if words.startswith("a ") else words


def _verdict(result: Looks, comparison: ComparisonSpec) -> str:
    """:func:`verdict` in the success endpoint's words."""
    decision = result.decisions[comparison.name]
    look = result.looks[-1] if result.looks else None
    n = (
        0
        if look is None
        else min(look.seeds_per_row[comparison.a], look.seeds_per_row[comparison.b])
    )
    paper = comparison.paper_difference
    if decision == "larger":
        return "reproduced" if paper is not None else "a better"
    if decision == "smaller":
        return "contradicted" if paper is not None else "a worse"
    if decision == "continue":
        return f"open: look {result.next_look} pending"
    # "equal": not decided by the last look taken.
    if paper is not None and look is not None:
        row = next(x for x in look.comparisons if x.name == comparison.name)
        if row.hi_family < paper - inference.TIE_TOLERANCE:
            return "paper's effect ruled out"
        return f"inconclusive at {n} seeds"
    return f"no difference found at {n} seeds" if paper is None else f"inconclusive at {n} seeds"
