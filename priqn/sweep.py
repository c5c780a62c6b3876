"""``priqn sweep``: train, evaluate and report a whole experiment grid.

An experiment file (``experiments/<name>.toml``) names a grid: policies (agent and
preorder options) × training seeds, the training preset and budget, the scenario
family and the evaluation settings. :func:`expand` turns it into :class:`Cell` s, one
run folder each (``<runs_dir>/<experiment>/<policy>__seed<k>/``); :func:`run_sweep`
trains and evaluates every cell that is not complete yet, then runs the report.

Every cell runs in its own child process (``python -m priqn.sweep --cell SPEC``):
libsumo allows one simulation per process, a crash or an out-of-memory kill takes
down one cell and not the sweep, the child's output goes to a log file that ends
with the cell's one-line error (:data:`ERROR_MARK`), and Ctrl-C can stop a cell by
signalling its process group. The same child command runs locally (a pool of ``--jobs`` slots) or
inside Ray tasks (:mod:`priqn.sweep_ray`), so both back-ends produce the same run
folders. A cell is complete iff its run's ``meta.json`` and its ``eval/meta.json``
both say ``"status": "complete"`` (docs/ARCHITECTURE.md); completion is always read
from the run folders, never from the sweep's memory, so a re-run skips finished
cells and resumes interrupted ones.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import fnmatch
import importlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from concurrent import futures
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from priqn import paths
from priqn.agents.config import AGENT_SPECS
from priqn.config import config_differences, from_dict, load_toml, to_dict
from priqn.errors import PriqnError
from priqn.io import atomic_open, atomic_write_json
from priqn.runs import RunFolder

DEFAULT_CELL_FN = "priqn.sweep:train_and_evaluate"
"""Import path of the function a cell's child process runs (tests substitute fast ones)."""

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
_SWEEP_DIR = ".sweep"
_STOP_GRACE_S = 10.0

# --------------------------------------------------------------------------- experiment file


@dataclass(frozen=True)
class ExperimentSpec:
    """The ``[experiment]`` table: what every cell of the grid shares."""

    name: str
    """Experiment name (letters, digits, ``._-``); cells run in ``<runs_dir>/<name>/``."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """Training seeds; every policy is trained once per seed."""
    net: str = "all"
    """Scenario family trained on: ``tjunction``, ``fourway`` or ``all`` (both pools)."""
    preset: str = "default"
    """Training preset (``priqn train --preset``)."""
    steps: int | None = None
    """Training budget in agent decisions per cell; unset keeps the preset's."""
    set: tuple[str, ...] = ()
    """TrainConfig overrides ``KEY=VALUE`` (as ``priqn train --set``) for every cell."""
    runs_dir: str = "runs"
    """Folder holding the experiment's run folders (relative to the working directory)."""
    report_dir: str | None = None
    """Where the report goes; unset: ``reports/<name>`` (relative to the working directory)."""
    report_seed: int = 0
    """Seed of the report's bootstrap confidence intervals."""
    description: str = ""
    """Free text: what this grid reproduces."""


@dataclass(frozen=True)
class ResourceSpec:
    """The ``[resources]`` table: what one cell needs (local pool size, Ray task options)."""

    cpus_per_cell: float = 2.0
    """CPU cores one cell keeps busy (learner + env worker processes)."""
    gpus_per_cell: float = 0.0
    """GPUs one cell needs (Ray ``num_gpus``; fractions share a GPU)."""


@dataclass(frozen=True)
class PolicySpec:
    """One ``[[policy]]`` entry: a row of the results table, trained once per seed."""

    name: str
    """Row name, used in run-folder names (letters, digits, ``._-``)."""
    agent: str
    """Agent to train (``priqn train --agent``: iqn, ensemble-iqn, ma-iqn, pr-iqn)."""
    comparator: str | None = None
    """Pr-IQN: distribution comparison metric."""
    train_preorder: bool | None = None
    """Pr-IQN: bootstrap each head from its optimal subset (preorder used in training)."""
    eps: float | None = None
    """Pr-IQN: comparison threshold epsilon."""
    preorder: str | None = None
    """Pr-IQN: objective preorder, ``total`` | ``partial`` or a preorder TOML file."""
    normalisation: str | None = None
    """Pr-IQN: quantile normalisation, ``zscore`` (the paper) | ``scaled`` (docs/preorder.md)."""
    set: tuple[str, ...] = ()
    """Further TrainConfig overrides ``KEY=VALUE`` for this row (after the experiment's)."""


