"""An experiment file (``experiments/<name>.toml``) parsed and checked: the grid's schema.

``load_experiment`` reads the ``[experiment]`` table (name, seeds, pool, preset, budget,
overrides), the ``[[policy]]`` rows (agent and Pr-IQN options), ``[evaluate]``,
``[resources]`` and the designs (``[sequential]``, ``[[question]]``, ``[calibration]``);
every mistake is one line naming the file and the key.

Torch-free and below both readers of an experiment: :mod:`priqn.sweep` runs its cells,
:mod:`priqn.analysis` reports on them. Where a cell's run folder lives is spelled here
once (:func:`cell_dir_name`, :meth:`Experiment.cell_dir`).
"""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from priqn import paths
from priqn.agents.config import (
    COMPARATOR_NAMES,
    NORMALISATIONS,
    PREORDER_PRESETS,
    SHIPPED_AGENTS,
    AgentConfig,
    agent_spec,
    resolve_spec,
)
from priqn.config import from_dict, load_toml, parse_override, value_pairs
from priqn.errors import PriqnError, did_you_mean
from priqn.objectives import OUTCOMES
from priqn.run.evaluations import snapshot_evaluation

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")


# --------------------------------------------------------------------------- experiment file


CELL_ORDERS: tuple[str, ...] = ("policy", "seed", "cost")
"""Values of ``[experiment].order``."""


@dataclass(frozen=True)
class ExperimentSpec:
    """The ``[experiment]`` table: what every cell of the grid shares."""

    name: str
    """Experiment name (letters, digits, ``._-``); cells run in ``<runs_dir>/<name>/``."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """Training seeds; every policy is trained once per seed."""
    net: str = "all"
    """Scenario family trained on: ``tjunction``, ``fourway`` or ``all`` (both pools)."""
    preset: str = "default"
    """Training preset (``priqn train --preset``)."""
    steps: int | None = None
    """Training budget in agent decisions per cell; unset keeps the preset's."""
    traffic: str | None = None
    """A named traffic setting for every cell (``priqn train --traffic``; docs/environment.md,
    "Traffic"), applied before ``set``; unset: the preset's traffic."""
    set: tuple[str, ...] = ()
    """TrainConfig overrides ``KEY=VALUE`` (as ``priqn train --set``) for every cell."""
    runs_dir: str = "runs"
    """Folder holding the experiment's run folders (relative to the working directory)."""
    report_dir: str | None = None
    """Where the report goes; unset: ``reports/<name>`` (relative to the working directory)."""
    report_seed: int = 0
    """Seed of the report's bootstrap confidence intervals."""
    description: str = ""
    """Free text: what this grid reproduces."""
    order: str = "policy"
    """Order cells run in: ``policy`` (each row's seeds together), ``seed`` (every row's
    first seed, then every row's second, ...: an interrupted long grid has all rows; within
    a seed the costliest rows first) or ``cost`` (the costliest cells first over the whole
    grid, so parallel slots finish together instead of one long cell running alone)."""
    controls: tuple[str, ...] = ()
    """Control evaluations of the greedy baselines' cells (IQN, Ensemble-IQN, MA-IQN):
    ``near-greedy`` (or ``near-greedy-eps<ε>``) evaluates the same network once more
    acting at random among its near-best actions, into ``eval-<control>/`` (``priqn
    evaluate --acting near-greedy [--acting-eps ε]``); such a cell is complete once its
    controls are too. Pr-IQN cells have none."""

    def __post_init__(self) -> None:
        _check_traffic(self.traffic)
        if self.order not in CELL_ORDERS:
            raise ValueError(f"order: expected one of {', '.join(CELL_ORDERS)}, got {self.order!r}")
        from priqn.evaluation.protocol import EvalConfig, control_config, evaluation_name

        for name in self.controls:
            try:
                canonical = evaluation_name(control_config(EvalConfig(), name))
            except PriqnError as exc:
                raise ValueError(f"controls: {exc}") from None
            if canonical != name:  # the name is the folder the cell's state is read from
                raise ValueError(f"controls: write {name!r} as {canonical!r}")


@dataclass(frozen=True)
class ResourceSpec:
    """The ``[resources]`` table: what one cell needs (local pool size and GPU shares, Ray
    task options)."""

    cpus_per_cell: float = 1.0
    """CPU cores one cell counts for: the local pool runs ``cores // cpus_per_cell`` cells at
    a time, Ray reserves it as ``num_cpus``. 1 for the default preset: a cell is one learner
    thread plus env workers that mostly wait on it, so one cell alone leaves a second core
    partly idle and two cells on 2 cores give 1.56x the decisions per hour of one
    (``priqn bench sweep``; docs/sweeps.md, "Local machine")."""
    gpus_per_cell: float = 0.0
    """GPUs one cell needs: Ray ``num_gpus``; in a local sweep each cell is pinned to its
    share of one GPU (``CUDA_VISIBLE_DEVICES``) and at most ``floor(1 / gpus_per_cell)``
    cells run on each GPU (a whole number k above 1: k GPUs a cell); ignored, with a
    warning, where torch sees no GPU (docs/sweeps.md, "Local machine")."""


