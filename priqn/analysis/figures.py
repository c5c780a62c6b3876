"""Figures in the paper's style (rliable's plot utilities): each function returns a
matplotlib figure, which a report's section holds and the one renderer writes as PNG and
PDF (:func:`priqn.analysis.artifacts.render`; deterministic bytes: no timestamps,
a fixed SVG hash salt, the Agg backend). Nothing here writes a file; a run's
``learning_curve.png`` is drawn by :mod:`priqn.run.curve`.
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.colors import to_hex, to_rgb  # noqa: E402
from matplotlib.ticker import FuncFormatter  # noqa: E402

from priqn.agents.labels import trained_row  # noqa: E402
from priqn.analysis.claims import ClaimResult  # noqa: E402
from priqn.analysis.sequential import Look, Looks, row_verdict  # noqa: E402
from priqn.analysis.stats import PAIR_SEPARATOR, SCORE_METRICS, RliableResult  # noqa: E402
from priqn.analysis.tables import OUTCOMES  # noqa: E402
from priqn.experiment import ComparisonSpec, SequentialSpec  # noqa: E402


def seed_dots(
    ax: plt.Axes, x: np.ndarray, row: float, color: Any, reused: np.ndarray, resumed: np.ndarray
) -> None:
    """One row's per-training-seed endpoints ``x`` at height ``row``: circles for cells
    trained in this experiment, open where a cell comes from a prior grid (``reused``),
    squares where its training resumed after a session ended before the budget shown
    (``resumed``; from there on not the uninterrupted run's)."""
    for is_reused in (False, True):
        for is_resumed in (False, True):
            mask = (reused == is_reused) & (resumed == is_resumed)
            if mask.any():
                ax.plot(
                    x[mask],
                    np.full(int(mask.sum()), row),
                    "s" if is_resumed else "o",
                    color=color,
                    mfc="none" if is_reused else color,
                    ms=5 if not is_resumed else 4.5,
                    alpha=0.8,
                )


def seed_dot_handles(color: Any, reused: bool, resumed: bool) -> list:
    """Legend entries for :func:`seed_dots`: the kinds of cell a figure shows."""
    handles = [plt.Line2D([], [], ls="", marker="o", color=color, label="seed (this experiment)")]
    if reused:
        handles.append(
            plt.Line2D([], [], ls="", marker="o", mfc="none", mec=color, label="seed (prior grid)")
        )
    if resumed:
        handles.append(
            plt.Line2D(
                [],
                [],
                ls="",
                marker="s",
                color=color,
                ms=4.5,
                label="seed whose training resumed (a session ended)",
            )
        )
    return handles


def legend_above(ax: plt.Axes, handles: list, title: str, ncol: int) -> None:
    """The legend of a dot / interval figure: small, frameless, centred above the axes."""
    ax.legend(
        handles=handles,
        fontsize=7,
        loc="lower center",
        ncol=ncol,
        bbox_to_anchor=(0.5, 1.0),
        title=title,
        title_fontsize="medium",
        frameon=False,
    )


ROW_PALETTE: tuple[str, ...] = (
    *(to_hex(c) for c in plt.get_cmap("tab10").colors),
    "#1a237e",  # navy
    "#00897b",  # teal
    "#b8860b",  # dark goldenrod
    "#6d0f1f",  # maroon
    "#222222",  # near-black
    "#64dd17",  # light green
    "#d500f9",  # violet
    "#546e7a",  # slate
)
"""Colours of trained rows, in report order: tab10, then eight dark or saturated colours
that tab10 lacks, so up to 18 trained rows get colours of their own."""

DERIVED_SHADES: tuple[tuple[str, float], ...] = (
    ("white", 0.5),
    ("black", 0.35),
    ("white", 0.75),
    ("black", 0.6),
)
"""How a derived row's colour departs from its trained row's (mixed with white or black by
that fraction), for the 1st, 2nd, ... derived row of one trained row."""


def row_colors(labels: list[str]) -> dict[str, tuple]:
    """One colour per row, by its place in ``labels`` (the report's row order), so a row
    has the same colour in every figure of a report.

    A row derived from a trained row in ``labels`` (its near-greedy control or its policy
    at a kept budget, :func:`priqn.agents.labels.trained_row`) gets a lighter or darker shade of
    that row's colour rather than a colour of its own, so a figure shows which rows are
    one network, and the trained rows keep the distinct colours."""
    present = set(labels)
    parent = {label: base if (base := trained_row(label)) in present else label for label in labels}
    trained = list(dict.fromkeys(parent.values()))
    base_rgb = {label: to_rgb(ROW_PALETTE[i % len(ROW_PALETTE)]) for i, label in enumerate(trained)}
    colors: dict[str, tuple] = {}
    derived_count: dict[str, int] = {}
    for label in labels:
        rgb = np.array(base_rgb[parent[label]])
        if parent[label] != label:
            k = derived_count[parent[label]] = derived_count.get(parent[label], 0) + 1
            toward, fraction = DERIVED_SHADES[(k - 1) % len(DERIVED_SHADES)]
            rgb = (1 - fraction) * rgb + fraction * np.array(to_rgb(toward))
        colors[label] = (*(float(c) for c in rgb), 1.0)
    return colors


def select_pairs(result: RliableResult, max_pairs: int) -> pd.DataFrame:
    """Pairs to draw: all if few, else the top-IQM policy against every other (both ways)."""
    poi = result.improvement
    if len(poi) <= max_pairs:
        return poi
    best = result.aggregates.sort_values(["iqm", "label"], ascending=[False, True])["label"].iloc[0]
    return poi[(poi["x"] == best) | (poi["y"] == best)].sort_values(
        ["x", "y"], key=lambda s: s != best
    )


def probability_of_improvement_figure(result: RliableResult, max_pairs: int = 24) -> plt.Figure:
    """P(X > Y) with CIs, X on the left, Y on the right (the paper's Figure 4)."""
    from rliable import plot_utils

    pairs = select_pairs(result, max_pairs)
    keys = [f"{x}{PAIR_SEPARATOR}{y}" for x, y in zip(pairs["x"], pairs["y"], strict=True)]
    estimates = dict(zip(keys, pairs["p"], strict=True))
    intervals = {
        k: np.array([lo, hi]) for k, lo, hi in zip(keys, pairs["lo"], pairs["hi"], strict=True)
    }
    colors = row_colors(list(result.scores))
    fig, ax = plt.subplots(figsize=(6.5, 0.45 * len(keys) + 1.2))
    plot_utils.plot_probability_of_improvement(
        estimates,
        intervals,
        pair_separator=PAIR_SEPARATOR,
        ax=ax,
        colors=[colors[x] for x in pairs["x"]],
        xticks=[0.0, 0.25, 0.5, 0.75, 1.0],
        xlabel=f"P(X > Y), {SCORE_METRICS.get(result.metric, result.metric)} per task",
        ticklabelsize="medium",
        labelsize="medium",
    )
    ax.set_xlim(0.0, 1.0)
    ax.axvline(0.5, color="grey", linestyle="--", linewidth=0.8)
    return fig


def aggregates_figure(results: dict[str, RliableResult]) -> plt.Figure:
    """IQM and optimality gap with 95% CIs, per scored metric (the paper's Figure 5)."""
    from rliable import plot_utils

    first = next(iter(results.values()))
    labels = list(first.scores)
    names, points, intervals = [], {k: [] for k in labels}, {k: [[], []] for k in labels}
    for metric, res in results.items():
        short = SCORE_METRICS.get(metric, metric)
        agg = res.aggregates.set_index("label")
        for stat, title in (("iqm", f"IQM {short} ↑"), ("og", f"Optimality gap {short} ↓")):
            names.append(title)
            for k in labels:
                points[k].append(agg.loc[k, stat])
                intervals[k][0].append(agg.loc[k, f"{stat}_lo"])
                intervals[k][1].append(agg.loc[k, f"{stat}_hi"])
    fig, axes = plot_utils.plot_interval_estimates(
        {k: np.array(v) for k, v in points.items()},
        {k: np.array(v) for k, v in intervals.items()},
        metric_names=names,
        algorithms=labels,
        colors=row_colors(labels),
        xlabel="score (success rate / route progress, 95% stratified-bootstrap CI)",
        subfigure_width=3.0,
        row_height=0.45,
        xlabel_y_coordinate=-0.02 - 0.5 / max(len(labels), 1),
    )
    for ax in np.atleast_1d(axes):
        ax.title.set_fontsize("medium")
        ax.tick_params(labelsize="small")
    for text in fig.texts:  # rliable's x label is xx-large
        text.set_fontsize("medium")
    return fig


def performance_profile_figure(result: RliableResult) -> plt.Figure:
    """Fraction of (run, task) scores above tau, with CIs."""
    from rliable import plot_utils

    prof = result.profiles
    labels = list(result.scores)
    taus = np.sort(prof["tau"].unique())
    profiles, cis = {}, {}
    for label in labels:
        p = prof[prof["label"] == label].sort_values("tau")
        profiles[label] = p["fraction"].to_numpy()
        cis[label] = np.stack([p["lo"].to_numpy(), p["hi"].to_numpy()])
    fig, ax = plt.subplots(figsize=(6.5, 4.0))
    plot_utils.plot_performance_profiles(
        profiles,
        taus,
        performance_profile_cis=cis,
        colors=row_colors(labels),
        xlabel=f"{SCORE_METRICS.get(result.metric, result.metric)} per (run, task) τ",
        ylabel="Fraction of runs with score > τ",
        ax=ax,
        labelsize="medium",
        ticklabelsize="small",
    )
    ax.legend(fontsize="small", loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False)
    return fig


def _episodes_text(curve: pd.DataFrame, source: str) -> str:
    """``"6"`` or ``"162–540"``: episodes behind one seed's score at ``source``'s points."""
    mine = curve[curve["source"] == source]
    lo, hi = int(mine["episodes_min"].min()), int(mine["episodes_max"].max())
    return f"{lo}" if lo == hi else f"{lo}–{hi}"


def _draw_efficiency_row(
    ax: plt.Axes, part: pd.DataFrame, color: Any, label: str, dodge: float
) -> None:
    """One row of :func:`sample_efficiency_figure`: the in-training points as a line with
    its interval band, the full evaluations as dodged markers with error bars."""
    from priqn.analysis.curves import PERIODIC, SNAPSHOT

    line = part[part["source"] == PERIODIC]
    if len(line):
        ax.plot(line["budget"], line["mean"], color=color, lw=1.4, label=label)
        ax.fill_between(line["budget"], line["lo"], line["hi"], color=color, alpha=0.15, lw=0)
    dots = part[part["source"] == SNAPSHOT]
    if len(dots):
        mean = dots["mean"].to_numpy(float)
        yerr = np.stack([mean - dots["lo"].to_numpy(float), dots["hi"].to_numpy(float) - mean])
        ax.errorbar(
            dots["budget"].to_numpy(float) + dodge,
            mean,
            yerr=np.nan_to_num(yerr),
            fmt="o",
            color=color,
            ms=4.5,
            mec="black",
            mew=0.5,
            elinewidth=1.2,
            capsize=2.5,
            label=None if len(line) else label,
        )


def sample_efficiency_figure(
    curve: pd.DataFrame,
    panel_rows: Sequence[tuple[str, list[str]]],
    colors: Mapping[str, Any],
    reference: str | None = None,
) -> plt.Figure:
    """Sample-efficiency curves (:mod:`priqn.analysis.curves`): hold-out success against
    training decisions, one panel per ``(title, rows)``, legends outside the axes.

    Line and band: the in-training evaluations (mean over seeds, 95 % stratified-bootstrap
    interval over seeds); markers with error bars (dodged sideways per row): the full
    hold-out evaluations of the final policy and of kept snapshots. ``reference`` (e.g.
    IQN): its in-training line, dotted, in every panel that does not hold it.
    """
    from priqn.analysis.curves import seed_counts

    n = len(panel_rows)
    fig, axes = plt.subplots(
        n,
        1,
        figsize=(8.0, 0.9 + 2.3 * n),
        sharex=True,
        sharey=True,
        squeeze=False,
        layout="constrained",
    )
    budgets = curve["budget"].to_numpy(float)
    span = float(budgets.max() - budgets.min()) or float(budgets.max()) or 1.0
    for ax, (title, rows) in zip(axes[:, 0], panel_rows, strict=True):
        if reference is not None and reference not in rows:
            _draw_reference_line(ax, curve, reference, colors[reference])
        for i, row in enumerate(rows):
            dodge = (i - (len(rows) - 1) / 2) * 0.02 * span
            label = f"{row} ({seed_counts(curve, row)})"
            _draw_efficiency_row(ax, curve[curve["row"] == row], colors[row], label, dodge)
        _frame_efficiency_panel(ax, title)
    axes[-1, 0].set_xlabel("training decisions")
    axes[-1, 0].xaxis.set_major_formatter(
        FuncFormatter(lambda x, _: f"{x / 1000:g}k" if abs(x) >= 1000 else f"{x:g}")
    )
    fig.legend(
        handles=_efficiency_style_handles(curve),
        loc="outside upper center",
        fontsize=7,
        frameon=False,
    )
    return fig


def efficiency_figure(curve: pd.DataFrame, agents: Mapping[str, str]) -> plt.Figure:
    """A report's sample-efficiency figure (:func:`priqn.analysis.curves.efficiency`'s
    curve and rows): baselines and Pr-IQN variants in panels of at most 4 rows
    (:func:`~priqn.analysis.curves.panels`), the IQN row that reaches furthest dotted in the
    panels without it (:func:`~priqn.analysis.curves.reference_row`), each row in its colour
    of the report's figures (by its place in ``agents``, row -> agent in the report's order)."""
    from priqn.analysis.curves import panels, reference_row, row_kinds

    rows = [row for row in agents if row in set(curve["row"])]
    return sample_efficiency_figure(
        curve,
        panels(rows, row_kinds(dict(agents))),
        row_colors(list(agents)),
        reference_row(curve, agents),
    )


def _frame_efficiency_panel(ax: plt.Axes, title: str) -> None:
    """A panel of :func:`sample_efficiency_figure` around its curves: title, the success
    axis from 0 to 1, grid, and the rows' legend outside on the right."""
    ax.set_title(title, fontsize=9, loc="left")
    ax.set_ylim(-0.03, 1.03)
    ax.grid(True, color="0.9")
    ax.set_ylabel("hold-out success", fontsize=8)
    ax.tick_params(labelsize=8)
    ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=7, frameon=False)


