"""The report of an experiment with ``[[question]]`` designs (kind ``questions``,
``priqn report results/explain``).

Per question: its design, the looks taken, each comparison's estimate, Welch interval,
minimum detectable difference and verdict words (:mod:`priqn.analysis.questions`); across
questions, each group's endpoints at every budget its cells reach, and the change of a
difference between budgets over the same seeds; then the descriptive sections of how the
counted cells' episodes end (:mod:`priqn.analysis.questions_outcomes`) and the
sample-efficiency curves (:func:`priqn.analysis.curves.efficiency`). Built as sections
(:func:`questions_report`, rendered by :func:`priqn.analysis.artifacts.render`); deterministic: the same committed cells
give byte-identical files (tables, figures, ``report.md``, ``meta.json``).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from priqn.agents.labels import budget_text, seeds_text
from priqn.analysis import curves, inference, questions
from priqn.analysis.curves import CURVE_REPS, CURVE_SEED
from priqn.analysis.figures import efficiency_figure, looks_figure
from priqn.analysis.load import RESUMED_NOTE, commit_text, resumed_before, resumed_text
from priqn.analysis.questions_outcomes import outcome_sections
from priqn.analysis.render import interval, markdown_table, points
from priqn.analysis.sections import Report, Section
from priqn.analysis.sequential import Looks, row_verdict
from priqn.experiment import Experiment, SequentialSpec
from priqn.run.evaluations import evaluated, evaluation_dir, kept_evaluations, recorded_eval_status
from priqn.run.folder import RunFolder, Status

ENDPOINT_TEXT = {
    "success": "hold-out success rate",
    "violation": "safety-violation rate (collision or off-road)",
}
"""How the report names each endpoint."""


def budgets_of(exp: Experiment, group: str) -> list[int]:
    """Every budget some row of ``group`` reaches (its steps and kept snapshots), ascending."""
    found: set[int] = set()
    for pol in exp.group(group):
        steps = exp.row_steps(pol)
        found.update([*pol.keep_at, *([steps] if steps else [])])
    return sorted(found)


def budget_frame(exp: Experiment, question: SequentialSpec) -> pd.DataFrame:
    """Per (group, budget, training seed) of ``question``'s seeds: every outcome rate where
    the cell's evaluation at that budget is complete. Columns: group, budget, train_seed,
    one per :data:`questions.OUTCOME_RATES` (success, violation, timeout, collision,
    off_road), episodes."""
    rows = []
    for group in questions.rows_of(exp, question):
        for budget in budgets_of(exp, group):
            for seed in question.seeds:
                where = exp.cell_at(group, seed, budget)
                if where is None:
                    continue
                folder = RunFolder(where[1])
                if recorded_eval_status(folder, where[2]) != Status.COMPLETE:
                    continue
                rates, n = questions.outcome_rates(evaluation_dir(folder, where[2]))
                rows.append((group, budget, seed, *rates.values(), n))
    columns = ["group", "budget", "train_seed", *questions.OUTCOME_RATES, "episodes"]
    return pd.DataFrame(rows, columns=columns)


def change_frame(frame: pd.DataFrame, a: str, b: str, endpoint: str) -> pd.DataFrame:
    """How ``a − b`` on ``endpoint`` changes from the smallest budget to each larger one,
    over the seeds complete at both budgets for both groups: per seed the change of each
    group's score, then mean(Δa) − mean(Δb) with its Welch 95 % interval (descriptive)."""
    rows = []
    budgets = sorted(set(frame["budget"]))
    if not budgets:
        return pd.DataFrame(columns=["from", "to", "seeds", "change", "lo", "hi"])
    base = budgets[0]
    for budget in budgets[1:]:
        deltas = []
        for group in (a, b):
            mine = frame[frame["group"] == group].pivot_table(
                index="train_seed", columns="budget", values=endpoint
            )
            if base not in mine or budget not in mine:
                deltas.append(np.array([]))
                continue
            deltas.append((mine[budget] - mine[base]).dropna().to_numpy(float))
        n = min(d.size for d in deltas)
        if n < 2:
            continue
        lo, hi = inference.welch_interval(deltas[0], deltas[1])
        change = float(deltas[0].mean() - deltas[1].mean())
        rows.append((base, budget, n, change, lo, hi))
    return pd.DataFrame(rows, columns=["from", "to", "seeds", "change", "lo", "hi"])