@dataclass(frozen=True)
class PolicySpec:
    """One ``[[policy]]`` entry: a row of the results table, trained once per seed."""

    name: str
    """Row name, used in run-folder names (letters, digits, ``._-``)."""
    agent: str
    """Agent to train (``priqn train --agent``: iqn, ensemble-iqn, ma-iqn, pr-iqn)."""
    comparator: str | None = None
    """Pr-IQN: distribution comparison metric."""
    train_preorder: bool | None = None
    """Pr-IQN: bootstrap each head from its optimal subset (preorder used in training)."""
    eps: float | None = None
    """Pr-IQN: comparison threshold epsilon."""
    preorder: str | None = None
    """Pr-IQN: objective preorder, ``total`` | ``partial`` or a preorder TOML file."""
    normalisation: str | None = None
    """Pr-IQN: quantile normalisation, ``zscore`` (the paper) | ``scaled`` (docs/preorder.md)."""
    traffic: str | None = None
    """A named traffic setting for this row's cells (``priqn train --traffic``), applied after
    the experiment's ``set``, before the row's own."""
    set: tuple[str, ...] = ()
    """Further TrainConfig overrides ``KEY=VALUE`` for this row (after the experiment's)."""
    cost: float = 1.0
    """Relative wall time of one cell of this row (scheduling only: ``order = "seed"`` and
    ``"cost"`` start the costliest cells first), e.g. 2.5 for Ensemble-IQN on 2 cores."""
    seeds: tuple[int, ...] | None = None
    """This row's training seeds instead of ``[experiment].seeds`` (rows may differ)."""
    steps: int | None = None
    """This row's training budget in decisions instead of ``[experiment].steps``."""
    keep_at: tuple[int, ...] = ()
    """Budgets at which this row's cells also keep their policy and evaluate it, into
    ``eval-at<N>/`` (``checkpoint.keep_at``); one long run then answers several budgets."""
    group: str | None = None
    """The policy this row trains when several rows train it to different budgets (``iqn``
    at 60k and at 240k): a ``[[question]]`` comparison names the group, and its seeds at a
    budget come from every row of the group that reaches that budget. Rows of one group
    may differ only in seeds, steps, keep_at, cost and reuse, and their ε schedules must
    match in absolute decisions (checked). Unset: the row's own name."""
    reuse: dict[str, tuple[int, ...]] = field(default_factory=dict)
    """Cells of this row an earlier grid trained, read from there and never trained here:
    ``{"results/headline" = [3, 4, ...]}`` (folder relative to the working directory ->
    seeds; the cell is ``<folder>/<row name>__seed<k>``)."""

    def __post_init__(self) -> None:
        _check_traffic(self.traffic)

    @property
    def group_name(self) -> str:
        """:attr:`group`, or the row's own name."""
        return self.group or self.name


def _check_traffic(name: str | None) -> None:
    from priqn.env.traffic import TRAFFIC_SETTINGS

    if name is not None and name not in TRAFFIC_SETTINGS:
        raise ValueError(
            f"traffic: unknown setting {name!r} (valid: {', '.join(TRAFFIC_SETTINGS)})"
            + did_you_mean(name, TRAFFIC_SETTINGS)
        )


SEQUENTIAL_METHODS: tuple[str, ...] = ("adastop",)
"""Values of ``[sequential].method``."""
ENDPOINTS: tuple[str, ...] = ("success", "violation")
"""Values of ``[sequential].endpoint``: ``success`` = one training seed's hold-out success
rate, averaged over the evaluation densities (each density weighted equally);
``violation`` = its safety-violation rate (an episode ending in a collision or off the
road), averaged the same way (lower is better)."""


@dataclass(frozen=True)
class ComparisonSpec:
    """One ``[[sequential.comparison]]``: a pre-registered difference ``a − b`` of the endpoint."""

    name: str
    """What the comparison claims, as the report prints it (``Pr-IQN* > IQN``)."""
    family: str
    """Family it belongs to; each family controls its own family-wise error at ``alpha``."""
    a: str
    """Policy (row) name on the left of the difference."""
    b: str
    """Policy (row) name on the right."""
    paper_difference: float | None = None
    """The paper's reported ``a − b`` on the endpoint, in success-rate units (0.149 = 14.9
    points); unset for a comparison the paper does not make (ours: two-sided, no claim)."""


