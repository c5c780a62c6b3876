"""The report of a ``[sequential]`` table (kind ``sequential``, the one-question layout),
from its looks.

:func:`sequential_report` builds its sections (rendered by
:func:`priqn.analysis.artifacts.render`), deterministically (the same committed cells give the same bytes): ``report.md``
(verdicts, each look, per-density success, the next cells, every cell),
``tables/scores.csv`` / ``looks.csv`` / ``density.csv`` / ``sample_efficiency.csv`` and
``figures/headline`` (per-seed success of each row), ``figures/looks`` (each comparison
look by look) and ``figures/sample_efficiency`` (:func:`priqn.analysis.curves.efficiency`).
The scores are :mod:`priqn.analysis.questions`' (as for any design), the decisions
:mod:`priqn.analysis.sequential`'s; nothing here decides. ``[[question]]`` tables have
their own layout, :mod:`priqn.analysis.questions_report`; the choice is
:func:`priqn.analysis.reports.choose_kind`'s.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from priqn.analysis import curves, inference, questions
from priqn.analysis.curves import CURVE_REPS, CURVE_SEED
from priqn.analysis.figures import efficiency_figure, looks_figure
from priqn.analysis.load import RESUMED_NOTE, resumed_before, resumed_text
from priqn.analysis.render import markdown_table, points, points_interval
from priqn.analysis.sections import Report, Section
from priqn.analysis.sequential import ComparisonLook, Looks, relative_path, row_verdict
from priqn.experiment import cell_dir_name
from priqn.run.folder import RunFolder

PAPER_TRAINING_DECISIONS = 2_000_000
"""The paper's training budget per run (``priqn/presets/train_paper.toml`` total_steps)."""
SCORE_COLUMNS: tuple[str, ...] = ("policy", "seed", "score", "episodes", "git_sha", "run_dir")
"""Columns of ``tables/scores.csv``: :data:`priqn.analysis.questions.COLUMNS` less the
training seed and the evaluation (a row's seed is its position; every cell is ``eval/``)."""


def density_frame(exp: Any, scores: pd.DataFrame) -> pd.DataFrame:
    """Descriptive only (the endpoint is the mean over densities): per row and evaluation
    density, the hold-out success over the row's scored cells — mean and 95 % t interval
    over training seeds — beside the paper's Table II value for the row's label, if it has
    one. Columns: policy, density, seeds, mean, lo, hi, paper. ``tables/density.csv``."""
    from priqn.analysis.paper import PAPER_DENSITIES, PAPER_SUCCESS

    rows = []
    for policy in [p.name for p in exp.policies]:
        mine = scores[scores["policy"] == policy]
        if mine.empty:
            continue
        success_SD = pd.DataFrame(  # one row per cell (seed), one column per density
            [
                questions.endpoint_by_density(RunFolder(d).eval_dir, "success")[0]
                for d in mine["run_dir"]
            ]
        ).sort_index(axis=1)
        label = RunFolder(mine["run_dir"].iloc[0]).meta().get("labels", {}).get("label")
        paper = dict(zip(PAPER_DENSITIES, PAPER_SUCCESS.get(str(label), ()), strict=False))
        for density, column in success_SD.items():
            x = column.dropna().to_numpy(float)
            lo, hi = inference.mean_interval(x)
            rows.append(
                {
                    "policy": policy,
                    "density": float(density),
                    "seeds": x.size,
                    "mean": x.mean(),
                    "lo": lo,
                    "hi": hi,
                    "paper": paper.get(float(density), np.nan),
                }
            )
    columns = ["policy", "density", "seeds", "mean", "lo", "hi", "paper"]
    return pd.DataFrame(rows, columns=columns)


def looks_frame(result: Looks) -> pd.DataFrame:
    """One row per (look, comparison): ``tables/looks.csv``."""
    rows = [
        {
            "look": look.k,
            **dataclasses.asdict(c),
            "level_spent": look.level_spent[c.family],
            "needed": look.needed.get(c.family, np.nan),
        }
        for look in result.looks
        for c in look.comparisons
    ]
    fields = [f.name for f in dataclasses.fields(ComparisonLook)]
    columns = ["look", *fields, "level_spent", "needed"]
    return pd.DataFrame(rows, columns=columns).astype({"decided_at": "Int64"})


