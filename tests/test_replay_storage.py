"""``replay.storage`` (issue 51): where the replay observations live changes no batch.

``host`` (numpy, the default), ``device`` (torch tensors on the learner's device: the CPU
here) and ``pinned``'s gather into staging buffers (page-locked on CUDA; ordinary memory
here, which the values do not depend on) give the same batches bit for bit from the same
generator; a replay file written from one storage loads into another; a seeded run with
``device`` storage, stopped and resumed, is the same training as the ``host`` run.
``tests/test_cuda.py`` checks the same on a GPU.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from test_train import TINY, cli

from priqn.agents import frames
from priqn.agents.frames import PinnedFrames, check_storage
from priqn.agents.replay import ReplayBuffer
from priqn.errors import PriqnError
from priqn.run.train_config import resolve_config

SPEC = {"bev": ((2, 6, 6), np.uint8), "kinematics": ((3,), np.float32)}
E = 3


def random_obs(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    return {
        "bev": rng.integers(0, 256, (n, 2, 6, 6), dtype=np.uint8),
        "kinematics": rng.normal(size=(n, 3)).astype(np.float32),
    }


def filled(
    storage: str, steps: int = 40, capacity: int = 60, seed: int = 0, device: Any = None
) -> ReplayBuffer:
    """A 3-env, 3-step buffer filled with random steps whose episodes end now and then
    (terminated or truncated, each with its final observation); rings wrap around."""
    rb = ReplayBuffer(SPEC, E, capacity, n_step=3, gamma=(0.9, 0.5, 0.99), num_objectives=3,
                      storage=storage, device=device)  # fmt: skip
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        term, trunc = rng.random(E) < 0.1, rng.random(E) < 0.1
        finals = random_obs(rng, E)
        final = [{k: v[e] for k, v in finals.items()} if term[e] or trunc[e] else None
                 for e in range(E)]  # fmt: skip
        reward = rng.normal(size=(E, 3)).astype(np.float32)
        rb.add(random_obs(rng, E), rng.integers(0, 5, E), reward, term, trunc, final)
    return rb


def as_numpy(batch: dict) -> dict:
    """A batch with every tensor as a numpy array (on the host)."""
    out = {}
    for name, value in batch.items():
        if isinstance(value, dict):
            out[name] = as_numpy(value)
        else:
            out[name] = value.cpu().numpy() if isinstance(value, torch.Tensor) else value
    return out


def assert_same_batch(a: dict, b: dict) -> None:
    a, b = as_numpy(a), as_numpy(b)
    assert list(a) == list(b)
    for name in a:
        if isinstance(a[name], dict):
            assert_same_batch(a[name], b[name])
        else:
            assert a[name].dtype == b[name].dtype and a[name].shape == b[name].shape, name
            assert a[name].tobytes() == b[name].tobytes(), name


def staged(rb: ReplayBuffer) -> ReplayBuffer:
    """``rb`` with its batches gathered as ``pinned`` gathers them (two staging slots,
    copies to the device), in ordinary memory on the CPU."""
    store = PinnedFrames(SPEC, rb.num_envs, rb.rows, torch.device("cpu"), pin=False)
    store.arrays = rb.frames.arrays
    rb.frames = store
    return rb


def test_every_storage_gives_the_same_batches_bit_for_bit() -> None:
    host, device, pinned = filled("host"), filled("device"), staged(filled("host"))
    assert isinstance(device.obs["bev"], torch.Tensor)
    for k in SPEC:
        assert np.array_equal(host.obs[k], device.obs[k].numpy())
    assert np.array_equal(host.written, device.written) and len(host) == len(device)
    assert host.nbytes() == device.nbytes() and host.bytes_per_row() == device.bytes_per_row()
    rngs = [np.random.default_rng(3) for _ in range(3)]
    kept = []
    for _ in range(5):
        want = host.sample(16, rngs[0])
        got_device, got_pinned = device.sample(16, rngs[1]), pinned.sample(16, rngs[2])
        assert isinstance(got_device["obs"]["bev"], torch.Tensor)
        assert isinstance(got_pinned["reward"], torch.Tensor)
        assert_same_batch(want, got_device)
        assert_same_batch(want, got_pinned)
        kept.append((as_numpy(want), got_pinned))
    for want, got in kept:  # staging slots are reused: earlier batches are left alone
        assert_same_batch(want, got)
    assert all(r0.bit_generator.state == r.bit_generator.state for r0 in rngs for r in rngs)


def test_truncated_episodes_and_replay_files_cross_storages(tmp_path: Path) -> None:
    """The replay files do not know the storage: rows saved from one load into another
    (chunks and the whole-buffer file), and resume's truncation writes the same rows."""
    host, device = filled("host", steps=25), filled("device", steps=25)
    nxt = random_obs(np.random.default_rng(9), E)
    host.truncate_open_episodes(nxt)
    device.truncate_open_episodes(nxt)
    for src, dst_storage in ((host, "device"), (device, "host"), (device, "device")):
        with open(tmp_path / "rows.npz", "wb") as fh:
            src.save_rows(fh, np.zeros(E, np.int64))
        with open(tmp_path / "whole.npz", "wb") as fh:
            src.save_to(fh)
        chunks, whole = filled(dst_storage, steps=0), filled(dst_storage, steps=0)
        chunks.load_rows(tmp_path / "rows.npz")
        whole.load_state_file(tmp_path / "whole.npz")
        for back in (chunks, whole):
            assert np.array_equal(back.written, host.written)
            for k in SPEC:
                assert np.array_equal(np.asarray(back.obs[k]), np.asarray(host.obs[k])), k
            assert_same_batch(
                host.sample(8, np.random.default_rng(1)), back.sample(8, np.random.default_rng(1))
            )


