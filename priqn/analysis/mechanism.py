"""``priqn mechanism``: why Pr-IQN leaves the road, measured over many episodes (descriptive).

Replays evaluated Pr-IQN cells on the scenes of their own ``eval/`` (the same reset and
acting seeds, the one rollout loop :func:`priqn.evaluation.rollout.rollout` with the quantiles
recorded) and measures per training seed (docs/mechanism.md):

1. **removal**: how often the top level (safety) leaves out of its optimal subset the
   action a lower objective's head would take on its own (its greedy action), and how
   often an episode ends in a violation (collision or off-road) within a few decisions
   after such a removal, against the decisions without one;
2. **calibration**: what the safety head's quantiles predict at the executed action
   (whatever the top level examined) — the predicted probability of the safety penalty
   (share of the K fixed-grid quantiles at or below half the penalty) and the predicted
   return — against whether the episode ended in a violation (a reliability table and
   curve);
3. **collapsed vs healthy**: the same measures for seeds whose hold-out success (all of
   their ``eval/episodes.csv``) is below a threshold, and for the others.

Writes into ``--out``: ``mechanism.csv`` and ``mechanism.md`` (one row per seed, then
one per group; the reliability table below it in the markdown), ``reliability.csv``,
``mechanism.png`` (the figure) and ``decisions/<run>.csv`` (every replayed decision; a
run whose file is there with the asked-for episodes is not replayed again).

The counting works on :class:`priqn.evaluation.rollout.RolloutStep` records and needs no SUMO:
:func:`decision_rows` (one episode's steps → rows), :func:`seed_summary`,
:func:`reliability_table`.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from priqn.agents.labels import budget_text
from priqn.analysis.load import read_episodes
from priqn.analysis.render import markdown_table, write_csv
from priqn.analysis.standstill import EPISODE_KEYS, episodes_in
from priqn.errors import PriqnError
from priqn.io import atomic_write_bytes, atomic_write_text, read_json
from priqn.run.folder import RunFolder

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
        name = RunFolder.snapshot_evaluation(self.snapshot) if self.snapshot else ""
        return f"{RunFolder.evaluation_folder(name)}/"


# ----------------------------------------------------------------------------- counting


def decision_rows(
    steps: Sequence[Any],
    objectives: Sequence[str],
    levels: Sequence[str],
    cfg: MechanismConfig,
    penalty: float,
    gamma: float,
    speeds_A: np.ndarray,
) -> list[dict[str, Any]]:
    """One episode's :class:`~priqn.evaluation.rollout.RolloutStep` records (in order, the last one
    with the episode's values) → one row per decision.

    ``objectives``: the heads' objectives (per-objective heads); ``levels``: the L axis of
    the decisions' subsets; ``penalty``: the safety penalty (> 0); ``gamma``: the
    discount, for the realised safety return-to-go the safety head predicts; ``speeds_A``:
    each action's target speed [m/s] (:func:`priqn.env.intersection.action_grid`).
    """
    if not steps or steps[-1].episode is None:
        raise ValueError("decision_rows: needs one whole episode (its last step ends it)")
    end = steps[-1].episode
    violation = bool(end["collision"] or end["off_road"])
    safety_head, top_level = objectives.index(CALIBRATED), levels.index(cfg.top)
    lower = [o for o in levels if o != cfg.top]
    rewards_T = np.array([float(s.reward_N[safety_head]) for s in steps])
    # Realised discounted safety return-to-go, from each decision on.
    to_go_T = np.zeros(len(steps))
    acc = 0.0
    for t in range(len(steps) - 1, -1, -1):
        acc = rewards_T[t] + gamma * acc
        to_go_T[t] = acc
    scene = steps[0].scene
    rows = []
    for t, s in enumerate(steps):
        d = s.decision
        q_HKA, subsets_LA = d.quantiles_BHKA[0], d.subsets_BLA[0]
        means_HA = q_HKA.mean(axis=1)
        q_K = q_HKA[safety_head, :, s.action]
        left = len(steps) - 1 - t  # decisions after this one
        row: dict[str, Any] = {
            "eval_run": scene.eval_run,
            "net": scene.net,
            "density": scene.density,
            "episode": scene.episode,
            "decision": s.step,
            "action": s.action,
        }
        keeps_A = subsets_LA[top_level]
        greedy_O = {o: int(np.argmax(means_HA[objectives.index(o)])) for o in lower}
        row.update(
            speed_mps=float(speeds_A[s.action]),
            top_max_speed_mps=float(speeds_A[keeps_A].max()),
            lower_greedy_speed_mps=float(speeds_A[greedy_O[cfg.lower]]),
        )
        removed = []
        for o, greedy in greedy_O.items():
            row[f"greedy_{o}"] = greedy
            row[f"removes_{o}"] = not bool(keeps_A[greedy])
            removed.append(row[f"removes_{o}"])
        row.update(
            removes_any=any(removed),
            size_top=int(keeps_A.sum()),
            size_leaf=int(d.leaf_BA[0].sum()),
            calibrated_head=CALIBRATED,
            pred_violation=float(np.mean(q_K <= -penalty / 2.0)),
            pred_return=float(q_K.mean()),
            return_to_go=float(to_go_T[t]),
            episode_violation=violation,
            episode_off_road=bool(end["off_road"]),
            episode_collision=bool(end["collision"]),
            episode_timeout=bool(end["timeout"]),
            violation_within=violation and left < cfg.horizon,
            off_road_within=bool(end["off_road"]) and left < cfg.horizon,
        )
        rows.append(row)
    return rows


def _rate(values: Any) -> float:
    values = np.asarray(values, dtype=float)
    return float(values.mean()) if values.size else math.nan


def seed_summary(decisions: Any, cfg: MechanismConfig) -> dict[str, Any]:
    """One seed's measures from its decision rows (a pandas frame of :func:`decision_rows`).

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


