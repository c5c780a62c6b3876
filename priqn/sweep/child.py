"""The child process of one cell: ``python -m priqn.sweep.child --cell SPEC_JSON``.

It runs the cell function (default :func:`train_and_evaluate`) and ends its log with the
cell's one-line error. It imports the cells, never the scheduler.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import json
import os
import signal
import socket
import sys
import traceback

from priqn.errors import PriqnError
from priqn.run.folder import RunFolder, Status
from priqn.sweep.cells import Cell, build_eval_config, build_train_config
from priqn.sweep.process import DEFAULT_CELL_FN, ERROR_MARK


def train_and_evaluate(cell: Cell) -> None:
    """Run one cell to completion: train (resuming an interrupted run), then evaluate
    (its own acting, then each control evaluation of a baseline cell, then each policy
    kept at a budget of ``checkpoint.keep_at``, into ``eval-at<N>/``)."""
    from priqn.evaluation.cli import evaluate_run
    from priqn.evaluation.protocol import control_config
    from priqn.train import train

    state = cell.state()
    if state not in (Status.COMPLETE, Status.TRAINED):
        cfg = build_train_config(cell)
        has_checkpoint = RunFolder(cell.run_dir).latest_checkpoint.is_file()
        if has_checkpoint:
            train(cfg, cell.run_dir, resume=True)
        else:
            # Nothing to resume (new, or killed before its first checkpoint): start over.
            train(cfg, cell.run_dir, force=cell.run_dir.exists(), traffic=cell.traffic)
    eval_cfg = build_eval_config(cell)
    own = eval_cfg.family  # the experiment's [evaluate] family is the cell's own: eval/
    for name in ("", *cell.controls):  # each returns at once if already complete
        evaluate_run(cell.run_dir, control_config(eval_cfg, name), own_family=own)
    for budget in cell.snapshots:  # each kept snapshot the cell counts (its keep_at)
        evaluate_run(cell.run_dir, dataclasses.replace(eval_cfg, snapshot=budget), own_family=own)


def _cell_main(spec_json: str) -> int:
    """Body of ``python -m priqn.sweep.child --cell SPEC``: one cell in this (child) process."""
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


def _die_with_parent(parent_pid: int | None) -> None:
    """Linux: SIGTERM this child when the process that started it dies (a killed sweep or Ray worker)."""
    if not sys.platform.startswith("linux") or parent_pid is None:
        return
    with contextlib.suppress(Exception):
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        sys.exit("priqn sweep: the sweep that started this cell is gone")


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--cell":
        sys.exit(_cell_main(sys.argv[2]))
    sys.exit("usage: python -m priqn.sweep.child --cell SPEC_JSON (internal; use 'priqn sweep')")
