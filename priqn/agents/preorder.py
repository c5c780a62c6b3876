"""Preorders over objectives, distribution comparators and Algorithm 1 (optimal subsets).

This is the decision core of Pr-IQN: every acting step and every TD target calls
:func:`optimal_subsets`. It implements our reading of Algorithm 1; ``docs/preorder.md``
explains the method and records the benchmark.

Shapes (glossary): ``B`` states, ``N`` objectives (in ``Preorder.objectives`` order),
``K`` quantiles on the fixed grid ``τ_k = (k + 0.5) / K``, ``A`` actions.

>>> po = Preorder.preset("partial")
>>> out = optimal_subsets(quantiles_BNKA, po, comparator="qd", eps=0.2)
>>> out.per_objective  # bool [B, N, A]: optimal subset S_r of every objective
>>> out.leaf           # bool [B, A]: the leaf's subset (virtual global leaf if several)

Relations are ``[B, A, A]`` boolean matrices indexed ``[a, b]``: ``dom[a, b]`` means
"a dominates b", ``domby[a, b]`` "a is dominated by b". ``domby`` is always ``domᵀ``;
both are kept so that every elementwise step reads contiguous memory.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import torch

from priqn.agents.config import COMPARATOR_NAMES, PREORDER_PRESETS
from priqn.config import from_dict, load_toml
from priqn.errors import PriqnError

SELECT_RULES: tuple[str, ...] = ("top-scc", "plain")
"""``top-scc``: docs/preorder.md (never empty); ``plain``: Alg. 1 line 23 literally."""


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
        self._plans: dict[bool, Any] = {}  # static select() plans, see _plan()
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


# ============================================================================ comparators


def quantile_grid(
    num_quantiles: int, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """The fixed selection grid ``τ_k = (k + 0.5) / K``, shape ``[K]``."""
    return (torch.arange(num_quantiles, device=device, dtype=dtype) + 0.5) / num_quantiles


MIN_STD: float = 1e-6
"""Floor of the per-(state, objective) standard deviation used for z-scoring."""


def zscore(quantiles_BNKA: torch.Tensor, min_std: float = MIN_STD) -> torch.Tensor:
    """Per state and objective: ``Z̃ = (Z − mean) / max(std, min_std)`` over all K·A entries.

    Population std. Every comparator scores these normalised quantiles (Z̃ in the
    paper), so ε means the same on every objective. (The comparators below use the
    equivalent affine forms and never build Z̃; this is the literal definition.)
    """
    std, mean = torch.std_mean(quantiles_BNKA, dim=(-2, -1), correction=0, keepdim=True)
    return (quantiles_BNKA - mean) / std.clamp(min=min_std)


@dataclasses.dataclass(frozen=True)
class ComparatorOptions:
    """Options of the comparators; each comparator reads only its own."""

    mv_lambda: float = 0.5
    """MV: weight λ of the standard-deviation penalty (on z-scored quantiles)."""
    cvar_alpha: float = 0.25
    """CVaR: tail level α in (0, 1]; grid quantiles with τ_k ≤ α are averaged."""

    def __post_init__(self) -> None:
        if not math.isfinite(self.mv_lambda):
            raise PriqnError(f"mv_lambda: expected a finite number, got {self.mv_lambda!r}")
        if not 0.0 < self.cvar_alpha <= 1.0:
            raise PriqnError(f"cvar_alpha: expected a number in (0, 1], got {self.cvar_alpha!r}")


# Every score is affine in Z̃ = (Z − m) / s. The comparators get the centred quantiles
# Z − m TRANSPOSED to [B, N, A, K] (K contiguous, so reductions over the actions and
# over the quantiles both run on the fast path) and the clamped std s [B, N, 1], and
# never materialise Z̃: these passes over the largest tensor dominate the cost.


def _score_qd(
    c_BNAK: torch.Tensor, s_BN1: torch.Tensor, options: ComparatorOptions
) -> torch.Tensor:
    """QD (Eq. 3-5): score(a) = −mean_k |Z̃[k, a] − max_b Z̃[k, b]|.

    The ideal is ≥ every entry, so this is (mean_k C[k, a] − mean_k max_b C[k, b]) / s.
    """
    ideal_BN1 = c_BNAK.amax(dim=-2).mean(dim=-1, keepdim=True)
    return (c_BNAK.mean(dim=-1) - ideal_BN1) / s_BN1


def _score_mv(
    c_BNAK: torch.Tensor, s_BN1: torch.Tensor, options: ComparatorOptions
) -> torch.Tensor:
    """Mean-variance: score(a) = mean_k Z̃[k, a] − λ · std_k Z̃[k, a] (population std)."""
    mean_BNA = c_BNAK.mean(dim=-1)
    k = c_BNAK.shape[-1]
    std_BNA = torch.linalg.vector_norm(c_BNAK - mean_BNA.unsqueeze(-1), dim=-1) / math.sqrt(k)
    return (mean_BNA - options.mv_lambda * std_BNA) / s_BN1


def _score_cvar(
    c_BNAK: torch.Tensor, s_BN1: torch.Tensor, options: ComparatorOptions
) -> torch.Tensor:
    """CVaR_α: score(a) = mean of Z̃[k, a] over the grid quantiles with τ_k ≤ α."""
    count = cvar_count(c_BNAK.shape[-1], options.cvar_alpha)
    return c_BNAK[..., :count].mean(dim=-1) / s_BN1


def cvar_count(num_quantiles: int, alpha: float) -> int:
    """How many grid quantiles ``τ_k = (k + 0.5)/K`` satisfy ``τ_k ≤ α`` (error if none)."""
    count = sum(1 for k in range(num_quantiles) if (k + 0.5) / num_quantiles <= alpha)
    if count == 0:
        raise PriqnError(
            f"cvar_alpha={alpha} selects no quantile of the K={num_quantiles} grid "
            f"(smallest τ is {0.5 / num_quantiles:g}); raise cvar_alpha or K"
        )
    return count


ComparatorFn = Callable[[torch.Tensor, torch.Tensor, ComparatorOptions], torch.Tensor]


def _score_mean(
    c_BNAK: torch.Tensor, s_BN1: torch.Tensor, options: ComparatorOptions
) -> torch.Tensor:
    """FSD's score (for display and ties only): mean_k Z̃[k, a]. Its relations are pairwise."""
    return c_BNAK.mean(dim=-1) / s_BN1


