"""``priqn bench loop``: the training loop's one-off and growing stalls (issue 61), each
against what it replaced, in one command.

1. **metrics.csv** — a run of ``--decisions`` decisions with an episode every
   ``--episode-length`` decisions writes its metrics every 1,000 decisions. Before: the
   whole file rewritten each time (:func:`priqn.run.metrics.write_metrics`, atomic, with
   fsync), a cost that grows with the square of the run's length. Now: the rows since the
   last write appended (:class:`priqn.run.metrics.MetricsFile`, fsync). Both are timed on
   the same rows in a temporary folder, and their files compared byte for byte.
2. **preload** — a vector env of ``--workers`` workers, from its creation to the end of
   ``--steps`` vector steps of random actions, with and without ``preload_nets`` in every
   worker first (parsing every net, drawing every route, loading the sensors' compiled
   loops). Without it, those costs fall into the first resets and steps, where the vector
   step waits for the slowest worker. Timed: the creation (with its preload), the first
   reset, the slowest step, and the whole.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

LOG_INTERVAL = 1000
"""Decisions between metrics writes (the presets' ``log_interval_steps``)."""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--decisions", type=int, default=500000, help="run length for metrics.csv (500000)"
    )
    parser.add_argument("--episode-length", type=int, default=40, help="decisions per episode (40)")
    parser.add_argument("--workers", type=int, default=2, help="env workers for preload (2)")
    parser.add_argument("--steps", type=int, default=30, help="vector steps for preload (30)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the env and its actions")
    parser.add_argument(
        "--skip-preload", action="store_true", help="time metrics.csv only (no SUMO)"
    )


def run(args: argparse.Namespace) -> int:
    from priqn.errors import PriqnError

    if args.decisions < LOG_INTERVAL or args.episode_length < 1:
        raise PriqnError(f"--decisions >= {LOG_INTERVAL} and --episode-length >= 1 expected")
    if args.workers < 1 or args.steps < 1:
        raise PriqnError("--workers and --steps: expected >= 1")
    m = metrics_writes(args.decisions, args.episode_length)
    print(
        f"priqn bench loop: metrics.csv over {args.decisions:,} decisions "
        f"({m['rows']:,} rows, {m['writes']} writes): rewrite {m['rewrite_s']:.2f} s, "
        f"append {m['append_s']:.2f} s: {m['rewrite_s'] / m['append_s']:.1f}x "
        f"(files {'identical' if m['same'] else 'DIFFER'})"
    )
    if args.skip_preload:
        return 0
    print(f"preload: {args.workers} workers, {args.steps} vector steps (seconds)")
    print(f"{'':>8} {'create':>7} {'1st reset':>9} {'slowest step':>12} {'whole':>7}")
    timed = {p: preload_timing(p, args.workers, args.steps, args.seed) for p in (False, True)}
    for preload, t in timed.items():
        print(
            f"{'with' if preload else 'without':>8} {t['create_s']:>7.2f} {t['reset_s']:>9.2f} "
            f"{t['slowest_step_s']:>12.3f} {t['whole_s']:>7.2f}"
        )
    off, on = timed[False], timed[True]
    print(
        f"first reset {off['reset_s'] / on['reset_s']:.1f}x shorter with preload; slowest step "
        f"{off['slowest_step_s'] / on['slowest_step_s']:.1f}x; whole {off['whole_s'] / on['whole_s']:.2f}x"
    )
    return 0


def metrics_writes(decisions: int, episode_length: int) -> dict[str, Any]:
    """The same rows written both ways (see the module docstring): seconds and whether the
    two files came out the same."""
    from priqn.run.metrics import METRIC_COLUMNS, MetricsFile, write_metrics

    row = {c: 0 for c in METRIC_COLUMNS} | {"kind": "train", "net": "tjunction/t_00",
                                            "command": "left", "loss": 0.01234}  # fmt: skip
    per_write = LOG_INTERVAL // episode_length or 1
    with tempfile.TemporaryDirectory() as tmp:
        old, new = Path(tmp) / "rewrite.csv", Path(tmp) / "append.csv"
        rows: list[dict[str, Any]] = []
        file = MetricsFile(new, METRIC_COLUMNS, [])
        rewrite_s = append_s = 0.0
        writes = decisions // LOG_INTERVAL
        for w in range(writes):
            rows += [row | {"step": (w + 1) * LOG_INTERVAL, "episode": len(rows) + i}
                     for i in range(per_write)]  # fmt: skip
            t0 = time.perf_counter()
            write_metrics(old, rows, METRIC_COLUMNS)
            t1 = time.perf_counter()
            file.flush(rows)
            t2 = time.perf_counter()
            rewrite_s, append_s = rewrite_s + t1 - t0, append_s + t2 - t1
        same = old.read_bytes() == new.read_bytes()
    return {"rows": len(rows), "writes": writes, "rewrite_s": rewrite_s, "append_s": append_s,
            "same": same}  # fmt: skip


def preload_timing(preload: bool, workers: int, steps: int, seed: int) -> dict[str, float]:
    """Seconds of a fresh vector env's creation, first reset, slowest step and the whole."""
    from priqn.env.intersection import EnvConfig
    from priqn.env.vector import make_vector_env

    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    venv = make_vector_env(EnvConfig(), workers, seed=seed, preload=preload)
    try:
        t1 = time.perf_counter()
        venv.reset()
        t2 = time.perf_counter()
        slowest = 0.0
        for _ in range(steps):
            s = time.perf_counter()
            venv.step(rng.integers(5, 25, size=workers))
            slowest = max(slowest, time.perf_counter() - s)
        t3 = time.perf_counter()
    finally:
        venv.close()
    return {"create_s": t1 - t0, "reset_s": t2 - t1, "slowest_step_s": slowest, "whole_s": t3 - t0}
