"""Where cells run: a :class:`Backend` protocol, the local process pool and Ray tasks.

Both back-ends start the same child command per cell (:mod:`priqn.sweep.process`), so
they produce the same run folders. ``ray`` is an optional extra (``pip install
'priqn[ray]'``) imported only inside :class:`RayBackend` and :func:`ray_cell`: each cell
becomes one Ray task declaring ``num_cpus`` / ``num_gpus`` from ``[resources]``; the task
starts the child on whichever node Ray picks, so a cell never shares a process with
libsumo from another cell. Results are the run folders the child writes under the runs
folder (on a multi-node cluster: a shared filesystem path, docs/sweeps.md).

Locally, ``gpus_per_cell > 0`` pins each cell to a share of one GPU (or to whole GPUs
when it is 2 or more) through the child's ``CUDA_VISIBLE_DEVICES`` (:class:`GpuShares`),
and the pool runs at most as many cells as the GPUs hold.
"""

from __future__ import annotations

import math
import os
import socket
import sys
import threading
from concurrent import futures
from pathlib import Path
from typing import Any, Protocol

from priqn.errors import PriqnError
from priqn.experiment import ResourceSpec
from priqn.sweep.process import _STOP_GRACE_S, run_cell_process

# --------------------------------------------------------------------------- GPU shares


def gpu_count() -> int:
    """CUDA GPUs this process sees (0 without a CUDA build of torch); tests fake it."""
    try:
        import torch
    except ImportError:  # pragma: no cover - torch is a dependency
        return 0
    return int(torch.cuda.device_count()) if torch.cuda.is_available() else 0


def visible_gpus() -> list[str]:
    """The ids a cell's ``CUDA_VISIBLE_DEVICES`` may name: this process's own
    ``CUDA_VISIBLE_DEVICES`` entries if set, else ``0 .. gpu_count() - 1``."""
    n = gpu_count()
    mine = os.environ.get("CUDA_VISIBLE_DEVICES", "").strip()
    if mine:
        return [x.strip() for x in mine.split(",") if x.strip()][:n]
    return [str(i) for i in range(n)]


class GpuShares:
    """Hands each local cell its GPU(s) as a ``CUDA_VISIBLE_DEVICES`` value.

    ``per_cell <= 1``: every GPU holds ``floor(1 / per_cell)`` cells (0.25: four) and a
    cell gets the GPU with the most free room (ties: the lowest id), so cells spread
    over the GPUs. ``per_cell > 1`` must be a whole number k: the GPUs form
    ``floor(n / k)`` groups of k, one cell per group. Thread-safe.
    """

    def __init__(self, ids: list[str], per_cell: float) -> None:
        if per_cell <= 0:
            raise PriqnError(f"[resources] gpus_per_cell = {per_cell:g}: expected > 0")
        if not ids:
            raise PriqnError(
                f"[resources] gpus_per_cell = {per_cell:g} but this machine has no CUDA GPU "
                "torch can see; set gpus_per_cell = 0 (or --gpus-per-cell 0) or use --ray"
            )
        if per_cell <= 1:
            per_gpu = math.floor(1.0 / per_cell + 1e-9)
            self._free = {gpu: per_gpu for gpu in ids}
        else:
            k = round(per_cell)
            if abs(per_cell - k) > 1e-9:
                raise PriqnError(
                    f"[resources] gpus_per_cell = {per_cell:g}: above 1 a cell takes whole "
                    "GPUs locally; expected a whole number"
                )
            if len(ids) < k:
                raise PriqnError(
                    f"[resources] gpus_per_cell = {k} but this machine has {len(ids)} GPU(s)"
                )
            self._free = {",".join(ids[i : i + k]): 1 for i in range(0, len(ids) - k + 1, k)}
        self.per_cell = per_cell
        self.num_gpus = len(ids)
        self.capacity = sum(self._free.values())
        """Cells the GPUs hold at once."""
        self._order = list(self._free)
        self._lock = threading.Lock()

    def acquire(self) -> str:
        """A free share: the ``CUDA_VISIBLE_DEVICES`` value for one cell."""
        with self._lock:
            gpu = max(self._order, key=lambda g: (self._free[g], -self._order.index(g)))
            if self._free[gpu] < 1:
                raise RuntimeError("GpuShares: no free GPU share (more cells than slots)")
            self._free[gpu] -= 1
            return gpu

    def release(self, gpu: str) -> None:
        """Give back a share from :meth:`acquire`."""
        with self._lock:
            self._free[gpu] += 1