COMPARATOR_FUNCTIONS: dict[str, ComparatorFn] = {
    "qd": _score_qd,
    "mv": _score_mv,
    "cvar": _score_cvar,
    "fsd": _score_mean,
}
"""Comparator name → ``fn(Z − mean as [B, N, A, K], std [B, N, 1], options) -> [B, N, A]``.

Scores are of the z-scored quantiles Z̃ = (Z − mean) / std; higher is better. Score
comparators relate a and b by ``score(a) − score(b) > ε``; the comparators in
:data:`PAIRWISE` relate them by their own rule instead (their score is only shown).
"""

if tuple(COMPARATOR_FUNCTIONS) != tuple(COMPARATOR_NAMES):  # one function per name, same order
    raise ImportError(
        f"priqn.agents.preorder.COMPARATOR_FUNCTIONS {tuple(COMPARATOR_FUNCTIONS)} "
        f"!= priqn.agents.config.COMPARATOR_NAMES {tuple(COMPARATOR_NAMES)}"
    )

PAIRWISE: frozenset[str] = frozenset({"fsd"})
"""Comparators whose relation is not an ε-difference of scores (see :func:`fsd_relations`)."""


def _comparator(name: str) -> ComparatorFn:
    try:
        return COMPARATOR_FUNCTIONS[name]
    except (KeyError, TypeError):
        raise PriqnError(
            f"unknown comparator {name!r} (valid: {', '.join(COMPARATOR_FUNCTIONS)})"
        ) from None


def _spread_floor_N1(
    spread_floor: torch.Tensor | Sequence[float] | None, n: int, like: torch.Tensor
) -> torch.Tensor | None:
    """The per-objective spread floor as ``[N, 1]`` on ``like``'s device (None = none)."""
    if spread_floor is None:
        return None
    floor_N = torch.as_tensor(spread_floor, dtype=like.dtype, device=like.device).reshape(-1)
    if floor_N.numel() != n:
        raise PriqnError(
            f"spread_floor: expected one value per objective ({n}), got {floor_N.numel()}"
        )
    if not bool(torch.isfinite(floor_N).all()) or bool((floor_N < 0).any()):
        raise PriqnError("spread_floor: expected finite values >= 0")
    return floor_N.view(n, 1)


