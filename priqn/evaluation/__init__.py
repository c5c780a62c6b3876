"""The evaluation protocol and its machinery, one module per concept (``priqn evaluate``
itself is :mod:`priqn.evaluation.cli`).

Modules import one way, each only from those before it:

- :mod:`~priqn.evaluation.protocol` — torch-free, what the analysis reads: ``EvalConfig``,
  :class:`~priqn.evaluation.protocol.EvalScene` and ``make_scenes`` (the scene rule), the
  episode table's columns, the evaluation folders' names;
- :mod:`~priqn.evaluation.rollout` — the one rollout loop (``rollout``, ``RolloutStep``,
  ``run_scenes``) of evaluation, training's evaluation, ``priqn inspect`` and the analysis;
- :mod:`~priqn.evaluation.targets` — what an evaluation plays: the runs under some paths,
  the nets (the hold-out family, or your own, checked first) and the env set to them;
- :mod:`~priqn.evaluation.store` — an evaluation folder: its cells, its ``meta.json``
  checks (one place) and resuming (``evaluate_policy``);
- :mod:`~priqn.evaluation.reference` — the reference drivers (``--reference sumo|random``).
"""
