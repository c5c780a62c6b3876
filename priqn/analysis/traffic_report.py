"""The same runs under another traffic setting (``priqn report RUNS --traffic NAME``, kind
``traffic``; descriptive).

Each run's own evaluation (``eval/``, under the traffic it trained with) beside its
``eval-traffic-<NAME>/`` (``priqn evaluate RUN --traffic NAME``: the same scenes, only the
NPCs' setting replaced). The policies trained under their own traffic, so nothing here
decides; frames, then estimates, then sections:

1. **frames** (:func:`traffic_episodes`): every run's episodes under both, over the scenes
   both played (:func:`~priqn.analysis.mixes.common_scenes`), and each training seed's
   rates (:func:`~priqn.analysis.questions.seed_rates`: per density, then the mean);
2. **estimates**: the outcome mix per row, traffic and density; per row, the change
   NAME − own paired per training seed with its t interval
   (:func:`~priqn.analysis.mixes.paired_changes`); between every two rows under each
   traffic, the difference with its Welch interval; scene by scene, how each outcome under
   the own traffic ends under NAME;
3. **sections**, rendered by :func:`priqn.analysis.artifacts.render`: ``traffic.md``,
   ``tables/traffic_{mix,changes,rows,transitions}.csv``, ``figures/traffic_seeds``.

Runs without a complete ``eval-traffic-<NAME>/`` are refused with the command that makes
the first, or with ``--partial`` left out and named.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd

from priqn.analysis import inference
from priqn.analysis.load import find_run_dirs, read_episodes
from priqn.analysis.mixes import common_scenes, mix_table, paired_changes, paired_outcomes
from priqn.analysis.questions import seed_rates
from priqn.analysis.render import markdown_table, percent, points_interval
from priqn.analysis.sections import Report, Section
from priqn.analysis.tables import policy_order
from priqn.errors import PriqnError
from priqn.evaluation.protocol import TRAFFIC_PREFIX
from priqn.io import read_json
from priqn.objectives import OUTCOMES
from priqn.run.evaluations import evaluation_complete, evaluation_dir
from priqn.run.folder import RunFolder

OWN = "own"
"""The ``traffic`` value of a run's own evaluation (``eval/``)."""
ENDPOINTS = ("success", "violation", "timeout")
"""The rates compared per row and between rows (violation: collision or off-road)."""


def traffic_episodes(
    runs: str | Path, traffic: str, partial: bool
) -> tuple[pd.DataFrame, list[str]]:
    """Every run's episodes under its own traffic and under ``traffic`` (column
    ``traffic``: :data:`OWN` or the name), over the scenes both played, and the runs left
    out (``partial``; otherwise a run without the evaluation is a one-line error naming the
    command that makes it). Both evaluations must share the scenes and the episode limit."""
    name = f"{TRAFFIC_PREFIX}{traffic}"
    frames, missing = [], []
    for run in find_run_dirs(runs):
        folder = RunFolder(run)
        if not (evaluation_complete(folder) and evaluation_complete(folder, name)):
            if not partial:
                raise PriqnError(
                    f"{evaluation_dir(folder, name)}: no complete evaluation; run 'priqn "
                    f"evaluate {run} --traffic {traffic}' (or report the rest with --partial)"
                )
            missing.append(str(run))
            continue
        both = [evaluation_dir(folder), evaluation_dir(folder, name)]
        metas = [read_json(d / RunFolder.META) for d in both]
        if metas[0]["holdout_hash"] != metas[1]["holdout_hash"] or (
            metas[0]["env_config"]["max_episode_steps"]
            != metas[1]["env_config"]["max_episode_steps"]
        ):
            raise PriqnError(
                f"{both[1]}: other scenes or another episode limit than {both[0].name}/; "
                f"evaluate again with 'priqn evaluate {run} --traffic {traffic}'"
            )
        for where, eval_dir in zip((OWN, traffic), both, strict=True):
            frames.append(read_episodes(eval_dir).assign(traffic=where))
    if not frames:
        raise PriqnError(f"{runs}: no run with a complete {name}/ evaluation")
    return common_scenes(pd.concat(frames, ignore_index=True), "traffic"), missing


