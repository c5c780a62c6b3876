"""Agents: rules (hand-built quantiles), registry, network shapes, replay, one learner step."""

from __future__ import annotations

import types

import numpy as np
import pytest
import torch

from priqn.agents import config as agent_config
from priqn.agents import rules
from priqn.agents.config import (
    SHIPPED_AGENTS,
    AgentConfig,
    AgentSpec,
    LearnerConfig,
    NetworkConfig,
)
from priqn.agents.learner import Learner
from priqn.agents.network import QuantileNetwork, tau_grid
from priqn.agents.policy import Policy
from priqn.agents.registry import make_agent
from priqn.agents.replay import ReplayBuffer
from priqn.errors import PriqnError
from priqn.objectives import OBJECTIVES

K, A = 8, 6


def flat(values_NA: list[list[float]]) -> torch.Tensor:
    """Quantiles [1, N, K, A] whose K quantiles all equal the given mean (+ tiny spread)."""
    v = torch.tensor(values_NA, dtype=torch.float32)  # [N, A]
    spread = torch.linspace(-0.01, 0.01, K).view(1, K, 1)
    return (v.unsqueeze(1) + spread).unsqueeze(0)


# ------------------------------------------------------------------------------ rules


def test_masked_uniform_choice_by_hand():
    mask = torch.tensor([[False, True, False, True, True, False]] * 3)
    u = torch.tensor([0.0, 0.5, 0.99])
    # True entries: 1, 3, 4 -> j = floor(u*3) = 0, 1, 2
    assert rules.masked_uniform_choice(mask, u).tolist() == [1, 3, 4]


def test_masked_uniform_choice_is_uniform_over_the_mask():
    mask = torch.tensor([[True, False, True, False, False, True]]).expand(30000, -1)
    u = torch.rand(30000, generator=torch.Generator().manual_seed(0))
    counts = torch.bincount(rules.masked_uniform_choice(mask, u), minlength=A)
    assert counts[[1, 3, 4]].sum() == 0
    assert counts[[0, 2, 5]].min() > 9500


def test_target_rule_uses_only_actions_of_s_h_with_a_given_mask():
    q = torch.zeros(1, 2, K, A)
    q[0, 0, :, 5] = 10.0  # head 0's global argmax is action 5
    q[0, 0, :, 2] = 3.0
    q[0, 1, :, 1] = 7.0
    mask = torch.tensor([[[True, True, True, False, False, False], [True] * A]])
    subsets = lambda _q: types.SimpleNamespace(per_objective=mask)  # noqa: E731
    assert rules.target_optimal_subset(q, subsets).tolist() == [[2, 1]]
    assert rules.target_own_argmax(q, None).tolist() == [[5, 1]]


def test_pr_iqn_target_with_the_real_preorder_avoids_the_global_argmax():
    # Safety: actions 0-2 safe (0), 3-5 crash (-10). Progress prefers action 5 strongly.
    safety = [0.0, 0.0, 0.0, -10.0, -10.0, -10.0]
    mid = [0.0] * A
    progress = [1.0, 2.0, 3.0, 4.0, 5.0, 9.0]
    q = flat([safety, mid, mid, progress, mid])
    agent = make_agent("pr-iqn", AgentConfig(eps=0.2))
    s = agent.subsets(q)
    assert s.per_objective[0, 0].tolist() == [True, True, True, False, False, False]
    a_star = agent.target_actions(q)
    assert a_star[0, 3].item() == 2  # progress head: best action inside S_progress
    assert q[0, 3].mean(0).argmax().item() == 5  # ... while its global argmax is unsafe
    assert bool(s.per_objective[0, 3, a_star[0, 3]])
    off = make_agent("pr-iqn", AgentConfig(train_preorder=False))
    assert off.target_actions(q)[0, 3].item() == 5


