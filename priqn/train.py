"""``priqn train``: train one agent of Table II into a self-explaining run folder.

Read :func:`_train_loop` top to bottom: act (ε-greedy over the agent's acting rule) →
``envs.step_async`` → ``replay.sample`` → ``learner.update`` (while the env workers
simulate) → ``envs.step_wait`` → ``replay.add`` → log, evaluate on the hold-out nets,
checkpoint. Everything a run needs to be understood later lands
in ``runs/<name>/`` (docs/ARCHITECTURE.md "Run folder"):

- ``config.toml`` the resolved :class:`TrainConfig` (loadable back),
- ``meta.json`` git SHA, versions, scenario manifest hashes, seeds, labels, ``status``,
- ``metrics.csv`` one row per training episode (``kind=train``) and per evaluation
  episode (``kind=eval``), ``tb/`` TensorBoard, ``learning_curve.png``,
- ``checkpoints/latest.pt`` (+ ``replay-<step>.npz``), written atomically; resume reads
  them back, replay buffer included.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import math
import os
import platform
import shutil
import socket
import subprocess
import sys
import time
import zipfile
from collections import deque
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from priqn.agents.config import AGENT_SPECS, AgentConfig, LearnerConfig, NetworkConfig
from priqn.agents.scalarise import crash_margin, scheme_weights
from priqn.config import apply_overrides, describe, dumps_toml, from_dict, load_toml, to_dict
from priqn.env.intersection import EnvConfig
from priqn.errors import PriqnError
from priqn.io import (
    atomic_open,
    atomic_torch_save,
    atomic_write_json,
    atomic_write_text,
    read_json,
    remove_stale_temp_files,
    torch_load,
)
from priqn.objectives import OBJECTIVES, SUBSET_COLUMNS
from priqn.runs import live_trainer
from priqn.timing import SectionClock

PRESETS_DIR = Path(__file__).resolve().parent / "presets"
PRESETS: tuple[str, ...] = ("default", "paper")
"""Training presets: ``priqn/presets/train_<name>.toml``."""
NETS: tuple[str, ...] = ("tjunction", "fourway", "all")
"""Training pools ``--net`` accepts (EnvConfig.family)."""


# ============================================================================ config


@dataclasses.dataclass(frozen=True)
class ReplayConfig:
    """Replay buffer and update ratio."""

    capacity: int = 50_000
    """Transitions kept (all workers together); frames are stored once, as uint8."""
    learning_starts: int = 2_000
    """Env decisions collected before the first update."""
    decisions_per_update: int = 4
    """Env decisions (summed over workers) per gradient update."""


@dataclasses.dataclass(frozen=True)
class ExplorationConfig:
    """ε-greedy schedule over env decisions: linear from ε_start to ε_end, then flat."""

    eps_start: float = 1.0
    """ε at decision 0 (probability of a uniformly random action)."""
    eps_end: float = 0.05
    """ε after the decay."""
    decay_fraction: float = 0.3
    """Fraction of total_steps over which ε decays linearly."""

    def __post_init__(self) -> None:
        for name in ("eps_start", "eps_end", "decay_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name}: expected a number in [0, 1]")


@dataclasses.dataclass(frozen=True)
class EvalDuringTrainingConfig:
    """Greedy evaluation episodes on hold-out nets while training."""

    interval_steps: int = 10_000
    """Env decisions between evaluations (0 = never)."""
    episodes: int = 6
    """Episodes per evaluation."""
    family: str = "holdout"
    """Scenario family the evaluation episodes are drawn from."""


@dataclasses.dataclass(frozen=True)
class CheckpointConfig:
    """Checkpoints (written atomically; the newest one is all a resume needs)."""

    interval_steps: int = 10_000
    """Env decisions between checkpoints (one more is written at the end)."""
    save_replay: bool = True
    """Save the replay buffer with each checkpoint. A resume then restores the networks,
    Adam, the replay buffer, the τ / replay / exploration generators and the step count;
    it does not restore the episodes in flight (they end as truncated) nor the env
    workers' generators (reseeded from the env seed and the session number), so the
    episodes after a resume differ from an uninterrupted run's. Without the buffer the
    resume refills it before learning again. meta.json lists every session and the step
    it resumed from."""


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """One training run (``priqn train --list-options`` prints every key)."""

    seed: int = 0
    """Master seed; every child seed (env workers, torch init, τ, replay, exploration) derives from it."""
    total_steps: int = 100_000
    """Training budget in env decisions, summed over workers."""
    num_envs: int = 2
    """Env worker processes (each runs one SUMO)."""
    device: str = "auto"
    """Torch device: auto (CUDA when present), cpu or cuda."""
    torch_threads: int = 1
    """CPU threads for torch in the learner process (0 = torch's default). On a small CPU the
    env workers need the other cores: oversubscribed torch threads slow everything down."""
    overlap_updates: bool = True
    """Run the learner's updates while the env workers simulate (step_async → update →
    step_wait). False: the serial order act → step → store → update (a step's batch may
    then include that step's transitions); kept to measure the gain in priqn bench train."""
    log_interval_steps: int = 1_000
    """Env decisions between TensorBoard scalars / metrics.csv flushes."""
    env: EnvConfig = dataclasses.field(default_factory=lambda: EnvConfig(obs_size_px=64))
    """The environment (family = --net, obs_size_px, densities, ...)."""
    agent: AgentConfig = dataclasses.field(default_factory=AgentConfig)
    """Agent and its Pr-IQN options."""
    network: NetworkConfig = dataclasses.field(default_factory=NetworkConfig)
    """Encoder and head sizes."""
    learner: LearnerConfig = dataclasses.field(default_factory=LearnerConfig)
    """IQN hyper-parameters."""
    replay: ReplayConfig = dataclasses.field(default_factory=ReplayConfig)
    """Replay buffer."""
    exploration: ExplorationConfig = dataclasses.field(default_factory=ExplorationConfig)
    """ε-greedy schedule."""
    evaluation: EvalDuringTrainingConfig = dataclasses.field(
        default_factory=EvalDuringTrainingConfig
    )
    """Periodic hold-out evaluation."""
    checkpoint: CheckpointConfig = dataclasses.field(default_factory=CheckpointConfig)
    """Checkpointing."""

    def __post_init__(self) -> None:
        if self.total_steps < 1 or self.num_envs < 1:
            raise ValueError("total_steps and num_envs: expected positive integers")
        if self.device not in ("auto", "cpu", "cuda") and not self.device.startswith("cuda:"):
            raise ValueError(f"device: expected auto, cpu or cuda, got {self.device!r}")
        if self.replay.capacity < 2 * self.num_envs * (self.learner.n_step + 2):
            raise ValueError("replay.capacity: too small for num_envs and learner.n_step")
        spec = AGENT_SPECS.get(self.agent.name)  # unknown names: one line in _validate_names
        scalar_heads = spec is not None and spec(self.agent).reward_rule == "weighted-sum"
        if scalar_heads and len(set(self.learner.gamma_5)) > 1:
            raise ValueError(
                f"learner.gamma: agent {self.agent.name!r} learns one weighted-sum reward, "
                "so it needs one discount (per-objective values are for ma-iqn and pr-iqn)"
            )

    @property
    def safety_penalty(self) -> float:
        """The smaller one-off safety penalty (collision or off-road) [-]."""
        return min(self.env.reward.collision_penalty, self.env.reward.off_road_penalty)

    @property
    def reward_weights(self) -> tuple[float, ...]:
        """The weighted-sum weights this run uses: ``agent.reward_weights`` when given, else
        ``agent.reward_scheme`` resolved for this run's episode length, γ and safety penalty."""
        if self.agent.reward_weights is not None:
            return tuple(self.agent.reward_weights)
        return scheme_weights(
            self.agent.reward_scheme,
            self.safety_penalty,
            self.env.max_episode_steps,
            max(self.learner.gamma_5),  # the longest horizon: the margin holds for all
        )

    @property
    def agent_config(self) -> AgentConfig:
        """``agent`` with its weights resolved (what every agent of this run is built from)."""
        return dataclasses.replace(self.agent, reward_weights=self.reward_weights)

    @property
    def crash_margin(self) -> float:
        """Safety event cost over the worst accumulable lower-level penalty (> 1: crashing never pays)."""
        return crash_margin(
            self.reward_weights,
            self.safety_penalty,
            self.env.max_episode_steps,
            self.learner.gamma_5,
        )


def _deep_merge(base: dict[str, Any], extra: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in extra.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), dict):
            out[k] = _deep_merge(out[k], v)
        else:
            out[k] = v
    return out


