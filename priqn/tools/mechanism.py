"""``priqn mechanism``: why Pr-IQN leaves the road, measured over many episodes (descriptive).

Replays evaluated Pr-IQN cells on the scenes of their own ``eval/`` (the same reset and
acting seeds, the one rollout loop :func:`priqn.evaluation.rollout.rollout` with the quantiles
recorded) and measures per training seed (docs/mechanism.md):

1. **removal**: how often the top level (safety) leaves out of its optimal subset the
   action a lower objective's head would take on its own (its greedy action), and how
   often an episode ends in a violation (collision or off-road) within a few decisions
   after such a removal, against the decisions without one;
2. **calibration**: what the safety head's quantiles predict at the executed action
   (whatever the top level examined) — the predicted probability of the safety penalty
   (share of the K fixed-grid quantiles at or below half the penalty) and the predicted
   return — against whether the episode ended in a violation (a reliability table and
   curve);
3. **collapsed vs healthy**: the same measures for seeds whose hold-out success (all of
   their ``eval/episodes.csv``) is below a threshold, and for the others.

Writes the report folder ``--out`` (:func:`priqn.analysis.mechanism.mechanism_report`:
``report.md``, ``tables/mechanism.csv``, ``tables/reliability.csv``,
``figures/mechanism.png``/``.pdf``, ``meta.json``) and caches every replayed decision
(:class:`priqn.analysis.decisions.DecisionCache` under ``--decisions``; a cell whose rows
are there, of the same schema version and parameters, is not replayed again).
``--standstill`` measures why a policy stands still instead (:mod:`priqn.tools.standstill`);
``--collisions`` classifies every evaluated collision (:mod:`priqn.tools.collisions`).

Here: the replay (:func:`replay_cell`, through :mod:`priqn.tools.cells`), the per-decision
rows (:func:`decision_rows`, from :class:`priqn.evaluation.rollout.RolloutStep` records; no
SUMO; their schema is :data:`priqn.analysis.decisions.MECHANISM_ROWS`) and the command.
The seed measures, the tables and the figure are :mod:`priqn.analysis.mechanism`'s.
"""

from __future__ import annotations

import argparse
import contextlib
import shlex
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from priqn.analysis.artifacts import render
from priqn.analysis.decisions import (
    EPISODE_KEYS,
    MECHANISM_ROWS,
    CellRows,
    default_cache,
    ended_as_evaluated,
)
from priqn.analysis.mechanism import (
    CALIBRATED,
    DEFAULT_COLLAPSED_BELOW,
    DEFAULT_EPISODES,
    MechanismConfig,
    mechanism_report,
)
from priqn.analysis.standstill import DEFAULT_TARGET
from priqn.errors import PriqnError
from priqn.io import ensure_dir, removed_on_failure
from priqn.run.checkpointer import load_policy
from priqn.run.folder import RunFolder
from priqn.tools.cells import ReplayCell, load_cells, replay_scenes, replayed_episodes
from priqn.tools.decisions import decision_key, greedy_removals

# ----------------------------------------------------------------------------- counting


