"""An agent built from its :class:`~priqn.agents.config.AgentSpec`: rules, weights, optimal subsets.

:class:`Agent` applies a spec's three rules (the functions the spec holds) with the run's
weighted-sum weights and, for an agent that ``uses_preorder``, its
:class:`PreorderSubsets`; :func:`make_agent` builds one from an agent name and config
(the whole construction path, network, learner and policy included, reads top to bottom
in :mod:`priqn.agents.build`). The shipped agents are declared in
:mod:`priqn.agents.shipped`; docs/your-own-agent.md adds one.

Shape suffixes as in :mod:`priqn.agents.network` (``B`` batch, ``H`` heads, ``K`` quantiles,
``A`` actions), plus ``O``: the run's objectives (``env.objectives``, five by default, six
with ``right_of_way``), the length of the reward vector. :mod:`priqn.agents.subsets` calls the
same axis ``N``; inside ``priqn.agents`` ``N`` is the learner's τ samples.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import torch

from priqn.agents import rules
from priqn.agents.config import COMPARATOR_NAMES, AgentConfig, AgentSpec, resolve_spec
from priqn.agents.scalarise import scheme_weights
from priqn.errors import PriqnError
from priqn.objectives import OBJECTIVES


def load_preorder(spec: str, objectives: tuple[str, ...] = OBJECTIVES) -> Any:
    """'total' | 'partial' | 'right-of-way' | path to a preorder TOML → ``Preorder`` over the
    run's ``objectives``, in their order (one line when it names others)."""
    from priqn.agents.preorder import Preorder

    try:
        return Preorder.resolve(spec, objectives)
    except PriqnError as exc:
        raise PriqnError(f"agent.preorder: {exc}") from None


