"""The replay feed of ``priqn bench train --replay-storage``: batches sampled from a full
replay buffer and the learner updates on them, per ``replay.storage``, against ``host``.

Each preset's buffer is filled once, directly (synthetic frames, the preset's capacity and
env count, no env), and copied into every other storage asked for, so every storage
samples the same rows. For every agent and storage two rates are timed, the cases taking
turns in the same rounds (the best round counts): ``replay.sample`` alone (its batch on
the device: CUDA is synchronised at the end of a round), and ``sample → Learner.update``,
the learning step of :meth:`priqn.train.Trainer.learn`.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from typing import Any

import numpy as np

from priqn.bench.learners import obs_space


def synthetic_replay(cfg: Any, space: Any, capacity: int, rng: np.random.Generator) -> Any:
    """A ``host`` replay buffer of ``cfg`` (``num_envs`` rings, n-step, γ) whose every row is
    written: 64 random frames repeated, random actions and rewards, an episode end at
    about one row in 50 (half of them terminal)."""
    from priqn.agents.build import obs_spec
    from priqn.agents.replay import ReplayBuffer

    spec = obs_spec(space)
    rb = ReplayBuffer(spec, cfg.num_envs, capacity, cfg.learner.n_step, cfg.learner.gamma,
                      num_objectives=len(cfg.objective_names))  # fmt: skip
    block = {
        k: (rng.integers(0, 2, (64, *shape), dtype=np.uint8) * 255).astype(dt)
        if np.dtype(dt) == np.uint8
        else rng.normal(size=(64, *shape)).astype(dt)
        for k, (shape, dt) in spec.items()
    }
    for k, a in rb.obs.items():
        for e in range(rb.num_envs):
            for lo in range(0, rb.rows, 64):
                n = min(64, rb.rows - lo)
                a[e, lo : lo + n] = block[k][:n]
    shape = rb.action.shape
    rb.action[...] = rng.integers(0, 5, shape)
    rb.reward[...] = rng.normal(size=rb.reward.shape)
    rb.starts[...] = True
    rb.ended[...] = rng.random(shape) < 0.02
    rb.terminated[...] = rb.ended & (rng.random(shape) < 0.5)
    rb.written[:] = rb.rows
    return rb


def in_storage(host: Any, storage: str, device: Any) -> Any:
    """A replay buffer with ``host``'s rows, its observations kept in ``storage``."""
    from priqn.agents.frames import assign
    from priqn.agents.replay import ReplayBuffer

    spec = host.frames.shapes
    rb = ReplayBuffer(spec, host.num_envs, host.num_envs * host.rows, host.n_step,
                      tuple(host.gamma_O), host.num_objectives, storage, device)  # fmt: skip
    for k, a in host.obs.items():
        assign(rb.obs[k], a)
    for name in ("action", "reward", "starts", "ended", "terminated", "written"):
        np.copyto(getattr(rb, name), getattr(host, name))
    return rb


def _time(step: Any, seconds: float, cuda: bool) -> float:
    """Calls of ``step()`` per second over about ``seconds`` (at least 5 calls)."""
    import torch

    if cuda:
        torch.cuda.synchronize()
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds or n < 5:
        step()
        n += 1
    if cuda:
        torch.cuda.synchronize()
    return n / (time.perf_counter() - t0)


def _learn(learner: Any, sample: Any) -> None:
    """One learning step: a batch from the replay, one update on it."""
    learner.update(sample())