def difference_frame(frame: pd.DataFrame, a: str, b: str, endpoint: str) -> pd.DataFrame:
    """``a − b`` on ``endpoint`` at each budget both groups reach, over the seeds complete
    there for each: mean(a) − mean(b) with its Welch 95 % interval (descriptive; budgets
    where a group has fewer than 2 seeds are left out)."""
    rows = []
    for budget in sorted(set(frame["budget"])):
        at = frame[frame["budget"] == budget]
        a_S, b_S = (at.loc[at["group"] == g, endpoint].to_numpy(float) for g in (a, b))
        if min(a_S.size, b_S.size) < 2:
            continue
        lo, hi = inference.welch_interval(a_S, b_S)
        rows.append((budget, a_S.size, b_S.size, float(a_S.mean() - b_S.mean()), lo, hi))
    return pd.DataFrame(rows, columns=["budget", "seeds_a", "seeds_b", "difference", "lo", "hi"])


def _comparison_rows(
    exp: Experiment, question: SequentialSpec, scores: pd.DataFrame, result: Looks
) -> list[dict[str, Any]]:
    """One dict per comparison: seeds, estimate, interval, MDD, decision, verdict."""
    out = []
    for c in question.comparisons:
        a = scores[scores["policy"] == c.a]["score"].to_numpy(float)
        b = scores[scores["policy"] == c.b]["score"].to_numpy(float)
        last = (
            next((x for x in result.looks[-1].comparisons if x.name == c.name), None)
            if result.looks
            else None
        )
        n_a, n_b = (last.n_a, last.n_b) if last else (a.size, b.size)
        a, b = a[:n_a], b[:n_b]
        enough = a.size >= 2 and b.size >= 2
        lo, hi = inference.welch_interval(a, b) if enough else (math.nan, math.nan)
        out.append(
            {
                "question": question.name,
                "comparison": c.name,
                "endpoint": question.endpoint,
                "budget": question.budget,
                "a": c.a,
                "b": c.b,
                "seeds_a": int(a.size),
                "seeds_b": int(b.size),
                "difference": float(a.mean() - b.mean()) if a.size and b.size else math.nan,
                "lo": lo,
                "hi": hi,
                "mdd": inference.min_detectable_difference(a, b, question.alpha)
                if enough
                else math.inf,
                "paper_difference": c.paper_difference,
                "decision": result.decisions[c.name],
                "looks": len(result.looks),
                "verdict": row_verdict(question, result, c),
            }
        )
    return out


