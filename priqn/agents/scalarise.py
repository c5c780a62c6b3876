"""Weighted-sum scalarisation of the reward vector for IQN, Ensemble-IQN and MA-IQN.

The scalar baselines learn (or, for MA-IQN, act on) ``Σ_i w_i r_i``. A weighted sum is
only a fair baseline if it never makes crashing cheap: ending the episode with a safety
event must cost more than the worst lower-level penalty the agent could still collect
by driving on. ``docs/implementation-details.md`` ("Reward weights") derives the bound:

    w_safety · P  >  (w_risk + w_lane + w_comfort) · H_T,    H_T = Σ_{t<T} γ^t

with ``P = min(collision_penalty, off_road_penalty)`` (the one-off safety event), the
lower terms' per-decision range ``[-1, 0]`` and ``T`` decisions per episode. Progress is
``[0, 1]`` per decision: crashing forfeits it, which only makes crashing worse, so it
does not enter. :func:`crash_margin` is the left side over the right side; a scheme is
safe when it is > 1.

Schemes follow the hierarchy-level normalisation of the paper's reference [1]: every
level's per-decision term has the same unit range, weights fall by a constant ratio ρ
per level below safety, and the lower levels share one scale ``c`` chosen so that the
bound holds with a margin ``m``:

    w = (1, c, c/ρ, c/ρ², c/ρ³),   c = P / (m · H_T · (1 + 1/ρ + 1/ρ³))

(risk, lane keeping and comfort are levels 1, 2 and 4 below safety). Torch-free.

With declared objectives (``env.objectives``, docs/your-own-objective.md) the same rule
holds for any list: ``safety`` is the crash term, the lower penalties are the objectives
declared ``cost_only`` (their per-decision reward lies in [low, 0]; the bound uses
``|low|``), and an objective's level is its position in the list (``safety`` first).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

from priqn.errors import PriqnError
from priqn.objectives import OBJECTIVES, Objective, resolve_objectives

PENALISING_LOWER_OBJECTIVES: tuple[str, ...] = ("risk", "lane_keeping", "comfort")
"""Lower-level objectives of the default list whose per-decision reward lies in [-1, 0]
(docs/environment.md); for any list: :func:`penalising_lower`."""
CRASH_OBJECTIVE = "safety"
"""The objective whose one-off penalty crashing costs."""

DEFAULT_EPISODE_STEPS = 100
"""EnvConfig.max_episode_steps default: the T the named schemes are computed for."""
DEFAULT_GAMMA = 0.99
"""LearnerConfig.gamma default."""
DEFAULT_SAFETY_PENALTY = 10.0
"""RewardConfig collision_penalty / off_road_penalty default."""


def horizon(max_episode_steps: int, gamma: float) -> float:
    """``H_T = Σ_{t<T} γ^t``: the largest discounted count of decisions left [decisions]."""
    if gamma >= 1.0:
        return float(max_episode_steps)
    return (1.0 - gamma**max_episode_steps) / (1.0 - gamma)


Objectives = Sequence[str | Objective]
"""An ``env.objectives`` list: entries (names, dotted paths) or declarations."""


def penalising_lower(objectives: Objectives = OBJECTIVES) -> tuple[tuple[str, float], ...]:
    """``(name, |low|)`` of every objective declared ``cost_only`` other than safety, in
    list order: the lower-level penalties the crash bound weighs (|low| = its worst
    per-decision cost; 1 for the built-in risk, lane keeping and comfort)."""
    if tuple(objectives) == OBJECTIVES:  # the default list, without resolving anything
        return tuple((o, 1.0) for o in PENALISING_LOWER_OBJECTIVES)
    out = []
    for o in resolve_objectives(objectives):
        if o.cost_only and o.name != CRASH_OBJECTIVE:
            if not isinstance(o.bounds, tuple):
                raise PriqnError(
                    f"objective {o.name!r}: a cost_only objective needs fixed (low, high) bounds "
                    "for the weighted-sum crash bound"
                )
            out.append((o.name, abs(float(o.bounds[0]))))
    return tuple(out)


def _names(objectives: Objectives) -> tuple[str, ...]:
    if tuple(objectives) == OBJECTIVES:
        return OBJECTIVES
    return tuple(o.name for o in resolve_objectives(objectives))


def crash_margin(
    weights: Sequence[float],
    safety_penalty: float = DEFAULT_SAFETY_PENALTY,
    max_episode_steps: int = DEFAULT_EPISODE_STEPS,
    gamma: float | Sequence[float] = DEFAULT_GAMMA,
    objectives: Objectives = OBJECTIVES,
) -> float:
    """Cost of a safety event over the worst accumulable lower-level penalty (> 1 = safe).

    ``weights`` in ``objectives`` order; ``safety_penalty`` the smaller of the collision
    and off-road penalties; ``gamma`` one number or one per objective. ``inf`` when no
    lower objective is penalised or there is no ``safety`` objective to protect.
    """
    names = _names(objectives)
    w = dict(zip(names, weights, strict=True))
    g = dict(zip(names, _per_objective(gamma, len(names)), strict=True))
    if CRASH_OBJECTIVE not in w:
        return math.inf
    worst_lower = sum(  # c = 1.0 for the built-ins: 1.0 * x == x, bit for bit
        w[o] * (c * horizon(max_episode_steps, g[o])) for o, c in penalising_lower(objectives)
    )
    crash = w[CRASH_OBJECTIVE] * safety_penalty
    return math.inf if worst_lower <= 0 else crash / worst_lower


def _per_objective(gamma: float | Sequence[float], n: int = len(OBJECTIVES)) -> tuple[float, ...]:
    if isinstance(gamma, (int, float)):
        return (float(gamma),) * n
    return tuple(float(x) for x in gamma)


def hierarchy_weights(
    ratio: float,
    margin: float,
    safety_penalty: float = DEFAULT_SAFETY_PENALTY,
    max_episode_steps: int = DEFAULT_EPISODE_STEPS,
    gamma: float = DEFAULT_GAMMA,
    objectives: Objectives = OBJECTIVES,
) -> tuple[float, ...]:
    """``(1, c, c/ρ, c/ρ², c/ρ³)`` with ``c`` such that :func:`crash_margin` = ``margin``
    (one weight per objective, level = position; ``safety`` must come first)."""
    names = _names(objectives)
    if names[0] != CRASH_OBJECTIVE:
        raise PriqnError(
            f"agent.reward_scheme: the weighted-sum schemes need {CRASH_OBJECTIVE!r} first in "
            f"env.objectives (got {', '.join(names)}); or give agent.reward_weights"
        )
    levels = {o: i for i, o in enumerate(names)}  # safety 0, risk 1, ... comfort 4
    share = sum(c * ratio ** -(levels[o] - 1) for o, c in penalising_lower(objectives))
    c = safety_penalty / (margin * horizon(max_episode_steps, gamma) * share)
    return (1.0,) + tuple(c * ratio ** -(i - 1) for i in range(1, len(names)))


def task_progress_weights(
    ratio: float,
    margin: float,
    episode_share: float,
    safety_penalty: float = DEFAULT_SAFETY_PENALTY,
    max_episode_steps: int = DEFAULT_EPISODE_STEPS,
    gamma: float = DEFAULT_GAMMA,
    objectives: Objectives = OBJECTIVES,
) -> tuple[float, ...]:
    """:func:`hierarchy_weights` for the penalising levels, and a progress weight such
    that a whole episode of full progress is worth ``episode_share`` safety events:
    ``w_progress · H_T = episode_share · P``. Progress is ≥ 0, so it cannot make crashing
    cheap (the crash margin is that of the penalties alone)."""
    names = _names(objectives)
    if "progress" not in names:
        raise PriqnError(
            "agent.reward_scheme: this scheme weighs the 'progress' objective, which "
            f"env.objectives lacks ({', '.join(names)}); pick hln-2 / hln-4 or agent.reward_weights"
        )
    w = list(hierarchy_weights(ratio, margin, safety_penalty, max_episode_steps, gamma, objectives))
    w[names.index("progress")] = episode_share * safety_penalty / horizon(max_episode_steps, gamma)
    return tuple(w)


@dataclasses.dataclass(frozen=True)
class Scheme:
    """A named weighting rule."""

    description: str
    """One line for --list-options and the docs."""
    ratio: float | None = None
    """Hierarchy-level decay ρ per level below safety (None: fixed ``weights``)."""
    margin: float | None = None
    """Required crash margin m (None: fixed ``weights``)."""
    weights: tuple[float, ...] | None = None
    """Fixed weights (the pre-fairness default)."""
    progress_share: float | None = None
    """If set: the progress weight makes a whole episode of full progress worth this many
    safety events (:func:`task_progress_weights`) instead of following the ratio."""

    def resolve(
        self,
        safety_penalty: float = DEFAULT_SAFETY_PENALTY,
        max_episode_steps: int = DEFAULT_EPISODE_STEPS,
        gamma: float = DEFAULT_GAMMA,
        objectives: Objectives = OBJECTIVES,
    ) -> tuple[float, ...]:
        if self.weights is not None:
            if len(self.weights) != len(objectives):
                raise PriqnError(
                    f"agent.reward_scheme: fixed weights for the {len(self.weights)} default "
                    f"objectives, but env.objectives has {len(objectives)}; pick hln-2, hln-4 "
                    "or give agent.reward_weights"
                )
            return self.weights
        assert self.ratio is not None and self.margin is not None
        if self.progress_share is not None:
            return task_progress_weights(
                self.ratio,
                self.margin,
                self.progress_share,
                safety_penalty,
                max_episode_steps,
                gamma,
                objectives,
            )
        return hierarchy_weights(
            self.ratio, self.margin, safety_penalty, max_episode_steps, gamma, objectives
        )


SCHEMES: dict[str, Scheme] = {
    "hln-2": Scheme(
        "hierarchy-level normalisation, weights halve per level, crash margin 2", 2.0, 2.0
    ),
    "hln-4": Scheme(
        "hierarchy-level normalisation, weights quarter per level, crash margin 2", 4.0, 2.0
    ),
    "hln-2-task": Scheme(
        "hln-2's penalties (crash margin 2) with progress as the task reward: a whole "
        "episode of full progress is worth one safety event",
        2.0,
        2.0,
        progress_share=1.0,
    ),
    "halving": Scheme(
        "the pre-fairness weights (1, .5, .25, .125, .0625): crashing can be cheaper than "
        "an episode of lower-level penalties (crash margin 0.19); for comparison only",
        weights=(1.0, 0.5, 0.25, 0.125, 0.0625),
    ),
}
"""Scheme name → rule. ``hln-2-task`` is the agents' default (the sensitivity check's best)."""


def scheme_weights(
    name: str,
    safety_penalty: float = DEFAULT_SAFETY_PENALTY,
    max_episode_steps: int = DEFAULT_EPISODE_STEPS,
    gamma: float = DEFAULT_GAMMA,
    objectives: Objectives = OBJECTIVES,
) -> tuple[float, ...]:
    """Weights of the named scheme for an episode of ``max_episode_steps`` decisions, one
    per objective of ``objectives`` (``env.objectives``)."""
    if name not in SCHEMES:
        raise PriqnError(
            f"agent.reward_scheme: unknown scheme {name!r} (valid: {', '.join(SCHEMES)})"
        )
    return SCHEMES[name].resolve(safety_penalty, max_episode_steps, gamma, objectives)