def normalised(
    quantiles_BNKA: torch.Tensor,
    spread_floor: torch.Tensor | Sequence[float] | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Centred quantiles ``Z − mean`` as ``[..., N, A, K]`` and the spread ``s`` ``[..., N, 1]``.

    ``Z̃ = (Z − mean) / s``. Paper-literal (``spread_floor=None``): ``s = max(std, 1e-6)``
    per state and objective (population std over all K·A entries). Scale-aware: ``s =
    max(std, 1e-6, spread_floor[i])`` with a per-objective floor (e.g. from
    :class:`RunningScale`), so differences that are tiny against the objective's typical
    spread stay inside ε instead of being blown up by a tiny per-state std.
    Inputs below float32 precision (float16, bfloat16) are normalised in float32.
    """
    q = quantiles_BNKA
    if q.dtype not in (torch.float32, torch.float64):
        q = q.float()
    if q.ndim < 2 or q.shape[-2] < 1 or q.shape[-1] < 1:
        raise PriqnError(f"quantiles: need [..., K, A] with K, A >= 1, got {list(q.shape)}")
    b_shape, (k, a) = q.shape[:-2], q.shape[-2:]
    m_BN11 = q.flatten(-2).mean(dim=-1).view(*b_shape, 1, 1)
    c_BNAK = torch.empty((*b_shape, a, k), dtype=q.dtype, device=q.device)
    torch.sub(q.transpose(-1, -2), m_BN11, out=c_BNAK)
    # Two-pass population std: the norm of the centred values.
    s_BN1 = torch.linalg.vector_norm(c_BNAK.flatten(-2), dim=-1, keepdim=True)
    s_BN1 = (s_BN1 / math.sqrt(k * a)).clamp(min=MIN_STD)
    floor_N1 = _spread_floor_N1(spread_floor, q.shape[-3] if q.ndim >= 3 else 1, q)
    if floor_N1 is not None:
        s_BN1 = torch.maximum(s_BN1, floor_N1)
    return c_BNAK, s_BN1


def comparator_scores(
    quantiles_BNKA: torch.Tensor,
    comparator: str = "qd",
    *,
    mv_lambda: float = 0.5,
    cvar_alpha: float = 0.25,
    spread_floor: torch.Tensor | Sequence[float] | None = None,
) -> torch.Tensor:
    """Scores ``[..., N, A]`` (higher is better) of every action for every objective.

    ``quantiles_BNKA`` is ``[..., N, K, A]``; ``spread_floor`` selects the scale-aware
    normalisation (see :func:`normalised`).
    """
    fn = _comparator(comparator)
    options = ComparatorOptions(mv_lambda=float(mv_lambda), cvar_alpha=float(cvar_alpha))
    c_BNAK, s_BN1 = normalised(quantiles_BNKA, spread_floor)
    return fn(c_BNAK, s_BN1, options)


def fsd_relations(
    c_BAK: torch.Tensor, s_B1: torch.Tensor, eps: torch.Tensor | float
) -> tuple[torch.Tensor, torch.Tensor]:
    """ε-first-order stochastic dominance between every pair of actions of one objective.

    ``c_BAK`` are centred quantiles on the fixed grid, ``s_B1`` the spread (see
    :func:`normalised`), so ``Z̃ = c / s``. With ``d_k = Z̃[k, a] − Z̃[k, b]``:

        dom[a, b]  ⇔  min_k d_k ≥ −ε   and   mean_k d_k > ε

    "no quantile of a is worse than b's by more than ε, and a is better by more than ε
    on average". ``domby`` is ``domᵀ``. ``dom[a, b]`` implies mean Z̃(a) > mean Z̃(b) + ε,
    so the relation is a sub-relation of the strict ε-order of the means (acyclic, and
    never both ways). Pairs whose quantile functions cross by more than ε are left
    incomparable — the distributional information QD throws away (docs/preorder.md).
    """
    z_BAK = c_BAK / s_B1.unsqueeze(-1)
    d_BAAK = z_BAK.unsqueeze(2) - z_BAK.unsqueeze(1)  # [B, a, b, K]
    mean_BAA = d_BAAK.mean(dim=-1)
    worst_BAA = d_BAAK.amin(dim=-1)
    dom_BAA = (mean_BAA > eps) & (worst_BAA >= -eps)
    return dom_BAA, dom_BAA.transpose(-1, -2)


class RunningScale:
    """Per-objective running scale of the return spread, for the scale-aware normalisation.

    ``update(quantiles_BNKA)`` folds in a batch: the per-state population std over the
    K·A entries, averaged over the batch, enters an exponential moving average with
    weight ``momentum`` (the first batch sets it). ``floor()`` is ``fraction × scale``
    ``[N]``, the spread floor :func:`optimal_subsets` takes as ``spread_floor``. Until
    the first update the floor is 0 (= the paper-literal normalisation). Deterministic;
    ``state_dict`` / ``load_state_dict`` let checkpoints carry it.
    """

    def __init__(self, num_objectives: int, momentum: float = 0.01, fraction: float = 1.0) -> None:
        if not 0.0 < momentum <= 1.0:
            raise PriqnError(f"scale momentum: expected a number in (0, 1], got {momentum!r}")
        if not fraction >= 0.0:
            raise PriqnError(f"scale fraction: expected a number >= 0, got {fraction!r}")
        self.momentum = float(momentum)
        self.fraction = float(fraction)
        self.scale_N = torch.zeros(int(num_objectives), dtype=torch.float64)
        self.count = 0

    @torch.no_grad()
    def update(self, quantiles_BNKA: torch.Tensor) -> None:
        q = quantiles_BNKA.detach().to(torch.float64)
        std_BN = torch.std(q.flatten(-2), dim=-1, correction=0)
        batch_N = std_BN.reshape(-1, std_BN.shape[-1]).mean(dim=0).cpu()
        if batch_N.numel() != self.scale_N.numel():
            raise PriqnError(
                f"running scale: expected {self.scale_N.numel()} objectives, got {batch_N.numel()}"
            )
        if self.count == 0:
            self.scale_N = batch_N
        else:
            self.scale_N = (1.0 - self.momentum) * self.scale_N + self.momentum * batch_N
        self.count += 1

    def floor(self) -> torch.Tensor:
        """``fraction × running scale`` ``[N]`` (float64, CPU)."""
        return self.fraction * self.scale_N

    def state_dict(self) -> dict[str, Any]:
        return {"scale": self.scale_N.tolist(), "count": self.count}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        self.scale_N = torch.tensor(state["scale"], dtype=torch.float64)
        self.count = int(state["count"])


# ============================================================================ Algorithm 1


@dataclasses.dataclass(frozen=True)
class OptimalSubsets:
    """Output of :func:`optimal_subsets` (leading ``B`` absent for a single state)."""

    per_objective: torch.Tensor
    """bool ``[B, N, A]``: optimal subset S_r of every objective, N in preorder order."""
    leaf: torch.Tensor
    """bool ``[B, A]``: the leaf's subset; Agg over the leaves when there are several."""
    scores: torch.Tensor
    """float ``[B, N, A]``: comparator scores (higher is better) the relations come from."""
    objectives: tuple[str, ...]
    """Names of the N axis."""

    def subset(self, objective: str) -> torch.Tensor:
        """bool ``[B, A]``: the optimal subset of one objective."""
        if objective not in self.objectives:
            raise PriqnError(
                f"unknown objective {objective!r} (valid: {', '.join(self.objectives)})"
            )
        return self.per_objective[..., self.objectives.index(objective), :]

    def sizes(self) -> dict[str, float]:
        """Mean optimal-subset size |S_r| over the batch per objective, and of the leaf."""
        per_N = self.per_objective.float().sum(dim=-1).reshape(-1, len(self.objectives))
        out = dict(zip(self.objectives, per_N.mean(dim=0).tolist(), strict=True))
        out["leaf"] = float(self.leaf.float().sum(dim=-1).mean())
        return out


def _eps_tensor(
    eps: float | Sequence[float] | Mapping[str, float], po: Preorder, device: torch.device
) -> torch.Tensor:
    names = po.objectives
    if isinstance(eps, Mapping):
        unknown = [k for k in eps if k not in names]
        missing = [n for n in names if n not in eps]
        if unknown or missing:
            raise PriqnError(
                f"eps: the table must give one value per objective ({', '.join(names)}); "
                f"unknown: {', '.join(map(str, unknown)) or '-'}; missing: {', '.join(missing) or '-'}"
            )
        values = [eps[n] for n in names]
    elif isinstance(eps, (int, float)) and not isinstance(eps, bool):
        values = [eps] * len(names)
    elif isinstance(eps, torch.Tensor) and eps.ndim == 0:
        values = [float(eps)] * len(names)
    elif isinstance(eps, (Sequence, torch.Tensor)) and not isinstance(eps, str):
        values = [v.item() if isinstance(v, torch.Tensor) else v for v in eps]
        if len(values) != len(names):
            raise PriqnError(
                f"eps: expected one value per objective ({len(names)}: {', '.join(names)}), "
                f"got {len(values)}"
            )
    else:
        raise PriqnError(f"eps: expected a number, a list or a table of numbers, got {eps!r}")
    for name, v in zip(names, values, strict=True):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v) or v < 0:
            raise PriqnError(f"eps[{name}]: expected a number >= 0 (inf allowed), got {v!r}")
    return torch.tensor([float(v) for v in values], dtype=torch.float64, device=device)


