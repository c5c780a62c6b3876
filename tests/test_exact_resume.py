"""A resumed run is the same run (issue 49): killed at any moment, resumed, it ends bit for
bit as the uninterrupted run of its seed.

Each run trains 300 decisions with 2 env workers, a checkpoint every 100 decisions, an
in-training evaluation at 200 and a kept snapshot at 250 (TINY networks and 32 px
observations). The uninterrupted run of each agent is made once for the module; a killed
run is compared with it by ``priqn diff`` and by its files: metrics.csv (every column but
wall_s), policy.pt, the snapshot, and meta.json's record of the resume as exact.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_train import TINY, cli, read_metrics

STEPS = 300
ARGS = [
    "--seed", "5", "--steps", str(STEPS), "--num-envs", "2",
    "--set", "checkpoint.interval_steps=100", "--set", "checkpoint.keep_at=[250]",
    "--set", "evaluation.interval_steps=200", "--set", "evaluation.episodes=1", *TINY,
]  # fmt: skip
ENV = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")

# Runs `priqn train` with checkpoint.save swapped for one that kills the process (SIGKILL)
# in the middle of writing the second latest.pt: the replay rows of that checkpoint are on
# disk, latest.pt's temp file is half written, the old latest.pt still stands.
DIE_IN_WRITE = """
import os, signal, sys
import priqn.run.checkpoint as ck
from priqn.io import atomic_open
real, calls = ck.save, []
def save(state, path):
    if str(path).endswith("latest.pt"):
        calls.append(path)
        if len(calls) == 2:
            with atomic_open(path, "wb") as fh:
                fh.write(b"half a checkpoint")
                fh.flush()
                os.kill(os.getpid(), signal.SIGKILL)
    return real(state, path)
