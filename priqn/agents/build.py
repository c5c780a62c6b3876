"""How a run's agent is built, top to bottom: config → agent spec → agent → network → learner, policy.

1. :func:`build_agent`: ``agent.name`` → its declaration (shipped, ``package.module:NAME``
   or an entry point of group ``priqn.agents``: :func:`priqn.agents.config.resolve_agent`)
   → its :class:`~priqn.agents.config.AgentSpec` (heads and the three rule functions) →
   an :class:`~priqn.agents.registry.Agent` with the run's weights and, when the spec
   ``uses_preorder``, its optimal-subset function (:func:`~priqn.agents.registry.make_agent`).
2. :func:`build_network`: the :class:`QuantileNetwork` with the spec's number of heads.
3. :func:`build_learner` (training) and :func:`build_policy` (acting) around that network;
   :func:`build_trained_policy`: that network with a trained run's weights, acting.

``priqn.train.train``, ``priqn.run.checkpointer.load_policy`` and ``priqn bench train`` build through
here, so a plug-in agent (docs/your-own-agent.md) trains, evaluates and is inspected
exactly like a shipped one. The config is a :class:`priqn.run.train_config.TrainConfig`
(typed by :class:`RunConfig`, as this package sits below it).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np
import torch

from priqn.agents.config import AgentConfig, LearnerConfig, NetworkConfig
from priqn.agents.learner import Learner
from priqn.agents.network import OBS_KEYS, QuantileNetwork
from priqn.agents.policy import Policy
from priqn.agents.registry import Agent, make_agent
from priqn.errors import PriqnError


class RunConfig(Protocol):
    """What building reads of a run's :class:`priqn.run.train_config.TrainConfig`."""

    @property
    def resolved_agent(self) -> AgentConfig: ...

    @property
    def network(self) -> NetworkConfig: ...

    @property
    def learner(self) -> LearnerConfig: ...

    @property
    def objective_names(self) -> tuple[str, ...]: ...


class TrainedState(Protocol):
    """What building a trained policy reads of a :class:`priqn.run.checkpoint.PolicyState`."""

    online: dict[str, Any]
    agent: dict[str, Any]
    num_actions: int


def build_agent(cfg: RunConfig) -> Agent:
    """The run's agent: ``cfg.resolved_agent.name`` resolved to its spec, for the run's
    objectives (unknown names, comparators and preorders: one line)."""
    agent_cfg = cfg.resolved_agent
    return make_agent(agent_cfg.name, agent_cfg, cfg.objective_names)


def obs_spec(space: Any) -> dict[str, tuple[tuple[int, ...], Any]]:
    """``key -> (shape, dtype)`` of the observations the network reads (:data:`OBS_KEYS`)."""
    missing = [k for k in OBS_KEYS if k not in space.spaces]
    if missing:
        raise PriqnError(f"observation space lacks {missing} (ARCHITECTURE.md Environment)")
    return {k: (tuple(space[k].shape), space[k].dtype) for k in OBS_KEYS}


def obs_scales(space: Any) -> dict[str, float]:
    """1 / the Box's ``high`` of each uint8 grid, so the network sees [0, 1]."""
    return {k: 1.0 / max(1.0, float(np.max(space[k].high))) for k in ("bev", "lidar")}


def build_network(
    cfg: RunConfig, obs_space: Any, num_actions: int, seed: int, agent: Agent
) -> QuantileNetwork:
    """The run's network with ``agent``'s heads, initialised from ``seed`` (the global torch
    RNG is left as it was)."""
    shapes = {k: s for k, (s, _) in obs_spec(obs_space).items()}
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return QuantileNetwork(
            shapes, obs_scales(obs_space), num_actions, agent.num_heads, cfg.network
        )


def build_learner(
    cfg: RunConfig,
    agent: Agent,
    obs_space: Any,
    num_actions: int,
    device: torch.device,
    seeds: Mapping[str, int],
) -> Learner:
    """Online and target networks (initialised from ``seeds["torch_init"]``), Adam and the
    τ generator (``seeds["tau"]``) of a training run."""
    network = build_network(cfg, obs_space, num_actions, seeds["torch_init"], agent)
    return Learner(network, agent, cfg.learner, device, tau_seed=seeds["tau"])


def build_policy(
    cfg: RunConfig,
    agent: Agent,
    network: QuantileNetwork,
    device: torch.device | str = "cpu",
    env_config: Any = None,
    labels: Mapping[str, Any] | None = None,
) -> Policy:
    """Greedy acting with ``network`` by ``agent``'s acting rule on the run's τ grid."""
    return Policy(network, agent, cfg.learner.num_quantiles, device, env_config, labels)


def build_trained_policy(
    cfg: RunConfig,
    agent: Agent,
    obs_space: Any,
    state: TrainedState,
    device: torch.device | str = "cpu",
    env_config: Any = None,
    labels: Mapping[str, Any] | None = None,
    restore: Callable[[Callable[[], Any]], Any] = lambda load_state: load_state(),
) -> Policy:
    """:func:`build_policy` around the run's network with the trained weights of ``state``:
    ``state.online`` loaded into it (built from seed 0, then overwritten; eval mode) and
    ``state.agent`` into ``agent`` (the scaled normalisation's scale). ``restore`` calls
    each ``load_state_dict``; a run folder passes one that turns weights that do not fit
    into one line naming their file (:func:`priqn.run.checkpoint.restore`)."""
    network = build_network(cfg, obs_space, int(state.num_actions), seed=0, agent=agent)
    restore(lambda: network.load_state_dict(state.online))
    network.eval()
    restore(lambda: agent.load_state_dict(state.agent))
    return build_policy(cfg, agent, network, device, env_config, labels)
