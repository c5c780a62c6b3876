"""``priqn sweep``: the command line over :func:`~priqn.sweep.scheduler.run_sweep`."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path
from typing import Any

from priqn.errors import PriqnError
from priqn.experiment import cell_dir_name, load_experiment
from priqn.paths import EXPERIMENTS, shipped
from priqn.run.folder import Status
from priqn.sweep.cells import cell_progress, expand, select, stale_cells, time_left, validate
from priqn.sweep.process import DEFAULT_CELL_FN
from priqn.sweep.scheduler import SweepFolder, default_jobs, run_sweep

# --------------------------------------------------------------------------- CLI


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """``priqn sweep EXPERIMENT [--jobs N | --ray [ADDRESS]] ...``."""
    parser.add_argument(
        "experiment",
        help="experiment file, or a name: ./experiments/NAME.toml, else shipped ("
        + ", ".join(sorted(p.stem for p in shipped(EXPERIMENTS).glob("*.toml")))
        + ")",
    )
    _resource_flags(parser)
    _cell_flags(parser)
    _run_nothing_flags(parser)
    _code_flags(parser)


def _resource_flags(parser: argparse.ArgumentParser) -> None:
    """Where the cells run and how many at a time: the local pool or Ray, and the
    overrides of the file's ``[experiment].runs_dir`` and ``[resources]``."""
    parser.add_argument(
        "--jobs",
        "-j",
        type=int,
        default=None,
        help="cells at a time (local default: cores // [resources].cpus_per_cell; "
        "with --ray: a cap on cells in flight, default none)",
    )
    parser.add_argument(
        "--ray",
        nargs="?",
        const="",
        default=None,
        metavar="ADDRESS",
        help="run cells as Ray tasks; no ADDRESS starts a local Ray cluster, 'auto' or "
        "host:6379 / ray://host:10001 connects to an existing one (pip install 'priqn[ray]')",
    )
    parser.add_argument("--runs-dir", default=None, help="override [experiment].runs_dir")
    parser.add_argument(
        "--cpus-per-cell", type=float, default=None, help="override [resources].cpus_per_cell"
    )
    parser.add_argument(
        "--gpus-per-cell", type=float, default=None, help="override [resources].gpus_per_cell"
    )


def _cell_flags(parser: argparse.ArgumentParser) -> None:
    """Which cells run, how often a failed one is retried, and the report after them."""
    parser.add_argument(
        "--only",
        nargs="+",
        default=(),
        metavar="GLOB",
        help="run only cells whose name matches, e.g. 'table2/pr-iqn-qd-*__seed0'",
    )
    parser.add_argument(
        "--retries", type=int, default=1, help="extra attempts for a failed cell (default 1)"
    )
    parser.add_argument("--no-report", action="store_true", help="skip the report at the end")


def _run_nothing_flags(parser: argparse.ArgumentParser) -> None:
    """The actions that run no cell: list the cells, commit the complete ones, forecast
    a sequential design."""
    parser.add_argument(
        "--list", action="store_true", help="list the cells and their state; run nothing"
    )
    parser.add_argument(
        "--commit",
        action="store_true",
        help="commit every complete cell git reports as new or changed, in one commit of "
        "only their folders (what .gitignore lets through); run nothing",
    )
    parser.add_argument(
        "--forecast",
        type=int,
        default=None,
        metavar="SIMS",
        help="sequential designs: simulate SIMS completions of the experiment from the "
        "committed seeds and print how likely each comparison is to be decided, if the "
        "estimates so far or the paper's differences are true; run nothing "
        "(priqn.analysis.forecast)",
    )


def _code_flags(parser: argparse.ArgumentParser) -> None:
    """The code each cell's child process runs: a frozen checkout, the cell function."""
    parser.add_argument(
        "--code",
        default=None,
        metavar="DIR",
        help="run every cell with the priqn checkout at DIR (a snapshot worktree: "
        "git worktree add --detach DIR COMMIT), so a long grid trains at one frozen commit "
        "while this checkout changes; each cell records DIR's commit",
    )
    parser.add_argument(
        "--cell-fn",
        default=DEFAULT_CELL_FN,
        metavar="MODULE:FUNC",
        help="advanced: function run for each cell in its child process, called with the "
        f"Cell (default {DEFAULT_CELL_FN}: train, then evaluate)",
    )


