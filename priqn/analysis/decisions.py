"""Per-decision rows of the replay reports (``priqn mechanism``, ``--standstill``): their
schema, their cache, and the one set of functions that summarises them into a report.

``priqn mechanism`` (:mod:`priqn.tools.mechanism`) and its ``--standstill`` mode
(:mod:`priqn.tools.standstill`) replay evaluated cells and write one row per decision.
Here, with no torch and no SUMO:

- :class:`RowSchema`: the columns of each kind of row (:data:`MECHANISM_ROWS`,
  :data:`STANDSTILL_ROWS`), with dtype, unit and meaning, and a version number;
- :class:`DecisionCache`: the rows of a replayed cell on disk, keyed by the schema's
  version and the replay's parameters (another version or other parameters: replayed
  again);
- :class:`DecisionMeasure` and :func:`seed_table`: one row per cell (its identity, the
  share of replayed episodes that ended as evaluated, the kind's measures) and one per
  group of cells (means over its cells);
- :func:`markdown` and :func:`decision_report`: the report (report.md, tables/*.csv,
  figures/<kind>.png+.pdf, meta.json) as sections, rendered by :func:`priqn.analysis.artifacts.render`.

The measures of each kind are :mod:`priqn.analysis.mechanism`'s and
:mod:`priqn.analysis.standstill`'s.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from priqn.analysis.artifacts import write_csv, write_json
from priqn.analysis.render import markdown_table
from priqn.analysis.sections import Report, Section
from priqn.io import read_json

# ----------------------------------------------------------------------------- schema


@dataclass(frozen=True)
class Column:
    """One column of a kind of decision row."""

    name: str
    """Its name; ``<level>`` stands for each lower level, ``<head>`` for each compared
    head (one column per level or head, in their order)."""
    dtype: str
    """``int``, ``float``, ``bool`` or ``str``."""
    unit: str
    """Its unit ('' for none: indices, flags, names)."""
    doc: str
    """What it holds."""
    only: str = ""
    """'' for every row; ``subsets``: only rows of an agent with optimal subsets (Pr-IQN)."""

    def pattern(self) -> re.Pattern[str]:
        """The names this column stands for."""
        text = re.escape(self.name).replace("<level>", "[a-z_]+").replace("<head>", "[a-z_]+")
        return re.compile(f"^{text}$")


@dataclass(frozen=True)
class RowSchema:
    """The columns of one kind of decision row and their version: a cache written under
    another version is replayed again (:class:`DecisionCache`)."""

    kind: str
    """``mechanism`` or ``standstill``."""
    version: int
    """Raised whenever a column is added, dropped, renamed or computed differently."""
    columns: tuple[Column, ...]

    def check(self, frame: Any) -> str:
        """'' when ``frame``'s columns are this schema's (every column of every row there,
        none unknown); else what is wrong, in a few words."""
        names = list(frame.columns)
        unknown = [n for n in names if not any(c.pattern().match(n) for c in self.columns)]
        missing = [
            c.name for c in self.columns if not c.only and not any(map(c.pattern().match, names))
        ]
        if unknown or missing:
            return f"unknown columns {unknown}, missing {missing}"
        return ""


KEY_COLUMNS: tuple[Column, ...] = (
    Column("eval_run", "int", "", "the evaluation run of the scene"),
    Column("net", "str", "", "the hold-out net (``<folder>/<stem>``)"),
    Column("density", "float", "", "the scene's traffic density"),
    Column("episode", "int", "", "the episode index within (eval run, net, density)"),
    Column("decision", "int", "", "the decision's index in its episode, from 0"),
    Column("action", "int", "", "the executed action (speed-major grid)"),
)
"""The columns that name one replayed decision (:func:`priqn.tools.decisions.decision_key`)."""

MECHANISM_ROWS = RowSchema(
    "mechanism",
    1,
    KEY_COLUMNS
    + (
        Column("speed_mps", "float", "m/s", "the executed action's target speed"),
        Column("top_max_speed_mps", "float", "m/s", "the fastest target speed the top level keeps"),
        Column(
            "lower_greedy_speed_mps",
            "float",
            "m/s",
            "target speed of the lower objective's greedy action",
        ),
        Column(
            "greedy_<level>", "int", "", "the level's head's greedy action (argmax of its mean)"
        ),
        Column(
            "removes_<level>", "bool", "", "the top level's subset leaves that greedy action out"
        ),
        Column("removes_any", "bool", "", "the top level removes some lower level's greedy action"),
        Column("size_top", "int", "actions", "size of the top level's optimal subset"),
        Column("size_leaf", "int", "actions", "size of the leaf set the action was drawn from"),
        Column("calibrated_head", "str", "", "the head whose predictions follow (safety)"),
        Column(
            "pred_violation",
            "float",
            "probability",
            "share of the calibrated head's K quantiles at the action at or below −penalty/2",
        ),  # fmt: skip
        Column("pred_return", "float", "reward", "the calibrated head's mean at the action"),
        Column("return_to_go", "float", "reward", "realised discounted safety return from here on"),
        Column("episode_violation", "bool", "", "the episode ends in a collision or off the road"),
        Column("episode_off_road", "bool", "", "the episode ends off the road"),
        Column("episode_collision", "bool", "", "the episode ends in a collision"),
        Column("episode_timeout", "bool", "", "the episode times out"),
        Column("violation_within", "bool", "", "a violation ends the episode within the horizon"),
        Column("off_road_within", "bool", "", "leaving the road ends it within the horizon"),
        Column("replay_matches", "bool", "", "the episode ended as eval/episodes.csv says"),
    ),
)
"""One row per decision of ``priqn mechanism`` (:func:`priqn.tools.mechanism.decision_rows`);
``<level>``: each level below ``--top``."""

STANDSTILL_ROWS = RowSchema(
    "standstill",
    1,
    KEY_COLUMNS
    + (
        Column("stop", "bool", "", "the executed action targets 0 m/s"),
        Column("episode_timeout", "bool", "", "the episode times out"),
        Column("episode_success", "bool", "", "the episode succeeds"),
        Column("replay_matches", "bool", "", "the episode ended as eval/episodes.csv says"),
        Column("go_survives", "bool", "", "a go action reaches the --target level", "subsets"),
        Column(
            "removed_by",
            "str",
            "",
            "else the first level whose subset holds no go action",
            "subsets",
        ),
        Column("<head>_best_stop", "int", "", "the head's best stop action (-1: none)", "subsets"),
        Column("<head>_best_go", "int", "", "the head's best go action (-1: none)", "subsets"),
        Column("<head>_mean_stop", "float", "reward", "its mean over the K quantiles", "subsets"),
        Column("<head>_mean_go", "float", "reward", "its mean over the K quantiles", "subsets"),
        Column("<head>_raw_diff", "float", "reward", "mean_stop − mean_go", "subsets"),
        Column("<head>_z_diff", "float", "spreads", "raw_diff over the floored spread", "subsets"),
        Column("<head>_spread", "float", "reward", "std of the head's K·A quantiles", "subsets"),
    ),
)
"""One row per decision of ``priqn mechanism --standstill``
(:func:`priqn.tools.standstill.standstill_rows`); ``<head>``: safety and risk."""

EPISODE_KEYS: list[str] = ["eval_run", "net", "density", "episode"]
"""The columns that name one replayed episode in a table of decision rows."""


def episodes_in(frame: Any) -> int:
    """How many episodes a table of decision rows holds (0 for an empty one)."""
    return int(frame.groupby(EPISODE_KEYS).ngroups) if len(frame) else 0


def ended_as_evaluated(evaluated: Any, key: tuple, steps: int, ended: Mapping[str, Any]) -> bool:
    """Whether a replayed episode (``steps`` decisions, ``ended``: its final values) ended
    as its row ``key`` of the cell's ``episodes.csv`` (``evaluated``, indexed by
    :data:`EPISODE_KEYS`) says: the same length, success, collision and off-road flags."""
    want = evaluated.loc[key]
    return int(want["steps"]) == steps and all(
        bool(want[k]) == bool(ended[k]) for k in ("success", "collision", "off_road")
    )


# ----------------------------------------------------------------------------- cache


def default_cache() -> Path:
    """Where decision rows are cached unless ``--decisions`` says:
    ``$XDG_CACHE_HOME/priqn/decisions`` (``~/.cache/priqn/decisions``)."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "priqn" / "decisions"


