"""The grid report (kind ``grid``): Tables I and II, rliable statistics and figures from
evaluated runs (``priqn report`` on a folder of runs that is no design's; the choice is
:func:`priqn.analysis.reports.choose_kind`'s).

:func:`grid_report` builds its sections (``make_report(runs_dir, out_dir, seed=0)`` renders
them, :func:`priqn.analysis.artifacts.render`)::

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
                                      learning_curves: the sample-efficiency curves
    out_dir/tables/sample_efficiency.csv  their numbers (priqn.analysis.curves)
    out_dir/figures/claims.{png,pdf}  the claims' success-rate comparisons, when measured
    out_dir/tables/generalisation_<hash>.{md,csv}  per set of other nets the runs were
                                      evaluated on (``priqn evaluate --nets``), when any

Same inputs and seed give byte-identical tables and report.md (no timestamps).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

from priqn.analysis.render import markdown_table
from priqn.analysis.request import DEFAULT_REPS, ReportRequest, report_command
from priqn.analysis.sections import Report, Section
from priqn.run.folder import RunFolder

if TYPE_CHECKING:
    from priqn.analysis.curves import Efficiency

MIN_SEEDS_FOR_STATISTICS = 2
"""Fewer training seeds per policy: no best/second marks and no CIs in the report."""


def _fmt_ci(point: float, lo: float, hi: float) -> str:
    return f"{point:.3f} [{lo:.3f}, {hi:.3f}]"


def _rliable_markdown(aggregates: dict[str, Any], order: list[str]) -> str:
    """IQM / optimality-gap table from ``{metric: aggregates DataFrame}``."""
    from priqn.analysis.stats import SCORE_METRICS

    heads = ["Policy"]
    for metric in aggregates:
        short = SCORE_METRICS[metric]
        heads += [f"IQM {short} ↑", f"Optimality gap {short} ↓"]
    aggs = {m: a.set_index("label") for m, a in aggregates.items()}
    rows = []
    for label in order:
        row = [label]
        for agg in aggs.values():
            a = agg.loc[label]
            row += [
                _fmt_ci(a["iqm"], a["iqm_lo"], a["iqm_hi"]),
                _fmt_ci(a["og"], a["og_lo"], a["og_hi"]),
            ]
        rows.append(row)
    return markdown_table(heads, rows, "l" + "r" * (len(heads) - 1)) + "\n"


def _poi_matrix_markdown(result: Any, order: list[str]) -> str:
    poi = result.improvement.set_index(["x", "y"])
    short = [f"({i + 1})" for i in range(len(order))]
    rows = []
    for i, x in enumerate(order):
        cells = [f"({i + 1}) {x}"]
        for y in order:
            if x == y:
                cells.append("–")
            else:
                r = poi.loc[(x, y)]
                cells.append(f"{r['p']:.2f} [{r['lo']:.2f}, {r['hi']:.2f}]")
        rows.append(cells)
    return markdown_table(["X \\ Y", *short], rows, "l" + "r" * len(order)) + "\n"


@dataclasses.dataclass
class ReportInputs:
    """Step 1 (:func:`load_inputs`): what the report reads, and what it must say about it."""

    runs_root: Path
    """The folder of runs reported."""
    evaluation: Any
    """The loaded :class:`priqn.analysis.load.Evaluation`."""
    notes: list[str]
    """Sentences for the report's Notes (partial grid, unequal seeds, ...)."""
    ranked: bool
    """At least MIN_SEEDS_FOR_STATISTICS training seeds per policy (marks and CIs)."""
    unranked_why: str = ""
    """Why not ranked (empty when ranked)."""
    generalisation: list[Any] = dataclasses.field(default_factory=list)
    """:class:`priqn.analysis.generalisation.NetsEvaluation` per set of other nets the runs
    were evaluated on (``priqn evaluate --nets``); empty when none, and then the report is
    exactly what it was before such evaluations existed."""
    references: Any = None
    """:class:`priqn.analysis.reference.References` (``--reference``); None without them."""

    @property
    def episodes(self) -> Any:
        """The episode table (one row per hold-out episode)."""
        return self.evaluation.episodes


