"""priqn.wrappers on a fake vector-reward env (no SUMO)."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

from priqn.agents.scalarise import scheme_weights
from priqn.errors import PriqnError
from priqn.wrappers import ScalarizeReward, ScalarizeVectorReward


class FakeEnv(gymnasium.Env):
    """Rewards [1, 2, 3, 4, 5] every step; ends after 3 steps."""

    observation_space = gymnasium.spaces.Box(0, 1, (1,), np.float32)
    action_space = gymnasium.spaces.Discrete(2)
    reward_space = gymnasium.spaces.Box(
        np.array([-10, -1, -1, 0, -1], np.float32), np.array([0, 0, 0, 2, 0], np.float32)
    )

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(1, np.float32), {}

    def step(self, action):
        self.t += 1
        return np.zeros(1, np.float32), np.arange(1.0, 6.0), self.t >= 3, False, {}


def test_scalarize_single_env_by_hand():
    env = ScalarizeReward(FakeEnv(), weights=(1, 0.5, 0, 0, -1))
    env.reset(seed=0)
    _, r, _, _, info = env.step(0)
    assert r == pytest.approx(1 + 1.0 - 5)  # 1*1 + .5*2 + 0 + 0 - 1*5
    assert info["reward_vector"].tolist() == [1, 2, 3, 4, 5]
    # Range from reward_space: low = -10*1 + -1*.5 + 0 + 0 + (-1 * 0) ; high = 0 + 0 + .. + 1
    assert env.reward_range == pytest.approx((-10.5, 1.0))


def test_default_is_the_agents_scheme_and_bad_weights_are_one_line():
    env = ScalarizeReward(FakeEnv())
    assert env.weights_O.tolist() == pytest.approx(scheme_weights("hln-2-task"))
    with pytest.raises(PriqnError, match=r"weights: expected a scheme name or 5 finite numbers"):
        ScalarizeReward(FakeEnv(), weights=(1, 2))
    with pytest.raises(PriqnError, match=r"unknown scheme 'x'"):
        ScalarizeReward(FakeEnv(), weights="x")


class FakeVectorEnv(gymnasium.vector.VectorEnv):
    """Two envs whose rewards are [1, 2, 3, 4, 5] each step (as priqn's vector env gives)."""

    def __init__(self):
        self.num_envs = 2
        self.single_observation_space = FakeEnv.observation_space
        self.single_action_space = FakeEnv.action_space
        self.observation_space = gymnasium.spaces.Box(0, 1, (2, 1), np.float32)
        self.action_space = gymnasium.spaces.MultiDiscrete([2, 2])

    def reset(self, *, seed=None, options=None):
        return np.zeros((2, 1), np.float32), {}

    def step(self, actions):
        rewards = np.tile(np.arange(1.0, 6.0, dtype=np.float32), (2, 1))
        done = np.zeros(2, bool)
        return np.zeros((2, 1), np.float32), rewards, done, done, {}


def test_scalarize_vector_env():
    envs = ScalarizeVectorReward(FakeVectorEnv(), weights=(0, 0, 0, 1, 0))
    envs.reset(seed=0)
    _, r, _, _, infos = envs.step(np.zeros(2, np.int64))
    assert r.dtype == np.float32 and r.tolist() == [4.0, 4.0]
    assert infos["reward_vector"].shape == (2, 5)


# --------------------------------------------------------------------------- other libraries
# Optional: `pip install -e ".[compat]"`; skipped when the packages are absent. Each runs
# SUMO in a subprocess (libsumo: one simulation per process).

MO_GYM = """
import gymnasium, mo_gymnasium as mo_gym, numpy as np, priqn
env = gymnasium.make("priqn/Intersection-v0", obs_size_px=32, max_episode_steps=6)
env = mo_gym.wrappers.MORecordEpisodeStatistics(env, gamma=0.99)
env = mo_gym.wrappers.LinearReward(env, weight=np.array([1.0, 0.5, 0.25, 0.125, 0.0625]))
env.reset(seed=0)
done = False
while not done:
    obs, r, term, trunc, info = env.step(12)
    done = term or trunc
assert np.isscalar(r) or np.ndim(r) == 0, r
assert info["vector_reward"].shape == (5,), info
assert info["episode"]["r"].shape == (5,), info["episode"]
print("ok", float(r))
"""

SB3 = """
import gymnasium, priqn
from stable_baselines3 import DQN
from priqn.wrappers import ScalarizeReward
env = ScalarizeReward(gymnasium.make("priqn/Intersection-v0", obs_size_px=64, max_episode_steps=20))
model = DQN("MultiInputPolicy", env, learning_starts=50, buffer_size=500, batch_size=16,
            train_freq=4, seed=0, verbose=0, device="cpu")
model.learn(total_timesteps=300)
action, _ = model.predict(env.reset(seed=1)[0], deterministic=True)
assert 0 <= int(action) < 25
print("ok")
"""


@pytest.mark.parametrize(
    ("module", "script"), [("mo_gymnasium", MO_GYM), ("stable_baselines3", SB3)]
)
def test_other_libraries_drive_the_env(module, script):
    import subprocess
    import sys

    pytest.importorskip(module)
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=600
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.startswith("ok")
