"""Table II (driving metrics) and Table I (objective returns) as data, Markdown, LaTeX, CSV.

Statistics (both tables): a **unit** is one (training seed, evaluation run) pair of a
policy; its value at a density is the mean over all its episodes at that density
(all hold-out nets pooled; every net has the same number of episodes). A table cell
is ``mean ± std`` over the units, std the **sample** standard deviation (ddof=1;
"n/a" with a single unit).

Best / second (per column, per density): policies are ranked on the mean *as
printed* (rounded to the table's decimals), lowest first for ↓ columns, highest
first for ↑ columns; equal printed means share a rank (dense ranking). Every row
with the best value is **bold**, every row with the next distinct value is
underlined. NaN means are never marked. This makes ties deterministic and visible.

Δ% (Table I) = 100 · (mean_policy − mean_ref) / |mean_ref| with ref the IQN policy
at the same density, so a positive Δ% is always an improvement (the returns are
mostly penalties, i.e. negative).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from priqn.agents.config import SHIPPED_AGENTS
from priqn.agents.labels import CHECK, CROSS, DASH, PolicyLabel, flag_value
from priqn.analysis.load import CONFIG_COLUMNS, config_key
from priqn.analysis.render import csv_text, markdown_table, percent
from priqn.objectives import OBJECTIVES, OUTCOMES, names_in_columns

AGENT_ORDER: tuple[str, ...] = tuple(SHIPPED_AGENTS)
"""Row order of agents (the paper's, as registered); unknown agents follow alphabetically."""
COMPARATOR_ORDER: tuple[str, ...] = ("mv", "cvar", "qd", "fsd")
"""Row order of the Pr-IQN comparators (the paper's: MV, CVaR, QD; then ours)."""


@dataclass(frozen=True)
class MetricColumn:
    """One evaluation column of a table."""

    name: str
    """Header, e.g. ``CR``."""
    column: str
    """Episode-table column averaged."""
    higher_is_better: bool
    """Direction for best / second."""
    decimals: int
    """Printed decimals (ranking uses the printed value)."""
    ranked: bool = True
    """Mark best / second (False for descriptive columns such as episode length)."""

    @property
    def header(self) -> str:
        if not self.ranked:
            return self.name
        return f"{self.name} {'↑' if self.higher_is_better else '↓'}"


TABLE2_METRICS: tuple[MetricColumn, ...] = (
    MetricColumn("CR", "collision", False, 3),
    MetricColumn("OR", "off_road", False, 3),
    MetricColumn("SR", "success", True, 3),
    MetricColumn("RP", "route_progress", True, 3),
)
TABLE1_METRICS: tuple[MetricColumn, ...] = (
    MetricColumn("Safety", "return_safety", True, 2),
    MetricColumn("Risk", "return_risk", True, 2),
    MetricColumn("Lane keeping", "return_lane_keeping", True, 2),
    # An early crash collects fewer risk and lane penalties: per-decision means and the
    # episode length show whether a better episode return is only a shorter episode.
    MetricColumn("Risk / decision", "risk_per_decision", True, 3),
    MetricColumn("Lane / decision", "lane_keeping_per_decision", True, 3),
    MetricColumn("Length", "steps", True, 1, ranked=False),
)
PER_DECISION: dict[str, str] = {
    "risk_per_decision": "return_risk",
    "lane_keeping_per_decision": "return_lane_keeping",
}
"""Derived Table I columns: episode return / episode length (decisions)."""
CONFIG_HEADERS: tuple[str, ...] = (
    "Policy",
    "Comparison metric",
    "Training preorder",
    "Threshold ε",
    "Partial order",
)


def policy_sort_key(key: tuple) -> tuple:
    """Sort key of a configuration ``(agent, comparator, train_preorder, eps, partial_order)``.

    The paper's order: IQN, Ensemble, MA-IQN, then Pr-IQN by comparator (MV, CVaR,
    QD), partial order off before on, larger eps first, training preorder off first.
    """
    agent, comparator, train_preorder, eps, partial = key
    a = AGENT_ORDER.index(agent) if agent in AGENT_ORDER else len(AGENT_ORDER)
    c = (
        COMPARATOR_ORDER.index(comparator)
        if comparator in COMPARATOR_ORDER
        else len(COMPARATOR_ORDER)
    )
    try:
        e = -float(eps) if eps is not None else 0.0
    except (TypeError, ValueError):  # per-objective thresholds, e.g. "[0.2, 0.4]"
        e = 0.0
    return (
        a,
        str(agent),
        c,
        str(comparator),
        bool(flag_value(partial)),
        e,
        bool(flag_value(train_preorder)),
    )


def policy_configs(episodes: pd.DataFrame) -> dict[str, tuple]:
    """Label -> configuration tuple, in table order (ties broken by label)."""
    per_label = episodes.drop_duplicates("label").set_index("label")
    configs = {str(label): config_key(row) for label, row in per_label.iterrows()}
    return dict(sorted(configs.items(), key=lambda kv: (policy_sort_key(kv[1]), kv[0])))


def policy_order(episodes: pd.DataFrame) -> list[str]:
    """Policy labels in table order."""
    return list(policy_configs(episodes))


def config_cells(key: tuple, label: str | None = None) -> list[str]:
    """The five configuration cells of a row, rendered like the paper.

    A label with words beyond the paper's columns (our rows: ``Pr-IQN QD ✓ 0.2 ✗ scaled``,
    ``IQN hln-4``) shows them beside the policy name, so such rows stay distinguishable.
    """
    row = dict(zip(CONFIG_COLUMNS, key, strict=True), label=label or "")
    policy = PolicyLabel.from_row(row)
    cells = policy.cells()
    if policy.extra:
        cells[0] += f" ({' '.join(policy.extra)})"
    return cells


def unit_values(episodes: pd.DataFrame, columns: Sequence[str]) -> pd.DataFrame:
    """Per (label, density, train_seed, eval_run) mean of ``columns`` over episodes."""
    return (
        episodes.groupby(["label", "density", "train_seed", "eval_run"], sort=True)[list(columns)]
        .mean()
        .astype(float)
    )


def summarise(
    episodes: pd.DataFrame,
    metrics: Sequence[MetricColumn],
    order: Sequence[str],
    ranked: bool = True,
) -> pd.DataFrame:
    """Long table: one row per (density, label, metric) with mean, std (ddof=1), n, mark.

    ``ranked=False`` leaves every mark empty (too few training seeds to rank policies).
    """
    units = unit_values(episodes, [m.column for m in metrics])
    grouped = units.groupby(level=["density", "label"], sort=True)
    mean, std, n = grouped.mean(), grouped.std(ddof=1), grouped.count()
    rows = []
    for density in sorted(episodes["density"].unique()):
        for label in order:
            if (density, label) not in mean.index:
                continue
            for m in metrics:
                rows.append(
                    {
                        "density": float(density),
                        "label": label,
                        "metric": m.name,
                        "mean": float(mean.loc[(density, label), m.column]),
                        "std": float(std.loc[(density, label), m.column]),
                        "n": int(n.loc[(density, label), m.column]),
                    }
                )
    long = pd.DataFrame(rows, columns=["density", "label", "metric", "mean", "std", "n"])
    long["mark"] = ""
    for m in metrics if ranked else ():
        for density in long["density"].unique():
            sel = (long["metric"] == m.name) & (long["density"] == density)
            long.loc[sel, "mark"] = best_marks(long.loc[sel, "mean"].to_numpy(), m)
    return long


def best_marks(means: np.ndarray, metric: MetricColumn) -> list[str]:
    """``"best"`` / ``"second"`` / ``""`` per entry (dense ranking of printed means)."""
    if not metric.ranked:
        return [""] * len(means)
    printed = [None if not np.isfinite(v) else round(float(v), metric.decimals) for v in means]
    distinct = sorted({v for v in printed if v is not None}, reverse=metric.higher_is_better)
    best = distinct[0] if distinct else None
    second = distinct[1] if len(distinct) > 1 else None
    return [
        "best" if v is not None and v == best else "second" if v is not None and v == second else ""
        for v in printed
    ]


def add_delta(long: pd.DataFrame, reference: str | None) -> pd.DataFrame:
    """Add ``delta_pct`` = 100 (mean − ref) / |ref| per density and metric (NaN if no ref)."""
    out = long.copy()
    out["delta_pct"] = np.nan
    if reference is None:
        return out
    ref = out[out["label"] == reference].set_index(["density", "metric"])["mean"]
    for i, row in out.iterrows():
        r = ref.get((row["density"], row["metric"]))
        if r is not None and np.isfinite(r) and r != 0:
            out.at[i, "delta_pct"] = 100.0 * (row["mean"] - r) / abs(r)
    return out


def baseline_label(configs: dict[str, tuple]) -> str | None:
    """The IQN policy's label (first in order), the baseline of Table I's Δ%, or None when
    no IQN was evaluated."""
    return next((label for label, key in configs.items() if key[0] == "iqn"), None)


@dataclass(frozen=True)
class Table:
    """A summarised table ready to render."""

    title: str
    """Caption."""
    long: pd.DataFrame
    """Rows (density, label, metric, mean, std, n, mark[, delta_pct])."""
    metrics: tuple[MetricColumn, ...]
    """Evaluation columns in order."""
    configs: dict[str, tuple]
    """Label -> configuration, in row order."""
    with_delta: bool = False
    """Show Δ% next to every value (Table I)."""
    references: tuple[str, ...] = ()
    """Labels of reference-driver rows (``priqn report --reference``): in ``long``, shown
    after the policies with dashes for the configuration, never ranked nor marked."""


def table2(
    episodes: pd.DataFrame,
    ranked: bool = True,
    references: pd.DataFrame | None = None,
    reference_order: Sequence[str] = (),
) -> Table:
    """Table II: CR, OR, SR, RP per density and policy configuration.

    ``references``: reference drivers' episodes (rows ``reference_order``), summarised the
    same way but apart, so they never take part in the best / second marks.
    """
    configs = policy_configs(episodes)
    long = summarise(episodes, TABLE2_METRICS, list(configs), ranked)
    if references is not None and len(references):
        refs = summarise(references, TABLE2_METRICS, list(reference_order), ranked=False)
        long = pd.concat([long, refs], ignore_index=True)
    return Table(
        "Table II: driving metrics (mean ± sample std over training seeds × evaluation runs)",
        long,
        TABLE2_METRICS,
        configs,
        references=tuple(reference_order) if references is not None and len(references) else (),
    )


def _rows(table: Table) -> list[tuple[str, tuple, bool]]:
    """``(label, configuration, is a reference)`` of every row in order: the policies, then
    the reference drivers (no configuration)."""
    none = (None,) * len(CONFIG_COLUMNS)
    rows = [(label, key, False) for label, key in table.configs.items()]
    return rows + [(label, none, True) for label in table.references]


def reference_cells(label: str) -> list[str]:
    """The configuration cells of a reference driver's row: its name, then dashes."""
    return [label, *[DASH] * (len(CONFIG_HEADERS) - 1)]


def table1(episodes: pd.DataFrame, ranked: bool = True) -> Table:
    """Table I: safety / risk / lane-keeping episode returns with Δ% relative to IQN,
    per-decision risk and lane keeping, and the mean episode length.

    Columns follow the runs' objectives: one a run did not drive with (``env.objectives``)
    has no column, one it declared beyond the default five gets one."""
    steps = episodes["steps"].where(episodes["steps"] > 0)  # -1: length not recorded
    per_decision = {k: v for k, v in PER_DECISION.items() if v in episodes.columns}
    episodes = episodes.assign(**{k: episodes[v] / steps for k, v in per_decision.items()})
    configs = policy_configs(episodes)
    returns, derived = (
        [m for m in part if m.column in episodes.columns]
        for part in (TABLE1_METRICS[:3], TABLE1_METRICS[3:])
    )
    metrics = (*returns, *declared_metrics(episodes), *derived)
    long = add_delta(summarise(episodes, metrics, list(configs), ranked), baseline_label(configs))
    return Table(
        "Table I: episode returns per objective, per-decision means and episode length "
        "(mean ± sample std over training seeds × evaluation runs) and Δ% relative to IQN",
        long,
        metrics,
        configs,
        with_delta=True,
    )


def declared_metrics(episodes: pd.DataFrame) -> tuple[MetricColumn, ...]:
    """Table I columns of the objectives a run declared beyond the default five
    (``return_<name>`` columns of ``env.objectives``, e.g. ``right_of_way``)."""
    extra = [n for n in names_in_columns(list(episodes.columns)) if n not in OBJECTIVES]
    return tuple(
        MetricColumn(n.replace("_", " ").capitalize(), f"return_{n}", True, 2) for n in extra
    )


# ----------------------------------------------------------------------------- rendering


def _value(row: pd.Series, metric: MetricColumn) -> str:
    d = metric.decimals
    std = "n/a" if not np.isfinite(row["std"]) else f"{row['std']:.{d}f}"
    return f"{row['mean']:.{d}f} ± {std}"


def _delta(row: pd.Series) -> str:
    v = row.get("delta_pct", np.nan)
    return DASH if not np.isfinite(v) else f"{v:+.1f}%"


def _cells(table: Table, density: float, label: str) -> list[tuple[str, str, str]]:
    """(value text, mark, delta text) per metric for one row."""
    sel = table.long[(table.long["density"] == density) & (table.long["label"] == label)]
    by_metric = {row["metric"]: row for _, row in sel.iterrows()}
    out = []
    for m in table.metrics:
        row = by_metric.get(m.name)
        if row is None:
            out.append((DASH, "", DASH))
        else:
            out.append((_value(row, m), row["mark"], _delta(row)))
    return out


def _headers(table: Table) -> list[str]:
    heads = list(CONFIG_HEADERS)
    for m in table.metrics:
        heads.append(m.header)
        if table.with_delta:
            heads.append(f"Δ% {m.name}")
    return heads


def _density_label(density: float) -> str:
    """0.5 → "0.5", 1 → "1.0": at least one decimal, as in the paper's tables."""
    text = f"{density:g}"
    return text if "." in text or "e" in text else f"{text}.0"


def to_markdown(table: Table) -> str:
    """GitHub Markdown: best **bold**, second <u>underlined</u>, densities as row groups."""
    heads = _headers(table)
    lines = [
        f"**{table.title}**",
        "",
        "| " + " | ".join(heads) + " |",
        "|"
        + "|".join(":--" if i < len(CONFIG_HEADERS) else "--:" for i in range(len(heads)))
        + "|",
    ]
    for density in sorted(table.long["density"].unique()):
        lines.append(f"| *Traffic density {_density_label(density)}* |" + " |" * (len(heads) - 1))
        for label, key, reference in _rows(table):
            if not ((table.long["density"] == density) & (table.long["label"] == label)).any():
                continue
            row = config_cells(key, label)
            if reference:
                row = [f"*{label}*", *reference_cells(label)[1:]]
            for text, mark, delta in _cells(table, density, label):
                row.append(
                    f"**{text}**"
                    if mark == "best"
                    else f"<u>{text}</u>"
                    if mark == "second"
                    else text
                )
                if table.with_delta:
                    row.append(delta)
            lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def _tex_escape(text: str) -> str:
    return (
        text.replace("\\", r"\textbackslash{}")
        .replace("&", r"\&")
        .replace("%", r"\%")
        .replace("_", r"\_")
        .replace("#", r"\#")
        .replace(CHECK, r"\checkmark")
        .replace(CROSS, r"$\times$")
        .replace(DASH, "--")
        .replace("ε", r"$\epsilon$")
        .replace("↑", r"$\uparrow$")
        .replace("↓", r"$\downarrow$")
        .replace("Δ", r"$\Delta$")
        .replace("±", r"$\pm$")
        .replace("×", r"$\times$")
    )


def to_latex(table: Table) -> str:
    """LaTeX (booktabs, amssymb): best \\textbf, second \\underline."""
    heads = _headers(table)
    n_cfg = len(CONFIG_HEADERS)
    spec = "l" * n_cfg + "r" * (len(heads) - n_cfg)
    lines = [
        "% requires \\usepackage{booktabs,amssymb}",
        "\\begin{table}[t]",
        "\\centering",
        f"\\caption{{{_tex_escape(table.title)}}}",
        f"\\begin{{tabular}}{{{spec}}}",
        "\\toprule",
        " & ".join(_tex_escape(h) for h in heads) + " \\\\",
    ]
    for density in sorted(table.long["density"].unique()):
        lines.append("\\midrule")
        lines.append(
            f"\\multicolumn{{{len(heads)}}}{{l}}{{\\textit{{Traffic density {_density_label(density)}}}}} \\\\"
        )
        lines.append("\\midrule")
        for label, key, reference in _rows(table):
            if not ((table.long["density"] == density) & (table.long["label"] == label)).any():
                continue
            row = [_tex_escape(c) for c in config_cells(key, label)]
            if reference:
                cells = reference_cells(label)
                row = [f"\\textit{{{_tex_escape(cells[0])}}}", *map(_tex_escape, cells[1:])]
            for text, mark, delta in _cells(table, density, label):
                t = _tex_escape(text)
                row.append(
                    f"\\textbf{{{t}}}"
                    if mark == "best"
                    else f"\\underline{{{t}}}"
                    if mark == "second"
                    else t
                )
                if table.with_delta:
                    row.append(_tex_escape(delta))
            lines.append(" & ".join(row) + " \\\\")
    lines += ["\\bottomrule", "\\end{tabular}", "\\end{table}"]
    return "\n".join(lines) + "\n"


def to_csv(table: Table) -> str:
    """Raw numbers, one row per (density, policy): ``<M>_mean, <M>_std, <M>_n, <M>_mark``."""
    records = []
    for density in sorted(table.long["density"].unique()):
        for label, key, reference in _rows(table):
            sel = table.long[(table.long["density"] == density) & (table.long["label"] == label)]
            if sel.empty:
                continue
            rec: dict[str, object] = {"density": density, "label": label}
            rec.update(
                {c: ("" if v is None else v) for c, v in zip(CONFIG_COLUMNS, key, strict=True)}
            )
            if table.references:  # only then: a report without references stays as it was
                rec["reference"] = reference
            for _, row in sel.iterrows():
                name = row["metric"].lower().replace(" ", "_")
                rec[f"{name}_mean"] = row["mean"]
                rec[f"{name}_std"] = row["std"]
                rec[f"{name}_n"] = row["n"]
                rec[f"{name}_mark"] = row["mark"]
                if table.with_delta:
                    rec[f"{name}_delta_pct"] = row["delta_pct"]
            records.append(rec)
    return csv_text(pd.DataFrame(records))


COMMAND_ORDER: tuple[str, ...] = ("left", "straight", "right")
"""Column order of the route commands; others follow alphabetically."""


def route_commands(episodes: pd.DataFrame) -> pd.Series:
    """Each episode's route command as text (``unknown`` where none was recorded)."""
    return episodes["command"].fillna("").astype(str).replace("", "unknown")


def outcomes_by_command(episodes: pd.DataFrame, order: Sequence[str]) -> pd.DataFrame:
    """How each policy's episodes end, per route command, densities pooled.

    One row per (policy, command) in table order: ``episodes`` (count) and the fraction of
    them ending in each of :data:`OUTCOMES` (they sum to 1). Shows *why* a success rate is
    low — e.g. a policy that never completes a left turn because it waits until the time
    limit — which Table II's per-density means hide.
    """
    command_E = route_commands(episodes)
    commands = sorted(
        command_E.unique(),
        key=lambda c: (COMMAND_ORDER.index(c) if c in COMMAND_ORDER else len(COMMAND_ORDER), c),
    )
    rows = []
    for label in order:
        mine = episodes["label"] == label
        for command in commands:
            part = episodes[mine & (command_E == command)]
            if part.empty:
                continue
            fractions = {o: float(part[o].astype(bool).mean()) for o in OUTCOMES}
            rows.append({"label": label, "command": command, "episodes": len(part), **fractions})
    return pd.DataFrame(rows, columns=["label", "command", "episodes", *OUTCOMES])


def outcomes_markdown(frame: pd.DataFrame) -> str:
    """The outcome table as Markdown: one row per (policy, command), percentages."""
    rows = [
        [
            row.label,
            row.command,
            str(row.episodes),
            *(percent(getattr(row, o), 0) for o in OUTCOMES),
        ]
        for row in frame.itertuples(index=False)
    ]
    heads = ["Policy", "Command", "Episodes", "Success", "Collision", "Off-road", "Timeout"]
    return markdown_table(heads, rows, "llrrrrr") + "\n"
