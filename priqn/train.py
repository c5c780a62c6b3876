"""``priqn train``: train one agent of Table II into a self-describing run folder.

Read :func:`_train_loop` top to bottom, CleanRL style: act (ε-greedy over the agent's
acting rule) → step the env workers → learn while they simulate → collect the step and
store it → log → evaluate on the hold-out nets → keep a snapshot at a listed budget →
checkpoint, each a named call of :class:`Trainer`. The first four are the stepper's
(:mod:`priqn.run.stepper`, chosen once from the config: every worker at once, the
updates overlapped with the step or after it, or the workers in groups that step in
turn); the loop handles each step it yields. Before the loop, :class:`Trainer` builds
the network, learner, policy and replay buffer, :func:`_resume` restores a checkpoint
and :class:`HoldoutEvaluation` starts its env worker. A checkpoint or snapshot is copied
in the loop (:func:`priqn.run.checkpointer.capture_training`) and its files written by
a background thread (:class:`priqn.run.writer.BackgroundWriter`) while the loop goes
on. The config is :mod:`priqn.run.train_config`; every file of the run folder goes
through :class:`priqn.run.folder.RunFolder`, in :mod:`priqn.run.checkpoint`'s format for
the torch files; :mod:`priqn.run.provenance` gathers what meta.json records about the
run's origin; tqdm, TensorBoard and metrics.csv sit behind one :class:`TrainLogger`.
"""

from __future__ import annotations

import argparse
import contextlib
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
from priqn.env.traffic import TRAFFIC_SETTINGS, traffic_values
from priqn.env.vector import restore_episodes
from priqn.errors import PriqnError
from priqn.io import missing_folders
from priqn.objectives import subset_columns
from priqn.run.checkpoint import REMEDY, Checkpoint, PolicyState, restore
from priqn.run.checkpointer import (
    CheckpointWrite,
    capture_training,
    copy_tensors,
    keep_snapshot,
    load_checkpoint,
    replay_files,
    save_policy,
)
from priqn.run.episodes import episode_values, final_info
from priqn.run.folder import RunFolder, Status
from priqn.run.metrics import MetricsFile, metric_columns, metrics_row, read_metrics
from priqn.run.provenance import thread_limits
from priqn.run.session import (
    mark_resume_exact,
    same_cpu_as_before,
    start_session,
    undo_failed_start,
)
from priqn.run.stepper import ALL_ENVS, make_stepper, open_env_workers
from priqn.run.timing import SectionClock
from priqn.run.train_config import (
    NETS,
    PRESETS,
    ExplorationConfig,
    TrainConfig,
    cuda_determinism,
    default_run_name,
    policy_labels,
    resolve_config,
    select_device,
)
from priqn.run.writer import BackgroundWriter
from priqn.sim.scenario import family_net_refs


def linear_epsilon(cfg: ExplorationConfig, step: int, total_steps: int) -> float:
    """ε at env decision ``step``: linear from eps_start to eps_end over
    :meth:`~priqn.run.train_config.ExplorationConfig.decay_decisions`, then flat."""
    frac = min(1.0, step / cfg.decay_decisions(total_steps))
    return cfg.eps_start + frac * (cfg.eps_end - cfg.eps_start)


def _env_reset_seed(env_seed: int, session: int) -> int | None:
    """Reset seed of the vector env in training session ``session`` (0 = first, 1.. = resumes)."""
    if session == 0:
        return None
    return int(np.random.SeedSequence(env_seed, spawn_key=(session,)).generate_state(1)[0])


# ============================================================================ logging


