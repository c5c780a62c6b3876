"""How every report renders what it computed: CSV text and Markdown tables, one way each.

The report kinds (:mod:`priqn.analysis.report`, ``sequential_report``,
``questions_report``, ``calibration``, ``horizon``, ``mechanism``, ``standstill``,
``collisions``, ``design_report``) choose their columns; the shape of the text and of its
numbers (:func:`percent`, :func:`points`, :func:`interval`) is decided here, so a
committed CSV or table reads the same whichever report made it. Every file is written by
:mod:`priqn.analysis.artifacts` (a report's by its ``render``, a CSV outside any report by
its ``write_csv``); nothing here writes.
"""

from __future__ import annotations

import math
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


def percent(share: float, digits: int = 1) -> str:
    """A share as a percentage: ``0.1234`` -> ``12.3 %`` (``digits`` decimals)."""
    return f"{100 * share:.{digits}f} %"


def points(difference: float | None) -> str:
    """A difference of shares in signed percentage points: ``0.021`` -> ``+2.1``; ``–``
    where there is none (None or NaN)."""
    if difference is None or math.isnan(difference):
        return "–"
    return f"{100 * difference:+.1f}"


def interval(lo: float, hi: float) -> str:
    """An interval of differences in points: ``[-3.2, +1.0]``."""
    return f"[{points(lo)}, {points(hi)}]"


def points_interval(difference: float, lo: float, hi: float) -> str:
    """A difference and its interval in points: ``+2.1 [-3.2, +7.4]``."""
    return f"{points(difference)} {interval(lo, hi)}"
