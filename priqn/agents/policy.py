"""Acting with a trained (or training) network: the policy side of the acting/learning split."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from priqn.agents.learner import to_tensors
from priqn.agents.network import QuantileNetwork, tau_grid
from priqn.agents.registry import Agent


class Policy:
    """Greedy acting rule of one agent on the fixed τ grid (no ε-exploration).

    ``act(obs_batch, rng)`` → ``int64 [B]``. Pr-IQN samples uniformly from its leaf
    optimal subset using ``rng``; the other agents are deterministic (``rng`` is still
    advanced by one draw per state so every agent consumes the same stream).
    ``env_config`` and ``labels`` are filled by ``priqn.train.load_policy``.
    """

    def __init__(
        self,
        network: QuantileNetwork,
        agent: Agent,
        num_quantiles: int,
        device: torch.device | str = "cpu",
        env_config: Any = None,
        labels: Mapping[str, Any] | None = None,
    ) -> None:
        self.device = torch.device(device)
        self.network = network.to(self.device)
        self.agent = agent
        self.grid_K = tau_grid(num_quantiles, self.device)
        self.env_config = env_config
        self.labels = dict(labels or {})

    @torch.no_grad()
    def quantiles(self, obs_batch: Mapping[str, np.ndarray]) -> torch.Tensor:
        """Fixed-grid quantiles ``[B, H, K, A]`` of a numpy observation batch."""
        obs = to_tensors(obs_batch, self.device)
        B = obs["command"].shape[0]
        return self.network(obs, self.grid_K.expand(B, -1))

    @torch.no_grad()
    def act(self, obs_batch: Mapping[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        """Greedy actions ``int64 [B]`` for a batch of observations."""
        q_BHKA = self.quantiles(obs_batch)
        u_B = torch.from_numpy(rng.random(q_BHKA.shape[0])).to(self.device)
        return self.agent.act(q_BHKA, u_B).cpu().numpy().astype(np.int64)
