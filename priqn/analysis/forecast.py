"""How likely a sequential design is to decide, given the seeds it has: a simulation.

For planning only: nothing here enters a look, a decision or a verdict. The committed
seeds are kept as they are; the seeds still to train (up to the design's last look) are
drawn per row from a normal with the row's committed standard deviation over seeds,
clipped to the endpoint's range [0, 1], around a mean set by a **scenario**:

- ``observed``: each row's committed mean (the estimates so far are the truth);
- ``paper``: for every comparison with a ``paper_difference``, row ``b`` sits that far
  below row ``a``'s committed mean (the paper's differences are the truth), the other
  rows at their committed means.

AdaStop's looks are then taken on each completed data set exactly as the report takes them
(:func:`priqn.analysis.sequential.take_looks`), with ``permutations`` draws instead of the
design's for time. Arrays: ``scores_S`` per row, seeds in look order.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pandas as pd

from priqn.analysis import sequential
from priqn.errors import PriqnError
from priqn.experiment import SequentialSpec

SCENARIOS: tuple[str, ...] = ("observed", "paper")
"""The scenarios :func:`forecast` simulates, in order."""

PERMUTATIONS: int = 2000
"""AdaStop's B at each look of a simulated experiment. With n = 5 a look has only 252
splits, so any B above that gives the design's own permutation sets (docs/statistics.md)."""

SCENARIO_TEXT: dict[str, str] = {
    "observed": "if each row's mean so far is its true mean",
    "paper": "if the paper's differences are true (b = a's mean so far - the paper's difference)",
}
"""One line per scenario, for printing."""

FORECAST_COLUMNS: tuple[str, ...] = (
    "scenario",
    "comparison",
    "verdict",
    "share",
    "mean_seeds",
    "sims",
)
"""One row per (scenario, comparison, verdict word reached): the share of the simulated
experiments that ended with that pre-registered verdict
(:func:`priqn.analysis.sequential.verdict`), and the mean seeds per row the comparison
took over all of them (decided early: fewer)."""


def scenarios_for(design: SequentialSpec) -> tuple[str, ...]:
    """The :data:`SCENARIOS` that apply to ``design``: ``paper`` only where a comparison
    has a paper difference."""
    if any(c.paper_difference is not None for c in design.comparisons):
        return SCENARIOS
    return ("observed",)


def scenario_means(
    design: SequentialSpec, observed: dict[str, float], scenario: str
) -> dict[str, float]:
    """Row -> the mean its future seeds are drawn around under ``scenario``."""
    if scenario == "observed":
        return dict(observed)
    if scenario != "paper":
        raise PriqnError(f"forecast scenario {scenario!r}: expected one of {list(SCENARIOS)}")
    means, pinned = dict(observed), set()
    for c in design.comparisons:
        if c.paper_difference is not None and c.b not in pinned:
            means[c.b] = observed[c.a] - c.paper_difference
            pinned.add(c.b)
    return means


def committed_rows(scores: pd.DataFrame, rows: list[str]) -> dict[str, np.ndarray]:
    """Row (of ``rows``) -> ``scores_S`` of its committed contiguous seeds
    (:func:`priqn.analysis.sequential.scores_by_policy`); a one-line PriqnError when a row
    has fewer than two (no spread to draw its future seeds with)."""
    have = sequential.scores_by_policy(scores, rows)
    few = [f"{r} ({v.size})" for r, v in have.items() if v.size < 2]
    if few:
        raise PriqnError(f"forecast: need at least 2 committed seeds per row: {', '.join(few)}")
    return have


def forecast(
    design: SequentialSpec,
    have: dict[str, np.ndarray],
    sims: int = 200,
    permutations: int = PERMUTATIONS,
    seed: int = 0,
    on_sim: Callable[[], None] | None = None,
) -> pd.DataFrame:
    """:data:`FORECAST_COLUMNS` for every scenario of :func:`scenarios_for` and comparison
    (see the module docstring), in the design's verdict words.

    ``have``: every row of the design -> its committed ``scores_S`` (:func:`committed_rows`:
    at least two seeds each, for the spread). ``seed`` seeds the draws and the
    permutations; ``on_sim`` is called once per simulated experiment (a progress bar)."""
    observed = {r: float(v.mean()) for r, v in have.items()}
    sd = {r: float(v.std(ddof=1)) for r, v in have.items()}
    cap, cap_look = design.interims[-1], len(design.interims)
    rng = np.random.default_rng(seed)
    out = []
    for scenario in scenarios_for(design):
        means = scenario_means(design, observed, scenario)
        verdicts: dict[str, dict[str, int]] = {c.name: {} for c in design.comparisons}
        seeds_used = dict.fromkeys(verdicts, 0)
        for i in range(sims):
            completed = {r: _completed(have[r], means[r], sd[r], cap, rng) for r in have}
            run = dataclasses.replace(design, permutations=permutations, seed=seed + i)
            result = sequential.take_looks(run, completed)
            last = {c.name: c for c in result.looks[-1].comparisons}
            for c in design.comparisons:
                word = sequential.verdict(run, result, c)
                verdicts[c.name][word] = verdicts[c.name].get(word, 0) + 1
                seeds_used[c.name] += design.interims[(last[c.name].decided_at or cap_look) - 1]
            if on_sim is not None:
                on_sim()
        out += [
            {
                "scenario": scenario,
                "comparison": name,
                "verdict": word,
                "share": n / sims,
                "mean_seeds": seeds_used[name] / sims,
                "sims": sims,
            }
            for name, counts in verdicts.items()
            for word, n in sorted(counts.items(), key=lambda kv: -kv[1])
        ]
    return pd.DataFrame(out, columns=list(FORECAST_COLUMNS))


def _completed(
    scores_S: np.ndarray, mean: float, sd: float, cap: int, rng: np.random.Generator
) -> np.ndarray:
    """A row's committed seeds followed by draws up to ``cap`` seeds, clipped to [0, 1]."""
    drawn = np.clip(rng.normal(mean, sd, max(0, cap - scores_S.size)), 0.0, 1.0)
    return np.concatenate([scores_S, drawn])
