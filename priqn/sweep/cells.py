"""Cells: one (policy, seed) of a grid, its run folder, its state and its configs.

A cell is complete iff its run's ``meta.json`` and its ``eval/meta.json`` both say
``"status": "complete"``; the state (a :class:`priqn.run.folder.Status`) is always read from the
run folder (:class:`priqn.run.folder.RunFolder`), never from a sweep's memory. The cell's folder
is ``<runs_dir>/<experiment>/<policy>__seed<k>`` (:func:`priqn.experiment.cell_dir_name`).
"""

from __future__ import annotations

import dataclasses
import fnmatch
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from priqn.agents.config import has_scalar_value
from priqn.config import (
    config_differences,
    from_dict,
    parse_override,
    to_dict,
    toml_value,
    value_pairs,
)
from priqn.errors import PriqnError
from priqn.experiment import (
    Experiment,
    PolicySpec,
    cell_config,
    cell_dir_name,
    policy_difference,
)
from priqn.io import read_json
from priqn.run.evaluations import (
    eval_meta,
    evaluated,
    evaluation_dir,
    recorded_eval_status,
    snapshot_evaluation,
)
from priqn.run.folder import RunFolder, Status
from priqn.run.metrics import read_metrics

# --------------------------------------------------------------------------- cells


@dataclass(frozen=True)
class Cell:
    """One (policy, seed) pair of the grid: one training run and its evaluation."""

    experiment: str
    """Experiment name."""
    policy: str
    """Policy (row) name."""
    seed: int
    """Training seed."""
    run_dir: Path
    """Run folder: ``<runs_dir>/<experiment>/<policy>__seed<seed>``."""
    agent: str
    """Agent name (``priqn train --agent``)."""
    net: str
    """Scenario family (``priqn train --net``)."""
    preset: str
    """Training preset (``priqn train --preset``)."""
    steps: int | None
    """Training budget (``priqn train --steps``); None keeps the preset's."""
    values: tuple[tuple[str, Any], ...]
    """Typed TrainConfig values, ``(dotted key, value)`` pairs in the order they apply
    (:meth:`priqn.experiment.Experiment.row_values`; lists as tuples:
    :func:`priqn.config.value_pairs`)."""
    evaluate: dict[str, Any]
    """EvalConfig fields."""
    source: str
    """Experiment file, named in the child's errors."""
    controls: tuple[str, ...] = ()
    """Control evaluations beside ``eval/``, by name (``near-greedy``, ``near-greedy-eps0.005``:
    ``priqn.evaluation.protocol.control_config``); empty for Pr-IQN rows."""
    snapshots: tuple[int, ...] = ()
    """Budgets whose kept policy is evaluated too, into ``eval-at<N>/`` (``checkpoint.keep_at``)."""
    traffic: str = ""
    """The named traffic setting the cell trains under ('' = the preset's), which its run
    records (:meth:`priqn.experiment.Experiment.row_traffic`)."""

    @property
    def evaluations(self) -> tuple[str, ...]:
        """Every evaluation the cell needs by name: ``""`` (``eval/``), each control, each
        kept snapshot (``at<N>``)."""
        return ("", *self.controls, *map(snapshot_evaluation, self.snapshots))

    @property
    def name(self) -> str:
        """``<experiment>/<policy>__seed<k>``: unique, readable, filesystem-safe."""
        return f"{self.experiment}/{self.dir_name}"

    @property
    def dir_name(self) -> str:
        """``<policy>__seed<k>``: the run folder's name (:func:`priqn.experiment.cell_dir_name`)."""
        return cell_dir_name(self.policy, self.seed)

    def state(self) -> Status:
        """The cell's state, read from its run folder (:func:`cell_state`)."""
        return cell_state(self.run_dir, self.evaluations[1:])

    def is_complete(self) -> bool:
        """Trained and every evaluation (its own and each control) complete."""
        return self.state() == Status.COMPLETE

    def to_spec(self) -> dict[str, Any]:
        """JSON-able description handed to the cell's child process: the fields (``values``
        as ``[key, value]`` lists), ``name``, and the values once more as ``overrides``
        (``KEY=<TOML value>`` strings), the one field a child at an older commit
        (``priqn sweep --code DIR``) reads them from."""
        legacy = [f"{key}={toml_value(value)}" for key, value in self.values]
        return {**to_dict(self), "name": self.name, "overrides": legacy}

    @classmethod
    def from_spec(cls, spec: dict[str, Any]) -> Cell:
        """Inverse of :meth:`to_spec`; a spec from an older driver, with ``overrides`` only,
        has them parsed once."""
        names = {f.name for f in dataclasses.fields(cls)}
        kw = {k: v for k, v in spec.items() if k in names}
        kw["run_dir"] = Path(kw["run_dir"])
        if "values" in kw:
            kw["values"] = value_pairs(kw["values"])
        else:
            where = f"{spec.get('source', 'cell spec')} ({spec.get('policy')})"
            kw["values"] = value_pairs(parse_override(o, where) for o in spec["overrides"])
        kw["controls"] = tuple(kw.get("controls", ()))
        kw["snapshots"] = tuple(kw.get("snapshots", ()))
        return cls(**kw)


