"""The measures, tables and figure of ``priqn mechanism`` (descriptive), from its decision rows.

``priqn mechanism`` (:mod:`priqn.tools.mechanism`) replays evaluated Pr-IQN cells and
writes one row per decision (:data:`priqn.analysis.decisions.MECHANISM_ROWS`); here, from
those rows alone (docs/mechanism.md): :func:`removal_measures` (one seed's removal,
violation, calibration and waiting measures), :func:`reliability_table` (the safety
head's predictions binned against what happened), :func:`mechanism_measure` (the seed table's
columns and groups: collapsed, healthy, all) and :func:`mechanism_report` (the report,
as :func:`priqn.analysis.decisions.decision_report`'s sections). No torch, no SUMO.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from priqn.analysis.decisions import (
    EPISODE_KEYS,
    MECHANISM_ROWS,
    CellRows,
    DecisionCache,
    DecisionMeasure,
    ReportTable,
    decision_report,
    default_cache,
    rate,
    replay_share,
    seed_table,
)
from priqn.analysis.sections import Report
from priqn.run.evaluations import evaluation_folder, snapshot_evaluation

DEFAULT_EPISODES = 54
"""Episodes replayed per seed by default: the first evaluation run of the headline cells."""
DEFAULT_COLLAPSED_BELOW = 0.42
"""A seed is *collapsed* when its hold-out success rate (whole ``eval/``) is below this."""
RELIABILITY_EDGES: tuple[float, ...] = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
"""Bin edges of the predicted violation probability (the last bin includes 1)."""
GROUPS: tuple[str, ...] = ("collapsed", "healthy", "all")
"""Group rows of the table, in order."""
CALIBRATED = "safety"
"""The objective whose head's calibration is measured: its return is 0 or the violation
penalty discounted, so its quantiles predict a violation whatever ``--top`` is."""


@dataclasses.dataclass(frozen=True)
class MechanismConfig:
    """What ``priqn mechanism`` replays and how it counts."""

    episodes: int = DEFAULT_EPISODES
    """Episodes per seed: the first of the cell's evaluation scenes in the order (eval run,
    episode, net, density) (:func:`replay_scenes`); 0 = all of them."""
    top: str = "safety"
    """The level whose removals and standing still are counted. Calibration is always
    the safety head's (:data:`CALIBRATED`), the one head that learns the violation penalty."""
    lower: str = "lane_keeping"
    """The lower objective whose greedy action's removal drives the violation measures."""
    horizon: int = 5
    """A violation "after" a decision: the episode ends in one within this many decisions,
    the decision itself included (5 = 2.5 s at the default decision interval)."""
    collapsed_below: float = DEFAULT_COLLAPSED_BELOW
    """Hold-out success rate under which a seed counts as collapsed."""
    workers: int = 1
    """Env worker processes (one SUMO simulation each)."""
    snapshot: int = 0
    """0: each run's final policy on its ``eval/`` scenes; N: the policy it kept at N
    decisions (``checkpoint.keep_at``) on the scenes of ``eval-at<N>/``."""
    decisions: str = ""
    """Folder of the decision-row cache ("": :func:`priqn.analysis.decisions.default_cache`)."""

    def cache(self) -> DecisionCache:
        """The decision-row cache: :attr:`decisions`, else the default folder."""
        return DecisionCache(Path(self.decisions) if self.decisions else default_cache())

    def params(self, run: Path, episodes: int) -> dict[str, Any]:
        """What a cell's mechanism rows depend on, beside the schema (the cache's key):
        the run folder (resolved), the policy replayed, the episodes and the counting."""
        return {
            "run": str(Path(run).resolve()),
            "snapshot": self.snapshot,
            "episodes": episodes,
            "top": self.top,
            "lower": self.lower,
            "horizon": self.horizon,
        }

    @property
    def evaluation(self) -> str:
        """The evaluation folder replayed: ``eval/`` or ``eval-at<N>/``."""
        name = snapshot_evaluation(self.snapshot) if self.snapshot else ""
        return f"{evaluation_folder(name)}/"


# ----------------------------------------------------------------------------- counting


