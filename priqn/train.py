"""``priqn train``: train one agent of Table II into a self-describing run folder.

Read :func:`_train_loop` top to bottom, CleanRL style: act (ε-greedy over the agent's
acting rule) → issue the env step → learn while the env workers simulate → collect
the step → store it → log; then evaluate on the hold-out nets and checkpoint on their
intervals. The config is :mod:`priqn.train_config`; every file of the run folder goes
through :class:`priqn.runs.RunFolder`; tqdm, TensorBoard and metrics.csv sit behind
one :class:`TrainLogger`.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
import zipfile
from collections import deque
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from priqn.config import describe, flatten, to_dict
from priqn.episodes import episode_values, final_info
from priqn.errors import PriqnError
from priqn.objectives import OBJECTIVES, SUBSET_COLUMNS
from priqn.runs import RunFolder
from priqn.sim.scenario import family_net_refs
from priqn.timing import SectionClock
from priqn.train_config import (
    NETS,
    ExplorationConfig,
    TrainConfig,
    build_network,
    default_run_name,
    obs_spec,
    resolve_config,
    select_device,
)


def linear_epsilon(cfg: ExplorationConfig, step: int, total_steps: int) -> float:
    """ε at env decision ``step``: linear from eps_start to eps_end over decay_fraction."""
    decay = max(1.0, cfg.decay_fraction * total_steps)
    frac = min(1.0, step / decay)
    return cfg.eps_start + frac * (cfg.eps_end - cfg.eps_start)


def _env_reset_seed(env_seed: int, session: int) -> int | None:
    """Reset seed of the vector env in training session ``session`` (0 = first, 1.. = resumes)."""
    if session == 0:
        return None
    return int(np.random.SeedSequence(env_seed, spawn_key=(session,)).generate_state(1)[0])


def metrics_row(
    kind: str, values: Mapping[str, Any], net: str, weights: Sequence[float]
) -> dict[str, Any]:
    """One metrics.csv row of an ended episode (``kind`` train or eval) from its
    :func:`priqn.episodes.episode_values` and its net."""
    returns = np.array([values[f"return_{o}"] for o in OBJECTIVES])
    row: dict[str, Any] = {"kind": kind}
    row.update(
        {f"return_{o}": round(float(r), 5) for o, r in zip(OBJECTIVES, returns, strict=True)}
    )
    row["return_weighted"] = round(float(returns @ np.asarray(weights)), 5)
    row["length"] = values["steps"]
    row.update({k: int(values[k]) for k in ("success", "collision", "off_road", "timeout")})
    row["route_progress"] = round(values["route_progress"], 4)
    row["density_realised"] = round(values["density_realised"], 4)
    row["net"] = net
    row["command"] = str(values.get("command", ""))
    return row


# ============================================================================ logging


class TrainLogger:
    """Where a training run reports: the tqdm bar, TensorBoard and metrics.csv.

    ``episode`` records a finished training episode, ``interval`` writes the periodic
    scalars and metrics.csv, ``evaluation`` the in-training evaluation episodes,
    ``checkpoint`` flushes everything and redraws learning_curve.png.
    """

    def __init__(self, cfg: TrainConfig, run: RunFolder, step: int, resume: bool) -> None:
        from torch.utils.tensorboard import SummaryWriter
        from tqdm import tqdm

        self.cfg, self.run = cfg, run
        self.rows: list[dict[str, Any]] = run.read_metrics(step) if resume else []
        self.recent: deque[dict[str, Any]] = deque(maxlen=100)
        self.writer = SummaryWriter(str(run.tensorboard_dir), purge_step=step if resume else None)
        self.bar = tqdm(
            total=cfg.total_steps,
            initial=step,
            unit="dec",
            desc=run.name,
            dynamic_ncols=True,
            disable=None,
            mininterval=1.0,
        )

    def episode(self, row: dict[str, Any], step: int) -> None:
        self.rows.append(row)
        self.recent.append(row)
        scalars = {k: row[k] for k in ("return_weighted", "success", "collision")}
        scalars.update({f"return_{o}": row[f"return_{o}"] for o in OBJECTIVES})
        scalars.update({k: row[k] for k in SUBSET_COLUMNS if k in row})  # acting |S_r|
        for key, value in scalars.items():
            self.writer.add_scalar(f"episode/{key}", value, step)

    def progress(self, decisions: int, line: str | None) -> None:
        self.bar.update(decisions)
        if line is not None:
            self.bar.set_postfix_str(line, refresh=False)

    def interval(self, step: int, line: str, scalars: Mapping[str, float]) -> None:
        if self.bar.disable:  # not a terminal (sweep, nohup): one plain line per interval
            print(f"{self.run.name} step {step}/{self.cfg.total_steps} {line}", flush=True)
        for key, value in scalars.items():  # epsilon, updates/s, loss, target |S_r|
            self.writer.add_scalar(f"train/{key}", value, step)
        self.run.write_metrics(self.rows)

    def evaluation(self, rows: list[dict[str, Any]], step: int) -> None:
        self.rows.extend(rows)
        for key in ("success", "return_weighted"):
            self.writer.add_scalar(f"eval/{key}", float(np.mean([r[key] for r in rows])), step)
        self.run.write_metrics(self.rows)

    def checkpoint(self) -> None:
        from priqn.analysis.figures import write_training_curve

        self.run.write_metrics(self.rows)
        self.writer.flush()
        write_training_curve(self.rows, self.run.learning_curve_path, self.run.name)

    def close(self) -> None:
        self.bar.close()
        self.writer.close()


def _postfix(episodes: int, recent: Sequence[Mapping[str, Any]], eps: float, ups: float) -> str:
    if not recent:
        return f"ep 0 ε {eps:.2f} upd/s {ups:.0f}"
    sr = np.mean([r["success"] for r in recent])
    rets = " ".join(
        f"{o[:4]} {np.mean([r[f'return_{o}'] for r in recent]):+.2f}" for o in OBJECTIVES
    )
    return f"ep {episodes} SR {sr:.2f} R[{rets}] ε {eps:.2f} upd/s {ups:.0f}"


# ============================================================================ training


def train(cfg: TrainConfig, run_dir: str | Path, resume: bool = False, force: bool = False) -> Path:
    """Train ``cfg`` into ``run_dir``; ``resume`` continues from its latest checkpoint.

    Returns the run folder. meta.json says ``running`` while training, ``complete``
    when the budget is spent, ``failed`` (with the error) otherwise.
    """
    run = RunFolder(run_dir)
    was_complete = resume and run.recorded_status() == "complete"
    run.prepare(cfg, resume, force)
    # A resume that fails never turns a finished run into a failed one: its status goes
    # back to complete and the error is kept beside it.
    failed_status = "complete" if was_complete else "failed"
    try:
        _train_loop(cfg, run, resume)
    except KeyboardInterrupt:
        run.update_meta(status=failed_status, error="interrupted (continue with --resume)")
        raise
    except BaseException as exc:
        try:
            run.update_meta(status=failed_status, error=f"{type(exc).__name__}: {exc}")
        except Exception:  # noqa: BLE001 - e.g. the disk is full; the original error matters
            pass
        raise
    return run.path


def _train_loop(cfg: TrainConfig, run: RunFolder, resume: bool) -> None:  # noqa: C901 - one loop
    import torch

    from priqn.agents.learner import Learner
    from priqn.agents.policy import Policy, SubsetSizeMeans
    from priqn.agents.registry import make_agent
    from priqn.agents.replay import ReplayBuffer
    from priqn.env.vector import make_vector_env

    meta = run.meta()
    seeds: dict[str, int] = meta["seeds"]
    session = len(meta["sessions"]) - 1
    if cfg.torch_threads > 0:
        torch.set_num_threads(cfg.torch_threads)
    device = select_device(cfg.device)
    E = cfg.num_envs
    weights = cfg.reward_weights

    # --- env, agent, learner, replay -------------------------------------------------
    envs = make_vector_env(cfg.env, E, seed=seeds["env"])
    eval_envs = None
    logger = None
    try:
        obs_space = envs.single_observation_space
        num_actions = int(envs.single_action_space.n)
        obs_shapes = {
            k: (list(obs_space[k].shape), str(obs_space[k].dtype), float(np.max(obs_space[k].high)))
            for k in obs_spec(obs_space)
        }
        agent = make_agent(cfg.agent.name, cfg.agent_config)
        network = build_network(cfg, obs_space, num_actions, seeds["torch_init"])
        learner = Learner(network, agent, cfg.learner, device, tau_seed=seeds["tau"])
        policy = Policy(learner.online, agent, cfg.learner.num_quantiles, device)
        replay = ReplayBuffer(
            obs_spec(obs_space), E, cfg.replay.capacity, cfg.learner.n_step, cfg.learner.gamma
        )
        rng_replay = np.random.default_rng(seeds["replay"])
        rng_act = np.random.default_rng(seeds["explore"])
        step, episodes, wall_before = 0, 0, 0.0
        run.update_meta(
            replay_bytes_per_transition=replay.bytes_per_row(),
            replay_bytes_total=replay.nbytes(),
            device=str(device),
            num_params=sum(p.numel() for p in learner.online.parameters()),
            reward_weights=list(cfg.reward_weights),
            crash_margin=round(cfg.crash_margin, 4),
        )

        resume_obs = None
        if resume:
            state = run.load_checkpoint(device)
            learner.load_state_dict(state["learner"])
            rng_replay.bit_generator.state = state["rng_replay"]
            rng_act.bit_generator.state = state["rng_act"]
            step, episodes, wall_before = state["step"], state["episodes"], state["wall_s"]
            replay_file = run.replay_file(state)
            if replay_file is not None:
                try:
                    replay.load_state_file(replay_file)
                except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile) as exc:
                    raise PriqnError(
                        f"{replay_file}: damaged or unreadable replay buffer "
                        f"({type(exc).__name__}); the run cannot resume exactly: "
                        "train it again with --force"
                    ) from None
                resume_obs = state["obs"]

        # Session 0: per-worker seeds derived from seeds["env"] by make_vector_env; a resume
        # reseeds from (seeds["env"], session) so it does not replay the first scenes.
        obs, _ = envs.reset(seed=_env_reset_seed(seeds["env"], session))
        if resume_obs is not None:
            # Episodes in flight at the checkpoint end there (truncated, bootstrapped).
            replay.truncate_open_episodes(resume_obs)
        logger = TrainLogger(cfg, run, step, resume)

        # --- the loop ------------------------------------------------------------------
        last_loss = math.nan
        last_stats: dict[str, float] = {}
        subset_sizes = SubsetSizeMeans(E, policy.subset_size_names)
        clock = SectionClock()  # where the wall time goes (meta.json time_s)

        def learn(decisions: int) -> dict[str, float]:
            """The updates due after ``decisions``; the last one's stats ({} if none)."""
            stats: dict[str, float] = {}
            if decisions < cfg.replay.learning_starts or len(replay) < cfg.learner.batch_size:
                return stats
            due = (decisions - cfg.replay.learning_starts) // cfg.replay.decisions_per_update + 1
            while learner.updates < due:
                with clock("replay_sample"):
                    batch = replay.sample(cfg.learner.batch_size, rng_replay)
                with clock("update"):
                    stats = learner.update(batch)
            return stats

        t0 = time.perf_counter()
        t_rate, upd_rate_at, upd_per_s = t0, learner.updates, 0.0
        next_log = step + cfg.log_interval_steps
        next_eval = _next_multiple(step, cfg.evaluation.interval_steps)
        next_ckpt = _next_multiple(step, cfg.checkpoint.interval_steps)
        while step < cfg.total_steps:
            # 1. act: agent's acting rule, ε-greedy on top
            with clock("act"):
                epsilon = linear_epsilon(cfg.exploration, step, cfg.total_steps)
                actions = policy.act(obs, rng_act)
                subset_sizes.add(policy.last_subset_sizes)
                explore = rng_act.random(E) < epsilon
                actions = np.where(explore, rng_act.integers(num_actions, size=E), actions)

            # 2. issue the env step: the workers simulate while this process learns
            with clock("env_issue"):
                envs.step_async(actions)

            # 3. learn: one update per decisions_per_update decisions after learning_starts,
            # counted with this step's decisions. The batch comes from the transitions
            # stored so far (not the E in flight); a resume without a saved replay buffer
            # refills a batch's worth first.
            if cfg.overlap_updates:
                last_stats = learn(step + E) or last_stats

            # 4. collect the step (SAME_STEP autoreset: the true last obs is in final_obs)
            # and store it
            with clock("env_wait"):
                next_obs, rewards, terminated, truncated, infos = envs.step_wait()
            with clock("replay_add"):
                ended = np.logical_or(terminated, truncated)
                final_obs = [infos["final_obs"][e] if ended[e] else None for e in range(E)]
                replay.add(obs, actions, rewards, terminated, truncated, final_obs)
            obs = next_obs
            step += E
            if not cfg.overlap_updates:
                last_stats = learn(step) or last_stats
            last_loss = last_stats.get("loss", math.nan)

            # 5. log: finished episodes, progress, periodic scalars and metrics.csv
            log_t0 = time.perf_counter()
            wall = wall_before + log_t0 - t0
            for e in np.flatnonzero(ended):
                episodes += 1
                info = final_info(infos, int(e))
                row = metrics_row("train", episode_values(info), str(info["net"]), weights)
                row.update(subset_sizes.pop(int(e)))
                row.update(
                    step=step,
                    episode=episodes,
                    wall_s=round(wall, 2),
                    epsilon=round(epsilon, 4),
                    updates=learner.updates,
                    loss=round(last_loss, 5) if not math.isnan(last_loss) else "",
                )
                logger.episode(row, step)
            if log_t0 - t_rate >= 5.0:
                upd_per_s = (learner.updates - upd_rate_at) / (log_t0 - t_rate)
                t_rate, upd_rate_at = log_t0, learner.updates
            line = None
            if ended.any() or step >= next_log:
                line = _postfix(episodes, logger.recent, epsilon, upd_per_s)
            logger.progress(E, line)
            if line is not None and step >= next_log:
                next_log = step + cfg.log_interval_steps
                scalars = {"epsilon": epsilon, "updates_per_s": upd_per_s, **last_stats}
                logger.interval(step, line, scalars)
            clock.add("logging", time.perf_counter() - log_t0)

            # 6. evaluate greedily on the hold-out nets
            if cfg.evaluation.interval_steps > 0 and step >= next_eval:
                with clock("evaluate"):
                    next_eval = _next_multiple(step, cfg.evaluation.interval_steps)
                    if eval_envs is None:
                        eval_cfg = dataclasses.replace(
                            cfg.env, family=cfg.evaluation.family, nets=()
                        )
                        eval_envs = make_vector_env(eval_cfg, 1, seed=seeds["eval_env"])
                        eval_nets = family_net_refs(
                            cfg.evaluation.family,
                            Path(cfg.env.nets_dir) if cfg.env.nets_dir else None,
                        )
                    rows = _evaluate(
                        eval_envs, policy, cfg, step, seeds["eval_env"], weights, eval_nets
                    )
                    for r in rows:
                        r.update(step=step, wall_s=round(wall, 2), updates=learner.updates)
                    logger.evaluation(rows, step)

            # 7. checkpoint
            if step >= next_ckpt or step >= cfg.total_steps:
                with clock("checkpoint"):
                    next_ckpt = _next_multiple(step, cfg.checkpoint.interval_steps)
                    wall = wall_before + time.perf_counter() - t0
                    state = {
                        "step": step,
                        "episodes": episodes,
                        "wall_s": wall,
                        "learner": learner.state_dict(),
                        "rng_replay": rng_replay.bit_generator.state,
                        "rng_act": rng_act.bit_generator.state,
                        "obs": {k: np.array(v) for k, v in obs.items()},
                        "obs_shapes": obs_shapes,
                        "num_actions": num_actions,
                        "config": to_dict(cfg),
                    }
                    run.save_checkpoint(state, replay, cfg.checkpoint.save_replay)
                    logger.checkpoint()
                    run.update_meta(steps_done=step, episodes_done=episodes, wall_s=round(wall, 1))
        logger.close()
        # The final policy alone (online weights + the agent's learned state, a few MB):
        # what a committed result folder keeps instead of checkpoints and replay.
        run.save_policy(
            {
                "online": learner.online.state_dict(),
                "agent": learner.agent.state_dict(),
                "obs_shapes": obs_shapes,
                "num_actions": num_actions,
                "step": step,
            }
        )
        time_s = clock.totals()
        if agent.subsets is not None:  # inside "act" and "update"
            time_s["algorithm1"] = round(agent.subsets.seconds, 4)
        run.update_meta(
            time_s=time_s,
            status="complete",
            steps_done=step,
            episodes_done=episodes,
            updates_done=learner.updates,
            finished=datetime.now(UTC).isoformat(timespec="seconds"),
        )
    finally:
        if logger is not None:
            logger.close()
        envs.close()
        if eval_envs is not None:
            eval_envs.close()


