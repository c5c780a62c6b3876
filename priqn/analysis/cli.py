"""``priqn report``: its flags and what they run.

An experiment's runs folder with a design (``[sequential]``, ``[[question]]`` or
``[calibration]``) gets that design's report (:func:`priqn.analysis.report.write_experiment_report`);
any other folder of evaluated runs the Tables I/II report (:func:`priqn.analysis.report.make_report`).
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from priqn.analysis.report import (
    DEFAULT_REPS,
    design_experiment,
    make_report,
    write_experiment_report,
)
from priqn.errors import PriqnError


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "runs", nargs="?", default="runs", help="folder of evaluated runs (default runs/)"
    )
    parser.add_argument("--out", help="output folder (default reports/<runs folder name>/)")
    parser.add_argument(
        "--seed", type=int, default=0, help="np.random seed before every rliable call"
    )
    parser.add_argument("--reps", type=int, default=DEFAULT_REPS, help="bootstrap replications")
    parser.add_argument(
        "--seeds", type=int, default=None, help="refuse if a policy has fewer training seeds"
    )
    parser.add_argument(
        "--experiment",
        default=None,
        metavar="NAME",
        help="the runs are a sequential experiment's (default: the experiment file named like "
        "the runs folder, if it has a [sequential] design): report its looks and verdicts",
    )
    parser.add_argument(
        "--reference",
        action="append",
        default=[],
        metavar="DIR",
        help="a reference driver's folder (priqn evaluate --reference sumo|random --out DIR): "
        "unranked rows in Table II and the outcome breakdown; repeat for several",
    )
    parser.add_argument(
        "--horizon",
        metavar="N[,N...]",
        help="instead: the same runs at these evaluation-only episode limits (priqn evaluate "
        "--max-episode-steps N) beside their own evaluation: outcome mix per row and density, "
        "and where the timeouts go (horizon.md, descriptive)",
    )
    parser.add_argument(
        "--partial",
        action="store_true",
        help="report the fully evaluated runs of a grid still running; name the rest",
    )


def run(args: argparse.Namespace) -> int:
    if args.reps < 1:
        raise PriqnError(f"--reps: must be >= 1, got {args.reps}")
    out = Path(args.out) if args.out else Path("reports") / Path(args.runs).resolve().name
    if args.horizon:
        from priqn.analysis.horizon import write_horizon_report

        try:
            limits = [int(x) for x in args.horizon.split(",") if x.strip()]
        except ValueError:
            raise PriqnError(f"--horizon {args.horizon!r}: expected limits like 200,600") from None
        command = f"priqn report {shlex.quote(str(args.runs))} --horizon {args.horizon} --out {shlex.quote(str(out))}"
        print(write_horizon_report(args.runs, limits, out, command))
        return 0
    exp = design_experiment(args.runs, args.experiment)
    if exp is not None:
        if args.reference:
            raise PriqnError("--reference: not for a sequential experiment's report")
        command = f"priqn report {shlex.quote(str(args.runs))} --out {shlex.quote(str(out))}"
        print(write_experiment_report(exp, out, command))
        return 0
    command = (
        f"priqn report {shlex.quote(str(args.runs))} --out {shlex.quote(str(out))} "
        f"--seed {args.seed} --reps {args.reps}"
        + (f" --seeds {args.seeds}" if args.seeds else "")
        + (" --partial" if args.partial else "")
        + "".join(f" --reference {shlex.quote(str(d))}" for d in args.reference)
    )
    print(
        make_report(
            args.runs,
            out,
            seed=args.seed,
            reps=args.reps,
            min_seeds=args.seeds,
            command=command,
            partial=args.partial,
            references=tuple(args.reference),
        )
    )
    return 0
