"""Commands that look at trained runs from outside, imported by nothing but the CLI.

- :mod:`~priqn.tools.inspector` — ``priqn inspect``: why a policy acted, per-objective
  quantiles and optimal subsets, decision by decision (an HTML page);
- :mod:`~priqn.tools.mechanism` — ``priqn mechanism``: evaluated Pr-IQN cells replayed,
  the safety level's removals and the safety head's calibration per seed; its
  ``--standstill`` (:mod:`~priqn.tools.standstill`): why a policy stands still;
- :mod:`~priqn.tools.play` — ``priqn play``: watch a policy drive in sumo-gui, record it;
- :mod:`~priqn.tools.diff` — ``priqn diff``: are two runs the same training, bit for bit?

Shared by the diagnosis tools: :mod:`~priqn.tools.decisions` (what one decision shows:
greedy actions, the level that removed an action) and :mod:`~priqn.tools.cells`
(evaluated cells played again on their own scenes). The tables and figures made from
the per-decision rows are :mod:`priqn.analysis.mechanism` and
:mod:`priqn.analysis.standstill`.
"""
