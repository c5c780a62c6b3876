"""An evaluation design's report (kind ``evaluation``): committed policies of earlier
experiments played on another scenario family, and the pre-registered questions asked of
them (``priqn report --evaluation out-of-range``; the design:
:mod:`priqn.evaluation.design`).

Frames, then estimates, then sections, rendered by :func:`priqn.analysis.artifacts.render`:

1. **frames** (:func:`read_scores`): per source design, row, training seed and evaluation
   (the in-range hold-out one the source names, and the family's
   ``eval-family-<family>/``) the outcome rates, each density weighted equally (nets pooled
   within a density), as the designs score a seed; and the violation and success rates per
   net feature level (:func:`net_features`);
2. **estimates** (:func:`decide`): per endpoint, ``a − b`` per source by Welch over training
   seeds, p the larger of Welch's and the permutation test's (:func:`priqn.analysis.inference.seed_test`),
   Holm across the sources; the words of docs/statistics.md;
3. **sections**: the verdicts, the outcome mix, the paired drops from in range, the
   violations by net feature, and the cells.

A design whose cells are not all evaluated is refused with the command that evaluates the
first missing one, or with ``--partial`` reported as far as it goes, every verdict
``pending``: Holm decides the sources together.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from priqn.agents.labels import seeds_text
from priqn.analysis import inference
from priqn.analysis.load import read_episodes
from priqn.analysis.mixes import paired_changes
from priqn.analysis.questions import OUTCOME_RATES, seed_rates
from priqn.analysis.render import interval, markdown_table, percent, points
from priqn.analysis.sections import Report, Section
from priqn.errors import PriqnError
from priqn.evaluation.design import FEATURES, net_features
from priqn.evaluation.protocol import FAMILY_PREFIX, recorded_traffic
from priqn.experiment import cell_dir_parts
from priqn.io import read_json
from priqn.run.evaluations import evaluation_complete, evaluation_dir
from priqn.run.folder import RunFolder

WHERE = ("in range", "out of range")
"""The two evaluations of every cell: its in-range hold-out one and the family's."""
ENDPOINTS = ("success", "violation")
"""The questions' endpoints, in the order their tests draw from the report's generator."""
RATES = tuple(OUTCOME_RATES)
"""Every rate of a seed's table: the endpoints, timeouts and the violation's two parts."""


@dataclasses.dataclass(frozen=True)
class Frames:
    """What the report reads from the cells."""

    scores: pd.DataFrame
    """One row per (source, row, seed, where): ``source, role, row, label, seed, where,
    episodes`` and every rate of :data:`RATES` (fractions)."""
    features: pd.DataFrame
    """One row per (source, row, seed, feature, level): ``nets`` (how many) and the
    violation and success rates over those nets' out-of-range episodes."""
    missing: tuple[str, ...]
    """Cell folders whose out-of-range (or in-range) evaluation is not complete."""
    cells: int
    """Cells the design names."""
    family_hash: str
    """The family's manifest hash every out-of-range evaluation recorded ('' if none yet)."""


