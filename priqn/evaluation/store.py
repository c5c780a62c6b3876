"""An evaluation folder (``<run>/eval[-<name>]/``): one CSV per finished (eval run, net,
density) cell under ``cells/``, ``meta.json`` (its status, hold-out hash, EvalConfig and
seeds) and, once every cell is done, ``episodes.csv``.

Resumable: each finished cell is written atomically; a second call skips finished cells.
``meta.json`` says ``"status": "complete"`` only after every cell is done. A different
hold-out set or EvalConfig than the evaluation already in the folder refuses to mix
(:func:`earlier_evaluation`, the one check; ``force`` starts over).
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from priqn.config import to_dict
from priqn.errors import PriqnError
from priqn.evaluation.protocol import (
    LABEL_KEYS,
    EvalConfig,
    EvalScene,
    episode_columns,
    eval_config_changes,
    make_scenes,
)
from priqn.evaluation.rollout import run_scenes
from priqn.io import atomic_write_json, atomic_write_text, read_json
from priqn.objectives import OBJECTIVES, names_in_columns
from priqn.run.folder import RunFolder, Status


def cell_file(eval_dir: Path, cell: tuple[int, str, float]) -> Path:
    """File of one finished (eval run, net, density) cell."""
    eval_run, net, density = cell
    return (
        eval_dir / RunFolder.EVAL_CELLS / f"r{eval_run}__{net.replace('/', '__')}__d{density:g}.csv"
    )


def _write_cell(path: Path, rows: list[dict[str, Any]]) -> None:
    import pandas as pd

    names = names_in_columns(list(rows[0])) if rows else OBJECTIVES  # the policy's objectives
    frame = pd.DataFrame(rows, columns=list(episode_columns(names))).sort_values("episode")
    atomic_write_text(path, frame.to_csv(index=False, lineterminator="\n"))


def _cell_complete(path: Path, expected_rows: int) -> bool:
    if not path.is_file():
        return False
    import pandas as pd

    try:
        frame = pd.read_csv(path)
    except (OSError, ValueError):
        return False
    names = names_in_columns(list(frame.columns))
    return len(frame) == expected_rows and list(frame.columns) == list(episode_columns(names))


def earlier_evaluation(
    eval_dir: Path, holdout_hash: str, eval_config: Mapping[str, Any]
) -> dict[str, Any] | None:
    """The ``meta.json`` of the evaluation already in ``eval_dir`` (None if there is none),
    once checked that this one may keep it: the same hold-out set (``holdout_hash``) and
    no result-affecting change of ``eval_config`` (a recorded EvalConfig, ``to_dict``);
    else a one-line PriqnError (``--force`` starts over). Finished or not: its
    ``status`` says which. The one meta check of :func:`evaluate_policy` and
    ``priqn.evaluation.cli.evaluate_run`` (which returns a complete one as it is)."""
    meta_path = Path(eval_dir) / RunFolder.META
    if not meta_path.is_file():
        return None
    old = read_json(meta_path)
    if old.get("holdout_hash") != holdout_hash:
        raise PriqnError(
            f"{meta_path}: this run was evaluated on a different hold-out set (holdout_hash "
            f"{str(old.get('holdout_hash'))[:12]} vs now {holdout_hash[:12]}); use --force to start over"
        )
    diff = eval_config_changes(old.get("eval_config") or {}, dict(eval_config))
    if diff:
        raise PriqnError(
            f"{meta_path}: an evaluation with a different eval_config is already here "
            f"({diff}); use --force to start over"
        )
    return old


def _new_meta(
    cfg: EvalConfig,
    net_ids: Sequence[str],
    holdout_hash: str,
    run_name: str,
    extra_meta: dict[str, Any] | None,
) -> dict[str, Any]:
    """``meta.json`` of an evaluation that starts (status running; ``extra_meta`` last)."""
    return {
        "status": Status.RUNNING,
        "holdout_family": None if cfg.nets else cfg.family,
        "holdout_hash": holdout_hash,
        "holdout_nets": sorted(net_ids),
        "eval_config": to_dict(cfg),
        "eval_seed": cfg.seed,
        "scene_seed_rule": "SeedSequence(seed, spawn_key=(eval_run, net_index, density_index, episode)).generate_state(2) -> (reset_seed, act_seed)",
        "run": run_name,
        **(extra_meta or {}),
    }


def _unfinished_cells(
    eval_dir: Path, cells: Mapping[tuple[int, str, float], Sequence[EvalScene]]
) -> set[tuple[int, str, float]]:
    """The cells of ``cells`` (cell -> its scenes) with no complete file in ``eval_dir``."""
    return {c for c, sc in cells.items() if not _cell_complete(cell_file(eval_dir, c), len(sc))}


class _EvaluationWriter:
    """Where an evaluation's results go while it runs: ``meta.json`` with the time spent so
    far (an interrupted evaluation's time included), and each cell's file once its last
    episode is in."""

    def __init__(
        self,
        eval_dir: Path,
        meta: dict[str, Any],
        earlier_s: float,
        fixed: Mapping[str, Any],
        cells: Mapping[tuple[int, str, float], list[EvalScene]],
        todo_cells: Sequence[tuple[int, str, float]],
    ) -> None:
        self.eval_dir, self.meta, self.earlier_s, self.fixed = eval_dir, meta, earlier_s, fixed
        self.cells = cells
        """Cell -> its scenes (all of them, kept cells included)."""
        self.pending: dict[tuple[int, str, float], list[dict[str, Any]]] = {
            c: [] for c in todo_cells
        }
        """Cell -> rows of its episodes played so far (cells still to play)."""
        self.started = time.perf_counter()

    def write_meta(self, **fields: Any) -> None:
        """Write meta.json with the evaluation's time so far (kept across interruptions)."""
        wall_s = round(self.earlier_s + time.perf_counter() - self.started, 1)
        self.meta.update(fields, wall_s=wall_s)
        atomic_write_json(self.eval_dir / RunFolder.META, self.meta)

    def on_episode(self, scene: EvalScene, values: dict[str, Any]) -> None:
        """An episode ended: its row; its cell's file once the cell is complete."""
        row = {
            **self.fixed,
            "eval_run": scene.eval_run,
            "net": scene.net,
            "density": scene.density,
            "episode": scene.episode,
            "reset_seed": scene.reset_seed,
            "command": scene.command or "",
            **values,
        }
        self.pending[scene.cell].append(row)
        if len(self.pending[scene.cell]) == len(self.cells[scene.cell]):
            _write_cell(cell_file(self.eval_dir, scene.cell), self.pending.pop(scene.cell))
            self.write_meta()


def evaluate_policy(
    policy: Any,
    eval_dir: Path,
    cfg: EvalConfig,
    net_ids: Sequence[str],
    holdout_hash: str,
    run_name: str,
    make_env: Callable[[int], Any],
    extra_meta: dict[str, Any] | None = None,
    force: bool = False,
) -> Path:
    """Evaluate ``policy`` on every scene; write cells, ``episodes.csv`` and ``meta.json``.

    ``make_env(num_envs)`` builds the vector env (SAME_STEP autoreset). Finished
    cells already under ``eval_dir/cells`` are kept; returns ``episodes.csv``.
    """
    import pandas as pd
    from tqdm.auto import tqdm

    eval_dir = Path(eval_dir)
    meta = _new_meta(cfg, net_ids, holdout_hash, run_name, extra_meta)
    old = None if force else earlier_evaluation(eval_dir, holdout_hash, meta["eval_config"])
    if force and eval_dir.exists():
        shutil.rmtree(eval_dir)
    labels = dict(getattr(policy, "labels", {}) or {})
    fixed = {key: labels.get(key) for key in LABEL_KEYS}
    fixed.update({"run": run_name, "holdout_hash": holdout_hash})
    scenes = make_scenes(cfg, net_ids)
    cells: dict[tuple[int, str, float], list[EvalScene]] = {}
    for scene in scenes:
        cells.setdefault(scene.cell, []).append(scene)
    todo_cells = _unfinished_cells(eval_dir, cells)
    # Evaluation time already spent on the kept cells (a resumed evaluation) counts too.
    earlier_s = float((old or {}).get("wall_s") or 0.0)
    writer = _EvaluationWriter(eval_dir, meta, earlier_s, fixed, cells, todo_cells)
    writer.write_meta()

    todo = [s for s in scenes if s.cell in todo_cells]
    if todo:
        vec_env = make_env(min(cfg.num_workers, len(todo)))
        try:
            with tqdm(total=len(todo), desc=f"evaluate {run_name}", unit="ep", disable=None) as bar:
                run_scenes(policy, vec_env, todo, writer.on_episode, progress=bar)
        finally:
            vec_env.close()

    frames = [pd.read_csv(cell_file(eval_dir, c)) for c in sorted(cells)]
    episodes = pd.concat(frames, ignore_index=True)
    out = eval_dir / RunFolder.EVAL_EPISODES
    atomic_write_text(out, episodes.to_csv(index=False, lineterminator="\n"))
    writer.write_meta(status=Status.COMPLETE, episodes=len(episodes))
    return out
