"""Replay buffer that stores each observation once, as uint8 where the env gives uint8.

Layout: one ring of rows per env worker (``[E, R, ...]``, ``R = capacity // E``). Row
``p`` holds the observation o_p and, if it starts a transition, the action, the reward
vector and the end flags. The next state of a transition is simply the next row of the
same env, so a frame is stored once, not twice. When an episode ends (SAME_STEP
autoreset), the true final observation (``infos["final_obs"]``) is written as an extra
row that starts no transition, and the reset observation follows it.

n-step returns are assembled at sampling time: Σ_{k<m} γ^k r_{p+k} over the m ≤ n
steps before the episode ends, bootstrapped from row p+m with discount γ^m (0 when
the episode terminated; a truncation — timeout — still bootstraps).

Where the observations live (numpy on the host, or torch tensors on the learner's
device) and how a batch reaches the device is the ``storage``
(:mod:`priqn.agents.frames`); the rows a batch holds do not depend on it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from priqn.agents.frames import assign, host_view, make_frames
from priqn.objectives import NUM_OBJECTIVES


class ReplayBuffer:
    """Per-env rings of observations; :meth:`sample` returns n-step transitions."""

    def __init__(
        self,
        obs_spec: Mapping[str, tuple[tuple[int, ...], Any]],
        num_envs: int,
        capacity: int,
        n_step: int = 1,
        gamma: float | Sequence[float] = 0.99,
        num_objectives: int = NUM_OBJECTIVES,
        storage: str = "host",
        device: Any = None,
    ) -> None:
        """``storage``: ``replay.storage`` (:data:`~priqn.agents.frames.REPLAY_STORAGES`);
        ``device``: the learner's torch device (``None``: the CPU)."""
        if capacity < 2 * num_envs:
            raise ValueError(f"replay capacity {capacity} too small for {num_envs} envs")
        if n_step < 1:
            raise ValueError("n_step must be >= 1")
        self.num_envs = int(num_envs)
        self.rows = int(capacity) // self.num_envs
        self.n_step = int(n_step)
        self.num_objectives = int(num_objectives)
        """O: length of the reward vector (the run's objectives)."""
        # γ per objective [O] (a number applies to all): the n-step sum discounts each
        # reward component with its own γ_i and the bootstrap discount is γ_i^m.
        self.gamma_O = np.broadcast_to(
            np.asarray(gamma, dtype=np.float64), (self.num_objectives,)
        ).copy()
        E, R = self.num_envs, self.rows
        self.frames = make_frames(storage, obs_spec, E, R, device)
        """The observations' store (its ``arrays``: per key the ring ``[E, R, ...]``)."""
        self.action = np.zeros((E, R), dtype=np.int64)
        self.reward = np.zeros((E, R, self.num_objectives), dtype=np.float32)
        self.starts = np.zeros((E, R), dtype=bool)
        """Row starts a transition (False for final-observation rows)."""
        self.ended = np.zeros((E, R), dtype=bool)
        """The transition starting at this row ended its episode (terminated or truncated)."""
        self.terminated = np.zeros((E, R), dtype=bool)
        self.written = np.zeros(E, dtype=np.int64)
        """Rows written so far per env (absolute position of the next row)."""

    @property
    def obs(self) -> dict[str, Any]:
        """Per observation key the ring ``[E, R, ...]`` (numpy arrays; torch tensors on the
        learner's device with ``storage = "device"``)."""
        return self.frames.arrays

    # ------------------------------------------------------------------ writing

    def _claim_row(self, e: int) -> int:
        """Env ``e``'s next ring row, its flags cleared (``written`` counts it)."""
        r = int(self.written[e] % self.rows)
        self.starts[e, r] = False
        self.ended[e, r] = False
        self.terminated[e, r] = False
        self.written[e] += 1
        return r

    def _write_row(self, e: int, obs: Mapping[str, np.ndarray]) -> int:
        """Store one observation (keys → one row) as env ``e``'s next row, starting none."""
        r = self._claim_row(e)
        row = {k: np.asarray(obs[k])[None] for k in self.frames.shapes}
        self.frames.write(np.array([e]), np.array([r]), row)
        return r

    def add(
        self,
        obs: Mapping[str, np.ndarray],
        actions_E: np.ndarray,
        rewards_EO: np.ndarray,
        terminated_E: np.ndarray,
        truncated_E: np.ndarray,
        final_obs: Sequence[Mapping[str, np.ndarray] | None],
        envs: slice = slice(None),
    ) -> None:
        """Store one vector-env step: batched ``obs`` (keys → ``[E, ...]``) and what followed,
        for the envs ``envs`` (every env, or one group's slice of them: ``E`` rows).

        ``final_obs[e]`` is the true last observation of the ``e``-th of them when its
        episode ended in this step (SAME_STEP autoreset puts the reset observation in the
        next ``obs``).
        """
        e_E = np.arange(self.num_envs)[envs]
        r_E = np.array([self._claim_row(e) for e in e_E.tolist()], dtype=np.int64)
        self.frames.write(e_E, r_E, obs)  # every env's row at once (one copy per key)
        end_E = np.logical_or(terminated_E, truncated_E)
        self.action[e_E, r_E] = actions_E
        self.reward[e_E, r_E] = rewards_EO
        self.starts[e_E, r_E] = True
        self.ended[e_E, r_E] = end_E
        self.terminated[e_E, r_E] = terminated_E
        for i in np.flatnonzero(end_E).tolist():
            if final_obs[i] is None:
                raise ValueError(f"env {int(e_E[i])} ended without a final observation")
            self._write_row(int(e_E[i]), final_obs[i])

    def truncate_open_episodes(self, next_obs: Mapping[str, np.ndarray]) -> None:
        """End every env's open episode here (a resume): its last transition is truncated
        and bootstraps from ``next_obs[e]``, the observation that followed it."""
        for e in range(self.num_envs):
            if self.written[e] == 0:
                continue
            r = int((self.written[e] - 1) % self.rows)
            if self.starts[e, r] and not self.ended[e, r]:
                self.ended[e, r] = True
                self._write_row(e, {k: next_obs[k][e] for k in self.frames.shapes})

    # ------------------------------------------------------------------ reading

    def __len__(self) -> int:
        """Transitions stored (rows that start one and are still in the buffer)."""
        return int(self.starts.sum())

    def bytes_per_row(self) -> int:
        """Memory of one row (one observation + action, reward and flags), in bytes."""
        return int(self.frames.row_nbytes() + 8 + 4 * self.num_objectives + 3)

    def nbytes(self) -> int:
        """Memory held by the buffer's arrays (on the host and on the device), in bytes."""
        arrays = [self.action, self.reward, self.starts, self.ended, self.terminated]
        obs = self.num_envs * self.rows * self.frames.row_nbytes()
        return int(obs + sum(a.nbytes for a in arrays))

    def sample(self, batch_size: int, rng: np.random.Generator) -> dict[str, Any]:
        """``batch_size`` n-step transitions, uniform over stored ones.

        Returns ``obs`` / ``next_obs`` (dicts of ``[B, ...]``), ``action [B]``, ``reward
        [B, O]`` (n-step discounted sum), ``discount [B, O]`` (γ_i^m per objective, 0 if
        terminated); ``O`` = ``num_objectives``. Numpy arrays with ``storage = "host"``;
        ``"device"``: the observations are torch tensors on the device (the rest numpy);
        ``"pinned"``: everything is torch tensors on the device, copied asynchronously.
        The values are the same in every storage.
        """
        lo = np.maximum(self.written - self.rows, 0)
        avail = self.written - lo
        if avail.sum() < 2:
            raise ValueError("replay buffer is empty")
        env_p = avail / avail.sum()
        picks_e: list[np.ndarray] = []
        picks_p: list[np.ndarray] = []
        got = 0
        for _ in range(1000):
            m = 2 * (batch_size - got) + 8
            e = rng.choice(self.num_envs, size=m, p=env_p)
            p = lo[e] + (rng.random(m) * avail[e]).astype(np.int64)
            ok = self._complete(e, p) & self.starts[e, p % self.rows]
            picks_e.append(e[ok])
            picks_p.append(p[ok])
            got += int(ok.sum())
            if got >= batch_size:
                break
        else:
            raise ValueError("replay buffer holds no complete transition yet")
        e = np.concatenate(picks_e)[:batch_size]
        p = np.concatenate(picks_p)[:batch_size]
        return self._gather(e, p)

    def _complete(self, e: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Rows whose n-step window (up to the episode end) is fully written."""
        ok = np.ones(len(p), dtype=bool)
        alive = np.ones(len(p), dtype=bool)
        for k in range(self.n_step):
            q = p + k
            ok &= ~alive | (q + 1 < self.written[e])
            alive &= ~self.ended[e, q % self.rows]
        return ok

    def _gather(self, e: np.ndarray, p: np.ndarray) -> dict[str, Any]:
        B = len(p)
        reward = np.zeros((B, self.num_objectives), dtype=np.float32)
        disc = np.ones((B, self.num_objectives), dtype=np.float64)
        alive = np.ones(B, dtype=bool)
        done = np.zeros(B, dtype=bool)
        nxt = p + self.n_step
        for k in range(self.n_step):
            r = (p + k) % self.rows
            reward += (alive[:, None] * disc).astype(np.float32) * self.reward[e, r]
            end = alive & self.ended[e, r]
            done |= end & self.terminated[e, r]
            nxt = np.where(end, p + k + 1, nxt)
            disc = np.where(alive[:, None], disc * self.gamma_O, disc)
            alive &= ~end
        r0, r1 = p % self.rows, nxt % self.rows
        rest = {
            "action": self.action[e, r0],
            "reward": reward,
            "discount": np.where(done[:, None], 0.0, disc).astype(np.float32),
        }
        return self.frames.batch(e, r0, r1, rest)

    # ------------------------------------------------------------------ persistence

    def save_to(self, fh: Any) -> None:
        """Write the buffer as an uncompressed ``.npz`` into the open binary ``fh``.

        Only rows written so far are saved (a young buffer makes a small file).
        """
        used = int(min(self.written.max(), self.rows))
        arrays = {f"obs.{k}": host_view(a[:, :used]) for k, a in self.obs.items()}
        for name in _ROW_ARRAYS:
            arrays[name] = getattr(self, name)[:, :used]
        arrays["written"] = self.written
        np.savez(fh, **arrays)

    def save_rows(self, fh: Any, since_E: Any) -> np.ndarray:
        """Write, compressed, the rows written since ``since_E`` (per env, the absolute
        positions :attr:`written` had at the previous save; zeros for the first) into the
        open binary ``fh``; returns :attr:`written` now (the next save's ``since_E``).

        One zip of zstd-compressed ``.npy`` members (:func:`write_arrays`): ``end`` ``[E]``,
        ``segments`` ``[S, 3]`` (env, first, last + 1 absolute row of each stretch that does
        not wrap around the ring) and each segment's
        rows of every array (``obs.<key>.<s>``, ``action.<s>``, ...), written from views of
        the ring, streamed (no copy of the rows). Rows the ring has overwritten since are
        left out. :meth:`load_rows` applies such files in the order they were written. BEV
        and LiDAR rasters are mostly empty: 24,576 bytes a row at 64 px become about 450
        (docs/implementation-details.md §8, ``priqn bench replay``)."""
        since = np.asarray(since_E, dtype=np.int64)
        start = np.maximum(since, self.written - self.rows)
        segments = [
            (e, lo, hi)
            for e in range(self.num_envs)
            for lo, hi in _pieces(int(start[e]), int(self.written[e]), self.rows)
        ]
        arrays: dict[str, np.ndarray] = {
            "end": self.written.copy(),
            "segments": np.asarray(segments, dtype=np.int64).reshape(-1, 3),
        }
        for s, (e, lo, hi) in enumerate(segments):
            rows = slice(lo % self.rows, lo % self.rows + hi - lo)
            for k, a in self.obs.items():
                arrays[f"obs.{k}.{s}"] = host_view(a[e, rows])
            for name in _ROW_ARRAYS:
                arrays[f"{name}.{s}"] = getattr(self, name)[e, rows]
        write_arrays(fh, arrays)
        return arrays["end"]

    def load_rows(self, path: Any) -> None:
        """Apply one file of :meth:`save_rows` (same env count and row shapes)."""
        with ArrayFile(path) as data:
            end, segments = data["end"], data["segments"]
            if end.shape != (self.num_envs,):
                raise ValueError(f"replay rows: saved for {end.shape[0]} envs, not {self.num_envs}")
            for s, (e, lo, hi) in enumerate(segments.tolist()):
                rows = slice(lo % self.rows, lo % self.rows + hi - lo)
                for k, a in self.obs.items():
                    _put(a[e, rows], data[f"obs.{k}.{s}"], f"obs.{k}")
                for name in _ROW_ARRAYS:
                    _put(getattr(self, name)[e, rows], data[f"{name}.{s}"], name)
            self.written[:] = np.maximum(self.written, end)

    def overwritten(self, end_E: Any) -> bool:
        """Every row written before ``end_E`` (per env) has been overwritten in the ring."""
        return bool(np.all(np.asarray(end_E) <= self.written - self.rows))

    def load_state_file(self, path: Any) -> None:
        """Restore from a file written by :meth:`save_to` (same env count and row shapes)."""
        with np.load(path) as data:
            self._copy(self.written, data["written"], "written")
            for k in self.obs:
                self._copy(self.obs[k], data[f"obs.{k}"], f"obs.{k}")
            for name in _ROW_ARRAYS:
                self._copy(getattr(self, name), data[name], name)

    @staticmethod
    def _copy(dst: Any, src: np.ndarray, name: str) -> None:
        """Copy saved rows ``src`` into the front of ``dst`` (rows may be fewer; ``dst`` a
        numpy array or a torch tensor)."""
        shape = tuple(dst.shape)
        if len(shape) != src.ndim or shape[:1] != src.shape[:1] or shape[2:] != src.shape[2:]:
            raise ValueError(f"replay {name}: saved shape {src.shape} does not fit {shape}")
        if len(shape) == 1:
            assign(dst, src)
        elif src.shape[1] > shape[1]:
            raise ValueError(f"replay {name}: saved {src.shape[1]} rows > capacity {shape[1]}")
        else:
            assign(dst[:, : src.shape[1]], src)


_ROW_ARRAYS = ("action", "reward", "starts", "ended", "terminated")
"""The per-row arrays beside the observations (every file format writes them in this order)."""


ZSTD_LEVEL = 3
"""zstd level of the replay files: as small as zlib's level 6 on our rasters, 6x as fast
(measured on 1,200 real observations at 64 and 128 px, docs/implementation-details.md §8)."""


def write_arrays(fh: Any, arrays: Mapping[str, np.ndarray]) -> None:
    """Write ``arrays`` into the open binary ``fh``: a zip (stored) whose member
    ``<name>.npy.zst`` is the array's ``.npy`` bytes compressed with zstd, streamed in
    chunks (no whole copy of an array). :class:`ArrayFile` reads it."""
    import zipfile

    import zstandard

    compressor = zstandard.ZstdCompressor(level=ZSTD_LEVEL)
    with zipfile.ZipFile(fh, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name, array in arrays.items():
            with zf.open(f"{name}.npy.zst", "w", force_zip64=True) as member:
                with compressor.stream_writer(member, closefd=False) as out:
                    np.lib.format.write_array(out, np.asanyarray(array), allow_pickle=False)


class ArrayFile:
    """The arrays of a :func:`write_arrays` file, read one by one: ``data[name]`` (a
    damaged member is a ValueError, a missing one a KeyError, as with ``np.load``)."""

    def __init__(self, path: Any) -> None:
        import zipfile

        self._zip = zipfile.ZipFile(path)

    def __getitem__(self, name: str) -> np.ndarray:
        import zstandard

        try:
            with self._zip.open(f"{name}.npy.zst") as member:
                with zstandard.ZstdDecompressor().stream_reader(member) as raw:
                    return np.lib.format.read_array(raw, allow_pickle=False)
        except zstandard.ZstdError as exc:  # a damaged member: as numpy's own errors
            raise ValueError(f"{name}: {exc}") from None

    def __enter__(self) -> ArrayFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self._zip.close()


def _pieces(lo: int, hi: int, rows: int) -> list[tuple[int, int]]:
    """Absolute rows ``lo:hi`` cut where they wrap around a ring of ``rows``."""
    out = []
    while lo < hi:
        cut = min(hi, (lo // rows + 1) * rows)
        out.append((lo, cut))
        lo = cut
    return out


def _put(dst: Any, src: np.ndarray, name: str) -> None:
    """``dst[...] = src`` for one segment's rows (``dst`` a numpy array or a torch tensor),
    refusing saved rows of another shape."""
    if src.shape != tuple(dst.shape):
        raise ValueError(f"replay {name}: saved rows {src.shape} do not fit {tuple(dst.shape)}")
    assign(dst, src)
