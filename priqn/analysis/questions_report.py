"""The report of an experiment with ``[[question]]`` designs (``priqn report results/explain``).

Per question: its design, the looks taken, each comparison's estimate, Welch interval,
minimum detectable difference and verdict words (:mod:`priqn.analysis.questions`); across
questions, each group's endpoints at every budget its cells reach, and the change of a
difference between budgets over the same seeds. Deterministic: the same committed cells
give byte-identical files (tables, figure, ``report.md``, ``meta.json``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from priqn.agents.labels import budget_text, seeds_text
from priqn.analysis import inference, questions, tables
from priqn.analysis.load import (
    RESUMED_NOTE,
    SORT_COLUMNS,
    commit_text,
    read_evaluation,
    resumed_before,
    resumed_text,
)
from priqn.analysis.paper import PAPER_DENSITIES
from priqn.analysis.render import markdown_table, write_csv
from priqn.analysis.sequential import Looks, relative_path, verdict
from priqn.analysis.sequential_report import looks_figure
from priqn.experiment import OUTCOMES, Experiment, SequentialSpec
from priqn.io import atomic_write_text
from priqn.run.episodes import resolve_outcomes
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
                "verdict": verdict(question, result, c),
            }
        )
    return out


def _pts(x: float) -> str:
    return "–" if x is None or math.isnan(x) else f"{100 * x:+.1f}"


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


def report_markdown(
    exp: Experiment,
    comparisons: pd.DataFrame,
    looks: pd.DataFrame,
    budgets: pd.DataFrame,
    changes: pd.DataFrame,
    command: str,
    descriptive: Sequence[str] = (),
    scores: pd.DataFrame | None = None,
) -> str:
    """``report.md`` of an experiment with questions (``descriptive``: the lines of the
    outcome-mix, outcome-by-manoeuvre, Table I and sample-efficiency sections,
    :func:`_mix_lines`, :func:`_manoeuvre_lines`, :func:`_returns_lines` and
    :func:`_efficiency`;
    ``scores``: every question's counted cells,
    ``tables/scores.csv``, for the "Cells" section)."""
    e = exp.experiment
    lines = [
        f"# {e.name}: pre-registered questions",
        "",
        f"Made by `{command}` from the cells' run folders and the design in `{exp.path.name}` "
        "(committed before any of its own cells trained).",
        "",
        f"{e.description}",
        "",
        *_verdict_lines(comparisons),
        *_question_lines(exp, looks),
        *_budget_lines(budgets),
        *_change_lines(changes),
        "![per-seed endpoints](figures/questions.png)",
        "",
        *descriptive,
        *_cells_lines(scores if scores is not None else pd.DataFrame()),
    ]
    return "\n".join(lines)


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
        paper = (
            "–"
            if r.paper_difference is None or pd.isna(r.paper_difference)
            else _pts(r.paper_difference)
        )
        rows.append([
            str(r.question), str(r.comparison), budget_text(r.budget), f"{r.seeds_a} / {r.seeds_b}",
            _pts(r.difference), f"[{_pts(r.lo)}, {_pts(r.hi)}]", mdd, paper, str(r.looks),
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
        [str(int(r.look)), r.comparison, f"{r.seeds_a} vs {r.seeds_b}", _pts(r.difference),
         f"[{_pts(r.lo)}, {_pts(r.hi)}]", _needed_pts(r.needed), r.decision]
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
    return [*lines, "", "![outcomes by budget](figures/outcomes_by_budget.png)", ""]


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
         budget_text(r["to"]), str(r["seeds"]), _pts(r["change"]),
         f"[{_pts(r['lo'])}, {_pts(r['hi'])}]", str(r["comparisons"])]
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
    exp: Experiment, question: SequentialSpec
) -> tuple[pd.DataFrame, list[pd.DataFrame]] | None:
    """``question``'s budget frame and its comparisons' change frames, when one of its
    groups reaches more than one budget (else None)."""
    groups = questions.rows_of(exp, question)
    if not any(len(budgets_of(exp, g)) > 1 for g in groups):
        return None
    frame = budget_frame(exp, question)
    changes = [
        change_frame(frame, c.a, c.b, endpoint).assign(
            comparison=c.name, endpoint=endpoint, a=c.a, b=c.b
        )
        for c in question.comparisons
        for endpoint in questions.ENDPOINT_FLAGS
    ]
    return frame.assign(question=question.name), changes


def counted_episodes(exp: Experiment, scores: pd.DataFrame) -> dict[int, pd.DataFrame]:
    """Per question budget, the hold-out episodes of the cells the questions count
    (``scores``), each cell read once: one frame of episodes (outcomes resolved, sorted),
    each named by its group's policy label (with the group's name where two groups share a
    label) in ``label`` and by its training seed in ``train_seed``."""
    if scores.empty:
        return {}
    budget_of = {q.name: q.budget for q in exp.designs}
    cells = scores.assign(budget=scores["question"].map(budget_of)).drop_duplicates(
        ["budget", "policy", "train_seed"]
    )
    out = {}
    for budget, part in cells.groupby("budget", sort=True):
        frames = []
        for row in part.itertuples(index=False):
            run = Path(row.run_dir)
            evaluation = row.evaluation if isinstance(row.evaluation, str) else ""
            frame, _ = read_evaluation(run.name, run, evaluation_dir(RunFolder(run), evaluation))
            label = str(frame["label"].iloc[0]).removesuffix(f" @{budget_text(int(budget))}")
            frames.append(frame.assign(label=label, group=row.policy))
        episodes = pd.concat(frames, ignore_index=True)
        shared = episodes.groupby("label")["group"].transform("nunique") > 1
        episodes.loc[shared, "label"] += " " + episodes.loc[shared, "group"]
        episodes = resolve_outcomes(episodes.drop(columns="group"))
        episodes = episodes.sort_values(list(SORT_COLUMNS), kind="mergesort")
        out[int(budget)] = episodes.reset_index(drop=True)
    return out


def returns_tables(episodes_by_budget: dict[int, pd.DataFrame]) -> dict[int, tables.Table]:
    """Table I (episode returns per objective, per-decision risk and lane keeping, episode
    length; Δ% relative to IQN) per question budget, from :func:`counted_episodes`: each
    group at each budget is one row, named by its policy label. Unranked: descriptive."""
    return {b: tables.table1(e, ranked=False) for b, e in episodes_by_budget.items()}


def seed_shares(episodes: pd.DataFrame) -> pd.DataFrame:
    """Per label, training seed, density and outcome: the share of that seed's episodes
    at that density ending in that outcome (columns label, train_seed, density, outcome,
    rate)."""
    flags = episodes[list(OUTCOMES)].astype(bool).astype(float)
    keys = [episodes["label"], episodes["train_seed"], episodes["density"].astype(float)]
    per_seed = flags.groupby(keys, sort=False).mean().reset_index()
    return per_seed.melt(["label", "train_seed", "density"], var_name="outcome", value_name="rate")


def _paper_mix(label: str, densities: list[float]) -> dict[tuple[str, float], float]:
    """``(outcome, density) -> rate`` of the paper's Table II row of ``label`` at those of
    ``densities`` it has (empty when it has no such row)."""
    from priqn.analysis.paper import paper_outcomes

    paper = paper_outcomes(label)
    if paper is None:
        return {}
    return {
        (o, d): paper[o][PAPER_DENSITIES.index(d)]
        for o in OUTCOMES
        for d in densities
        if d in PAPER_DENSITIES
    }


def _mix_rows(
    episodes: pd.DataFrame,
) -> tuple[list[list[str]], list[dict[str, Any]], list[dict[str, Any]]]:
    """The Markdown rows and CSV records of :func:`_mix_lines`: per label and outcome, each
    density's rate (each seed's share first, :func:`seed_shares`, then their mean:
    :func:`~priqn.analysis.calibration.mean_mix`) beside the paper's (its Table II row of the same
    label), the L1 distance of the 12 numbers to the paper's row, and each training seed's
    own L1 (its shares, not the mean; median [min, max] in the Markdown, one record per
    seed in the third list)."""
    from priqn.analysis.calibration import l1_by_outcome, mean_mix, rates_of

    shares = seed_shares(episodes)
    mix = mean_mix(shares, group="label", seed="train_seed")
    densities = sorted(mix["density"].unique())
    md_rows, records, seed_records = [], [], []
    for label, mine in mix.groupby("label", sort=False):
        rate = rates_of(mine)
        theirs = _paper_mix(str(label), densities)
        full = len(theirs) == len(OUTCOMES) * len(densities) == 12
        l1 = sum(l1_by_outcome(rate, theirs).values()) if full else math.nan
        seed_l1 = {
            seed: sum(l1_by_outcome(rates_of(own), theirs).values())
            for seed, own in shares[shares["label"] == label].groupby("train_seed", sort=True)
        } if full else {}  # fmt: skip
        seed_records += [{"label": label, "train_seed": k, "l1_to_paper": v}
                         for k, v in seed_l1.items()]  # fmt: skip
        per_seed = (
            f"{np.median(list(seed_l1.values())):.2f} "
            f"[{min(seed_l1.values()):.2f}, {max(seed_l1.values()):.2f}]"
            if seed_l1
            else ""
        )
        for i, outcome in enumerate(OUTCOMES):
            cells = [
                f"{rate[(outcome, d)]:.3f}"
                + (f" ({theirs[(outcome, d)]:.3f})" if (outcome, d) in theirs else "")
                for d in densities
            ]
            head = [str(label), str(int(mine["seeds"].min()))] if i == 0 else ["", ""]
            tail = [f"{l1:.3f}", per_seed] if i == 0 and full else ["", ""]
            md_rows.append([*head, outcome.replace("_", "-"), *cells, *tail])
            records += [
                {"label": label, "seeds": int(mine["seeds"].min()), "outcome": outcome,
                 "density": d, "rate": rate[(outcome, d)],
                 "paper": theirs.get((outcome, d), math.nan), "l1_to_paper": l1}
                for d in densities
            ]  # fmt: skip
    return md_rows, records, seed_records


def _mix_lines(episodes_by_budget: dict[int, pd.DataFrame], out: Path) -> list[str]:
    """The outcome-mix section: per question budget, how each group's hold-out episodes
    end at each density beside the paper's Table II row of the same label, with the L1
    distance calibration uses (``tables/outcome_mix_<budget>.csv``); none while no cell
    is counted."""
    if not episodes_by_budget:
        return []
    lines = [
        "## Outcome mix beside the paper's (descriptive)",
        "",
        "How the hold-out episodes end, per density: the share of each outcome, each "
        "training seed's first, then their mean; in brackets the paper's Table II row of "
        "the same label (2M decisions in CARLA; its timeouts are what success, collision "
        "and off-road leave). L1: the distance of the 12 numbers to the paper's row, as "
        "the calibration's rule measures it; of a seed alone: each training seed's own "
        "shares' distance, median [min, max] (`tables/outcome_mix_<budget>_seeds.csv`). "
        "Descriptive: no test decides on these.",
        "",
    ]
    for budget, episodes in episodes_by_budget.items():
        md_rows, records, seed_records = _mix_rows(episodes)
        name = f"outcome_mix_{budget_text(budget)}"
        write_csv(out / "tables" / f"{name}.csv", pd.DataFrame(records))
        if seed_records:
            write_csv(out / "tables" / f"{name}_seeds.csv", pd.DataFrame(seed_records))
        densities = sorted(episodes["density"].astype(float).unique())
        heads = ["policy", "seeds", "outcome", *(f"density {float(d)}" for d in densities),
                 "L1", "L1 of a seed alone"]  # fmt: skip
        lines += [f"### At {budget_text(budget)} decisions", "", markdown_table(heads, md_rows), ""]
    return lines


def manoeuvre_table(episodes: pd.DataFrame) -> pd.DataFrame:
    """How each label's episodes end per ego manoeuvre (:func:`tables.outcomes_by_command`:
    densities and seeds pooled, every seed playing the same hold-out scenes), with its
    ``seeds`` and ``timeout_progress``, the median route progress of the episodes that
    timed out (NaN where none did); labels in first-seen order."""
    labels = list(dict.fromkeys(episodes["label"]))
    table = tables.outcomes_by_command(episodes, labels)
    seeds = episodes.groupby("label")["train_seed"].nunique()
    timed_out = episodes["timeout"].astype(bool)
    keys = [episodes["label"][timed_out], tables.route_commands(episodes)[timed_out]]
    median = episodes[timed_out].groupby(keys)["route_progress"].median().to_dict()
    table.insert(2, "seeds", table["label"].map(seeds))
    table["timeout_progress"] = [
        median.get((label, command), math.nan)
        for label, command in zip(table["label"], table["command"], strict=True)
    ]
    return table


def _manoeuvre_lines(episodes_by_budget: dict[int, pd.DataFrame], out: Path) -> list[str]:
    """The outcome-by-manoeuvre section: per question budget, how each group's hold-out
    episodes end for each route command of the ego (:func:`manoeuvre_table`,
    ``tables/outcome_by_manoeuvre_<budget>.csv`` and its figure); none while no cell is
    counted."""
    from priqn.analysis.figures import outcomes_figure, save_figure

    if not episodes_by_budget:
        return []
    lines = [
        "## Outcome by manoeuvre (descriptive)",
        "",
        "How the hold-out episodes end for each route command of the ego: the share of "
        "each outcome over every density and training seed (every seed plays the same "
        "scenes). Timeouts' progress: the median route progress (0 at the route's start, 1 "
        "at its end) of the episodes that timed out. Descriptive: no test decides on these.",
        "",
    ]
    heads = ["policy", "manoeuvre", "seeds", "episodes",
             *(o.replace("_", "-") for o in OUTCOMES), "timeouts' progress"]  # fmt: skip
    for budget, episodes in episodes_by_budget.items():
        name = f"outcome_by_manoeuvre_{budget_text(budget)}"
        table = manoeuvre_table(episodes)
        write_csv(out / "tables" / f"{name}.csv", table)
        save_figure(outcomes_figure(table, list(dict.fromkeys(table["label"]))),
                    out / "figures", name)  # fmt: skip
        rows = [
            [r.label, r.command, str(r.seeds), str(r.episodes),
             *(f"{getattr(r, o):.3f}" for o in OUTCOMES),
             "–" if math.isnan(r.timeout_progress) else f"{r.timeout_progress:.2f}"]
            for r in table.itertuples(index=False)
        ]  # fmt: skip
        lines += [
            f"### At {budget_text(budget)} decisions",
            "",
            markdown_table(heads, rows),
            "",
            f"![outcome by manoeuvre at {budget_text(budget)}](figures/{name}.png)",
            "",
        ]
    return lines


def _returns_lines(episodes_by_budget: dict[int, pd.DataFrame], out: Path) -> list[str]:
    """The Table I section: per question budget, ``tables/table1_<budget>.{md,csv}`` and
    the table itself; none while no cell is counted."""
    by_budget = returns_tables(episodes_by_budget)
    if not by_budget:
        return []
    lines = [
        "## Returns per objective (Table I, descriptive)",
        "",
        "The paper's Table I over the cells the questions count, at each question's budget "
        "(mean ± sample std over training seeds × evaluation runs, Δ% relative to IQN). "
        "Descriptive: no test decides on these columns.",
        "",
    ]
    for budget, table in by_budget.items():
        name = f"table1_{budget_text(budget)}"
        atomic_write_text(out / "tables" / f"{name}.md", tables.to_markdown(table))
        atomic_write_text(out / "tables" / f"{name}.csv", tables.to_csv(table))
        lines += [f"### At {budget_text(budget)} decisions", "", tables.to_markdown(table)]
    return lines


def _efficiency(exp: Experiment, out: Path) -> list[str]:
    """The sample-efficiency curves of every complete cell's group (periodic evaluations
    and full evaluations at each budget, kept snapshots included): table, figure and the
    report's lines; none while no cell is complete."""
    from priqn.analysis import curves, sequential_report
    from priqn.analysis.figures import save_figure

    cells = [
        cell
        for cell in curves.experiment_cells(exp)
        if evaluated(folder := RunFolder(cell[2]), kept_evaluations(folder))
    ]
    points, notes = curves.curve_points(cells)
    if points.empty:
        return []
    curve = curves.sample_efficiency(
        points, sequential_report.CURVE_REPS, sequential_report.CURVE_SEED
    )
    write_csv(out / "tables" / "sample_efficiency.csv", curve)
    save_figure(
        sequential_report.efficiency_figure(exp, curve), out / "figures", "sample_efficiency"
    )
    return [
        "## Sample efficiency (descriptive)",
        "",
        "Hold-out success against training decisions, one curve per group over its complete "
        "cells: lines are the in-training evaluations (6 episodes a point), markers the full "
        "evaluations (162 episodes) at each budget a cell reaches, kept snapshots included; "
        f"mean over training seeds with a 95 % stratified-bootstrap band "
        f"({sequential_report.CURVE_REPS} replications, seed {sequential_report.CURVE_SEED}).",
        *([""] + [f"- {n}" for n in notes] if notes else []),
        "",
        "![sample efficiency](figures/sample_efficiency.png)",
        "",
    ]