ck.save = save
from priqn.cli import main
sys.exit(main(["train", *sys.argv[1:]]))
"""


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("uninterrupted")
    runs = {}
    for agent in ("iqn", "pr-iqn"):
        out = cli("--agent", agent, "--runs-dir", str(root), "--name", agent, *ARGS)
        assert out.returncode == 0, out.stderr[-2000:]
        runs[agent] = root / agent
    return runs


def _steps_done(run: Path) -> int:
    try:
        return int(json.loads((run / "meta.json").read_text()).get("steps_done", 0))
    except (OSError, ValueError):
        return 0


def _kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL the trainer and its env workers (its process group)."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait(30)


def _assert_same_training(full: Path, resumed: Path, sessions: int = 2) -> None:
    """``resumed`` (in ``sessions`` sessions, the later ones exact resumes) is ``full``'s
    training: priqn diff, metrics.csv but wall_s, policy.pt and the kept snapshot."""
    out = subprocess.run(
        [sys.executable, "-m", "priqn.cli", "diff", str(full), str(resumed)],
        capture_output=True, text=True, env=ENV, timeout=120,
    )  # fmt: skip
    assert out.returncode == 0, out.stdout + out.stderr
    assert "the runs are the same training" in out.stdout
    drop = lambda rows: [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]  # noqa: E731
    assert drop(read_metrics(full)) == drop(read_metrics(resumed))
    assert any(r["kind"] == "eval" for r in read_metrics(resumed))
    for name in ("policy.pt", "snapshots/policy-at250.pt"):
        assert (full / name).read_bytes() == (resumed / name).read_bytes(), name
    meta = json.loads((resumed / "meta.json").read_text())
    assert meta["status"] == "complete" and meta["steps_done"] == STEPS
    assert [s["resume"] for s in meta["sessions"]] == [False] + [True] * (sessions - 1)
    assert all(s["exact"] is True for s in meta["sessions"][1:])


def kill_after_the_first_checkpoint(runs_dir: Path, agent: str, args: list[str]) -> Path:
    """Train ``agent`` with ``args`` (a checkpoint every 100 decisions) into
    ``runs_dir/agent`` and SIGKILL it, and its env workers, at a random moment after its
    first checkpoint and no later than its last one before the end (at 200: a fast
    machine can train the other 200 decisions inside the random wait); returns the run
    folder."""
    run = runs_dir / agent
    proc = subprocess.Popen(
        [sys.executable, "-m", "priqn.cli", "train", "--agent", agent,
         "--runs-dir", str(runs_dir), "--name", agent, *args],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=ENV, start_new_session=True,
    )  # fmt: skip
    deadline = time.time() + 240
    try:
        while time.time() < deadline and proc.poll() is None and _steps_done(run) < 100:
            time.sleep(0.05)
        assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
        kill_at = time.time() + random.uniform(0.0, 3.0)  # after the first checkpoint
        while time.time() < kill_at and _steps_done(run) < STEPS - 100:
            time.sleep(0.02)
    finally:
        _kill_group(proc)
    return run


@pytest.mark.parametrize("agent", ["iqn", "pr-iqn"])
def test_sigkill_at_a_random_decision_then_resume_is_the_same_training(
    tmp_path: Path, uninterrupted: dict[str, Path], agent: str
) -> None:
    run = kill_after_the_first_checkpoint(tmp_path, agent, ARGS)
    meta = json.loads((run / "meta.json").read_text())
    assert meta["status"] == "running" and 100 <= meta["steps_done"] < STEPS, meta["steps_done"]
    out = cli("--resume", str(run))
    assert out.returncode == 0, out.stderr[-2000:]
    _assert_same_training(uninterrupted[agent], run)


def test_kill_while_writing_a_checkpoint_then_resume_is_the_same_training(
    tmp_path: Path, uninterrupted: dict[str, Path]
) -> None:
    run = tmp_path / "pr-iqn"
    out = subprocess.run(
        [sys.executable, "-c", DIE_IN_WRITE, "--agent", "pr-iqn", "--runs-dir", str(tmp_path),
         "--name", "pr-iqn", *ARGS],
        capture_output=True, text=True, env=ENV, timeout=300, start_new_session=True,
    )  # fmt: skip
    assert out.returncode == -signal.SIGKILL, out.stderr[-2000:]
    # The second checkpoint's replay rows were written, its latest.pt was not.
    files = sorted(p.name for p in (run / "checkpoints").iterdir())
    assert "replay-000000000200.npz" in files and any(".tmp" in f for f in files), files
    assert _steps_done(run) == 100
    out = cli("--resume", str(run))
    assert out.returncode == 0, out.stderr[-2000:]
    _assert_same_training(uninterrupted["pr-iqn"], run)


def test_a_resume_at_another_commit_or_off_its_episodes_is_one_line(
    tmp_path: Path, uninterrupted: dict[str, Path]
) -> None:
    import shutil

    from priqn.run import checkpoint

    src = uninterrupted["iqn"]
    # Another commit: meta.json says the checkpoint was written elsewhere.
    other = tmp_path / "other"
    shutil.copytree(src, other)
    meta = json.loads((other / "meta.json").read_text())
    meta.update(git_sha="0" * 40, status="failed")
    (other / "meta.json").write_text(json.dumps(meta))
    out = cli("--resume", str(other), "--steps", str(STEPS + 100))
    assert out.returncode == 2 and "written by the code at 000000000000" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    # Episodes that, played again, do not reach the checkpoint's observation.
    off = tmp_path / "off"
    shutil.copytree(src, off)
    state = checkpoint.load(off / "checkpoints" / "latest.pt")
    state.obs["kinematics"] = state.obs["kinematics"] + np.float32(1.0)
    checkpoint.save(state, off / "checkpoints" / "latest.pt")
    out = cli("--resume", str(off), "--steps", str(STEPS + 100))
    assert out.returncode == 2, out.stderr[-2000:]
    assert "do not reach the checkpoint's observation ('kinematics' differs)" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1


def test_bench_replay_measures_both_writes(tmp_path: Path) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "priqn.cli", "bench", "replay", "--px", "32", "--capacity", "400",
         "--interval", "200", "--decisions", "40"],
        capture_output=True, text=True, env=ENV, timeout=300, cwd=tmp_path,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    for mode in ("whole, uncompressed", "rows since last, compressed", "load whole, compressed"):
        assert f"    {mode} " in out.stdout, out.stdout
    assert not list(tmp_path.iterdir())  # its files went with their temporary folder


def test_a_resume_on_another_cpu_model_is_not_exact(tmp_path: Path) -> None:
    """The learner's floats depend on the CPU model: only a resume on the model of the
    session before counts as exact (an unknown or missing model does not)."""
    from priqn.run.folder import RunFolder
    from priqn.run.session import same_cpu_as_before

    run = RunFolder(tmp_path / "run")
    run.path.mkdir()
    cases = [("Xeon", "Xeon", True), ("Xeon", "EPYC", False), (None, "Xeon", False),
             ("unknown", "unknown", False)]  # fmt: skip
    for before, now, same in cases:
        sessions = [{"resume": False, "cpu": before}, {"resume": True, "cpu": now}]
        run.write_meta({"sessions": [{k: v for k, v in s.items() if v} for s in sessions]})
        assert same_cpu_as_before(run) is same, (before, now)
    run.write_meta({"sessions": [{"resume": False, "cpu": "Xeon"}]})
    assert same_cpu_as_before(run) is False


def test_the_recorded_cpu_tells_apart_what_its_model_name_does_not() -> None:
    """Two virtual CPUs that both call themselves "AMD EPYC" but differ in generation and
    vector unit (issue 70: their learners' losses differed at the first update) are recorded
    as two CPUs; the same one twice as one."""
    from priqn.run.provenance import cpu_model

    def cpuinfo(family: int, model: int, flags: str) -> str:
        one = (f"processor\t: {{}}\nvendor_id\t: AuthenticAMD\ncpu family\t: {family}\n"
               f"model\t\t: {model}\nmodel name\t: AMD EPYC\nstepping\t: 1\nflags\t\t: {flags}\n")  # fmt: skip
        return "\n".join(one.format(i) for i in range(2))

    milan = cpu_model(cpuinfo(25, 1, "fpu sse4_2 avx avx2 fma"))
    genoa = cpu_model(cpuinfo(25, 17, "fpu sse4_2 avx avx2 avx512f fma"))
    assert milan == "AMD EPYC (family 25, model 1, stepping 1; avx2)"
    assert genoa == "AMD EPYC (family 25, model 17, stepping 1; avx512f)"
    assert milan != genoa and milan == cpu_model(cpuinfo(25, 1, "fpu sse4_2 avx avx2 fma"))
    assert cpu_model("processor\t: 0\nmodel name\t: Xeon\n") == "Xeon"  # no more detail given
