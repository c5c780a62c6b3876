"""The evaluations a run folder holds, as the sweep and the reports read them: their names,
their folders and the status each records.

``eval/`` is the run's own hold-out evaluation; each other evaluation of the run is a
folder ``eval-<name>/`` beside it: a control (``eval-near-greedy/``), your own nets
(``eval-nets-<hash>/``) or a kept snapshot (``eval-at<N>[-<control>]/``,
:func:`snapshot_evaluation`). Each has its own ``meta.json`` whose ``status`` says whether
it is complete. Writing them is :mod:`priqn.evaluation`'s; this module only reads, and
stays torch-free.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from priqn.io import read_json
from priqn.run.folder import RunFolder, Status, status_in

SNAPSHOT_PREFIX = "at"
"""Evaluations of a kept snapshot are ``eval-at<N>[-<control>]/`` (:func:`snapshot_evaluation`)."""


def snapshot_evaluation(budget: int) -> str:
    """The evaluation name of the policy kept at ``budget`` decisions: ``at<budget>``
    (its folder ``eval-at<budget>/``)."""
    return f"{SNAPSHOT_PREFIX}{budget}"


def evaluation_folder(name: str = "") -> str:
    """The folder name of evaluation ``name``: ``eval`` for "", else ``eval-<name>``."""
    return f"{RunFolder.EVAL}-{name}" if name else RunFolder.EVAL


def evaluation_dir(run: RunFolder, name: str = "") -> Path:
    """``eval/`` of ``run`` for ``name`` "", else ``eval-<name>/`` (e.g. ``eval-near-greedy``)."""
    return run.path / evaluation_folder(name)


def control_evaluations(run: RunFolder) -> list[str]:
    """Names of the control evaluations (``eval-<name>/`` folders beside ``eval/``), sorted."""
    prefix = f"{RunFolder.EVAL}-"
    return sorted(p.name[len(prefix) :] for p in run.path.glob(prefix + "*") if p.is_dir())


def kept_evaluations(run: RunFolder) -> list[str]:
    """The evaluation names (``at<N>``) of the snapshots meta.json records as kept."""
    return [snapshot_evaluation(int(b)) for b in run.meta().get("snapshots") or {}]


def eval_meta(run: RunFolder) -> dict[str, Any]:
    """eval/meta.json."""
    return read_json(run.eval_meta_path)


def recorded_eval_status(run: RunFolder, name: str = "") -> str | None:
    """eval/meta.json's ``status`` as written (None when never evaluated or unreadable);
    ``name``: of the control evaluation ``eval-<name>/`` instead."""
    return status_in(evaluation_dir(run, name) / RunFolder.META)


def evaluation_complete(run: RunFolder, name: str = "") -> bool:
    """Trained, and the evaluation ``name`` (``""``: ``eval/``) complete, read from the
    recorded statuses: the one test of "this cell's score can be read" that the sweep
    and the reports share."""
    return (
        run.recorded_status() == Status.COMPLETE
        and recorded_eval_status(run, name) == Status.COMPLETE
    )


def evaluated(run: RunFolder, names: Sequence[str] = ()) -> bool:
    """:func:`evaluation_complete` for ``eval/`` and every ``eval-<name>/`` of ``names``:
    what a sweep counts as a complete cell."""
    return all(evaluation_complete(run, name) for name in ("", *names))
