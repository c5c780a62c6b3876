"""A policy's Table II identity: agent, comparator, training preorder, ε, partial order.

One :class:`PolicyLabel` per trained configuration. It is built from a run's config
(:meth:`PolicyLabel.of_config`), written into ``meta.json`` and every evaluation episode
row (:meth:`to_row`), read back by the analysis (:meth:`from_row`) and rendered the
same way everywhere (:meth:`render`, :meth:`cells`). Torch-free; the agent facts
(display names, which agents use a preorder) come from :mod:`priqn.agents.config`.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Iterable, Mapping
from typing import Any

from priqn.agents.config import COMPARATOR_NAMES, AgentConfig, agent_spec

CONFIG_COLUMNS: tuple[str, ...] = ("agent", "comparator", "train_preorder", "eps", "partial_order")
"""The paper's configuration columns, in Table II order: the keys of :meth:`PolicyLabel.to_row`,
of every evaluation episode row and of the analysis' configuration key (one row of Table II)."""
DASH = "–"
CHECK, CROSS = "✓", "✗"


@dataclasses.dataclass(frozen=True)
class PolicyLabel:
    """What distinguishes one row of Table II from another."""

    agent: str
    """Agent name (``iqn``, ``ensemble-iqn``, ``ma-iqn``, ``pr-iqn``)."""
    comparator: str | None = None
    """Comparator of a preorder agent (``qd``, ``mv``, ``cvar``, ``fsd``); None otherwise."""
    train_preorder: bool | None = None
    """Heads bootstrap from their optimal subsets (Eq. 6); None for agents without a preorder."""
    eps: float | tuple[float, ...] | None = None
    """Tolerance ε (one value or one per objective); None for agents without a preorder."""
    partial_order: bool | None = None
    """The preorder is not a chain over all objectives; None for agents without a preorder."""
    extra: tuple[str, ...] = ()
    """Words beyond the paper's columns that tell our own rows apart (``scaled``, ``hln-4``)."""

    @property
    def uses_preorder(self) -> bool:
        spec = agent_spec(self.agent)
        return spec is not None and spec.uses_preorder

    @property
    def display_name(self) -> str:
        spec = agent_spec(self.agent)
        return spec.display_name if spec is not None else self.agent

    @classmethod
    def of_config(cls, agent: AgentConfig, partial_order: bool | None) -> PolicyLabel:
        """The label of a run of ``agent`` (with its preorder's ``partial_order``)."""
        spec = agent_spec(agent.name, agent)
        if spec is None or not spec.uses_preorder:
            extra = (
                () if agent.reward_scheme == AgentConfig.reward_scheme else (agent.reward_scheme,)
            )
            return cls(agent.name, extra=extra)
        extra = () if agent.normalisation == AgentConfig.normalisation else (agent.normalisation,)
        return cls(
            agent.name, agent.comparator, agent.train_preorder, agent.eps, partial_order, extra
        )

    def render(self) -> str:
        """``IQN``, ``Pr-IQN QD ✓ 0.2 ✗``, ``Pr-IQN QD ✓ 0.2 ✗ scaled``, ``IQN hln-4``."""
        cells = self.cells()
        words = [cells[0]] + (cells[1:] if self.uses_preorder else [])
        return " ".join([*words, *self.extra])

    def cells(self) -> list[str]:
        """The five Table II configuration cells (dashes where an option does not apply)."""
        if not self.uses_preorder:
            return [self.display_name, DASH, DASH, DASH, DASH]
        comp = self.comparator
        comp = DASH if comp is None else COMPARATOR_NAMES.get(comp, comp)
        return [
            self.display_name,
            comp,
            _tick(self.train_preorder),
            _eps_text(self.eps),
            _tick(self.partial_order),
        ]

    def to_row(self) -> dict[str, Any]:
        """``{agent, comparator, train_preorder, eps, partial_order, label}`` ('' = not applicable)."""
        row: dict[str, Any] = {
            k: ("" if getattr(self, k) is None else getattr(self, k)) for k in CONFIG_COLUMNS
        }
        row["label"] = self.render()
        return row

    @classmethod
    def from_row(cls, row: Mapping[str, Any]) -> PolicyLabel:
        """Back from :meth:`to_row` as written to JSON or read from a CSV (strings, NaN)."""
        agent = str(row["agent"])
        spec = agent_spec(agent)
        uses = spec is not None and spec.uses_preorder
        words = str(row.get("label", "")).split(" ")
        extra = tuple(w for w in words[(5 if uses else 1) :] if w)
        if not uses:
            return cls(agent, extra=extra)
        comparator = _missing_to_none(row.get("comparator"))
        return cls(
            agent,
            None if comparator is None else str(comparator),
            flag_value(row.get("train_preorder")),
            _eps_value(row.get("eps")),
            flag_value(row.get("partial_order")),
            extra,
        )