def run(args: argparse.Namespace) -> int:
    """Entry point of ``priqn sweep``."""
    exp = load_experiment(
        args.experiment,
        runs_dir=args.runs_dir,
        cpus_per_cell=args.cpus_per_cell,
        gpus_per_cell=args.gpus_per_cell,
    )
    if args.jobs is not None and args.jobs < 1:
        raise PriqnError(f"--jobs {args.jobs}: expected a positive number of cells")
    if args.retries < 0:
        raise PriqnError(f"--retries {args.retries}: expected 0 or more")
    code_dir = _code_dir(args.code)
    if args.list:
        _list(exp, args.jobs, args.only or ())
        return 0
    if args.forecast is not None:
        return _forecast(exp, args.forecast)
    if args.commit:
        return _commit(exp)
    if exp.designs:
        _check_code_commit(exp, code_dir)
    if args.cell_fn == DEFAULT_CELL_FN:
        validate(exp)
        stale = stale_cells(exp)
        if stale:
            name, diff = next(iter(stale.items()))
            print(
                f"priqn sweep: warning: {len(stale)} complete cell(s) were made with another "
                f"config than {exp.path} gives now (e.g. {name}: {diff}); they are kept as they "
                "are: delete their run folders to re-run them",
                file=sys.stderr,
            )
    _sigterm_as_interrupt()
    kw: dict[str, Any] = {
        "jobs": args.jobs,
        "use_ray": args.ray is not None,
        "ray_address": args.ray or None,
        "retries": args.retries,
        "cell_fn": args.cell_fn,
        "code_dir": code_dir,
    }
    if exp.designs and not args.only:
        return _run_sequential(exp, report=not args.no_report, **kw)
    result = run_sweep(exp, only=args.only, report=not args.no_report, **kw)
    return _summarise(exp, result)


def _summarise(exp: Any, result: Any) -> int:
    """Print the sweep's outcome; the exit status (1 when a cell failed)."""
    print(
        f"priqn sweep {exp.experiment.name}: {len(result.complete)} complete "
        f"({len(result.skipped)} skipped, {len(result.completed)} run now), "
        f"{len(result.failed)} failed"
    )
    for name, error in result.failed.items():
        print(f"  FAILED {name}: {error}")
    if result.failed:
        print(f"  logs: {SweepFolder(exp.runs_dir).logs_dir}")
    return 1 if result.failed else 0


def _commit(exp: Any) -> int:
    """``--commit``: commit the complete, uncommitted cells (:mod:`priqn.sweep.commit`)."""
    from priqn.sweep.commit import commit_complete_cells

    done = commit_complete_cells(exp)
    name = exp.experiment.name
    if done.sha is None:
        print(f"priqn sweep {name}: no complete cell to commit")
    else:
        cells = ", ".join(c.run_dir.name for c in done.cells)
        print(f"priqn sweep {name}: committed {len(done.cells)} cell(s) as {done.sha}: {cells}")
    if done.refused:
        cells = ", ".join(c.run_dir.name for c in done.refused)
        print(
            f"priqn sweep {name}: warning: not committed, trained at a commit "
            f"[sequential].code_commits does not list or with uncommitted changes: {cells}",
            file=sys.stderr,
        )
    return 0


