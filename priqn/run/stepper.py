"""How the training loop steps its env workers: one stepper, chosen once from the config
(:func:`make_stepper`), that :func:`priqn.train._train_loop` iterates over.

Each item it yields is one env step acted for, simulated, stored in the replay buffer
and learned from (the updates due by then), the trainer's ``step`` counting its
decisions; the loop then logs it, evaluates, keeps a snapshot and checkpoints. The same
calls of :class:`priqn.train.Trainer` in three orders:

- **overlapped** (the default, :class:`AllAtOnce`): act → issue the step → learn while
  the workers simulate → collect and store it;
- **serial** (``overlap_updates = false``, :class:`AllAtOnce`): act → issue → collect and
  store → learn (a step's batch may then include that step's transitions);
- **in groups** (``env_groups`` > 1, :class:`InGroups`): the groups of
  :class:`~priqn.env.vector.EnvGroups` step in turn; while the others simulate, one
  group's step is collected, stored and learned from, the loop handles it, and the group
  is acted for and sent its next step.

Whatever the order, it is fixed by the config, never by timing: one seed, one run
(docs/implementation-details.md §12).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator, Mapping
from typing import Any, NamedTuple

import numpy as np

ALL_ENVS = slice(None)
"""Every env worker (the rows of an ``[E, ...]`` array); a group's rows are a slice of them."""


class Landed(NamedTuple):
    """One env step collected, stored and learned from, as the loop gets it."""

    ended: np.ndarray
    """Per worker of the step, whether its episode ended (``[E]``, or ``[E / G]`` bool)."""
    infos: dict[str, Any]
    """The step's infos (an ended episode's ``final_info``)."""
    rows: slice
    """The workers that stepped (:data:`ALL_ENVS`, or a group's rows)."""


def open_env_workers(cfg: Any, seed: int) -> Any:
    """The env workers of ``cfg`` (a :class:`~priqn.run.train_config.TrainConfig`): one
    vector env, or :class:`~priqn.env.vector.EnvGroups` with ``env_groups`` > 1, seeded
    alike (their scenes preloaded). The caller closes them."""
    from priqn.env.vector import EnvGroups, make_vector_env

    if cfg.env_groups > 1:
        return EnvGroups(cfg.env, cfg.num_envs, cfg.env_groups, seed=seed, preload=True)
    return make_vector_env(cfg.env, cfg.num_envs, seed=seed, preload=True)


def make_stepper(
    cfg: Any, t: Any, envs: Any, obs: Mapping[str, np.ndarray]
) -> AllAtOnce | InGroups:
    """The stepper of ``cfg`` for trainer ``t`` (a :class:`priqn.train.Trainer`) and the
    workers of :func:`open_env_workers`, starting from the observations ``obs``."""
    if cfg.env_groups > 1:
        return InGroups(t, envs, obs)
    return AllAtOnce(t, envs, obs, overlap=cfg.overlap_updates)


class AllAtOnce:
    """Every worker steps at once (``env_groups = 1``), up to the budget. With ``overlap``
    the learner's updates run while the workers simulate the step; without, after it is
    stored (the serial order)."""

    def __init__(self, t: Any, envs: Any, obs: Mapping[str, np.ndarray], overlap: bool) -> None:
        self.t, self.envs, self.overlap = t, envs, overlap
        self.obs = obs
        """The observations every worker stands at (keys → ``[E, ...]``)."""

    def __iter__(self) -> Iterator[Landed]:
        t = self.t
        while t.step < t.cfg.total_steps:
            actions = t.act(self.obs)  # act: the agent's acting rule, ε-greedy on top
            t.issue(self.envs, actions)  # step: the env workers simulate it meanwhile
            if self.overlap:
                t.learn(t.step + t.num_envs)  # learn while they simulate
                self.obs, ended, infos = t.collect(self.envs, self.obs, actions)  # store
            else:
                self.obs, ended, infos = t.collect(self.envs, self.obs, actions)  # store
                t.learn(t.step + t.num_envs)  # then learn
            t.step += t.num_envs
            yield Landed(ended, infos, ALL_ENVS)

    def observations(self) -> Mapping[str, np.ndarray]:
        """Every worker's observation now (keys → ``[E, ...]``)."""
        return self.obs


class InGroups:
    """The groups of :class:`~priqn.env.vector.EnvGroups` step in turn, up to the budget.

    Every group is acted for and sent a step; then, one at a time in the order sent, a
    group's step is collected and stored, the updates due by then run while the other
    groups simulate, the loop handles the step, and the group is acted for and sent its
    next.

    The pipeline empties at every checkpoint (and at the budget): no group is sent a step
    that would pass it and the steps in flight are collected, so the loop's checkpoint,
    due at the last of them, finds none in flight and a resume continues exactly.
    """

    def __init__(self, t: Any, envs: Any, obs: Mapping[str, np.ndarray]) -> None:
        self.t, self.envs = t, envs
        self.obs_G = [{k: v[rows] for k, v in obs.items()} for rows in envs.rows]
        """Per group, the observations its workers stand at (keys → ``[E / G, ...]``)."""
        self.actions_G: list[np.ndarray] = [np.empty(0, dtype=np.int64) for _ in envs.rows]
        """Per group, the actions of its step in flight ``[E / G]``."""
        self.in_flight: deque[int] = deque()
        """The groups with a step in flight, the one sent first on the left."""

    def __iter__(self) -> Iterator[Landed]:
        t = self.t
        while t.step < t.cfg.total_steps:
            empty_at = min(t.next_ckpt, t.cfg.total_steps)  # the next checkpoint
            for g in range(t.cfg.env_groups):
                self._send(g, empty_at)
            while self.in_flight:
                g, ended, infos = self._collect()
                t.learn(t.step)  # while the other groups simulate
                yield Landed(ended, infos, self.envs.rows[g])
                self._send(g, empty_at)  # its next step

    def observations(self) -> dict[str, np.ndarray]:
        """Every worker's observation now (keys → ``[E, ...]``), in worker order."""
        return {k: np.concatenate([o[k] for o in self.obs_G]) for k in self.obs_G[0]}

    def _send(self, g: int, empty_at: int) -> None:
        """Act for group ``g`` and send its step, unless the decisions sent would then
        pass ``empty_at`` (the next checkpoint or the budget)."""
        t, size = self.t, self.envs.size
        if t.step + len(self.in_flight) * size < empty_at:
            self.actions_G[g] = t.act(self.obs_G[g], self.envs.rows[g])
            t.issue(self.envs.groups[g], self.actions_G[g])
            self.in_flight.append(g)

    def _collect(self) -> tuple[int, np.ndarray, dict[str, Any]]:
        """Collect the step sent first and store it; returns (its group, ended ``[E / G]``,
        infos). ``step`` counts its decisions."""
        g = self.in_flight.popleft()
        env, rows = self.envs.groups[g], self.envs.rows[g]
        self.obs_G[g], ended, infos = self.t.collect(env, self.obs_G[g], self.actions_G[g], rows)
        self.t.step += self.envs.size
        return g, ended, infos