def figure(exp: Experiment, scores_by_question: dict[str, pd.DataFrame]) -> Any:
    """One panel per question: each group's per-seed endpoint (dots in the group's colour
    of the sample-efficiency figure, :func:`priqn.analysis.figures.seed_dots`: open for a
    prior grid's cell, square where the training resumed before the question's budget),
    its mean (bar) and 95 % t interval (thin line), at the question's budget."""
    from priqn.analysis.figures import plt, row_colors, seed_dots

    colors = row_colors(list(dict.fromkeys(p.group_name for p in exp.policies)))
    own = Path(exp.runs_dir).resolve()
    names = [q.name for q in exp.designs]
    fig, axes = plt.subplots(len(names), 1, figsize=(7.5, 1.45 * len(names) + 0.6), squeeze=False)
    for ax, q in zip(axes[:, 0], exp.designs, strict=True):
        scores = scores_by_question[q.name]
        groups = questions.rows_of(exp, q)
        for i, group in enumerate(groups):
            mine = scores[scores["policy"] == group]
            x = mine["score"].to_numpy(float)
            dirs = [Path(d) for d in mine["run_dir"]]
            reused = np.array([not d.resolve().is_relative_to(own) for d in dirs], dtype=bool)
            resumed = np.array([resumed_before(d, q.budget) for d in dirs], dtype=bool)
            seed_dots(ax, x, i, colors[group], reused, resumed)
            if x.size:
                ax.plot([x.mean()] * 2, [i - 0.3, i + 0.3], color="black", lw=1.8)
            if x.size >= 2:
                ax.plot(inference.mean_interval(x), [i + 0.32] * 2, color="black", lw=0.9)
        counts = scores.groupby("policy")["seed"].nunique()
        ax.set_yticks(
            range(len(groups)),
            [f"{g} ({int(counts.get(g, 0))} seeds)" for g in groups],
            fontsize=7,
        )
        ax.set_ylim(len(groups) - 0.5, -0.6)
        ax.set_xlim(0, 1)
        ax.grid(axis="x", color="0.9")
        ax.set_title(
            f"{q.name}: {ENDPOINT_TEXT[q.endpoint]} at {budget_text(q.budget)} decisions",
            fontsize=8,
            loc="left",
        )
    axes[-1, 0].set_xlabel(
        "per training seed, mean over densities (dot: seed; open: a prior grid's cell; square: "
        "its training resumed before this budget;\nbar: mean; thin: 95 % t interval)",
        fontsize=7,
    )
    fig.tight_layout()
    return fig


def _cells_lines(scores: pd.DataFrame) -> list[str]:
    """The "Cells" section: every cell a question counts, once, with the evaluations it
    is counted by, its commit and where its training resumed."""
    if scores.empty:
        return []
    lines = [
        "## Cells",
        "",
        "| run folder | train seed | commit | counted by (question: evaluation) | resumed at |",
        "|:--|--:|:--|:--|:--|",
    ]
    ordered = scores.sort_values(["policy", "train_seed"], kind="mergesort")
    for run_dir, part in ordered.groupby("run_dir", sort=False):
        counted = ", ".join(
            f"{q}: {'eval' if not isinstance(ev, str) or not ev else f'eval-{ev}'}/"
            for q, ev in part[["question", "evaluation"]].itertuples(index=False)
        )
        first = part.iloc[0]
        lines.append(
            f"| `{run_dir}` | {int(first.train_seed)} | {commit_text(run_dir)} | "
            f"{counted} | {resumed_text(run_dir)} |"
        )
    return [*lines, "", RESUMED_NOTE, ""]


def _verdict_lines(comparisons: pd.DataFrame) -> list[str]:
    """The "Verdicts" section: one row per comparison (``comparisons.csv``), and its key."""
    heads = ["question", "comparison", "budget", "seeds (a / b)", "a − b [points]",
             "Welch 95 %", "MDD", "paper", "looks", "verdict"]  # fmt: skip
    rows = []
    for r in comparisons.itertuples():
        mdd = "∞" if math.isinf(r.mdd) else f"±{100 * r.mdd:.1f}"
        rows.append([
            str(r.question), str(r.comparison), budget_text(r.budget), f"{r.seeds_a} / {r.seeds_b}",
            points(r.difference), interval(r.lo, r.hi), mdd, points(r.paper_difference), str(r.looks),
            f"**{r.verdict}**",
        ])  # fmt: skip
    return [
        "## Verdicts",
        "",
        *markdown_table(heads, rows).split("\n"),
        "",
        "Points: percentage points of the endpoint (success rate, or violation rate where "
        "the question's endpoint is violations: there a positive difference means a violates "
        "more). Welch intervals are descriptive (not adjusted for the looks); the verdict is "
        "the design's (AdaStop with a two-sided boundary, docs/statistics.md). MDD: the "
        "smallest |difference| a fixed two-sided Welch test at the question's α would see "
        "with 80 % power at the seeds reached and their spread.",
        "",
    ]


