"""The scheduler: run every cell that is not complete, retry failures, then report.

:func:`run_sweep` takes an :class:`~priqn.experiment.Experiment`, skips complete
cells, submits the rest to a back-end, retries a failed cell once with its log, stops
cleanly on Ctrl-C (unfinished cells resume on the next run), writes ``summary.json``
and runs the report. One sweep per experiment folder at a time (a lock). The sweep's own
files live in the experiment folder's ``.sweep/`` (:class:`SweepFolder`).
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm.auto import tqdm

import priqn.sweep.backends as backends
from priqn.errors import PriqnError
from priqn.experiment import Experiment, ResourceSpec
from priqn.io import atomic_write_json
from priqn.sweep.backends import Backend, LocalBackend, RayBackend
from priqn.sweep.cells import Cell, expand, select
from priqn.sweep.process import DEFAULT_CELL_FN, describe_failure

# --------------------------------------------------------------------------- the sweep's files


class SweepFolder:
    """``<runs_dir>/<experiment>/.sweep/``: every file a sweep writes beside its cells.

    ``lock`` (one sweep per experiment folder), ``logs/<policy>__seed<k>.attempt<n>.log``
    (each attempt's child output) and ``summary.json`` (the cells' states when the sweep
    ended). Nothing else spells these names.
    """

    DIR = ".sweep"
    LOCK = "lock"
    LOGS = "logs"
    SUMMARY = "summary.json"

    def __init__(self, exp_dir: str | os.PathLike) -> None:
        self.exp_dir = Path(exp_dir)
        """The experiment folder (the cells' run folders are its other children)."""
        self.path = self.exp_dir / self.DIR
        """The ``.sweep/`` folder itself."""

    @property
    def lock_path(self) -> Path:
        return self.path / self.LOCK

    @property
    def logs_dir(self) -> Path:
        return self.path / self.LOGS

    @property
    def summary_path(self) -> Path:
        return self.path / self.SUMMARY

    def log_path(self, cell: Cell, attempt: int) -> Path:
        """The log of ``cell``'s ``attempt`` (1 = the first)."""
        return self.logs_dir / f"{cell.dir_name}.attempt{attempt}.log"

    @contextlib.contextmanager
    def lock(self) -> Iterator[None]:
        """One sweep per experiment folder at a time (advisory lock, released on exit)."""
        import fcntl

        self.path.mkdir(parents=True, exist_ok=True)
        with self.lock_path.open("a") as fh:
            try:
                fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                raise PriqnError(
                    f"{self.exp_dir}: another 'priqn sweep' is running this experiment "
                    f"(lock {self.lock_path}); wait for it or stop it first"
                ) from None
            try:
                yield
            finally:
                fcntl.flock(fh.fileno(), fcntl.LOCK_UN)

    def write_summary(self, summary: dict[str, Any]) -> None:
        """summary.json (atomically)."""
        atomic_write_json(self.summary_path, summary)


# --------------------------------------------------------------------------- the scheduler


@dataclass
class SweepResult:
    """What a sweep did. A cell is in at most one of skipped / completed / failed (in
    none if the sweep was interrupted before it finished)."""

    skipped: list[str] = field(default_factory=list)
    """Already complete before this sweep: no work done."""
    completed: list[str] = field(default_factory=list)
    """Completed by this sweep."""
    failed: dict[str, str] = field(default_factory=dict)
    """Cell -> one-line error of its last attempt (after the retry)."""
    retried: list[str] = field(default_factory=list)
    """Cells whose first attempt failed (they may have completed on the retry)."""
    report: Path | None = None
    """The report written after the grid, if any."""
    interrupted: bool = False
    """Ctrl-C stopped the sweep; unfinished cells resume on the next run."""

    @property
    def complete(self) -> list[str]:
        """All cells complete now (skipped + completed)."""
        return self.skipped + self.completed


def gpu_shares(resources: ResourceSpec) -> backends.GpuShares | None:
    """This machine's GPUs shared out ``gpus_per_cell`` a cell; None when that is 0 or
    torch sees no CUDA GPU here (cells then run on the CPU, as before GPUs were shared)."""
    if resources.gpus_per_cell <= 0:
        return None
    ids = backends.visible_gpus()
    return backends.GpuShares(ids, resources.gpus_per_cell) if ids else None


def default_jobs(resources: ResourceSpec) -> int:
    """Cells at a time on this machine: ``max(1, cores // cpus_per_cell)``, and with
    ``gpus_per_cell > 0`` no more than the GPUs hold (``floor(1 / gpus_per_cell)`` each)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return backends.local_slots(resources, cores or 1, gpu_shares(resources))


def run_sweep(
    exp: Experiment,
    *,
    jobs: int | None = None,
    ray_address: str | None = None,
    use_ray: bool = False,
    retries: int = 1,
    only: Sequence[str] = (),
    report: bool = True,
    progress: bool | None = None,
    cell_fn: str = DEFAULT_CELL_FN,
    log: Callable[[str], None] | None = None,
    code_dir: Path | None = None,
) -> SweepResult:
    """Train and evaluate every incomplete cell, retrying failures ``retries`` times, then report.

    ``use_ray`` runs cells as Ray tasks (``ray_address`` None: a new local Ray cluster;
    ``"auto"`` or an address: an existing one); otherwise a local pool of ``jobs``
    child processes (default :func:`default_jobs`), each pinned to its GPU share when
    ``[resources].gpus_per_cell > 0`` and a GPU is visible (``jobs`` is then capped by
    what the GPUs hold). ``only`` keeps cells whose name
    matches one of the glob patterns. ``code_dir``: every cell's child runs the priqn
    found there (a snapshot worktree) instead of this one. A failing cell never stops the
    others.
    Ctrl-C stops the running cells (they stay incomplete) and re-raises
    KeyboardInterrupt after writing the sweep summary.
    """
    say = log or (lambda msg: print(msg, file=sys.stderr))
    cells = select(expand(exp), only, exp.path)
    exp.runs_dir.mkdir(parents=True, exist_ok=True)
    result = SweepResult()
    with SweepFolder(exp.runs_dir).lock():
        todo = _skip_complete(cells, result)
        if not todo:
            say(f"priqn sweep {exp.experiment.name}: all {len(cells)} cells already complete")
            _write_summary(exp, cells, result)
        else:
            backend = _backend(exp, jobs, use_ray, ray_address, say)
            say(
                f"priqn sweep {exp.experiment.name}: {len(cells)} cells, "
                f"{len(result.skipped)} already complete, {len(todo)} to run ({backend.describe()})"
            )
            try:
                in_flight = _InFlight(todo, exp, result, say, progress)
                _schedule(
                    backend,
                    in_flight,
                    exp.runs_dir,
                    retries,
                    _spec_extra(cell_fn, code_dir, exp.resources.cpus_per_cell),
                )
            finally:
                backend.close()
                _write_summary(exp, cells, result)
    if report and not result.interrupted:
        result.report = _report_when_complete(exp, say)
    return result


def _spec_extra(cell_fn: str, code_dir: Path | None, cpus_per_cell: float) -> dict[str, Any]:
    """What every cell's spec carries beside the cell's own: the function its child runs,
    its thread limit (its CPU share, at least 1: :func:`priqn.sweep.process.thread_env`)
    and, with ``code_dir``, the priqn checkout the child imports."""
    return {
        "cell_fn": cell_fn,
        "threads": max(1, int(cpus_per_cell)),
        **({"code_dir": str(code_dir)} if code_dir is not None else {}),
    }


def _skip_complete(cells: list[Cell], result: SweepResult) -> list[Cell]:
    """The cells still to run; the complete ones go to ``result.skipped``."""
    todo = []
    for c in cells:
        if c.is_complete():
            result.skipped.append(c.name)
        else:
            todo.append(c)
    return todo


def _backend(
    exp: Experiment,
    jobs: int | None,
    use_ray: bool,
    ray_address: str | None,
    say: Callable[[str], None],
) -> Backend:
    """Where the cells run: Ray tasks (``use_ray``), else a local pool of ``jobs`` child
    processes (default :func:`default_jobs`) on this machine's GPU shares, with a warning
    when ``gpus_per_cell > 0`` but torch sees no GPU."""
    if use_ray:
        return RayBackend(ray_address, exp.resources, jobs)
    shares = gpu_shares(exp.resources)
    if shares is None and exp.resources.gpus_per_cell > 0:
        say(
            f"priqn sweep: warning: [resources] gpus_per_cell = "
            f"{exp.resources.gpus_per_cell:g} but torch sees no CUDA GPU here: "
            "cells run on the CPU"
        )
    return LocalBackend(jobs or default_jobs(exp.resources), shares)


def _report_when_complete(exp: Experiment, say: Callable[[str], None]) -> Path | None:
    """The experiment's report when every cell of its grid is complete (not only those
    this sweep selected); else None, saying why (a report never mixes in missing runs)."""
    missing = [c.name for c in expand(exp) if not c.is_complete()]
    if missing:
        say(
            f"priqn sweep: report skipped: {len(missing)} cell(s) not complete "
            f"(e.g. {missing[0]}); a report never mixes in missing runs"
        )
        return None
    return _run_report(exp, say)


class _InFlight:
    """One sweep's cells on their way: the queue of (cell, attempt) still to submit, the
    back-end's handles running, the outcome of each finished attempt, and the progress
    shown (a tqdm bar on a terminal, one line per finished cell in a log)."""

    def __init__(
        self,
        todo: list[Cell],
        exp: Experiment,
        result: SweepResult,
        say: Callable[[str], None],
        progress: bool | None,
    ) -> None:
        self.queue: list[tuple[Cell, int]] = [(c, 1) for c in todo]
        self.running: dict[Any, tuple[Cell, int]] = {}
        self.total, self.result, self.say = len(todo), result, say
        self.show_bar = sys.stderr.isatty() if progress is None else progress
        self.bar = tqdm(
            total=len(todo),
            unit="cell",
            desc=exp.experiment.name,
            disable=not self.show_bar,
            dynamic_ncols=True,
            file=sys.stderr,
        )
        self.started = time.monotonic()

    def counts(self) -> str:
        r = self.result
        return (
            f"done={len(r.completed)} running={len(self.running)} "
            f"failed={len(r.failed)} queued={len(self.queue)}"
        )

    def note(self, msg: str) -> None:
        """A line beside the bar (or in the log)."""
        if self.show_bar:
            tqdm.write(msg, file=sys.stderr)
        else:
            self.say(msg)

    def finished(self, cell: Cell, what: str) -> None:
        """``cell`` is done for good (``what``: complete / FAILED)."""
        self.bar.update(1)
        if not self.show_bar:  # a log file or a batch job: one line per finished cell
            n = len(self.result.completed) + len(self.result.failed)
            rate_s = (time.monotonic() - self.started) / n
            eta = tqdm.format_interval(rate_s * (self.total - n))
            self.say(f"[{n}/{self.total}] {cell.name} {what} ({self.counts()}, ETA {eta})")

    def landed(
        self, cell: Cell, attempt: int, rc: int, tail: str, complete: bool, retries: int
    ) -> None:
        """Record an attempt's end: complete, queued again (``attempt <= retries``), or failed."""
        if rc == 0 and complete:
            self.result.completed.append(cell.name)
            self.finished(cell, "complete")
            return
        error = describe_failure(rc, tail)
        if attempt <= retries:
            self.result.retried.append(cell.name)
            self.note(f"cell {cell.name} failed (attempt {attempt}): {error}; retrying")
            self.queue.append((cell, attempt + 1))
        else:
            self.result.failed[cell.name] = error
            self.note(f"cell {cell.name} FAILED: {error}")
            self.finished(cell, "FAILED")


