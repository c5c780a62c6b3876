"""Checkpoints and snapshots written off the loop's critical path (issue 61,
:mod:`priqn.run.writer`): the same files, meta.json never ahead of them, the replay rows
those of the capture, and a failed write stopping the run in one line."""

from __future__ import annotations

import dataclasses
import io
import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import torch
from test_checkpoint import make_checkpoint
from test_train import TINY

from priqn.errors import PriqnError
from priqn.run import checkpoint
from priqn.run.checkpointer import (
    capture_checkpoint,
    copy_tensors,
    load_checkpoint,
    replay_files,
    save_checkpoint,
)
from priqn.run.folder import RunFolder
from priqn.run.writer import BackgroundWriter


def _fail() -> None:
    raise PriqnError("latest.pt: no space left on device")


def test_a_job_error_is_raised_in_the_loop_thread_at_the_next_sync_point() -> None:
    threads: list[str] = []
    with BackgroundWriter() as writer:
        writer.submit(lambda: threads.append(threading.current_thread().name))
        writer.submit(_fail)  # waits for the first job, which succeeded
        assert threads and threads[0] != threading.current_thread().name
        with pytest.raises(PriqnError, match="no space left"):
            writer.wait()
        writer.wait()  # raised once: nothing in flight any more
        writer.submit(_fail)
        with pytest.raises(PriqnError, match="no space left"):
            writer.submit(lambda: None)  # the next hand-over raises it
    writer = BackgroundWriter()
    writer.submit(_fail)
    with pytest.raises(PriqnError, match="no space left"):  # leaving the block raises it
        with writer:
            pass
    writer = BackgroundWriter()
    writer.submit(_fail)
    with pytest.raises(KeyError):  # the block's own error goes on, the job's is dropped
        with writer:
            raise KeyError("the loop's error")
    inline = BackgroundWriter(background=False)
    with pytest.raises(PriqnError, match="no space left"):  # without a thread: at once
        inline.submit(_fail)


def test_check_raises_a_failed_job_without_waiting_for_a_running_one() -> None:
    release = threading.Event()
    with BackgroundWriter() as writer:
        writer.submit(release.wait)
        writer.check()  # still running: no wait, no error
        release.set()
        writer.wait()
        writer.submit(_fail)
        writer._in_flight.exception()  # type: ignore[union-attr]  # let it fail
        with pytest.raises(PriqnError):
            writer.check()