def near_greedy(label: PolicyLabel, eps: float) -> PolicyLabel:
    """``label``'s network evaluated with near-greedy acting (``priqn evaluate --acting
    near-greedy``): the same row with the words ``near-greedy ε=<eps>`` appended."""
    return dataclasses.replace(label, extra=(*label.extra, "near-greedy", f"ε={eps:g}"))


def at_budget(label: PolicyLabel, budget: int) -> PolicyLabel:
    """``label``'s policy as kept at ``budget`` decisions (an ``eval-at<N>/`` evaluation of
    ``checkpoint.keep_at``): the same row with ``@60k`` (or ``@<N>``) appended, so each
    budget is a row of its own."""
    return dataclasses.replace(label, extra=(*label.extra, f"@{budget_text(budget)}"))


def budget_text(decisions: int) -> str:
    """A budget in decisions as the reports write it: ``60k``, or ``61500`` off the thousands."""
    return f"{decisions // 1000}k" if decisions % 1000 == 0 else str(decisions)


def seeds_text(seeds: Iterable[int]) -> str:
    """Training seeds as ranges: ``0–21``, ``0–19, 25, 30–31`` (sorted, each once)."""
    runs: list[list[int]] = []
    for seed in sorted(set(seeds)):
        if runs and seed == runs[-1][1] + 1:
            runs[-1][1] = seed
        else:
            runs.append([seed, seed])
    return ", ".join(str(a) if a == b else f"{a}–{b}" for a, b in runs)


_DERIVED_WORDS = re.compile(r"(?: near-greedy ε=\S+| @\d+k?)+$")
"""The words :func:`near_greedy` and :func:`at_budget` append, at the end of a rendered label."""


def trained_row(rendered: str) -> str:
    """The rendered label of the trained row that ``rendered`` derives from: ``IQN
    near-greedy ε=0.2`` and ``IQN @60k`` give ``IQN``; a label without the words of
    :func:`near_greedy` or :func:`at_budget` is its own trained row."""
    return _DERIVED_WORDS.sub("", rendered)


def _missing_to_none(value: Any) -> Any:
    if value is None or value == "" or (isinstance(value, float) and math.isnan(value)):
        return None
    return value


def flag_value(value: Any) -> bool | None:
    """A boolean cell from JSON (bool) or CSV ('True', '1', ...); None if empty."""
    value = _missing_to_none(value)
    if value is None:
        return None
    if isinstance(value, str):
        return value.strip().lower() in ("true", "1", "yes")
    return bool(value)


def _eps_value(value: Any) -> float | tuple[float, ...] | None:
    value = _missing_to_none(value)
    if value is None or isinstance(value, (int, float)):
        return None if value is None else float(value)
    if isinstance(value, (list, tuple)):
        return tuple(float(v) for v in value)
    text = str(value).strip("[]() ")
    parts = [p for p in text.replace("/", ",").split(",") if p.strip()]
    return float(parts[0]) if len(parts) == 1 else tuple(float(p) for p in parts)


def _tick(flag: bool | None) -> str:
    return DASH if flag is None else (CHECK if flag else CROSS)


def _eps_text(eps: float | tuple[float, ...] | None) -> str:
    if eps is None:
        return DASH
    if isinstance(eps, tuple):
        return "/".join(f"{e:g}" for e in eps)
    return f"{eps:g}"
