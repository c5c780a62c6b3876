"""Learners for the benchmarks, on synthetic batches: the env's observation space built
without SUMO, random transitions of its shapes, and a warmed-up learner of a preset's
network (used by ``priqn bench train`` and its replay-feed part, :mod:`priqn.bench.feed`)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np


def obs_space(cfg: Any) -> Any:
    """The env's observation space for ``cfg.env`` (built without starting SUMO)."""
    from priqn.env.intersection import IntersectionEnv

    env = IntersectionEnv(cfg.env)
    try:
        return env.observation_space, int(env.action_space.n)
    finally:
        env.close()


def synthetic_batch(space: Any, batch: int, rng: np.random.Generator) -> dict[str, Any]:
    """``batch`` random transitions shaped like ``space`` (binary frames, normal vectors)."""

    def sample_obs() -> dict[str, np.ndarray]:
        out = {}
        for k in ("bev", "lidar", "command", "kinematics"):
            sp = space[k]
            if sp.dtype == np.uint8:
                out[k] = rng.integers(0, 2, (batch, *sp.shape), dtype=np.uint8) * 255
            else:
                out[k] = rng.normal(size=(batch, *sp.shape)).astype(sp.dtype)
        return out

    return {
        "obs": sample_obs(),
        "next_obs": sample_obs(),
        "reward": rng.normal(size=(batch, 5)).astype(np.float32),
        "discount": np.full(batch, 0.99, dtype=np.float32),
    }


def make_learner(
    preset: str,
    agent_name: str,
    batch_size: int,
    device: str,
    bf16: bool = False,
    compile_: str = "off",
) -> tuple[Any, Any]:
    """A learner of ``preset``'s network for ``agent_name`` on ``device``, warmed up on
    synthetic batches (compiled: its kernels built, its CUDA graphs recorded), and
    ``(cfg, batches)``: the config it was made from and four synthetic batches."""
    from priqn.agents.learner import Learner
    from priqn.agents.registry import make_agent
    from priqn.run.train_config import build_network, resolve_config, select_device

    cfg = resolve_config(preset=preset, agent=agent_name)
    learner_cfg = dataclasses.replace(
        cfg.learner,
        batch_size=batch_size,
        autocast_bf16=bf16,
        compile=compile_,
    )
    cfg = dataclasses.replace(cfg, learner=learner_cfg)
    space, num_actions = obs_space(cfg)
    dev = select_device(device)
    net = build_network(cfg, space, num_actions, seed=0)
    learner = Learner(
        net,
        make_agent(agent_name, cfg.resolved_agent, cfg.objective_names),
        cfg.learner,
        dev,
        tau_seed=0,
    )
    rng = np.random.default_rng(0)
    batches = []
    for _ in range(4):
        b = synthetic_batch(space, batch_size, rng)
        b["action"] = rng.integers(0, num_actions, batch_size)
        batches.append(b)
    for i in range(5):  # warm-up (compiled: builds the kernels, records the CUDA graphs)
        learner.update(batches[i % 4])
    return learner, (cfg, batches)