def resolve_config(
    preset: str = "default",
    agent: str | None = None,
    seed: int | None = None,
    net: str | None = None,
    steps: int | None = None,
    overrides: Sequence[str] = (),
    where: str = "--set",
    config_file: str | Path | None = None,
    num_envs: int | None = None,
    device: str | None = None,
) -> TrainConfig:
    """Preset TOML, then ``config_file``, then the flags, then ``--set`` overrides."""
    if preset not in PRESETS:
        raise PriqnError(f"--preset: unknown preset {preset!r} (valid: {', '.join(PRESETS)})")
    preset_path = PRESETS_DIR / f"train_{preset}.toml"
    data = to_dict(TrainConfig())
    data = _deep_merge(data, load_toml(preset_path))
    from_dict(TrainConfig, data, where=str(preset_path))  # name the preset in its errors
    if config_file is not None:
        data = _deep_merge(data, load_toml(config_file))
        from_dict(TrainConfig, data, where=str(config_file))
    flags: dict[str, Any] = {}
    if net is not None:
        if net not in NETS:
            raise PriqnError(f"--net: unknown net {net!r} (valid: {', '.join(NETS)})")
        data["env"]["family"] = net
    for key, value in (("seed", seed), ("total_steps", steps), ("num_envs", num_envs)):
        if value is not None:
            flags[key] = value
    if device is not None:
        flags["device"] = device
    data.update(flags)
    if agent is not None:
        data["agent"]["name"] = agent
    cfg = from_dict(TrainConfig, data, where="priqn train flags")
    cfg = apply_overrides(cfg, list(overrides), where=where)
    _validate_names(cfg)
    preorder = Path(cfg.agent.preorder)
    if cfg.agent.preorder not in ("total", "partial") and preorder.is_file():
        # a preorder TOML is recorded by absolute path, so load_policy works from any cwd
        agent = dataclasses.replace(cfg.agent, preorder=str(preorder.resolve()))
        cfg = dataclasses.replace(cfg, agent=agent)
    return cfg


def _validate_names(cfg: TrainConfig) -> None:
    """Unknown agent / comparator / preorder → one line before anything starts."""
    from priqn.agents.registry import make_agent

    make_agent(cfg.agent.name, cfg.agent_config)


# ============================================================================ run folder


def derive_seeds(seed: int) -> dict[str, int]:
    """Every child seed of a run, from ``SeedSequence(seed)`` (recorded in meta.json)."""
    names = ("env", "eval_env", "torch_init", "tau", "replay", "explore")
    children = np.random.SeedSequence(seed).spawn(len(names))
    return {
        n: int(c.generate_state(1, dtype=np.uint32)[0])
        for n, c in zip(names, children, strict=True)
    }


def _env_reset_seed(env_seed: int, session: int) -> int | None:
    """Reset seed of the vector env in training session ``session`` (0 = first, 1.. = resumes)."""
    if session == 0:
        return None
    return int(np.random.SeedSequence(env_seed, spawn_key=(session,)).generate_state(1)[0])


