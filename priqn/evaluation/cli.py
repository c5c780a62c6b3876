"""``priqn evaluate``: every trained run meets the same hold-out scenes.

``priqn evaluate runs/<name> [runs/<other> ...]`` (or a folder of runs) plays each
run's greedy policy on the hold-out nets × traffic densities × ``eval_runs``
evaluation runs, ``episodes_per_cell`` episodes per (evaluation run, net, density)
cell, and writes one row per episode to ``runs/<name>/eval/episodes.csv``. The protocol
(scenes, seeds, columns, folder names) is :mod:`priqn.evaluation.protocol`; resuming
is :mod:`priqn.evaluation.store`.

``--acting near-greedy`` evaluates the greedy baselines once more, acting at random
among their near-best actions (the acting-randomness control), into ``eval-near-greedy/``.

``--max-episode-steps N`` plays the same scenes at an evaluation-only episode limit into
``eval-limit<N>/`` beside ``eval/`` (``priqn report --horizon``).

``--nets PATH ...`` plays the same protocol on your own ``.net.xml`` files (checked before
any episode) into ``eval-nets-<hash>/`` beside ``eval/`` (the generalisation table of
``priqn report``). ``--reference sumo|random --out DIR`` evaluates a reference driver
(SUMO's own driver models, or uniform random actions) on the same scenes into ``DIR/eval/``
(``priqn report --reference DIR``; :mod:`priqn.evaluation.reference`).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from priqn.checks import check_acting_eps, check_density
from priqn.config import apply_values, from_dict, load_toml, to_dict
from priqn.errors import PriqnError
from priqn.evaluation.protocol import ACTINGS, EvalConfig, eval_dir_of
from priqn.evaluation.reference import (
    DEFAULT_REFERENCE_DIR,
    REFERENCES,
    evaluate_reference,
    reference_env_config,
)
from priqn.evaluation.store import earlier_evaluation, evaluate_policy
from priqn.evaluation.targets import evaluation_env, evaluation_target, find_runs
from priqn.run.checkpointer import load_policy
from priqn.run.folder import RunFolder, Status


def evaluate_run(
    run_dir: str | Path, cfg: EvalConfig, force: bool = False, own_family: str | None = None
) -> Path:
    """Evaluate the trained run in ``run_dir``; returns ``run_dir/eval/episodes.csv``.

    The run must be complete (``meta.json`` status). A finished evaluation with the
    same hold-out hash and EvalConfig is returned as is; a half-finished one goes on.
    With ``cfg.nets`` the run is evaluated on those nets instead, into
    ``eval-nets-<hash>/`` (:func:`~priqn.evaluation.protocol.evaluation_name`); every net
    is checked first (:func:`~priqn.evaluation.targets.evaluation_nets`), so a net that
    cannot be used stops before any episode. On a ``cfg.family`` other than the run's own
    hold-out family (``own_family``; None: the run's ``evaluation.family``) it goes to
    ``eval-family-<name>/``; ``eval/`` is only ever the run's own family.
    """
    run = RunFolder(run_dir)
    if not run.path.is_dir():
        raise PriqnError(f"{run.path}: no such run folder")
    if not run.meta_path.is_file():
        raise PriqnError(f"{run.meta_path}: missing; is {run.path} a run made by 'priqn train'?")
    status = run.meta().get("status")
    if status != Status.COMPLETE:
        raise PriqnError(
            f"{run.meta_path}: status is {status!r}; evaluate only complete runs "
            f"(finish it with 'priqn train --resume')"
        )

    net_ids, holdout_hash, nets = evaluation_target(cfg, run.config().env.commands)
    if own_family is None:
        own_family = run.config().evaluation.family
    eval_dir = eval_dir_of(run, cfg, holdout_hash if nets else "", own_family)
    episodes_path = eval_dir / RunFolder.EVAL_EPISODES
    old = None if force else earlier_evaluation(eval_dir, holdout_hash, to_dict(cfg))
    if old is not None and old.get("status") == Status.COMPLETE and episodes_path.is_file():
        return episodes_path

    from priqn.env.vector import make_vector_env

    policy = load_policy(run, device=cfg.device, snapshot=cfg.snapshot)
    if cfg.acting == "near-greedy":
        policy = policy.near_greedy(cfg.acting_eps)
    env_cfg = evaluation_env(policy.env_config, cfg, nets)

    def make_env(num_envs: int) -> Any:
        # The vector env's own seed only seeds autoresets, whose scenes are discarded.
        return make_vector_env(env_cfg, num_envs=num_envs, seed=cfg.seed, preload=True)

    import torch

    # The policy acts on one state at a time: more torch threads only fight the env
    # workers (and anything else running) for the cores, 10-60x slower on 2 busy cores.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    extra_meta: dict[str, Any] = {"env_config": to_dict(env_cfg)}
    if nets is not None:
        extra_meta.update(nets=nets["nets"], nets_hash=holdout_hash)
    try:
        return evaluate_policy(
            policy,
            eval_dir,
            cfg,
            net_ids,
            holdout_hash,
            run.name,
            make_env,
            extra_meta=extra_meta,
            force=force,
        )
    finally:
        torch.set_num_threads(threads)


def evaluate(paths: Iterable[str | Path], cfg: EvalConfig, force: bool = False) -> list[Path]:
    """Evaluate every run under ``paths`` (one after another); returns episode tables.

    With near-greedy acting, runs of agents that act on optimal subsets (Pr-IQN) are
    skipped with a note on stderr: the control is for the greedy baselines.
    """
    runs = find_runs(paths)
    if cfg.acting == "near-greedy":
        runs = [run for run in runs if _has_scalar_value(run)]
        if not runs:
            raise PriqnError(
                "near-greedy acting: none of these runs is an IQN, Ensemble-IQN or MA-IQN run"
            )
    return [evaluate_run(run, cfg, force=force) for run in runs]


def _has_scalar_value(run: Path) -> bool:
    from priqn.agents.config import has_scalar_value

    name = RunFolder(run).config().agent.name
    if has_scalar_value(name):
        return True
    print(
        f"{run}: skipped ({name} acts on its optimal subsets; near-greedy is for the greedy baselines)",
        file=sys.stderr,
    )
    return False


# ----------------------------------------------------------------------------- CLI


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "runs",
        nargs="*",
        help="run folders, or folders of runs (with --reference: the runs whose env the "
        "reference plays; none = priqn train's default env)",
    )
    parser.add_argument("--config", help="TOML file with EvalConfig fields")
    parser.add_argument("--episodes", type=int, help="episodes per (eval run, net, density) cell")
    parser.add_argument("--eval-runs", type=int, help="evaluation runs (default 3)")
    parser.add_argument("--densities", help="comma-separated densities (default 0.5,0.75,1.0)")
    parser.add_argument("--seed", type=int, help="evaluation seed (default 2026)")
    parser.add_argument("--workers", type=int, help="environment worker processes")
    parser.add_argument(
        "--acting",
        choices=ACTINGS,
        help="own (default: the agent's rule, into eval/) or near-greedy (the acting-randomness "
        "control for the greedy baselines, into eval-near-greedy/)",
    )
    parser.add_argument(
        "--acting-eps", type=float, help="near-greedy tolerance ε [per-state std] (default 0.2)"
    )
    parser.add_argument(
        "--family",
        help="scenario family of the evaluation nets (default holdout, into eval/; another "
        "family than the run's own hold-out family goes into eval-family-<name>/ beside eval/)",
    )
    parser.add_argument(
        "--nets",
        nargs="+",
        metavar="PATH",
        help="evaluate on these .net.xml files / folders of them instead (no manifest needed), "
        "into eval-nets-<hash>/ beside eval/ (docs/your-own-net.md)",
    )
    parser.add_argument(
        "--junction", help="with --nets: the junction id to drive through (default: the busiest)"
    )
    parser.add_argument(
        "--snapshot",
        type=int,
        metavar="N",
        help="evaluate the policy the run kept at N decisions (checkpoint.keep_at) instead of "
        "its final one, into eval-at<N>/ beside eval/",
    )
    parser.add_argument(
        "--max-episode-steps",
        type=int,
        metavar="N",
        help="an evaluation-only episode limit of N decisions, into eval-limit<N>/ beside "
        "eval/ (left out of Table II; the policy's training is untouched)",
    )
    parser.add_argument(
        "--traffic",
        metavar="NAME",
        help="play another named traffic setting's NPCs on the same scenes (e.g. tm-carla), "
        "into eval-traffic-<name>/ beside eval/; the episode limit stays the run's",
    )
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="any EvalConfig field"
    )
    parser.add_argument("--force", action="store_true", help="discard earlier evaluations")
    parser.add_argument(
        "--reference",
        choices=tuple(REFERENCES),
        help="evaluate a reference driver instead of runs: sumo (SUMO's own driver models "
        "drive the ego) or random (uniform random actions); same scenes (docs/evaluation.md)",
    )
    parser.add_argument(
        "--out",
        metavar="DIR",
        help=f"with --reference: its folder (default {DEFAULT_REFERENCE_DIR}/<name>/; "
        "the evaluation goes to DIR/eval/ or DIR/eval-nets-<hash>/)",
    )


def config_from_args(args: argparse.Namespace) -> EvalConfig:
    """EvalConfig from ``--config``, then the ``--set`` overrides, then the shortcut flags
    (typed values: :func:`priqn.config.apply_values`)."""
    cfg = (
        from_dict(EvalConfig, load_toml(args.config), where=args.config)
        if args.config
        else EvalConfig()
    )
    values: list[tuple[str, Any]] = []  # the shortcut flags, typed; after --set, so they win
    if args.episodes is not None:
        values.append(("episodes_per_cell", args.episodes))
    if args.eval_runs is not None:
        values.append(("eval_runs", args.eval_runs))
    if args.seed is not None:
        values.append(("seed", args.seed))
    if args.workers is not None:
        values.append(("num_workers", args.workers))
    if args.acting is not None:
        values.append(("acting", args.acting))
    if args.family is not None:
        values.append(("family", args.family))
    if args.traffic is not None:
        from priqn.env.traffic import traffic_setting

        traffic_setting(args.traffic)  # an unknown name: one line, before any episode
        values.append(("traffic", args.traffic))
    if args.snapshot is not None:
        if args.snapshot <= 0:
            raise PriqnError(
                f"--snapshot {args.snapshot}: expected a budget > 0 (checkpoint.keep_at)"
            )
        values.append(("snapshot", args.snapshot))
    if args.max_episode_steps is not None:
        if args.max_episode_steps <= 0:
            raise PriqnError(
                f"--max-episode-steps {args.max_episode_steps}: expected a limit > 0 decisions"
            )
        values.append(("episode_limit", args.max_episode_steps))
    if args.acting_eps is not None:
        values.append(("acting_eps", check_acting_eps(args.acting_eps, "--acting-eps")))
    if args.densities:
        try:
            densities = [float(x) for x in args.densities.split(",") if x.strip()]
        except ValueError as exc:
            raise PriqnError(f"--densities {args.densities!r}: expected e.g. 0.5,0.75,1.0") from exc
        if not densities:
            raise PriqnError(f"--densities {args.densities!r}: expected e.g. 0.5,0.75,1.0")
        values.append(("densities", tuple(check_density(v, "--densities") for v in densities)))
    if args.set or values:  # one check of all: a flag may mend a --set value
        cfg = apply_values(cfg, [*args.set, *values])
    if args.nets and args.family:
        raise PriqnError("--family and --nets: pick one (--nets evaluates on those nets only)")
    if args.nets:  # paths as given (no TOML quoting on the way)
        cfg = dataclasses.replace(cfg, nets=tuple(args.nets))
    if args.junction is not None:
        if not cfg.nets:
            raise PriqnError(
                f"--junction {args.junction}: only with --nets (a hold-out net has one junction)"
            )
        cfg = dataclasses.replace(cfg, junction=args.junction)
    return cfg


def run(args: argparse.Namespace) -> int:
    cfg = config_from_args(args)
    if args.reference and cfg.snapshot:
        raise PriqnError("--snapshot: only for trained runs, not with --reference")
    if args.reference:
        out = args.out or str(Path(DEFAULT_REFERENCE_DIR) / args.reference)
        env, env_of = reference_env_config(args.runs)
        print(evaluate_reference(args.reference, out, cfg, env, env_of, force=args.force))
        return 0
    if args.out:
        raise PriqnError("--out: only with --reference (a run's evaluations live in its folder)")
    if not args.runs:
        raise PriqnError("no runs given: name run folders or folders of runs (e.g. runs/)")
    for path in evaluate(args.runs, cfg, force=args.force):
        print(path)
    return 0
