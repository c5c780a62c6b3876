"""The one rollout loop: ``priqn evaluate`` (also of the reference drivers), training's
periodic evaluation, ``priqn inspect`` and the mechanism analysis all play their scenes
(:class:`~priqn.evaluation.protocol.EvalScene`) here, one typed record per decision."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np

from priqn.evaluation.protocol import EvalScene
from priqn.run.episodes import episode_values, final_info


def _select(obs: Any, i: int) -> Any:
    if isinstance(obs, dict):
        return {k: _select(v, i) for k, v in obs.items()}
    return np.asarray(obs)[i : i + 1]


@dataclasses.dataclass(frozen=True)
class RolloutStep:
    """One decision of one scene as :func:`rollout` played it."""

    scene: EvalScene
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
    """When this decision ended the episode: its values (:func:`priqn.run.episodes.episode_values`
    and the mean ``subset_<name>`` sizes); None before."""


# long: one loop over vector steps; its per-worker state (scene, generator, step, obs) is
# shared by the reset of a worker and the step of all, so it reads best in one place.
def rollout(
    policy: Any,
    vec_env: Any,
    scenes: Sequence[EvalScene],
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
    slot: list[EvalScene | None] = [None] * num_envs
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
    scenes: Sequence[EvalScene],
    on_episode: Callable[[EvalScene, dict[str, Any]], None],
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