def _next_multiple(step: int, interval: int) -> int:
    if interval <= 0:
        return sys.maxsize
    return (step // interval + 1) * interval


def _evaluate(
    envs: Any,
    policy: Any,
    cfg: TrainConfig,
    step: int,
    eval_seed: int,
    weights: Sequence[float],
    nets: Sequence[str],
) -> list[dict[str, Any]]:
    """Greedy episodes on the hold-out ``nets``, played by the evaluation's own rollout
    (:func:`priqn.evaluate.run_scenes`); the scenes depend only on ``eval_seed`` and ``step``."""
    from priqn.evaluate import Scene, run_scenes

    rng = np.random.default_rng([eval_seed, step])
    scenes = [
        Scene(
            eval_run=0,
            net=str(nets[int(rng.integers(len(nets)))]),
            density=float(cfg.env.densities[int(rng.integers(len(cfg.env.densities)))]),
            episode=i,
            reset_seed=int(rng.integers(2**31)),
            act_seed=int(rng.integers(2**31)),
            command=None,
        )
        for i in range(cfg.evaluation.episodes)
    ]
    rows: list[dict[str, Any]] = []

    def on_episode(scene: Any, values: dict[str, Any]) -> None:
        row = metrics_row("eval", values, scene.net, weights)
        row.update({k: values[k] for k in SUBSET_COLUMNS if k in values})  # preorder agents
        row.update(episode=scene.episode + 1, epsilon=0.0, loss="")
        rows.append(row)

    run_scenes(policy, envs, scenes, on_episode)
    return sorted(rows, key=lambda r: r["episode"])


# ============================================================================ CLI


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Flags of ``priqn train`` (every config key is also reachable with --set)."""
    parser.add_argument(
        "--net",
        metavar="POOL|FILE|DIR",
        help=f"training pool ({', '.join(NETS)}; default tjunction), or your own .net.xml "
        "file or folder of them (docs/your-own-net.md)",
    )
    parser.add_argument("--agent", help="iqn | ensemble-iqn | ma-iqn | pr-iqn (default pr-iqn)")
    parser.add_argument("--seed", type=int, help="master seed (default 0)")
    parser.add_argument(
        "--preset", default="default", help="default (CPU, 64 px) | paper (128 px, GPU)"
    )
    parser.add_argument("--steps", type=int, help="training budget in env decisions (total_steps)")
    parser.add_argument("--config", metavar="FILE", help="TOML file merged over the preset")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config key (repeatable)",
    )
    parser.add_argument("--name", help="run folder name (default from net, agent, options, seed)")
    parser.add_argument(
        "--runs-dir", default="runs", help="parent folder of run folders (default runs)"
    )
    parser.add_argument("--resume", metavar="RUN_DIR", help="continue an interrupted run")
    parser.add_argument("--force", action="store_true", help="overwrite an existing run folder")
    parser.add_argument("--device", help="auto | cpu | cuda (default auto)")
    parser.add_argument("--num-envs", type=int, help="env worker processes")
    parser.add_argument(
        "--list-options",
        action="store_true",
        help="print every config key, its default and meaning",
    )


def run(args: argparse.Namespace) -> int:
    if args.list_options:
        values = flatten(to_dict(resolve_config(preset=args.preset)))
        print(f"# priqn train config keys; values of the '{args.preset}' preset (--preset)")
        for key, _default, doc in describe(TrainConfig):
            print(f"{key} = {values.get(key)!r}\n    {doc}")
        return 0
    if args.resume:
        run_dir = Path(args.resume)
        cfg = RunFolder(run_dir).config()
        changed = [f for f in ("net", "agent", "seed", "config", "num_envs") if getattr(args, f)]
        if changed or args.set or args.preset != "default" or args.force:
            raise PriqnError(
                "--resume continues a run with its own config.toml; only --steps and --device may change"
            )
        if args.steps is not None:
            cfg = dataclasses.replace(cfg, total_steps=args.steps)
        if args.device is not None:
            cfg = dataclasses.replace(cfg, device=args.device)
        train(cfg, run_dir, resume=True)
    else:
        cfg = resolve_config(
            preset=args.preset,
            agent=args.agent,
            seed=args.seed,
            net=args.net,
            steps=args.steps,
            overrides=args.set,
            config_file=args.config,
            num_envs=args.num_envs,
            device=args.device,
        )
        run_dir = Path(args.runs_dir) / (args.name or default_run_name(cfg))
        train(cfg, run_dir, force=args.force)
    print(f"priqn train: run folder {run_dir}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    os.environ.setdefault("MPLBACKEND", "Agg")
    from priqn.cli import main

    sys.exit(main(["train", *sys.argv[1:]]))
