"""Training: config resolution and errors (fast), CLI smoke runs with the real env (subprocess)."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from priqn.errors import PriqnError
from priqn.run import checkpoint
from priqn.run.checkpointer import load_policy
from priqn.run.metrics import METRIC_COLUMNS
from priqn.run.session import remove_run
from priqn.run.train_config import (
    ExplorationConfig,
    TrainConfig,
    default_run_name,
    derive_seeds,
    policy_labels,
    resolve_config,
)
from priqn.train import linear_epsilon, train

CUDA = torch.cuda.is_available()

TINY = [
    "--set", "env.obs_size_px=32",
    "--set", "env.max_episode_steps=25",
    "--set", "replay.learning_starts=64",
    "--set", "replay.capacity=4000",
    "--set", "network.latent_dim=64",
    "--set", "network.hidden_dim=64",
    "--set", "learner.num_tau_samples=8",
    "--set", "learner.num_tau_prime_samples=8",
    "--set", "learner.num_quantiles=8",
    "--set", "log_interval_steps=50",
]  # fmt: skip


def cli(*args: str, **kw) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    return subprocess.run(
        [sys.executable, "-m", "priqn.cli", "train", *args],
        capture_output=True, text=True, env=env, timeout=300, **kw,
    )  # fmt: skip


def read_metrics(run: Path) -> list[dict[str, str]]:
    with (run / "metrics.csv").open() as fh:
        return list(csv.DictReader(fh))


def assert_complete_run_folder(run: Path, steps: int) -> dict:
    meta = json.loads((run / "meta.json").read_text())
    assert meta["status"] == "complete", meta.get("error")
    assert meta["steps_done"] >= steps
    for key in ("git_sha", "versions", "manifest_hashes", "seeds", "labels"):
        assert meta[key], key
    assert set(meta["seeds"]) == {"env", "eval_env", "torch_init", "tau", "replay", "explore"}
    assert meta["versions"]["sumo"] and meta["replay_bytes_per_transition"] > 0
    for name in ("config.toml", "metrics.csv", "learning_curve.png", "checkpoints/latest.pt"):
        assert (run / name).is_file(), name
    assert any((run / "tb").iterdir())
    rows = read_metrics(run)
    assert rows and tuple(rows[0]) == METRIC_COLUMNS
    assert not list(run.rglob("*.tmp"))
    return meta


# ---------------------------------------------------------------------------- fast, no SUMO


def test_presets_resolve_and_flags_win():
    cfg = resolve_config(preset="paper", agent="ma-iqn", seed=3, net="fourway", steps=500)
    assert (cfg.env.obs_size_px, cfg.env.family, cfg.seed, cfg.total_steps) == (
        128,
        "fourway",
        3,
        500,
    )
    assert cfg.agent.name == "ma-iqn" and cfg.learner.num_tau_samples == 64
    default = resolve_config()
    assert default.env.obs_size_px == 64 and default.agent.name == "pr-iqn"


def test_config_errors_are_one_line(tmp_path):
    with pytest.raises(PriqnError, match=r"unknown agent 'dqn'"):
        resolve_config(agent="dqn")
    with pytest.raises(PriqnError, match=r"agent.comparator: unknown comparator 'w1'"):
        resolve_config(overrides=["agent.comparator=w1"])
    with pytest.raises(PriqnError, match=r"agent.preorder: unknown preorder 'lexi'"):
        resolve_config(overrides=["agent.preorder=lexi"])
    with pytest.raises(PriqnError, match=r"unknown key 'learner.lrr'"):
        resolve_config(overrides=["learner.lrr=1e-3"])
    with pytest.raises(
        PriqnError, match=r"--preset: unknown preset 'huge' \(valid: default, paper, right-of-way\)"
    ):
        resolve_config(preset="huge")
    bad = tmp_path / "bad.toml"
    bad.write_text("[learner]\nkappa_x = 1\n")
    with pytest.raises(PriqnError, match=r"bad.toml.learner: unknown key 'kappa_x'"):
        resolve_config(config_file=bad)


def test_existing_run_folder_is_refused_without_resume_or_force(tmp_path):
    run = tmp_path / "r"
    run.mkdir()
    (run / "x").write_text("keep")
    with pytest.raises(PriqnError, match="already exists; use --resume .* or --force"):
        train(TrainConfig(), run)
    with pytest.raises(PriqnError, match="nothing to resume"):
        train(TrainConfig(), run, resume=True)
    assert (run / "x").read_text() == "keep"
    missing = resolve_config(overrides=[f'env.nets_dir="{tmp_path / "no_nets"}"'])
    with pytest.raises(PriqnError, match="no manifest for family"):
        train(missing, tmp_path / "r2")
    assert not (tmp_path / "r2").exists()


def test_resume_refuses_a_different_config(tmp_path):
    from priqn.config import dumps_toml, to_dict

    run = tmp_path / "r"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "latest.pt").write_bytes(b"")
    (run / "config.toml").write_text(dumps_toml(to_dict(resolve_config(agent="iqn"))))
    with pytest.raises(PriqnError, match=r"different config \(agent.name = 'iqn' in the run"):
        train(resolve_config(agent="pr-iqn"), run, resume=True)
    out = cli("--resume", str(run), "--agent", "ma-iqn")
    assert out.returncode == 2 and "only --steps and --device may change" in out.stderr


def test_seeds_epsilon_labels_names():
    a, b = derive_seeds(3), derive_seeds(4)
    assert a == derive_seeds(3) and a != b and len(set(a.values())) == len(a)
    ex = ExplorationConfig(eps_start=1.0, eps_end=0.1, decay_fraction=0.5)
    assert linear_epsilon(ex, 0, 100) == 1.0
    assert linear_epsilon(ex, 25, 100) == pytest.approx(0.55)
    assert linear_epsilon(ex, 90, 100) == pytest.approx(0.1)
    cfg = resolve_config(seed=2, overrides=["agent.preorder=partial", "agent.train_preorder=false"])
    labels = policy_labels(cfg)
    assert labels["label"] == "Pr-IQN QD ✗ 0.2 ✓" and labels["train_seed"] == 2
    assert default_run_name(cfg) == "tjunction_pr-iqn_qd_eps0.2_notrain_partial_s2"
    assert policy_labels(resolve_config(agent="iqn"))["label"] == "IQN"


def test_list_options_prints_every_key():
    out = cli("--list-options")
    assert out.returncode == 0, out.stderr
    for key in ("agent.comparator", "learner.kappa", "replay.capacity", "env.obs_size_px"):
        assert f"\n{key} = " in out.stdout


# ---------------------------------------------------------------------------- real env (subprocess)


def test_smoke_pr_iqn_kill9_then_resume(tmp_path):
    """A run killed with SIGKILL after a checkpoint resumes: steps, updates, metrics continue."""
    args = ["--agent", "pr-iqn", "--steps", "320", "--num-envs", "2", "--runs-dir", str(tmp_path),
            "--name", "run", "--set", "checkpoint.interval_steps=80",
            "--set", "evaluation.interval_steps=160", "--set", "evaluation.episodes=1", *TINY]  # fmt: skip
    run = tmp_path / "run"
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    proc = subprocess.Popen(
        [sys.executable, "-m", "priqn.cli", "train", *args],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, text=True,
    )  # fmt: skip
    deadline = time.time() + 240
    try:
        while time.time() < deadline and proc.poll() is None:
            meta = run / "meta.json"
            if meta.is_file() and json.loads(meta.read_text()).get("steps_done", 0) >= 160:
                break
            time.sleep(0.2)
        assert proc.poll() is None, proc.stderr.read()
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(30)
    meta = json.loads((run / "meta.json").read_text())
    assert meta["status"] == "running"
    killed_at = meta["steps_done"]
    assert 160 <= killed_at < 320
    assert (
        cli("--agent", "pr-iqn", "--runs-dir", str(tmp_path), "--name", "run", *TINY).returncode
        == 2
    )

    out = cli("--resume", str(run))
    assert out.returncode == 0, out.stderr
    meta = assert_complete_run_folder(run, 320)
    assert meta["steps_done"] == 320 and len(meta["sessions"]) == 2
    assert meta["updates_done"] == (320 - 64) // 4 + 1
    rows = read_metrics(run)
    train_rows = [r for r in rows if r["kind"] == "train"]
    steps = [int(r["step"]) for r in train_rows]
    assert steps == sorted(steps) and max(steps) > killed_at
    assert [int(r["episode"]) for r in train_rows] == list(range(1, len(train_rows) + 1))
    assert any(r["kind"] == "eval" for r in rows)
    chunks = checkpoint.load(run / "checkpoints" / "latest.pt").replay_chunks
    assert sorted(p.name for p in (run / "checkpoints").glob("replay-*.npz")) == [
        c["file"] for c in chunks
    ]

    policy = load_policy(run)
    assert policy.labels["agent"] == "pr-iqn" and policy.labels["train_seed"] == 0
    assert policy.env_config.obs_size_px == 32
    s = policy.env_config.obs_size_px
    obs = {
        "bev": np.zeros((3, 4, s, s), np.uint8),
        "lidar": np.zeros((3, 2, s, s), np.uint8),
        "command": np.eye(3, dtype=np.float32),
        "kinematics": np.zeros((3, 4), np.float32),
    }
    acts = policy.act(obs, np.random.default_rng(0))
    assert acts.dtype == np.int64 and acts.shape == (3,)


@pytest.mark.parametrize("agent", ["iqn", "ensemble-iqn", "ma-iqn"])
def test_smoke_baselines_write_a_complete_run_folder(tmp_path, agent):
    out = cli("--agent", agent, "--steps", "120", "--num-envs", "1", "--runs-dir", str(tmp_path),
              "--name", agent, "--set", "evaluation.interval_steps=0", *TINY)  # fmt: skip
    assert out.returncode == 0, out.stderr
    meta = assert_complete_run_folder(tmp_path / agent, 120)
    assert meta["labels"]["agent"] == agent
    # A committed result keeps policy.pt, not checkpoints: the same greedy policy loads.
    import shutil

    with_ckpt = load_policy(tmp_path / agent).network.state_dict()
    shutil.rmtree(tmp_path / agent / "checkpoints")
    only_policy = load_policy(tmp_path / agent).network.state_dict()
    assert with_ckpt.keys() == only_policy.keys()
    assert all(torch.equal(v, only_policy[k]) for k, v in with_ckpt.items())


ON_DEVICES = pytest.mark.parametrize(
    "device",
    ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not CUDA, reason="no CUDA device"))],
)


@pytest.mark.slow
@ON_DEVICES
def test_same_seed_same_training(tmp_path, device):
    """Determinism: two runs with one seed give the same episodes and the same weights
    (on CUDA too, where a machine has it)."""
    common = ["--agent", "pr-iqn", "--steps", "200", "--num-envs", "2", "--runs-dir", str(tmp_path),
              "--set", "evaluation.interval_steps=0", "--device", device, *TINY]  # fmt: skip
    for name in ("a", "b"):
        out = cli(*common, "--name", name)
        assert out.returncode == 0, out.stderr
    drop = ("wall_s",)
    rows = [
        [{k: v for k, v in r.items() if k not in drop} for r in read_metrics(tmp_path / n)]
        for n in "ab"
    ]
    assert rows[0] == rows[1]
    sa, sb = (
        torch.load(tmp_path / n / "checkpoints/latest.pt", weights_only=True, map_location="cpu")
        for n in "ab"
    )
    for k, v in sa["learner"]["online"].items():
        assert torch.equal(v, sb["learner"]["online"][k]), k


@ON_DEVICES
def test_long_run_prefix_is_the_short_run(tmp_path, device):
    """Budgets within one run (issue 33): with ε decay fixed in decisions, the first 200
    decisions of a 400-decision run are a 200-decision run's, bit for bit -- its metrics
    (in-training evaluation included) and the snapshot it keeps at 200 equal the short
    run's metrics and policy.pt. On CUDA too, where a machine has it."""
    common = ["--agent", "pr-iqn", "--num-envs", "2", "--runs-dir", str(tmp_path), "--device", device,
              "--set", "evaluation.interval_steps=100", "--set", "evaluation.episodes=1", *TINY]  # fmt: skip
    short = cli(
        *common, "--steps", "200", "--name", "short", "--set", "exploration.decay_fraction=0.3"
    )
    assert short.returncode == 0, short.stderr
    long = cli(*common, "--steps", "400", "--name", "long", "--set", "exploration.decay_steps=60",
               "--set", "checkpoint.keep_at=[200]")  # fmt: skip
    assert long.returncode == 0, long.stderr

    def rows(name: str) -> list[dict[str, str]]:
        kept = [r for r in read_metrics(tmp_path / name) if int(r["step"]) <= 200]
        return [{k: v for k, v in r.items() if k != "wall_s"} for r in kept]

    assert rows("short") and rows("short") == rows("long")
    assert any(r["kind"] == "eval" for r in rows("long"))
    assert any(int(r["step"]) > 200 for r in read_metrics(tmp_path / "long"))
    final = torch.load(tmp_path / "short/policy.pt", weights_only=True, map_location="cpu")
    kept = torch.load(
        tmp_path / "long/snapshots/policy-at200.pt", weights_only=True, map_location="cpu"
    )
    assert kept["step"] == final["step"] == 200
    for k, v in final["online"].items():
        assert torch.equal(v, kept["online"][k]), k
    meta = json.loads((tmp_path / "long/meta.json").read_text())
    assert meta["snapshots"]["200"]["file"] == "snapshots/policy-at200.pt"
    assert len(meta["snapshots"]["200"]["sha256"]) == 64
    # The same run without the fixed decay differs after the first decision's ε: the test can fail.
    other = cli(*common, "--steps", "400", "--name", "other", "--set", "checkpoint.keep_at=[200]")
    assert other.returncode == 0, other.stderr
    assert rows("other") != rows("short")

    # priqn diff says the same, also once the snapshot's weights are gone (as in git, where
    # only meta.json's SHA-256 of them is kept), and names the decay of the other run.
    from priqn.run.folder import RunFolder
    from priqn.tools.diff import diff_runs

    def diff(a: str, b: str) -> dict[str, bool | None]:
        _, found = diff_runs(RunFolder(tmp_path / a), RunFolder(tmp_path / b))
        return {p.name: p.same for p in found}

    same = {"config": True, "metrics": True, "weights": True, "episodes": None}
    assert diff("long", "short") == same
    (tmp_path / "long/snapshots/policy-at200.pt").unlink()
    assert diff("short", "long") == same
    found = diff_runs(RunFolder(tmp_path / "short"), RunFolder(tmp_path / "other"))[1]
    assert (
        found[0].text
        == "ε decays over 120 decisions, not 60 (fix the decay in decisions: exploration.decay_steps)"
    )
    assert [p.same for p in found[1:3]] == [False, False]  # metrics and weights at 200


