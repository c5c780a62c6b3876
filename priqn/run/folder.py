"""The run folder: the paths of a training run's files, its config, meta.json and status.

A run folder (``runs/<name>/``, or a committed ``results/<grid>/<cell>/``) holds::

    config.toml            the resolved TrainConfig (loadable back)
    meta.json              provenance, seeds, labels, status, trainer pid/host, sessions
    metrics.csv            one row per training / in-training evaluation episode
    learning_curve.png     the curves of metrics.csv
    tb/                    TensorBoard scalars
    checkpoints/latest.pt  the newest checkpoint (+ replay-<step>.npz); what --resume reads
    policy.pt              final online weights of a complete run (what results keep)
    eval/episodes.csv      hold-out evaluation, one row per episode (+ eval/meta.json,
    eval/cells/            finished evaluation cells, kept for a resumed evaluation)
    nets.json              your own nets (env.nets) with their SHA-256, when the run used them

:class:`RunFolder` names these files (its constants and paths; no other module spells a
file name) and reads and writes config.toml and meta.json, the run's status among them.
What the run does with the other files has its own module beside it:
:mod:`priqn.run.session` starts and resumes training sessions (meta.json ``sessions``),
:mod:`priqn.run.checkpointer` saves and loads the torch files (in
:mod:`priqn.run.checkpoint`'s format) and the policy, :mod:`priqn.run.metrics` writes and
reads metrics.csv, :mod:`priqn.run.evaluations` reads the evaluations' names and status.
The run folder only knows files: what meta.json records about the run's origin (nets,
SUMO, git) is gathered by :mod:`priqn.run.provenance` and handed in as a
:class:`Provenance`.

A run folder has one writer: ``meta.json`` records the trainer's pid and host while it
runs (:meth:`RunFolder.live_trainer`), and a ``running`` run whose trainer is gone reads
as ``interrupted`` (:meth:`RunFolder.status`).
"""

from __future__ import annotations

import dataclasses
import os
import socket
from collections.abc import Mapping
from enum import StrEnum
from pathlib import Path
from typing import Any

from priqn.config import from_dict, load_toml
from priqn.errors import PriqnError
from priqn.io import atomic_write_json, read_json


class Status(StrEnum):
    """The state of a run, an evaluation or a sweep cell: the one spelling of each word.

    ``meta.json`` (training) records ``running``, ``complete`` or ``failed``, an
    evaluation's ``eval*/meta.json`` ``running`` or ``complete``; :meth:`RunFolder.status`
    reads a ``running`` run whose trainer died as ``interrupted``, and a sweep cell
    (:func:`priqn.sweep.cells.cell_state`) is also ``trained`` (an evaluation missing) or
    ``new``. Members are ``str``: JSON writes the bare word, and they compare equal to it.
    """

    NEW = "new"
    """Nothing recorded yet (a cell without a readable meta.json)."""
    RUNNING = "running"
    """Being trained or evaluated (or its process was killed; see ``interrupted``)."""
    INTERRUPTED = "interrupted"
    """``running`` on disk, but its trainer on this host is gone: resumable."""
    FAILED = "failed"
    """Training stopped with an error (meta.json ``error`` says which)."""
    TRAINED = "trained"
    """A cell whose training is complete and an evaluation is not."""
    COMPLETE = "complete"
    """Done: training finished (meta.json) or every evaluation cell written (eval/meta.json)."""


@dataclasses.dataclass(frozen=True)
class Provenance:
    """Where a training session comes from, as meta.json (and nets.json) record it.

    Gathered by the training side (:func:`priqn.run.provenance.gather`) and handed to
    :func:`priqn.run.session.start_session`: the run folder writes it and compares it on a
    resume, but never reads a net or asks SUMO itself.
    """

    git_sha: str
    """priqn's git commit (``-dirty`` when changed), or why there is none."""
    versions: dict[str, str]
    """priqn, Python, torch, numpy, gymnasium and SUMO versions."""
    manifest_hashes: dict[str, str]
    """Manifest hash of every scenario family the run reads; ``"own"``: that of env.nets."""
    own_nets: dict[str, Any] | None = None
    """nets.json: the manifest of the run's own nets (``env.nets``); None without them."""


