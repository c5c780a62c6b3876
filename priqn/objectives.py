"""The five driving objectives, in the fixed order of every reward vector and head."""

from __future__ import annotations

OBJECTIVES: tuple[str, ...] = ("safety", "risk", "lane_keeping", "progress", "comfort")
"""Objective names in reward-vector order; highest priority first in the total order."""

NUM_OBJECTIVES: int = len(OBJECTIVES)
