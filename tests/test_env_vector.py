"""make_vector_env: spawned workers, vector rewards, SAME_STEP autoreset, dead workers reported."""

from __future__ import annotations

import os
import signal
import sys
import time

import numpy as np
import pytest

from priqn.env.config import EnvConfig
from priqn.env.vector import make_vector_env, worker_seeds
from priqn.errors import PriqnError


def test_worker_seeds_are_derived_and_distinct() -> None:
    a = worker_seeds(7, 4)
    assert a == worker_seeds(7, 4) and len(set(a)) == 4
    assert a != worker_seeds(8, 4)


def test_bad_worker_count() -> None:
    with pytest.raises(PriqnError, match="num_envs"):
        make_vector_env(EnvConfig(), 0)


def test_vector_env_steps_resets_and_reports_dead_workers() -> None:
    had_libsumo = "libsumo" in sys.modules
    cfg = EnvConfig(family="tjunction", obs_size_px=32, max_episode_steps=12)
    venv = make_vector_env(cfg, num_envs=2, seed=3)
    try:
        obs, infos = venv.reset()
        assert obs["bev"].shape == (2, 4, 32, 32) and obs["kinematics"].shape == (2, 4)
        assert infos["net"].shape == (2,)
        finished = 0
        for _ in range(14):  # the 12-step limit ends every episode at least once
            obs, rewards, terminated, truncated, infos = venv.step(np.array([12, 12]))
            assert rewards.shape == (2, 5) and rewards.dtype == np.float32
            done = terminated | truncated
            if done.any():
                finished += int(done.sum())
                assert "final_obs" in infos and "final_info" in infos
                i = int(np.flatnonzero(done)[0])
                assert infos["final_info"]["episode_steps"][i] >= 1
                assert infos["episode_steps"][i] == 0  # SAME_STEP: already reset
        assert finished >= 2
        if not had_libsumo:
            assert "libsumo" not in sys.modules  # the parent never runs SUMO
        os.kill(venv.processes[1].pid, signal.SIGKILL)
        time.sleep(0.3)
        with pytest.raises(PriqnError, match="worker 1 .* died"):
            venv.step(np.array([12, 12]))
    finally:
        venv.close()


def _serial_rewards(seed: int, actions: list[int]) -> np.ndarray:
    from priqn.env.intersection import IntersectionEnv

    env = IntersectionEnv(EnvConfig(family="tjunction", obs_size_px=32), seed=seed)
    try:
        env.reset()  # the constructor seed, as a vector worker uses it
        out = []
        for a in actions:
            _, r, term, trunc, _ = env.step(a)
            out.append(r)
            if term or trunc:
                break
        return np.array(out)
    finally:
        env.close()


def test_a_vector_worker_replays_the_serial_episode() -> None:
    import concurrent.futures
    import multiprocessing

    actions = [17, 12, 13, 17, 22, 17, 11, 17] * 4
    (seed,) = worker_seeds(5, 1)
    ctx = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(1, mp_context=ctx) as pool:
        serial = pool.submit(_serial_rewards, seed, actions).result(timeout=120)
    venv = make_vector_env(EnvConfig(family="tjunction", obs_size_px=32), num_envs=1, seed=5)
    try:
        venv.reset()
        parallel = []
        for a in actions[: len(serial)]:
            _, r, _, _, _ = venv.step(np.array([a]))
            parallel.append(r[0])
    finally:
        venv.close()
    np.testing.assert_array_equal(np.array(parallel), serial)


def test_a_worker_killed_while_the_parent_waits_is_named() -> None:
    # The training loop blocks in step_wait while the workers step: a worker that dies
    # then shows up as a broken pipe before the OS reports its exit (issue 10).
    cfg = EnvConfig(family="tjunction", obs_size_px=32)
    venv = make_vector_env(cfg, num_envs=2, seed=3)
    try:
        venv.reset()
        victim = venv.processes[0].pid
        os.kill(victim, signal.SIGSTOP)  # it cannot answer the step sent next
        venv.step_async(np.array([12, 12]))
        os.kill(victim, signal.SIGKILL)
        with pytest.raises(PriqnError, match=r"vector env step: worker 0 \(exit code -9\) died"):
            venv.step_wait()
        assert venv.closed
    finally:
        venv.close()