def test_a_bad_storage_is_one_line_listing_the_valid_ones(tmp_path: Path) -> None:
    with pytest.raises(PriqnError, match=r"storage: unknown 'gpu' \(valid: host, pinned, device\)"):
        resolve_config(overrides=["replay.storage=gpu"])
    out = cli("--set", "replay.storage=gpu", "--runs-dir", str(tmp_path), "--name", "x")
    assert out.returncode == 2, out.stderr[-2000:]
    assert out.stderr.strip().count("\n") == 0 and "valid: host, pinned, device" in out.stderr
    assert not (tmp_path / "x").exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA machine can pin memory")
def test_pinned_without_cuda_is_one_line_before_the_run_folder(tmp_path: Path) -> None:
    with pytest.raises(PriqnError, match=r"'pinned' needs CUDA .* this machine has none"):
        check_storage("pinned", torch.device("cpu"))
    out = cli("--set", "replay.storage=pinned", "--runs-dir", str(tmp_path), "--name", "x")
    assert out.returncode == 2 and out.stderr.strip().count("\n") == 0, out.stderr[-2000:]
    assert "needs CUDA" in out.stderr and not (tmp_path / "x").exists()


def test_device_storage_that_does_not_fit_is_refused_before_it_is_allocated(monkeypatch) -> None:
    monkeypatch.setattr(frames, "available_bytes", lambda device: 2**30 + 1000)
    with pytest.raises(PriqnError, match=r"needs 0\.0 GB on cpu.*lower replay\.capacity"):
        ReplayBuffer(SPEC, E, 60, storage="device")
    ReplayBuffer(SPEC, E, 6, storage="device")  # 2 rows of 84 bytes per env fit
    ReplayBuffer(SPEC, E, 600_000, storage="host")  # host memory: not checked


ARGS = [
    "--agent", "pr-iqn", "--seed", "11", "--num-envs", "2",
    "--set", "checkpoint.interval_steps=100", "--set", "evaluation.interval_steps=0",
    "--set", "exploration.decay_steps=90", *TINY,
]  # fmt: skip


def test_device_storage_trains_and_resumes_as_host_storage(tmp_path: Path) -> None:
    """300 seeded decisions with host storage; the same with device storage, stopped at 200
    and resumed to 300: ``priqn diff`` says the same training (metrics and weights)."""
    host = cli("--runs-dir", str(tmp_path), "--name", "host", "--steps", "300", *ARGS)
    assert host.returncode == 0, host.stderr[-2000:]
    first = cli("--runs-dir", str(tmp_path), "--name", "device", "--steps", "200", *ARGS,
                "--set", "replay.storage=device")  # fmt: skip
    assert first.returncode == 0, first.stderr[-2000:]
    resumed = cli("--resume", str(tmp_path / "device"), "--steps", "300")
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    meta = json.loads((tmp_path / "device" / "meta.json").read_text())
    assert meta["status"] == "complete" and meta["sessions"][1]["exact"] is True
    assert meta["updates_done"] > 0
    out = subprocess.run(
        [sys.executable, "-m", "priqn.cli", "diff", str(tmp_path / "host"), str(tmp_path / "device")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 0 and "the runs are the same training" in out.stdout, out.stdout