def _transitive_closure(rel_BAA: torch.Tensor) -> torch.Tensor:
    """Reachability by paths of length >= 1: up to ⌈log2(A−1)⌉ squarings of ``R ∨ R·R``.

    After m squarings R holds every path of up to 2**m edges; a simple path has at most
    A − 1. On CPU the loop stops as soon as R stops changing (exact, and the common
    case is 1-2 squarings); on accelerators it runs all squarings to avoid syncs.
    """
    a = rel_BAA.shape[-1]
    r = rel_BAA.to(torch.float32)
    early_exit = r.device.type == "cpu"
    for _ in range(max(a - 2, 0).bit_length()):
        nxt = (torch.matmul(r, r) + r).clamp_(max=1.0)
        if early_exit and torch.equal(nxt, r):
            break
        r = nxt
    return r > 0.5


def select(
    candidates_BA: torch.Tensor,
    dom_BAA: torch.Tensor,
    domby_BAA: torch.Tensor | None = None,
    rule: str = "top-scc",
) -> torch.Tensor:
    """select(C, Dom, DomBy): the actions of C that survive "beaten by" inside C.

    ``beaten[a, b] = DomBy[a, b] ∧ ¬(Dom[a, b] ∧ DomBy[a, b])``: b dominates a and the
    pair is not incomparable (``DomBy`` defaults to ``Domᵀ``). ``top-scc`` keeps a ∈ C
    iff every b ∈ C that beats a through a chain inside C is beaten by a through a chain
    inside C — the top strongly connected components, never empty when C is not.
    ``plain`` keeps ``{a ∈ C : no b ∈ C beats a}`` (Alg. 1 line 23); both agree when
    the relation on C has no cycle.
    """
    if domby_BAA is None:
        domby_BAA = dom_BAA.transpose(-1, -2)
    # Keep only edges INTO C: a path that starts in C then never leaves it, and rows
    # outside C are dropped by the final "& C".
    beaten_BAA = domby_BAA & ~dom_BAA & candidates_BA.unsqueeze(-2)
    if rule == "plain":
        return candidates_BA & ~beaten_BAA.any(dim=-1)
    if rule != "top-scc":
        raise PriqnError(f"unknown select rule {rule!r} (valid: {', '.join(SELECT_RULES)})")
    reach_BAA = _transitive_closure(beaten_BAA)
    escaped_BA = (reach_BAA & ~reach_BAA.transpose(-1, -2)).any(dim=-1)
    return candidates_BA & ~escaped_BA


