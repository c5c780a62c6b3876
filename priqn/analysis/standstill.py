"""``priqn mechanism --standstill``: why a Pr-IQN policy stands still (descriptive).

Replays evaluated cells on the first scenes of their own ``eval/`` (the one rollout loop,
quantiles recorded, as ``priqn mechanism``) and counts, per decision (docs/mechanism.md,
"Standing still"):

1. **go survival**: whether any "go" action (target speed > 0) is still in the optimal
   subset the ``--target`` level (default ``progress``) chooses from, i.e. in every level
   above it in the total order; if not, the *remover*: the first level whose subset
   holds no go action;
2. **stop vs go**: for ``safety`` and ``risk``, the best stop and the best go action by
   that head's mean over the K fixed-grid quantiles: their raw means (reward units), the
   raw difference, the z-scored QD score difference the comparator saw (the raw
   difference over the per-state spread ``s = max(std, 1e-6)`` of all K·A quantiles), and
   that raw spread;
3. for a scalar agent (IQN): whether its greedy (executed) action stands still.

The counting works on :class:`priqn.evaluation.rollout.RolloutStep` records and needs no
SUMO: :func:`go_survival`, :func:`stop_vs_go`, :func:`standstill_rows`,
:func:`seed_summary`.
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from priqn.analysis.render import markdown_table, write_csv
from priqn.io import atomic_write_bytes, atomic_write_text

COMPARED: tuple[str, ...] = ("safety", "risk")
"""Objectives whose best stop and best go actions are compared per decision."""
REMOVERS: tuple[str, ...] = ("safety", "risk", "lane_keeping")
"""The levels above ``progress`` in the total order, in order (the table's columns)."""
MIN_STD = 1e-6
"""The comparators' floor of the per-state spread (``priqn.preorder.MIN_STD``)."""


# ----------------------------------------------------------------------------- counting


def go_survival(
    subsets_LA: np.ndarray, levels: Sequence[str], above: Sequence[str], go_A: np.ndarray
) -> tuple[bool, str]:
    """``(any go action survives every level of above, the first level of above whose
    subset holds no go action or "")``.

    ``subsets_LA``: bool ``[L, A]`` optimal subsets, L named by ``levels``; ``above``: the
    levels from the root down to the target level's parent (total order); ``go_A``: bool
    ``[A]``, the actions that move (target speed > 0).
    """
    go_A = np.asarray(go_A, dtype=bool)
    for name in above:
        if not (np.asarray(subsets_LA[levels.index(name)], dtype=bool) & go_A).any():
            return False, name
    return True, ""


def stop_vs_go(
    q_KA: np.ndarray,
    go_A: np.ndarray,
    candidates_A: np.ndarray | None = None,
    spread_floor: float = 0.0,
) -> dict[str, float | int]:
    """One objective's fixed-grid quantiles ``[K, A]``: among ``candidates_A`` (the set its
    level chooses from, its parent's subset; None = all actions) the best stop and the
    best go action (argmax of the mean over K), their means, ``raw_diff`` = mean(stop) −
    mean(go), ``z_diff`` = the QD score difference score(stop) − score(go) the comparator
    sees (= raw_diff / s), and ``spread`` = the population std of all K·A entries, with
    ``s = max(spread, 1e-6, spread_floor)`` as in :func:`priqn.preorder.normalised`.
    The level keeps no go action iff ``z_diff`` > ε (QD, a total order). Without a stop
    or a go candidate, those entries are NaN / -1."""
    q = np.asarray(q_KA, dtype=np.float64)
    go_A = np.asarray(go_A, dtype=bool)
    cand_A = np.ones_like(go_A) if candidates_A is None else np.asarray(candidates_A, bool)
    mean_A = q.mean(axis=0)
    spread = float(q.std())
    best = {}
    for name, mask in (("stop", cand_A & ~go_A), ("go", cand_A & go_A)):
        idx = np.flatnonzero(mask)
        best[name] = int(idx[int(np.argmax(mean_A[idx]))]) if idx.size else -1
    mean = {k: float(mean_A[i]) if i >= 0 else math.nan for k, i in best.items()}
    raw = mean["stop"] - mean["go"]
    return {
        "best_stop": best["stop"],
        "best_go": best["go"],
        "mean_stop": mean["stop"],
        "mean_go": mean["go"],
        "raw_diff": raw,
        "z_diff": raw / max(spread, MIN_STD, spread_floor),
        "spread": spread,
    }


def standstill_rows(
    steps: Sequence[Any],
    objectives: Sequence[str],
    above: Sequence[str],
    speeds_A: np.ndarray,
    spread_floor_O: Sequence[float] | None = None,
) -> list[dict[str, Any]]:
    """One episode's :class:`~priqn.evaluation.rollout.RolloutStep` records → one row per
    decision. A decision with optimal subsets (Pr-IQN) gets the go survival through
    ``above`` and :func:`stop_vs_go` of the :data:`COMPARED` heads among ``objectives``
    (head order), each among its parent's subset in ``above`` (the root: all actions);
    one without (IQN) only its action's speed."""
    if not steps or steps[-1].episode is None:
        raise ValueError("standstill_rows: needs one whole episode (its last step ends it)")
    end = steps[-1].episode
    go_A = np.asarray(speeds_A) > 0.0
    rows = []
    for s in steps:
        d = s.decision
        row: dict[str, Any] = {
            "eval_run": s.scene.eval_run,
            "net": s.scene.net,
            "density": s.scene.density,
            "episode": s.scene.episode,
            "decision": s.step,
            "action": s.action,
            "stop": not bool(go_A[s.action]),
            "episode_timeout": bool(end["timeout"]),
            "episode_success": bool(end["success"]),
        }
        if d.subsets_BLA is not None:
            survives, remover = go_survival(d.subsets_BLA[0], d.levels, above, go_A)
            row.update(go_survives=survives, removed_by=remover)
            for name in (o for o in COMPARED if o in objectives and o in above):
                h, i = list(objectives).index(name), list(above).index(name)
                floor = 0.0 if spread_floor_O is None else float(spread_floor_O[h])
                parent = None if i == 0 else d.subsets_BLA[0, d.levels.index(above[i - 1])]
                measures = stop_vs_go(d.quantiles_BHKA[0, h], go_A, parent, floor)
                for key, v in measures.items():
                    row[f"{name}_{key}"] = v
        rows.append(row)
    return rows


def _rate(values: Any) -> float:
    values = np.asarray(values, dtype=float)
    return float(values.mean()) if values.size else math.nan


def _median(values: Any) -> float:
    """The median over the finite values (NaN: the level saw no stop or no go)."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    return float(np.median(values)) if values.size else math.nan


def seed_summary(d: Any) -> dict[str, Any]:
    """One cell's measures from its decision rows (a pandas frame of :func:`standstill_rows`).

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


# ----------------------------------------------------------------------------- replay


def replay(cell: Any, scenes: Sequence[Any], target: str, progress: Any = None) -> Any:
    """Play ``scenes`` (a :class:`priqn.analysis.mechanism.ReplayCell`'s) with its policy,
    quantiles recorded; its :func:`standstill_rows` (pandas)."""
    import pandas as pd
    import torch

    from priqn.env.intersection import action_grid
    from priqn.env.vector import make_vector_env
    from priqn.evaluation.rollout import rollout
    from priqn.evaluation.targets import evaluation_env
    from priqn.run.folder import RunFolder

    policy = RunFolder(cell.path).load_policy(device="cpu", snapshot=cell.snapshot)
    agent = policy.agent
    above: tuple[str, ...] = ()
    floor = None
    if agent.subsets is not None:
        above = _above(agent.subsets.preorder, target)
        if agent.subsets.scale is not None:
            floor = [float(v) for v in agent.subsets.scale.floor().reshape(-1)]
    env_cfg = evaluation_env(policy.env_config, cell.eval_config, None)
    speeds_A = action_grid(env_cfg)[:, 0]
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    venv = make_vector_env(env_cfg, 1, seed=cell.eval_config.seed)
    rows: list[dict[str, Any]] = []
    open_steps: dict[Any, list[Any]] = {}
    try:
        for step in rollout(policy, venv, scenes, quantiles=agent.subsets is not None):
            open_steps.setdefault(step.scene, []).append(step)
            if step.episode is None:
                continue
            played = open_steps.pop(step.scene)
            rows.extend(standstill_rows(played, agent.objectives, above, speeds_A, floor))
            if progress is not None:
                progress.update(1)
    finally:
        venv.close()
        torch.set_num_threads(threads)
    return pd.DataFrame(rows)


def _above(preorder: Any, target: str) -> tuple[str, ...]:
    """The levels above ``target`` in a total order, root first (error otherwise)."""
    from priqn.errors import PriqnError

    if not preorder.is_chain():
        raise PriqnError("--standstill: needs a total-order preorder (a chain)")
    order = tuple(preorder.topological_order())
    if target not in order:
        raise PriqnError(f"--target {target}: not a level ({', '.join(order)})")
    return order[: order.index(target)]


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


def analyse(
    cells: Sequence[Any],
    out: Path,
    decisions_dir: Path,
    pick_scenes: Callable[[Any], Sequence[Any]],
    target: str = "progress",
) -> Path:
    """Replay every cell (``pick_scenes(cell)``: its scenes), write ``standstill.csv``,
    ``standstill.md`` and ``standstill.png`` into ``out`` and one decision file per cell
    into ``decisions_dir`` (a file there with the asked-for episodes is not replayed)."""
    import pandas as pd
    from tqdm.auto import tqdm

    from priqn.run.folder import RunFolder

    scenes = {c.name: list(pick_scenes(c)) for c in cells}
    seeds, frames = [], []
    with tqdm(total=sum(map(len, scenes.values())), desc="standstill", unit="ep") as bar:
        for cell in cells:
            cached = decisions_dir / f"{cell.name}.csv"
            frame = pd.read_csv(cached) if cached.is_file() else None
            if frame is None or episodes_in(frame) != len(scenes[cell.name]):
                frame = replay(cell, scenes[cell.name], target, progress=bar)
                write_csv(cached, frame, float_format=None)
            else:
                bar.update(len(scenes[cell.name]))
            group = cell.name.split("__seed")[0]
            frames.append(frame.assign(group=group))
            row = {"group": group, "run": cell.name, "seed": RunFolder(cell.path).config().seed}
            row["holdout_timeout"] = _rate(cell.episodes["timeout"].astype(bool))
            row["replay_matches"] = replay_matches(frame, cell.episodes)
            row.update(seed_summary(frame))
            seeds.append(row)
    table = pd.DataFrame(seeds)
    full = pd.concat([table, group_rows(table)], ignore_index=True)
    write_csv(out / "standstill.csv", full, float_format=None)
    eps = max((float(c.episodes["eps"].iloc[0]) for c in cells if "eps" in c.episodes), default=0.2)
    write_figure(table, pd.concat(frames, ignore_index=True), eps, out / "standstill.png")
    shown = full[[c for c in TABLE_COLUMNS if c in full.columns]]
    counts = ", ".join(f"{k}: {len(v)}" for k, v in list(scenes.items())[:1])
    text = [
        "# Standing still (priqn mechanism --standstill)",
        "",
        f"{len(cells)} cells, episodes per cell as replayed ({counts}, the first of each "
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