_PREORDER_OPTIONS = ("comparator", "train_preorder", "eps", "preorder", "normalisation")
COMPARATORS = ("qd", "mv", "cvar", "fsd")
"""Comparison metrics of Table II (``priqn.preorder.COMPARATORS``; a test keeps them equal)."""
NORMALISATIONS = ("zscore", "scaled")
"""Quantile normalisations (``priqn.agents.config.NORMALISATIONS``)."""
PREORDERS = ("total", "partial")
"""Preorder presets (``priqn.preorder.PRESETS``; a test keeps them equal)."""

# Policy option -> TrainConfig key (``priqn train --set`` name).
_TRAIN_KEYS = {
    "agent": "agent.name",
    "comparator": "agent.comparator",
    "train_preorder": "agent.train_preorder",
    "eps": "agent.eps",
    "preorder": "agent.preorder",
    "normalisation": "agent.normalisation",
}


@dataclass(frozen=True)
class Experiment:
    """A parsed experiment file."""

    path: Path
    """The TOML file it came from (named in errors)."""
    experiment: ExperimentSpec
    """Shared settings."""
    policies: tuple[PolicySpec, ...]
    """The rows of the grid, in file order."""
    evaluate: dict[str, Any] = field(default_factory=dict)
    """EvalConfig fields (``priqn.evaluate.EvalConfig``) for every cell."""
    resources: ResourceSpec = ResourceSpec()
    """Per-cell resource needs."""

    @property
    def runs_dir(self) -> Path:
        """``<runs_dir>/<name>``: the folder holding this experiment's run folders."""
        return Path(self.experiment.runs_dir) / self.experiment.name

    @property
    def report_dir(self) -> Path:
        """Where :func:`run_sweep` writes the report."""
        return Path(self.experiment.report_dir or Path("reports") / self.experiment.name)