def _select_threshold(
    candidates_BA: torch.Tensor, scores_BA: torch.Tensor, eps: torch.Tensor
) -> torch.Tensor:
    """select() when every pair of C is undecided by the inherited relations.

    Then "b beats a" is just ``score(b) − score(a) > ε`` (an acyclic relation), and
    a survives iff ``max_{b ∈ C} score(b) − score(a) ≤ ε``. Rounding is monotone, so
    this equals the pairwise test bit for bit, at O(A) instead of O(A²) per state.
    """
    masked_BA = torch.where(candidates_BA, scores_BA, -math.inf)
    best_B1 = masked_BA.amax(dim=-1, keepdim=True)
    return candidates_BA & ~((best_B1 - scores_BA) > eps)


def _check_quantiles(quantiles: Any, po: Preorder) -> torch.Tensor:
    if not isinstance(quantiles, torch.Tensor):
        raise PriqnError(f"quantiles: expected a torch tensor, got {type(quantiles).__name__}")
    if not quantiles.is_floating_point():
        raise PriqnError(f"quantiles: expected a float tensor, got {quantiles.dtype}")
    if quantiles.ndim not in (3, 4):
        raise PriqnError(
            f"quantiles: expected shape [B, N, K, A] or [N, K, A], got {list(quantiles.shape)}"
        )
    n, k, a = quantiles.shape[-3:]
    if n != len(po):
        raise PriqnError(
            f"quantiles: N = {n} objectives in shape {list(quantiles.shape)} but the preorder "
            f"has {len(po)} ({', '.join(po.objectives)})"
        )
    if k < 1 or a < 1:
        raise PriqnError(f"quantiles: need K >= 1 quantiles and A >= 1 actions, got K={k}, A={a}")
    return quantiles


