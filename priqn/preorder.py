"""Preorders over objectives, distribution comparators and Algorithm 1: the public module.

``from priqn.preorder import Preorder, optimal_subsets`` is how users, docs and plug-ins
reach the decision core of Pr-IQN (``docs/preorder.md``). The code lives in
:mod:`priqn.agents.preorder`, beside the agents that call it on every acting step and
every TD target, and beside the torch-free agent facts it reads (the comparator names
and preset names of :mod:`priqn.agents.config`); this module only re-exports its public
names, so the room ``priqn.preorder`` imports ``priqn.agents`` and never the other way.
"""

from __future__ import annotations

from priqn.agents.preorder import (
    COMPARATOR_FUNCTIONS,
    MIN_STD,
    PAIRWISE,
    SELECT_RULES,
    ComparatorFn,
    ComparatorOptions,
    OptimalSubsets,
    Preorder,
    PreorderSpec,
    RunningScale,
    comparator_scores,
    cvar_count,
    fsd_relations,
    normalised,
    optimal_subsets,
    quantile_grid,
    select,
    zscore,
)

__all__ = [
    "COMPARATOR_FUNCTIONS",
    "MIN_STD",
    "PAIRWISE",
    "SELECT_RULES",
    "ComparatorFn",
    "ComparatorOptions",
    "OptimalSubsets",
    "Preorder",
    "PreorderSpec",
    "RunningScale",
    "comparator_scores",
    "cvar_count",
    "fsd_relations",
    "normalised",
    "optimal_subsets",
    "quantile_grid",
    "select",
    "zscore",
]
