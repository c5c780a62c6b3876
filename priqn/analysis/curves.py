"""Sample-efficiency curves: hold-out success against training decisions, per row.

Two estimators of a training seed's success at a budget, never mixed:

- **periodic** (:data:`PERIODIC`): the in-training evaluation a run logs in its
  ``metrics.csv`` (rows with ``kind == "eval"``: a few hold-out episodes, 6 by default,
  every ``eval_every`` decisions); a seed's point is its success rate over those
  episodes at that step.
- **snapshot** (:data:`SNAPSHOT`): a full hold-out evaluation of a policy (``priqn
  evaluate``): the final one (``eval/``, at the run's ``total_steps``) and each kept
  snapshot's (``eval-at<N>/``, ``checkpoint.keep_at``). A seed's point is its success
  rate averaged over the evaluation densities (each weighted equally), as the endpoint
  of docs/statistics.md.

:func:`curve_points` reads both from run folders (cells are ``(row, seed, run folder)``:
rows of one group trained to different budgets simply share a row name, see
:func:`experiment_cells`); :func:`sample_efficiency` gives, per row, estimator and
budget, the **mean** over training seeds with a 95 % percentile stratified-bootstrap
interval over seeds (rliable's ``get_interval_estimates``, one call per point after
``np.random.seed(seed)``, so a point's interval depends on its own seeds only).

Why the mean and not rliable's IQM: a periodic point is a rate over 6 episodes (7
possible values), so the middle half of the seeds is mostly ties; with 3 seeds rliable's
IQM trims no seed at all (``int(0.25 * 3) = 0``) and *is* the mean; and the verdicts
(claims, sequential designs) are about the mean over seeds, so the curve's final point
is the number they test.

:func:`efficiency` is the one route from cells to a report's sample-efficiency section
(the curve, its rows and notes; drawn by :func:`priqn.analysis.figures.efficiency_figure`):
every report (the grid's, a ``[sequential]`` table's, ``[[question]]`` tables') chooses
only its cells and rows, and writes what it returns.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from priqn.analysis.load import read_episodes
from priqn.errors import PriqnError
from priqn.evaluation.protocol import snapshot_budget
from priqn.run.evaluations import control_evaluations, evaluation_dir, recorded_eval_status
from priqn.run.folder import RunFolder, Status

CURVE_SEED = 0
"""``np.random.seed`` before each rliable call of the sample-efficiency curves (recorded)."""
CURVE_REPS = 2000
"""Bootstrap replications of the sample-efficiency curves' intervals."""

PERIODIC = "periodic"
"""In-training evaluation rows of ``metrics.csv`` (few episodes per point)."""
SNAPSHOT = "snapshot"
"""Full hold-out evaluations: ``eval/`` (final policy) and ``eval-at<N>/`` (kept snapshots)."""
SOURCES = (PERIODIC, SNAPSHOT)

POINT_COLUMNS = ("row", "train_seed", "run", "source", "budget", "success", "episodes")
"""Columns of :func:`curve_points`: one row per (cell, estimator, budget)."""
CURVE_COLUMNS = (
    "row",
    "source",
    "budget",
    "seeds",
    "episodes_min",
    "episodes_max",
    "mean",
    "lo",
    "hi",
)
"""Columns of :func:`sample_efficiency` (``tables/sample_efficiency.csv``): ``seeds`` at
the point, the fewest and most episodes behind one seed's score, ``lo``/``hi`` the 95 %
interval (NaN below 2 seeds)."""


def periodic_points(run: Path) -> pd.DataFrame | str:
    """``budget, success, episodes`` of each in-training evaluation in ``run``'s
    ``metrics.csv``, or a string saying why there are none."""
    path = RunFolder(run).metrics_path
    if not path.is_file():
        return "no metrics.csv"
    try:
        metrics = pd.read_csv(path, low_memory=False)
    except (OSError, ValueError) as exc:
        return f"metrics.csv unreadable ({exc})"
    if not {"kind", "step", "success"} <= set(metrics.columns):
        return "metrics.csv has no kind, step and success columns"
    evals = metrics[metrics["kind"] == "eval"]
    frame = pd.DataFrame(
        {
            "budget": pd.to_numeric(evals["step"], errors="coerce"),
            "success": pd.to_numeric(evals["success"].map(_as_float), errors="coerce"),
        }
    ).dropna()
    if frame.empty:
        return "no in-training evaluation in metrics.csv"
    grouped = frame.groupby("budget", sort=True)["success"]
    out = pd.DataFrame({"success": grouped.mean(), "episodes": grouped.size()}).reset_index()
    return out.astype({"budget": int, "success": float, "episodes": int})


