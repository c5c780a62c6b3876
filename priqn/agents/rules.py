"""The three rules that make the four agents out of one IQN learner (docs/implementation-details.md §1).

Every agent is the same network with ``H`` heads. Agents differ only in

- a **reward rule**: what each head learns (the weighted-sum scalar for every head, or
  one objective per head);
- an **acting rule**: quantiles of the current state → one action per state;
- a **target rule**: quantiles of the next state → the bootstrap action of each head.

Each rule is a named function in a registry (:data:`REWARD_RULES`, :data:`ACTING_RULES`,
:data:`TARGET_RULES`); ``priqn.agents.registry`` combines them into agents.
:data:`SCALAR_VALUES` and :func:`near_greedy_subsets` make the evaluation-only
acting-randomness control of the greedy agents (docs/evaluation.md).

All quantiles given to the acting and target rules are on the FIXED grid
τ_k = (k + 0.5)/K (``network.tau_grid``), so selection is deterministic for a network.
The preorder rules get an ``OptimalSubsets``-like object ``subsets(quantiles_BHKA)``
with ``per_objective [B, H, A]`` and ``leaf [B, A]`` bool tensors (``priqn.preorder``).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, Protocol

import torch

from priqn.errors import PriqnError


class SubsetFn(Protocol):
    """quantiles ``[B, N, K, A]`` → object with ``per_objective [B,N,A]``, ``leaf [B,A]``."""

    def __call__(self, quantiles_BNKA: torch.Tensor) -> Any: ...


# ----------------------------------------------------------------------------- rewards


def reward_weighted_sum(
    rewards_B5: torch.Tensor, weights_5: torch.Tensor, num_heads: int
) -> torch.Tensor:
    """Every head learns the same scalar Σ_i w_i r_i: ``[B, 5]`` → ``[B, H]``."""
    return (rewards_B5 @ weights_5).unsqueeze(1).expand(-1, num_heads)


def reward_per_objective(
    rewards_B5: torch.Tensor, weights_5: torch.Tensor, num_heads: int
) -> torch.Tensor:
    """Head h learns objective h (weights unused): ``[B, 5]`` → ``[B, 5]``."""
    if num_heads != rewards_B5.shape[1]:
        raise ValueError(f"per-objective reward needs one head per objective, got {num_heads}")
    return rewards_B5


REWARD_RULES: dict[str, Callable[..., torch.Tensor]] = {
    "weighted-sum": reward_weighted_sum,
    "per-objective": reward_per_objective,
}
"""Reward rule name → ``fn(rewards_B5, weights_5, num_heads) -> rewards_BH``."""


# ----------------------------------------------------------------------------- acting


def masked_uniform_choice(mask_BA: torch.Tensor, u_B: torch.Tensor) -> torch.Tensor:
    """Pick uniformly among the True entries of each row, driven by ``u_B`` ∈ [0, 1).

    The j-th True entry (j = ⌊u · count⌋) is taken, so a given ``u`` always gives the
    same action: randomness comes only from the caller's generator. Rows must not be
    empty (``priqn.preorder`` guarantees a non-empty leaf set).
    """
    count_B = mask_BA.sum(dim=1)
    if bool((count_B == 0).any()):
        raise ValueError("masked_uniform_choice: a row of the mask is empty")
    j_B = torch.clamp((u_B * count_B).long(), max=count_B - 1)
    rank_BA = torch.cumsum(mask_BA.long(), dim=1) - 1  # rank of each True entry in its row
    hit_BA = mask_BA & (rank_BA == j_B.unsqueeze(1))
    return hit_BA.long().argmax(dim=1)


def act_argmax(
    quantiles_BHKA: torch.Tensor,
    subsets: SubsetFn | None,
    u_B: torch.Tensor,
    weights_5: torch.Tensor | None = None,
):
    """IQN: argmax over actions of the (single) head's mean."""
    return quantiles_BHKA.mean(dim=2)[:, 0].argmax(dim=1)


def act_argmax_mean_of_heads(quantiles_BHKA, subsets, u_B, weights_5=None):
    """Ensemble-IQN: argmax of the heads' mean (each head's mean over K, then over H)."""
    return quantiles_BHKA.mean(dim=2).mean(dim=1).argmax(dim=1)


def act_argmax_sum_of_heads(quantiles_BHKA, subsets, u_B, weights_5=None):
    """MA-IQN: argmax of the weighted sum Σ_i w_i · mean(Z_i) of the per-objective heads.

    The same weights as the IQN scheme: a head's mean is the expected return of one
    objective, so this is the value of the scalar reward IQN learns (linearity), and
    MA-IQN gets the same crash bound (docs/implementation-details.md). ``None`` sums
    the heads unweighted (the pre-fairness rule).
    """
    means_BHA = quantiles_BHKA.mean(dim=2)
    if weights_5 is None:
        return means_BHA.sum(dim=1).argmax(dim=1)
    return torch.einsum("bha,h->ba", means_BHA, weights_5).argmax(dim=1)


def act_leaf_uniform(quantiles_BHKA, subsets, u_B, weights_5=None):
    """Pr-IQN: uniform sample from the leaf optimal subset (the virtual leaf if several)."""
    if subsets is None:
        raise ValueError("the leaf-uniform acting rule needs optimal subsets")
    return masked_uniform_choice(subsets(quantiles_BHKA).leaf, u_B)