def resolve_experiment_path(name_or_path: str | os.PathLike) -> Path:
    """A path, or a bare name: ``table2`` -> ``./experiments/table2.toml``, else the shipped one."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    if p.suffix == "" and len(p.parts) == 1:
        dirs = paths.search_path(paths.EXPERIMENTS)
        for d in dirs:
            if (d / f"{p.name}.toml").is_file():
                return d / f"{p.name}.toml"
        known = sorted({q.stem for d in dirs for q in d.glob("*.toml")})
        raise PriqnError(
            f"{p}: no such experiment file (known in ./experiments/ and shipped: {', '.join(known) or 'none'})"
        )
    raise PriqnError(f"{p}: file not found")


def load_experiment(
    path: str | os.PathLike,
    runs_dir: str | os.PathLike | None = None,
    cpus_per_cell: float | None = None,
    gpus_per_cell: float | None = None,
) -> Experiment:
    """Parse and check an experiment file; every mistake is one line naming file and key.

    ``runs_dir`` / ``cpus_per_cell`` / ``gpus_per_cell`` override the file's values.
    """
    p = resolve_experiment_path(path)
    data = load_toml(p)
    sections = {"experiment", "policy", "evaluate", "resources"}
    unknown = sorted(set(data) - sections)
    if unknown:
        raise PriqnError(
            f"{p}: unknown section {unknown[0]!r} (valid: {', '.join(sorted(sections))})"
        )
    if "experiment" not in data:
        raise PriqnError(f"{p}: missing [experiment] table (name, seeds, net, preset, steps)")
    exp = from_dict(ExperimentSpec, data["experiment"], where=f"{p} [experiment]")
    _check_name(exp.name, f"{p} [experiment].name")
    if not exp.seeds:
        raise PriqnError(
            f"{p} [experiment].seeds: empty; expected at least one seed, e.g. [0, 1, 2]"
        )
    if len(set(exp.seeds)) != len(exp.seeds):
        raise PriqnError(f"{p} [experiment].seeds: duplicate seeds in {list(exp.seeds)}")
    if any(s < 0 for s in exp.seeds):
        raise PriqnError(f"{p} [experiment].seeds: seeds must be >= 0, got {list(exp.seeds)}")
    if exp.steps is not None and exp.steps <= 0:
        raise PriqnError(f"{p} [experiment].steps: expected a positive integer, got {exp.steps}")
    _check_overrides(exp.set, f"{p} [experiment].set")

    raw_policies = data.get("policy", [])
    if not isinstance(raw_policies, list) or not raw_policies:
        raise PriqnError(f"{p}: expected one or more [[policy]] tables (name, agent, options)")
    policies = []
    seen: set[str] = set()
    for i, raw in enumerate(raw_policies, start=1):
        label = raw.get("name", f"#{i}") if isinstance(raw, dict) else f"#{i}"
        where = f"{p} [[policy]] {label}"
        pol = from_dict(PolicySpec, raw, where=where)
        _check_name(pol.name, f"{where}.name")
        if pol.agent not in AGENT_SPECS:
            raise PriqnError(
                f"{where}.agent: unknown agent {pol.agent!r} (valid: {', '.join(AGENT_SPECS)})"
            )
        if pol.name in seen:
            raise PriqnError(f"{where}.name: duplicate policy name {pol.name!r}")
        seen.add(pol.name)
        if pol.agent != "pr-iqn":
            for opt in _PREORDER_OPTIONS:
                if getattr(pol, opt) is not None:
                    raise PriqnError(
                        f"{where}.{opt}: applies only to agent 'pr-iqn', not {pol.agent!r}"
                    )
        for opt, valid in (
            ("comparator", COMPARATORS),
            ("preorder", PREORDERS),
            ("normalisation", NORMALISATIONS),
        ):
            value = getattr(pol, opt)
            custom_preorder = opt == "preorder" and str(value).endswith(".toml")
            if value is not None and value not in valid and not custom_preorder:
                raise PriqnError(
                    f"{where}.{opt}: expected one of {', '.join(map(repr, valid))}"
                    + (" or a preorder .toml file" if opt == "preorder" else "")
                    + f", got {value!r}"
                )
        if pol.eps is not None and pol.eps < 0:
            raise PriqnError(f"{where}.eps: expected a threshold >= 0, got {pol.eps}")
        _check_overrides(pol.set, f"{where}.set")
        policies.append(pol)

    evaluate = data.get("evaluate", {})
    if not isinstance(evaluate, dict):
        raise PriqnError(f"{p} [evaluate]: expected a table of EvalConfig fields")
    res_data = dict(data.get("resources", {}))
    for key, value in (("cpus_per_cell", cpus_per_cell), ("gpus_per_cell", gpus_per_cell)):
        if value is not None:
            res_data[key] = value
    resources = from_dict(ResourceSpec, res_data, where=f"{p} [resources]")
    if resources.cpus_per_cell <= 0 or resources.gpus_per_cell < 0:
        raise PriqnError(
            f"{p} [resources]: cpus_per_cell must be > 0 and gpus_per_cell >= 0, "
            f"got {resources.cpus_per_cell} and {resources.gpus_per_cell}"
        )
    # Absolute, so Ray workers (whose working directory differs) write to the same place.
    exp = dataclasses.replace(exp, runs_dir=str(Path(runs_dir or exp.runs_dir).absolute()))
    return Experiment(p, exp, tuple(policies), dict(evaluate), resources)


def _check_name(name: str, where: str) -> None:
    if not _NAME_RE.match(name):
        raise PriqnError(
            f"{where}: {name!r} is not a safe folder name; use letters, digits, '.', '_' or '-'"
        )


def _check_overrides(items: Sequence[str], where: str) -> None:
    for item in items:
        if "=" not in item or not item.split("=", 1)[0].strip():
            raise PriqnError(f'{where}: {item!r} is not KEY=VALUE, e.g. "learner.lr=1e-4"')


# --------------------------------------------------------------------------- cells


@dataclass(frozen=True)
class Cell:
    """One (policy, seed) pair of the grid: one training run and its evaluation."""

    experiment: str
    """Experiment name."""
    policy: str
    """Policy (row) name."""
    seed: int
    """Training seed."""
    run_dir: Path
    """Run folder: ``<runs_dir>/<experiment>/<policy>__seed<seed>``."""
    agent: str
    """Agent name (``priqn train --agent``)."""
    net: str
    """Scenario family (``priqn train --net``)."""
    preset: str
    """Training preset (``priqn train --preset``)."""
    steps: int | None
    """Training budget (``priqn train --steps``); None keeps the preset's."""
    overrides: tuple[str, ...]
    """TrainConfig ``KEY=VALUE`` overrides, in the order they apply."""
    evaluate: dict[str, Any]
    """EvalConfig fields."""
    source: str
    """Experiment file, named in the child's errors."""

    @property
    def name(self) -> str:
        """``<experiment>/<policy>__seed<k>``: unique, readable, filesystem-safe."""
        return f"{self.experiment}/{self.policy}__seed{self.seed}"

    def to_spec(self) -> dict[str, Any]:
        """JSON-able description handed to the cell's child process."""
        return {**to_dict(self), "name": self.name}

    @classmethod
    def from_spec(cls, spec: dict[str, Any]) -> Cell:
        """Inverse of :meth:`to_spec`."""
        names = {f.name for f in dataclasses.fields(cls)}
        kw = {k: v for k, v in spec.items() if k in names}
        kw["run_dir"] = Path(kw["run_dir"])
        kw["overrides"] = tuple(kw["overrides"])
        return cls(**kw)


