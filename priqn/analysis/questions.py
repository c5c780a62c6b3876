"""Several pre-registered sequential designs over one grid (``[[question]]``), replayed.

An experiment file may hold several questions (``priqn/data/experiments/explain.toml``),
each a sequential design of its own (:class:`priqn.experiment.SequentialSpec` with a name,
an endpoint, a training budget and its seeds in look order), whose comparisons name row
*groups*: one policy trained to different budgets by several rows. For each question this
module

1. collects one endpoint score per (group, seed) at the question's budget
   (:func:`collect`): a cell trained to that budget (``eval/``) or a longer cell's policy
   kept at it (``eval-at<N>/``), or a cell an earlier grid trained (``reuse``), checked to
   train the same policy and at a commit the question lists;
2. replays it with :func:`priqn.analysis.sequential.replay`, the headline's AdaStop
   replay, through a :class:`QuestionView` (the question's groups as rows, its seed
   order as seeds 0, 1, ...);
3. gives each comparison its verdict words (:func:`verdict`) and says which cells the
   next looks need (:func:`next_cells`).

The report is :mod:`priqn.analysis.questions_report`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd

from priqn.analysis import forecast as planning
from priqn.analysis import sequential
from priqn.analysis.load import read_episodes
from priqn.errors import PriqnError
from priqn.experiment import (
    Experiment,
    PolicySpec,
    SequentialSpec,
    check_code,
    policy_difference,
)
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


def outcome_rates(eval_dir: str | Path) -> tuple[dict[str, float], int]:
    """Every rate of :data:`OUTCOME_RATES` for one evaluation, each averaged over the
    densities as the endpoints are, and the number of episodes (one read of the table)."""
    episodes = read_episodes(eval_dir)
    rates = {o: float(_rate_by_density(episodes, o).mean()) for o in OUTCOME_RATES}
    return rates, len(episodes)


@dataclasses.dataclass(frozen=True)
class Row:
    """A group seen as one row of a sequential design (what the replay reads: ``name``)."""

    name: str


@dataclasses.dataclass(frozen=True)
class QuestionView:
    """One question in the shape :func:`priqn.analysis.sequential.replay` reads an
    experiment: ``sequential`` (the design), ``policies`` (its groups as rows)."""

    sequential: SequentialSpec
    policies: tuple[Row, ...]


def view(question: SequentialSpec) -> QuestionView:
    """The question's groups, in the order its comparisons name them."""
    groups: list[str] = []
    for c in question.comparisons:
        groups += [g for g in (c.a, c.b) if g not in groups]
    return QuestionView(question, tuple(Row(g) for g in groups))


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
"""Columns of :func:`collect`: ``policy`` is the group, ``seed`` the position in the
question's seed order (what the replay counts), ``train_seed`` the training seed."""