def _question_lines(exp: Experiment, looks: pd.DataFrame) -> list[str]:
    """The "Questions" section: each question's pre-registered design and looks taken."""
    lines = ["## Questions", ""]
    for q in exp.designs:
        mine = looks[looks["question"] == q.name]
        lines += [
            f"### {q.name}",
            "",
            f"- **Question**: {q.question}",
            f"- **Endpoint**: per training seed, {ENDPOINT_TEXT[q.endpoint]} on the hold-out "
            f"episodes, averaged over the densities {exp.evaluate.get('densities')}.",
            f"- **Budget**: {q.budget} decisions per cell ({exp.experiment.preset} preset).",
            f"- **Seeds** in look order: {list(q.seeds)}; looks at {list(q.interims)}; "
            f"α = {q.alpha:g} (two-sided), β = {q.beta:g}, {q.permutations} permutations, "
            f"seed {q.seed}; commits allowed: {', '.join(c[:12] for c in q.code_commits) or 'any'}.",
            f"- **Looks taken**: {len(mine['look'].unique()) if len(mine) else 0}.",
            "",
            *_look_table(mine),
        ]
    if len(looks):
        lines += [
            "Each comparison look by look: a dot outside its look's grey band is decided "
            "there (the band is ± the |difference| it needed).",
            "",
            "![each comparison look by look](figures/looks.png)",
            "",
        ]
    return lines


def _look_table(looks: pd.DataFrame) -> list[str]:
    """One question's looks taken (its rows of ``tables/looks.csv``) as a table: seeds,
    estimate, Welch interval, the |difference| the look needed and AdaStop's decision."""
    if not len(looks):
        return []
    rows = [
        [str(int(r.look)), r.comparison, f"{r.seeds_a} vs {r.seeds_b}", points(r.difference),
         interval(r.lo, r.hi), _needed_pts(r.needed), r.decision]
        for r in looks.itertuples(index=False)
    ]  # fmt: skip
    heads = ["look", "comparison", "seeds", "difference [points]", "Welch 95 %", "needed",
             "decision"]  # fmt: skip
    return [*markdown_table(heads, rows).split("\n"), ""]


def _needed_pts(needed: float) -> str:
    """The |difference| a look needed, in points (∞: too few splits to decide; –: the
    family was finished at an earlier look)."""
    if math.isnan(needed):
        return "–"
    return "∞" if math.isinf(needed) else f"{100 * needed:.1f}"


def _budget_lines(budgets: pd.DataFrame) -> list[str]:
    """Each group's endpoints at every budget its cells reach (none: no lines)."""
    if not len(budgets):
        return []
    lines = [
        "## Every budget the cells reach (descriptive)",
        "",
        "Mean over the seeds complete at that budget, among the seeds of every question "
        "whose groups reach more than one budget. Every episode ends in one outcome, so "
        "success, violations (collision or off-road) and timeouts sum to 1; the figure "
        "below draws them per group, n training seeds under each bar.",
        "",
    ]
    summary = budgets.groupby(["group", "budget"]).agg(
        seeds=("train_seed", lambda s: f"{s.nunique()} ({seeds_text(s)})"),
        success=("success", "mean"),
        violation=("violation", "mean"),
        timeout=("timeout", "mean"),
    )
    rows = [
        [str(group), budget_text(budget), r.seeds, f"{r.success:.3f}", f"{r.violation:.3f}",
         f"{r.timeout:.3f}"]
        for (group, budget), r in summary.iterrows()
    ]  # fmt: skip
    heads = ["group", "budget", "training seeds", "success", "violations", "timeouts"]
    lines += markdown_table(heads, rows).split("\n")
    return [
        *lines,
        "",
        "![outcomes by budget](figures/outcomes_by_budget.png)",
        "",
        "Each training seed at every budget it reaches, one line per seed (a seed that waits "
        "shows as a high timeout line):",
        "",
        "![each seed by budget](figures/budget_seeds.png)",
        "",
    ]


