"""The calibration report: which row (setting) of a grid has the outcome mix nearest a target.

An experiment with a ``[calibration]`` table (:class:`priqn.experiment.CalibrationSpec`,
``priqn/data/experiments/calibrate.toml``) trains one policy under several settings and
chooses one by a rule fixed before its cells trained: a row's *mix* is, per evaluation
density, the share of its hold-out episodes ending in each of
:data:`~priqn.objectives.OUTCOMES` (one per episode), averaged over its training seeds
(each seed's rate first); its *distance* is the L1 distance of those numbers to the
target's; the chosen row has the smallest distance (a tie: the row first in the file).

Descriptive, as the rule is: no interval decides anything here. Pure functions of the
cells' ``eval/episodes.csv`` (:func:`cell_rates`, :func:`setting_mixes`,
:func:`distances`, :func:`choose`), then :func:`calibration_report` (kind ``calibration``,
sections rendered by :func:`priqn.analysis.artifacts.render`: ``report.md``, four CSVs in
``tables/``, a figure in ``figures/`` and ``meta.json``). How sure the choice is, beside
it: each seed's own distance (:func:`seed_distances`) and the rule applied again to
bootstrap resamples of each row's seeds (:func:`choice_bootstrap`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from priqn.analysis.mixes import cell_rates, l1_by_outcome, mean_mix, rates_of
from priqn.analysis.render import markdown_table
from priqn.analysis.sections import Report, Section
from priqn.errors import PriqnError
from priqn.experiment import CalibrationSpec, Experiment, check_code
from priqn.objectives import OUTCOMES
from priqn.run.evaluations import evaluated
from priqn.run.folder import RunFolder

MIX_COLUMNS = ("row", "traffic", "seed", "outcome", "density", "rate")
"""Columns of :func:`setting_mixes`: one row per (cell, outcome, density)."""

BOOTSTRAP_RESAMPLES = 10_000
"""Resamples of :func:`choice_bootstrap` in the report."""

BOOTSTRAP_SEED = 2026
"""Seed of the report's :func:`choice_bootstrap` generator (``numpy.random.default_rng``);
recorded in report.md and meta.json."""


def setting_mixes(exp: Experiment) -> tuple[pd.DataFrame, list[str]]:
    """Every complete cell's rates (columns :data:`MIX_COLUMNS`) and the cells not counted
    yet (``row__seed<k>: why``). A cell trained at a commit the calibration does not list,
    or from a dirty checkout, is a one-line error."""
    cal = _spec(exp)
    rows, missing = [], []
    for pol in exp.policies:
        for seed in exp.row_seeds(pol):
            run = RunFolder(exp.cell_dir(pol.name, seed))
            if not evaluated(run):
                missing.append(f"{run.path.name}: not complete")
                continue
            check_code(
                cal, str(run.meta().get("git_sha", "")), run.path, f"{exp.path} [calibration]"
            )
            rates = cell_rates(run.path / RunFolder.EVAL)
            for density, by_outcome in rates.iterrows():
                for outcome in OUTCOMES:
                    rows.append(
                        (pol.name, pol.traffic or "", seed, outcome, density, by_outcome[outcome])
                    )
    return pd.DataFrame(rows, columns=list(MIX_COLUMNS)), missing


def distances(mean: pd.DataFrame, cal: CalibrationSpec, order: list[str]) -> pd.DataFrame:
    """Per row (in ``order``, those with cells): ``l1`` to the target mix over every
    (outcome, density) the target gives, ``seeds``, and the four outcomes' parts of it.
    A row that lacks one of the target's densities is a one-line error."""
    target = cal.target_mix()
    out = []
    for row in order:
        mine = mean[mean["row"] == row]
        if mine.empty:
            continue
        have = rates_of(mine)
        lacking = [key for key in target if key not in have]
        if lacking:
            raise PriqnError(f"{row}: no episodes at density {lacking[0][1]} (the target has it)")
        parts = l1_by_outcome(have, target)
        out.append({"row": row, "l1": sum(parts.values()), "seeds": int(mine.seeds.min()), **parts})
    return pd.DataFrame(out, columns=["row", "l1", "seeds", *OUTCOMES])