class PreorderSubsets:
    """``quantiles_BNKA → OptimalSubsets`` with this agent's preorder, comparator and ε.

    With the scaled normalisation it owns the per-objective :class:`RunningScale`, which
    the learner feeds (:meth:`observe`) and checkpoints (:meth:`state_dict`). Each call
    returns its result and keeps nothing (the learner and :class:`Policy.decide` get the
    subsets their rule used from :func:`rules.target_with_subsets` / ``act_with_subsets``).
    """

    def __init__(self, preorder: Any, cfg: AgentConfig) -> None:
        from priqn.agents.comparators import RunningScale
        from priqn.agents.subsets import optimal_subsets

        self.preorder = preorder
        self.comparator = cfg.comparator
        self.eps = cfg.eps if isinstance(cfg.eps, float) else list(cfg.eps)
        self.scale = None
        if cfg.normalisation == "scaled":
            self.scale = RunningScale(len(preorder), cfg.scale_momentum, cfg.scale_fraction)
        self.seconds = 0.0
        """Wall time spent in Algorithm 1 so far (for ``priqn bench train``) [s]."""
        self._fn = optimal_subsets

    def __call__(self, quantiles_BNKA: torch.Tensor) -> Any:
        t0 = time.perf_counter()
        floor = None if self.scale is None else self.scale.floor()
        out = self._fn(
            quantiles_BNKA,
            self.preorder,
            comparator=self.comparator,
            eps=self.eps,
            spread_floor=floor,
        )
        self.seconds += time.perf_counter() - t0
        return out

    def observe(self, quantiles_BNKA: torch.Tensor) -> None:
        """Fold a batch of fixed-grid quantiles into the running scale (scaled only)."""
        if self.scale is not None:
            self.scale.update(quantiles_BNKA)

    def state_dict(self) -> dict[str, Any]:
        return {} if self.scale is None else {"scale": self.scale.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if self.scale is not None and "scale" in state:
            self.scale.load_state_dict(state["scale"])


class Agent:
    """Acting and target selection of one named agent (no network, no optimiser).

    ``act(quantiles_BHKA, u_B)`` → actions ``[B]``; ``target_actions(next_BHKA)`` →
    ``[B, H]``; ``head_rewards(rewards_BO)`` → ``[B, H]``. Quantiles are on the fixed grid.
    """

    def __init__(
        self,
        name: str,
        cfg: AgentConfig,
        spec: AgentSpec,
        subsets: Any,
        objectives: tuple[str, ...] = OBJECTIVES,
    ) -> None:
        self.name = name
        self.objectives = tuple(objectives)
        """The run's objective names (reward-vector and per-objective head order)."""
        self.cfg = cfg
        self.spec = spec
        self.subsets = subsets
        weights = cfg.reward_weights or scheme_weights(cfg.reward_scheme, objectives=objectives)
        self.reward_weights_O = torch.tensor(weights, dtype=torch.float32)
        """``[O]`` weighted-sum weights, one per objective (the reward rule and acting use them)."""

    @property
    def num_heads(self) -> int:
        return self.spec.num_heads

    def head_rewards(self, rewards_BO: torch.Tensor) -> torch.Tensor:
        """Reward per head ``[B, H]`` from the reward vectors ``rewards_BO`` (the reward rule)."""
        w = self.reward_weights_O.to(rewards_BO.device, rewards_BO.dtype)
        return self.spec.reward(rewards_BO, w, self.num_heads)

    def head_discounts(self, discount_BO: torch.Tensor) -> torch.Tensor:
        """Bootstrap discount per head ``[B, H]``: γ_h^m for per-objective heads; a
        head mixing objectives has one γ (config validation keeps the objectives' equal)."""
        if self.spec.per_objective_heads:
            return discount_BO
        return discount_BO[:, :1].expand(-1, self.num_heads)

    def act(self, quantiles_BHKA: torch.Tensor, u_B: torch.Tensor) -> torch.Tensor:
        w = self.reward_weights_O.to(quantiles_BHKA.device, quantiles_BHKA.dtype)
        return self.spec.act(quantiles_BHKA, self.subsets, u_B, w)

    def state_dict(self) -> dict[str, Any]:
        """Learned state outside the network (the running scale of the scaled normalisation)."""
        return {} if self.subsets is None else self.subsets.state_dict()

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if self.subsets is not None:
            self.subsets.load_state_dict(state)

    def target_actions(self, next_quantiles_BHKA: torch.Tensor) -> torch.Tensor:
        """The action each head bootstraps from, ``[B, H]`` (the target rule)."""
        return self.spec.target(next_quantiles_BHKA, self.subsets)

    def target_actions_and_subsets(
        self, next_quantiles_BHKA: torch.Tensor
    ) -> tuple[torch.Tensor, Any]:
        """``(actions_BH, the optimal subsets the target rule used, or None)``."""
        return rules.target_with_subsets(self.spec.target, next_quantiles_BHKA, self.subsets)

    @property
    def labels(self) -> dict[str, Any]:
        """Table II columns and label of this agent (:class:`priqn.agents.labels.PolicyLabel`)."""
        from priqn.agents.labels import PolicyLabel

        return PolicyLabel.of_config(self.cfg, self.partial_order).to_row()

    @property
    def partial_order(self) -> bool | None:
        """True unless the preorder is a chain over all objectives; None without a preorder."""
        return None if self.subsets is None else not self.subsets.preorder.is_chain()


def _resolve(
    name: str, cfg: AgentConfig | None, overrides: dict[str, Any], objectives: tuple[str, ...]
) -> tuple[AgentConfig, AgentSpec, Any]:
    """The agent's config, spec and preorder (None without one), checked: unknown names,
    comparators and preorders raise a one-line :class:`PriqnError`."""
    cfg = dataclasses.replace(cfg or AgentConfig(), name=name, **overrides)
    try:
        cfg.check_lengths(tuple(objectives))
    except ValueError as exc:
        raise PriqnError(f"agent.{exc}") from None
    spec = resolve_spec(cfg, len(objectives))
    preorder = None
    if spec.uses_preorder:
        if cfg.comparator not in COMPARATOR_NAMES:  # checked here: a one-line error before training
            raise PriqnError(
                f"agent.comparator: unknown comparator {cfg.comparator!r} (valid: {', '.join(COMPARATOR_NAMES)})"
            )
        preorder = load_preorder(cfg.preorder, tuple(objectives))
    return cfg, spec, preorder


def check_agent(
    name: str, cfg: AgentConfig | None = None, objectives: tuple[str, ...] = OBJECTIVES
) -> None:
    """Raise the one-line :class:`PriqnError` :func:`make_agent` would, without building it."""
    _resolve(name, cfg, {}, objectives)


def make_agent(
    name: str,
    cfg: AgentConfig | None = None,
    objectives: tuple[str, ...] = OBJECTIVES,
    **overrides: Any,
) -> Agent:
    """Build agent ``name`` (shipped, ``package.module:NAME`` or an entry point of group
    ``priqn.agents``: :func:`priqn.agents.config.resolve_agent`) for a run with the given
    objective names (per-objective heads, preorder, weights follow them).

    Unknown names, comparators and preorders raise a one-line :class:`PriqnError`.
    """
    cfg, spec, preorder = _resolve(name, cfg, overrides, objectives)
    subsets = None if preorder is None else PreorderSubsets(preorder, cfg)
    return Agent(name, cfg, spec, subsets, tuple(objectives))