def _git_sha() -> str:
    """priqn's git commit (``-dirty`` if changed) in a checkout; "not a checkout" if installed."""
    from priqn.paths import PACKAGE_DIR

    root = PACKAGE_DIR.parent
    if not (root / ".git").exists():
        return "not a checkout"
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=10
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=10,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return (sha or "unknown") + ("-dirty" if dirty else "")


def _versions() -> dict[str, str]:
    import gymnasium
    import torch

    import priqn

    out = {
        "priqn": priqn.__version__,
        "python": platform.python_version(),
        "torch": torch.__version__,
        "numpy": np.__version__,
        "gymnasium": gymnasium.__version__,
    }
    try:
        from priqn.sim.sumo import sumo_version

        out["sumo"] = sumo_version()
    except Exception as exc:  # noqa: BLE001 - recorded, never fatal
        out["sumo"] = f"unknown ({type(exc).__name__})"
    return out


def _manifest_hashes(families: Sequence[str], nets_dir: str) -> dict[str, str]:
    """Manifest hash per family; a family without generated nets is a one-line error."""
    from priqn.sim.scenario import manifest_hash

    root = Path(nets_dir) if nets_dir else None
    return {fam: manifest_hash(fam, root) for fam in families}


def _pool_families(family: str) -> list[str]:
    return ["tjunction", "fourway"] if family == "all" else [family]


def policy_labels(cfg: TrainConfig) -> dict[str, Any]:
    """Table II labels of a run: agent, comparator, train_preorder, eps, partial_order, seed, label."""
    from priqn.agents.registry import make_agent

    labels = make_agent(cfg.agent.name, cfg.agent_config).labels
    labels["train_seed"] = cfg.seed
    labels["label"] = _label(labels)
    if labels["agent"] == "pr-iqn" and cfg.agent.normalisation != "zscore":
        labels["label"] += f" {cfg.agent.normalisation}"  # our scale-aware rows
    if labels["agent"] != "pr-iqn" and cfg.agent.reward_scheme != AgentConfig.reward_scheme:
        labels["label"] += f" {cfg.agent.reward_scheme}"  # a non-default weighted sum
    return labels


_DISPLAY = {"iqn": "IQN", "ensemble-iqn": "Ensemble", "ma-iqn": "MA-IQN", "pr-iqn": "Pr-IQN"}


def _label(labels: Mapping[str, Any]) -> str:
    name = _DISPLAY.get(labels["agent"], labels["agent"])
    if labels["agent"] != "pr-iqn":
        return name
    eps = labels["eps"]
    eps_s = f"{eps:g}" if isinstance(eps, float) else "/".join(f"{e:g}" for e in eps)
    tick = {True: "✓", False: "✗"}
    return (
        f"{name} {labels['comparator'].upper() if labels['comparator'] != 'cvar' else 'CVaR'} "
        f"{tick[bool(labels['train_preorder'])]} {eps_s} {tick[bool(labels['partial_order'])]}"
    )


def default_run_name(cfg: TrainConfig) -> str:
    """``<net>_<agent>[_<comparator>_eps<eps>[_notrain][_partial]]_s<seed>``."""
    parts = [cfg.env.family, cfg.agent.name]
    if cfg.agent.name == "pr-iqn":
        eps = cfg.agent.eps
        parts.append(cfg.agent.comparator)
        parts.append("eps" + (f"{eps:g}" if isinstance(eps, float) else "custom"))
        if not cfg.agent.train_preorder:
            parts.append("notrain")
        if cfg.agent.preorder != "total":
            parts.append(Path(cfg.agent.preorder).stem)
        if cfg.agent.normalisation != "zscore":
            parts.append(cfg.agent.normalisation)
    parts.append(f"s{cfg.seed}")
    return "_".join(parts)


def load_run_config(run_dir: str | Path) -> TrainConfig:
    """The resolved config of a run folder (``config.toml``)."""
    path = Path(run_dir) / "config.toml"
    if not path.is_file():
        raise PriqnError(f"{run_dir}: not a run folder (no config.toml)")
    return from_dict(TrainConfig, load_toml(path), where=str(path))


def _flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dict → ``{"a.b": value}``."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, Mapping):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _config_diff(a: TrainConfig, b: TrainConfig, ignore: Sequence[str]) -> str | None:
    fa, fb = _flatten(to_dict(a)), _flatten(to_dict(b))
    for k in sorted(set(fa) | set(fb)):
        if k not in ignore and fa.get(k) != fb.get(k):
            return f"{k} = {fa.get(k)!r} in the run, {fb.get(k)!r} now"
    return None


