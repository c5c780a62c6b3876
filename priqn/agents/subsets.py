"""Algorithm 1: the optimal subsets of every objective of a preorder, for a batch of states.

This is the decision core of Pr-IQN: every acting step and every TD target calls
:func:`optimal_subsets`. It implements our reading of Algorithm 1; ``docs/preorder.md``
explains the method and records the benchmark. The preorder is
:class:`priqn.agents.preorder.Preorder`, the scores and relations come from
:mod:`priqn.agents.comparators`, and :mod:`priqn.bench.references.subsets` is the slow,
literal version the tests and ``priqn bench preorder`` check this one against.

Shapes (glossary): ``B`` states, ``N`` objectives (in ``Preorder.objectives`` order),
``K`` quantiles on the fixed grid ``τ_k = (k + 0.5) / K``, ``A`` actions.

>>> po = Preorder.preset("partial")
>>> out = optimal_subsets(quantiles_BNKA, po, comparator="qd", eps=0.2)
>>> out.per_objective  # bool [B, N, A]: optimal subset S_r of every objective
>>> out.leaf           # bool [B, A]: the leaf's subset (virtual global leaf if several)

Relations are ``[B, A, A]`` boolean matrices indexed ``[a, b]``: ``dom[a, b]`` means
"a dominates b", ``domby[a, b]`` "a is dominated by b". ``domby`` is always ``domᵀ``;
both are kept so that every elementwise step reads contiguous memory.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import torch

from priqn.agents.comparators import (
    PAIRWISE,
    ComparatorOptions,
    comparator_function,
    fsd_relations,
    normalised,
)
from priqn.agents.preorder import Preorder
from priqn.errors import PriqnError

SELECT_RULES: tuple[str, ...] = ("top-scc", "plain")
"""``top-scc``: docs/preorder.md (never empty); ``plain``: Alg. 1 line 23 literally."""


@dataclasses.dataclass(frozen=True)
class OptimalSubsets:
    """Output of :func:`optimal_subsets` (leading ``B`` absent for a single state)."""

    per_objective: torch.Tensor
    """bool ``[B, N, A]``: optimal subset S_r of every objective, N in preorder order."""
    leaf: torch.Tensor
    """bool ``[B, A]``: the leaf's subset; Agg over the leaves when there are several."""
    scores: torch.Tensor
    """float ``[B, N, A]``: comparator scores (higher is better) the relations come from."""
    objectives: tuple[str, ...]
    """Names of the N axis."""

    def subset(self, objective: str) -> torch.Tensor:
        """bool ``[B, A]``: the optimal subset of one objective."""
        if objective not in self.objectives:
            raise PriqnError(
                f"unknown objective {objective!r} (valid: {', '.join(self.objectives)})"
            )
        return self.per_objective[..., self.objectives.index(objective), :]

    def sizes(self) -> dict[str, float]:
        """Mean optimal-subset size |S_r| over the batch per objective, and of the leaf."""
        return {k: float(v) for k, v in self.size_tensors().items()}

    def size_tensors(self) -> dict[str, torch.Tensor]:
        """:meth:`sizes` as 0-d tensors on the subsets' device: no host sync until read."""
        per_N = self.per_objective.float().sum(dim=-1).reshape(-1, len(self.objectives))
        out = dict(zip(self.objectives, per_N.mean(dim=0).unbind(), strict=True))
        out["leaf"] = self.leaf.float().sum(dim=-1).mean()
        return out


