"""A training run's lifecycle in files and records: what a run is, what it writes, where
it comes from. Torch-free at import (the analysis and the sweep read run folders).

- :mod:`~priqn.run.train_config` — what a run is: ``TrainConfig``, presets,
  ``resolve_config``, seeds, run names, ``policy_labels``;
- :mod:`~priqn.run.folder` — ``RunFolder``: the paths of a run folder's files, its
  config, meta.json, status and the one-writer lock; ``Status``, ``Provenance``;
- :mod:`~priqn.run.session` — a training session started or resumed (``start_session``),
  meta.json's ``sessions``;
- :mod:`~priqn.run.checkpoint` — the format of a run's torch files (``Checkpoint``,
  ``PolicyState``);
- :mod:`~priqn.run.checkpointer` — those files saved and loaded in a run folder, a
  training session's checkpoint captured (``capture_training``), and ``load_policy``
  (the network built by :mod:`priqn.agents.build`);
- :mod:`~priqn.run.stepper` — how the training loop steps its env workers (all at once,
  the updates overlapped or after the step, or in groups in turn), chosen from the config;
- :mod:`~priqn.run.writer` — ``BackgroundWriter``: the thread that writes a training
  session's checkpoints, snapshots and meta.json records while the loop goes on;
- :mod:`~priqn.run.metrics` — the format of ``metrics.csv``, written and read;
- :mod:`~priqn.run.evaluations` — the evaluations a run folder holds: names, folders,
  recorded status;
- :mod:`~priqn.run.episodes` — the one reader of an ended episode's ``final_info``;
- :mod:`~priqn.run.provenance` — ``gather``: git, versions, scenario manifests;
- :mod:`~priqn.run.timing` — ``SectionClock``, where a loop's wall time goes.

The loop that fills a run folder is :mod:`priqn.train` (it imports the evaluation and
the analysis' figures, both of which read run folders, so it sits above them).
"""