SEED_ENDPOINTS = {"success": "success", "violation": "violations", "timeout": "timeouts"}
"""The per-seed budget figure's rows: outcome-rate column -> its label."""


def budget_seeds_figure(budgets: pd.DataFrame) -> Any:
    """Each training seed's success, violations and timeouts at every budget its cells
    reach: one column of panels per group, one row per endpoint, one line per seed (its
    number at its right end), the group's mean over those seeds dashed."""
    import matplotlib.pyplot as plt

    groups = sorted(set(budgets["group"]))
    xs = sorted(set(budgets["budget"]))
    fig, axes = plt.subplots(
        len(SEED_ENDPOINTS), len(groups), figsize=(3.6 * len(groups), 7.2),
        sharex=True, sharey=True, squeeze=False,
    )  # fmt: skip
    for col, group in enumerate(groups):
        mine = budgets[budgets["group"] == group]
        for row, (column, label) in enumerate(SEED_ENDPOINTS.items()):
            ax = axes[row][col]
            for seed, seed_rows in mine.groupby("train_seed"):
                seed_rows = seed_rows.sort_values("budget")
                pos = [xs.index(b) for b in seed_rows["budget"]]
                ax.plot(pos, seed_rows[column], marker="o", ms=3, lw=1, alpha=0.7)
                ax.annotate(str(seed), (pos[-1], seed_rows[column].iloc[-1]), fontsize=6,
                            xytext=(3, 0), textcoords="offset points", va="center")  # fmt: skip
            means = mine.groupby("budget")[column].mean()
            ax.plot([xs.index(b) for b in means.index], means, "k--", lw=1.5, label="mean")
            ax.set_ylim(-0.02, 1.02)
            ax.grid(alpha=0.3)
            if row == 0:
                ax.set_title(group, fontsize=9)
            if col == 0:
                ax.set_ylabel(f"{label} (share of episodes)", fontsize=8)
            if row == len(SEED_ENDPOINTS) - 1:
                ax.set_xticks(range(len(xs)), [budget_text(b) for b in xs], fontsize=8)
                ax.set_xlabel("decisions trained", fontsize=8)
    axes[0][0].legend(fontsize=7, loc="best")
    fig.suptitle("Each training seed by budget (descriptive)", fontsize=10)
    fig.tight_layout()
    return fig


def budget_outcomes_figure(budgets: pd.DataFrame) -> Any:
    """How each group's episodes end at every budget its cells reach: one panel per group,
    one stacked bar per budget (means over the seeds complete there, as the table; the
    number of training seeds under each bar, n)."""
    from priqn.analysis.figures import outcomes_figure

    by = budgets.groupby(["group", "budget"])
    means = by[list(questions.OUTCOME_RATES)].mean().join(by["train_seed"].nunique())
    means = means.reset_index().sort_values(["budget", "group"])
    means = means.assign(label=means["group"], budget=[budget_text(b) for b in means["budget"]])
    groups = sorted(set(means["group"]))
    fig = outcomes_figure(means, groups, by="budget")
    for ax, group in zip(fig.axes, groups, strict=False):
        seeds = means[means["group"] == group].set_index("budget")["train_seed"]
        ticks = [t.get_text() for t in ax.get_xticklabels()]
        ax.set_xticks(
            range(len(ticks)),
            [f"{t}\nn = {seeds[t]}" if t in seeds else t for t in ticks],
            rotation=0,
            fontsize=7,
        )
    return fig


