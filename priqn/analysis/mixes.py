"""Outcome mixes: how a set of episodes ends, as shares per outcome and density.

A *mix* is, per evaluation density, the share of episodes ending in each of
:data:`~priqn.objectives.OUTCOMES` (one per episode); a row's mix is its seeds' shares
averaged (each seed's first); two mixes are compared by their L1 distance. The
calibration report (:mod:`priqn.analysis.calibration`) chooses a setting by it, and a
question report's outcome-mix section (:mod:`priqn.analysis.questions_outcomes`) sets
each row beside the paper's by it.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from priqn.analysis.load import read_episodes
from priqn.objectives import OUTCOMES


def cell_rates(eval_dir: str | Path) -> pd.DataFrame:
    """``float [densities x outcomes]``: the share of one evaluation's episodes ending in
    each outcome, per density (index sorted); each row sums to 1."""
    episodes = read_episodes(eval_dir)
    flags = episodes[list(OUTCOMES)].astype(bool).astype(float)
    return flags.groupby(episodes["density"].astype(float)).mean()


def mean_mix(mixes: pd.DataFrame, group: str = "row", seed: str = "seed") -> pd.DataFrame:
    """``rate`` averaged over each ``group``'s seeds (column ``seed``): one line per
    (``group``, outcome, density), in first-seen order, with ``seeds`` (how many). A
    question report's outcome mix is the same mean, by label and training seed."""
    grouped = mixes.groupby([group, "outcome", "density"], sort=False)
    return grouped.agg(rate=("rate", "mean"), seeds=(seed, "nunique")).reset_index()


def l1_by_outcome(
    have: dict[tuple[str, float], float], target: dict[tuple[str, float], float]
) -> dict[str, float]:
    """Per outcome of :data:`~priqn.objectives.OUTCOMES`, the L1 distance of ``have`` to
    ``target`` over the densities ``target`` gives (both ``(outcome, density) -> rate``;
    ``have`` has every key of ``target``). Their sum is a mix's distance."""
    return {o: sum(abs(have[k] - t) for k, t in target.items() if k[0] == o) for o in OUTCOMES}


def rates_of(lines: pd.DataFrame) -> dict[tuple[str, float], float]:
    """``(outcome, density) -> rate`` of mix lines (columns outcome, density, rate: one
    row's :func:`mean_mix` lines, or a question report's outcome mix)."""
    keys = zip(lines.outcome, lines.density.astype(float), strict=True)
    return dict(zip(keys, lines.rate.astype(float), strict=True))