def policy_overrides(policy: PolicySpec) -> list[str]:
    """TrainConfig overrides (``KEY=VALUE``) a policy's options stand for, then its ``set``."""
    out = []
    for opt in _PREORDER_OPTIONS:
        value = getattr(policy, opt)
        if value is not None:
            out.append(f"{_TRAIN_KEYS[opt]}={_toml_value(value)}")
    return out + list(policy.set)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    return repr(value)


def expand(exp: Experiment) -> list[Cell]:
    """All cells of the grid: policies in file order, seeds in file order within each."""
    e = exp.experiment
    cells = []
    for pol in exp.policies:
        overrides = tuple(e.set) + tuple(policy_overrides(pol))
        for seed in e.seeds:
            cells.append(
                Cell(
                    experiment=e.name,
                    policy=pol.name,
                    seed=seed,
                    run_dir=exp.runs_dir / f"{pol.name}__seed{seed}",
                    agent=pol.agent,
                    net=e.net,
                    preset=e.preset,
                    steps=e.steps,
                    overrides=overrides,
                    evaluate=dict(exp.evaluate),
                    source=str(exp.path),
                )
            )
    return cells


def cell_state(run_dir: Path) -> str:
    """``complete`` | ``trained`` (eval missing) | ``running`` | ``interrupted`` (its trainer
    died) | ``failed`` | ``new``.

    Read from the run folder only: ``meta.json`` and ``eval/meta.json`` statuses.
    ``running`` may also be a run whose sweep was killed; the next sweep resumes it.
    """
    folder = RunFolder(run_dir)
    run = folder.recorded_status()
    if run == "running" and folder.status() == "interrupted":
        return "interrupted"  # its trainer died (kill -9, crash): the next sweep resumes it
    if run == "complete":
        return "complete" if folder.recorded_eval_status() == "complete" else "trained"
    if run in ("running", "failed"):
        return run
    return "new"


def is_complete(run_dir: Path) -> bool:
    """A cell is complete iff training and evaluation both say ``"status": "complete"``."""
    return cell_state(run_dir) == "complete"


# --------------------------------------------------------------------------- one cell (child)


def build_train_config(cell: Cell) -> Any:
    """The cell's resolved :class:`priqn.train_config.TrainConfig` (preset, agent, seed, net, steps, overrides)."""
    from priqn.train_config import resolve_config

    return resolve_config(
        preset=cell.preset,
        agent=cell.agent,
        seed=cell.seed,
        net=cell.net,
        steps=cell.steps,
        overrides=list(cell.overrides),
        where=f"{cell.source} ({cell.policy})",
    )


def build_eval_config(cell: Cell) -> Any:
    """The cell's :class:`priqn.evaluate.EvalConfig` from the experiment's ``[evaluate]``."""
    from priqn.evaluate import EvalConfig

    return from_dict(EvalConfig, cell.evaluate, where=f"{cell.source} [evaluate]")


