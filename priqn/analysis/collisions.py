"""The collision forensics table (``priqn mechanism RUNS --collisions``, descriptive).

From one row per collision (:mod:`priqn.tools.collisions`): per traffic setting, row and
density, how many collisions, the share of each kind (:data:`COLLISION_KINDS`), the share
the NPC struck, and the share a Traffic-Manager-like NPC would have prevented (it could have
stopped when the ego entered its path: the TM's collision stage brakes there).
:func:`write_report` writes the report folder through
:class:`priqn.analysis.artifacts.ReportFolder`: ``report.md``, ``tables/collisions.csv``
(every collision), ``tables/collisions_by_kind.csv`` (the table) and ``meta.json``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd

from priqn.analysis.artifacts import ReportFolder
from priqn.analysis.render import markdown_table
from priqn.objectives import COLLISION_KINDS

GROUP: tuple[str, ...] = ("traffic", "label", "density")
"""A table row: the traffic setting, the policy row, the evaluation density."""


def _flag(values: pd.Series) -> pd.Series:
    """A column of True / False / '' (CSV text or values) as floats, '' as NaN."""
    text = values.astype(str).str.strip().str.lower()
    return text.map({"true": 1.0, "false": 0.0, "1": 1.0, "0": 0.0, "1.0": 1.0, "0.0": 0.0})


def kind_table(collisions: pd.DataFrame) -> pd.DataFrame:
    """Per :data:`GROUP`: ``collisions`` (count), ``seeds``, the share of each kind, the share
    struck by the NPC and the share a TM-like NPC would have prevented; after each traffic
    and row's densities, a row ``density`` "all" pooling them (every collision counts once)."""
    rows: list[dict[str, Any]] = []
    parts = [
        ((*key, density), part)
        for key, group in collisions.groupby(list(GROUP[:2]), sort=True)
        for density, part in [*group.groupby("density", sort=True), ("all", group)]
    ]
    for key, part in parts:
        row = dict(zip(GROUP, key, strict=True))
        row["collisions"] = len(part)
        row["seeds"] = part["train_seed"].nunique()
        for kind in COLLISION_KINDS:
            row[kind] = float((part["collision_kind"] == kind).mean())
        row["npc_struck"] = float(part["collision_striker"].isin(["npc", "both"]).mean())
        row["tm_would_prevent"] = float(_flag(part["collision_tm_would_prevent"]).fillna(0).mean())
        rows.append(row)
    return pd.DataFrame(rows)


def write_report(collisions: pd.DataFrame, out: str | Path, command: str) -> Path:
    """The report folder ``out``: ``tables/collisions.csv`` (every collision),
    ``tables/collisions_by_kind.csv`` and ``report.md`` (the table), ``meta.json``
    (``command``: the one that makes it); returns report.md."""
    folder = ReportFolder.open(out)
    folder.table("collisions", collisions)
    fields = {
        "collisions": len(collisions),
        "cells_with_collisions": sorted(set(collisions.get("cell", []))),
    }
    folder.meta("collisions", command, None, fields)
    if collisions.empty:
        return folder.text("report.md", "# Collisions\n\nNo collision to describe.\n")
    table = kind_table(collisions)

    def pct(x: float) -> str:
        return f"{100 * x:.0f} %"

    replayed = collisions["replayed_collision"].astype(str)
    again = int((replayed == "True").sum())
    replays = int(replayed.isin(["True", "False"]).sum())
    text = [
        "# Collisions, by kind (descriptive)",
        "",
        "Each evaluated collision, classified (priqn/env/forensics.py): who struck whom, and "
        "whether the NPC could have stopped when the ego entered its path (then a Traffic "
        "Manager-like NPC, whose collision stage brakes for the ego in its path, would have "
        "prevented it). Kinds:",
        "",
        *(f"- `{k}`: {v}" for k, v in COLLISION_KINDS.items()),
        "",
        (
            f"Made by `{command}`. Replayed: {replays} collisions of evaluations made before the forensics existed; "
            f"{again} ended in a collision again."
            if replays
            else f"Made by `{command}`. Read from the evaluations' own records (no replay)."
        ),
        "",
        markdown_table(
            [
                "traffic",
                "row",
                "density",
                "collisions",
                "seeds",
                *COLLISION_KINDS,
                "NPC struck",
                "TM-like NPC would prevent",
            ],
            [
                [
                    r["traffic"],
                    r["label"],
                    r["density"] if r["density"] == "all" else f"{r['density']:g}",
                    str(r["collisions"]),
                    str(r["seeds"]),
                    *(pct(r[k]) for k in COLLISION_KINDS),
                    pct(r["npc_struck"]),
                    pct(r["tm_would_prevent"]),
                ]
                for r in table.to_dict("records")
            ],
        ),
        "",
    ]
    folder.table("collisions_by_kind", table)
    return folder.text("report.md", "\n".join(text))