def _prepare_run_dir(cfg: TrainConfig, run_dir: Path, resume: bool, force: bool) -> dict[str, Any]:
    """Check / create the run folder; write config.toml and meta.json (status running)."""
    # Everything that can refuse the run comes before the folder is touched.
    families = sorted(set(_pool_families(cfg.env.family)) | {cfg.evaluation.family})
    hashes = _manifest_hashes(families, cfg.env.nets_dir)
    labels = policy_labels(cfg)
    ckpt = run_dir / "checkpoints" / "latest.pt"
    owner = live_trainer(run_dir)
    if owner is not None and (resume or force):
        raise PriqnError(
            f"{run_dir}: still being trained by {owner} (meta.json status running); "
            "stop that process first (a run folder has one writer)"
        )
    if resume:
        if not ckpt.is_file():
            raise PriqnError(f"{run_dir}: nothing to resume (no checkpoints/latest.pt)")
        stored = load_run_config(run_dir)
        diff = _config_diff(stored, cfg, ignore=("total_steps", "device"))
        if diff:
            raise PriqnError(f"{run_dir}: --resume with a different config ({diff})")
        meta = read_json(run_dir / "meta.json")
        remove_stale_temp_files(run_dir)  # left by a killed write of the last session
    else:
        if run_dir.exists() and any(run_dir.iterdir()):
            if not force:
                raise PriqnError(
                    f"{run_dir}: run folder already exists; use --resume to continue it or --force to overwrite"
                )
            shutil.rmtree(run_dir)
        meta = {
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
            "seed": cfg.seed,
            "seeds": derive_seeds(cfg.seed),
            "sessions": [],
        }
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PriqnError(f"{run_dir}: cannot create the run folder ({exc.strerror})") from exc
    atomic_write_text(run_dir / "config.toml", dumps_toml(to_dict(cfg)))
    meta.update(
        {
            "run": run_dir.name,
            "status": "running",
            "error": None,
            "git_sha": _git_sha(),
            "versions": _versions(),
            "manifest_hashes": hashes,
            "labels": labels,
            "total_steps": cfg.total_steps,
            "host": socket.gethostname(),
            "pid": os.getpid(),
        }
    )
    meta.setdefault("steps_done", 0)
    meta["sessions"].append(
        {
            "started": datetime.now(UTC).isoformat(timespec="seconds"),
            "resume": resume,
            "from_step": int(meta.get("steps_done", 0)) if resume else 0,
        }
    )
    atomic_write_json(run_dir / "meta.json", meta)
    return meta


# ============================================================================ metrics


POLICY_FILE = "policy.pt"
"""Final online-network weights of a complete run (``load_policy`` falls back to it)."""


METRIC_COLUMNS: tuple[str, ...] = (
    "kind",
    "step",
    "episode",
    "wall_s",
    "epsilon",
    "updates",
    "loss",
    *(f"return_{o}" for o in OBJECTIVES),
    "return_weighted",
    "length",
    "success",
    "collision",
    "off_road",
    "timeout",
    "route_progress",
    "density_realised",
    *SUBSET_COLUMNS,
    "net",
    "command",
)
"""Columns of ``metrics.csv``: one row per training (kind=train) or evaluation episode."""