def removal_measures(decisions: Any, cfg: MechanismConfig) -> dict[str, Any]:
    """One seed's measures from its decision rows (:data:`MECHANISM_ROWS`, pandas).

    Rates over decisions unless the name says episodes; NaN where a condition never held.
    """
    d = decisions
    removes = d[f"removes_{cfg.lower}"].astype(bool)
    standstill = d["speed_mps"] == 0.0
    by_episode = d.groupby(EPISODE_KEYS, sort=False)
    episode_removal = by_episode[f"removes_{cfg.lower}"].any()
    episode_violation = by_episode["episode_violation"].first()
    out: dict[str, Any] = {
        "episodes": int(by_episode.ngroups),
        "decisions": len(d),
        "replay_violation": rate(episode_violation),
    }
    for column in d.columns:
        if column.startswith("removes_"):
            out[column] = rate(d[column])
    out.update(
        {
            "violation_after_removal": rate(d.loc[removes, "violation_within"]),
            "violation_otherwise": rate(d.loc[~removes, "violation_within"]),
            "off_road_after_removal": rate(d.loc[removes, "off_road_within"]),
            "off_road_otherwise": rate(d.loc[~removes, "off_road_within"]),
            "episodes_with_removal": rate(episode_removal),
            "violation_episodes_with_removal": rate(episode_violation[episode_removal]),
            "violation_episodes_without": rate(episode_violation[~episode_removal]),
            "pred_violation": rate(d["pred_violation"]),
            "observed_violation": rate(d["episode_violation"]),
            "brier": rate((d["pred_violation"] - d["episode_violation"].astype(float)) ** 2),
            "pred_return": rate(d["pred_return"]),
            "return_to_go": rate(d["return_to_go"]),
            "timeout_episodes": rate(by_episode["episode_timeout"].first()),
            "standstill": rate(standstill),
            "top_only_standstill": rate(d["top_max_speed_mps"] == 0.0),
            "standstill_top_allowed_moving": rate(standstill & (d["top_max_speed_mps"] > 0.0)),
            f"standstill_{cfg.lower}_moving": rate(
                standstill & (d["lower_greedy_speed_mps"] > 0.0)
            ),
        }
    )
    return out


def reliability_table(decisions: Any, edges: Sequence[float] = RELIABILITY_EDGES) -> Any:
    """Decisions binned by predicted violation probability: per bin ``n``, the mean
    prediction and the observed share of episodes ending in a violation (pandas)."""
    import pandas as pd

    p = decisions["pred_violation"].to_numpy(dtype=float)
    bins = np.clip(np.searchsorted(edges, p, side="right") - 1, 0, len(edges) - 2)
    rows = []
    for b in range(len(edges) - 1):
        hit = bins == b
        rows.append(
            {
                "bin": f"[{edges[b]:.1f}, {edges[b + 1]:.1f}{']' if b == len(edges) - 2 else ')'}",
                "n": int(hit.sum()),
                "pred_violation": rate(p[hit]),
                "observed_violation": rate(decisions["episode_violation"].to_numpy()[hit]),
            }
        )
    return pd.DataFrame(rows)


MARKDOWN_COLUMNS: tuple[str, ...] = (
    "run",
    "holdout_success",
    "collapsed",
    "episodes",
    "decisions",
    "replay_matches",
    "removes_{lower}",
    "removes_any",
    "violation_after_removal",
    "violation_otherwise",
    "off_road_after_removal",
    "off_road_otherwise",
    "pred_violation",
    "observed_violation",
    "brier",
    "timeout_episodes",
    "standstill",
    "top_only_standstill",
    "standstill_{lower}_moving",
)
"""Columns of the seed table in report.md (all of them are in tables/mechanism.csv)."""
COUNTS = {"episodes": "g", "decisions": "g", "n": "g"}
"""report.md's formats of the count columns (a group row's count is a mean)."""


def mechanism_measure(cfg: MechanismConfig) -> DecisionMeasure:
    """The seed table of ``priqn mechanism``: per cell its name, row, training seed,
    hold-out success (``collapsed`` below ``cfg.collapsed_below``), ``replay_matches`` and
    :func:`removal_measures`; group rows: the collapsed, the healthy and all seeds."""

    def identity(cell: CellRows) -> dict[str, Any]:
        success = float(cell.evaluated["success"].astype(float).mean())
        return {
            "run": cell.name,
            "row": cell.row,
            "seed": cell.seed,
            "holdout_success": success,
            "collapsed": success < cfg.collapsed_below,
            "replay_matches": replay_share(cell.decisions),
        }

    def groups(seeds: Any) -> list[tuple[dict[str, Any], Any]]:
        out = []
        for group in GROUPS:
            mask = (seeds["collapsed"] == (group == "collapsed")) | (group == "all")
            ident = {"run": f"mean of {group} seeds", "row": "", "seed": int(mask.sum())}
            out.append(({**ident, "collapsed": group}, mask))
        return out

    return DecisionMeasure(
        "mechanism",
        identity,
        lambda d: removal_measures(d, cfg),
        groups,
        tuple(c.format(lower=cfg.lower) for c in MARKDOWN_COLUMNS),
        COUNTS,
    )


# ----------------------------------------------------------------------------- outputs


