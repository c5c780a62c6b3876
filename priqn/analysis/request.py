"""What a report is asked for, and the command that regenerates it.

A :class:`ReportRequest` holds ``priqn report``'s arguments (or a sweep's experiment);
:func:`report_command` is the one builder of the command a report records in
``report.md`` and ``meta.json``: re-running it from the working directory regenerates the
folder byte for byte. :mod:`priqn.analysis.reports` chooses the kind and its builder, which
gets this command to record.
"""

from __future__ import annotations

import dataclasses
import shlex
from pathlib import Path
from typing import Any

DEFAULT_REPS = 2000
"""Bootstrap replications by default (rliable suggests >= 2000 for 95% CIs)."""


@dataclasses.dataclass(frozen=True)
class ReportRequest:
    """What a report is asked for: ``priqn report``'s arguments, or a sweep's experiment."""

    runs: Path
    """The folder of runs reported."""
    out: Path
    """The report's folder."""
    experiment: Any = None
    """The :class:`priqn.experiment.Experiment` the runs are (:func:`priqn.analysis.reports.experiment_of`), or None."""
    seed: int = 0
    """Grid: ``np.random.seed`` before every rliable call (``--seed``)."""
    reps: int = DEFAULT_REPS
    """Grid: bootstrap replications (``--reps``)."""
    min_seeds: int | None = None
    """Grid: refuse a policy with fewer training seeds (``--seeds``)."""
    partial: bool = False
    """Report what is in while cells are missing (``--partial``): the grid's evaluated runs,
    an evaluation design's or a traffic report's complete cells."""
    references: tuple[str, ...] = ()
    """Grid: reference drivers' folders (``--reference``)."""
    horizon: tuple[int, ...] = ()
    """Evaluation-only episode limits (``--horizon``); non-empty: the horizon report."""
    traffic: str | None = None
    """Another named traffic setting (``--traffic``): the runs' evaluations under it beside
    their own (the traffic report)."""
    evaluation: Any = None
    """An evaluation design (:class:`priqn.evaluation.design.EvaluationDesign`,
    ``--evaluation``): its report over the cells it names; ``runs`` is then unused."""

    @property
    def experiment_name(self) -> str | None:
        """The experiment's name (``meta.json``'s ``experiment``), or None."""
        return None if self.experiment is None else self.experiment.experiment.name


def report_command(request: ReportRequest, kind: str) -> str:
    """The ``priqn report`` command that regenerates ``request``'s folder byte for byte (run
    from the working directory; paths relative to it where they are inside it): recorded
    in ``report.md`` and ``meta.json``."""
    from priqn.analysis.sequential import relative_path

    if kind == "evaluation":
        words = ["priqn", "report", "--evaluation", request.evaluation.design.name]
        words += ["--out", relative_path(request.out), "--seed", str(request.seed)]
        return shlex.join(words + (["--partial"] if request.partial else []))
    words = ["priqn", "report", relative_path(request.runs)]
    if kind == "horizon":
        words += ["--horizon", ",".join(str(n) for n in request.horizon)]
    if kind == "traffic":
        words += ["--traffic", str(request.traffic)]
    words += ["--out", relative_path(request.out)]
    if kind == "traffic" and request.partial:
        words += ["--partial"]
    if kind == "grid":
        words += ["--seed", str(request.seed), "--reps", str(request.reps)]
        words += ["--seeds", str(request.min_seeds)] if request.min_seeds else []
        words += ["--partial"] if request.partial else []
        for folder in request.references:
            words += ["--reference", str(folder)]
    return shlex.join(words)
