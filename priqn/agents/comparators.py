"""Distribution comparators: how the quantiles of one objective score and relate actions.

The τ grid (:func:`quantile_grid`), the normalisation every comparator scores
(:func:`normalised`: the paper's per-state z-score, or scale-aware with a per-objective
floor from :class:`RunningScale`), the score comparators QD, MV and CVaR
(:data:`COMPARATOR_FUNCTIONS`) and the pairwise ε-first-order stochastic dominance
(:func:`fsd_relations`). Algorithm 1 (:mod:`priqn.agents.subsets`) turns their scores
and relations into optimal subsets; ``docs/preorder.md`` explains the method.

Shapes (glossary): ``B`` states, ``N`` objectives, ``K`` quantiles on the fixed grid
``τ_k = (k + 0.5) / K``, ``A`` actions.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import torch

from priqn.agents.config import COMPARATOR_NAMES
from priqn.errors import PriqnError


def quantile_grid(
    num_quantiles: int, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """The fixed selection grid ``τ_k = (k + 0.5) / K``, shape ``[K]``."""
    return (torch.arange(num_quantiles, device=device, dtype=dtype) + 0.5) / num_quantiles


MIN_STD: float = 1e-6
"""Floor of the per-(state, objective) standard deviation used for z-scoring."""


def zscore(quantiles_BNKA: torch.Tensor, min_std: float = MIN_STD) -> torch.Tensor:
    """Per state and objective: ``Z̃ = (Z − mean) / max(std, min_std)`` over all K·A entries.

    Population std. Every comparator scores these normalised quantiles (Z̃ in the
    paper), so ε means the same on every objective. (The comparators below use the
    equivalent affine forms and never build Z̃; this is the literal definition.)
    """
    std, mean = torch.std_mean(quantiles_BNKA, dim=(-2, -1), correction=0, keepdim=True)
    return (quantiles_BNKA - mean) / std.clamp(min=min_std)


@dataclasses.dataclass(frozen=True)
class ComparatorOptions:
    """Options of the comparators; each comparator reads only its own."""

    mv_lambda: float = 0.5
    """MV: weight λ of the standard-deviation penalty (on z-scored quantiles)."""
    cvar_alpha: float = 0.25
    """CVaR: tail level α in (0, 1]; grid quantiles with τ_k ≤ α are averaged."""

    def __post_init__(self) -> None:
        if not math.isfinite(self.mv_lambda):
            raise PriqnError(f"mv_lambda: expected a finite number, got {self.mv_lambda!r}")
        if not 0.0 < self.cvar_alpha <= 1.0:
            raise PriqnError(f"cvar_alpha: expected a number in (0, 1], got {self.cvar_alpha!r}")


# Every score is affine in Z̃ = (Z − m) / s. The comparators get the centred quantiles
# Z − m TRANSPOSED to [B, N, A, K] (K contiguous, so reductions over the actions and
# over the quantiles both run on the fast path) and the clamped std s [B, N, 1], and
# never materialise Z̃: these passes over the largest tensor dominate the cost.


def _score_qd(
    c_BNAK: torch.Tensor, s_BN1: torch.Tensor, options: ComparatorOptions
) -> torch.Tensor:
    """QD (Eq. 3-5): score(a) = −mean_k |Z̃[k, a] − max_b Z̃[k, b]|.

    The ideal is ≥ every entry, so this is (mean_k C[k, a] − mean_k max_b C[k, b]) / s.
    """
    ideal_BN1 = c_BNAK.amax(dim=-2).mean(dim=-1, keepdim=True)
    return (c_BNAK.mean(dim=-1) - ideal_BN1) / s_BN1


def _score_mv(
    c_BNAK: torch.Tensor, s_BN1: torch.Tensor, options: ComparatorOptions
) -> torch.Tensor:
    """Mean-variance: score(a) = mean_k Z̃[k, a] − λ · std_k Z̃[k, a] (population std)."""
    mean_BNA = c_BNAK.mean(dim=-1)
    k = c_BNAK.shape[-1]
    std_BNA = torch.linalg.vector_norm(c_BNAK - mean_BNA.unsqueeze(-1), dim=-1) / math.sqrt(k)
    return (mean_BNA - options.mv_lambda * std_BNA) / s_BN1


def _score_cvar(
    c_BNAK: torch.Tensor, s_BN1: torch.Tensor, options: ComparatorOptions
) -> torch.Tensor:
    """CVaR_α: score(a) = mean of Z̃[k, a] over the grid quantiles with τ_k ≤ α."""
    count = cvar_count(c_BNAK.shape[-1], options.cvar_alpha)
    return c_BNAK[..., :count].mean(dim=-1) / s_BN1


def cvar_count(num_quantiles: int, alpha: float) -> int:
    """How many grid quantiles ``τ_k = (k + 0.5)/K`` satisfy ``τ_k ≤ α`` (error if none)."""
    count = sum(1 for k in range(num_quantiles) if (k + 0.5) / num_quantiles <= alpha)
    if count == 0:
        raise PriqnError(
            f"cvar_alpha={alpha} selects no quantile of the K={num_quantiles} grid "
            f"(smallest τ is {0.5 / num_quantiles:g}); raise cvar_alpha or K"
        )
    return count


ComparatorFn = Callable[[torch.Tensor, torch.Tensor, ComparatorOptions], torch.Tensor]


def _score_mean(
    c_BNAK: torch.Tensor, s_BN1: torch.Tensor, options: ComparatorOptions
) -> torch.Tensor:
    """FSD's score (for display and ties only): mean_k Z̃[k, a]. Its relations are pairwise."""
    return c_BNAK.mean(dim=-1) / s_BN1


