"""rliable statistics, descriptive: IQM, optimality gap, P(X > Y), performance profiles.

Axes (the choice matters, rliable issue #20: bootstrapping the wrong axis gives CIs
that are too narrow):

- a **run** (rows, R) is one **training seed**: its evaluation runs share one trained
  network and add almost no variance (docs/statistics.md), so they are averaged within
  the seed, never counted as independent runs;
- a **task** (columns, T) is one (density, hold-out net) pair;
- a cell's score is the episode mean of a metric (success → success rate, route
  progress → mean route progress) over that seed's episodes on that task.

The stratified bootstrap resamples training seeds within each task, never episodes or
evaluation runs. With few seeds a bootstrap over them is too narrow (3 seeds: 10
distinct multisets), so these figures describe; verdicts come from
:mod:`priqn.analysis.claims` (Welch intervals and permutation tests over seeds).

rliable 1.2 draws bootstrap indices from numpy's *global* RNG (its ``random_state``
does not reach the bootstrap), so every rliable call below is preceded by
``np.random.seed(seed)``; each policy (and each pair) is bootstrapped in its own
call, so its CI does not depend on which other policies are in the report.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pandas as pd

from priqn.errors import PriqnError

RUN_AXIS: tuple[str, ...] = ("train_seed",)
"""Columns whose combinations form rliable's run axis: one run per training seed."""
SEED_RUN_AXIS: tuple[str, ...] = ("train_seed", "eval_run")
"""The paper's run axis (training seed × evaluation run), which counts a seed's evaluation
runs as independent and so gives intervals too narrow; kept for comparison only."""
TASK_AXIS: tuple[str, ...] = ("density", "net")
"""Columns whose combinations form rliable's task axis."""
SCORE_METRICS: dict[str, str] = {"success": "SR", "route_progress": "RP"}
"""Episode columns scored with rliable (all lie in [0, 1], optimum 1)."""
PAIR_SEPARATOR = ";;"
"""Joins policy labels into rliable's pair keys ``"X;;Y"``."""


def score_matrices(
    episodes: pd.DataFrame,
    metric: str,
    order: list[str],
    run_axis: tuple[str, ...] = RUN_AXIS,
) -> tuple[dict[str, np.ndarray], list[tuple], list[tuple]]:
    """Per-policy ``scores_RT`` matrices of the episode mean of ``metric``.

    Returns ``(scores, runs, tasks)``. ``scores[label]`` has shape ``[R_label, T]``:
    one row per ``run_axis`` value of that policy (default: per training seed, averaged
    over its episodes), sorted; one column per (density, net) task in the order of
    ``tasks``, shared by every policy. ``runs`` is the sorted union of the run keys over
    policies (policies may have different seeds). A policy lacking a task in some run raises.
    """
    cells = (
        episodes.groupby(["label", *run_axis, *TASK_AXIS], sort=True)[metric].mean().astype(float)
    )
    tasks = sorted({k[len(run_axis) + 1 :] for k in cells.index})
    scores: dict[str, np.ndarray] = {}
    runs: set[tuple] = set()
    for label in order:
        table = cells.loc[label].unstack(list(TASK_AXIS))
        table = table.reindex(columns=pd.MultiIndex.from_tuples(tasks, names=list(TASK_AXIS)))
        if table.isna().any().any():
            row, col = np.argwhere(table.isna().to_numpy())[0]
            raise PriqnError(
                f"policy {label!r}: run {table.index[row]} has no episodes on task "
                f"{table.columns[col]}; every run must cover every (density, net)"
            )
        scores[label] = table.to_numpy(dtype=float)
        runs.update(table.index)
    return scores, sorted(runs), tasks


def _iqm_og(scores_RT: np.ndarray) -> np.ndarray:
    from rliable import metrics

    return np.array(
        [metrics.aggregate_iqm(scores_RT), metrics.aggregate_optimality_gap(scores_RT, 1.0)]
    )


def aggregate_estimates(
    scores: dict[str, np.ndarray], reps: int, seed: int, ci_size: float = 0.95
) -> pd.DataFrame:
    """IQM and optimality gap (threshold 1) with stratified-bootstrap CIs.

    Returns one row per policy: ``label, iqm, iqm_lo, iqm_hi, og, og_lo, og_hi``.
    """
    from rliable import library as rly

    rows = []
    for label, scores_RT in scores.items():
        np.random.seed(seed)
        point, interval = rly.get_interval_estimates(
            {label: scores_RT}, _iqm_og, reps=reps, confidence_interval_size=ci_size
        )
        lo_hi = interval[label]
        rows.append(
            {
                "label": label,
                "iqm": float(point[label][0]),
                "iqm_lo": float(lo_hi[0, 0]),
                "iqm_hi": float(lo_hi[1, 0]),
                "og": float(point[label][1]),
                "og_lo": float(lo_hi[0, 1]),
                "og_hi": float(lo_hi[1, 1]),
            }
        )
    return pd.DataFrame(rows)


