"""The four agents priqn ships, declared as your own agent would be (docs/your-own-agent.md).

Each is a function ``(agent_cfg, num_objectives) -> AgentSpec`` holding its rules
themselves (:mod:`priqn.agents.rules`: go to their definitions from here).
:data:`priqn.agents.config.SHIPPED_AGENTS` names them by path, the way an entry point of
group ``priqn.agents`` names a plug-in. Importing this module does not import torch.

| agent | heads | reward rule | acting rule | target rule |
|---|---|---|---|---|
| ``iqn`` | 1 | weighted-sum | argmax | own-argmax |
| ``ensemble-iqn`` | ``ensemble_heads`` (5) | weighted-sum | argmax-mean-of-heads | own-argmax |
| ``ma-iqn`` | O (one per objective) | per-objective | argmax-sum-of-heads | own-argmax |
| ``pr-iqn`` | O (one per objective) | per-objective | leaf-uniform | optimal-subset (``train_preorder``) or own-argmax |
"""

from __future__ import annotations

from priqn.agents import rules
from priqn.agents.config import AgentConfig, AgentSpec


def iqn(cfg: AgentConfig, num_objectives: int) -> AgentSpec:
    """IQN (Dabney et al. 2018): one head learns the weighted-sum reward; greedy on its mean."""
    return AgentSpec(
        "IQN",
        1,
        reward=rules.reward_weighted_sum,
        act=rules.act_argmax,
        target=rules.target_own_argmax,
        scalar_value=rules.value_of_head,
    )


def ensemble_iqn(cfg: AgentConfig, num_objectives: int) -> AgentSpec:
    """Ensemble-IQN: ``ensemble_heads`` heads learn the weighted-sum reward, each with its
    own τ samples; greedy on the heads' mean."""
    return AgentSpec(
        "Ensemble",
        cfg.ensemble_heads,
        reward=rules.reward_weighted_sum,
        act=rules.act_argmax_mean_of_heads,
        target=rules.target_own_argmax,
        scalar_value=rules.value_mean_of_heads,
        own_taus=True,
    )


def ma_iqn(cfg: AgentConfig, num_objectives: int) -> AgentSpec:
    """MA-IQN: one head per objective; greedy on the weighted sum of the heads' means."""
    return AgentSpec(
        "MA-IQN",
        num_objectives,
        reward=rules.reward_per_objective,
        act=rules.act_argmax_sum_of_heads,
        target=rules.target_own_argmax,
        per_objective_heads=True,
        scalar_value=rules.value_sum_of_heads,
    )


def pr_iqn(cfg: AgentConfig, num_objectives: int) -> AgentSpec:
    """Pr-IQN (the paper): one head per objective; acts uniformly in the leaf optimal subset
    of the preorder; each head bootstraps from its own optimal subset (Eq. 6) unless
    ``train_preorder`` is off."""
    return AgentSpec(
        "Pr-IQN",
        num_objectives,
        reward=rules.reward_per_objective,
        act=rules.act_leaf_uniform,
        target=rules.target_optimal_subset if cfg.train_preorder else rules.target_own_argmax,
        per_objective_heads=True,
        uses_preorder=True,
    )
