"""Outcome mixes: how a set of episodes ends, as shares per outcome and density.

A *mix* is, per evaluation density, the share of episodes ending in each of
:data:`~priqn.objectives.OUTCOMES` (one per episode); a row's mix is its seeds' shares
averaged (each seed's first); two mixes are compared by their L1 distance. The
calibration report (:mod:`priqn.analysis.calibration`) chooses a setting by it, and a
question report's outcome-mix section (:mod:`priqn.analysis.questions_outcomes`) sets
each row beside the paper's by it. The same policies played under two conditions (another
episode limit, traffic or family) are compared scene by scene (:func:`common_scenes`,
:func:`outcome_of`) and seed by seed (:func:`paired_changes` of
:func:`priqn.analysis.questions.seed_rates`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from priqn.analysis import inference
from priqn.analysis.load import read_episodes
from priqn.evaluation.protocol import SCENE_COLUMNS
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


def common_scenes(episodes: pd.DataFrame, by: str) -> pd.DataFrame:
    """Only each run's scenes played under every one of its conditions (column ``by``: the
    episode limit, the traffic; a longer limit may have played fewer, e.g. ``--eval-runs
    1``), so that every condition's mix is over the same scenes."""
    key = ["run", *SCENE_COLUMNS]
    conditions = episodes.groupby("run")[by].nunique()
    counts = episodes.groupby(key)[by].nunique().rename("played").reset_index()
    counts = counts[counts["played"] == counts["run"].map(conditions)]
    return episodes.merge(counts[key], on=key, how="inner")


def outcome_of(episodes: pd.DataFrame) -> pd.Series:
    """The one outcome of each episode (a name of :data:`OUTCOMES`)."""
    flags = episodes[list(OUTCOMES)].astype(bool)
    return flags.idxmax(axis=1).where(flags.any(axis=1), "timeout")


def paired_outcomes(base: pd.DataFrame, other: pd.DataFrame) -> pd.DataFrame:
    """Scene by scene (``run`` and :data:`SCENE_COLUMNS`), each scene's outcome in ``other``
    (``outcome``) beside its outcome in ``base`` (``outcome_base``) and ``base``'s
    ``label``: the scenes both played, in ``other``'s order (the same policies under two
    conditions; a traffic report's transitions, a horizon report's timeouts)."""
    key = ["run", *SCENE_COLUMNS]
    base = base.assign(outcome_base=outcome_of(base)).set_index(key)[["label", "outcome_base"]]
    other = other.assign(outcome=outcome_of(other)).set_index(key)[["outcome"]]
    return other.join(base, how="inner")


def mix_table(episodes: pd.DataFrame, by: str) -> pd.DataFrame:
    """``label, <by>, density, seeds`` and the share of each outcome, per row, condition
    (column ``by``) and density: per seed first, then the mean over the row's seeds."""
    frame = episodes.assign(**{o: episodes[o].astype(bool).astype(float) for o in OUTCOMES})
    keys = ["label", by, "density"]
    per_seed = frame.groupby([*keys, "train_seed"])[list(OUTCOMES)].mean()
    table = per_seed.groupby(keys).mean()
    table["seeds"] = per_seed.groupby(keys).size()
    return table.reset_index()[[*keys, "seeds", *OUTCOMES]]


def paired_changes(
    scores: pd.DataFrame, keys: list[str], where: tuple[str, str], endpoints: tuple[str, ...]
) -> pd.DataFrame:
    """Per group of ``keys`` (one row of policies): each endpoint under ``where[0]`` and
    ``where[1]`` (column ``where`` of ``scores``: one row per group, ``seed`` and condition),
    and the change ``where[1]`` − ``where[0]`` paired per training seed: its mean and 95 % t
    interval (:func:`~priqn.analysis.inference.mean_interval`), and the seeds."""
    wide = scores.pivot_table(index=[*keys, "seed"], columns="where", values=list(endpoints))
    rows = []
    for group, part in wide.groupby(level=keys if len(keys) > 1 else keys[0], sort=False):
        record: dict[str, Any] = dict(zip(keys, np.atleast_1d(group), strict=True))
        record["seeds"] = len(part)
        for endpoint in endpoints:
            change = (part[(endpoint, where[1])] - part[(endpoint, where[0])]).to_numpy()
            lo, hi = inference.mean_interval(change)
            record |= {
                f"{endpoint}_{i}": float(part[(endpoint, w)].mean())
                for i, w in zip(("in", "out"), where, strict=True)
            }
            record |= {f"{endpoint}_change": float(change.mean()),
                       f"{endpoint}_change_lo": lo, f"{endpoint}_change_hi": hi}  # fmt: skip
        rows.append(record)
    return pd.DataFrame(rows)