@dataclass(frozen=True)
class DecisionCache:
    """Replayed cells' decision rows on disk: ``<folder>/<kind>/<cell>.<key>.csv`` and,
    beside it, ``.json`` with the schema's kind and version and the replay's parameters
    (``key``: a hash of those). Rows of another schema version or other parameters have
    another key, so they are never read: the cell is replayed again."""

    folder: Path

    def path(self, schema: RowSchema, cell: str, params: Mapping[str, Any]) -> Path:
        """The CSV file of ``cell``'s rows under ``schema`` and ``params``."""
        key = hashlib.sha256(json.dumps(self._record(schema, params), sort_keys=True).encode())
        return self.folder / schema.kind / f"{cell}.{key.hexdigest()[:12]}.csv"

    @staticmethod
    def _record(schema: RowSchema, params: Mapping[str, Any]) -> dict[str, Any]:
        return {"rows": schema.kind, "schema_version": schema.version, "params": dict(params)}

    def load(self, schema: RowSchema, cell: str, params: Mapping[str, Any], episodes: int) -> Any:
        """The cached rows (pandas) when they are there, of this schema version and
        parameters, with ``episodes`` episodes and the schema's columns; else None."""
        import pandas as pd

        path = self.path(schema, cell, params)
        meta = path.with_suffix(".json")
        if not path.is_file() or not meta.is_file():
            return None
        if read_json(meta) != self._record(schema, params):
            return None
        frame = pd.read_csv(path, float_precision="round_trip")  # the floats as replayed
        if episodes_in(frame) != episodes or schema.check(frame):
            return None
        return frame

    def save(self, schema: RowSchema, cell: str, params: Mapping[str, Any], frame: Any) -> Path:
        """Write ``frame`` (one cell's rows, checked against ``schema``) and its record."""
        wrong = schema.check(frame)
        if wrong:
            raise ValueError(f"{cell}: not {schema.kind} rows v{schema.version}: {wrong}")
        path = self.path(schema, cell, params)
        write_csv(path, frame, float_format=None)
        write_json(path.with_suffix(".json"), self._record(schema, params))
        return path

    def rows(
        self,
        schema: RowSchema,
        cell: str,
        params: Mapping[str, Any],
        episodes: int,
        replay: Callable[[], Any],
        progress: Any = None,
    ) -> Any:
        """``cell``'s rows: the cached ones (:meth:`load`), else ``replay()``'s, saved."""
        frame = self.load(schema, cell, params, episodes)
        if frame is not None:
            if progress is not None:
                progress.update(episodes)
            return frame
        frame = replay()
        self.save(schema, cell, params, frame)
        return frame