def test_pr_iqn_acts_only_inside_the_leaf_set():
    safety = [0.0, 0.0, 0.0, -10.0, -10.0, -10.0]
    mid = [0.0] * A
    progress = [1.0, 1.0, 1.0, 9.0, 9.0, 9.0]
    comfort = [0.0, 5.0, 5.0, 0.0, 0.0, 0.0]
    q = flat([safety, mid, mid, progress, comfort]).expand(4000, -1, -1, -1)
    agent = make_agent("pr-iqn", AgentConfig(eps=0.2))
    leaf = agent.subsets(q[:1]).leaf[0]
    assert leaf.tolist() == [False, True, True, False, False, False]
    u = torch.rand(4000, generator=torch.Generator().manual_seed(1))
    acts = agent.act(q, u)
    assert set(acts.tolist()) == {1, 2}


def test_baseline_acting_rules_by_hand():
    q = flat([[1, 0, 0, 0, 0, 0], [0, 0.6, 0, 0, 0, 0], [0, 0.6, 0, 0, 0, 0], [0] * 6, [0] * 6])
    u = torch.zeros(1)
    # MA-IQN acts on the IQN scheme's weighted sum of head means (hln-2-task by default):
    # action 0: 1 * w_safety = 1; action 1: 0.6 * (w_risk + w_lane) = 0.6 * 0.0728 = 0.044.
    assert make_agent("ma-iqn").act(q, u).item() == 0
    # With equal weights it is the plain sum: 1.2 > 1.
    assert make_agent("ma-iqn", AgentConfig(reward_weights=(1.0,) * 5)).act(q, u).item() == 1
    assert make_agent("ensemble-iqn").act(q, u).item() == 1  # mean over heads
    assert make_agent("iqn").act(q[:, :1], u).item() == 0


def test_near_greedy_set_by_hand():
    """One state, K = 2, A = 3, both quantiles of action a equal to a: means 0, 1, 2.
    The 6 entries have population std sqrt(2/3) = 0.816, so action 1 is 1.22 std below
    the best and action 0 2.45: ε 1.0 keeps {2}, ε 1.3 {1, 2}, ε 2.5 all three."""
    values_BKA = torch.tensor([[[0.0, 1.0, 2.0], [0.0, 1.0, 2.0]]])
    sets = {
        eps: rules.near_greedy_subsets(values_BKA, eps).leaf[0].tolist()
        for eps in (0.0, 1.0, 1.3, 2.5)
    }
    assert sets == {
        0.0: [False, False, True],
        1.0: [False, False, True],
        1.3: [False, True, True],
        2.5: [True, True, True],
    }


@pytest.mark.parametrize("name", ["iqn", "ensemble-iqn", "ma-iqn"])
def test_scalar_value_ranks_like_the_greedy_rule(name):
    """The near-greedy control ranks actions by the value the agent's greedy rule uses:
    the argmax of its mean is the greedy action, so ε = 0 acts greedily."""
    agent = make_agent(name)
    q = torch.randn(64, agent.num_heads, K, A, generator=torch.Generator().manual_seed(3))
    values = rules.SCALAR_VALUES[agent.spec.acting_rule](q, agent.reward_weights_O)
    assert agent.spec.scalar_value is rules.SCALAR_VALUES[agent.spec.acting_rule]
    greedy = agent.act(q, torch.zeros(64))
    assert torch.equal(values.mean(dim=1).argmax(dim=1), greedy)
    subset = rules.near_greedy_subsets(values, 0.0).leaf
    assert subset.sum(dim=1).eq(1).all() and torch.equal(subset.long().argmax(dim=1), greedy)