@dataclasses.dataclass
class ReportTables:
    """Step 2 (:func:`build_tables`): Table II, Table I and how episodes end."""

    table2: Any
    table1: Any
    outcomes: Any
    order: list[str]
    """Policy labels in Table II order (every later step uses it)."""
    generalisation: list[Any] = dataclasses.field(default_factory=list)
    """``(NetsEvaluation, table)`` per ``ReportInputs.generalisation`` entry, same order."""
    reference_order: list[str] = dataclasses.field(default_factory=list)
    """Reference drivers' labels, shown after the policies (never ranked; not in ``order``)."""


@dataclasses.dataclass
class ReportStatistics:
    """Step 3 (:func:`compute_statistics`): rliable (descriptive) and the claims (verdicts)."""

    rliable: dict[str, Any]
    """Metric -> :class:`priqn.analysis.stats.RliableResult` (empty when not ranked)."""
    claims: list[Any]
    """:class:`priqn.analysis.claims.ClaimResult` per claim."""

    @property
    def claims_checked(self) -> bool:
        """At least one claim has every row in the report."""
        return any(not r.missing for r in self.claims)


def load_inputs(
    runs_dir: str | Path,
    partial: bool,
    min_seeds: int | None,
    references: tuple[str | Path, ...] = (),
) -> ReportInputs:
    """Load every evaluated run, check seeds, and collect the notes the report must carry.

    ``references``: reference-driver folders (``priqn evaluate --reference``), checked
    against the runs (:func:`priqn.analysis.reference.load_references`)."""
    from priqn.analysis.generalisation import load_generalisation
    from priqn.analysis.load import check_seeds, load_evaluation

    runs_root = Path(runs_dir)
    evaluation = load_evaluation(runs_root, partial=partial)
    generalisation, unfinished = load_generalisation(runs_root, partial=partial)
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
    ranked = int(seeds_per_policy.min()) >= MIN_SEEDS_FOR_STATISTICS
    unranked_why = ""
    if not ranked:
        short = seeds_per_policy[seeds_per_policy < MIN_SEEDS_FOR_STATISTICS]
        unranked_why = (
            f"No best/second marks and no confidence intervals: {short.index[0]!r} has "
            f"{int(short.iloc[0])} training seed(s) (at least {MIN_SEEDS_FOR_STATISTICS} per "
            "policy are needed to rank policies or compute intervals over seeds)."
        )
        notes.append(unranked_why)
    if unfinished:
        notes.append(
            f"Partial report: {len(unfinished)} evaluation(s) on other nets not complete "
            f"were left out of the generalisation tables: {', '.join(unfinished)}."
        )
    refs = None
    if references:
        from priqn.analysis.reference import load_references

        refs = load_references(references, evaluation, generalisation)
    return ReportInputs(runs_root, evaluation, notes, ranked, unranked_why, generalisation, refs)


def build_tables(inputs: ReportInputs) -> ReportTables:
    """Table II, Table I and the outcome breakdown, in Table II's row order."""
    from priqn.analysis import tables

    refs = inputs.references
    ref_order = list(refs.labels) if refs is not None else []
    t2 = tables.table2(
        inputs.episodes, inputs.ranked, refs.episodes if refs is not None else None, ref_order
    )
    t1 = tables.table1(inputs.episodes, inputs.ranked)
    order = list(t2.configs)
    if tables.baseline_label(t2.configs) is None:
        inputs.notes.append("No IQN policy was evaluated, so Table I has no Δ%.")
    from priqn.analysis.generalisation import generalisation_table

    by_nets = refs.by_nets if refs is not None else {}
    general = [
        (g, generalisation_table(g.episodes, None, by_nets.get(g.nets_hash), ref_order))
        for g in inputs.generalisation
    ]
    outcomes = tables.outcomes_by_command(inputs.episodes, order)
    if refs is not None:  # the reference drivers' rows after the policies'
        import pandas as pd

        ref_outcomes = tables.outcomes_by_command(refs.episodes, ref_order)
        outcomes = pd.concat([outcomes, ref_outcomes], ignore_index=True)
    return ReportTables(t2, t1, outcomes, order, general, ref_order)