COMPARATOR_FUNCTIONS: dict[str, ComparatorFn] = {
    "qd": _score_qd,
    "mv": _score_mv,
    "cvar": _score_cvar,
    "fsd": _score_mean,
}
"""Comparator name → ``fn(Z − mean as [B, N, A, K], std [B, N, 1], options) -> [B, N, A]``.

Scores are of the z-scored quantiles Z̃ = (Z − mean) / std; higher is better. Score
comparators relate a and b by ``score(a) − score(b) > ε``; the comparators in
:data:`PAIRWISE` relate them by their own rule instead (their score is only shown).
"""

if tuple(COMPARATOR_FUNCTIONS) != tuple(COMPARATOR_NAMES):  # one function per name, same order
    raise ImportError(
        f"priqn.agents.comparators.COMPARATOR_FUNCTIONS {tuple(COMPARATOR_FUNCTIONS)} "
        f"!= priqn.agents.config.COMPARATOR_NAMES {tuple(COMPARATOR_NAMES)}"
    )

PAIRWISE: frozenset[str] = frozenset({"fsd"})
"""Comparators whose relation is not an ε-difference of scores (see :func:`fsd_relations`)."""


def comparator_function(name: str) -> ComparatorFn:
    """The score function of comparator ``name`` (error naming the valid ones)."""
    try:
        return COMPARATOR_FUNCTIONS[name]
    except (KeyError, TypeError):
        raise PriqnError(
            f"unknown comparator {name!r} (valid: {', '.join(COMPARATOR_FUNCTIONS)})"
        ) from None


def _spread_floor_N1(
    spread_floor: torch.Tensor | Sequence[float] | None, n: int, like: torch.Tensor
) -> torch.Tensor | None:
    """The per-objective spread floor as ``[N, 1]`` on ``like``'s device (None = none)."""
    if spread_floor is None:
        return None
    floor_N = torch.as_tensor(spread_floor, dtype=like.dtype, device=like.device).reshape(-1)
    if floor_N.numel() != n:
        raise PriqnError(
            f"spread_floor: expected one value per objective ({n}), got {floor_N.numel()}"
        )
    on_accelerator = isinstance(spread_floor, torch.Tensor) and spread_floor.device.type != "cpu"
    # A floor already on an accelerator (RunningScale's, finite and >= 0 by construction)
    # is not checked here: reading it back would be a host sync on every call.
    if not on_accelerator and (
        not bool(torch.isfinite(floor_N).all()) or bool((floor_N < 0).any())
    ):
        raise PriqnError("spread_floor: expected finite values >= 0")
    return floor_N.view(n, 1)


