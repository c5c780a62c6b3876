"""``priqn bench sweep``: cells per hour running sweep cells one at a time vs ``--jobs`` at a time.

Runs the same short training cells twice in one command: first one at a time (the
baseline), then ``--jobs`` at a time. Each cell is its own ``priqn train`` child process
(libsumo allows one simulation per process; a sweep cell is one too) with the default
preset, no in-training evaluation and no checkpoint before the last, writing into a
temporary runs folder. The wall clock of each mode, from the first cell's start to the
last cell's end, gives cells per hour; the ratio concurrent / sequential says whether
``priqn sweep --jobs N`` (or ``[resources].cpus_per_cell``) should put more cells on this
machine at once. The ratio, not the absolute figures, is the result: both modes run under
the same machine load, in the same command.

``--cells 1,2,4,8`` (a list) measures scaling instead: 1 cell alone, then 2 at a time, 4,
8, and prints the aggregate decisions/s of each level (the sum of its cells' training-loop
rates) as a ratio to one cell's. With ``--device cuda`` on several GPUs the cells are
pinned round-robin (``CUDA_VISIBLE_DEVICES``); on one GPU they share it, which is what
``[resources].gpus_per_cell = 1/n`` does in a local sweep.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from priqn.errors import PriqnError

RECOMMEND_THRESHOLD = 1.05
"""Concurrent / sequential cells per hour above which running ``jobs`` cells at a time pays
(a smaller gain is within the noise of a loaded machine and costs ``jobs`` x the memory)."""


# --------------------------------------------------------------------------- arithmetic


def cells_per_hour(cells: int, wall_s: float) -> float:
    """Cells finished per hour when ``cells`` cells took ``wall_s`` seconds of wall clock."""
    if cells < 0 or wall_s <= 0:
        raise ValueError(f"expected cells >= 0 and wall_s > 0, got {cells} and {wall_s}")
    return 3600.0 * cells / wall_s


def concurrency_ratio(sequential_per_hour: float, concurrent_per_hour: float) -> float:
    """Concurrent cells per hour over sequential cells per hour (> 1: concurrency pays)."""
    if sequential_per_hour <= 0:
        raise ValueError(f"expected sequential cells per hour > 0, got {sequential_per_hour}")
    return concurrent_per_hour / sequential_per_hour


def recommend_jobs(ratio: float, jobs: int, threshold: float = RECOMMEND_THRESHOLD) -> int:
    """Cells at a time to use: ``jobs`` if ``ratio`` (concurrent / sequential) beats
    ``threshold``, else 1."""
    return jobs if ratio > threshold else 1


def aggregate_rate(rates: list[float | None]) -> float | None:
    """Decisions/s of cells that ran at once: the sum of their rates (None if one is missing)."""
    if not rates or any(r is None for r in rates):
        return None
    return float(sum(r for r in rates if r is not None))


def scaling_ratios(aggregates: list[float | None]) -> list[float | None]:
    """Each level's aggregate decisions/s over the first level's (one cell alone)."""
    base = aggregates[0] if aggregates else None
    if base is None or base <= 0:
        return [None] * len(aggregates)
    return [None if a is None else a / base for a in aggregates]


def grid_forecast(
    per_cell_rates: dict[int, float], runs: int, decisions: int
) -> tuple[float, int, float]:
    """``(hours of one run alone, cells at a time, hours of the grid)`` from measured
    per-cell decisions/s at each level (cells at a time -> one cell's rate then).

    One run alone: ``decisions`` at the rate of level 1. The grid: ``runs`` runs of
    ``decisions`` each, ``n`` at a time, in ``ceil(runs / n)`` waves of
    ``decisions / rate(n)`` seconds; the level with the fewest hours. A last wave of fewer
    cells would run at least as fast, so the grid figure is an upper bound at that level.
    """
    if runs < 1 or decisions < 1 or not per_cell_rates or 1 not in per_cell_rates:
        raise ValueError("expected runs, decisions >= 1 and a measured rate of one cell alone")
    if min(per_cell_rates.values()) <= 0:
        raise ValueError(f"expected decisions/s > 0, got {per_cell_rates}")
    hours = {n: -(-runs // n) * decisions / rate / 3600.0 for n, rate in per_cell_rates.items()}
    best = min(hours, key=lambda n: (hours[n], n))
    return decisions / per_cell_rates[1] / 3600.0, best, hours[best]


def _positive_counts(text: str, option: str, expected: str) -> list[int]:
    """A comma-separated list of positive integers, or a one-line error naming ``option``."""
    try:
        counts = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        counts = []
    if not counts or min(counts) < 1:
        raise PriqnError(f"{option} {text}: expected {expected}")
    return counts


def parse_cells(text: str) -> list[int]:
    """``--cells``: one count (``2``) or a list of levels (``1,2,4,8``; 1 is put first)."""
    counts = _positive_counts(
        text, "--cells", "a positive number of cells or a list such as 1,2,4,8"
    )
    return counts if len(counts) == 1 else sorted(set(counts) | {1})


def parse_workers(text: str) -> list[int]:
    """``--workers``: ``[]`` (the preset's, or ``share``), one count, or a list of counts."""
    if text in ("", "share"):
        return []
    expected = "a positive number, a list such as 4,8,16, or 'share'"
    return _positive_counts(text, "--workers", expected)


def _workers(args: argparse.Namespace, cells: int, cores: int) -> tuple[str, ...]:
    """The ``num_envs`` override of a level of ``cells`` cells at a time (none: the preset's)."""
    if args.workers == "share":
        return (f"num_envs={max(1, cores // cells)}",)
    counts = parse_workers(args.workers)
    return (f"num_envs={counts[0]}",) if len(counts) == 1 else ()


def usable_cores() -> int:
    """CPU cores this process may run on (what ``priqn sweep``'s local default divides)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


# --------------------------------------------------------------------------- running cells


@dataclass
class CellRun:
    """One finished cell of one mode."""

    index: int
    """Cell number (0-based; also its training seed)."""
    elapsed_s: float
    """Wall clock of its ``priqn train`` process, start to exit."""
    decisions_per_s: float | None = None
    """Env decisions per second of its training loop (``meta.json`` steps_done / wall_s)."""


def train_command(
    runs_dir: Path,
    name: str,
    seed: int,
    agent: str,
    net: str,
    steps: int,
    device: str,
    extra: tuple[str, ...] = (),
    preset: str = "default",
) -> list[str]:
    """The ``priqn train`` command of one benchmark cell: ``preset``, ``steps``
    decisions, learning from decision ``min(500, steps // 4)`` on, no evaluation during
    training, one checkpoint (the last, without the replay buffer); ``extra`` are further
    ``KEY=VALUE`` overrides (``--set``)."""
    sets = [
        "evaluation.interval_steps=0",
        f"checkpoint.interval_steps={10 * steps}",
        "checkpoint.save_replay=false",
        f"replay.learning_starts={min(500, steps // 4)}",
        *extra,
    ]
    return [
        sys.executable, "-m", "priqn.cli", "train",
        "--preset", preset, "--agent", agent, "--net", net, "--seed", str(seed),
        "--steps", str(steps), "--device", device,
        "--runs-dir", str(runs_dir), "--name", name,
        *(arg for s in sets for arg in ("--set", s)),
    ]  # fmt: skip


def _stop(proc: subprocess.Popen, grace_s: float = 10.0) -> None:
    """SIGINT a cell's process group (training stops cleanly), SIGKILL what is left."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            pass
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)  # env workers left behind
    proc.wait()


def _last_line(path: Path) -> str:
    """The last non-empty line of a log (a failed cell's error)."""
    try:
        lines = [ln.strip() for ln in path.read_text(errors="replace").splitlines()]
    except OSError:
        return ""
    lines = [ln for ln in lines if ln]
    return lines[-1] if lines else ""


def run_cells(
    commands: list[list[str]],
    logs: list[Path],
    jobs: int,
    on_done: Callable[[int, float], None] | None = None,
    envs: list[dict[str, str]] | None = None,
) -> tuple[float, list[float]]:
    """Run ``commands`` ``jobs`` at a time, in order, each in its own process group with its
    output in ``logs[i]`` and ``envs[i]`` added to its environment; returns (wall clock of
    the whole batch, each command's elapsed s).

    ``on_done(i, elapsed_s)`` is called as each command ends. A command that fails stops
    the others and raises :class:`PriqnError` naming its log; Ctrl-C stops them all.
    """
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    queue = list(range(len(commands)))
    running: dict[int, tuple[subprocess.Popen, float, Any]] = {}
    elapsed = [0.0] * len(commands)
    t0 = time.perf_counter()
    try:
        while queue or running:
            while queue and len(running) < jobs:
                i = queue.pop(0)
                logs[i].parent.mkdir(parents=True, exist_ok=True)
                fh = logs[i].open("w")
                proc = subprocess.Popen(
                    commands[i],
                    stdout=fh,
                    stderr=subprocess.STDOUT,
                    stdin=subprocess.DEVNULL,
                    env={**env, **(envs[i] if envs else {})},
                    start_new_session=True,  # its env workers form one group with it
                )
                running[i] = (proc, time.perf_counter(), fh)
            time.sleep(0.1)
            for i, (proc, started, fh) in list(running.items()):
                rc = proc.poll()
                if rc is None:
                    continue
                elapsed[i] = time.perf_counter() - started
                del running[i]
                fh.close()
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(proc.pid, signal.SIGKILL)  # stragglers of this cell only
                if rc != 0:
                    raise PriqnError(
                        f"benchmark cell {i} failed (exit status {rc}): "
                        f"{_last_line(logs[i]) or 'no output'} (log: {logs[i]})"
                    )
                if on_done is not None:
                    on_done(i, elapsed[i])
    finally:
        for proc, _, fh in running.values():
            _stop(proc)
            fh.close()
    return time.perf_counter() - t0, elapsed


def _decisions_per_s(run_dir: Path) -> float | None:
    """Env decisions/s of a finished training run, from its ``meta.json`` (None if absent)."""
    try:
        meta = json.loads((run_dir / "meta.json").read_text())
        return float(meta["steps_done"]) / float(meta["wall_s"])
    except (OSError, ValueError, KeyError, TypeError, ZeroDivisionError):
        return None


def steady_rate(steps_wall: list[tuple[int, float]], from_fraction: float = 0.5) -> float | None:
    """Decisions/s over the last part of a run, from its episodes' ``(step, wall_s)``:
    between the first episode ending at or after ``from_fraction`` of the last step and the
    last episode. Start-up (SUMO, the first CUDA graphs or kernels) and the updates-free
    start are left out, which is what a long run's hours are made of. None with fewer than
    two such episodes."""
    if not steps_wall:
        return None
    last_step, last_wall = steps_wall[-1]
    later = [(s, w) for s, w in steps_wall if s >= from_fraction * last_step]
    first_step, first_wall = later[0]
    if len(later) < 2 or last_wall <= first_wall:
        return None
    return (last_step - first_step) / (last_wall - first_wall)


def _steady_decisions_per_s(run_dir: Path) -> float | None:
    """:func:`steady_rate` of a finished run's training episodes (``metrics.csv``)."""
    try:
        with (run_dir / "metrics.csv").open(newline="") as fh:
            rows = [r for r in csv.DictReader(fh) if r.get("kind") == "train"]
        return steady_rate([(int(r["step"]), float(r["wall_s"])) for r in rows])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def measure_mode(
    root: Path,
    mode: str,
    jobs: int,
    cells: int,
    agent: str,
    net: str,
    steps: int,
    device: str,
    gpus: list[str] | None = None,
    extra: tuple[str, ...] = (),
    preset: str = "default",
) -> dict[str, Any]:
    """Run ``cells`` benchmark cells ``jobs`` at a time into ``root/mode``; their timings.

    ``gpus``: cell i sees only ``gpus[i % len(gpus)]`` (``CUDA_VISIBLE_DEVICES``)."""
    runs_dir = root / mode
    commands = [
        train_command(runs_dir, f"cell{i}", i, agent, net, steps, device, extra, preset)
        for i in range(cells)
    ]
    logs = [runs_dir / f"cell{i}.log" for i in range(cells)]
    finished = []

    def done(i: int, elapsed_s: float) -> None:
        finished.append(i)
        rate = _decisions_per_s(runs_dir / f"cell{i}")
        rate_text = f", {rate:.1f} decisions/s" if rate is not None else ""
        print(
            f"  {mode}: cell {len(finished)}/{cells} (seed {i}) done in {elapsed_s:.1f} s"
            f"{rate_text}",
            file=sys.stderr,
            flush=True,
        )

    print(f"{mode}: {cells} cells, {jobs} at a time ...", file=sys.stderr, flush=True)
    envs = [{"CUDA_VISIBLE_DEVICES": gpus[i % len(gpus)]} for i in range(cells)] if gpus else None
    wall_s, elapsed = run_cells(commands, logs, jobs, done, envs)
    runs = [CellRun(i, elapsed[i], _decisions_per_s(runs_dir / f"cell{i}")) for i in range(cells)]
    return {
        "mode": mode,
        "jobs": jobs,
        "wall_s": wall_s,
        "cells_per_hour": cells_per_hour(cells, wall_s),
        "cells": [
            {
                "seed": r.index,
                "elapsed_s": r.elapsed_s,
                "decisions_per_s": r.decisions_per_s,
                "steady_decisions_per_s": _steady_decisions_per_s(runs_dir / f"cell{r.index}"),
            }
            for r in runs
        ],
    }


# --------------------------------------------------------------------------- CLI


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Options of ``priqn bench sweep``."""
    parser.add_argument(
        "--steps", type=int, default=4000, help="training decisions per cell (default 4000)"
    )
    parser.add_argument(
        "--cells",
        default="2",
        help="cells per mode (default 2), or a list such as 1,2,4,8: that many at a time, "
        "aggregate decisions/s against one cell",
    )
    parser.add_argument("--agent", default="iqn", help="agent every cell trains (default iqn)")
    parser.add_argument(
        "--preset", default="default", help="training preset of every cell (default default)"
    )
    parser.add_argument(
        "--workers",
        default="",
        help="env workers per cell (num_envs; default the preset's): a number; a list such as "
        "4,8,16 with --cells 1 (one cell per count, decisions/s against the first); or "
        "'share' with a --cells list (each level's cells split the cores: cores // n each)",
    )
    parser.add_argument("--net", default="tjunction", help="training pool (default tjunction)")
    parser.add_argument(
        "--jobs", type=int, default=2, help="cells at a time in the concurrent mode (default 2)"
    )
    parser.add_argument("--device", default="auto", help="auto | cpu | cuda (as priqn train)")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="further config override for every cell (repeatable), e.g. learner.compile=off",
    )
    parser.add_argument(
        "--keep", action="store_true", help="keep the temporary runs folder (its path is printed)"
    )
    parser.add_argument("--json", type=Path, default=None, help="also write the results here")
    parser.add_argument(
        "--forecast-decisions",
        type=int,
        default=2_000_000,
        help="with a --cells list: forecast runs of this many decisions (default 2,000,000)",
    )
    parser.add_argument(
        "--forecast-runs",
        type=int,
        default=33,
        help="with a --cells list: forecast a grid of this many runs (default 33: Table II)",
    )


def _check(args: argparse.Namespace) -> list[int]:
    """One-line errors for options that cannot measure anything; the ``--cells`` counts."""
    if args.steps < 1:
        raise PriqnError(f"--steps {args.steps}: expected a positive number of decisions")
    if args.forecast_runs < 1 or args.forecast_decisions < 1:
        raise PriqnError("--forecast-runs, --forecast-decisions: expected positive numbers")
    counts = parse_cells(str(args.cells))
    workers = parse_workers(args.workers)
    if len(workers) > 1 and counts != [1]:
        raise PriqnError(f"--workers {args.workers}: a list of worker counts needs --cells 1")
    if args.workers == "share" and len(counts) == 1:
        raise PriqnError("--workers share: expected a --cells list such as 1,2,4,8")
    if len(counts) > 1 or len(workers) > 1:
        return counts
    args.cells = counts[0]
    if args.jobs < 2:
        raise PriqnError(f"--jobs {args.jobs}: expected 2 or more (1 is the baseline mode)")
    if args.cells < args.jobs:
        raise PriqnError(
            f"--cells {args.cells}: expected at least --jobs ({args.jobs}) cells, "
            "else the concurrent mode never runs that many at a time"
        )
    return counts


def measure_modes(
    args: argparse.Namespace,
    plans: list[tuple[str, int, int, tuple[str, ...]]],
    gpus: list[str] | None = None,
) -> list[dict[str, Any]]:
    """:func:`measure_mode` for each ``(mode, jobs, cells, overrides)`` of ``plans`` in one
    scratch runs folder, removed afterwards unless ``--keep`` or a cell failed (its log is
    in there). ``overrides`` are the plan's own ``--set``s, after ``--set``'s."""
    root = Path(tempfile.mkdtemp(prefix="priqn-bench-sweep-"))
    keep = args.keep
    try:
        return [
            measure_mode(
                root,
                mode,
                jobs,
                cells,
                args.agent,
                args.net,
                args.steps,
                args.device,
                gpus,
                (*args.set, *overrides),
                args.preset,
            )  # fmt: skip
            for mode, jobs, cells, overrides in plans
        ]
    except PriqnError:
        keep = True
        raise
    finally:
        if keep:
            print(f"runs folder kept: {root}", file=sys.stderr)
        else:
            shutil.rmtree(root, ignore_errors=True)


def run(args: argparse.Namespace) -> int:
    """Entry point of ``priqn bench sweep``."""
    from priqn.experiment import ResourceSpec
    from priqn.sweep.scheduler import default_jobs

    counts = _check(args)
    if len(parse_workers(args.workers)) > 1:
        return run_workers(args)
    if len(counts) > 1:
        return run_scaling(args, counts)
    cores = usable_cores()
    print(
        f"priqn bench sweep: {args.cells} {args.agent} cells on {args.net}, {args.steps} "
        f"decisions each ({args.preset} preset, no evaluation), one at a time then {args.jobs} at "
        f"a time; {cores} cores, load average {os.getloadavg()[0]:.1f} at start",
        flush=True,
    )
    modes = measure_modes(
        args, [("sequential", 1, args.cells, ()), ("concurrent", args.jobs, args.cells, ())]
    )
    seq, conc = modes
    ratio = concurrency_ratio(seq["cells_per_hour"], conc["cells_per_hour"])
    best = recommend_jobs(ratio, args.jobs)
    print(f"{'mode':<11} {'jobs':>4} {'wall s':>8} {'cells/h':>8}   decisions/s per cell")
    for m in modes:
        rates = ", ".join(
            "-" if c["decisions_per_s"] is None else f"{c['decisions_per_s']:.1f}"
            for c in m["cells"]
        )
        print(
            f"{m['mode']:<11} {m['jobs']:>4} {m['wall_s']:>8.1f} {m['cells_per_hour']:>8.1f}   "
            f"{rates}"
        )
    print(f"concurrent / sequential: {ratio:.2f}x cells per hour")
    verdict = "<=" if best == 1 else ">"
    print(
        f"recommended: jobs={best} (ratio {ratio:.2f} {verdict} {RECOMMEND_THRESHOLD}) on "
        f"{cores} cores; priqn sweep's local default here with the default [resources] "
        f"(cpus_per_cell = {ResourceSpec().cpus_per_cell:g}): "
        f"{default_jobs(ResourceSpec())} at a time; --jobs N overrides it"
    )
    if args.json is not None:
        args.json.write_text(
            json.dumps(
                {
                    "agent": args.agent,
                    "net": args.net,
                    "steps": args.steps,
                    "cells": args.cells,
                    "cores": cores,
                    "sequential": seq,
                    "concurrent": conc,
                    "ratio": ratio,
                    "recommended_jobs": best,
                },
                indent=2,
            )
            + "\n"
        )
    return 0


def _cell_gpus(device: str) -> list[str] | None:
    """GPU ids to pin scaling cells to round-robin: None off CUDA or with one GPU."""
    if not device.startswith("cuda") or ":" in device:
        return None
    from priqn.sweep.backends import visible_gpus

    ids = visible_gpus()
    return ids if len(ids) > 1 else None


def _header(args: argparse.Namespace, what: str, cores: int, pinned: str = "") -> None:
    print(
        f"priqn bench sweep: {args.agent} cells on {args.net}, {args.steps} decisions each "
        f"({args.preset} preset, no evaluation), {what} on device {args.device}{pinned}; "
        f"{cores} cores, load average {os.getloadavg()[0]:.1f} at start",
        flush=True,
    )


def _level_rates(level: dict[str, Any]) -> tuple[float | None, float | None]:
    """(aggregate decisions/s start-up included, aggregate steady decisions/s) of a level."""
    cells = level["cells"]
    return (
        aggregate_rate([c["decisions_per_s"] for c in cells]),
        aggregate_rate([c["steady_decisions_per_s"] for c in cells]),
    )


def _print_levels(label: str, keys: list[int], levels: list[dict[str, Any]]) -> list[float | None]:
    """The table of a scaling measurement; each level's steady aggregate (None: unmeasured).
    Ratios are steady aggregate over the first level's."""
    overall, steady = zip(*(_level_rates(m) for m in levels), strict=True)
    ratios = scaling_ratios(list(steady))
    print(
        f"{label:>7} {'wall s':>8} {'decisions/s':>12} {'steady':>9} {'per cell':>9} {'x first':>8}"
    )
    for key, m, agg, st, ratio in zip(keys, levels, overall, steady, ratios, strict=True):
        m.update(aggregate_decisions_per_s=agg, steady_decisions_per_s=st, ratio=ratio)
        cells = len(m["cells"])
        print(
            f"{key:>7} {m['wall_s']:>8.1f} {_num(agg):>12} {_num(st):>9} "
            f"{_num(None if st is None else st / cells):>9} "
            f"{'-' if ratio is None else f'{ratio:.2f}x':>8}"
        )
    print(
        "(decisions/s: steps / wall of each cell's training loop, start-up included; steady: "
        "over the second half of its decisions; summed over a level's cells)"
    )
    return list(steady)


def _num(x: float | None) -> str:
    return "-" if x is None else f"{x:.1f}"


def _write_json(args: argparse.Namespace, cores: int, **fields: Any) -> None:
    if args.json is None:
        return
    head = {"agent": args.agent, "net": args.net, "preset": args.preset, "steps": args.steps,
            "device": args.device, "cores": cores}  # fmt: skip
    args.json.write_text(json.dumps({**head, **fields}, indent=2) + "\n")


def run_workers(args: argparse.Namespace) -> int:
    """``--workers 4,8,16 --cells 1``: one cell per worker count; decisions/s against the first."""
    cores, counts = usable_cores(), parse_workers(args.workers)
    _header(args, f"one cell with {', '.join(map(str, counts))} env workers", cores)
    levels = measure_modes(args, [(f"w{w}", 1, 1, (f"num_envs={w}",)) for w in counts])
    _print_levels("workers", counts, levels)
    _write_json(args, cores, workers=counts, levels=levels)
    return 0


def run_scaling(args: argparse.Namespace, counts: list[int]) -> int:
    """``--cells 1,2,4,...``: each level's cells at once; aggregate decisions/s vs one cell,
    and the forecast of a grid on this box from the steady per-cell rates."""
    cores = usable_cores()
    gpus = _cell_gpus(args.device)
    pinned = f", pinned round-robin to GPUs {','.join(gpus)}" if gpus else ""
    what = f"{', '.join(map(str, counts))} at a time" + (
        " (each level's cells share the cores)" if args.workers == "share" else ""
    )
    _header(args, what, cores, pinned)
    levels = measure_modes(args, [(f"x{n}", n, n, _workers(args, n, cores)) for n in counts], gpus)
    steady = _print_levels("cells", counts, levels)
    best = max(
        (i for i in range(len(counts)) if steady[i] is not None),
        key=lambda i: steady[i] or 0.0,
        default=None,
    )
    if best is not None:
        n = counts[best]
        share = (
            f"; in a local sweep: gpus_per_cell = {len(gpus or [0]) / n:.3g}"
            if args.device.startswith("cuda")
            else ""
        )
        print(
            f"most decisions/s: {n} cell(s) at a time ({levels[best]['ratio']:.2f}x one cell){share}"
        )
    rates = {n: a / n for n, a in zip(counts, steady, strict=True) if a is not None}
    if 1 in rates:
        one, n, grid = grid_forecast(rates, args.forecast_runs, args.forecast_decisions)
        alone = " ".join(_workers(args, 1, cores)) or "the preset's num_envs"
        print(
            f"forecast on this box: one {args.forecast_decisions:,}-decision run {one:.2f} h "
            f"({alone}; --cells 1 --workers 4,8,16 finds the fastest count for one run); "
            f"{args.forecast_runs} such runs {grid:.1f} h at {n} cell(s) at a time (steady "
            f"training-loop rates of these {args.steps:,}-decision {args.agent} cells; no "
            "evaluation, no start-up)"
        )
    _write_json(args, cores, levels=levels)
    return 0