@dataclass(frozen=True)
class SequentialSpec:
    """One pre-registered group-sequential design over seeds: a ``[[question]]`` table, or
    the ``[sequential]`` table (the one design of its file, unnamed).

    Interim ``k`` (k = 1..K) looks at the first ``interims[k-1]`` seeds (of :attr:`seeds`,
    in look order) of every row or group still in play. Written and committed before any
    of the experiment's own cells train (docs/results.md, "Headline").
    """

    comparisons: tuple[ComparisonSpec, ...]
    """The pre-registered comparisons (``[[sequential.comparison]]``)."""
    method: str = "adastop"
    """Group-sequential test: ``adastop`` (Mathieu et al. 2023, permutation tests with a
    linear α-spending rule and step-down family-wise error control; the ``adastop`` package)."""
    endpoint: str = "success"
    """Per-seed score every comparison uses (:data:`ENDPOINTS`)."""
    interims: tuple[int, ...] = (5, 10, 15, 20)
    """Seeds per row at each interim look: n, 2n, ..., Kn (AdaStop adds n seeds a look)."""
    alpha: float = 0.05
    """Family-wise error rate of each family (two-sided)."""
    beta: float = 0.0
    """AdaStop's power spent on early 'equal' decisions (0: equality only at the last look)."""
    permutations: int = 10000
    """AdaStop's B: random permutations once the exact set is larger."""
    seed: int = 0
    """Seed of AdaStop's permutation draws (numpy RandomState): the decisions replay exactly."""
    prior_runs: str | None = None
    """Folder of an earlier grid whose cells of the same rows supply ``prior_seeds``
    (relative to the working directory), e.g. ``results/table2_cpu``."""
    prior_seeds: tuple[int, ...] = ()
    """Seeds taken from ``prior_runs`` (they come first in the seed order)."""
    code_commits: tuple[str, ...] = ()
    """Git commits a cell may have trained at (its ``meta.json`` ``git_sha``); the report
    refuses any other. Empty: not checked."""
    name: str = ""
    """``[[question]]`` only: the question's name (``budget``), unique in the file; empty
    for the ``[sequential]`` table."""
    question: str = ""
    """``[[question]]`` only: the question in words, as the report prints it."""
    budget: int | None = None
    """The training budget (decisions) the endpoint is read at: a cell trained to it
    (``eval/``) or a longer cell's snapshot kept at it (``eval-at<N>/``). Written in a
    ``[[question]]``; the ``[sequential]`` table's is ``[experiment].steps``."""
    seeds: tuple[int, ...] = ()
    """The training seeds in look order (look k uses the first ``interims[k-1]``); every
    group a comparison names must have each of them at ``budget``. Written in a
    ``[[question]]``; the ``[sequential]`` table's are ``prior_seeds + [experiment].seeds``."""

    def code_problem(self, git_sha: str) -> str | None:
        """Why a cell trained at ``git_sha`` (its ``meta.json`` ``git_sha``) cannot count:
        ``"unlisted"`` (a commit ``code_commits`` lists none of), ``"dirty"`` (a checkout
        with uncommitted changes), or None when it counts. The report refuses such a cell
        and ``priqn sweep --commit`` leaves it uncommitted."""
        if self.code_commits and git_sha.removesuffix("-dirty") not in self.code_commits:
            return "unlisted"
        return "dirty" if git_sha.endswith("-dirty") else None

    @property
    def seeds_per_look(self) -> int:
        """AdaStop's n: seeds added per row at each interim."""
        return self.interims[0]

    def families(self) -> dict[str, list[ComparisonSpec]]:
        """Family name -> its comparisons, in file order."""
        out: dict[str, list[ComparisonSpec]] = {}
        for c in self.comparisons:
            out.setdefault(c.family, []).append(c)
        return out


@dataclass(frozen=True)
class CalibrationSpec:
    """The ``[calibration]`` table: a pre-registered rule that picks one row (a setting) of
    the grid by how near its outcome mix is to a target mix (docs/environment.md, "Traffic").

    A row's mix is, per evaluation density, the share of its hold-out episodes ending in each
    of :data:`OUTCOMES`, averaged over its training seeds (each seed's rate first): 4
    outcomes x the densities. The rule: the row whose mix has the smallest L1 distance (sum
    of absolute differences over all those numbers) to the target; a tie goes to the row
    first in the file. Nothing else (no method's result) enters the choice.
    """

    target: str
    """What the target mix is, as the report prints it (the paper's IQN row, Table II)."""
    densities: tuple[float, ...]
    """The evaluation densities the target gives, in the order of the lists below."""
    success: tuple[float, ...]
    """Target success rate per density."""
    collision: tuple[float, ...]
    """Target collision rate per density."""
    off_road: tuple[float, ...]
    """Target off-road rate per density."""
    timeout: tuple[float, ...]
    """Target timeout rate per density (the paper's: 1 - success - collision - off-road)."""
    code_commits: tuple[str, ...] = ()
    """Git commits the cells may have trained at (``meta.json`` ``git_sha``); the report
    refuses any other, and a dirty checkout. Empty: not checked."""

    def __post_init__(self) -> None:
        n = len(self.densities)
        if n == 0:
            raise ValueError("densities: expected at least one density")
        for name in OUTCOMES:
            values = getattr(self, name)
            if len(values) != n:
                raise ValueError(f"{name}: expected {n} rates (one per density), got {len(values)}")
            if any(not 0.0 <= v <= 1.0 for v in values):
                raise ValueError(f"{name}: expected rates in [0, 1], got {list(values)}")
        for i, d in enumerate(self.densities):
            total = sum(getattr(self, name)[i] for name in OUTCOMES)
            if abs(total - 1.0) > 1e-6:
                raise ValueError(
                    f"density {d}: the four rates sum to {total:.4f}; expected 1 (one outcome "
                    "per episode)"
                )

    def target_mix(self) -> dict[tuple[str, float], float]:
        """``(outcome, density) -> target rate``."""
        return {
            (name, d): getattr(self, name)[i]
            for name in OUTCOMES
            for i, d in enumerate(self.densities)
        }

    def code_problem(self, git_sha: str) -> str | None:
        """As :meth:`SequentialSpec.code_problem`: ``"unlisted"``, ``"dirty"`` or None."""
        return SequentialSpec((), code_commits=self.code_commits).code_problem(git_sha)


def check_code(
    design: SequentialSpec | CalibrationSpec, git_sha: str, cell: Any, where: str
) -> None:
    """One line when ``cell``, trained at ``git_sha``, cannot count for ``design`` (named
    ``where``, e.g. ``<file> [sequential]``): a commit its ``code_commits`` does not list,
    or a checkout with uncommitted changes. The reports and ``priqn sweep --commit`` apply
    it to every cell of a pre-registered design, which never mixes code versions."""
    problem = design.code_problem(git_sha)
    if problem == "unlisted":
        raise PriqnError(
            f"{cell}: trained at commit {git_sha[:12]}, which {where}.code_commits does not "
            "list; a pre-registered design never mixes code versions (retrain it at the "
            "frozen commit)"
        )
    if problem == "dirty":
        raise PriqnError(
            f"{cell}: trained from a checkout with uncommitted changes ({git_sha}); "
            "retrain it from the frozen commit"
        )