class TrainLogger:
    """Where a training run reports: the tqdm bar, TensorBoard and metrics.csv.

    ``episode`` records a finished training episode, ``interval`` writes the periodic
    scalars and metrics.csv, ``evaluation`` the in-training evaluation episodes,
    ``checkpoint`` flushes everything, and ``learning_curve`` redraws learning_curve.png
    (in the checkpoint's background write).
    """

    def __init__(self, cfg: TrainConfig, run: RunFolder, step: int, resume: bool) -> None:
        from torch.utils.tensorboard import SummaryWriter
        from tqdm import tqdm

        self.cfg, self.run = cfg, run
        self.rows: list[dict[str, Any]] = read_metrics(run.metrics_path, step) if resume else []
        self.recent: deque[dict[str, Any]] = deque(maxlen=100)
        self.objectives = cfg.objective_names
        self.subset_columns = subset_columns(self.objectives)
        self.columns = metric_columns(self.objectives)
        """metrics.csv's columns for this run's objectives."""
        self.metrics = MetricsFile(run.metrics_path, self.columns, self.rows)
        """metrics.csv, appended to as rows come (a resume truncates it to its checkpoint)."""
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
        scalars.update({f"return_{o}": row[f"return_{o}"] for o in self.objectives})
        scalars.update({k: row[k] for k in self.subset_columns if k in row})  # acting |S_r|
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
        self.metrics.flush(self.rows)

    def evaluation(self, rows: list[dict[str, Any]], step: int) -> None:
        self.rows.extend(rows)
        for key in ("success", "return_weighted"):
            self.writer.add_scalar(f"eval/{key}", float(np.mean([r[key] for r in rows])), step)
        self.metrics.flush(self.rows)

    def checkpoint(self) -> None:
        """metrics.csv and TensorBoard flushed: every row so far is on disk."""
        self.metrics.flush(self.rows)
        self.writer.flush()

    def learning_curve(self, rows: Sequence[Mapping[str, Any]]) -> None:
        """learning_curve.png of ``rows`` (a copy of :attr:`rows`: drawn in the writer's
        thread while the loop adds more; matplotlib is used by no other thread then)."""
        from priqn.run.curve import write_training_curve

        write_training_curve(rows, self.run.learning_curve_path, self.run.name)

    def close(self) -> None:
        self.bar.close()
        self.writer.close()

    def __enter__(self) -> TrainLogger:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _postfix(
    episodes: int,
    recent: Sequence[Mapping[str, Any]],
    eps: float,
    ups: float,
    objectives: Sequence[str],
) -> str:
    if not recent:
        return f"ep 0 ε {eps:.2f} upd/s {ups:.0f}"
    sr = np.mean([r["success"] for r in recent])
    rets = " ".join(
        f"{o[:4]} {np.mean([r[f'return_{o}'] for r in recent]):+.2f}" for o in objectives
    )
    return f"ep {episodes} SR {sr:.2f} R[{rets}] ε {eps:.2f} upd/s {ups:.0f}"


# ============================================================================ training


def train(
    cfg: TrainConfig,
    run_dir: str | Path,
    resume: bool = False,
    force: bool = False,
    background_writes: bool = True,
    traffic: str = "",
) -> Path:
    """Train ``cfg`` into ``run_dir``; ``resume`` continues from its latest checkpoint.
    ``traffic``: the named traffic setting ``cfg`` was made with (``--traffic``), which a new
    run records in meta.json (a resume keeps the recorded one).

    Returns the run folder. meta.json says ``running`` while training, ``complete``
    when the budget is spent, ``failed`` (with the error) otherwise; a new run that fails
    before training wrote a file leaves no folder (:func:`undo_failed_start`). ``background_writes``
    False writes checkpoints and snapshots in the loop (the same files; ``priqn bench
    loop`` times both).
    """
    from priqn.agents.build import build_agent
    from priqn.run import provenance

    run = RunFolder(run_dir)
    was_complete = resume and run.recorded_status() == Status.COMPLETE
    # Everything that can refuse the run comes before its folder is touched.
    origin = provenance.gather(cfg)
    select_device(cfg.device)  # CUDA asked for where there is none: one line
    _check_replay_storage(cfg)
    # The session's one agent, for the run's objectives.
    agent = build_agent(cfg)
    # What only the env workers find (a junction the nets lack, SUMO failing to start)
    # comes after: a new run that fails so is taken back, folder and all (undo_failed_start).
    made = [] if resume else missing_folders(run.path)
    start_session(run, cfg, resume, force, origin, policy_labels(cfg, agent), traffic)
    # A resume that fails never turns a finished run into a failed one: its status goes
    # back to complete and the error is kept beside it.
    failed_status = Status.COMPLETE if was_complete else Status.FAILED
    try:
        _train_loop(cfg, run, agent, resume, background_writes)
    except BaseException as exc:
        if undo_failed_start(run, made):
            raise
        if isinstance(exc, KeyboardInterrupt):
            run.update_meta(status=failed_status, error="interrupted (continue with --resume)")
            raise
        try:
            run.update_meta(status=failed_status, error=f"{type(exc).__name__}: {exc}")
        except Exception:  # noqa: BLE001 - e.g. the disk is full; the original error matters
            pass
        raise
    return run.path


