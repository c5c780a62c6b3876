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
3. **checkpoints** — the same training run (``priqn train``'s default preset, pr-iqn on
   tjunction, ``--ckpt-decisions`` decisions, a checkpoint every ``--ckpt-interval``,
   learning from the first on) twice: its checkpoints written in the loop, as before,
   and by the background writer (:mod:`priqn.run.writer`). Timed: the loop's blocking
   time in checkpoints (meta.json ``time_s.checkpoint``: the capture, the metrics flush,
   the waits for the writer) and the whole run; ``priqn diff`` says whether the two are
   the same training.
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
    parser.add_argument(
        "--ckpt-decisions", type=int, default=1200, help="training run for checkpoints (1200)"
    )
    parser.add_argument(
        "--ckpt-interval", type=int, default=200, help="decisions between checkpoints (200)"
    )
    parser.add_argument(
        "--ckpt-repeats",
        type=int,
        default=1,
        help="pairs of runs for checkpoints, in turn which goes first (1)",
    )
    parser.add_argument(
        "--skip-checkpoints", action="store_true", help="no training run (checkpoints)"
    )


def run(args: argparse.Namespace) -> int:
    from priqn.errors import PriqnError

    if args.decisions < LOG_INTERVAL or args.episode_length < 1:
        raise PriqnError(f"--decisions >= {LOG_INTERVAL} and --episode-length >= 1 expected")
    if args.workers < 1 or args.steps < 1:
        raise PriqnError("--workers and --steps: expected >= 1")
    if not 0 < args.ckpt_interval <= args.ckpt_decisions or args.ckpt_repeats < 1:
        raise PriqnError("--ckpt-interval: expected 1 to --ckpt-decisions; --ckpt-repeats >= 1")
    m = metrics_writes(args.decisions, args.episode_length)
    print(
        f"priqn bench loop: metrics.csv over {args.decisions:,} decisions "
        f"({m['rows']:,} rows, {m['writes']} writes): rewrite {m['rewrite_s']:.2f} s, "
        f"append {m['append_s']:.2f} s: {m['rewrite_s'] / m['append_s']:.1f}x "
        f"(files {'identical' if m['same'] else 'DIFFER'})"
    )
    if not args.skip_preload:
        print_preload(args.workers, args.steps, args.seed)
    if not args.skip_checkpoints:
        print_checkpoints(args.ckpt_decisions, args.ckpt_interval, args.ckpt_repeats, args.seed)
    return 0


def print_preload(workers: int, steps: int, seed: int) -> None:
    """Section 2: env workers with and without preload."""
    print(f"preload: {workers} workers, {steps} vector steps (seconds)")
    print(f"{'':>8} {'create':>7} {'1st reset':>9} {'slowest step':>12} {'whole':>7}")
    timed = {p: preload_timing(p, workers, steps, seed) for p in (False, True)}
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


def print_checkpoints(decisions: int, interval: int, repeats: int, seed: int) -> None:
    """Section 3: one training run with checkpoints written in the loop and in the
    background, ``repeats`` times each (summed)."""
    t: dict[str, float] = {}
    same = True
    for r in range(repeats):
        timed = checkpoint_timing(decisions, interval, seed, background_first=r % 2 == 1)
        same = same and bool(timed.pop("same"))
        for key, seconds in timed.items():
            t[key] = t.get(key, 0.0) + seconds
    print(
        f"checkpoints: pr-iqn on tjunction, {decisions:,} decisions, one every {interval:,} "
        f"({-(-decisions // interval)} checkpoints; {repeats} run(s) each, summed; seconds)"
    )
    print(f"{'':>10} {'blocking':>8} {'whole':>7}")
    for mode in ("inline", "background"):
        print(f"{mode:>10} {t[f'{mode}_blocking_s']:>8.2f} {t[f'{mode}_whole_s']:>7.2f}")
    print(
        f"blocking {t['inline_blocking_s'] / t['background_blocking_s']:.1f}x shorter in the "
        f"background; whole {t['inline_whole_s'] / t['background_whole_s']:.2f}x "
        f"({'the same training' if same else 'NOT THE SAME TRAINING'})"
    )


def checkpoint_timing(
    decisions: int, interval: int, seed: int, background_first: bool = False
) -> dict[str, Any]:
    """The same run trained with its checkpoints written in the loop (``inline``) and by
    the background writer (``background``; first if ``background_first``): the loop's
    seconds blocked in checkpoints and the whole run's, and whether ``priqn diff`` finds
    them the same training."""
    from priqn.run.folder import RunFolder
    from priqn.run.train_config import resolve_config
    from priqn.tools.diff import diff_runs
    from priqn.train import train

    overrides = [  # learning from the first checkpoint on, no in-training evaluation
        f"checkpoint.interval_steps={interval}",
        f"replay.learning_starts={interval}",
        "evaluation.interval_steps=0",
    ]
    cfg = resolve_config(
        agent="pr-iqn", seed=seed, net="tjunction", steps=decisions, overrides=overrides
    )
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        runs = {}
        modes = ("background", "inline") if background_first else ("inline", "background")
        for mode in modes:
            t0 = time.perf_counter()
            runs[mode] = RunFolder(train(cfg, Path(tmp) / mode, background_writes=mode != "inline"))
            out[f"{mode}_whole_s"] = time.perf_counter() - t0
            out[f"{mode}_blocking_s"] = runs[mode].meta()["time_s"]["checkpoint"]
        _, parts = diff_runs(runs["inline"], runs["background"])
        out["same"] = all(p.same for p in parts if p.same is not None)
    return out


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
    from priqn.env.config import EnvConfig
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