_PREORDER_OPTIONS = ("comparator", "train_preorder", "eps", "preorder", "normalisation")

# Policy option -> TrainConfig key (``priqn train --set`` name).
_TRAIN_KEYS = {
    "agent": "agent.name",
    "comparator": "agent.comparator",
    "train_preorder": "agent.train_preorder",
    "eps": "agent.eps",
    "preorder": "agent.preorder",
    "normalisation": "agent.normalisation",
}


@dataclass(frozen=True)
class Experiment:
    """A parsed experiment file."""

    path: Path
    """The TOML file it came from (named in errors)."""
    experiment: ExperimentSpec
    """Shared settings."""
    policies: tuple[PolicySpec, ...]
    """The rows of the grid, in file order."""
    evaluate: dict[str, Any] = field(default_factory=dict)
    """EvalConfig fields (``priqn.evaluation.protocol.EvalConfig``) for every cell."""
    resources: ResourceSpec = ResourceSpec()
    """Per-cell resource needs."""
    designs: tuple[SequentialSpec, ...] = ()
    """The pre-registered sequential designs over the grid, each with its own endpoint,
    budget, seeds and looks: the ``[[question]]`` tables (named; comparisons name row
    groups), or the ``[sequential]`` table as the one unnamed design (comparisons name
    rows; its seeds ``prior_seeds + [experiment].seeds``, its budget ``[experiment].steps``)."""
    calibration: CalibrationSpec | None = None
    """A pre-registered rule choosing one row by its outcome mix (``[calibration]``)."""

    @property
    def sequential(self) -> SequentialSpec | None:
        """The ``[sequential]`` table's design (the one unnamed design), if the file has one."""
        return self.designs[0] if self.designs and not self.designs[0].name else None

    def design_where(self, design: SequentialSpec) -> str:
        """How errors name ``design``: ``<file> [sequential]`` or ``<file> [[question]] <name>``."""
        return f"{self.path} " + (f"[[question]] {design.name}" if design.name else "[sequential]")

    @property
    def code_commits(self) -> tuple[str, ...]:
        """Every commit a design or the calibration lets a cell train at (empty: not checked)."""
        commits = [c for d in self.designs for c in d.code_commits]
        if self.calibration is not None:
            commits += self.calibration.code_commits
        return tuple(dict.fromkeys(commits))

    def code_problem(self, git_sha: str) -> str | None:
        """:meth:`SequentialSpec.code_problem` over :attr:`code_commits` (``"unlisted"``,
        ``"dirty"`` or None); None for a grid without a design or calibration."""
        if not self.designs and self.calibration is None:
            return None
        return SequentialSpec((), code_commits=self.code_commits).code_problem(git_sha)

    def row_seeds(self, policy: PolicySpec) -> tuple[int, ...]:
        """The seeds ``policy``'s row trains here (its own, else ``[experiment].seeds``)."""
        return policy.seeds if policy.seeds is not None else self.experiment.seeds

    def row_steps(self, policy: PolicySpec) -> int | None:
        """``policy``'s training budget (its own, else ``[experiment].steps``; None: the preset's)."""
        return policy.steps if policy.steps is not None else self.experiment.steps

    def row_config(self, policy: PolicySpec, seed: int) -> Any:
        """The :class:`~priqn.run.train_config.TrainConfig` ``policy``'s row trains with ``seed``
        (what ``priqn train`` builds from the preset, the flags and the values; the sweep's
        cells carry the same fields: :func:`cell_config`)."""
        return cell_config(
            preset=self.experiment.preset,
            agent=policy.agent,
            seed=seed,
            net=self.experiment.net,
            steps=self.row_steps(policy),
            values=self.row_values(policy),
            source=self.path,
            policy=policy.name,
        )

    def row_values(self, policy: PolicySpec) -> tuple[tuple[str, Any], ...]:
        """``policy``'s row's typed TrainConfig values, ``(dotted key, value)`` pairs in the
        order they apply: ``[experiment]`` traffic and set, then the row's traffic, options
        (and ``keep_at``) and set (each ``set`` string parsed once)."""
        from priqn.env.traffic import traffic_values

        where = f"{self.path} [experiment].set"
        return value_pairs(
            [
                *traffic_values(self.experiment.traffic),
                *(parse_override(item, where) for item in self.experiment.set),
                *traffic_values(policy.traffic),
                *policy_values(policy, f"{self.path} [[policy]] {policy.name}.set"),
            ]
        )

    def row_traffic(self, policy: PolicySpec) -> str:
        """The named traffic setting ``policy``'s row trains under, as its runs record it:
        the row's own, else the ``[experiment]``'s ('' for none: the preset's traffic)."""
        return policy.traffic or self.experiment.traffic or ""

    def group(self, name: str) -> list[PolicySpec]:
        """The rows of group ``name`` (:attr:`PolicySpec.group_name`), in file order."""
        return [pol for pol in self.policies if pol.group_name == name]

    def cell_at(self, group: str, seed: int, budget: int) -> tuple[PolicySpec, Path, str] | None:
        """Where ``group``'s seed ``seed`` is evaluated at ``budget``: ``(row, run folder,
        evaluation name)`` (``""`` for ``eval/``, ``at<N>`` for a kept snapshot), or None
        when no row of the group has that seed at that budget. A row trained to exactly
        ``budget`` comes before a longer one's snapshot."""
        found = []
        for pol in self.group(group):
            if seed in self.row_seeds(pol):
                run = self.cell_dir(pol.name, seed)
            else:
                runs = [r for r, seeds in pol.reuse.items() if seed in seeds]
                if not runs:
                    continue
                run = Path(runs[0]) / cell_dir_name(pol.name, seed)
            if self.row_steps(pol) == budget:
                found.insert(0, (pol, run, ""))
            elif budget in pol.keep_at:
                found.append((pol, run, snapshot_evaluation(budget)))
        return found[0] if found else None

    @property
    def runs_dir(self) -> Path:
        """``<runs_dir>/<name>``: the folder holding this experiment's run folders."""
        return Path(self.experiment.runs_dir) / self.experiment.name

    @property
    def report_dir(self) -> Path:
        """Where :func:`priqn.sweep.run_sweep` writes the report."""
        return Path(self.experiment.report_dir or Path("reports") / self.experiment.name)

    def cell_dir(self, policy: str, seed: int) -> Path:
        """The run folder of ``policy`` trained with ``seed``: ``<runs_dir>/<name>/<policy>__seed<k>``."""
        return self.runs_dir / cell_dir_name(policy, seed)