def test_near_greedy_policy_label_acting_and_refusal():
    iqn = make_agent("iqn")
    policy = Policy(small_net(1), iqn, K, labels=iqn.labels)
    control = policy.near_greedy(0.2)
    assert control.labels["label"] == "IQN near-greedy ε=0.2" and policy.labels["label"] == "IQN"
    assert control.network is policy.network and control.subset_size_names == ("leaf",)
    rng = np.random.default_rng(0)
    obs = {
        "bev": rng.integers(0, 255, (5, 4, 32, 32)).astype(np.uint8),
        "lidar": rng.integers(0, 255, (5, 2, 32, 32)).astype(np.uint8),
        "command": np.eye(3, dtype=np.float32)[[0, 1, 2, 0, 1]],
        "kinematics": rng.normal(size=(5, 4)).astype(np.float32),
    }
    values_BKA = policy.quantiles(obs)[:, 0]
    allowed_BA = rules.near_greedy_subsets(values_BKA, 0.2).leaf.numpy()
    decision = control.decide(obs, rng)
    actions = decision.actions_B
    assert allowed_BA[np.arange(5), actions].all()
    assert np.array_equal(decision.leaf_BA, allowed_BA) and decision.subsets_BLA is None
    assert decision.subset_sizes_BS.shape == (5, 1)
    assert (decision.subset_sizes_BS[:, 0] == allowed_BA.sum(axis=1)).all()
    with pytest.raises(PriqnError, match="near-greedy acting applies to agents with one scalar"):
        Policy(small_net(5), make_agent("pr-iqn"), K).near_greedy(0.2)


def test_rewards_follow_the_rule():
    r = torch.tensor([[1.0, 2.0, 4.0, 8.0, 16.0]])
    iqn = make_agent("iqn", AgentConfig(reward_weights=(1.0, 0.5, 0.25, 0.125, 0.0625)))
    assert iqn.head_rewards(r).tolist() == [[5.0]]
    assert make_agent("ensemble-iqn").head_rewards(r).shape == (1, 5)
    assert torch.equal(make_agent("ma-iqn").head_rewards(r), r)


# ------------------------------------------------------------------------------ registry


@pytest.mark.parametrize("name", sorted(SHIPPED_AGENTS))
def test_registry_builds_each_agent(name):
    agent = make_agent(name)
    assert agent.num_heads == (1 if name == "iqn" else 5)
    assert agent.labels["agent"] == name
    q = torch.randn(3, agent.num_heads, K, A)
    assert agent.act(q, torch.rand(3)).shape == (3,)
    assert agent.target_actions(q).shape == (3, agent.num_heads)


def test_registry_errors_are_one_line():
    with pytest.raises(
        PriqnError,
        match=r"^agent.name: unknown agent 'dqn' \(valid: iqn, ensemble-iqn, ma-iqn, pr-iqn; "
        r"or 'package.module:NAME'",
    ):
        make_agent("dqn")
    with pytest.raises(PriqnError, match=r"agent.comparator: unknown comparator 'wd'"):
        make_agent("pr-iqn", comparator="wd")
    with pytest.raises(PriqnError, match=r"agent.preorder: .*'lexi'"):
        make_agent("pr-iqn", preorder="lexi")


def test_partial_order_label_and_per_objective_eps():
    agent = make_agent("pr-iqn", AgentConfig(preorder="partial", eps=(0.1, 0.2, 0.2, 0.3, 0.4)))
    assert agent.labels["partial_order"] is True
    assert make_agent("pr-iqn").labels["partial_order"] is False
    assert agent.subsets(torch.randn(2, 5, K, A)).leaf.shape == (2, A)


# ------------------------------------------------------------------------------ network


def small_net(heads: int, size: int = 32) -> QuantileNetwork:
    shapes = {"bev": (4, size, size), "lidar": (2, size, size), "command": (3,), "kinematics": (4,)}
    cfg = NetworkConfig(conv_channels=(8, 8, 8), latent_dim=32, hidden_dim=32, num_cosines=16)
    torch.manual_seed(0)
    return QuantileNetwork(shapes, {"bev": 1 / 255, "lidar": 1 / 255}, A, heads, cfg)


def random_batch(rng: np.random.Generator, b: int, discount: float) -> dict[str, object]:
    """A learner batch of ``b`` random transitions with one discount for every objective."""
    return {
        "obs": random_obs(rng, b),
        "next_obs": random_obs(rng, b),
        "action": rng.integers(0, A, b),
        "reward": rng.normal(size=(b, 5)).astype(np.float32),
        "discount": np.full(b, discount, dtype=np.float32),
    }