def _train_loop(
    cfg: TrainConfig, run: RunFolder, agent: Any, resume: bool, background_writes: bool = True
) -> None:
    """One training session of ``run`` with ``agent``, from its checkpoint if ``resume``.

    Checkpoints and snapshots are written by a background thread (``background_writes``),
    every meta.json write of the loop with them; leaving the ``with`` block waits for the
    one in flight, so :func:`_finish` writes after it."""
    meta = run.meta()
    seeds: dict[str, int] = meta["seeds"]
    session = len(meta["sessions"]) - 1
    device = _torch_device(cfg)
    with contextlib.ExitStack() as stack:  # closes the logger and the env workers once
        envs = open_env_workers(cfg, seeds["env"])  # in groups with env_groups > 1
        stack.callback(envs.close)
        writer = stack.enter_context(BackgroundWriter(background_writes))
        t = Trainer(cfg, agent, envs, seeds, device, writer)
        run.update_meta(**t.facts())
        resumed = _resume(run, t, device) if resume else None
        obs = _start_episodes(run, t, envs, resumed, _env_reset_seed(seeds["env"], session))
        evaluation = None
        if cfg.evaluation.interval_steps > 0:
            evaluation = stack.enter_context(HoldoutEvaluation(cfg, seeds["eval_env"]))
        logger = stack.enter_context(TrainLogger(cfg, run, t.step, resume))

        t.start()
        stepper = make_stepper(cfg, t, envs, obs)  # serial, overlapped or in groups
        for ended, infos, rows in stepper:  # 1.-4. act, step, learn, collect and store
            t.log(logger, ended, infos, rows)  # 5. log
            if evaluation is not None and t.step >= t.next_eval:
                t.evaluate(evaluation, logger)  # 6. evaluate greedily on the hold-out nets
            if t.step in cfg.checkpoint.keep_at:
                t.keep_snapshot(run)  # 7. keep the policy at a listed budget
            if t.step >= t.next_ckpt or t.step >= cfg.total_steps:
                t.checkpoint(run, logger, envs, stepper.observations())  # 8. checkpoint
    _finish(run, t)