def cell_dir_name(policy: str, seed: int) -> str:
    """``<policy>__seed<k>``: the run-folder name of one cell of a grid (unique in the
    experiment's folder, readable, filesystem-safe)."""
    return f"{policy}__seed{seed}"


def cell_dir_parts(name: str) -> tuple[str, int]:
    """The policy and seed of a cell's run-folder name: the inverse of :func:`cell_dir_name`
    (``iqn__seed82`` -> ``("iqn", 82)``)."""
    policy, seed = name.rsplit("__seed", 1)
    return policy, int(seed)


def resolve_experiment_path(name_or_path: str | os.PathLike) -> Path:
    """A path, or a bare name: ``table2`` -> ``./experiments/table2.toml``, else the shipped one."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    if p.suffix == "" and len(p.parts) == 1:
        dirs = paths.search_path(paths.EXPERIMENTS)
        for d in dirs:
            if (d / f"{p.name}.toml").is_file():
                return d / f"{p.name}.toml"
        known = sorted({q.stem for d in dirs for q in d.glob("*.toml")})
        raise PriqnError(
            f"{p}: no such experiment file (known in ./experiments/ and shipped: "
            f"{', '.join(known) or 'none'})" + did_you_mean(p.name, known)
        )
    raise PriqnError(f"{p}: file not found")


def load_experiment(
    path: str | os.PathLike,
    runs_dir: str | os.PathLike | None = None,
    cpus_per_cell: float | None = None,
    gpus_per_cell: float | None = None,
) -> Experiment:
    """Parse and check an experiment file; every mistake is one line naming file and key.

    ``runs_dir`` / ``cpus_per_cell`` / ``gpus_per_cell`` override the file's values.
    """
    p = resolve_experiment_path(path)
    data = load_toml(p)
    _check_sections(data, p)
    exp = _load_experiment_table(data["experiment"], p)
    policies = _load_policies(data.get("policy", []), exp, p)
    evaluate = data.get("evaluate", {})
    if not isinstance(evaluate, dict):
        raise PriqnError(f"{p} [evaluate]: expected a table of EvalConfig fields")
    resources = _load_resources(data.get("resources", {}), p, cpus_per_cell, gpus_per_cell)
    designs: tuple[SequentialSpec, ...] = ()
    if "sequential" in data:
        if "question" in data:
            raise PriqnError(f"{p}: [sequential] and [[question]]: use one or the other")
        designs = (_load_sequential(data["sequential"], exp, policies, p),)
    # Absolute, so Ray workers (whose working directory differs) write to the same place.
    exp = dataclasses.replace(exp, runs_dir=str(Path(runs_dir or exp.runs_dir).absolute()))
    out = Experiment(p, exp, tuple(policies), dict(evaluate), resources, designs)
    if "question" in data:
        out = dataclasses.replace(out, designs=_load_questions(data["question"], out))
    if "calibration" in data:
        out = dataclasses.replace(out, calibration=_load_calibration(data["calibration"], out))
    return out


_SECTIONS = frozenset(
    ("experiment", "policy", "evaluate", "resources", "sequential", "question", "calibration")
)
"""The tables an experiment file may have (``[experiment]`` and ``[[policy]]`` required)."""


def _check_sections(data: dict[str, Any], p: Path) -> None:
    """Only known tables, and an ``[experiment]`` table among them."""
    unknown = sorted(set(data) - _SECTIONS)
    if unknown:
        raise PriqnError(
            f"{p}: unknown section {unknown[0]!r} (valid: {', '.join(sorted(_SECTIONS))})"
        )
    if "experiment" not in data:
        raise PriqnError(f"{p}: missing [experiment] table (name, seeds, net, preset, steps)")


def _load_experiment_table(raw: Any, p: Path) -> ExperimentSpec:
    """Parse and check the ``[experiment]`` table: its name, seeds, steps and overrides."""
    exp = from_dict(ExperimentSpec, raw, where=f"{p} [experiment]")
    _check_name(exp.name, f"{p} [experiment].name")
    if not exp.seeds:
        raise PriqnError(
            f"{p} [experiment].seeds: empty; expected at least one seed, e.g. [0, 1, 2]"
        )
    if len(set(exp.seeds)) != len(exp.seeds):
        raise PriqnError(f"{p} [experiment].seeds: duplicate seeds in {list(exp.seeds)}")
    if any(s < 0 for s in exp.seeds):
        raise PriqnError(f"{p} [experiment].seeds: seeds must be >= 0, got {list(exp.seeds)}")
    if exp.steps is not None and exp.steps <= 0:
        raise PriqnError(f"{p} [experiment].steps: expected a positive integer, got {exp.steps}")
    _check_overrides(exp.set, f"{p} [experiment].set")
    return exp


def _load_resources(
    raw: Any, p: Path, cpus_per_cell: float | None, gpus_per_cell: float | None
) -> ResourceSpec:
    """Parse and check the ``[resources]`` table, with the command line's overrides."""
    res_data = dict(raw)
    for key, value in (("cpus_per_cell", cpus_per_cell), ("gpus_per_cell", gpus_per_cell)):
        if value is not None:
            res_data[key] = value
    resources = from_dict(ResourceSpec, res_data, where=f"{p} [resources]")
    if resources.cpus_per_cell <= 0 or resources.gpus_per_cell < 0:
        raise PriqnError(
            f"{p} [resources]: cpus_per_cell must be > 0 and gpus_per_cell >= 0, "
            f"got {resources.cpus_per_cell} and {resources.gpus_per_cell}"
        )
    return resources