def train_and_evaluate(cell: Cell) -> None:
    """Run one cell to completion: train (resuming an interrupted run), then evaluate."""
    from priqn.evaluate import evaluate_run
    from priqn.train import train

    state = cell_state(cell.run_dir)
    if state not in ("complete", "trained"):
        cfg = build_train_config(cell)
        has_checkpoint = RunFolder(cell.run_dir).latest_checkpoint.is_file()
        if has_checkpoint:
            train(cfg, cell.run_dir, resume=True)
        else:
            # Nothing to resume (new, or killed before its first checkpoint): start over.
            train(cfg, cell.run_dir, force=cell.run_dir.exists())
    if not is_complete(cell.run_dir):
        evaluate_run(cell.run_dir, build_eval_config(cell))


def _cell_main(spec_json: str) -> int:
    """Body of ``python -m priqn.sweep --cell SPEC``: one cell in this (child) process."""
    spec = json.loads(spec_json)
    _die_with_parent(spec.get("parent_pid"))
    # An ignored or blocked SIGINT is inherited through exec (Ray workers block it;
    # `nohup` and `cmd &` ignore it); the sweep stops a cell with SIGINT so that
    # training can mark its run interrupted, so take it back.
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    signal.signal(signal.SIGINT, signal.default_int_handler)
    module_name, _, fn_name = spec.get("cell_fn", DEFAULT_CELL_FN).partition(":")
    fn = getattr(importlib.import_module(module_name), fn_name)
    cell = Cell.from_spec(spec)
    where = f" on Ray node {spec['ray_node']}" if spec.get("ray_node") else ""
    print(
        f"priqn sweep: cell {cell.name} (attempt {spec.get('attempt', 1)}) pid {os.getpid()}"
        f" host {socket.gethostname()}{where}"
    )
    sys.stdout.flush()
    try:
        fn(cell)
        return 0
    except KeyboardInterrupt:
        error, rc = "interrupted", 130
    except PriqnError as exc:
        error, rc = f"priqn: error: {exc}", 2
    except Exception as exc:  # noqa: BLE001 - any failure of a cell becomes its one-line error
        traceback.print_exc()
        error, rc = " ".join(f"{type(exc).__name__}: {exc}".split()), 1
    sys.stdout.flush()
    print(ERROR_MARK + error, file=sys.stderr, flush=True)
    return rc


# --------------------------------------------------------------------------- running a child


def cell_command(spec: dict[str, Any]) -> list[str]:
    """The child command that runs one cell (same locally and inside a Ray task)."""
    return [sys.executable, "-m", "priqn.sweep", "--cell", json.dumps(spec, sort_keys=True)]


def _die_with_parent(parent_pid: int | None) -> None:
    """Linux: SIGTERM this child when the process that started it dies (a killed sweep or Ray worker)."""
    if not sys.platform.startswith("linux") or parent_pid is None:
        return
    with contextlib.suppress(Exception):
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        sys.exit("priqn sweep: the sweep that started this cell is gone")


def _stop_group(proc: subprocess.Popen, grace_s: float = _STOP_GRACE_S) -> None:
    """SIGINT the child's process group (lets training checkpoint), SIGKILL after ``grace_s``."""
    if proc.poll() is not None:
        return
    for sig, wait_s in ((signal.SIGINT, grace_s), (signal.SIGKILL, 5.0)):
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, sig)
        try:
            proc.wait(timeout=wait_s)
            return
        except subprocess.TimeoutExpired:
            continue


def log_tail(path: Path, lines: int = 1) -> str:
    """Last ``lines`` non-empty lines of a log (the one-line error of a failed cell)."""
    try:
        with path.open("rb") as fh:
            fh.seek(0, os.SEEK_END)
            fh.seek(max(0, fh.tell() - 16384))
            text = fh.read().decode("utf-8", errors="replace")
    except OSError:
        return ""
    kept = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return "\n".join(kept[-lines:])


