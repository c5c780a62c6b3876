"""Run-folder facts every command reads the same way: who is training it, and its status.

(The first piece of the run-folder type the architecture issue asks for.)
"""

from __future__ import annotations

import os
import socket
from pathlib import Path

from priqn.io import read_json


def live_trainer(run_dir: Path) -> str | None:
    """``"pid N on host H"`` when a live process on this host is training ``run_dir``.

    ``meta.json`` records the trainer's host and pid with ``status: running``; a run whose
    trainer died (kill -9, a crash, the machine rebooted) is not live: see
    :func:`run_status`. A trainer on another host cannot be checked and counts as live.
    """
    meta_path = run_dir / "meta.json"
    if not meta_path.is_file():
        return None
    meta = read_json(meta_path)
    if meta.get("status") != "running" or meta.get("pid") is None:
        return None
    pid, host = int(meta["pid"]), str(meta.get("host"))
    if pid == os.getpid() and host == socket.gethostname():
        return None
    if host == socket.gethostname() and not _pid_alive(pid):
        return None
    return f"pid {pid} on host {host}"


def run_status(run_dir: Path) -> str:
    """meta.json's status, with ``interrupted`` for a ``running`` run whose trainer is dead."""
    meta = read_json(run_dir / "meta.json")
    status = str(meta.get("status"))
    if status == "running" and meta.get("pid") is not None and live_trainer(run_dir) is None:
        return "interrupted"
    return status


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    # A zombie (exited, not yet reaped) has finished training too.
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
            return fh.read().split(") ", 1)[1][:1] != "Z"
    except OSError:
        return True
