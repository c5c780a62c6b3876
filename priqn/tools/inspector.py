"""``priqn inspect``: why a policy chose each action, decision by decision.

Re-runs a trained policy on evaluation scenes (the scene seeds of ``priqn evaluate``,
so an inspected episode is the evaluated one) through the one rollout loop of
``priqn evaluate`` (:func:`priqn.evaluation.rollout.rollout`, asked for quantiles and
frames; one forward pass per decision) and writes into ``--out``:

- ``index.html``: one self-contained page (frames beside it in ``frames/``; no server,
  no network) with a slider and a play button. Each frame shows the BEV + LiDAR view,
  the action grid (v_f × d_f) as a heat map per head with each preorder level's optimal
  subset S_r outlined, the leaf set and the chosen action, a quantile fan of the chosen
  action and of the best action the preorder removed, and the reward terms and running
  returns; every agent gets its comparable view (IQN: its head; Ensemble: each head and
  their mean; MA-IQN: each objective and the weighted sum it acts on; Pr-IQN: subsets).
- ``episode.gif``: the same frames as an animation.
- ``decisions.csv``: per decision the action, the reward vector and running returns,
  |S_r| per level and, for every objective's head, the level that removed its greedy action.
- ``quantiles.npz``: the fixed-grid quantiles ``[T, H, K, A]`` behind every frame, and the
  subsets ``[T, N, A]`` / leaf ``[T, A]`` the page shows (for checks and your own plots).
- ``summary.png``: how often each level was the one that pruned, and mean |S_r| per level.

``--near-greedy EPS`` inspects a baseline acting as the acting-randomness control of
``priqn evaluate --acting near-greedy`` (the same scenes and acting seeds): the orange
dots are then the near-greedy set it sampled from (``size_near_greedy`` in decisions.csv).
"""

from __future__ import annotations

import argparse
import dataclasses
import html
import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from priqn.checks import check_acting_eps, check_density
from priqn.errors import PriqnError
from priqn.io import atomic_write_bytes, atomic_write_text
from priqn.run.checkpointer import load_policy
from priqn.run.evaluations import eval_meta
from priqn.run.folder import RunFolder
from priqn.tools.decisions import KEPT, greedy_removals


@dataclasses.dataclass(frozen=True)
class InspectConfig:
    """Which evaluation scenes to inspect."""

    net: str = ""
    """Net ``"<family>/<net_id>"`` ('' = the first net of the evaluation family)."""
    density: float = 0.0
    """Traffic density (0 = the first evaluation density)."""
    command: str = ""
    """Override the scene's route command (left / straight / right; '' = the scene's own;
    an override changes the scene, so it is no longer the evaluated episode)."""
    seed: int | None = None
    """Evaluation seed (None = the run's own evaluation seed, or EvalConfig's default)."""
    eval_run: int = 0
    """Evaluation run whose scenes are inspected (0-based)."""
    episodes: int = 1
    """Episodes of the (eval run, net, density) cell to inspect, from the first."""
    frame_dpi: int = 80
    """Resolution of the frame images [dots per inch]."""
    near_greedy_eps: float | None = None
    """Inspect the acting-randomness control at this ε (``priqn evaluate --acting
    near-greedy``; IQN / Ensemble / MA-IQN only): the orange dots are its near-greedy set."""


@dataclasses.dataclass(frozen=True)
class InspectedDecision:
    """Everything the page shows about one decision."""

    episode: int
    """Index of the inspected episode (0-based)."""
    step: int
    """Decision index within the episode (0-based)."""
    action: int
    """The chosen action."""
    quantiles_HKA: np.ndarray
    """float32 ``[H, K, A]``: the fixed-grid quantiles the policy acted on."""
    subsets_NA: np.ndarray | None
    """bool ``[N, A]``: each preorder level's optimal subset (None without a preorder)."""
    leaf_A: np.ndarray | None
    """bool ``[A]``: the set the action was sampled from (leaf or near-greedy set)."""
    reward_O: np.ndarray
    """``[O]``: the reward vector the decision earned (O = the run's objectives)."""
    returns_O: np.ndarray
    """``[O]``: the episode's returns up to and including this decision."""
    frame: np.ndarray
    """RGB image of the state decided on (BEV | LiDAR)."""


# ----------------------------------------------------------------------------- scenes


