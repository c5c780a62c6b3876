"""Evaluation protocol: every trained run meets the same hold-out scenes.

``priqn evaluate runs/<name> [runs/<other> ...]`` (or a folder of runs) plays each
run's greedy policy on the hold-out nets × traffic densities × ``eval_runs``
evaluation runs, ``episodes_per_cell`` episodes per (evaluation run, net, density)
cell, and writes one row per episode to ``runs/<name>/eval/episodes.csv``.

Scenes are identical for every policy: the reset seed of episode ``e`` in cell
(evaluation run ``r``, net ``n``, density ``d``) is drawn from
``SeedSequence(EvalConfig.seed, spawn_key=(r, n, d, e))`` where ``n`` and ``d`` are
indices into the sorted hold-out net ids and the configured densities. The
training seed never enters. The policy's own randomness (Pr-IQN samples from its
leaf subset) uses a generator seeded from the same key, so an episode's result does
not depend on how many workers ran it or in which order.

Resumable: each finished cell is written atomically to ``eval/cells/``; a second
call skips finished cells. ``eval/meta.json`` says ``"status": "complete"`` only
after every cell is done; it records the hold-out manifest hash, the EvalConfig
and the seeds. A different hold-out set or EvalConfig than a half-finished
evaluation refuses to mix (``--force`` starts over).

``--acting near-greedy`` evaluates the greedy baselines once more, acting at random
among their near-best actions (the acting-randomness control), into ``eval-near-greedy/``.

``--nets PATH ...`` plays the same protocol on your own ``.net.xml`` files (checked before
any episode) into ``eval-nets-<hash>/`` beside ``eval/`` (the generalisation table of
``priqn report``). ``--reference sumo|random --out DIR`` evaluates a reference driver
(SUMO's own driver models, or uniform random actions) on the same scenes into ``DIR/eval/``
(``priqn report --reference DIR``).
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import shutil
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from priqn.config import apply_overrides, config_differences, from_dict, load_toml, to_dict
from priqn.episodes import episode_values, final_info
from priqn.errors import PriqnError
from priqn.io import atomic_write_json, atomic_write_text, read_json, sha256_file
from priqn.labels import CONFIG_COLUMNS
from priqn.objectives import OBJECTIVES, names_in_columns, return_columns, subset_columns
from priqn.runs import SNAPSHOT_PREFIX, RunFolder, Status

LABEL_KEYS: tuple[str, ...] = (*CONFIG_COLUMNS, "train_seed", "label")
"""Keys of ``Policy.labels`` copied into every episode row."""


def episode_columns(objectives: Sequence[str] = OBJECTIVES) -> tuple[str, ...]:
    """Columns of ``eval/episodes.csv`` for a policy with these objective names, in order
    (``return_<name>`` / ``subset_<name>`` follow the run's ``env.objectives``)."""
    return (
        "run",
        "label",
        *(key for key in LABEL_KEYS if key != "label"),
        "eval_run",
        "net",
        "density",
        "density_realised",
        "success",
        "collision",
        "off_road",
        "timeout",
        "route_progress",
        "steps",
        *return_columns(objectives),
        *subset_columns(objectives),
        "holdout_hash",
        # Beyond the contract's list: the scene's identity, so "same scenes" can be checked.
        "episode",
        "command",
        "reset_seed",
    )


EPISODE_COLUMNS: tuple[str, ...] = episode_columns(OBJECTIVES)
"""Columns of ``eval/episodes.csv`` with the default objectives (one row per episode)."""


ACTINGS: tuple[str, ...] = ("own", "near-greedy")
"""Values of ``EvalConfig.acting``; each evaluates into its own folder (:func:`eval_dir_of`)."""


@dataclasses.dataclass(frozen=True)
class EvalConfig:
    """How a trained run is evaluated (recorded in ``eval/meta.json``)."""

    family: str = "holdout"
    """Scenario family of the evaluation nets (never a training pool)."""
    densities: tuple[float, ...] = (0.5, 0.75, 1.0)
    """Requested traffic densities (active actors / maximum actors)."""
    eval_runs: int = 3
    """Evaluation runs per trained run (the paper: 3), each with its own scenes."""
    episodes_per_cell: int = 6
    """Episodes per (evaluation run, net, density) cell. Small by default so a CPU
    evaluation of one run takes minutes; raise it for publication numbers."""
    seed: int = 2026
    """Evaluation seed: every scene and the policy's acting randomness derive from it
    (never from the training seed), so every policy meets the same scenes."""
    commands: tuple[str, ...] = ()
    """Ego route commands cycled over the episodes of a cell ("left", "straight",
    "right"); empty = the environment draws the command from the reset seed."""
    num_workers: int = 2
    """Environment worker processes (the parent process never runs SUMO)."""
    max_episode_steps: int = 0
    """Override of the run's episode step limit; 0 keeps the run's own."""
    device: str = "cpu"
    """Torch device for the policy network."""
    acting: str = "own"
    """How the policy acts: "own" (its agent's rule: greedy, or Pr-IQN's sample from its
    leaf subset; written to eval/) or "near-greedy" (the acting-randomness control for
    IQN, Ensemble-IQN and MA-IQN: uniform among the actions whose mean is within
    acting_eps of the best; written to eval-near-greedy/, labelled as its own row)."""
    acting_eps: float = 0.2
    """Tolerance ε of near-greedy acting, in per-state standard deviations of the scalar
    value's quantiles (the z-score of Pr-IQN's comparators; 0.2 is Pr-IQN*'s ε)."""
    nets: tuple[str, ...] = ()
    """Plain ``.net.xml`` files and/or folders of them to evaluate on instead of ``family``
    (no manifest; docs/your-own-net.md). Written to ``eval-nets-<hash>/`` beside ``eval/``
    (:func:`evaluation_name`), never into ``eval/``; one path or a list."""
    junction: str = ""
    """With ``nets``: the id of the junction to drive through ('' = each net's junction with
    the most approaches)."""
    snapshot: int = 0
    """Evaluate the policy the run kept at this many decisions (``checkpoint.keep_at``)
    instead of its final one, into ``eval-at<N>/`` beside ``eval/`` (0: the final policy)."""

    def __post_init__(self) -> None:
        if isinstance(self.nets, str):  # one path (--set nets=my_nets/)
            object.__setattr__(self, "nets", (self.nets,) if self.nets else ())
        if not all(isinstance(n, str) and n for n in self.nets):
            raise ValueError(f"nets: expected .net.xml files or folders, got {list(self.nets)}")
        object.__setattr__(self, "nets", tuple(self.nets))
        if self.acting not in ACTINGS:
            raise ValueError(f"acting: {self.acting!r} is not one of {', '.join(ACTINGS)}")
        if not self.acting_eps >= 0:
            raise ValueError(f"acting_eps: must be >= 0, got {self.acting_eps}")
        if not self.densities:
            raise ValueError("densities: need at least one density")
        if any(not 0.0 < d <= 1.0 for d in self.densities):
            raise ValueError(f"densities: each must be in (0, 1], got {list(self.densities)}")
        if len(set(self.densities)) != len(self.densities):
            raise ValueError(f"densities: duplicates in {list(self.densities)}")
        if self.eval_runs < 1:
            raise ValueError(f"eval_runs: must be >= 1, got {self.eval_runs}")
        if self.episodes_per_cell < 1:
            raise ValueError(f"episodes_per_cell: must be >= 1, got {self.episodes_per_cell}")
        if self.num_workers < 1:
            raise ValueError(f"num_workers: must be >= 1, got {self.num_workers}")
        if self.snapshot < 0:
            raise ValueError(
                f"snapshot: expected 0 (the final policy) or a budget, got {self.snapshot}"
            )
        if self.max_episode_steps < 0:
            raise ValueError(f"max_episode_steps: must be >= 0, got {self.max_episode_steps}")
        bad = [c for c in self.commands if c not in ("left", "straight", "right")]
        if bad:
            raise ValueError(f"commands: {bad[0]!r} is not one of left, straight, right")


@dataclasses.dataclass(frozen=True)
class Scene:
    """One evaluation episode: what the environment is reset to and the acting seed."""

    eval_run: int
    """Evaluation-run index (0-based)."""
    net: str
    """Net as ``"<family>/<net_id>"``."""
    density: float
    """Requested traffic density."""
    episode: int
    """Episode index within the cell."""
    reset_seed: int
    """Seed passed to ``env.reset``."""
    act_seed: int
    """Seed of the policy's acting generator for this episode."""
    command: str | None
    """Route command, or None to let the environment draw it."""

    @property
    def cell(self) -> tuple[int, str, float]:
        return (self.eval_run, self.net, self.density)

    def reset_options(self) -> dict[str, Any]:
        options: dict[str, Any] = {"net": self.net, "density": self.density}
        if self.command is not None:
            options["command"] = self.command
        return options


def make_scenes(cfg: EvalConfig, net_ids: Sequence[str]) -> list[Scene]:
    """All evaluation episodes in canonical order (eval run, net, density, episode).

    ``net_ids`` are the hold-out nets' ids (without family); they are sorted, so the
    scenes depend only on the set of nets, ``cfg.seed`` and the cell's indices. With
    ``cfg.nets`` they are the nets' full names (``"<folder>/<stem>"``, :func:`evaluation_nets`)
    and the same rule applies.
    """
    scenes = []
    for r in range(cfg.eval_runs):
        for n, net_id in enumerate(sorted(net_ids)):
            for d, density in enumerate(cfg.densities):
                for e in range(cfg.episodes_per_cell):
                    ss = np.random.SeedSequence(cfg.seed, spawn_key=(r, n, d, e))
                    reset_seed, act_seed = (int(x) for x in ss.generate_state(2, dtype=np.uint32))
                    command = cfg.commands[e % len(cfg.commands)] if cfg.commands else None
                    scenes.append(
                        Scene(
                            r,
                            net_id if cfg.nets else f"{cfg.family}/{net_id}",
                            float(density),
                            e,
                            reset_seed,
                            act_seed,
                            command,
                        )
                    )
    return scenes


RESULT_NEUTRAL_FIELDS: frozenset[str] = frozenset({"num_workers", "nets", "junction"})
"""EvalConfig fields that do not change any episode (may differ on resume). ``nets`` and
``junction`` say where the files lie and what was asked; what is evaluated on (each net's
name, SHA-256 and junction) is the evaluation's nets hash, checked on its own."""

NETS_PREFIX = "nets-"
"""Evaluations on your own nets are ``eval-nets-<hash>[-<control>]/`` (:func:`evaluation_name`)."""
NETS_HASH_CHARS = 8
"""Hex digits of the nets hash in an evaluation folder's name."""


def eval_config_differences(old: dict[str, Any], new: dict[str, Any]) -> list[tuple[str, Any, Any]]:
    """Result-affecting differences of two recorded EvalConfigs (``config_differences``).

    A field missing from a record written before the field existed counts as its
    default: the evaluation behaved as the default does (``acting`` was always "own").
    """
    defaults = to_dict(EvalConfig())
    return config_differences(
        {**defaults, **old}, {**defaults, **new}, ignore=RESULT_NEUTRAL_FIELDS
    )


def eval_config_changes(old: dict[str, Any], new: dict[str, Any]) -> str:
    """``"field old -> new, ..."`` for result-affecting EvalConfig fields that differ."""
    diff = eval_config_differences(old, new)
    return ", ".join(f"{k} {a!r} -> {b!r}" for k, a, b in diff)


def evaluation_name(cfg: EvalConfig, nets_hash: str = "") -> str:
    """Name of the evaluation ``cfg`` makes: "" (the run's own, ``eval/``), ``near-greedy``
    (a control at the default ε, ``eval-near-greedy/``) or ``near-greedy-eps<ε>``.

    With ``cfg.nets``: ``nets-<first 8 hex digits of nets_hash>`` (:func:`nets_hash`), then
    the control's name if any (``nets-1a2b3c4d-near-greedy``): an evaluation on other nets
    never shares a folder with the hold-out one. With ``cfg.snapshot`` N: ``at<N>`` first
    (``at60000``, ``at60000-near-greedy``).
    """
    if cfg.nets and not nets_hash:
        raise ValueError("evaluation_name: an evaluation on cfg.nets needs their nets_hash")
    control = ""
    if cfg.acting != "own":
        control = (
            cfg.acting
            if cfg.acting_eps == EvalConfig.acting_eps
            else f"{cfg.acting}-eps{cfg.acting_eps:g}"
        )
    snapshot = RunFolder.snapshot_evaluation(cfg.snapshot) if cfg.snapshot else ""
    nets = f"{NETS_PREFIX}{nets_hash[:NETS_HASH_CHARS]}" if cfg.nets else ""
    return "-".join(p for p in (snapshot, nets, control) if p)


def is_nets_evaluation(name: str) -> bool:
    """Whether ``eval-<name>/`` is an evaluation on other nets (not part of Table II)."""
    return snapshot_budget(name)[1].startswith(NETS_PREFIX)


def snapshot_budget(name: str) -> tuple[int, str]:
    """``(N, rest)`` of an evaluation name ``at<N>[-rest]`` (a kept snapshot's); ``(0, name)``
    for the final policy's."""
    match = re.fullmatch(rf"{SNAPSHOT_PREFIX}(\d+)(?:-(.*))?", name)
    if match is None:
        return 0, name
    return int(match[1]), match[2] or ""


def control_config(cfg: EvalConfig, name: str) -> EvalConfig:
    """``cfg`` acting as the control ``name`` says (inverse of :func:`evaluation_name`).

    A one-line PriqnError for a name that is not ``near-greedy`` or ``near-greedy-eps<ε>``.
    """
    if not name:
        return dataclasses.replace(cfg, acting="own")
    match = re.fullmatch(r"(?P<acting>[a-z-]+?)(?:-eps(?P<eps>[0-9.e+-]+))?", name)
    if match is None or match["acting"] not in ACTINGS or match["acting"] == "own":
        raise PriqnError(
            f"control {name!r}: expected near-greedy or near-greedy-eps<ε> (e.g. near-greedy-eps0.01)"
        )
    try:
        eps = float(match["eps"]) if match["eps"] else EvalConfig.acting_eps
        return dataclasses.replace(cfg, acting=match["acting"], acting_eps=eps)
    except ValueError as exc:
        raise PriqnError(f"control {name!r}: {exc}") from None


def eval_dir_of(run: RunFolder, cfg: EvalConfig, nets_hash: str = "") -> Path:
    """The run's evaluation folder for ``cfg``: ``eval/`` or ``eval-<name>/`` (:func:`evaluation_name`)."""
    return run.evaluation_dir(evaluation_name(cfg, nets_hash))


def evaluation_nets(cfg: EvalConfig, commands: Sequence[str]) -> dict[str, Any]:
    """The manifest of ``cfg.nets``, every net checked now, before any episode.

    ``{"junction", "nets": [{"id", "path", "files": {name: sha256}, "junction"}, ...]}``,
    sorted by id, in the format of a run's ``nets.json``: ``id`` is the net's name
    (``"<folder>/<stem>"`` of its resolved path, the name the env and the episode table
    use), ``path`` its absolute path, ``junction`` the junction driven through. A path that
    is no ``.net.xml`` (or folder of them), a net SUMO cannot load, one without a usable
    intersection or without a route for the evaluated ``commands`` (``cfg.commands``, else
    at least one of the run's ``commands``) is a one-line :class:`PriqnError` naming it.
    """
    from priqn.env.scenes import own_net_files
    from priqn.sim.roadmap import RoadMap
    from priqn.sim.session import check_net

    files = own_net_files([str(Path(n).resolve()) for n in cfg.nets], where="--nets")
    entries = []
    for ref, path in sorted(files.items()):
        check_net(path)  # SUMO can load it (libsumo would crash a worker on a broken net)
        roadmap = RoadMap.load(path, junction=cfg.junction or None)
        offered = roadmap.commands()
        wanted = cfg.commands or tuple(commands)
        missing = [c for c in cfg.commands if c not in offered]
        if missing or not any(c in offered for c in wanted):
            raise PriqnError(
                f"{path}: junction {roadmap.junction_id} has no {(missing or wanted)[0]!r} route "
                f"(it offers: {', '.join(offered)}); evaluate other commands or pick another "
                "junction with --junction"
            )
        entries.append(
            {
                "id": ref,
                "path": str(path),
                "files": {path.name: sha256_file(path)},
                "junction": roadmap.junction_id,
            }
        )
    return {"junction": cfg.junction, "nets": entries}


def nets_hash(manifest: dict[str, Any]) -> str:
    """SHA-256 identifying what an evaluation on your own nets drives on: one line
    ``<id>/<file> <sha256> junction <id>`` per net, sorted (moving the files keeps it)."""
    import hashlib

    lines = sorted(
        f"{net['id']}/{name} {sha} junction {net['junction']}"
        for net in manifest["nets"]
        for name, sha in net["files"].items()
    )
    return hashlib.sha256("\n".join(lines).encode()).hexdigest()


def cell_file(eval_dir: Path, cell: tuple[int, str, float]) -> Path:
    """File of one finished (eval run, net, density) cell."""
    eval_run, net, density = cell
    return (
        eval_dir / RunFolder.EVAL_CELLS / f"r{eval_run}__{net.replace('/', '__')}__d{density:g}.csv"
    )


# ----------------------------------------------------------------------------- episodes


def _select(obs: Any, i: int) -> Any:
    if isinstance(obs, dict):
        return {k: _select(v, i) for k, v in obs.items()}
    return np.asarray(obs)[i : i + 1]


@dataclasses.dataclass(frozen=True)
class RolloutStep:
    """One decision of one scene as :func:`rollout` played it."""

    scene: Scene
    """The scene (episode) this decision belongs to."""
    step: int
    """Decision index within the episode (0-based)."""
    action: int
    """The action sent to the env."""
    decision: Any
    """The policy's :class:`priqn.agents.policy.Decision` for this state alone (B = 1)."""
    reward_N: np.ndarray
    """float64 ``[N]``: the reward vector this decision earned (the run's objectives)."""
    frame: np.ndarray | None
    """The env's rendering of the state decided on (``frames=True``; else None)."""
    episode: dict[str, Any] | None
    """When this decision ended the episode: its values (:func:`priqn.episodes.episode_values`
    and the mean ``subset_<name>`` sizes); None before."""


def rollout(
    policy: Any,
    vec_env: Any,
    scenes: Sequence[Scene],
    quantiles: bool = False,
    frames: bool = False,
) -> Iterator[RolloutStep]:
    """Play every scene once on ``vec_env`` (SAME_STEP autoreset) with ``policy``, yielding
    each decision as a :class:`RolloutStep`. The one rollout loop: ``priqn evaluate`` (also
    of the reference drivers), training's periodic evaluation, ``priqn inspect`` and the
    mechanism analysis all play their scenes here.

    ``policy.decide(obs, rng, quantiles=...)`` gets one row at a time with the scene's
    acting generator, so results do not depend on the number of workers, nor on
    ``quantiles`` (record the quantiles) or ``frames`` (render the state before each
    decision, ``vec_env.call("render")``; its env needs ``render_mode="rgb_array"``).
    Each worker takes the next scene when its episode ends: it is reset to that scene with
    ``options['reset_mask']`` (the autoreset's own scene is discarded). (A first plain
    reset initialises every worker; its scenes are discarded too.) Steps come in
    (vector step, worker) order; a scene's steps in order.
    """
    from priqn.agents.policy import SubsetSizeMeans

    num_envs = int(vec_env.num_envs)
    sizes = SubsetSizeMeans(num_envs, getattr(policy, "subset_size_names", ()))
    queue = list(scenes)
    slot: list[Scene | None] = [None] * num_envs
    rngs: list[np.random.Generator | None] = [None] * num_envs
    steps = [0] * num_envs
    obs: Any = None

    def assign(i: int) -> None:
        nonlocal obs
        steps[i] = 0
        if not queue:
            slot[i], rngs[i] = None, None
            return
        scene = queue.pop(0)
        mask = np.zeros(num_envs, dtype=np.bool_)
        mask[i] = True
        seeds = [scene.reset_seed if j == i else None for j in range(num_envs)]
        new_obs, _ = vec_env.reset(
            seed=seeds, options={**scene.reset_options(), "reset_mask": mask}
        )
        obs = _merge(obs, new_obs, i)
        slot[i] = scene
        rngs[i] = np.random.default_rng(scene.act_seed)

    # Every worker needs a first reset before a masked one; that scene is discarded.
    obs, _ = vec_env.reset()
    obs = _copy(obs)
    for i in range(num_envs):
        assign(i)
    while any(s is not None for s in slot):
        actions = np.zeros(num_envs, dtype=np.int64)
        decisions: list[Any] = [None] * num_envs
        for i, scene in enumerate(slot):
            if scene is not None:
                decisions[i] = policy.decide(_select(obs, i), rngs[i], quantiles=quantiles)
                actions[i] = int(np.asarray(decisions[i].actions_B).reshape(-1)[0])
                sizes.add(decisions[i].subset_sizes_BS, rows=slice(i, i + 1))
        rendered = vec_env.call("render") if frames else None
        obs, rewards, terminated, truncated, infos = vec_env.step(actions)
        for i, scene in enumerate(slot):
            if scene is None:
                continue
            ended = bool(terminated[i] or truncated[i])
            values = None
            if ended:
                values = episode_values(final_info(infos, i))
                values.update(sizes.pop(i))
            yield RolloutStep(
                scene,
                steps[i],
                int(actions[i]),
                decisions[i],
                np.asarray(rewards[i], dtype=np.float64).reshape(-1),
                None if rendered is None else np.asarray(rendered[i]),
                values,
            )
            steps[i] += 1
            if ended:
                assign(i)


def run_scenes(
    policy: Any,
    vec_env: Any,
    scenes: Sequence[Scene],
    on_episode: Callable[[Scene, dict[str, Any]], None],
    progress: Any | None = None,
) -> None:
    """Play every scene once with :func:`rollout`; ``on_episode(scene, values)`` is called
    with the episode's values as each episode finishes (and ``progress.update(1)``)."""
    for step in rollout(policy, vec_env, scenes):
        if step.episode is not None:
            on_episode(step.scene, step.episode)
            if progress is not None:
                progress.update(1)


def _merge(obs: Any, new_obs: Any, i: int) -> Any:
    """Copy row ``i`` of ``new_obs`` into ``obs`` (or take ``new_obs`` if none yet)."""
    if obs is None:
        return _copy(new_obs)
    if isinstance(obs, dict):
        for k in obs:
            obs[k] = _merge(obs[k], new_obs[k], i)
        return obs
    obs = np.array(obs, copy=True)
    obs[i] = np.asarray(new_obs)[i]
    return obs


def _copy(obs: Any) -> Any:
    if isinstance(obs, dict):
        return {k: _copy(v) for k, v in obs.items()}
    return np.array(obs, copy=True)


# ----------------------------------------------------------------------------- one run


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
    meta_path = eval_dir / RunFolder.META
    meta = {
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
    earlier_s = 0.0  # evaluation time already spent on the kept cells (a resumed evaluation)
    if meta_path.is_file() and not force:
        old = read_json(meta_path)
        earlier_s = float(old.get("wall_s") or 0.0)
        if old.get("holdout_hash") != holdout_hash:
            raise PriqnError(
                f"{meta_path}: this run was evaluated on a different hold-out set (holdout_hash "
                f"{str(old.get('holdout_hash'))[:12]} vs now {holdout_hash[:12]}); use --force to start over"
            )
        diff = eval_config_changes(old.get("eval_config") or {}, meta["eval_config"])
        if diff:
            raise PriqnError(
                f"{meta_path}: an evaluation with a different eval_config is already here "
                f"({diff}); use --force to start over"
            )
    if force and eval_dir.exists():
        shutil.rmtree(eval_dir)
    started = time.perf_counter()

    def write_meta(**fields: Any) -> None:
        """Write meta.json with the evaluation's time so far (kept across interruptions)."""
        meta.update(fields, wall_s=round(earlier_s + time.perf_counter() - started, 1))
        atomic_write_json(meta_path, meta)

    write_meta()

    labels = dict(getattr(policy, "labels", {}) or {})
    fixed = {key: labels.get(key) for key in LABEL_KEYS}
    fixed.update({"run": run_name, "holdout_hash": holdout_hash})

    scenes = make_scenes(cfg, net_ids)
    cells: dict[tuple[int, str, float], list[Scene]] = {}
    for scene in scenes:
        cells.setdefault(scene.cell, []).append(scene)
    todo_cells = {
        c for c, sc in cells.items() if not _cell_complete(cell_file(eval_dir, c), len(sc))
    }
    todo = [s for s in scenes if s.cell in todo_cells]
    pending: dict[tuple[int, str, float], list[dict[str, Any]]] = {c: [] for c in todo_cells}

    def on_episode(scene: Scene, values: dict[str, Any]) -> None:
        row = {
            **fixed,
            "eval_run": scene.eval_run,
            "net": scene.net,
            "density": scene.density,
            "episode": scene.episode,
            "reset_seed": scene.reset_seed,
            "command": scene.command or "",
            **values,
        }
        pending[scene.cell].append(row)
        if len(pending[scene.cell]) == len(cells[scene.cell]):
            _write_cell(cell_file(eval_dir, scene.cell), pending.pop(scene.cell))
            write_meta()

    if todo:
        num_envs = min(cfg.num_workers, len(todo))
        vec_env = make_env(num_envs)
        try:
            with tqdm(total=len(todo), desc=f"evaluate {run_name}", unit="ep", disable=None) as bar:
                run_scenes(policy, vec_env, todo, on_episode, progress=bar)
        finally:
            vec_env.close()

    frames = [pd.read_csv(cell_file(eval_dir, c)) for c in sorted(cells)]
    episodes = pd.concat(frames, ignore_index=True)
    out = eval_dir / RunFolder.EVAL_EPISODES
    atomic_write_text(out, episodes.to_csv(index=False, lineterminator="\n"))
    write_meta(status=Status.COMPLETE, episodes=len(episodes))
    return out


def _evaluation_target(
    cfg: EvalConfig, commands: Sequence[str]
) -> tuple[list[str], str, dict[str, Any] | None]:
    """``(net ids, hash, nets manifest)`` of what ``cfg`` evaluates on: the hold-out family
    (its manifest hash; no nets manifest) or ``cfg.nets`` (checked now, :func:`evaluation_nets`;
    their :func:`nets_hash`). ``commands``: the env's, for the check of ``cfg.nets``."""
    if cfg.nets:
        nets = evaluation_nets(cfg, commands)
        return [n["id"] for n in nets["nets"]], nets_hash(nets), nets
    from priqn.sim.scenario import load_manifest, manifest_hash

    return _net_ids(load_manifest(cfg.family)), manifest_hash(cfg.family), None


def _evaluation_env(env_config: Any, cfg: EvalConfig, nets: dict[str, Any] | None) -> Any:
    """``env_config`` (a run's EnvConfig) set to play ``cfg``'s scenes: on the checked files
    of ``nets`` by their absolute paths, else on the hold-out family (also for a run trained
    on its own nets or junction); ``cfg.max_episode_steps`` if set."""
    if nets is not None:
        files = tuple(n["path"] for n in nets["nets"])
        env_cfg = dataclasses.replace(env_config, nets=files, junction=cfg.junction)
    else:
        env_cfg = dataclasses.replace(env_config, family=cfg.family, nets=(), junction="")
    if cfg.max_episode_steps:
        env_cfg = dataclasses.replace(env_cfg, max_episode_steps=cfg.max_episode_steps)
    return env_cfg


def _net_ids(manifest: Any) -> list[str]:
    nets = manifest.get("nets") if isinstance(manifest, dict) else getattr(manifest, "nets", None)
    if not nets:
        raise PriqnError("hold-out manifest lists no nets; run 'priqn scenario generate'")
    ids = [n["id"] if isinstance(n, dict) else getattr(n, "id", n) for n in nets]
    return sorted(str(i) for i in ids)


def evaluate_run(run_dir: str | Path, cfg: EvalConfig, force: bool = False) -> Path:
    """Evaluate the trained run in ``run_dir``; returns ``run_dir/eval/episodes.csv``.

    The run must be complete (``meta.json`` status). A finished evaluation with the
    same hold-out hash and EvalConfig is returned as is; a half-finished one goes on.
    With ``cfg.nets`` the run is evaluated on those nets instead, into
    ``eval-nets-<hash>/`` (:func:`evaluation_name`); every net is checked first
    (:func:`evaluation_nets`), so a net that cannot be used stops before any episode.
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

    net_ids, holdout_hash, nets = _evaluation_target(cfg, run.config().env.commands)
    eval_dir = eval_dir_of(run, cfg, holdout_hash if nets else "")
    meta_path, episodes_path = eval_dir / RunFolder.META, eval_dir / RunFolder.EVAL_EPISODES
    if not force and meta_path.is_file():
        old = read_json(meta_path)
        if (
            old.get("status") == Status.COMPLETE
            and old.get("holdout_hash") == holdout_hash
            and not eval_config_changes(old.get("eval_config") or {}, to_dict(cfg))
            and episodes_path.is_file()
        ):
            return episodes_path

    from priqn.env.vector import make_vector_env

    policy = run.load_policy(device=cfg.device, snapshot=cfg.snapshot)
    if cfg.acting == "near-greedy":
        policy = policy.near_greedy(cfg.acting_eps)
    env_cfg = _evaluation_env(policy.env_config, cfg, nets)

    def make_env(num_envs: int) -> Any:
        # The vector env's own seed only seeds autoresets, whose scenes are discarded.
        return make_vector_env(env_cfg, num_envs=num_envs, seed=cfg.seed)

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


def find_runs(paths: Iterable[str | Path]) -> list[Path]:
    """Run folders named by ``paths``: a run folder itself, or a folder of runs."""
    runs: list[Path] = []
    for p in map(Path, paths):
        if not p.is_dir():
            raise PriqnError(f"{p}: no such folder")
        if RunFolder(p).is_run():
            runs.append(p)
            continue
        inner = sorted(c for c in p.iterdir() if RunFolder(c).is_run())
        if not inner:
            raise PriqnError(f"{p}: neither a run folder (config.toml) nor a folder of runs")
        runs.extend(inner)
    return runs


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
    from priqn.agent_config import has_scalar_value

    name = RunFolder(run).config().agent.name
    if has_scalar_value(name):
        return True
    print(
        f"{run}: skipped ({name} acts on its optimal subsets; near-greedy is for the greedy baselines)",
        file=sys.stderr,
    )
    return False


# ----------------------------------------------------------------------------- reference drivers


REFERENCES: dict[str, str] = {"sumo": "SUMO driver", "random": "Random actions"}
"""Reference drivers (``priqn evaluate --reference NAME``) and their row names."""
REFERENCE_WORD = "(reference)"
"""Ends every reference row's label, e.g. ``SUMO driver (reference)``."""
DEFAULT_REFERENCE_DIR = "reference"
"""A reference evaluation goes to ``reference/<name>/`` unless ``--out`` says otherwise."""
OBSERVATION_FIELDS: frozenset[str] = frozenset(
    {"obs_size_px", "render_size_px", "bev_range_m", "bev_behind_m", "bev_channels"}
)
"""EnvConfig fields that change what a policy sees but no scene, move or measure."""
SCENE_NEUTRAL_FIELDS: frozenset[str] = OBSERVATION_FIELDS | {
    "family",
    "nets",
    "nets_dir",
    "junction",
}
"""EnvConfig fields a reference evaluation may take from any of its runs (the nets are the
evaluation's own)."""


def reference_label(name: str) -> str:
    """The label of reference driver ``name``'s rows: ``SUMO driver (reference)``."""
    return f"{REFERENCES[name]} {REFERENCE_WORD}"


class ReferenceDriver:
    """A reference "policy": ``sumo`` (SUMO drives the ego, ``EnvConfig.ego_driver``; the
    action is ignored) or ``random`` (uniform over the action grid, from the scene's acting
    generator, so it is reproducible like a policy's own randomness)."""

    def __init__(self, name: str, num_actions: int) -> None:
        """``name``: a key of :data:`REFERENCES`; ``num_actions``: the env's action count."""
        if name not in REFERENCES:
            raise PriqnError(f"--reference {name}: expected one of {', '.join(REFERENCES)}")
        self.name = name
        """Driver name (a key of :data:`REFERENCES`)."""
        self.num_actions = int(num_actions)
        """Size of the env's action grid."""
        self.labels: dict[str, Any] = {key: "" for key in LABEL_KEYS}
        """Episode-row identity: ``agent`` = the driver's name, training seed 0 (none)."""
        self.labels.update(agent=name, train_seed=0, label=reference_label(name))

    def act(self, obs: Any, rng: np.random.Generator) -> np.ndarray:
        """One action: uniform at random (``random``); 0, ignored by the env (``sumo``)."""
        if self.name == "random":
            return np.array([int(rng.integers(self.num_actions))], np.int64)
        return np.zeros(1, np.int64)

    def decide(self, obs: Any, rng: np.random.Generator, quantiles: bool = False) -> Any:
        """:meth:`act` as a :class:`priqn.agents.policy.Decision` (no subsets, no quantiles)."""
        from priqn.agents.policy import Decision

        return Decision(self.act(obs, rng))


def reference_env_config(paths: Iterable[str | Path]) -> tuple[Any, list[str]]:
    """The EnvConfig a reference evaluation plays with, and the runs it comes from.

    From the runs under ``paths`` (their scenes, episode length, action grid and rewards):
    they must agree on every field but what only a policy sees and the nets
    (:data:`SCENE_NEUTRAL_FIELDS`). No paths: ``priqn train``'s default env.
    """
    from priqn.train_config import TrainConfig

    runs = find_runs(paths) if paths else []
    if not runs:
        return TrainConfig().env, []
    configs = [(run, RunFolder(run).config().env) for run in runs]
    first, env = configs[0]
    for run, other in configs[1:]:
        diff = config_differences(to_dict(env), to_dict(other), ignore=SCENE_NEUTRAL_FIELDS)
        if diff:
            key, a, b = diff[0]
            raise PriqnError(
                f"{run}: its env differs from {first}'s ({key} {a!r} vs {b!r}); a reference "
                "plays one env: evaluate it against runs that share it (or one run)"
            )
    return env, [RunFolder(run).name for run in runs]


def evaluate_reference(
    name: str,
    out_dir: str | Path,
    cfg: EvalConfig,
    env_config: Any,
    env_of: Sequence[str] = (),
    force: bool = False,
) -> Path:
    """Evaluate reference driver ``name`` with ``cfg``'s protocol; returns its episode table.

    Same scenes as every policy evaluated with ``cfg`` (the scene rule never reads a run):
    the hold-out family into ``out_dir/eval/``, or ``cfg.nets`` into
    ``out_dir/eval-nets-<hash>/``; resumable like a run's evaluation. ``env_config``: the
    env the driver plays (:func:`reference_env_config`; ``env_of`` names its runs). The
    rows are labelled :func:`reference_label`; ``priqn report --reference out_dir`` shows them.
    """
    if cfg.acting != "own":
        raise PriqnError(f"--reference {name}: --acting applies to trained policies only")
    from priqn.env.vector import make_vector_env

    driver = ReferenceDriver(name, env_config.n_speeds * env_config.n_offsets)
    net_ids, holdout_hash, nets = _evaluation_target(cfg, env_config.commands)
    folder = RunFolder(out_dir)
    eval_dir = folder.evaluation_dir(evaluation_name(cfg, holdout_hash if nets else ""))
    env_cfg = _evaluation_env(env_config, cfg, nets)
    env_cfg = dataclasses.replace(env_cfg, ego_driver="sumo" if name == "sumo" else "planner")
    meta_path = eval_dir / RunFolder.META
    if not force and meta_path.is_file() and read_json(meta_path).get("reference") != name:
        raise PriqnError(
            f"{meta_path}: holds no {name!r} reference evaluation; pick another --out "
            "(or --force to start over)"
        )

    def make_env(num_envs: int) -> Any:
        return make_vector_env(env_cfg, num_envs=num_envs, seed=cfg.seed)

    from priqn.provenance import git_sha, versions

    extra_meta: dict[str, Any] = {
        "reference": name,
        "env_of": list(env_of),
        "env_config": to_dict(env_cfg),
        "git_sha": git_sha(),  # a reference has no run folder: its provenance lives here
        "versions": versions(),
    }
    if nets is not None:
        extra_meta.update(nets=nets["nets"], nets_hash=holdout_hash)
    return evaluate_policy(
        driver,
        eval_dir,
        cfg,
        net_ids,
        holdout_hash,
        f"{DEFAULT_REFERENCE_DIR}/{name}",
        make_env,
        extra_meta=extra_meta,
        force=force,
    )


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
        "--family", help="scenario family of the hold-out nets (default holdout; into eval/)"
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
    """EvalConfig from ``--config``, the shortcut flags and ``--set`` overrides."""
    cfg = (
        from_dict(EvalConfig, load_toml(args.config), where=args.config)
        if args.config
        else EvalConfig()
    )
    sets = list(args.set)
    if args.episodes is not None:
        sets.append(f"episodes_per_cell={args.episodes}")
    if args.eval_runs is not None:
        sets.append(f"eval_runs={args.eval_runs}")
    if args.seed is not None:
        sets.append(f"seed={args.seed}")
    if args.workers is not None:
        sets.append(f"num_workers={args.workers}")
    if args.acting is not None:
        sets.append(f"acting={args.acting!r}")
    if args.family is not None:
        sets.append(f"family={args.family!r}")
    if args.snapshot is not None:
        if args.snapshot <= 0:
            raise PriqnError(
                f"--snapshot {args.snapshot}: expected a budget > 0 (checkpoint.keep_at)"
            )
        sets.append(f"snapshot={args.snapshot}")
    if args.acting_eps is not None:
        if not args.acting_eps >= 0:
            raise PriqnError(
                f"--acting-eps {args.acting_eps:g}: expected a tolerance >= 0 "
                "(per-state standard deviations), e.g. 0.2"
            )
        sets.append(f"acting_eps={args.acting_eps!r}")
    if args.densities:
        try:
            values = [float(x) for x in args.densities.split(",") if x.strip()]
        except ValueError as exc:
            raise PriqnError(f"--densities {args.densities!r}: expected e.g. 0.5,0.75,1.0") from exc
        if not values or any(not 0.0 < v <= 1.0 for v in values):
            raise PriqnError(
                f"--densities {args.densities}: each density must be in (0, 1] "
                "(active actors / maximum actors), e.g. 0.5,0.75,1.0"
            )
        sets.append(f"densities=[{', '.join(repr(v) for v in values)}]")
    cfg = apply_overrides(cfg, sets) if sets else cfg
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
