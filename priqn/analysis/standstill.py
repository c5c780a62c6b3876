"""The measures, table and figure of ``priqn mechanism --standstill`` (descriptive).

``priqn mechanism --standstill`` (:mod:`priqn.tools.standstill`) replays evaluated cells
and writes one row per decision: does a go action survive to the ``--target`` level, which
level removed the last one, and the safety / risk heads' best stop vs best go
(docs/mechanism.md, "Standing still"). Here, from those rows alone: :func:`seed_summary`
(one cell's shares and medians), :func:`seed_row`, :func:`group_rows` and
:func:`write_report` (``standstill.csv``, ``standstill.md``, ``standstill.png``), and the
per-decision table helpers both ``priqn mechanism`` measures use (:data:`EPISODE_KEYS`,
:func:`episodes_in`, :func:`replay_matches`). No torch, no SUMO.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from priqn.analysis.render import markdown_table, write_csv
from priqn.io import atomic_write_bytes, atomic_write_text

COMPARED: tuple[str, ...] = ("safety", "risk")
"""Objectives whose best stop and best go actions are compared per decision."""
REMOVERS: tuple[str, ...] = ("safety", "risk", "lane_keeping")
"""The levels above ``progress`` in the total order, in order (the table's columns)."""


# ----------------------------------------------------------------------------- counting


def _rate(values: Any) -> float:
    values = np.asarray(values, dtype=float)
    return float(values.mean()) if values.size else math.nan


def _median(values: Any) -> float:
    """The median over the finite values (NaN: the level saw no stop or no go)."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    return float(np.median(values)) if values.size else math.nan


def seed_summary(d: Any) -> dict[str, Any]:
    """One cell's measures from its decision rows (a pandas frame of
    :func:`priqn.tools.standstill.standstill_rows`).

    Shares over all decisions; ``<o>_*_removed`` are medians over the decisions whose
    remover is ``o`` (safety or risk), ``<o>_*_all`` over all decisions; NaN where none."""
    episodes = d.groupby(["eval_run", "net", "density", "episode"], sort=False)
    out: dict[str, Any] = {
        "episodes": int(episodes.ngroups),
        "decisions": len(d),
        "replay_timeout": _rate(episodes["episode_timeout"].first()),
        "stop": _rate(d["stop"]),
    }
    if "go_survives" not in d.columns:
        return out
    removed = d["removed_by"].fillna("").astype(str)
    out["no_go"] = _rate(~d["go_survives"].astype(bool))
    for level in REMOVERS:
        out[f"no_go_{level}"] = _rate(removed == level)
    for name in COMPARED:
        if f"{name}_raw_diff" not in d.columns:
            continue
        hit = removed == name
        for key in ("mean_stop", "mean_go", "raw_diff", "z_diff", "spread"):
            out[f"{name}_{key}_removed"] = _median(d.loc[hit, f"{name}_{key}"])
            out[f"{name}_{key}_all"] = _median(d[f"{name}_{key}"])
    return out


# ----------------------------------------------------------------------------- outputs


def _markdown(frame: Any) -> str:
    cols = list(frame.columns)
    rows = []
    for _, r in frame.iterrows():
        cells = []
        for c in cols:
            v = r[c]
            if isinstance(v, (float, np.floating)):
                cells.append("–" if math.isnan(v) else f"{v:.3g}" if "diff" in c else f"{v:.3f}")
            else:
                cells.append(str(v))
        rows.append(cells)
    return markdown_table(cols, rows)


def group_rows(table: Any) -> Any:
    """One row per group (the cells' row name): each measure's mean over its seeds."""
    numeric = [c for c in table.columns if c not in ("group", "run", "seed")]
    rows = []
    for group, part in table.groupby("group", sort=False):
        row: dict[str, Any] = {"group": group, "run": f"mean of {len(part)} seeds", "seed": ""}
        for c in numeric:
            row[c] = float(part[c].astype(float).mean())
        rows.append(row)
    import pandas as pd

    return pd.DataFrame(rows)


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
"""Columns of the table in standstill.md (all of them, and more, are in standstill.csv)."""


def write_figure(table: Any, decisions: Any, eps: float, path: Path) -> None:
    """``standstill.png``: per seed and group, the share of decisions with no go action
    left for progress by removing level (Pr-IQN) or stopping (IQN), with the hold-out
    timeout rate; and safety's raw stop − go difference against its raw spread."""
    import matplotlib

    matplotlib.use("Agg")
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
    ax_a.set_title("decisions where no go action reaches progress's choice", fontsize=9)
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
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120, metadata={"Software": None})
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def seed_row(group: str, run: str, seed: Any, evaluated: Any, decisions: Any) -> dict[str, Any]:
    """One row of the table: the cell's group (its row name), name and training seed, the
    timeout rate of its whole evaluation (``evaluated``: its ``episodes.csv``, pandas), the
    share of replayed episodes that ended as evaluated (:func:`replay_matches`) and
    :func:`seed_summary` of its decision rows."""
    row = {"group": group, "run": run, "seed": seed}
    row["holdout_timeout"] = _rate(evaluated["timeout"].astype(bool))
    row["replay_matches"] = replay_matches(decisions, evaluated)
    row.update(seed_summary(decisions))
    return row