def _load_calibration(raw: Any, exp: Experiment) -> CalibrationSpec:
    """Parse and check the ``[calibration]`` table of ``exp`` (which has no sequential
    design): its densities are the evaluated ones, if ``[evaluate]`` names them."""
    p = exp.path
    if exp.designs:
        raise PriqnError(f"{p}: [calibration] and a sequential design: use one or the other")
    cal = from_dict(CalibrationSpec, raw, where=f"{p} [calibration]")
    wanted = tuple(float(d) for d in exp.evaluate.get("densities", ()))
    if wanted and sorted(wanted) != sorted(cal.densities):
        raise PriqnError(
            f"{p} [calibration].densities: {list(cal.densities)} are not the evaluated "
            f"densities {list(wanted)}"
        )
    return cal


def _load_policies(raw_policies: Any, exp: ExperimentSpec, p: Path) -> list[PolicySpec]:
    """Parse and check the ``[[policy]]`` rows (names, agents, Pr-IQN options, each row's
    seeds / budget / snapshots / reused cells, groups); one line per mistake."""
    if not isinstance(raw_policies, list) or not raw_policies:
        raise PriqnError(f"{p}: expected one or more [[policy]] tables (name, agent, options)")
    policies = []
    seen: set[str] = set()
    for i, raw in enumerate(raw_policies, start=1):
        label = raw.get("name", f"#{i}") if isinstance(raw, dict) else f"#{i}"
        where = f"{p} [[policy]] {label}"
        pol = from_dict(PolicySpec, raw, where=where)
        _check_name(pol.name, f"{where}.name")
        # Shipped, an installed priqn.agents entry point or your package.module:NAME (the
        # experiment file is yours: importing the agent it names is by intent).
        spec = resolve_spec(AgentConfig(name=pol.agent), where=f"{where}.agent")
        if pol.name in seen:
            raise PriqnError(f"{where}.name: duplicate policy name {pol.name!r}")
        seen.add(pol.name)
        if not spec.uses_preorder:
            for opt in _PREORDER_OPTIONS:
                if getattr(pol, opt) is not None:
                    raise PriqnError(
                        f"{where}.{opt}: applies only to agent {_preorder_agents()}, not {pol.agent!r}"
                    )
        for opt, valid in (
            ("comparator", tuple(COMPARATOR_NAMES)),
            ("preorder", PREORDER_PRESETS),
            ("normalisation", NORMALISATIONS),
        ):
            value = getattr(pol, opt)
            custom_preorder = opt == "preorder" and str(value).endswith(".toml")
            if value is not None and value not in valid and not custom_preorder:
                raise PriqnError(
                    f"{where}.{opt}: expected one of {', '.join(map(repr, valid))}"
                    + (" or a preorder .toml file" if opt == "preorder" else "")
                    + f", got {value!r}"
                )
        if pol.eps is not None and pol.eps < 0:
            raise PriqnError(f"{where}.eps: expected a threshold >= 0, got {pol.eps}")
        _check_overrides(pol.set, f"{where}.set")
        _check_row(pol, exp, where)
        policies.append(pol)
    _check_groups(policies, p)
    return policies


def _check_row(pol: PolicySpec, exp: ExperimentSpec, where: str) -> None:
    """A row's own seeds, budget, kept snapshots and reused cells make sense."""
    seeds = pol.seeds if pol.seeds is not None else exp.seeds
    if not seeds or len(set(seeds)) != len(seeds) or any(k < 0 for k in seeds):
        raise PriqnError(f"{where}.seeds: expected distinct seeds >= 0, got {list(seeds)}")
    steps = pol.steps if pol.steps is not None else exp.steps
    if pol.steps is not None and pol.steps <= 0:
        raise PriqnError(f"{where}.steps: expected a positive integer, got {pol.steps}")
    keep = list(pol.keep_at)
    if keep != sorted(set(keep)) or any(b <= 0 or (steps and b >= steps) for b in keep):
        raise PriqnError(
            f"{where}.keep_at: expected ascending budgets below the row's steps ({steps}), got {keep}"
        )
    for folder, reused in pol.reuse.items():
        both = sorted(set(reused) & set(seeds))
        if both:
            raise PriqnError(
                f"{where}.reuse: seed {both[0]} is both trained here and reused from {folder}"
            )