def test_steps_done_says_n_only_once_latest_pt_at_n_is_on_disk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The constructed race: latest.pt's write held back, the loop goes on; meta.json keeps
    the previous progress until the file is there, and never a read-modify-write at once."""
    run = RunFolder(tmp_path / "run")
    run.path.mkdir()
    run.write_meta({"steps_done": 40, "status": "running"})
    started, release = threading.Event(), threading.Event()
    real_save = checkpoint.save

    def slow_save(state: checkpoint.Checkpoint, path: Path) -> None:
        started.set()
        release.wait(10)
        real_save(state, path)

    monkeypatch.setattr(checkpoint, "save", slow_save)
    with BackgroundWriter() as writer:
        pending = capture_checkpoint(run, make_checkpoint(step=80), None, {"steps_done": 80})
        writer.submit(pending.write)
        assert started.wait(10)
        assert run.meta()["steps_done"] == 40 and not run.latest_checkpoint.exists()
        release.set()
        writer.wait()
    assert run.meta() == {"steps_done": 80, "status": "running"}
    assert load_checkpoint(run, "cpu").step == 80


def _add_rows(replay, first: int, count: int) -> None:
    """Rows ``first`` .. of a 2-env buffer of 1-byte frames: row p of env e holds 10 e + p."""
    for p in range(first, first + count):
        obs = {"x": np.array([[p], [10 + p]], np.uint8)}
        replay.add(obs, np.array([p, p]), np.zeros((2, 5)), np.zeros(2, bool),
                   np.zeros(2, bool), [None, None])  # fmt: skip


def test_a_captured_checkpoint_saves_the_rows_of_its_capture(tmp_path: Path) -> None:
    """Rows stored after the capture are not in its file; the ring coming round to the
    rows it has yet to save is seen before the step that would overwrite them."""
    from priqn.agents.replay import ReplayBuffer

    run = RunFolder(tmp_path / "run")
    replay = ReplayBuffer({"x": ((1,), np.uint8)}, num_envs=2, capacity=12)  # 6 rows per env
    _add_rows(replay, 0, 3)
    pending = capture_checkpoint(run, make_checkpoint(step=30), replay)
    assert pending.state.replay_chunks == [{"file": "replay-000000000030.npz", "end": [3, 3]}]
    assert not pending.ring_reaches(replay)  # rows 3, 4 overwrite nothing of rows 0-2
    _add_rows(replay, 3, 2)
    assert pending.ring_reaches(replay)  # rows 5, 6: row 6 would overwrite row 0
    pending.write()
    fresh = ReplayBuffer({"x": ((1,), np.uint8)}, num_envs=2, capacity=12)
    for path in replay_files(run, load_checkpoint(run, "cpu")):
        fresh.load_rows(path)
    assert fresh.written.tolist() == [3, 3]
    assert fresh.obs["x"][1, :3, 0].tolist() == [10, 11, 12]
    assert fresh.obs["x"][1, 3:, 0].tolist() == [0, 0, 0]
    # The next checkpoint adds rows 3-7 (the ring then holds rows 2-7) and reaches them at
    # once; captured and written apart it saves what save_checkpoint saves in one go.
    _add_rows(replay, 5, 3)
    following = dataclasses.replace(
        make_checkpoint(step=80), replay_chunks=pending.state.replay_chunks
    )
    second = capture_checkpoint(run, following, replay)
    assert second.ring_reaches(replay)
    second.write()
    at_once = save_checkpoint(RunFolder(tmp_path / "at-once"), following, replay)
    assert second.state.replay_chunks == at_once.replay_chunks
    assert [c["file"] for c in at_once.replay_chunks] == [
        "replay-000000000030.npz",
        "replay-000000000080.npz",
    ]


def test_copied_tensors_save_to_the_same_bytes_and_stay_as_copied() -> None:
    base = torch.arange(12, dtype=torch.float32)
    net = torch.nn.Linear(3, 2)
    state = {"a": base[:6].view(2, 3), "b": base[6:], "net": net.state_dict(), "n": 3}
    copied = copy_tensors(state)

    def saved(value: object) -> bytes:
        buf = io.BytesIO()
        torch.save(value, buf)
        return buf.getvalue()

    assert saved(copied) == saved(state)  # one storage for a and b, as before
    before = saved(copied)
    with torch.no_grad():
        base.add_(1.0)
        net.weight.mul_(2.0)
    assert saved(copied) == before


def test_a_failed_background_write_stops_the_run_in_one_line(tmp_path: Path) -> None:
    """latest.pt's write fails in the writer's thread at the first checkpoint (100): the
    run stops within a log interval, says so in one line and in meta.json, whose
    steps_done never said 100."""
    fail_first_checkpoint = (
        "import sys\n"
        "import priqn.run.checkpoint as ck\n"
        "from priqn.errors import PriqnError\n"
        "def save(state, path):\n"
        "    raise PriqnError(f'{path}: no space left on device')\n"
        "ck.save = save\n"
        "from priqn.cli import main\n"
        "sys.exit(main(['train', *sys.argv[1:]]))\n"
    )
    args = ["--agent", "iqn", "--seed", "5", "--steps", "300", "--num-envs", "2",
            "--runs-dir", str(tmp_path), "--name", "run",
            "--set", "checkpoint.interval_steps=100", "--set", "evaluation.interval_steps=0",
            *TINY]  # fmt: skip
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    out = subprocess.run(
        [sys.executable, "-c", fail_first_checkpoint, *args],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    assert out.returncode == 2, out.stderr[-2000:]
    assert out.stderr.strip().splitlines() == [
        f"priqn: error: {tmp_path / 'run' / 'checkpoints' / 'latest.pt'}: no space left on device"
    ], out.stderr[-2000:]
    meta = json.loads((tmp_path / "run" / "meta.json").read_text())
    assert meta["status"] == "failed" and "no space left on device" in meta["error"]
    assert meta.get("steps_done", 0) == 0
    rows = (tmp_path / "run" / "metrics.csv").read_text().splitlines()
    # Raised at a log interval (every 50) or, at the latest, by the next checkpoint (200).
    assert max(int(r.split(",")[1]) for r in rows[1:]) <= 200


def _replay_arrays(path: Path) -> dict[str, np.ndarray]:
    """Every array of a replay file (its zip's timestamps aside)."""
    import zipfile

    from priqn.agents.replay import ArrayFile

    names = [n.removesuffix(".npy.zst") for n in zipfile.ZipFile(path).namelist()]
    with ArrayFile(path) as data:
        return {name: data[name] for name in names}


def test_a_ring_shorter_than_a_checkpoint_interval_trains_as_written_in_the_loop(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A replay ring of 40 rows against a checkpoint every 80 decisions (1 env worker):
    each checkpoint's rows fill the ring, so the loop waits for the writer before its next
    step; the run is the run whose checkpoints are written in the loop, files included."""
    from priqn.run.checkpointer import CheckpointWrite
    from priqn.run.train_config import resolve_config
    from priqn.tools.diff import diff_runs
    from priqn.train import train

    reached, real_reaches = [], CheckpointWrite.ring_reaches

    def ring_reaches(self: CheckpointWrite, replay: object, rows: int = 2) -> bool:
        reached.append(real_reaches(self, replay, rows))
        return reached[-1]

    monkeypatch.setattr(CheckpointWrite, "ring_reaches", ring_reaches)

    sets = [*TINY[1::2], "replay.capacity=40", "checkpoint.interval_steps=80",
            "checkpoint.keep_at=[120]", "evaluation.interval_steps=0"]  # fmt: skip
    cfg = resolve_config(
        agent="iqn", seed=5, net="tjunction", steps=160, num_envs=1, overrides=sets
    )
    inline = RunFolder(train(cfg, tmp_path / "inline", background_writes=False))
    reached.clear()
    background = RunFolder(train(cfg, tmp_path / "background"))
    assert reached.count(True) >= 1  # the loop waited for the writer to spare its rows
    _, parts = diff_runs(inline, background)
    assert all(p.same is not False for p in parts), [p.text for p in parts]
    for name in ("policy.pt", "snapshots/policy-at120.pt"):
        assert (inline.path / name).read_bytes() == (background.path / name).read_bytes()
    a, b = load_checkpoint(inline, "cpu"), load_checkpoint(background, "cpu")
    assert a.replay_chunks == b.replay_chunks and a.step == b.step == 160
    for path_a, path_b in zip(replay_files(inline, a), replay_files(background, b), strict=True):
        arrays_a, arrays_b = _replay_arrays(path_a), _replay_arrays(path_b)
        assert arrays_a.keys() == arrays_b.keys()
        assert all(np.array_equal(arrays_a[k], arrays_b[k]) for k in arrays_a), path_b.name
    for meta in (inline.meta(), background.meta()):
        assert meta["status"] == "complete" and meta["steps_done"] == 160
        assert set(meta["snapshots"]) == {"120"}
