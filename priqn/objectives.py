"""The five driving objectives, in the fixed order of every reward vector and head."""

from __future__ import annotations

OBJECTIVES: tuple[str, ...] = ("safety", "risk", "lane_keeping", "progress", "comfort")
"""Objective names in reward-vector order; highest priority first in the total order."""

NUM_OBJECTIVES: int = len(OBJECTIVES)

SUBSET_COLUMNS: tuple[str, ...] = (*(f"subset_{o}" for o in OBJECTIVES), "subset_leaf")
"""Episode-table / metrics columns: mean optimal-subset size |S_r| at the acting steps of
an episode, per objective and of the leaf (empty for agents without a preorder)."""
