"""The format of a run's two torch files, owned here and nowhere else.

* :class:`Checkpoint` — ``checkpoints/latest.pt``: everything a resume restores (the
  learner's networks, Adam, τ generator and agent state, the replay and exploration
  generators, the counters, the observation in flight) plus what loading a policy from
  it needs (``obs_shapes``, ``num_actions``).
* :class:`PolicyState` — ``policy.pt``: the final online weights and the agent's learned
  state of a complete run (a few MB; all a committed result folder keeps).

On disk each is a plain dict of its fields (the keys written since the first release, so
old files still load), saved with :func:`priqn.io.atomic_torch_save` (temp file + rename,
with a ``<file>.sha256`` sidecar). :func:`load` and :func:`load_policy_state` turn a
damaged, truncated or foreign file into one :class:`~priqn.errors.PriqnError` line that
names the file. Which file lives where (and the replay buffer file a checkpoint names) is
:class:`priqn.runs.RunFolder`'s business.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Mapping
from typing import Any, ClassVar, TypeVar

import numpy as np

from priqn.errors import PriqnError
from priqn.io import atomic_torch_save, torch_load
from priqn.objectives import OBJECTIVES

REMEDY = "delete the run folder's checkpoints/ and train again with --force"
"""What to do about a damaged checkpoint (the end of its one-line error)."""


@dataclasses.dataclass
class PolicyState:
    """``policy.pt``: a trained policy without its optimiser or replay buffer."""

    online: dict[str, Any]
    """The online network's ``state_dict``."""
    agent: dict[str, Any]
    """The agent's learned state (the scaled normalisation's running scale; else {})."""
    obs_shapes: dict[str, Any]
    """Per observation key ``[shape, dtype, high]``, to rebuild the observation space."""
    num_actions: int
    """Size of the discrete action space."""
    step: int
    """Env decisions trained."""
    objectives: list[str] = dataclasses.field(default_factory=lambda: list(OBJECTIVES))
    """The objective names the heads were trained for (``env.objectives`` resolved)."""

    OPTIONAL: ClassVar[dict[str, Callable[[], Any]]] = {
        "agent": dict,
        "objectives": lambda: list(OBJECTIVES),
    }
    """Keys an older file may lack, with the factory of their default."""


@dataclasses.dataclass
class Checkpoint:
    """``checkpoints/latest.pt``: the state of a training session at env decision ``step``."""

    step: int
    """Env decisions done (all workers together)."""
    episodes: int
    """Training episodes ended."""
    wall_s: float
    """Wall time of every session so far [s]."""
    learner: dict[str, Any]
    """:meth:`priqn.agents.learner.Learner.state_dict` (online, target, optimizer,
    updates, tau_generator, agent)."""
    rng_replay: dict[str, Any]
    """Bit-generator state of the replay sampling generator."""
    rng_act: dict[str, Any]
    """Bit-generator state of the exploration generator."""
    obs: dict[str, np.ndarray]
    """The observation each env worker was in (``[num_envs, ...]`` per key)."""
    obs_shapes: dict[str, Any]
    """Per observation key ``[shape, dtype, high]``, to rebuild the observation space."""
    num_actions: int
    """Size of the discrete action space."""
    config: dict[str, Any]
    """The run's :class:`~priqn.train_config.TrainConfig` as a dict (for the record)."""
    replay_file: str | None = None
    """Name of the replay buffer file saved with it, in the same folder (None: none)."""
    torch_version: str = ""
    """torch that wrote the file (filled by :func:`save`)."""
    objectives: list[str] = dataclasses.field(default_factory=lambda: list(OBJECTIVES))
    """The run's objective names (reward-vector and per-objective head order)."""

    OPTIONAL: ClassVar[dict[str, Callable[[], Any]]] = {
        "replay_file": lambda: None,
        "torch_version": str,
        "objectives": lambda: list(OBJECTIVES),
    }
    """Keys an older file may lack, with the factory of their default."""

    def policy_state(self) -> PolicyState:
        """The greedy policy this checkpoint holds (what ``policy.pt`` would keep)."""
        return PolicyState(
            online=self.learner["online"],
            agent=self.learner.get("agent", {}),
            obs_shapes=self.obs_shapes,
            num_actions=self.num_actions,
            step=self.step,
            objectives=list(self.objectives),
        )


_State = TypeVar("_State", Checkpoint, PolicyState)


def as_dict(state: Checkpoint | PolicyState) -> dict[str, Any]:
    """The on-disk dict of ``state``: its fields in order (tensors not copied)."""
    return {f.name: getattr(state, f.name) for f in dataclasses.fields(state)}


def save(state: Checkpoint | PolicyState, path: str | os.PathLike) -> None:
    """Write ``state`` to ``path`` atomically (a :class:`Checkpoint` records the torch
    version that wrote it)."""
    import torch

    if isinstance(state, Checkpoint):
        state = dataclasses.replace(state, torch_version=torch.__version__)
    atomic_torch_save(as_dict(state), path)


def load(path: str | os.PathLike, map_location: Any = "cpu", remedy: str = REMEDY) -> Checkpoint:
    """The :class:`Checkpoint` in ``path``; a damaged file is one line ending in ``remedy``."""
    return _load(Checkpoint, path, map_location, remedy)


def load_policy_state(
    path: str | os.PathLike, map_location: Any = "cpu", remedy: str = REMEDY
) -> PolicyState:
    """The :class:`PolicyState` in ``path`` (``policy.pt``); a damaged file is one line."""
    return _load(PolicyState, path, map_location, remedy)


def _load(cls: type[_State], path: str | os.PathLike, map_location: Any, remedy: str) -> _State:
    """Read ``path`` and check it holds every required field of ``cls`` (one-line errors)."""
    what = "checkpoint" if cls is Checkpoint else "policy file"
    data = torch_load(path, what, remedy, map_location)
    if not isinstance(data, Mapping):
        raise PriqnError(f"{path}: not a priqn {what} (a {type(data).__name__}); {remedy}")
    optional = cls.OPTIONAL
    names = [f.name for f in dataclasses.fields(cls)]
    missing = [n for n in names if n not in data and n not in optional]
    if missing:
        raise PriqnError(f"{path}: not a priqn {what} (no {', '.join(missing)}); {remedy}")
    values = {n: data[n] if n in data else optional[n]() for n in names}
    return cls(**values)
