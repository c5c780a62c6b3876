"""What a training run is: :class:`TrainConfig`, presets, and what follows from a config.

``resolve_config`` layers a preset TOML (``priqn/presets/train_<name>.toml``), a config
file, the ``priqn train`` flags, typed values (a traffic setting, a grid row's options) and
``--set`` overrides into one :class:`TrainConfig`;
``derive_seeds`` gives every child seed; ``default_run_name`` and ``policy_labels``
name the run. Agents, networks, learners and policies are built in one place,
:mod:`priqn.agents.build` (``build_network`` here is its entry for ``priqn bench
train``). Torch is imported only by the functions that build something.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from priqn.agents.config import (
    PREORDER_PRESETS,
    AgentConfig,
    LearnerConfig,
    NetworkConfig,
    agent_spec,
    resolve_spec,
)
from priqn.agents.frames import REPLAY_STORAGES
from priqn.agents.scalarise import crash_margin, scheme_weights
from priqn.config import ConfigValues, apply_values, from_dict, load_toml, to_dict, value_pairs
from priqn.env.config import EnvConfig
from priqn.errors import PriqnError, did_you_mean
from priqn.objectives import objective_names

PRESETS_DIR = Path(__file__).resolve().parents[1] / "presets"
PRESETS: tuple[str, ...] = ("default", "paper", "right-of-way")
"""Training presets: ``priqn/presets/train_<name>.toml``."""
NETS: tuple[str, ...] = ("tjunction", "fourway", "all")
"""Training pools ``--net`` accepts (EnvConfig.family)."""


@dataclasses.dataclass(frozen=True)
class ReplayConfig:
    """Replay buffer and update ratio."""

    capacity: int = 50_000
    """Transitions kept (all workers together); frames are stored once, as uint8."""
    learning_starts: int = 2_000
    """Env decisions collected before the first update."""
    decisions_per_update: int = 4
    """Env decisions (summed over workers) per gradient update."""
    storage: str = "host"
    """Where the observations are kept and how a batch reaches the learner's device: host
    (numpy in host memory; the learner copies each batch), pinned (host memory; batches
    gathered into page-locked buffers and copied asynchronously; CUDA only) or device
    (torch tensors on the learner's device, batches gathered there; GPU memory on CUDA,
    checked up front). Every storage gives the same batches, so the same training. On a
    GPU, device is the fast one (an H200 at the paper preset: 1.3-1.4x updates/s with
    sampling; pinned about as host; docs/implementation-details.md §12)."""

    def __post_init__(self) -> None:
        if self.storage not in REPLAY_STORAGES:
            raise ValueError(
                f"storage: unknown {self.storage!r} (valid: {', '.join(REPLAY_STORAGES)})"
            )


@dataclasses.dataclass(frozen=True)
class ExplorationConfig:
    """ε-greedy schedule over env decisions: linear from ε_start to ε_end, then flat."""

    eps_start: float = 1.0
    """ε at decision 0 (probability of a uniformly random action)."""
    eps_end: float = 0.05
    """ε after the decay."""
    decay_fraction: float = 0.3
    """Fraction of total_steps over which ε decays linearly (when decay_steps is 0)."""
    decay_steps: int = 0
    """Env decisions over which ε decays linearly, fixed in absolute decisions (0: use
    decay_fraction of total_steps). Set, the schedule does not depend on the budget: with
    the same seed, the first 60k decisions of a 240k run are those of a 60k run whose
    decay_fraction × 60k equals it (docs/implementation-details.md, "Budgets")."""

    def __post_init__(self) -> None:
        for name in ("eps_start", "eps_end", "decay_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name}: expected a number in [0, 1]")
        if self.decay_steps < 0:
            raise ValueError(
                f"decay_steps: expected 0 or a positive number of decisions, got {self.decay_steps}"
            )

    def decay_decisions(self, total_steps: int) -> float:
        """Decisions over which ε decays in a run of ``total_steps`` (at least 1)."""
        if self.decay_steps > 0:
            return max(1.0, float(self.decay_steps))
        return max(1.0, self.decay_fraction * total_steps)


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
    keep_at: tuple[int, ...] = ()
    """Budgets (env decisions, ascending, each below total_steps and a multiple of num_envs)
    at which the policy is also kept as ``snapshots/policy-at<N>.pt`` (its SHA-256 in
    meta.json ``snapshots``): one run then answers several budgets, each snapshot
    evaluated with ``priqn evaluate --snapshot N`` into ``eval-at<N>/``. The final policy
    is ``policy.pt``. Keeping a snapshot changes no training."""
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
    cuda_deterministic: bool = True
    """On CUDA, cuDNN's and cuBLAS's deterministic kernels, so one seed gives one run there as
    it does on the CPU, and a kept snapshot is the shorter run's bit for bit. They cost eager
    updates about a quarter of their speed on an H200, compiled ones nothing (`priqn bench
    train --cuda-nondeterministic`); false trades the guarantee for that. No effect on the CPU."""
    torch_threads: int = 1
    """CPU threads for torch in the learner process (0 = torch's default). On a small CPU the
    env workers need the other cores: oversubscribed torch threads slow everything down."""
    overlap_updates: bool = True
    """Run the learner's updates while the env workers simulate (step_async → update →
    step_wait). False: the serial order act → step → store → update (a step's batch may
    then include that step's transitions); kept to measure the gain in priqn bench train."""
    env_groups: int = 1
    """Split the env workers into this many groups that step in turn (a divisor of
    num_envs): while one group simulates, the loop collects another's step, learns from it
    and acts for it, so neither the workers nor the learner wait for the other. 1 (the
    default): every worker steps at once, as before. A new order of acting, stepping and
    updates, so a different run of the seed (deterministic too); the pipeline empties at
    each checkpoint, so a resume stays exact (docs/implementation-details.md §12). With
    groups, a group's updates run once its step is stored, while the other groups
    simulate: ``overlap_updates`` does not apply."""
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
        if self.seed < 0:  # numpy's SeedSequence takes non-negative integers only
            raise ValueError(f"seed: expected an integer >= 0, got {self.seed}")
        if self.total_steps < 1 or self.num_envs < 1:
            raise ValueError("total_steps and num_envs: expected positive integers")
        if self.device not in ("auto", "cpu", "cuda") and not self.device.startswith("cuda:"):
            raise ValueError(f"device: expected auto, cpu or cuda, got {self.device!r}")
        if self.env_groups < 1 or self.num_envs % self.env_groups:
            raise ValueError(
                f"env_groups: expected a divisor of num_envs ({self.num_envs}), "
                f"got {self.env_groups}"
            )
        if self.replay.capacity < 2 * self.num_envs * (self.learner.n_step + 2):
            raise ValueError("replay.capacity: too small for num_envs and learner.n_step")
        keep = self.checkpoint.keep_at
        if list(keep) != sorted(set(keep)) or any(
            not 0 < b < self.total_steps or b % self.num_envs for b in keep
        ):
            raise ValueError(
                f"checkpoint.keep_at: expected ascending budgets below total_steps "
                f"({self.total_steps}), each a multiple of num_envs ({self.num_envs}), got {list(keep)}"
            )
        n = len(self.env.objectives)
        self.agent.check_lengths(tuple(self.env.objectives))
        self.learner.gammas(n)  # one γ or one per objective
        try:
            mixed_heads = not resolve_spec(self.agent, n).per_objective_heads
        except PriqnError:  # unknown names: one line in _validate_names
            mixed_heads = False
        if mixed_heads and len(set(self.gammas)) > 1:
            raise ValueError(
                f"learner.gamma: agent {self.agent.name!r} learns one weighted-sum reward (its "
                "heads mix objectives), so it needs one discount (per-objective values are for "
                "agents with per-objective heads: ma-iqn, pr-iqn)"
            )

    @property
    def objective_names(self) -> tuple[str, ...]:
        """The run's objective names (``env.objectives`` resolved; reward-vector, head and
        ``return_<name>`` column order)."""
        return objective_names(self.env.objectives)

    @property
    def gammas(self) -> tuple[float, ...]:
        """γ per objective of the run (``env.objectives`` order)."""
        return self.learner.gammas(len(self.env.objectives))

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
            max(self.gammas),  # the longest horizon: the margin holds for all
            self.env.objectives,
        )

    @property
    def resolved_agent(self) -> AgentConfig:
        """``agent`` with its weights resolved (what every agent of this run is built from)."""
        return dataclasses.replace(self.agent, reward_weights=self.reward_weights)

    @property
    def crash_margin(self) -> float:
        """Safety event cost over the worst accumulable lower-level penalty (> 1: crashing never pays)."""
        return crash_margin(
            self.reward_weights,
            self.safety_penalty,
            self.env.max_episode_steps,
            self.gammas,
            self.env.objectives,
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
    values: ConfigValues = (),
) -> TrainConfig:
    """Preset TOML, then ``config_file``, then the flags, then the typed ``values``
    (``(dotted key, value)`` pairs in order: a traffic setting, a grid row's options), then
    the ``--set`` ``overrides`` strings, all checked together (:func:`priqn.config.apply_values`)."""
    if preset not in PRESETS:
        raise PriqnError(
            f"--preset: unknown preset {preset!r} (valid: {', '.join(PRESETS)})"
            + did_you_mean(preset, PRESETS)
        )
    preset_path = PRESETS_DIR / f"train_{preset}.toml"
    data = to_dict(TrainConfig())
    data = _deep_merge(data, load_toml(preset_path))
    from_dict(TrainConfig, data, where=str(preset_path))  # name the preset in its errors
    if config_file is not None:
        data = _deep_merge(data, load_toml(config_file))
        from_dict(TrainConfig, data, where=str(config_file))
    flags: dict[str, Any] = {}
    if net is not None:
        if net in NETS:
            data["env"]["family"] = net
        elif net.endswith(".net.xml") or Path(net).is_dir():
            if not Path(net).exists():
                raise PriqnError(f"--net: {net}: no such file or folder")
            data["env"]["nets"] = [net]  # your own net(s): docs/your-own-net.md
        else:
            raise PriqnError(
                f"--net: unknown net {net!r} (valid: {', '.join(NETS)}, a .net.xml file or a "
                "folder of them)" + did_you_mean(net, NETS)
            )
    for key, value in (("seed", seed), ("total_steps", steps), ("num_envs", num_envs)):
        if value is not None:
            flags[key] = value
    if device is not None:
        flags["device"] = device
    data.update(flags)
    if agent is not None:
        data["agent"]["name"] = agent
    cfg = from_dict(TrainConfig, data, where="priqn train flags")
    cfg = apply_values(cfg, [*value_pairs(values), *overrides], where=where)
    _validate_names(cfg)
    if cfg.env.nets:  # recorded by absolute path, so a run folder works from any cwd
        nets = tuple(str(Path(n).resolve()) for n in cfg.env.nets)
        cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, nets=nets))
    preorder = Path(cfg.agent.preorder)
    if cfg.agent.preorder not in PREORDER_PRESETS and preorder.is_file():
        # a preorder TOML is recorded by absolute path, so load_policy works from any cwd
        agent = dataclasses.replace(cfg.agent, preorder=str(preorder.resolve()))
        cfg = dataclasses.replace(cfg, agent=agent)
    return cfg


