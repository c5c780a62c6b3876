"""The format of a run's two torch files, owned here and nowhere else.

* :class:`Checkpoint` — ``checkpoints/latest.pt``: everything a resume restores (the
  learner's networks, Adam, τ generator and agent state, the replay and exploration
  generators, the counters, the observation in flight, each env worker's episode in
  flight, the logging state, the list of replay files) plus what loading a policy from
  it needs (``obs_shapes``, ``num_actions``).
* :class:`PolicyState` — ``policy.pt``: the final online weights and the agent's learned
  state of a complete run (a few MB; all a committed result folder keeps).

On disk each is a plain dict of its fields (the keys written since the first release, so
old files still load) plus ``format`` (:data:`FORMAT_VERSION`), saved with
:func:`priqn.io.atomic_torch_save` (temp file + rename, with a ``<file>.sha256`` sidecar).
It holds nothing but tensors and plain data (dicts, lists, numbers, strings), so every
load is ``torch.load(weights_only=True)`` (:func:`priqn.io.torch_load`): a file from
anyone runs no code. :func:`load` and :func:`load_policy_state` turn a damaged,
truncated, tampered or foreign file into one :class:`~priqn.errors.PriqnError` line that
names the file, and :func:`restore` does the same for weights that do not fit a network.
Which file lives where (and the replay buffer file a checkpoint names) is
:class:`priqn.run.folder.RunFolder`'s business.
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

FORMAT_VERSION = 2
"""The on-disk format written now, under the key ``format``. 1 (no ``format`` key, before
issue 35): ``obs`` numpy arrays and ``torch_version`` torch's ``TorchVersion``, read
through :func:`legacy_allow_list`; 2: ``obs`` tensors (numpy again once loaded),
``torch_version`` a str: tensors and plain data only."""

FORMAT_KEY = "format"
"""The key of the format version in the on-disk dict (absent: format 1)."""

LEGACY_DTYPES = ("uint8", "float32")
"""The observation dtypes a format-1 checkpoint's numpy ``obs`` may have (all priqn's
observations ever had); any other dtype is refused in one line."""

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
    """The run's :class:`~priqn.run.train_config.TrainConfig` as a dict (for the record)."""
    replay_file: str | None = None
    """Name of the uncompressed replay buffer file saved with it, in the same folder, by
    checkpoints before issue 49 (None: none; newer ones use ``replay_chunks``)."""
    torch_version: str = ""
    """torch that wrote the file (filled by :func:`save`)."""
    objectives: list[str] = dataclasses.field(default_factory=lambda: list(OBJECTIVES))
    """The run's objective names (reward-vector and per-objective head order)."""
    replay_chunks: list[dict[str, Any]] | None = None
    """The replay buffer as compressed files of the rows each checkpoint added, in the order
    written, each ``{"file": name, "end": [rows written per env when it was saved]}``
    (:meth:`priqn.agents.replay.ReplayBuffer.save_rows`); files whose rows the ring has all
    overwritten are dropped. None: no buffer saved this way (see ``replay_file``)."""
    in_flight: list[dict[str, Any]] | None = None
    """Per env worker, the episode it was in (``IntersectionEnv.episode_record``: the
    generator state of its reset, its options, its actions): a resume plays them again and
    goes on at the very decision. None: a checkpoint from before issue 49."""
    logging: dict[str, Any] = dataclasses.field(default_factory=dict)
    """What the loop's logging carries across decisions: the in-flight episodes' optimal
    subset size sums and counts, the latest update's statistics (``metrics.csv`` rows)."""

    OPTIONAL: ClassVar[dict[str, Callable[[], Any]]] = {
        "replay_file": lambda: None,
        "torch_version": str,
        "objectives": lambda: list(OBJECTIVES),
        "replay_chunks": lambda: None,
        "in_flight": lambda: None,
        "logging": dict,
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
    """The on-disk dict of ``state``: its fields in order (tensors not copied), the
    observations as tensors, then ``format``: nothing but tensors and plain data."""
    import torch

    data = {f.name: getattr(state, f.name) for f in dataclasses.fields(state)}
    if isinstance(state, Checkpoint):
        data["obs"] = {k: torch.from_numpy(np.array(v)) for k, v in state.obs.items()}
        data["torch_version"] = str(state.torch_version)
    data[FORMAT_KEY] = FORMAT_VERSION
    return data


def save(state: Checkpoint | PolicyState, path: str | os.PathLike) -> None:
    """Write ``state`` to ``path`` atomically (a :class:`Checkpoint` records the torch
    version that wrote it)."""
    import torch

    if isinstance(state, Checkpoint):
        state = dataclasses.replace(state, torch_version=str(torch.__version__))
    atomic_torch_save(as_dict(state), path)


def legacy_allow_list() -> list[Any]:
    """What a format-1 checkpoint holds beyond tensors and plain data, admitted by name and
    nothing else: numpy arrays of :data:`LEGACY_DTYPES` (``obs``; an array is rebuilt
    from its raw bytes, never from pickled objects) and torch's ``TorchVersion`` (a str)."""
    from torch.torch_version import TorchVersion

    reconstruct = np.zeros(0).__reduce__()[0]  # numpy(._)core.multiarray._reconstruct
    return [
        np.ndarray,
        np.dtype,
        *(type(np.dtype(name)) for name in LEGACY_DTYPES),
        TorchVersion,
        (reconstruct, "numpy.core.multiarray._reconstruct"),
        (reconstruct, "numpy._core.multiarray._reconstruct"),
    ]


def restore(load_state: Callable[[], Any], path: str | os.PathLike, remedy: str) -> Any:
    """Call ``load_state`` (a ``load_state_dict`` of the weights in ``path``); weights whose
    names or shapes do not fit the network are one line naming ``path``, not torch's."""
    try:
        return load_state()
    except (RuntimeError, KeyError, ValueError, TypeError, AttributeError, IndexError) as exc:
        detail = " ".join(str(exc).split())
        detail = detail[:240] + ("..." if len(detail) > 240 else "")
        raise PriqnError(
            f"{path}: its weights do not fit the network this run's config.toml describes "
            f"({type(exc).__name__}: {detail}); {remedy}"
        ) from None


def load(path: str | os.PathLike, map_location: Any = "cpu", remedy: str = REMEDY) -> Checkpoint:
    """The :class:`Checkpoint` in ``path``; a damaged file is one line ending in ``remedy``."""
    return _load(Checkpoint, path, map_location, remedy)


def load_policy_state(
    path: str | os.PathLike, map_location: Any = "cpu", remedy: str = REMEDY
) -> PolicyState:
    """The :class:`PolicyState` in ``path`` (``policy.pt``); a damaged file is one line."""
    return _load(PolicyState, path, map_location, remedy)


def _load(cls: type[_State], path: str | os.PathLike, map_location: Any, remedy: str) -> _State:
    """Read ``path`` (tensors and plain data only) and check it holds every required field
    of ``cls`` with the right kind of value (one-line errors)."""
    what = "checkpoint" if cls is Checkpoint else "policy file"
    allow = legacy_allow_list() if cls is Checkpoint else ()
    data = torch_load(path, what, remedy, map_location, allow)
    if not isinstance(data, Mapping):
        raise PriqnError(f"{path}: not a priqn {what} (a {type(data).__name__}); {remedy}")
    version = data.get(FORMAT_KEY, 1)
    if not isinstance(version, int) or not 1 <= version <= FORMAT_VERSION:
        raise PriqnError(
            f"{path}: a {what} of format {version!r}, but this priqn reads formats 1 to "
            f"{FORMAT_VERSION}; load it with the priqn that wrote it (or a newer one)"
        )
    optional = cls.OPTIONAL
    names = [f.name for f in dataclasses.fields(cls)]
    missing = [n for n in names if n not in data and n not in optional]
    if missing:
        raise PriqnError(f"{path}: not a priqn {what} (no {', '.join(missing)}); {remedy}")
    values = {n: data[n] if n in data else optional[n]() for n in names}
    wrong = [n for n, kinds in _KINDS.items() if n in names and not isinstance(values[n], kinds)]
    if cls is Checkpoint and not wrong:
        wrong = _wrong_checkpoint_parts(values)
        values["obs"] = _observations(values["obs"], path, what, remedy)
    if wrong:
        raise PriqnError(
            f"{path}: not a priqn {what} (wrong kind of value in {', '.join(wrong)}); {remedy}"
        )
    return cls(**values)


_KINDS: dict[str, type | tuple[type, ...]] = {
    "online": Mapping,
    "agent": Mapping,
    "obs_shapes": Mapping,
    "num_actions": int,
    "step": int,
    "objectives": (list, tuple),
    "episodes": int,
    "wall_s": (int, float),
    "learner": Mapping,
    "rng_replay": Mapping,
    "rng_act": Mapping,
    "obs": Mapping,
    "config": Mapping,
    "replay_file": (str, type(None)),
    "torch_version": str,
    "replay_chunks": (list, type(None)),
    "in_flight": (list, type(None)),
    "logging": Mapping,
}
"""The kind of value each on-disk field must hold (what a loader may rely on)."""


def _wrong_checkpoint_parts(values: Mapping[str, Any]) -> list[str]:
    """The parts of a checkpoint's ``learner`` that are not what a resume restores."""
    import torch

    learner = values["learner"]
    kinds = {
        "online": Mapping,
        "target": Mapping,
        "optimizer": Mapping,
        "updates": int,
        "tau_generator": torch.Tensor,
    }
    return [f"learner.{k}" for k, kind in kinds.items() if not isinstance(learner.get(k), kind)]


def _observations(
    obs: Mapping[str, Any], path: str | os.PathLike, what: str, remedy: str
) -> dict[str, np.ndarray]:
    """``obs`` as numpy arrays on the CPU (format 2 stores tensors, format 1 arrays)."""
    import torch

    out: dict[str, np.ndarray] = {}
    for key, value in obs.items():
        if isinstance(value, torch.Tensor):
            out[key] = value.cpu().numpy()
        elif isinstance(value, np.ndarray) and value.dtype.name in LEGACY_DTYPES:
            out[key] = value
        else:
            raise PriqnError(
                f"{path}: not a priqn {what} (obs[{key!r}] is a {type(value).__name__}, "
                "expected a tensor); " + remedy
            )
    return out