def _schedule(
    backend: Any, cells: _InFlight, runs_dir: Path, retries: int, spec_extra: dict[str, Any]
) -> None:
    """Submit ``cells`` to ``backend`` as its slots free up (each spec with ``spec_extra``:
    the cell function, the code folder), until every cell completed or failed its last
    attempt. Ctrl-C cancels the running cells and re-raises."""
    slots = backend.slots
    try:
        while cells.queue or cells.running:
            while cells.queue and (slots is None or len(cells.running) < slots):
                cell, attempt = cells.queue.pop(0)
                spec = {**cell.to_spec(), "attempt": attempt, **spec_extra}
                log_path = SweepFolder(runs_dir).log_path(cell, attempt)
                cells.running[backend.submit(spec, log_path)] = (cell, attempt)
            cells.bar.set_postfix_str(cells.counts(), refresh=True)
            for handle, rc, tail, complete in backend.wait(list(cells.running), timeout_s=1.0):
                cell, attempt = cells.running.pop(handle)
                cells.landed(cell, attempt, rc, tail, complete, retries)
            cells.bar.set_postfix_str(cells.counts(), refresh=True)
    except KeyboardInterrupt:
        cells.result.interrupted = True
        cells.note(
            f"interrupted: stopping {len(cells.running)} running cell(s); they stay incomplete"
        )
        backend.cancel(list(cells.running))
        raise
    finally:
        cells.bar.close()


def _write_summary(exp: Experiment, cells: list[Cell], result: SweepResult) -> None:
    states = {c.name: c.state() for c in cells}
    SweepFolder(exp.runs_dir).write_summary(
        {
            "experiment": exp.experiment.name,
            "file": str(exp.path),
            "finished_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "interrupted": result.interrupted,
            "cells": {
                c.name: {
                    "run_dir": str(c.run_dir),
                    "state": states[c.name],
                    "error": result.failed.get(c.name),
                }
                for c in cells
            },
        },
    )


def _run_report(exp: Experiment, say: Callable[[str], None]) -> Path | None:
    try:
        from priqn.analysis.reports import write_experiment_report
    except ModuleNotFoundError as exc:
        say(f"priqn sweep: report skipped ({exc.name} is not installed)")
        return None
    out = write_experiment_report(exp, exp.report_dir)
    say(f"priqn sweep: report in {out}")
    return Path(out)
