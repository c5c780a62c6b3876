"""How every report renders what it computed: CSV text and Markdown tables, one way each.

The report kinds (:mod:`priqn.analysis.report`, ``sequential_report``,
``questions_report``, ``calibration``, ``horizon``, ``mechanism``, ``standstill``,
``collisions``, ``design_report``) choose their columns and format their cells; the shape
of the text is decided here, so a committed CSV or table reads the same whichever report
made it. Every file is written by :mod:`priqn.analysis.artifacts` (a report's by its
``render``, a CSV outside any report by its ``write_csv``); nothing here writes.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

FLOAT_FORMAT = "%.10g"
"""Floats in a report's CSV tables: 10 significant digits (enough to recompute every
figure of the Markdown, short enough to diff)."""

_ALIGN = {"l": ":--", "r": "--:", "-": "---"}


def csv_text(frame: Any, float_format: str | None = FLOAT_FORMAT) -> str:
    """``frame`` (a pandas DataFrame) as CSV: no index, ``\\n`` line ends on every OS;
    ``float_format=None`` writes floats as pandas does by default (their repr)."""
    return frame.to_csv(index=False, float_format=float_format, lineterminator="\n")


def markdown_table(
    heads: Sequence[str], rows: Iterable[Sequence[str]], align: str | None = None
) -> str:
    """A Markdown table of already formatted cells, without a final newline.

    ``align``: one letter per column, ``l`` (left), ``r`` (right) or ``-`` (unspecified);
    ``None``: every column unspecified (``|---|``).
    """
    align = align or "-" * len(heads)
    if len(align) != len(heads):
        raise ValueError(f"align {align!r}: expected one letter per column ({len(heads)})")
    lines = [
        "| " + " | ".join(heads) + " |",
        "|" + "".join(f"{_ALIGN[a]}|" for a in align),
    ]
    lines += ["| " + " | ".join(cells) + " |" for cells in rows]
    return "\n".join(lines)