def random_obs(rng: np.random.Generator, b: int, size: int = 32) -> dict[str, np.ndarray]:
    return {
        "bev": rng.integers(0, 256, (b, 4, size, size), dtype=np.uint8),
        "lidar": rng.integers(0, 4, (b, 2, size, size), dtype=np.uint8),
        "command": np.eye(3, dtype=np.float32)[rng.integers(0, 3, b)],
        "kinematics": rng.normal(size=(b, 4)).astype(np.float32),
    }


def test_network_shapes_and_grid():
    net = small_net(5)
    obs = {k: torch.as_tensor(v) for k, v in random_obs(np.random.default_rng(0), 3).items()}
    out = net(obs, torch.rand(3, 7))
    assert out.shape == (3, 5, 7, A)
    assert tau_grid(4).tolist() == [0.125, 0.375, 0.625, 0.875]
    # the same τ gives the same quantile whatever else is in the batch of τ
    taus = torch.rand(3, 7)
    taus2 = taus.clone()
    taus2[:, 1:] = 0.5
    assert torch.allclose(net(obs, taus)[:, :, 0], net(obs, taus2)[:, :, 0], atol=1e-6)


# ------------------------------------------------------------------------------ replay


def tiny_obs(v: float, e: int = 1) -> dict[str, np.ndarray]:
    return {"x": np.full((e, 1), v, dtype=np.float32)}


def test_replay_n_step_final_obs_and_discounts():
    rb = ReplayBuffer({"x": ((1,), np.float32)}, num_envs=1, capacity=64, n_step=2, gamma=0.5)
    r = lambda v: np.array([[v, 0, 0, 0, 0]], dtype=np.float32)  # noqa: E731
    f, t = np.array([False]), np.array([True])
    rb.add(tiny_obs(0), np.array([0]), r(1), f, f, [None])
    rb.add(tiny_obs(1), np.array([1]), r(2), f, t, [{"x": np.array([99.0], np.float32)}])  # timeout
    rb.add(tiny_obs(10), np.array([2]), r(4), t, f, [{"x": np.array([98.0], np.float32)}])  # crash
    rb.add(tiny_obs(20), np.array([3]), r(8), f, f, [None])
    batch = rb._gather(np.zeros(3, dtype=np.int64), np.array([0, 1, 3]))
    # row 0: 1 + 0.5*2, then the timeout ends the episode: bootstrap from 99 with 0.5^2
    assert batch["reward"][:, 0].tolist() == [2.0, 2.0, 4.0]
    assert batch["next_obs"]["x"][:, 0].tolist() == [99.0, 99.0, 98.0]
    assert batch["discount"][:, 0].tolist() == [0.25, 0.5, 0.0]
    assert (batch["discount"] == batch["discount"][:, :1]).all()  # one gamma: equal columns
    # row 5 (obs 20) has no complete 2-step window yet; final rows never start transitions
    rng = np.random.default_rng(0)
    s = rb.sample(64, rng)
    assert set(s["obs"]["x"][:, 0].tolist()) == {0.0, 1.0, 10.0}
    assert len(rb) == 4 and rb.bytes_per_row() == 4 + 8 + 20 + 3


def test_replay_discounts_each_objective_with_its_own_gamma():
    # Two steps of rewards 1 (all objectives), n = 2, gamma_i = (1, .5, .5, .5, .9):
    # n-step reward_i = 1 + gamma_i; bootstrap discount gamma_i ** 2.
    gammas = (1.0, 0.5, 0.5, 0.5, 0.9)
    rb = ReplayBuffer({"x": ((1,), np.float32)}, num_envs=1, capacity=16, n_step=2, gamma=gammas)
    f = np.array([False])
    for t in range(4):
        rb.add(tiny_obs(t, 1), np.array([0]), np.ones((1, 5), np.float32), f, f, [None])
    s = rb.sample(4, np.random.default_rng(0))
    assert np.allclose(s["reward"], [1 + g for g in gammas])
    assert np.allclose(s["discount"], [g**2 for g in gammas])