def _difference_lines(differences: pd.DataFrame) -> list[str]:
    """Each difference at every budget both its groups reach, once per pair of groups (the
    comparisons that compare them named beside it); none: no lines."""
    if not len(differences):
        return []
    rows = [
        [f"{r['a']} − {r['b']}", str(r["endpoint"]), budget_text(r["budget"]),
         f"{r['seeds_a']} / {r['seeds_b']}", points(r["difference"]),
         interval(r["lo"], r["hi"]), str(r["comparisons"])]
        for r in differences.to_dict("records")
    ]  # fmt: skip
    heads = ["a − b", "endpoint", "budget", "seeds (a / b)", "difference [points]",
             "Welch 95 %", "comparisons"]  # fmt: skip
    return [
        "## The difference at every budget (descriptive)",
        "",
        "At each budget both groups reach, over the seeds complete there: mean(a) − mean(b) "
        "of the endpoint with its Welch 95 % interval. Only the question's own budget has "
        "a verdict (above); these numbers decide nothing.",
        "",
        *markdown_table(heads, rows).split("\n"),
        "",
    ]


def _change_lines(changes: pd.DataFrame) -> list[str]:
    """How each difference changes between budgets over the same seeds, once per pair of
    groups (the comparisons that compare them named beside it); none: no lines."""
    if not len(changes):
        return []
    lines = [
        "## Change of the difference with the budget (descriptive)",
        "",
        "Per seed, each group's change of the endpoint from the smaller budget; then the "
        "difference of the mean changes (a − b) with its Welch 95 % interval.",
        "",
    ]
    rows = [
        [f"{r['a']} − {r['b']}", str(r["endpoint"]), budget_text(r["from"]),
         budget_text(r["to"]), str(r["seeds"]), points(r["change"]),
         interval(r["lo"], r["hi"]), str(r["comparisons"])]
        for r in changes.to_dict("records")
    ]  # fmt: skip
    heads = ["a − b", "endpoint", "from", "to", "seeds", "change [points]", "Welch 95 %",
             "comparisons"]  # fmt: skip
    return [*lines, *markdown_table(heads, rows).split("\n"), ""]


LOOK_COLUMNS = [
    "question",
    "look",
    "comparison",
    "seeds_a",
    "seeds_b",
    "difference",
    "lo",
    "hi",
    "decision",
    "alpha_spent",
    "needed",
]
"""Columns of ``tables/looks.csv``: one row per question, look and comparison (``lo``,
``hi``: the look's Welch 95 % interval, descriptive)."""


def _look_rows(question: SequentialSpec, result: Looks) -> list[dict[str, Any]]:
    """One ``tables/looks.csv`` row per look and comparison of ``question``."""
    return [
        {
            "question": question.name,
            "look": look.k,
            "comparison": c.name,
            "seeds_a": c.n_a,
            "seeds_b": c.n_b,
            "difference": c.diff,
            "lo": c.lo,
            "hi": c.hi,
            "decision": c.decision,
            "alpha_spent": look.level_spent.get(c.family),
            "needed": look.needed.get(c.family, math.nan),
        }
        for look in result.looks
        for c in look.comparisons
    ]


def _budget_tables(
    exp: Experiment, question: SequentialSpec, read: dict[Any, pd.DataFrame]
) -> tuple[pd.DataFrame, list[pd.DataFrame], list[pd.DataFrame]] | None:
    """``question``'s budget frame and its comparisons' change and difference frames
    (:func:`change_frame`, :func:`difference_frame`), when one of its groups reaches more
    than one budget (else None). ``read``: the budget frames read so far, by groups and
    seeds (questions that share both share the frame: its cells are read once)."""
    groups = questions.rows_of(exp, question)
    if not any(len(budgets_of(exp, g)) > 1 for g in groups):
        return None
    key = (tuple(groups), tuple(question.seeds))
    if key not in read:
        read[key] = budget_frame(exp, question)
    frame = read[key]

    def per_comparison(tabulate: Any) -> list[pd.DataFrame]:
        return [
            tabulate(frame, c.a, c.b, endpoint).assign(
                comparison=c.name, endpoint=endpoint, a=c.a, b=c.b
            )
            for c in question.comparisons
            for endpoint in questions.ENDPOINT_FLAGS
        ]

    changes, differences = per_comparison(change_frame), per_comparison(difference_frame)
    return frame.assign(question=question.name), changes, differences


