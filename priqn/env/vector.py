"""N environments in N worker processes: libsumo allows one simulation per process.

:func:`make_vector_env` builds a gymnasium ``AsyncVectorEnv`` with the ``spawn``
start method (the parent process never imports or runs SUMO) and ``SAME_STEP``
autoreset, so a finished episode's last observation and info come back in
``infos["final_obs"]`` / ``infos["final_info"]`` of the same step and rewards stay a
clean ``float32 [num_envs, 5]`` array (``NEXT_STEP`` would mix a scalar 0 reward into
the vector rewards on the reset step).

Worker ``i``'s first episode is seeded with a child of
``numpy.random.SeedSequence(seed)``; later episodes draw their seeds from the
worker's generator, so one integer fixes every episode of every worker.

A worker that dies (e.g. SUMO crashed the process, or it was killed) is reported as a
one-line :class:`~priqn.errors.PriqnError` naming the worker and its exit code, also
when it dies while the parent waits on it; a worker whose env raises a
:class:`~priqn.errors.PriqnError` is reported as ``vector env worker <i>: <message>``
(no traceback); any other exception keeps its type, gets the worker's name and its
traceback is printed (an internal error). The vector env is closed either way.

``gymnasium.make_vec`` builds this vector env by default; its ``vectorization_mode="async"``
(gymnasium's own ``AsyncVectorEnv``) gets ``SAME_STEP`` autoreset as well, and ``"sync"`` is
refused in one line (:func:`fit_gymnasium_vectorizer`).
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.connection
import sys
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from gymnasium.vector import AsyncVectorEnv, AutoresetMode, VectorEnv
from gymnasium.vector.async_vector_env import AsyncState

from priqn.errors import PriqnError

DEAD_WORKER_WAIT_S = 2.0
"""How long a broken pipe waits for the OS to report which worker ended [s]."""


class _EnvFactory:
    """Picklable constructor of one worker's env (spawn pickles it into the worker)."""

    def __init__(self, config: Any, seed: int, render_mode: str | None) -> None:
        self.config, self.seed, self.render_mode = config, seed, render_mode

    def __call__(self):  # noqa: ANN204 - returns a gymnasium.Env
        from priqn.env.intersection import IntersectionEnv  # imported in the worker only

        return IntersectionEnv(self.config, render_mode=self.render_mode, seed=self.seed)


