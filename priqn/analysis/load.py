"""Load every evaluated run under a folder into one tidy episode table.

Mixed inputs are refused, never averaged: runs evaluated on different hold-out sets
(manifest hashes differ) or with different evaluation settings, two runs claiming
the same (policy, training seed), one label naming two configurations, or runs
that were trained but not (fully) evaluated all raise a one-line
:class:`~priqn.errors.PriqnError`.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pandas as pd

from priqn.agents.labels import CONFIG_COLUMNS, PolicyLabel, at_budget, budget_text
from priqn.errors import PriqnError
from priqn.evaluation.protocol import (
    episode_columns,
    is_family_evaluation,
    is_nets_evaluation,
    is_traffic_evaluation,
    limit_of,
    snapshot_budget,
)
from priqn.io import read_json
from priqn.objectives import OBJECTIVES, names_in_columns
from priqn.run.episodes import resolve_outcomes
from priqn.run.evaluations import control_evaluations, evaluation_dir, recorded_eval_status
from priqn.run.folder import RunFolder, Status
from priqn.run.session import resumed_at

SORT_COLUMNS: tuple[str, ...] = ("label", "train_seed", "eval_run", "net", "density", "episode")
"""Canonical row order of the loaded table (so every statistic sees the same order)."""

EVAL_SETTINGS: tuple[str, ...] = (
    "family",
    "densities",
    "eval_runs",
    "episodes_per_cell",
    "seed",
    "commands",
    "max_episode_steps",
)
"""EvalConfig fields that must agree between runs compared in one report."""


@dataclasses.dataclass(frozen=True)
class RunInfo:
    """One evaluated run as found on disk."""

    name: str
    """Run folder name."""
    path: Path
    """Run folder."""
    holdout_hash: str
    """Hold-out manifest hash the run was evaluated on."""
    eval_config: dict[str, Any]
    """The recorded EvalConfig."""
    label: str
    """Policy-configuration label."""
    train_seed: int
    """Training seed."""
    eval_dir: str = "eval"
    """The evaluation folder read (``eval``, or a control such as ``eval-near-greedy``)."""


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """Everything a report needs from a runs folder."""

    episodes: pd.DataFrame
    """One row per episode (columns of ``priqn.evaluation.protocol.EPISODE_COLUMNS``), sorted."""
    runs: tuple[RunInfo, ...]
    """The evaluated runs, sorted by name."""
    holdout_hash: str
    """The single hold-out manifest hash every run was evaluated on."""
    eval_config: dict[str, Any]
    """The shared evaluation settings."""
    left_out: tuple[str, ...] = ()
    """Run folders left out because their evaluation is not complete (``partial=True``)."""


def read_episodes(eval_dir: str | Path, resolve: bool = True, text: bool = False) -> pd.DataFrame:
    """``<eval_dir>/episodes.csv``, the one reader of an evaluation's episode table: one
    outcome per episode (:func:`priqn.run.episodes.resolve_outcomes`), or with ``resolve``
    False the flags as written; ``text``: every cell as the exact text written (empty
    cells as ``""``; for comparing runs bit for bit, never resolved). An unreadable table
    is one line naming it."""
    episodes_csv = Path(eval_dir) / RunFolder.EVAL_EPISODES
    try:
        if text:
            return pd.read_csv(episodes_csv, dtype=str, keep_default_na=False)
        frame = pd.read_csv(episodes_csv)
        return resolve_outcomes(frame) if resolve else frame
    except (OSError, ValueError, KeyError) as exc:
        raise PriqnError(f"{episodes_csv}: unreadable episode table ({exc})") from None


def find_run_dirs(runs_dir: str | Path) -> list[Path]:
    """Run folders in ``runs_dir`` (a folder with ``config.toml`` or ``eval/``), sorted.

    ``runs_dir`` may itself be one run folder.
    """
    root = Path(runs_dir)
    if not root.is_dir():
        raise PriqnError(f"{root}: no such folder; expected a folder of runs (e.g. runs/)")

    def is_run(p: Path) -> bool:
        return RunFolder(p).is_run() or RunFolder(p).has_evaluation()

    if is_run(root):
        return [root]
    return sorted(p for p in root.iterdir() if p.is_dir() and is_run(p))


def list_evaluations(
    run_dirs: list[Path], nets: bool
) -> tuple[list[tuple[str, Path, Path]], list[str]]:
    """``(complete, unfinished)`` evaluations of ``run_dirs``: ``(name, run, eval_dir)`` of
    each complete one, the names of the rest. A name is ``<run>`` for ``eval/`` and
    ``<run>/eval-<name>`` for any other folder. ``nets``: only evaluations on other nets
    (``eval-nets-*``, reported apart by :mod:`priqn.analysis.generalisation`); otherwise
    ``eval/`` and its controls."""
    complete: list[tuple[str, Path, Path]] = []
    unfinished: list[str] = []
    for run in run_dirs:
        folder = RunFolder(run)
        names = [
            c
            for c in control_evaluations(folder)
            if is_nets_evaluation(c) == nets
            and not limit_of(c)  # limits: priqn report --horizon
            and not is_family_evaluation(c)  # other families (eval-family-<name>/): apart
            and not is_traffic_evaluation(c)  # other traffic (eval-traffic-<name>/): apart
        ]
        for control in names if nets else ["", *names]:
            eval_dir = evaluation_dir(folder, control)
            name = f"{run.name}/{eval_dir.name}" if control else run.name
            if recorded_eval_status(folder, control) == Status.COMPLETE:
                complete.append((name, run, eval_dir))
            else:
                unfinished.append(name)
    return complete, unfinished


def load_evaluation(runs_dir: str | Path, partial: bool = False) -> Evaluation:
    """Load and cross-check every evaluated run under ``runs_dir``.

    ``partial``: leave out runs whose evaluation is not complete (a grid still running)
    and name them in ``Evaluation.left_out``, instead of refusing.
    """
    root = Path(runs_dir)
    run_dirs = find_run_dirs(root)
    if not run_dirs:
        raise PriqnError(
            f"{root}: no runs here; train with 'priqn train' and evaluate with 'priqn evaluate'"
        )
    # Every evaluation of every run: its own (eval/) and any control (eval-<name>/), each
    # named like "<run>" or "<run>/eval-<name>" and reported as its own policy row.
    evaluations, unevaluated = list_evaluations(run_dirs, nets=False)
    if unevaluated and not partial:
        shown = ", ".join(unevaluated[:5]) + (" ..." if len(unevaluated) > 5 else "")
        raise PriqnError(
            f"{root}: {len(unevaluated)} of {len(evaluations) + len(unevaluated)} evaluations not complete: {shown}; "
            f"run 'priqn evaluate {root}' first, or report the evaluated ones with --partial"
        )
    if not evaluations:
        raise PriqnError(f"{root}: none of its {len(unevaluated)} runs is fully evaluated yet")

    frames, infos = [], []
    for name, run, eval_dir in evaluations:
        frame, info = read_evaluation(name, run, eval_dir)
        frames.append(frame)
        infos.append(info)

    _check_same(
        infos, "holdout_hash", lambda i: i.holdout_hash, "evaluated on different hold-out sets"
    )
    for key in EVAL_SETTINGS:
        _check_same(
            infos, key, lambda i, k=key: i.eval_config.get(k), f"evaluated with different {key}"
        )

    episodes = resolve_outcomes(pd.concat(frames, ignore_index=True))
    _check_policies(episodes)
    episodes = episodes.sort_values(list(SORT_COLUMNS), kind="mergesort").reset_index(drop=True)
    return Evaluation(
        episodes=episodes,
        runs=tuple(infos),
        holdout_hash=infos[0].holdout_hash,
        eval_config=infos[0].eval_config,
        left_out=tuple(unevaluated),
    )


def read_evaluation(
    name: str, run: Path, eval_dir: Path, reference: bool = False
) -> tuple[pd.DataFrame, RunInfo]:
    """One finished evaluation folder: its episode table (``run`` column set to ``name``,
    columns of ``EPISODE_COLUMNS``) and its :class:`RunInfo`; a one-line error for a table
    that is unreadable, lacks a column, is empty or disagrees with its ``meta.json``, and
    for a reference driver's evaluation (``priqn evaluate --reference``) read as a run's or
    the other way round (``reference``)."""
    meta_path = eval_dir / RunFolder.META
    meta = read_json(meta_path)
    if bool(meta.get("reference")) != reference:
        raise PriqnError(
            f"{meta_path}: the {meta['reference']!r} reference driver's evaluation, not a run's; "
            f"report it with 'priqn report RUNS --reference {run}', not among the runs"
            if meta.get("reference")
            else f"{meta_path}: a run's evaluation, not a reference driver's "
            "('priqn evaluate --reference sumo|random --out DIR' makes one)"
        )
    csv = eval_dir / RunFolder.EVAL_EPISODES
    frame = read_episodes(eval_dir, resolve=False)  # resolved once all are concatenated
    # The default columns, or those of the run's own objectives (env.objectives).
    columns = episode_columns(names_in_columns(list(frame.columns)) or OBJECTIVES)
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise PriqnError(f"{csv}: missing column {missing[0]!r}; re-run 'priqn evaluate --force'")
    if frame.empty:
        raise PriqnError(f"{csv}: no episodes; re-run 'priqn evaluate --force {run}'")
    for column in ("holdout_hash", "label", "train_seed"):
        if frame[column].nunique(dropna=False) != 1:
            raise PriqnError(f"{csv}: column {column!r} is not constant within one run")
    holdout = str(meta.get("holdout_hash"))
    if str(frame["holdout_hash"].iloc[0]) != holdout:
        raise PriqnError(f"{csv}: holdout_hash differs from {meta_path}")
    budget, _ = snapshot_budget(eval_dir.name.removeprefix(f"{RunFolder.EVAL}-"))
    if budget and eval_dir.name != RunFolder.EVAL:  # a kept snapshot: its budget is in its row
        frame["label"] = at_budget(PolicyLabel.from_row(frame.iloc[0]), budget).render()
    frame["run"] = name
    info = RunInfo(
        name=name,
        path=run,
        holdout_hash=holdout,
        eval_config=dict(meta.get("eval_config") or {}),
        label=str(frame["label"].iloc[0]),
        train_seed=int(frame["train_seed"].iloc[0]),
        eval_dir=eval_dir.name,
    )
    return frame[list(columns)], info


def load_episodes(runs_dir: str | Path) -> pd.DataFrame:
    """All evaluated runs under ``runs_dir`` as one episode table (see :func:`load_evaluation`)."""
    return load_evaluation(runs_dir).episodes


def _check_same(infos: list[RunInfo], what: str, get: Any, message: str) -> None:
    groups: dict[str, list[str]] = {}
    for info in infos:
        groups.setdefault(json.dumps(get(info), sort_keys=True), []).append(info.name)
    if len(groups) > 1:
        parts = "; ".join(
            f"{value[:24]}: {', '.join(names[:3])}{' ...' if len(names) > 3 else ''}"
            for value, names in sorted(groups.items())
        )
        raise PriqnError(
            f"runs were {message} ({what} {parts}); re-evaluate them alike or report them apart"
        )


def config_key(row: pd.Series | dict[str, Any]) -> tuple[Any, ...]:
    """A policy configuration as a hashable tuple (NaN/empty -> None)."""
    return tuple(None if pd.isna(row[c]) or row[c] == "" else row[c] for c in CONFIG_COLUMNS)


def _check_policies(episodes: pd.DataFrame) -> None:
    per_run = episodes.drop_duplicates("run")
    configs: dict[str, tuple[Any, str]] = {}
    seeds: dict[tuple[str, int], str] = {}
    for _, row in per_run.iterrows():
        label, run = str(row["label"]), str(row["run"])
        key = config_key(row)
        if label in configs and configs[label][0] != key:
            other = configs[label][1]
            raise PriqnError(
                f"label {label!r} names two configurations (run {other}: {configs[label][0]}, "
                f"run {run}: {key}); give them distinct labels"
            )
        configs.setdefault(label, (key, run))
        seed_key = (label, int(row["train_seed"]))
        if seed_key in seeds:
            raise PriqnError(
                f"runs {seeds[seed_key]} and {run} are both policy {label!r} with training seed "
                f"{seed_key[1]}; remove one (a report never averages duplicates)"
            )
        seeds[seed_key] = run


def check_seeds(episodes: pd.DataFrame, min_seeds: int) -> None:
    """Raise if any policy has fewer than ``min_seeds`` training seeds."""
    counts = episodes.groupby("label", sort=True)["train_seed"].nunique()
    short = counts[counts < min_seeds]
    if len(short):
        label, n = short.index[0], int(short.iloc[0])
        raise PriqnError(
            f"policy {label!r} has {n} training seed(s) but {min_seeds} were asked for "
            f"({len(short)} policies short); train the missing seeds or lower --seeds"
        )


def resumed_text(run_dir: str | Path) -> str:
    """``–``, or the budgets at which the run's training resumed (``40k, 170k``); ``–``
    also for a run folder without a meta.json (nothing recorded)."""
    folder = RunFolder(run_dir)
    if not folder.meta_path.is_file():
        return "–"
    return ", ".join(map(budget_text, resumed_at(folder))) or "–"


def resumed_before(run_dir: str | Path, budget: int | None = None) -> bool:
    """Whether the run's training resumed after an interruption before ``budget``
    decisions (any resume where None), so its policy there is not the uninterrupted
    run's; False for a run folder without a meta.json."""
    folder = RunFolder(run_dir)
    if not folder.meta_path.is_file():
        return False
    return any(budget is None or b < budget for b in resumed_at(folder))


def commit_text(run_dir: str | Path) -> str:
    """The commit a run trained at, as the reports print it (12 hex digits), or ``–``
    where its meta.json records none."""
    folder = RunFolder(run_dir)
    sha = folder.meta().get("git_sha") if folder.meta_path.is_file() else None
    return f"`{str(sha)[:12]}`" if sha else "–"


RESUMED_NOTE = (
    "*Resumed at*: the cell's training was interrupted (a session ended) and went on from "
    "its last checkpoint, with fresh scenes and its replay buffer as saved "
    "(`checkpoint.save_replay`; refilled first where it was not); from there on its "
    "training differs from an uninterrupted run's (docs/implementation-details.md §8). "
    "A cell resumed exactly (its replay buffer and episodes in flight restored on the same "
    "CPU model: the uninterrupted run, bit for bit) is not listed."
)
"""What the reports' "resumed at" column means."""