def read_scores(design: Any, root: str | Path = ".") -> Frames:
    """Every named cell's rates in range and out of range (:class:`Frames`); a cell whose
    evaluations disagree on the traffic or the episode limit is a one-line error."""
    name = f"{FAMILY_PREFIX}{design.design.family}"
    nets = pd.DataFrame(net_features(design.design.family, design.design.feature_skew_split_deg))
    scores, features, missing, hashes = [], [], [], set()
    for source in design.source:
        for cell in source.cell_dirs(root):
            folder = RunFolder(cell)
            if not (
                evaluation_complete(folder, name) and evaluation_complete(folder, source.in_range)
            ):
                missing.append(str(cell))
                continue
            both = [evaluation_dir(folder, source.in_range), evaluation_dir(folder, name)]
            envs = [read_json(d / RunFolder.META)["env_config"] for d in both]
            played = [
                {"traffic": recorded_traffic(env), "max_episode_steps": env["max_episode_steps"]}
                for env in envs
            ]
            for key in ("traffic", "max_episode_steps"):
                if played[0][key] != played[1][key]:
                    raise PriqnError(
                        f"{both[1]}: env {key} {envs[1][key]!r} differs from {both[0].name}/'s "
                        f"{envs[0][key]!r}; the design plays each cell as its in-range evaluation"
                    )
            hashes.add(read_json(both[1] / RunFolder.META)["holdout_hash"])
            row, seed = cell_dir_parts(cell.name)
            for where, eval_dir in zip(WHERE, both, strict=True):
                episodes = read_episodes(eval_dir)
                key = {"source": source.experiment, "role": source.role, "row": row,
                       "label": str(episodes["label"].iloc[0]), "seed": seed}  # fmt: skip
                scores.append({**key, "where": where, "episodes": len(episodes),
                               **seed_rates(episodes)})  # fmt: skip
            played = episodes.merge(nets, on="net", how="left")
            for feature in FEATURES:
                for level, part in played.groupby(feature):
                    rates = seed_rates(part)
                    features.append({**key, "feature": feature, "level": level,
                                     "nets": part["net"].nunique(),
                                     "violation": rates["violation"], "success": rates["success"]})  # fmt: skip
    if len(hashes) > 1:
        raise PriqnError(
            f"{design.design.name}: the out-of-range evaluations played different nets "
            f"(manifest hashes {sorted(h[:12] for h in hashes)}); re-evaluate with one family"
        )
    cells = design.cells()
    return Frames(
        pd.DataFrame(scores), pd.DataFrame(features), tuple(missing), cells,
        next(iter(hashes), ""),
    )  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Verdict:
    """One question of one source: ``a − b`` out of range."""

    source: str
    endpoint: str
    seeds_a: int
    seeds_b: int
    mean_a: float
    mean_b: float
    diff: float
    lo: float
    """Two-sided 95 % Welch interval of ``diff`` (descriptive)."""
    hi: float
    hi_family: float
    """One-sided Welch upper bound at α / (number of sources): what rules the paper's effect out."""
    p: float
    p_holm: float
    word: str


def decide(design: Any, frames: Frames, seed: int) -> list[Verdict]:
    """Every source's two questions (:data:`ENDPOINTS`), Holm across the sources per
    endpoint; the permutation tests draw from ``numpy.random.default_rng(seed)`` in the
    order endpoint, source. Every word is ``pending`` while a cell is missing."""
    d = design.design
    rng = np.random.default_rng(seed)
    out = frames.scores[frames.scores["where"] == WHERE[1]]
    m = len(design.source)
    verdicts = []
    for endpoint in ENDPOINTS:
        items = []
        for source in design.source:
            own = out[out["source"] == source.experiment]
            a, b = (
                own[own["row"] == r].sort_values("seed")[endpoint].to_numpy() for r in (d.a, d.b)
            )
            if min(a.size, b.size) >= 2:
                items.append((source.experiment, a, b, inference.seed_test(a, b, rng)[0]))
        p_holm = inference.holm([p for *_, p in items])
        for (name, a, b, p), adjusted in zip(items, p_holm, strict=True):
            lo, hi = inference.welch_interval(a, b)
            hi_family = inference.upper_bound(a, b, d.alpha / m)
            diff = float(a.mean() - b.mean())
            if frames.missing:
                word = f"pending ({frames.cells - len(frames.missing)} of {frames.cells} cells)"
            elif endpoint == "success":
                word = inference.verdict_word(
                    "better", diff, hi_family, adjusted, d.alpha, d.paper_success_difference
                )
            elif adjusted <= d.alpha:
                word = "a violates more" if diff > 0 else "a violates less"
            else:
                word = f"no difference found at {min(a.size, b.size)} seeds"
            verdicts.append(
                Verdict(
                    name,
                    endpoint,
                    a.size,
                    b.size,
                    float(a.mean()),
                    float(b.mean()),
                    diff,
                    lo,
                    hi,
                    hi_family,
                    float(p),
                    float(adjusted),
                    word,
                )  # fmt: skip
            )
    return verdicts


def drops(frames: Frames) -> pd.DataFrame:
    """Per source and row: in range, out of range and the change (out − in) of success and
    violations, the mean of each seed's change with its 95 % t interval, and the seeds."""
    return paired_changes(frames.scores, ["source", "row", "label"], WHERE, ENDPOINTS)


def feature_table(frames: Frames) -> pd.DataFrame:
    """Per feature level, source and row: the mean over seeds of the violation and success
    rates on that level's nets, and the seeds and nets behind them."""
    keys = ["feature", "level", "source", "row", "label"]
    table = frames.features.groupby(keys, sort=False).agg(
        nets=("nets", "max"), seeds=("seed", "nunique"),
        violation=("violation", "mean"), success=("success", "mean"),
    )  # fmt: skip
    order = {f: i for i, f in enumerate(FEATURES)}
    return (
        table.reset_index()
        .sort_values(
            ["feature", "level"],
            key=lambda c: c.map(order) if c.name == "feature" else c,
            kind="stable",
        )  # fmt: skip
        .reset_index(drop=True)
    )


