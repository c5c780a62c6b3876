"""learner.compile: what each setting resolves to, and a compiled update equals an eager one.

The compiled update runs the same operations as the eager one, so it may differ only by
float rounding (kernel fusion reorders sums): on CPU the losses of 8 updates agree within
1e-5 relative and the weights within 1e-5 absolute. τ are drawn eagerly from the same
generator either way, so the τ stream (and the global RNG) is left exactly as eager
leaves it. On CUDA (``on``: mode "reduce-overhead", CUDA graphs; ``graphs``: the eager
kernels recorded as CUDA graphs, the default there) the same check runs with
looser bounds (cuDNN may pick other algorithms): losses within 1e-3 relative, weights
within 1e-4 (Adam's ε = 3.125e-4 keeps a rounding difference in a gradient from moving
a weight by more than about 3x that difference a step); skipped without CUDA.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_agents import random_batch, small_net

from priqn.agents import learner as learner_mod
from priqn.agents.config import LearnerConfig
from priqn.agents.learner import Learner, resolve_compile
from priqn.agents.registry import make_agent
from priqn.errors import PriqnError

CPU = torch.device("cpu")
CUDA = torch.device("cuda")
LOSS_RTOL_CPU = 1e-5
"""Compiled vs eager loss on CPU, relative (measured: < 1e-6 after 8 updates)."""
WEIGHT_ATOL_CPU = 1e-5
"""Compiled vs eager weights after 8 updates at lr 1e-3 on CPU (measured: 3e-8)."""
LOSS_RTOL_CUDA = 1e-3
"""Compiled (CUDA graphs) vs eager loss on CUDA, relative."""
WEIGHT_ATOL_CUDA = 1e-4
"""Compiled vs eager weights after 8 updates on CUDA."""
needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")


def run_updates(
    name: str, compile_: str, device: torch.device, updates: int = 8
) -> tuple[list[float], Learner, torch.Tensor]:
    """``updates`` updates of a fresh learner (target sync every 3, so the compiled target
    network must see the copied weights); the losses, the learner, the global RNG state
    after them."""
    cfg = LearnerConfig(
        lr=1e-3,
        num_tau_samples=8,
        num_tau_prime_samples=8,
        num_quantiles=8,
        target_update_interval=3,
        compile=compile_,
    )
    agent = make_agent(name)
    learner = Learner(small_net(agent.num_heads), agent, cfg, device, tau_seed=5)
    rng = np.random.default_rng(0)
    torch.manual_seed(123)
    losses = [learner.update(random_batch(rng, 16, discount=0.9))["loss"] for _ in range(updates)]
    return losses, learner, torch.random.get_rng_state()


def assert_same_training(
    name: str, device: torch.device, loss_rtol: float, weight_atol: float, setting: str = "on"
) -> None:
    eager_losses, eager, eager_rng = run_updates(name, "off", device)
    comp_losses, comp, comp_rng = run_updates(name, setting, device)
    assert not eager.compiled and comp.compiled
    np.testing.assert_allclose(comp_losses, eager_losses, rtol=loss_rtol)
    comp_state = comp.online.state_dict()
    for key, a in eager.online.state_dict().items():
        torch.testing.assert_close(comp_state[key], a, rtol=0, atol=weight_atol)
    for a, b in zip(eager.target.parameters(), comp.target.parameters(), strict=True):
        torch.testing.assert_close(b, a, rtol=0, atol=weight_atol)
    # Same random numbers consumed: the τ stream goes on identically, the global RNG too.
    assert torch.equal(eager.tau_generator.get_state(), comp.tau_generator.get_state())
    assert torch.equal(eager_rng, comp_rng)
    assert comp.updates == eager.updates
    # The checkpointed state has the same keys (the compiled wrappers are not saved).
    assert comp.state_dict().keys() == eager.state_dict().keys()
    assert list(comp.state_dict()["online"]) == list(eager.state_dict()["online"])


def test_compile_settings_resolve_by_device(monkeypatch: pytest.MonkeyPatch) -> None:
    assert LearnerConfig().compile == "auto"
    with pytest.raises(ValueError, match="compile: unknown 'yes'"):
        LearnerConfig(compile="yes")
    with pytest.raises(PriqnError, match="learner.compile: unknown 'yes'"):
        resolve_compile("yes", CPU)
    assert resolve_compile("auto", CPU) == "eager"  # it did not pay on the project's CPU
    assert resolve_compile("off", CPU) == "eager"
    assert resolve_compile("on", CPU) == "inductor"
    with pytest.raises(PriqnError, match="'graphs' records CUDA graphs, not possible with a cpu"):
        resolve_compile("graphs", CPU)
    assert resolve_compile("auto", CUDA) == "graphs"  # the default on a GPU
    assert resolve_compile("auto", CUDA, bf16=True) == "eager"  # autocast is not recorded
    with pytest.raises(PriqnError, match="not possible with bf16 autocast"):
        resolve_compile("graphs", CUDA, bf16=True)
    assert resolve_compile("graphs", CUDA) == "graphs"
    assert resolve_compile("off", CUDA) == "eager"
    monkeypatch.setattr(learner_mod, "has_compiler", lambda device: True)
    assert resolve_compile("on", CUDA) == "inductor"
    monkeypatch.setattr(learner_mod, "AUTO_UPDATE", {})
    assert resolve_compile("auto", CUDA) == "eager"  # auto follows AUTO_UPDATE
    monkeypatch.setattr(learner_mod, "has_compiler", lambda device: False)
    with pytest.raises(PriqnError, match="no back-end for cuda"):
        resolve_compile("on", CUDA)


def test_the_default_presets_learner_is_eager_on_cpu() -> None:
    """``compile = "off"`` is what the presets resolve to here: training stays bit for bit."""
    from priqn.run.train_config import resolve_config

    for preset in ("default", "paper"):
        cfg = resolve_config(preset=preset, agent="pr-iqn")
        assert resolve_compile(cfg.learner.compile, CPU) == "eager"
    agent = make_agent("iqn")
    learner = Learner(small_net(1), agent, LearnerConfig(), CPU, tau_seed=0)
    assert not learner.compiled and learner._target_forward is learner.target


@pytest.mark.parametrize("name", ["ensemble-iqn", "pr-iqn"])
def test_compiled_update_equals_eager_on_cpu(name: str) -> None:
    """Inductor on CPU: own τ per head (the diagonal of ``_own_group``) and Algorithm 1
    targets; IQN runs on CUDA below. About 45 s of compiling per agent on a loaded
    2-core machine."""
    assert_same_training(name, CPU, LOSS_RTOL_CPU, WEIGHT_ATOL_CPU)


@needs_cuda
@pytest.mark.parametrize("name", ["iqn", "ensemble-iqn", "pr-iqn"])
def test_compiled_update_equals_eager_on_cuda(name: str) -> None:
    """CUDA graphs (mode "reduce-overhead"), target syncs included; where Triton is missing
    ``"on"`` is a one-line error instead."""
    if not learner_mod.has_compiler(CUDA):
        with pytest.raises(PriqnError, match="no back-end for cuda"):
            run_updates(name, "on", CUDA)
        return
    assert_same_training(name, CUDA, LOSS_RTOL_CUDA, WEIGHT_ATOL_CUDA)


@needs_cuda
@pytest.mark.parametrize("name", ["iqn", "ensemble-iqn", "pr-iqn"])
def test_graphed_update_equals_eager_on_cuda(name: str) -> None:
    """The CUDA graphs replay the eager kernels: same losses and weights within the CUDA
    bounds (target syncs every 3 updates reach the recorded target network)."""
    assert_same_training(name, CUDA, LOSS_RTOL_CUDA, WEIGHT_ATOL_CUDA, setting="graphs")


@needs_cuda
def test_auto_records_cuda_graphs() -> None:
    agent = make_agent("pr-iqn")
    learner = Learner(small_net(agent.num_heads), agent, LearnerConfig(), CUDA, tau_seed=0)
    assert learner.update_kind == "graphs" and learner.compiled


@needs_cuda
def test_graphed_learners_side_by_side_each_train_as_alone() -> None:
    """Several learners in one process (as in tests and notebooks), their updates
    interleaved, a batch size changing half-way (a second pair of graphs) and one learner
    resumed in place from the other's state: each follows its eager twin."""

    def learners(setting: str) -> list[Learner]:
        cfg = LearnerConfig(lr=1e-3, num_tau_samples=8, num_tau_prime_samples=8,
                            num_quantiles=8, target_update_interval=3, compile=setting)  # fmt: skip
        out = []
        for seed, name in enumerate(("pr-iqn", "iqn", "pr-iqn")):
            agent = make_agent(name)
            torch.manual_seed(seed)
            out.append(Learner(small_net(agent.num_heads), agent, cfg, CUDA, tau_seed=seed))
        return out

    def train(group: list[Learner]) -> list[float]:
        rng = np.random.default_rng(0)
        losses = []
        for step in range(10):
            batch = random_batch(rng, 16 if step < 5 else 8, discount=0.9)
            losses += [learner.update(batch)["loss"] for learner in group]
            if step == 6:  # the third resumes from the first's state, in place
                group[2].load_state_dict(group[0].state_dict())
        return losses

    eager, graphed = learners("off"), learners("graphs")
    assert all(g.update_kind == "graphs" for g in graphed)
    np.testing.assert_allclose(train(graphed), train(eager), rtol=LOSS_RTOL_CUDA)
    for e, g in zip(eager, graphed, strict=True):
        for a, b in zip(e.online.parameters(), g.online.parameters(), strict=True):
            torch.testing.assert_close(b, a, rtol=0, atol=WEIGHT_ATOL_CUDA)