def _as_float(v: Any) -> float:
    if isinstance(v, str):
        return {"true": 1.0, "false": 0.0}.get(v.strip().lower(), float("nan"))
    return float(v)


def evaluation_success(eval_dir: Path) -> tuple[float, int]:
    """A finished evaluation's success rate averaged over its densities (each weighted
    equally) and its number of episodes."""
    episodes = read_episodes(eval_dir)
    per_density = episodes.groupby("density")["success"].mean().astype(float)
    return float(per_density.mean()), len(episodes)


def snapshot_points(run: Path) -> pd.DataFrame | str:
    """``budget, success, episodes`` of ``run``'s complete full evaluations of its own
    policy: ``eval/`` at its ``total_steps`` (meta.json) and every ``eval-at<N>/`` (kept
    snapshot, no control), or a string saying why there are none."""
    folder = RunFolder(run)
    found: list[tuple[int, Path]] = []
    for name in control_evaluations(folder):
        budget, rest = snapshot_budget(name)
        if budget and not rest and recorded_eval_status(folder, name) == Status.COMPLETE:
            found.append((budget, evaluation_dir(folder, name)))
    total = _total_steps(folder)
    if total and recorded_eval_status(folder) == Status.COMPLETE:
        found.append((total, folder.eval_dir))
    if not found:
        return "no complete evaluation with a known budget (meta.json total_steps)"
    rows = [(b, *evaluation_success(d)) for b, d in sorted(found)]
    return pd.DataFrame(rows, columns=["budget", "success", "episodes"])


def _total_steps(folder: RunFolder) -> int:
    """The run's training budget from meta.json (0 when unknown)."""
    try:
        return int(folder.meta().get("total_steps") or 0)
    except (PriqnError, TypeError, ValueError):
        return 0


def curve_points(cells: Iterable[tuple[str, int, Path]]) -> tuple[pd.DataFrame, list[str]]:
    """Every point of every cell ``(row, training seed, run folder)``: a frame with
    :data:`POINT_COLUMNS` (sorted by row order, source, budget, seed) and notes naming
    the cells that lack an estimator, and why."""
    frames, notes, order = [], [], {}
    for row, seed, run in cells:
        order.setdefault(row, len(order))
        for source, read in ((PERIODIC, periodic_points), (SNAPSHOT, snapshot_points)):
            found = read(Path(run))
            if isinstance(found, str):
                what = "in-training" if source == PERIODIC else "full hold-out"
                notes.append(f"{Path(run).name}: {found}, so no {what} evaluation on its curve")
                continue
            frames.append(
                found.assign(row=row, train_seed=int(seed), run=Path(run).name, source=source)
            )
    if not frames:
        return pd.DataFrame(columns=list(POINT_COLUMNS)), notes
    points = pd.concat(frames, ignore_index=True)[list(POINT_COLUMNS)]
    points["_order"] = points["row"].map(order)
    points = points.sort_values(["_order", "source", "budget", "train_seed"], kind="mergesort")
    return points.drop(columns="_order").reset_index(drop=True), notes


def _mean_of(scores_RT: np.ndarray) -> np.ndarray:
    return np.array([scores_RT.mean()])


def sample_efficiency(points: pd.DataFrame, reps: int, seed: int) -> pd.DataFrame:
    """Per row, estimator and budget of ``points`` (:func:`curve_points`): the mean
    success over training seeds and its 95 % stratified-bootstrap interval over seeds
    (``scores_R1``: one score per seed, one task; ``np.random.seed(seed)`` before each
    rliable call). Columns :data:`CURVE_COLUMNS`, rows in ``points``' order."""
    from rliable import library as rly

    rows = []
    keys = ["row", "source", "budget"]
    for (row, source, budget), part in points.groupby(keys, sort=False):
        scores_R1 = part["success"].to_numpy(float)[:, None]
        lo = hi = float("nan")
        if len(scores_R1) >= 2:
            np.random.seed(seed)
            _, interval = rly.get_interval_estimates(
                {"x": scores_R1}, _mean_of, reps=reps, confidence_interval_size=0.95
            )
            lo, hi = (float(v) for v in interval["x"][:, 0])
        rows.append(
            (row, source, int(budget), len(scores_R1))
            + (int(part["episodes"].min()), int(part["episodes"].max()))
            + (float(scores_R1.mean()), lo, hi)
        )
    return pd.DataFrame(rows, columns=list(CURVE_COLUMNS))