def _draw_reference_line(ax: plt.Axes, curve: pd.DataFrame, reference: str, color: Any) -> None:
    """The ``reference`` row's in-training line, dotted, in a panel of
    :func:`sample_efficiency_figure` that does not hold it."""
    from priqn.analysis.curves import PERIODIC

    ref = curve[(curve["row"] == reference) & (curve["source"] == PERIODIC)]
    ax.plot(
        ref["budget"],
        ref["mean"],
        color=color,
        lw=1.0,
        ls=":",
        label=f"{reference} (for reference)",
    )


def _efficiency_style_handles(curve: pd.DataFrame) -> list[Any]:
    """The figure-wide legend of :func:`sample_efficiency_figure`: what the line with its
    band and what the markers are, each only where ``curve`` draws it."""
    from priqn.analysis.curves import PERIODIC, SNAPSHOT

    sources = set(curve["source"])
    handles = []
    if PERIODIC in sources:
        text = (
            f"in-training evaluation ({_episodes_text(curve, PERIODIC)} episodes per seed): "
            "mean over seeds, band = 95 % bootstrap CI over seeds"
        )
        handles.append(plt.Line2D([], [], color="0.3", lw=1.4, label=text))
    if SNAPSHOT in sources:
        text = (
            f"full hold-out evaluation ({_episodes_text(curve, SNAPSHOT)} episodes per seed) "
            "of the final policy / kept snapshots: mean, 95 % CI"
        )
        handles.append(
            plt.Line2D([], [], color="0.3", marker="o", mec="black", mew=0.5, ls="", label=text)
        )
    return handles


