"""The preorder over objectives: a DAG of named objectives, read, checked and walked.

A :class:`Preorder` is pure structure: objective names (the order of the ``N`` axis of
every quantile tensor), edges ``(higher, lower)``, parents, children, roots, leaves and a
deterministic topological order. It is read from a ``[preorder]`` TOML table or a preset
and checked (unknown names, duplicates, cycles) with errors that name the file. This
module imports neither torch nor another module of :mod:`priqn.agents` but the torch-free
:mod:`priqn.agents.config`, so run folders, the sweep and the analysis can read a preorder
without loading torch.

Beside it: the comparators (:mod:`priqn.agents.comparators`), Algorithm 1
(:mod:`priqn.agents.subsets`) and its slow reference (:mod:`priqn.bench.references.subsets`);
the public module is :mod:`priqn.preorder`; ``docs/preorder.md`` explains the method.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable, Hashable, Iterable, Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

from priqn.agents.config import PREORDER_PRESETS
from priqn.config import from_dict, load_toml
from priqn.errors import PriqnError

T = TypeVar("T")


# ============================================================================ preorder


@dataclasses.dataclass(frozen=True)
class PreorderSpec:
    """The ``[preorder]`` table of a TOML file."""

    objectives: tuple[str, ...]
    """Objective names; their order is the order of the N axis of the quantiles."""
    edges: tuple[list[str], ...] = ()
    """Pairs ``[higher, lower]``: the first objective takes precedence over the second."""
    description: str = ""
    """Free text shown by ``describe`` (optional)."""


class Preorder:
    """A preorder over named objectives: a DAG whose edge ``(hi, lo)`` means hi ≻ lo.

    Objectives that no path connects are incomparable. The objective order given here
    is the order of the ``N`` axis of every quantile tensor and every output.
    ``source`` names where the preorder came from (a file) in error messages.
    """

    def __init__(
        self,
        objectives: Sequence[str],
        edges: Iterable[tuple[str, str] | Sequence[str]] = (),
        *,
        source: str = "preorder",
        description: str = "",
    ) -> None:
        self.source = str(source)
        self.description = str(description)
        if isinstance(objectives, str) or not isinstance(objectives, Sequence):
            raise PriqnError(f"{source}: objectives must be a list of names, got {objectives!r}")
        names = list(objectives)
        if not names:
            raise PriqnError(f"{source}: a preorder needs at least one objective")
        seen: set[str] = set()
        for name in names:
            if not isinstance(name, str) or not name.strip():
                raise PriqnError(
                    f"{source}: objective names must be non-empty strings, got {name!r}"
                )
            if name in seen:
                raise PriqnError(f"{source}: objective {name!r} is listed twice in objectives")
            seen.add(name)
        self._objectives: tuple[str, ...] = tuple(names)
        self._index = {name: i for i, name in enumerate(names)}
        valid = ", ".join(names)

        edge_list: list[tuple[str, str]] = []
        for edge in edges:
            if isinstance(edge, str) or not isinstance(edge, Sequence) or len(edge) != 2:
                raise PriqnError(
                    f"{source}: edge {edge!r} must be a pair [higher, lower] of objective names"
                )
            hi, lo = edge
            for name in (hi, lo):
                if name not in self._index:
                    raise PriqnError(
                        f"{source}: edge [{hi!r}, {lo!r}] names unknown objective {name!r} "
                        f"(valid: {valid})"
                    )
            if hi == lo:
                raise PriqnError(
                    f"{source}: cyclic preorder: {hi} -> {lo} (an objective cannot precede itself)"
                )
            if (hi, lo) in edge_list:
                raise PriqnError(f"{source}: edge [{hi!r}, {lo!r}] is listed twice")
            edge_list.append((hi, lo))
        self._edges: tuple[tuple[str, str], ...] = tuple(edge_list)

        n = len(names)
        parents: list[list[int]] = [[] for _ in range(n)]
        children: list[list[int]] = [[] for _ in range(n)]
        for hi, lo in edge_list:
            parents[self._index[lo]].append(self._index[hi])
            children[self._index[hi]].append(self._index[lo])
        self._parents_idx = tuple(tuple(sorted(p)) for p in parents)
        self._children_idx = tuple(tuple(sorted(c)) for c in children)
        cycle = self._find_cycle()
        if cycle:
            raise PriqnError(
                f"{source}: cyclic preorder: {' -> '.join(cycle)}; edges [higher, lower] "
                "must form a DAG"
            )
        self._topo_idx = self._kahn()
        self._memo: dict[Hashable, Any] = {}  # see memo()
        self._leaves_idx = tuple(i for i in range(n) if not self._children_idx[i])

    # ---------------------------------------------------------------- constructors

    @classmethod
    def chain(cls, objectives: Sequence[str], *, source: str = "preorder") -> Preorder:
        """Total order: ``objectives[0] ≻ objectives[1] ≻ ...``."""
        names = list(objectives)
        return cls(names, list(itertools.pairwise(names)), source=source)

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], where: str = "[preorder]", source: str | None = None
    ) -> Preorder:
        """From the contents of a ``[preorder]`` table (``objectives``, ``edges``).

        ``where`` names the table in type errors, ``source`` the preorder in the others.
        """
        spec = from_dict(PreorderSpec, data, where)
        return cls(
            spec.objectives, spec.edges, source=source or where, description=spec.description
        )

    @classmethod
    def from_toml(cls, path: str | Path) -> Preorder:
        """Read the ``[preorder]`` table of a TOML file; errors name the file."""
        data = load_toml(path)
        if "preorder" not in data:
            raise PriqnError(
                f"{path}: missing [preorder] table (expected objectives = [...] and "
                "edges = [[higher, lower], ...])"
            )
        return cls.from_dict(data["preorder"], where=f"{path} [preorder]", source=str(path))

    @classmethod
    def preset(cls, name: str) -> Preorder:
        """One of the shipped presets: ``total`` (the chain), ``partial`` or ``right-of-way``."""
        if name not in PREORDER_PRESETS:
            raise PriqnError(
                f"unknown preorder preset {name!r} (valid: {', '.join(PREORDER_PRESETS)})"
            )
        with resources.as_file(resources.files("priqn") / "presets" / f"{name}.toml") as path:
            po = cls.from_toml(path)
        po.source = f"preset {name!r}"
        return po

    @classmethod
    def resolve(
        cls, spec: str | Path | Preorder, objectives: Sequence[str] | None = None
    ) -> Preorder:
        """``"total"`` | ``"partial"`` | a TOML path | a Preorder → Preorder.

        With ``objectives`` (e.g. :data:`priqn.objectives.OBJECTIVES`), the preorder
        must name exactly those objectives and is returned in that order, so its N axis
        matches the reward vector and the network heads. ``"total"`` with objectives other
        than the default five is the chain of ``objectives`` in their order.
        """
        from priqn.objectives import OBJECTIVES

        if spec == "total" and objectives is not None and tuple(objectives) != OBJECTIVES:
            return cls.chain(objectives, source="preset 'total' (chain of env.objectives)")
        if isinstance(spec, Preorder):
            po = spec
        elif isinstance(spec, str) and spec in PREORDER_PRESETS:
            po = cls.preset(spec)
        elif isinstance(spec, (str, Path)) and Path(spec).is_file():
            po = cls.from_toml(spec)
        else:
            raise PriqnError(
                f"unknown preorder {str(spec)!r}: expected 'total', 'partial' or a path to a "
                "TOML file with a [preorder] table"
            )
        return po if objectives is None else po.reordered(objectives)

    def reordered(self, objectives: Sequence[str]) -> Preorder:
        """The same preorder with its objectives (the N axis) in the given order."""
        want = list(objectives)
        if sorted(want) != sorted(self._objectives) or len(set(want)) != len(want):
            missing = [n for n in want if n not in self._index]
            extra = [n for n in self._objectives if n not in want]
            raise PriqnError(
                f"{self.source}: preorder objectives ({', '.join(self._objectives)}) do not "
                f"match the run's objectives (env.objectives: {', '.join(want)}); missing: "
                f"{', '.join(missing) or '-'}; extra: {', '.join(extra) or '-'}"
            )
        return Preorder(want, self._edges, source=self.source, description=self.description)

    # ---------------------------------------------------------------- queries

    @property
    def objectives(self) -> tuple[str, ...]:
        """Objective names in N-axis order."""
        return self._objectives

    @property
    def edges(self) -> tuple[tuple[str, str], ...]:
        """Edges ``(higher, lower)`` as given."""
        return self._edges

    def __len__(self) -> int:
        return len(self._objectives)

    def index(self, name: str) -> int:
        """Position of objective ``name`` on the N axis."""
        try:
            return self._index[name]
        except KeyError:
            raise PriqnError(
                f"{self.source}: unknown objective {name!r} (valid: {', '.join(self._objectives)})"
            ) from None

    def parents(self, name: str) -> tuple[str, ...]:
        """Direct higher-priority objectives of ``name`` (N-axis order)."""
        return tuple(self._objectives[i] for i in self._parents_idx[self.index(name)])

    def children(self, name: str) -> tuple[str, ...]:
        """Direct lower-priority objectives of ``name`` (N-axis order)."""
        return tuple(self._objectives[i] for i in self._children_idx[self.index(name)])

    def roots(self) -> tuple[str, ...]:
        """Objectives without parents."""
        return tuple(o for i, o in enumerate(self._objectives) if not self._parents_idx[i])

    def leaves(self) -> tuple[str, ...]:
        """Objectives without children (several ⇒ a virtual global leaf aggregates them)."""
        return tuple(self._objectives[i] for i in self._leaves_idx)

    def topological_order(self) -> tuple[str, ...]:
        """Parents before children; ties broken by N-axis order (deterministic)."""
        return tuple(self._objectives[i] for i in self._topo_idx)

    def is_chain(self) -> bool:
        """True for a total order (one root, one leaf, every node at most one parent/child)."""
        return (
            all(len(p) <= 1 for p in self._parents_idx)
            and len(self._leaves_idx) == 1
            and (len(self.roots()) == 1)
        )

    @property
    def parent_indices(self) -> tuple[tuple[int, ...], ...]:
        """Per objective (N-axis order), the N-axis positions of its parents, ascending."""
        return self._parents_idx

    @property
    def topological_indices(self) -> tuple[int, ...]:
        """:meth:`topological_order` as N-axis positions."""
        return self._topo_idx

    @property
    def leaf_indices(self) -> tuple[int, ...]:
        """:meth:`leaves` as N-axis positions (ascending)."""
        return self._leaves_idx

    def memo(self, key: Hashable, build: Callable[[], T]) -> T:
        """``build()`` on the first call with ``key``, the kept result on every later one.

        For facts derived from the structure alone (Algorithm 1's select plans,
        :mod:`priqn.agents.subsets`): objectives and edges never change after
        construction, so they never go stale. :meth:`reordered` starts a new memo.
        """
        try:
            return self._memo[key]
        except KeyError:
            value = self._memo[key] = build()
            return value

    def to_dict(self) -> dict[str, Any]:
        """Contents of a ``[preorder]`` table (round-trips through :meth:`from_dict`)."""
        data: dict[str, Any] = {
            "objectives": list(self._objectives),
            "edges": [list(e) for e in self._edges],
        }
        if self.description:
            data["description"] = self.description
        return data

    def describe(self) -> str:
        """One line: ``a > b > c`` for a chain, else the edge list."""
        if self.is_chain():
            return " > ".join(self.topological_order())
        return ", ".join(f"{hi} > {lo}" for hi, lo in self._edges) or " ~ ".join(self._objectives)

    def __repr__(self) -> str:
        return f"Preorder({self.describe()})"

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Preorder):
            return NotImplemented
        return self._objectives == other._objectives and set(self._edges) == set(other._edges)

    def __hash__(self) -> int:
        return hash((self._objectives, frozenset(self._edges)))

    # ---------------------------------------------------------------- internals

    def _find_cycle(self) -> list[str]:
        """A cycle as a name list (first == last), or [] for a DAG."""
        n = len(self._objectives)
        state = [0] * n  # 0 unvisited, 1 on the DFS stack, 2 done
        stack: list[int] = []

        def visit(i: int) -> list[int]:
            state[i] = 1
            stack.append(i)
            for j in self._children_idx[i]:
                if state[j] == 1:
                    return stack[stack.index(j) :] + [j]
                if state[j] == 0:
                    found = visit(j)
                    if found:
                        return found
            stack.pop()
            state[i] = 2
            return []

        for i in range(n):
            if state[i] == 0:
                found = visit(i)
                if found:
                    return [self._objectives[k] for k in found]
        return []

    def _kahn(self) -> tuple[int, ...]:
        indegree = [len(p) for p in self._parents_idx]
        order: list[int] = []
        ready = [i for i, d in enumerate(indegree) if d == 0]
        while ready:
            i = min(ready)
            ready.remove(i)
            order.append(i)
            for j in self._children_idx[i]:
                indegree[j] -= 1
                if indegree[j] == 0:
                    ready.append(j)
        return tuple(order)
