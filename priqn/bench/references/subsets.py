"""Algorithm 1 the slow, literal way: the oracle the batched core is checked against.

:func:`reference_optimal_subsets` computes what :func:`priqn.agents.subsets.optimal_subsets`
computes, one state at a time and one objective at a time, in float64 numpy and plain
Python: z-scored quantiles and comparator scores per objective, the relation matrices
``Dom`` / ``DomBy`` as the paper writes them, and select() with the top-SCC rule of
``docs/preorder.md`` (closure by repeated boolean matrix products until it stops
changing). It is written line by line from the paper on purpose: it shares no helper
with the batched core that could share a bug, and it imports no torch.

Its two users: the property tests of ``tests/test_preorder.py`` (every subset of random
preorders and quantiles) and ``priqn bench preorder`` (:mod:`priqn.bench.preorder`), which
times the batched core against it and checks that both agree.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from priqn.agents.preorder import Preorder
from priqn.errors import PriqnError


def _normalised(z_KA: np.ndarray) -> np.ndarray:
    """Z̃ of one state and objective: ``(Z − mean) / max(std, 1e-6)`` over all K·A entries."""
    return (z_KA - z_KA.mean()) / max(z_KA.std(), 1e-6)


def _score(z_KA: np.ndarray, comparator: str, mv_lambda: float, tail: int) -> np.ndarray:
    """Comparator scores ``[A]`` of one state and objective (higher is better)."""
    zt = _normalised(z_KA)
    if comparator == "qd":
        ideal = zt.max(axis=1)
        return -np.abs(zt - ideal[:, None]).mean(axis=0)
    if comparator == "mv":
        return zt.mean(axis=0) - mv_lambda * zt.std(axis=0)
    if comparator == "cvar":
        return zt[:tail].mean(axis=0)
    if comparator == "fsd":  # the shown score only; the relation is pairwise
        return zt.mean(axis=0)
    raise PriqnError(f"unknown comparator {comparator!r} (valid: qd, mv, cvar, fsd)")


def _local_relations(
    z_KA: np.ndarray, scores_A: np.ndarray, comparator: str, eps: float
) -> tuple[np.ndarray, np.ndarray]:
    """One objective's own ``(Dom, DomBy)`` ``[A, A]``: ε-score differences, or ε-FSD."""
    if comparator == "fsd":  # a dominates b iff min_k d_k >= -eps and mean_k d_k > eps
        zt = _normalised(z_KA)
        d = zt[:, :, None] - zt[:, None, :]  # [K, a, b]
        dom = (d.min(axis=0) >= -eps) & (d.mean(axis=0) > eps)
        return dom, dom.T
    diff = scores_A[:, None] - scores_A[None, :]
    return diff > eps, diff < -eps


def _select(cand: np.ndarray, dom: np.ndarray, domby: np.ndarray) -> np.ndarray:
    """select(C, Dom, DomBy) with the top-SCC rule: a ∈ C survives unless some b ∈ C
    reaches a through "beats" edges inside C and a does not reach b back."""
    incomparable = dom & domby
    down = domby & ~incomparable & cand[:, None] & cand[None, :]
    reach = down.copy()
    while True:
        nxt = reach | ((reach.astype(np.int32) @ reach.astype(np.int32)) > 0)
        if (nxt == reach).all():
            break
        reach = nxt
    escaped = (reach & ~reach.T).any(axis=1)
    return cand & ~escaped


def reference_optimal_subsets(
    quantiles_BNKA: Any,
    po: Preorder,
    eps: float | Sequence[float],
    comparator: str = "qd",
    *,
    mv_lambda: float = 0.5,
    cvar_alpha: float = 0.25,
    scores_BNA: Any = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Algorithm 1 state by state → (subsets bool ``[B, N, A]``, leaf bool ``[B, A]``).

    ``quantiles_BNKA`` (array-like, read as float64) are on the fixed grid, N in
    ``po.objectives`` order; ``eps`` is one tolerance or one per objective. The score
    comparators relate actions by ``score(a) − score(b) > ε`` with the scores computed
    here, or with ``scores_BNA`` when given (e.g. the batched core's own
    ``OptimalSubsets.scores``, so that rounding cannot flip a relation that sits exactly
    at ε); ``fsd`` relates them by ε-first-order stochastic dominance of the z-scored
    quantiles.
    """
    q = np.asarray(quantiles_BNKA, dtype=np.float64)
    b_count, n, k, a = q.shape
    eps_N = [float(eps)] * n if isinstance(eps, (int, float)) else [float(e) for e in eps]
    tail = sum(1 for i in range(k) if (i + 0.5) / k <= cvar_alpha)
    given = None if scores_BNA is None else np.asarray(scores_BNA, dtype=np.float64)
    topo = [po.index(name) for name in po.topological_order()]
    parents = [[po.index(p) for p in po.parents(name)] for name in po.objectives]
    leaves = [po.index(name) for name in po.leaves()]

    subsets = np.zeros((b_count, n, a), dtype=bool)
    leaf = np.zeros((b_count, a), dtype=bool)
    for b in range(b_count):
        dom: dict[int, np.ndarray] = {}
        domby: dict[int, np.ndarray] = {}
        s: dict[int, np.ndarray] = {}
        for r in topo:
            sc = given[b, r] if given is not None else _score(q[b, r], comparator, mv_lambda, tail)
            dom_local, domby_local = _local_relations(q[b, r], sc, comparator, eps_N[r])
            if not parents[r]:
                s_up = np.ones(a, dtype=bool)
                dom_up = np.zeros((a, a), dtype=bool)
                domby_up = np.zeros((a, a), dtype=bool)
            else:
                dom_up = np.logical_or.reduce([dom[p] for p in parents[r]])
                domby_up = np.logical_or.reduce([domby[p] for p in parents[r]])
                if len(parents[r]) == 1:
                    s_up = s[parents[r][0]]
                else:
                    union = np.logical_or.reduce([s[p] for p in parents[r]])
                    s_up = _select(union, dom_up, domby_up)
            undecided = ~(dom_up | domby_up)
            dom[r] = (~undecided & dom_up) | (undecided & dom_local)
            domby[r] = (~undecided & domby_up) | (undecided & domby_local)
            s[r] = _select(s_up, dom[r], domby[r])
            subsets[b, r] = s[r]
        if len(leaves) == 1:
            leaf[b] = s[leaves[0]]
        else:
            union = np.logical_or.reduce([s[i] for i in leaves])
            leaf[b] = _select(
                union,
                np.logical_or.reduce([dom[i] for i in leaves]),
                np.logical_or.reduce([domby[i] for i in leaves]),
            )
    return subsets, leaf