class Trainer:
    """The learning side of one training session, and the steps of its loop.

    Built before the loop: the network, learner, greedy policy and replay buffer, then
    the replay and exploration generators. For every env step the stepper
    (:mod:`priqn.run.stepper`) calls :meth:`act`, :meth:`issue`, :meth:`collect` and
    :meth:`learn`, then :func:`_train_loop` calls :meth:`log`, :meth:`evaluate`,
    :meth:`keep_snapshot` and :meth:`checkpoint`; ``step`` counts env decisions (all
    workers together). The files of a checkpoint or snapshot are written by ``writer``
    (its thread, while the loop goes on) from copies the loop takes.
    """

    def __init__(
        self,
        cfg: TrainConfig,
        agent: Any,
        envs: Any,
        seeds: Mapping[str, int],
        device: Any,
        writer: BackgroundWriter,
    ) -> None:
        from priqn.agents.build import build_learner, build_policy, obs_spec
        from priqn.agents.policy import SubsetSizeMeans
        from priqn.agents.replay import ReplayBuffer

        self.cfg, self.num_envs, self.weights = cfg, cfg.num_envs, cfg.reward_weights
        self.objectives = cfg.objective_names
        """The run's objective names (reward vector, heads, columns)."""
        obs_space = envs.single_observation_space
        self.num_actions = int(envs.single_action_space.n)
        self.obs_shapes = {
            k: (list(obs_space[k].shape), str(obs_space[k].dtype), float(np.max(obs_space[k].high)))
            for k in obs_spec(obs_space)
        }
        self.learner = build_learner(cfg, agent, obs_space, self.num_actions, device, seeds)
        self.policy = build_policy(cfg, agent, self.learner.online, device)
        self.replay = ReplayBuffer(
            obs_spec(obs_space),
            self.num_envs,
            cfg.replay.capacity,
            cfg.learner.n_step,
            cfg.learner.gamma,
            num_objectives=len(self.objectives),
            storage=cfg.replay.storage,
            device=device,
        )
        self.rng_replay = np.random.default_rng(seeds["replay"])
        self.rng_act = np.random.default_rng(seeds["explore"])
        self.subset_sizes = SubsetSizeMeans(self.num_envs, self.policy.subset_size_names)
        self.clock = SectionClock()  # where the wall time goes (meta.json time_s)
        self.step, self.episodes, self.wall_before = 0, 0, 0.0
        self.epsilon, self.wall = cfg.exploration.eps_start, 0.0
        self.latest_update_stats: dict[str, float] = {}
        """The latest learner update's statistics (loss, q_mean, target |S_r|), for logging."""
        self.replay_chunks: list[dict[str, Any]] | None = None
        """The replay files the latest checkpoint names (the next one adds to them)."""
        self.writer = writer
        """Writes the checkpoints' and snapshots' files and meta.json's records of them."""
        self.writing: CheckpointWrite | None = None
        """The latest checkpoint handed to the writer, until its replay rows are safe."""
        self.same_learner = True
        """A resume restored the learner on the device it was written on (τ generator too)."""

    def facts(self) -> dict[str, Any]:
        """What meta.json records about this session's learner and replay buffer."""
        return {
            "replay_bytes_per_transition": self.replay.bytes_per_row(),
            "replay_bytes_total": self.replay.nbytes(),
            "device": str(self.learner.device),
            "num_params": sum(p.numel() for p in self.learner.online.parameters()),
            "reward_weights": list(self.weights),
            "crash_margin": round(self.cfg.crash_margin, 4),
            "objectives": list(self.objectives),
            "objective_declarations": _declarations(self.cfg),
            "threads": thread_limits(),
        }

    def start(self) -> None:
        """Start the wall clock and the log / evaluation / checkpoint schedules at ``step``."""
        cfg = self.cfg
        self.t0 = time.perf_counter()
        self.t_rate, self.updates_at_rate, self.updates_per_s = self.t0, self.learner.updates, 0.0
        self.next_log = self.step + cfg.log_interval_steps
        self.next_eval = _next_multiple(self.step, cfg.evaluation.interval_steps)
        self.next_ckpt = _next_multiple(self.step, cfg.checkpoint.interval_steps)

    def act(self, obs: Mapping[str, np.ndarray], rows: slice = ALL_ENVS) -> np.ndarray:
        """Actions ``[E]`` for the workers ``rows`` (``obs``: theirs): the agent's acting
        rule, replaced by a uniform one with probability ε (:func:`linear_epsilon` at
        ``step``)."""
        E = len(range(self.num_envs)[rows])
        with self.clock("act"):
            self.epsilon = linear_epsilon(self.cfg.exploration, self.step, self.cfg.total_steps)
            decision = self.policy.decide(obs, self.rng_act)
            self.subset_sizes.add(decision.subset_sizes_BS, rows)
            actions = decision.actions_B
            explore = self.rng_act.random(E) < self.epsilon
            return np.where(explore, self.rng_act.integers(self.num_actions, size=E), actions)

    def issue(self, envs: Any, actions: np.ndarray) -> None:
        """Send ``actions`` to the env workers, which simulate the step in the background."""
        with self.clock("env_issue"):
            envs.step_async(actions)

    def collect(
        self, envs: Any, obs: Mapping[str, np.ndarray], actions: np.ndarray, rows: slice = ALL_ENVS
    ) -> tuple[dict[str, np.ndarray], np.ndarray, dict[str, Any]]:
        """Wait for the step issued with ``actions`` to the workers ``rows`` (``envs``:
        theirs) and store its transitions; returns (next observations, ended ``[E]`` bool,
        infos). SAME_STEP autoreset: an ended episode's true last observation is in
        ``final_obs``."""
        with self.clock("env_wait"):
            next_obs, rewards, terminated, truncated, infos = envs.step_wait()
        with self.clock("replay_add"):
            ended = np.logical_or(terminated, truncated)
            final_obs = [infos["final_obs"][e] if ended[e] else None for e in range(len(ended))]
            self._spare_checkpoint_rows()
            self.replay.add(obs, actions, rewards, terminated, truncated, final_obs, rows)
        return next_obs, ended, infos

    def learn(self, decisions: int) -> None:
        """The updates due once ``decisions`` count: one per decisions_per_update decisions
        after learning_starts. The batch comes from the transitions stored so far (not
        those in flight); a resume without a saved replay buffer refills a batch's worth
        first. ``latest_update_stats``: the latest update's statistics."""
        cfg = self.cfg
        if decisions < cfg.replay.learning_starts or len(self.replay) < cfg.learner.batch_size:
            return
        due = (decisions - cfg.replay.learning_starts) // cfg.replay.decisions_per_update + 1
        stats: dict[str, float] = {}
        while self.learner.updates < due:
            with self.clock("replay_sample"):
                batch = self.replay.sample(cfg.learner.batch_size, self.rng_replay)
            with self.clock("update"):
                stats = self.learner.update(batch)
        self.latest_update_stats = stats or self.latest_update_stats

    def log(
        self,
        logger: TrainLogger,
        ended: np.ndarray,
        infos: Mapping[str, Any],
        rows: slice = ALL_ENVS,
    ) -> None:
        """The ended episodes of the workers ``rows`` (metrics.csv, TensorBoard), the
        progress bar and, every log_interval_steps, the training scalars."""
        log_t0 = time.perf_counter()
        self.wall = self.wall_before + log_t0 - self.t0
        latest_loss = self.latest_update_stats.get("loss", math.nan)
        for e in np.flatnonzero(ended):
            self.episodes += 1
            info = final_info(infos, int(e))
            row = metrics_row(
                "train", episode_values(info), str(info["net"]), self.weights, self.objectives
            )
            row.update(self.subset_sizes.pop(range(self.num_envs)[rows][e]))
            row.update(
                step=self.step,
                episode=self.episodes,
                wall_s=round(self.wall, 2),
                epsilon=round(self.epsilon, 4),
                updates=self.learner.updates,
                loss=round(latest_loss, 5) if not math.isnan(latest_loss) else "",
            )
            logger.episode(row, self.step)
        if log_t0 - self.t_rate >= 5.0:
            self.updates_per_s = (self.learner.updates - self.updates_at_rate) / (
                log_t0 - self.t_rate
            )
            self.t_rate, self.updates_at_rate = log_t0, self.learner.updates
        line = None
        if ended.any() or self.step >= self.next_log:
            line = _postfix(
                self.episodes, logger.recent, self.epsilon, self.updates_per_s, logger.objectives
            )
        logger.progress(len(ended), line)
        if line is not None and self.step >= self.next_log:
            self.next_log = self.step + self.cfg.log_interval_steps
            scalars = {"epsilon": self.epsilon, "updates_per_s": self.updates_per_s}
            logger.interval(self.step, line, {**scalars, **self.latest_update_stats})
            self.writer.check()  # a failed background write stops the run here at the latest
        self.clock.add("logging", time.perf_counter() - log_t0)

    def evaluate(self, evaluation: HoldoutEvaluation, logger: TrainLogger) -> None:
        """Greedy episodes on the hold-out nets, logged as ``eval`` rows."""
        with self.clock("evaluate"):
            self.next_eval = _next_multiple(self.step, self.cfg.evaluation.interval_steps)
            rows = evaluation.run(self.policy, self.step, self.weights)
            for r in rows:
                r.update(step=self.step, wall_s=round(self.wall, 2), updates=self.learner.updates)
            logger.evaluation(rows, self.step)

    def policy_state(self) -> PolicyState:
        """The greedy policy now: online weights and the agent's learned state (policy.pt)."""
        return PolicyState(
            online=self.learner.online.state_dict(),
            agent=self.learner.agent.state_dict(),
            obs_shapes=self.obs_shapes,
            num_actions=self.num_actions,
            step=self.step,
            objectives=list(self.objectives),
        )

    def keep_snapshot(self, run: RunFolder) -> None:
        """snapshots/policy-at<step>.pt (checkpoint.keep_at), its SHA-256 in meta.json:
        the policy copied now, its file written by the writer."""
        with self.clock("checkpoint"):
            state = copy_tensors(self.policy_state())
            self.writer.submit(lambda: keep_snapshot(run, state))
            self.writing = None  # the checkpoint before it is written by now (submit waited)

    def checkpoint(
        self, run: RunFolder, logger: TrainLogger, envs: Any, obs: Mapping[str, Any]
    ) -> None:
        """checkpoints/latest.pt (+ the replay rows added since the last one, and every
        worker's episode in flight), metrics and meta.json's progress.

        The state is captured here (:func:`~priqn.run.checkpointer.capture_training`:
        copies of the learner's tensors, the generators, the observations; the replay rows
        stay in the ring, :meth:`_spare_checkpoint_rows`) and metrics.csv flushed, then the
        writer writes the files and, once latest.pt is on disk, meta.json's
        ``steps_done``, then learning_curve.png. It first waits for the previous
        checkpoint (whose error, if any, is raised here); the run's last one is waited
        for."""
        with self.clock("checkpoint"):
            self.writer.wait()
            self.next_ckpt = _next_multiple(self.step, self.cfg.checkpoint.interval_steps)
            self.writing = pending = capture_training(run, self, envs, obs)
            self.replay_chunks = pending.state.replay_chunks
            logger.checkpoint()  # metrics.csv holds every row to here before latest.pt does
            rows = list(logger.rows)

            def write() -> None:
                pending.write()  # the replay file, latest.pt, then meta.json's progress
                logger.learning_curve(rows)

            self.writer.submit(write)
            if self.step >= self.cfg.total_steps:  # the last: nothing left to overlap it
                self.writer.wait()

    def _spare_checkpoint_rows(self) -> None:
        """Wait for the checkpoint being written before the next step's rows could
        overwrite, in the replay ring, rows it has yet to save (the presets' rings hold
        two checkpoint intervals or more: the write is long done by then)."""
        if self.writing is not None and self.writing.ring_reaches(self.replay):
            self.writer.wait()
            self.writing = None