def optimal_subsets(
    quantiles: torch.Tensor,
    po: Preorder | str,
    comparator: str = "qd",
    eps: float | Sequence[float] | Mapping[str, float] = 0.2,
    *,
    mv_lambda: float = 0.5,
    cvar_alpha: float = 0.25,
    select_rule: str = "top-scc",
    check_finite: bool = True,
    spread_floor: torch.Tensor | Sequence[float] | None = None,
) -> OptimalSubsets:
    """Algorithm 1 for a batch: quantiles ``[B, N, K, A]`` → optimal subsets.

    ``quantiles`` are on the fixed grid ``τ_k = (k + 0.5)/K`` (see :func:`quantile_grid`),
    N in ``po.objectives`` order; ``[N, K, A]`` gives outputs without the B axis.
    ``eps`` is the tolerance ε ≥ 0: one number, one per objective, or ``{name: ε}``.
    ``mv_lambda`` / ``cvar_alpha`` are read by the ``mv`` / ``cvar`` comparators only.
    ``select_rule`` is ``"top-scc"`` (docs/preorder.md, never empty) or ``"plain"``
    (Alg. 1 line 23 literally; can be empty in deep DAGs). ``check_finite`` rejects
    NaN/inf quantiles (one device sync). ``spread_floor`` (``[N]``, e.g.
    :meth:`RunningScale.floor`) selects the scale-aware normalisation; None is the
    paper's per-state z-score. ``comparator="fsd"`` relates actions by ε-first-order
    stochastic dominance (:func:`fsd_relations`) instead of a score difference.

    Python loops run only over the N objectives (and the log2 A closure squarings).
    """
    return _optimal_subsets(
        quantiles,
        po,
        comparator,
        eps,
        mv_lambda=mv_lambda,
        cvar_alpha=cvar_alpha,
        select_rule=select_rule,
        check_finite=check_finite,
        dense_only=False,
        spread_floor=spread_floor,
    )


@dataclasses.dataclass(frozen=True)
class _SelectPlan:
    """Static facts about a preorder that let select() skip work, all exact.

    - ``threshold[r]``: r is a tree objective (every ancestor has at most one parent).
      Its S↑ has every pair undecided, so select() is the O(A) threshold rule.
    - ``plain[r]`` / ``agg_plain[r]`` / ``leaf_plain``: the "beaten by" relation that
      select (resp. Agg at r, the virtual leaf) sees on its candidates has no cycle,
      so the top-SCC rule equals the plain rule and the closure is skipped. True when
      the candidates are "clean" (no beats-edge among them; they can only be split by
      the local comparator, whose strict ε-relation orders by score) or, for an Agg,
      when it merges two tree objectives that are roots or children of one tree
      objective (the union of two ε-score relations minus conflicts has no cycle:
      along a cycle each score would have to rise by more than ε on its own edges
      more often than it falls by at most ε on the other's). docs/preorder.md proves it.
    - ``needs[r]``: relation matrices are built (r is below a merge, or an ancestor of
      such an objective, or a leaf/ancestor with several leaves).
    """

    threshold: tuple[bool, ...]
    plain: tuple[bool, ...]
    agg_plain: tuple[bool, ...]
    leaf_plain: bool
    needs: tuple[bool, ...]


