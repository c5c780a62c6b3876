"""Commands that look at trained runs from outside, imported by nothing but the CLI.

- :mod:`~priqn.tools.inspector` — ``priqn inspect``: why a policy acted, per-objective
  quantiles and optimal subsets, decision by decision (an HTML page);
- :mod:`~priqn.tools.play` — ``priqn play``: watch a policy drive in sumo-gui, record it;
- :mod:`~priqn.tools.diff` — ``priqn diff``: are two runs the same training, bit for bit?
"""
