"""What a declared objective sees of a decision, and the five built-in terms as declarations.

:class:`DecisionContext` is the one argument of every objective's ``measure``: what the
env measured and read over one decision. The built-in measures pick their inputs out of
``ctx.measures``; the built-in rewards are :mod:`priqn.env.rewards`' functions, called with
the same arguments as before objectives were declared (so the default reward vector is
bit-identical). :class:`EnvObjectives` is the env's resolved list: the functions
imported once, the reward vector and ``reward_space`` bounds in declared order.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from priqn.env import rewards as R
from priqn.objectives import Objective, load_callable, resolve_objectives


@dataclasses.dataclass(frozen=True)
class DecisionContext:
    """One decision as the objectives see it (arrays ``[T]`` over its counted SUMO steps)."""

    config: Any
    """The env's :class:`~priqn.env.config.EnvConfig` (``config.reward``: RewardConfig)."""
    measures: Any
    """The built-in measurements (:class:`priqn.env.intersection.Measures`): events,
    conflict times, lateral offset, heading error, advance, speed, jerk, lateral accel."""
    trajectory: Any
    """The executed plan (:class:`priqn.env.planner.Trajectory`); sample k is the ego after
    SUMO step k (x, y [m], heading_rad, speed_mps, s, d [m])."""
    steps: np.ndarray
    """int ``[T]``: the plan samples of the counted SUMO steps (1..T)."""
    actors: Any
    """:class:`priqn.env.reads.StepActors` read after each counted step (ids, boxes,
    speeds, headings)."""
    route: Any
    """The ego's :class:`priqn.sim.roadmap.EgoRoute` (edges, lanes, goal)."""
    scene: Any
    """The episode's :class:`priqn.env.scenes.Scene` (``roadmap``: the net read by sumolib)."""
    target_speed_mps: float
    """Progress reward's target speed v* [m/s]."""


# ---------------------------------------------------------------- the five built-ins


def measure_safety(ctx: DecisionContext) -> tuple[bool, bool]:
    """(collision, off_road) of the decision."""
    return ctx.measures.collision, ctx.measures.off_road


def reward_safety(m: tuple[bool, bool], rc: R.RewardConfig) -> float:
    """:func:`priqn.env.rewards.safety`."""
    return R.safety(m[0], m[1], rc)


def bounds_safety(rc: R.RewardConfig) -> tuple[float, float]:
    """(-max(collision_penalty, off_road_penalty), 0)."""
    return -max(rc.collision_penalty, rc.off_road_penalty), 0.0


def measure_risk(ctx: DecisionContext) -> np.ndarray:
    """Time to the first conflict seen from each step [s]."""
    return ctx.measures.conflict_time_s


def reward_risk(m: np.ndarray, rc: R.RewardConfig) -> float:
    """:func:`priqn.env.rewards.risk`."""
    return R.risk(m, rc)


def measure_lane_keeping(ctx: DecisionContext) -> tuple[np.ndarray, np.ndarray]:
    """(lateral offset [m], heading error [rad]) per step."""
    return ctx.measures.lateral_offset_m, ctx.measures.heading_error_rad


def reward_lane_keeping(m: tuple[np.ndarray, np.ndarray], rc: R.RewardConfig) -> float:
    """:func:`priqn.env.rewards.lane_keeping`."""
    return R.lane_keeping(m[0], m[1], rc)


def measure_progress(ctx: DecisionContext) -> tuple[float, np.ndarray, float, float, bool]:
    """(advance [m], speed [m/s] per step, target speed [m/s], decision length [s], success)."""
    m = ctx.measures
    return (m.advance_m, m.speed_mps, ctx.target_speed_mps, ctx.config.decision_interval_s,
            m.success)  # fmt: skip


def reward_progress(m: tuple[float, np.ndarray, float, float, bool], rc: R.RewardConfig) -> float:
    """:func:`priqn.env.rewards.progress`."""
    return R.progress(*m, rc)


def bounds_progress(rc: R.RewardConfig) -> tuple[float, float]:
    """(0, 1 + success_bonus)."""
    return 0.0, 1.0 + rc.success_bonus


def measure_comfort(ctx: DecisionContext) -> tuple[np.ndarray, np.ndarray]:
    """(jerk [m/s³], lateral acceleration [m/s²]) per step."""
    return ctx.measures.jerk_mps3, ctx.measures.lateral_accel_mps2


def reward_comfort(m: tuple[np.ndarray, np.ndarray], rc: R.RewardConfig) -> float:
    """:func:`priqn.env.rewards.comfort`."""
    return R.comfort(m[0], m[1], rc)


# ---------------------------------------------------------------- the env's list


class EnvObjectives:
    """An env's objectives resolved once: names, bounds and the reward vector."""

    def __init__(self, entries: Sequence[str | Objective], rc: R.RewardConfig) -> None:
        self.declared = resolve_objectives(entries)
        self.names: tuple[str, ...] = tuple(o.name for o in self.declared)
        self._rc = rc
        self._fns = [
            (
                load_callable(o.measure, f"objective {o.name!r} measure"),
                load_callable(o.reward, f"objective {o.name!r} reward"),
            )
            for o in self.declared
        ]
        bounds = [o.resolved_bounds(rc) for o in self.declared]
        self.low = np.array([b[0] for b in bounds], np.float32)
        """float32 [N]: per-decision lower bounds (declared order)."""
        self.high = np.array([b[1] for b in bounds], np.float32)
        """float32 [N]: per-decision upper bounds."""

    def __len__(self) -> int:
        return len(self.names)

    def reward_vector(self, ctx: DecisionContext) -> np.ndarray:
        """``float32 [N]``: each objective's reward of the decision, in declared order."""
        return np.array(
            [float(reward(measure(ctx), self._rc)) for measure, reward in self._fns],
            dtype=np.float32,
        )