def test_replay_truncate_open_episodes_and_save_load(tmp_path):
    rb = ReplayBuffer({"x": ((1,), np.float32)}, num_envs=2, capacity=32, n_step=1, gamma=0.9)
    f = np.array([False, False])
    rb.add(tiny_obs(1, 2), np.array([0, 1]), np.zeros((2, 5), np.float32), f, f, [None, None])
    rb.truncate_open_episodes(tiny_obs(7, 2))
    s = rb.sample(8, np.random.default_rng(0))
    assert s["next_obs"]["x"][:, 0].tolist() == [7.0] * 8
    assert np.allclose(s["discount"], 0.9)
    with open(tmp_path / "r.npz", "wb") as fh:
        rb.save_to(fh)
    rb2 = ReplayBuffer({"x": ((1,), np.float32)}, num_envs=2, capacity=32, n_step=1, gamma=0.9)
    rb2.load_state_file(tmp_path / "r.npz")
    assert np.array_equal(rb2.written, rb.written) and np.array_equal(rb2.obs["x"], rb.obs["x"])


# ------------------------------------------------------------------------------ learner


@pytest.mark.parametrize("name", ["iqn", "pr-iqn"])
def test_learner_fits_a_fixed_batch(name):
    torch.manual_seed(0)
    agent = make_agent(name)
    net = small_net(agent.num_heads)
    cfg = LearnerConfig(lr=1e-3, num_tau_samples=8, num_tau_prime_samples=8, num_quantiles=8)
    learner = Learner(net, agent, cfg, torch.device("cpu"), tau_seed=0)
    rng = np.random.default_rng(0)
    batch = random_batch(rng, 16, discount=0.0)  # terminal: targets are the rewards
    first = [learner.update(batch)["loss"] for _ in range(5)]
    for _ in range(150):
        last = learner.update(batch)["loss"]
    assert np.isfinite(first).all() and last < 0.5 * first[0]
    policy = Policy(learner.online, agent, 8)
    acts = policy.act(random_obs(rng, 5), np.random.default_rng(0))
    assert acts.dtype == np.int64 and acts.shape == (5,) and acts.max() < A


def test_scaled_normalisation_learns_its_scale_and_logs_subset_sizes():
    agent = make_agent("pr-iqn", AgentConfig(normalisation="scaled", scale_momentum=0.5))
    cfg = LearnerConfig(num_tau_samples=4, num_tau_prime_samples=4, num_quantiles=4)
    learner = Learner(small_net(agent.num_heads), agent, cfg, torch.device("cpu"), tau_seed=0)
    rng = np.random.default_rng(0)
    batch = random_batch(rng, 6, discount=0.9)
    assert agent.subsets.scale.count == 0
    stats = learner.update(batch)
    assert agent.subsets.scale.count == 1 and (agent.subsets.scale.floor() > 0).all()
    keys = {f"subset_size/{o}" for o in OBJECTIVES} | {"subset_size/leaf"}
    assert keys <= set(stats) and all(1 <= stats[k] <= A for k in keys)
    # The scale is part of the learner's state (checkpoints, load_policy).
    state = learner.state_dict()
    other = make_agent("pr-iqn", AgentConfig(normalisation="scaled"))
    Learner(small_net(other.num_heads), other, cfg, torch.device("cpu"), 0).load_state_dict(state)
    assert other.subsets.scale.scale_N.tolist() == agent.subsets.scale.scale_N.tolist()
    # Paper-literal agents have no scale and the same stats keys.
    plain = make_agent("pr-iqn")
    assert plain.subsets.scale is None and plain.state_dict() == {}


def test_own_tau_group_takes_each_heads_block():
    from priqn.agents.learner import _own_group

    q = torch.zeros(1, 2, 6, 1)  # [B, H, G*T, A] with G = H = 2, T = 3
    q[0, :, :, 0] = torch.arange(6.0) + 100 * torch.arange(2.0)[:, None]
    out = _own_group(q, 2)
    assert out[0, :, :, 0].tolist() == [[0.0, 1.0, 2.0], [103.0, 104.0, 105.0]]
    assert _own_group(q, 1) is q