def _forecast(exp: Any, sims: int) -> int:
    """``--forecast SIMS``: the planning simulation of each sequential design (stdout): the
    ``[sequential]`` table or each ``[[question]]``; a design whose rows lack two complete
    seeds is named and skipped."""
    from tqdm import tqdm

    from priqn.analysis import forecast, questions

    if sims < 1:
        raise PriqnError(f"--forecast {sims}: expected a positive number of simulations")
    if not exp.designs:
        raise PriqnError(f"--forecast: {exp.path} has no [sequential] design or [[question]]")
    for design in exp.designs:
        title = " ".join(filter(None, (exp.experiment.name, design.name)))
        scores = questions.collect(exp, design)
        try:
            have = forecast.committed_rows(scores, questions.rows_of(exp, design))
        except PriqnError as exc:
            print(f"{title}: not forecast ({str(exc).removeprefix('forecast: ')})")
            continue
        total = sims * len(forecast.scenarios_for(design))
        with tqdm(
            total=total, desc=f"forecast {design.name}".strip(), unit="sim", disable=None
        ) as bar:
            table = forecast.forecast(design, have, sims=sims, on_sim=bar.update)
        _print_forecast(title, design, have, table)
    print(
        f"({sims} simulated experiments a scenario, {forecast.PERMUTATIONS} permutations each; "
        "planning only, not a verdict: docs/statistics.md)"
    )
    return 0


def _print_forecast(title: str, design: Any, have: dict[str, Any], table: Any) -> None:
    """One design's forecast: its rows' spread, then per scenario each comparison's
    verdict shares."""
    from priqn.analysis import forecast

    print(
        f"{title}: if the seeds still to train (up to {design.interims[-1]} per row) follow "
        "each row's spread so far "
        f"({', '.join(f'{r} {v.size} seeds, SD {v.std(ddof=1):.3f}' for r, v in have.items())}):"
    )
    for scenario, part in table.groupby("scenario", sort=False):
        print(f"  {forecast.SCENARIO_TEXT[scenario]}:")
        for comparison, rows in part.groupby("comparison", sort=False):
            words = ", ".join(f"{r.verdict} {r.share:.0%}" for r in rows.itertuples())
            print(
                f"    {comparison}: {words}; "
                f"{rows['mean_seeds'].iloc[0]:.1f} seeds per row on average"
            )


def _list(exp: Any, jobs: int | None, only: list[str] | tuple[str, ...] = ()) -> None:
    """``--list``: every cell (those matching ``--only``) and its state (stdout); for a
    sequential design, which cells the next look needs; the tally and the time left
    (:func:`time_left`) on stderr."""
    needed: set[str] = set()
    if exp.designs:
        next_cells, where = _design_plan(exp)
        needed = {cell_dir_name(p, s) for p, s in next_cells}
    cells = select(expand(exp), only, exp.path)
    states = [c.state() for c in cells]
    for c, state in zip(cells, states, strict=True):
        progress = cell_progress(c, state)
        mark = ("  " + progress if progress else "") + (
            "  <- next look" if c.run_dir.name in needed else ""
        )
        print(f"{c.name:<48} {state:<11} {c.run_dir}{mark}")
    counts = ", ".join(f"{states.count(s)} {s}" for s in dict.fromkeys(sorted(states)))
    # The listing is stdout (one cell a line, for scripts); the tally goes to stderr.
    print(f"{exp.experiment.name}: {len(cells)} cells: {counts}", file=sys.stderr)
    if exp.designs:
        print(f"{exp.experiment.name}: sequential design: {where}", file=sys.stderr)
        left = [c for c in cells if c.run_dir.name in needed]
    else:
        left = [c for c, state in zip(cells, states, strict=True) if state != Status.COMPLETE]
    if left:
        slots = jobs or default_jobs(exp.resources)
        print(f"{exp.experiment.name}: {_time_left_line(exp, left, slots)}", file=sys.stderr)


def _time_left_line(exp: Any, left: list[Any], slots: int) -> str:
    """One line: about how long the cells ``left`` take, ``slots`` at a time."""
    est = time_left(exp, left, slots)
    if est.hours is None:
        return (
            f"time left for {len(left)} cell(s): unknown until {', '.join(est.untimed)} "
            "has a complete cell to time it by"
        )
    per = ", ".join(
        f"{p} {m:.0f} min" + (" (scaled from its group's other budgets)" if p in est.scaled else "")
        for p, m in est.minutes_per_cell.items()
    )
    return (
        f"about {est.hours:.1f} h left for {len(left)} cell(s), {slots} at a time "
        f"(per cell, the median of this experiment's complete cells: {per}; an estimate)"
    )


