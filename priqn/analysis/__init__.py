"""Analysis of evaluated runs, cut like rliable by what the user does.

- :mod:`analysis.load` — every evaluated run under a folder into one episode table
  (refusing mixed inputs);
- :mod:`analysis.stats` — rliable estimates (IQM, optimality gap, P(X > Y),
  performance profiles) on ``scores_RT`` matrices;
- :mod:`analysis.tables` — Table II and Table I as data, Markdown, LaTeX and CSV;
- :mod:`analysis.figures` — the paper-style figures (PNG + PDF);
- :mod:`analysis.report` — ``priqn report`` / :func:`analysis.report.make_report`;
- :mod:`analysis.generalisation` — evaluations on other nets (``priqn evaluate --nets``),
  reported apart from Table II;
- :mod:`analysis.reference` — reference drivers (``priqn evaluate --reference``) as
  unranked rows.

The protocol and every statistical choice are documented in ``docs/evaluation.md``.
"""
