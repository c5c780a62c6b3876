"""docs/your-own-agent.md, run: an agent priqn does not ship trains, evaluates, reports and
is inspected through ``agent.name = "tests.agent_example:SHIELDED_IQN"``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
AGENT = "tests.agent_example:SHIELDED_IQN"

TINY = [
    "--steps", "120", "--device", "cpu", "--seed", "3",
    "--set", "env.obs_size_px=32", "--set", "env.max_episode_steps=25",
    "--set", "replay.learning_starts=64", "--set", "replay.capacity=4000",
    "--set", "network.latent_dim=64", "--set", "network.hidden_dim=64",
    "--set", "learner.num_tau_samples=8", "--set", "learner.num_tau_prime_samples=8",
    "--set", "learner.num_quantiles=8", "--set", "log_interval_steps=50",
    "--set", "evaluation.interval_steps=0",
]  # fmt: skip
EVAL = ["--episodes", "1", "--eval-runs", "1", "--densities", "0.5"]


def cli(*args: str, ok: bool = True) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg", PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-m", "priqn.cli", *args], capture_output=True,
                         text=True, timeout=600, cwd=ROOT, env=env)  # fmt: skip
    assert (out.returncode == 0) == ok, out.stderr[-3000:]
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    """The shielded agent and a tiny IQN, each trained and evaluated, in one runs folder."""
    root = tmp_path_factory.mktemp("own-agent")
    for name, agent in (("shielded", AGENT), ("iqn", "iqn")):
        cli("train", "--agent", agent, "--runs-dir", str(root), "--name", name, *TINY)
        cli("evaluate", str(root / name), *EVAL)
    return root


def test_an_agent_from_a_test_module_trains_with_its_own_heads(runs):
    meta = json.loads((runs / "shielded" / "meta.json").read_text())
    assert meta["status"] == "complete" and meta["labels"]["agent"] == AGENT
    import torch

    state = torch.load(runs / "shielded" / "policy.pt", weights_only=True)
    assert state["online"]["head_out.weight"].shape[0] == 2 * 25  # two heads x 25 actions
    metrics = pd.read_csv(runs / "shielded" / "metrics.csv")
    assert (metrics["kind"] == "train").any() and metrics["loss"].notna().any()


def test_it_is_evaluated_reported_and_inspected(runs, tmp_path):
    episodes = pd.read_csv(runs / "shielded" / "eval" / "episodes.csv")
    assert set(episodes["agent"]) == {AGENT} and set(episodes["label"]) == {AGENT}
    cli("report", str(runs), "--out", str(tmp_path / "report"), "--reps", "20")
    table2 = pd.read_csv(tmp_path / "report" / "tables" / "table2.csv")
    assert table2["label"].tolist() == ["IQN", AGENT]  # its own row, after the shipped ones
    assert (
        f"| {AGENT} | – | – | – | – |" in (tmp_path / "report" / "tables" / "table2.md").read_text()
    )
    scene = episodes.iloc[0]
    out = tmp_path / "inspect"
    cli("inspect", str(runs / "shielded"), "--net", scene["net"], "--density", "0.5",
        "--out", str(out))  # fmt: skip
    decisions = pd.read_csv(out / "decisions.csv")
    assert len(decisions) and decisions["action"].notna().all()


def test_a_run_folder_cannot_supply_its_agent_module(runs, tmp_path):
    """Trust model: an agent module that would be imported from the run folder is refused."""
    import shutil

    from priqn.errors import PriqnError
    from priqn.run.folder import RunFolder

    run = tmp_path / "evil_pkg_run"
    shutil.copytree(runs / "shielded", run)
    (run / "__init__.py").write_text("raise SystemExit('ran')\n")
    text = (run / "config.toml").read_text().replace(AGENT, "evil_pkg_run:AGENT")
    (run / "config.toml").write_text(text)
    sys.path.insert(0, str(tmp_path))
    try:
        with pytest.raises(PriqnError, match=r"agent.name names 'evil_pkg_run:AGENT'.*run folder"):
            RunFolder(run).config()
    finally:
        sys.path.remove(str(tmp_path))


def test_a_sweep_grid_may_name_the_agent_by_path(tmp_path: Path, monkeypatch) -> None:
    """An experiment row with ``agent = "package.module:NAME"`` expands into cells that
    train it (the experiment file is the user's own, so its agent is imported by intent)."""
    from priqn.sweep import expand, load_experiment
    from priqn.sweep.cells import build_train_config

    monkeypatch.syspath_prepend(str(ROOT))
    path = tmp_path / "own.toml"
    path.write_text(
        f'[experiment]\nname = "own"\nseeds = [0]\nnet = "tjunction"\n'
        f'[[policy]]\nname = "shielded"\nagent = "{AGENT}"\n'
        '[[policy]]\nname = "iqn"\nagent = "iqn"\n'
    )
    cells = expand(load_experiment(path, runs_dir=tmp_path))
    assert [(c.policy, c.agent) for c in cells] == [("shielded", AGENT), ("iqn", "iqn")]
    assert build_train_config(cells[0]).agent.name == AGENT
    assert cells[0].controls == ()  # a path-named agent gets no near-greedy control
    path.write_text(path.read_text().replace(AGENT, "tests.agent_example:NO_SUCH"))
    with pytest.raises(Exception, match=r"own.toml \[\[policy\]\] shielded.agent: module"):
        load_experiment(path, runs_dir=tmp_path)
