"""Agents: one IQN learner with H heads; four variants as reward/acting/target rules.

Public names (imported lazily: importing the package costs nothing until one is used;
the configs and specs themselves live in the torch-free :mod:`priqn.agents.config`):
``make_agent``, ``Agent``, ``SHIPPED_AGENTS``, ``AgentConfig``, ``NetworkConfig``,
``LearnerConfig``, ``QuantileNetwork``, ``Learner``, ``ReplayBuffer``, ``Policy``,
``quantile_huber_loss``, ``tau_grid``.

Also here, each its own module: :mod:`~priqn.agents.labels` (a policy's Table II
identity, torch-free) and the preorder core: :mod:`~priqn.agents.preorder` (the preorder
graph, torch-free), :mod:`~priqn.agents.comparators` (the comparators and the running
scale) and :mod:`~priqn.agents.subsets` (Algorithm 1); the public module is
:mod:`priqn.preorder`, which re-exports them. Algorithm 1's slow reference lives with
the bench, in :mod:`priqn.bench.references.subsets`.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS: dict[str, str] = {
    "make_agent": "priqn.agents.registry",
    "Agent": "priqn.agents.registry",
    "SHIPPED_AGENTS": "priqn.agents.config",
    "AgentConfig": "priqn.agents.config",
    "NetworkConfig": "priqn.agents.config",
    "LearnerConfig": "priqn.agents.config",
    "QuantileNetwork": "priqn.agents.network",
    "tau_grid": "priqn.agents.network",
    "Learner": "priqn.agents.learner",
    "ReplayBuffer": "priqn.agents.replay",
    "Policy": "priqn.agents.policy",
    "quantile_huber_loss": "priqn.agents.loss",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'priqn.agents' has no attribute {name!r}")