class RunFolder:
    """One run folder: the paths of its files, its config, meta.json and status."""

    CONFIG = "config.toml"
    META = "meta.json"
    METRICS = "metrics.csv"
    LEARNING_CURVE = "learning_curve.png"
    TENSORBOARD = "tb"
    CHECKPOINTS = "checkpoints"
    LATEST = "latest.pt"
    POLICY = "policy.pt"
    SNAPSHOTS = "snapshots"
    EVAL = "eval"
    EVAL_EPISODES = "episodes.csv"
    EVAL_CELLS = "cells"
    NETS_MANIFEST = "nets.json"

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        """The folder itself."""

    def __repr__(self) -> str:
        return f"RunFolder({str(self.path)!r})"

    def __fspath__(self) -> str:
        return str(self.path)

    @property
    def name(self) -> str:
        return self.path.name

    def rel(self, path: Path) -> str:
        """``path`` relative to the run folder, for messages (``checkpoints/latest.pt``)."""
        return str(path.relative_to(self.path))

    # ---------------------------------------------------------------- paths
    @property
    def config_path(self) -> Path:
        return self.path / self.CONFIG

    @property
    def meta_path(self) -> Path:
        return self.path / self.META

    @property
    def metrics_path(self) -> Path:
        return self.path / self.METRICS

    @property
    def learning_curve_path(self) -> Path:
        return self.path / self.LEARNING_CURVE

    @property
    def tensorboard_dir(self) -> Path:
        return self.path / self.TENSORBOARD

    @property
    def checkpoint_dir(self) -> Path:
        return self.path / self.CHECKPOINTS

    @property
    def latest_checkpoint(self) -> Path:
        return self.checkpoint_dir / self.LATEST

    @property
    def policy_path(self) -> Path:
        return self.path / self.POLICY

    def snapshot_path(self, budget: int) -> Path:
        """``snapshots/policy-at<budget>.pt``: the policy kept at ``budget`` decisions
        (``checkpoint.keep_at``; a ``policy.pt`` of that budget)."""
        return self.path / self.SNAPSHOTS / f"policy-at{budget}.pt"

    @property
    def nets_manifest_path(self) -> Path:
        """nets.json: the run's own nets (``env.nets``) with their SHA-256."""
        return self.path / self.NETS_MANIFEST

    @property
    def eval_dir(self) -> Path:
        """The run's own evaluation (``eval/``); the others live beside it
        (:func:`priqn.run.evaluations.evaluation_dir`)."""
        return self.path / self.EVAL

    @property
    def eval_meta_path(self) -> Path:
        return self.eval_dir / self.META

    @property
    def eval_episodes_path(self) -> Path:
        return self.eval_dir / self.EVAL_EPISODES

    def is_run(self) -> bool:
        """A trained (or training) run: it has a config.toml."""
        return self.config_path.is_file()

    def has_evaluation(self) -> bool:
        return self.eval_dir.is_dir()

    # ---------------------------------------------------------------- config and meta
    def config(self) -> Any:
        """The run's resolved :class:`priqn.run.train_config.TrainConfig`."""
        from priqn.run.train_config import TrainConfig

        if not self.is_run():
            raise PriqnError(f"{self.path}: not a run folder (no {self.CONFIG})")
        data = load_toml(self.config_path)
        env = data.get("env") if isinstance(data, Mapping) else None
        objectives = env.get("objectives") if isinstance(env, Mapping) else None
        if isinstance(objectives, list):
            for entry in objectives:
                self._refuse_module_from_the_folder(entry)
        agent = data.get("agent") if isinstance(data, Mapping) else None
        if isinstance(agent, Mapping):  # a plug-in agent's 'package.module:NAME'
            self._refuse_module_from_the_folder(agent.get("name"), "agent.name")
        return from_dict(TrainConfig, data, where=str(self.config_path))

    def _refuse_module_from_the_folder(self, entry: Any, field: str = "env.objectives") -> None:
        """A ``package.module:NAME`` entry of config.toml (an objective of ``env.objectives``,
        or ``agent.name``) whose package would be found
        in this run folder (or a folder holding it, e.g. a namespace package ``results``
        when Python runs from the checkout) is refused before anything is imported: a run
        folder is data, never code. Located with ``find_spec`` of the top-level name,
        which runs nothing."""
        import importlib.util

        if not isinstance(entry, str) or ":" not in entry:
            return
        top = entry.partition(":")[0].partition(".")[0]
        try:
            spec = importlib.util.find_spec(top) if top else None
        except (ImportError, ValueError):
            return  # resolve_objectives says it cannot import it, in one line
        if spec is None:
            return
        folder = self.path.resolve()
        places = [Path(p).resolve() for p in spec.submodule_search_locations or ()]
        origin = Path(spec.origin).resolve() if spec.origin and spec.has_location else None
        if any(folder.is_relative_to(p) for p in places) or (
            origin is not None and origin.is_relative_to(folder)
        ):
            raise PriqnError(
                f"{self.config_path}: {field} names {entry!r}, whose package {top!r} "
                "would be imported from the run folder itself; priqn imports plug-ins only "
                "from installed packages or your own modules, never from a run folder (data)"
            )

    def meta(self) -> dict[str, Any]:
        """meta.json (a missing or unreadable file is a one-line error)."""
        return read_json(self.meta_path)

    def write_meta(self, meta: Mapping[str, Any]) -> None:
        atomic_write_json(self.meta_path, dict(meta))

    def update_meta(self, **fields: Any) -> None:
        """Merge ``fields`` into meta.json (atomically)."""
        meta = self.meta()
        meta.update(fields)
        self.write_meta(meta)

    def recorded_status(self) -> str | None:
        """meta.json's ``status`` as written (None without a readable meta.json)."""
        return status_in(self.meta_path)

    def trained_to(self) -> int:
        """Decisions the run has trained, as its meta.json records them: the budget
        (``total_steps``) once complete, else the last checkpoint's ``steps_done``."""
        meta = self.meta()
        if meta.get("status") == Status.COMPLETE:
            return int(meta.get("total_steps") or meta.get("steps_done") or 0)
        return int(meta.get("steps_done") or 0)

    def status(self) -> str:
        """meta.json's status, with ``interrupted`` for a ``running`` run whose trainer is dead."""
        meta = self.meta()
        status = str(meta.get("status"))
        if status == Status.RUNNING and meta.get("pid") is not None and self.live_trainer() is None:
            return Status.INTERRUPTED
        return status

    def live_trainer(self) -> str | None:
        """``"pid N on host H"`` when a live process on this host is training this run.

        ``meta.json`` records the trainer's host and pid with ``status: running``; a run
        whose trainer died (kill -9, a crash, the machine rebooted) is not live. A trainer
        on another host cannot be checked and counts as live.
        """
        if not self.meta_path.is_file():
            return None
        meta = self.meta()
        if meta.get("status") != Status.RUNNING or meta.get("pid") is None:
            return None
        pid, host = int(meta["pid"]), str(meta.get("host"))
        if pid == os.getpid() and host == socket.gethostname():
            return None
        if host == socket.gethostname() and not _pid_alive(pid):
            return None
        return f"pid {pid} on host {host}"


def live_trainer(run_dir: str | os.PathLike) -> str | None:
    """:meth:`RunFolder.live_trainer` of ``run_dir``."""
    return RunFolder(run_dir).live_trainer()


def run_status(run_dir: str | os.PathLike) -> str:
    """:meth:`RunFolder.status` of ``run_dir``."""
    return RunFolder(run_dir).status()


def status_in(meta_path: Path) -> str | None:
    """The ``status`` a meta.json records (a run's or an evaluation's), as written; None
    without a readable file."""
    try:
        meta = read_json(meta_path)
    except PriqnError:
        return None
    return meta.get("status") if isinstance(meta, dict) else None


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