def test_ensemble_heads_see_their_own_taus():
    agent = make_agent("ensemble-iqn", AgentConfig(ensemble_heads=3))
    net = small_net(agent.num_heads)
    seen = []
    forward = net.forward
    net.forward = lambda obs, taus: seen.append(taus.shape) or forward(obs, taus)
    cfg = LearnerConfig(num_tau_samples=4, num_tau_prime_samples=5, num_quantiles=2)
    learner = Learner(net, agent, cfg, torch.device("cpu"), tau_seed=0)
    learner.target.forward = net.forward  # record the target pass too
    rng = np.random.default_rng(0)
    batch = random_batch(rng, 2, discount=0.9)
    learner.update(batch)
    # target: 3 heads x 5 own tau' + the K = 2 grid; online: 3 heads x 4 own tau
    assert seen == [(2, 3 * 5 + 2), (2, 3 * 4)]
    assert make_agent("iqn").spec.own_taus is False and agent.spec.own_taus is True


def test_learner_state_roundtrip_continues_identically():
    agent = make_agent("ma-iqn")
    cfg = LearnerConfig(num_tau_samples=4, num_tau_prime_samples=4, num_quantiles=4)
    rng = np.random.default_rng(0)
    batch = random_batch(rng, 4, discount=0.9)
    a = Learner(small_net(5), agent, cfg, torch.device("cpu"), tau_seed=3)
    a.update(batch)
    state = a.state_dict()
    b = Learner(small_net(5), agent, cfg, torch.device("cpu"), tau_seed=99)
    b.load_state_dict({k: (v if k != "tau_generator" else v.clone()) for k, v in state.items()})
    assert a.update(batch)["loss"] == b.update(batch)["loss"]
    assert OBJECTIVES[0] == "safety"


def test_a_tau_generator_state_from_the_other_device_type_reseeds_deterministically():
    """A CUDA generator's state (Philox: 16 bytes) cannot continue a CPU generator (5056):
    the learner seeds its τ stream from those bytes, the same way every time, and says so."""
    agent = make_agent("ma-iqn")
    cfg = LearnerConfig(num_tau_samples=4, num_tau_prime_samples=4, num_quantiles=4)
    batch = random_batch(np.random.default_rng(0), 4, discount=0.9)
    a = Learner(small_net(5), agent, cfg, torch.device("cpu"), tau_seed=3)
    a.update(batch)
    state = dict(a.state_dict(), tau_generator=torch.arange(16, dtype=torch.uint8))
    losses = []
    for tau_seed in (0, 1):
        b = Learner(small_net(5), agent, cfg, torch.device("cpu"), tau_seed=tau_seed)
        assert b.load_state_dict(state) is False and b.updates == 1
        losses.append(b.update(batch)["loss"])
    assert losses[0] == losses[1]
    other = dict(state, tau_generator=torch.arange(1, 17, dtype=torch.uint8))
    c = Learner(small_net(5), agent, cfg, torch.device("cpu"), tau_seed=0)
    c.load_state_dict(other)
    assert c.update(batch)["loss"] != losses[0]
    assert Learner(small_net(5), agent, cfg, torch.device("cpu"), 0).load_state_dict(a.state_dict())


def test_parameter_counts_in_the_docs():
    """docs/implementation-details.md states every agent's parameter count: keep it true."""
    from pathlib import Path

    from priqn.bench.learners import obs_space
    from priqn.run.train_config import build_network, resolve_config

    doc = (Path(__file__).parents[1] / "docs" / "implementation-details.md").read_text()
    names = {"iqn": "IQN", "ensemble-iqn": "Ensemble-IQN", "ma-iqn": "MA-IQN", "pr-iqn": "Pr-IQN"}
    for agent, shown in names.items():
        counts = []
        for preset in ("default", "paper"):
            cfg = resolve_config(preset=preset, agent=agent)
            space, n = obs_space(cfg)
            counts.append(sum(p.numel() for p in build_network(cfg, space, n, 0).parameters()))
        heads = 1 if agent == "iqn" else 5
        assert f"| {shown} | {heads} | {counts[0]:,} | {counts[1]:,} |" in doc, (agent, counts)


