"""What a report is made of, before anything is written: sections, then one report.

Every report kind builds a :class:`Report` — its kind, the name of its Markdown file, an
ordered list of :class:`Section` objects and its ``meta.json`` fields — from frames it read
and estimates it computed, without touching the disk. :func:`priqn.analysis.artifacts.render`
is the one renderer: it opens the output folder and writes every section's tables, figures
and text files, the Markdown (the sections' text in order) and ``meta.json``. So a kind is
a pure function of its inputs, and every report folder has the shape the renderer gives it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

from priqn.analysis.render import FLOAT_FORMAT


@dataclasses.dataclass(frozen=True)
class Section:
    """One part of a report: its Markdown lines and what it shows beside them."""

    lines: Sequence[str]
    """Markdown lines of this part (joined with ``\\n`` after the previous section's)."""
    tables: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    """``tables/<name>.csv`` by name: pandas DataFrames, written with :data:`FLOAT_FORMAT`."""
    figures: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    """``figures/<name>.png`` and ``.pdf`` by name: matplotlib Figures (closed once written)."""
    files: Mapping[str, str] = dataclasses.field(default_factory=dict)
    """Other text files by path relative to the folder (``tables/<name>.md``, ``.tex``)."""


@dataclasses.dataclass(frozen=True)
class Report:
    """A whole report, ready to render (:func:`priqn.analysis.artifacts.render`)."""

    kind: str
    """``meta.json``'s ``kind``: a name in :data:`priqn.analysis.reports.REPORTS`."""
    markdown: str
    """The Markdown file's name in the folder (``report.md``, ``horizon.md``)."""
    sections: Sequence[Section]
    """The parts, in reading order."""
    command: str
    """The command that regenerates the folder byte for byte (``meta.json``)."""
    experiment: str | None
    """The experiment's (or evaluation design's) name, or None (``meta.json``)."""
    meta: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    """The kind's own ``meta.json`` fields."""
    float_format: str | None = FLOAT_FORMAT
    """How every table's floats are written (:func:`priqn.analysis.render.csv_text`)."""

    def text(self) -> str:
        """The Markdown file: every section's lines, in order, one per line."""
        return "\n".join(line for section in self.sections for line in section.lines)