# ----------------------------------------------------------------------------- replay


@dataclasses.dataclass(frozen=True)
class ReplayCell:
    """One evaluated Pr-IQN cell and what its replay needs."""

    path: Path
    """The run folder."""
    name: str
    """Its name (``<row>__seed<k>``)."""
    holdout_success: float
    """Success rate over its whole evaluation (``eval/`` or ``eval-at<N>/``)."""
    episodes: Any
    """That evaluation's ``episodes.csv`` (pandas)."""
    eval_config: Any
    """The :class:`priqn.evaluation.protocol.EvalConfig` it was evaluated with."""
    net_ids: tuple[str, ...]
    """The hold-out nets it was evaluated on."""
    snapshot: int = 0
    """0: the run's final policy and ``eval/``; N: the policy it kept at N decisions and
    that policy's evaluation ``eval-at<N>/``."""


def load_cell(path: Path, snapshot: int = 0) -> ReplayCell:
    """A run folder with a complete ``eval/`` (``snapshot`` N: ``eval-at<N>/``): its
    episodes and evaluation config."""

    from priqn.evaluation.protocol import EvalConfig
    from priqn.sim.scenario import manifest_hash

    run = RunFolder(path)
    eval_dir = run.evaluation_dir(RunFolder.snapshot_evaluation(snapshot) if snapshot else "")
    meta_path = eval_dir / RunFolder.META
    if snapshot and run.is_run():
        keep_at = list(run.config().checkpoint.keep_at)
        if snapshot not in keep_at:
            raise PriqnError(
                f"{path}: kept no policy at {snapshot} decisions (checkpoint.keep_at = {keep_at})"
            )
        if not meta_path.is_file():
            raise PriqnError(
                f"{path}: {run.rel(eval_dir)} not evaluated; "
                f"run priqn evaluate {path} --snapshot {snapshot}"
            )
    if not run.is_run() or not meta_path.is_file():
        raise PriqnError(f"{path}: not an evaluated run folder (no config.toml or eval/meta.json)")
    meta = read_json(meta_path)
    known = {f.name for f in dataclasses.fields(EvalConfig)}
    fields = {
        k: (tuple(v) if isinstance(v, list) else v)
        for k, v in (meta.get("eval_config") or {}).items()
        if k in known
    }
    eval_cfg = EvalConfig(**fields)
    if eval_cfg.nets or eval_cfg.acting != "own":
        raise PriqnError(
            f"{path}: {run.rel(eval_dir)} is not a hold-out evaluation of the policy's own acting"
        )
    if meta.get("holdout_hash") != manifest_hash(eval_cfg.family):
        raise PriqnError(
            f"{meta_path}: evaluated on another version of the {eval_cfg.family!r} nets "
            "(holdout_hash differs from the shipped manifest); its scenes cannot be replayed"
        )
    episodes = read_episodes(eval_dir, resolve=False)
    return ReplayCell(
        run.path,
        run.name + (f"@{budget_text(snapshot)}" if snapshot else ""),
        float(episodes["success"].astype(float).mean()),
        episodes,
        eval_cfg,
        tuple(meta.get("holdout_nets") or ()),
        snapshot,
    )


