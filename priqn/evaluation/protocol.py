"""The evaluation protocol: every trained run meets the same hold-out scenes (torch-free).

A run's greedy policy plays the hold-out nets × traffic densities × ``eval_runs``
evaluation runs, ``episodes_per_cell`` episodes per (evaluation run, net, density) cell,
one row per episode in ``eval/episodes.csv`` (:func:`episode_columns`).

Scenes are identical for every policy: the reset seed of episode ``e`` in cell
(evaluation run ``r``, net ``n``, density ``d``) is drawn from
``SeedSequence(EvalConfig.seed, spawn_key=(r, n, d, e))`` where ``n`` and ``d`` are
indices into the sorted hold-out net ids and the configured densities. The
training seed never enters. The policy's own randomness (Pr-IQN samples from its
leaf subset) uses a generator seeded from the same key, so an episode's result does
not depend on how many workers ran it or in which order.

An evaluation's folder is named by what it evaluates (:func:`evaluation_name`):
``eval/`` (the run's own acting on the hold-out family), ``eval-near-greedy[-eps<ε>]/``
(the acting-randomness control), ``eval-nets-<hash>/`` (your own nets),
``eval-family-<name>/`` (another scenario family, e.g. ``out-of-range``),
``eval-traffic-<name>/`` (another traffic setting's NPCs, e.g. ``tm-carla``), ``eval-at<N>/``
(a kept snapshot); the analysis reads these names back (:func:`snapshot_budget`,
:func:`is_nets_evaluation`, :func:`is_family_evaluation`, :func:`is_traffic_evaluation`,
:func:`control_config`).
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from priqn.agents.labels import CONFIG_COLUMNS
from priqn.checks import check_acting_eps, check_density
from priqn.config import config_differences, to_dict
from priqn.errors import PriqnError
from priqn.objectives import OBJECTIVES, return_columns, subset_columns
from priqn.run.evaluations import SNAPSHOT_PREFIX, evaluation_dir, snapshot_evaluation
from priqn.run.folder import RunFolder

LABEL_KEYS: tuple[str, ...] = (*CONFIG_COLUMNS, "train_seed", "label")
"""Keys of ``Policy.labels`` copied into every episode row."""


def episode_columns(objectives: Sequence[str] = OBJECTIVES) -> tuple[str, ...]:
    """Columns of ``eval/episodes.csv`` for a policy with these objective names, in order
    (``return_<name>`` / ``subset_<name>`` follow the run's ``env.objectives``)."""
    return (
        "run",
        "label",
        *(key for key in LABEL_KEYS if key != "label"),
        "eval_run",
        "net",
        "density",
        "density_realised",
        "success",
        "collision",
        "off_road",
        "timeout",
        "route_progress",
        "steps",
        *return_columns(objectives),
        *subset_columns(objectives),
        "holdout_hash",
        # Beyond the contract's list: the scene's identity, so "same scenes" can be checked.
        "episode",
        "command",
        "reset_seed",
    )


EPISODE_COLUMNS: tuple[str, ...] = episode_columns(OBJECTIVES)
"""Columns of ``eval/episodes.csv`` with the default objectives (one row per episode)."""

SCENE_COLUMNS: tuple[str, ...] = ("eval_run", "net", "density", "episode")
"""Columns of an episode row that name its scene (:class:`EvalScene`): the same scene in
two evaluations of one run (another limit, traffic or snapshot) has the same values."""


ACTINGS: tuple[str, ...] = ("own", "near-greedy")
"""Values of ``EvalConfig.acting``; each evaluates into its own folder (:func:`eval_dir_of`)."""


@dataclasses.dataclass(frozen=True)
class EvalConfig:
    """How a trained run is evaluated (recorded in ``eval/meta.json``)."""

    family: str = "holdout"
    """Scenario family of the evaluation nets (never a training pool). A family other than
    the run's own hold-out family (its ``evaluation.family``) is written to
    ``eval-family-<name>/`` beside ``eval/`` (:func:`evaluation_name`), never into ``eval/``."""
    densities: tuple[float, ...] = (0.5, 0.75, 1.0)
    """Requested traffic densities (active actors / maximum actors)."""
    eval_runs: int = 3
    """Evaluation runs per trained run (the paper: 3), each with its own scenes."""
    episodes_per_cell: int = 6
    """Episodes per (evaluation run, net, density) cell. Small by default so a CPU
    evaluation of one run takes minutes; raise it for publication numbers."""
    seed: int = 2026
    """Evaluation seed: every scene and the policy's acting randomness derive from it
    (never from the training seed), so every policy meets the same scenes."""
    commands: tuple[str, ...] = ()
    """Ego route commands cycled over the episodes of a cell ("left", "straight",
    "right"); empty = the environment draws the command from the reset seed."""
    num_workers: int = 2
    """Environment worker processes (the parent process never runs SUMO)."""
    max_episode_steps: int = 0
    """Override of the run's episode step limit in the evaluation itself (an experiment's
    ``[evaluate]`` protocol: its cells' ``eval/``); 0 keeps the run's own."""
    episode_limit: int = 0
    """An evaluation-only episode limit [decisions] for a side evaluation beside the run's
    own: played into ``eval-limit<N>/``, never into ``eval/``, and left out of Table II
    (``priqn evaluate --max-episode-steps N``; docs/evaluation.md, "The horizon"). The
    observation holds no clock, so a limit changes no decision, only where an episode is
    cut. 0: none. Wins over ``max_episode_steps``."""
    device: str = "cpu"
    """Torch device for the policy network."""
    acting: str = "own"
    """How the policy acts: "own" (its agent's rule: greedy, or Pr-IQN's sample from its
    leaf subset; written to eval/) or "near-greedy" (the acting-randomness control for
    IQN, Ensemble-IQN and MA-IQN: uniform among the actions whose mean is within
    acting_eps of the best; written to eval-near-greedy/, labelled as its own row)."""
    acting_eps: float = 0.2
    """Tolerance ε of near-greedy acting, in per-state standard deviations of the scalar
    value's quantiles (the z-score of Pr-IQN's comparators; 0.2 is Pr-IQN*'s ε)."""
    nets: tuple[str, ...] = ()
    """Plain ``.net.xml`` files and/or folders of them to evaluate on instead of ``family``
    (no manifest; docs/your-own-net.md). Written to ``eval-nets-<hash>/`` beside ``eval/``
    (:func:`evaluation_name`), never into ``eval/``; one path or a list."""
    junction: str = ""
    """With ``nets``: the id of the junction to drive through ('' = each net's junction with
    the most approaches)."""
    snapshot: int = 0
    """Evaluate the policy the run kept at this many decisions (``checkpoint.keep_at``)
    instead of its final one, into ``eval-at<N>/`` beside ``eval/`` (0: the final policy)."""
    traffic: str = ""
    """A named traffic setting (:data:`priqn.env.traffic.TRAFFIC_SETTINGS`) whose NPC
    behaviour (``env.traffic``) the evaluation plays instead of the run's own, on the same
    scenes, into ``eval-traffic-<name>/`` beside ``eval/`` ('' = the run's own traffic). Only
    the NPCs change: the episode limit stays the run's, or the evaluation's
    (``max_episode_steps``, ``episode_limit``)."""

    def __post_init__(self) -> None:
        if isinstance(self.nets, str):  # one path (--set nets=my_nets/)
            object.__setattr__(self, "nets", (self.nets,) if self.nets else ())
        if not all(isinstance(n, str) and n for n in self.nets):
            raise ValueError(f"nets: expected .net.xml files or folders, got {list(self.nets)}")
        object.__setattr__(self, "nets", tuple(self.nets))
        if self.acting not in ACTINGS:
            raise ValueError(f"acting: {self.acting!r} is not one of {', '.join(ACTINGS)}")
        check_acting_eps(self.acting_eps, "acting_eps", error=ValueError)
        if not self.densities:
            raise ValueError("densities: need at least one density")
        for d in self.densities:
            check_density(d, "densities", error=ValueError)
        if len(set(self.densities)) != len(self.densities):
            raise ValueError(f"densities: duplicates in {list(self.densities)}")
        if self.eval_runs < 1:
            raise ValueError(f"eval_runs: must be >= 1, got {self.eval_runs}")
        if self.episodes_per_cell < 1:
            raise ValueError(f"episodes_per_cell: must be >= 1, got {self.episodes_per_cell}")
        if self.num_workers < 1:
            raise ValueError(f"num_workers: must be >= 1, got {self.num_workers}")
        if self.snapshot < 0:
            raise ValueError(
                f"snapshot: expected 0 (the final policy) or a budget, got {self.snapshot}"
            )
        if self.max_episode_steps < 0:
            raise ValueError(f"max_episode_steps: must be >= 0, got {self.max_episode_steps}")
        if self.episode_limit < 0:
            raise ValueError(f"episode_limit: must be >= 0, got {self.episode_limit}")
        bad = [c for c in self.commands if c not in ("left", "straight", "right")]
        if bad:
            raise ValueError(f"commands: {bad[0]!r} is not one of left, straight, right")


@dataclasses.dataclass(frozen=True)
class EvalScene:
    """One evaluation episode: what the environment is reset to and the acting seed."""

    eval_run: int
    """Evaluation-run index (0-based)."""
    net: str
    """Net as ``"<family>/<net_id>"``."""
    density: float
    """Requested traffic density."""
    episode: int
    """Episode index within the cell."""
    reset_seed: int
    """Seed passed to ``env.reset``."""
    act_seed: int
    """Seed of the policy's acting generator for this episode."""
    command: str | None
    """Route command, or None to let the environment draw it."""

    @property
    def cell(self) -> tuple[int, str, float]:
        return (self.eval_run, self.net, self.density)

    def reset_options(self) -> dict[str, Any]:
        options: dict[str, Any] = {"net": self.net, "density": self.density}
        if self.command is not None:
            options["command"] = self.command
        return options


def make_scenes(cfg: EvalConfig, net_ids: Sequence[str]) -> list[EvalScene]:
    """All evaluation episodes in canonical order (eval run, net, density, episode).

    ``net_ids`` are the hold-out nets' ids (without family); they are sorted, so the
    scenes depend only on the set of nets, ``cfg.seed`` and the cell's indices. With
    ``cfg.nets`` they are the nets' full names (``"<folder>/<stem>"``,
    :func:`~priqn.evaluation.targets.evaluation_nets`) and the same rule applies.
    """
    scenes = []
    for r in range(cfg.eval_runs):
        for n, net_id in enumerate(sorted(net_ids)):
            for d, density in enumerate(cfg.densities):
                for e in range(cfg.episodes_per_cell):
                    ss = np.random.SeedSequence(cfg.seed, spawn_key=(r, n, d, e))
                    reset_seed, act_seed = (int(x) for x in ss.generate_state(2, dtype=np.uint32))
                    command = cfg.commands[e % len(cfg.commands)] if cfg.commands else None
                    scenes.append(
                        EvalScene(
                            r,
                            net_id if cfg.nets else f"{cfg.family}/{net_id}",
                            float(density),
                            e,
                            reset_seed,
                            act_seed,
                            command,
                        )
                    )
    return scenes


RESULT_NEUTRAL_FIELDS: frozenset[str] = frozenset({"num_workers", "nets", "junction"})
"""EvalConfig fields that do not change any episode (may differ on resume). ``nets`` and
``junction`` say where the files lie and what was asked; what is evaluated on (each net's
name, SHA-256 and junction) is the evaluation's nets hash, checked on its own."""

LIMIT_PREFIX = "limit"
"""Evaluations at an evaluation-only episode limit are ``eval-limit<N>/`` (``episode_limit``)."""
NETS_PREFIX = "nets-"
"""Evaluations on your own nets are ``eval-nets-<hash>[-<control>]/`` (:func:`evaluation_name`)."""
NETS_HASH_CHARS = 8
"""Hex digits of the nets hash in an evaluation folder's name."""
FAMILY_PREFIX = "family-"
"""Evaluations on another scenario family than the run's own hold-out family are
``eval-family-<name>[-<control>]/`` (:func:`evaluation_name`)."""
_FAMILY_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")
TRAFFIC_PREFIX = "traffic-"
"""Evaluations under another traffic setting's NPCs than the run's own are
``eval-traffic-<name>[-<control>]/`` (:func:`evaluation_name`)."""


def recorded_env_config(env: Mapping[str, Any]) -> dict[str, Any]:
    """A recorded env config (an evaluation's meta.json ``env_config``) in the current
    form, so old and new records compare (``priqn.analysis.reference``, which reads files
    only, calls it here): its traffic as the traffic played (:func:`recorded_traffic`: the
    flat ``path_*`` keys of older records as their table, every field added since at its
    default, and a record written before traffic settings existed as SUMO's drivers, the
    defaults). An empty record stays empty: it says nothing of what was played."""
    out = dict(env)
    if out and isinstance(out.get("traffic", {}), Mapping):
        out["traffic"] = to_dict(recorded_traffic(out))
    return out


def recorded_traffic(env: Mapping[str, Any]) -> Any:
    """The traffic a recorded env config played (an evaluation's meta.json
    ``env_config``), as a :class:`priqn.env.traffic.TrafficBehaviour` with every default
    filled in: records of any form (the flat ``path_*`` keys of older ones, or fields added
    since) compare by what the NPCs did, not by how it was written."""
    from priqn.config import from_dict
    from priqn.env.traffic import TrafficBehaviour, upgrade_traffic_table

    table = upgrade_traffic_table(env.get("traffic") or {})
    return from_dict(TrafficBehaviour, table, "env_config.traffic")


def eval_config_differences(old: dict[str, Any], new: dict[str, Any]) -> list[tuple[str, Any, Any]]:
    """Result-affecting differences of two recorded EvalConfigs (``config_differences``).

    A field missing from a record written before the field existed counts as its
    default: the evaluation behaved as the default does (``acting`` was always "own").
    """
    defaults = to_dict(EvalConfig())
    return config_differences(
        {**defaults, **old}, {**defaults, **new}, ignore=RESULT_NEUTRAL_FIELDS
    )


def eval_config_changes(old: dict[str, Any], new: dict[str, Any]) -> str:
    """``"field old -> new, ..."`` for result-affecting EvalConfig fields that differ."""
    diff = eval_config_differences(old, new)
    return ", ".join(f"{k} {a!r} -> {b!r}" for k, a, b in diff)


def evaluation_name(
    cfg: EvalConfig, nets_hash: str = "", own_family: str = EvalConfig.family
) -> str:
    """Name of the evaluation ``cfg`` makes: "" (the run's own, ``eval/``), ``near-greedy``
    (a control at the default ε, ``eval-near-greedy/``) or ``near-greedy-eps<ε>``.

    With ``cfg.nets``: ``nets-<first 8 hex digits of nets_hash>``
    (:func:`~priqn.evaluation.targets.nets_hash`), then the control's name if any (``nets-1a2b3c4d-near-greedy``): an evaluation on other nets
    never shares a folder with the hold-out one. With ``cfg.snapshot`` N: ``at<N>`` first
    (``at60000``, ``at60000-near-greedy``). With ``cfg.episode_limit`` N: ``limit<N>`` before
    the control (``limit600``, ``at60000-limit600-near-greedy``). With ``cfg.family`` other
    than ``own_family`` (the run's hold-out family, ``holdout`` unless its
    ``evaluation.family`` says otherwise): ``family-<name>`` after the snapshot
    (``family-out-of-range``, ``at60000-family-out-of-range-near-greedy``); on its own
    family the name is unchanged, so ``eval/`` stays the run's hold-out evaluation. With
    ``cfg.traffic``: ``traffic-<name>`` after the family (``traffic-tm-carla``).
    """
    if cfg.nets and not nets_hash:
        raise ValueError("evaluation_name: an evaluation on cfg.nets needs their nets_hash")
    control = ""
    if cfg.acting != "own":
        control = (
            cfg.acting
            if cfg.acting_eps == EvalConfig.acting_eps
            else f"{cfg.acting}-eps{cfg.acting_eps:g}"
        )
    snapshot = snapshot_evaluation(cfg.snapshot) if cfg.snapshot else ""
    limit = f"{LIMIT_PREFIX}{cfg.episode_limit}" if cfg.episode_limit else ""
    nets = f"{NETS_PREFIX}{nets_hash[:NETS_HASH_CHARS]}" if cfg.nets else ""
    family = ""
    if not cfg.nets and cfg.family != own_family:
        if not _FAMILY_NAME.fullmatch(cfg.family):
            raise PriqnError(
                f"family {cfg.family!r}: expected a scenario family's name (letters, digits, "
                "'_', '.', '-'), not a path"
            )
        family = f"{FAMILY_PREFIX}{cfg.family}"
    traffic = ""
    if cfg.traffic:
        if not _FAMILY_NAME.fullmatch(cfg.traffic):
            raise PriqnError(f"traffic {cfg.traffic!r}: expected a named traffic setting")
        traffic = f"{TRAFFIC_PREFIX}{cfg.traffic}"
    return "-".join(p for p in (snapshot, nets, family, traffic, limit, control) if p)


def limit_of(name: str) -> int:
    """The evaluation-only episode limit of evaluation ``name`` (its ``limit<N>`` part), or
    0 for an evaluation at the run's own limit."""
    match = re.search(rf"(?:^|-){LIMIT_PREFIX}(\d+)(?:-|$)", name)
    return int(match[1]) if match else 0


def is_nets_evaluation(name: str) -> bool:
    """Whether ``eval-<name>/`` is an evaluation on other nets (not part of Table II)."""
    return snapshot_budget(name)[1].startswith(NETS_PREFIX)


def is_traffic_evaluation(name: str) -> bool:
    """Whether ``eval-<name>/`` played another traffic setting's NPCs than the run's own
    (``traffic-<setting>`` in its name; not part of Table II)."""
    return f"-{TRAFFIC_PREFIX}" in f"-{name}"


def is_family_evaluation(name: str) -> bool:
    """Whether ``eval-<name>/`` is an evaluation on another scenario family than the run's
    own hold-out family (not part of Table II)."""
    return snapshot_budget(name)[1].startswith(FAMILY_PREFIX)


def snapshot_budget(name: str) -> tuple[int, str]:
    """``(N, rest)`` of an evaluation name ``at<N>[-rest]`` (a kept snapshot's); ``(0, name)``
    for the final policy's."""
    match = re.fullmatch(rf"{SNAPSHOT_PREFIX}(\d+)(?:-(.*))?", name)
    if match is None:
        return 0, name
    return int(match[1]), match[2] or ""


def control_config(cfg: EvalConfig, name: str) -> EvalConfig:
    """``cfg`` acting as the control ``name`` says (inverse of :func:`evaluation_name`).

    A one-line PriqnError for a name that is not ``near-greedy`` or ``near-greedy-eps<ε>``.
    """
    if not name:
        return dataclasses.replace(cfg, acting="own")
    match = re.fullmatch(r"(?P<acting>[a-z-]+?)(?:-eps(?P<eps>[0-9.e+-]+))?", name)
    if match is None or match["acting"] not in ACTINGS or match["acting"] == "own":
        raise PriqnError(
            f"control {name!r}: expected near-greedy or near-greedy-eps<ε> (e.g. near-greedy-eps0.01)"
        )
    try:
        eps = float(match["eps"]) if match["eps"] else EvalConfig.acting_eps
        return dataclasses.replace(cfg, acting=match["acting"], acting_eps=eps)
    except ValueError as exc:
        raise PriqnError(f"control {name!r}: {exc}") from None


def eval_dir_of(
    run: RunFolder, cfg: EvalConfig, nets_hash: str = "", own_family: str = EvalConfig.family
) -> Path:
    """The run's evaluation folder for ``cfg``: ``eval/`` or ``eval-<name>/``
    (:func:`evaluation_name`; ``own_family``: the run's hold-out family)."""
    return evaluation_dir(run, evaluation_name(cfg, nets_hash, own_family))
