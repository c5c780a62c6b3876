"""What one decision of a trained policy shows, for the diagnosis tools.

``priqn inspect`` (``decisions.csv``), ``priqn mechanism`` (its decision files) and
``priqn mechanism --standstill`` each write one row per decision; the facts those rows
share are computed here, once:

- :func:`greedy_actions`: the action each head would take on its own (argmax of its mean
  over the K fixed-grid quantiles);
- :func:`removed_by`: the preorder level that removed an action, or every action of a set
  (the first level, in a given order, whose optimal subset holds none of them);
- :func:`greedy_removals`: both together, per head;
- :func:`decision_key`: the columns that name a replayed decision (scene, step, action).

Pure numpy on the arrays of a :class:`priqn.agents.policy.Decision`; no torch, no SUMO.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

KEPT = ""
"""What :func:`removed_by` returns when the actions survive every level it walked."""


def greedy_actions(quantiles_HKA: np.ndarray) -> np.ndarray:
    """int ``[H]``: each head's greedy action, the argmax over A of its mean over K
    (``quantiles_HKA``: ``[H, K, A]``; the first action of a tie)."""
    return np.argmax(np.asarray(quantiles_HKA).mean(axis=1), axis=1)


def removed_by(
    subsets_LA: np.ndarray, levels: Sequence[str], order: Sequence[str], actions: Any
) -> str:
    """The first level of ``order`` whose optimal subset holds none of ``actions``, or
    :data:`KEPT` ('') when some of them survive every level of ``order``.

    ``subsets_LA``: bool ``[L, A]``, one optimal subset per level, named by ``levels``
    (a leaf set may be one more row); ``order``: the levels to walk, in order (a
    preorder's topological order, the levels above a target level, or one level alone:
    then the answer says whether that level keeps any of ``actions``); ``actions``: one
    action index, or a bool ``[A]`` mask of several (the "go" actions).
    """
    keep_LA = np.asarray(subsets_LA, dtype=bool)
    wanted_A = np.zeros(keep_LA.shape[-1], dtype=bool)
    wanted_A[actions] = True
    for name in order:
        if not (keep_LA[list(levels).index(name)] & wanted_A).any():
            return name
    return KEPT


def greedy_removals(
    quantiles_HKA: np.ndarray,
    heads: Sequence[str],
    subsets_LA: np.ndarray,
    levels: Sequence[str],
    order: Sequence[str],
) -> dict[str, tuple[int, str]]:
    """Head name → (its greedy action, :func:`removed_by` of that action over ``order``).

    ``heads``: what each head of ``quantiles_HKA`` estimates, in head order (per-objective
    heads); ``subsets_LA`` / ``levels`` / ``order`` as in :func:`removed_by`."""
    greedy_H = greedy_actions(quantiles_HKA)
    out = {}
    for h, name in enumerate(heads):
        greedy = int(greedy_H[h])
        out[name] = (greedy, removed_by(subsets_LA, levels, order, greedy))
    return out


def decision_key(step: Any) -> dict[str, Any]:
    """The columns that name one replayed decision
    (:class:`priqn.evaluation.rollout.RolloutStep`): its scene (``eval_run``, ``net``,
    ``density``, ``episode``), ``decision`` (its index in the episode) and ``action``."""
    return {
        "eval_run": step.scene.eval_run,
        "net": step.scene.net,
        "density": step.scene.density,
        "episode": step.scene.episode,
        "decision": step.step,
        "action": step.action,
    }
