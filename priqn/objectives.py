"""Objectives as declarations: a name, a measure, a reward, per-decision bounds.

A run drives with the objectives its config lists (``env.objectives``, default
:data:`OBJECTIVES`), in that order in every reward vector, network head and
per-objective column (``return_<name>``, ``subset_<name>``). Each entry is resolved to an
:class:`Objective` declaration by :func:`resolve_objective`:

1. a built-in name (:data:`BUILTIN_OBJECTIVES`: the five driving objectives and
   ``right_of_way``);
2. ``package.module:NAME``, a dotted path to an :class:`Objective` in your own package;
3. the name of an entry point in group ``priqn.objectives`` (``pyproject.toml``:
   ``[project.entry-points."priqn.objectives"] my_term = "my_pkg.objectives:MY_TERM"``).

The measure and reward functions are named by dotted path (or given as callables) and
imported only where the env runs; this module imports neither torch nor the env, so the
torch-free side (columns, metrics, analysis) reads names and bounds without SUMO.
docs/your-own-objective.md walks through adding one.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

from priqn.errors import PriqnError
from priqn.plugins import import_path, import_plugin

OBJECTIVES: tuple[str, ...] = ("safety", "risk", "lane_keeping", "progress", "comfort")
"""The default objective list (``env.objectives``), in reward-vector order; highest
priority first in the total order."""

NUM_OBJECTIVES: int = len(OBJECTIVES)
"""Length of the default list."""

ENTRY_POINT_GROUP = "priqn.objectives"
"""Entry-point group under which other packages register :class:`Objective` declarations."""

Bounds = tuple[float, float] | str | Callable[[Any], tuple[float, float]]
"""Per-decision reward bounds: a ``(low, high)`` pair, or a function (callable or dotted
path) of the env's ``RewardConfig`` returning one."""


@dataclasses.dataclass(frozen=True)
class Objective:
    """One declared objective: how the env measures a decision and scores it.

    The env calls ``measure(ctx)`` once per decision with a
    :class:`priqn.env.objective_terms.DecisionContext` (what the decision measured and
    read: ego plan, actors per SUMO step, route, net, config), then
    ``reward(measured, reward_cfg)`` with its result and the env's ``RewardConfig``; the
    reward is one float per decision inside ``bounds``.
    """

    name: str
    """Column and head name (``return_<name>``); a Python identifier."""
    measure: str | Callable[..., Any]
    """``fn(ctx) -> measured``: a callable or ``"package.module:function"``."""
    reward: str | Callable[..., float]
    """``fn(measured, reward_cfg) -> float``: a callable or ``"package.module:function"``."""
    bounds: Bounds
    """Per-decision reward range ``(low, high)``, or a function of ``RewardConfig`` giving it
    (``reward_space``; the weighted-sum crash bound)."""
    cost_only: bool
    """The reward is never positive (≤ 0 every decision): the weighted-sum crash bound
    (:mod:`priqn.agents.scalarise`) counts it among the penalties crashing must outweigh."""
    description: str = ""
    """One line for docs and ``--list-options``."""

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.isidentifier():
            raise PriqnError(
                f"objective {self.name!r}: name must be a Python identifier (it names columns)"
            )
        if isinstance(self.bounds, tuple):
            lo, hi = self.bounds
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise PriqnError(
                    f"objective {self.name!r}: bounds must be finite (low, high) with "
                    f"low <= high, got {self.bounds!r}"
                )
            if self.cost_only and hi > 0:
                raise PriqnError(
                    f"objective {self.name!r}: cost_only = true but bounds allow rewards > 0 "
                    f"({self.bounds!r})"
                )

    def resolved_bounds(self, reward_cfg: Any) -> tuple[float, float]:
        """``(low, high)`` for this env's ``RewardConfig``."""
        if isinstance(self.bounds, tuple):
            return float(self.bounds[0]), float(self.bounds[1])
        lo, hi = load_callable(self.bounds, f"objective {self.name!r} bounds")(reward_cfg)
        return float(lo), float(hi)

    def record(self) -> dict[str, Any]:
        """What ``meta.json`` keeps of the declaration (functions by dotted path)."""
        bounds = list(self.bounds) if isinstance(self.bounds, tuple) else _path_of(self.bounds)
        return {
            "name": self.name,
            "measure": _path_of(self.measure),
            "reward": _path_of(self.reward),
            "bounds": bounds,
            "cost_only": self.cost_only,
        }


def _builtin(name: str, bounds: Bounds, cost_only: bool, description: str) -> Objective:
    mod = "priqn.env.objective_terms"
    return Objective(name, f"{mod}:measure_{name}", f"{mod}:reward_{name}", bounds, cost_only,
                     description)  # fmt: skip


BUILTIN_OBJECTIVES: dict[str, Objective] = {
    "safety": _builtin(
        "safety", "priqn.env.objective_terms:bounds_safety", True,
        "-collision_penalty / -off_road_penalty once on the decision that ends in one, else 0",
    ),
    "risk": _builtin(
        "risk", (-1.0, 0.0), True, "conflict-aware time to conflict below 3 s, in [-1, 0]"
    ),
    "lane_keeping": _builtin(
        "lane_keeping", (-1.0, 0.0), True, "lateral offset and heading error, in [-1, 0]"
    ),
    "progress": _builtin(
        "progress", "priqn.env.objective_terms:bounds_progress", False,
        "route advance and target-speed adherence in [0, 1], + success_bonus at the goal",
    ),
    "comfort": _builtin("comfort", (-1.0, 0.0), True, "jerk and lateral acceleration, in [-1, 0]"),
    "right_of_way": Objective(
        "right_of_way",
        "priqn.env.right_of_way:measure",
        "priqn.env.right_of_way:reward",
        (-1.0, 0.0),
        True,
        "-1 per decision the ego blocks a conflict area of a link it must yield on while a "
        "priority foe is due there (docs/environment.md)",
    ),
}  # fmt: skip
"""Objectives priqn declares itself, by name (``right_of_way`` is not in the default list)."""


