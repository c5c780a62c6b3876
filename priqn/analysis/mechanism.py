"""The measures, tables and figure of ``priqn mechanism`` (descriptive), from its decision rows.

``priqn mechanism`` (:mod:`priqn.tools.mechanism`) replays evaluated Pr-IQN cells and
writes one row per decision; here, from those rows alone (docs/mechanism.md):
:func:`seed_summary` (one seed's removal, violation, calibration and waiting measures),
:func:`reliability_table` (the safety head's predictions binned against what happened),
:func:`group_rows` (collapsed, healthy, all) and :func:`write_report` (``mechanism.csv``,
``mechanism.md``, ``reliability.csv``, ``mechanism.png``). No torch, no SUMO.
"""

from __future__ import annotations

import dataclasses
import io
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from priqn.analysis.render import markdown_table, write_csv
from priqn.analysis.standstill import EPISODE_KEYS
from priqn.io import atomic_write_bytes, atomic_write_text
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
    """Folder of the per-decision files ("": ``<out>/decisions``)."""

    def decisions_dir(self, out: Path) -> Path:
        """Where the per-decision files go: :attr:`decisions`, else ``out/decisions``."""
        return Path(self.decisions) if self.decisions else out / "decisions"

    @property
    def evaluation(self) -> str:
        """The evaluation folder replayed: ``eval/`` or ``eval-at<N>/``."""
        name = snapshot_evaluation(self.snapshot) if self.snapshot else ""
        return f"{evaluation_folder(name)}/"


# ----------------------------------------------------------------------------- counting


def _rate(values: Any) -> float:
    values = np.asarray(values, dtype=float)
    return float(values.mean()) if values.size else math.nan


def seed_summary(decisions: Any, cfg: MechanismConfig) -> dict[str, Any]:
    """One seed's measures from its decision rows (a pandas frame of
    :func:`priqn.tools.mechanism.decision_rows`).

    Rates over decisions unless the name says episodes; NaN where a condition never held.
    """
    d = decisions
    removes = d[f"removes_{cfg.lower}"].astype(bool)
    standstill = d["speed_mps"] == 0.0
    by_episode = d.groupby(["eval_run", "net", "density", "episode"], sort=False)
    episode_removal = by_episode[f"removes_{cfg.lower}"].any()
    episode_violation = by_episode["episode_violation"].first()
    out: dict[str, Any] = {
        "episodes": int(by_episode.ngroups),
        "decisions": len(d),
        "replay_violation": _rate(episode_violation),
    }
    for column in d.columns:
        if column.startswith("removes_"):
            out[column] = _rate(d[column])
    out.update(
        {
            "violation_after_removal": _rate(d.loc[removes, "violation_within"]),
            "violation_otherwise": _rate(d.loc[~removes, "violation_within"]),
            "off_road_after_removal": _rate(d.loc[removes, "off_road_within"]),
            "off_road_otherwise": _rate(d.loc[~removes, "off_road_within"]),
            "episodes_with_removal": _rate(episode_removal),
            "violation_episodes_with_removal": _rate(episode_violation[episode_removal]),
            "violation_episodes_without": _rate(episode_violation[~episode_removal]),
            "pred_violation": _rate(d["pred_violation"]),
            "observed_violation": _rate(d["episode_violation"]),
            "brier": _rate((d["pred_violation"] - d["episode_violation"].astype(float)) ** 2),
            "pred_return": _rate(d["pred_return"]),
            "return_to_go": _rate(d["return_to_go"]),
            "timeout_episodes": _rate(by_episode["episode_timeout"].first()),
            "standstill": _rate(standstill),
            "top_only_standstill": _rate(d["top_max_speed_mps"] == 0.0),
            "standstill_top_allowed_moving": _rate(standstill & (d["top_max_speed_mps"] > 0.0)),
            f"standstill_{cfg.lower}_moving": _rate(
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
                "pred_violation": _rate(p[hit]),
                "observed_violation": _rate(decisions["episode_violation"].to_numpy()[hit]),
            }
        )
    return pd.DataFrame(rows)


def group_rows(seeds: Any) -> Any:
    """Group rows (collapsed, healthy, all): each measure's mean over the group's seeds."""
    import pandas as pd

    numeric = [c for c in seeds.columns if c not in ("run", "row", "seed", "collapsed")]
    rows = []
    for group in GROUPS:
        part = seeds if group == "all" else seeds[seeds["collapsed"] == (group == "collapsed")]
        row = {"run": f"mean of {group} seeds", "row": "", "seed": len(part), "collapsed": group}
        for c in numeric:
            row[c] = float(part[c].astype(float).mean()) if len(part) else math.nan
        rows.append(row)
    return pd.DataFrame(rows)


# ----------------------------------------------------------------------------- outputs


def _markdown(frame: Any, digits: int = 3) -> str:
    cols = list(frame.columns)
    rows = []
    for _, r in frame.iterrows():
        cells = []
        for c in cols:
            v = r[c]
            if isinstance(v, float) and c in ("episodes", "decisions", "n"):
                cells.append("–" if math.isnan(v) else f"{v:g}")  # counts (group: means)
            elif isinstance(v, float):
                cells.append("–" if math.isnan(v) else f"{v:.{digits}f}")
            else:
                cells.append(str(v))
        rows.append(cells)
    return markdown_table(cols, rows)


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
"""Columns of the seed table in mechanism.md (all of them are in mechanism.csv)."""


def write_figure(seeds: Any, reliability: dict[str, Any], cfg: MechanismConfig, path: Path) -> None:
    """``mechanism.png``: removal rate against hold-out success per seed, and the safety
    head's reliability curve per group."""
    import matplotlib

    matplotlib.use("Agg")
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
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=130, metadata={"Software": None})
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def seed_row(
    run: str, seed: int, holdout_success: float, decisions: Any, cfg: MechanismConfig
) -> dict[str, Any]:
    """One row of the seed table: the cell's name, row and training seed, its hold-out
    success (``collapsed`` below ``cfg.collapsed_below``), the share of its replayed
    episodes that ended as evaluated, and :func:`seed_summary` of its decision rows."""
    row = {
        "run": run,
        "row": run.split("__seed")[0],
        "seed": seed,
        "holdout_success": holdout_success,
        "collapsed": holdout_success < cfg.collapsed_below,
        "replay_matches": _rate(decisions.groupby(EPISODE_KEYS)["replay_matches"].first()),
    }
    row.update(seed_summary(decisions, cfg))
    return row


