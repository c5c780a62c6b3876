"""priqn inspect on a tiny trained run: frames, subsets, and the evaluated episode."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from priqn.objectives import OBJECTIVES

TINY = [
    "--set", "env.obs_size_px=32",
    "--set", "env.max_episode_steps=12",
    "--set", "replay.learning_starts=64",
    "--set", "replay.capacity=4000",
    "--set", "network.latent_dim=64",
    "--set", "network.hidden_dim=64",
    "--set", "learner.num_tau_samples=8",
    "--set", "learner.num_tau_prime_samples=8",
    "--set", "learner.num_quantiles=8",
    "--set", "evaluation.interval_steps=0",
]  # fmt: skip


def cli(*args: str) -> subprocess.CompletedProcess:
    out = subprocess.run(
        [sys.executable, "-m", "priqn.cli", *args], capture_output=True, text=True, timeout=600
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return out


@pytest.fixture(scope="module")
def evaluated_run(tmp_path_factory) -> Path:
    """A tiny Pr-IQN run (partial order), evaluated on one episode per hold-out cell."""
    root = tmp_path_factory.mktemp("inspect")
    cli("train", "--agent", "pr-iqn", "--steps", "120", "--runs-dir", str(root), "--name", "run",
        "--device", "cpu", "--set", "agent.preorder=partial", *TINY)  # fmt: skip
    cli("evaluate", str(root / "run"), "--episodes", "1", "--eval-runs", "1",
        "--densities", "0.5")  # fmt: skip
    return root / "run"


def _page_rows(page: Path) -> list[dict]:
    text = page.read_text()
    data = re.search(r'<script id="decisions" type="application/json">(.*?)</script>', text, re.S)
    return json.loads(data.group(1))


def test_inspect_shows_the_evaluated_episode_and_its_subsets(evaluated_run, tmp_path):
    episodes = pd.read_csv(evaluated_run / "eval" / "episodes.csv")
    scene = episodes.iloc[0]
    out = tmp_path / "out"
    cli("inspect", str(evaluated_run), "--net", scene["net"], "--density", "0.5", "--out", str(out))

    decisions = pd.read_csv(out / "decisions.csv")
    rows = _page_rows(out / "index.html")
    frames = sorted((out / "frames").glob("*.png"))
    # One frame per decision, in the page and on disk.
    assert len(rows) == len(decisions) == len(frames) == int(scene["steps"])
    assert (out / "episode.gif").stat().st_size > 0 and (out / "summary.png").is_file()
    # Same scene as priqn evaluate: same length, same returns at the end.
    last = decisions.iloc[-1]
    for o in OBJECTIVES:
        assert last[f"return_{o}"] == pytest.approx(scene[f"return_{o}"], abs=1e-5), o
    # The subsets the page shows are optimal_subsets of the saved quantiles.
    from priqn.preorder import Preorder, optimal_subsets
    from priqn.run.folder import RunFolder

    cfg = RunFolder(evaluated_run).config().agent
    saved = np.load(out / "quantiles.npz")
    po = Preorder.resolve(cfg.preorder, OBJECTIVES)
    again = optimal_subsets(torch.from_numpy(saved["quantiles_THKA"]), po, cfg.comparator, cfg.eps)
    shown = np.array([r["subsets"] for r in rows])
    assert np.array_equal(shown, again.per_objective.numpy())
    assert np.array_equal(np.array([r["leaf"] for r in rows]), again.leaf.numpy())
    assert all(again.leaf.numpy()[t, a] for t, a in enumerate(decisions["action"]))
    sizes = again.per_objective.numpy().sum(-1)
    assert decisions[[f"size_{o}" for o in OBJECTIVES]].to_numpy().tolist() == sizes.tolist()
    # The episode table's per-episode subset sizes are the means over the same decisions.
    for o in (*OBJECTIVES, "leaf"):
        assert scene[f"subset_{o}"] == pytest.approx(decisions[f"size_{o}"].mean(), abs=1e-3), o


def test_inspect_refuses_an_unknown_net_in_one_line(evaluated_run, tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "priqn.cli", "inspect", str(evaluated_run), "--net",
         "holdout/nope", "--out", str(tmp_path / "x")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 2
    assert "--net: 'holdout/nope' is not a net of family 'holdout'" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_page_slider_changes_the_frame_in_headless_chromium(evaluated_run, tmp_path):
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        pytest.skip("chromium not installed (apt-get install chromium)")
    out = tmp_path / "out"
    cli("inspect", str(evaluated_run), "--density", "0.5", "--out", str(out))
    probe = (
        (out / "index.html")
        .read_text()
        .replace(
            "show(0);", 'show(0); show(1); document.title = "frame=" + img.getAttribute("src");'
        )
    )
    (out / "probe.html").write_text(probe)
    res = subprocess.run(
        [browser, "--headless", "--no-sandbox", "--disable-gpu", "--dump-dom",
         (out / "probe.html").as_uri()],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert "<title>frame=frames/0001.png</title>" in res.stdout


def test_inspect_the_near_greedy_control_replays_its_evaluated_episode(evaluated_run, tmp_path):
    """--near-greedy EPS inspects the acting-randomness control: the episode evaluate
    --acting near-greedy played (same scene, same acting seed), with the set it sampled
    from as the leaf; a Pr-IQN run is refused in one line."""
    root = tmp_path / "runs"
    cli("train", "--agent", "iqn", "--steps", "120", "--runs-dir", str(root), "--name", "iqn",
        "--device", "cpu", *TINY)  # fmt: skip
    run = root / "iqn"
    cli("evaluate", str(run), "--episodes", "1", "--eval-runs", "1", "--densities", "0.5",
        "--acting", "near-greedy", "--acting-eps", "0.5")  # fmt: skip
    scene = pd.read_csv(run / "eval-near-greedy-eps0.5" / "episodes.csv").iloc[0]
    assert scene["label"] == "IQN near-greedy ε=0.5"
    out = tmp_path / "out"
    cli("inspect", str(run), "--net", scene["net"], "--density", "0.5", "--near-greedy", "0.5",
        "--out", str(out))  # fmt: skip
    decisions = pd.read_csv(out / "decisions.csv")
    assert len(decisions) == int(scene["steps"])
    for o in OBJECTIVES:
        last = decisions.iloc[-1][f"return_{o}"]
        assert last == pytest.approx(scene[f"return_{o}"], abs=1e-5), o
    leaf = np.load(out / "quantiles.npz")["leaf_TA"]
    assert all(leaf[t, a] for t, a in enumerate(decisions["action"]))
    assert decisions["size_near_greedy"].tolist() == leaf.sum(axis=1).tolist()
    assert scene["subset_leaf"] == pytest.approx(decisions["size_near_greedy"].mean(), abs=1e-3)

    refused = subprocess.run(
        [sys.executable, "-m", "priqn.cli", "inspect", str(evaluated_run), "--near-greedy",
         "0.2", "--out", str(tmp_path / "pr")],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert refused.returncode != 0 and len(refused.stderr.strip().splitlines()) == 1
    assert "near-greedy acting applies to agents with one scalar value" in refused.stderr


@pytest.mark.parametrize("density", ["2", "-0.5", "nan"])
def test_inspect_refuses_a_bad_density_in_one_line_before_reading_the_run(
    density, tmp_path, capsys
):
    from priqn.cli import main

    # No run folder: --density is checked first, so no trained run is needed.
    argv = ["inspect", str(tmp_path / "no-run"), "--net", "holdout/fourway_00", "--density"]
    assert main([*argv, density, "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err.strip().splitlines() == [
        f"priqn: error: --density: {float(density):g} is out of range; expected values in "
        "(0, 1] (traffic density = active actors / maximum actors)"
    ]
    assert "Traceback" not in err and not (tmp_path / "x").exists()