def _eps_tensor(
    eps: float | Sequence[float] | Mapping[str, float], po: Preorder, device: torch.device
) -> torch.Tensor:
    names = po.objectives
    if isinstance(eps, Mapping):
        unknown = [k for k in eps if k not in names]
        missing = [n for n in names if n not in eps]
        if unknown or missing:
            raise PriqnError(
                f"eps: the table must give one value per objective ({', '.join(names)}); "
                f"unknown: {', '.join(map(str, unknown)) or '-'}; missing: {', '.join(missing) or '-'}"
            )
        values = [eps[n] for n in names]
    elif isinstance(eps, (int, float)) and not isinstance(eps, bool):
        values = [eps] * len(names)
    elif isinstance(eps, torch.Tensor) and eps.ndim == 0:
        values = [float(eps)] * len(names)
    elif isinstance(eps, (Sequence, torch.Tensor)) and not isinstance(eps, str):
        values = [v.item() if isinstance(v, torch.Tensor) else v for v in eps]
        if len(values) != len(names):
            raise PriqnError(
                f"eps: expected one value per objective ({len(names)}: {', '.join(names)}), "
                f"got {len(values)}"
            )
    else:
        raise PriqnError(f"eps: expected a number, a list or a table of numbers, got {eps!r}")
    for name, v in zip(names, values, strict=True):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v) or v < 0:
            raise PriqnError(f"eps[{name}]: expected a number >= 0 (inf allowed), got {v!r}")
    return torch.tensor([float(v) for v in values], dtype=torch.float64, device=device)


def _transitive_closure(rel_BAA: torch.Tensor) -> torch.Tensor:
    """Reachability by paths of length >= 1: up to ⌈log2(A−1)⌉ squarings of ``R ∨ R·R``.

    After m squarings R holds every path of up to 2**m edges; a simple path has at most
    A − 1. On CPU the loop stops as soon as R stops changing (exact, and the common
    case is 1-2 squarings); on accelerators it runs all squarings to avoid syncs.
    """
    a = rel_BAA.shape[-1]
    r = rel_BAA.to(torch.float32)
    early_exit = r.device.type == "cpu"
    for _ in range(max(a - 2, 0).bit_length()):
        nxt = (torch.matmul(r, r) + r).clamp_(max=1.0)
        if early_exit and torch.equal(nxt, r):
            break
        r = nxt
    return r > 0.5


def select(
    candidates_BA: torch.Tensor,
    dom_BAA: torch.Tensor,
    domby_BAA: torch.Tensor | None = None,
    rule: str = "top-scc",
) -> torch.Tensor:
    """select(C, Dom, DomBy): the actions of C that survive "beaten by" inside C.

    ``beaten[a, b] = DomBy[a, b] ∧ ¬(Dom[a, b] ∧ DomBy[a, b])``: b dominates a and the
    pair is not incomparable (``DomBy`` defaults to ``Domᵀ``). ``top-scc`` keeps a ∈ C
    iff every b ∈ C that beats a through a chain inside C is beaten by a through a chain
    inside C — the top strongly connected components, never empty when C is not.
    ``plain`` keeps ``{a ∈ C : no b ∈ C beats a}`` (Alg. 1 line 23); both agree when
    the relation on C has no cycle.
    """
    if domby_BAA is None:
        domby_BAA = dom_BAA.transpose(-1, -2)
    # Keep only edges INTO C: a path that starts in C then never leaves it, and rows
    # outside C are dropped by the final "& C".
    beaten_BAA = domby_BAA & ~dom_BAA & candidates_BA.unsqueeze(-2)
    if rule == "plain":
        return candidates_BA & ~beaten_BAA.any(dim=-1)
    if rule != "top-scc":
        raise PriqnError(f"unknown select rule {rule!r} (valid: {', '.join(SELECT_RULES)})")
    reach_BAA = _transitive_closure(beaten_BAA)
    escaped_BA = (reach_BAA & ~reach_BAA.transpose(-1, -2)).any(dim=-1)
    return candidates_BA & ~escaped_BA


def _select_threshold(
    candidates_BA: torch.Tensor, scores_BA: torch.Tensor, eps: torch.Tensor
) -> torch.Tensor:
    """select() when every pair of C is undecided by the inherited relations.

    Then "b beats a" is just ``score(b) − score(a) > ε`` (an acyclic relation), and
    a survives iff ``max_{b ∈ C} score(b) − score(a) ≤ ε``. Rounding is monotone, so
    this equals the pairwise test bit for bit, at O(A) instead of O(A²) per state.
    """
    masked_BA = torch.where(candidates_BA, scores_BA, -math.inf)
    best_B1 = masked_BA.amax(dim=-1, keepdim=True)
    return candidates_BA & ~((best_B1 - scores_BA) > eps)