def decision_rows(
    steps: Sequence[Any],
    objectives: Sequence[str],
    levels: Sequence[str],
    cfg: MechanismConfig,
    penalty: float,
    gamma: float,
    speeds_A: np.ndarray,
) -> list[dict[str, Any]]:
    """One episode's :class:`~priqn.evaluation.rollout.RolloutStep` records (in order, the last one
    with the episode's values) → one row per decision.

    ``objectives``: the heads' objectives (per-objective heads); ``levels``: the L axis of
    the decisions' subsets; ``penalty``: the safety penalty (> 0); ``gamma``: the
    discount, for the realised safety return-to-go the safety head predicts; ``speeds_A``:
    each action's target speed [m/s] (:func:`priqn.env.intersection.action_grid`).
    A lower objective's greedy action is removed when ``cfg.top``'s subset leaves it out
    (:func:`priqn.tools.decisions.greedy_removals` over that one level).
    """
    if not steps or steps[-1].episode is None:
        raise ValueError("decision_rows: needs one whole episode (its last step ends it)")
    end = steps[-1].episode
    violation = bool(end["collision"] or end["off_road"])
    safety_head, top_level = objectives.index(CALIBRATED), levels.index(cfg.top)
    lower = [o for o in levels if o != cfg.top]
    to_go_T = _return_to_go([float(s.reward_N[safety_head]) for s in steps], gamma)
    rows = []
    for t, s in enumerate(steps):
        d = s.decision
        q_HKA, subsets_LA = d.quantiles_BHKA[0], d.subsets_BLA[0]
        q_K = q_HKA[safety_head, :, s.action]
        left = len(steps) - 1 - t  # decisions after this one
        row: dict[str, Any] = decision_key(s)
        keeps_A = subsets_LA[top_level]
        removals = greedy_removals(q_HKA, objectives, subsets_LA, levels, (cfg.top,))
        row.update(
            speed_mps=float(speeds_A[s.action]),
            top_max_speed_mps=float(speeds_A[keeps_A].max()),
            lower_greedy_speed_mps=float(speeds_A[removals[cfg.lower][0]]),
        )
        for o in lower:
            greedy, remover = removals[o]
            row[f"greedy_{o}"] = greedy
            row[f"removes_{o}"] = remover == cfg.top
        row.update(
            removes_any=any(row[f"removes_{o}"] for o in lower),
            size_top=int(keeps_A.sum()),
            size_leaf=int(d.leaf_BA[0].sum()),
            calibrated_head=CALIBRATED,
            pred_violation=float(np.mean(q_K <= -penalty / 2.0)),
            pred_return=float(q_K.mean()),
            return_to_go=float(to_go_T[t]),
            episode_violation=violation,
            episode_off_road=bool(end["off_road"]),
            episode_collision=bool(end["collision"]),
            episode_timeout=bool(end["timeout"]),
            violation_within=violation and left < cfg.horizon,
            off_road_within=bool(end["off_road"]) and left < cfg.horizon,
        )
        rows.append(row)
    return rows


def _return_to_go(rewards: Sequence[float], gamma: float) -> np.ndarray:
    """``[T]``: the realised discounted return from each decision on."""
    rewards_T = np.array(rewards)
    to_go_T = np.zeros(len(rewards_T))
    acc = 0.0
    for t in range(len(rewards_T) - 1, -1, -1):
        acc = rewards_T[t] + gamma * acc
        to_go_T[t] = acc
    return to_go_T


# ----------------------------------------------------------------------------- replay


def replay_cell(cell: ReplayCell, cfg: MechanismConfig, progress: Any = None) -> Any:
    """Replay the first ``cfg.episodes`` scenes of ``cell``'s evaluation; its decision rows
    (pandas), with ``replay_matches``: the episode ended as ``eval/episodes.csv`` says
    (outcome flags and length)."""
    import pandas as pd

    from priqn.env.intersection import action_grid
    from priqn.evaluation.protocol import make_scenes
    from priqn.evaluation.targets import evaluation_env

    policy = load_policy(cell.path, device="cpu", snapshot=cell.snapshot)
    agent = policy.agent
    if agent.subsets is None or agent.spec.reward_rule != "per-objective":
        raise PriqnError(
            f"{cell.path}: the run's agent is {agent.name}; the mechanism needs a Pr-IQN run"
        )
    levels = tuple(agent.subsets.preorder.objectives)
    for name, what in ((cfg.top, "--top"), (cfg.lower, "--lower")):
        if name not in levels:
            raise PriqnError(
                f"{what} {name}: not an objective of {cell.name} ({', '.join(levels)})"
            )
    if CALIBRATED not in agent.objectives:
        raise PriqnError(
            f"{cell.path}: no {CALIBRATED} head to calibrate ({', '.join(agent.objectives)})"
        )
    scenes = replay_scenes(make_scenes(cell.eval_config, cell.net_ids), cfg.episodes)
    env_cfg = evaluation_env(policy.env_config, cell.eval_config, None)
    reward = env_cfg.reward
    penalty = min(reward.collision_penalty, reward.off_road_penalty)
    gamma = float(RunFolder(cell.path).config().learner.gamma)
    speeds_A = action_grid(env_cfg)[:, 0]
    expected = cell.episodes.set_index(EPISODE_KEYS)
    workers = min(cfg.workers, len(scenes))
    rows: list[dict[str, Any]] = []
    episodes = replayed_episodes(policy, env_cfg, scenes, cell.eval_config.seed, workers)
    with contextlib.closing(episodes):
        for played in episodes:
            last = played[-1]
            new = decision_rows(played, agent.objectives, levels, cfg, penalty, gamma, speeds_A)
            key = last.scene.cell + (last.scene.episode,)
            matches = ended_as_evaluated(expected, key, len(played), last.episode)
            for r in new:
                r["replay_matches"] = matches
            rows.extend(new)
            if progress is not None:
                progress.update(1)
    return pd.DataFrame(rows)