def inspection_scenes(run_dir: Path, cfg: InspectConfig) -> tuple[list[Any], Any]:
    """The evaluation scenes to inspect, and the EvalConfig they come from."""
    from priqn.evaluation.protocol import EvalConfig, make_scenes
    from priqn.sim.scenario import load_manifest

    run = RunFolder(run_dir)
    fields: dict[str, Any] = {}
    if run.eval_meta_path.is_file():  # the scenes the run was evaluated on
        fields = dict(eval_meta(run).get("eval_config") or {})
    base = EvalConfig()
    known = {f.name for f in dataclasses.fields(EvalConfig)}
    kw = {k: (tuple(v) if isinstance(v, list) else v) for k, v in fields.items() if k in known}
    if cfg.seed is not None:
        kw["seed"] = cfg.seed
    family = cfg.net.split("/")[0] if cfg.net else kw.get("family", base.family)
    kw["family"] = family
    kw["eval_runs"] = max(int(kw.get("eval_runs", base.eval_runs)), cfg.eval_run + 1)
    kw["episodes_per_cell"] = max(int(kw.get("episodes_per_cell", 1)), cfg.episodes)
    densities = tuple(kw.get("densities", base.densities))
    if cfg.density and cfg.density not in densities:
        densities = (*densities, float(cfg.density))
    kw["densities"] = densities
    eval_cfg = EvalConfig(**kw)
    net_ids = sorted(n["id"] for n in load_manifest(family)["nets"])
    net = cfg.net or f"{family}/{net_ids[0]}"
    if net.split("/", 1)[-1] not in net_ids:
        raise PriqnError(
            f"--net: {net!r} is not a net of family {family!r} "
            f"(valid: {', '.join(f'{family}/{n}' for n in net_ids)})"
        )
    density = float(cfg.density or densities[0])
    scenes = [
        s
        for s in make_scenes(eval_cfg, net_ids)
        if s.net == net and s.density == density and s.eval_run == cfg.eval_run
    ][: cfg.episodes]
    if cfg.command:
        scenes = [dataclasses.replace(s, command=cfg.command) for s in scenes]
    return scenes, eval_cfg


# ----------------------------------------------------------------------------- rollout


def rollout(policy: Any, vec_env: Any, scenes: list[Any]) -> list[InspectedDecision]:
    """Play each scene exactly as ``priqn evaluate`` does (the one rollout loop,
    :func:`priqn.evaluation.rollout.rollout`, with quantiles and frames), recording every decision.

    ``vec_env`` renders (``render_mode="rgb_array"``); one forward pass per decision.
    """
    from tqdm import tqdm

    from priqn.evaluation.rollout import rollout as play

    decisions: list[InspectedDecision] = []
    episode = {scene: e for e, scene in enumerate(scenes)}
    returns: dict[Any, np.ndarray] = {}
    with tqdm(total=len(scenes), desc="inspect", unit="episode", disable=None) as bar:
        for s in play(policy, vec_env, scenes, quantiles=True, frames=True):
            d = s.decision
            total = returns.get(s.scene, np.zeros(len(policy.agent.objectives))) + s.reward_N
            returns[s.scene] = total
            decisions.append(
                InspectedDecision(
                    episode[s.scene],
                    s.step,
                    s.action,
                    d.quantiles_BHKA[0],
                    None if d.subsets_BLA is None else d.subsets_BLA[0],
                    None if d.leaf_BA is None else d.leaf_BA[0],
                    s.reward_N,
                    total.copy(),
                    s.frame,
                )
            )
            if s.episode is not None:
                bar.update(1)
    return decisions


# ----------------------------------------------------------------------------- analysis


def head_names(agent: Any) -> list[str]:
    """What each head of ``agent`` estimates."""
    if agent.spec.reward_rule == "per-objective":
        return list(agent.objectives)
    if agent.num_heads == 1:
        return ["weighted sum"]
    return [f"head {h} (weighted sum)" for h in range(agent.num_heads)]


