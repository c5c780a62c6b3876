"""Fake evaluated runs with hand-checkable episode tables, for the analysis tests.

``write_run`` writes one run folder's ``eval/`` as ``priqn evaluate`` would; ``iqn_value`` and
``pr_value`` are the two policies whose statistics the tests check by hand. The ``runs``
fixture (conftest.py) lays out two seeds of each."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from priqn.evaluation.protocol import episode_columns
from priqn.objectives import OBJECTIVES

HASH = "a" * 64
EVAL_CONFIG = {
    "family": "holdout",
    "densities": [0.5, 1.0],
    "eval_runs": 2,
    "episodes_per_cell": 2,
    "seed": 2026,
    "commands": [],
    "max_episode_steps": 0,
}
IQN = {
    "agent": "iqn",
    "comparator": None,
    "train_preorder": None,
    "eps": None,
    "partial_order": None,
}
PR = {
    "agent": "pr-iqn",
    "comparator": "qd",
    "train_preorder": True,
    "eps": 0.2,
    "partial_order": False,
}
ENS = {
    "agent": "ensemble-iqn",
    "comparator": None,
    "train_preorder": None,
    "eps": None,
    "partial_order": None,
}


def write_run(
    root: Path,
    name: str,
    label: str,
    config: dict,
    seed: int,
    value,
    *,
    holdout=HASH,
    eval_config=None,
    eval_dir_name="eval",
    status="complete",
    objectives=OBJECTIVES,
):
    """One evaluated run; ``value(seed, eval_run, density, net, episode) -> dict`` of episode fields.

    ``eval_dir_name`` ``eval-<name>`` writes a control evaluation beside the run's own;
    ``objectives`` are the run's ``env.objectives`` (its ``return_<name>`` columns)."""
    cfg = eval_config or EVAL_CONFIG
    rows = []
    for r in range(cfg["eval_runs"]):
        for net in ("holdout/a", "holdout/b"):
            for d in cfg["densities"]:
                for e in range(cfg["episodes_per_cell"]):
                    v = {
                        "success": False,
                        "collision": False,
                        "off_road": False,
                        "route_progress": 0.5,
                        **{f"return_{o}": 0.0 for o in objectives},
                    }
                    v.update(value(seed, r, d, net, e))
                    rows.append(
                        {
                            "run": name,
                            "label": label,
                            **config,
                            "train_seed": seed,
                            "eval_run": r,
                            "net": net,
                            "density": d,
                            "density_realised": d,
                            "timeout": False,
                            "steps": 10,
                            "holdout_hash": holdout,
                            "episode": e,
                            "command": "left",
                            "reset_seed": 1000 * r + e,
                            **v,
                        }
                    )
    eval_dir = root / name / eval_dir_name
    eval_dir.mkdir(parents=True)
    (root / name / "config.toml").write_text("")
    pd.DataFrame(rows, columns=list(episode_columns(objectives))).to_csv(
        eval_dir / "episodes.csv", index=False
    )
    (eval_dir / "meta.json").write_text(
        json.dumps({"status": status, "holdout_hash": holdout, "eval_config": cfg})
    )


# IQN: unit (seed, eval_run) success rates at density 0.5: seed0 -> r0 0.0, r1 0.5; seed1 -> 0.5, 1.0
# (both nets identical). Mean 0.5, sample std sqrt(((.5)^2 + 0 + 0 + (.5)^2) / 3) = 0.408.
def iqn_value(seed, r, d, net, e):
    rate = {(0, 0): 0.0, (0, 1): 0.5, (1, 0): 0.5, (1, 1): 1.0}[(seed, r)]
    success = e < round(rate * 2)
    return {
        "success": success,
        "collision": not success,
        "route_progress": 1.0 if success else 0.5,
        "return_safety": -10.0 if d == 0.5 else -4.0,
        "return_risk": -2.0,
        "return_lane_keeping": 1.0,
    }


# Pr-IQN: always succeeds except one off-road episode per unit at density 1.0.
def pr_value(seed, r, d, net, e):
    off = d == 1.0 and net == "holdout/a" and e == 0
    return {
        "success": not off,
        "off_road": off,
        "route_progress": 0.8 if off else 1.0,
        "return_safety": -5.0 if d == 0.5 else -4.0,
        "return_risk": -3.0,
        "return_lane_keeping": 1.0 + seed,
    }


def tiny_grid(name: str, steps: int) -> str:
    """The head of an experiment TOML whose cells really train and evaluate, in about a
    minute: a tiny network and episodes, one density, one episode per hold-out net."""
    return f"""
[experiment]
name = "{name}"
net = "tjunction"
steps = {steps}
set = ["env.obs_size_px=32", "env.max_episode_steps=25", "network.latent_dim=64",
       "network.hidden_dim=64", "replay.capacity=4000", "replay.learning_starts=64",
       "evaluation.interval_steps=0", "exploration.decay_steps=60"]
[evaluate]
densities = [0.5]
eval_runs = 1
episodes_per_cell = 1
num_workers = 1
"""