def seed_scores(episodes: pd.DataFrame) -> pd.DataFrame:
    """One row per (row, training seed, traffic): ``label, seed, where`` and every rate of
    :func:`~priqn.analysis.questions.seed_rates`."""
    rows = [
        {"label": label, "seed": int(seed), "where": where, **seed_rates(part)}
        for (label, seed, where), part in episodes.groupby(
            ["label", "train_seed", "traffic"], sort=False
        )
    ]
    return pd.DataFrame(rows)


def between_rows(scores: pd.DataFrame, order: list[str]) -> pd.DataFrame:
    """Under each traffic, every two rows, ``a`` after ``b`` in ``order`` (Table II's: so
    Pr-IQN − IQN): ``a − b`` of each endpoint over training seeds with its Welch 95 %
    interval, and the seeds."""
    out = []
    for where, part in scores.groupby("where", sort=False):
        for b, a in itertools.combinations(order, 2):
            sa, sb = part[part["label"] == a], part[part["label"] == b]
            record = {"traffic": where, "a": a, "b": b, "seeds_a": len(sa), "seeds_b": len(sb)}
            for endpoint in ENDPOINTS:
                lo, hi = inference.welch_interval(sa[endpoint].to_numpy(), sb[endpoint].to_numpy())
                diff = float(sa[endpoint].mean() - sb[endpoint].mean())
                record |= {endpoint: diff, f"{endpoint}_lo": lo, f"{endpoint}_hi": hi}
            out.append(record)
    return pd.DataFrame(out)


def transitions(episodes: pd.DataFrame, traffic: str) -> pd.DataFrame:
    """Scene by scene, per row and outcome under its own traffic (``own``): how many
    episodes ended so (``episodes``) and the share of them ending in each outcome under
    ``traffic``."""
    under = episodes["traffic"]
    joined = paired_outcomes(episodes[under == OWN], episodes[under == traffic])
    counts = pd.crosstab([joined["label"], joined["outcome_base"]], joined["outcome"])
    counts = counts.reindex(columns=list(OUTCOMES), fill_value=0)
    table = counts.div(counts.sum(axis=1), axis=0)
    table.insert(0, "episodes", counts.sum(axis=1))
    return table.rename_axis(["label", "own"]).reset_index().rename_axis(columns=None)


def seeds_figure(scores: pd.DataFrame, order: list[str], traffic: str) -> plt.Figure:
    """Per endpoint, each training seed's rate under its own traffic and under ``traffic``,
    joined by a line, one column of seeds per row."""
    fig, axes = plt.subplots(1, 2, figsize=(8.4, 3.6), sharey=True)
    for ax, endpoint in zip(axes, ("success", "violation"), strict=True):
        for i, label in enumerate(order):
            wide = scores[scores["label"] == label].pivot(index="seed", columns="where",
                                                          values=endpoint)  # fmt: skip
            for own, then in zip(wide[OWN], wide[traffic], strict=True):
                ax.plot([2 * i, 2 * i + 1], [100 * own, 100 * then], "o-", color=f"C{i}",
                        alpha=0.6, ms=3, lw=0.8)  # fmt: skip
        ax.set_xticks(
            [x for i in range(len(order)) for x in (2 * i, 2 * i + 1)],
            [f"{label}\n{w}" for label in order for w in (OWN, traffic)],
            fontsize=7,
        )
        ax.set_title(f"{endpoint} per training seed", fontsize=9)
    axes[0].set_ylabel("share of hold-out episodes, %")
    fig.tight_layout()
    return fig


def traffic_report(
    runs: str | Path, traffic: str, command: str, partial: bool, experiment: str | None = None
) -> Report:
    """The traffic report of ``runs`` under ``traffic`` (kind ``traffic``, descriptive)."""
    episodes, missing = traffic_episodes(runs, traffic, partial)
    order = policy_order(episodes)
    scores = seed_scores(episodes)
    mix = mix_table(episodes, "traffic")
    changes = paired_changes(scores, ["label"], (OWN, traffic), ENDPOINTS)
    rows, moved = between_rows(scores, order), transitions(episodes, traffic)
    sections = [
        _title_section(runs, traffic, command, episodes, missing),
        _changes_section(changes, traffic, seeds_figure(scores, order, traffic)),
        _rows_section(rows),
        _mix_section(mix),
        _transitions_section(moved, traffic),
    ]
    fields = {
        "traffic": traffic,
        "runs": sorted(set(episodes["run"])),
        "left_out": missing,
    }
    return Report("traffic", "traffic.md", sections, command, experiment, fields)