# ----------------------------------------------------------------------------- seeds


def rate(values: Any) -> float:
    """The mean of ``values`` as floats (a share, for flags); NaN when there are none."""
    values = np.asarray(values, dtype=float)
    return float(values.mean()) if values.size else math.nan


def median(values: Any) -> float:
    """The median over the finite values; NaN when there are none."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    return float(np.median(values)) if values.size else math.nan


def replay_share(decisions: Any) -> float:
    """Share of a cell's replayed episodes that ended as evaluated (``replay_matches``)."""
    return rate(decisions.groupby(EPISODE_KEYS)["replay_matches"].first())


@dataclass(frozen=True)
class CellRows:
    """One replayed cell: what the seed table needs of it."""

    name: str
    """``<row>__seed<k>`` (``@<budget>`` for a kept snapshot)."""
    seed: int
    """Its training seed."""
    evaluated: Any
    """Its whole evaluation's ``episodes.csv`` (pandas)."""
    decisions: Any
    """Its replayed decision rows (pandas)."""

    @property
    def row(self) -> str:
        """The experiment row it belongs to: the name before ``__seed``."""
        return self.name.split("__seed")[0]


@dataclass(frozen=True)
class DecisionMeasure:
    """What one kind of report makes of decision rows: the seed table's leading columns
    of a cell, its measures, the groups of cells averaged below, and the Markdown view."""

    kind: str
    """The report's kind (``meta.json``) and the name of its table and figure."""
    identity: Callable[[CellRows], dict[str, Any]]
    """A cell's leading columns (name, seed, hold-out rates, ``replay_matches``)."""
    summary: Callable[[Any], dict[str, Any]]
    """A cell's measures from its decision rows (pandas)."""
    groups: Callable[[Any], list[tuple[dict[str, Any], Any]]]
    """The seed table → each group's leading columns and its rows (a boolean mask)."""
    shown: tuple[str, ...]
    """The columns of the table in report.md (the CSV has all)."""
    formats: Mapping[str, str] = field(default_factory=dict)
    """Format spec per column in report.md (default ``.3f`` for floats)."""