def _check_quantiles(quantiles: Any, po: Preorder) -> torch.Tensor:
    if not isinstance(quantiles, torch.Tensor):
        raise PriqnError(f"quantiles: expected a torch tensor, got {type(quantiles).__name__}")
    if not quantiles.is_floating_point():
        raise PriqnError(f"quantiles: expected a float tensor, got {quantiles.dtype}")
    if quantiles.ndim not in (3, 4):
        raise PriqnError(
            f"quantiles: expected shape [B, N, K, A] or [N, K, A], got {list(quantiles.shape)}"
        )
    n, k, a = quantiles.shape[-3:]
    if n != len(po):
        raise PriqnError(
            f"quantiles: N = {n} objectives in shape {list(quantiles.shape)} but the preorder "
            f"has {len(po)} ({', '.join(po.objectives)})"
        )
    if k < 1 or a < 1:
        raise PriqnError(f"quantiles: need K >= 1 quantiles and A >= 1 actions, got K={k}, A={a}")
    return quantiles


def optimal_subsets(
    quantiles: torch.Tensor,
    po: Preorder | str,
    comparator: str = "qd",
    eps: float | Sequence[float] | Mapping[str, float] = 0.2,
    *,
    mv_lambda: float = 0.5,
    cvar_alpha: float = 0.25,
    select_rule: str = "top-scc",
    check_finite: bool = True,
    spread_floor: torch.Tensor | Sequence[float] | None = None,
) -> OptimalSubsets:
    """Algorithm 1 for a batch: quantiles ``[B, N, K, A]`` → optimal subsets.

    ``quantiles`` are on the fixed grid ``τ_k = (k + 0.5)/K`` (see :func:`quantile_grid`),
    N in ``po.objectives`` order; ``[N, K, A]`` gives outputs without the B axis.
    ``eps`` is the tolerance ε ≥ 0: one number, one per objective, or ``{name: ε}``.
    ``mv_lambda`` / ``cvar_alpha`` are read by the ``mv`` / ``cvar`` comparators only.
    ``select_rule`` is ``"top-scc"`` (docs/preorder.md, never empty) or ``"plain"``
    (Alg. 1 line 23 literally; can be empty in deep DAGs). ``check_finite`` rejects
    NaN/inf quantiles (one device sync). ``spread_floor`` (``[N]``, e.g.
    :meth:`RunningScale.floor`) selects the scale-aware normalisation; None is the
    paper's per-state z-score. ``comparator="fsd"`` relates actions by ε-first-order
    stochastic dominance (:func:`fsd_relations`) instead of a score difference.

    Python loops run only over the N objectives (and the log2 A closure squarings).
    """
    return _optimal_subsets(
        quantiles,
        po,
        comparator,
        eps,
        mv_lambda=mv_lambda,
        cvar_alpha=cvar_alpha,
        select_rule=select_rule,
        check_finite=check_finite,
        dense_only=False,
        spread_floor=spread_floor,
    )


@dataclasses.dataclass(frozen=True)
class _SelectPlan:
    """Static facts about a preorder that let select() skip work, all exact.

    - ``threshold[r]``: r is a tree objective (every ancestor has at most one parent).
      Its S↑ has every pair undecided, so select() is the O(A) threshold rule.
    - ``plain[r]`` / ``agg_plain[r]`` / ``leaf_plain``: the "beaten by" relation that
      select (resp. Agg at r, the virtual leaf) sees on its candidates has no cycle,
      so the top-SCC rule equals the plain rule and the closure is skipped. True when
      the candidates are "clean" (no beats-edge among them; they can only be split by
      the local comparator, whose strict ε-relation orders by score) or, for an Agg,
      when it merges two tree objectives that are roots or children of one tree
      objective (the union of two ε-score relations minus conflicts has no cycle:
      along a cycle each score would have to rise by more than ε on its own edges
      more often than it falls by at most ε on the other's). docs/preorder.md proves it.
    - ``needs[r]``: relation matrices are built (r is below a merge, or an ancestor of
      such an objective, or a leaf/ancestor with several leaves).
    """

    threshold: tuple[bool, ...]
    plain: tuple[bool, ...]
    agg_plain: tuple[bool, ...]
    leaf_plain: bool
    needs: tuple[bool, ...]


