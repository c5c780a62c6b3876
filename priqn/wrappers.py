"""Wrappers for single-objective RL libraries: the 5-vector reward as one number.

>>> import gymnasium, priqn
>>> from priqn.wrappers import ScalarizeReward
>>> env = ScalarizeReward(gymnasium.make("priqn/Intersection-v0", obs_size_px=64))  # hln-2
>>> env = ScalarizeReward(env, weights=(1, 0.1, 0.05, 0.02, 0.01))  # your own weights

The reward becomes ``Σ_i w_i r_i`` (the env's ``config.objectives`` order; by default
safety, risk, lane keeping, progress, comfort) and the vector stays available as ``info["reward_vector"]``.
``weights`` is a scheme name of :mod:`priqn.agents.scalarise` (default ``"hln-2-task"``, the
agents' default, whose crash margin keeps crashing from ever paying; docs/implementation-details.md) or one
number per objective. :class:`ScalarizeVectorReward` does the same for a vector env
(``gymnasium.make_vec``), returning ``float32 [num_envs]`` rewards.
MO-Gymnasium users need no wrapper: the env has ``reward_space`` (Box, N objectives).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np

from priqn.agents.config import AgentConfig
from priqn.agents.scalarise import scheme_weights
from priqn.errors import PriqnError
from priqn.objectives import OBJECTIVES, objective_names

DEFAULT_SCHEME: str = AgentConfig.reward_scheme
"""The agents' default weighted-sum scheme, also the wrappers' default."""


def resolve_weights(
    weights: str | Sequence[float], objectives: Sequence[str] = OBJECTIVES
) -> np.ndarray:
    """A scheme name or one number per objective → ``float64 [O]`` (one-line errors);
    ``objectives``: the env's ``config.objectives``."""
    if isinstance(weights, str):
        return np.asarray(scheme_weights(weights, objectives=objectives), dtype=np.float64)
    n = len(objectives)
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.shape != (n,) or not np.isfinite(w).all():
        raise PriqnError(
            f"weights: expected a scheme name or {n} finite numbers "
            f"({', '.join(objective_names(objectives))}), got {weights!r}"
        )
    return w


def _env_objectives(env: Any) -> tuple[str, ...]:
    """The ``config.objectives`` of a priqn env (the default list for other envs)."""
    cfg = getattr(getattr(env, "unwrapped", env), "config", None)
    return tuple(getattr(cfg, "objectives", OBJECTIVES))


class ScalarizeReward(gymnasium.Wrapper):
    """Single env: reward ``Σ_i w_i r_i`` (float); the vector in ``info["reward_vector"]``."""

    def __init__(self, env: gymnasium.Env, weights: str | Sequence[float] = DEFAULT_SCHEME) -> None:
        super().__init__(env)
        self.weights_O = resolve_weights(weights, _env_objectives(env))
        """float64 ``[O]``: one weight per objective of the env (O = its objectives)."""
        low, high = _bounds(env, self.weights_O)
        self.reward_range = (low, high)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward_O, terminated, truncated, info = self.env.step(action)
        reward_O = np.asarray(reward_O, dtype=np.float64)
        info = {**info, "reward_vector": reward_O}
        return obs, float(reward_O @ self.weights_O), terminated, truncated, info


class ScalarizeVectorReward(gymnasium.vector.VectorWrapper):
    """Vector env: rewards ``float32 [num_envs]``; vectors in ``infos["reward_vector"]``."""

    def __init__(
        self, env: gymnasium.vector.VectorEnv, weights: str | Sequence[float] = DEFAULT_SCHEME
    ) -> None:
        super().__init__(env)
        objectives = tuple(getattr(env.unwrapped, "objectives", OBJECTIVES))  # priqn's make_vec
        self.weights_O = resolve_weights(weights, objectives)
        """float64 ``[O]``: one weight per objective of the env (O = its objectives)."""

    def step(self, actions: Any) -> tuple[Any, np.ndarray, Any, Any, dict[str, Any]]:
        obs, rewards_EO, terminated, truncated, infos = self.env.step(actions)
        rewards_EO = np.asarray(rewards_EO, dtype=np.float64)
        infos = {**infos, "reward_vector": rewards_EO}
        return obs, (rewards_EO @ self.weights_O).astype(np.float32), terminated, truncated, infos


def _bounds(env: gymnasium.Env, w_O: np.ndarray) -> tuple[float, float]:
    """Range of the scalar reward from the env's ``reward_space`` (±inf without one)."""
    space = getattr(env.unwrapped, "reward_space", None)
    if space is None:
        return -np.inf, np.inf
    lo, hi = np.asarray(space.low, np.float64), np.asarray(space.high, np.float64)
    return float(np.minimum(w_O * lo, w_O * hi).sum()), float(np.maximum(w_O * lo, w_O * hi).sum())