@pytest.mark.parametrize("name", sorted(SHIPPED_AGENTS))
def test_decide_records_what_the_acting_rule_used_without_side_channels(name):
    """Policy.decide returns the actions, each level's optimal subset (the ones Algorithm 1
    gives for the recorded quantiles), the leaf and, when asked, the quantiles; asking for
    the quantiles changes neither the actions nor the generator's stream; nothing of the
    decision is left on the policy."""
    torch.manual_seed(0)
    agent = make_agent(name)
    policy = Policy(small_net(agent.num_heads), agent, 8)
    obs = random_obs(np.random.default_rng(1), 6)
    rng_a, rng_b = np.random.default_rng(5), np.random.default_rng(5)
    plain = policy.decide(obs, rng_a)
    full = policy.decide(obs, rng_b, quantiles=True)
    assert rng_a.random() == rng_b.random()  # the same draws consumed
    assert np.array_equal(plain.actions_B, full.actions_B) and plain.quantiles_BHKA is None
    assert full.quantiles_BHKA.shape == (6, agent.num_heads, 8, A)
    assert np.array_equal(policy.act(obs, np.random.default_rng(5)), plain.actions_B)
    assert not [k for k in vars(policy) if k.startswith("last")]
    if agent.subsets is None:
        assert plain.subsets_BLA is None and plain.leaf_BA is None
        assert plain.subset_sizes_BS is None and policy.subset_size_names == ()
        return
    from priqn.preorder import optimal_subsets

    again = optimal_subsets(
        torch.from_numpy(full.quantiles_BHKA), agent.subsets.preorder, agent.cfg.comparator,
        agent.cfg.eps,
    )  # fmt: skip
    assert plain.levels == agent.subsets.preorder.objectives
    assert np.array_equal(plain.subsets_BLA, again.per_objective.numpy())
    assert np.array_equal(plain.leaf_BA, again.leaf.numpy())
    assert plain.leaf_BA[np.arange(6), plain.actions_B].all()
    sizes = np.concatenate([again.per_objective.sum(-1), again.leaf.sum(-1, keepdim=True)], -1)
    assert plain.subset_sizes_BS.tolist() == sizes.tolist()
    assert policy.subset_size_names == (*plain.levels, "leaf")
    one = plain.row(2)
    assert one.actions_B.tolist() == [plain.actions_B[2]] and one.subsets_BLA.shape == (1, 5, A)


def test_act_with_subsets_returns_the_subsets_the_rule_acted_on():
    q = torch.randn(4, 5, 8, A)
    agent = make_agent("pr-iqn")
    u = torch.rand(4)
    w = agent.reward_weights_O
    actions, out = rules.act_with_subsets(rules.act_leaf_uniform, q, agent.subsets, u, w)
    assert torch.equal(actions, agent.act(q, u)) and torch.equal(out.leaf, agent.subsets(q).leaf)
    actions, out = rules.act_with_subsets(rules.act_argmax, q[:, :1], None, u, w)
    assert out is None and torch.equal(actions, q[:, 0].mean(1).argmax(1))


# ------------------------------------------------------------------------------ the agent interface


@pytest.mark.parametrize("name", sorted(SHIPPED_AGENTS))
def test_shipped_specs_hold_their_rule_functions(name):
    """A spec holds its rules themselves; their names are the registries' keys (docs, logs)."""
    spec = make_agent(name).spec
    assert spec.reward is rules.REWARD_RULES[spec.reward_rule]
    assert spec.act is rules.ACTING_RULES[spec.acting_rule]
    assert spec.target is rules.TARGET_RULES[spec.target_rule]
    assert spec.per_objective_heads == (spec.reward_rule == "per-objective")
    assert spec.uses_preorder == (spec.acting_rule == "leaf-uniform")
    assert (spec.scalar_value is None) == spec.uses_preorder
    assert agent_config.has_scalar_value(name) == (not spec.uses_preorder)


