"""Training sessions of a run folder: starting one, resuming one, and what meta.json
records of them (``sessions``).

A run is trained in one or more sessions: the first starts a new folder
(:func:`start_session` with ``resume`` False; ``--force`` first removes an old one,
:func:`remove_run`), each ``--resume`` continues it from its latest checkpoint. Every
session appends ``{started, resume, from_step, cpu}`` to meta.json's ``sessions``; an
exact resume adds ``exact`` (:func:`mark_resume_exact`), and :func:`resumed_at` lists
the others, the resumes a report must mention.
"""

from __future__ import annotations

import os
import shutil
import socket
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from priqn.config import config_differences, dumps_toml, to_dict
from priqn.errors import PriqnError
from priqn.io import (
    atomic_write_json,
    atomic_write_text,
    remove_empty_folders,
    remove_stale_temp_files,
)
from priqn.run.folder import Provenance, RunFolder, Status


def start_session(
    run: RunFolder,
    cfg: Any,
    resume: bool,
    force: bool,
    provenance: Provenance,
    labels: Mapping[str, Any],
    traffic: str = "",
) -> dict[str, Any]:
    """Check / create ``run`` for a training session; write config.toml, nets.json
    (own nets) and meta.json (``provenance``, ``labels``, status running, this process
    as the trainer; a new run's ``traffic``, the named setting it was trained with, where
    one was chosen: :func:`priqn.env.traffic.run_setting_name`). Returns the meta.

    Everything that can refuse the run comes before the folder is touched (what
    gathering ``provenance`` refuses comes before this call).
    """
    owner = run.live_trainer()
    if owner is not None and (resume or force):
        raise PriqnError(
            f"{run.path}: still being trained by {owner} (meta.json status running); "
            "stop that process first (a run folder has one writer)"
        )
    meta = _resumed_meta(run, cfg, provenance) if resume else _new_meta(run, cfg, force)
    if traffic and not resume:
        meta["traffic"] = traffic
    try:
        run.path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PriqnError(f"{run.path}: cannot create the run folder ({exc.strerror})") from exc
    atomic_write_text(run.config_path, dumps_toml(to_dict(cfg)))
    if provenance.own_nets is not None:
        atomic_write_json(run.nets_manifest_path, provenance.own_nets)
    meta.update(
        {
            "run": run.path.name,
            "status": Status.RUNNING,
            "error": None,
            "git_sha": provenance.git_sha,
            "versions": dict(provenance.versions),
            "manifest_hashes": dict(provenance.manifest_hashes),
            "labels": dict(labels),
            "total_steps": cfg.total_steps,
            "host": socket.gethostname(),
            "pid": os.getpid(),
        }
    )
    meta.setdefault("steps_done", 0)
    meta["sessions"].append(
        {
            "started": datetime.now(UTC).isoformat(timespec="seconds"),
            "resume": resume,
            "from_step": int(meta.get("steps_done", 0)) if resume else 0,
            "cpu": provenance.versions.get("cpu", "unknown"),
        }
    )
    run.write_meta(meta)
    return meta


def _resumed_meta(run: RunFolder, cfg: Any, provenance: Provenance) -> dict[str, Any]:
    """meta.json of the run to resume; refused unless it has a checkpoint, the same
    config (bar total_steps and device) and unchanged own nets."""
    if not run.latest_checkpoint.is_file():
        raise PriqnError(f"{run.path}: nothing to resume (no {run.rel(run.latest_checkpoint)})")
    diff = config_differences(to_dict(run.config()), to_dict(cfg), ignore=("total_steps", "device"))
    if diff:
        k, old, new = diff[0]
        raise PriqnError(
            f"{run.path}: --resume with a different config ({k} = {old!r} in the run, {new!r} now)"
        )
    meta = run.meta()
    recorded = meta.get("objectives")  # absent before objectives were declared: the five
    if recorded is not None and tuple(recorded) != tuple(cfg.objective_names):
        raise PriqnError(
            f"{run.path}: --resume: the run was trained for objectives "
            f"({', '.join(recorded)}) but {run.CONFIG} lists "
            f"({', '.join(cfg.objective_names)}); restore it or start a new run"
        )
    written_at = meta.get("git_sha")
    if written_at and written_at != provenance.git_sha:
        raise PriqnError(
            f"{run.path}: --resume: its checkpoint was written by the code at "
            f"{written_at[:12]}, this is {provenance.git_sha[:12]}; resume it with that "
            "code (a worktree of it: docs/sweeps.md) so that it goes on as it would have"
        )
    own_hash = provenance.manifest_hashes.get("own")
    if own_hash is not None and meta.get("manifest_hashes", {}).get("own") != own_hash:
        raise PriqnError(
            f"{run.path}: --resume: a net of env.nets changed since the run started "
            f"(see {run.NETS_MANIFEST}); restore it or start a new run"
        )
    remove_stale_temp_files(run.path)  # left by a killed write of the last session
    return meta