def _two_tree_siblings(po: Preorder, idx: Sequence[int], tree: Sequence[bool]) -> bool:
    if len(idx) != 2 or not all(tree[i] for i in idx):
        return False
    p, q = (po._parents_idx[i] for i in idx)
    return (not p and not q) or (len(p) == 1 and p == q)


def _plan(po: Preorder, dense_only: bool) -> _SelectPlan:
    cached = po._plans.get(dense_only)
    if cached is not None:
        return cached
    n = len(po)
    tree = [False] * n
    clean = [False] * n  # S_r has no beats-edge under Dom[r]
    plain = [False] * n
    agg_plain = [False] * n
    for r in po._topo_idx:
        parents = po._parents_idx[r]
        tree[r] = not parents or (len(parents) == 1 and tree[parents[0]])
        if not parents:
            plain[r] = True
        elif len(parents) == 1:
            plain[r] = clean[parents[0]]
        else:
            agg_plain[r] = _two_tree_siblings(po, parents, tree)
            plain[r] = agg_plain[r]  # a plain Agg leaves a clean S↑
        clean[r] = plain[r]
    leaves = po._leaves_idx
    leaf_plain = len(leaves) == 1 or _two_tree_siblings(po, leaves, tree)
    if dense_only:
        tree = [False] * n
        plain = [False] * n
        agg_plain = [False] * n
        leaf_plain = len(leaves) == 1
    needs = [not t for t in tree]
    if len(leaves) > 1:
        for i in leaves:
            needs[i] = True
    for r in reversed(po._topo_idx):  # children before parents: push the need upwards
        if needs[r]:
            for p in po._parents_idx[r]:
                needs[p] = True
    plan = _SelectPlan(tuple(tree), tuple(plain), tuple(agg_plain), leaf_plain, tuple(needs))
    po._plans[dense_only] = plan
    return plan


