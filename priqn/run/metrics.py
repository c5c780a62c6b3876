"""The format of a run's ``metrics.csv``: its columns and the row of one ended episode.

One row per training episode (``kind`` train) or in-training evaluation episode
(``kind`` eval). :func:`metrics_row` fills the episode's own columns; the training loop
adds where it stood (``step``, ``episode``, ``wall_s``, ``epsilon``, ``updates``,
``loss``) and, for the preorder agents, the mean optimal-subset sizes.
:func:`write_metrics` and :func:`read_metrics` write and read the file (its place in a
run folder: :attr:`priqn.run.folder.RunFolder.metrics_path`).
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from priqn.io import atomic_write_text
from priqn.objectives import OBJECTIVES, OUTCOMES, return_columns, subset_columns


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
    row.update({k: int(values[k]) for k in OUTCOMES})
    row["route_progress"] = round(values["route_progress"], 4)
    row["density_realised"] = round(values["density_realised"], 4)
    row["net"] = net
    row["command"] = str(values.get("command", ""))
    return row


def write_metrics(
    path: str | os.PathLike,
    rows: Sequence[Mapping[str, Any]],
    columns: Sequence[str] = METRIC_COLUMNS,
) -> None:
    """metrics.csv at ``path`` with ``columns`` (atomically): :func:`metric_columns` of the
    run's objectives, :data:`METRIC_COLUMNS` by default."""
    atomic_write_text(path, _csv_rows(rows, columns, header=True))


def _csv_rows(rows: Sequence[Mapping[str, Any]], columns: Sequence[str], header: bool) -> str:
    """``rows`` as metrics.csv text (the header first if ``header``), as the csv module writes."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(columns), extrasaction="ignore")
    if header:
        writer.writeheader()
    writer.writerows(rows)
    return buf.getvalue()


class MetricsFile:
    """metrics.csv written as it grows: each :meth:`flush` appends the rows added since the
    last one (and fsyncs), instead of rewriting the whole file, whose cost grows with the
    run. The bytes are those :func:`write_metrics` writes for the same rows.

    ``rows`` are the rows already kept (a resume's rows up to its checkpoint,
    :func:`read_metrics`): a file that holds more (rows after the checkpoint, or a row torn
    by a crash) is rewritten at once, atomically, with just those, as a resume truncates it.
    """

    def __init__(
        self, path: str | os.PathLike, columns: Sequence[str], rows: Sequence[Mapping[str, Any]]
    ) -> None:
        self.path = Path(path)
        self.columns = tuple(columns)
        self.written = 0
        """Rows on disk (the header is written with the first)."""
        if rows or self.path.exists():
            write_metrics(self.path, rows, self.columns)
            self.written = len(rows)
        self._header = bool(rows) or self.path.exists()

    def flush(self, rows: Sequence[Mapping[str, Any]]) -> None:
        """Append ``rows[written:]`` (``rows``: every row of the run so far, in order)."""
        if self._header and len(rows) == self.written:
            return
        text = _csv_rows(rows[self.written :], self.columns, header=not self._header)
        with self.path.open("a", encoding="utf-8", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        self.written, self._header = len(rows), True


def read_metrics(path: str | os.PathLike, max_step: int | None = None) -> list[dict[str, Any]]:
    """metrics.csv rows at ``path`` (as strings) up to ``max_step``; [] when there is none yet.

    A row left incomplete by a crash in the middle of an append ends the rows read."""
    path = Path(path)
    if not path.is_file():
        return []
    with path.open(encoding="utf-8", newline="") as fh:
        reader = csv.DictReader(fh)
        rows = []
        for row in reader:
            if None in row.values() or None in row:
                break  # torn (too few fields, or too many): nothing after it was written whole
            rows.append(row)
    if max_step is None:
        return rows
    return [r for r in rows if int(float(r["step"])) <= max_step]
