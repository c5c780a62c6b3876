"""A run folder's torch files, saved and loaded: ``checkpoints/latest.pt`` with its replay
files, ``policy.pt``, the kept ``snapshots/policy-at<N>.pt``, and the greedy policy
loaded back from them (:func:`load_policy`).

Where each file lives is :class:`~priqn.run.folder.RunFolder`'s (its paths), what is in
it :mod:`priqn.run.checkpoint`'s (the format); this module decides the order of the
writes (replay files first, then ``latest.pt`` naming them) and which file a policy is
loaded from. The network a policy acts with is built by :mod:`priqn.agents.build`.
Torch-free at import, like the format.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

from priqn.errors import PriqnError
from priqn.io import atomic_open, sha256_file
from priqn.run import checkpoint
from priqn.run.checkpoint import Checkpoint, PolicyState
from priqn.run.folder import RunFolder


def save_checkpoint(run: RunFolder, state: Checkpoint, replay: Any | None) -> Checkpoint:
    """The replay rows added since the previous checkpoint (``state.replay_chunks``, the
    previous one's list) as a new compressed file, then latest.pt naming every replay
    file still needed, then the files it does not name removed. Returns the state as
    saved (its ``replay_chunks`` are the next checkpoint's previous list).

    ``replay`` None saves no buffer (``checkpoint.save_replay = false``). Each file is
    atomic and latest.pt is the commit point, so a kill at any moment, in the middle of
    this too, leaves a latest.pt whose replay files are all there. The format is
    :mod:`priqn.run.checkpoint`'s.
    """
    chunks = None
    if replay is not None:
        chunks = [c for c in state.replay_chunks or [] if not replay.overwritten(c["end"])]
        since = chunks[-1]["end"] if chunks else [0] * replay.num_envs
        name = f"replay-{state.step:012d}.npz"
        with atomic_open(run.checkpoint_dir / name, "wb") as fh:
            end = replay.save_rows(fh, since)
        chunks.append({"file": name, "end": [int(n) for n in end]})
    state = dataclasses.replace(state, replay_file=None, replay_chunks=chunks)
    checkpoint.save(state, run.latest_checkpoint)
    keep = {c["file"] for c in chunks or []}
    for old in run.checkpoint_dir.glob("replay-*.npz"):
        if old.name not in keep:
            old.unlink(missing_ok=True)
    return state


def load_checkpoint(run: RunFolder, device: Any) -> Checkpoint:
    """The latest checkpoint (a damaged file is a one-line error saying what to do)."""
    return checkpoint.load(
        run.latest_checkpoint,
        device,
        f"delete the run folder's {run.CHECKPOINTS}/ and train again with --force",
    )


def replay_files(run: RunFolder, state: Checkpoint) -> list[Path]:
    """The replay buffer files a checkpoint names, in the order to load them: its
    compressed chunks, or the one uncompressed file of an older checkpoint ([] if it
    saved none)."""
    if state.replay_chunks is not None:
        return [run.checkpoint_dir / c["file"] for c in state.replay_chunks]
    return [run.checkpoint_dir / state.replay_file] if state.replay_file else []


def save_policy(run: RunFolder, state: PolicyState) -> None:
    """policy.pt: the final online weights and the agent's learned state (a few MB)."""
    checkpoint.save(state, run.policy_path)


def save_snapshot(run: RunFolder, state: PolicyState) -> str:
    """``snapshots/policy-at<step>.pt`` (same format as policy.pt); returns its SHA-256,
    which meta.json keeps (``snapshots``) so a snapshot not committed stays checkable."""
    path = run.snapshot_path(state.step)
    checkpoint.save(state, path)
    return sha256_file(path)


def load_policy(run: RunFolder | str | os.PathLike, device: str = "cpu", snapshot: int = 0) -> Any:
    """Greedy :class:`priqn.agents.policy.Policy` of the trained run ``run`` (a folder).

    From the latest checkpoint when present (a run in progress, or resumable); else
    from policy.pt, which is all a committed result folder keeps. ``snapshot`` N > 0:
    the policy kept at N decisions (``snapshots/policy-at<N>.pt``) instead.
    """
    from priqn.agents.build import build_agent, build_trained_policy
    from priqn.run.train_config import observation_space, policy_labels, select_device

    run = run if isinstance(run, RunFolder) else RunFolder(run)
    cfg = run.config()
    dev = select_device(device)
    remedy = "restore it from git or re-train the run (priqn train --force)"
    source, state = _policy_state(run, cfg, dev, snapshot, remedy)
    agent = build_agent(cfg)
    space = observation_space(state.obs_shapes)
    labels = policy_labels(cfg, agent)
    return build_trained_policy(
        cfg,
        agent,
        space,
        state,
        dev,
        cfg.env,
        labels,
        restore=lambda load_state: checkpoint.restore(load_state, source, remedy),
    )


def _policy_state(
    run: RunFolder, cfg: Any, device: Any, snapshot: int, remedy: str
) -> tuple[Path, PolicyState]:
    """The file a policy is loaded from and its :class:`PolicyState`: snapshot N, else
    latest.pt, else policy.pt; refused when trained for other objectives than config.toml's."""
    latest, final = run.latest_checkpoint, run.policy_path
    if snapshot:
        source = run.snapshot_path(snapshot)
        state = _load_snapshot(run, snapshot, cfg.checkpoint.keep_at, device)
    elif latest.is_file():
        source, state = latest, checkpoint.load(latest, device, remedy).policy_state()
    elif final.is_file():
        source, state = final, checkpoint.load_policy_state(final, device, remedy)
    else:
        raise PriqnError(
            f"{run.path}: no {run.rel(latest)} or {run.rel(final)} to load a policy from"
        )
    names = cfg.objective_names
    if tuple(state.objectives) != names:
        raise PriqnError(
            f"{run.path}: the policy was trained for objectives "
            f"({', '.join(state.objectives)}) but {run.CONFIG} lists ({', '.join(names)}); "
            "restore the run's config.toml or train again"
        )
    return source, state


def _load_snapshot(
    run: RunFolder, budget: int, keep_at: tuple[int, ...], device: Any
) -> PolicyState:
    """The :class:`PolicyState` kept at ``budget``, checked against meta.json's SHA-256."""
    path = run.snapshot_path(budget)
    if budget not in keep_at:
        kept = ", ".join(map(str, keep_at)) or "none"
        raise PriqnError(
            f"{run.path}: no snapshot at {budget} decisions (checkpoint.keep_at of this run: {kept})"
        )
    if not path.is_file():
        raise PriqnError(
            f"{run.path}: {run.rel(path)} is missing (snapshots are not committed with a "
            "result folder; meta.json keeps their SHA-256): re-train the run to get it back"
        )
    recorded = (run.meta().get("snapshots") or {}).get(str(budget), {}).get("sha256")
    if recorded and recorded != sha256_file(path):
        raise PriqnError(
            f"{path}: not the snapshot this run kept (its SHA-256 differs from meta.json's)"
        )
    remedy = "re-train the run to get it back (priqn train --force)"
    return checkpoint.load_policy_state(path, device, remedy)
