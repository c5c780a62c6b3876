"""Generalisation: how each policy does on nets outside the hold-out set, reported apart.

``priqn evaluate RUNS --nets my_nets/`` writes each run's episodes on those nets to
``<run>/eval-nets-<hash>/`` (:func:`priqn.evaluation.protocol.evaluation_name`). Such evaluations are
never part of Table II (its loader leaves them out); :func:`load_generalisation` reads
them, groups them by nets hash (one group per set of nets: the same files, names and
junctions) and cross-checks each group like Table II's inputs (same evaluation settings,
one run per policy and training seed). :func:`generalisation_table` summarises a group:
one row per policy (Table II's order) with its success, collision, off-road and timeout
rates, densities and nets pooled, ``mean ± sample std`` over the units (training seed ×
evaluation run, as Table II), and how many training seeds and episodes it rests on.
Descriptive: no best / second marks, no claims.

``priqn report`` adds a "Generalisation" section and ``tables/generalisation_<hash>.{md,csv}``
when any run has such an evaluation, and nothing otherwise.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from priqn.analysis.load import (
    EVAL_SETTINGS,
    SORT_COLUMNS,
    RunInfo,
    _check_policies,
    _check_same,
    find_run_dirs,
    list_evaluations,
    read_evaluation,
)
from priqn.analysis.render import markdown_table
from priqn.errors import PriqnError
from priqn.evaluation.protocol import NETS_HASH_CHARS
from priqn.io import read_json
from priqn.run.episodes import resolve_outcomes
from priqn.run.folder import RunFolder

OUTCOME_COLUMNS: tuple[tuple[str, str], ...] = (
    ("success", "Success ↑"),
    ("collision", "Collision ↓"),
    ("off_road", "Off-road ↓"),
    ("timeout", "Timeout"),
)
"""(episode column, header) of the generalisation table, in order (one outcome per episode)."""
GENERALISATION_SETTINGS: tuple[str, ...] = tuple(k for k in EVAL_SETTINGS if k != "family")
"""EvalConfig fields that must agree within one set of nets (the family is not used there)."""


@dataclasses.dataclass(frozen=True)
class NetsEvaluation:
    """Every evaluation on one set of own nets (one nets hash) found under a runs folder."""

    nets_hash: str
    """SHA-256 of the nets (:func:`priqn.evaluation.targets.nets_hash`); its first digits name the folders."""
    nets: tuple[dict[str, Any], ...]
    """The nets as ``meta.json`` records them: ``id``, ``path``, ``files`` (SHA-256), ``junction``."""
    episodes: pd.DataFrame
    """One row per episode (``priqn.evaluation.protocol.EPISODE_COLUMNS``), one outcome each, sorted."""
    runs: tuple[RunInfo, ...]
    """The evaluations read, sorted by name (``<run>/eval-nets-<hash>``)."""
    eval_config: dict[str, Any]
    """The shared evaluation settings."""

    @property
    def short_hash(self) -> str:
        """The digits of the hash the folders are named with."""
        return self.nets_hash[:NETS_HASH_CHARS]


def load_generalisation(
    runs_dir: str | Path, partial: bool = False
) -> tuple[list[NetsEvaluation], list[str]]:
    """Every ``eval-nets-*`` evaluation under ``runs_dir``, one :class:`NetsEvaluation` per
    nets hash (sorted by hash), and the names of those left out as not complete.

    An incomplete one is a one-line error unless ``partial``; so are mixed evaluation
    settings within one set of nets and two runs of one policy with the same training seed.
    No such evaluation: ``([], [])``.
    """
    root = Path(runs_dir)
    found, unfinished = list_evaluations(find_run_dirs(root), nets=True)
    if unfinished and not partial:
        shown = ", ".join(unfinished[:5]) + (" ..." if len(unfinished) > 5 else "")
        raise PriqnError(
            f"{root}: {len(unfinished)} evaluation(s) on other nets not complete: {shown}; "
            "finish them with the same 'priqn evaluate --nets ...', or report with --partial"
        )
    groups: dict[str, list[tuple[pd.DataFrame, RunInfo, dict[str, Any]]]] = {}
    for label, run, eval_dir in found:
        frame, info = read_evaluation(label, run, eval_dir)
        meta = read_json(eval_dir / RunFolder.META)
        groups.setdefault(info.holdout_hash, []).append((frame, info, meta))
    out = []
    for nets_hash, members in sorted(groups.items()):
        infos = [info for _, info, _ in members]
        for key in GENERALISATION_SETTINGS:
            _check_same(
                infos,
                key,
                lambda i, k=key: i.eval_config.get(k),
                f"evaluated on nets {nets_hash[:NETS_HASH_CHARS]} with different {key}",
            )
        episodes = resolve_outcomes(pd.concat([f for f, _, _ in members], ignore_index=True))
        _check_policies(episodes)
        episodes = episodes.sort_values(list(SORT_COLUMNS), kind="mergesort")
        out.append(
            NetsEvaluation(
                nets_hash=nets_hash,
                nets=tuple(members[0][2].get("nets") or ()),
                episodes=episodes.reset_index(drop=True),
                runs=tuple(sorted(infos, key=lambda i: i.name)),
                eval_config=infos[0].eval_config,
            )
        )
    return out, unfinished


def generalisation_table(
    episodes: pd.DataFrame,
    order: list[str] | None = None,
    references: pd.DataFrame | None = None,
    reference_order: list[str] | None = None,
) -> pd.DataFrame:
    """One row per policy (``order``, default Table II's order of the policies in
    ``episodes``): ``label``, ``seeds`` (training seeds), ``units`` (training seed ×
    evaluation run), ``episodes``, and per outcome of :data:`OUTCOME_COLUMNS`
    ``<outcome>_mean`` / ``<outcome>_std`` — the mean over units of each unit's rate
    (densities and nets pooled) and its sample std (ddof=1; NaN for one unit).

    ``references``: reference drivers' episodes on the same nets, as rows ``reference_order``
    after the policies; the table then has a ``reference`` column (True on those rows).
    """
    from priqn.analysis.tables import policy_order

    table = _outcome_rows(episodes, policy_order(episodes) if order is None else order)
    if references is None or not len(references):
        return table
    refs = _outcome_rows(references, list(reference_order or []))
    return pd.concat(
        [table.assign(reference=False), refs.assign(reference=True)], ignore_index=True
    )


def _outcome_rows(episodes: pd.DataFrame, order: list[str]) -> pd.DataFrame:
    """The rows of :func:`generalisation_table` for the labels ``order`` in ``episodes``."""
    names = [c for c, _ in OUTCOME_COLUMNS]
    flags = episodes[["label", "train_seed", "eval_run"]].assign(
        **{c: episodes[c].astype(bool).astype(float) for c in names}
    )
    units = flags.groupby(["label", "train_seed", "eval_run"], sort=True)[names].mean()
    rows = []
    for label in order:
        if label not in units.index.get_level_values("label"):
            continue
        mine = units.xs(label, level="label")
        row: dict[str, Any] = {
            "label": label,
            "seeds": int(mine.index.get_level_values("train_seed").nunique()),
            "units": len(mine),
            "episodes": int((episodes["label"] == label).sum()),
        }
        for c in names:
            row[f"{c}_mean"] = float(mine[c].mean())
            row[f"{c}_std"] = float(mine[c].std(ddof=1)) if len(mine) > 1 else float("nan")
        rows.append(row)
    columns = ["label", "seeds", "units", "episodes"]
    columns += [f"{c}_{s}" for c in names for s in ("mean", "std")]
    return pd.DataFrame(rows, columns=columns)


def table_markdown(table: pd.DataFrame) -> str:
    """The generalisation table as Markdown: rates as ``mean ± std`` (3 decimals); reference
    drivers' rows in italics, with "–" for training seeds."""
    heads = ["Policy", "Seeds", "Episodes", *(h for _, h in OUTCOME_COLUMNS)]
    rows = []
    for row in table.to_dict("records"):
        reference = bool(row.get("reference", False))
        label = f"*{row['label']}*" if reference else str(row["label"])
        cells = [label, "–" if reference else str(row["seeds"]), str(row["episodes"])]
        for c, _ in OUTCOME_COLUMNS:
            std = row[f"{c}_std"]
            cells.append(f"{row[f'{c}_mean']:.3f} ± {'n/a' if np.isnan(std) else f'{std:.3f}'}")
        rows.append(cells)
    return markdown_table(heads, rows, "lrr" + "r" * len(OUTCOME_COLUMNS)) + "\n"