def figure(exp: Any, scores: pd.DataFrame) -> Any:
    """Per-seed endpoint of every row (dots: filled = this experiment's cells, open = the
    prior grid's, square = training resumed after a session ended), the row mean (bar)
    with its 95 % t interval, and where Pr-IQN* would sit if the paper's difference to each
    baseline held (diamonds on the compared row)."""
    from priqn.analysis.figures import legend_above, plt, seed_dot_handles, seed_dots

    seq = exp.sequential
    policies = [p.name for p in exp.policies]
    fig, ax = plt.subplots(figsize=(7.5, 0.55 * len(policies) + 1.6))
    means = {}
    any_resumed = False
    for i, policy in enumerate(policies):
        mine = scores[scores["policy"] == policy]
        x = mine["score"].to_numpy(float)
        prior = mine["seed"].isin(seq.prior_seeds).to_numpy()
        resumed = np.array([resumed_before(d) for d in mine["run_dir"]], dtype=bool)
        seed_dots(ax, x, i, "tab:blue", prior, resumed)
        any_resumed |= bool(resumed.any())
        if len(x):
            means[policy] = float(x.mean())
            ax.plot([x.mean()] * 2, [i - 0.3, i + 0.3], color="black", lw=1.8)
        if len(x) >= 2:
            ax.plot(inference.mean_interval(x), [i + 0.32] * 2, color="black", lw=0.9)
    diamonds = sorted(
        (means[c.b] + c.paper_difference, policies.index(c.a), c.b)
        for c in seq.comparisons
        if c.paper_difference is not None and c.b in means
    )
    for x, row, baseline in diamonds:
        ax.plot(x, row - 0.38, "D", mfc="none", mec="tab:red", ms=6)
        # A row's leftmost label sits to its left, the others to their right: no overlap.
        first = min(d[0] for d in diamonds if d[1] == row) == x
        ax.annotate(
            f"vs {baseline}",
            (x, row - 0.38),
            xytext=(-6, 0) if first else (6, 0),
            textcoords="offset points",
            ha="right" if first else "left",
            va="center",
            fontsize=6,
            color="tab:red",
        )
    # The legend names the row the diamonds stand for (each comparison's first row).
    rows_with_diamonds = sorted({policies[row] for _, row, _ in diamonds})
    diamond_rows = rows_with_diamonds[0] if len(rows_with_diamonds) == 1 else "each row"
    counts = scores.groupby("policy")["seed"].nunique()
    ax.set_yticks(
        range(len(policies)), [f"{p} ({int(counts.get(p, 0))} seeds)" for p in policies], fontsize=8
    )
    ax.set_ylim(len(policies) - 0.5, -0.7)
    ax.set_xlim(0, 1)
    ax.grid(axis="x", color="0.9")
    ax.set_xlabel("hold-out success rate, mean over densities (one dot per training seed)")
    handles = [
        *seed_dot_handles("tab:blue", reused=True, resumed=any_resumed),
        plt.Line2D([], [], color="black", lw=1.8, label="mean; thin: 95 % t interval"),
        plt.Line2D(
            [],
            [],
            ls="",
            marker="D",
            mfc="none",
            mec="tab:red",
            label=f"where {diamond_rows} would sit at the paper's difference",
        ),
    ]
    legend_above(ax, handles, f"{exp.experiment.name}: per-seed success of each row", ncol=2)
    return fig


def _needed(x: float) -> str:
    """A look's boundary in points, or why the look could not reject."""
    return "none possible (too few splits)" if not np.isfinite(x) else f"{100 * x:.1f} points"


def _density_lines(frame: pd.DataFrame, steps: int | None) -> list[str]:
    """The report's per-density section (descriptive) from :func:`density_frame`; ``steps``:
    the cells' training decisions (the paper's values come from the paper preset's)."""
    if frame.empty:
        return []
    densities = sorted(frame["density"].unique())
    lines = [
        "## Per density (descriptive)",
        "",
        "Hold-out success by traffic density, mean [95 % t interval] over each row's "
        "committed seeds, with the paper's Table II value where the row is one of its rows "
        f"(trained for {PAPER_TRAINING_DECISIONS:,} decisions; these cells for "
        f"{f'{steps:,}' if steps else 'their preset'}). The decisions above use the mean over "
        "densities only.",
        "",
    ]
    table = []
    for policy, rows in frame.groupby("policy", sort=False):
        cells = [str(policy), str(int(rows["seeds"].iloc[0]))]
        for r in rows.sort_values("density").itertuples():
            text = f"{r.mean:.3f} [{r.lo:.3f}, {r.hi:.3f}]"
            if np.isfinite(r.paper):
                text += f" (paper {r.paper:.3f})"
            cells.append(text)
        table.append(cells)
    heads = ["row", "seeds", *(f"density {d:g}" for d in densities)]
    return [*lines, *markdown_table(heads, table, "lr" + "l" * len(densities)).split("\n"), ""]