def expand(exp: Experiment) -> list[Cell]:
    """All cells of the grid in run order: policies in file order with their seeds in
    file order (``order = "policy"``); seed by seed over every policy, the costliest rows
    of a seed first (``"seed"``); or the costliest cells first over the whole grid
    (``"cost"``: longest-processing-time first, so parallel slots end together). Ties
    keep file order (stable sorts)."""
    e = exp.experiment
    pairs = [(pol, seed) for pol in exp.policies for seed in exp.row_seeds(pol)]
    if e.order in ("seed", "cost"):  # seed by seed; within a seed in file order
        seeds = sorted({seed for _, seed in pairs}, key=_first_index([s for _, s in pairs]))
        rows = (
            sorted(exp.policies, key=lambda pol: -pol.cost) if e.order == "seed" else exp.policies
        )
        pairs = [(pol, seed) for seed in seeds for pol in rows if seed in exp.row_seeds(pol)]
    if e.order == "cost":
        pairs.sort(key=lambda ps: -ps[0].cost)
    return [cell_of(exp, pol, seed) for pol, seed in pairs]


def select(cells: list[Cell], only: Sequence[str], source: Any) -> list[Cell]:
    """The cells whose name matches one of the glob patterns ``only`` (all when empty);
    a one-line error naming ``source`` when none does (``--only``)."""
    if not only:
        return cells
    kept = [c for c in cells if any(fnmatch.fnmatch(c.name, pat) for pat in only)]
    if not kept:
        raise PriqnError(f"--only {' '.join(only)}: matches no cell of {source}")
    return kept


def cell_of(exp: Experiment, pol: PolicySpec, seed: int) -> Cell:
    """Row ``pol`` of ``exp`` trained with ``seed``, as a :class:`Cell`."""
    e = exp.experiment
    return Cell(
        experiment=e.name,
        policy=pol.name,
        seed=seed,
        run_dir=exp.cell_dir(pol.name, seed),
        agent=pol.agent,
        net=e.net,
        preset=e.preset,
        steps=exp.row_steps(pol),
        values=exp.row_values(pol),
        evaluate=dict(exp.evaluate),
        source=str(exp.path),
        controls=tuple(e.controls) if has_scalar_value(pol.agent) else (),
        snapshots=pol.keep_at,
        traffic=exp.row_traffic(pol),
    )


def _first_index(items: list[int]) -> Any:
    """Sort key: the position of an item's first occurrence in ``items``."""
    first = {x: i for i, x in reversed(list(enumerate(items)))}
    return first.__getitem__


def cell_state(run_dir: Path, controls: tuple[str, ...] = ()) -> Status:
    """``complete`` | ``trained`` (an evaluation missing) | ``running`` | ``interrupted``
    (its trainer died) | ``failed`` | ``new``.

    Read from the run folder only: ``meta.json``, ``eval/meta.json`` and, for each of
    ``controls`` (controls and kept snapshots: :attr:`Cell.evaluations`),
    ``eval-<name>/meta.json`` statuses. ``running`` may also be a run
    whose sweep was killed; the next sweep resumes it.
    """
    folder = RunFolder(run_dir)
    run = folder.recorded_status()
    if run == Status.RUNNING and folder.status() == Status.INTERRUPTED:
        return Status.INTERRUPTED  # its trainer died (kill -9, crash): the next sweep resumes it
    if run == Status.COMPLETE:
        return Status.COMPLETE if evaluated(folder, controls) else Status.TRAINED
    if run in (Status.RUNNING, Status.FAILED):
        return Status(run)
    return Status.NEW