def mechanism_figure(seeds: Any, reliability: dict[str, Any], cfg: MechanismConfig) -> Any:
    """Removal rate against hold-out success per seed, and the safety head's reliability
    curve per group (a matplotlib figure)."""
    import matplotlib.pyplot as plt

    fig, (ax_a, ax_b) = plt.subplots(1, 2, figsize=(10, 4.2), layout="constrained")
    for collapsed, color, name in ((True, "tab:red", "collapsed"), (False, "tab:blue", "healthy")):
        part = seeds[seeds["collapsed"] == collapsed]
        ax_a.scatter(part["holdout_success"], part[f"removes_{cfg.lower}"], color=color, label=name)
        ax_a.scatter(
            part["holdout_success"],
            part["violation_after_removal"],
            color=color,
            marker="x",
            label=f"{name}: violation ≤{cfg.horizon} dec. after removal",
        )
    ax_a.axvline(cfg.collapsed_below, color="0.5", ls="--", lw=0.8)
    ax_a.set_xlabel(f"hold-out success rate (whole {cfg.evaluation})")
    ax_a.set_ylabel("share of decisions")
    ax_a.set_title(f"{cfg.top} removes {cfg.lower}'s greedy action (dots)", fontsize=9)
    ax_a.legend(fontsize=7)
    ax_b.plot([0, 1], [0, 1], color="0.6", ls="--", lw=0.8)
    for group, color in (("collapsed", "tab:red"), ("healthy", "tab:blue"), ("all", "k")):
        table = reliability.get(group)
        if table is None or not table["n"].sum():
            continue
        shown = table[table["n"] > 0]
        ax_b.plot(
            shown["pred_violation"], shown["observed_violation"], marker="o", color=color,
            label=f"{group} ({int(table['n'].sum())} decisions)",
        )  # fmt: skip
    ax_b.set_xlim(0, 1)
    ax_b.set_ylim(0, 1)
    ax_b.set_xlabel(f"predicted P(violation): {CALIBRATED} quantiles ≤ −penalty/2 at the action")
    ax_b.set_ylabel("observed: episode ends in a violation")
    ax_b.set_title(f"{CALIBRATED} head reliability (decisions)", fontsize=9)
    ax_b.legend(fontsize=7)
    return fig


def mechanism_report(cells: Sequence[CellRows], cfg: MechanismConfig, command: str) -> Report:
    """The report of ``priqn mechanism`` (``command``: the one that makes it) from the
    replayed cells: ``tables/mechanism.csv`` (a row per seed, then per group),
    ``tables/reliability.csv``, ``figures/mechanism.png``/``.pdf``, ``report.md`` and
    ``meta.json``."""
    import pandas as pd

    m = mechanism_measure(cfg)
    table = seed_table(m, cells)
    seeds = table.iloc[: len(cells)]
    reliability = {}
    for group in GROUPS:
        names = seeds["run"][(seeds["collapsed"] == (group == "collapsed")) | (group == "all")]
        if len(names):
            frames = {c.name: c.decisions for c in cells}
            reliability[group] = reliability_table(pd.concat([frames[n] for n in names]))
    rel = pd.concat([t.assign(group=g) for g, t in reliability.items()], ignore_index=True)
    intro = (
        f"{len(cells)} seeds, {cfg.episodes or 'all'} episodes each (the first of each cell's "
        f"{cfg.evaluation} scenes by eval run, episode, net, density"
        + (f"; the policy each kept at {cfg.snapshot} decisions" if cfg.snapshot else "")
        + f"), top level `{cfg.top}`, lower objective `{cfg.lower}`, violation "
        f"horizon {cfg.horizon} decisions; collapsed = hold-out success < "
        f"{cfg.collapsed_below:g}. Measures: docs/mechanism.md. Rates are over decisions "
        "unless named after episodes; group rows are means over their seeds."
    )
    tables = [
        ReportTable("mechanism", table, m.shown, formats=m.formats),
        ReportTable(
            "reliability",
            rel,
            ("group", "bin", "n", "pred_violation", "observed_violation"),
            f"Reliability of the {CALIBRATED} head (decisions)",
            COUNTS,
        ),
    ]
    fields = {
        "cells": [c.name for c in cells],
        "episodes": cfg.episodes,
        "top": cfg.top,
        "lower": cfg.lower,
        "horizon": cfg.horizon,
        "collapsed_below": cfg.collapsed_below,
        "snapshot": cfg.snapshot,
        "decision_rows": {"kind": MECHANISM_ROWS.kind, "version": MECHANISM_ROWS.version},
    }
    title = "Pr-IQN mechanism (priqn mechanism)"
    figure = mechanism_figure(seeds, reliability, cfg)
    return decision_report("mechanism", command, title, intro, tables, figure, fields)
