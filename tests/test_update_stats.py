"""An update's statistics are read at log time (issue 61): ``Learner.update`` returns them
as tensors, unread (no host sync), and reading gives the floats an eager ``float()`` of
each tensor gives. The running scale of the scaled normalisation stays on the quantiles'
device and folds a batch in as before (constructed numbers checked by hand)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_agents import random_batch, small_net

from priqn.agents.comparators import RunningScale
from priqn.agents.config import LearnerConfig
from priqn.agents.learner import Learner, UpdateStats
from priqn.agents.registry import make_agent


def test_stats_are_read_once_and_as_float_reads_each_tensor() -> None:
    tensors = {
        "loss": torch.tensor(0.1, dtype=torch.float32),  # not exactly 0.1 in float32
        "q_mean": torch.tensor(-2.7, dtype=torch.bfloat16),
        "subset_size/safety": torch.tensor(3.25, dtype=torch.float64),
    }
    stats = UpdateStats(tensors)
    assert stats.pending and len(stats) == 3 and list(stats) == list(tensors)
    assert dict(stats) == {k: float(t) for k, t in tensors.items()}
    assert stats["loss"] == float(np.float32(0.1)) != 0.1
    assert not stats.pending


@pytest.mark.parametrize("agent", ["iqn", "pr-iqn"])
def test_an_update_returns_its_stats_unread(agent: str) -> None:
    spec = make_agent(agent)
    cfg = LearnerConfig(num_tau_samples=8, num_tau_prime_samples=8, num_quantiles=8)
    learner = Learner(small_net(spec.num_heads), spec, cfg, torch.device("cpu"), tau_seed=5)
    stats = learner.update(random_batch(np.random.default_rng(0), 16, discount=0.9))
    assert isinstance(stats, UpdateStats) and stats.pending
    keys = set(stats)
    assert {"loss", "q_mean"} <= keys
    assert any(k.startswith("subset_size/") for k in keys) == (agent == "pr-iqn")
    assert all(isinstance(v, float) and np.isfinite(v) for v in stats.values())


def test_running_scale_folds_in_a_batch_and_survives_a_load() -> None:
    # Two objectives; every state's K x A entries are {0, 2} (std 1) and {0, 4} (std 2).
    q_BNKA = torch.tensor([[[[0.0, 2.0]], [[0.0, 4.0]]]] * 3)
    scale = RunningScale(2, momentum=0.5, fraction=2.0)
    scale.update(q_BNKA)
    assert scale.floor().tolist() == [2.0, 4.0]  # the first batch sets it: 2 x (1, 2)
    restored = RunningScale(2, momentum=0.5, fraction=2.0)
    restored.load_state_dict(scale.state_dict())
    restored.update(q_BNKA * 3)  # std 3 and 6: 0.5 x (1, 2) + 0.5 x (3, 6) = (2, 4)
    assert restored.floor().tolist() == [4.0, 8.0] and restored.count == 2