def test_the_learner_gets_the_target_subsets_as_a_return_value():
    """The target rule's subsets come back from the call (no ``last`` side channel): their
    sizes are the learner's subset_size/* statistics, and only when they were used."""
    batch = random_batch(np.random.default_rng(0), 6, discount=0.9)
    cfg = LearnerConfig(num_tau_samples=4, num_tau_prime_samples=4, num_quantiles=4)
    for train_preorder, logged in ((True, True), (False, False)):
        agent = make_agent("pr-iqn", AgentConfig(train_preorder=train_preorder))
        assert not hasattr(agent.subsets, "last")
        q = torch.randn(4, 5, K, A)
        actions, used = agent.target_actions_and_subsets(q)
        assert torch.equal(actions, agent.target_actions(q))
        assert (used is not None) == logged
        if used is not None:
            assert torch.equal(used.per_objective, agent.subsets(q).per_objective)
        stats = Learner(small_net(5), agent, cfg, torch.device("cpu"), tau_seed=0).update(batch)
        assert any(k.startswith("subset_size/") for k in stats) == logged


class _Entry:
    """An installed entry point, as importlib.metadata gives it."""

    def __init__(self, value: object) -> None:
        self.value = value

    def load(self) -> object:
        if isinstance(self.value, Exception):
            raise self.value
        return self.value


def test_agents_from_a_path_and_from_an_entry_point(monkeypatch):
    from tests import agent_example

    spec = agent_config.resolve_spec(AgentConfig(name="tests.agent_example:SHIELDED_IQN"))
    assert spec is agent_example.SHIELDED_IQN and spec.acting_rule.endswith(":act_shielded")
    assert rules.lookup(rules.ACTING_RULES, spec.acting_rule, "acting rule") is spec.act
    # Tables read names from data files: a path is never imported from there.
    assert agent_config.agent_spec("tests.agent_example:SHIELDED_IQN") is None
    entries = {"shielded": _Entry(agent_example.SHIELDED_IQN), "broken": _Entry(ImportError("x"))}
    monkeypatch.setattr(agent_config, "_entry_points", lambda: entries)
    assert agent_config.agent_spec("shielded").display_name == "Shielded-IQN"
    assert make_agent("shielded").num_heads == 2
    with pytest.raises(
        PriqnError, match=r"valid: iqn, ensemble-iqn, ma-iqn, pr-iqn, broken, shielded;"
    ):
        make_agent("dqn")
    with pytest.raises(
        PriqnError, match=r"^agent.name: entry point 'broken' failed to load \(x\)$"
    ):
        make_agent("broken")
    with pytest.raises(
        PriqnError, match=r"^agent.name: module 'tests.agent_example' has no 'NOPE'$"
    ):
        make_agent("tests.agent_example:NOPE")
    with pytest.raises(PriqnError, match=r"is a float, expected an AgentSpec or a function"):
        make_agent("tests.agent_example:SHIELD_MARGIN")


def test_a_declaration_that_breaks_the_interface_is_one_line():
    with pytest.raises(PriqnError, match=r"^agent 'X': num_heads must be a positive integer$"):
        AgentSpec("X", 0, rules.reward_weighted_sum, rules.act_argmax, rules.target_own_argmax)
    with pytest.raises(PriqnError, match=r"^agent 'X': act must be a function$"):
        AgentSpec("X", 1, rules.reward_weighted_sum, "argmax", rules.target_own_argmax)  # type: ignore[arg-type]


def test_the_shipped_declarations_and_their_rules_import_without_torch():
    """Labels and tables resolve shipped agents torch-free (priqn/agents/shipped.py and rules.py)."""
    import subprocess
    import sys

    code = (
        "import sys; from priqn.agents.config import agent_spec, has_scalar_value; "
        "assert agent_spec('pr-iqn').display_name == 'Pr-IQN' and has_scalar_value('iqn'); "
        "assert 'torch' not in sys.modules, 'torch imported'"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