OUTCOME_COLORS: dict[str, str] = dict(
    zip(OUTCOMES, ("tab:green", "tab:red", "tab:orange", "tab:gray"), strict=True)
)
"""Bar colour of each episode outcome (:data:`priqn.analysis.tables.OUTCOMES`, in order)."""


def outcomes_figure(frame: pd.DataFrame, order: list[str], by: str = "command") -> plt.Figure:
    """Stacked bars: how each policy's episodes end, one panel per policy (``label``), one
    bar per value of ``by`` in the order they first appear (a route command, or a budget).

    ``frame`` is :func:`priqn.analysis.tables.outcomes_by_command`'s table, or any with
    the columns ``label``, ``by`` and the outcome rates :data:`OUTCOME_COLORS` names.
    """
    bars = list(dict.fromkeys(frame[by]))
    labels = [label for label in order if label in set(frame["label"])]
    ncols = min(len(labels), 7)
    nrows = -(-len(labels) // ncols)
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(1.2 + 1.3 * ncols, 0.4 + 2.9 * nrows), sharey=True, squeeze=False
    )
    for ax in axes.flat[len(labels) :]:
        ax.set_visible(False)
    for ax, label in zip(axes.flat, labels, strict=False):
        mine = frame[frame["label"] == label].set_index(by).reindex(bars)
        bottom = np.zeros(len(bars))
        for outcome, color in OUTCOME_COLORS.items():
            values = mine[outcome].fillna(0.0).to_numpy(float)
            ax.bar(bars, values, bottom=bottom, color=color, label=outcome.replace("_", "-"))
            bottom += values
        ax.set_title(textwrap.fill(label, 14), fontsize=8)
        ax.tick_params(axis="x", labelsize=7, rotation=45)
        ax.set_ylim(0, 1)
    for row in axes:
        row[0].set_ylabel("fraction of episodes")
    handles, names = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, names, loc="upper center", ncol=4, fontsize=8, bbox_to_anchor=(0.5, 1.08))
    fig.tight_layout()
    return fig