def write_report(
    seeds: Sequence[dict[str, Any]],
    decisions: Sequence[Any],
    replayed: dict[str, int],
    eps: float,
    target: str,
    out: Path,
) -> Path:
    """Write ``standstill.csv``, ``standstill.png`` and ``standstill.md`` into ``out`` from
    the seed rows (:func:`seed_row`), every cell's decision rows with a ``group`` column
    (pandas frames), the episodes replayed per cell (name → count), the ε of the figure's
    threshold line and the ``--target`` level; returns the table."""
    import pandas as pd

    table = pd.DataFrame(seeds)
    full = pd.concat([table, group_rows(table)], ignore_index=True)
    write_csv(out / "standstill.csv", full, float_format=None)
    write_figure(table, pd.concat(decisions, ignore_index=True), eps, out / "standstill.png")
    shown = full[[c for c in TABLE_COLUMNS if c in full.columns]]
    counts = ", ".join(f"{k}: {v}" for k, v in list(replayed.items())[:1])
    text = [
        "# Standing still (priqn mechanism --standstill)",
        "",
        f"{len(seeds)} cells, episodes per cell as replayed ({counts}, the first of each "
        "cell's eval/ scenes by eval run, episode, net, density). Shares over decisions; "
        "`no_go_<level>`: no go action (target speed > 0) is left in the subset "
        f"{target} chooses from, and `<level>` is the first level whose subset holds none. "
        "`*_removed`: medians over the decisions that level removed; `*_all`: over all. "
        "`holdout_timeout`: the cell's whole eval/episodes.csv. Measures: docs/mechanism.md.",
        "",
        _markdown(shown),
        "",
        "![standstill](standstill.png)",
        "",
    ]
    atomic_write_text(out / "standstill.md", "\n".join(text))
    return out / "standstill.csv"


EPISODE_KEYS = ["eval_run", "net", "density", "episode"]
"""The columns that name one replayed episode in a per-decision table."""


def episodes_in(frame: Any) -> int:
    """How many episodes a per-decision table holds (0 for an empty one)."""
    return int(frame.groupby(EPISODE_KEYS).ngroups) if len(frame) else 0


def replay_matches(frame: Any, evaluated: Any) -> float:
    """Share of replayed episodes whose length, success and timeout equal their row of
    the cell's ``eval/episodes.csv`` (``evaluated``, pandas)."""
    played = frame.groupby(EPISODE_KEYS, sort=False).agg(
        steps=("decision", "size"),
        success=("episode_success", "first"),
        timeout=("episode_timeout", "first"),
    )
    want = evaluated.set_index(EPISODE_KEYS)[["steps", "success", "timeout"]]
    same = [
        int(want.loc[key, "steps"]) == int(r.steps)
        and bool(want.loc[key, "success"]) == bool(r.success)
        and bool(want.loc[key, "timeout"]) == bool(r.timeout)
        for key, r in played.iterrows()
    ]
    return _rate(same)