def _interval(lo: float, hi: float) -> str:
    """``[lo, hi]`` in points; "" where there is none (a row with one seed)."""
    return "" if math.isnan(lo) or math.isnan(hi) else interval(lo, hi)


def design_report(
    design: Any, command: str, seed: int, partial: bool, root: str | Path = "."
) -> Report:
    """The report of evaluation design ``design`` (:class:`~priqn.evaluation.design.EvaluationDesign`)
    over the cells under ``root``; refused while a cell is missing unless ``partial``."""
    frames = read_scores(design, root)
    if frames.missing and not partial:
        first = frames.missing[0]
        raise PriqnError(
            f"{first}: no complete evaluation on family {design.design.family!r} "
            f"({len(frames.missing)} of {frames.cells} cells missing); run 'priqn evaluate "
            f"{first} --family {design.design.family}' (the design's limit with --set "
            "max_episode_steps=N), or report what is in with --partial"
        )
    if frames.scores.empty:
        raise PriqnError(f"{design.design.name}: no cell is evaluated yet")
    verdicts = decide(design, frames, seed)
    sections = [
        _title(design, frames, command, seed),
        _verdict_section(design, verdicts),
        _drop_section(drops(frames), frames),
        _feature_section(feature_table(frames)),
        _cells_section(frames),
    ]
    meta = {
        "design": design.design.name,
        "family": design.design.family,
        "family_hash": frames.family_hash,
        "seed": seed,
        "partial": partial,
        "cells": frames.cells,
        "missing": list(frames.missing),
    }
    return Report("evaluation", "report.md", sections, command, design.design.name, meta)


def _title(design: Any, frames: Frames, command: str, seed: int) -> Section:
    d = design.design
    done = frames.cells - len(frames.missing)
    return Section(
        [
            f"# {d.name}: {d.description}",
            "",
            f"Made by `{command}`. Evaluation only: the committed policies of "
            f"{', '.join(s.experiment for s in design.source)} played on the family "
            f"`{d.family}` under their own traffic and evaluation limit. {done} of "
            f"{frames.cells} cells evaluated"
            + (" (partial: every verdict pending)." if frames.missing else ".")
            + f" Permutation tests drew from `numpy.random.default_rng({seed})`.",
            "",
        ]
    )


def _verdict_section(design: Any, verdicts: list[Verdict]) -> Section:
    d = design.design
    table = pd.DataFrame([dataclasses.asdict(v) for v in verdicts])
    role = {s.experiment: s.role for s in design.source}
    rows = [
        [
            v.source,
            role[v.source],
            v.endpoint,
            f"{v.seeds_a} / {v.seeds_b}",
            percent(v.mean_a),
            percent(v.mean_b),
            points(v.diff),
            _interval(v.lo, v.hi) or "– (one seed)",
            points(v.hi_family),
            "–" if math.isnan(v.p) else f"{v.p:.3g}",
            "–" if math.isnan(v.p_holm) else f"{v.p_holm:.3g}",
            v.word,
        ]  # fmt: skip
        for v in verdicts
    ]
    return Section(
        [
            f"## Verdicts: {d.a} (a) − {d.b} (b), out of range",
            "",
            "Per training seed, the rate over its out-of-range episodes (densities weighted "
            "equally). Success: one-sided against the paper's "
            f"{points(d.paper_success_difference)} points; violations (collision or off-road): "
            f"two-sided. Welch over seeds, p the larger of Welch's and the permutation test's, "
            f"Holm across the sources per endpoint at α = {d.alpha:g}. The interval is the "
            "descriptive 95 % one; the bound is the one-sided bound at α / (sources) that "
            "rules the paper's effect out.",
            "",
            (
                markdown_table(
                    [
                        "source",
                        "role",
                        "endpoint",
                        "seeds a / b",
                        "a",
                        "b",
                        "a − b (pts)",
                        "95 % interval",
                        "bound",
                        "p",
                        "p (Holm)",
                        "verdict",
                    ],  # fmt: skip
                    rows,
                )
                if rows
                else "No source has evaluated seeds of both rows yet: no verdict."
            ),
            "",
        ],
        tables={"verdicts": table},
    )


def _change_interval(row: Any, endpoint: str) -> str:
    """`` [lo, hi]`` of a row's mean change on ``endpoint``, or ``, one seed``."""
    interval = _interval(
        getattr(row, f"{endpoint}_change_lo"), getattr(row, f"{endpoint}_change_hi")
    )
    return f" {interval}" if interval else ", one seed"


