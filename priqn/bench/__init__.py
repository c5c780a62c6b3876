"""``priqn bench``: speed measured as ratios against a baseline run in the same command.

Sub-benchmarks live in their own modules (``priqn.bench.env``, ``.preorder``,
``.train``, ``.sweep``, ``.replay``, ``.loop``), each with ``configure_parser`` / ``run`` like a CLI command.
The slow baselines they time against (which are also the tests' oracles) live in
:mod:`priqn.bench.references`.
"""

from __future__ import annotations

import argparse
import importlib

BENCHES: dict[str, str] = {
    "env": "env decisions/s vs the raw libsumo floor; vector-env scaling",
    "preorder": "batched optimal subsets vs a per-state reference loop",
    "train": "updates/s of IQN vs Pr-IQN; env decisions/s with learning on",
    "sweep": "sweep cells per hour: one at a time vs two (--jobs) at a time",
    "replay": "the replay buffer in a checkpoint: compressed, incremental vs the whole, uncompressed",
    "loop": "the loop's stalls: metrics.csv appended vs rewritten; env workers with vs without preload; checkpoints on a writer thread vs in the loop",
}


def configure_parser(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="bench", required=True, metavar="BENCH")
    for name, text in BENCHES.items():
        p = sub.add_parser(name, help=text, description=text)
        importlib.import_module(f"priqn.bench.{name}").configure_parser(p)


def run(args: argparse.Namespace) -> int:
    return int(importlib.import_module(f"priqn.bench.{args.bench}").run(args) or 0)