def _validate_names(cfg: TrainConfig) -> None:
    """Unknown agent / comparator / preorder → one line before anything starts (checked
    without building the agent: :func:`priqn.train.train` builds it once)."""
    from priqn.agents.registry import check_agent

    check_agent(cfg.agent.name, cfg.resolved_agent, cfg.objective_names)


def derive_seeds(seed: int) -> dict[str, int]:
    """Every child seed of a run, from ``SeedSequence(seed)`` (recorded in meta.json)."""
    names = ("env", "eval_env", "torch_init", "tau", "replay", "explore")
    children = np.random.SeedSequence(seed).spawn(len(names))
    return {
        n: int(c.generate_state(1, dtype=np.uint32)[0])
        for n, c in zip(names, children, strict=True)
    }


def policy_labels(cfg: TrainConfig, agent: Any = None) -> dict[str, Any]:
    """Table II labels of a run (:class:`priqn.agents.labels.PolicyLabel` row) plus ``train_seed``.

    ``agent``: the run's agent when already built (else it is built here)."""
    from priqn.agents.build import build_agent

    if agent is None:
        agent = build_agent(cfg)
    labels = agent.labels
    labels["train_seed"] = cfg.seed
    return labels


def pool_families(family: str) -> list[str]:
    """The scenario families of a training pool (``all`` = both)."""
    return ["tjunction", "fourway"] if family == "all" else [family]