def run_cell_process(
    spec: dict[str, Any], log_path: Path, stop: threading.Event | None = None
) -> tuple[int, str, bool]:
    """Run one cell's child process to its end: (exit status, one-line error, complete).

    ``complete`` is read from the run folder right here, where the cell ran (on a
    Ray node without a shared runs folder the driver could not see it).

    Output (stdout + stderr) goes to ``log_path`` through a temp file renamed when the
    child ends. ``stop`` (or an exception such as KeyboardInterrupt in this thread)
    stops the child's whole process group; the log is kept and the exception re-raised.
    When the child ends, whatever is left of its process group (env workers) is
    killed. A negative status is the signal that killed the child.
    """
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    spec = {**spec, "parent_pid": os.getpid()}
    log_path.parent.mkdir(parents=True, exist_ok=True)
    interrupted: BaseException | None = None
    with atomic_open(log_path, "w") as log:
        proc = subprocess.Popen(
            cell_command(spec),
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            env=env,
            start_new_session=True,  # own process group: Ctrl-C reaches it only through us
        )
        try:
            while True:
                try:
                    rc = proc.wait(timeout=0.25)
                    break
                except subprocess.TimeoutExpired:
                    if stop is not None and stop.is_set():
                        _stop_group(proc)
                        rc = proc.wait()
                        break
        except BaseException as exc:  # KeyboardInterrupt (Ray task cancelled), SystemExit
            interrupted = exc
            _stop_group(proc)
            rc = proc.wait()
        finally:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(proc.pid, signal.SIGKILL)  # stragglers of this cell only
    if interrupted is not None:
        raise interrupted
    return rc, cell_error(log_path), is_complete(Path(spec["run_dir"]))


ERROR_MARK = "priqn sweep: cell failed: "
"""Prefix of the one-line error a cell's child prints last when it fails."""


def cell_error(log_path: Path) -> str:
    """A cell's one-line error: its last ``ERROR_MARK`` line, else its last output line."""
    tail = log_tail(log_path, lines=200)
    marked = [ln for ln in tail.splitlines() if ln.startswith(ERROR_MARK)]
    if marked:
        return marked[-1][len(ERROR_MARK) :]
    return tail.splitlines()[-1] if tail else ""


def describe_failure(rc: int, tail: str) -> str:
    """One line for a cell that ended with status ``rc`` and last log line ``tail``."""
    if rc < 0:
        try:
            name = signal.Signals(-rc).name
        except ValueError:
            name = f"signal {-rc}"
        hint = " (out of memory?)" if -rc == signal.SIGKILL else ""
        return f"killed by {name}{hint}" + (f"; last output: {tail}" if tail else "")
    if rc == 0:
        return "exited normally but its run is not marked complete" + (
            f"; last output: {tail}" if tail else ""
        )
    return tail or f"exited with status {rc} and no output"


# --------------------------------------------------------------------------- back-ends


class LocalBackend:
    """Runs cells as child processes on this machine, ``jobs`` at a time."""

    def __init__(self, jobs: int) -> None:
        self.slots = max(1, jobs)
        self._stop = threading.Event()
        self._pool = futures.ThreadPoolExecutor(max_workers=self.slots, thread_name_prefix="cell")

    def describe(self) -> str:
        return f"local pool, {self.slots} cell(s) at a time"

    def submit(self, spec: dict[str, Any], log_path: Path) -> futures.Future:
        return self._pool.submit(run_cell_process, spec, log_path, self._stop)

    def wait(self, handles: list[Any], timeout_s: float) -> list[tuple[Any, int, str, bool]]:
        done, _ = futures.wait(handles, timeout=timeout_s, return_when=futures.FIRST_COMPLETED)
        out = []
        for h in done:
            try:
                out.append((h, *h.result()))
            except PriqnError as exc:
                out.append((h, 1, str(exc), False))
            except OSError as exc:
                out.append((h, 1, f"could not start the cell process: {exc}", False))
        return out

    def cancel(self, handles: list[Any]) -> None:
        self._stop.set()
        futures.wait(handles, timeout=_STOP_GRACE_S + 10.0)

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


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


