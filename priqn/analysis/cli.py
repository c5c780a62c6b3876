"""``priqn report``: its flags, as a :class:`~priqn.analysis.request.ReportRequest`.

Which report a folder gets (an experiment's design, the horizon, else the Tables I/II
grid report) and the command its ``meta.json`` records are
:mod:`priqn.analysis.reports`' choice and :func:`priqn.analysis.request.report_command`'s,
the same for ``priqn sweep``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from priqn.analysis.reports import experiment_of, write_report
from priqn.analysis.request import DEFAULT_REPS, ReportRequest
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
        help="the runs are this experiment's, one with a [sequential], [[question]] or "
        "[calibration] design (default: the experiment file named like the runs folder, if "
        "any): report its looks and verdicts, or its choice",
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
        "--traffic",
        metavar="NAME",
        help="instead: the same runs under another traffic setting (priqn evaluate RUN "
        "--traffic NAME) beside their own evaluation: each row's change paired per seed, the "
        "rows' difference under each, the outcome mix, scene by scene (traffic.md, descriptive)",
    )
    parser.add_argument(
        "--evaluation",
        metavar="NAME",
        help="instead: the report of an evaluation design (evaluations/NAME.toml, e.g. "
        "out-of-range) over the committed cells it names; the runs argument is unused",
    )
    parser.add_argument(
        "--partial",
        action="store_true",
        help="report the fully evaluated runs of a grid still running; name the rest",
    )


def run(args: argparse.Namespace) -> int:
    if args.reps < 1:
        raise PriqnError(f"--reps: must be >= 1, got {args.reps}")
    runs = Path(args.runs)
    if args.evaluation:
        from priqn.evaluation.design import load_design

        design = load_design(args.evaluation)
        out = Path(args.out) if args.out else Path("reports") / design.design.name
        request = ReportRequest(runs, out, None, seed=args.seed, partial=args.partial,
                                evaluation=design)  # fmt: skip
        print(write_report(request))
        return 0
    out = Path(args.out) if args.out else Path("reports") / runs.resolve().name
    request = ReportRequest(
        runs,
        out,
        experiment_of(runs, args.experiment),
        seed=args.seed,
        reps=args.reps,
        min_seeds=args.seeds,
        partial=args.partial,
        references=tuple(args.reference),
        horizon=_limits(args.horizon) if args.horizon else (),
        traffic=args.traffic,
    )
    print(write_report(request))
    return 0


def _limits(text: str) -> tuple[int, ...]:
    """``--horizon 200,600`` as limits (a one-line error for anything else)."""
    try:
        return tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise PriqnError(f"--horizon {text!r}: expected limits like 200,600") from None