def compute_statistics(
    inputs: ReportInputs, order: list[str], reps: int, seed: int
) -> ReportStatistics:
    """rliable over training seeds (when ranked) and every claim's verdict."""
    from priqn.analysis import claims
    from priqn.analysis.stats import SCORE_METRICS, rliable_statistics

    rliable = {}
    if inputs.ranked:
        rliable = {
            m: rliable_statistics(inputs.episodes, m, order, reps, seed) for m in SCORE_METRICS
        }
    return ReportStatistics(rliable, claims.evaluate_claims(inputs.episodes, seed))


def efficiency_of(inputs: ReportInputs, tabs: ReportTables, reps: int, seed: int) -> Efficiency:
    """The sample-efficiency section (:func:`priqn.analysis.curves.efficiency`) of every
    run's own policy (controls share their run's training: no curve of their own), rows in
    Table II's order."""
    from priqn.analysis import curves

    cells = [
        (r.label, r.train_seed, r.path)
        for r in inputs.evaluation.runs
        if r.eval_dir == RunFolder.EVAL
    ]
    agents = {label: tabs.table2.configs[label][0] for label in tabs.order}
    return curves.efficiency(cells, agents, reps, seed)


def _rliable_section(inputs: ReportInputs, order: list[str], stats: ReportStatistics) -> Section:
    """The rliable section: its statistics' tables and figures (none with too few seeds)."""
    import pandas as pd

    from priqn.analysis import figures

    if not stats.rliable:
        return Section(["## rliable", "", f"Not computed. {inputs.unranked_why}", ""])
    frames = {
        name: pd.concat([getattr(r, part).assign(metric=m) for m, r in stats.rliable.items()])
        for name, part in (
            ("rliable_aggregates", "aggregates"),
            ("probability_of_improvement", "improvement"),
            ("performance_profiles", "profiles"),
        )
    }
    sr = stats.rliable["success"]
    drawn = {
        "probability_of_improvement": figures.probability_of_improvement_figure(sr),
        "iqm_optimality_gap": figures.aggregates_figure(stats.rliable),
        "performance_profile": figures.performance_profile_figure(sr),
    }
    lines = [
        "## rliable (descriptive)",
        "",
        "One score per training seed and task (evaluation runs averaged within a seed); the "
        "stratified bootstrap resamples seeds, so with few seeds these intervals are too "
        "narrow: they describe, the claims section decides.",
        "",
        _rliable_markdown({m: r.aggregates for m, r in stats.rliable.items()}, order),
        "Probability of improvement P(X > Y) on success rate (row X, column Y) [95% CI]:",
        "",
        _poi_matrix_markdown(stats.rliable["success"], order),
        "![P(X > Y)](figures/probability_of_improvement.png) "
        "([pdf](figures/probability_of_improvement.pdf))",
        "",
        "![IQM and optimality gap](figures/iqm_optimality_gap.png) ([pdf](figures/iqm_optimality_gap.pdf))",
        "",
        "![Performance profile](figures/performance_profile.png) ([pdf](figures/performance_profile.pdf))",
        "",
    ]
    return Section(lines, tables=frames, figures=drawn)


def _generalisation_section(tabs: ReportTables) -> Section:
    """The "Generalisation" section (evaluations on other nets), one table per set of nets;
    empty when the runs were evaluated on no other nets."""
    from priqn.analysis.generalisation import section_markdown, table_markdown

    if not tabs.generalisation:
        return Section([])
    groups = [g for g, _ in tabs.generalisation]
    stems = {f"generalisation_{nets.short_hash}": table for nets, table in tabs.generalisation}
    return Section(
        [section_markdown(groups, [t for _, t in tabs.generalisation])],
        tables=stems,
        files={f"tables/{stem}.md": table_markdown(table) for stem, table in stems.items()},
    )