def write_report(
    seeds: Sequence[dict[str, Any]], decisions: dict[str, Any], cfg: MechanismConfig, out: Path
) -> Path:
    """Write ``mechanism.csv``, ``reliability.csv``, ``mechanism.png`` and ``mechanism.md``
    into ``out`` from the seed rows (:func:`seed_row`) and each seed's decision rows (run
    name → pandas frame); returns the table."""
    import pandas as pd

    table = pd.DataFrame(seeds)
    full = pd.concat([table, group_rows(table)], ignore_index=True)
    write_csv(out / "mechanism.csv", full, float_format=None)

    reliability = {}
    for group in GROUPS:
        names = [
            r["run"] for r in seeds if group == "all" or r["collapsed"] == (group == "collapsed")
        ]
        if names:
            reliability[group] = reliability_table(pd.concat([decisions[n] for n in names]))
    rel = pd.concat([t.assign(group=g) for g, t in reliability.items()], ignore_index=True)
    write_csv(out / "reliability.csv", rel, float_format=None)
    write_figure(table, reliability, cfg, out / "mechanism.png")
    columns = [c.format(lower=cfg.lower) for c in MARKDOWN_COLUMNS]
    text = [
        "# Pr-IQN mechanism (priqn mechanism)",
        "",
        f"{len(seeds)} seeds, {cfg.episodes or 'all'} episodes each (the first of each cell's "
        f"{cfg.evaluation} scenes by eval run, episode, net, density"
        + (f"; the policy each kept at {cfg.snapshot} decisions" if cfg.snapshot else "")
        + f"), top level `{cfg.top}`, lower objective `{cfg.lower}`, violation "
        f"horizon {cfg.horizon} decisions; collapsed = hold-out success < "
        f"{cfg.collapsed_below:g}. Measures: docs/mechanism.md. Rates are over decisions "
        "unless named after episodes; group rows are means over their seeds.",
        "",
        _markdown(full[columns]),
        "",
        f"## Reliability of the {CALIBRATED} head (decisions)",
        "",
        _markdown(rel[["group", "bin", "n", "pred_violation", "observed_violation"]]),
        "",
        "![mechanism](mechanism.png)",
        "",
    ]
    atomic_write_text(out / "mechanism.md", "\n".join(text))
    return out / "mechanism.csv"