def _drop_section(table: pd.DataFrame, frames: Frames) -> Section:
    rows = []
    for r in table.itertuples():
        rows.append(
            [r.source, r.label, str(r.seeds)]
            + [
                f"{percent(getattr(r, f'{e}_in'))} → {percent(getattr(r, f'{e}_out'))} "
                f"({points(getattr(r, f'{e}_change'))}{_change_interval(r, e)})"
                for e in ENDPOINTS
            ]
        )
    return Section(
        [
            "## From in range to out of range (descriptive)",
            "",
            "Each row's rate on its in-range hold-out evaluation and on the family, and the "
            "mean of the per-seed changes (out − in, points) with its 95 % t interval over "
            "seeds.",
            "",
            markdown_table(["source", "row", "seeds", "success", "violations"], rows),
            "",
            "![in range and out of range per seed](figures/seeds.png)",
            "",
        ],
        tables={"drops": table, "seeds": frames.scores},
        figures={"seeds": _seed_figure(frames.scores)},
    )


def _feature_section(table: pd.DataFrame) -> Section:
    columns = list(dict.fromkeys(zip(table["source"], table["label"], strict=True)))
    rows = []
    for (feature, level), part in table.groupby(["feature", "level"], sort=False):
        cell = {(r.source, r.label): r for r in part.itertuples()}
        rows.append(
            [feature, level, str(int(part["nets"].max()))]
            + [percent(cell[c].violation) if c in cell else "" for c in columns]
        )
    return Section(
        [
            "## Violations by net feature (descriptive)",
            "",
            "The violation rate on the nets of each feature level (mean over training seeds), "
            "per source and row. The designed features (lane width, skew, radius, lanes) "
            "each split the nets 4 / 4.",
            "",
            markdown_table(
                ["feature", "level", "nets", *(f"{s}: {label}" for s, label in columns)], rows
            ),
            "",
        ],
        tables={"features": table},
    )


def _cells_section(frames: Frames) -> Section:
    lines = ["## Cells", ""]
    if frames.missing:
        lines += [f"Not yet evaluated ({len(frames.missing)}):", ""]
        lines += [f"- `{cells}`: seeds {seeds}" for cells, seeds in _seed_ranges(frames.missing)]
    else:
        lines += [f"All {frames.cells} cells evaluated (per-seed rates: `tables/seeds.csv`)."]
    return Section([*lines, ""])


def _seed_ranges(cells: tuple[str, ...]) -> list[tuple[str, str]]:
    """Cell folders ``<grid>/<policy>__seed<k>`` folded per (grid, policy), in first-seen
    order: ``("results/x/iqn__seed*", "82–99")``."""
    seeds: dict[str, list[int]] = {}
    for cell in cells:
        stem, seed = cell_dir_parts(cell)
        seeds.setdefault(f"{stem}__seed*", []).append(seed)
    return [(stem, seeds_text(found)) for stem, found in seeds.items()]


def _seed_figure(scores: pd.DataFrame) -> plt.Figure:
    """Per source (columns) and endpoint (rows): each seed's rate in range and out of range,
    one line per seed, coloured by row."""
    from priqn.analysis.figures import row_colors

    sources = list(dict.fromkeys(scores["source"]))
    colors = row_colors(list(dict.fromkeys(scores["label"])))
    fig, axes = plt.subplots(
        len(ENDPOINTS), len(sources), figsize=(3.2 * len(sources), 5.4), squeeze=False
    )
    for j, source in enumerate(sources):
        own = scores[scores["source"] == source]
        for i, endpoint in enumerate(ENDPOINTS):
            ax = axes[i][j]
            for (label, _), seed in own.groupby(["label", "seed"], sort=False):
                y = seed.set_index("where").reindex(list(WHERE))[endpoint] * 100
                ax.plot([0, 1], y, color=colors[label], alpha=0.35, lw=1)
            for label, part in own.groupby("label", sort=False):
                mean = part.groupby("where")[endpoint].mean().reindex(list(WHERE)) * 100
                ax.plot([0, 1], mean, color=colors[label], lw=3, marker="o", label=label)
            ax.set_xticks([0, 1], list(WHERE))
            ax.set_xlim(-0.2, 1.2)
            ax.set_ylim(-2, 102)
            ax.set_title(f"{source}: {endpoint}", fontsize=9)
            if j == 0:
                ax.set_ylabel(f"{endpoint} (% of episodes)")
    axes[0][0].legend(fontsize=7, loc="best")
    fig.tight_layout()
    return fig
