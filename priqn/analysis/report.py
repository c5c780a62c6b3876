"""``priqn report``: Tables I and II, rliable statistics and figures from evaluated runs.

``make_report(runs_dir, out_dir, seed=0)`` writes::

    out_dir/report.md                 everything at a glance
    out_dir/meta.json                 inputs (runs, hold-out hash), seed, reps, command
    out_dir/tables/table2.{md,tex,csv}, table1.{md,tex,csv}
    out_dir/tables/rliable_aggregates.csv, probability_of_improvement.csv,
                   performance_profiles.csv
    out_dir/tables/outcomes_by_command.csv  how episodes end, per policy and command
    out_dir/tables/claims.csv         the paper's claims (priqn.analysis.claims), when the
                                      report holds every row of at least one claim
    out_dir/figures/{probability_of_improvement,iqm_optimality_gap,
                     performance_profile,learning_curves,
                     outcomes_by_command,seeds}.{png,pdf}
    out_dir/figures/claims.{png,pdf}  the claims' success-rate comparisons, when measured

Same inputs and seed give byte-identical tables and report.md (no timestamps).
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path
from typing import Any

from priqn.errors import PriqnError
from priqn.io import atomic_write_json, atomic_write_text
from priqn.runs import RunFolder

DEFAULT_REPS = 2000
MIN_SEEDS_FOR_STATISTICS = 2
"""Fewer training seeds per policy: no best/second marks and no CIs in the report."""
"""Bootstrap replications by default (rliable suggests >= 2000 for 95% CIs)."""


def _fmt_ci(point: float, lo: float, hi: float) -> str:
    return f"{point:.3f} [{lo:.3f}, {hi:.3f}]"


def _rliable_markdown(aggregates: dict[str, Any], order: list[str]) -> str:
    """IQM / optimality-gap table from ``{metric: aggregates DataFrame}``."""
    from priqn.analysis.stats import SCORE_METRICS

    heads = ["Policy"]
    for metric in aggregates:
        short = SCORE_METRICS[metric]
        heads += [f"IQM {short} ↑", f"Optimality gap {short} ↓"]
    lines = ["| " + " | ".join(heads) + " |", "|:--|" + "--:|" * (len(heads) - 1)]
    aggs = {m: a.set_index("label") for m, a in aggregates.items()}
    for label in order:
        row = [label]
        for agg in aggs.values():
            a = agg.loc[label]
            row += [
                _fmt_ci(a["iqm"], a["iqm_lo"], a["iqm_hi"]),
                _fmt_ci(a["og"], a["og_lo"], a["og_hi"]),
            ]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def _poi_matrix_markdown(result: Any, order: list[str]) -> str:
    poi = result.improvement.set_index(["x", "y"])
    short = [f"({i + 1})" for i in range(len(order))]
    lines = [
        "| X \\ Y | " + " | ".join(short) + " |",
        "|:--|" + "--:|" * len(order),
    ]
    for i, x in enumerate(order):
        cells = []
        for y in order:
            if x == y:
                cells.append("–")
            else:
                r = poi.loc[(x, y)]
                cells.append(f"{r['p']:.2f} [{r['lo']:.2f}, {r['hi']:.2f}]")
        lines.append(f"| ({i + 1}) {x} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def make_report(
    runs_dir: str | Path,
    out_dir: str | Path,
    seed: int = 0,
    reps: int = DEFAULT_REPS,
    min_seeds: int | None = None,
    command: str | None = None,
    partial: bool = False,
) -> Path:
    """Write the report for every evaluated run under ``runs_dir``; returns ``report.md``.

    ``min_seeds``: refuse when a policy has fewer training seeds. ``seed`` goes to
    ``np.random.seed`` before every rliable call (recorded in the report). ``partial``:
    report the fully evaluated runs of a grid still running, and say which were left out.
    """
    import pandas as pd

    from priqn.analysis import claims, figures, tables
    from priqn.analysis.load import (
        check_seeds,
        find_run_dirs,
        load_evaluation,
        load_learning_curves,
    )
    from priqn.analysis.stats import (
        RUN_AXIS,
        SCORE_METRICS,
        SEED_AXIS,
        TASK_AXIS,
        aggregate_estimates,
        rliable_statistics,
        score_matrices,
    )

    out = Path(out_dir)
    runs_root = Path(runs_dir)
    evaluation = load_evaluation(runs_root, partial=partial)
    episodes = evaluation.episodes
    if min_seeds is not None:
        check_seeds(episodes, min_seeds)
    notes: list[str] = []
    if evaluation.left_out:
        notes.append(
            f"Partial report: {len(evaluation.left_out)} run folder(s) not fully evaluated "
            f"were left out: {', '.join(evaluation.left_out)}."
        )
    seeds_per_policy = episodes.groupby("label")["train_seed"].nunique()
    if seeds_per_policy.nunique() > 1:
        notes.append(
            "Policies have different numbers of training seeds: "
            + ", ".join(f"{k}: {v}" for k, v in seeds_per_policy.sort_index().items())
        )

    # Ranking or bootstrapping one training seed per policy would dress noise up as a
    # result: with fewer than 2 seeds the tables carry no marks and no CIs are printed.
    seeds_min = int(seeds_per_policy.min())
    ranked = seeds_min >= MIN_SEEDS_FOR_STATISTICS
    if not ranked:
        short = seeds_per_policy[seeds_per_policy < MIN_SEEDS_FOR_STATISTICS]
        unranked_why = (
            f"No best/second marks and no confidence intervals: {short.index[0]!r} has "
            f"{int(short.iloc[0])} training seed(s) (at least {MIN_SEEDS_FOR_STATISTICS} per "
            "policy are needed to rank policies or bootstrap over runs)."
        )
        notes.append(unranked_why)
    t2, t1 = tables.table2(episodes, ranked), tables.table1(episodes, ranked)
    order = list(t2.configs)
    if tables.reference_label(t2.configs) is None:
        notes.append("No IQN policy was evaluated, so Table I has no Δ%.")
    tdir, fdir = out / "tables", out / "figures"
    for name, table in (("table2", t2), ("table1", t1)):
        atomic_write_text(tdir / f"{name}.md", tables.to_markdown(table))
        atomic_write_text(tdir / f"{name}.tex", tables.to_latex(table))
        atomic_write_text(tdir / f"{name}.csv", tables.to_csv(table))

    results: dict[str, Any] = {}
    if ranked:
        results = {m: rliable_statistics(episodes, m, order, reps, seed) for m in SCORE_METRICS}
        seed_only = {
            m: aggregate_estimates(score_matrices(episodes, m, order, SEED_AXIS)[0], reps, seed)
            for m in SCORE_METRICS
        }
        csv_kw: dict[str, Any] = {"index": False, "float_format": "%.10g", "lineterminator": "\n"}
        atomic_write_text(
            tdir / "rliable_aggregates.csv",
            pd.concat([r.aggregates.assign(metric=m) for m, r in results.items()]).to_csv(**csv_kw),
        )
        atomic_write_text(
            tdir / "rliable_aggregates_seeds.csv",
            pd.concat([a.assign(metric=m) for m, a in seed_only.items()]).to_csv(**csv_kw),
        )
        atomic_write_text(
            tdir / "probability_of_improvement.csv",
            pd.concat([r.improvement.assign(metric=m) for m, r in results.items()]).to_csv(
                **csv_kw
            ),
        )
        atomic_write_text(
            tdir / "performance_profiles.csv",
            pd.concat([r.profiles.assign(metric=m) for m, r in results.items()]).to_csv(**csv_kw),
        )

        sr = results["success"]
        figures.save_figure(
            figures.probability_of_improvement_figure(sr), fdir, "probability_of_improvement"
        )
        figures.save_figure(figures.aggregates_figure(results), fdir, "iqm_optimality_gap")
        figures.save_figure(figures.performance_profile_figure(sr), fdir, "performance_profile")
    figures.save_figure(figures.seed_success_figure(episodes, order), fdir, "seeds")
    outcomes = tables.outcomes_by_command(episodes, order)
    atomic_write_text(
        tdir / "outcomes_by_command.csv",
        outcomes.to_csv(index=False, float_format="%.10g", lineterminator="\n"),
    )
    figures.save_figure(figures.outcomes_figure(outcomes, order), fdir, "outcomes_by_command")
    claim_results = claims.evaluate_claims(episodes, reps, seed)
    claims_checked = any(not r.missing for r in claim_results)
    claims_fig = figures.claims_figure(claim_results) if claims_checked else None
    if claims_checked:
        atomic_write_text(
            tdir / "claims.csv",
            claims.to_frame(claim_results).to_csv(
                index=False, float_format="%.10g", lineterminator="\n"
            ),
        )
        if claims_fig is not None:
            figures.save_figure(claims_fig, fdir, "claims")
    curves, curve_notes = load_learning_curves(find_run_dirs(runs_root), evaluation)
    if len(curves):
        figures.save_figure(figures.learning_curves_figure(curves, order), fdir, "learning_curves")
    notes += curve_notes

    cmd = (
        command
        or f"priqn report {shlex.quote(str(runs_root))} --out {shlex.quote(str(out))} --seed {seed} --reps {reps}"
    )
    ec = evaluation.eval_config
    if ranked:
        n_runs, n_tasks = len(next(iter(sr.scores.values()))), len(sr.tasks)
        axes = f"e.g. {n_runs} runs × {n_tasks} tasks for {order[0]}. "
        rliable_md = [
            "## rliable",
            "",
            _rliable_markdown({m: r.aggregates for m, r in results.items()}, order),
            f"Over training seeds only (run = {' × '.join(SEED_AXIS)}; evaluation runs averaged "
            "within a seed, so the CI reflects training-seed variation alone):",
            "",
            _rliable_markdown(seed_only, order),
            "Probability of improvement P(X > Y) on success rate (row X, column Y) [95% CI]:",
            "",
            _poi_matrix_markdown(sr, order),
            "![P(X > Y)](figures/probability_of_improvement.png) "
            "([pdf](figures/probability_of_improvement.pdf))",
            "",
            "![IQM and optimality gap](figures/iqm_optimality_gap.png) ([pdf](figures/iqm_optimality_gap.pdf))",
            "",
            "![Performance profile](figures/performance_profile.png) ([pdf](figures/performance_profile.pdf))",
            "",
        ]
    else:
        axes = ""
        rliable_md = ["## rliable", "", f"Not computed. {unranked_why}", ""]
    md = [
        "# priqn evaluation report" + (" (partial)" if evaluation.left_out else ""),
        "",
        *(
            [
                f"**Partial:** {len(evaluation.runs)} evaluated run(s); "
                f"{len(evaluation.left_out)} not yet evaluated left out (see Notes).",
                "",
            ]
            if evaluation.left_out
            else []
        ),
        f"Made by `{cmd}`; episodes by `priqn evaluate` on every run below.",
        "",
        *(
            [
                "Rows with `near-greedy ε=…` in their name are the acting-randomness control: "
                "the same networks as the rows without it, evaluated acting at random among "
                "the actions whose mean return is within ε (per-state std) of the best "
                "(`priqn evaluate --acting near-greedy`; docs/evaluation.md).",
                "",
            ]
            if any(r.eval_dir != RunFolder.EVAL for r in evaluation.runs)
            else []
        ),
        f"- **Hold-out set**: family `{ec.get('family')}`, manifest hash `{evaluation.holdout_hash}` "
        "(identical for every run).",
        f"- **Evaluation**: densities {ec.get('densities')}, {ec.get('eval_runs')} evaluation runs, "
        f"{ec.get('episodes_per_cell')} episodes per (evaluation run, net, density), evaluation seed "
        f"{ec.get('seed')}.",
        f"- **Statistics seed**: `np.random.seed({seed})` before every rliable call; "
        f"{reps} bootstrap replications, 95% percentile CIs.",
        f"- **rliable axes**: run = ({' × '.join(RUN_AXIS)}), task = ({' × '.join(TASK_AXIS)}); "
        f"{axes}Scores: success rate (SR) and mean "
        "route progress (RP) per cell; optimality-gap threshold 1.",
        "- **Tables**: mean ± sample std (ddof=1) over training seeds × evaluation runs; "
        + (
            "**best** / <u>second</u> per column and density on the printed means (ties share)."
            if ranked
            else "no best / second marks (too few training seeds; see rliable)."
        ),
        "",
        "## Table II — driving metrics",
        "",
        tables.to_markdown(t2),
        "![Success rate per training seed](figures/seeds.png) ([pdf](figures/seeds.pdf))",
        "",
        "## How episodes end, by route command",
        "",
        "Densities pooled; every episode ends in exactly one outcome (timeout = the "
        "time limit reached without finishing the route).",
        "",
        tables.outcomes_markdown(outcomes),
        "![Outcomes by command](figures/outcomes_by_command.png) "
        "([pdf](figures/outcomes_by_command.pdf))",
        "",
        "## Table I — objective returns",
        "",
        tables.to_markdown(t1),
        *(
            [
                "## The paper's claims",
                "",
                claims.to_markdown(claim_results, reps, seed),
                *(
                    ["![The claims](figures/claims.png) ([pdf](figures/claims.pdf))", ""]
                    if claims_fig is not None
                    else []
                ),
            ]
            if claims_checked
            else []
        ),
        *rliable_md,
        "## Learning curves",
        "",
        (
            "![Learning curves](figures/learning_curves.png) ([pdf](figures/learning_curves.pdf))"
            if len(curves)
            else "No usable metrics.csv in any run; no learning curves."
        ),
        "",
        "## Inputs",
        "",
        "| run | policy | training seed | hold-out hash |",
        "|:--|:--|--:|:--|",
        *[
            f"| {r.name} | {r.label} | {r.train_seed} | `{r.holdout_hash[:16]}` |"
            for r in evaluation.runs
        ],
        "",
    ]
    if notes:
        md += ["## Notes", "", *[f"- {n}" for n in notes], ""]
    md += [
        "Files: `tables/` (Markdown, LaTeX, CSV), `figures/` (PNG, PDF), `meta.json`.",
        "",
    ]
    report = out / "report.md"
    atomic_write_text(report, "\n".join(md))
    atomic_write_json(
        out / "meta.json",
        {
            "command": cmd,
            "seed": seed,
            "bootstrap_reps": reps,
            "min_seeds": min_seeds,
            "run_axis": list(RUN_AXIS),
            "task_axis": list(TASK_AXIS),
            "holdout_hash": evaluation.holdout_hash,
            "eval_config": ec,
            "runs": [
                {
                    "name": r.name,
                    "label": r.label,
                    "train_seed": r.train_seed,
                    "holdout_hash": r.holdout_hash,
                }
                for r in evaluation.runs
            ],
            "policies": order,
            "left_out": list(evaluation.left_out),
            "notes": notes,
        },
    )
    return report


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
        "--partial",
        action="store_true",
        help="report the fully evaluated runs of a grid still running; name the rest",
    )


def run(args: argparse.Namespace) -> int:
    if args.reps < 1:
        raise PriqnError(f"--reps: must be >= 1, got {args.reps}")
    out = Path(args.out) if args.out else Path("reports") / Path(args.runs).resolve().name
    command = (
        f"priqn report {shlex.quote(str(args.runs))} --out {shlex.quote(str(out))} "
        f"--seed {args.seed} --reps {args.reps}"
        + (f" --seeds {args.seeds}" if args.seeds else "")
        + (" --partial" if args.partial else "")
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
        )
    )
    return 0
