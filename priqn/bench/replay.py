"""``priqn bench replay``: the replay buffer in a checkpoint, compressed and incremental,
against the uncompressed whole-buffer write it replaced (issue 49), in one command.

Fills a :class:`priqn.agents.replay.ReplayBuffer` of ``--capacity`` transitions (2 env
rings, as the default preset) with real observations: ``--decisions`` of them are taken
from the env (hold-out nets, densities 0.5-1.0, random actions) and cycled to fill the
buffer, so every row is a real BEV / LiDAR raster. Then, per observation size, it times
and sizes:

- ``whole, uncompressed``: :meth:`ReplayBuffer.save_to` of the full buffer, what every
  checkpoint wrote before (``np.savez``);
- ``rows since last, compressed``: :meth:`ReplayBuffer.save_rows` of the rows one
  checkpoint interval adds (``--interval`` decisions), what a checkpoint writes now
  (zstd, :func:`priqn.agents.replay.write_arrays`);
- ``whole, compressed``: the same for the full buffer (the first checkpoint after a
  full ring, and the cost of loading it back: ``load``).

Each file is written to disk in the working directory and fsynced, as a checkpoint is.
It prints bytes per transition, seconds per checkpoint and the ratios, and the buffer's
memory (unchanged: the rows live uncompressed in RAM, as before).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from typing import Any

import numpy as np


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--px", type=int, nargs="+", default=[64, 128], help="observation sizes (64 128)"
    )
    parser.add_argument(
        "--capacity", type=int, default=50000, help="replay transitions (50000, the default preset)"
    )
    parser.add_argument(
        "--interval", type=int, default=10000, help="decisions between checkpoints (10000)"
    )
    parser.add_argument(
        "--decisions", type=int, default=600, help="real observations taken from the env (600)"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the env and its actions")


def real_observations(px: int, decisions: int, seed: int) -> list[dict[str, np.ndarray]]:
    """``decisions`` observations of the hold-out nets at ``px`` (random actions, resets)."""
    from priqn.env.config import EnvConfig
    from priqn.env.intersection import IntersectionEnv

    env = IntersectionEnv(EnvConfig(family="holdout", obs_size_px=px), seed=seed)
    rng = np.random.default_rng(seed)
    try:
        obs, _ = env.reset()
        out = [obs]
        while len(out) < decisions:
            obs, _, terminated, truncated, _ = env.step(int(rng.integers(5, 25)))  # moving
            out.append(obs)
            if terminated or truncated:
                obs, _ = env.reset()
                out.append(obs)
        return out[:decisions]
    finally:
        env.close()


def filled_buffer(observations: list[dict[str, np.ndarray]], capacity: int) -> Any:
    """A 2-env buffer whose rings are full of the observations, cycled."""
    from priqn.agents.replay import ReplayBuffer

    spec = {k: (v.shape, v.dtype) for k, v in observations[0].items()}
    replay = ReplayBuffer(spec, num_envs=2, capacity=capacity)
    n = len(observations)
    for t in range(replay.rows):
        pair = (observations[(2 * t) % n], observations[(2 * t + 1) % n])
        batch = {k: np.stack([o[k] for o in pair]) for k in spec}
        replay.add(batch, np.zeros(2, np.int64), np.zeros((2, 5), np.float32),
                   np.zeros(2, bool), np.zeros(2, bool), [None, None])  # fmt: skip
    return replay


def _timed(write: Any, folder: str) -> tuple[float, int, str]:
    """Seconds to ``write`` a file in ``folder`` and fsync it (as a checkpoint does), its
    size and its path."""
    fd, path = tempfile.mkstemp(dir=folder, suffix=".npz")
    t0 = time.perf_counter()
    with os.fdopen(fd, "wb") as fh:
        write(fh)
        fh.flush()
        os.fsync(fh.fileno())
    return time.perf_counter() - t0, os.path.getsize(path), path


def measure(replay: Any, interval: int, folder: str) -> dict[str, tuple[float, int, int]]:
    """``mode -> (seconds, bytes, transitions written)`` for the three writes (files in
    ``folder``), and the load of the whole compressed one."""
    full = int(replay.written.sum())
    since = np.maximum(replay.written - interval // replay.num_envs, 0)
    out = {}
    s, size, _ = _timed(replay.save_to, folder)
    out["whole, uncompressed"] = (s, size, full)
    s, size, _ = _timed(lambda fh: replay.save_rows(fh, since), folder)
    out["rows since last, compressed"] = (s, size, int((replay.written - since).sum()))
    s, size, path = _timed(lambda fh: replay.save_rows(fh, np.zeros_like(replay.written)), folder)
    out["whole, compressed"] = (s, size, full)
    t0 = time.perf_counter()
    replay.load_rows(path)
    out["load whole, compressed"] = (time.perf_counter() - t0, size, full)
    return out


def run(args: argparse.Namespace) -> int:
    from priqn.errors import PriqnError

    if min(args.capacity, args.interval, args.decisions) < 1 or min(args.px) < 16:
        raise PriqnError("--capacity, --interval, --decisions: expected >= 1; --px: >= 16")
    print(
        f"priqn bench replay: {args.capacity:,} transitions, a checkpoint every "
        f"{args.interval:,} decisions, {args.decisions} real observations cycled"
    )
    for px in args.px:
        replay = filled_buffer(real_observations(px, args.decisions, args.seed), args.capacity)
        with tempfile.TemporaryDirectory(prefix="priqn-bench-replay-", dir=".") as folder:
            results = measure(replay, args.interval, folder)
        base_s, base_b, base_n = results["whole, uncompressed"]
        print(f"  {px} px: buffer in RAM {replay.nbytes() / 2**20:,.0f} MiB "
              f"({replay.bytes_per_row():,} bytes a row)")  # fmt: skip
        for mode, (s, size, n) in results.items():
            print(
                f"    {mode:28s} {size / n:9,.0f} bytes/transition  {s:7.2f} s  "
                f"{size / 2**20:8,.1f} MiB  (x{size / n / (base_b / base_n):.3f} bytes, "
                f"x{s / base_s:.2f} time of the whole uncompressed write)"
            )
    return 0