def pruned_by(d: InspectedDecision, preorder: Any) -> dict[str, str]:
    """For each objective's head: the first level (topological order, then the leaf)
    whose set does not contain that head's greedy action (:data:`KEPT` = it survives to
    the leaf); :func:`priqn.tools.decisions.greedy_removals`."""
    if d.subsets_NA is None:
        return {}
    levels, order, subsets_LA = preorder.objectives, preorder.topological_order(), d.subsets_NA
    if d.leaf_A is not None:  # the leaf is the last set an action can be removed from
        levels, order = (*levels, "leaf"), (*order, "leaf")
        subsets_LA = np.concatenate([subsets_LA, d.leaf_A[None]])
    removals = greedy_removals(d.quantiles_HKA, preorder.objectives, subsets_LA, levels, order)
    return {name: level for name, (_, level) in removals.items()}


def decision_rows(decisions: list[InspectedDecision], agent: Any, table: np.ndarray) -> list[dict]:
    """``decisions.csv`` rows."""
    preorder = None if agent.subsets is None else agent.subsets.preorder
    rows = []
    for d in decisions:
        row: dict[str, Any] = {
            "episode": d.episode,
            "decision": d.step,
            "action": d.action,
            "v_f_mps": round(float(table[d.action, 0]), 4),
            "d_f_m": round(float(table[d.action, 1]), 4),
        }
        for i, o in enumerate(agent.objectives):
            row[f"reward_{o}"] = round(float(d.reward_O[i]), 6)
        for i, o in enumerate(agent.objectives):
            row[f"return_{o}"] = round(float(d.returns_O[i]), 6)
        if preorder is not None:
            for n, o in enumerate(preorder.objectives):
                row[f"size_{o}"] = int(d.subsets_NA[n].sum())
            row["size_leaf"] = int(d.leaf_A.sum())
            for o, level in pruned_by(d, preorder).items():
                row[f"pruned_by_{o}"] = level
        elif d.leaf_A is not None:  # the near-greedy control
            row["size_near_greedy"] = int(d.leaf_A.sum())
        rows.append(row)
    return rows


# ----------------------------------------------------------------------------- pictures


def _panel_values(d: InspectedDecision, agent: Any) -> list[tuple[str, np.ndarray]]:
    """(title, values [A]) of every heat map: each head, plus the acting rule's view."""
    means_HA = d.quantiles_HKA.mean(axis=1)
    names = head_names(agent)
    panels = [(names[h], means_HA[h]) for h in range(means_HA.shape[0])]
    if agent.spec.acting_rule == "argmax-mean-of-heads":
        panels.append(("acting: mean of heads", means_HA.mean(axis=0)))
    elif agent.spec.acting_rule == "argmax-sum-of-heads":
        w = agent.reward_weights_O.cpu().numpy()
        panels.append(("acting: weighted sum", (w[:, None] * means_HA).sum(axis=0)))
    return panels