def choose(dist: pd.DataFrame) -> str:
    """The rule: the row with the smallest ``l1``; a tie goes to the row first in ``dist``."""
    if dist.empty:
        raise PriqnError("calibration: no complete cell to choose from")
    return str(dist.loc[dist["l1"].idxmin(), "row"])  # idxmin: the first of equal minima


def target_vector(cal: CalibrationSpec) -> np.ndarray:
    """``float [keys]``: the target's rates in :meth:`~CalibrationSpec.target_mix` order."""
    return np.array(list(cal.target_mix().values()))


def seed_mixes(
    mixes: pd.DataFrame, cal: CalibrationSpec, order: list[str]
) -> dict[str, pd.DataFrame]:
    """Per row (in ``order``, those with cells): ``float [seeds x keys]`` indexed by seed
    (ascending), each seed's own rate at every ``(outcome, density)`` key of the target
    (:meth:`target_mix` order). A seed without one of the target's densities is a one-line
    error."""
    keys = list(cal.target_mix())
    out = {}
    for row in order:
        mine = mixes[mixes["row"] == row]
        if mine.empty:
            continue
        table = mine.pivot_table(index="seed", columns=["outcome", "density"], values="rate")
        table = table.reindex(columns=pd.MultiIndex.from_tuples(keys))
        gaps = table.isna().any(axis=1)
        if gaps.any():
            seed = table.index[gaps.to_numpy()][0]
            raise PriqnError(f"{row}__seed{seed}: no episodes at a density the target has")
        out[row] = table.astype(float)
    return out


def _l1_to(mixes_by_key: np.ndarray, target: np.ndarray) -> np.ndarray:
    """L1 distance of each mix (last axis: keys) to ``target`` (``float [keys]``)."""
    return np.abs(mixes_by_key - target).sum(axis=-1)


def seed_distances(by_row: dict[str, pd.DataFrame], target: np.ndarray) -> dict[str, np.ndarray]:
    """Per row, ``float [seeds]``: each seed's own L1 distance to ``target``
    (:func:`target_vector`; its mix, not the row's mean), from :func:`seed_mixes`."""
    return {row: _l1_to(m.to_numpy(), target) for row, m in by_row.items()}


def choice_bootstrap(
    by_row: dict[str, np.ndarray] | dict[str, pd.DataFrame],
    target: np.ndarray,
    resamples: int,
    seed: int,
) -> pd.DataFrame:
    """The rule applied to ``resamples`` bootstrap resamples: in each, every row's seeds
    (``by_row``: ``float [seeds x keys]``) are drawn with replacement, independently per
    row, and averaged; the row with the smallest L1 to ``target`` (``float [keys]``) is
    chosen (a tie: the row first in ``by_row``). Per row: ``chosen`` (share of resamples
    choosing it), ``l1_low`` / ``l1_high`` (2.5 / 97.5 % percentiles of its L1). All
    draws from ``numpy.random.default_rng(seed)``, row by row in ``by_row``'s order."""
    if resamples < 1 or not by_row:
        raise ValueError(f"expected resamples >= 1 and at least one row, got {resamples}")
    rng = np.random.default_rng(seed)
    l1_rows_by_resample = []
    for mix in by_row.values():
        seeds_keys = np.asarray(mix, dtype=float)
        picks_by_seed = rng.integers(0, len(seeds_keys), size=(resamples, len(seeds_keys)))
        means_keys = seeds_keys[picks_by_seed].mean(axis=1)  # [resamples x keys]
        l1_rows_by_resample.append(_l1_to(means_keys, target))
    l1 = np.stack(l1_rows_by_resample)  # [rows x resamples]
    chosen = np.bincount(l1.argmin(axis=0), minlength=len(by_row)) / resamples
    low, high = np.percentile(l1, [2.5, 97.5], axis=1)
    return pd.DataFrame({"row": list(by_row), "chosen": chosen, "l1_low": low, "l1_high": high})


def _spec(exp: Experiment) -> CalibrationSpec:
    if exp.calibration is None:
        raise PriqnError(f"{exp.path}: no [calibration] table")
    return exp.calibration


