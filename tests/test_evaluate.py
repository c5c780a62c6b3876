"""Evaluation protocol: same scenes for every policy, resumable cells, meta, CLI config.

The protocol is exercised on a tiny fake environment that obeys the IntersectionEnv
info contract (no SUMO), inside gymnasium's SyncVectorEnv with SAME_STEP autoreset.
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv

from priqn.errors import PriqnError
from priqn.evaluation.cli import config_from_args, configure_parser
from priqn.evaluation.protocol import EPISODE_COLUMNS, EvalConfig, make_scenes
from priqn.evaluation.store import cell_file, evaluate_policy

NETS = ["fourway_00", "tjunction_00"]


class FakeEnv(gym.Env):
    """Episode length, outcome and returns are functions of the reset seed and actions."""

    def __init__(self) -> None:
        self.observation_space = gym.spaces.Dict(
            {
                "seed": gym.spaces.Box(0, 2**32, (1,), np.float64),
                "density": gym.spaces.Box(0, 1, (1,), np.float64),
            }
        )
        self.action_space = gym.spaces.Discrete(3)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        options = options or {}
        self.scene_seed = int(seed if seed is not None else self.np_random.integers(2**31))
        self.net = options.get("net", "holdout/random")
        self.density = float(options.get("density", 0.5))
        self.length = 1 + self.scene_seed % 4
        self.t = 0
        self.action_sum = 0
        return self._obs(), {}

    def _obs(self):
        return {"seed": np.array([self.scene_seed], float), "density": np.array([self.density])}

    def step(self, action):
        self.t += 1
        self.action_sum += int(action)
        done = self.t >= self.length
        success = done and (self.scene_seed + self.action_sum) % 2 == 0
        info = {
            "success": success,
            "collision": done and not success,
            "off_road": False,
            "timeout": False,
            "route_progress": self.t / self.length,
            "density_realised": self.density * 0.9,
            "returns": np.array([-self.action_sum, -1.0, 0.5, self.t, 0.0], np.float32),
            "episode_steps": self.t,
            "command": "left",
        }
        return self._obs(), 0.0, done, False, info


class FakePolicy:
    """Action = (scene seed + a draw from the episode's generator) mod 3."""

    def __init__(self, label: str = "IQN", seed: int = 0) -> None:
        self.calls = 0
        self.labels = {
            "agent": "iqn",
            "comparator": None,
            "train_preorder": None,
            "eps": None,
            "partial_order": None,
            "train_seed": seed,
            "label": label,
        }

    def act(self, obs, rng):
        self.calls += 1
        assert obs["seed"].shape == (1, 1)
        return np.array([(int(obs["seed"][0, 0]) + int(rng.integers(3))) % 3], np.int64)

    def decide(self, obs, rng, quantiles=False):
        from priqn.agents.policy import Decision

        return Decision(self.act(obs, rng))


def make_env(num_envs: int):
    return SyncVectorEnv([FakeEnv for _ in range(num_envs)], autoreset_mode=AutoresetMode.SAME_STEP)


CFG = EvalConfig(densities=(0.5, 1.0), eval_runs=2, episodes_per_cell=3, num_workers=2)


def _evaluate(tmp_path, cfg=CFG, policy=None, name="run"):
    policy = policy or FakePolicy()
    out = evaluate_policy(policy, tmp_path / name / "eval", cfg, NETS, "h" * 64, name, make_env)
    return out, policy


def test_scenes_depend_only_on_eval_seed_and_cell() -> None:
    scenes = make_scenes(CFG, list(reversed(NETS)))
    assert len(scenes) == 2 * 2 * 2 * 3
    assert scenes == make_scenes(CFG, NETS)  # net order given does not matter
    assert len({s.reset_seed for s in scenes}) == len(scenes)
    assert scenes[0].net == "holdout/fourway_00" and scenes[0].reset_options() == {
        "net": "holdout/fourway_00",
        "density": 0.5,
    }
    other = make_scenes(
        EvalConfig(densities=(0.5, 1.0), eval_runs=2, episodes_per_cell=3, seed=7), NETS
    )
    assert [s.reset_seed for s in other] != [s.reset_seed for s in scenes]
    cycled = make_scenes(EvalConfig(commands=("left", "right"), episodes_per_cell=3), NETS)
    assert [s.command for s in cycled[:3]] == ["left", "right", "left"]


def test_episode_table_columns_and_meta(tmp_path) -> None:
    out, _ = _evaluate(tmp_path)
    frame = pd.read_csv(out)
    assert list(frame.columns) == list(EPISODE_COLUMNS)
    assert len(frame) == 24
    assert set(frame["net"]) == {f"holdout/{n}" for n in NETS}
    assert sorted(frame["density"].unique()) == [0.5, 1.0]
    assert (frame["density_realised"] == frame["density"] * 0.9).all()
    assert (frame["success"] != frame["collision"]).all()
    assert frame["holdout_hash"].eq("h" * 64).all() and frame["label"].eq("IQN").all()
    meta = json.loads((out.parent / "meta.json").read_text())
    assert meta["status"] == "complete" and meta["holdout_hash"] == "h" * 64
    assert meta["eval_config"]["episodes_per_cell"] == 3 and meta["eval_seed"] == 2026
    assert meta["wall_s"] >= 0.0  # the evaluation's own time, for the grid's cost accounting


def test_results_do_not_depend_on_worker_count(tmp_path) -> None:
    a, _ = _evaluate(tmp_path, name="one", cfg=EvalConfig(**{**CFG.__dict__, "num_workers": 1}))
    b, _ = _evaluate(tmp_path, name="three", cfg=EvalConfig(**{**CFG.__dict__, "num_workers": 3}))
    fa, fb = pd.read_csv(a).drop(columns="run"), pd.read_csv(b).drop(columns="run")
    pd.testing.assert_frame_equal(fa, fb)


def test_every_policy_meets_the_same_scenes(tmp_path) -> None:
    a, _ = _evaluate(tmp_path, name="a", policy=FakePolicy("IQN", seed=0))
    b, _ = _evaluate(tmp_path, name="b", policy=FakePolicy("Other", seed=5))
    keys = ["eval_run", "net", "density", "episode", "reset_seed"]
    pd.testing.assert_frame_equal(pd.read_csv(a)[keys], pd.read_csv(b)[keys])


def test_resume_redoes_only_missing_cells(tmp_path) -> None:
    out, policy = _evaluate(tmp_path)
    full = pd.read_csv(out)
    assert policy.calls > 0
    eval_dir = out.parent
    scene = make_scenes(CFG, NETS)[5]
    cell_file(eval_dir, scene.cell).unlink()
    meta = json.loads((eval_dir / "meta.json").read_text())
    # an interrupted evaluation that had already spent 1000 s on the kept cells
    (eval_dir / "meta.json").write_text(json.dumps({**meta, "status": "running", "wall_s": 1000.0}))
    again = FakePolicy()
    out2 = evaluate_policy(again, eval_dir, CFG, NETS, "h" * 64, "run", make_env)
    redone = full[
        (full["eval_run"] == scene.eval_run)
        & (full["net"] == scene.net)
        & (full["density"] == scene.density)
    ]
    assert again.calls == redone["steps"].sum()  # one act per step of the redone cell only
    pd.testing.assert_frame_equal(pd.read_csv(out2), full)
    resumed = json.loads((eval_dir / "meta.json").read_text())
    assert resumed["status"] == "complete"
    assert 1000.0 <= resumed["wall_s"] < 1100.0  # time spent before the stop is kept


class StopsAfter(FakePolicy):
    """A policy whose process is stopped (Ctrl-C) after ``calls_left`` decisions."""

    def __init__(self, calls_left: int) -> None:
        super().__init__()
        self.calls_left = calls_left

    def act(self, obs, rng):
        if self.calls == self.calls_left:
            raise KeyboardInterrupt
        return super().act(obs, rng)


def test_an_interrupted_evaluation_keeps_its_time(tmp_path) -> None:
    eval_dir = tmp_path / "run" / "eval"
    with pytest.raises(KeyboardInterrupt):
        evaluate_policy(StopsAfter(40), eval_dir, CFG, NETS, "h" * 64, "run", make_env)
    stopped = json.loads((eval_dir / "meta.json").read_text())
    assert stopped["status"] == "running" and list((eval_dir / "cells").iterdir())
    assert stopped["wall_s"] >= 0.0  # written when the last finished cell landed
    # the stopped attempt's time, as if it had been long, is carried into the resumed one
    (eval_dir / "meta.json").write_text(json.dumps({**stopped, "wall_s": 1000.0}))
    evaluate_policy(FakePolicy(), eval_dir, CFG, NETS, "h" * 64, "run", make_env)
    resumed = json.loads((eval_dir / "meta.json").read_text())
    assert resumed["status"] == "complete" and 1000.0 <= resumed["wall_s"] < 1100.0


def test_refuses_to_mix_with_other_holdout_or_config(tmp_path) -> None:
    out, _ = _evaluate(tmp_path)
    with pytest.raises(PriqnError, match="different hold-out set"):
        evaluate_policy(FakePolicy(), out.parent, CFG, NETS, "x" * 64, "run", make_env)
    cfg = EvalConfig(**{**CFG.__dict__, "episodes_per_cell": 2})
    with pytest.raises(PriqnError, match="different eval_config.*episodes_per_cell 3 -> 2"):
        evaluate_policy(FakePolicy(), out.parent, cfg, NETS, "h" * 64, "run", make_env)
    more_workers = EvalConfig(**{**CFG.__dict__, "num_workers": 1})
    evaluate_policy(FakePolicy(), out.parent, more_workers, NETS, "h" * 64, "run", make_env)
    out3 = evaluate_policy(
        FakePolicy(), out.parent, cfg, NETS, "h" * 64, "run", make_env, force=True
    )
    assert len(pd.read_csv(out3)) == 16


def test_config_from_args_and_validation(tmp_path) -> None:
    parser = argparse.ArgumentParser()
    configure_parser(parser)
    args = parser.parse_args(
        ["runs/x", "--episodes", "2", "--densities", "0.5,1", "--set", "eval_runs=1"]
    )
    cfg = config_from_args(args)
    assert (cfg.episodes_per_cell, cfg.densities, cfg.eval_runs) == (2, (0.5, 1.0), 1)
    with pytest.raises(PriqnError, match="densities"):
        config_from_args(parser.parse_args(["r", "--densities", "0.5,1.5"]))
    with pytest.raises(PriqnError, match="unknown key"):
        config_from_args(parser.parse_args(["r", "--set", "episodes=3"]))


def test_acting_option_validation_flags_and_older_records() -> None:
    """``acting`` is checked and settable from the CLI; a record written before the field
    existed reads as its default ("own"), so older evaluations are not stale."""
    from priqn.evaluation.protocol import eval_config_changes
    from priqn.run.folder import RunFolder

    with pytest.raises(ValueError, match="acting: 'random' is not one of own, near-greedy"):
        EvalConfig(acting="random")
    with pytest.raises(
        ValueError, match=r"^acting_eps: -0.1 is out of range; expected a tolerance >= 0"
    ):
        EvalConfig(acting_eps=-0.1)
    parser = argparse.ArgumentParser()
    configure_parser(parser)
    cfg = config_from_args(
        parser.parse_args(["r", "--acting", "near-greedy", "--acting-eps", "0.1"])
    )
    assert (cfg.acting, cfg.acting_eps) == ("near-greedy", 0.1)
    with pytest.raises(
        PriqnError, match=r"^--acting-eps: -1 is out of range; expected a tolerance >= 0"
    ):
        config_from_args(parser.parse_args(["r", "--acting", "near-greedy", "--acting-eps", "-1"]))

    from priqn.config import to_dict
    from priqn.evaluation.protocol import control_config, eval_dir_of, evaluation_name

    old = {k: v for k, v in to_dict(CFG).items() if k not in ("acting", "acting_eps")}
    assert eval_config_changes(old, to_dict(CFG)) == ""
    changed = dataclasses.replace(CFG, acting="near-greedy")
    assert eval_config_changes(old, to_dict(changed)) == "acting 'own' -> 'near-greedy'"
    run = RunFolder("runs/x")
    assert eval_dir_of(run, CFG) == run.path / "eval"
    assert eval_dir_of(run, changed) == run.path / "eval-near-greedy"
    other = dataclasses.replace(changed, acting_eps=0.05)
    assert eval_dir_of(run, other) == run.path / "eval-near-greedy-eps0.05"
    for cfg in (CFG, changed, other):  # the control name round-trips
        assert control_config(CFG, evaluation_name(cfg)) == cfg
    for bad in ("coin", "own", "near-greedy-eps", "near-greedy-epsx"):
        with pytest.raises(PriqnError, match=f"control {bad!r}: "):
            control_config(CFG, bad)


def test_evaluate_run_rejects_missing_and_unfinished_runs(tmp_path) -> None:
    from priqn.evaluation.cli import evaluate_run

    with pytest.raises(PriqnError, match="no such run folder"):
        evaluate_run(tmp_path / "nope", CFG)
    run = tmp_path / "r"
    run.mkdir()
    with pytest.raises(PriqnError, match="meta.json: missing"):
        evaluate_run(run, CFG)
    (run / "meta.json").write_text(json.dumps({"status": "running"}))
    with pytest.raises(PriqnError, match="status is 'running'"):
        evaluate_run(run, CFG)


# ----------------------------------------------------------------------------- end to end


TINY_TRAIN = [
    "--steps", "20", "--num-envs", "1", "--device", "cpu",
    "--set", "env.obs_size_px=32",
    "--set", "env.max_episode_steps=15",
    "--set", "replay.learning_starts=10",
    "--set", "learner.batch_size=4",
    "--set", "evaluation.interval_steps=100000",
    "--set", "checkpoint.interval_steps=100000",
]  # fmt: skip


def _priqn(args: list[str], cwd) -> None:
    import subprocess
    import sys

    proc = subprocess.run(
        [sys.executable, "-m", "priqn.cli", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, f"priqn {' '.join(args)} failed:\n{proc.stdout}\n{proc.stderr}"


@pytest.fixture(scope="module")
def tiny_runs(tmp_path_factory):
    """Four tiny trained runs (IQN, Pr-IQN; training seeds 0 and 1: a report needs two
    seeds per policy for its CIs), trained through the CLI in subprocesses."""
    pytest.importorskip("priqn.train", reason="priqn.train (training engineer) not there yet")
    root = tmp_path_factory.mktemp("e2e")
    runs = root / "runs"
    for agent in ("iqn", "pr-iqn"):
        for seed in ("0", "1"):
            _priqn(
                [
                    "train",
                    "--agent",
                    agent,
                    "--seed",
                    seed,
                    "--runs-dir",
                    str(runs),
                    "--name",
                    f"{agent}_s{seed}",
                    *TINY_TRAIN,
                ],
                root,
            )
    return root, runs


@pytest.mark.slow
def test_end_to_end_train_evaluate_report(tiny_runs) -> None:
    root, runs = tiny_runs
    tiny_eval = [
        "--episodes",
        "1",
        "--eval-runs",
        "2",
        "--densities",
        "0.5",
        "--workers",
        "1",
        "--set",
        "max_episode_steps=15",
    ]
    _priqn(["evaluate", str(runs), *tiny_eval], root)
    for agent in ("iqn_s0", "iqn_s1", "pr-iqn_s0", "pr-iqn_s1"):
        frame = pd.read_csv(runs / agent / "eval" / "episodes.csv")
        assert list(frame.columns) == list(EPISODE_COLUMNS)
        assert len(frame) == 2 * 3  # eval runs x hold-out nets x densities x episodes
        assert frame["holdout_hash"].nunique() == 1 and (frame["steps"] <= 15).all()
        meta = json.loads((runs / agent / "eval" / "meta.json").read_text())
        assert meta["status"] == "complete"
    a = pd.read_csv(runs / "iqn_s0" / "eval" / "episodes.csv")
    b = pd.read_csv(runs / "pr-iqn_s0" / "eval" / "episodes.csv")
    keys = ["eval_run", "net", "density", "episode", "reset_seed", "command"]
    pd.testing.assert_frame_equal(a[keys], b[keys])  # same scenes for both policies

    # The acting-randomness control: IQN runs only (Pr-IQN is skipped), same scenes.
    _priqn(["evaluate", str(runs), *tiny_eval, "--acting", "near-greedy"], root)
    assert not (runs / "pr-iqn_s0" / "eval-near-greedy").exists()
    c = pd.read_csv(runs / "iqn_s0" / "eval-near-greedy" / "episodes.csv")
    pd.testing.assert_frame_equal(a[keys], c[keys])
    assert set(c["label"]) == {"IQN near-greedy ε=0.2"} and (c["subset_leaf"] >= 1).all()

    out = root / "report"
    _priqn(["report", str(runs), "--out", str(out), "--reps", "50"], root)
    expected = [
        "report.md",
        "meta.json",
        *(f"tables/{t}.{e}" for t in ("table1", "table2") for e in ("md", "tex", "csv")),
        "tables/rliable_aggregates.csv",
        "tables/probability_of_improvement.csv",
        "tables/performance_profiles.csv",
        *(
            f"figures/{f}.{e}"
            for f in (
                "probability_of_improvement",
                "iqm_optimality_gap",
                "performance_profile",
                "learning_curves",
            )
            for e in ("png", "pdf")
        ),
    ]
    missing = [name for name in expected if not (out / name).is_file()]
    assert not missing, missing
    report = (out / "report.md").read_text()
    assert "| IQN |" in report and "Pr-IQN" in report
    assert "| IQN (near-greedy ε=0.2) |" in report


def test_densities_flag_out_of_range_blames_the_flag(tmp_path) -> None:
    import subprocess
    import sys

    out = subprocess.run(
        [sys.executable, "-m", "priqn.cli", "evaluate", str(tmp_path), "--densities", "1.5"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert out.returncode == 2
    assert "--densities: 1.5 is out of range; expected values in (0, 1]" in out.stderr
    assert "--set" not in out.stderr


def test_rollout_yields_each_decision_once_and_the_episode_at_its_end() -> None:
    """The one rollout loop: every scene's decisions in order, numbered from 0, the
    episode's values on its last decision only; the same for any worker count."""
    from priqn.evaluation.rollout import rollout

    scenes = make_scenes(CFG, NETS)[:7]
    by_workers = {}
    for workers in (1, 3):
        env = make_env(workers)
        try:
            steps = list(rollout(FakePolicy(), env, scenes))
        finally:
            env.close()
        per_scene: dict = {}
        for s in steps:
            per_scene.setdefault(s.scene, []).append(s)
        assert list(per_scene) == scenes if workers == 1 else set(per_scene) == set(scenes)
        for scene, played in per_scene.items():
            assert [s.step for s in played] == list(range(len(played)))
            assert [s.episode is not None for s in played] == [False] * (len(played) - 1) + [True]
            assert played[-1].episode["steps"] == len(played) == 1 + scene.reset_seed % 4
            assert all(s.decision.actions_B.tolist() == [s.action] for s in played)
            assert all(s.frame is None and s.reward_N.shape == (1,) for s in played)
        by_workers[workers] = {
            scene: [s.action for s in played] for scene, played in per_scene.items()
        }
    assert by_workers[1] == by_workers[3]