def seed_counts(curve: pd.DataFrame, row: str) -> str:
    """``"3 seeds"`` or ``"10–30 seeds"``: the training seeds behind ``row``'s points."""
    n = curve.loc[curve["row"] == row, "seeds"]
    lo, hi = int(n.min()), int(n.max())
    return f"{lo} seed{'s' * (lo != 1)}" if lo == hi else f"{lo}–{hi} seeds"


def experiment_cells(exp: Any) -> list[tuple[str, int, Path]]:
    """``(group, seed, run folder)`` of every existing cell of ``exp``'s rows: its own
    seeds, the cells it reuses from earlier grids and a ``[sequential]`` design's prior
    seeds. Rows of one group
    (:attr:`priqn.experiment.PolicySpec.group_name`) share the group's curve, whatever
    budget each trains to: a 60k row's points and a 240k row's (with its kept snapshots'
    ``eval-at<N>/``) fall on one curve, its seed count changing along it."""
    from priqn.experiment import cell_dir_name

    seq = exp.sequential
    prior = [(seq.prior_runs, seq.prior_seeds)] if seq is not None and seq.prior_seeds else []
    cells = []
    for pol in exp.policies:
        runs = [(s, exp.cell_dir(pol.name, s)) for s in exp.row_seeds(pol)]
        runs += [
            (s, Path(root) / cell_dir_name(pol.name, s))
            for root, seeds in [*prior, *pol.reuse.items()]
            for s in seeds
        ]
        cells += [(pol.group_name, s, run) for s, run in runs if Path(run).is_dir()]
    return cells


def row_kinds(agents: dict[str, str]) -> dict[str, str]:
    """Panel of each row by its agent: ``Pr-IQN variants`` or ``Baselines``."""
    return {
        row: "Pr-IQN variants" if agent == "pr-iqn" else "Baselines"
        for row, agent in agents.items()
    }


def panels(
    rows: Sequence[str], kinds: dict[str, str], per_panel: int = 4
) -> list[tuple[str, list[str]]]:
    """Rows split into small multiples: one group per kind (in first-seen order), a kind
    with more than ``per_panel`` rows cut into balanced consecutive chunks (``title (1/3)``)."""
    by_kind: dict[str, list[str]] = {}
    for row in rows:
        by_kind.setdefault(kinds.get(row, "Rows"), []).append(row)
    out = []
    for kind, mine in by_kind.items():
        n = -(-len(mine) // per_panel)
        for i, chunk in enumerate(np.array_split(np.array(mine, dtype=object), n)):
            out.append((kind if n == 1 else f"{kind} ({i + 1}/{n})", [str(r) for r in chunk]))
    return out


@dataclass(frozen=True)
class Efficiency:
    """A report's sample-efficiency section as data (:func:`efficiency`); nothing written."""

    curve: pd.DataFrame
    """:func:`sample_efficiency`'s table (``tables/sample_efficiency.csv``); empty: no curve."""
    agents: dict[str, str]
    """Row -> agent, every row of the report in its order (the figure's colours and panels)."""
    notes: list[str]
    """The cells that lack an estimator, and why (:func:`curve_points`)."""
    reps: int
    """Bootstrap replications of every point's interval."""
    seed: int
    """``np.random.seed`` before each point's rliable call."""

    @property
    def drawn(self) -> bool:
        """Whether there is a curve to show (else the report says so, or leaves it out)."""
        return len(self.curve) > 0


def efficiency(
    cells: Iterable[tuple[str, int, Path]], agents: Mapping[str, str], reps: int, seed: int
) -> Efficiency:
    """The sample-efficiency section of a report: :func:`sample_efficiency` of every point
    of ``cells`` ``(row, training seed, run folder)`` (:func:`curve_points`), rows in the
    order of ``agents`` (row -> agent, the report's row order: every row of the report,
    curve or not, so each keeps its colour of the report's other figures)."""
    points, notes = curve_points(cells)
    rank = {row: i for i, row in enumerate(agents)}
    points = points.sort_values("row", key=lambda s: s.map(rank), kind="mergesort")
    return Efficiency(sample_efficiency(points, reps, seed), dict(agents), notes, reps, seed)


def reference_row(curve: pd.DataFrame, agents: Mapping[str, str]) -> str | None:
    """The row drawn dotted, for reference, in the panels without it: the IQN row whose
    curve reaches furthest (the first in ``agents``' order among equals: with IQN at 60k
    and at 240k, the one a Pr-IQN* 240k curve is compared with); None without an IQN curve."""
    reach = curve.groupby("row")["budget"].max()
    iqn = [row for row, agent in agents.items() if agent == "iqn" and row in reach.index]
    return max(iqn, key=lambda row: reach[row]) if iqn else None  # max keeps the first of ties
