"""The one writer of a report's files: every report (grid, sequential, questions,
calibration, horizon, collisions, mechanism, standstill) writes through a
:class:`ReportFolder`, so every report folder has the same shape::

    <out>/report.md           what a person reads (the report's own name for it)
    <out>/meta.json           how it was made: one schema (:data:`META_SCHEMA`)
    <out>/tables/<name>.csv   every table as CSV (also .md / .tex where a report shows them)
    <out>/figures/<name>.png  every figure as PNG (150 dpi) and PDF

Every file is written atomically (temp file + rename), so a report interrupted half way
leaves each file either as it was or whole; the folder is checked once, up front, with a
one-line error on a folder that cannot be made. Output is deterministic for the same
inputs: no timestamps in PNG or PDF metadata, a fixed SVG hash salt, the Agg backend.
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from priqn.analysis.render import FLOAT_FORMAT, csv_text  # noqa: E402
from priqn.io import atomic_write_bytes, atomic_write_json, atomic_write_text, ensure_dir  # noqa: E402

plt.rcParams["svg.hashsalt"] = "priqn"
plt.rcParams["pdf.compression"] = 6

META_SCHEMA = 1
"""Version of meta.json's shape. Every report's meta.json has ``schema`` (this number),
``kind`` (the report's kind: a name in :data:`priqn.analysis.reports.REPORTS`),
``command`` (the command that regenerates the folder byte for byte) and ``experiment``
(the experiment's name, or null for a folder of runs that is no experiment's), beside
the kind's own fields; keys sorted (stable bytes)."""

FIGURE_DPI = 150
"""Resolution of every report figure's PNG, in dots per inch."""


@dataclass(frozen=True)
class ReportFolder:
    """A report's output folder; :meth:`open` checks and makes it."""

    root: Path
    """The folder (``--out``)."""

    @classmethod
    def open(cls, out: str | Path) -> ReportFolder:
        """The folder ``out``, made with its parents; one line naming it if it cannot be."""
        return cls(ensure_dir(out))

    @property
    def tables(self) -> Path:
        """``tables/``: every table as CSV (and Markdown or LaTeX where a report shows it)."""
        return self.root / "tables"

    @property
    def figures(self) -> Path:
        """``figures/``: every figure as PNG and PDF."""
        return self.root / "figures"

    def table(self, name: str, frame: Any, float_format: str | None = FLOAT_FORMAT) -> Path:
        """``tables/<name>.csv`` from a pandas DataFrame (no index, ``\\n`` line ends);
        returns its path."""
        return write_csv(self.root / "tables" / f"{name}.csv", frame, float_format)

    def figure(self, name: str, fig: plt.Figure) -> list[Path]:
        """``figures/<name>.png`` (:data:`FIGURE_DPI`) and ``figures/<name>.pdf``; closes
        the figure; returns both paths."""
        paths = []
        for ext, kwargs in (
            ("png", {"dpi": FIGURE_DPI, "metadata": {"Software": None}}),
            ("pdf", {"metadata": {"CreationDate": None, "ModDate": None}}),
        ):
            buf = io.BytesIO()
            fig.savefig(buf, format=ext, bbox_inches="tight", **kwargs)
            paths.append(self.binary(f"figures/{name}.{ext}", buf.getvalue()))
        plt.close(fig)
        return paths

    def text(self, relative: str, content: str) -> Path:
        """Any text file of the report (``report.md``, ``tables/<name>.md``), atomically."""
        path = self.root / relative
        atomic_write_text(path, content)
        return path

    def binary(self, relative: str, content: bytes) -> Path:
        """Any binary file of the report, atomically."""
        path = self.root / relative
        atomic_write_bytes(path, content)
        return path

    def meta(
        self, kind: str, command: str, experiment: str | None, fields: Mapping[str, Any]
    ) -> Path:
        """``meta.json`` in the one schema (:data:`META_SCHEMA`); ``fields``: the kind's
        own, which may not reuse the common keys."""
        common = {"schema": META_SCHEMA, "kind": kind, "command": command, "experiment": experiment}
        clash = sorted(set(common) & set(fields))
        if clash:
            raise ValueError(f"meta.json fields {clash} are the schema's own")
        path = self.root / "meta.json"
        atomic_write_json(path, {**common, **fields})
        return path


def write_csv(path: str | Path, frame: Any, float_format: str | None = FLOAT_FORMAT) -> Path:
    """``frame`` (a pandas DataFrame) as CSV at ``path`` (:func:`priqn.analysis.render.csv_text`:
    no index, ``\\n`` line ends), atomically; also for a CSV outside any report folder (a
    replay's decision rows, ``priqn probe --csv``), so analysis writes CSV one way."""
    path = Path(path)
    atomic_write_text(path, csv_text(frame, float_format))
    return path


def write_json(path: str | Path, record: Any) -> Path:
    """``record`` as indented, key-sorted JSON at ``path``, atomically (a cache's record
    beside its rows; a report's meta.json goes through :meth:`ReportFolder.meta`)."""
    path = Path(path)
    atomic_write_json(path, record)
    return path


def render(out: str | Path, report: Any) -> Path:
    """Write ``report`` (a :class:`priqn.analysis.sections.Report`) into the folder ``out``,
    the one renderer of the reports built from sections: each section's tables, figures and
    text files, then the Markdown and ``meta.json``; returns the Markdown file."""
    folder = ReportFolder.open(out)
    for section in report.sections:
        for name, frame in section.tables.items():
            folder.table(name, frame, report.float_format)
        for name, fig in section.figures.items():
            folder.figure(name, fig)
        for relative, content in section.files.items():
            folder.text(relative, content)
    path = folder.text(report.markdown, report.text())
    folder.meta(report.kind, report.command, report.experiment, report.meta)
    return path