def feed_rates(
    preset: str,
    agents: list[str],
    storages: tuple[str, ...],
    batch_size: int,
    seconds: float,
    device: str,
    capacity: int = 0,
    compile_: str = "auto",
    rounds: int = 3,
) -> list[dict[str, Any]]:
    """One row per (agent, storage) of ``preset``: samples/s and updates/s with sampling.

    ``storages`` start with the baseline (``host``); ``capacity`` 0 is the preset's
    ``replay.capacity``; ``compile_`` is the learners' ``learner.compile`` (as training:
    ``auto``). ``seconds`` per case and rate, split in ``rounds`` rounds.
    """
    from priqn.bench.learners import make_learner
    from priqn.run.train_config import cuda_determinism, resolve_config, select_device

    dev = select_device(device)
    if dev.type == "cuda":
        cuda_determinism(True)  # training's kernels; before the first CUDA matrix product
    cfg = resolve_config(preset=preset)
    cfg = dataclasses.replace(cfg, learner=dataclasses.replace(cfg.learner, batch_size=batch_size))
    space, _ = obs_space(cfg)
    host = synthetic_replay(cfg, space, capacity or cfg.replay.capacity, np.random.default_rng(0))
    buffers = {s: host if s == "host" else in_storage(host, s, dev) for s in storages}
    learners = {
        a: make_learner(preset, a, batch_size, device, compile_=compile_)[0] for a in agents
    }
    rng = np.random.default_rng(1)
    cases = [(a, s) for a in agents for s in storages]
    samples = dict.fromkeys(cases, 0.0)
    updates = dict.fromkeys(cases, 0.0)
    cuda = dev.type == "cuda"
    for _ in range(rounds):
        for a, s in cases:
            rb, learner = buffers[s], learners[a]
            t = seconds / rounds / 2
            sample = functools.partial(rb.sample, batch_size, rng)
            learn = functools.partial(_learn, learner, sample)
            samples[a, s] = max(samples[a, s], _time(sample, t, cuda))
            updates[a, s] = max(updates[a, s], _time(learn, t, cuda))
    return [
        {
            "preset": preset,
            "agent": a,
            "storage": s,
            "device": str(dev),
            "obs_px": cfg.env.obs_size_px,
            "transitions": len(host),
            "update_kind": learners[a].update_kind,
            "samples_per_s": samples[a, s],
            "updates_per_s": updates[a, s],
        }  # fmt: skip
        for a, s in cases
    ]


def ratio_lines(rows: list[dict[str, Any]]) -> list[str]:
    """One line per agent and storage other than the first (``host``): its rates over the
    first storage's, in samples/s and in updates/s with sampling."""
    base = {r["agent"]: r for r in rows if r["storage"] == rows[0]["storage"]}
    lines = []
    for r in rows:
        b = base[r["agent"]]
        if r is b:
            continue
        lines.append(
            f"{r['agent']}: {r['storage']} / {b['storage']} on {r['device']}: "
            f"{r['samples_per_s'] / b['samples_per_s']:.2f}x samples/s "
            f"({1000 / b['samples_per_s']:.2f} -> {1000 / r['samples_per_s']:.2f} ms/sample), "
            f"{r['updates_per_s'] / b['updates_per_s']:.2f}x updates/s with sampling "
            f"({1000 / b['updates_per_s']:.2f} -> {1000 / r['updates_per_s']:.2f} ms/update)"
        )
    return lines


def print_feed(rows: list[dict[str, Any]], batch_size: int) -> None:
    """The table of :func:`feed_rates` and its ratio lines."""
    r0 = rows[0]
    print(
        f"\nreplay feed ({r0['preset']} preset, {r0['obs_px']} px, {r0['transitions']} "
        f"transitions, batch {batch_size}, update {r0['update_kind']}): sample alone, and "
        "sample -> update"
    )
    print(f"{'agent':<10} {'storage':<8} {'samples/s':>10} {'ms/sample':>10} {'updates/s':>10}")
    for r in rows:
        print(
            f"{r['agent']:<10} {r['storage']:<8} {r['samples_per_s']:>10.1f} "
            f"{1000 / r['samples_per_s']:>10.2f} {r['updates_per_s']:>10.1f}",
            flush=True,
        )
    for line in ratio_lines(rows):
        print(f"{r0['preset']:<8} {line}", flush=True)