def replay_scenes(scenes: Sequence[Any], episodes: int) -> list[Any]:
    """The first ``episodes`` (0 = all) of a cell's evaluation scenes in the order
    (eval run, episode, net, density): every net and density of the first evaluation run
    in turn, so a subset is balanced whatever a cell's episodes per cell. Scenes depend
    only on the eval seed and these indices, so cells evaluated with more episodes per
    cell (table2_cpu: 20) replay the same first scenes as the others (headline: 6)."""
    ordered = sorted(scenes, key=lambda s: (s.eval_run, s.episode, s.net, s.density))
    return ordered[:episodes] if episodes else ordered


def replay_cell(cell: ReplayCell, cfg: MechanismConfig, progress: Any = None) -> Any:
    """Replay the first ``cfg.episodes`` scenes of ``cell``'s evaluation; its decision rows
    (pandas), with ``replay_matches``: the episode ended as ``eval/episodes.csv`` says
    (outcome flags and length)."""
    import pandas as pd
    import torch

    from priqn.env.intersection import action_grid
    from priqn.env.vector import make_vector_env
    from priqn.evaluation.protocol import make_scenes
    from priqn.evaluation.rollout import rollout
    from priqn.evaluation.targets import evaluation_env

    policy = RunFolder(cell.path).load_policy(device="cpu", snapshot=cell.snapshot)
    agent = policy.agent
    if agent.subsets is None or agent.spec.reward_rule != "per-objective":
        raise PriqnError(f"{cell.path}: a {agent.name} run; the mechanism needs a Pr-IQN run")
    levels = tuple(agent.subsets.preorder.objectives)
    for name, what in ((cfg.top, "--top"), (cfg.lower, "--lower")):
        if name not in levels:
            raise PriqnError(
                f"{what} {name}: not an objective of {cell.name} ({', '.join(levels)})"
            )
    if CALIBRATED not in agent.objectives:
        raise PriqnError(
            f"{cell.path}: no {CALIBRATED} head to calibrate ({', '.join(agent.objectives)})"
        )
    scenes = replay_scenes(make_scenes(cell.eval_config, cell.net_ids), cfg.episodes)
    env_cfg = evaluation_env(policy.env_config, cell.eval_config, None)
    reward = env_cfg.reward
    penalty = min(reward.collision_penalty, reward.off_road_penalty)
    gamma = float(RunFolder(cell.path).config().learner.gamma)
    speeds_A = action_grid(env_cfg)[:, 0]
    expected = cell.episodes.set_index(["eval_run", "net", "density", "episode"])
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # one state at a time: more threads only fight the env workers
    venv = make_vector_env(env_cfg, min(cfg.workers, len(scenes)), seed=cell.eval_config.seed)
    rows: list[dict[str, Any]] = []
    open_steps: dict[Any, list[Any]] = {}
    try:
        for step in rollout(policy, venv, scenes, quantiles=True):
            open_steps.setdefault(step.scene, []).append(step)
            if step.episode is None:
                continue
            played = open_steps.pop(step.scene)
            new = decision_rows(played, agent.objectives, levels, cfg, penalty, gamma, speeds_A)
            want = expected.loc[step.scene.cell + (step.scene.episode,)]
            matches = int(want["steps"]) == len(played) and all(
                bool(want[k]) == bool(step.episode[k]) for k in ("success", "collision", "off_road")
            )
            for r in new:
                r["replay_matches"] = matches
            rows.extend(new)
            if progress is not None:
                progress.update(1)
    finally:
        venv.close()
        torch.set_num_threads(threads)
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


