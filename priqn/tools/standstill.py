"""``priqn mechanism --standstill``: why a policy stands still, decision by decision (descriptive).

Replays evaluated cells on the first scenes of their own ``eval/`` (the one rollout loop,
quantiles recorded, as ``priqn mechanism``: :mod:`priqn.tools.cells`) and counts, per
decision (docs/mechanism.md, "Standing still"):

1. **go survival**: whether any "go" action (target speed > 0) is still in the optimal
   subset the ``--target`` level (default ``progress``) chooses from, i.e. in every level
   above it in the total order; if not, the *remover*: the first level whose subset
   holds no go action (:func:`priqn.tools.decisions.removed_by`);
2. **stop vs go**: for ``safety`` and ``risk``, the best stop and the best go action by
   that head's mean over the K fixed-grid quantiles: their raw means (reward units), the
   raw difference, the z-scored QD score difference the comparator saw (the raw
   difference over the per-state spread ``s = max(std, 1e-6)`` of all K·A quantiles), and
   that raw spread;
3. for a scalar agent (IQN): whether its greedy (executed) action stands still.

The rows (:func:`stop_vs_go`, :func:`standstill_rows`; their schema is
:data:`priqn.analysis.decisions.STANDSTILL_ROWS`) work on
:class:`priqn.evaluation.rollout.RolloutStep` records and need no SUMO; the seed measures,
the table and the figure are :mod:`priqn.analysis.standstill`'s.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from priqn.analysis.artifacts import render
from priqn.analysis.decisions import EPISODE_KEYS, STANDSTILL_ROWS, CellRows, ended_as_evaluated
from priqn.analysis.mechanism import MechanismConfig
from priqn.analysis.standstill import COMPARED, DEFAULT_TARGET, standstill_report
from priqn.errors import PriqnError
from priqn.run.checkpointer import load_policy
from priqn.run.folder import RunFolder
from priqn.tools.cells import replayed_episodes
from priqn.tools.decisions import decision_key, removed_by

MIN_STD = 1e-6
"""The comparators' floor of the per-state spread (``priqn.preorder.MIN_STD``)."""


# ----------------------------------------------------------------------------- counting


def stop_vs_go(
    q_KA: np.ndarray,
    go_A: np.ndarray,
    candidates_A: np.ndarray | None = None,
    spread_floor: float = 0.0,
) -> dict[str, float | int]:
    """One objective's fixed-grid quantiles ``[K, A]``: among ``candidates_A`` (the set its
    level chooses from, its parent's subset; None = all actions) the best stop and the
    best go action (argmax of the mean over K), their means, ``raw_diff`` = mean(stop) −
    mean(go), ``z_diff`` = the QD score difference score(stop) − score(go) the comparator
    sees (= raw_diff / s), and ``spread`` = the population std of all K·A entries, with
    ``s = max(spread, 1e-6, spread_floor)`` as in :func:`priqn.preorder.normalised`.
    The level keeps no go action iff ``z_diff`` > ε (QD, a total order). Without a stop
    or a go candidate, those entries are NaN / -1."""
    q = np.asarray(q_KA, dtype=np.float64)
    go_A = np.asarray(go_A, dtype=bool)
    cand_A = np.ones_like(go_A) if candidates_A is None else np.asarray(candidates_A, bool)
    mean_A = q.mean(axis=0)
    spread = float(q.std())
    best = {}
    for name, mask in (("stop", cand_A & ~go_A), ("go", cand_A & go_A)):
        idx = np.flatnonzero(mask)
        best[name] = int(idx[int(np.argmax(mean_A[idx]))]) if idx.size else -1
    mean = {k: float(mean_A[i]) if i >= 0 else math.nan for k, i in best.items()}
    raw = mean["stop"] - mean["go"]
    return {
        "best_stop": best["stop"],
        "best_go": best["go"],
        "mean_stop": mean["stop"],
        "mean_go": mean["go"],
        "raw_diff": raw,
        "z_diff": raw / max(spread, MIN_STD, spread_floor),
        "spread": spread,
    }


