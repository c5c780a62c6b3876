"""Issue 71, before any evaluation: where an evaluation on another scenario family goes
(``eval-family-<name>/``, never ``eval/``), and the pre-registered evaluation design
(``priqn/data/evaluations/out-of-range.toml``) parses and names committed cells. The family
and its nets are checked in tests/test_scenarios.py and tests/test_roadmap.py."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from fake_runs import IQN, PR, iqn_value, pr_value, write_run

from priqn.analysis.load import list_evaluations, load_evaluation
from priqn.errors import PriqnError
from priqn.evaluation.cli import config_from_args, configure_parser
from priqn.evaluation.design import load_design
from priqn.evaluation.protocol import (
    EvalConfig,
    eval_dir_of,
    evaluation_name,
    is_family_evaluation,
    is_nets_evaluation,
    limit_of,
    snapshot_budget,
)
from priqn.experiment import load_experiment
from priqn.run.folder import RunFolder

REPO = Path(__file__).resolve().parents[1]


# --------------------------------------------------------------------------- folder names


def test_another_family_evaluates_beside_eval_and_the_own_family_into_eval() -> None:
    run = RunFolder("runs/x")
    own = EvalConfig()  # holdout, the run's own hold-out family
    oor = dataclasses.replace(own, family="out-of-range")
    assert evaluation_name(own) == "" and eval_dir_of(run, own) == Path("runs/x/eval")
    assert evaluation_name(oor) == "family-out-of-range"
    assert eval_dir_of(run, oor) == Path("runs/x/eval-family-out-of-range")
    # The design's limit is the run's (max_episode_steps) and keeps the name; an
    # evaluation-only limit, a snapshot and a control stack as for eval/.
    assert evaluation_name(dataclasses.replace(oor, max_episode_steps=200)) == (
        "family-out-of-range"
    )
    both = dataclasses.replace(oor, snapshot=60000, episode_limit=600, acting="near-greedy")
    assert evaluation_name(both) == "at60000-family-out-of-range-limit600-near-greedy"
    assert limit_of(evaluation_name(both)) == 600
    assert snapshot_budget(evaluation_name(both)) == (
        60000, "family-out-of-range-limit600-near-greedy"
    )  # fmt: skip
    # "Own" is the run's hold-out family: a run whose evaluation.family is another one
    # writes that one to eval/ and the hold-out family beside it.
    assert evaluation_name(oor, own_family="out-of-range") == ""
    assert evaluation_name(own, own_family="out-of-range") == "family-holdout"
    # Names read back: a family evaluation is neither a nets evaluation nor a control.
    assert is_family_evaluation("family-out-of-range")
    assert is_family_evaluation("at60000-family-out-of-range-near-greedy")
    assert not is_family_evaluation("near-greedy") and not is_family_evaluation("nets-01234567")
    assert not is_nets_evaluation("family-out-of-range")
    with pytest.raises(PriqnError, match=r"family '\.\./x': expected a scenario family's name"):
        evaluation_name(dataclasses.replace(own, family="../x"))


def test_cli_family_flag_reaches_the_folder_name() -> None:
    import argparse

    parser = argparse.ArgumentParser()
    configure_parser(parser)
    cfg = config_from_args(
        parser.parse_args(["r", "--family", "out-of-range", "--set", "max_episode_steps=200"])
    )
    assert (cfg.family, cfg.max_episode_steps) == ("out-of-range", 200)
    assert eval_dir_of(RunFolder("r"), cfg) == Path("r/eval-family-out-of-range")
    assert eval_dir_of(RunFolder("r"), config_from_args(parser.parse_args(["r"]))) == Path("r/eval")


def test_evaluate_run_routes_by_the_runs_own_family(tmp_path: Path, monkeypatch) -> None:
    """evaluate_run picks the folder before loading any policy or SUMO: a complete
    evaluation already in the chosen folder is returned as it is (nothing runs)."""
    from priqn.evaluation import cli as eval_cli

    calls = []

    def fake_target(cfg, commands):
        calls.append(cfg.family)
        return ["n0"], f"hash-{cfg.family}", None

    def fake_earlier(eval_dir, holdout_hash, eval_config):
        return {"status": "complete"}

    class _Config:
        class evaluation:  # noqa: N801 - stands for TrainConfig.evaluation
            family = "holdout"

        class env:  # noqa: N801
            commands = ()

    run = tmp_path / "cell"
    for folder in ("eval", "eval-family-out-of-range"):
        (run / folder).mkdir(parents=True)
        (run / folder / "episodes.csv").write_text("x\n")
    (run / "meta.json").write_text('{"status": "complete"}')
    monkeypatch.setattr(eval_cli, "evaluation_target", fake_target)
    monkeypatch.setattr(eval_cli, "earlier_evaluation", fake_earlier)
    monkeypatch.setattr(RunFolder, "config", lambda self: _Config)
    monkeypatch.setattr(eval_cli, "load_policy", lambda *a, **k: pytest.fail("nothing to play"))
    oor = EvalConfig(family="out-of-range")
    assert eval_cli.evaluate_run(run, oor) == run / "eval-family-out-of-range" / "episodes.csv"
    assert eval_cli.evaluate_run(run, EvalConfig()) == run / "eval" / "episodes.csv"
    # A sweep cell's [evaluate] family is its own: eval/ (as before).
    assert eval_cli.evaluate_run(run, oor, own_family="out-of-range") == (
        run / "eval" / "episodes.csv"
    )
    assert calls == ["out-of-range", "holdout", "out-of-range"]


def test_the_env_plays_the_family() -> None:
    """The evaluation env of a run is set to the family, and the env draws from its nets
    (found only by playing it: the pool names were fixed to the training ones, so 'priqn
    evaluate --family out-of-range' stopped in EnvConfig with a traceback); an unknown
    family is one line naming env.family, with the nearest name."""
    from priqn.env.scenes import ScenePool, known_pools
    from priqn.evaluation.targets import evaluation_env
    from priqn.run.train_config import resolve_config

    env = evaluation_env(resolve_config().env, EvalConfig(family="out-of-range"), None)
    assert env.family == "out-of-range" and "out-of-range" in known_pools()
    pool = ScenePool(env.family, env.nets_dir, marking_width_m=0.5)
    assert len(pool) == 8 and all(ref.startswith("out-of-range/") for ref in pool.refs)
    with pytest.raises(
        PriqnError,
        match=r"^evaluation env\.family: unknown pool 'out-of-rang' .*did you mean 'out-of-range'\?$",
    ):
        evaluation_env(resolve_config().env, EvalConfig(family="out-of-rang"), None)


def test_an_out_of_range_net_resets_and_steps() -> None:
    """One episode start on a three-lane, skewed out-of-range net, in SUMO."""
    import gymnasium

    import priqn  # noqa: F401 - registers the env

    env = gymnasium.make("priqn/Intersection-v0", family="out-of-range", obs_size_px=64)
    try:
        options = {"density": 1.0, "net": "out-of-range/tjunction_02", "command": "left"}
        obs, info = env.reset(seed=0, options=options)
        assert info["net"] == "out-of-range/tjunction_02"
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert reward.shape == (5,)
    finally:
        env.close()


@pytest.mark.parametrize("side", ["eval-family-out-of-range", "eval-traffic-tm-carla"])
def test_table2_never_reads_a_family_or_traffic_evaluation(runs: Path, side: str) -> None:
    """Evaluations on another family or under another traffic (issue 68's
    ``eval-traffic-<name>/``) are reported apart: Table II reads ``eval/`` only."""
    before = load_evaluation(runs)
    for seed in (0, 1):
        write_run(runs, f"iqn_s{seed}", "IQN", IQN, seed, pr_value, eval_dir_name=side)
        write_run(runs, f"pr_s{seed}", "Pr-IQN QD ✓ 0.2 ✗", PR, seed, iqn_value, eval_dir_name=side)
    after = load_evaluation(runs)
    assert [r.eval_dir for r in after.runs] == ["eval"] * 4
    assert after.episodes.equals(before.episodes)
    run_dirs = sorted(p for p in runs.iterdir() if p.is_dir())
    assert list_evaluations(run_dirs, nets=True) == ([], [])


# --------------------------------------------------------------------------- the design


def test_out_of_range_design_parses_and_names_committed_cells() -> None:
    design = load_design("out-of-range")
    d = design.design
    assert (d.name, d.family, d.a, d.b) == (
        "out-of-range",
        "out-of-range",
        "pr-iqn-qd-tp-eps0.2",
        "iqn",
    )
    assert d.paper_success_difference == pytest.approx(0.149) and d.alpha == 0.05
    assert [(s.experiment, s.role) for s in design.source] == [
        ("paper-point-tm", "primary"), ("paper-point", "secondary"), ("headline", "secondary"),
    ]  # fmt: skip
    limits = {"paper-point-tm": 200, "paper-point": 0, "headline": 0}
    for s in design.source:
        exp = load_experiment(s.experiment)
        # The design's own rows, seeds, traffic and protocol, as its experiment file says.
        assert set(s.rows) == {p.name for p in exp.policies}, s.experiment
        assert s.seeds == tuple(exp.experiment.seeds), s.experiment
        assert s.traffic == (exp.experiment.traffic or "sumo")
        assert s.max_episode_steps == limits[s.experiment]
        cfg = design.eval_config(s)
        ev = {**exp.evaluate, "family": "out-of-range"}
        assert dataclasses.replace(cfg, max_episode_steps=0) == dataclasses.replace(
            EvalConfig(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in ev.items()}),
            max_episode_steps=0,
        )
        assert cfg.max_episode_steps == exp.evaluate.get("max_episode_steps", 0)
        assert evaluation_name(cfg) == "family-out-of-range"
        # Every named cell is committed, trained and evaluated in range.
        for cell in s.cell_dirs(REPO):
            assert (cell / "eval" / "meta.json").is_file(), cell
            assert (cell / "config.toml").is_file(), cell
    assert design.cells() == 40 + 40 + 68


def test_bad_design_is_one_line(tmp_path: Path) -> None:
    text = (REPO / "priqn/data/evaluations/out-of-range.toml").read_text(encoding="utf-8")
    cases = {
        'name = "out-of-range"': ("name = \"other\"", r"design\.name: 'other' differs from the file name"),
        'role = "primary"': ('role = "first"', r"role: expected one of primary, secondary"),
        'traffic = "tm-long"': ('traffic = "tm-lng"', r"traffic: unknown setting 'tm-lng'"),
        'rows = ["iqn", "pr-iqn-qd-tp-eps0.2"]': ('rows = ["iqn"]', r"rows lack the design's row 'pr-iqn-qd-tp-eps0.2'"),
        "eval_runs = 3": ("eval_runs = 3\nepisodes = 6", r"unknown key 'episodes'"),
    }  # fmt: skip
    for old, (new, pattern) in cases.items():
        path = tmp_path / "out-of-range.toml"
        path.write_text(text.replace(old, new, 1), encoding="utf-8")
        with pytest.raises(PriqnError, match=pattern) as exc:
            load_design(path)
        assert "\n" not in str(exc.value)