class PriqnVectorEnv(AsyncVectorEnv):
    """``AsyncVectorEnv`` whose worker deaths and errors become one-line :class:`PriqnError`s."""

    def reset_async(self, *args: Any, **kwargs: Any) -> None:
        self._guard("reset", super().reset_async, *args, **kwargs)

    def reset_wait(self, *args: Any, **kwargs: Any):  # noqa: ANN201
        return self._guard("reset", super().reset_wait, *args, **kwargs)

    def step_async(self, actions: Any) -> None:
        self._guard("step", super().step_async, actions)

    def step_wait(self, *args: Any, **kwargs: Any):  # noqa: ANN201
        obs, rewards, terminated, truncated, infos = self._guard(
            "step", super().step_wait, *args, **kwargs
        )
        return obs, np.asarray(rewards, dtype=np.float32), terminated, truncated, infos

    def call_wait(self, *args: Any, **kwargs: Any):  # noqa: ANN201
        return self._guard("call", super().call_wait, *args, **kwargs)

    def _guard(self, what: str, fn, *args: Any, **kwargs: Any):  # noqa: ANN001, ANN202
        try:
            return fn(*args, **kwargs)
        except (EOFError, BrokenPipeError, ConnectionResetError) as exc:
            dead = [f"worker {i} (exit code {code})" for i, code in self._dead_workers()]
            who = ", ".join(dead) if dead else "a worker"
            self._abandon()
            raise PriqnError(
                f"vector env {what}: {who} died (SUMO crashed or the process was killed); "
                "the vector env is closed, make a new one"
            ) from exc
        except PriqnError:
            self._abandon()
            raise
        except multiprocessing.TimeoutError as exc:
            self._abandon()
            raise PriqnError(
                f"vector env {what}: no answer from the workers within the timeout; closed them"
            ) from exc

    def _dead_workers(self, wait_s: float = DEAD_WORKER_WAIT_S) -> list[tuple[int, int | None]]:
        """``(index, exit code)`` of the workers that ended.

        A broken pipe can be seen before the OS has reaped the process, so wait up to
        ``wait_s`` for at least one worker to end.
        """
        sentinels = {p.sentinel: p for p in self.processes}
        # A process's sentinel is ready when its files are closed, a moment before the
        # OS can report its exit status: join those (a blocking wait for the status).
        for sentinel in multiprocessing.connection.wait(list(sentinels), timeout=wait_s):
            sentinels[sentinel].join(timeout=wait_s)
        return [(i, p.exitcode) for i, p in enumerate(self.processes) if p.exitcode is not None]

    def _raise_if_errors(self, successes: Iterable[bool]) -> None:
        """Raise the workers' errors naming the worker (replaces gymnasium's, which logs tracebacks)."""
        successes = list(successes)
        if all(successes):
            return
        errors = []
        for _ in range(len(successes) - sum(successes)):
            index, exctype, value, trace = self.error_queue.get()
            self.parent_pipes[index].close()
            self.parent_pipes[index] = None
            errors.append((index, exctype, value, trace))
        self._state = AsyncState.DEFAULT
        index, exctype, value, trace = min(errors, key=lambda e: e[0])
        if issubclass(exctype, PriqnError):
            raise PriqnError(f"vector env worker {index}: {value}")
        sys.stderr.write(f"vector env worker {index} raised:\n{trace}")
        try:
            exc = exctype(f"vector env worker {index}: {value}")
        except Exception:  # noqa: BLE001 - an exception type with an unusual constructor
            exc = RuntimeError(f"vector env worker {index}: {exctype.__name__}: {value}")
        raise exc

    def _abandon(self) -> None:
        """Kill the remaining workers without waiting on a dead pipe."""
        for p in self.processes:
            if p.is_alive():
                p.terminate()
        for p in self.processes:
            p.join(timeout=5)
        self.closed = True

    def close_extras(self, timeout: float | None = None, terminate: bool = False) -> None:
        if all(not p.is_alive() for p in self.processes):
            return
        try:
            super().close_extras(timeout=timeout, terminate=terminate)
        except (EOFError, BrokenPipeError, ConnectionResetError, OSError):
            self._abandon()


def worker_seeds(seed: int, num_envs: int) -> list[int]:
    """The first-episode seed of each worker: children of ``SeedSequence(seed)``."""
    children = np.random.SeedSequence(int(seed)).spawn(int(num_envs))
    return [int(c.generate_state(1, dtype=np.uint32)[0]) for c in children]


def make_vector_env(
    config: Any = None,
    num_envs: int = 2,
    seed: int = 0,
    render_mode: str | None = None,
    preload: bool = False,
) -> PriqnVectorEnv:
    """``num_envs`` :class:`~priqn.env.intersection.IntersectionEnv` in spawned worker processes.

    ``config`` is an :class:`~priqn.env.config.EnvConfig` (None = defaults). Call
    ``reset()`` without a seed to use the per-worker seeds derived from ``seed``
    (:func:`worker_seeds`); ``reset(seed=s)`` reseeds worker i with ``s + i`` as gymnasium
    does. Rewards come out ``float32 [num_envs, N]`` (N = ``len(config.objectives)``).
    ``preload``: every worker parses its nets and loads the sensors' compiled loops now
    (``preload_nets``, no random draw), not at its first resets, where the vector step would
    wait for the slowest worker's.
    """
    if not isinstance(num_envs, int) or num_envs < 1:
        raise PriqnError(f"num_envs: expected an integer >= 1, got {num_envs!r}")
    venv = _vector_env(config, worker_seeds(seed, num_envs), render_mode)
    if preload:
        try:
            venv.call("preload_nets")
        except BaseException:
            venv.close()
            raise
    return venv


def _vector_env(config: Any, seeds: list[int], render_mode: str | None) -> PriqnVectorEnv:
    """One :class:`PriqnVectorEnv` whose worker ``i`` starts from ``seeds[i]``."""
    if config is None:
        from priqn.env.config import EnvConfig  # pure-python; no SUMO import

        config = EnvConfig()
    fns = [_EnvFactory(config, s, render_mode) for s in seeds]
    venv = PriqnVectorEnv(
        fns,
        context="spawn",
        autoreset_mode=AutoresetMode.SAME_STEP,
        daemon=True,
        shared_memory=True,
    )
    venv.objectives = tuple(config.objectives)  # the reward vector's entries, in order
    return venv


