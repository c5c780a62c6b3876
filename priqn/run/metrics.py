"""The format of a run's ``metrics.csv``: its columns and the row of one ended episode.

One row per training episode (``kind`` train) or in-training evaluation episode
(``kind`` eval). :func:`metrics_row` fills the episode's own columns; the training loop
adds where it stood (``step``, ``episode``, ``wall_s``, ``epsilon``, ``updates``,
``loss``) and, for the preorder agents, the mean optimal-subset sizes. The file itself
is written and read by :class:`priqn.run.folder.RunFolder`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from priqn.objectives import OBJECTIVES, return_columns, subset_columns


def metric_columns(objectives: Sequence[str] = OBJECTIVES) -> tuple[str, ...]:
    """Columns of ``metrics.csv`` for a run with these objective names (``return_<name>``
    and ``subset_<name>`` follow the run's ``env.objectives``)."""
    return (
        "kind",
        "step",
        "episode",
        "wall_s",
        "epsilon",
        "updates",
        "loss",
        *return_columns(objectives),
        "return_weighted",
        "length",
        "success",
        "collision",
        "off_road",
        "timeout",
        "route_progress",
        "density_realised",
        *subset_columns(objectives),
        "net",
        "command",
    )


METRIC_COLUMNS: tuple[str, ...] = metric_columns(OBJECTIVES)
"""Columns of ``metrics.csv`` with the default objectives: one row per training (kind=train)
or evaluation episode."""


def metrics_row(
    kind: str,
    values: Mapping[str, Any],
    net: str,
    weights: Sequence[float],
    objectives: Sequence[str] = OBJECTIVES,
) -> dict[str, Any]:
    """One metrics.csv row of an ended episode (``kind`` train or eval) from its
    :func:`priqn.run.episodes.episode_values` and its net (``objectives``: the run's names)."""
    returns = np.array([values[f"return_{o}"] for o in objectives])
    row: dict[str, Any] = {"kind": kind}
    row.update(
        {f"return_{o}": round(float(r), 5) for o, r in zip(objectives, returns, strict=True)}
    )
    row["return_weighted"] = round(float(returns @ np.asarray(weights)), 5)
    row["length"] = values["steps"]
    row.update({k: int(values[k]) for k in ("success", "collision", "off_road", "timeout")})
    row["route_progress"] = round(values["route_progress"], 4)
    row["density_realised"] = round(values["density_realised"], 4)
    row["net"] = net
    row["command"] = str(values.get("command", ""))
    return row