def analyse(paths: Sequence[str | Path], out: Path, cfg: MechanismConfig) -> Path:
    """Replay every cell under ``paths``, write the outputs into ``out``; returns the table."""
    import pandas as pd
    from tqdm.auto import tqdm

    from priqn.evaluation.targets import find_runs

    cells = [load_cell(p, cfg.snapshot) for p in find_runs(paths)]
    seeds, frames = [], {}
    total = sum(
        len(c.episodes) if not cfg.episodes else min(cfg.episodes, len(c.episodes)) for c in cells
    )
    with tqdm(total=total, desc="mechanism", unit="ep", disable=None) as bar:
        for cell in cells:
            cached = cfg.decisions_dir(out) / f"{cell.name}.csv"
            want = min(cfg.episodes or len(cell.episodes), len(cell.episodes))
            frame = pd.read_csv(cached) if cached.is_file() else None
            stale = frame is not None and not set(_NEWEST_COLUMNS) <= set(frame.columns)
            if frame is None or stale or episodes_in(frame) != want:
                frame = replay_cell(cell, cfg, progress=bar)
                write_csv(cached, frame, float_format=None)
            else:
                bar.update(want)
            frames[cell.name] = frame
            row = {
                "run": cell.name,
                "row": cell.name.split("__seed")[0],
                "seed": int(RunFolder(cell.path).config().seed),
                "holdout_success": cell.holdout_success,
                "collapsed": cell.holdout_success < cfg.collapsed_below,
                "replay_matches": _rate(frame.groupby(EPISODE_KEYS)["replay_matches"].first()),
            }
            row.update(seed_summary(frame, cfg))
            seeds.append(row)
    table = pd.DataFrame(seeds)
    full = pd.concat([table, group_rows(table)], ignore_index=True)
    write_csv(out / "mechanism.csv", full, float_format=None)

    reliability = {}
    for group in GROUPS:
        names = [
            r["run"] for r in seeds if group == "all" or r["collapsed"] == (group == "collapsed")
        ]
        if names:
            reliability[group] = reliability_table(pd.concat([frames[n] for n in names]))
    rel = pd.concat([t.assign(group=g) for g, t in reliability.items()], ignore_index=True)
    write_csv(out / "reliability.csv", rel, float_format=None)
    write_figure(table, reliability, cfg, out / "mechanism.png")
    columns = [c.format(lower=cfg.lower) for c in MARKDOWN_COLUMNS]
    text = [
        "# Pr-IQN mechanism (priqn mechanism)",
        "",
        f"{len(cells)} seeds, {cfg.episodes or 'all'} episodes each (the first of each cell's "
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


_NEWEST_COLUMNS = ("episode_timeout", "speed_mps", "calibrated_head")
"""Decision columns an older priqn did not write: a cached file without them is replayed
(before ``calibrated_head``, ``--top risk`` calibrated the risk head)."""


# ----------------------------------------------------------------------------- CLI


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("runs", nargs="+", help="evaluated Pr-IQN run folders, or folders of them")
    parser.add_argument("--out", required=True, help="output folder (table, figure, decisions/)")
    parser.add_argument(
        "--episodes",
        type=int,
        default=DEFAULT_EPISODES,
        help=f"episodes per seed, the first of its eval/ scenes by (eval run, episode, net, "
        f"density) (default {DEFAULT_EPISODES}: the headline cells' first evaluation run; 0 = all)",
    )
    parser.add_argument("--top", default="safety", help="level whose removals count (safety)")
    parser.add_argument(
        "--lower", default="lane_keeping", help="lower objective whose greedy action (lane_keeping)"
    )
    parser.add_argument(
        "--horizon", type=int, default=5, help="decisions after a removal that count (default 5)"
    )
    parser.add_argument(
        "--collapsed-below",
        type=float,
        default=DEFAULT_COLLAPSED_BELOW,
        help=f"hold-out success below which a seed is collapsed (default {DEFAULT_COLLAPSED_BELOW})",
    )
    parser.add_argument("--workers", type=int, default=1, help="env worker processes (default 1)")
    parser.add_argument(
        "--standstill",
        action="store_true",
        help="instead: why the policy stands still (does any go action reach progress's "
        "choice, which level removed the last one, safety/risk stop-vs-go differences raw "
        "and z-scored; IQN cells: greedy stop share); writes standstill.md/.csv/.png",
    )
    parser.add_argument(
        "--decisions",
        default="",
        metavar="DIR",
        help="folder of the per-decision files (default OUT/decisions)",
    )
    parser.add_argument(
        "--snapshot",
        type=int,
        default=0,
        metavar="N",
        help="replay the policy each run kept at N decisions (checkpoint.keep_at) on the "
        "scenes of its eval-at<N>/ (default: the final policy on eval/)",
    )


def run(args: argparse.Namespace) -> int:
    if args.episodes < 0:
        raise PriqnError(f"--episodes: expected >= 0 (0 = all), got {args.episodes}")
    if args.horizon < 1:
        raise PriqnError(f"--horizon: expected >= 1 decision, got {args.horizon}")
    if args.workers < 1:
        raise PriqnError(f"--workers: expected >= 1, got {args.workers}")
    if args.snapshot < 0:
        raise PriqnError(
            f"--snapshot: expected a kept budget in decisions (0: the final policy), got {args.snapshot}"
        )
    if not 0.0 <= args.collapsed_below <= 1.0:
        raise PriqnError(
            f"--collapsed-below: expected a success rate in [0, 1], got {args.collapsed_below}"
        )
    cfg = MechanismConfig(
        episodes=args.episodes,
        top=args.top,
        lower=args.lower,
        horizon=args.horizon,
        collapsed_below=args.collapsed_below,
        workers=args.workers,
        snapshot=args.snapshot,
        decisions=args.decisions,
    )
    if args.standstill:
        print(_standstill(args.runs, Path(args.out), cfg))
        return 0
    print(analyse(args.runs, Path(args.out), cfg))
    return 0


def _standstill(paths: Sequence[str | Path], out: Path, cfg: MechanismConfig) -> Path:
    """``--standstill``: :func:`priqn.analysis.standstill.analyse` on the cells under
    ``paths`` (any agent), each on the first ``cfg.episodes`` scenes of its evaluation."""
    from priqn.analysis import standstill
    from priqn.evaluation.protocol import make_scenes
    from priqn.evaluation.targets import find_runs

    cells = [load_cell(p, cfg.snapshot) for p in find_runs(paths)]

    def scenes(cell: ReplayCell) -> list[Any]:
        return replay_scenes(make_scenes(cell.eval_config, cell.net_ids), cfg.episodes)

    return standstill.analyse(cells, out, cfg.decisions_dir(out), scenes)