def _row_notes(inputs: ReportInputs, tabs: ReportTables) -> list[str]:
    """Paragraphs saying what the rows beyond the trained policies are (controls, references)."""
    md = []
    if any(r.eval_dir != RunFolder.EVAL for r in inputs.evaluation.runs):
        md += [
            "Rows with `near-greedy ε=…` in their name are the acting-randomness control: "
            "the same networks as the rows without it, evaluated acting at random among "
            "the actions whose mean return is within ε (per-state std) of the best "
            "(`priqn evaluate --acting near-greedy`; docs/evaluation.md).",
            "",
        ]
    if tabs.reference_order:
        md += [
            "Rows in *italics* ending in `(reference)` are reference drivers on the same "
            "scenes (`priqn evaluate --reference`; docs/evaluation.md): the ego driven by "
            "SUMO's own car-following, junction and lane-change models, or by uniform "
            "random actions. They are never ranked or marked and no claim uses them.",
            "",
        ]
    return md


def _curves_section(efficiency: Efficiency, seed: int, reps: int) -> Section:
    """The "Sample-efficiency curves" section (:mod:`priqn.analysis.curves`)."""
    from priqn.analysis.figures import efficiency_figure

    if not efficiency.drawn:
        return Section(
            [
                "## Sample-efficiency curves",
                "",
                "No run has an in-training evaluation or a full evaluation with a known "
                "budget; no curves.",
                "",
            ]
        )
    lines = [
        "## Sample-efficiency curves",
        "",
        "Hold-out success against training decisions, per row: the mean over training "
        "seeds with a 95 % percentile stratified-bootstrap interval over seeds "
        f"(`np.random.seed({seed})` before each point's rliable call, {reps} replications). "
        "Two estimators, drawn apart: the line and its band are the in-training "
        "evaluations (a few hold-out episodes per seed, logged in `metrics.csv`); the "
        "markers with error bars are full hold-out evaluations (the final policy's "
        "`eval/`, kept snapshots' `eval-at<N>/`; a seed's success averaged over the "
        "densities). The mean, not the IQM: with few seeds the IQM trims no seed, and a "
        "rate over a few episodes takes few values (docs/evaluation.md). Numbers: "
        "`tables/sample_efficiency.csv`.",
        "",
        "![Sample-efficiency curves](figures/learning_curves.png) "
        "([pdf](figures/learning_curves.pdf))",
        "",
    ]
    return Section(
        lines,
        tables={"sample_efficiency": efficiency.curve},
        figures={"learning_curves": efficiency_figure(efficiency.curve, efficiency.agents)},
    )


def _inputs_section(inputs: ReportInputs) -> list[str]:
    """The "Inputs" section: every evaluated run (and reference driver) with its hold-out
    hash, the commit it trained at and where its training resumed."""
    from priqn.analysis.load import RESUMED_NOTE, commit_text, resumed_text

    refs = inputs.references.runs if inputs.references is not None else ()
    return [
        "## Inputs",
        "",
        "| run | policy | training seed | hold-out hash | commit | resumed at |",
        "|:--|:--|--:|:--|:--|:--|",
        *[
            f"| {r.name} | {r.label} | {r.train_seed} | `{r.holdout_hash[:16]}` | "
            f"{commit_text(r.path)} | {resumed_text(r.path)} |"
            for r in inputs.evaluation.runs
        ],
        *[f"| {r.name} | *{r.label}* | – | `{r.holdout_hash[:16]}` | – | – |" for r in refs],
        "",
        RESUMED_NOTE,
        "",
    ]


def report_sections(
    inputs: ReportInputs,
    tabs: ReportTables,
    stats: ReportStatistics,
    efficiency: Efficiency,
    cmd: str,
    seed: int,
    reps: int,
) -> list[Section]:
    """``report.md``'s sections, everything at a glance, in reading order."""
    closing = ["Files: `tables/` (Markdown, LaTeX, CSV), `figures/` (PNG, PDF), `meta.json`.", ""]
    if inputs.notes:
        closing = ["## Notes", "", *[f"- {n}" for n in inputs.notes], "", *closing]
    return [
        Section(_header_section(inputs, tabs, stats, cmd, seed, reps)),
        _tables_section(inputs, tabs),
        _generalisation_section(tabs),
        _claims_section(stats, seed) if stats.claims_checked else Section([]),
        _rliable_section(inputs, tabs.order, stats),
        _curves_section(efficiency, seed, reps),
        Section(_inputs_section(inputs)),
        Section(closing),
    ]