def is_complete(run_dir: Path, controls: tuple[str, ...] = ()) -> bool:
    """A cell is complete iff training and every evaluation say ``"status": "complete"``."""
    return cell_state(run_dir, controls) == Status.COMPLETE


# --------------------------------------------------------------------------- one cell (child)


def build_train_config(cell: Cell) -> Any:
    """The cell's resolved :class:`priqn.run.train_config.TrainConfig` (preset, agent, seed,
    net, steps, values), as :meth:`priqn.experiment.Experiment.row_config` builds its row's."""
    return cell_config(
        preset=cell.preset,
        agent=cell.agent,
        seed=cell.seed,
        net=cell.net,
        steps=cell.steps,
        values=cell.values,
        source=cell.source,
        policy=cell.policy,
    )


def build_eval_config(cell: Cell) -> Any:
    """The cell's :class:`priqn.evaluation.protocol.EvalConfig` from the experiment's ``[evaluate]``."""
    from priqn.evaluation.protocol import EvalConfig

    return from_dict(EvalConfig, cell.evaluate, where=f"{cell.source} [evaluate]")


def stale_cells(exp: Experiment) -> dict[str, str]:
    """Complete cells made with another TrainConfig / EvalConfig than the file gives now.

    They are kept (never re-run silently); the value says the first difference.
    ``device`` is ignored (a run may move between machines).
    """
    out = {}
    for c in expand(exp):
        if not c.is_complete():
            continue
        try:
            recorded = to_dict(RunFolder(c.run_dir).config())
        except PriqnError as exc:
            out[c.name] = str(exc)
            continue
        wanted = to_dict(build_train_config(c))
        diff = config_differences(recorded, wanted, ignore=("device",))
        prefix = ""
        if not diff:
            from priqn.evaluation.protocol import eval_config_differences

            recorded = eval_meta(RunFolder(c.run_dir)).get("eval_config") or {}
            diff = eval_config_differences(recorded, to_dict(build_eval_config(c)))
            prefix = "evaluate."
        if diff:
            key, old, new = diff[0]
            out[c.name] = f"{prefix}{key}: {old!r} != {new!r}"
    return out


def validate(exp: Experiment) -> None:
    """Build every cell's TrainConfig and the EvalConfig now, so a typo fails before any
    work; rows of one group must train the same policy
    (:func:`priqn.experiment.policy_difference`), so the first N decisions of a longer
    row are those of a row trained to N."""
    cells = expand(exp)
    configs: dict[str, Any] = {}
    for c in cells:
        if c.policy not in configs:
            configs[c.policy] = build_train_config(c)
    for pol in exp.policies:
        ref = exp.group(pol.group_name)[0]
        if ref.name == pol.name or pol.name not in configs or ref.name not in configs:
            continue
        problem = policy_difference(configs[ref.name], configs[pol.name])
        if problem:
            raise PriqnError(
                f"{exp.path} [[policy]] {pol.name}: rows of group {pol.group_name!r} must train "
                f"one policy, but {problem} (here vs {ref.name!r})"
            )
    if cells:
        build_eval_config(cells[0])


# --------------------------------------------------------------------------- time left


def training_minutes(cell: Cell) -> float:
    """Wall minutes a complete cell's training took (its ``meta.json`` ``wall_s``)."""
    return float(RunFolder(cell.run_dir).meta().get("wall_s") or 0.0) / 60.0


def evaluation_minutes(cell: Cell) -> float:
    """Wall minutes a complete cell's evaluations took (their ``meta.json`` ``wall_s``)."""
    folder = RunFolder(cell.run_dir)
    seconds = 0.0
    for name in cell.evaluations:
        seconds += float(read_json(evaluation_dir(folder, name) / folder.META).get("wall_s") or 0.0)
    return seconds / 60.0