def local_slots(resources: ResourceSpec, cores: int, gpus: GpuShares | None = None) -> int:
    """Cells at a time on one machine: ``max(1, cores // cpus_per_cell)``, and no more than
    ``gpus`` holds (``floor(1 / gpus_per_cell)`` per GPU)."""
    slots = max(1, int(cores // resources.cpus_per_cell))
    return slots if gpus is None else max(1, min(slots, gpus.capacity))


def _run_on_share(
    shares: GpuShares | None,
    spec: dict[str, Any],
    log_path: Path,
    stop: threading.Event,
) -> tuple[int, str, bool]:
    """One local cell on its GPU share (if any), released before the cell counts as done."""
    if shares is None:
        return run_cell_process(spec, log_path, stop)
    gpu = shares.acquire()
    try:
        return run_cell_process({**spec, "cuda_visible_devices": gpu}, log_path, stop)
    finally:
        shares.release(gpu)


# --------------------------------------------------------------------------- back-ends


class Backend(Protocol):
    """What the scheduler needs from a place that runs cells."""

    slots: int | None
    """Cells in flight at most (None: as many as the back-end accepts)."""

    def describe(self) -> str:
        """One line for the sweep's header (``local pool, 1 cell(s) at a time``)."""

    def submit(self, spec: dict[str, Any], log_path: Path) -> Any:
        """Start the cell's child process; returns a handle for :meth:`wait`."""

    def wait(self, handles: list[Any], timeout_s: float) -> list[tuple[Any, int, str, bool]]:
        """``(handle, exit code, log tail, complete)`` of the cells that ended (maybe none)."""

    def cancel(self, handles: list[Any]) -> None:
        """Stop these cells (their children checkpoint and mark their runs interrupted)."""

    def close(self) -> None:
        """Release the back-end (the thread pool, a Ray cluster this sweep started)."""


class LocalBackend:
    """Runs cells as child processes on this machine, ``jobs`` at a time; with ``gpus``,
    each on its GPU share and no more at once than the GPUs hold."""

    def __init__(self, jobs: int, gpus: GpuShares | None = None) -> None:
        self.slots = max(1, jobs if gpus is None else min(jobs, gpus.capacity))
        self._gpus = gpus
        self._stop = threading.Event()
        self._pool = futures.ThreadPoolExecutor(max_workers=self.slots, thread_name_prefix="cell")

    def describe(self) -> str:
        text = f"local pool, {self.slots} cell(s) at a time"
        if self._gpus is not None:
            text += f", {self._gpus.per_cell:g} GPU each on {self._gpus.num_gpus} GPU(s)"
        return text

    def submit(self, spec: dict[str, Any], log_path: Path) -> futures.Future:
        return self._pool.submit(_run_on_share, self._gpus, spec, log_path, self._stop)

    def wait(self, handles: list[Any], timeout_s: float) -> list[tuple[Any, int, str, bool]]:
        done, _ = futures.wait(handles, timeout=timeout_s, return_when=futures.FIRST_COMPLETED)
        out = []
        for h in done:
            try:
                out.append((h, *h.result()))
            except PriqnError as exc:
                out.append((h, 1, str(exc), False))
            except OSError as exc:
                out.append((h, 1, f"could not start the cell process: {exc}", False))
        return out

    def cancel(self, handles: list[Any]) -> None:
        self._stop.set()
        futures.wait(handles, timeout=_STOP_GRACE_S + 10.0)

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


def _import_ray() -> Any:
    try:
        import ray
    except ModuleNotFoundError:
        raise PriqnError(
            "--ray: the 'ray' package is not installed; install it with: pip install 'priqn[ray]'"
        ) from None
    return ray


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """A ``host:port`` / ``ray://host:port`` address must accept a TCP connection.

    Ray itself retries an unreachable head for minutes; this fails in seconds.
    """
    if address in ("auto", "local"):
        return
    hostport = address.removeprefix("ray://").rstrip("/")
    host, sep, port = hostport.rpartition(":")
    if not sep or not port.isdigit():
        raise PriqnError(
            f"--ray {address}: expected auto, HOST:PORT (e.g. head:6379) or ray://HOST:PORT"
        )
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise PriqnError(
            f"--ray {address}: cannot reach a Ray head there ({reason}); is 'ray start --head' "
            "running and the port open?"
        ) from None


def ray_cell(spec: dict[str, Any], log_path: str) -> tuple[int, str, bool]:
    """Body of one cell's Ray task: run the cell's child process on this node.

    Cancelling the task (Ctrl-C in the driver) raises KeyboardInterrupt here, which
    stops the child's process group before the task ends.
    """
    import ray

    # The cell's log names the node that ran it (results from many nodes land in one
    # runs folder; docs/sweeps.md).
    node = ray.get_runtime_context().get_node_id()
    return run_cell_process({**spec, "ray_node": node}, Path(log_path))


class RayBackend:
    """Submits cells as Ray tasks; ``address`` None starts a new local Ray cluster."""

    def __init__(self, address: str | None, resources: ResourceSpec, max_inflight: int | None):
        ray = _import_ray()
        self._ray = ray
        self._owns = False
        if ray.is_initialized():
            pass  # a caller (a notebook, a test) already connected: use that cluster as is
        elif address:
            _check_reachable(address)
            try:
                ray.init(address=address, log_to_driver=False)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                raise PriqnError(
                    f"--ray {address}: cannot connect to a Ray cluster: {msg}"
                ) from None
            self._owns = True
        else:
            ray.init(address="local", include_dashboard=False, log_to_driver=False)
            self._owns = True
        self.address = address or "local"
        self.slots = max_inflight
        self._resources = resources
        self._remote = ray.remote(
            num_cpus=resources.cpus_per_cell,
            num_gpus=resources.gpus_per_cell,
            max_retries=0,  # the sweep retries a failed cell itself, with its log
        )(ray_cell)
        total = ray.cluster_resources()
        self.cluster_cpus = float(total.get("CPU", 0.0))
        self.cluster_gpus = float(total.get("GPU", 0.0))
        if self.cluster_cpus < resources.cpus_per_cell or (
            resources.gpus_per_cell > 0 and self.cluster_gpus < resources.gpus_per_cell
        ):
            need = f"{resources.cpus_per_cell:g} CPU / {resources.gpus_per_cell:g} GPU"
            have = f"{self.cluster_cpus:g} CPU / {self.cluster_gpus:g} GPU"
            msg = (
                f"[resources]: each cell asks for {need} but the Ray cluster has {have} in all; "
                "lower them (--cpus-per-cell / --gpus-per-cell) or add nodes"
            )
            if self._owns and address is None:  # our own local cluster never grows
                ray.shutdown()
                raise PriqnError(msg)
            # An existing cluster may autoscale: submit anyway, Ray holds the tasks.
            print(f"priqn sweep: warning: {msg}; cells wait until nodes join", file=sys.stderr)

    def describe(self) -> str:
        cap = f", at most {self.slots} in flight" if self.slots else ""
        return (
            f"Ray cluster {self.address}: {self.cluster_cpus:g} CPU / {self.cluster_gpus:g} GPU, "
            f"{self._resources.cpus_per_cell:g} CPU / {self._resources.gpus_per_cell:g} GPU per cell{cap}"
        )

    def submit(self, spec: dict[str, Any], log_path: Path) -> Any:
        return self._remote.remote(spec, str(Path(log_path).absolute()))

    def wait(self, handles: list[Any], timeout_s: float) -> list[tuple[Any, int, str, bool]]:
        ray = self._ray
        if not handles:
            return []
        ready, _ = ray.wait(handles, num_returns=1, timeout=timeout_s)
        out = []
        for ref in ready:
            try:
                rc, tail, complete = ray.get(ref)
            except ray.exceptions.RayError as exc:
                # The task itself died (node lost, worker killed): a failed attempt.
                lines = [ln for ln in str(exc).splitlines() if ln.strip()]
                rc, complete = 1, False
                tail = f"Ray task failed: {type(exc).__name__}: {lines[-1] if lines else ''}"
            out.append((ref, rc, tail, complete))
        return out

    def cancel(self, handles: list[Any]) -> None:
        ray = self._ray
        for ref in handles:
            try:
                ray.cancel(ref)  # KeyboardInterrupt in the task: it stops its child first
            except Exception:  # noqa: BLE001 - best effort while shutting down
                pass
        if handles:
            ray.wait(handles, num_returns=len(handles), timeout=_STOP_GRACE_S + 10.0)

    def close(self) -> None:
        if self._owns and self._ray.is_initialized():
            self._ray.shutdown()