def _header_section(
    inputs: ReportInputs,
    tabs: ReportTables,
    stats: ReportStatistics,
    cmd: str,
    seed: int,
    reps: int,
) -> list[str]:
    """The title, what made the report, and how: hold-out set, evaluation, statistics."""
    from priqn.analysis.stats import RUN_AXIS, TASK_AXIS

    evaluation, ec = inputs.evaluation, inputs.evaluation.eval_config
    axes = ""
    if stats.rliable:
        sr = stats.rliable["success"]
        n_runs, n_tasks = len(next(iter(sr.scores.values()))), len(sr.tasks)
        axes = f"e.g. {n_runs} runs × {n_tasks} tasks for {tabs.order[0]}. "
    partial = evaluation.left_out
    return [
        "# priqn evaluation report" + (" (partial)" if partial else ""),
        "",
        *(
            [
                f"**Partial:** {len(evaluation.runs)} evaluated run(s); "
                f"{len(partial)} not yet evaluated left out (see Notes).",
                "",
            ]
            if partial
            else []
        ),
        f"Made by `{cmd}`; episodes by `priqn evaluate` on every run below.",
        "",
        *_row_notes(inputs, tabs),
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
            if inputs.ranked
            else "no best / second marks (too few training seeds; see rliable)."
        ),
        "",
    ]


def _tables_section(inputs: ReportInputs, tabs: ReportTables) -> Section:
    """Table II, how episodes end, and Table I, each with its figure; Tables I/II as
    Markdown, LaTeX and CSV."""
    from priqn.analysis import figures, tables

    files = {
        f"tables/{name}.{ext}": write(table)
        for name, table in (("table2", tabs.table2), ("table1", tabs.table1))
        for ext, write in (("md", tables.to_markdown), ("tex", tables.to_latex),
                           ("csv", tables.to_csv))
    }  # fmt: skip
    drawn = {
        "seeds": figures.seed_success_figure(inputs.episodes, tabs.order),
        "outcomes_by_command": figures.outcomes_figure(
            tabs.outcomes, tabs.order + tabs.reference_order
        ),
    }
    lines = [
        "## Table II — driving metrics",
        "",
        tables.to_markdown(tabs.table2),
        "![Success rate per training seed](figures/seeds.png) ([pdf](figures/seeds.pdf))",
        "",
        "## How episodes end, by route command",
        "",
        "Densities pooled; every episode ends in exactly one outcome, by precedence "
        "collision > off-road > timeout > success (timeout = the time limit reached "
        "without finishing the route).",
        "",
        tables.outcomes_markdown(tabs.outcomes),
        "![Outcomes by command](figures/outcomes_by_command.png) "
        "([pdf](figures/outcomes_by_command.pdf))",
        "",
        "## Table I — objective returns",
        "",
        tables.to_markdown(tabs.table1),
    ]
    drawn = {k: v for k, v in drawn.items() if v is not None}
    return Section(lines, tables={"outcomes_by_command": tabs.outcomes}, figures=drawn, files=files)


def _claims_section(stats: ReportStatistics, seed: int) -> Section:
    """The "The paper's claims" section (:mod:`priqn.analysis.claims_report`)."""
    from priqn.analysis import claims_report, figures

    fig = figures.claims_figure(stats.claims)
    lines = [
        "## The paper's claims",
        "",
        claims_report.to_markdown(stats.claims, seed),
        "![The claims](figures/claims.png) ([pdf](figures/claims.pdf))",
        "",
    ]
    return Section(
        lines,
        tables={"claims": claims_report.to_frame(stats.claims)},
        figures={} if fig is None else {"claims": fig},
    )