def _new_meta(run: RunFolder, cfg: Any, force: bool) -> dict[str, Any]:
    """The first meta.json of a new run; an existing folder is refused, or removed with
    ``force``."""
    from priqn.run.train_config import derive_seeds

    if run.path.exists() and any(run.path.iterdir()):
        if not force:
            raise PriqnError(
                f"{run.path}: run folder already exists; use --resume to continue it or --force to overwrite"
            )
        remove_run(run)
    return {
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "seed": cfg.seed,
        "seeds": derive_seeds(cfg.seed),
        "sessions": [],
    }


START_FILES = (RunFolder.CONFIG, RunFolder.META, RunFolder.NETS_MANIFEST)
"""What :func:`start_session` writes into a run folder (before training writes anything)."""


def undo_failed_start(run: RunFolder, made: Sequence[Path]) -> bool:
    """Take back a new run that failed before training wrote a file (an env worker that
    could not start, a junction the nets lack, ...): the files :func:`start_session` wrote
    and the folders ``made`` for it (:func:`priqn.io.missing_folders`, before it), so the
    same command can simply be run again. True if it did; a folder holding anything else
    (training got further) stays, its meta.json saying why it failed."""
    try:
        if not made or any(p.name not in START_FILES for p in run.path.iterdir()):
            return False
        for name in START_FILES:
            (run.path / name).unlink(missing_ok=True)
    except OSError:  # unreadable, or a file that cannot go: leave it marked failed
        return False
    remove_empty_folders(made)
    return not run.path.exists()


def remove_run(run: RunFolder) -> None:
    """Delete the folder (``--force``); refused in one line, touching nothing, when any
    part of it cannot be deleted (a read-only folder)."""
    locked = [d for d, _, _ in os.walk(run.path) if not os.access(d, os.W_OK | os.X_OK)]
    if locked:
        raise PriqnError(
            f"{locked[0]}: read-only, so --force cannot replace the run; "
            "make it writable (chmod -R u+w) or pick another --name"
        )
    try:
        shutil.rmtree(run.path)
    except OSError as exc:
        raise PriqnError(
            f"{exc.filename or run.path}: cannot delete the old run for --force ({exc.strerror})"
        ) from None


def resumed_at(run: RunFolder) -> list[int]:
    """The decisions at which training resumed after an interruption (meta.json
    ``sessions``) the old way: from the last checkpoint with fresh scenes (and a refilled
    replay buffer unless saved), so the training after it differs from an uninterrupted
    run's. An exact resume (:func:`mark_resume_exact`) is not listed."""
    sessions = run.meta().get("sessions") or []
    return [
        int(s["from_step"])
        for s in sessions
        if s.get("resume") and "from_step" in s and not s.get("exact")
    ]


def mark_resume_exact(run: RunFolder) -> None:
    """Record that this session's resume restored the replay buffer and the episodes in
    flight on the CPU model of the session before (meta.json ``sessions[-1].exact``):
    the run cannot tell it was stopped, so :func:`resumed_at` and the reports no longer
    list it."""
    meta = run.meta()
    meta["sessions"][-1]["exact"] = True
    run.write_meta(meta)


def same_cpu_as_before(run: RunFolder) -> bool:
    """This session runs on the CPU model the previous one ran on (both recorded): the
    learner's float results depend on it (measured: another Xeon / EPYC gave a loss
    differing in its 7th digit after 2,552 decisions), so only then is a resume exact."""
    sessions = run.meta().get("sessions") or []
    if len(sessions) < 2:
        return False
    before, now = sessions[-2].get("cpu"), sessions[-1].get("cpu")
    return bool(before) and before == now and before != "unknown"