def _curves_lines(has_curves: bool) -> list[str]:
    """The report's sample-efficiency section (descriptive)."""
    if not has_curves:
        return []
    return [
        "## Sample efficiency (descriptive)",
        "",
        "Hold-out success against training decisions, per row: the mean over the row's "
        "counted seeds with a 95 % percentile stratified-bootstrap interval over seeds "
        f"(`np.random.seed({CURVE_SEED})` before each point's rliable call, {CURVE_REPS} "
        "replications). The line and band are the in-training evaluations (a few hold-out "
        "episodes per seed, the legend says how many; from `metrics.csv`); the markers with error "
        "bars are the full hold-out evaluations (`eval/` of the final policy and "
        "`eval-at<N>/` of kept snapshots; a seed's success averaged over the densities, "
        "the endpoint above). Two estimators of different precision: never read one "
        "against the other. Numbers: `tables/sample_efficiency.csv`.",
        "",
        "![sample efficiency](figures/sample_efficiency.png) "
        "([pdf](figures/sample_efficiency.pdf))",
        "",
    ]


def _design_lines(exp: Any, command: str) -> list[str]:
    """The title, what made the report, and the pre-registered design in five bullets."""
    seq, e = exp.sequential, exp.experiment
    return [
        f"# {e.name}: pre-registered sequential experiment",
        "",
        f"Made by `{command}` from the cells' run folders and the design in `{exp.path.name}` "
        "(committed before any of its own cells trained).",
        "",
        f"- **Question**: {e.description}",
        f"- **Endpoint**: per training seed, hold-out success rate averaged over the densities "
        f"{exp.evaluate.get('densities')}.",
        f"- **Method**: {seq.method} with a two-sided boundary (docs/statistics.md), looks at "
        f"{list(seq.interims)} seeds per row (n = {seq.seeds_per_look} new seeds a look), "
        f"α = {seq.alpha:g} per family (spent linearly over the looks), β = {seq.beta:g}, "
        f"{seq.permutations} permutations, seed {seq.seed}.",
        f"- **Seeds**: {list(seq.prior_seeds)} from `{seq.prior_runs}`, the rest from "
        f"`{relative_path(exp.runs_dir)}`; code commits allowed: "
        f"{', '.join(c[:12] for c in seq.code_commits) or 'any'}.",
        f"- **Budget**: {e.steps} decisions per cell ({e.preset} preset); every verdict holds "
        "at this budget only.",
        "",
    ]


def _verdict_lines(exp: Any, scores: pd.DataFrame, result: Looks) -> list[str]:
    """The "Verdicts" section: one row per comparison at the last look, and how to read it."""
    counts = scores.groupby("policy")["seed"].nunique()
    last = result.looks[-1] if result.looks else None
    lines = [
        "## Verdicts" if result.finished else "## Verdicts so far",
        "",
        "| comparison | family | paper | estimate [95% CI], points | seeds | AdaStop | verdict |",
        "|:--|:--|--:|:--|:--|:--|:--|",
    ]
    for c in exp.sequential.comparisons:
        row = None if last is None else next(x for x in last.comparisons if x.name == c.name)
        paper = points(c.paper_difference)
        if row is None:
            est, seeds = "no look yet", f"{int(counts.get(c.a, 0))} vs {int(counts.get(c.b, 0))}"
        else:
            est = points_interval(row.diff, row.lo, row.hi)
            seeds = f"{row.n_a} vs {row.n_b}"
        decided = result.decisions[c.name]
        if row is not None and row.decided_at:
            decided += f" (look {row.decided_at})"
        lines.append(
            f"| {c.name} | {c.family} | {paper} | {est} | {seeds} | {decided} | "
            f"**{row_verdict(exp.sequential, result, c)}** |"
        )
    return [
        *lines,
        "",
        "Intervals are Welch t 95 % over training seeds, descriptive (not adjusted for the "
        "looks); the decisions are AdaStop's, which control each family's error over all "
        "looks, so an interval can exclude 0 where AdaStop finds no difference: the verdict "
        "is AdaStop's. *paper's effect ruled out* needs a comparison left undecided at the "
        "last look and a one-sided Welch bound at α / m below the paper's difference.",
        "",
        "![per-seed success](figures/headline.png) ([pdf](figures/headline.pdf))",
        "",
    ]