def seed_table(measure: DecisionMeasure, cells: Iterable[CellRows]) -> Any:
    """One row per cell (``measure.identity`` then ``measure.summary``), then one per
    group (:func:`group_means`), as pandas."""
    import pandas as pd

    seeds = pd.DataFrame([{**measure.identity(c), **measure.summary(c.decisions)} for c in cells])
    return pd.concat([seeds, group_means(seeds, measure.groups(seeds))], ignore_index=True)


def group_means(table: Any, groups: Sequence[tuple[Mapping[str, Any], Any]]) -> Any:
    """One row per group (its leading columns, its rows of ``table`` as a boolean mask):
    every other column's mean over the group's rows (NaN for an empty group)."""
    import pandas as pd

    rows = []
    for identity, mask in groups:
        part = table[mask]
        row = dict(identity)
        for c in table.columns:
            if c not in identity:
                row[c] = float(part[c].astype(float).mean()) if len(part) else math.nan
        rows.append(row)
    return pd.DataFrame(rows)


# ----------------------------------------------------------------------------- report


def markdown(frame: Any, formats: Mapping[str, str] | None = None) -> str:
    """``frame`` as a Markdown table: floats by their column's format spec in
    ``formats`` (default ``.3f``), NaN as "–", anything else as text."""
    formats = formats or {}
    cols = list(frame.columns)
    rows = []
    for _, r in frame.iterrows():
        cells = []
        for c in cols:
            v = r[c]
            if isinstance(v, (float, np.floating)):
                cells.append("–" if math.isnan(v) else format(v, formats.get(c, ".3f")))
            else:
                cells.append(str(v))
        rows.append(cells)
    return markdown_table(cols, rows)


@dataclass(frozen=True)
class ReportTable:
    """A table of a report: ``tables/<name>.csv`` (floats exact), and in report.md under
    ``heading`` when ``shown`` names its columns there."""

    name: str
    frame: Any
    shown: tuple[str, ...] = ()
    heading: str = ""
    formats: Mapping[str, str] = field(default_factory=dict)


def decision_report(
    kind: str,
    command: str,
    title: str,
    intro: str,
    tables: Sequence[ReportTable],
    figure: Any,
    fields: Mapping[str, Any],
) -> Report:
    """The report of decision rows (kind ``kind``): ``report.md`` (``title``, ``intro``,
    the command, each shown table, the figure), ``tables/<name>.csv`` (floats exact),
    ``figures/<kind>.png`` and ``.pdf``, and ``meta.json`` (``kind``, ``command``,
    ``fields``); rendered by :func:`priqn.analysis.artifacts.render`."""
    sections = [Section([f"# {title}", "", intro, "", f"Made by `{command}`.", ""])]
    for t in tables:
        lines = [f"## {t.heading}", ""] if t.shown and t.heading else []
        lines += [markdown(t.frame[list(t.shown)], t.formats), ""] if t.shown else []
        sections.append(Section(lines, tables={t.name: t.frame}))
    sections.append(Section([f"![{kind}](figures/{kind}.png)", ""], figures={kind: figure}))
    return Report(kind, "report.md", sections, command, None, fields, float_format=None)
