"""The measures, table and figure of ``priqn mechanism --standstill`` (descriptive).

``priqn mechanism --standstill`` (:mod:`priqn.tools.standstill`) replays evaluated cells
and writes one row per decision (:data:`priqn.analysis.decisions.STANDSTILL_ROWS`): does a
go action survive to the ``--target`` level, which level removed the last one, and the
safety / risk heads' best stop vs best go (docs/mechanism.md, "Standing still"). Here,
from those rows alone: :func:`waiting_measures` (one cell's shares and medians),
:func:`standstill_measure` (the seed table's columns and groups: each row of cells) and
:func:`standstill_report` (the report, as
:func:`priqn.analysis.decisions.decision_report`'s sections). No torch, no SUMO.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from priqn.analysis.decisions import (
    EPISODE_KEYS,
    STANDSTILL_ROWS,
    CellRows,
    DecisionMeasure,
    ReportTable,
    decision_report,
    episodes_in,
    median,
    rate,
    replay_share,
    seed_table,
)
from priqn.analysis.sections import Report

COMPARED: tuple[str, ...] = ("safety", "risk")
"""Objectives whose best stop and best go actions are compared per decision."""
REMOVERS: tuple[str, ...] = ("safety", "risk", "lane_keeping")
"""The levels above ``progress`` in the total order, in order (the table's columns)."""
DEFAULT_TARGET = "progress"
"""The level whose choice set the go survival is counted for (``--target``)."""


# ----------------------------------------------------------------------------- counting


def waiting_measures(d: Any) -> dict[str, Any]:
    """One cell's measures from its decision rows (:data:`STANDSTILL_ROWS`, pandas).

    Shares over all decisions; ``<o>_*_removed`` are medians over the decisions whose
    remover is ``o`` (safety or risk), ``<o>_*_all`` over all decisions; NaN where none."""
    episodes = d.groupby(EPISODE_KEYS, sort=False)
    out: dict[str, Any] = {
        "episodes": int(episodes.ngroups),
        "decisions": len(d),
        "replay_timeout": rate(episodes["episode_timeout"].first()),
        "stop": rate(d["stop"]),
    }
    if "go_survives" not in d.columns:
        return out
    removed = d["removed_by"].fillna("").astype(str)
    out["no_go"] = rate(~d["go_survives"].astype(bool))
    for level in REMOVERS:
        out[f"no_go_{level}"] = rate(removed == level)
    for name in COMPARED:
        if f"{name}_raw_diff" not in d.columns:
            continue
        hit = removed == name
        for key in ("mean_stop", "mean_go", "raw_diff", "z_diff", "spread"):
            out[f"{name}_{key}_removed"] = median(d.loc[hit, f"{name}_{key}"])
            out[f"{name}_{key}_all"] = median(d[f"{name}_{key}"])
    return out


TABLE_COLUMNS: tuple[str, ...] = (
    "group",
    "seed",
    "holdout_timeout",
    "replay_timeout",
    "replay_matches",
    "episodes",
    "decisions",
    "stop",
    "no_go",
    "no_go_safety",
    "no_go_risk",
    "no_go_lane_keeping",
    "safety_raw_diff_removed",
    "safety_z_diff_removed",
    "safety_spread_removed",
    "safety_spread_all",
    "risk_raw_diff_removed",
    "risk_z_diff_removed",
    "risk_spread_removed",
)
"""Columns of the table in report.md (all of them, and more, are in tables/standstill.csv)."""


def standstill_measure(columns: Sequence[str] = TABLE_COLUMNS) -> DecisionMeasure:
    """The seed table of ``--standstill``: per cell its group (row name), name, training
    seed, the timeout rate of its whole evaluation, ``replay_matches`` and
    :func:`waiting_measures`; group rows: each row of cells. ``columns``: those of
    :data:`TABLE_COLUMNS` the table has (a table of IQN cells alone has no ``no_go``)."""

    def identity(cell: CellRows) -> dict[str, Any]:
        return {
            "group": cell.row,
            "run": cell.name,
            "seed": cell.seed,
            "holdout_timeout": rate(cell.evaluated["timeout"].astype(bool)),
            "replay_matches": replay_share(cell.decisions),
        }

    def groups(seeds: Any) -> list[tuple[dict[str, Any], Any]]:
        out = []
        for group in seeds["group"].unique():
            mask = seeds["group"] == group
            out.append(
                ({"group": group, "run": f"mean of {int(mask.sum())} seeds", "seed": ""}, mask)
            )
        return out

    diffs = {c: ".3g" for c in columns if "diff" in c}
    return DecisionMeasure("standstill", identity, waiting_measures, groups, tuple(columns), diffs)


# ----------------------------------------------------------------------------- outputs


def standstill_figure(table: Any, decisions: Any, eps: float, target: str = DEFAULT_TARGET) -> Any:
    """Per seed and group, the share of decisions with no go action left for ``target`` by
    removing level (Pr-IQN) or stopping (IQN), with the hold-out timeout rate; and
    safety's raw stop − go difference against its raw spread (a matplotlib figure)."""
    import matplotlib.pyplot as plt

    fig, (ax_a, ax_b) = plt.subplots(1, 2, figsize=(13, 4.6), layout="constrained")
    colors = {"safety": "tab:red", "risk": "tab:orange", "lane_keeping": "tab:purple"}
    x = np.arange(len(table))
    bottom = np.zeros(len(table))
    for level, color in colors.items():
        share = table.get(f"no_go_{level}", np.full(len(table), np.nan)).astype(float)
        share = np.nan_to_num(share.to_numpy())
        ax_a.bar(x, share, bottom=bottom, color=color, label=f"no go left: removed by {level}")
        bottom += share
    iqn = table["no_go"].isna().to_numpy() if "no_go" in table else np.ones(len(table), bool)
    ax_a.bar(x[iqn], table["stop"].to_numpy()[iqn], color="tab:gray", label="greedy stop (IQN)")
    ax_a.scatter(x, table["holdout_timeout"], color="k", marker="_", s=120, zorder=3,
                 label="hold-out timeout rate (eval/)")  # fmt: skip
    ax_a.set_xticks(x, [str(s) for s in table["seed"]], fontsize=6)
    for group in table["group"].unique():
        at = x[(table["group"] == group).to_numpy()]
        ax_a.axvline(at[0] - 0.5, color="0.7", lw=0.6)
        ax_a.text(at.mean(), 0.97, group, ha="center", va="top", fontsize=7)
    ax_a.set_xlabel("training seed")
    ax_a.set_ylabel("share of replayed decisions")
    ax_a.set_ylim(0, 1)
    ax_a.legend(fontsize=6, loc="upper right", bbox_to_anchor=(1.0, 0.92))
    ax_a.set_title(f"decisions where no go action reaches {target}'s choice", fontsize=9)
    for group, marker in zip(decisions["group"].unique(), ("o", "s", "^", "v"), strict=False):
        part = decisions[(decisions["group"] == group) & decisions["safety_spread"].notna()]
        if not len(part):
            continue
        removed = part["removed_by"].fillna("") == "safety"
        for hit, color in ((removed, "tab:red"), (~removed, "tab:blue")):
            ax_b.scatter(part.loc[hit, "safety_spread"], part.loc[hit, "safety_raw_diff"].abs().clip(lower=1e-6),
                         s=3, alpha=0.3, marker=marker, color=color,
                         label=f"{group}: {'safety removes all go' if color == 'tab:red' else 'other'}")  # fmt: skip
    spreads = decisions["safety_spread"].dropna() if "safety_spread" in decisions else []
    grid = (
        np.geomspace(max(float(np.min(spreads)), 1e-6), float(np.max(spreads)), 50)
        if len(spreads)
        else np.array([1.0])
    )
    ax_b.plot(grid, eps * grid, color="k", lw=0.8, ls="--", label=f"|raw diff| = ε·s (ε = {eps:g})")
    ax_b.set_xscale("log")
    ax_b.set_yscale("log")
    ax_b.set_xlabel("safety spread s: raw std of all K·A safety quantiles")
    ax_b.set_ylabel("|mean(best stop) − mean(best go)|, safety, raw")
    ax_b.set_title("safety: raw stop − go difference vs spread (per decision)", fontsize=9)
    ax_b.legend(fontsize=6, markerscale=3)
    return fig


def standstill_report(
    cells: Sequence[CellRows],
    episodes: int,
    eps: float,
    target: str,
    command: str,
) -> Report:
    """The report of ``--standstill`` (``command``: the one that makes it)
    from the replayed cells (``episodes``: asked per cell, 0 = all; ``eps``: the ε of the
    figure's threshold line; ``target``: the ``--target`` level): ``tables/standstill.csv``
    (a row per cell, then per group), ``figures/standstill.png``/``.pdf``, ``report.md``
    and ``meta.json``."""
    import pandas as pd

    table = seed_table(standstill_measure(), cells)
    m = standstill_measure([c for c in TABLE_COLUMNS if c in table.columns])
    decisions = pd.concat([c.decisions.assign(group=c.row) for c in cells], ignore_index=True)
    counts = ", ".join(f"{c.name}: {episodes_in(c.decisions)}" for c in cells[:1])
    intro = (
        f"{len(cells)} cells, episodes per cell as replayed ({counts}, the first of each "
        "cell's eval/ scenes by eval run, episode, net, density). Shares over decisions; "
        "`no_go_<level>`: no go action (target speed > 0) is left in the subset "
        f"{target} chooses from, and `<level>` is the first level whose subset holds none. "
        "`*_removed`: medians over the decisions that level removed; `*_all`: over all. "
        "`holdout_timeout`: the cell's whole eval/episodes.csv. Measures: docs/mechanism.md."
    )
    fields = {
        "cells": [c.name for c in cells],
        "episodes": episodes,
        "target": target,
        "decision_rows": {"kind": STANDSTILL_ROWS.kind, "version": STANDSTILL_ROWS.version},
    }
    figure = standstill_figure(table.iloc[: len(cells)], decisions, eps, target)
    tables = [ReportTable("standstill", table, m.shown, formats=m.formats)]
    title = "Standing still (priqn mechanism --standstill)"
    return decision_report("standstill", command, title, intro, tables, figure, fields)