def test_an_error_in_a_worker_names_it_without_a_traceback(capfd) -> None:
    venv = make_vector_env(EnvConfig(family="tjunction", obs_size_px=32), num_envs=2, seed=3)
    try:
        with pytest.raises(PriqnError) as exc:
            venv.reset(options={"colour": "red"})
        assert str(exc.value) == (
            "vector env worker 0: reset options: unknown key 'colour' (valid: net, density, command)"
        )
        assert "Traceback" not in capfd.readouterr().err
    finally:
        venv.close()


@pytest.mark.parametrize(("mode", "kind"), [(None, "PriqnVectorEnv"), ("async", "AsyncVectorEnv")])
def test_gymnasium_make_vec_runs_past_an_episode_end(mode: str | None, kind: str) -> None:
    import gymnasium
    from gymnasium.vector import AutoresetMode

    import priqn  # noqa: F401  (registers the env)

    venv = gymnasium.make_vec(
        "priqn/Intersection-v0",
        num_envs=2,
        vectorization_mode=mode,
        obs_size_px=32,
        max_episode_steps=4,
        seed=3,
    )
    try:
        assert type(venv).__name__ == kind and venv.num_envs == 2
        assert venv.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
        venv.reset()
        ended = 0
        for _ in range(6):  # past the 4-decision limit: the autoreset keeps vector rewards
            _, rewards, term, trunc, infos = venv.step(np.array([12, 12]))
            assert rewards.shape == (2, 5)  # NEXT_STEP would give (2,) on the reset step
            if (term | trunc).any():
                assert "final_obs" in infos and "final_info" in infos
            ended += int((term | trunc).sum())
        assert ended >= 2
    finally:
        venv.close()


def test_gymnasium_make_vec_refuses_sync_and_next_step_in_one_line() -> None:
    import gymnasium
    from gymnasium.vector import AutoresetMode

    import priqn  # noqa: F401  (registers the env)
    from priqn.env.intersection import IntersectionEnv
    from priqn.env.vector import GYMNASIUM_SYNC_REFUSED, NEXT_STEP_REFUSED, make_env

    assert make_env.metadata == IntersectionEnv.metadata
    with pytest.raises(PriqnError) as sync:
        gymnasium.make_vec("priqn/Intersection-v0", num_envs=2, vectorization_mode="sync")
    assert str(sync.value) == GYMNASIUM_SYNC_REFUSED and "\n" not in str(sync.value)
    with pytest.raises(PriqnError) as next_step:  # refused before any worker starts
        gymnasium.make_vec(
            "priqn/Intersection-v0",
            num_envs=2,
            vectorization_mode="async",
            vector_kwargs={"autoreset_mode": AutoresetMode.NEXT_STEP},
        )
    assert str(next_step.value) == NEXT_STEP_REFUSED and "SAME_STEP" in NEXT_STEP_REFUSED


def test_env_config_from_dict_and_keywords_and_reward_space() -> None:
    import gymnasium

    import priqn  # noqa: F401

    env = gymnasium.make(
        "priqn/Intersection-v0", config={"family": "fourway", "obs_size_px": 32}, densities=[0.5]
    )
    cfg = env.unwrapped.config
    assert (cfg.family, cfg.obs_size_px, cfg.densities) == ("fourway", 32, (0.5,))
    space = env.unwrapped.reward_space
    assert space.shape == (5,) and space.low.tolist() == [-10, -1, -1, 0, -1]
    assert space.high.tolist() == [0, 0, 0, 2, 0]  # progress <= 1 per decision + bonus 1
    with pytest.raises(PriqnError, match=r"env config: unknown key 'colour' \(valid: "):
        gymnasium.make("priqn/Intersection-v0", colour="red")
    env.close()
