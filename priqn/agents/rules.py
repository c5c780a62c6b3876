"""The rules that make the four shipped agents out of one IQN learner (docs/implementation-details.md §1).

Every agent is the same network with ``H`` heads. Agents differ only in

- a **reward rule**: what each head learns (the weighted-sum scalar for every head, or
  one objective per head);
- an **acting rule**: quantiles of the current state → one action per state;
- a **target rule**: quantiles of the next state → the bootstrap action of each head.

The signatures are the protocols of :mod:`priqn.agents.config` (:class:`RewardRule`,
:class:`ActingRule`, :class:`TargetRule`, :class:`ScalarValue`); an
:class:`~priqn.agents.config.AgentSpec` holds the functions themselves
(:mod:`priqn.agents.shipped` declares the four agents with these). Each carries a
``rule_name`` (:func:`named`) and sits in a name registry (:data:`REWARD_RULES`,
:data:`ACTING_RULES`, :data:`TARGET_RULES`) for docs and logs. :data:`SCALAR_VALUES` and
:func:`near_greedy_subsets` make the evaluation-only acting-randomness control of the
greedy agents (docs/evaluation.md).

All quantiles given to the acting and target rules are on the FIXED grid
τ_k = (k + 0.5)/K (``network.tau_grid``), so selection is deterministic for a network.
The preorder rules get an ``OptimalSubsets``-like object ``subsets(quantiles_BHKA)``
with ``per_objective [B, H, A]`` and ``leaf [B, A]`` bool tensors (``priqn.agents.subsets``).
Shape suffix ``O``: the run's objectives (the reward vector).

Importing this module does not import torch (the shipped declarations are read by the
torch-free labels and tables); the two functions that call ``torch.einsum`` import it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from priqn.errors import PriqnError, did_you_mean
from priqn.plugins import import_path

if TYPE_CHECKING:
    from torch import Tensor

F = TypeVar("F", bound=Callable[..., Any])


class SubsetFn(Protocol):
    """quantiles ``[B, N, K, A]`` → object with ``per_objective [B,N,A]``, ``leaf [B,A]``."""

    def __call__(self, quantiles_BNKA: Tensor) -> Any: ...


def named(name: str) -> Callable[[F], F]:
    """Give a rule its name (``AgentSpec.acting_rule`` and friends read it)."""

    def mark(fn: F) -> F:
        fn.rule_name = name  # type: ignore[attr-defined]
        return fn

    return mark


# ----------------------------------------------------------------------------- rewards


@named("weighted-sum")
def reward_weighted_sum(rewards_BO: Tensor, weights_O: Tensor, num_heads: int) -> Tensor:
    """Every head learns the same scalar Σ_i w_i r_i: ``[B, O]`` → ``[B, H]``."""
    return (rewards_BO @ weights_O).unsqueeze(1).expand(-1, num_heads)


@named("per-objective")
def reward_per_objective(rewards_BO: Tensor, weights_O: Tensor, num_heads: int) -> Tensor:
    """Head h learns objective h (weights unused): ``[B, O]`` → ``[B, O]``."""
    if num_heads != rewards_BO.shape[1]:
        raise ValueError(f"per-objective reward needs one head per objective, got {num_heads}")
    return rewards_BO


REWARD_RULES: dict[str, Callable[..., Tensor]] = {
    "weighted-sum": reward_weighted_sum,
    "per-objective": reward_per_objective,
}
"""Reward rule name → ``fn(rewards_BO, weights_O, num_heads) -> rewards_BH``."""


# ----------------------------------------------------------------------------- acting


def masked_uniform_choice(mask_BA: Tensor, u_B: Tensor) -> Tensor:
    """Pick uniformly among the True entries of each row, driven by ``u_B`` ∈ [0, 1).

    The j-th True entry (j = ⌊u · count⌋) is taken, so a given ``u`` always gives the
    same action: randomness comes only from the caller's generator. Rows must not be
    empty (``priqn.agents.subsets`` guarantees a non-empty leaf set).
    """
    count_B = mask_BA.sum(dim=1)
    if bool((count_B == 0).any()):
        raise ValueError("masked_uniform_choice: a row of the mask is empty")
    j_B = (u_B * count_B).long().clamp(max=count_B - 1)
    rank_BA = mask_BA.long().cumsum(dim=1) - 1  # rank of each True entry in its row
    hit_BA = mask_BA & (rank_BA == j_B.unsqueeze(1))
    return hit_BA.long().argmax(dim=1)


@named("argmax")
def act_argmax(
    quantiles_BHKA: Tensor, subsets: SubsetFn | None, u_B: Tensor, weights_O: Tensor
) -> Tensor:
    """IQN: argmax over actions of the (single) head's mean."""
    return quantiles_BHKA.mean(dim=2)[:, 0].argmax(dim=1)