def normalised(
    quantiles_BNKA: torch.Tensor,
    spread_floor: torch.Tensor | Sequence[float] | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Centred quantiles ``Z − mean`` as ``[..., N, A, K]`` and the spread ``s`` ``[..., N, 1]``.

    ``Z̃ = (Z − mean) / s``. Paper-literal (``spread_floor=None``): ``s = max(std, 1e-6)``
    per state and objective (population std over all K·A entries). Scale-aware: ``s =
    max(std, 1e-6, spread_floor[i])`` with a per-objective floor (e.g. from
    :class:`RunningScale`), so differences that are tiny against the objective's typical
    spread stay inside ε instead of being blown up by a tiny per-state std.
    Inputs below float32 precision (float16, bfloat16) are normalised in float32.
    """
    q = quantiles_BNKA
    if q.dtype not in (torch.float32, torch.float64):
        q = q.float()
    if q.ndim < 2 or q.shape[-2] < 1 or q.shape[-1] < 1:
        raise PriqnError(f"quantiles: need [..., K, A] with K, A >= 1, got {list(q.shape)}")
    b_shape, (k, a) = q.shape[:-2], q.shape[-2:]
    m_BN11 = q.flatten(-2).mean(dim=-1).view(*b_shape, 1, 1)
    c_BNAK = torch.empty((*b_shape, a, k), dtype=q.dtype, device=q.device)
    torch.sub(q.transpose(-1, -2), m_BN11, out=c_BNAK)
    # Two-pass population std: the norm of the centred values.
    s_BN1 = torch.linalg.vector_norm(c_BNAK.flatten(-2), dim=-1, keepdim=True)
    s_BN1 = (s_BN1 / math.sqrt(k * a)).clamp(min=MIN_STD)
    floor_N1 = _spread_floor_N1(spread_floor, q.shape[-3] if q.ndim >= 3 else 1, q)
    if floor_N1 is not None:
        s_BN1 = torch.maximum(s_BN1, floor_N1)
    return c_BNAK, s_BN1


def comparator_scores(
    quantiles_BNKA: torch.Tensor,
    comparator: str = "qd",
    *,
    mv_lambda: float = 0.5,
    cvar_alpha: float = 0.25,
    spread_floor: torch.Tensor | Sequence[float] | None = None,
) -> torch.Tensor:
    """Scores ``[..., N, A]`` (higher is better) of every action for every objective.

    ``quantiles_BNKA`` is ``[..., N, K, A]``; ``spread_floor`` selects the scale-aware
    normalisation (see :func:`normalised`).
    """
    fn = comparator_function(comparator)
    options = ComparatorOptions(mv_lambda=float(mv_lambda), cvar_alpha=float(cvar_alpha))
    c_BNAK, s_BN1 = normalised(quantiles_BNKA, spread_floor)
    return fn(c_BNAK, s_BN1, options)


def fsd_relations(
    c_BAK: torch.Tensor, s_B1: torch.Tensor, eps: torch.Tensor | float
) -> tuple[torch.Tensor, torch.Tensor]:
    """ε-first-order stochastic dominance between every pair of actions of one objective.

    ``c_BAK`` are centred quantiles on the fixed grid, ``s_B1`` the spread (see
    :func:`normalised`), so ``Z̃ = c / s``. With ``d_k = Z̃[k, a] − Z̃[k, b]``:

        dom[a, b]  ⇔  min_k d_k ≥ −ε   and   mean_k d_k > ε

    "no quantile of a is worse than b's by more than ε, and a is better by more than ε
    on average". ``domby`` is ``domᵀ``. ``dom[a, b]`` implies mean Z̃(a) > mean Z̃(b) + ε,
    so the relation is a sub-relation of the strict ε-order of the means (acyclic, and
    never both ways). Pairs whose quantile functions cross by more than ε are left
    incomparable — the distributional information QD throws away (docs/preorder.md).
    """
    z_BAK = c_BAK / s_B1.unsqueeze(-1)
    d_BAAK = z_BAK.unsqueeze(2) - z_BAK.unsqueeze(1)  # [B, a, b, K]
    mean_BAA = d_BAAK.mean(dim=-1)
    worst_BAA = d_BAAK.amin(dim=-1)
    dom_BAA = (mean_BAA > eps) & (worst_BAA >= -eps)
    return dom_BAA, dom_BAA.transpose(-1, -2)


class RunningScale:
    """Per-objective running scale of the return spread, for the scale-aware normalisation.

    ``update(quantiles_BNKA)`` folds in a batch: the per-state population std over the
    K·A entries, averaged over the batch, enters an exponential moving average with
    weight ``momentum`` (the first batch sets it). ``floor()`` is ``fraction × scale``
    ``[N]``, the spread floor :func:`priqn.agents.subsets.optimal_subsets` takes as
    ``spread_floor``. Until the first update the floor is 0 (= the paper-literal
    normalisation). Deterministic; ``state_dict`` / ``load_state_dict`` let checkpoints
    carry it.
    """

    def __init__(self, num_objectives: int, momentum: float = 0.01, fraction: float = 1.0) -> None:
        if not 0.0 < momentum <= 1.0:
            raise PriqnError(f"scale momentum: expected a number in (0, 1], got {momentum!r}")
        if not fraction >= 0.0:
            raise PriqnError(f"scale fraction: expected a number >= 0, got {fraction!r}")
        self.momentum = float(momentum)
        self.fraction = float(fraction)
        self.scale_N = torch.zeros(int(num_objectives), dtype=torch.float64)
        self.count = 0

    @torch.no_grad()
    def update(self, quantiles_BNKA: torch.Tensor) -> None:
        """Fold in a batch of quantiles ``[..., N, K, A]`` (see the class docstring)."""
        q = quantiles_BNKA.detach().to(torch.float64)
        std_BN = torch.std(q.flatten(-2), dim=-1, correction=0)
        batch_N = std_BN.reshape(-1, std_BN.shape[-1]).mean(dim=0)  # stays on the device
        if batch_N.numel() != self.scale_N.numel():
            raise PriqnError(
                f"running scale: expected {self.scale_N.numel()} objectives, got {batch_N.numel()}"
            )
        if self.count == 0:
            self.scale_N = batch_N
        else:
            scale_N = self.scale_N.to(batch_N.device)  # a no-op but after a load
            self.scale_N = (1.0 - self.momentum) * scale_N + self.momentum * batch_N
        self.count += 1

    def floor(self) -> torch.Tensor:
        """``fraction × running scale`` ``[N]`` (float64, on the device of the quantiles
        it was last updated with: no host sync per update)."""
        return self.fraction * self.scale_N

    def state_dict(self) -> dict[str, Any]:
        """The scale and the number of updates, as plain Python (for a checkpoint)."""
        return {"scale": self.scale_N.tolist(), "count": self.count}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore what :meth:`state_dict` returned."""
        self.scale_N = torch.tensor(state["scale"], dtype=torch.float64)
        self.count = int(state["count"])