CLAIM_WORD_COLORS = {
    "reproduced": "tab:green",
    "contradicted": "tab:red",
    "paper's effect ruled out": "tab:orange",
    "equivalent": "tab:cyan",
    "inconclusive": "tab:gray",
}
"""Colour of each verdict word in :func:`claims_figure`."""


def claims_figure(results: Sequence[ClaimResult]) -> plt.Figure | None:
    """Every measured primary success-rate comparison of the claims as a forest plot.

    Bar: the Welch 95 % interval over training seeds (coloured by the comparison's verdict
    word), cut at ±100 points (a difference of two rates cannot leave them); dot: the
    difference; diamond: the paper's difference where it gives one. None when no success
    comparison is measured.
    """
    rows = [
        (r.claim.key, x) for r in results for x in r.results if x.comparison.metric == "success"
    ]
    if not rows:
        return None
    fig, ax = plt.subplots(figsize=(8.5, 0.32 * len(rows) + 1.4))
    ax.axvline(0, color="0.4", lw=0.8, zorder=1)
    labels = []
    for i, (key, x) in enumerate(rows):
        c = x.comparison
        labels.append(
            f"{key}: {c.first.render()} − {c.second.render()} ({x.n_first} vs {x.n_second})"
        )
        lo, hi = (float(np.clip(100 * v, -100, 100)) for v in (x.lo, x.hi))
        ax.plot([lo, hi], [i, i], color=CLAIM_WORD_COLORS[x.word], lw=4, zorder=3)
        ax.plot(100 * x.diff, i, "o", color="black", ms=3, zorder=4)
        if c.paper is not None:
            ax.plot(100 * c.paper, i, "D", mfc="none", mec="tab:blue", ms=6, zorder=4)
        if i and rows[i - 1][0] != key:
            ax.axhline(i - 0.5, color="0.75", lw=0.5)
    ax.set_yticks(range(len(rows)), labels, fontsize=7)
    ax.set_ylim(len(rows) - 0.5, -0.5)
    ax.set_xlim(-100, 100)
    ax.set_xlabel("success-rate difference on the endpoint (mean over densities), points")
    used = {x.word for _, x in rows}
    handles = [
        plt.Line2D([], [], color=color, lw=4, label=word)
        for word, color in CLAIM_WORD_COLORS.items()
        if word in used
    ] + [plt.Line2D([], [], ls="", marker="D", mfc="none", mec="tab:blue", label="paper")]
    legend_above(
        ax,
        handles,
        "The paper's claims: Welch 95 % intervals over training seeds (seeds per row)",
        ncol=3,
    )
    return fig