def analyse(paths: Sequence[str | Path], out: Path, cfg: MechanismConfig, command: str) -> Path:
    """Replay every cell under ``paths`` (a cell whose rows are in ``cfg.cache()`` is read
    instead), write the report folder ``out``
    (:func:`priqn.analysis.mechanism.mechanism_report`); returns its report.md."""
    from tqdm.auto import tqdm

    cells = load_cells(paths, cfg.snapshot)
    cache = cfg.cache()
    replayed = []
    wanted = {c.name: min(cfg.episodes or len(c.episodes), len(c.episodes)) for c in cells}
    with tqdm(total=sum(wanted.values()), desc="mechanism", unit="ep", disable=None) as bar:
        for cell in cells:
            want = wanted[cell.name]
            params = cfg.params(cell.path, want)

            def replay(cell: ReplayCell = cell) -> Any:
                return replay_cell(cell, cfg, progress=bar)

            rows = cache.rows(MECHANISM_ROWS, cell.name, params, want, replay, bar)
            seed = int(RunFolder(cell.path).config().seed)
            replayed.append(CellRows(cell.name, seed, cell.episodes, rows))
    return render(out, mechanism_report(replayed, cfg, command))


# ----------------------------------------------------------------------------- CLI


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("runs", nargs="+", help="evaluated Pr-IQN run folders, or folders of them")
    parser.add_argument(
        "--out", required=True, help="report folder (report.md, tables/, figures/, meta.json)"
    )
    parser.add_argument(
        "--episodes",
        type=int,
        default=DEFAULT_EPISODES,
        help=f"episodes per seed, the first of its eval/ scenes by (eval run, episode, net, "
        f"density) (default {DEFAULT_EPISODES}: the headline cells' first evaluation run; 0 = all)",
    )
    parser.add_argument("--top", default="safety", help="level whose removals count (safety)")
    parser.add_argument(
        "--lower", default="lane_keeping", help="lower objective whose greedy action (lane_keeping)"
    )
    parser.add_argument(
        "--horizon", type=int, default=5, help="decisions after a removal that count (default 5)"
    )
    parser.add_argument(
        "--collapsed-below",
        type=float,
        default=DEFAULT_COLLAPSED_BELOW,
        help=f"hold-out success below which a seed is collapsed (default {DEFAULT_COLLAPSED_BELOW})",
    )
    parser.add_argument("--workers", type=int, default=1, help="env worker processes (default 1)")
    parser.add_argument(
        "--standstill",
        action="store_true",
        help="instead: why the policy stands still (does any go action reach the --target "
        "level's choice, which level removed the last one, safety/risk stop-vs-go differences "
        "raw and z-scored; IQN cells: greedy stop share)",
    )
    parser.add_argument(
        "--target",
        default=DEFAULT_TARGET,
        metavar="LEVEL",
        help=f"with --standstill: the level whose choice set a go action must reach "
        f"(default {DEFAULT_TARGET})",
    )
    parser.add_argument(
        "--collisions",
        action="store_true",
        help="instead: the kind of every evaluated collision (who struck whom, could the NPC "
        "have stopped; replayed where the evaluation predates the record, any agent)",
    )
    parser.add_argument(
        "--traffic",
        default=None,
        metavar="NAME",
        help="with --collisions: replay every collision scene under this named traffic "
        "setting instead of the run's own (e.g. tm-strict): which would it have prevented",
    )
    parser.add_argument(
        "--decisions",
        default="",
        metavar="DIR",
        help=f"cache of the per-decision rows (default {default_cache()}); rows of another "
        "schema version or other parameters are replayed again",
    )
    parser.add_argument(
        "--snapshot",
        type=int,
        default=0,
        metavar="N",
        help="replay the policy each run kept at N decisions (checkpoint.keep_at) on the "
        "scenes of its eval-at<N>/ (default: the final policy on eval/)",
    )