def nets_markdown(nets: NetsEvaluation) -> str:
    """The nets of one group: name, junction driven through, file and SHA-256 (first 16)."""
    lines = ["| net | junction | file | SHA-256 |", "|:--|:--|:--|:--|"]
    for net in nets.nets:
        for name, sha in dict(net.get("files") or {}).items():
            lines.append(f"| {net.get('id')} | {net.get('junction')} | {name} | `{sha[:16]}` |")
    return "\n".join(lines) + "\n"


def section_markdown(groups: list[NetsEvaluation], tables: list[pd.DataFrame]) -> str:
    """The report's "Generalisation" section: per set of nets, its nets and its table."""
    md = [
        "## Generalisation — other nets",
        "",
        "Episodes on nets outside the hold-out set (`priqn evaluate --nets`; "
        "docs/your-own-net.md), reported apart from Table II and never in the claims. Same "
        "scene rule as the hold-out set; rates over all densities and nets, mean ± sample std "
        "over training seeds × evaluation runs; no best / second marks.",
        "",
    ]
    for nets, table in zip(groups, tables, strict=True):
        ec = nets.eval_config
        md += [
            f"### Nets `{nets.short_hash}` ({len(nets.nets)} net{'' if len(nets.nets) == 1 else 's'})",
            "",
            f"Nets hash `{nets.nets_hash}`; densities {ec.get('densities')}, "
            f"{ec.get('eval_runs')} evaluation runs, {ec.get('episodes_per_cell')} episodes per "
            f"(evaluation run, net, density), evaluation seed {ec.get('seed')}; "
            f"folders `<run>/eval-nets-{nets.short_hash}*`.",
            "",
            nets_markdown(nets),
            table_markdown(table),
        ]
    return "\n".join(md)