def _design_plan(exp: Any) -> tuple[list[tuple[str, int]], str]:
    """``((row, seed) cells the next looks need, where the design stands in one line)``
    over every design: the ``[sequential]`` table or each ``[[question]]``."""
    from priqn.analysis import questions

    cells: list[tuple[str, int]] = []
    plans = []
    for design in exp.designs:
        scores, plan = questions.take_looks(exp, design)
        cells += [c for c in questions.cells_needed(exp, design, scores, plan) if c not in cells]
        plans.append((design, plan))
    if exp.sequential is None:
        states = [
            f"{q.name} finished after {len(plan.looks)} look(s)"
            if plan.finished
            else f"{q.name} at look {plan.next_look}"
            for q, plan in plans
        ]
        return cells, f"{'; '.join(states)}; {len(cells)} cell(s) needed"
    ((_, plan),) = plans
    if plan.finished or not cells:
        state = "finished" if plan.finished else f"waiting for look {plan.next_look}"
        words = "; ".join(f"{k}: {v}" for k, v in plan.decisions.items())
        return cells, f"{state} after {len(plan.looks)} look(s): {words}"
    rows = ", ".join(plan.open_rows)
    return cells, f"look {plan.next_look} needs {len(cells)} cell(s) of {rows}"


def _run_sequential(exp: Any, report: bool, **kw: Any) -> int:
    """Pre-registered sequential designs: train the cells the next looks need, take the
    looks, and go on until every comparison is decided or the last look is taken."""

    while True:
        cells, where = _design_plan(exp)
        if not cells:
            print(f"priqn sweep {exp.experiment.name}: sequential design {where}")
            break
        print(f"priqn sweep {exp.experiment.name}: {where}", file=sys.stderr)
        only = [f"{exp.experiment.name}/{cell_dir_name(p, s)}" for p, s in cells]
        result = run_sweep(exp, only=only, report=False, **kw)
        if result.failed or result.interrupted:
            return _summarise(exp, result)
    if report:
        from priqn.analysis.reports import write_experiment_report

        path = write_experiment_report(exp, exp.report_dir)
        print(f"priqn sweep: report in {path}", file=sys.stderr)
    return 0


def _code_dir(arg: str | None) -> Path | None:
    """``--code DIR`` checked: a priqn checkout (absolute, so children find it anywhere)."""
    if arg is None:
        return None
    path = Path(arg).absolute()
    if not (path / "priqn" / "__init__.py").is_file():
        raise PriqnError(f"--code {arg}: no priqn package there (expected {path}/priqn/)")
    return path


def _check_code_commit(exp: Any, code_dir: Path | None) -> None:
    """A sequential design lists the commits its cells may train at: refuse any other."""
    from priqn.run.provenance import git_sha

    listed = exp.code_commits
    if not listed:
        return
    sha = git_sha(code_dir)
    if sha not in listed:
        where = f"--code {code_dir}" if code_dir else "this checkout"
        raise PriqnError(
            f"{exp.path} [sequential].code_commits: cells would train at {sha[:12]} ({where}), "
            f"which the design does not list; run them from a snapshot of the frozen commit "
            f"{listed[-1][:12]}: --code DIR (docs/sweeps.md)"
        )


def _sigterm_as_interrupt() -> None:
    """SIGTERM (a batch scheduler, ``kill``) stops the sweep like Ctrl-C: cells stopped cleanly.

    SIGINT gets Python's KeyboardInterrupt handler even when it was inherited as ignored
    (a shell starts ``cmd &`` with SIGINT ignored, and Python then leaves it so), so
    ``kill -INT`` stops a background sweep too.
    """

    def handler(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, handler)
        signal.signal(signal.SIGINT, signal.default_int_handler)
