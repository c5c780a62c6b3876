"""``priqn sweep``: train, evaluate and report a whole experiment grid.

An experiment file (``experiments/<name>.toml``) names a grid: policies (agent and
preorder options) × training seeds, the training preset and budget, the scenario
family and the evaluation settings. :func:`expand` turns it into :class:`Cell` s, one
run folder each (``<runs_dir>/<experiment>/<policy>__seed<k>/``); :func:`run_sweep`
trains and evaluates every cell that is not complete yet, then runs the report.

Every cell runs in its own child process (``python -m priqn.sweep.child --cell SPEC``):
libsumo allows one simulation per process, a crash or an out-of-memory kill takes down
one cell and not the sweep, the child's output goes to a log file that ends with the
cell's one-line error, and Ctrl-C can stop a cell by signalling its process group. The
same child runs locally (a pool of ``--jobs`` slots) or inside Ray tasks, so both
back-ends produce the same run folders; completion is always read from the run
folders, so a re-run skips finished cells and resumes interrupted ones.

The package's modules import one way, each only from those before it:

    experiment → cells → process → backends → scheduler → cli       (child: cells, process)
"""

from __future__ import annotations

from priqn.sweep.backends import Backend, LocalBackend, RayBackend, ray_cell
from priqn.sweep.cells import (
    Cell,
    build_eval_config,
    build_train_config,
    cell_state,
    expand,
    is_complete,
    stale_cells,
    validate,
)
from priqn.sweep.cli import configure_parser, run
from priqn.sweep.experiment import (
    COMPARATORS,
    NORMALISATIONS,
    PREORDERS,
    Experiment,
    ExperimentSpec,
    PolicySpec,
    ResourceSpec,
    load_experiment,
    policy_overrides,
    resolve_experiment_path,
)
from priqn.sweep.process import (
    DEFAULT_CELL_FN,
    ERROR_MARK,
    cell_command,
    cell_error,
    describe_failure,
    log_tail,
    run_cell_process,
)
from priqn.sweep.scheduler import SweepResult, _sweep_lock, default_jobs, run_sweep

__all__ = [
    "COMPARATORS",
    "DEFAULT_CELL_FN",
    "ERROR_MARK",
    "NORMALISATIONS",
    "PREORDERS",
    "Backend",
    "Cell",
    "Experiment",
    "ExperimentSpec",
    "LocalBackend",
    "PolicySpec",
    "RayBackend",
    "ResourceSpec",
    "SweepResult",
    "_sweep_lock",
    "build_eval_config",
    "build_train_config",
    "cell_command",
    "cell_error",
    "cell_state",
    "configure_parser",
    "default_jobs",
    "describe_failure",
    "expand",
    "is_complete",
    "load_experiment",
    "log_tail",
    "policy_overrides",
    "ray_cell",
    "resolve_experiment_path",
    "run",
    "run_cell_process",
    "run_sweep",
    "stale_cells",
    "validate",
]