def _mix_table(mean: pd.DataFrame, cal: CalibrationSpec, order: list[str], traffic: dict) -> str:
    """Markdown: one line per row and the target's, outcome x density columns."""
    cols = [(o, d) for o in OUTCOMES for d in cal.densities]
    heads = [
        "setting (row)",
        "traffic",
        "seeds",
        *(f"{o.replace('_', '-')} {d:g}" for o, d in cols),
    ]
    target = cal.target_mix()
    rows = [["**target**", "–", "–", *(f"{target[c]:.3f}" for c in cols)]]
    for row in order:
        mine = mean[mean["row"] == row]
        if mine.empty:
            continue
        have = rates_of(mine)
        cells = [f"{have[c]:.3f}" if c in have else "–" for c in cols]
        rows.append([row, traffic[row], str(int(mine.seeds.min())), *cells])
    return markdown_table(heads, rows)


def _distance_table(dist: pd.DataFrame, chosen: str, final: bool) -> str:
    mark = "chosen" if final else "nearest so far"
    rows = [
        [f"**{r.row}** ({mark})" if r.row == chosen else r.row, str(r.seeds),
         *(f"{v:.3f}" for v in (r.l1, r.success, r.collision, r.off_road, r.timeout))]
        for r in dist.itertuples(index=False)
    ]  # fmt: skip
    heads = ["setting (row)", "seeds", "L1", "success", "collision", "off-road", "timeout"]
    return markdown_table(heads, rows)


def _sureness(mixes: pd.DataFrame, cal: CalibrationSpec, order: list[str]) -> tuple[Section, dict]:
    """The section "How sure is the choice" (with ``tables/seed_distances.csv`` and
    ``tables/choice_bootstrap.csv``) and meta.json's ``bootstrap`` record."""
    by_row, target = seed_mixes(mixes, cal, order), target_vector(cal)
    per_seed = seed_distances(by_row, target)
    seeds = {row: list(m.index) for row, m in by_row.items()}
    boot = choice_bootstrap(by_row, target, BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED)
    seed_frame = pd.DataFrame(
        [(row, s, d) for row in by_row for s, d in zip(seeds[row], per_seed[row], strict=True)],
        columns=["row", "seed", "l1"],
    )
    rows = [
        [b.row, ", ".join(f"{s}: {d:.2f}" for s, d in zip(seeds[b.row], per_seed[b.row],
                                                          strict=True)),
         f"[{b.l1_low:.2f}, {b.l1_high:.2f}]", f"{b.chosen:.1%}"]
        for b in boot.itertuples(index=False)
    ]  # fmt: skip
    heads = ["setting (row)", "L1 of each seed alone", "L1, bootstrap 95 %", "chosen in"]
    lines = [
        "## How sure is the choice (descriptive)",
        "",
        "The rule compares each row's mean over its seeds. Beside it: each seed's own "
        "distance to the target, and the rule applied again to "
        f"{BOOTSTRAP_RESAMPLES:,} bootstrap resamples, each drawing every row's seeds with "
        "replacement (rows independently; `numpy.random.default_rng("
        f"{BOOTSTRAP_SEED})`): the share of resamples that choose each row, and the "
        "2.5–97.5 % percentiles of its distance. With few seeds a row, a resample takes "
        "few distinct means: a rough picture of the seed spread, not a test.",
        "",
        markdown_table(heads, rows),
        "",
    ]
    record = {
        "resamples": BOOTSTRAP_RESAMPLES,
        "seed": BOOTSTRAP_SEED,
        "chosen": {b.row: round(float(b.chosen), 6) for b in boot.itertuples()},
    }
    tables = {"seed_distances": seed_frame, "choice_bootstrap": boot}
    return Section(lines, tables=tables), record


