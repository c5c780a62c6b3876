"""Every kind of report, and the one place a report's kind is chosen.

:data:`REPORTS` names each kind (the ``kind`` of its ``meta.json``, :mod:`priqn.analysis.artifacts`)
with the function that builds its sections (:mod:`priqn.analysis.sections`). ``priqn report`` and ``priqn sweep`` both go through
:func:`write_report`: a :class:`~priqn.analysis.request.ReportRequest` (the runs folder,
the output folder and the options) gets its kind from :func:`choose_kind`, its
``meta.json`` command from :func:`~priqn.analysis.request.report_command` (the one builder
of that string); the kind's report is built, then rendered by the one renderer
(:func:`priqn.analysis.artifacts.render`)::

    --evaluation NAME             evaluation    priqn.analysis.design_report
    --horizon N,...               horizon       priqn.analysis.horizon
    --traffic NAME                traffic       priqn.analysis.traffic_report
    an experiment's [calibration] calibration   priqn.analysis.calibration
    its [sequential] table        sequential    priqn.analysis.sequential_report
    its [[question]] tables       questions     priqn.analysis.questions_report
    any other folder of runs      grid          priqn.analysis.report (Tables I/II, rliable)

The experiment of a runs folder is the one named by ``--experiment``, else the experiment
file named like the folder (``results/headline`` -> ``headline``), else none
(:func:`experiment_of`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

from priqn.analysis.request import ReportRequest, report_command
from priqn.analysis.sections import Report
from priqn.errors import PriqnError
from priqn.io import removed_on_failure


@dataclasses.dataclass(frozen=True)
class ReportKind:
    """One kind of report: its name (``meta.json``'s ``kind``), what it shows, and how it is
    built from sections (``build``)."""

    name: str
    """``meta.json``'s ``kind``."""
    summary: str
    """What it shows, in a few words."""
    build: Callable[..., Report]
    """The kind's :class:`~priqn.analysis.sections.Report`, rendered by
    :func:`priqn.analysis.artifacts.render`: ``build(request, command)`` for a kind of
    ``priqn report``, ``build(<the replayed cells>, ..., command)`` for one of ``priqn
    mechanism`` (:mod:`priqn.tools` replays, then builds)."""
    made_by: str = "priqn report"
    """The command that makes it: ``priqn report`` or ``priqn mechanism``."""


def _grid(request: ReportRequest, command: str) -> Report:
    from priqn.analysis.report import grid_report

    return grid_report(
        request.runs,
        command,
        seed=request.seed,
        reps=request.reps,
        min_seeds=request.min_seeds,
        partial=request.partial,
        references=request.references,
        experiment=request.experiment_name,
    )


def _sequential(request: ReportRequest, command: str) -> Report:
    from priqn.analysis.sequential_report import sequential_report

    return sequential_report(request.experiment, command)


def _questions(request: ReportRequest, command: str) -> Report:
    from priqn.analysis.questions_report import questions_report

    return questions_report(request.experiment, command)


def _calibration(request: ReportRequest, command: str) -> Report:
    from priqn.analysis.calibration import calibration_report

    return calibration_report(request.experiment, command)


def _evaluation(request: ReportRequest, command: str) -> Report:
    from priqn.analysis.design_report import design_report

    return design_report(request.evaluation, command, request.seed, request.partial)


def _traffic(request: ReportRequest, command: str) -> Report:
    from priqn.analysis.traffic_report import traffic_report

    return traffic_report(
        request.runs, request.traffic, command, request.partial, request.experiment_name
    )


def _mechanism(*args: Any) -> Report:
    from priqn.analysis.mechanism import mechanism_report

    return mechanism_report(*args)


def _standstill(*args: Any) -> Report:
    from priqn.analysis.standstill import standstill_report

    return standstill_report(*args)


def _collisions(*args: Any) -> Report:
    from priqn.analysis.collisions import collisions_report

    return collisions_report(*args)


def _horizon(request: ReportRequest, command: str) -> Report:
    from priqn.analysis.horizon import horizon_report

    return horizon_report(request.runs, request.horizon, command, request.experiment_name)


REPORTS: dict[str, ReportKind] = {
    kind.name: kind
    for kind in (
        ReportKind("grid", "Tables I and II, rliable statistics, the claims", _grid),
        ReportKind("sequential", "a [sequential] table's looks and verdicts", _sequential),
        ReportKind("questions", "[[question]] tables' looks and verdicts", _questions),
        ReportKind("calibration", "the row whose outcome mix is nearest a target", _calibration),
        ReportKind("horizon", "the runs at longer evaluation-only episode limits", _horizon),
        ReportKind("evaluation", "an evaluation design's questions on another family", _evaluation),
        ReportKind("traffic", "the runs under another traffic setting beside their own", _traffic),
        # Built from replayed decisions by `priqn mechanism` (priqn.tools replays the cells,
        # then builds the report from their rows), not by `priqn report`.
        ReportKind(
            "mechanism", "safety removals and the safety head's calibration", _mechanism,
            made_by="priqn mechanism",
        ),
        ReportKind(
            "standstill", "where and why Pr-IQN stands still", _standstill,
            made_by="priqn mechanism",
        ),
        ReportKind(
            "collisions", "who struck whom, and could it have been prevented", _collisions,
            made_by="priqn mechanism",
        ),
    )
}  # fmt: skip
"""Every kind of report, by the name its ``meta.json`` records."""


def experiment_of(runs: str | Path, name: str | None = None) -> Any:
    """The experiment whose runs live in ``runs``: the one named ``name`` (a one-line
    error if its cells live elsewhere), else the experiment file named like the folder
    (``results/headline`` -> ``headline``) if there is one; None otherwise."""
    from priqn.experiment import load_experiment

    folder = Path(runs)
    if name is None:
        try:
            return load_experiment(folder.name, runs_dir=folder.parent)
        except PriqnError:
            return None
    exp = load_experiment(name, runs_dir=folder.parent)
    if Path(exp.runs_dir).resolve() != folder.resolve():
        raise PriqnError(
            f"--experiment {name}: its cells live in {Path(exp.runs_dir).name}/, not {folder.name}/"
        )
    if not exp.designs and exp.calibration is None:
        raise PriqnError(
            f"--experiment {name}: {exp.path} has no [sequential], [[question]] or "
            "[calibration] design"
        )
    return exp


def choose_kind(request: ReportRequest) -> str:
    """The kind of report ``request`` gets (a name in :data:`REPORTS`)."""
    exp = request.experiment
    if request.evaluation is not None:
        return "evaluation"
    if request.horizon and request.traffic:
        raise PriqnError("--horizon and --traffic: one report at a time")
    if request.horizon:
        return "horizon"
    if request.traffic:
        return "traffic"
    if exp is None or (not exp.designs and exp.calibration is None):
        return "grid"
    if request.references:
        raise PriqnError("--reference: not for an experiment's design report")
    if exp.calibration is not None:
        return "calibration"
    return "sequential" if exp.sequential is not None else "questions"


def write_report(request: ReportRequest) -> Path:
    """Write ``request``'s report by its kind (:func:`choose_kind`), recording
    :func:`report_command`; returns the report's Markdown file. A report refused (no runs,
    an unevaluated one, ...) leaves no empty output folder it made."""
    kind = choose_kind(request)
    from priqn.analysis.artifacts import render

    report = REPORTS[kind].build(request, report_command(request, kind))  # before any file
    with removed_on_failure(request.out):
        return render(request.out, report)


def write_experiment_report(exp: Any, out: str | Path) -> Path:
    """The report ``priqn sweep`` writes after an experiment's cells: :func:`write_report`
    of its runs folder (a grid's statistics seeded by ``[experiment].report_seed``)."""
    request = ReportRequest(Path(exp.runs_dir), Path(out), exp, seed=exp.experiment.report_seed)
    return write_report(request)