def _check_replay_storage(cfg: TrainConfig) -> None:
    """A ``replay.storage`` that cannot run on the run's device: one line, before the run
    folder is touched (whether ``device`` storage fits is checked when it is allocated)."""
    if cfg.replay.storage == "host":
        return
    from priqn.agents.frames import check_storage

    check_storage(cfg.replay.storage, select_device(cfg.device))


def _declarations(cfg: TrainConfig) -> list[dict[str, Any]]:
    """meta.json's record of the run's objective declarations (functions by dotted path)."""
    from priqn.objectives import resolve_objectives

    return [o.record() for o in resolve_objectives(cfg.env.objectives)]


def _torch_device(cfg: TrainConfig) -> Any:
    """The torch device of ``cfg`` (and torch's CPU threads set to cfg.torch_threads)."""
    import torch

    if cfg.torch_threads > 0:
        torch.set_num_threads(cfg.torch_threads)
    device = select_device(cfg.device)
    if device.type == "cuda":
        cuda_determinism(cfg.cuda_deterministic)
    return device


def _resume(run: RunFolder, t: Trainer, device: Any) -> Checkpoint:
    """Restore the latest checkpoint into ``t``: the learner, both generators, the counters,
    the logging state and the replay buffer when it was saved. Returns the checkpoint."""
    state = load_checkpoint(run, device)
    if tuple(state.objectives) != tuple(t.objectives):
        raise PriqnError(
            f"{run.path}: --resume: the checkpoint was trained for objectives "
            f"({', '.join(state.objectives)}) but {run.CONFIG} lists ({', '.join(t.objectives)}); "
            "restore the run's config.toml or start a new run"
        )
    t.same_learner = restore(
        lambda: t.learner.load_state_dict(state.learner), run.latest_checkpoint, REMEDY
    )
    if not t.same_learner:
        written_on = "cuda" if device.type == "cpu" else "cpu"
        print(
            f"priqn train: {run.path.name}: the checkpoint was written on {written_on}, this "
            f"session runs on {device.type}: the τ samples restart from a seed "
            "derived from the checkpoint's (CPU and CUDA runs cannot continue bit for bit)"
        )
    t.rng_replay.bit_generator.state = state.rng_replay
    t.rng_act.bit_generator.state = state.rng_act
    t.step, t.episodes, t.wall_before = state.step, state.episodes, state.wall_s
    if state.logging:
        t.subset_sizes.sum_EN[...] = np.asarray(state.logging["subset_sum"], dtype=np.float64)
        t.subset_sizes.count_E[...] = np.asarray(state.logging["subset_count"], dtype=np.float64)
        t.latest_update_stats = dict(state.logging["update_stats"])
    t.replay_chunks = state.replay_chunks
    for replay_file in replay_files(run, state):
        try:
            if state.replay_chunks is None:
                t.replay.load_state_file(replay_file)
            else:
                t.replay.load_rows(replay_file)
        except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile) as exc:
            raise PriqnError(
                f"{replay_file}: damaged or unreadable replay buffer "
                f"({type(exc).__name__}); the run cannot resume exactly: "
                "train it again with --force"
            ) from None
    return state