def _title_section(
    runs: str | Path, traffic: str, command: str, episodes: pd.DataFrame, missing: list[str]
) -> Section:
    runs_in = episodes["run"].nunique()
    lines = [
        f"# {Path(runs).name} under `{traffic}` (descriptive)",
        "",
        f"Made by `{command}`. {runs_in} run(s), each played on its own hold-out scenes "
        f"under the traffic it trained with (`{OWN}`, `eval/`) and under `{traffic}` "
        f"(`eval-{TRAFFIC_PREFIX}{traffic}/`, `priqn evaluate RUN --traffic {traffic}`), "
        f"{len(episodes) // 2} episode pairs. The policies trained under their own traffic: "
        "nothing here decides. A seed's rate is its share per density, then the mean over "
        "densities; intervals are t 95 % over training seeds.",
        "",
    ]
    if missing:
        lines += [
            f"**Partial:** {len(missing)} run(s) without a complete evaluation under "
            f"`{traffic}` left out: " + ", ".join(f"`{Path(m).name}`" for m in missing) + ".",
            "",
        ]
    return Section(lines)


def _changes_section(changes: pd.DataFrame, traffic: str, fig: plt.Figure) -> Section:
    heads = ["row", "seeds"] + [f"{e} {w}" for e in ENDPOINTS for w in (OWN, traffic, "change")]
    body = [
        [r["label"], str(r["seeds"])]
        + [
            cell
            for e in ENDPOINTS
            for cell in (
                percent(r[f"{e}_in"]),
                percent(r[f"{e}_out"]),
                points_interval(r[f"{e}_change"], r[f"{e}_change_lo"], r[f"{e}_change_hi"]),
            )
        ]  # fmt: skip
        for r in changes.to_dict("records")
    ]
    return Section(
        [
            f"## Each row under `{traffic}` against its own traffic",
            "",
            f"Change: {traffic} − {OWN}, the mean of each training seed's change, points "
            "[95 % t interval].",
            "",
            markdown_table(heads, body),
            "",
            "![each seed under both](figures/traffic_seeds.png)",
            "",
        ],
        tables={"traffic_changes": changes},
        figures={"traffic_seeds": fig},
    )


def _rows_section(rows: pd.DataFrame) -> Section:
    heads = ["traffic", "a − b", "seeds"] + [f"{e}, points [Welch 95 %]" for e in ENDPOINTS]
    body = [
        [r["traffic"], f"{r['a']} − {r['b']}", f"{r['seeds_a']} vs {r['seeds_b']}"]
        + [points_interval(r[e], r[f"{e}_lo"], r[f"{e}_hi"]) for e in ENDPOINTS]
        for r in rows.to_dict("records")
    ]
    return Section(
        ["## Between rows under each traffic", "", markdown_table(heads, body), ""],
        tables={"traffic_rows": rows},
    )


def _mix_section(mix: pd.DataFrame) -> Section:
    heads = ["row", "traffic", "density", "seeds", *OUTCOMES]
    body = [
        [
            r.label,
            r.traffic,
            f"{r.density:g}",
            str(r.seeds),
            *(percent(getattr(r, o)) for o in OUTCOMES),
        ]
        for r in mix.itertuples()
    ]
    heading = "## Outcome mix per row, traffic and density (mean over training seeds)"
    return Section([heading, "", markdown_table(heads, body), ""], tables={"traffic_mix": mix})


def _transitions_section(moved: pd.DataFrame, traffic: str) -> Section:
    heads = ["row", f"under {OWN}", "episodes", *(f"then {o} under {traffic}" for o in OUTCOMES)]
    body = [
        [r["label"], r["own"], str(r["episodes"]), *(percent(r[o]) for o in OUTCOMES)]
        for r in moved.to_dict("records")
    ]
    return Section(
        [
            "## Scene by scene",
            "",
            f"Of each row's episodes that ended in an outcome under its own traffic, the share "
            f"ending in each outcome on the same scene under `{traffic}`.",
            "",
            markdown_table(heads, body),
            "",
        ],
        tables={"traffic_transitions": moved},
    )