def collect(exp: Experiment, question: SequentialSpec) -> pd.DataFrame:
    """The endpoint of every complete cell of ``question`` (columns :data:`COLUMNS`).

    A cell trained at a commit the question does not list, from a dirty checkout, or (a
    reused one) with a config that does not train its row's policy, is refused in one
    line: a question never mixes code versions or policies.
    """
    rows = []
    for group in (r.name for r in view(question).policies):
        for position, seed in enumerate(question.seeds):
            where = exp.cell_at(group, seed, question.budget)
            if where is None:  # load_experiment checked every seed exists: unreachable
                raise PriqnError(f"{exp.path}: group {group!r} has no seed {seed}")
            pol, run_dir, evaluation = where
            folder = RunFolder(run_dir)
            if not folder.evaluation_complete(evaluation):
                continue
            sha = str(folder.meta().get("git_sha", ""))
            _check_cell(exp, question, pol, seed, folder, sha)
            per_density, n = endpoint_by_density(
                folder.evaluation_dir(evaluation), question.endpoint
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


def _check_cell(
    exp: Experiment,
    question: SequentialSpec,
    pol: PolicySpec,
    seed: int,
    folder: RunFolder,
    sha: str,
) -> None:
    """One line when a cell cannot count for ``question`` (its code or its policy)."""
    check_code(question, sha, folder.path, f"{exp.path} [[question]] {question.name}")
    if seed in exp.row_seeds(pol):
        return  # trained by this grid: the sweep built its config from the row
    wanted = exp.row_config(pol, seed)
    difference = policy_difference(wanted, folder.config())
    if difference:
        raise PriqnError(
            f"{folder.path}: reused for row {pol.name!r}, but it does not train that row's "
            f"policy: {difference}"
        )


def replay(exp: Experiment, question: SequentialSpec) -> tuple[pd.DataFrame, sequential.Replay]:
    """The question's scores and its AdaStop replay (:func:`sequential.replay`)."""
    scores = collect(exp, question)
    return scores, sequential.replay(view(question), scores)


def verdict(question: SequentialSpec, result: sequential.Replay, comparison: Any) -> str:
    """The pre-registered verdict words (explain.toml, "Questions and verdict words"):
    the headline's for a success comparison; for a violation rate (lower is better, no
    paper difference) ``a violates more`` / ``a violates less`` / ``no difference
    found at N seeds``."""
    return reword(question, comparison, sequential.verdict(view(question), result, comparison))


def reword(question: SequentialSpec, comparison: Any, word: str) -> str:
    """A verdict word of :func:`priqn.analysis.sequential.verdict` in the question's own
    words: for a violation rate without a paper difference, ``a better`` is ``a violates
    more`` and ``a worse`` ``a violates less``."""
    if question.endpoint != "violation" or comparison.paper_difference is not None:
        return word
    return {"a better": "a violates more", "a worse": "a violates less"}.get(word, word)


def forecast_scenarios(question: SequentialSpec) -> tuple[str, ...]:
    """The :data:`priqn.analysis.forecast.SCENARIOS` that apply to ``question``: ``paper``
    only where a comparison has a paper difference."""
    if any(c.paper_difference is not None for c in question.comparisons):
        return planning.SCENARIOS
    return ("observed",)


def forecast(
    question: SequentialSpec,
    scores: pd.DataFrame,
    sims: int,
    seed: int = 0,
    on_sim: Callable[[], None] | None = None,
) -> pd.DataFrame:
    """:func:`priqn.analysis.forecast.forecast` of one question from its complete cells'
    ``scores`` (:func:`collect`), in the question's verdict words, over
    :func:`forecast_scenarios`. Planning only. A one-line PriqnError when a group has
    fewer than two complete seeds (no spread to draw from)."""
    table = planning.forecast(
        view(question),
        scores,
        sims=sims,
        seed=seed,
        on_sim=on_sim,
        scenarios=forecast_scenarios(question),
    )
    by_name = {c.name: c for c in question.comparisons}
    table["verdict"] = [
        reword(question, by_name[name], word)
        for name, word in zip(table["comparison"], table["verdict"], strict=True)
    ]
    return table


def next_cells(exp: Experiment) -> list[tuple[str, int]]:
    """``(row, training seed)`` cells this grid must train for the next look of every open
    question, in question then seed order, each once (reused cells are never trained)."""
    out: list[tuple[str, int]] = []
    for question in exp.questions:
        scores, result = replay(exp, question)
        if result.next_look is None:
            continue
        done = {(g, s) for g, s in scores[["policy", "seed"]].itertuples(index=False)}
        upto = result.next_look * question.seeds_per_look
        for position, seed in enumerate(question.seeds[:upto]):
            for group in result.open_rows:
                if (group, position) in done:
                    continue
                pol, _, _ = exp.cell_at(group, seed, question.budget)
                if seed in exp.row_seeds(pol) and (pol.name, seed) not in out:
                    out.append((pol.name, seed))
    return out
