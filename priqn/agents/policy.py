"""Acting with a trained (or training) network: the policy side of the acting/learning split."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from priqn.agents import rules
from priqn.agents.network import QuantileNetwork, tau_grid, to_tensors
from priqn.agents.registry import Agent
from priqn.errors import PriqnError
from priqn.labels import PolicyLabel, near_greedy


class Policy:
    """Greedy acting rule of one agent on the fixed τ grid (no ε-exploration).

    ``act(obs_batch, rng)`` → ``int64 [B]``. Pr-IQN samples uniformly from its leaf
    optimal subset using ``rng``; the other agents are deterministic (``rng`` is still
    advanced by one draw per state so every agent consumes the same stream).
    ``env_config`` and ``labels`` are filled by ``priqn.runs.load_policy``.
    :meth:`near_greedy` gives the same network acting by the near-greedy control rule.
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
        self.last_subset_sizes: np.ndarray | None = None
        """float ``[B, N + 1]`` after :meth:`act` of a preorder agent: |S_r| per objective
        and of the leaf for each state (None for agents without a preorder)."""
        names = () if agent.subsets is None else agent.subsets.preorder.objectives
        self.subset_size_names: tuple[str, ...] = tuple(names) + (("leaf",) if names else ())
        """Column names of ``last_subset_sizes``."""
        self.near_greedy_eps: float | None = None
        """Set by :meth:`near_greedy`: act uniformly within ε of the best (the control)."""
        self.last_near_greedy_BA: np.ndarray | None = None
        """bool ``[B, A]`` after :meth:`act` of a near-greedy policy: the set it sampled from."""

    @torch.no_grad()
    def quantiles(self, obs_batch: Mapping[str, np.ndarray]) -> torch.Tensor:
        """Fixed-grid quantiles ``[B, H, K, A]`` of a numpy observation batch."""
        obs = to_tensors(obs_batch, self.device)
        B = obs["command"].shape[0]
        return self.network(obs, self.grid_K.expand(B, -1))

    def near_greedy(self, eps: float) -> Policy:
        """This network acting by the control rule :func:`rules.near_greedy_subsets` at ``eps``.

        Only for agents with a scalar value (IQN, Ensemble-IQN, MA-IQN); the label gets
        the words ``near-greedy ε=<eps>`` so its evaluation is its own Table II row, and
        ``last_subset_sizes`` reports the size of the near-greedy set as ``leaf``.
        """
        if self.agent.spec.acting_rule not in rules.SCALAR_VALUES:
            raise PriqnError(
                f"near-greedy acting applies to agents with one scalar value "
                f"(iqn, ensemble-iqn, ma-iqn), not {self.agent.name!r}, which already "
                "samples from its optimal subsets"
            )
        if not eps >= 0:
            raise PriqnError(f"near-greedy ε: expected a number >= 0, got {eps!r}")
        control = Policy(self.network, self.agent, self.grid_K.shape[0], self.device)
        control.env_config = self.env_config
        control.labels = dict(self.labels)
        if self.labels:
            control.labels.update(near_greedy(PolicyLabel.from_row(self.labels), eps).to_row())
        control.near_greedy_eps = float(eps)
        control.subset_size_names = ("leaf",)
        return control

    @torch.no_grad()
    def act(self, obs_batch: Mapping[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        """Actions ``int64 [B]`` for a batch of observations (greedy, leaf sample or control)."""
        q_BHKA = self.quantiles(obs_batch)
        u_B = torch.from_numpy(rng.random(q_BHKA.shape[0])).to(self.device)
        if self.near_greedy_eps is not None:
            w = self.agent.reward_weights_5.to(q_BHKA.device, q_BHKA.dtype)
            values_BKA = rules.SCALAR_VALUES[self.agent.spec.acting_rule](q_BHKA, w)
            out = rules.near_greedy_subsets(values_BKA, self.near_greedy_eps)
            self.last_near_greedy_BA = out.leaf.cpu().numpy()
            self.last_subset_sizes = self.last_near_greedy_BA.sum(axis=-1, keepdims=True)
            return rules.masked_uniform_choice(out.leaf, u_B).cpu().numpy().astype(np.int64)
        actions = self.agent.act(q_BHKA, u_B).cpu().numpy().astype(np.int64)
        subsets = self.agent.subsets
        if subsets is not None and subsets.last is not None:
            out = subsets.last
            self.last_subset_sizes = (
                torch.cat(
                    [out.per_objective.sum(dim=-1), out.leaf.sum(dim=-1, keepdim=True)], dim=-1
                )
                .cpu()
                .numpy()
            )
        return actions


class SubsetSizeMeans:
    """Per-env running means of the acting optimal-subset sizes over an episode.

    ``add(sizes_EN)`` after each acting step (rows of envs that did not act may be
    skipped with ``rows``); ``pop(e)`` returns ``{"subset_<name>": mean}`` for env e's
    episode and restarts its mean. Empty for agents without a preorder.
    """

    def __init__(self, num_envs: int, names: tuple[str, ...]) -> None:
        self.names = names
        self.sum_EN = np.zeros((num_envs, len(names)))
        self.count_E = np.zeros(num_envs)

    def add(self, sizes_BN: np.ndarray | None, rows: Any = slice(None)) -> None:
        if sizes_BN is None or not self.names:
            return
        self.sum_EN[rows] += sizes_BN
        self.count_E[rows] += 1

    def pop(self, e: int) -> dict[str, float]:
        if not self.names:
            return {}
        mean_N = self.sum_EN[e] / max(self.count_E[e], 1.0)
        self.sum_EN[e] = 0.0
        self.count_E[e] = 0.0
        return {f"subset_{n}": round(float(v), 3) for n, v in zip(self.names, mean_N, strict=True)}