def _two_tree_siblings(po: Preorder, idx: Sequence[int], tree: Sequence[bool]) -> bool:
    if len(idx) != 2 or not all(tree[i] for i in idx):
        return False
    p, q = (po.parent_indices[i] for i in idx)
    return (not p and not q) or (len(p) == 1 and p == q)


def _plan(po: Preorder, dense_only: bool) -> _SelectPlan:
    """The select plan of ``po``, built once per preorder and ``dense_only``."""
    return po.memo(("select-plan", dense_only), lambda: _build_plan(po, dense_only))


def _build_plan(po: Preorder, dense_only: bool) -> _SelectPlan:
    """:class:`_SelectPlan` from the structure of ``po`` (``dense_only``: no shortcut)."""
    n = len(po)
    tree = [False] * n
    clean = [False] * n  # S_r has no beats-edge under Dom[r]
    plain = [False] * n
    agg_plain = [False] * n
    for r in po.topological_indices:
        parents = po.parent_indices[r]
        tree[r] = not parents or (len(parents) == 1 and tree[parents[0]])
        if not parents:
            plain[r] = True
        elif len(parents) == 1:
            plain[r] = clean[parents[0]]
        else:
            agg_plain[r] = _two_tree_siblings(po, parents, tree)
            plain[r] = agg_plain[r]  # a plain Agg leaves a clean S↑
        clean[r] = plain[r]
    leaves = po.leaf_indices
    leaf_plain = len(leaves) == 1 or _two_tree_siblings(po, leaves, tree)
    if dense_only:
        tree = [False] * n
        plain = [False] * n
        agg_plain = [False] * n
        leaf_plain = len(leaves) == 1
    needs = [not t for t in tree]
    if len(leaves) > 1:
        for i in leaves:
            needs[i] = True
    for r in reversed(po.topological_indices):  # children before parents: push the need up
        if needs[r]:
            for p in po.parent_indices[r]:
                needs[p] = True
    return _SelectPlan(tuple(tree), tuple(plain), tuple(agg_plain), leaf_plain, tuple(needs))


