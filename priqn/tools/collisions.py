"""``priqn mechanism RUNS --collisions --out DIR``: the kind of every evaluated collision.

Evaluations made since issue 62 record each collision's forensics in ``episodes.csv``
(:mod:`priqn.env.forensics`: who struck whom, the speeds, whether the NPC could have
stopped, the kind). Committed evaluations made before stay as they are: this tool plays
their collision episodes again, on the same scenes with the same policy and seeds (the
env is deterministic per seed, so each ends as it did; ``replayed_collision`` says so),
and reads the forensics from the replay. An evaluation that already has them is read,
not replayed.

``--traffic NAME`` replays every collision scene under another named traffic setting
instead: which of them that traffic's NPCs would have prevented (with the same policy,
whose later decisions may change with the traffic: the same scenes, not the same episodes).

Writes the report folder ``DIR`` (:func:`priqn.analysis.collisions.collisions_report`):
``tables/collisions.csv`` (one row per collision), ``tables/collisions_by_kind.csv`` and
``report.md`` (per row and density: the share of each kind, and the share a
Traffic-Manager-like NPC would have prevented), ``meta.json``.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from priqn.evaluation.protocol import SCENE_COLUMNS
from priqn.objectives import COLLISION_COLUMNS
from priqn.run.checkpointer import load_policy
from priqn.run.episodes import resolve_outcomes
from priqn.tools.cells import ReplayCell, replayed_episodes


def collision_rows(
    cell: ReplayCell, workers: int = 1, progress: Any = None, traffic: str | None = None
) -> list[dict]:
    """One row per collision of ``cell``'s evaluation: its scene, the row's label and seed,
    the traffic, and the forensics (read, or replayed where the table lacks them).

    ``traffic``: replay every collision scene under that named setting's NPCs instead
    (:data:`priqn.env.traffic.TRAFFIC_SETTINGS`; the evaluation's episode limit stays):
    ``replayed_collision`` says whether the scene still ends in a collision there, and the
    forensics are the replay's (empty where it does not)."""
    episodes = resolve_outcomes(cell.episodes)
    hits = episodes[episodes["collision"].astype(bool)]
    base = {"cell": cell.name}
    if traffic is None and all(c in hits.columns for c in COLLISION_COLUMNS):
        return [{**base, **_identity(r), **{c: r[c] for c in COLLISION_COLUMNS},
                 "replayed_collision": ""} for r in hits.to_dict("records")]  # fmt: skip
    from priqn.evaluation.protocol import make_scenes
    from priqn.evaluation.targets import evaluation_env

    keys = {tuple(r[k] for k in SCENE_COLUMNS): r for r in hits.to_dict("records")}
    scenes = [
        s
        for s in make_scenes(cell.eval_config, cell.net_ids)
        if (s.eval_run, s.net, s.density, s.episode) in keys
    ]
    if not scenes:
        return []
    policy = load_policy(cell.path, device="cpu", snapshot=cell.snapshot)
    env_cfg = evaluation_env(policy.env_config, cell.eval_config, None)
    if traffic is not None:
        from priqn.env.traffic import traffic_setting

        env_cfg = dataclasses.replace(env_cfg, traffic=traffic_setting(traffic).behaviour)
    rows = []
    played = replayed_episodes(
        policy, env_cfg, scenes, cell.eval_config.seed, workers=workers, quantiles=False
    )
    with contextlib.closing(played):
        for steps in played:
            scene, values = steps[-1].scene, steps[-1].episode
            row = keys[(scene.eval_run, scene.net, scene.density, scene.episode)]
            rows.append({**base, **_identity(row), **{c: values.get(c, "") for c in COLLISION_COLUMNS},
                         "replayed_collision": bool(values["collision"])})  # fmt: skip
            if progress is not None:
                progress.update(1)
    return rows


def _identity(row: dict) -> dict:
    """The scene and row of an episode row."""
    keep = ("label", "agent", "train_seed", *SCENE_COLUMNS, "command")
    return {k: row.get(k, "") for k in keep}


def analyse(
    cells: Sequence[ReplayCell], out: Path, workers: int, command: str, traffic: str | None = None
) -> Path:
    """Every cell's collisions and their table into the report folder ``out``
    (``command``: the one that makes it, for ``meta.json``; ``traffic``: replay them under
    that named setting, :func:`collision_rows`); returns its report.md."""
    import pandas as pd
    from tqdm.auto import tqdm

    from priqn.analysis.artifacts import render
    from priqn.analysis.collisions import collisions_report

    total = sum(int(resolve_outcomes(c.episodes)["collision"].astype(bool).sum()) for c in cells)
    rows: list[dict] = []
    with tqdm(total=total, desc="collisions", unit="ep", disable=None) as bar:
        for cell in cells:
            rows += collision_rows(cell, workers, bar, traffic)
    own = {c.name: _traffic_name(c.path) for c in cells}
    frame = pd.DataFrame(rows)
    if not frame.empty:
        frame.insert(1, "traffic", frame["cell"].map(own))
        if traffic is not None:
            frame.insert(2, "replay_traffic", traffic)
    return render(out, collisions_report(frame, command, replay_traffic=traffic))


def _traffic_name(run: Path) -> str:
    """The named traffic setting a run was trained with ('' for none): the name it
    records, else the one its config plays (:func:`priqn.env.traffic.run_setting_name`)."""
    from priqn.env.traffic import run_setting_name
    from priqn.run.folder import RunFolder

    folder = RunFolder(run)
    return run_setting_name(folder.meta(), folder.config().env)