class EnvGroups:
    """The ``num_envs`` env workers as ``groups`` vector envs of ``num_envs // groups`` each,
    which the training loop steps in turn (``env_groups``): while one group simulates, the
    loop collects, learns from and acts for another.

    Worker ``i`` (group ``i // size``) starts from the seed it has in
    :func:`make_vector_env` with the same ``seed`` and ``num_envs``; ``reset(seed=s)``
    reseeds it with ``s + i``. Whole-vector calls (``reset``, ``call``, ``set_attr``,
    ``close``) take and return every worker in that order, so a checkpoint's episodes in
    flight and :func:`restore_episodes` do not know the grouping.
    """

    def __init__(
        self, config: Any, num_envs: int, groups: int, seed: int = 0, preload: bool = False
    ) -> None:
        if groups < 1 or num_envs % groups:
            raise PriqnError(
                f"env_groups: expected a divisor of num_envs ({num_envs}), got {groups}"
            )
        self.num_envs, self.size = int(num_envs), int(num_envs) // int(groups)
        seeds = worker_seeds(seed, num_envs)
        self.groups: list[PriqnVectorEnv] = []
        try:
            for lo in range(0, self.num_envs, self.size):
                self.groups.append(_vector_env(config, seeds[lo : lo + self.size], None))
        except BaseException:
            self.close()
            raise
        first = self.groups[0]
        self.single_observation_space = first.single_observation_space
        self.single_action_space = first.single_action_space
        self.objectives = first.objectives
        self.rows = [slice(lo, lo + self.size) for lo in range(0, self.num_envs, self.size)]
        """Group ``g``'s workers as a slice of every ``[num_envs, ...]`` array."""
        if preload:  # as make_vector_env's preload
            try:
                self.call("preload_nets")
            except BaseException:
                self.close()
                raise

    def reset(self, seed: int | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Every worker's first observation (``[num_envs, ...]`` per key) and the groups' infos."""
        parts = [
            g.reset(seed=None if seed is None else seed + rows.start)
            for g, rows in zip(self.groups, self.rows, strict=True)
        ]
        obs = {k: np.concatenate([o[k] for o, _ in parts]) for k in parts[0][0]}
        return obs, {"groups": [info for _, info in parts]}

    def call(self, name: str) -> tuple[Any, ...]:
        """``name`` called on every worker, in worker order."""
        return tuple(x for g in self.groups for x in g.call(name))

    def set_attr(self, name: str, values: Sequence[Any]) -> None:
        """Set ``name`` on worker ``i`` to ``values[i]``."""
        values = list(values)
        for g, rows in zip(self.groups, self.rows, strict=True):
            g.set_attr(name, values[rows])

    def close(self) -> None:
        for g in self.groups:
            g.close()


def restore_episodes(venv: Any, records: Any) -> dict[str, np.ndarray]:
    """Each worker plays again the episode of its record (``IntersectionEnv.episode_record``,
    one per worker, in order) and the batched observations they stand at come back
    (``[num_envs, ...]`` per key): how a training resume continues the episodes in flight."""
    records = list(records)
    if len(records) != venv.num_envs:
        raise PriqnError(f"restore_episodes: {len(records)} records for {venv.num_envs} workers")
    venv.set_attr("pending_episode", records)
    obs = venv.call("restore_pending_episode")
    return {k: np.stack([o[k] for o in obs]) for k in obs[0]}


def make_vec(
    num_envs: int = 2,
    config: Any = None,
    seed: int = 0,
    render_mode: str | None = None,
    **overrides: Any,
) -> PriqnVectorEnv:
    """``gymnasium.make_vec("priqn/Intersection-v0", num_envs=N, ...)`` (vector entry point).

    The process-isolated vector env of :func:`make_vector_env` (gymnasium's default mode
    here). ``vectorization_mode="async"`` works too, with ``SAME_STEP`` autoreset, and
    ``"sync"`` is refused (:func:`fit_gymnasium_vectorizer`). ``config`` and keyword
    overrides are as for the single env; ``seed`` derives every worker's seeds.
    """
    from priqn.env.intersection import make_config  # pure-python; no SUMO import

    return make_vector_env(make_config(config, overrides), num_envs, seed, render_mode)


def make_env(*args: Any, **kwargs: Any):  # noqa: ANN201 - returns an IntersectionEnv
    """``gymnasium.make("priqn/Intersection-v0", ...)`` (entry point): an ``IntersectionEnv``.

    Same arguments as :class:`~priqn.env.intersection.IntersectionEnv`; first
    :func:`fit_gymnasium_vectorizer`, as ``gymnasium.make_vec``'s ``"sync"`` and
    ``"async"`` modes make their envs through here.
    """
    fit_gymnasium_vectorizer()
    from priqn.env.intersection import IntersectionEnv

    return IntersectionEnv(*args, **kwargs)


# IntersectionEnv.metadata: gymnasium.make reads the render modes before it makes the env.
make_env.metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 2}  # type: ignore[attr-defined]

GYMNASIUM_SYNC_REFUSED = (
    "gymnasium.make_vec('priqn/Intersection-v0', vectorization_mode='sync') cannot run this "
    "env: libsumo runs one SUMO simulation per process and SyncVectorEnv keeps one number "
    "per env as the reward; leave vectorization_mode out (worker processes) or use 'async'"
)
NEXT_STEP_REFUSED = (
    "gymnasium.make_vec('priqn/Intersection-v0', vectorization_mode='async'): autoreset_mode "
    "NEXT_STEP puts a scalar 0 reward beside the other envs' 5-vector rewards; use "
    "vector_kwargs={'autoreset_mode': AutoresetMode.SAME_STEP} (the default here)"
)


def fit_gymnasium_vectorizer() -> None:
    """Fit the vector env that ``gymnasium.make_vec`` is building around this env, if any.

    gymnasium shows an env nothing of its vectorizer, so this reads the call stack: the
    ``make_vec`` call's arguments and the ``SyncVectorEnv`` / ``AsyncVectorEnv`` whose
    ``__init__`` is making the env. Outside ``make_vec``'s ``"sync"`` / ``"async"`` modes
    (``gymnasium.make``, the default vector entry point, a worker) it does nothing.

    * ``"async"`` without an ``autoreset_mode`` in ``vector_kwargs``: switches the
      ``AsyncVectorEnv`` to ``SAME_STEP`` before it starts its workers (gymnasium's default
      ``NEXT_STEP`` answers a reset step with a scalar 0 reward, and the batch of 5-vectors
      breaks); an explicit ``NEXT_STEP`` is refused in one line unless ``wrappers`` (which
      may make the reward one number) are given.
    * ``"sync"``: refused in one line, unless one env with ``wrappers``: libsumo runs one
      simulation per process and ``SyncVectorEnv`` stores one float reward per env.
    """
    found = _gymnasium_make_vec_call()
    if found is None:
        return
    call, venv = found
    mode = getattr(call.get("vectorization_mode"), "value", call.get("vectorization_mode"))
    wrapped = bool(call.get("wrappers"))
    if mode == "sync" and (call.get("num_envs") != 1 or not wrapped):
        raise PriqnError(GYMNASIUM_SYNC_REFUSED)
    if mode != "async" or not isinstance(venv, AsyncVectorEnv):
        return
    if getattr(venv, "autoreset_mode", None) != AutoresetMode.NEXT_STEP:
        return
    if "autoreset_mode" not in (call.get("vector_kwargs") or {}):
        venv.autoreset_mode = AutoresetMode.SAME_STEP  # read when the workers start
    elif not wrapped:
        raise PriqnError(NEXT_STEP_REFUSED)


def _gymnasium_make_vec_call() -> tuple[dict[str, Any], VectorEnv | None] | None:
    """The locals of the enclosing ``gymnasium.make_vec`` call and the gymnasium vector env
    under construction below it (None when not called from ``make_vec``)."""
    venv = None
    frame = sys._getframe(1)
    try:
        while frame is not None:
            name = frame.f_code.co_name
            if name == "__init__" and venv is None:
                obj = frame.f_locals.get("self")
                if isinstance(obj, VectorEnv):
                    venv = obj
            elif name == "make_vec" and (
                frame.f_globals.get("__name__") == "gymnasium.envs.registration"
            ):
                return dict(frame.f_locals), venv
            frame = frame.f_back
        return None
    finally:
        del frame
