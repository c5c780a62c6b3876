"""A pre-registered design's cells over one grid, scored and its looks taken.

An experiment file's designs (:attr:`priqn.experiment.Experiment.designs`) are its
``[[question]]`` tables (``priqn/data/experiments/explain.toml``) or its ``[sequential]``
table, loaded as one unnamed question (``headline.toml``). Each is a sequential design
(:class:`priqn.experiment.SequentialSpec`) with an endpoint, a training budget and its
seeds in look order; a question's comparisons name row *groups* (one policy trained to
different budgets by several rows), the ``[sequential]`` table's name rows. For each
design this module

1. collects one endpoint score per (row or group, seed) at the design's budget
   (:func:`collect`): a cell trained to that budget (``eval/``) or a longer cell's policy
   kept at it (``eval-at<N>/``), a cell an earlier grid trained (``reuse``, or the
   ``[sequential]`` table's ``prior_runs``), checked to train at a commit the design lists
   (and, reused by a row, to train that row's policy);
2. takes its looks with :func:`priqn.analysis.sequential.take_looks` (:func:`take_looks`);
3. says which cells the next looks need (:func:`cells_needed`, :func:`next_cells`).

The reports are :mod:`priqn.analysis.sequential_report` (the ``[sequential]`` table) and
:mod:`priqn.analysis.questions_report` (``[[question]]`` tables).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from priqn.analysis import sequential
from priqn.analysis.load import read_episodes
from priqn.errors import PriqnError
from priqn.experiment import (
    Experiment,
    PolicySpec,
    SequentialSpec,
    cell_dir_name,
    check_code,
    policy_difference,
)
from priqn.run.evaluations import evaluation_complete, evaluation_dir
from priqn.run.folder import RunFolder

ENDPOINT_FLAGS: dict[str, tuple[str, ...]] = {
    "success": ("success",),
    "violation": ("collision", "off_road"),
}
"""Episode flags each endpoint counts (one outcome per episode: :func:`resolve_outcomes`)."""
OUTCOME_RATES: dict[str, tuple[str, ...]] = {
    **ENDPOINT_FLAGS,
    "timeout": ("timeout",),
    "collision": ("collision",),
    "off_road": ("off_road",),
}
"""The endpoints, the one remaining outcome (timeouts: success, violation and timeout sum
to 1) and the violation's two parts, for the reports' descriptive tables and figures (a
design's endpoint is one of :data:`ENDPOINT_FLAGS`)."""


def _rate_by_density(episodes: pd.DataFrame, outcome: str) -> pd.Series:
    hit = episodes[list(OUTCOME_RATES[outcome])].astype(bool).any(axis=1)
    return hit.groupby(episodes["density"]).mean().astype(float)


def endpoint_by_density(eval_dir: str | Path, endpoint: str) -> tuple[pd.Series, int]:
    """An evaluation's ``endpoint`` rate per density (index: density, sorted) and the
    number of episodes behind it, from ``<eval_dir>/episodes.csv``."""
    episodes = read_episodes(eval_dir)
    return _rate_by_density(episodes, endpoint), len(episodes)


def seed_rates(episodes: pd.DataFrame) -> dict[str, float]:
    """Every rate of :data:`OUTCOME_RATES` of one training seed's episodes: its rate per
    density, then the mean over densities (each density weighted equally, nets pooled
    within a density), as the designs score a seed."""
    return {o: float(_rate_by_density(episodes, o).mean()) for o in OUTCOME_RATES}


def outcome_rates(eval_dir: str | Path) -> tuple[dict[str, float], int]:
    """Every rate of :data:`OUTCOME_RATES` for one evaluation (:func:`seed_rates`) and the
    number of episodes (one read of the table)."""
    episodes = read_episodes(eval_dir)
    return seed_rates(episodes), len(episodes)


def rows_of(exp: Experiment, design: SequentialSpec) -> list[str]:
    """What ``design``'s looks count as rows: for the ``[sequential]`` table every row of
    the grid, in file order; for a question its groups, in the order its comparisons name
    them."""
    if not design.name:  # the [sequential] table
        return [pol.name for pol in exp.policies]
    groups: list[str] = []
    for c in design.comparisons:
        groups += [g for g in (c.a, c.b) if g not in groups]
    return groups


COLUMNS: tuple[str, ...] = (
    "policy",
    "seed",
    "train_seed",
    "score",
    "episodes",
    "git_sha",
    "run_dir",
    "evaluation",
)
"""Columns of :func:`collect`: ``policy`` is the row or group, ``seed`` the position in
the design's seed order (what the looks count), ``train_seed`` the training seed."""


def collect(exp: Experiment, design: SequentialSpec) -> pd.DataFrame:
    """The endpoint of every complete cell of ``design`` (columns :data:`COLUMNS`), by row
    (:func:`rows_of`) then position.

    A cell trained at a commit the design does not list, from a dirty checkout, or (a
    reused one) with a config that does not train its row's policy, is refused in one
    line: a design never mixes code versions or policies.
    """
    if design.prior_seeds and not Path(str(design.prior_runs)).is_dir():
        raise PriqnError(
            f"{exp.design_where(design)}.prior_runs: {design.prior_runs} is not a folder here "
            f"({Path.cwd()}); run from the folder it is relative to (the repository root)"
        )
    rows = []
    for group in rows_of(exp, design):
        for position, seed in enumerate(design.seeds):
            pol, run_dir, evaluation = cell_of(exp, design, group, seed)
            folder = RunFolder(run_dir)
            if not evaluation_complete(folder, evaluation):
                continue
            sha = str(folder.meta().get("git_sha", ""))
            _check_cell(exp, design, pol, seed, folder, sha)
            per_density, n = endpoint_by_density(
                evaluation_dir(folder, evaluation), design.endpoint
            )
            rows.append(
                (
                    group,
                    position,
                    seed,
                    float(per_density.mean()),
                    n,
                    sha,
                    sequential.relative_path(run_dir),
                    evaluation,
                )
            )
    return pd.DataFrame(rows, columns=list(COLUMNS))


def cell_of(
    exp: Experiment, design: SequentialSpec, group: str, seed: int
) -> tuple[PolicySpec, Path, str]:
    """Where ``design`` reads ``group``'s seed ``seed``: ``(row, run folder, evaluation)``
    (:meth:`priqn.experiment.Experiment.cell_at`; for the ``[sequential]`` table, whose
    comparisons name rows, the row's own cell or its prior grid's)."""
    if not design.name:  # the [sequential] table
        pol = next(p for p in exp.policies if p.name == group)
        root = Path(str(design.prior_runs)) if seed in design.prior_seeds else exp.runs_dir
        return pol, root / cell_dir_name(group, seed), ""
    where = exp.cell_at(group, seed, design.budget or 0)
    if where is None:  # load_experiment checked every seed exists: unreachable
        raise PriqnError(f"{exp.path}: group {group!r} has no seed {seed}")
    return where


def _check_cell(
    exp: Experiment,
    design: SequentialSpec,
    pol: PolicySpec,
    seed: int,
    folder: RunFolder,
    sha: str,
) -> None:
    """One line when a cell cannot count for ``design`` (its code or its policy)."""
    check_code(design, sha, folder.path, exp.design_where(design))
    if seed in exp.row_seeds(pol) or seed in design.prior_seeds:
        return  # trained by this grid (the sweep built its config from the row) or its prior
    wanted = exp.row_config(pol, seed)
    difference = policy_difference(wanted, folder.config())
    if difference:
        raise PriqnError(
            f"{folder.path}: reused for row {pol.name!r}, but it does not train that row's "
            f"policy: {difference}"
        )


def take_looks(exp: Experiment, design: SequentialSpec) -> tuple[pd.DataFrame, sequential.Looks]:
    """The design's scores (:func:`collect`) and its AdaStop looks
    (:func:`priqn.analysis.sequential.take_looks`)."""
    scores = collect(exp, design)
    by_row = sequential.scores_by_policy(scores, rows_of(exp, design))
    return scores, sequential.take_looks(design, by_row)


def cells_needed(
    exp: Experiment, design: SequentialSpec, scores: pd.DataFrame, result: sequential.Looks
) -> list[tuple[str, int]]:
    """``(row, training seed)`` cells this grid must train for ``design``'s next look (none
    when finished), in seed order: the open rows' positions up to the look not among
    ``scores`` (its complete cells, which ``result``'s looks were taken on), each once; cells
    an earlier grid trained (reused, prior) are never trained here."""
    if result.next_look is None:
        return []
    done = {(g, s) for g, s in scores[["policy", "seed"]].itertuples(index=False)}
    upto = result.next_look * design.seeds_per_look
    out: list[tuple[str, int]] = []
    for position, seed in enumerate(design.seeds[:upto]):
        for group in result.open_rows:
            if (group, position) in done:
                continue
            pol, _, _ = cell_of(exp, design, group, seed)
            if seed in exp.row_seeds(pol) and (pol.name, seed) not in out:
                out.append((pol.name, seed))
    return out


def next_cells(exp: Experiment) -> list[tuple[str, int]]:
    """:func:`cells_needed` of every design of ``exp``, in design order, each cell once."""
    out: list[tuple[str, int]] = []
    for design in exp.designs:
        scores, result = take_looks(exp, design)
        out += [c for c in cells_needed(exp, design, scores, result) if c not in out]
    return out
