"""A run folder's torch files, saved and loaded: ``checkpoints/latest.pt`` with its replay
files, ``policy.pt``, the kept ``snapshots/policy-at<N>.pt``, and the greedy policy
loaded back from them (:func:`load_policy`).

Where each file lives is :class:`~priqn.run.folder.RunFolder`'s (its paths), what is in
it :mod:`priqn.run.checkpoint`'s (the format); this module decides the order of the
writes (replay files first, then ``latest.pt`` naming them, then meta.json's record) and
which file a policy is loaded from. A checkpoint is captured (:func:`capture_checkpoint`;
a training session's gathered from its trainer by :func:`capture_training`) apart from
its writing (:meth:`CheckpointWrite.write`), which the training loop hands to its
background writer (:mod:`priqn.run.writer`). The network a policy acts with is built by
:mod:`priqn.agents.build`.
Torch-free at import, like the format.
"""

from __future__ import annotations

import copy
import dataclasses
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from priqn.config import to_dict
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
    :mod:`priqn.run.checkpoint`'s. :func:`capture_checkpoint` and
    :meth:`CheckpointWrite.write` in one go.
    """
    pending = capture_checkpoint(run, state, replay)
    pending.write()
    return pending.state


@dataclasses.dataclass(frozen=True, eq=False)
class CheckpointWrite:
    """A checkpoint captured in the loop whose files are still to be written (by
    :meth:`write`, in the loop or in :class:`~priqn.run.writer.BackgroundWriter`'s thread)."""

    run: RunFolder
    state: Checkpoint
    """The checkpoint as it will be saved: its ``replay_chunks`` final, its tensors and
    arrays the capture's own (the learner goes on training meanwhile)."""
    replay: Any | None
    """The replay buffer as it stood at the capture (:func:`frozen_rows`), None: no buffer."""
    since: np.ndarray | None
    """Per env, the rows the previous replay file ended at: the new file holds the rows
    from ``max(since, end - ring rows)`` to the capture's end."""
    progress: dict[str, Any] = dataclasses.field(default_factory=dict)
    """meta.json's fields (``steps_done`` ...) written once latest.pt is on disk ({}: none)."""

    def write(self) -> None:
        """The new replay file, latest.pt naming every replay file still needed, the files
        it does not name removed, then meta.json's ``progress``."""
        if self.replay is not None and self.state.replay_chunks:
            with atomic_open(self.run.checkpoint_dir / self.state.replay_chunks[-1]["file"]) as fh:
                self.replay.save_rows(fh, self.since)
        checkpoint.save(self.state, self.run.latest_checkpoint)
        keep = {c["file"] for c in self.state.replay_chunks or []}
        for old in self.run.checkpoint_dir.glob("replay-*.npz"):
            if old.name not in keep:
                old.unlink(missing_ok=True)
        if self.progress:
            self.run.update_meta(**self.progress)

    def ring_reaches(self, replay: Any, rows: int = 2) -> bool:
        """Whether writing ``rows`` more rows per env into ``replay`` (the live buffer; one
        vector step writes at most 2: the transition and an ended episode's final
        observation) could overwrite a row this write has yet to save."""
        if self.replay is None or self.since is None:
            return False
        end = self.replay.written
        first = np.maximum(self.since, end - replay.rows)  # the first row the new file holds
        return bool(np.any(replay.written + rows > first + replay.rows))


def capture_checkpoint(
    run: RunFolder, state: Checkpoint, replay: Any | None, progress: dict[str, Any] | None = None
) -> CheckpointWrite:
    """The files of checkpoint ``state`` decided now, to be written by the returned
    :meth:`CheckpointWrite.write`: the replay files it names (those whose rows the ring
    has not all overwritten, and a new one of the rows added since the last), and the
    buffer's rows frozen where they stand (:func:`frozen_rows`).

    ``state`` must hold its own copies of anything the loop goes on changing (the
    learner's tensors: :func:`copy_tensors`); ``replay``'s rows up to the capture must stay
    until the write is done (:meth:`CheckpointWrite.ring_reaches` says when they would not).
    """
    chunks = since = frozen = None
    if replay is not None:
        chunks = [c for c in state.replay_chunks or [] if not replay.overwritten(c["end"])]
        since = np.asarray(chunks[-1]["end"] if chunks else [0] * replay.num_envs)
        frozen = frozen_rows(replay)
        name = f"replay-{state.step:012d}.npz"
        chunks.append({"file": name, "end": [int(n) for n in frozen.written]})
    state = dataclasses.replace(state, replay_file=None, replay_chunks=chunks)
    return CheckpointWrite(run, state, frozen, since, dict(progress or {}))


def capture_training(
    run: RunFolder, trainer: Any, envs: Any, obs: Mapping[str, np.ndarray]
) -> CheckpointWrite:
    """The checkpoint of a training session as it stands now (:func:`capture_checkpoint`),
    with meta.json's ``steps_done``, ``episodes_done`` and ``wall_s`` to record once it is
    written.

    ``trainer`` is the session's :class:`priqn.train.Trainer`; from it: the counters and
    the wall time, a copy of the learner's state (networks, optimiser, τ generator), the
    replay and exploration generators, the logging state (the acting rule's subset-size
    means, the latest update's statistics) and, with ``checkpoint.save_replay``, the
    replay buffer. ``envs`` (no step in flight) and ``obs``: the env workers and their
    observations; every worker's episode in flight is recorded, so a resume plays it
    again to this very decision (:func:`priqn.env.vector.restore_episodes`).
    """
    t = trainer
    wall = t.wall_before + time.perf_counter() - t.t0
    state = Checkpoint(
        step=t.step,
        episodes=t.episodes,
        wall_s=wall,
        learner=copy_tensors(t.learner.state_dict()),
        rng_replay=t.rng_replay.bit_generator.state,
        rng_act=t.rng_act.bit_generator.state,
        obs={k: np.array(v) for k, v in obs.items()},
        obs_shapes=t.obs_shapes,
        num_actions=t.num_actions,
        config=to_dict(t.cfg),
        objectives=list(t.objectives),
        replay_chunks=t.replay_chunks,
        in_flight=list(envs.call("episode_record")),
        logging={
            "subset_sum": t.subset_sizes.sum_EN.tolist(),
            "subset_count": t.subset_sizes.count_E.tolist(),
            "update_stats": dict(t.latest_update_stats),
        },
    )
    progress = {"steps_done": t.step, "episodes_done": t.episodes, "wall_s": round(wall, 1)}
    replay = t.replay if t.cfg.checkpoint.save_replay else None
    return capture_checkpoint(run, state, replay, progress)


def frozen_rows(replay: Any) -> Any:
    """``replay`` as it stands now, for :meth:`~priqn.agents.replay.ReplayBuffer.save_rows`
    after the loop has stored more: the same rings (no copy), its count of rows written
    (``written``, all that says where the rows end) copied. The rows it saves are the
    ones stored up to now as long as the ring has not come round to them."""
    view = copy.copy(replay)
    view.written = replay.written.copy()
    return view


def copy_tensors(value: Any) -> Any:
    """A copy of ``value`` (a state dict: nested dicts and lists of tensors, arrays and
    plain data) that the loop's further training cannot change. Tensors sharing a storage
    still share one (:func:`copy.deepcopy`), so the copy saves to the same bytes."""
    return copy.deepcopy(value)


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


def keep_snapshot(run: RunFolder, state: PolicyState) -> None:
    """``snapshots/policy-at<step>.pt`` (:func:`save_snapshot`), then its SHA-256 in
    meta.json's ``snapshots``."""
    sha = save_snapshot(run, state)
    snapshots = dict(run.meta().get("snapshots") or {})
    snapshots[str(state.step)] = {"file": run.rel(run.snapshot_path(state.step)), "sha256": sha}
    run.update_meta(snapshots=snapshots)


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