def cell_budget(cell: Cell) -> int | None:
    """A cell's training budget: its ``steps`` or, where the preset's applies, meta.json's
    ``total_steps`` (None if neither)."""
    total = (
        cell.steps if cell.steps is not None else RunFolder(cell.run_dir).meta().get("total_steps")
    )
    return int(total) if isinstance(total, (int, float)) and total > 0 else None


def training_progress(cell: Cell) -> tuple[int, int | None]:
    """``(decisions its metrics.csv has logged, its budget)`` (:func:`cell_budget`)."""
    rows = read_metrics(RunFolder(cell.run_dir).metrics_path)
    return (int(float(rows[-1]["step"])) if rows else 0), cell_budget(cell)


def training_fraction_done(cell: Cell) -> float:
    """Share of a cell's training decisions its ``metrics.csv`` has logged (0 when none or
    when its budget is unknown)."""
    logged, total = training_progress(cell)
    return min(1.0, logged / total) if total else 0.0


PACE_WINDOW: int = 20_000
"""Decisions over which ``--list`` measures a training cell's recent pace."""


def training_minutes_to_go(cell: Cell) -> float | None:
    """Wall minutes a training cell still needs at its recent pace: the decisions its
    ``metrics.csv`` logged over the last :data:`PACE_WINDOW` decisions of its current
    session (``wall_s``; meta.json ``sessions``), per second. None until that session has
    logged two rows a second apart."""
    folder = RunFolder(cell.run_dir)
    total = cell_budget(cell)
    sessions = folder.meta().get("sessions") or []
    since = int(sessions[-1].get("from_step") or 0) if sessions else 0
    rows = [
        (int(float(r["step"])), float(r["wall_s"]))
        for r in read_metrics(folder.metrics_path)
        if r.get("wall_s") not in (None, "") and int(float(r["step"])) > since
    ]
    if not total or len(rows) < 2:
        return None
    last_step, last_wall = rows[-1]
    first_step, first_wall = next((s, w) for s, w in rows if s >= last_step - PACE_WINDOW)
    if last_wall - first_wall < 1 or last_step <= first_step:
        return None
    per_second = (last_step - first_step) / (last_wall - first_wall)
    return max(0, total - last_step) / per_second / 60.0


def cell_progress(cell: Cell, state: Status) -> str:
    """Where a started cell stands, in words (``priqn sweep --list``): the decisions
    logged of its budget while it trains (with the minutes to go at its recent pace,
    :func:`training_minutes_to_go`), or stopped training; the evaluations
    (``eval/``, ``eval-<name>/``) still missing once trained; "" when new or complete."""
    if state in (Status.RUNNING, Status.INTERRUPTED, Status.FAILED):
        logged, total = training_progress(cell)
        if not total:
            return f"{logged:,} decisions"
        eta = training_minutes_to_go(cell) if state == Status.RUNNING else None
        to_go = f", about {eta:,.0f} min of training to go" if eta is not None else ""
        return f"{logged:,}/{total:,} decisions{to_go}"
    if state == Status.TRAINED:
        folder = RunFolder(cell.run_dir)
        missing = [
            evaluation_dir(folder, name).name
            for name in cell.evaluations
            if recorded_eval_status(folder, name) != Status.COMPLETE
        ]
        return "to evaluate: " + ", ".join(missing)
    return ""


@dataclass(frozen=True)
class TimeLeft:
    """Estimated wall time until ``cells`` are complete, ``slots`` at a time."""

    hours: float | None
    """Makespan of the cells left, handed in order to the first free slot; None when a
    row has no complete cell to time it by."""
    minutes_per_cell: dict[str, float]
    """Policy -> median wall minutes of its complete cells in this experiment (for a
    policy in :attr:`scaled`, the estimate from its group's other budgets)."""
    untimed: tuple[str, ...]
    """Policies with cells left but no complete cell yet, nor one of their group's."""
    scaled: tuple[str, ...] = ()
    """Policies timed by their group's complete cells at another budget (reused ones
    included), scaled to their own budget and evaluations."""


def reused_cells(exp: Experiment) -> list[Cell]:
    """The cells rows read from earlier grids (``reuse``), as cells of those rows."""
    return [
        dataclasses.replace(
            cell_of(exp, pol, seed), run_dir=Path(folder) / cell_dir_name(pol.name, seed)
        )
        for pol in exp.policies
        for folder, seeds in pol.reuse.items()
        for seed in seeds
    ]


