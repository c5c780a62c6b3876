"""The collision forensics table (``priqn mechanism RUNS --collisions``, descriptive).

From one row per collision (:mod:`priqn.tools.collisions`): per traffic setting, row and
density, how many collisions, the share of each kind (:data:`COLLISION_KINDS`), the share
the NPC struck, and the share a Traffic-Manager-like NPC would have prevented (it could have
stopped when the ego entered its path: the TM's collision stage brakes there).
:func:`collisions_report` builds the report as sections (rendered by
:func:`priqn.analysis.artifacts.render`): ``report.md``, ``tables/collisions.csv``
(every collision), ``tables/collisions_by_kind.csv`` (the table) and ``meta.json``.
"""

from __future__ import annotations

from typing import Any

import pandas as pd

from priqn.analysis.render import markdown_table, percent
from priqn.analysis.sections import Report, Section
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


def prevented_table(collisions: pd.DataFrame) -> pd.DataFrame:
    """Of collisions replayed under another traffic (``replay_traffic``): per own traffic and
    row, ``scenes`` (collisions of the evaluation), ``again`` (scenes that collide in the
    replay too) and ``prevented`` (the share that no longer does)."""
    again = collisions["replayed_collision"].astype(str) == "True"
    rows = []
    for (traffic, label), part in collisions.groupby(["traffic", "label"], sort=True):
        n, k = len(part), int(again[part.index].sum())
        rows.append({"traffic": traffic, "label": label, "scenes": n, "again": k,
                     "prevented": (n - k) / n})  # fmt: skip
    return pd.DataFrame(rows)


def _prevented_text(prevented: pd.DataFrame, traffic: str) -> list[str]:
    """The report's lines on a replay under ``traffic`` (:func:`prevented_table`): how many
    still collide, in all and per row."""
    again, scenes = int(prevented["again"].sum()), int(prevented["scenes"].sum())
    rows = [
        [r["traffic"], r["label"], str(r["scenes"]), str(r["again"]), percent(r["prevented"], 0)]
        for r in prevented.to_dict("records")
    ]
    return [
        f"Every collision scene of the evaluations replayed under `{traffic}` traffic, with "
        "the same policy and seeds (its later decisions may change with the traffic: the same "
        f"scenes, not the same episodes). {again} of {scenes} still end in a collision.",
        "",
        markdown_table(
            ["own traffic", "row", "collisions", f"still under {traffic}", "prevented"], rows
        ),
        "",
        f"The kinds below are those of the replays that still collide under `{traffic}`.",
    ]


def _kinds_markdown(table: pd.DataFrame) -> str:
    """:func:`kind_table` as a markdown table, shares in whole percent."""
    header = ["traffic", "row", "density", "collisions", "seeds", *COLLISION_KINDS]
    rows = [
        [
            r["traffic"],
            r["label"],
            r["density"] if r["density"] == "all" else f"{r['density']:g}",
            str(r["collisions"]),
            str(r["seeds"]),
            *(percent(r[k], 0) for k in COLLISION_KINDS),
            percent(r["npc_struck"], 0),
            percent(r["tm_would_prevent"], 0),
        ]
        for r in table.to_dict("records")
    ]
    return markdown_table([*header, "NPC struck", "TM-like NPC would prevent"], rows)


def collisions_report(
    collisions: pd.DataFrame, command: str, replay_traffic: str | None = None
) -> Report:
    """The collisions report: ``tables/collisions.csv`` (every collision),
    ``tables/collisions_by_kind.csv`` and ``report.md`` (the table), ``meta.json``
    (``command``: the one that makes it). ``replay_traffic``: the collisions were replayed
    under that traffic setting (``--traffic``): the report also says which share of each
    row's collisions it prevented (``tables/prevented.csv``), and the kinds table describes
    the replays that still collide."""
    fields = {
        "collisions": len(collisions),
        "cells_with_collisions": sorted(set(collisions.get("cell", []))),
    }
    if replay_traffic is not None:
        fields["replay_traffic"] = replay_traffic

    def report(*sections: Section) -> Report:
        return Report("collisions", "report.md", sections, command, None, fields)

    every = {"collisions": collisions}
    if collisions.empty:
        return report(Section(["# Collisions", "", "No collision to describe.", ""], every))
    replayed = collisions["replayed_collision"].astype(str)
    if replay_traffic is None:
        again = int((replayed == "True").sum())
        replays = int(replayed.isin(["True", "False"]).sum())
        source = [
            f"Made by `{command}`. Replayed: {replays} collisions of evaluations made before the forensics existed; "
            f"{again} ended in a collision again."
            if replays
            else f"Made by `{command}`. Read from the evaluations' own records (no replay)."
        ]
        described = collisions
    else:
        prevented = prevented_table(collisions)
        every["prevented"] = prevented
        source = [
            f"Made by `{command}`.",
            "",
            *_prevented_text(prevented, replay_traffic),
        ]
        described = collisions[replayed == "True"]
    if described.empty:
        return report(Section(["# Collisions (descriptive)", "", *source, ""], every))
    table = kind_table(described)
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
        *source,
        "",
        _kinds_markdown(table),
        "",
    ]
    return report(Section(text, {**every, "collisions_by_kind": table}))
