"""Preorders over objectives, distribution comparators and Algorithm 1: the public module.

``from priqn.preorder import Preorder, optimal_subsets`` is how users, docs and plug-ins
reach the decision core of Pr-IQN (``docs/preorder.md``). The code lives in
:mod:`priqn.agents`, beside the agents that call it on every acting step and every TD
target, and beside the torch-free agent facts it reads (the comparator names and preset
names of :mod:`priqn.agents.config`): the preorder graph in :mod:`priqn.agents.preorder`
(torch-free), the comparators in :mod:`priqn.agents.comparators`, Algorithm 1 in
:mod:`priqn.agents.subsets`. This module only re-exports their public names, so the room
``priqn.preorder`` imports ``priqn.agents`` and never the other way.
"""

from __future__ import annotations

from priqn.agents.comparators import (
    COMPARATOR_FUNCTIONS,
    MIN_STD,
    PAIRWISE,
    ComparatorFn,
    ComparatorOptions,
    RunningScale,
    comparator_scores,
    cvar_count,
    fsd_relations,
    normalised,
    quantile_grid,
    zscore,
)
from priqn.agents.preorder import Preorder, PreorderSpec
from priqn.agents.subsets import SELECT_RULES, OptimalSubsets, optimal_subsets, select

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
