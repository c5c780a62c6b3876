"""Acting with a trained (or training) network: the policy side of the acting/learning split."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from priqn.agents import rules
from priqn.agents.labels import PolicyLabel, near_greedy
from priqn.agents.network import QuantileNetwork, tau_grid, to_tensors
from priqn.agents.registry import Agent
from priqn.checks import check_acting_eps
from priqn.errors import PriqnError


@dataclasses.dataclass(frozen=True)
class Decision:
    """What one acting call decided for a batch of ``B`` states, and why.

    Returned by :meth:`Policy.decide` (and by any rollout "policy", e.g. the reference
    drivers, with only ``actions_B``). ``L`` is the number of preorder levels (the
    preorder's objectives, in N-axis order), ``A`` the number of actions.
    """

    actions_B: np.ndarray
    """int64 ``[B]``: the chosen actions."""
    levels: tuple[str, ...] = ()
    """Names of the L axis of ``subsets_BLA`` (the preorder's objectives; () without one)."""
    subsets_BLA: np.ndarray | None = None
    """bool ``[B, L, A]``: each preorder level's optimal subset S_r (None without a preorder)."""
    leaf_BA: np.ndarray | None = None
    """bool ``[B, A]``: the set the action was sampled from: the leaf optimal subset, or the
    near-greedy set of the acting-randomness control (None for a greedy argmax)."""
    quantiles_BHKA: np.ndarray | None = None
    """float32 ``[B, H, K, A]``: the fixed-grid quantiles acted on (only when asked for)."""

    @property
    def subset_sizes_BS(self) -> np.ndarray | None:
        """int ``[B, S]``: |S_r| per level then the leaf's (S = L + 1), or the near-greedy
        set's size alone (S = 1); None when the policy acted on no set. Columns:
        :attr:`Policy.subset_size_names`."""
        if self.subsets_BLA is not None and self.leaf_BA is not None:
            return np.concatenate(
                [self.subsets_BLA.sum(axis=-1), self.leaf_BA.sum(axis=-1, keepdims=True)], axis=-1
            )
        if self.leaf_BA is not None:
            return self.leaf_BA.sum(axis=-1, keepdims=True)
        return None

    def row(self, b: int) -> Decision:
        """This record for state ``b`` alone (every array keeps a B axis of 1)."""

        def pick(x: np.ndarray | None) -> np.ndarray | None:
            return None if x is None else x[b : b + 1]

        return Decision(
            self.actions_B[b : b + 1],
            self.levels,
            pick(self.subsets_BLA),
            pick(self.leaf_BA),
            pick(self.quantiles_BHKA),
        )


class Policy:
    """Greedy acting rule of one agent on the fixed τ grid (no ε-exploration).

    ``decide(obs_batch, rng)`` → :class:`Decision` (actions ``int64 [B]``, the optimal
    subsets acted on and, with ``quantiles=True``, the quantiles); ``act`` → the actions
    alone. Pr-IQN samples uniformly from its leaf optimal subset using ``rng``; the other
    agents are deterministic (``rng`` is still advanced by one draw per state so every
    agent consumes the same stream). ``env_config`` and ``labels`` are filled by
    ``priqn.run.checkpointer.load_policy``. :meth:`near_greedy` gives the same network acting by the
    near-greedy control rule.
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
        names = () if agent.subsets is None else agent.subsets.preorder.objectives
        self.levels: tuple[str, ...] = tuple(names)
        """The preorder's objectives: the L axis of :attr:`Decision.subsets_BLA`."""
        self.subset_size_names: tuple[str, ...] = tuple(names) + (("leaf",) if names else ())
        """Column names of :attr:`Decision.subset_sizes_BS` (() without a preorder)."""
        self.near_greedy_eps: float | None = None
        """Set by :meth:`near_greedy`: act uniformly within ε of the best (the control)."""

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
        its decisions report the near-greedy set as the leaf (size column ``leaf``).
        """
        if self.agent.spec.acting_rule not in rules.SCALAR_VALUES:
            raise PriqnError(
                f"near-greedy acting applies to agents with one scalar value "
                f"(iqn, ensemble-iqn, ma-iqn), not {self.agent.name!r}, which already "
                "samples from its optimal subsets"
            )
        check_acting_eps(eps, "near-greedy ε")
        control = Policy(self.network, self.agent, self.grid_K.shape[0], self.device)
        control.env_config = self.env_config
        control.labels = dict(self.labels)
        if self.labels:
            control.labels.update(near_greedy(PolicyLabel.from_row(self.labels), eps).to_row())
        control.near_greedy_eps = float(eps)
        control.levels = ()
        control.subset_size_names = ("leaf",)
        return control

    @torch.no_grad()
    def decide(
        self, obs_batch: Mapping[str, np.ndarray], rng: np.random.Generator, quantiles: bool = False
    ) -> Decision:
        """The :class:`Decision` for a batch of observations (greedy, leaf sample or control).

        One forward pass and one draw of ``rng`` per state, whatever is recorded;
        ``quantiles=True`` adds the fixed-grid quantiles (a copy to the host).
        """
        q_BHKA = self.quantiles(obs_batch)
        u_B = torch.from_numpy(rng.random(q_BHKA.shape[0])).to(self.device)
        w = self.agent.reward_weights_O.to(q_BHKA.device, q_BHKA.dtype)
        q_host = q_BHKA.float().cpu().numpy() if quantiles else None
        if self.near_greedy_eps is not None:
            values_BKA = rules.SCALAR_VALUES[self.agent.spec.acting_rule](q_BHKA, w)
            out = rules.near_greedy_subsets(values_BKA, self.near_greedy_eps)
            actions_B = rules.masked_uniform_choice(out.leaf, u_B)
            return Decision(
                actions_B.cpu().numpy().astype(np.int64),
                leaf_BA=out.leaf.cpu().numpy(),
                quantiles_BHKA=q_host,
            )
        act = rules.lookup(rules.ACTING_RULES, self.agent.spec.acting_rule, "acting rule")
        actions_B, out = rules.act_with_subsets(act, q_BHKA, self.agent.subsets, u_B, w)
        actions = actions_B.cpu().numpy().astype(np.int64)
        if out is None:
            return Decision(actions, quantiles_BHKA=q_host)
        # One copy to the host: every level's subset and the leaf's, [B, L + 1, A].
        sets_BSA = torch.cat([out.per_objective, out.leaf.unsqueeze(1)], dim=1).cpu().numpy()
        return Decision(actions, self.levels, sets_BSA[:, :-1], sets_BSA[:, -1], q_host)

    def act(self, obs_batch: Mapping[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        """Actions ``int64 [B]`` for a batch of observations: :meth:`decide`'s actions."""
        return self.decide(obs_batch, rng).actions_B


class SubsetSizeMeans:
    """Per-env running means of the acting optimal-subset sizes over an episode.

    ``add(sizes_EN)`` (:attr:`Decision.subset_sizes_BS`) after each acting step (rows of envs that did not act may be
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
