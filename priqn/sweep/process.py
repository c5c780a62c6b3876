"""Running one cell as a child process: the command, its log, stopping it, its error.

The same child command (``python -m priqn.sweep.child --cell SPEC``) runs locally and
inside Ray tasks; its output goes to a log file that ends with the cell's one-line error
(:data:`ERROR_MARK`), and a stop signals the child's whole process group.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from priqn.io import atomic_open
from priqn.run.provenance import THREAD_VARIABLES
from priqn.sweep.cells import Cell

DEFAULT_CELL_FN = "priqn.sweep.child:train_and_evaluate"
"""Import path of the function a cell's child process runs (tests substitute fast ones)."""


_STOP_GRACE_S = 10.0


# --------------------------------------------------------------------------- running a child


def cell_command(spec: dict[str, Any]) -> list[str]:
    """The child command that runs one cell (same locally and inside a Ray task)."""
    return [sys.executable, "-m", "priqn.sweep.child", "--cell", json.dumps(spec, sort_keys=True)]


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


def thread_env(threads: int, environ: Mapping[str, str]) -> dict[str, str]:
    """The thread limits of a cell with ``threads`` CPUs: each of :data:`THREAD_VARIABLES`
    set to it, unless ``environ`` (the sweep's own environment) sets it already, which wins.
    Without them every cell's libraries start a thread per core and fight the other cells
    (and their own env workers) for the cores."""
    return {name: str(threads) for name in THREAD_VARIABLES if name not in environ}


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
    killed. A negative status is the signal that killed the child. ``spec["code_dir"]``
    (optional) goes first on the child's ``PYTHONPATH``: the cell runs that copy of priqn.
    """
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    if spec.get("code_dir"):  # cells run a frozen snapshot of priqn (priqn sweep --code)
        env["PYTHONPATH"] = os.pathsep.join(
            p for p in (str(spec["code_dir"]), env.get("PYTHONPATH", "")) if p
        )
        # `python -m` puts the working directory first on sys.path, ahead of PYTHONPATH:
        # a checkout there would shadow the snapshot (Python >= 3.11: PYTHONSAFEPATH).
        env["PYTHONSAFEPATH"] = "1"
    if spec.get("cuda_visible_devices") is not None:  # the local pool's GPU share
        env["CUDA_VISIBLE_DEVICES"] = str(spec["cuda_visible_devices"])
    if spec.get("threads"):
        env.update(thread_env(int(spec["threads"]), os.environ))
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
    return rc, cell_error(log_path), Cell.from_spec(spec).is_complete()


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