def _write_metrics(path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=METRIC_COLUMNS, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_text(path, buf.getvalue())


def _read_metrics(path: Path, max_step: int) -> list[dict[str, Any]]:
    if not path.is_file():
        return []
    with path.open(encoding="utf-8", newline="") as fh:
        return [r for r in csv.DictReader(fh) if int(float(r["step"])) <= max_step]


def _episode_row(
    kind: str, final_info: Mapping[str, Any], e: int, weights: Sequence[float]
) -> dict:
    """One metrics row from gymnasium's batched ``final_info`` of env ``e``."""
    returns = np.asarray(final_info["returns"][e], dtype=np.float64)
    row: dict[str, Any] = {"kind": kind}
    for i, o in enumerate(OBJECTIVES):
        row[f"return_{o}"] = round(float(returns[i]), 5)
    row["return_weighted"] = round(float(returns @ np.asarray(weights)), 5)
    row["length"] = int(final_info["episode_steps"][e])
    for k in ("success", "collision", "off_road", "timeout"):
        row[k] = int(bool(final_info[k][e]))
    row["route_progress"] = round(float(final_info["route_progress"][e]), 4)
    row["density_realised"] = round(float(final_info["density_realised"][e]), 4)
    row["net"] = str(final_info["net"][e])
    row["command"] = str(final_info["command"][e])
    return row


def plot_learning_curve(rows: Sequence[Mapping[str, Any]], path: Path, title: str) -> None:
    """learning_curve.png: success rate, per-objective returns, loss, episode length."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pandas as pd

    df = pd.DataFrame(list(rows))
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), constrained_layout=True)
    fig.suptitle(title)
    if df.empty:
        for ax in axes.flat:
            ax.text(0.5, 0.5, "no finished episode yet", ha="center", transform=ax.transAxes)
    else:
        for col in (
            "step",
            "success",
            "collision",
            "off_road",
            "length",
            "loss",
            "return_weighted",
        ):
            df[col] = pd.to_numeric(df[col], errors="coerce")
        for o in OBJECTIVES:
            df[f"return_{o}"] = pd.to_numeric(df[f"return_{o}"], errors="coerce")
        tr, ev = df[df["kind"] == "train"], df[df["kind"] == "eval"]
        win = max(1, min(50, len(tr) // 5 or 1))
        ax = axes[0, 0]
        if len(tr):
            ax.plot(
                tr["step"], tr["success"].rolling(win, min_periods=1).mean(), label="train success"
            )
            ax.plot(
                tr["step"],
                tr["collision"].rolling(win, min_periods=1).mean(),
                label="train collision",
            )
            ax.plot(
                tr["step"],
                tr["off_road"].rolling(win, min_periods=1).mean(),
                label="train off-road",
            )
        if len(ev):
            g = ev.groupby("step")[["success", "collision"]].mean()
            ax.plot(g.index, g["success"], "o-", label="eval success (hold-out)")
            ax.plot(g.index, g["collision"], "x--", label="eval collision (hold-out)")
        ax.set(
            xlabel="env decisions",
            ylabel="rate",
            ylim=(-0.02, 1.02),
            title=f"rolling {win} episodes",
        )
        ax.legend(fontsize=8)
        ax = axes[0, 1]
        for o in OBJECTIVES:
            if len(tr):
                ax.plot(tr["step"], tr[f"return_{o}"].rolling(win, min_periods=1).mean(), label=o)
        ax.set(xlabel="env decisions", ylabel="episode return", title="train return per objective")
        ax.legend(fontsize=8)
        ax = axes[1, 0]
        if len(tr):
            ax.plot(tr["step"], tr["loss"], ".", ms=2)
        ax.set(xlabel="env decisions", ylabel="quantile Huber loss", title="loss (at episode end)")
        ax = axes[1, 1]
        if len(tr):
            ax.plot(tr["step"], tr["length"].rolling(win, min_periods=1).mean())
        ax.set(xlabel="env decisions", ylabel="decisions", title="episode length")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    with atomic_open(path, "wb") as fh:
        fh.write(buf.getvalue())


# ============================================================================ helpers


def linear_epsilon(cfg: ExplorationConfig, step: int, total_steps: int) -> float:
    """ε at env decision ``step``: linear from eps_start to eps_end over decay_fraction."""
    decay = max(1.0, cfg.decay_fraction * total_steps)
    frac = min(1.0, step / decay)
    return cfg.eps_start + frac * (cfg.eps_end - cfg.eps_start)


def _select_device(name: str) -> Any:
    import torch

    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise PriqnError(f"device: {name!r} requested but CUDA is not available here")
    return torch.device(name)


def _obs_spec(space: Any) -> dict[str, tuple[tuple[int, ...], Any]]:
    from priqn.agents.network import OBS_KEYS

    missing = [k for k in OBS_KEYS if k not in space.spaces]
    if missing:
        raise PriqnError(f"observation space lacks {missing} (ARCHITECTURE.md Environment)")
    return {k: (tuple(space[k].shape), space[k].dtype) for k in OBS_KEYS}


def _obs_scales(space: Any) -> dict[str, float]:
    """1 / the Box's ``high`` of each uint8 grid, so the network sees [0, 1]."""
    return {k: 1.0 / max(1.0, float(np.max(space[k].high))) for k in ("bev", "lidar")}


def build_network(cfg: TrainConfig, obs_space: Any, num_actions: int, seed: int) -> Any:
    """The run's QuantileNetwork, initialised from ``seed`` (global torch RNG untouched)."""
    import torch

    from priqn.agents.network import QuantileNetwork
    from priqn.agents.registry import make_agent

    heads = make_agent(cfg.agent.name, cfg.agent_config).num_heads
    spec = _obs_spec(obs_space)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return QuantileNetwork(
            {k: s for k, (s, _) in spec.items()},
            _obs_scales(obs_space),
            num_actions,
            heads,
            cfg.network,
        )


def _slice_obs(obs: Mapping[str, np.ndarray], i: int) -> dict[str, np.ndarray]:
    return {k: v[i] for k, v in obs.items()}


def _checkpoint_paths(run_dir: Path) -> tuple[Path, Path]:
    d = run_dir / "checkpoints"
    return d, d / "latest.pt"


def _save_checkpoint(run_dir: Path, state: dict[str, Any], replay: Any, save_replay: bool) -> None:
    """Replay file first, then latest.pt naming it, then old replay files removed.

    Each file is atomic; latest.pt is the commit point, so a kill at any moment leaves a
    consistent (latest.pt, replay file) pair.
    """
    import torch

    ckpt_dir, latest = _checkpoint_paths(run_dir)
    replay_name = None
    if save_replay:
        replay_name = f"replay-{state['step']:012d}.npz"
        with atomic_open(ckpt_dir / replay_name, "wb") as fh:
            replay.save_to(fh)
    state = dict(state, replay_file=replay_name, torch_version=torch.__version__)
    atomic_torch_save(state, latest)
    for old in ckpt_dir.glob("replay-*.npz"):
        if old.name != replay_name:
            old.unlink(missing_ok=True)


def _update_meta(run_dir: Path, **fields: Any) -> None:
    path = run_dir / "meta.json"
    meta = read_json(path)
    meta.update(fields)
    atomic_write_json(path, meta)


# ============================================================================ training


def train(cfg: TrainConfig, run_dir: str | Path, resume: bool = False, force: bool = False) -> Path:
    """Train ``cfg`` into ``run_dir``; ``resume`` continues from its latest checkpoint.

    Returns the run folder. meta.json says ``running`` while training, ``complete``
    when the budget is spent, ``failed`` (with the error) otherwise.
    """
    run_dir = Path(run_dir)
    meta_path = run_dir / "meta.json"
    was_complete = (
        resume and meta_path.is_file() and read_json(meta_path).get("status") == "complete"
    )
    _prepare_run_dir(cfg, run_dir, resume, force)
    # A resume that fails never turns a finished run into a failed one: its status goes
    # back to complete and the error is kept beside it.
    failed_status = "complete" if was_complete else "failed"
    try:
        _train_loop(cfg, run_dir, resume)
    except KeyboardInterrupt:
        _update_meta(run_dir, status=failed_status, error="interrupted (continue with --resume)")
        raise
    except BaseException as exc:
        try:
            _update_meta(run_dir, status=failed_status, error=f"{type(exc).__name__}: {exc}")
        except Exception:  # noqa: BLE001 - e.g. the disk is full; the original error matters
            pass
        raise
    return run_dir


def _train_loop(cfg: TrainConfig, run_dir: Path, resume: bool) -> None:  # noqa: C901 - one loop
    import torch
    from torch.utils.tensorboard import SummaryWriter
    from tqdm import tqdm

    from priqn.agents.learner import Learner
    from priqn.agents.policy import Policy, SubsetSizeMeans
    from priqn.agents.registry import make_agent
    from priqn.agents.replay import ReplayBuffer
    from priqn.env.vector import make_vector_env

    meta = read_json(run_dir / "meta.json")
    seeds: dict[str, int] = meta["seeds"]
    session = len(meta["sessions"]) - 1
    if cfg.torch_threads > 0:
        torch.set_num_threads(cfg.torch_threads)
    device = _select_device(cfg.device)
    E = cfg.num_envs
    weights = cfg.reward_weights

    # --- env, agent, learner, replay -------------------------------------------------
    envs = make_vector_env(cfg.env, E, seed=seeds["env"])
    eval_envs = None
    try:
        obs_space = envs.single_observation_space
        num_actions = int(envs.single_action_space.n)
        obs_shapes = {
            k: (list(obs_space[k].shape), str(obs_space[k].dtype), float(np.max(obs_space[k].high)))
            for k in _obs_spec(obs_space)
        }
        agent = make_agent(cfg.agent.name, cfg.agent_config)
        network = build_network(cfg, obs_space, num_actions, seeds["torch_init"])
        learner = Learner(network, agent, cfg.learner, device, tau_seed=seeds["tau"])
        policy = Policy(learner.online, agent, cfg.learner.num_quantiles, device)
        replay = ReplayBuffer(
            _obs_spec(obs_space), E, cfg.replay.capacity, cfg.learner.n_step, cfg.learner.gamma
        )
        rng_replay = np.random.default_rng(seeds["replay"])
        rng_act = np.random.default_rng(seeds["explore"])
        step, episodes, wall_before = 0, 0, 0.0
        metrics: list[dict[str, Any]] = []
        _update_meta(
            run_dir,
            replay_bytes_per_transition=replay.bytes_per_row(),
            replay_bytes_total=replay.nbytes(),
            device=str(device),
            num_params=sum(p.numel() for p in learner.online.parameters()),
            reward_weights=list(cfg.reward_weights),
            crash_margin=round(cfg.crash_margin, 4),
        )

        ckpt_dir, latest = _checkpoint_paths(run_dir)
        resume_obs = None
        if resume:
            state = torch_load(
                latest,
                "checkpoint",
                "delete the run folder's checkpoints/ and train again with --force",
                device,
            )
            learner.load_state_dict(state["learner"])
            rng_replay.bit_generator.state = state["rng_replay"]
            rng_act.bit_generator.state = state["rng_act"]
            step, episodes, wall_before = state["step"], state["episodes"], state["wall_s"]
            if state.get("replay_file"):
                replay_file = ckpt_dir / state["replay_file"]
                try:
                    replay.load_state_file(replay_file)
                except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile) as exc:
                    raise PriqnError(
                        f"{replay_file}: damaged or unreadable replay buffer "
                        f"({type(exc).__name__}); the run cannot resume exactly: "
                        "train it again with --force"
                    ) from None
                resume_obs = state["obs"]
            metrics = _read_metrics(run_dir / "metrics.csv", step)

        # Session 0: per-worker seeds derived from seeds["env"] by make_vector_env; a resume
        # reseeds from (seeds["env"], session) so it does not replay the first scenes.
        obs, _ = envs.reset(seed=_env_reset_seed(seeds["env"], session))
        if resume_obs is not None:
            # Episodes in flight at the checkpoint end there (truncated, bootstrapped).
            replay.truncate_open_episodes(resume_obs)
        writer = SummaryWriter(str(run_dir / "tb"), purge_step=step if resume else None)

        # --- the loop ------------------------------------------------------------------
        recent = deque(maxlen=100)
        last_loss = math.nan
        last_stats: dict[str, float] = {}
        subset_sizes = SubsetSizeMeans(E, policy.subset_size_names)
        clock = SectionClock()  # where the wall time goes (meta.json time_s)

        def learn(decisions: int) -> dict[str, float]:
            """The updates due after ``decisions``; the last one's stats ({} if none)."""
            stats: dict[str, float] = {}
            if decisions < cfg.replay.learning_starts or len(replay) < cfg.learner.batch_size:
                return stats
            due = (decisions - cfg.replay.learning_starts) // cfg.replay.decisions_per_update + 1
            while learner.updates < due:
                with clock("replay_sample"):
                    batch = replay.sample(cfg.learner.batch_size, rng_replay)
                with clock("update"):
                    stats = learner.update(batch)
            return stats

        t0 = time.perf_counter()
        t_rate, upd_rate_at, upd_per_s = t0, learner.updates, 0.0
        next_log = step + cfg.log_interval_steps
        next_eval = _next_multiple(step, cfg.evaluation.interval_steps)
        next_ckpt = _next_multiple(step, cfg.checkpoint.interval_steps)
        bar = tqdm(
            total=cfg.total_steps,
            initial=step,
            unit="dec",
            desc=run_dir.name,
            dynamic_ncols=True,
            disable=None,
            mininterval=1.0,
        )
        while step < cfg.total_steps:
            # 1. act: agent's acting rule, ε-greedy on top
            with clock("act"):
                epsilon = linear_epsilon(cfg.exploration, step, cfg.total_steps)
                actions = policy.act(obs, rng_act)
                subset_sizes.add(policy.last_subset_sizes)
                explore = rng_act.random(E) < epsilon
                actions = np.where(explore, rng_act.integers(num_actions, size=E), actions)

            # 2. issue the env step: the workers simulate while this process learns
            with clock("env_issue"):
                envs.step_async(actions)

            # 3. learn: one update per decisions_per_update decisions after learning_starts,
            # counted with this step's decisions. The batch comes from the transitions
            # stored so far (not the E in flight); a resume without a saved replay buffer
            # refills a batch's worth first.
            if cfg.overlap_updates:
                last_stats = learn(step + E) or last_stats

            # 4. collect the step (SAME_STEP autoreset: the true last obs is in final_obs)
            # and store it
            with clock("env_wait"):
                next_obs, rewards, terminated, truncated, infos = envs.step_wait()
            with clock("replay_add"):
                ended = np.logical_or(terminated, truncated)
                final_obs = [infos["final_obs"][e] if ended[e] else None for e in range(E)]
                replay.add(obs, actions, rewards, terminated, truncated, final_obs)
            obs = next_obs
            step += E
            if not cfg.overlap_updates:
                last_stats = learn(step) or last_stats
            last_loss = last_stats.get("loss", math.nan)
            log_t0 = time.perf_counter()

            # 5. episode stats
            wall = wall_before + time.perf_counter() - t0
            for e in np.flatnonzero(ended):
                episodes += 1
                row = _episode_row("train", infos["final_info"], int(e), weights)
                row.update(subset_sizes.pop(int(e)))
                row.update(
                    step=step,
                    episode=episodes,
                    wall_s=round(wall, 2),
                    epsilon=round(epsilon, 4),
                    updates=learner.updates,
                    loss=round(last_loss, 5) if not math.isnan(last_loss) else "",
                )
                metrics.append(row)
                recent.append(row)
                writer.add_scalar("episode/return_weighted", row["return_weighted"], step)
                writer.add_scalar("episode/success", row["success"], step)
                writer.add_scalar("episode/collision", row["collision"], step)
                for o in OBJECTIVES:
                    writer.add_scalar(f"episode/return_{o}", row[f"return_{o}"], step)
                for key in SUBSET_COLUMNS:  # acting optimal-subset sizes (preorder agents)
                    if key in row:
                        writer.add_scalar(f"episode/{key}", row[key], step)

            # 6. progress, logs, evaluation, checkpoint
            now = time.perf_counter()
            if now - t_rate >= 5.0:
                upd_per_s = (learner.updates - upd_rate_at) / (now - t_rate)
                t_rate, upd_rate_at = now, learner.updates
            bar.update(E)
            if ended.any() or step >= next_log:
                bar.set_postfix_str(_postfix(episodes, recent, epsilon, upd_per_s), refresh=False)
            if step >= next_log:
                next_log = step + cfg.log_interval_steps
                if bar.disable:  # not a terminal (sweep, nohup): one plain line per interval
                    line = _postfix(episodes, recent, epsilon, upd_per_s)
                    print(f"{run_dir.name} step {step}/{cfg.total_steps} {line}", flush=True)
                writer.add_scalar("train/epsilon", epsilon, step)
                writer.add_scalar("train/updates_per_s", upd_per_s, step)
                for key, value in last_stats.items():  # loss, q_mean, target subset sizes
                    writer.add_scalar(f"train/{key}", value, step)
                _write_metrics(run_dir / "metrics.csv", metrics)
            t_eval = time.perf_counter()
            clock.add("logging", t_eval - log_t0)
            if cfg.evaluation.interval_steps > 0 and step >= next_eval:
                next_eval = _next_multiple(step, cfg.evaluation.interval_steps)
                if eval_envs is None:
                    eval_cfg = dataclasses.replace(cfg.env, family=cfg.evaluation.family)
                    eval_envs = make_vector_env(eval_cfg, 1, seed=seeds["eval_env"])
                rows = _evaluate(eval_envs, policy, cfg, step, seeds["eval_env"], weights)
                for r in rows:
                    r.update(step=step, wall_s=round(wall, 2), updates=learner.updates)
                metrics.extend(rows)
                writer.add_scalar(
                    "eval/success", float(np.mean([r["success"] for r in rows])), step
                )
                writer.add_scalar(
                    "eval/return_weighted",
                    float(np.mean([r["return_weighted"] for r in rows])),
                    step,
                )
                _write_metrics(run_dir / "metrics.csv", metrics)
            t_ckpt = time.perf_counter()
            clock.add("evaluate", t_ckpt - t_eval)
            if step >= next_ckpt or step >= cfg.total_steps:
                next_ckpt = _next_multiple(step, cfg.checkpoint.interval_steps)
                wall = wall_before + time.perf_counter() - t0
                _write_metrics(run_dir / "metrics.csv", metrics)
                state = {
                    "step": step,
                    "episodes": episodes,
                    "wall_s": wall,
                    "learner": learner.state_dict(),
                    "rng_replay": rng_replay.bit_generator.state,
                    "rng_act": rng_act.bit_generator.state,
                    "obs": {k: np.array(v) for k, v in obs.items()},
                    "obs_shapes": obs_shapes,
                    "num_actions": num_actions,
                    "config": to_dict(cfg),
                }
                _save_checkpoint(run_dir, state, replay, cfg.checkpoint.save_replay)
                writer.flush()
                plot_learning_curve(metrics, run_dir / "learning_curve.png", run_dir.name)
                _update_meta(
                    run_dir, steps_done=step, episodes_done=episodes, wall_s=round(wall, 1)
                )
            clock.add("checkpoint", time.perf_counter() - t_ckpt)
        bar.close()
        writer.close()
        # The final policy alone (online weights + the agent's learned state, a few MB):
        # what a committed result folder keeps instead of checkpoints and replay.
        atomic_torch_save(
            {
                "online": learner.online.state_dict(),
                "agent": learner.agent.state_dict(),
                "obs_shapes": obs_shapes,
                "num_actions": num_actions,
                "step": step,
            },
            run_dir / POLICY_FILE,
        )
        time_s = clock.totals()
        if agent.subsets is not None:  # inside "act" and "update"
            time_s["algorithm1"] = round(agent.subsets.seconds, 4)
        _update_meta(
            run_dir,
            time_s=time_s,
            status="complete",
            steps_done=step,
            episodes_done=episodes,
            updates_done=learner.updates,
            finished=datetime.now(UTC).isoformat(timespec="seconds"),
        )
    finally:
        envs.close()
        if eval_envs is not None:
            eval_envs.close()