def _start_episodes(
    run: RunFolder, t: Trainer, envs: Any, resumed: Checkpoint | None, reset_seed: int | None
) -> dict[str, np.ndarray]:
    """The observations the loop starts from, one per env worker.

    A new run: fresh episodes (per-worker seeds derived from the env seed by
    make_vector_env). An exact resume (the checkpoint holds the replay buffer in
    ``replay_chunks`` and every worker's episode in flight): those episodes played again to
    the very decision, their observation checked against the checkpoint's. Otherwise (a
    checkpoint from before issue 49, or without its buffer): fresh episodes reseeded from
    (env seed, session), and a restored buffer's open episodes end at the checkpoint
    (truncated, bootstrapped).
    """
    if resumed is not None and resumed.in_flight is not None and resumed.replay_chunks:
        obs = restore_episodes(envs, resumed.in_flight)
        for key, saved in resumed.obs.items():
            if not np.array_equal(obs[key], saved):
                raise PriqnError(
                    f"{run.path}: --resume: the episodes in flight, played again, do not reach "
                    f"the checkpoint's observation ('{key}' differs): the code, the nets or "
                    "SUMO changed since it was written; train it again with --force"
                )
        if t.same_learner and same_cpu_as_before(run):
            mark_resume_exact(run)
        else:
            print(
                f"priqn train: {run.path.name}: resumed with its episodes in flight and replay "
                "buffer, but on another CPU model or device than the session before: the "
                "learner's floats may differ from there on (not marked exact)"
            )
        return obs
    obs, _ = envs.reset(seed=reset_seed)
    if resumed is not None and replay_files(run, resumed):
        t.replay.truncate_open_episodes(resumed.obs)
    return obs


