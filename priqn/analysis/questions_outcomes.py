"""How the cells a questions report counts end their episodes, at each question's budget
(the outcome mix also at every other budget the groups reach):
the descriptive sections of :mod:`priqn.analysis.questions_report` (outcome mix beside the
paper's Table II row, outcome by manoeuvre, Table I), their tables and figures.

:func:`outcome_sections` reads every counted cell's hold-out episodes once
(:func:`counted_episodes`) and returns the sections, each with its Markdown, tables and
figures (:class:`~priqn.analysis.sections.Section`). Descriptive: no test decides
on these numbers.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from priqn.agents.labels import budget_text
from priqn.analysis import tables
from priqn.analysis.load import SORT_COLUMNS, read_evaluation
from priqn.analysis.mixes import l1_by_outcome, mean_mix, rates_of
from priqn.analysis.paper import PAPER_DENSITIES
from priqn.analysis.render import markdown_table
from priqn.analysis.sections import Section
from priqn.experiment import Experiment
from priqn.objectives import OUTCOMES
from priqn.run.episodes import resolve_outcomes
from priqn.run.evaluations import evaluation_dir
from priqn.run.folder import RunFolder


def outcome_sections(
    exp: Experiment, scores: pd.DataFrame, budgets: pd.DataFrame | None = None
) -> list[Section]:
    """The outcome-mix, outcome-by-manoeuvre and Table I sections of the cells every
    question counts (``scores``, with a ``question`` column), at each question's budget,
    with their tables and figures; the outcome mix also at every other budget the groups
    reach (``budgets``: :func:`~priqn.analysis.questions_report.budget_frame`'s rows, the
    kept snapshots of the questions' seeds). Empty sections while no cell is counted."""
    episodes_by_budget = counted_episodes(exp, scores)
    other = budget_episodes(exp, budgets, skip=set(episodes_by_budget))
    mixes = dict(sorted({**episodes_by_budget, **other}.items()))
    return [
        _mix_section(mixes, others=sorted(other)),
        _manoeuvre_section(episodes_by_budget),
        _returns_section(episodes_by_budget),
    ]


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
        evaluations = [e if isinstance(e, str) else "" for e in part["evaluation"]]
        where = zip(part["policy"], map(Path, part["run_dir"]), evaluations, strict=True)
        out[int(budget)] = _episodes_at(int(budget), list(where))
    return out


def budget_episodes(
    exp: Experiment, budgets: pd.DataFrame | None, skip: set[int]
) -> dict[int, pd.DataFrame]:
    """As :func:`counted_episodes`, at every budget of ``budgets`` (group, budget and
    training seed of each complete evaluation: the questions' seeds at every budget their
    groups reach) but those in ``skip``: each cell's evaluation at that budget (a kept
    snapshot's, ``eval-at<N>/``)."""
    if budgets is None or not len(budgets):
        return {}
    out = {}
    for budget, part in budgets[~budgets["budget"].isin(skip)].groupby("budget", sort=True):
        cells = []
        for group, seed in part[["group", "train_seed"]].itertuples(index=False):
            where = exp.cell_at(group, int(seed), int(budget))
            if where is not None:
                cells.append((group, where[1], where[2]))
        out[int(budget)] = _episodes_at(int(budget), cells)
    return out


def _episodes_at(budget: int, cells: list[tuple[str, Path, str]]) -> pd.DataFrame:
    """The episodes of ``cells`` (group, run folder, evaluation name) at ``budget``, each
    cell read once, labelled as :func:`counted_episodes` says."""
    frames = []
    for group, run, evaluation in cells:
        frame, _ = read_evaluation(run.name, run, evaluation_dir(RunFolder(run), evaluation))
        label = str(frame["label"].iloc[0]).removesuffix(f" @{budget_text(budget)}")
        frames.append(frame.assign(label=label, group=group))
    episodes = pd.concat(frames, ignore_index=True)
    shared = episodes.groupby("label")["group"].transform("nunique") > 1
    episodes.loc[shared, "label"] += " " + episodes.loc[shared, "group"]
    episodes = resolve_outcomes(episodes.drop(columns="group"))
    episodes = episodes.sort_values(list(SORT_COLUMNS), kind="mergesort")
    return episodes.reset_index(drop=True)


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


def mix_rows(
    episodes: pd.DataFrame,
) -> tuple[list[list[str]], list[dict[str, Any]], list[dict[str, Any]]]:
    """The Markdown rows and CSV records of :func:`_mix_section`: per label and outcome, each
    density's rate (each seed's share first, :func:`seed_shares`, then their mean:
    :func:`~priqn.analysis.mixes.mean_mix`) beside the paper's (its Table II row of the same
    label), the L1 distance of the 12 numbers to the paper's row, and each training seed's
    own L1 (its shares, not the mean; median [min, max] in the Markdown, one record per
    seed in the third list)."""
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


def _mix_section(episodes_by_budget: dict[int, pd.DataFrame], others: list[int]) -> Section:
    """The outcome-mix section: per budget, how each group's hold-out episodes end at each
    density beside the paper's Table II row of the same label, with the L1 distance
    calibration uses (``tables/outcome_mix_<budget>.csv``); ``others``: the budgets no
    question asks at (said so in the text); none while no cell is counted."""
    if not episodes_by_budget:
        return Section([])
    tables_by_name: dict[str, pd.DataFrame] = {}
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
    if others:
        lines += [
            f"At {', '.join(budget_text(b) for b in others)}, where no question asks, the "
            "same over the questions' seeds whose kept snapshot there is evaluated "
            "(`eval-at<N>/`).",
            "",
        ]
    for budget, episodes in episodes_by_budget.items():
        md_rows, records, seed_records = mix_rows(episodes)
        name = f"outcome_mix_{budget_text(budget)}"
        tables_by_name[name] = pd.DataFrame(records)
        if seed_records:
            tables_by_name[f"{name}_seeds"] = pd.DataFrame(seed_records)
        densities = sorted(episodes["density"].astype(float).unique())
        heads = ["policy", "seeds", "outcome", *(f"density {float(d)}" for d in densities),
                 "L1", "L1 of a seed alone"]  # fmt: skip
        lines += [f"### At {budget_text(budget)} decisions", "", markdown_table(heads, md_rows), ""]
    return Section(lines, tables=tables_by_name)


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


def _manoeuvre_section(episodes_by_budget: dict[int, pd.DataFrame]) -> Section:
    """The outcome-by-manoeuvre section: per question budget, how each group's hold-out
    episodes end for each route command of the ego (:func:`manoeuvre_table`,
    ``tables/outcome_by_manoeuvre_<budget>.csv`` and its figure); none while no cell is
    counted."""
    from priqn.analysis.figures import outcomes_figure

    if not episodes_by_budget:
        return Section([])
    tables_by_name, figures_by_name = {}, {}
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
        tables_by_name[name] = table
        figures_by_name[name] = outcomes_figure(table, list(dict.fromkeys(table["label"])))
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
    return Section(lines, tables=tables_by_name, figures=figures_by_name)


def _returns_section(episodes_by_budget: dict[int, pd.DataFrame]) -> Section:
    """The Table I section: per question budget, ``tables/table1_<budget>.{md,csv}`` and
    the table itself; none while no cell is counted."""
    by_budget = returns_tables(episodes_by_budget)
    if not by_budget:
        return Section([])
    files = {}
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
        files[f"tables/{name}.md"] = tables.to_markdown(table)
        files[f"tables/{name}.csv"] = tables.to_csv(table)
        lines += [f"### At {budget_text(budget)} decisions", "", tables.to_markdown(table)]
    return Section(lines, files=files)