@named("argmax-mean-of-heads")
def act_argmax_mean_of_heads(
    quantiles_BHKA: Tensor, subsets: SubsetFn | None, u_B: Tensor, weights_O: Tensor
) -> Tensor:
    """Ensemble-IQN: argmax of the heads' mean (each head's mean over K, then over H)."""
    return quantiles_BHKA.mean(dim=2).mean(dim=1).argmax(dim=1)


@named("argmax-sum-of-heads")
def act_argmax_sum_of_heads(
    quantiles_BHKA: Tensor, subsets: SubsetFn | None, u_B: Tensor, weights_O: Tensor
) -> Tensor:
    """MA-IQN: argmax of the weighted sum Σ_i w_i · mean(Z_i) of the per-objective heads.

    The same weights as the IQN scheme: a head's mean is the expected return of one
    objective, so this is the value of the scalar reward IQN learns (linearity), and
    MA-IQN gets the same crash bound (docs/implementation-details.md).
    """
    import torch

    means_BHA = quantiles_BHKA.mean(dim=2)
    return torch.einsum("bha,h->ba", means_BHA, weights_O).argmax(dim=1)


@named("leaf-uniform")
def act_leaf_uniform(
    quantiles_BHKA: Tensor, subsets: SubsetFn | None, u_B: Tensor, weights_O: Tensor
) -> Tensor:
    """Pr-IQN: uniform sample from the leaf optimal subset (the virtual leaf if several)."""
    if subsets is None:
        raise ValueError("the leaf-uniform acting rule needs optimal subsets")
    return masked_uniform_choice(subsets(quantiles_BHKA).leaf, u_B)


ACTING_RULES: dict[str, Callable[..., Tensor]] = {
    "argmax": act_argmax,
    "argmax-mean-of-heads": act_argmax_mean_of_heads,
    "argmax-sum-of-heads": act_argmax_sum_of_heads,
    "leaf-uniform": act_leaf_uniform,
}
"""Acting rule name → ``fn(quantiles_BHKA, subsets | None, u_B, weights_O) -> actions_B`` (int64)."""


def _recording(subsets: SubsetFn, made: list[Any]) -> SubsetFn:
    """``subsets`` that also appends each result to ``made``."""

    def recorded(q_BNKA: Tensor) -> Any:
        out = subsets(q_BNKA)
        made.append(out)
        return out

    return recorded


def act_with_subsets(
    act: Callable[..., Tensor],
    quantiles_BHKA: Tensor,
    subsets: SubsetFn | None,
    u_B: Tensor,
    weights_O: Tensor,
) -> tuple[Tensor, Any]:
    """``(actions_B, the optimal subsets the rule acted on)``: acting rule ``act`` applied
    once; the subsets are what its call of ``subsets`` returned (None when it made none,
    e.g. an argmax rule)."""
    if subsets is None:
        return act(quantiles_BHKA, None, u_B, weights_O), None
    made: list[Any] = []
    actions_B = act(quantiles_BHKA, _recording(subsets, made), u_B, weights_O)
    return actions_B, (made[-1] if made else None)


# ----------------------------------------------------------------------------- near-greedy control


def value_of_head(quantiles_BHKA: Tensor, weights_O: Tensor) -> Tensor:
    """IQN ranks actions by its one head: ``[B, H, K, A]`` → ``[B, K, A]``."""
    return quantiles_BHKA[:, 0]


def value_mean_of_heads(quantiles_BHKA: Tensor, weights_O: Tensor) -> Tensor:
    """Ensemble-IQN ranks actions by the heads' mean: ``[B, H, K, A]`` → ``[B, K, A]``."""
    return quantiles_BHKA.mean(dim=1)


def value_sum_of_heads(quantiles_BHKA: Tensor, weights_O: Tensor) -> Tensor:
    """MA-IQN ranks actions by Σ_i w_i Z_i: ``[B, H, K, A]`` → ``[B, K, A]``."""
    import torch

    return torch.einsum("bhka,h->bka", quantiles_BHKA, weights_O)


