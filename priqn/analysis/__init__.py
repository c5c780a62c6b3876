"""Analysis of evaluated runs, cut like rliable by what the user does.

Read and estimate:

- :mod:`analysis.load` — every evaluated run under a folder into one episode table
  (refusing mixed inputs);
- :mod:`analysis.stats` — rliable estimates (IQM, optimality gap, P(X > Y),
  performance profiles) on ``scores_RT`` matrices;
- :mod:`analysis.inference` — intervals, tests, Holm, power and verdict words over
  training seeds;
- :mod:`analysis.paper` — what the paper reports (Table II rows, success rates, quoted
  gains), with sources;
- :mod:`analysis.claims` — the paper's claims as data and the verdict rule;
- :mod:`analysis.curves` — sample-efficiency curves (success against training decisions),
  one section every report shares (:func:`analysis.curves.efficiency`).

Pre-registered designs of an experiment file:

- :mod:`analysis.questions` — a design's cells (a ``[sequential]`` table or each
  ``[[question]]``) scored at its budget, its looks taken, and the cells its next look needs;
- :mod:`analysis.sequential` — AdaStop's looks taken in order on a design's scores, and
  the verdict words;
- :mod:`analysis.forecast` — how likely a design is to decide (a planning simulation);
- :mod:`analysis.calibration` — a ``[calibration]`` rule: the row whose outcome mix is
  nearest a target, and its report.

Tables, figures and reports:

- :mod:`analysis.tables` — Table II and Table I as data, Markdown, LaTeX and CSV;
- :mod:`analysis.figures` — the paper-style figures (matplotlib figures);
- :mod:`analysis.render` — the one CSV and Markdown table renderer;
- :mod:`analysis.sections` — :class:`~analysis.sections.Section` and
  :class:`~analysis.sections.Report`: what every report kind builds, pure of the disk;
- :mod:`analysis.artifacts` — :func:`~analysis.artifacts.render`, the one renderer of a
  report's files (``report.md``, ``meta.json`` in one schema, ``tables/``, ``figures/``
  as PNG + PDF);
- :mod:`analysis.mixes` — outcome mixes (shares per outcome and density) and their L1
  distances, shared by the calibration and the questions' outcome-mix section;
- :mod:`analysis.reports` — every kind of report (:data:`~analysis.reports.REPORTS`), and
  the one place ``priqn report`` and ``priqn sweep`` choose a folder's kind;
- :mod:`analysis.request` — what a report is asked for, and the one builder of the command
  its ``meta.json`` records (re-running it regenerates the folder byte for byte);
- :mod:`analysis.report` — the grid report (Tables I/II, rliable):
  :func:`analysis.report.grid_report` (rendered from Python by
  :func:`analysis.report.make_report`);
- :mod:`analysis.claims_report` — the claims section and ``tables/claims.csv``;
- :mod:`analysis.sequential_report` — the report of a ``[sequential]`` table;
- :mod:`analysis.questions_report` — the report of ``[[question]]`` tables, with
  :mod:`analysis.questions_outcomes`, its descriptive sections on how the counted cells'
  episodes end;
- :mod:`analysis.horizon` — the same runs at longer evaluation-only episode limits;
- :mod:`analysis.traffic_report` — the same runs under another traffic setting;
- :mod:`analysis.generalisation` — evaluations on other nets (``priqn evaluate --nets``),
  reported apart from Table II;
- :mod:`analysis.reference` — reference drivers (``priqn evaluate --reference``) as
  unranked rows;
- :mod:`analysis.mechanism`, :mod:`analysis.standstill` — ``priqn mechanism``'s seed
  measures, tables and figures from its per-decision rows (the replay that makes the rows,
  with torch and SUMO, is :mod:`priqn.tools.cells` and its two tools).

The protocol and every statistical choice are documented in ``docs/evaluation.md``.
"""