def frame_figure(
    d: InspectedDecision, agent: Any, table_A2: np.ndarray, shape_VD: tuple[int, int], dpi: int
) -> bytes:
    """One decision as a PNG: view, heat maps with subsets, quantile fans, rewards."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    panels = _panel_values(d, agent)
    n_v, n_d = shape_VD
    cols = max(len(panels), 3)
    fig = plt.figure(figsize=(2.3 * cols, 7.2), dpi=dpi)
    grid = fig.add_gridspec(3, cols, height_ratios=[1.25, 1.0, 0.9])
    ax = fig.add_subplot(grid[0, : cols // 2 + 1])
    ax.imshow(d.frame)
    ax.set_axis_off()
    ax.set_title(f"episode {d.episode}, decision {d.step}: BEV | LiDAR", fontsize=9)
    ax = fig.add_subplot(grid[0, cols // 2 + 1 :])
    ax.set_axis_off()
    lines = [f"{'':<13}{'reward':>9}{'return':>9}"] + [
        f"{o:<13}{d.reward_O[i]:>9.3f}{d.returns_O[i]:>9.2f}"
        for i, o in enumerate(agent.objectives)
    ]
    ax.text(0, 0.95, "\n".join(lines), family="monospace", fontsize=8, va="top")
    for c, (title, values_A) in enumerate(panels):
        ax = fig.add_subplot(grid[1, c])
        ax.imshow(values_A.reshape(n_v, n_d), cmap="viridis", origin="lower", aspect="auto")
        ax.set_title(title, fontsize=8)
        ax.set_xticks(range(n_d), [f"{x:g}" for x in table_A2[:n_d, 1]])
        ax.set_yticks(range(n_v), [f"{x:g}" for x in table_A2[::n_d, 0]])
        ax.set_xlabel("lateral offset d_f [m]", fontsize=7)
        ax.set_ylabel("target speed v_f [m/s]", fontsize=7)
        ax.tick_params(labelsize=6)
        if d.subsets_NA is not None and c < d.subsets_NA.shape[0]:
            for a in np.flatnonzero(d.subsets_NA[c]):
                v, k = divmod(int(a), n_d)
                ax.add_patch(Rectangle((k - 0.5, v - 0.5), 1, 1, fill=False, ec="cyan", lw=1.2))
        if d.leaf_A is not None:
            for a in np.flatnonzero(d.leaf_A):
                v, k = divmod(int(a), n_d)
                ax.plot(k, v, marker=".", color="orange", ms=3)
        v, k = divmod(d.action, n_d)
        ax.add_patch(Rectangle((k - 0.5, v - 0.5), 1, 1, fill=False, ec="red", lw=2))
    # Quantile fans: the chosen action vs the best action (by mean) the preorder removed.
    taus = (np.arange(d.quantiles_HKA.shape[1]) + 0.5) / d.quantiles_HKA.shape[1]
    removed = None if d.leaf_A is None else ~d.leaf_A
    for c in range(min(d.quantiles_HKA.shape[0], cols)):
        ax = fig.add_subplot(grid[2, c])
        q_KA = d.quantiles_HKA[c]
        ax.plot(taus, q_KA[:, d.action], color="red", lw=1.5, label="chosen")
        if removed is not None and removed.any():
            means = np.where(removed, q_KA.mean(axis=0), -np.inf)
            best = int(np.argmax(means))
            ax.plot(taus, q_KA[:, best], color="grey", lw=1, ls="--", label="best removed")
        ax.set_title(panels[c][0], fontsize=8)
        ax.set_xlabel("τ", fontsize=7)
        ax.tick_params(labelsize=6)
        if c == 0:
            ax.legend(fontsize=6)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return buf.getvalue()


def summary_figure(rows: list[dict], preorder: Any, path: Path) -> None:
    """``summary.png``: the chosen manoeuvre decision by decision.

    For a preorder agent also how often each level pruned a head's greedy action, and the
    mean |S_r| per level.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mosaic = (
        [["v"], ["d"]] if preorder is None else [["prune", "size", "v"], ["prune", "size", "d"]]
    )
    fig, axes = plt.subplot_mosaic(
        mosaic, figsize=(4.6 * len(mosaic[0]), 4.0), layout="constrained"
    )
    # What the policy chose, decision by decision: a policy that waits shows v_f = 0.
    x = np.arange(len(rows))
    episode_starts = [
        i for i in range(1, len(rows)) if rows[i]["episode"] != rows[i - 1]["episode"]
    ]
    for key, column, name, color in (
        ("v", "v_f_mps", "v_f [m/s]", "tab:blue"),
        ("d", "d_f_m", "d_f [m]", "tab:orange"),
    ):
        ax = axes[key]
        ax.step(x, [r[column] for r in rows], where="post", color=color)
        ax.set_ylabel(name, color=color)
        for i in episode_starts:
            ax.axvline(i, color="0.6", lw=0.8, ls="--")
    axes["v"].set_title("chosen action: target speed, lateral offset")
    axes["v"].tick_params(labelbottom=False)
    axes["v"].sharex(axes["d"])
    axes["d"].set_xlabel("decision (all inspected episodes)")
    if preorder is not None:
        levels = [*preorder.topological_order(), "leaf"]
        counts = {lv: 0 for lv in levels}
        for r in rows:
            for o in preorder.objectives:
                lv = r.get(f"pruned_by_{o}", KEPT)
                if lv:
                    counts[lv] += 1
        axes["prune"].bar(levels, [counts[lv] for lv in levels], color="tab:red")
        axes["prune"].set_title("level that removed a head's greedy action (count)")
        sizes = [np.mean([r[f"size_{lv}"] for r in rows]) for lv in levels]
        axes["size"].bar(levels, sizes, color="tab:blue")
        axes["size"].set_title("mean optimal-subset size |S_r|")
        for key in ("prune", "size"):
            axes[key].tick_params(axis="x", rotation=30, labelsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def gif_bytes(pngs: list[bytes], frame_ms: int = 400) -> bytes:
    """An animated GIF of PNG frames (Pillow, which matplotlib already needs)."""
    from PIL import Image

    images = [Image.open(io.BytesIO(p)).convert("RGB") for p in pngs]
    buf = io.BytesIO()
    images[0].save(
        buf, format="GIF", save_all=True, append_images=images[1:], duration=frame_ms, loop=0
    )
    return buf.getvalue()


PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>priqn inspect: {title}</title>
<style>body{{font-family:sans-serif;margin:1em}} #frame{{width:min(100%,1200px)}}
table{{border-collapse:collapse;font-size:13px}} td,th{{padding:2px 8px;border-bottom:1px solid #ddd}}</style>
</head><body>
<h2>priqn inspect — {title}</h2>
<p>{about}</p>
<p><button id="play">play</button>
<input id="slider" type="range" min="0" max="{last}" value="0" style="width:60%">
<span id="label"></span></p>
<img id="frame" src="frames/0000.png" alt="decision frame">
<table id="facts"></table>
<p><img src="summary.png" alt="pruning summary" style="max-width:100%"></p>
<script id="decisions" type="application/json">{data}</script>
<script>
const rows = JSON.parse(document.getElementById("decisions").textContent);
const slider = document.getElementById("slider"), img = document.getElementById("frame");
const label = document.getElementById("label"), facts = document.getElementById("facts");
function show(i) {{
  slider.value = i;
  img.src = "frames/" + String(i).padStart(4, "0") + ".png";
  const r = rows[i];
  label.textContent = "decision " + (i + 1) + " / " + rows.length;
  facts.innerHTML = Object.entries(r).map(([k, v]) => "<tr><th>" + k + "</th><td>" +
    (Array.isArray(v) ? v.map(x => (x ? 1 : 0)).join("") : v) + "</td></tr>").join("");
}}
slider.addEventListener("input", () => show(Number(slider.value)));
let timer = null;
document.getElementById("play").addEventListener("click", () => {{
  if (timer) {{ clearInterval(timer); timer = null; return; }}
  timer = setInterval(() => show((Number(slider.value) + 1) % rows.length), 400);
}});
show(0);
</script></body></html>
"""


def _page_rows(rows: list[dict], decisions: list[InspectedDecision]) -> list[dict]:
    out = []
    for r, d in zip(rows, decisions, strict=True):
        r = dict(r)
        if d.subsets_NA is not None:
            r["subsets"] = [[bool(x) for x in s] for s in d.subsets_NA]
        if d.leaf_A is not None:
            r["leaf"] = [bool(x) for x in d.leaf_A]
        out.append(r)
    return out


# ----------------------------------------------------------------------------- entry


def inspect_run(run_dir: str | Path, out_dir: str | Path, cfg: InspectConfig) -> Path:
    """Inspect ``run_dir`` on the configured scenes; returns ``out_dir/index.html``."""
    import pandas as pd

    from priqn.env.vector import make_vector_env

    run_dir, out = Path(run_dir), Path(out_dir)
    run = RunFolder(run_dir)
    if not run.is_run():
        raise PriqnError(f"{run_dir}: not a run folder (no {run.CONFIG})")
    scenes, eval_cfg = inspection_scenes(run_dir, cfg)
    policy = load_policy(run, device="cpu")
    if cfg.near_greedy_eps is not None:
        policy = policy.near_greedy(cfg.near_greedy_eps)
    env_cfg = dataclasses.replace(policy.env_config, family=eval_cfg.family, nets=(), junction="")
    if eval_cfg.max_episode_steps:
        env_cfg = dataclasses.replace(env_cfg, max_episode_steps=eval_cfg.max_episode_steps)
    # Frames for people at 128 px or more, whatever the observation size.
    view_cfg = dataclasses.replace(env_cfg, render_size_px=max(128, env_cfg.obs_size_px))
    # One env worker, as for every rollout (libsumo: one simulation per process).
    vec_env = make_vector_env(view_cfg, 1, seed=eval_cfg.seed, render_mode="rgb_array")
    try:
        decisions = rollout(policy, vec_env, scenes)
        table = np.asarray(vec_env.call("action_table")[0])
    finally:
        vec_env.close()

    agent = policy.agent
    rows = decision_rows(decisions, agent, table)
    atomic_write_text(out / "decisions.csv", pd.DataFrame(rows).to_csv(index=False))
    arrays: dict[str, np.ndarray] = {
        "quantiles_THKA": np.stack([d.quantiles_HKA for d in decisions]),
        "actions_T": np.array([d.action for d in decisions]),
    }
    if agent.subsets is not None:
        arrays["subsets_TNA"] = np.stack([d.subsets_NA for d in decisions])
    if decisions[0].leaf_A is not None:
        arrays["leaf_TA"] = np.stack([d.leaf_A for d in decisions])
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    atomic_write_bytes(out / "quantiles.npz", buf.getvalue())

    shape = (env_cfg.n_speeds, env_cfg.n_offsets)
    pngs = []
    for i, d in enumerate(decisions):
        png = frame_figure(d, agent, table, shape, cfg.frame_dpi)
        atomic_write_bytes(out / "frames" / f"{i:04d}.png", png)
        pngs.append(png)
    atomic_write_bytes(out / "episode.gif", gif_bytes(pngs))
    preorder = None if agent.subsets is None else agent.subsets.preorder
    summary_figure(rows, preorder, out / "summary.png")

    labels = policy.labels
    title = html.escape(f"{labels.get('label', run_dir.name)} — {scenes[0].net}")
    about = html.escape(
        f"run {run_dir.name}; {len(scenes)} episode(s) of evaluation run {cfg.eval_run}, "
        f"density {scenes[0].density:g}, evaluation seed {eval_cfg.seed}; "
        f"{len(decisions)} decisions. Heat maps: mean of each head's K quantiles over the "
        "action grid (rows v_f, columns d_f); cyan boxes: that level's optimal subset; "
        "orange dots: the leaf set (the near-greedy set for the acting-randomness control); "
        "red box: the chosen action."
    )
    data = json.dumps(_page_rows(rows, decisions)).replace("</", "<\\/")
    page = PAGE.format(title=title, about=about, last=len(decisions) - 1, data=data)
    atomic_write_text(out / "index.html", page)
    return out / "index.html"


def add_scene_arguments(parser: argparse.ArgumentParser, verb: str) -> None:
    """The scene-selection flags ``priqn inspect`` and ``priqn play`` share (``verb``: the
    word their help uses): --net, --density, --command, --seed, --eval-run, --episodes."""
    parser.add_argument("--net", default="", help="net '<family>/<net_id>' (default: first)")
    parser.add_argument(
        "--density", type=float, default=0.0, help="traffic density in (0, 1] (default: first)"
    )
    parser.add_argument("--command", default="", choices=["", "left", "straight", "right"])
    parser.add_argument("--seed", type=int, help="evaluation seed (default: the run's)")
    parser.add_argument("--eval-run", type=int, default=0, help="evaluation run (0-based)")
    parser.add_argument("--episodes", type=int, default=1, help=f"episodes to {verb}")


def scene_config(args: argparse.Namespace, near_greedy_eps: float | None = None) -> InspectConfig:
    """The :class:`InspectConfig` of :func:`add_scene_arguments`' flags, checked (one line each)."""
    if args.episodes < 1:
        raise PriqnError(f"--episodes: expected >= 1, got {args.episodes}")
    if args.density:  # 0 = the first evaluation density
        check_density(args.density, "--density")
    return InspectConfig(
        net=args.net,
        density=args.density,
        command=args.command,
        seed=args.seed,
        eval_run=args.eval_run,
        episodes=args.episodes,
        near_greedy_eps=near_greedy_eps,
    )


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="a run folder made by 'priqn train'")
    parser.add_argument("--out", required=True, help="output folder (index.html, frames, ...)")
    add_scene_arguments(parser, "inspect")
    parser.add_argument(
        "--near-greedy",
        type=float,
        metavar="EPS",
        help="inspect the acting-randomness control at this ε (as priqn evaluate --acting "
        "near-greedy --acting-eps EPS; IQN / Ensemble / MA-IQN runs)",
    )


def run(args: argparse.Namespace) -> int:
    if args.near_greedy is not None:
        check_acting_eps(args.near_greedy, "--near-greedy")
    page = inspect_run(args.run, args.out, scene_config(args, args.near_greedy))
    print(f"priqn inspect: wrote {page} (open it in a browser)")
    return 0