def command_line(args: argparse.Namespace) -> str:
    """The command that makes this report folder again (``meta.json``): the runs as given,
    the mode and every option that shapes the report and differs from its default
    (``--workers`` and ``--decisions`` shape nothing)."""
    words = ["priqn", "mechanism", *args.runs]
    defaults = MechanismConfig()
    options = [("--snapshot", args.snapshot, defaults.snapshot)]
    if args.collisions:
        words.append("--collisions")
        if args.traffic is not None:
            words += ["--traffic", args.traffic]
    elif args.standstill:
        words.append("--standstill")
        options += [("--target", args.target, DEFAULT_TARGET),
                    ("--episodes", args.episodes, defaults.episodes)]  # fmt: skip
    else:
        options += [
            ("--episodes", args.episodes, defaults.episodes),
            ("--top", args.top, defaults.top),
            ("--lower", args.lower, defaults.lower),
            ("--horizon", args.horizon, defaults.horizon),
            ("--collapsed-below", args.collapsed_below, defaults.collapsed_below),
        ]
    for flag, value, default in options:
        if value != default:
            words += [flag, f"{value:g}" if isinstance(value, float) else str(value)]
    words += ["--out", args.out]
    return shlex.join(words)


def run(args: argparse.Namespace) -> int:
    if args.episodes < 0:
        raise PriqnError(f"--episodes: expected >= 0 (0 = all), got {args.episodes}")
    if args.horizon < 1:
        raise PriqnError(f"--horizon: expected >= 1 decision, got {args.horizon}")
    if args.workers < 1:
        raise PriqnError(f"--workers: expected >= 1, got {args.workers}")
    if args.snapshot < 0:
        raise PriqnError(
            f"--snapshot: expected a kept budget in decisions (0: the final policy), got {args.snapshot}"
        )
    if not 0.0 <= args.collapsed_below <= 1.0:
        raise PriqnError(
            f"--collapsed-below: expected a success rate in [0, 1], got {args.collapsed_below}"
        )
    if args.standstill and args.collisions:
        raise PriqnError("--standstill and --collisions: pick one")
    if args.target != DEFAULT_TARGET and not args.standstill:
        raise PriqnError("--target: only with --standstill")
    if args.traffic is not None:
        from priqn.env.traffic import traffic_setting

        if not args.collisions:
            raise PriqnError("--traffic: only with --collisions")
        traffic_setting(args.traffic)  # an unknown name: one line listing the valid ones
    cfg = MechanismConfig(
        episodes=args.episodes,
        top=args.top,
        lower=args.lower,
        horizon=args.horizon,
        collapsed_below=args.collapsed_below,
        workers=args.workers,
        snapshot=args.snapshot,
        decisions=args.decisions,
    )
    with removed_on_failure(args.out):  # refused (an IQN run, ...): no empty --out left
        return _write(args, cfg)


def _write(args: argparse.Namespace, cfg: MechanismConfig) -> int:
    """The report ``args`` asks for, into ``args.out``."""
    command = command_line(args)
    out = ensure_dir(args.out)  # a folder that cannot be made: one line, before any replay
    if args.standstill:
        print(_standstill(args.runs, out, cfg, args.target, command))
        return 0
    if args.collisions:
        from priqn.tools import collisions

        cells = load_cells(args.runs, cfg.snapshot)
        print(collisions.analyse(cells, out, cfg.workers, command, args.traffic))
        return 0
    print(analyse(args.runs, out, cfg, command))
    return 0


def _standstill(
    paths: Sequence[str | Path], out: Path, cfg: MechanismConfig, target: str, command: str
) -> Path:
    """``--standstill``: :func:`priqn.tools.standstill.analyse` on the cells under
    ``paths`` (any agent), each on the first ``cfg.episodes`` scenes of its evaluation."""
    from priqn.evaluation.protocol import make_scenes
    from priqn.tools import standstill

    cells = load_cells(paths, cfg.snapshot)

    def scenes(cell: ReplayCell) -> list[Any]:
        return replay_scenes(make_scenes(cell.eval_config, cell.net_ids), cfg.episodes)

    return standstill.analyse(cells, out, cfg, scenes, target, command)