ACTING_RULES: dict[str, Callable[..., torch.Tensor]] = {
    "argmax": act_argmax,
    "argmax-mean-of-heads": act_argmax_mean_of_heads,
    "argmax-sum-of-heads": act_argmax_sum_of_heads,
    "leaf-uniform": act_leaf_uniform,
}
"""Acting rule name → ``fn(quantiles_BHKA, subsets | None, u_B, weights_5) -> actions_B`` (int64)."""


def act_with_subsets(
    act: Callable[..., torch.Tensor],
    quantiles_BHKA: torch.Tensor,
    subsets: SubsetFn | None,
    u_B: torch.Tensor,
    weights_5: torch.Tensor | None = None,
) -> tuple[torch.Tensor, Any]:
    """``(actions_B, the optimal subsets the rule acted on)``: acting rule ``act`` (an
    :data:`ACTING_RULES` value) applied once; the subsets are what its call of
    ``subsets`` returned (None when it made none, e.g. an argmax rule)."""
    if subsets is None:
        return act(quantiles_BHKA, None, u_B, weights_5), None
    made: list[Any] = []

    def recorded(q_BNKA: torch.Tensor) -> Any:
        out = subsets(q_BNKA)
        made.append(out)
        return out

    actions_B = act(quantiles_BHKA, recorded, u_B, weights_5)
    return actions_B, (made[-1] if made else None)


# ----------------------------------------------------------------------------- near-greedy control


def value_of_head(quantiles_BHKA: torch.Tensor, weights_5: torch.Tensor | None) -> torch.Tensor:
    """IQN ranks actions by its one head: ``[B, H, K, A]`` → ``[B, K, A]``."""
    return quantiles_BHKA[:, 0]


def value_mean_of_heads(quantiles_BHKA, weights_5):
    """Ensemble-IQN ranks actions by the heads' mean: ``[B, H, K, A]`` → ``[B, K, A]``."""
    return quantiles_BHKA.mean(dim=1)


def value_sum_of_heads(quantiles_BHKA, weights_5):
    """MA-IQN ranks actions by Σ_i w_i Z_i (unweighted sum without weights): ``[B, K, A]``."""
    if weights_5 is None:
        return quantiles_BHKA.sum(dim=1)
    return torch.einsum("bhka,h->bka", quantiles_BHKA, weights_5)


SCALAR_VALUES: dict[str, Callable[..., torch.Tensor]] = {
    "argmax": value_of_head,
    "argmax-mean-of-heads": value_mean_of_heads,
    "argmax-sum-of-heads": value_sum_of_heads,
}
"""Greedy acting rule name → ``fn(quantiles_BHKA, weights_5) -> values_BKA``: the scalar
return distribution the rule ranks actions by (the argmax of its mean over K is the
rule's action, up to float rounding). Agents acting on optimal subsets have none."""


def near_greedy_subsets(values_BKA: torch.Tensor, eps: float) -> Any:
    """The near-greedy set of the acting-randomness control (``.leaf``: bool ``[B, A]``).

    Pr-IQN's own rule for ONE objective: the optimal subset of a one-node preorder
    under the QD comparator, i.e. every action whose mean return is within ε per-state
    standard deviations (population std over all K·A quantiles, as the comparators'
    z-score) of the best mean. It always holds the greedy action; ε = 0 is greedy up
    to exact ties. A baseline acting uniformly in this set is stochastic like Pr-IQN
    while it still ranks actions by its own value; how stochastic depends on ε
    (docs/evaluation.md).
    """
    from priqn.preorder import optimal_subsets

    return optimal_subsets(values_BKA.unsqueeze(1), _value_preorder(), comparator="qd", eps=eps)


@functools.cache
def _value_preorder() -> Any:
    """The one-objective preorder of the near-greedy set (built once: it caches its plan)."""
    from priqn.preorder import Preorder

    return Preorder(["value"], source="near-greedy value")


# ----------------------------------------------------------------------------- targets


def masked_argmax(values_BHA: torch.Tensor, mask_BHA: torch.Tensor) -> torch.Tensor:
    """argmax over the actions where ``mask`` is True (ties → lowest index): ``[B, H]``."""
    return values_BHA.masked_fill(~mask_BHA, float("-inf")).argmax(dim=2)


def target_own_argmax(next_quantiles_BHKA: torch.Tensor, subsets: SubsetFn | None):
    """Each head bootstraps from its own argmax over all actions (Eq. 6 without S)."""
    return next_quantiles_BHKA.mean(dim=2).argmax(dim=2)


def target_optimal_subset(next_quantiles_BHKA: torch.Tensor, subsets: SubsetFn | None):
    """Pr-IQN Eq. 6: head h bootstraps from argmax over S_h(s') of its mean quantile."""
    if subsets is None:
        raise ValueError("the optimal-subset target rule needs optimal subsets")
    mask_BHA = subsets(next_quantiles_BHKA).per_objective
    return masked_argmax(next_quantiles_BHKA.mean(dim=2), mask_BHA)


TARGET_RULES: dict[str, Callable[..., torch.Tensor]] = {
    "own-argmax": target_own_argmax,
    "optimal-subset": target_optimal_subset,
}
"""Target rule name → ``fn(next_quantiles_BHKA, subsets | None) -> actions_BH`` (int64)."""


def lookup(registry: dict[str, Any], name: str, what: str) -> Any:
    """``registry[name]`` or a one-line error listing the valid names."""
    try:
        return registry[name]
    except KeyError:
        raise PriqnError(
            f"unknown {what} {name!r} (valid: {', '.join(sorted(registry))})"
        ) from None