def _scaled_minutes(
    exp: Experiment, complete: list[Cell], untimed: list[Cell]
) -> dict[str, tuple[float, float]]:
    """Policy -> (whole, evaluation) minutes of a cell of each ``untimed`` policy, from its
    group's ``complete`` cells: the median training minutes per decision times its budget,
    the median minutes per evaluation times its evaluations."""
    import statistics

    group = {pol.name: pol.group_name for pol in exp.policies}
    rates: dict[str, list[tuple[float, float]]] = {}
    for c in complete:
        budget = cell_budget(c)  # not from metrics.csv: a complete cell's is long
        if budget:
            per_eval = evaluation_minutes(c) / len(c.evaluations)
            rates.setdefault(group[c.policy], []).append((training_minutes(c) / budget, per_eval))
    out = {}
    for c in untimed:
        found = rates.get(group[c.policy])
        if c.policy in out or not found or not c.steps:
            continue
        evaluation = statistics.median(e for _, e in found) * len(c.evaluations)
        out[c.policy] = (statistics.median(t for t, _ in found) * c.steps + evaluation, evaluation)
    return out


def time_left(exp: Experiment, cells: list[Cell], slots: int) -> TimeLeft:
    """How long ``cells`` (the ones still to run, in the order the sweep starts them) will
    take at ``slots`` cells at a time, timed by this experiment's complete cells: each
    row's median; a running cell less the share of its training its ``metrics.csv`` has
    logged (also when interrupted: it resumes), a trained one only its row's median
    evaluation. A row with no complete cell is timed by its group's complete cells at
    another budget (reused ones too), scaled by decisions. An estimate from the cells'
    own history, for planning only; a training cell with a measured pace
    (:func:`training_minutes_to_go`) by that pace instead."""
    import heapq
    import statistics

    grid = expand(exp)
    state = {c.name: c.state() for c in grid}  # read once per cell
    complete = [c for c in grid if state[c.name] == Status.COMPLETE]
    done: dict[str, list[tuple[float, float]]] = {}  # policy -> (whole, evaluation) minutes
    for c in complete:
        evaluation = evaluation_minutes(c)
        done.setdefault(c.policy, []).append((training_minutes(c) + evaluation, evaluation))
    per_cell = {p: statistics.median(w for w, _ in m) for p, m in sorted(done.items())}
    per_eval = {p: statistics.median(e for _, e in m) for p, m in done.items()}
    missing = [c for c in cells if c.policy not in per_cell]
    scaled: dict[str, tuple[float, float]] = {}
    if missing:  # timed by their group's other budgets, reused cells included
        sources = complete + [c for c in reused_cells(exp) if c.is_complete()]
        scaled = _scaled_minutes(exp, sources, missing)
        for p, (whole, evaluation) in scaled.items():
            per_cell[p], per_eval[p] = whole, evaluation
    untimed = tuple(dict.fromkeys(c.policy for c in cells if c.policy not in per_cell))
    if untimed:
        return TimeLeft(None, per_cell, untimed, tuple(scaled))

    def minutes_left(c: Cell) -> float:
        whole, evaluation = per_cell[c.policy], per_eval[c.policy]
        if state[c.name] == Status.RUNNING and (to_go := training_minutes_to_go(c)) is not None:
            return to_go + evaluation  # at its own recent pace
        if state[c.name] in (Status.RUNNING, Status.INTERRUPTED):  # the share not yet logged
            return (whole - evaluation) * (1 - training_fraction_done(c)) + evaluation
        if state[c.name] == Status.TRAINED:  # trained, an evaluation missing
            return evaluation
        return whole

    started = (Status.RUNNING, Status.INTERRUPTED)
    running_first = sorted(cells, key=lambda c: state[c.name] not in started)  # stable
    queue = [minutes_left(c) for c in running_first]
    free_at = [0.0] * max(1, slots)  # minutes from now at which each slot is free
    for minutes in queue:
        heapq.heappush(free_at, heapq.heappop(free_at) + minutes)
    return TimeLeft(max(free_at) / 60.0, per_cell, (), tuple(scaled))