@contextlib.contextmanager
def _sweep_lock(exp_dir: Path) -> Iterator[None]:
    """One sweep per experiment folder at a time (advisory lock, released on exit)."""
    import fcntl

    lock_path = exp_dir / _SWEEP_DIR / "lock"
    lock_path.parent.mkdir(parents=True, exist_ok=True)
    with lock_path.open("a") as fh:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise PriqnError(
                f"{exp_dir}: another 'priqn sweep' is running this experiment "
                f"(lock {lock_path}); wait for it or stop it first"
            ) from None
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def default_jobs(resources: ResourceSpec) -> int:
    """Cells at a time on this machine: ``max(1, cores // cpus_per_cell)``."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, int((cores or 1) // resources.cpus_per_cell))


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
) -> SweepResult:
    """Train and evaluate every incomplete cell, retrying failures ``retries`` times, then report.

    ``use_ray`` runs cells as Ray tasks (``ray_address`` None: a new local Ray cluster;
    ``"auto"`` or an address: an existing one); otherwise a local pool of ``jobs``
    child processes (default :func:`default_jobs`). ``only`` keeps cells whose name
    matches one of the glob patterns. A failing cell never stops the others.
    Ctrl-C stops the running cells (they stay incomplete) and re-raises
    KeyboardInterrupt after writing the sweep summary.
    """
    say = log or (lambda msg: print(msg, file=sys.stderr))
    cells = expand(exp)
    if only:
        cells = [c for c in cells if any(fnmatch.fnmatch(c.name, pat) for pat in only)]
        if not cells:
            raise PriqnError(f"--only {' '.join(only)}: matches no cell of {exp.path}")
    exp_dir = exp.runs_dir
    exp_dir.mkdir(parents=True, exist_ok=True)
    result = SweepResult()
    with _sweep_lock(exp_dir):
        todo = []
        for c in cells:
            if is_complete(c.run_dir):
                result.skipped.append(c.name)
            else:
                todo.append(c)
        if todo:
            if use_ray:
                from priqn.sweep_ray import RayBackend

                backend: Any = RayBackend(ray_address, exp.resources, jobs)
            else:
                backend = LocalBackend(jobs or default_jobs(exp.resources))
            say(
                f"priqn sweep {exp.experiment.name}: {len(cells)} cells, "
                f"{len(result.skipped)} already complete, {len(todo)} to run ({backend.describe()})"
            )
            try:
                _schedule(backend, todo, exp, result, retries, cell_fn, progress, say)
            finally:
                backend.close()
                _write_summary(exp, cells, result)
        else:
            say(f"priqn sweep {exp.experiment.name}: all {len(cells)} cells already complete")
            _write_summary(exp, cells, result)
    if report and not result.interrupted:
        missing = [c.name for c in expand(exp) if not is_complete(c.run_dir)]
        if missing:
            say(
                f"priqn sweep: report skipped: {len(missing)} cell(s) not complete "
                f"(e.g. {missing[0]}); a report never mixes in missing runs"
            )
        else:
            result.report = _run_report(exp, say)
    return result


def _schedule(
    backend: Any,
    todo: list[Cell],
    exp: Experiment,
    result: SweepResult,
    retries: int,
    cell_fn: str,
    progress: bool | None,
    say: Callable[[str], None],
) -> None:
    from tqdm.auto import tqdm

    queue: list[tuple[Cell, int]] = [(c, 1) for c in todo]
    inflight: dict[Any, tuple[Cell, int]] = {}
    slots = backend.slots
    show_bar = sys.stderr.isatty() if progress is None else progress
    bar = tqdm(
        total=len(todo),
        unit="cell",
        desc=exp.experiment.name,
        disable=not show_bar,
        dynamic_ncols=True,
        file=sys.stderr,
    )
    started = time.monotonic()

    def counts() -> str:
        return (
            f"done={len(result.completed)} running={len(inflight)} "
            f"failed={len(result.failed)} queued={len(queue)}"
        )

    def note(msg: str) -> None:
        if show_bar:
            tqdm.write(msg, file=sys.stderr)
        else:
            say(msg)

    def finished(cell: Cell, what: str) -> None:
        bar.update(1)
        if not show_bar:  # a log file or a batch job: one line per finished cell
            n = len(result.completed) + len(result.failed)
            rate_s = (time.monotonic() - started) / n
            eta = tqdm.format_interval(rate_s * (len(todo) - n))
            say(f"[{n}/{len(todo)}] {cell.name} {what} ({counts()}, ETA {eta})")

    try:
        while queue or inflight:
            while queue and (slots is None or len(inflight) < slots):
                cell, attempt = queue.pop(0)
                spec = {**cell.to_spec(), "attempt": attempt, "cell_fn": cell_fn}
                log_path = (
                    exp.runs_dir
                    / _SWEEP_DIR
                    / "logs"
                    / f"{cell.policy}__seed{cell.seed}.attempt{attempt}.log"
                )
                inflight[backend.submit(spec, log_path)] = (cell, attempt)
            bar.set_postfix_str(counts(), refresh=True)
            for handle, rc, tail, complete in backend.wait(list(inflight), timeout_s=1.0):
                cell, attempt = inflight.pop(handle)
                if rc == 0 and complete:
                    result.completed.append(cell.name)
                    finished(cell, "complete")
                    continue
                error = describe_failure(rc, tail)
                if attempt <= retries:
                    result.retried.append(cell.name)
                    note(f"cell {cell.name} failed (attempt {attempt}): {error}; retrying")
                    queue.append((cell, attempt + 1))
                else:
                    result.failed[cell.name] = error
                    note(f"cell {cell.name} FAILED: {error}")
                    finished(cell, "FAILED")
            bar.set_postfix_str(counts(), refresh=True)
    except KeyboardInterrupt:
        result.interrupted = True
        note(f"interrupted: stopping {len(inflight)} running cell(s); they stay incomplete")
        backend.cancel(list(inflight))
        raise
    finally:
        bar.close()


def _write_summary(exp: Experiment, cells: list[Cell], result: SweepResult) -> None:
    states = {c.name: cell_state(c.run_dir) for c in cells}
    atomic_write_json(
        exp.runs_dir / _SWEEP_DIR / "summary.json",
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
        from priqn.analysis.report import make_report
    except ModuleNotFoundError as exc:
        say(f"priqn sweep: report skipped ({exc.name} is not installed)")
        return None
    out = make_report(
        exp.runs_dir,
        exp.report_dir,
        seed=exp.experiment.report_seed,
        command=f"priqn sweep {exp.path}",
    )
    say(f"priqn sweep: report in {out}")
    return Path(out)


# --------------------------------------------------------------------------- CLI


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """``priqn sweep EXPERIMENT [--jobs N | --ray [ADDRESS]] ...``."""
    parser.add_argument(
        "experiment",
        help="experiment file, or a name: ./experiments/NAME.toml, else shipped (table2, smoke)",
    )
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
    parser.add_argument(
        "--list", action="store_true", help="list the cells and their state; run nothing"
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
    if args.list:
        for c in expand(exp):
            print(f"{c.name:<48} {cell_state(c.run_dir):<9} {c.run_dir}")
        return 0
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
    result = run_sweep(
        exp,
        jobs=args.jobs,
        use_ray=args.ray is not None,
        ray_address=args.ray or None,
        retries=args.retries,
        only=args.only,
        report=not args.no_report,
        cell_fn=args.cell_fn,
    )
    print(
        f"priqn sweep {exp.experiment.name}: {len(result.complete)} complete "
        f"({len(result.skipped)} skipped, {len(result.completed)} run now), "
        f"{len(result.failed)} failed"
    )
    for name, error in result.failed.items():
        print(f"  FAILED {name}: {error}")
    if result.failed:
        print(f"  logs: {exp.runs_dir / _SWEEP_DIR / 'logs'}")
    return 1 if result.failed else 0


def stale_cells(exp: Experiment) -> dict[str, str]:
    """Complete cells made with another TrainConfig / EvalConfig than the file gives now.

    They are kept (never re-run silently); the value says the first difference.
    ``device`` is ignored (a run may move between machines).
    """
    out = {}
    for c in expand(exp):
        if not is_complete(c.run_dir):
            continue
        try:
            recorded = to_dict(RunFolder(c.run_dir).config())
        except PriqnError as exc:
            out[c.name] = str(exc)
            continue
        wanted = to_dict(build_train_config(c))
        diff = config_differences(recorded, wanted, ignore=("device",))
        prefix = ""
        if not diff:
            recorded = RunFolder(c.run_dir).eval_meta().get("eval_config") or {}
            diff = config_differences(recorded, to_dict(build_eval_config(c)))
            prefix = "evaluate."
        if diff:
            key, old, new = diff[0]
            out[c.name] = f"{prefix}{key}: {old!r} != {new!r}"
    return out


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


def validate(exp: Experiment) -> None:
    """Build every cell's TrainConfig and the EvalConfig now, so a typo fails before any work."""
    cells = expand(exp)
    seen: set[tuple[str, ...]] = set()
    for c in cells:
        key = (c.policy,)
        if key not in seen:
            seen.add(key)
            build_train_config(c)
    if cells:
        build_eval_config(cells[0])


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--cell":
        sys.exit(_cell_main(sys.argv[2]))
    sys.exit("usage: python -m priqn.sweep --cell SPEC_JSON (internal; use 'priqn sweep')")