def _efficiency_lines(efficiency: curves.Efficiency) -> list[str]:
    """The "Sample efficiency" section of :func:`_efficiency` (none without a curve)."""
    if not efficiency.drawn:
        return []
    notes = efficiency.notes
    return [
        "## Sample efficiency (descriptive)",
        "",
        "Hold-out success against training decisions, one curve per group over its complete "
        "cells: lines are the in-training evaluations (6 episodes a point), markers the full "
        "evaluations (162 episodes) at each budget a cell reaches, kept snapshots included; "
        f"mean over training seeds with a 95 % stratified-bootstrap band "
        f"({efficiency.reps} replications, seed {efficiency.seed}).",
        *([""] + [f"- {n}" for n in notes] if notes else []),
        "",
        "![sample efficiency](figures/sample_efficiency.png)",
        "",
    ]


def _efficiency(exp: Experiment) -> curves.Efficiency:
    """The sample-efficiency curves of every complete cell's group (periodic evaluations
    and full evaluations at each budget, kept snapshots included)."""
    cells = [
        cell
        for cell in curves.experiment_cells(exp)
        if evaluated(folder := RunFolder(cell[2]), kept_evaluations(folder))
    ]
    agents = {p.group_name: p.agent for p in exp.policies}
    return curves.efficiency(cells, agents, CURVE_REPS, CURVE_SEED)


@dataclasses.dataclass(frozen=True)
class DesignTables:
    """Every question's looks taken (:func:`design_tables`), as the report's tables."""

    scores: pd.DataFrame
    """Every question's counted cells (``question`` column): ``tables/scores.csv``."""
    comparisons: pd.DataFrame
    """One row per comparison (:func:`_comparison_rows`): ``tables/comparisons.csv``."""
    looks: pd.DataFrame
    """One row per question, look and comparison: ``tables/looks.csv``."""
    budgets: pd.DataFrame
    """Each group's outcome rates at every budget it reaches: ``tables/budgets.csv``."""
    budget_changes: pd.DataFrame
    """How each difference changes with the budget: ``tables/budget_changes.csv``."""
    budget_differences: pd.DataFrame
    """Each difference at every budget both its groups reach:
    ``tables/budget_differences.csv`` (written only when some group reaches more than one
    budget)."""
    by_question: dict[str, pd.DataFrame]
    """Each question's counted cells."""
    results: list[tuple[SequentialSpec, Looks]]
    """Each question with its looks taken."""

    CSV = ("scores", "comparisons", "looks", "budgets", "budget_changes")
    """The fields written as ``tables/<field>.csv``."""


