"""The weighted-sum schemes never make crashing cheap (issue: fair test, §2).

Every number is checked from the config values, by hand: H_T = (1 - 0.99**100) / 0.01
= 63.397 decisions, P = 10.
"""

from __future__ import annotations

import math

import pytest

from priqn.agents.config import AgentConfig, LearnerConfig
from priqn.agents.scalarise import SCHEMES, crash_margin, horizon, scheme_weights
from priqn.env.config import EnvConfig
from priqn.errors import PriqnError
from priqn.run.train_config import TrainConfig


def test_horizon_by_hand():
    assert horizon(100, 0.99) == pytest.approx(63.3968, abs=1e-4)
    assert horizon(3, 0.5) == pytest.approx(1 + 0.5 + 0.25)
    assert horizon(7, 1.0) == 7.0


def test_old_halving_weights_make_crashing_cheap():
    # worst lower-level penalty: (0.5 + 0.25 + 0.0625) * 63.397 = 51.51 > 10 = crash cost
    assert crash_margin((1.0, 0.5, 0.25, 0.125, 0.0625)) == pytest.approx(10 / 51.510, rel=1e-4)
    assert crash_margin(scheme_weights("halving")) < 1


@pytest.mark.parametrize("name", ["hln-2", "hln-4"])
def test_hierarchy_schemes_keep_a_crash_margin_of_two(name):
    w = scheme_weights(name)
    assert crash_margin(w) == pytest.approx(2.0)
    assert w[0] == 1.0 and all(a > b for a, b in zip(w, w[1:], strict=False))  # falls per level


def test_hln2_by_hand():
    # c = 10 / (2 * 63.397 * (1 + 1/2 + 1/8)) = 0.048534; then halving per level.
    w = scheme_weights("hln-2")
    c = 10 / (2 * horizon(100, 0.99) * 1.625)
    assert w == pytest.approx((1.0, c, c / 2, c / 4, c / 8))
    assert c == pytest.approx(0.048534, abs=1e-6)


def test_progress_does_not_enter_the_bound():
    # Crashing forfeits progress (>= 0), so only risk, lane keeping and comfort count.
    base = (1.0, 0.01, 0.01, 0.0, 0.01)
    assert crash_margin(base) == crash_margin((1.0, 0.01, 0.01, 5.0, 0.01))
    assert crash_margin((1.0, 0.0, 0.0, 1.0, 0.0)) == math.inf


def test_train_config_resolves_the_scheme_for_its_own_episodes():
    default = TrainConfig()
    assert default.agent.reward_weights is None  # resolved per run, never frozen in
    assert default.reward_weights == pytest.approx(scheme_weights("hln-2-task"))
    assert default.crash_margin == pytest.approx(2.0)
    # Longer episodes: the scheme rescales so the margin still holds.
    long = TrainConfig(env=EnvConfig(obs_size_px=64, max_episode_steps=300))
    assert long.crash_margin == pytest.approx(2.0)
    assert long.reward_weights[1] < default.reward_weights[1]
    # Explicit weights are kept as given; the margin reports what they mean.
    old = TrainConfig(agent=AgentConfig(reward_weights=(1.0, 0.5, 0.25, 0.125, 0.0625)))
    assert old.crash_margin < 1
    assert set(SCHEMES) == {"hln-2", "hln-4", "hln-2-task", "halving"}


def test_unknown_scheme_is_one_line():
    with pytest.raises(PriqnError, match=r"agent.reward_scheme: unknown scheme 'x' \(valid: hln-2"):
        scheme_weights("x")


def test_per_objective_discounts():
    # Lower objectives with gamma 0.5: H = 2 - 2**-99 ~ 2 decisions; crash 10 vs 3 * 0.1 * 2.
    gammas = (0.99, 0.5, 0.5, 0.99, 0.5)
    assert crash_margin((1.0, 0.1, 0.1, 0.1, 0.1), gamma=gammas) == pytest.approx(10 / 0.6)
    # Scalar-reward agents have one head, so one discount.
    with pytest.raises(ValueError, match=r"learner.gamma: agent 'iqn' learns one weighted-sum"):
        TrainConfig(agent=AgentConfig(name="iqn"), learner=LearnerConfig(gamma=gammas))
    cfg = TrainConfig(agent=AgentConfig(name="pr-iqn"), learner=LearnerConfig(gamma=gammas))
    assert cfg.crash_margin >= 2.0  # the scheme uses the longest horizon


def test_a_scheme_override_changes_the_weights():
    # The sensitivity grid sets agent.reward_scheme on top of a preset: the weights must
    # follow it (they once stayed those of the default scheme).
    from priqn.run.train_config import resolve_config

    cfg = resolve_config(preset="default", agent="iqn", overrides=["agent.reward_scheme=hln-4"])
    assert cfg.reward_weights == pytest.approx(scheme_weights("hln-4"))
    assert cfg.resolved_agent.reward_weights == pytest.approx(scheme_weights("hln-4"))
    old = resolve_config(preset="default", agent="iqn", overrides=["agent.reward_scheme=halving"])
    assert old.reward_weights == (1.0, 0.5, 0.25, 0.125, 0.0625) and old.crash_margin < 1


def test_hln2_task_keeps_the_penalties_and_makes_progress_the_task_reward():
    # Progress weight: a whole episode of full progress = one safety event:
    # w_p * 63.397 = 10 -> w_p = 0.15774. Penalties and crash margin as hln-2.
    w, base = scheme_weights("hln-2-task"), scheme_weights("hln-2")
    assert w[3] == pytest.approx(10 / horizon(100, 0.99)) and w[3] == pytest.approx(
        0.15774, abs=1e-5
    )
    assert [w[i] for i in (0, 1, 2, 4)] == pytest.approx([base[i] for i in (0, 1, 2, 4)])
    assert crash_margin(w) == pytest.approx(2.0)