# long: Algorithm 1 in one batched pass, level by level in topological order, so it reads
# against the paper's pseudo-code; each step is a few tensor lines under its own comment.
def _optimal_subsets(
    quantiles: torch.Tensor,
    po: Preorder | str,
    comparator: str,
    eps: float | Sequence[float] | Mapping[str, float],
    *,
    mv_lambda: float,
    cvar_alpha: float,
    select_rule: str,
    check_finite: bool,
    dense_only: bool,
    spread_floor: torch.Tensor | Sequence[float] | None = None,
) -> OptimalSubsets:
    if not isinstance(po, Preorder):
        po = Preorder.resolve(po)
    quantiles = _check_quantiles(quantiles, po)
    if select_rule not in SELECT_RULES:
        raise PriqnError(f"unknown select rule {select_rule!r} (valid: {', '.join(SELECT_RULES)})")
    single = quantiles.ndim == 3
    q_BNKA = quantiles.unsqueeze(0) if single else quantiles
    device = q_BNKA.device

    fn = _comparator(comparator)
    options = ComparatorOptions(mv_lambda=float(mv_lambda), cvar_alpha=float(cvar_alpha))
    c_BNAK, s_BN1 = normalised(q_BNKA, spread_floor)
    scores_BNA = fn(c_BNAK, s_BN1, options)
    pairwise = comparator in PAIRWISE
    # The shortcuts of _plan assume ε-score relations; pairwise comparators take the
    # dense path (relation matrices everywhere, top-SCC select).
    dense_only = dense_only or pairwise
    # NaN/inf anywhere in a (state, objective) block makes its mean, std and so every
    # score of the block non-finite: checking the small score tensor suffices.
    if check_finite and not bool(torch.isfinite(scores_BNA).all()):
        raise PriqnError(
            "quantiles: contain NaN or inf, or values so large that their spread overflows "
            "(has the network diverged?)"
        )
    eps_N = _eps_tensor(eps, po, device).to(scores_BNA.dtype)
    plan = _plan(po, dense_only)
    needs = plan.needs
    rule_r = ["plain" if ok else select_rule for ok in plan.plain]
    rule_agg = ["plain" if ok else select_rule for ok in plan.agg_plain]
    scores_NBA = scores_BNA.transpose(0, 1).contiguous()  # contiguous rows per objective
    b, n, a = scores_BNA.shape

    # Local relations of the comparator (Eq. 5 with ε), only where matrices are needed.
    local: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}
    rel_idx = [r for r in range(n) if needs[r]]
    if rel_idx and pairwise:
        for r in rel_idx:
            local[r] = fsd_relations(c_BNAK[:, r], s_BN1[:, r], eps_N[r])
    elif rel_idx:
        s_BRA = scores_BNA[:, rel_idx]
        diff_BRAA = s_BRA.unsqueeze(-1) - s_BRA.unsqueeze(-2)  # score(a) − score(b)
        eps_R11 = eps_N[rel_idx].view(-1, 1, 1)
        dom_BRAA = diff_BRAA > eps_R11
        domby_BRAA = diff_BRAA.neg_() > eps_R11  # score(b) − score(a) > ε (negation is exact)
        for j, r in enumerate(rel_idx):
            local[r] = (dom_BRAA[:, j], domby_BRAA[:, j])

    everything_BA = torch.ones(b, a, dtype=torch.bool, device=device)
    dom: dict[int, torch.Tensor] = {}
    domby: dict[int, torch.Tensor] = {}
    subsets: list[torch.Tensor] = [everything_BA] * n
    for r in po._topo_idx:
        parents = po._parents_idx[r]
        # (1) inherit: S↑, Dom↑, DomBy↑
        if not parents:
            s_up_BA = everything_BA
        elif len(parents) == 1:
            s_up_BA = subsets[parents[0]]
        else:  # Agg over the parents' subsets with the inherited relations
            union_BA = subsets[parents[0]]
            for p in parents[1:]:
                union_BA = union_BA | subsets[p]
            s_up_BA = select(union_BA, *_or_relations(parents, dom, domby), rule=rule_agg[r])
        # (2)-(4) undecided pairs take the local relation; the rest is inherited
        if needs[r]:
            local_dom, local_domby = local[r]
            if not parents:
                dom[r], domby[r] = local_dom, local_domby
            else:
                dom_up, domby_up = _or_relations(parents, dom, domby)
                undecided = ~(dom_up | domby_up)
                dom[r] = dom_up | (undecided & local_dom)
                domby[r] = domby_up | (undecided & local_domby)
        # (5) optimal subset
        if plan.threshold[r]:
            subsets[r] = _select_threshold(s_up_BA, scores_NBA[r], eps_N[r])
        else:
            subsets[r] = select(s_up_BA, dom[r], domby[r], rule=rule_r[r])

    leaves = po._leaves_idx
    if len(leaves) == 1:
        leaf_BA = subsets[leaves[0]]
    else:  # the virtual global leaf: Agg over the leaves
        union_BA = subsets[leaves[0]]
        for i in leaves[1:]:
            union_BA = union_BA | subsets[i]
        leaf_rule = "plain" if plan.leaf_plain else select_rule
        leaf_BA = select(union_BA, *_or_relations(leaves, dom, domby), rule=leaf_rule)

    per_objective = torch.stack(subsets, dim=1)
    if single:
        return OptimalSubsets(per_objective[0], leaf_BA[0], scores_BNA[0], po.objectives)
    return OptimalSubsets(per_objective, leaf_BA, scores_BNA, po.objectives)


def _or_relations(
    idx: Sequence[int], dom: Mapping[int, torch.Tensor], domby: Mapping[int, torch.Tensor]
) -> tuple[torch.Tensor, torch.Tensor]:
    dom_or, domby_or = dom[idx[0]], domby[idx[0]]
    for i in idx[1:]:
        dom_or = dom_or | dom[i]
        domby_or = domby_or | domby[i]
    return dom_or, domby_or
