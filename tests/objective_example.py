"""A researcher's own objective, declared outside priqn (docs/your-own-objective.md).

``env.objectives = [..., "tests.objective_example:IDLE"]`` adds it to a run without
touching priqn's source; ``tests/test_objectives.py`` trains, evaluates and inspects with it.
The term is deliberately trivial so its returns can be checked by hand: −0.5 per decision
in which the ego is slower than 1 m/s on average, else 0.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from priqn.objectives import Objective

IDLE_SPEED_MPS = 1.0
"""Mean speed over a decision below which it counts as idling [m/s]."""


def measure_mean_speed(ctx: Any) -> float:
    """Mean ego speed over the decision's counted SUMO steps [m/s]."""
    return float(np.mean(ctx.measures.speed_mps))


def reward_idle(mean_speed_mps: float, rc: Any) -> float:
    """−0.5 when the decision's mean speed is below IDLE_SPEED_MPS, else 0. Range [−0.5, 0]."""
    return -0.5 if mean_speed_mps < IDLE_SPEED_MPS else 0.0


def reward_constant(measured: Any, rc: Any) -> float:
    """−0.25 every decision (a constant cost: the return is −0.25 × episode length)."""
    return -0.25


IDLE = Objective(
    name="idle",
    measure=measure_mean_speed,
    reward=reward_idle,
    bounds=(-0.5, 0.0),
    cost_only=True,
    description="-0.5 per decision slower than 1 m/s on average",
)
"""Declared with callables."""

CONSTANT = Objective(
    name="constant_cost",
    measure="tests.objective_example:measure_mean_speed",
    reward="tests.objective_example:reward_constant",
    bounds=(-0.25, 0.0),
    cost_only=True,
    description="-0.25 every decision",
)
"""Declared with dotted paths."""
