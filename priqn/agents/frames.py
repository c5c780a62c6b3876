"""Where the replay buffer keeps its observations, and how a batch of them reaches the
learner's device: ``replay.storage`` (:data:`REPLAY_STORAGES`).

- ``host`` (default): numpy arrays in host memory. A batch is numpy arrays, which the
  learner copies to its device (:func:`priqn.agents.network.to_tensors`).
- ``pinned``: the same numpy storage; a batch's observations are gathered straight into
  reusable page-locked (pinned) host buffers and copied to the GPU with
  ``non_blocking=True`` (the action, reward and discount too). CUDA only.
- ``device``: torch tensors on the learner's device (GPU memory on CUDA, host memory on
  the CPU); a step's rows are copied in once when stored, and a batch is gathered there.

:class:`~priqn.agents.replay.ReplayBuffer` chooses the rows of a batch with the same numpy
generator, in the same order, whatever the storage, so every storage gives the same
batch values; only where they live and when they cross to the device differ. The action,
reward and flag rows (a few bytes each) stay numpy in every storage: the n-step sums are
computed on the host as before.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

import numpy as np

from priqn.errors import PriqnError

REPLAY_STORAGES: tuple[str, ...] = ("host", "pinned", "device")
"""Values of ``replay.storage`` (module docstring)."""

DEVICE_HEADROOM_BYTES = 1 << 30
"""Memory ``device`` storage leaves free on its device beyond the buffer [B] (the
networks, Adam and the activations of an update need some)."""


def check_storage(storage: str, device: Any) -> None:
    """Refuse, in one line, a storage that cannot run with the learner on ``device``."""
    if storage not in REPLAY_STORAGES:
        raise PriqnError(
            f"replay.storage: unknown {storage!r} (valid: {', '.join(REPLAY_STORAGES)})"
        )
    if storage != "pinned" or getattr(device, "type", device) == "cuda":
        return
    import torch

    if not torch.cuda.is_available():
        raise PriqnError(
            "replay.storage = 'pinned' needs CUDA (page-locked memory speeds up copies to a "
            "GPU) and this machine has none; use 'host' or 'device'"
        )
    raise PriqnError(
        f"replay.storage = 'pinned' copies batches to a GPU, but the learner runs on "
        f"{device}; use 'host' or 'device', or device = 'cuda'"
    )


def make_frames(
    storage: str,
    spec: Mapping[str, tuple[tuple[int, ...], Any]],
    num_envs: int,
    rows: int,
    device: Any = None,
) -> HostFrames:
    """The observation store of ``storage`` for ``num_envs`` rings of ``rows`` rows
    (``device``: the learner's torch device; ``None`` = the CPU)."""
    import torch

    device = torch.device("cpu") if device is None else torch.device(device)
    check_storage(storage, device)
    if storage == "device":
        return DeviceFrames(spec, num_envs, rows, device)
    if storage == "pinned":
        return PinnedFrames(spec, num_envs, rows, device)
    return HostFrames(spec, num_envs, rows)


class HostFrames:
    """``host``: per key a numpy array ``[E, R, ...]``; a batch is numpy arrays."""

    storage = "host"

    def __init__(
        self, spec: Mapping[str, tuple[tuple[int, ...], Any]], num_envs: int, rows: int
    ) -> None:
        self.shapes = {k: (tuple(shape), np.dtype(dt)) for k, (shape, dt) in spec.items()}
        """Per key the shape and dtype of one observation."""
        self.arrays: dict[str, Any] = self._allocate(num_envs, rows)
        """Per key the ring ``[E, R, ...]`` (numpy arrays; torch tensors for ``device``)."""

    def _allocate(self, num_envs: int, rows: int) -> dict[str, Any]:
        return {
            k: np.zeros((num_envs, rows, *shape), dtype=dt)
            for k, (shape, dt) in self.shapes.items()
        }

    def row_nbytes(self) -> int:
        """Bytes of one row (one observation, every key)."""
        return int(sum(int(np.prod(s)) * dt.itemsize for s, dt in self.shapes.values()))

    def write(self, e_W: np.ndarray, r_W: np.ndarray, obs_W: Mapping[str, np.ndarray]) -> None:
        """Store observation ``w`` of ``obs_W`` (keys → ``[W, ...]``) at env ``e_W[w]``, row
        ``r_W[w]`` (distinct places)."""
        for k, a in self.arrays.items():
            a[e_W, r_W] = obs_W[k]

    def batch(
        self, e_B: np.ndarray, r0_B: np.ndarray, r1_B: np.ndarray, rest: Mapping[str, np.ndarray]
    ) -> dict[str, Any]:
        """The batch of :meth:`ReplayBuffer.sample`: ``obs`` at rows ``(e_B, r0_B)``,
        ``next_obs`` at ``(e_B, r1_B)``, then ``rest`` (action, reward, discount)."""
        return {
            "obs": {k: a[e_B, r0_B] for k, a in self.arrays.items()},
            "next_obs": {k: a[e_B, r1_B] for k, a in self.arrays.items()},
            **rest,
        }


class DeviceFrames(HostFrames):
    """``device``: per key a torch tensor ``[E, R, ...]`` on ``device``; a batch's
    observations are tensors there (gathered with the same row indices)."""

    storage = "device"

    def __init__(
        self,
        spec: Mapping[str, tuple[tuple[int, ...], Any]],
        num_envs: int,
        rows: int,
        device: Any,
    ) -> None:
        self.device = device
        super().__init__(spec, num_envs, rows)

    def _allocate(self, num_envs: int, rows: int) -> dict[str, Any]:
        import torch

        check_fits(num_envs * rows * self.row_nbytes(), self.device)
        return {
            k: torch.zeros((num_envs, rows, *shape), dtype=_torch_dtype(dt), device=self.device)
            for k, (shape, dt) in self.shapes.items()
        }

    def write(self, e_W: np.ndarray, r_W: np.ndarray, obs_W: Mapping[str, np.ndarray]) -> None:
        """As :meth:`HostFrames.write`: one copy to the device per key and step."""
        import torch

        e, r = (torch.as_tensor(x, device=self.device) for x in (e_W, r_W))
        for k, a in self.arrays.items():
            a[e, r] = torch.as_tensor(np.ascontiguousarray(obs_W[k])).to(self.device, a.dtype)

    def batch(
        self, e_B: np.ndarray, r0_B: np.ndarray, r1_B: np.ndarray, rest: Mapping[str, np.ndarray]
    ) -> dict[str, Any]:
        import torch

        # Rows of the flattened rings [E·R, ...]: index_select copies whole rows (40x
        # faster than a[e, r] on the CPU at 64 px), with the same values.
        rows = self.arrays[next(iter(self.arrays))].shape[1]
        i0, i1 = (torch.as_tensor(e_B * rows + r, device=self.device) for r in (r0_B, r1_B))
        flat = {k: a.view(-1, *a.shape[2:]) for k, a in self.arrays.items()}
        return {
            "obs": {k: a.index_select(0, i0) for k, a in flat.items()},
            "next_obs": {k: a.index_select(0, i1) for k, a in flat.items()},
            **rest,
        }


class PinnedFrames(HostFrames):
    """``pinned``: numpy storage as ``host``; a batch is gathered into page-locked staging
    buffers (``np.take(..., out=)``, the same values as ``host``'s fancy indexing) and
    copied to ``device`` with ``non_blocking=True``.

    Two sets of staging buffers take turns; before one is filled again, the copies that
    last read it have finished (a CUDA event each), so a batch never sees the next one's
    rows. ``pin=False`` stages in ordinary memory (what the CPU tests check: the values).
    """

    storage = "pinned"

    def __init__(
        self,
        spec: Mapping[str, tuple[tuple[int, ...], Any]],
        num_envs: int,
        rows: int,
        device: Any,
        pin: bool = True,
    ) -> None:
        super().__init__(spec, num_envs, rows)
        self.device, self.pin = device, pin
        self._slots: list[dict[str, Any]] = [{}, {}]
        """Per slot: name → staging tensor, and ``"event"``: the CUDA event of its copies."""
        self._turn = 0

    def batch(
        self, e_B: np.ndarray, r0_B: np.ndarray, r1_B: np.ndarray, rest: Mapping[str, np.ndarray]
    ) -> dict[str, Any]:
        slot = self._slots[self._turn]
        self._turn = 1 - self._turn
        event = slot.pop("event", None)
        if event is not None:
            event.synchronize()  # the copies that last read this slot are done
        staged: dict[str, Any] = {"obs": {}, "next_obs": {}}
        for part, r_B in (("obs", r0_B), ("next_obs", r1_B)):
            for k, a in self.arrays.items():
                flat = a.reshape(a.shape[0] * a.shape[1], *a.shape[2:])  # a view
                out = self._buffer(slot, f"{part}.{k}", (len(e_B), *a.shape[2:]), a.dtype)
                # every index is in range: "clip" only spares np.take a buffered copy
                np.take(flat, e_B * a.shape[1] + r_B, axis=0, out=out.numpy(), mode="clip")
                staged[part][k] = out
        for name, value in rest.items():
            value = np.asarray(value)
            out = self._buffer(slot, name, value.shape, value.dtype)
            np.copyto(out.numpy(), value)
            staged[name] = out
        batch = {
            "obs": {k: self._send(v) for k, v in staged["obs"].items()},
            "next_obs": {k: self._send(v) for k, v in staged["next_obs"].items()},
            **{name: self._send(staged[name]) for name in rest},
        }
        if self.device.type == "cuda":
            import torch

            slot["event"] = torch.cuda.Event()
            slot["event"].record()  # after the copies, on the current stream
        return batch

    def _buffer(self, slot: dict[str, Any], name: str, shape: tuple[int, ...], dt: Any) -> Any:
        """Slot ``slot``'s staging tensor ``name`` of ``shape`` (made again when it changes)."""
        import torch

        out = slot.get(name)
        if out is None or tuple(out.shape) != tuple(shape) or out.numpy().dtype != dt:
            out = torch.empty(shape, dtype=_torch_dtype(np.dtype(dt)), pin_memory=self.pin)
            slot[name] = out
        return out

    def _send(self, staged: Any) -> Any:
        """A copy of ``staged`` on the device, asynchronous from pinned memory."""
        return staged.to(self.device, non_blocking=True, copy=True)


def _torch_dtype(dt: np.dtype) -> Any:
    """The torch dtype of numpy dtype ``dt``."""
    import torch

    return torch.from_numpy(np.zeros(0, dtype=dt)).dtype


def available_bytes(device: Any) -> int:
    """Memory free for new allocations on ``device`` [B]: CUDA's free memory, or the
    host's available memory (``MemAvailable``; the physical pages free where /proc is
    missing)."""
    if device.type == "cuda":
        import torch

        return int(torch.cuda.mem_get_info(device)[0])
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))


def check_fits(nbytes: int, device: Any) -> None:
    """Refuse, in one line, ``device`` storage of ``nbytes`` that would not fit there with
    :data:`DEVICE_HEADROOM_BYTES` to spare."""
    free = available_bytes(device)
    if nbytes + DEVICE_HEADROOM_BYTES > free:
        raise PriqnError(
            f"replay.storage = 'device': the buffer needs {nbytes / 1e9:.1f} GB on {device}, "
            f"which has {free / 1e9:.1f} GB free (1 GiB kept for the learner); lower "
            "replay.capacity or use replay.storage = 'host'"
        )


def host_view(rows: Any) -> np.ndarray:
    """``rows`` of a store as numpy: itself (numpy), a view (a CPU tensor) or a host copy
    (a GPU tensor); what the replay files are written from."""
    if isinstance(rows, np.ndarray):
        return rows
    return rows.cpu().numpy()


def assign(dst: Any, src: np.ndarray) -> None:
    """``dst[...] = src``: ``dst`` a numpy array, or a torch tensor (view) on any device."""
    if isinstance(dst, np.ndarray):
        dst[...] = src
        return
    import torch

    dst.copy_(torch.from_numpy(np.ascontiguousarray(src)))
