"""CUDA: the learner trains on a GPU, resumes there identically, and what it learned acts
the same on a CPU (a policy trained on a GPU machine is evaluated on a laptop).

Skipped where torch sees no CUDA device (CI, this project's CPU machine); run on a GPU
machine with ``pytest tests/test_cuda.py tests/test_preorder.py -k cuda``.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch
from test_agents import A, random_batch, random_obs, small_net

from priqn.agents.config import SHIPPED_AGENTS, LearnerConfig
from priqn.agents.learner import Learner
from priqn.agents.network import tau_grid
from priqn.agents.policy import Policy
from priqn.agents.registry import make_agent
from priqn.run import checkpoint
from priqn.run.checkpoint import Checkpoint, PolicyState

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")

CFG = LearnerConfig(lr=1e-3, num_tau_samples=8, num_tau_prime_samples=8, num_quantiles=8)


def cuda_learner(name: str, tau_seed: int = 0) -> Learner:
    agent = make_agent(name)
    return Learner(small_net(agent.num_heads), agent, CFG, torch.device("cuda"), tau_seed)


@pytest.mark.parametrize("name", sorted(SHIPPED_AGENTS))
def test_every_agent_fits_a_fixed_batch_on_cuda(name):
    learner = cuda_learner(name)
    assert next(learner.online.parameters()).is_cuda
    batch = random_batch(np.random.default_rng(0), 16, discount=0.0)  # targets = rewards
    first = learner.update(batch)["loss"]
    for _ in range(300):
        last = learner.update(batch)["loss"]
    assert np.isfinite(first) and last < 0.5 * first
    acts = Policy(learner.online, learner.agent, 8).act(
        random_obs(np.random.default_rng(1), 5), np.random.default_rng(0)
    )
    assert acts.dtype == np.int64 and acts.shape == (5,) and acts.max() < A


def saved_and_loaded(learner: Learner, map_location: str) -> dict:
    """``learner``'s state through a checkpoint file, loaded as a resume loads it (weights
    only, onto its device; the observations come back as CPU numpy arrays)."""
    obs = {"bev": np.arange(6, dtype=np.uint8).reshape(2, 3)}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "latest.pt"
        state = Checkpoint(0, 0, 0.0, learner.state_dict(), {}, {}, obs, {}, A, {})
        checkpoint.save(state, path)
        back = checkpoint.load(path, map_location)
    assert isinstance(back.obs["bev"], np.ndarray) and np.array_equal(back.obs["bev"], obs["bev"])
    return back.learner


def test_a_cuda_learner_resumes_identically_on_cuda():
    batch = random_batch(np.random.default_rng(0), 4, discount=0.9)
    a = cuda_learner("pr-iqn", tau_seed=3)
    a.update(batch)
    state = saved_and_loaded(a, "cuda")  # the τ generator's byte state lands on the GPU too
    b = cuda_learner("pr-iqn", tau_seed=99)
    assert b.load_state_dict(state) is True
    assert a.update(batch)["loss"] == b.update(batch)["loss"]


def test_a_run_moves_between_cuda_and_cpu():
    """``priqn train --resume RUN --device cpu`` of a GPU run (and back): the weights and
    optimiser move; the τ stream restarts from a seed derived from the other device's."""
    batch = random_batch(np.random.default_rng(0), 4, discount=0.9)
    for src, dst in (("cuda", "cpu"), ("cpu", "cuda")):
        agent = make_agent("pr-iqn")
        a = Learner(small_net(agent.num_heads), agent, CFG, torch.device(src), 0)
        a.update(batch)
        agent_b = make_agent("pr-iqn")
        b = Learner(small_net(agent_b.num_heads), agent_b, CFG, torch.device(dst), 0)
        assert b.load_state_dict(saved_and_loaded(a, dst)) is False
        for p_a, p_b in zip(a.online.parameters(), b.online.parameters(), strict=True):
            assert p_b.device.type == dst and torch.equal(p_a.cpu(), p_b.cpu())
        assert b.updates == 1 and np.isfinite(b.update(batch)["loss"])


def test_a_policy_trained_on_cuda_acts_the_same_on_cpu(tmp_path):
    learner = cuda_learner("pr-iqn")
    batch = random_batch(np.random.default_rng(0), 16, discount=0.9)
    for _ in range(20):
        learner.update(batch)
    path = tmp_path / "policy.pt"
    checkpoint.save(
        PolicyState(
            online=learner.online.state_dict(),
            agent=learner.agent.state_dict(),
            obs_shapes={},
            num_actions=A,
            step=20,
        ),
        path,
    )
    state = checkpoint.load_policy_state(path)  # map_location="cpu"
    assert all(t.device.type == "cpu" for t in state.online.values())
    cpu_net = small_net(learner.agent.num_heads)
    cpu_net.load_state_dict(state.online)
    obs = {k: torch.as_tensor(v) for k, v in random_obs(np.random.default_rng(2), 64).items()}
    grid = tau_grid(8)
    with torch.no_grad():
        q_cpu = cpu_net(obs, grid.expand(64, -1))
        q_gpu = learner.online(
            {k: v.cuda() for k, v in obs.items()}, grid.cuda().expand(64, -1)
        ).cpu()
    # Same weights, two devices: equal up to float32 reduction order and cuDNN's TF32
    # convolutions (10-bit mantissa inputs), so within 1 % of the largest quantile.
    err = (q_cpu - q_gpu).abs().max().item()
    assert err <= 1e-2 * q_cpu.abs().max().item(), err


def test_replay_storages_give_host_batches_on_cuda(tmp_path: Path) -> None:
    """``replay.storage`` on a GPU: ``device`` (rings in GPU memory) and ``pinned``
    (page-locked staging, asynchronous copies, two slots taking turns) give ``host``'s
    batches bit for bit, a GPU ring saves and loads as a host one, and ``device`` storage
    that cannot fit on the GPU is one line before anything is allocated."""
    from test_replay_storage import SPEC, as_numpy, assert_same_batch, filled

    from priqn.agents.replay import ReplayBuffer
    from priqn.errors import PriqnError

    dev = torch.device("cuda")
    host = filled("host")
    others = {s: filled(s, device=dev) for s in ("device", "pinned")}
    assert others["device"].obs["bev"].is_cuda
    rngs = {s: np.random.default_rng(3) for s in ("host", *others)}
    kept = []
    for _ in range(6):
        want = as_numpy(host.sample(16, rngs["host"]))
        for s, rb in others.items():
            got = rb.sample(16, rngs[s])
            assert got["obs"]["bev"].is_cuda
            kept.append((want, got))
    slot = others["pinned"].frames._slots[0]
    assert all(t.is_pinned() for name, t in slot.items() if name != "event")
    torch.cuda.synchronize()
    for want, got in kept:
        assert_same_batch(want, got)
    with open(tmp_path / "rows.npz", "wb") as fh:
        others["device"].save_rows(fh, np.zeros(3, np.int64))
    back = filled("host", steps=0)
    back.load_rows(tmp_path / "rows.npz")
    for k in SPEC:
        assert np.array_equal(back.obs[k], host.obs[k]), k
    with pytest.raises(PriqnError, match=r"replay.storage = 'device': the buffer needs .* GB"):
        ReplayBuffer(SPEC, 3, 3_000_000_000, storage="device", device=dev)