def seed_success_figure(episodes: pd.DataFrame, order: list[str]) -> plt.Figure:
    """Each policy's success rate per training seed (every density, net and evaluation
    run pooled): one dot per seed, a bar at their mean. Shows at a glance how far apart
    training seeds land next to how far apart the rows are."""
    rates = episodes.groupby(["label", "train_seed"])["success"].mean().astype(float)
    labels = [label for label in order if label in rates.index.get_level_values("label")]
    seeds = sorted(rates.index.get_level_values("train_seed").unique())
    colors = dict(zip(seeds, plt.get_cmap("tab10").colors, strict=False))
    fig, ax = plt.subplots(figsize=(6.5, 0.3 * len(labels) + 1.2))
    for i, label in enumerate(labels):
        mine = rates.loc[label]
        ax.plot([mine.mean()] * 2, [i - 0.3, i + 0.3], color="black", lw=1.5, zorder=2)
        for seed, rate in mine.items():
            ax.plot(rate, i, "o", color=colors[seed], ms=5, alpha=0.85, zorder=3)
    ax.set_yticks(range(len(labels)), labels, fontsize=7)
    ax.set_ylim(len(labels) - 0.5, -0.5)
    ax.set_xlim(0, 1)
    ax.grid(axis="x", color="0.9")
    ax.set_xlabel("success rate (all densities)")
    handles = [
        plt.Line2D([], [], ls="", marker="o", color=colors[s], label=f"seed {s}") for s in seeds
    ] + [plt.Line2D([], [], color="black", lw=1.5, label="mean over seeds")]
    legend_above(ax, handles, "Success rate per training seed", ncol=len(handles))
    return fig