def standstill_rows(
    steps: Sequence[Any],
    objectives: Sequence[str],
    above: Sequence[str],
    speeds_A: np.ndarray,
    spread_floor_O: Sequence[float] | None = None,
) -> list[dict[str, Any]]:
    """One episode's :class:`~priqn.evaluation.rollout.RolloutStep` records → one row per
    decision. A decision with optimal subsets (Pr-IQN) gets the go survival through
    ``above`` (no go action left: the first level of ``above`` whose subset holds none,
    :func:`priqn.tools.decisions.removed_by`) and :func:`stop_vs_go` of the :data:`COMPARED` heads among ``objectives``
    (head order), each among its parent's subset in ``above`` (the root: all actions);
    one without (IQN) only its action's speed."""
    if not steps or steps[-1].episode is None:
        raise ValueError("standstill_rows: needs one whole episode (its last step ends it)")
    end = steps[-1].episode
    go_A = np.asarray(speeds_A) > 0.0
    rows = []
    for s in steps:
        d = s.decision
        row: dict[str, Any] = decision_key(s)
        row.update(
            stop=not bool(go_A[s.action]),
            episode_timeout=bool(end["timeout"]),
            episode_success=bool(end["success"]),
        )
        if d.subsets_BLA is not None:
            remover = removed_by(d.subsets_BLA[0], d.levels, above, go_A)
            row.update(go_survives=not remover, removed_by=remover)
            for name in (o for o in COMPARED if o in objectives and o in above):
                h, i = list(objectives).index(name), list(above).index(name)
                floor = 0.0 if spread_floor_O is None else float(spread_floor_O[h])
                parent = None if i == 0 else d.subsets_BLA[0, d.levels.index(above[i - 1])]
                measures = stop_vs_go(d.quantiles_BHKA[0, h], go_A, parent, floor)
                for key, v in measures.items():
                    row[f"{name}_{key}"] = v
        rows.append(row)
    return rows


# ----------------------------------------------------------------------------- replay


def replay(cell: Any, scenes: Sequence[Any], target: str, progress: Any = None) -> Any:
    """Play ``scenes`` (a :class:`priqn.tools.cells.ReplayCell`'s) with its policy,
    quantiles recorded; its :func:`standstill_rows` (pandas), each with
    ``replay_matches``: its episode ended as the cell's ``episodes.csv`` says."""
    import pandas as pd

    from priqn.env.intersection import action_grid
    from priqn.evaluation.targets import evaluation_env

    policy = load_policy(cell.path, device="cpu", snapshot=cell.snapshot)
    agent = policy.agent
    above: tuple[str, ...] = ()
    floor = None
    if agent.subsets is not None:
        above = _above(agent.subsets.preorder, target)
        if agent.subsets.scale is not None:
            floor = [float(v) for v in agent.subsets.scale.floor().reshape(-1)]
    env_cfg = evaluation_env(policy.env_config, cell.eval_config, None)
    speeds_A = action_grid(env_cfg)[:, 0]
    rows: list[dict[str, Any]] = []
    episodes = replayed_episodes(
        policy, env_cfg, scenes, cell.eval_config.seed, quantiles=agent.subsets is not None
    )
    expected = cell.episodes.set_index(EPISODE_KEYS)
    with contextlib.closing(episodes):
        for played in episodes:
            last = played[-1]
            key = last.scene.cell + (last.scene.episode,)
            matches = ended_as_evaluated(expected, key, len(played), last.episode)
            new = standstill_rows(played, agent.objectives, above, speeds_A, floor)
            rows.extend({**r, "replay_matches": matches} for r in new)
            if progress is not None:
                progress.update(1)
    return pd.DataFrame(rows)


def _above(preorder: Any, target: str) -> tuple[str, ...]:
    """The levels above ``target`` in a total order, root first (error otherwise)."""
    if not preorder.is_chain():
        raise PriqnError("--standstill: needs a total-order preorder (a chain)")
    order = tuple(preorder.topological_order())
    if target not in order:
        raise PriqnError(f"--target {target}: not a level ({', '.join(order)})")
    return order[: order.index(target)]


def analyse(
    cells: Sequence[Any],
    out: Path,
    cfg: MechanismConfig,
    pick_scenes: Callable[[Any], Sequence[Any]],
    target: str = DEFAULT_TARGET,
    command: str = "",
) -> Path:
    """Replay every cell (``pick_scenes(cell)``: its scenes; a cell whose rows are in
    ``cfg.cache()`` is read instead; ``cfg.episodes``: asked per cell)
    and write the report folder ``out``
    (:func:`priqn.analysis.standstill.standstill_report`); returns its report.md."""
    from tqdm.auto import tqdm

    scenes = {c.name: list(pick_scenes(c)) for c in cells}
    cache = cfg.cache()
    replayed = []
    with tqdm(total=sum(map(len, scenes.values())), desc="standstill", unit="ep") as bar:
        for cell in cells:
            picked = scenes[cell.name]
            params = {"run": str(Path(cell.path).resolve()), "snapshot": cell.snapshot,
                      "episodes": len(picked), "target": target}  # fmt: skip

            def play(cell: Any = cell, picked: list[Any] = picked) -> Any:
                return replay(cell, picked, target, progress=bar)

            rows = cache.rows(STANDSTILL_ROWS, cell.name, params, len(picked), play, bar)
            seed = int(RunFolder(cell.path).config().seed)
            replayed.append(CellRows(cell.name, seed, cell.episodes, rows))
    eps = max((float(c.episodes["eps"].iloc[0]) for c in cells if "eps" in c.episodes), default=0.2)
    return render(out, standstill_report(replayed, cfg.episodes, eps, target, command))