def design_tables(exp: Experiment) -> DesignTables:
    """Take every question's looks and tabulate them (:class:`DesignTables`)."""
    scores_by_q, comparison_rows, look_rows, budget_frames = {}, [], [], []
    change_frames: list[pd.DataFrame] = []
    difference_frames: list[pd.DataFrame] = []
    results: list[tuple[SequentialSpec, Looks]] = []
    read: dict[Any, pd.DataFrame] = {}
    for q in exp.designs:
        scores, result = questions.take_looks(exp, q)
        scores_by_q[q.name] = scores
        results.append((q, result))
        comparison_rows += _comparison_rows(exp, q, scores, result)
        look_rows += _look_rows(q, result)
        by_budget = _budget_tables(exp, q, read)
        if by_budget is not None:
            budget_frames.append(by_budget[0])
            change_frames += by_budget[1]
            difference_frames += by_budget[2]
    budgets = pd.concat(budget_frames, ignore_index=True) if budget_frames else pd.DataFrame()
    budgets = (
        budgets.drop_duplicates(["group", "budget", "train_seed"]) if len(budgets) else budgets
    )
    change_frames = [f for f in change_frames if len(f)]  # (pandas warns on empty ones)
    changes = pd.concat(change_frames, ignore_index=True) if change_frames else pd.DataFrame()
    if len(changes):
        changes = _name_comparisons(
            changes, ["a", "b", "endpoint", "from", "to", "seeds", "change", "lo", "hi"]
        )
    difference_frames = [f for f in difference_frames if len(f)]
    differences = (
        _name_comparisons(
            pd.concat(difference_frames, ignore_index=True),
            ["a", "b", "endpoint", "budget", "seeds_a", "seeds_b", "difference", "lo", "hi"],
        )
        if difference_frames
        else pd.DataFrame()
    )
    all_scores = pd.concat(
        [s.assign(question=name) for name, s in scores_by_q.items()], ignore_index=True
    )
    comparisons = pd.DataFrame(comparison_rows)
    looks = pd.DataFrame(look_rows, columns=LOOK_COLUMNS)
    return DesignTables(
        all_scores, comparisons, looks, budgets, changes, differences, scores_by_q, results
    )


def _name_comparisons(frame: pd.DataFrame, keys: list[str]) -> pd.DataFrame:
    """One row per distinct ``keys`` (a pair of groups, an endpoint and budgets) with the
    comparisons that compare them joined in ``comparisons``."""
    return (
        frame.groupby(keys, sort=False, dropna=False)["comparison"]
        .agg("; ".join)
        .reset_index()
        .rename(columns={"comparison": "comparisons"})
    )


def questions_report(exp: Experiment, command: str) -> Report:
    """The questions' report (kind ``questions``); ``command``: the one that regenerates it."""
    t = design_tables(exp)
    e = exp.experiment
    monitoring = looks_figure(t.results, f"{e.name}: each comparison look by look")
    efficiency = _efficiency(exp)
    head = Section(
        [
            f"# {e.name}: pre-registered questions",
            "",
            f"Made by `{command}` from the cells' run folders and the design in "
            f"`{exp.path.name}` (committed before any of its own cells trained).",
            "",
            f"{e.description}",
            "",
        ],
        tables={name: getattr(t, name) for name in DesignTables.CSV}
        | ({"budget_differences": t.budget_differences} if len(t.budget_differences) else {}),
    )
    budget_figures = (
        {"outcomes_by_budget": budget_outcomes_figure(t.budgets),
         "budget_seeds": budget_seeds_figure(t.budgets)}
        if len(t.budgets) else {}
    )  # fmt: skip
    sections = [
        head,
        Section(_verdict_lines(t.comparisons)),
        Section(
            _question_lines(exp, t.looks),
            figures={} if monitoring is None else {"looks": monitoring},
        ),
        Section(_budget_lines(t.budgets), figures=budget_figures),
        Section(_difference_lines(t.budget_differences)),
        Section(_change_lines(t.budget_changes)),
        Section(
            ["![per-seed endpoints](figures/questions.png)", ""],
            figures={"questions": figure(exp, t.by_question)},
        ),
        *outcome_sections(exp, t.scores, t.budgets),
        Section(
            _efficiency_lines(efficiency),
            tables={"sample_efficiency": efficiency.curve} if efficiency.drawn else {},
            figures={"sample_efficiency": efficiency_figure(efficiency.curve, efficiency.agents)}
            if efficiency.drawn
            else {},
        ),
        Section(_cells_lines(t.scores)),
    ]
    looks = t.looks
    fields = {
        "verdicts": {r.comparison: r.verdict for r in t.comparisons.itertuples()},
        "looks": {
            q: int(looks.loc[looks["question"] == q, "look"].max() or 0)
            if (looks["question"] == q).any()
            else 0
            for q in t.by_question
        },
        "cells": {q: len(s) for q, s in t.by_question.items()},
    }
    return Report("questions", "report.md", sections, command, e.name, fields)
