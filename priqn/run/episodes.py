"""The one reader of an ended episode's info (gymnasium's SAME_STEP ``final_info``).

Training (metrics.csv), in-training evaluation and ``priqn evaluate`` (episodes.csv)
all summarise an episode through :func:`final_info` and :func:`episode_values`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from priqn.objectives import COLLISION_COLUMNS, OBJECTIVES, OUTCOME_PRECEDENCE, OUTCOMES


def one_outcome(flags: Mapping[str, bool]) -> dict[str, bool]:
    """The episode's flags with only the first set one (:data:`OUTCOME_PRECEDENCE`) kept."""
    out, earlier = {}, False
    for flag in OUTCOME_PRECEDENCE:
        out[flag] = bool(flags[flag]) and not earlier
        earlier |= out[flag]
    return out


def resolve_outcomes(episodes: Any) -> Any:
    """A copy of an episode table (pandas) whose flags obey :data:`OUTCOME_PRECEDENCE`.

    Each flag is cleared where an earlier one is set. Used by the report's loader, so
    episode tables written before the precedence existed (committed results are never
    re-run) are read with one outcome per episode.
    """
    out = episodes.copy()
    earlier = np.zeros(len(out), dtype=bool)
    for flag in OUTCOME_PRECEDENCE:
        value = out[flag].astype(bool).to_numpy() & ~earlier
        out[flag] = value if out[flag].dtype == bool else value.astype(out[flag].dtype)
        earlier |= value
    return out


def final_info(infos: Mapping[str, Any], i: int) -> dict[str, Any]:
    """The terminal info of env ``i`` from a SAME_STEP vector-env info dict."""
    final = infos.get("final_info")
    if final is None:
        raise RuntimeError("episode ended without 'final_info' in the vector-env infos")
    row = {}
    for key, value in final.items():
        if key.startswith("_"):
            continue
        mask = final.get(f"_{key}")
        if mask is not None and not bool(mask[i]):
            continue
        row[key] = value[i]
    return row


def episode_values(info: Mapping[str, Any]) -> dict[str, Any]:
    """An ended episode's outcome from its final info: flags, progress, realised density,
    length (``steps``), ``return_<objective>`` and the route command (if given).

    Exactly one of the outcome flags is set (:func:`one_outcome`): the env may report a
    collision and leaving the road in the same decision; the episode counts as a collision.
    """
    missing = [k for k in (*OUTCOMES, "route_progress", "returns") if k not in info]
    if missing:
        raise RuntimeError(f"environment info lacks {missing} (see docs/ARCHITECTURE.md, info)")
    returns = np.asarray(info["returns"], dtype=np.float64).reshape(-1)
    names = tuple(info.get("reward_names", OBJECTIVES))  # the env's declared objectives
    if returns.shape != (len(names),):
        raise RuntimeError(
            f"info['returns'] has shape {returns.shape}, expected ({len(names)},) "
            f"for objectives {', '.join(names)}"
        )
    flags = one_outcome({k: bool(info[k]) for k in OUTCOME_PRECEDENCE})
    values = {
        **{k: flags[k] for k in OUTCOMES},
        "route_progress": float(info["route_progress"]),
        "density_realised": float(info.get("density_realised", np.nan)),
        "steps": int(info.get("episode_steps", -1)),
    }
    values.update({f"return_{name}": float(v) for name, v in zip(names, returns, strict=True)})
    if "command" in info and info["command"] is not None:
        values["command"] = str(info["command"])
    # The collision's forensics (priqn.env.forensics), where the env records them.
    values.update({k: info[k] for k in COLLISION_COLUMNS if k in info})
    return values