def grid_report(
    runs_dir: str | Path,
    command: str,
    seed: int = 0,
    reps: int = DEFAULT_REPS,
    min_seeds: int | None = None,
    partial: bool = False,
    references: tuple[str | Path, ...] = (),
    experiment: str | None = None,
) -> Report:
    """The report of every evaluated run under ``runs_dir`` (kind ``grid``).

    load → tables → statistics → sections. ``min_seeds``: refuse when a policy has
    fewer training seeds. ``seed`` goes to ``np.random.seed`` before every rliable call
    and seeds Monte-Carlo permutation tests (recorded in the report). ``partial``: report
    the fully evaluated runs of a grid still running, and say which were left out.
    ``references``: reference-driver folders shown as unranked rows
    (:mod:`priqn.analysis.reference`); none leaves the report as it was. ``command``: the
    one recorded; ``experiment``: the experiment's name for ``meta.json`` (None: no
    experiment's runs).
    """
    inputs = load_inputs(runs_dir, partial, min_seeds, tuple(references))
    tabs = build_tables(inputs)
    stats = compute_statistics(inputs, tabs.order, reps, seed)
    efficiency = efficiency_of(inputs, tabs, reps, seed)
    inputs.notes.extend(efficiency.notes)
    sections = report_sections(inputs, tabs, stats, efficiency, command, seed, reps)
    meta = _meta(inputs, tabs, seed, reps, min_seeds)
    return Report("grid", "report.md", sections, command, experiment, meta)


def make_report(
    runs_dir: str | Path,
    out_dir: str | Path,
    seed: int = 0,
    reps: int = DEFAULT_REPS,
    min_seeds: int | None = None,
    command: str | None = None,
    partial: bool = False,
    references: tuple[str | Path, ...] = (),
    experiment: str | None = None,
) -> Path:
    """:func:`grid_report` rendered into ``out_dir`` (for use from Python); returns
    ``report.md``. ``command``: the one recorded (by default
    :func:`priqn.analysis.request.report_command`'s)."""
    from priqn.analysis.artifacts import render

    if command is None:
        request = ReportRequest(
            Path(runs_dir),
            Path(out_dir),
            seed=seed,
            reps=reps,
            min_seeds=min_seeds,
            partial=partial,
            references=tuple(str(r) for r in references),
        )
        command = report_command(request, "grid")
    report = grid_report(
        runs_dir, command, seed, reps, min_seeds, partial, tuple(references), experiment
    )
    return render(out_dir, report)


def _meta(
    inputs: ReportInputs,
    tabs: ReportTables,
    seed: int,
    reps: int,
    min_seeds: int | None,
) -> dict[str, Any]:
    """``meta.json``'s own fields of the grid report: how it was made, from which runs."""
    from priqn.analysis.stats import RUN_AXIS, TASK_AXIS

    evaluation = inputs.evaluation
    return {
        "seed": seed,
        "bootstrap_reps": reps,
        "min_seeds": min_seeds,
        "run_axis": list(RUN_AXIS),
        "task_axis": list(TASK_AXIS),
        "holdout_hash": evaluation.holdout_hash,
        "eval_config": evaluation.eval_config,
        "runs": [
            {
                "name": r.name,
                "label": r.label,
                "train_seed": r.train_seed,
                "holdout_hash": r.holdout_hash,
            }
            for r in evaluation.runs
        ],
        "policies": tabs.order,
        "left_out": list(evaluation.left_out),
        "notes": inputs.notes,
        **(
            {
                "generalisation": [
                    {
                        "nets_hash": g.nets_hash,
                        "nets": list(g.nets),
                        "eval_config": g.eval_config,
                        "runs": [r.name for r in g.runs],
                    }
                    for g, _ in tabs.generalisation
                ]
            }
            if tabs.generalisation
            else {}
        ),
        **(
            {
                "references": [
                    {"folder": r.name, "label": r.label, "holdout_hash": r.holdout_hash}
                    for r in inputs.references.runs
                ]
            }
            if inputs.references is not None
            else {}
        ),
    }