def _looks_lines(exp: Any, scores: pd.DataFrame, result: Looks) -> list[str]:
    """The "Looks" section: per look, the seeds, the α spent and each comparison's decision."""
    lines = ["## Looks", ""]
    if result.looks:
        lines += [
            "Each comparison look by look: a dot outside its look's grey band is decided "
            "there (the band is ± the |difference| it needed).",
            "",
            "![each comparison look by look](figures/looks.png) ([pdf](figures/looks.pdf))",
            "",
        ]
    if not result.looks:
        counts = scores.groupby("policy")["seed"].nunique()
        policies = [p.name for p in exp.policies]
        lines += [
            f"No look yet: the first needs {exp.sequential.interims[0]} seeds of every row "
            f"({', '.join(f'{p}: {int(counts.get(p, 0))}' for p in policies)}).",
            "",
        ]
    for look in result.looks:
        spent = ", ".join(f"{f} {v:.4f}" for f, v in look.level_spent.items())
        needed = ", ".join(f"{f} {_needed(v)}" for f, v in look.needed.items())
        lines += [
            f"**Look {look.k}** — seeds per row: "
            + ", ".join(f"{p} {n}" for p, n in look.seeds_per_row.items())
            + f"; α spent: {spent}"
            + (
                f"; |difference| an open comparison needed to be decided: {needed}."
                if needed
                else "."
            ),
            "",
            "| comparison | estimate [95% CI], points | decision |",
            "|:--|:--|:--|",
            *[
                f"| {c.name} | {points_interval(c.diff, c.lo, c.hi)} | {c.decision} |"
                for c in look.comparisons
            ],
            "",
        ]
    return lines


def _next_lines(exp: Any, scores: pd.DataFrame, result: Looks) -> list[str]:
    """The "Next" section: finished, or the cells the next look needs."""
    nxt = questions.cells_needed(exp, exp.sequential, scores, result)
    return [
        "## Next",
        "",
        "The design is finished: every comparison is decided or the last look is taken."
        if result.finished
        else f"Look {result.next_look} needs {len(nxt)} more cell(s): "
        + ", ".join(cell_dir_name(p, s) for p, s in nxt)
        + f" (`priqn sweep {exp.experiment.name} --code <frozen worktree>`).",
        "",
    ]


def _cells_lines(scores: pd.DataFrame, has_curves: bool) -> list[str]:
    """The report's "Cells" section (every counted cell) and its list of files."""
    return [
        "## Cells",
        "",
        "| row | seed | success (endpoint) | episodes | commit | resumed at | run folder |",
        "|:--|--:|--:|--:|:--|:--|:--|",
        *[
            f"| {r.policy} | {r.seed} | {r.score:.3f} | {r.episodes} | `{r.git_sha[:12]}` | "
            f"{resumed_text(r.run_dir)} | `{r.run_dir}` |"
            for r in scores.sort_values(["policy", "seed"], kind="mergesort").itertuples()
        ],
        "",
        RESUMED_NOTE,
        "",
        "Files: `tables/scores.csv`, `tables/looks.csv`, `tables/density.csv`, "
        + (
            "`tables/sample_efficiency.csv`, `figures/sample_efficiency.{png,pdf}`, "
            if has_curves
            else ""
        )
        + "`figures/headline.{png,pdf}`, "
        "`figures/looks.{png,pdf}` (from the first look on), `meta.json`.",
        "",
    ]


def sequential_report(exp: Any, command: str) -> Report:
    """The sequential experiment's report (kind ``sequential``); ``command``: the one that
    regenerates it. Deterministic: the same committed cells give byte-identical files."""
    scores, result = questions.take_looks(exp, exp.sequential)
    scores = scores[list(SCORE_COLUMNS)]
    group = {p.name: p.group_name for p in exp.policies}
    cells = [(group[r.policy], int(r.seed), Path(r.run_dir)) for r in scores.itertuples()]
    agents = {p.group_name: p.agent for p in exp.policies}
    efficiency = curves.efficiency(cells, agents, CURVE_REPS, CURVE_SEED)
    monitoring = looks_figure(
        [(exp.sequential, result)], f"{exp.experiment.name}: each comparison look by look"
    )
    curve = (
        Section(
            _curves_lines(True),
            tables={"sample_efficiency": efficiency.curve},
            figures={"sample_efficiency": efficiency_figure(efficiency.curve, efficiency.agents)},
        )
        if efficiency.drawn
        else Section([])
    )
    sections = [
        Section(_design_lines(exp, command)),
        Section(_verdict_lines(exp, scores, result), figures={"headline": figure(exp, scores)}),
        Section(
            _looks_lines(exp, scores, result),
            tables={"looks": looks_frame(result)},
            figures={} if monitoring is None else {"looks": monitoring},
        ),
        Section(
            _density_lines(density := density_frame(exp, scores), exp.experiment.steps),
            tables={"density": density},
        ),
        curve,
        Section(_next_lines(exp, scores, result)),
        Section(_cells_lines(scores, efficiency.drawn), tables={"scores": scores}),
    ]
    fields = {
        "looks": len(result.looks),
        "decisions": result.decisions,
        "verdicts": {
            c.name: row_verdict(exp.sequential, result, c) for c in exp.sequential.comparisons
        },
        "finished": result.finished,
        "cells": len(scores),
    }
    if efficiency.drawn:
        fields["curves"] = {"seed": CURVE_SEED, "reps": CURVE_REPS, "notes": efficiency.notes}
    return Report("sequential", "report.md", sections, command, exp.experiment.name, fields)
