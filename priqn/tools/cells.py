"""Evaluated cells played again on their own evaluation scenes (``priqn mechanism``).

A :class:`ReplayCell` is a run folder with a complete hold-out evaluation of its own
acting (``eval/``, or ``eval-at<N>/`` for the policy it kept at N decisions);
:func:`replay_scenes` picks the first of its scenes in a balanced order, and
:func:`replayed_episodes` plays them with the cell's policy through the one rollout loop
(:func:`priqn.evaluation.rollout.rollout`, the same reset and acting seeds as the
evaluation), one whole episode at a time. Torch and SUMO are imported inside the
functions that play.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from priqn.agents.labels import budget_text
from priqn.analysis.load import read_episodes
from priqn.errors import PriqnError
from priqn.io import read_json
from priqn.run.evaluations import evaluation_dir, snapshot_evaluation
from priqn.run.folder import RunFolder


@dataclasses.dataclass(frozen=True)
class ReplayCell:
    """One evaluated cell and what its replay needs (Pr-IQN for the mechanism, any agent for
    its ``--standstill``)."""

    path: Path
    """The run folder."""
    name: str
    """Its name (``<row>__seed<k>``)."""
    holdout_success: float
    """Success rate over its whole evaluation (``eval/`` or ``eval-at<N>/``)."""
    episodes: Any
    """That evaluation's ``episodes.csv`` (pandas)."""
    eval_config: Any
    """The :class:`priqn.evaluation.protocol.EvalConfig` it was evaluated with."""
    net_ids: tuple[str, ...]
    """The hold-out nets it was evaluated on."""
    snapshot: int = 0
    """0: the run's final policy and ``eval/``; N: the policy it kept at N decisions and
    that policy's evaluation ``eval-at<N>/``."""


def load_cell(path: Path, snapshot: int = 0) -> ReplayCell:
    """A run folder with a complete ``eval/`` (``snapshot`` N: ``eval-at<N>/``): its
    episodes and evaluation config."""

    from priqn.evaluation.protocol import EvalConfig
    from priqn.sim.scenario import manifest_hash

    run = RunFolder(path)
    eval_dir = evaluation_dir(run, snapshot_evaluation(snapshot) if snapshot else "")
    meta_path = eval_dir / RunFolder.META
    if snapshot and run.is_run():
        keep_at = list(run.config().checkpoint.keep_at)
        if snapshot not in keep_at:
            raise PriqnError(
                f"{path}: kept no policy at {snapshot} decisions (checkpoint.keep_at = {keep_at})"
            )
        if not meta_path.is_file():
            raise PriqnError(
                f"{path}: {run.rel(eval_dir)} not evaluated; "
                f"run priqn evaluate {path} --snapshot {snapshot}"
            )
    if not run.is_run() or not meta_path.is_file():
        raise PriqnError(f"{path}: not an evaluated run folder (no config.toml or eval/meta.json)")
    meta = read_json(meta_path)
    known = {f.name for f in dataclasses.fields(EvalConfig)}
    fields = {
        k: (tuple(v) if isinstance(v, list) else v)
        for k, v in (meta.get("eval_config") or {}).items()
        if k in known
    }
    eval_cfg = EvalConfig(**fields)
    if eval_cfg.nets or eval_cfg.acting != "own":
        raise PriqnError(
            f"{path}: {run.rel(eval_dir)} is not a hold-out evaluation of the policy's own acting"
        )
    if meta.get("holdout_hash") != manifest_hash(eval_cfg.family):
        raise PriqnError(
            f"{meta_path}: evaluated on another version of the {eval_cfg.family!r} nets "
            "(holdout_hash differs from the shipped manifest); its scenes cannot be replayed"
        )
    episodes = read_episodes(eval_dir, resolve=False)
    return ReplayCell(
        run.path,
        run.name + (f"@{budget_text(snapshot)}" if snapshot else ""),
        float(episodes["success"].astype(float).mean()),
        episodes,
        eval_cfg,
        tuple(meta.get("holdout_nets") or ()),
        snapshot,
    )


def load_cells(paths: Sequence[str | Path], snapshot: int = 0) -> list[ReplayCell]:
    """:func:`load_cell` for every run under ``paths``. A report names each cell once and
    groups cells by the row before ``__seed``, so runs of the same name from different
    designs (``results/budget-tm/iqn__seed80`` beside ``results/paper-point-tm/iqn__seed80``)
    are named ``<design>/<name>`` and grouped apart; the same name twice in one design
    folder is a one-line error."""
    from priqn.evaluation.targets import find_runs

    cells = [load_cell(p, snapshot) for p in find_runs(paths)]
    names = [c.name for c in cells]
    if len(set(names)) == len(names):
        return cells
    qualified = [
        dataclasses.replace(c, name=f"{Path(c.path).parent.name}/{c.name}")
        if names.count(c.name) > 1
        else c
        for c in cells
    ]
    seen: dict[str, Path] = {}
    for cell in qualified:
        if cell.name in seen:
            raise PriqnError(
                f"{cell.path}: named {cell.name} like {seen[cell.name]}; a report names each "
                "cell once: report them separately"
            )
        seen[cell.name] = Path(cell.path)
    return qualified


def replay_scenes(scenes: Sequence[Any], episodes: int) -> list[Any]:
    """The first ``episodes`` (0 = all) of a cell's evaluation scenes in the order
    (eval run, episode, net, density): every net and density of the first evaluation run
    in turn, so a subset is balanced whatever a cell's episodes per cell. Scenes depend
    only on the eval seed and these indices, so cells evaluated with more episodes per
    cell (table2_cpu: 20) replay the same first scenes as the others (headline: 6)."""
    ordered = sorted(scenes, key=lambda s: (s.eval_run, s.episode, s.net, s.density))
    return ordered[:episodes] if episodes else ordered


def replayed_episodes(
    policy: Any,
    env_cfg: Any,
    scenes: Sequence[Any],
    seed: int,
    workers: int = 1,
    quantiles: bool = True,
) -> Iterator[list[Any]]:
    """Play ``scenes`` with ``policy`` in ``workers`` env processes (one SUMO simulation
    each; ``seed``: the evaluation's), yielding each episode's
    :class:`~priqn.evaluation.rollout.RolloutStep` records, in order, once it ends (the
    last one carries the episode's values). ``quantiles``: record the fixed-grid quantiles
    (and subsets) of every decision. Torch runs one thread meanwhile (one state at a time:
    more threads only fight the env workers). Close the generator when stopping early."""
    import torch

    from priqn.env.vector import make_vector_env
    from priqn.evaluation.rollout import rollout

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    venv = make_vector_env(env_cfg, workers, seed=seed)
    open_steps: dict[Any, list[Any]] = {}
    try:
        for step in rollout(policy, venv, scenes, quantiles=quantiles):
            open_steps.setdefault(step.scene, []).append(step)
            if step.episode is not None:
                yield open_steps.pop(step.scene)
    finally:
        venv.close()
        torch.set_num_threads(threads)