def write_report(exp: Experiment, out_dir: str | Path, command: str | None = None) -> Path:
    """Write the questions' report into ``out_dir``; returns ``report.md``."""
    from priqn.analysis.figures import save_figure
    from priqn.io import atomic_write_json

    out = Path(out_dir)
    command = command or f"priqn report {relative_path(exp.runs_dir)} --out {relative_path(out)}"
    scores_by_q, comparison_rows, look_rows, budget_frames, change_frames = {}, [], [], [], []
    results: list[tuple[SequentialSpec, Looks]] = []
    for q in exp.designs:
        scores, result = questions.take_looks(exp, q)
        scores_by_q[q.name] = scores
        results.append((q, result))
        comparison_rows += _comparison_rows(exp, q, scores, result)
        look_rows += _look_rows(q, result)
        by_budget = _budget_tables(exp, q)
        if by_budget is not None:
            budget_frames.append(by_budget[0])
            change_frames += by_budget[1]
    comparisons = pd.DataFrame(comparison_rows)
    looks = pd.DataFrame(look_rows, columns=LOOK_COLUMNS)
    budgets = pd.concat(budget_frames, ignore_index=True) if budget_frames else pd.DataFrame()
    budgets = (
        budgets.drop_duplicates(["group", "budget", "train_seed"]) if len(budgets) else budgets
    )
    change_frames = [f for f in change_frames if len(f)]  # (pandas warns on empty ones)
    changes = pd.concat(change_frames, ignore_index=True) if change_frames else pd.DataFrame()
    if len(changes):  # one row per pair of groups and budgets, naming the comparisons
        keys = ["a", "b", "endpoint", "from", "to", "seeds", "change", "lo", "hi"]
        changes = (
            changes.groupby(keys, sort=False, dropna=False)["comparison"]
            .agg("; ".join)
            .reset_index()
            .rename(columns={"comparison": "comparisons"})
        )
    all_scores = pd.concat(
        [s.assign(question=name) for name, s in scores_by_q.items()], ignore_index=True
    )
    for name, frame in (("scores", all_scores), ("comparisons", comparisons), ("looks", looks),
                        ("budgets", budgets), ("budget_changes", changes)):  # fmt: skip
        write_csv(out / "tables" / f"{name}.csv", frame)
    save_figure(figure(exp, scores_by_q), out / "figures", "questions")
    monitoring = looks_figure(results, f"{exp.experiment.name}: each comparison look by look")
    if monitoring is not None:
        save_figure(monitoring, out / "figures", "looks")
    if len(budgets):
        save_figure(budget_outcomes_figure(budgets), out / "figures", "outcomes_by_budget")
    episodes_by_budget = counted_episodes(exp, all_scores)
    descriptive = [
        *_mix_lines(episodes_by_budget, out),
        *_manoeuvre_lines(episodes_by_budget, out),
        *_returns_lines(episodes_by_budget, out),
        *_efficiency(exp, out),
    ]
    report = out / "report.md"
    text = report_markdown(
        exp, comparisons, looks, budgets, changes, command, descriptive, all_scores
    )
    atomic_write_text(report, text)
    atomic_write_json(
        out / "meta.json",
        {
            "command": command,
            "experiment": exp.path.name,
            "verdicts": {r["comparison"]: r["verdict"] for r in comparison_rows},
            "looks": {
                q: int(looks[looks["question"] == q]["look"].max() or 0)
                if len(looks[looks["question"] == q])
                else 0
                for q in scores_by_q
            },
            "cells": {q: len(s) for q, s in scores_by_q.items()},
        },
    )
    return report