def looks_figure(designs: Sequence[tuple[SequentialSpec, Looks]], title: str) -> Any:
    """The monitoring chart of one or more designs (the ``[sequential]`` table, or each
    ``[[question]]`` with its looks): one panel per comparison, its estimate at each look
    taken (dot, Welch 95 % interval) inside the band AdaStop would not decide at that look
    (grey, ±the look's ``needed``), with 0 and the paper's difference marked. A dot outside
    its band is a difference found (orange); AdaStop's "equal" at the last look stays
    black; the looks still to come are empty slots. A question's panels name it
    (``success: ...``). None before the first look of any design."""
    panels = [(d, r, c) for d, r in designs if r.looks for c in d.comparisons]
    if not panels:
        return None
    ncols = min(2, len(panels))
    nrows = -(-len(panels) // ncols)
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(3.9 * ncols, 2.5 * nrows + 0.6), sharey=True, squeeze=False
    )
    for ax, (design, result, c) in zip(axes.flat, panels, strict=False):
        K = len(design.interims)
        ax.axhline(0, color="0.6", lw=0.8)
        if c.paper_difference is not None:
            ax.axhline(100 * c.paper_difference, color="tab:red", ls="--", lw=1)
        for look in result.looks:
            _draw_look(ax, look, c)
        ax.set_xticks(range(1, K + 1), [f"{n}" for n in design.interims], fontsize=8)
        ax.set_xlim(0.4, K + 0.6)
        ax.set_xlabel("seeds per row at the look", fontsize=8)
        name = f"{design.name}: {c.name}" if design.name else c.name
        ax.set_title(textwrap.fill(f"{name}: {row_verdict(design, result, c)}", 58), fontsize=8)
        ax.tick_params(axis="y", labelsize=8)
    for ax in axes.flat[len(panels) :]:
        ax.set_visible(False)
    for ax in axes[:, 0]:
        ax.set_ylabel("difference, points", fontsize=8)
    _looks_legend(fig, title)
    return fig


def _draw_look(ax: Any, look: Look, c: ComparisonSpec) -> None:
    """Comparison ``c`` at one look of :func:`looks_figure`: the band AdaStop would not
    decide in (while ``c`` is open, and at the look that decides it), then the estimate
    with its Welch interval, orange once a difference is found."""
    row = next(x for x in look.comparisons if x.name == c.name)
    needed = look.needed.get(c.family)
    if needed is not None and row.decided_at in (None, look.k):
        if np.isfinite(needed):
            ax.fill_between(
                [look.k - 0.3, look.k + 0.3],
                -100 * needed,
                100 * needed,
                color="0.88",
                lw=0,
                zorder=0,
            )
        else:  # too few splits to reject anything: the whole column
            ax.axvspan(look.k - 0.3, look.k + 0.3, color="0.88", lw=0, zorder=0)
    # Orange once AdaStop has found a difference (its decision after this look);
    # "equal" at the last look is no difference found: black, inside its band.
    decided = row.decision in ("larger", "smaller")
    ax.errorbar(
        look.k,
        100 * row.diff,
        yerr=[[100 * (row.diff - row.lo)], [100 * (row.hi - row.diff)]],
        fmt="o",
        color="tab:orange" if decided else "black",
        ms=4,
        lw=1,
        capsize=2,
    )


def _looks_legend(fig: Any, title: str) -> None:
    """The title and one legend row above the panels of :func:`looks_figure`: estimate,
    difference found, undecided band, paper's difference."""
    handles = [
        plt.Line2D([], [], color="black", marker="o", ms=4, lw=1, label="estimate, 95 % Welch"),
        plt.Line2D([], [], color="tab:orange", marker="o", ms=4, lw=1, label="difference found"),
        plt.Rectangle((0, 0), 1, 1, color="0.88", label="not decided at that look"),
        plt.Line2D([], [], color="tab:red", ls="--", lw=1, label="paper's difference"),
    ]
    top = 1 - 0.45 / fig.get_figheight()  # room for the title and the legend's row
    fig.suptitle(title, y=0.995, fontsize=10)
    fig.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, 1 - 0.3 / fig.get_figheight()),
        ncol=4,
        fontsize=7,
        frameon=False,
    )
    fig.tight_layout(rect=(0, 0, 1, top))
