"""The horizon (``priqn evaluate --max-episode-steps N``, ``priqn report --horizon``) on
fake runs whose outcomes a person can count: at the runs' own limit (100) every episode 0 of a
cell times out and every episode 1 succeeds; at 600 the cut episodes end in a collision on
net a and a success on net b."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fake_runs import IQN, write_run

from priqn.analysis.artifacts import render
from priqn.analysis.horizon import horizon_report, limit_episodes, timeout_table
from priqn.analysis.load import load_evaluation
from priqn.analysis.mixes import common_scenes, mix_table
from priqn.errors import PriqnError
from priqn.evaluation.protocol import EvalConfig, evaluation_name, limit_of


def _own(seed, r, d, net, e):
    return {"success": e == 1, "timeout": e == 0}


def _at600(seed, r, d, net, e):
    cut = e == 0
    return {"success": not (cut and net == "holdout/a"), "collision": cut and net == "holdout/a"}


def _runs(root: Path) -> Path:
    for seed in (0, 1):
        name = f"iqn__seed{seed}"
        write_run(root, name, "IQN", IQN, seed, _own)
        write_run(root, name, "IQN", IQN, seed, _at600, eval_dir_name="eval-limit600")
        for folder in ("eval", "eval-limit600"):  # the env each evaluation played
            meta = root / name / folder / "meta.json"
            data = json.loads(meta.read_text())
            data["env_config"] = {"max_episode_steps": 100 if folder == "eval" else 600}
            meta.write_text(json.dumps(data))
    return root


def test_an_evaluation_only_limit_has_its_own_folder_name() -> None:
    assert evaluation_name(EvalConfig(episode_limit=600)) == "limit600"
    assert evaluation_name(EvalConfig(episode_limit=600, snapshot=60000)) == "at60000-limit600"
    assert limit_of("at60000-limit600-near-greedy") == 600
    assert limit_of("near-greedy") == 0 and limit_of("") == 0
    # The protocol's own override stays in the run's own evaluation (eval/), as before.
    assert evaluation_name(EvalConfig(max_episode_steps=200)) == ""


def test_mix_and_where_the_timeouts_go_by_hand(tmp_path: Path) -> None:
    episodes = limit_episodes(_runs(tmp_path), [600])
    mix = mix_table(episodes, "limit").set_index(["limit", "density"])
    assert mix.loc[(100, 0.5), "timeout"] == 0.5 and mix.loc[(100, 0.5), "success"] == 0.5
    assert mix.loc[(600, 1.0), "success"] == 0.75 and mix.loc[(600, 1.0), "collision"] == 0.25
    assert mix.loc[(600, 1.0), "timeout"] == 0.0 and mix.loc[(600, 1.0), "seeds"] == 2
    moved = timeout_table(episodes).iloc[0]
    assert moved["episodes"] == 32 and moved["cut_at_own_limit"] == 0.5
    assert moved["cut_then_collision"] == 0.5 and moved["cut_then_success"] == 0.5
    assert moved["others_changed"] == 0.0


def test_the_report_and_its_errors(tmp_path: Path) -> None:
    runs = _runs(tmp_path / "runs")
    path = render(tmp_path / "out", horizon_report(runs, [600], "priqn report runs --horizon 600"))
    text = path.read_text()
    # cut 50 %; then success 50 %, collision 50 %, off-road 0, timeout 0; others changed 0
    assert "| IQN | 600 | 32 | 50.0 % | 50.0 % | 50.0 % | 0.0 % | 0.0 % | 0.0 % |" in text
    assert (tmp_path / "out" / "tables" / "horizon_mix.csv").is_file()
    with pytest.raises(PriqnError, match="eval-limit200: no complete evaluation; run 'priqn "
                       "evaluate .* --max-episode-steps 200'"):  # fmt: skip
        horizon_report(runs, [200], "")


def test_table_ii_leaves_the_limit_evaluations_out(tmp_path: Path) -> None:
    evaluation = load_evaluation(_runs(tmp_path))
    assert len(evaluation.episodes) == 32  # eval/ of both seeds only


def test_an_output_folder_that_cannot_be_made_is_one_line(tmp_path: Path) -> None:
    from priqn.io import ensure_dir

    (tmp_path / "file").write_text("")
    with pytest.raises(PriqnError, match=r"file/out: cannot write"):
        ensure_dir(tmp_path / "file" / "out")
    runs = _runs(tmp_path / "runs")
    with pytest.raises(PriqnError, match="^/proc/x: cannot write"):
        render(Path("/proc/x"), horizon_report(runs, [600], ""))


def test_the_mix_is_over_the_scenes_played_at_every_limit(tmp_path: Path) -> None:
    # The longer limit played only the first evaluation run's scenes (--eval-runs 1): the
    # own limit's mix is taken over those scenes too (8 per seed, not 16).
    episodes = limit_episodes(_runs(tmp_path), [600])
    short = episodes[episodes["eval_run"] == 0]
    kept = common_scenes(
        episodes[(episodes["limit"] == 100) | (episodes["eval_run"] == 0)], "limit"
    )
    assert len(kept) == len(short) and set(kept["eval_run"]) == {0}