def _next_multiple(step: int, interval: int) -> int:
    if interval <= 0:
        return sys.maxsize
    return (step // interval + 1) * interval


def _postfix(episodes: int, recent: Sequence[Mapping[str, Any]], eps: float, ups: float) -> str:
    if not recent:
        return f"ep 0 ε {eps:.2f} upd/s {ups:.0f}"
    sr = np.mean([r["success"] for r in recent])
    rets = " ".join(
        f"{o[:4]} {np.mean([r[f'return_{o}'] for r in recent]):+.2f}" for o in OBJECTIVES
    )
    return f"ep {episodes} SR {sr:.2f} R[{rets}] ε {eps:.2f} upd/s {ups:.0f}"


def _evaluate(
    envs: Any, policy: Any, cfg: TrainConfig, step: int, eval_seed: int, weights: Sequence[float]
) -> list[dict[str, Any]]:
    """Greedy episodes on ``envs`` (1 worker); the scene seeds depend only on ``step``."""
    rng = np.random.default_rng([eval_seed, step])
    rows: list[dict[str, Any]] = []
    obs, _ = envs.reset(seed=int(rng.integers(2**31)))
    while len(rows) < cfg.evaluation.episodes:
        actions = policy.act(obs, rng)
        obs, _, terminated, truncated, infos = envs.step(actions)
        if terminated[0] or truncated[0]:
            row = _episode_row("eval", infos["final_info"], 0, weights)
            row.update(episode=len(rows) + 1, epsilon=0.0, loss="")
            rows.append(row)
    return rows


# ============================================================================ evaluation API


def load_policy(run_dir: str | Path, device: str = "cpu") -> Any:
    """Greedy :class:`priqn.agents.policy.Policy` of a trained run (ARCHITECTURE.md)."""

    from priqn.agents.policy import Policy
    from priqn.agents.registry import make_agent

    run_dir = Path(run_dir)
    cfg = load_run_config(run_dir)
    latest = run_dir / "checkpoints" / "latest.pt"
    final = run_dir / POLICY_FILE
    if not latest.is_file() and not final.is_file():
        raise PriqnError(
            f"{run_dir}: no checkpoints/latest.pt or {POLICY_FILE} to load a policy from"
        )
    dev = _select_device(device)
    # The latest checkpoint when present (a run in progress, or resumable); else the
    # final policy file, which is all a committed result folder keeps.
    source = latest if latest.is_file() else final
    state = torch_load(
        source,
        "checkpoint" if source == latest else "policy file",
        "restore it from git or re-train the run (priqn train --force)",
        dev,
    )
    learned = state["learner"] if "learner" in state else state
    shapes = state["obs_shapes"]
    agent = make_agent(cfg.agent.name, cfg.agent_config)
    space = _observation_space(cfg, shapes)
    num_actions = int(state["num_actions"])
    network = build_network(cfg, space, num_actions, seed=0)
    network.load_state_dict(learned["online"])
    network.eval()
    agent.load_state_dict(learned.get("agent", {}))  # the running scale, if any
    labels = policy_labels(cfg)
    return Policy(network, agent, cfg.learner.num_quantiles, dev, cfg.env, labels)


def _observation_space(cfg: TrainConfig, shapes: Any) -> Any:
    """The observation space a checkpoint was trained on (stored in it)."""
    import gymnasium

    spaces = {}
    for k, (shape, dtype, high) in shapes.items():
        spaces[k] = gymnasium.spaces.Box(
            low=0 if dtype == "uint8" else -np.inf, high=high, shape=tuple(shape), dtype=dtype
        )
    return gymnasium.spaces.Dict(spaces)


# ============================================================================ CLI


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``priqn train`` (every config key is also reachable with --set)."""
    parser.add_argument("--net", choices=NETS, help="training pool (env.family; default tjunction)")
    parser.add_argument("--agent", help="iqn | ensemble-iqn | ma-iqn | pr-iqn (default pr-iqn)")
    parser.add_argument("--seed", type=int, help="master seed (default 0)")
    parser.add_argument(
        "--preset", default="default", help="default (CPU, 64 px) | paper (128 px, GPU)"
    )
    parser.add_argument("--steps", type=int, help="training budget in env decisions (total_steps)")
    parser.add_argument("--config", metavar="FILE", help="TOML file merged over the preset")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config key (repeatable)",
    )
    parser.add_argument("--name", help="run folder name (default from net, agent, options, seed)")
    parser.add_argument(
        "--runs-dir", default="runs", help="parent folder of run folders (default runs)"
    )
    parser.add_argument("--resume", metavar="RUN_DIR", help="continue an interrupted run")
    parser.add_argument("--force", action="store_true", help="overwrite an existing run folder")
    parser.add_argument("--device", help="auto | cpu | cuda (default auto)")
    parser.add_argument("--num-envs", type=int, help="env worker processes")
    parser.add_argument(
        "--list-options",
        action="store_true",
        help="print every config key, its default and meaning",
    )


def run(args: argparse.Namespace) -> int:
    if args.list_options:
        values = _flatten(to_dict(resolve_config(preset=args.preset)))
        print(f"# priqn train config keys; values of the '{args.preset}' preset (--preset)")
        for key, _default, doc in describe(TrainConfig):
            print(f"{key} = {values.get(key)!r}\n    {doc}")
        return 0
    if args.resume:
        run_dir = Path(args.resume)
        cfg = load_run_config(run_dir)
        changed = [f for f in ("net", "agent", "seed", "config", "num_envs") if getattr(args, f)]
        if changed or args.set or args.preset != "default" or args.force:
            raise PriqnError(
                "--resume continues a run with its own config.toml; only --steps and --device may change"
            )
        if args.steps is not None:
            cfg = dataclasses.replace(cfg, total_steps=args.steps)
        if args.device is not None:
            cfg = dataclasses.replace(cfg, device=args.device)
        train(cfg, run_dir, resume=True)
    else:
        cfg = resolve_config(
            preset=args.preset,
            agent=args.agent,
            seed=args.seed,
            net=args.net,
            steps=args.steps,
            overrides=args.set,
            config_file=args.config,
            num_envs=args.num_envs,
            device=args.device,
        )
        run_dir = Path(args.runs_dir) / (args.name or default_run_name(cfg))
        train(cfg, run_dir, force=args.force)
    print(f"priqn train: run folder {run_dir}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    os.environ.setdefault("MPLBACKEND", "Agg")
    from priqn.cli import main

    sys.exit(main(["train", *sys.argv[1:]]))
