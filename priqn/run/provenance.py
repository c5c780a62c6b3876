"""Where a training session comes from: what its run folder records about its origin.

:func:`gather` asks the layers that own each fact — the scenario manifests
(:mod:`priqn.sim.scenario`), your own nets (:mod:`priqn.env.scenes`,
:mod:`priqn.sim.roadmap`), SUMO (:mod:`priqn.sim.sumo`), git and the installed packages —
and returns a :class:`priqn.run.folder.Provenance`, which :func:`priqn.train.train` hands to
:func:`priqn.run.session.start_session`; the run folder only writes it. Everything here
that can refuse a run (a family without generated nets, a net that cannot be used) runs
before the run folder is touched.
"""

from __future__ import annotations

import os
import platform
import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from priqn.io import sha256_file
from priqn.run.folder import Provenance


def gather(cfg: Any) -> Provenance:
    """The provenance of a session training ``cfg`` (a :class:`~priqn.run.train_config.TrainConfig`):
    git commit, versions, the manifest hash of every family it reads and, with ``env.nets``,
    the manifest of those nets (its hash under ``"own"``)."""
    from priqn.run.train_config import pool_families
    from priqn.sim.scenario import hash_of_manifest

    pool = set() if cfg.env.nets else set(pool_families(cfg.env.family))
    hashes = manifest_hashes(sorted(pool | {cfg.evaluation.family}), cfg.env.nets_dir)
    own_nets = own_nets_manifest(cfg.env.nets, cfg.env.junction) if cfg.env.nets else None
    if own_nets is not None:
        hashes["own"] = hash_of_manifest(own_nets)
    return Provenance(
        git_sha=git_sha(), versions=versions(), manifest_hashes=hashes, own_nets=own_nets
    )


def git_sha(root: Path | None = None) -> str:
    """The git commit (``-dirty`` if changed) of the checkout at ``root`` (default: this
    priqn's); "not a checkout" if installed."""
    from priqn.paths import PACKAGE_DIR

    root = Path(root) if root is not None else PACKAGE_DIR.parent
    if not (root / ".git").exists():
        return "not a checkout"
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=10
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=10,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return (sha or "unknown") + ("-dirty" if dirty else "")


SIMD_LEVELS = ("avx512f", "avx2", "avx", "sse4_2")
"""CPU flags naming the widest vector unit, widest first: torch's CPU kernels pick their
code path by it, so two CPUs that differ in it round the learner's floats differently."""


def cpu_model(cpuinfo: str | None = None) -> str:
    """The CPU as the learner's float results depend on it (SIMD kernels), so a run records
    it: Linux ``/proc/cpuinfo``'s model name, then its family, model and stepping and the
    widest vector unit of :data:`SIMD_LEVELS`, e.g. ``AMD EPYC (family 25, model 1,
    stepping 1; avx2)``; else ``platform.processor()``. A virtual machine often shows one
    model name (``AMD EPYC``) for several generations: two such CPUs once gave a loss
    differing in its 5th digit at the first update (docs/results.md, issue 70), which the
    name alone could not tell apart. ``cpuinfo``: that file's text (tests)."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text(encoding="utf-8")
        except OSError:
            return platform.processor() or "unknown"
    fields: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        key, sep, value = line.partition(":")
        if sep and key.strip() not in fields:  # the first processor's
            fields[key.strip()] = value.strip()
    name = fields.get("model name")
    if not name:
        return platform.processor() or "unknown"
    ids = ", ".join(
        f"{label} {fields[key]}"
        for key, label in (("cpu family", "family"), ("model", "model"), ("stepping", "stepping"))
        if fields.get(key)
    )
    flags = set(fields.get("flags", "").split())
    simd = next((f for f in SIMD_LEVELS if f in flags), "")
    detail = "; ".join(part for part in (ids, simd) if part)
    return f"{name} ({detail})" if detail else name


def versions() -> dict[str, str]:
    """Versions of priqn, Python, torch, numpy, gymnasium and SUMO (SUMO's never fatal),
    and the CPU model (``cpu``)."""
    import gymnasium
    import torch

    import priqn

    out = {
        "priqn": priqn.__version__,
        "python": platform.python_version(),
        "torch": torch.__version__,
        "numpy": np.__version__,
        "gymnasium": gymnasium.__version__,
        "cpu": cpu_model(),
    }
    try:
        from priqn.sim.sumo import sumo_version

        out["sumo"] = sumo_version()
    except Exception as exc:  # noqa: BLE001 - recorded, never fatal
        out["sumo"] = f"unknown ({type(exc).__name__})"
    return out


def own_nets_manifest(nets: Sequence[str], junction: str) -> dict[str, Any]:
    """A manifest of ``env.nets`` as the generated families have one: id, path, SHA-256,
    and the junction each net is driven through (``junction`` or its default resolved).

    Every net is read (:meth:`RoadMap.load`), so one that cannot be used stops the run
    before it starts, in one line naming the file."""
    from priqn.env.scenes import own_net_files
    from priqn.sim.roadmap import RoadMap

    return {
        "family": "own",
        "junction": junction,
        "nets": [
            {
                "id": ref,
                "path": str(path.resolve()),
                "files": {path.name: sha256_file(path)},
                "junction": RoadMap.load(path, junction=junction).junction_id,
            }
            for ref, path in own_net_files(nets).items()
        ],
    }


def manifest_hashes(families: Sequence[str], nets_dir: str) -> dict[str, str]:
    """Manifest hash per family; a family without generated nets is a one-line error."""
    from priqn.sim.scenario import manifest_hash

    root = Path(nets_dir) if nets_dir else None
    return {fam: manifest_hash(fam, root) for fam in families}


THREAD_VARIABLES: tuple[str, ...] = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
"""The thread limits of the math libraries a process uses (torch's CPU threads follow
``OMP_NUM_THREADS`` unless ``torch_threads`` sets them; numpy's BLAS follows its own). A
sweep sets them per cell from its CPU share (:func:`priqn.sweep.process.thread_env`)."""


def thread_limits() -> dict[str, Any]:
    """What meta.json records of this process's CPU threads: torch's, and each of
    :data:`THREAD_VARIABLES` in its environment (None: unset)."""
    import torch

    return {"torch": torch.get_num_threads(), **{v: os.environ.get(v) for v in THREAD_VARIABLES}}