def mann_whitney_improvement(scores_x_RT: np.ndarray, scores_y_RT: np.ndarray) -> float:
    """rliable's ``metrics.probability_of_improvement``, vectorised (same value).

    Per task: the fraction of (run of X, run of Y) pairs where X scores higher, ties
    counting 1/2 (the Mann-Whitney U statistic over ``R_x * R_y``); then the mean
    over tasks. rliable's version calls scipy once per task and is ~100x slower
    inside a bootstrap.
    """
    x_R1T, y_1RT = scores_x_RT[:, None, :], scores_y_RT[None, :, :]
    per_task_T = (x_R1T > y_1RT).mean(axis=(0, 1)) + 0.5 * (x_R1T == y_1RT).mean(axis=(0, 1))
    return float(per_task_T.mean())


def probability_of_improvement(
    scores: dict[str, np.ndarray], reps: int, seed: int, ci_size: float = 0.95
) -> pd.DataFrame:
    """P(X > Y) for every ordered pair of distinct policies, with bootstrap CIs.

    rliable's definition: the Mann-Whitney probability that a run of X beats a run
    of Y on a task (ties count 1/2), averaged over tasks. Rows: ``x, y, p, lo, hi``.
    The bootstrap (independent per policy, stratified by task) uses
    :func:`mann_whitney_improvement`, the same statistic as rliable's.
    """
    from rliable import library as rly

    rows = []
    for x, y in itertools.permutations(scores, 2):
        key = f"{x}{PAIR_SEPARATOR}{y}"
        np.random.seed(seed)
        point, interval = rly.get_interval_estimates(
            {key: [scores[x], scores[y]]},
            mann_whitney_improvement,
            reps=reps,
            confidence_interval_size=ci_size,
        )
        lo, hi = np.asarray(interval[key]).reshape(-1)[:2]
        rows.append({"x": x, "y": y, "p": float(point[key]), "lo": float(lo), "hi": float(hi)})
    return pd.DataFrame(rows, columns=["x", "y", "p", "lo", "hi"])


def performance_profiles(
    scores: dict[str, np.ndarray],
    taus: np.ndarray,
    reps: int,
    seed: int,
    ci_size: float = 0.95,
) -> pd.DataFrame:
    """Run-score distributions (fraction of (run, task) scores > tau) with CIs.

    Rows: ``label, tau, fraction, lo, hi``.
    """
    from rliable import library as rly

    rows = []
    for label, scores_RT in scores.items():
        np.random.seed(seed)
        profile, ci = rly.create_performance_profile(
            {label: scores_RT}, taus, reps=reps, confidence_interval_size=ci_size
        )
        for tau, frac, lo, hi in zip(taus, profile[label], ci[label][0], ci[label][1], strict=True):
            rows.append(
                {
                    "label": label,
                    "tau": float(tau),
                    "fraction": float(frac),
                    "lo": float(lo),
                    "hi": float(hi),
                }
            )
    return pd.DataFrame(rows, columns=["label", "tau", "fraction", "lo", "hi"])


@dataclasses.dataclass(frozen=True)
class RliableResult:
    """rliable statistics of one metric (see the module docstring for the axes)."""

    metric: str
    """Episode column scored (``success`` or ``route_progress``)."""
    scores: dict[str, np.ndarray]
    """Policy label -> ``scores_RT``."""
    tasks: list[tuple]
    """The T (density, net) tasks, column order of every ``scores_RT``."""
    aggregates: pd.DataFrame
    """IQM / optimality gap with CIs, one row per policy."""
    improvement: pd.DataFrame
    """P(X > Y) with CIs for every ordered pair."""
    profiles: pd.DataFrame
    """Performance profiles with CIs."""
    seed: int
    """The seed given to ``np.random.seed`` before every rliable call."""
    reps: int
    """Bootstrap replications."""


def rliable_statistics(
    episodes: pd.DataFrame,
    metric: str,
    order: list[str],
    reps: int,
    seed: int,
    taus: np.ndarray | None = None,
) -> RliableResult:
    """All rliable statistics of ``metric`` for the policies in ``order``."""
    if reps < 1:
        raise PriqnError(f"bootstrap reps: must be >= 1, got {reps}")
    scores, _, tasks = score_matrices(episodes, metric, order)
    taus = np.linspace(0.0, 1.0, 21) if taus is None else taus
    return RliableResult(
        metric=metric,
        scores=scores,
        tasks=tasks,
        aggregates=aggregate_estimates(scores, reps, seed),
        improvement=probability_of_improvement(scores, reps, seed),
        profiles=performance_profiles(scores, taus, reps, seed),
        seed=seed,
        reps=reps,
    )