def _finish(run: RunFolder, t: Trainer) -> None:
    """policy.pt and meta.json's final record (status complete) of a finished session."""
    # The final policy alone (online weights + the agent's learned state, a few MB):
    # what a committed result folder keeps instead of checkpoints and replay.
    save_policy(run, t.policy_state())
    time_s = t.clock.totals()
    if t.learner.agent.subsets is not None:  # inside "act" and "update"
        time_s["algorithm1"] = round(t.learner.agent.subsets.seconds, 4)
    run.update_meta(
        time_s=time_s,
        status=Status.COMPLETE,
        steps_done=t.step,
        episodes_done=t.episodes,
        updates_done=t.learner.updates,
        finished=datetime.now(UTC).isoformat(timespec="seconds"),
    )


def _next_multiple(step: int, interval: int) -> int:
    if interval <= 0:
        return sys.maxsize
    return (step // interval + 1) * interval


class HoldoutEvaluation:
    """Greedy episodes on the hold-out nets during training, on one env worker of its own
    (started before the loop, reused by every evaluation; a context manager that closes it).

    The scenes of an evaluation depend only on the eval seed and the step, and are
    played by the one rollout loop (:func:`priqn.evaluation.rollout.rollout`, via ``run_scenes``).
    """

    def __init__(self, cfg: TrainConfig, seed: int) -> None:
        from priqn.env.vector import make_vector_env

        self.cfg, self.seed = cfg, seed
        root = Path(cfg.env.nets_dir) if cfg.env.nets_dir else None
        self.nets = family_net_refs(cfg.evaluation.family, root)
        env_cfg = dataclasses.replace(cfg.env, family=cfg.evaluation.family, nets=(), junction="")
        self.envs = make_vector_env(env_cfg, 1, seed=seed, preload=True)

    def __enter__(self) -> HoldoutEvaluation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.envs.close()

    def run(self, policy: Any, step: int, weights: Sequence[float]) -> list[dict[str, Any]]:
        """metrics.csv rows (kind eval, in episode order) of evaluation.episodes episodes."""
        from priqn.evaluation.protocol import EvalScene
        from priqn.evaluation.rollout import run_scenes

        cfg = self.cfg
        rng = np.random.default_rng([self.seed, step])
        scenes = [
            EvalScene(
                eval_run=0,
                net=str(self.nets[int(rng.integers(len(self.nets)))]),
                density=float(cfg.env.densities[int(rng.integers(len(cfg.env.densities)))]),
                episode=i,
                reset_seed=int(rng.integers(2**31)),
                act_seed=int(rng.integers(2**31)),
                command=None,
            )
            for i in range(cfg.evaluation.episodes)
        ]
        rows: list[dict[str, Any]] = []
        names = cfg.objective_names
        subsets = subset_columns(names)

        def on_episode(scene: Any, values: dict[str, Any]) -> None:
            row = metrics_row("eval", values, scene.net, weights, names)
            row.update({k: values[k] for k in subsets if k in values})  # preorder agents
            row.update(episode=scene.episode + 1, epsilon=0.0, loss="")
            rows.append(row)

        run_scenes(policy, self.envs, scenes, on_episode)
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
        "--preset",
        default="default",
        help=f"{' | '.join(PRESETS)} (priqn/presets/train_<name>.toml; default: default)",
    )
    parser.add_argument("--steps", type=int, help="training budget in env decisions (total_steps)")
    parser.add_argument(
        "--traffic",
        metavar="NAME",
        help="a named traffic setting, applied before --set and recorded in meta.json: "
        + "; ".join(f"{k}: {v.description}" for k, v in TRAFFIC_SETTINGS.items())
        + " (docs/environment.md, 'Traffic')",
    )
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
        changed = [
            f for f in ("net", "agent", "seed", "config", "num_envs", "traffic") if getattr(args, f)
        ]
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
        if args.seed is not None and args.seed < 0:
            raise PriqnError(f"--seed {args.seed}: expected an integer >= 0")
        cfg = resolve_config(
            preset=args.preset,
            agent=args.agent,
            seed=args.seed,
            net=args.net,
            steps=args.steps,
            values=traffic_values(args.traffic),
            overrides=args.set,
            config_file=args.config,
            num_envs=args.num_envs,
            device=args.device,
        )
        run_dir = Path(args.runs_dir) / (args.name or default_run_name(cfg))
        train(cfg, run_dir, force=args.force, traffic=args.traffic or "")
    print(f"priqn train: run folder {run_dir}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    os.environ.setdefault("MPLBACKEND", "Agg")
    from priqn.cli import main

    sys.exit(main(["train", *sys.argv[1:]]))