_GROUP_FREE = ("name", "seeds", "steps", "keep_at", "cost", "reuse", "group")
"""PolicySpec fields in which rows of one group may differ."""


def _check_groups(policies: Sequence[PolicySpec], p: Path) -> None:
    """Rows of one group train the same policy: equal in every field but :data:`_GROUP_FREE`
    (the ε schedules are compared in absolute decisions by :func:`priqn.sweep.cells.validate`)."""
    first: dict[str, PolicySpec] = {}
    for pol in policies:
        ref = first.setdefault(pol.group_name, pol)
        for f in dataclasses.fields(PolicySpec):
            if f.name not in _GROUP_FREE and getattr(pol, f.name) != getattr(ref, f.name):
                raise PriqnError(
                    f"{p} [[policy]] {pol.name}.{f.name}: rows of group {pol.group_name!r} train one "
                    f"policy, but {ref.name!r} has {getattr(ref, f.name)!r}"
                )
    group_of_row = {pol.name: pol.group_name for pol in policies}
    for pol in policies:
        if group_of_row.get(pol.group_name, pol.group_name) != pol.group_name:
            raise PriqnError(
                f"{p} [[policy]] {pol.name}.group: {pol.group!r} is a row of group "
                f"{group_of_row[pol.group_name]!r}; a group name names no other group's row"
            )


def _load_questions(raw: Any, exp: Experiment) -> tuple[SequentialSpec, ...]:
    """Parse and check the ``[[question]]`` tables: each a sequential design (as
    ``[sequential]``) with its own name, budget, seeds and looks, over row groups."""
    p = exp.path
    if not isinstance(raw, list) or not raw:
        raise PriqnError(f"{p}: expected one or more [[question]] tables")
    groups = {pol.group_name for pol in exp.policies}
    out: list[SequentialSpec] = []
    for i, rq in enumerate(raw, start=1):
        where = f"{p} [[question]] {rq.get('name', f'#{i}') if isinstance(rq, dict) else f'#{i}'}"
        seq = _parse_design(rq, where, "question.comparison", groups)
        _check_name(seq.name, f"{where}.name")
        if seq.name in {q.name for q in out}:
            raise PriqnError(f"{where}.name: duplicate question name {seq.name!r}")
        if seq.budget is None or seq.budget <= 0:
            raise PriqnError(
                f"{where}.budget: expected the training budget in decisions, e.g. 60000"
            )
        if len(set(seq.seeds)) != len(seq.seeds) or len(seq.seeds) != seq.interims[-1]:
            raise PriqnError(
                f"{where}.seeds: expected {seq.interims[-1]} distinct seeds (the last look), "
                f"got {list(seq.seeds)}"
            )
        for c in seq.comparisons:
            for group in (c.a, c.b):
                missing = [k for k in seq.seeds if exp.cell_at(group, k, seq.budget) is None]
                if missing:
                    raise PriqnError(
                        f"{where}: group {group!r} has no row with seed {missing[0]} at "
                        f"{seq.budget} decisions (a row's seeds or reuse, at its steps or keep_at)"
                    )
        out.append(seq)
    return tuple(out)


def _load_sequential(
    raw: Any, exp: ExperimentSpec, policies: Sequence[PolicySpec], p: Path
) -> SequentialSpec:
    """Parse and check ``[sequential]`` and its ``[[sequential.comparison]]`` tables: a
    one-question design over the grid's rows, unnamed, its seeds in look order
    ``prior_seeds + [experiment].seeds`` and its budget ``[experiment].steps``."""
    where = f"{p} [sequential]"
    seq = _parse_design(raw, where, "sequential.comparison", {pol.name for pol in policies})
    for key in ("name", "question", "budget", "seeds"):
        if getattr(seq, key) != getattr(SequentialSpec(()), key):
            raise PriqnError(f"{where}.{key}: only in a [[question]] table")
    order = list(seq.prior_seeds) + list(exp.seeds)
    if order != list(range(seq.interims[-1])):
        raise PriqnError(
            f"{where}: prior_seeds + [experiment].seeds must be 0, 1, ..., {seq.interims[-1] - 1} "
            f"(one seed per row per slot of the last look), got {order}"
        )
    if seq.prior_seeds and not seq.prior_runs:
        raise PriqnError(
            f"{where}.prior_runs: required with prior_seeds (the earlier grid's folder)"
        )
    return dataclasses.replace(seq, seeds=tuple(order), budget=exp.steps)