def figure(mean: pd.DataFrame, cal: CalibrationSpec, order: list[str]) -> Any:
    """The report's figure (``figures/calibration``): stacked outcome shares per density,
    the target's bar, then each row's."""
    from priqn.analysis.figures import plt

    colours = {"success": "#4c9a2a", "collision": "#c0392b", "off_road": "#e67e22",
               "timeout": "#95a5a6"}  # fmt: skip
    target = cal.target_mix()
    rows = [r for r in order if not mean[mean["row"] == r].empty]
    n = len(cal.densities)
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 4.2), sharey=True, squeeze=False)
    names = ["target", *rows]
    for ax, d in zip(axes[0], cal.densities, strict=True):
        bottom = np.zeros(len(names))
        for o in OUTCOMES:
            values = np.array([target[(o, d)]] + [rates_of(mean[mean.row == r]).get((o, d), 0.0)
                                                  for r in rows])  # fmt: skip
            ax.bar(range(len(names)), values, bottom=bottom, color=colours[o], label=o)
            bottom += values
        ax.set_xticks(range(len(names)), names, rotation=60, ha="right", fontsize=8)
        ax.set_title(f"density {d:g}")
    axes[0, 0].set_ylabel("share of hold-out episodes")
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=4, frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    return fig


def calibration_report(exp: Experiment, command: str) -> Report:
    """The calibration report (kind ``calibration``): report.md, ``tables/mix.csv`` (every
    cell's rates), ``tables/distances.csv``, ``tables/seed_distances.csv``,
    ``tables/choice_bootstrap.csv``, ``figures/calibration.png`` (and ``.pdf``); ``command``
    is the one that regenerates it. Cells not complete yet are named, and the choice is
    marked provisional until every cell is in."""
    cal = _spec(exp)
    mixes, missing = setting_mixes(exp)
    if mixes.empty:
        raise PriqnError(f"{exp.runs_dir}: no complete cell of {exp.experiment.name} yet")
    order = [p.name for p in exp.policies]
    traffic = {p.name: p.traffic or exp.experiment.traffic or "preset" for p in exp.policies}
    mean = mean_mix(mixes)
    dist = distances(mean, cal, order)
    chosen = choose(dist)
    sureness, bootstrap = _sureness(mixes, cal, order)
    budget = exp.experiment.steps
    one_row = len(order) == 1  # a check of one setting on more seeds: nothing to choose
    if one_row:
        verdict = (f"**{chosen}: L1 {dist.l1.min():.3f}** (one row: a check of its setting, "
                   f"nothing to choose{'; cells missing' if missing else ''}).")  # fmt: skip
    else:
        words = "chosen" if not missing else "provisionally nearest (cells missing)"
        verdict = f"**{words}: {chosen}** (L1 {dist.l1.min():.3f})."
    head = Section([
        f"# {exp.experiment.name}: calibration",
        "",
        f"Made by `{command}` from the cells' run folders and the rule in "
        f"`{exp.path.name}` (committed before any of its cells trained).",
        "",
        exp.experiment.description,
        "",
        f"Target: {cal.target}. Rule ({exp.path.name}, pre-registered): the row whose outcome "
        "mix (success, collision, off-road, timeout per density, each seed's rate averaged "
        "over its seeds) has the smallest L1 distance to the target's.",
        "",
        verdict,
        "",
        f"Budget: {budget:,} decisions per cell"
        + (f" ({budget / 2_000_000:.0%} of the paper's 2M)" if budget else "")
        + "; the target was measured after 2M decisions, and our IQN crashes less as it "
        "trains, so a setting matched here is matched at this budget only.",
        "",
    ])  # fmt: skip
    mix = Section(
        ["## Outcome mix per density", "", _mix_table(mean, cal, order, traffic), "",
         "![outcome mix per density](figures/calibration.png)", ""],
        tables={"mix": mixes},
        figures={"calibration": figure(mean, cal, order)},
    )  # fmt: skip
    distance = Section(
        ["## Distance to the target", "",
         _distance_table(dist, "" if one_row else chosen, final=not missing), ""],
        tables={"distances": dist},
    )  # fmt: skip
    sections = [head, mix, distance, sureness]
    if missing:
        sections.append(Section(["## Cells not counted yet", "", *(f"- {m}" for m in missing), ""]))
    fields = {
        "chosen": chosen,
        "final": not missing,
        "cells": int(mixes.groupby(["row", "seed"]).ngroups),
        "missing": missing,
        "distances": {r.row: round(float(r.l1), 6) for r in dist.itertuples()},
        "bootstrap": bootstrap,
    }
    return Report(
        "calibration", "report.md", sections, command, exp.experiment.name, fields, "%.6f"
    )
