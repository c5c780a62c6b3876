"""``priqn sweep``: train, evaluate and report a whole experiment grid.

An experiment file (``experiments/<name>.toml``, parsed by :mod:`priqn.experiment`) names
a grid: policies (agent and preorder options) × training seeds, the training preset and
budget, the scenario family and the evaluation settings. :func:`expand` turns it into :class:`Cell` s, one
run folder each (``<runs_dir>/<experiment>/<policy>__seed<k>/``); :func:`run_sweep`
trains and evaluates every cell that is not complete yet, then runs the report.

Every cell runs in its own child process (``python -m priqn.sweep.child --cell SPEC``):
libsumo allows one simulation per process, a crash or an out-of-memory kill takes down
one cell and not the sweep, the child's output goes to a log file that ends with the
cell's one-line error, and Ctrl-C can stop a cell by signalling its process group. The
same child runs locally (a pool of ``--jobs`` slots) or inside Ray tasks, so both
back-ends produce the same run folders; completion is always read from the run
folders, so a re-run skips finished cells and resumes interrupted ones.

The package's modules import one way, each only from those before it (the experiment
file itself is :mod:`priqn.experiment`, below the package, so the analysis can read it):

    cells → commit → process → backends → scheduler → cli       (child: cells, process)

:func:`commit_complete_cells` (``priqn sweep NAME --commit``) commits a grid's complete
cells to git as they land, and only them.

The names below are the package's public API; anything else is imported from its module.
"""

from __future__ import annotations

from priqn.experiment import Experiment, ResourceSpec, load_experiment, resolve_experiment_path
from priqn.sweep.cells import Cell, build_train_config, cell_state, expand, is_complete
from priqn.sweep.cli import configure_parser, run
from priqn.sweep.commit import commit_complete_cells
from priqn.sweep.process import ERROR_MARK, cell_error, describe_failure
from priqn.sweep.scheduler import SweepResult, default_jobs, run_sweep

__all__ = [
    "ERROR_MARK",
    "Cell",
    "Experiment",
    "ResourceSpec",
    "SweepResult",
    "build_train_config",
    "cell_error",
    "cell_state",
    "commit_complete_cells",
    "configure_parser",
    "default_jobs",
    "describe_failure",
    "expand",
    "is_complete",
    "load_experiment",
    "resolve_experiment_path",
    "run",
    "run_sweep",
]