def _parse_design(raw: Any, where: str, table: str, names: set[str]) -> SequentialSpec:
    """One sequential design and its comparisons (``a`` / ``b`` among ``names``), with the
    checks every design shares (method, endpoint, looks, alpha, permutations)."""
    if not isinstance(raw, dict):
        raise PriqnError(f"{where}: expected a table")
    raw = dict(raw)
    raw_comparisons = raw.pop("comparison", None)
    if not isinstance(raw_comparisons, list) or not raw_comparisons:
        raise PriqnError(f"{where}: expected one or more [[{table}]] tables (name, family, a, b)")
    comparisons = []
    for i, rc in enumerate(raw_comparisons, start=1):
        cw = f"{where} [[{table}]] #{i}"
        c = from_dict(ComparisonSpec, rc, where=cw)
        for side in ("a", "b"):
            if getattr(c, side) not in names:
                raise PriqnError(
                    f"{cw}.{side}: no [[policy]] named {getattr(c, side)!r} "
                    f"(valid: {', '.join(sorted(names))})"
                )
        if c.a == c.b:
            raise PriqnError(f"{cw}: a and b are the same policy {c.a!r}")
        comparisons.append(c)
    seq = from_dict(SequentialSpec, {**raw, "comparisons": ()}, where=where)
    seq = dataclasses.replace(seq, comparisons=tuple(comparisons))
    if seq.method not in SEQUENTIAL_METHODS:
        raise PriqnError(
            f"{where}.method: expected one of {', '.join(SEQUENTIAL_METHODS)}, got {seq.method!r}"
        )
    if seq.endpoint not in ENDPOINTS:
        raise PriqnError(
            f"{where}.endpoint: expected one of {', '.join(ENDPOINTS)}, got {seq.endpoint!r}"
        )
    n = seq.interims[0] if seq.interims else 0
    if n < 2 or list(seq.interims) != [n * (k + 1) for k in range(len(seq.interims))]:
        raise PriqnError(
            f"{where}.interims: expected equally spaced looks n, 2n, ..., Kn with n >= 2 "
            f"(AdaStop adds n seeds per look), got {list(seq.interims)}"
        )
    if not 0 < seq.alpha < 1 or not 0 <= seq.beta < 1:
        raise PriqnError(f"{where}: expected 0 < alpha < 1 and 0 <= beta < 1")
    if seq.permutations < 100:
        raise PriqnError(f"{where}.permutations: expected at least 100, got {seq.permutations}")
    return seq


BUDGET_KEYS: tuple[str, ...] = (
    "seed",
    "total_steps",
    "device",
    "checkpoint.keep_at",
    "exploration.decay_fraction",
    "exploration.decay_steps",
    "replay.storage",
)
"""TrainConfig keys in which two runs of one policy may differ (the ε decay only as long
as it spans the same absolute decisions; ``replay.storage`` moves the same batches)."""


def policy_difference(a: Any, b: Any) -> str | None:
    """Why two resolved TrainConfigs do not train the same policy (the first difference,
    as ``key is B, not A``), or None: equal but for :data:`BUDGET_KEYS`, with ε decaying
    over the same decisions, so the first N decisions of the longer are the shorter's."""
    from priqn.config import config_differences, to_dict

    decay = [x.exploration.decay_decisions(x.total_steps) for x in (a, b)]
    if decay[0] != decay[1]:
        return (
            f"ε decays over {decay[1]:g} decisions, not {decay[0]:g} "
            "(fix the decay in decisions: exploration.decay_steps)"
        )
    diff = config_differences(to_dict(a), to_dict(b), ignore=BUDGET_KEYS)
    if diff:
        key, old, new = diff[0]
        return f"{key} is {new!r}, not {old!r}"
    return None


def _preorder_agents() -> str:
    """The agents the Pr-IQN options apply to, as ``'pr-iqn'``."""
    return " or ".join(repr(n) for n in SHIPPED_AGENTS if agent_spec(n).uses_preorder)


def _check_name(name: str, where: str) -> None:
    if not _NAME_RE.match(name):
        raise PriqnError(
            f"{where}: {name!r} is not a safe folder name; use letters, digits, '.', '_' or '-'"
        )


def _check_overrides(items: Sequence[str], where: str) -> None:
    for item in items:
        if "=" not in item or not item.split("=", 1)[0].strip():
            raise PriqnError(f'{where}: {item!r} is not KEY=VALUE, e.g. "learner.lr=1e-4"')


def policy_values(policy: PolicySpec, where: str = "set") -> list[tuple[str, Any]]:
    """Typed TrainConfig values ``(dotted key, value)`` a policy's options stand for (and its
    ``keep_at``), then its ``set`` strings parsed once (``where`` names them in errors)."""
    out: list[tuple[str, Any]] = []
    for opt in _PREORDER_OPTIONS:
        value = getattr(policy, opt)
        if value is not None:
            out.append((_TRAIN_KEYS[opt], value))
    if policy.keep_at:
        out.append(("checkpoint.keep_at", tuple(policy.keep_at)))
    return out + [parse_override(item, where) for item in policy.set]


def cell_config(
    preset: str,
    agent: str,
    seed: int,
    net: str,
    steps: int | None,
    values: Sequence[tuple[str, Any]],
    source: str | Path,
    policy: str,
) -> Any:
    """The resolved :class:`~priqn.run.train_config.TrainConfig` of one cell of a grid: the
    one mapping of a row's settings onto :func:`~priqn.run.train_config.resolve_config`,
    shared by :meth:`Experiment.row_config` and :func:`priqn.sweep.cells.build_train_config`
    (``steps`` in decisions, None: the preset's; ``values`` as :meth:`Experiment.row_values`;
    errors name the experiment file ``source`` and the row ``policy``)."""
    from priqn.run.train_config import resolve_config

    return resolve_config(
        preset=preset,
        agent=agent,
        seed=seed,
        net=net,
        steps=steps,
        values=values,
        where=f"{source} ({policy})",
    )