SCALAR_VALUES: dict[str, Callable[..., Tensor]] = {
    "argmax": value_of_head,
    "argmax-mean-of-heads": value_mean_of_heads,
    "argmax-sum-of-heads": value_sum_of_heads,
}
"""Greedy acting rule name → ``fn(quantiles_BHKA, weights_O) -> values_BKA``: the scalar
return distribution the rule ranks actions by (the argmax of its mean over K is the
rule's action, up to float rounding; ``AgentSpec.scalar_value`` of the shipped agents).
Agents acting on optimal subsets have none."""


def near_greedy_subsets(values_BKA: Tensor, eps: float) -> Any:
    """The near-greedy set of the acting-randomness control (``.leaf``: bool ``[B, A]``).

    Pr-IQN's own rule for ONE objective: the optimal subset of a one-node preorder
    under the QD comparator, i.e. every action whose mean return is within ε per-state
    standard deviations (population std over all K·A quantiles, as the comparators'
    z-score) of the best mean. It always holds the greedy action; ε = 0 is greedy up
    to exact ties. A baseline acting uniformly in this set is stochastic like Pr-IQN
    while it still ranks actions by its own value; how stochastic depends on ε
    (docs/evaluation.md).
    """
    from priqn.agents.subsets import optimal_subsets

    return optimal_subsets(values_BKA.unsqueeze(1), _value_preorder(), comparator="qd", eps=eps)


@functools.cache
def _value_preorder() -> Any:
    """The one-objective preorder of the near-greedy set (built once: it caches its plan)."""
    from priqn.agents.preorder import Preorder

    return Preorder(["value"], source="near-greedy value")


# ----------------------------------------------------------------------------- targets


def masked_argmax(values_BHA: Tensor, mask_BHA: Tensor) -> Tensor:
    """argmax over the actions where ``mask`` is True (ties → lowest index): ``[B, H]``."""
    return values_BHA.masked_fill(~mask_BHA, float("-inf")).argmax(dim=2)


@named("own-argmax")
def target_own_argmax(next_quantiles_BHKA: Tensor, subsets: SubsetFn | None) -> Tensor:
    """Each head bootstraps from its own argmax over all actions (Eq. 6 without S)."""
    return next_quantiles_BHKA.mean(dim=2).argmax(dim=2)


@named("optimal-subset")
def target_optimal_subset(next_quantiles_BHKA: Tensor, subsets: SubsetFn | None) -> Tensor:
    """Pr-IQN Eq. 6: head h bootstraps from argmax over S_h(s') of its mean quantile."""
    if subsets is None:
        raise ValueError("the optimal-subset target rule needs optimal subsets")
    mask_BHA = subsets(next_quantiles_BHKA).per_objective
    return masked_argmax(next_quantiles_BHKA.mean(dim=2), mask_BHA)


TARGET_RULES: dict[str, Callable[..., Tensor]] = {
    "own-argmax": target_own_argmax,
    "optimal-subset": target_optimal_subset,
}
"""Target rule name → ``fn(next_quantiles_BHKA, subsets | None) -> actions_BH`` (int64)."""


def target_with_subsets(
    target: Callable[..., Tensor], next_quantiles_BHKA: Tensor, subsets: SubsetFn | None
) -> tuple[Tensor, Any]:
    """``(actions_BH, the optimal subsets the rule bootstrapped from)``: target rule
    ``target`` applied once; the subsets are what its call of ``subsets`` returned (None
    when it made none, e.g. own-argmax)."""
    if subsets is None:
        return target(next_quantiles_BHKA, None), None
    made: list[Any] = []
    actions_BH = target(next_quantiles_BHKA, _recording(subsets, made))
    return actions_BH, (made[-1] if made else None)


def lookup(registry: dict[str, Any], name: str, what: str) -> Any:
    """``registry[name]``; a plug-in's rule by its name ``module:qualified name``
    (:func:`priqn.agents.config.rule_name`); else a one-line error listing the valid names."""
    if name in registry:
        return registry[name]
    if ":" in name:
        return import_path(name, what)
    raise PriqnError(
        f"unknown {what} {name!r} (valid: {', '.join(sorted(registry))})"
        + did_you_mean(name, registry)
    )
