"""Reference drivers (``priqn evaluate --reference sumo|random``): SUMO's own driver
models, or uniform random actions, evaluated on the same scenes as every policy."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from priqn.config import config_differences, to_dict
from priqn.errors import PriqnError
from priqn.evaluation.protocol import LABEL_KEYS, EvalConfig, evaluation_name
from priqn.evaluation.store import evaluate_policy
from priqn.evaluation.targets import evaluation_env, evaluation_target, find_runs
from priqn.io import read_json
from priqn.run.evaluations import evaluation_dir
from priqn.run.folder import RunFolder

REFERENCES: dict[str, str] = {"sumo": "SUMO driver", "random": "Random actions"}
"""Reference drivers (``priqn evaluate --reference NAME``) and their row names."""
REFERENCE_WORD = "(reference)"
"""Ends every reference row's label, e.g. ``SUMO driver (reference)``."""
DEFAULT_REFERENCE_DIR = "reference"
"""A reference evaluation goes to ``reference/<name>/`` unless ``--out`` says otherwise."""
OBSERVATION_FIELDS: frozenset[str] = frozenset(
    {"obs_size_px", "render_size_px", "bev_range_m", "bev_behind_m", "bev_channels"}
)
"""EnvConfig fields that change what a policy sees but no scene, move or measure."""
SCENE_NEUTRAL_FIELDS: frozenset[str] = OBSERVATION_FIELDS | {
    "family",
    "nets",
    "nets_dir",
    "junction",
}
"""EnvConfig fields a reference evaluation may take from any of its runs (the nets are the
evaluation's own)."""


def reference_label(name: str) -> str:
    """The label of reference driver ``name``'s rows: ``SUMO driver (reference)``."""
    return f"{REFERENCES[name]} {REFERENCE_WORD}"


class ReferenceDriver:
    """A reference "policy": ``sumo`` (SUMO drives the ego, ``EnvConfig.ego_driver``; the
    action is ignored) or ``random`` (uniform over the action grid, from the scene's acting
    generator, so it is reproducible like a policy's own randomness)."""

    def __init__(self, name: str, num_actions: int) -> None:
        """``name``: a key of :data:`REFERENCES`; ``num_actions``: the env's action count."""
        if name not in REFERENCES:
            raise PriqnError(f"--reference {name}: expected one of {', '.join(REFERENCES)}")
        self.name = name
        """Driver name (a key of :data:`REFERENCES`)."""
        self.num_actions = int(num_actions)
        """Size of the env's action grid."""
        self.labels: dict[str, Any] = {key: "" for key in LABEL_KEYS}
        """Episode-row identity: ``agent`` = the driver's name, training seed 0 (none)."""
        self.labels.update(agent=name, train_seed=0, label=reference_label(name))

    def act(self, obs: Any, rng: np.random.Generator) -> np.ndarray:
        """One action: uniform at random (``random``); 0, ignored by the env (``sumo``)."""
        if self.name == "random":
            return np.array([int(rng.integers(self.num_actions))], np.int64)
        return np.zeros(1, np.int64)

    def decide(self, obs: Any, rng: np.random.Generator, quantiles: bool = False) -> Any:
        """:meth:`act` as a :class:`priqn.agents.policy.Decision` (no subsets, no quantiles)."""
        from priqn.agents.policy import Decision

        return Decision(self.act(obs, rng))


def reference_env_config(paths: Iterable[str | Path]) -> tuple[Any, list[str]]:
    """The EnvConfig a reference evaluation plays with, and the runs it comes from.

    From the runs under ``paths`` (their scenes, episode length, action grid and rewards):
    they must agree on every field but what only a policy sees and the nets
    (:data:`SCENE_NEUTRAL_FIELDS`). No paths: ``priqn train``'s default env.
    """
    from priqn.run.train_config import TrainConfig

    runs = find_runs(paths) if paths else []
    if not runs:
        return TrainConfig().env, []
    configs = [(run, RunFolder(run).config().env) for run in runs]
    first, env = configs[0]
    for run, other in configs[1:]:
        diff = config_differences(to_dict(env), to_dict(other), ignore=SCENE_NEUTRAL_FIELDS)
        if diff:
            key, a, b = diff[0]
            raise PriqnError(
                f"{run}: its env differs from {first}'s ({key} {a!r} vs {b!r}); a reference "
                "plays one env: evaluate it against runs that share it (or one run)"
            )
    return env, [RunFolder(run).name for run in runs]


def evaluate_reference(
    name: str,
    out_dir: str | Path,
    cfg: EvalConfig,
    env_config: Any,
    env_of: Sequence[str] = (),
    force: bool = False,
) -> Path:
    """Evaluate reference driver ``name`` with ``cfg``'s protocol; returns its episode table.

    Same scenes as every policy evaluated with ``cfg`` (the scene rule never reads a run):
    the hold-out family into ``out_dir/eval/``, or ``cfg.nets`` into
    ``out_dir/eval-nets-<hash>/``; resumable like a run's evaluation. ``env_config``: the
    env the driver plays (:func:`reference_env_config`; ``env_of`` names its runs). The
    rows are labelled :func:`reference_label`; ``priqn report --reference out_dir`` shows them.
    """
    if cfg.acting != "own":
        raise PriqnError(f"--reference {name}: --acting applies to trained policies only")
    from priqn.env.vector import make_vector_env

    driver = ReferenceDriver(name, env_config.n_speeds * env_config.n_offsets)
    net_ids, holdout_hash, nets = evaluation_target(cfg, env_config.commands)
    folder = RunFolder(out_dir)
    eval_dir = evaluation_dir(folder, evaluation_name(cfg, holdout_hash if nets else ""))
    env_cfg = evaluation_env(env_config, cfg, nets)
    env_cfg = dataclasses.replace(env_cfg, ego_driver="sumo" if name == "sumo" else "planner")
    meta_path = eval_dir / RunFolder.META
    if not force and meta_path.is_file() and read_json(meta_path).get("reference") != name:
        raise PriqnError(
            f"{meta_path}: holds no {name!r} reference evaluation; pick another --out "
            "(or --force to start over)"
        )

    def make_env(num_envs: int) -> Any:
        return make_vector_env(env_cfg, num_envs=num_envs, seed=cfg.seed, preload=True)

    from priqn.run.provenance import git_sha, versions

    extra_meta: dict[str, Any] = {
        "reference": name,
        "env_of": list(env_of),
        "env_config": to_dict(env_cfg),
        "git_sha": git_sha(),  # a reference has no run folder: its provenance lives here
        "versions": versions(),
    }
    if nets is not None:
        extra_meta.update(nets=nets["nets"], nets_hash=holdout_hash)
    return evaluate_policy(
        driver,
        eval_dir,
        cfg,
        net_ids,
        holdout_hash,
        f"{DEFAULT_REFERENCE_DIR}/{name}",
        make_env,
        extra_meta=extra_meta,
        force=force,
    )