def load_callable(spec: str | Callable[..., Any], where: str) -> Callable[..., Any]:
    """A callable, or the object ``"package.module:attribute"`` names (one-line errors)."""
    if callable(spec):
        return spec
    obj = import_path(spec, where)
    if not callable(obj):
        raise PriqnError(f"{where}: {spec!r} is not callable")
    return obj


def _path_of(fn: Any) -> str:
    if isinstance(fn, str):
        return fn
    return f"{getattr(fn, '__module__', '?')}:{getattr(fn, '__qualname__', repr(fn))}"


def _entry_points() -> dict[str, Any]:
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def resolve_objective(entry: str | Objective, where: str = "env.objectives") -> Objective:
    """The declaration an ``env.objectives`` entry names: a built-in name, a
    ``package.module:NAME`` path, or an entry point of group ``priqn.objectives``."""
    if isinstance(entry, Objective):
        return entry
    if not isinstance(entry, str) or not entry:
        raise PriqnError(
            f"{where}: expected objective names or 'package.module:NAME', got {entry!r}"
        )
    if entry in BUILTIN_OBJECTIVES:
        return BUILTIN_OBJECTIVES[entry]
    obj = import_plugin(
        entry, BUILTIN_OBJECTIVES, _entry_points(), where, "objective", "known",
        "priqn.objectives.Objective",
    )  # fmt: skip
    if not isinstance(obj, Objective):
        raise PriqnError(
            f"{where}: {entry!r} is a {type(obj).__name__}, expected a priqn.objectives.Objective"
        )
    return obj


def resolve_objectives(
    entries: Sequence[str | Objective], where: str = "env.objectives"
) -> tuple[Objective, ...]:
    """Every entry resolved (:func:`resolve_objective`); names must be unique, list non-empty."""
    if isinstance(entries, str) or not entries:
        raise PriqnError(f"{where}: expected a non-empty list of objectives, got {entries!r}")
    out = tuple(resolve_objective(e, where) for e in entries)
    names = [o.name for o in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise PriqnError(f"{where}: objective {dup[0]!r} is listed twice")
    return out


def objective_names(
    entries: Sequence[str | Objective], where: str = "env.objectives"
) -> tuple[str, ...]:
    """The names (columns, heads) of an ``env.objectives`` list; the default list's are
    returned without importing anything."""
    if tuple(entries) == OBJECTIVES:
        return OBJECTIVES
    return tuple(o.name for o in resolve_objectives(entries, where))


def return_columns(names: Sequence[str] = OBJECTIVES) -> tuple[str, ...]:
    """``return_<name>`` per objective."""
    return tuple(f"return_{o}" for o in names)


def subset_columns(names: Sequence[str] = OBJECTIVES) -> tuple[str, ...]:
    """Episode-table / metrics columns: mean optimal-subset size |S_r| at the acting steps
    of an episode, per objective and of the leaf (empty for agents without a preorder)."""
    return (*(f"subset_{o}" for o in names), "subset_leaf")


SUBSET_COLUMNS: tuple[str, ...] = subset_columns(OBJECTIVES)
""":func:`subset_columns` of the default list."""


def names_in_columns(columns: Sequence[str]) -> tuple[str, ...]:
    """The objective names of a table, read from its ``return_<name>`` columns (in order)."""
    return tuple(c.removeprefix("return_") for c in columns if c.startswith("return_")
                 and c != "return_weighted")  # fmt: skip


# --------------------------------------------------------------------------- how an episode ends
# Named once here, beside the objectives: the env, the episode tables, the experiment files
# and the reports import them from this module.

OUTCOMES: tuple[str, ...] = ("success", "collision", "off_road", "timeout")
"""How an episode ends, one of four (an episodes.csv row has exactly one of them true)."""

OUTCOME_PRECEDENCE: tuple[str, ...] = ("collision", "off_road", "timeout", "success")
"""How an episode ends, first match wins: an episode that both collides and leaves the
road (the same decision) counts as a collision only, so the outcome rates sum to 1."""

COLLISION_COLUMNS: tuple[str, ...] = (
    "collision_kind",
    "collision_striker",
    "collision_other",
    "collision_ego_speed_mps",
    "collision_npc_speed_mps",
    "collision_npc_could_stop",
    "collision_tm_would_prevent",
)
"""The forensics of a collision (:mod:`priqn.env.forensics`): the final ``info`` keys and the
``episodes.csv`` columns of evaluations made since issue 62 (older tables lack them)."""

COLLISION_KINDS: dict[str, str] = {
    "obstacle": "the ego hit a static obstacle",
    "rear-end": "one drove into the other's rear, both going the same way (striker says who)",
    "head-on": "front to front, opposite ways",
    "ego-into-npc": (
        "the ego drove into an NPC: its front into the NPC's side, or its side or rear into "
        "an NPC that stood"
    ),
    "ego-standing-in-path": (
        "an NPC drove into the ego standing or slow (< 2 m/s) in its path, "
        "which it could have stopped for"
    ),
    "ego-in-path": "an NPC drove into the moving ego in its path, which it could have stopped for",
    "ego-cut-in": "an NPC drove into the ego, which entered its path too late for it to stop",
}
"""The kinds of collision (``collision_kind``, :mod:`priqn.env.forensics`), each with what it
means; an NPC that could have stopped is one a Traffic-Manager-like NPC would not hit."""
