"""A researcher's own agent, declared outside priqn (docs/your-own-agent.md).

``agent.name = "tests.agent_example:SHIELDED_IQN"`` trains it without touching priqn's
source; ``tests/test_your_own_agent.py`` trains, evaluates, reports and inspects it.

**Safety-shielded IQN**: two heads on the one IQN network. Head 0 learns the weighted-sum
reward (as IQN), head 1 the first objective alone (``safety`` in every shipped objective
list). The shield keeps the actions whose safety head's mean is within
:data:`SHIELD_MARGIN` of the best; the agent acts greedily on head 0 among them, and head
0 bootstraps from that same shielded argmax (head 1 from its own argmax).
"""

from __future__ import annotations

import torch

from priqn.agents.config import AgentSpec

SHIELD_MARGIN = 0.5
"""An action is ruled out when its expected safety return is this far below the best [-]."""


def reward_task_and_safety(
    rewards_BO: torch.Tensor, weights_O: torch.Tensor, num_heads: int
) -> torch.Tensor:
    """Head 0: Σ_i w_i r_i; head 1: r_safety (the first objective): ``[B, O]`` → ``[B, 2]``."""
    return torch.stack([rewards_BO @ weights_O, rewards_BO[:, 0]], dim=1)


def shielded_argmax(quantiles_BHKA: torch.Tensor) -> torch.Tensor:
    """argmax of head 0's mean among the actions the safety head allows: ``[B]``."""
    means_BHA = quantiles_BHKA.mean(dim=2)
    safety_BA = means_BHA[:, 1]
    allowed_BA = safety_BA >= safety_BA.max(dim=1, keepdim=True).values - SHIELD_MARGIN
    return means_BHA[:, 0].masked_fill(~allowed_BA, float("-inf")).argmax(dim=1)


def act_shielded(
    quantiles_BHKA: torch.Tensor, subsets: object, u_B: torch.Tensor, weights_O: torch.Tensor
) -> torch.Tensor:
    """Greedy on the task head inside the safety shield (deterministic: ``u_B`` unused)."""
    return shielded_argmax(quantiles_BHKA)


def target_shielded(next_quantiles_BHKA: torch.Tensor, subsets: object) -> torch.Tensor:
    """Head 0 bootstraps from the shielded argmax, head 1 from its own argmax: ``[B, 2]``."""
    own_safety_B = next_quantiles_BHKA.mean(dim=2)[:, 1].argmax(dim=1)
    return torch.stack([shielded_argmax(next_quantiles_BHKA), own_safety_B], dim=1)


SHIELDED_IQN = AgentSpec(
    display_name="Shielded-IQN",
    num_heads=2,
    reward=reward_task_and_safety,
    act=act_shielded,
    target=target_shielded,
)
"""The declaration ``agent.name`` names (an AgentSpec; a function ``(agent_cfg,
num_objectives) -> AgentSpec`` works too, when heads or rules follow the config)."""