# long: Algorithm 1 in one batched pass, level by level in topological order, so it reads
# against the paper's pseudo-code; each step is a few tensor lines under its own comment.
def _optimal_subsets(
    quantiles: torch.Tensor,
    po: Preorder | str,
    comparator: str,
    eps: float | Sequence[float] | Mapping[str, float],
    *,
    mv_lambda: float,
    cvar_alpha: float,
    select_rule: str,
    check_finite: bool,
    dense_only: bool,
    spread_floor: torch.Tensor | Sequence[float] | None = None,
) -> OptimalSubsets:
    if not isinstance(po, Preorder):
        po = Preorder.resolve(po)
    quantiles = _check_quantiles(quantiles, po)
    if select_rule not in SELECT_RULES:
        raise PriqnError(f"unknown select rule {select_rule!r} (valid: {', '.join(SELECT_RULES)})")
    single = quantiles.ndim == 3
    q_BNKA = quantiles.unsqueeze(0) if single else quantiles
    device = q_BNKA.device

    fn = comparator_function(comparator)
    options = ComparatorOptions(mv_lambda=float(mv_lambda), cvar_alpha=float(cvar_alpha))
    c_BNAK, s_BN1 = normalised(q_BNKA, spread_floor)
    scores_BNA = fn(c_BNAK, s_BN1, options)
    pairwise = comparator in PAIRWISE
    # The shortcuts of _plan assume ε-score relations; pairwise comparators take the
    # dense path (relation matrices everywhere, top-SCC select).
    dense_only = dense_only or pairwise
    # NaN/inf anywhere in a (state, objective) block makes its mean, std and so every
    # score of the block non-finite: checking the small score tensor suffices.
    if check_finite and not bool(torch.isfinite(scores_BNA).all()):
        raise PriqnError(
            "quantiles: contain NaN or inf, or values so large that their spread overflows "
            "(has the network diverged?)"
        )
    eps_N = _eps_tensor(eps, po, device).to(scores_BNA.dtype)
    plan = _plan(po, dense_only)
    needs = plan.needs
    rule_r = ["plain" if ok else select_rule for ok in plan.plain]
    rule_agg = ["plain" if ok else select_rule for ok in plan.agg_plain]
    scores_NBA = scores_BNA.transpose(0, 1).contiguous()  # contiguous rows per objective
    b, n, a = scores_BNA.shape

    # Local relations of the comparator (Eq. 5 with ε), only where matrices are needed.
    local: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}
    rel_idx = [r for r in range(n) if needs[r]]
    if rel_idx and pairwise:
        for r in rel_idx:
            local[r] = fsd_relations(c_BNAK[:, r], s_BN1[:, r], eps_N[r])
    elif rel_idx:
        s_BRA = scores_BNA[:, rel_idx]
        diff_BRAA = s_BRA.unsqueeze(-1) - s_BRA.unsqueeze(-2)  # score(a) − score(b)
        eps_R11 = eps_N[rel_idx].view(-1, 1, 1)
        dom_BRAA = diff_BRAA > eps_R11
        domby_BRAA = diff_BRAA.neg_() > eps_R11  # score(b) − score(a) > ε (negation is exact)
        for j, r in enumerate(rel_idx):
            local[r] = (dom_BRAA[:, j], domby_BRAA[:, j])

    everything_BA = torch.ones(b, a, dtype=torch.bool, device=device)
    dom: dict[int, torch.Tensor] = {}
    domby: dict[int, torch.Tensor] = {}
    subsets: list[torch.Tensor] = [everything_BA] * n
    for r in po.topological_indices:
        parents = po.parent_indices[r]
        # (1) inherit: S↑, Dom↑, DomBy↑
        if not parents:
            s_up_BA = everything_BA
        elif len(parents) == 1:
            s_up_BA = subsets[parents[0]]
        else:  # Agg over the parents' subsets with the inherited relations
            union_BA = subsets[parents[0]]
            for p in parents[1:]:
                union_BA = union_BA | subsets[p]
            s_up_BA = select(union_BA, *_or_relations(parents, dom, domby), rule=rule_agg[r])
        # (2)-(4) undecided pairs take the local relation; the rest is inherited
        if needs[r]:
            local_dom, local_domby = local[r]
            if not parents:
                dom[r], domby[r] = local_dom, local_domby
            else:
                dom_up, domby_up = _or_relations(parents, dom, domby)
                undecided = ~(dom_up | domby_up)
                dom[r] = dom_up | (undecided & local_dom)
                domby[r] = domby_up | (undecided & local_domby)
        # (5) optimal subset
        if plan.threshold[r]:
            subsets[r] = _select_threshold(s_up_BA, scores_NBA[r], eps_N[r])
        else:
            subsets[r] = select(s_up_BA, dom[r], domby[r], rule=rule_r[r])

    leaves = po.leaf_indices
    if len(leaves) == 1:
        leaf_BA = subsets[leaves[0]]
    else:  # the virtual global leaf: Agg over the leaves
        union_BA = subsets[leaves[0]]
        for i in leaves[1:]:
            union_BA = union_BA | subsets[i]
        leaf_rule = "plain" if plan.leaf_plain else select_rule
        leaf_BA = select(union_BA, *_or_relations(leaves, dom, domby), rule=leaf_rule)

    per_objective = torch.stack(subsets, dim=1)
    if single:
        return OptimalSubsets(per_objective[0], leaf_BA[0], scores_BNA[0], po.objectives)
    return OptimalSubsets(per_objective, leaf_BA, scores_BNA, po.objectives)


def _or_relations(
    idx: Sequence[int], dom: Mapping[int, torch.Tensor], domby: Mapping[int, torch.Tensor]
) -> tuple[torch.Tensor, torch.Tensor]:
    dom_or, domby_or = dom[idx[0]], domby[idx[0]]
    for i in idx[1:]:
        dom_or = dom_or | dom[i]
        domby_or = domby_or | domby[i]
    return dom_or, domby_or