def success_rate(env_cfg, act, episodes: int, seed: int) -> float:
    """Fraction of ``episodes`` that end in success at density 0.5 (one worker process)."""
    from priqn.env.vector import make_vector_env

    envs = make_vector_env(env_cfg, 1, seed=seed)
    try:
        obs, _ = envs.reset()
        rng = np.random.default_rng(seed)
        wins: list[bool] = []
        while len(wins) < episodes:
            obs, _, term, trunc, info = envs.step(act(obs, rng))
            if term[0] or trunc[0]:
                wins.append(bool(info["final_info"]["success"][0]))
        return float(np.mean(wins))
    finally:
        envs.close()


@pytest.mark.slow
def test_default_pr_iqn_learns_tjunction_density_05(tmp_path):
    """Learning check (~1 h on 2 cores): default Pr-IQN beats a random policy clearly."""
    import dataclasses

    out = subprocess.run(
        [sys.executable, "-m", "priqn.cli", "train", "--net", "tjunction", "--agent", "pr-iqn",
         "--seed", "0", "--set", "env.densities=[0.5]", "--runs-dir", str(tmp_path), "--name", "learn"],
        capture_output=True, text=True, timeout=3 * 3600,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    policy = load_policy(tmp_path / "learn")
    env_cfg = dataclasses.replace(policy.env_config, densities=(0.5,))
    n = policy.env_config.n_speeds * policy.env_config.n_offsets
    learned = success_rate(env_cfg, policy.act, 60, seed=1234)
    random = success_rate(env_cfg, lambda obs, rng: rng.integers(0, n, 1), 60, seed=1234)
    print(f"learning check: greedy success {learned:.3f} vs random {random:.3f} (60 episodes each)")
    assert learned >= random + 0.2, (learned, random)


@pytest.mark.parametrize("damage", ["truncate", "zero", "flip"])
def test_damaged_checkpoint_is_one_line_and_a_complete_run_stays_complete(tmp_path, damage):
    out = cli("--agent", "iqn", "--steps", "80", "--num-envs", "1", "--runs-dir", str(tmp_path),
              "--name", "run", "--set", "evaluation.interval_steps=0", *TINY)  # fmt: skip
    assert out.returncode == 0, out.stderr
    run = tmp_path / "run"
    ckpt = run / "checkpoints" / "latest.pt"
    data = bytearray(ckpt.read_bytes())
    if damage == "truncate":
        data = data[: len(data) // 2]
    elif damage == "zero":
        data = bytearray()
    else:
        data[len(data) // 3 : len(data) // 3 + 64] = bytes(64)
    ckpt.write_bytes(bytes(data))
    res = cli("--resume", str(run), "--steps", "160")
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().count("\n") == 0, res.stderr
    assert f"{ckpt}: damaged or unreadable checkpoint" in res.stderr
    assert json.loads((run / "meta.json").read_text())["status"] == "complete"
    with pytest.raises(PriqnError, match=r"damaged or unreadable checkpoint"):
        load_policy(run)


def test_one_writer_per_run_folder_and_a_killed_run_shows_interrupted(tmp_path):
    import os
    import signal
    import time

    from priqn.run.folder import live_trainer, run_status
    from priqn.sweep import cell_state

    proc = subprocess.Popen(
        [sys.executable, "-m", "priqn.cli", "train", "--agent", "iqn", "--steps", "100000",
         "--num-envs", "1", "--runs-dir", str(tmp_path), "--name", "run",
         "--set", "evaluation.interval_steps=0", *TINY],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    run = tmp_path / "run"
    try:
        deadline = time.monotonic() + 120
        while live_trainer(run) is None and time.monotonic() < deadline:
            time.sleep(0.2)
        assert live_trainer(run) == f"pid {proc.pid} on host {__import__('socket').gethostname()}"
        force = ("--agent", "iqn", "--runs-dir", str(tmp_path), "--name", "run", "--force", *TINY)
        for args in (("--resume", str(run)), force):
            out = cli(*args)
            assert out.returncode == 2, out.stderr
            assert f"still being trained by pid {proc.pid}" in out.stderr
            assert len(out.stderr.strip().splitlines()) == 1
        assert run_status(run) == "running" and cell_state(run) == "running"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=60)
    assert json.loads((run / "meta.json").read_text())["status"] == "running"  # never updated
    assert run_status(run) == "interrupted" and cell_state(run) == "interrupted"
    assert live_trainer(run) is None


def test_force_over_a_read_only_run_is_one_line_and_deletes_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from priqn.run.folder import RunFolder

    run = tmp_path / "run"
    (run / "eval").mkdir(parents=True)
    (run / "meta.json").write_text('{"status": "complete"}')
    (run / "eval" / "episodes.csv").write_text("kept\n")
    before = sorted(p.relative_to(run) for p in run.rglob("*"))
    # Root may delete anything, so the read-only folder is simulated where priqn asks.
    real_access = os.access
    monkeypatch.setattr(
        os, "access", lambda p, mode: False if Path(p) == run / "eval" else real_access(p, mode)
    )
    with pytest.raises(PriqnError) as info:
        remove_run(RunFolder(run))
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f"{run / 'eval'}: read-only") and "--force" in msg
    assert sorted(p.relative_to(run) for p in run.rglob("*")) == before


def test_cuda_determinism_switches_torch_and_cpu_training_leaves_it_alone(monkeypatch):
    """cuda_deterministic: the switch sets cuDNN, cuBLAS's workspace and torch's flag, and
    back; a CPU run never touches them (CPU training stays what it was, bit for bit)."""
    from priqn.run.train_config import TrainConfig, cuda_determinism
    from priqn.train import _torch_device

    monkeypatch.delenv("CUBLAS_WORKSPACE_CONFIG", raising=False)
    before = (torch.are_deterministic_algorithms_enabled(), torch.backends.cudnn.deterministic)
    try:
        cuda_determinism(True)
        assert torch.are_deterministic_algorithms_enabled()
        assert torch.backends.cudnn.deterministic and not torch.backends.cudnn.benchmark
        assert os.environ["CUBLAS_WORKSPACE_CONFIG"] == ":4096:8"
        cuda_determinism(False)
        assert not torch.are_deterministic_algorithms_enabled()
        assert not torch.backends.cudnn.deterministic
        assert _torch_device(TrainConfig(device="cpu", torch_threads=0)).type == "cpu"
        assert not torch.are_deterministic_algorithms_enabled()
    finally:  # as it was (an in-process CUDA run earlier in the session may have set it)
        torch.use_deterministic_algorithms(before[0])
        torch.backends.cudnn.deterministic = before[1]