def default_run_name(cfg: TrainConfig) -> str:
    """``<net>_<agent>[_<comparator>_eps<eps>[_notrain][_partial]]_s<seed>``."""
    pool = cfg.env.family
    if cfg.env.nets:  # own nets: named after the first one
        pool = Path(cfg.env.nets[0]).name.removesuffix(".net.xml")
    parts = [pool, cfg.agent.name.rpartition(":")[2]]  # a plug-in path: its NAME
    spec = agent_spec(cfg.agent.name, cfg.agent)
    if spec is not None and spec.uses_preorder:
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


def select_device(name: str) -> Any:
    import torch

    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise PriqnError(
            f"device: {name!r} requested but CUDA is not available here (expected auto or cpu)"
        )
    return torch.device(name)


def cuda_determinism(on: bool) -> None:
    """Switch CUDA's deterministic kernels on or off for this process (cuDNN, cuBLAS and
    ``torch.use_deterministic_algorithms``). Without them two CUDA runs of one seed wrote
    the same metrics but different convolution weights (an H200, 2026-11-27)."""
    import torch

    if on:  # read when cuBLAS starts: set before the first CUDA matrix product
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    torch.backends.cudnn.benchmark = False
    torch.backends.cudnn.deterministic = on
    torch.use_deterministic_algorithms(on)


def build_network(
    cfg: TrainConfig, obs_space: Any, num_actions: int, seed: int, agent: Any = None
) -> Any:
    """:func:`priqn.agents.build.build_network` (``agent``: the run's agent when already
    built, else it is built here)."""
    from priqn.agents import build

    return build.build_network(cfg, obs_space, num_actions, seed, agent or build.build_agent(cfg))


def observation_space(shapes: Mapping[str, Any]) -> Any:
    """The observation space a checkpoint was trained on (its ``obs_shapes``)."""
    import gymnasium

    spaces = {}
    for k, (shape, dtype, high) in shapes.items():
        spaces[k] = gymnasium.spaces.Box(
            low=0 if dtype == "uint8" else -np.inf, high=high, shape=tuple(shape), dtype=dtype
        )
    return gymnasium.spaces.Dict(spaces)
