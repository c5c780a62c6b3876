"""``env_groups`` (issue 51): the env workers in groups that step in turn, so that acting,
stepping and updating overlap. A new order of the loop's steps, so a different run of a
seed than ``env_groups = 1`` -- but one seed, one run, and a resume that changes nothing.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_exact_resume import _assert_same_training, kill_after_the_first_checkpoint
from test_train import TINY, cli

from priqn.agents.replay import ReplayBuffer
from priqn.env.config import EnvConfig
from priqn.env.vector import EnvGroups, make_vector_env, restore_episodes
from priqn.errors import PriqnError
from priqn.run.train_config import resolve_config

STEPS = 300
PIPELINED = [
    "--seed", "5", "--steps", str(STEPS), "--num-envs", "2", "--set", "env_groups=2",
    "--set", "checkpoint.interval_steps=100", "--set", "checkpoint.keep_at=[250]",
    "--set", "evaluation.interval_steps=200", "--set", "evaluation.episodes=1", *TINY,
]  # fmt: skip


def test_env_groups_must_divide_num_envs() -> None:
    with pytest.raises(PriqnError, match=r"env_groups: expected a divisor of num_envs \(4\)"):
        resolve_config(num_envs=4, overrides=["env_groups=3"])
    with pytest.raises(PriqnError, match="env_groups"):
        resolve_config(overrides=["env_groups=0"])
    assert resolve_config(num_envs=4, overrides=["env_groups=2"]).env_groups == 2


def test_a_group_added_at_a_time_fills_the_buffer_as_all_at_once() -> None:
    """Four envs stored as two groups of two (a step of envs 0-1, then of 2-3) give the rings
    one step of all four gives: same rows, same flags, same final observations."""
    spec = {"x": ((3,), np.float32)}
    whole, halves = (ReplayBuffer(spec, 4, 40, n_step=2) for _ in range(2))
    rng = np.random.default_rng(0)
    for _ in range(6):
        obs = {"x": rng.random((4, 3), dtype=np.float32)}
        actions = rng.integers(5, size=4)
        rewards = rng.random((4, 5), dtype=np.float32)
        terminated = rng.random(4) < 0.2
        truncated = ~terminated & (rng.random(4) < 0.2)
        final = [
            {"x": obs["x"][e] + 1} if terminated[e] or truncated[e] else None for e in range(4)
        ]
        whole.add(obs, actions, rewards, terminated, truncated, final)
        for rows in (slice(0, 2), slice(2, 4)):
            part = {"x": obs["x"][rows]}
            halves.add(
                part, actions[rows], rewards[rows], terminated[rows], truncated[rows],
                final[rows], rows,
            )  # fmt: skip
    for name in ("action", "reward", "starts", "ended", "terminated", "written"):
        assert np.array_equal(getattr(whole, name), getattr(halves, name)), name
    assert np.array_equal(whole.obs["x"], halves.obs["x"])
    b1, b2 = (buf.sample(8, np.random.default_rng(1)) for buf in (whole, halves))
    assert np.array_equal(b1["obs"]["x"], b2["obs"]["x"])


def test_env_groups_are_the_vector_envs_workers_in_order() -> None:
    """Two groups of one worker start where the two workers of make_vector_env (same seed)
    start, reseed as gymnasium does (worker i: seed + i), and take and give every worker's
    episode record in worker order."""
    cfg = EnvConfig(family="tjunction", obs_size_px=32, max_episode_steps=12)
    groups = EnvGroups(cfg, num_envs=2, groups=2, seed=3)
    venv = make_vector_env(cfg, num_envs=2, seed=3)
    try:
        assert groups.rows == [slice(0, 1), slice(1, 2)] and groups.size == 1
        for seed in (None, 11):
            a, _ = groups.reset(seed=seed)
            b, _ = venv.reset(seed=seed)
            for k in b:
                assert np.array_equal(a[k], b[k]), (seed, k)
        for env in groups.groups:  # one step each, the groups in turn
            env.step_async(np.array([12]))
            env.step_wait()
        venv.step(np.array([12, 12]))
        records = groups.call("episode_record")
        assert records == tuple(venv.call("episode_record"))
        assert all(r is not None for r in records)
        restored = restore_episodes(groups, records[::-1])  # each plays the other's episode
        again = restore_episodes(venv, records[::-1])
        for k in again:
            assert np.array_equal(restored[k], again[k]), k
    finally:
        groups.close()
        venv.close()
    with pytest.raises(PriqnError, match="env_groups: expected a divisor of num_envs"):
        EnvGroups(cfg, num_envs=3, groups=2)


@pytest.fixture(scope="module")
def pipelined(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The uninterrupted pipelined Pr-IQN run of seed 5 (evaluation, snapshot, checkpoints)."""
    root = tmp_path_factory.mktemp("pipelined")
    out = cli("--agent", "pr-iqn", "--runs-dir", str(root), "--name", "full", *PIPELINED)
    assert out.returncode == 0, out.stderr[-2000:]
    return root / "full"


def test_pipelined_run_killed_then_resumed_is_the_same_training(
    tmp_path: Path, pipelined: Path
) -> None:
    run = kill_after_the_first_checkpoint(tmp_path, "pr-iqn", PIPELINED)
    out = cli("--resume", str(run))
    assert out.returncode == 0, out.stderr[-2000:]
    # Two runs of the seed, one of them in two sessions: the same training.
    _assert_same_training(pipelined, run)
    meta = json.loads((run / "meta.json").read_text())
    # learning starts at 64 decisions, then one update per 4 decisions: as many as the
    # loop with every worker at once makes
    assert meta["updates_done"] == (STEPS - 64) // 4 + 1
