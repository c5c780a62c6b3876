"""The training loop's stepper (``priqn.run.stepper``, issue 69): every stepping mode makes
the calls the loop made before it was one stepper (the loop of 5124fc0, kept below as
the reference), in the same order, checkpoints, evaluations and snapshots included.
A fake trainer records them; no env, no network."""

from __future__ import annotations

import sys
from collections import deque
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from priqn.run.stepper import ALL_ENVS, AllAtOnce, InGroups, make_stepper


def _next_multiple(step: int, interval: int) -> int:
    return sys.maxsize if interval <= 0 else (step // interval + 1) * interval


def _rows(rows: slice) -> tuple[Any, ...]:
    return (rows.start, rows.stop)


class FakeTrainer:
    """:class:`priqn.train.Trainer`'s loop calls, recorded with the step they came at."""

    def __init__(self, cfg: SimpleNamespace) -> None:
        self.cfg, self.num_envs, self.step = cfg, cfg.num_envs, 0
        self.calls: list[tuple[Any, ...]] = []
        self.next_ckpt = _next_multiple(0, cfg.checkpoint.interval_steps)
        self.next_eval = _next_multiple(0, cfg.evaluation.interval_steps)

    def act(self, obs: dict[str, np.ndarray], rows: slice = ALL_ENVS) -> np.ndarray:
        self.calls.append(("act", self.step, _rows(rows), obs["x"].tolist()))
        return obs["x"] * 10 + self.step

    def issue(self, envs: Any, actions: np.ndarray) -> None:
        self.calls.append(("issue", self.step, envs, actions.tolist()))

    def collect(
        self, envs: Any, obs: dict[str, np.ndarray], actions: np.ndarray, rows: slice = ALL_ENVS
    ) -> tuple[dict[str, np.ndarray], np.ndarray, dict[str, Any]]:
        self.calls.append(("collect", self.step, envs, _rows(rows), actions.tolist()))
        ended = (actions + self.step) % 3 == 0
        return {"x": obs["x"] + actions % 7}, ended, {"at": self.step}

    def learn(self, decisions: int) -> None:
        self.calls.append(("learn", self.step, decisions))

    def log(self, logger: Any, ended: np.ndarray, infos: Any, rows: slice = ALL_ENVS) -> None:
        self.calls.append(("log", self.step, ended.tolist(), infos, _rows(rows)))

    def evaluate(self, evaluation: Any, logger: Any) -> None:
        self.next_eval = _next_multiple(self.step, self.cfg.evaluation.interval_steps)
        self.calls.append(("evaluate", self.step))

    def keep_snapshot(self, run: Any) -> None:
        self.calls.append(("keep_snapshot", self.step))

    def checkpoint(self, run: Any, logger: Any, envs: Any, obs: dict[str, np.ndarray]) -> None:
        self.next_ckpt = _next_multiple(self.step, self.cfg.checkpoint.interval_steps)
        self.calls.append(("checkpoint", self.step, obs["x"].tolist()))


class FakeGroups:
    """:class:`priqn.env.vector.EnvGroups`' shape: ``groups``, ``rows``, ``size``."""

    def __init__(self, num_envs: int, groups: int) -> None:
        self.size = num_envs // groups
        self.groups = [f"group{g}" for g in range(groups)]
        self.rows = [slice(lo, lo + self.size) for lo in range(0, num_envs, self.size)]


def _after_a_step(cfg: Any, t: Any, envs: Any, obs: Any) -> None:
    """The loop's steps 5.-8., as :func:`priqn.train._train_loop` makes them."""
    if t.step >= t.next_eval:
        t.evaluate(None, None)
    if t.step in cfg.checkpoint.keep_at:
        t.keep_snapshot(None)
    if t.step >= t.next_ckpt or t.step >= cfg.total_steps:
        t.checkpoint(None, None, envs, obs)


def new_loop(cfg: Any, t: Any, envs: Any, obs: Any) -> None:
    stepper = make_stepper(cfg, t, envs, obs)
    for ended, infos, rows in stepper:
        t.log(None, ended, infos, rows)
        _after_a_step(cfg, t, envs, stepper.observations())


def reference_loop(cfg: Any, t: Any, envs: Any, obs: Any) -> None:
    """The loop of 5124fc0 (``_train_loop``, ``_pipelined_steps``, ``_Pipeline``)."""
    if cfg.env_groups > 1:
        obs_G = [{k: v[rows] for k, v in obs.items()} for rows in envs.rows]
        actions_G: list[Any] = [None] * cfg.env_groups
        in_flight: deque[int] = deque()

        def send(g: int, empty_at: int) -> None:
            if t.step + len(in_flight) * envs.size < empty_at:
                actions_G[g] = t.act(obs_G[g], envs.rows[g])
                t.issue(envs.groups[g], actions_G[g])
                in_flight.append(g)

        while t.step < cfg.total_steps:
            empty_at = min(t.next_ckpt, cfg.total_steps)
            for g in range(cfg.env_groups):
                send(g, empty_at)
            while in_flight:
                g = in_flight.popleft()
                obs_G[g], ended, infos = t.collect(
                    envs.groups[g], obs_G[g], actions_G[g], envs.rows[g]
                )
                t.step += envs.size
                t.learn(t.step)
                t.log(None, ended, infos, envs.rows[g])
                if t.step >= t.next_eval:
                    t.evaluate(None, None)
                if t.step in cfg.checkpoint.keep_at:
                    t.keep_snapshot(None)
                send(g, empty_at)
            all_obs = {k: np.concatenate([o[k] for o in obs_G]) for k in obs_G[0]}
            t.checkpoint(None, None, envs, all_obs)
    while t.step < cfg.total_steps and cfg.env_groups == 1:
        actions = t.act(obs)
        t.issue(envs, actions)
        landed = None if cfg.overlap_updates else t.collect(envs, obs, actions)
        t.learn(t.step + cfg.num_envs)
        obs, ended, infos = landed or t.collect(envs, obs, actions)
        t.step += cfg.num_envs
        t.log(None, ended, infos)
        _after_a_step(cfg, t, envs, obs)


def _config(num_envs: int, groups: int, overlap: bool, interval: int) -> SimpleNamespace:
    return SimpleNamespace(
        total_steps=60,
        num_envs=num_envs,
        env_groups=groups,
        overlap_updates=overlap,
        checkpoint=SimpleNamespace(interval_steps=interval, keep_at=(12, 30)),
        evaluation=SimpleNamespace(interval_steps=18),
    )


@pytest.mark.parametrize(
    ("num_envs", "groups", "overlap", "interval"),
    [
        (2, 1, True, 10),  # overlapped
        (2, 1, False, 10),  # serial
        (3, 1, True, 0),  # no checkpoint but the last
        (4, 2, True, 10),  # in groups: a checkpoint between two groups' steps
        (6, 3, True, 12),
        (6, 2, True, 7),  # a checkpoint interval no group step divides
        (4, 4, False, 0),
    ],
)
def test_every_stepping_mode_makes_the_calls_of_the_loop_before_it(
    num_envs: int, groups: int, overlap: bool, interval: int
) -> None:
    calls = []
    for loop in (reference_loop, new_loop):
        cfg = _config(num_envs, groups, overlap, interval)
        t = FakeTrainer(cfg)
        envs = FakeGroups(num_envs, groups) if groups > 1 else "envs"
        loop(cfg, t, envs, {"x": np.arange(num_envs)})
        calls.append(t.calls)
    assert calls[1] == calls[0]
    kinds = {c[0] for c in calls[0]}
    assert {"act", "issue", "collect", "learn", "log", "checkpoint", "evaluate"} <= kinds
    assert calls[0][-1][:2] == ("checkpoint", 60)


def test_the_stepper_is_chosen_once_from_the_config() -> None:
    t = FakeTrainer(_config(4, 2, True, 10))
    assert isinstance(make_stepper(t.cfg, t, FakeGroups(4, 2), {"x": np.arange(4)}), InGroups)
    t = FakeTrainer(_config(4, 1, False, 10))
    stepper = make_stepper(t.cfg, t, "envs", {"x": np.arange(4)})
    assert isinstance(stepper, AllAtOnce) and not stepper.overlap
