"""An evaluation design's report (``priqn report --evaluation``) on hand-built cells.

Two rows (a, b), three training seeds each, two out-of-range nets (``tjunction_00``:
narrow lanes, largest jitter 20.3 deg; ``fourway_02``: wide lanes, 12.6 deg), one density,
four episodes per net. Out of range, a's seeds succeed in 4/4, 3/4 and 2/4 of each net's
episodes (1.0, 0.75, 0.5), b's in 2/4, 1/4 and 0/4 (0.5, 0.25, 0.0); every failure is a
collision on tjunction_00 and a timeout on fourway_02. In range every episode succeeds.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from priqn.analysis.artifacts import render
from priqn.analysis.design_report import design_report, drops, feature_table, read_scores
from priqn.config import from_dict
from priqn.errors import PriqnError
from priqn.evaluation.design import EvaluationDesign, net_features

NETS = ("out-of-range/tjunction_00", "out-of-range/fourway_02")
SUCCESSES = {"a": (4, 3, 2), "b": (2, 1, 0)}  # per seed 1, 2, 3: successes of 4 per net
ENV = {"traffic": {"path_braking": True}, "max_episode_steps": 200}


def _evaluation(folder: Path, row: str, seed: int, successes: int, env: dict) -> None:
    rows = []
    for net in NETS:
        for e in range(4):
            ok = e < successes
            rows.append({"run": folder.parent.name, "label": row.upper(), "train_seed": seed,
                         "eval_run": 0, "net": net, "density": 1.0, "episode": e,
                         "success": ok, "collision": not ok and net == NETS[0],
                         "off_road": False, "timeout": not ok and net == NETS[1]})  # fmt: skip
    folder.mkdir(parents=True)
    pd.DataFrame(rows).to_csv(folder / "episodes.csv", index=False)
    meta = {"status": "complete", "env_config": env, "holdout_hash": "h" * 64}
    (folder / "meta.json").write_text(json.dumps(meta))


def _cells(root: Path, skip: tuple[str, ...] = (), env_out: dict = ENV) -> None:
    for row, counts in SUCCESSES.items():
        for seed, k in zip((1, 2, 3), counts, strict=True):
            cell = root / "grid" / f"{row}__seed{seed}"
            cell.mkdir(parents=True)
            (cell / "meta.json").write_text(json.dumps({"status": "complete"}))
            _evaluation(cell / "eval", row, seed, 4, ENV)
            if cell.name not in skip:
                _evaluation(cell / "eval-family-out-of-range", row, seed, k, env_out)


def _design(root: Path) -> EvaluationDesign:
    data = {
        "design": {
            "name": "oor",
            "family": "out-of-range",
            "a": "a",
            "b": "b",
            "description": "a vs b",
            "feature_skew_split_deg": 18.2,
        },  # fmt: skip
        "source": [
            {
                "experiment": "grid",
                "role": "primary",
                "runs_dir": str(root / "grid"),
                "rows": ["a", "b"],
                "seeds": [1, 2, 3],
                "traffic": "tm",
            }
        ],  # fmt: skip
        "evaluate": {"densities": [1.0], "eval_runs": 1, "episodes_per_cell": 4},
    }
    return from_dict(EvaluationDesign, data, "test design")


def test_scores_verdicts_and_drops_by_hand(tmp_path: Path) -> None:
    _cells(tmp_path)
    design = _design(tmp_path)
    frames = read_scores(design)
    out = frames.scores[frames.scores["where"] == "out of range"].set_index(["row", "seed"])
    assert out["success"].tolist() == [1.0, 0.75, 0.5, 0.5, 0.25, 0.0]
    # b's seed 3: 4 collisions on tjunction_00 and 4 timeouts on fourway_02 of 8 episodes
    assert out.loc[("b", 3), "violation"] == 0.5 and out.loc[("b", 3), "timeout"] == 0.5
    report = design_report(design, "cmd", seed=0, partial=False)
    verdicts = report.sections[1].tables["verdicts"].set_index("endpoint")
    success = verdicts.loc["success"]
    # a - b = 0.75 - 0.25; each row's variance 0.0625, SE sqrt(2 * 0.0625 / 3) = 0.2041,
    # Welch dof 4, t(0.975, 4) = 2.7764: the interval 0.5 -+ 0.5667
    assert success["diff"] == pytest.approx(0.5)
    assert success["lo"] == pytest.approx(0.5 - 2.7764 * 0.2041, abs=1e-3)
    # 3 vs 3 seeds: the permutation test's smallest p is 2 / 20 = 0.1 > 0.05, so nothing
    # is significant, and the one-sided bound (0.5 + t(0.95, 4) 0.2041 = 0.935) lies
    # above the paper's +0.149: inconclusive.
    assert success["p"] >= 0.1 and success["word"] == "inconclusive"
    assert verdicts.loc["violation", "word"] == "no difference found at 3 seeds"
    change = drops(frames).set_index("row")
    # In range every episode succeeds: a's change is mean(0, -0.25, -0.5) = -0.25.
    assert change.loc["a", "success_change"] == pytest.approx(-0.25)
    assert change.loc["b", "violation_change"] == pytest.approx(0.375)  # mean(2/8, 3/8, 4/8)


def test_violations_by_feature_by_hand(tmp_path: Path) -> None:
    _cells(tmp_path)
    table = feature_table(read_scores(_design(tmp_path))).set_index(["feature", "level", "row"])
    # Violations happen on tjunction_00 only (narrow lanes, more skewed): b's seeds there
    # collide in 2/4, 3/4 and 4/4 episodes, mean 0.75; on fourway_02 never.
    narrow = table.loc[("lane width", "below training (< 3 m)", "b")]
    assert narrow["violation"] == pytest.approx(0.75) and narrow["nets"] == 1
    assert table.loc[("lane width", "above training (> 3.6 m)", "b"), "violation"] == 0.0
    assert table.loc[("skew", "largest jitter > 18.2 deg", "a"), "violation"] == pytest.approx(0.25)
    assert list(dict.fromkeys(table.index.get_level_values("feature")))[:2] == [
        "lane width",
        "skew",
    ]


def test_missing_cells_are_refused_or_pending(tmp_path: Path) -> None:
    _cells(tmp_path, skip=("b__seed3",))
    design = _design(tmp_path)
    with pytest.raises(PriqnError, match=r"b__seed3: no complete evaluation on family "
                       r"'out-of-range' \(1 of 6 cells missing\); run 'priqn evaluate"):  # fmt: skip
        design_report(design, "cmd", seed=0, partial=False)
    report = design_report(design, "cmd", seed=0, partial=True)
    words = report.sections[1].tables["verdicts"]["word"].tolist()
    assert words == ["pending (5 of 6 cells)"] * 2
    path = render(tmp_path / "out", report)
    # The missing cells folded per (grid, policy): one line with the seed range.
    assert "b__seed*`: seeds 3\n" in path.read_text()
    assert (tmp_path / "out/figures/seeds.png").is_file()
    assert json.loads((tmp_path / "out/meta.json").read_text())["missing"][0].endswith("b__seed3")


def test_an_evaluation_under_other_traffic_is_refused(tmp_path: Path) -> None:
    _cells(tmp_path, env_out={**ENV, "traffic": {"path_braking": False}})
    with pytest.raises(
        PriqnError, match="eval-family-out-of-range: env traffic .* differs from eval/'s"
    ):
        read_scores(_design(tmp_path))


def test_the_same_traffic_recorded_in_two_forms_is_the_same_traffic(tmp_path: Path) -> None:
    """The committed in-range evaluations recorded tm's path braking flat (older code);
    the out-of-range ones record the table: the same traffic, so the cells are read. A
    table that really differs (CARLA's look-ahead) is still refused."""
    flat = {"path_braking": True, "path_look_ahead_s": 4.35, "path_look_ahead_max_m": 50.0,
            "path_look_ahead_min_m": 2.5, "path_reaction_time_s": 0.0, "path_stop_gap_m": 2.0}  # fmt: skip
    table = {"look_ahead_form": "linear", "look_ahead_s": 4.35, "look_ahead_max_m": 50.0,
             "look_ahead_min_m": 2.5, "reaction_time_s": 0.0, "stop_gap_m": 2.0}  # fmt: skip
    for where, braking in (("same", table), ("other", {**table, "look_ahead_form": "carla"})):
        root = tmp_path / where
        _cells(root, env_out={**ENV, "traffic": {"path_braking": braking}})
        for meta in root.glob("grid/*/eval/meta.json"):
            record = json.loads(meta.read_text())
            meta.write_text(json.dumps({**record, "env_config": {**ENV, "traffic": flat}}))
    assert len(read_scores(_design(tmp_path / "same")).scores) == 12
    with pytest.raises(PriqnError, match="env traffic .* differs from eval/'s"):
        read_scores(_design(tmp_path / "other"))


def test_the_same_seed_gives_the_same_report(tmp_path: Path) -> None:
    _cells(tmp_path)
    design = _design(tmp_path)
    first, second = (design_report(design, "cmd", seed=3, partial=False) for _ in range(2))
    a, b = (r.sections[1].tables["verdicts"] for r in (first, second))
    pd.testing.assert_frame_equal(a, b)
    assert np.isfinite(a["hi_family"]).all()


def test_the_shipped_family_splits_each_designed_feature_four_four() -> None:
    # docs/scenarios.md's table: largest jitter 20.3 deg (tjunction_00) ... 12.6 (fourway_02);
    # each designed level on 4 of the 8 nets.
    nets = pd.DataFrame(net_features("out-of-range", 18.2)).set_index("net")
    assert nets.loc["out-of-range/tjunction_00", "skew"] == "largest jitter > 18.2 deg"
    assert nets.loc["out-of-range/tjunction_03", "skew"] == "largest jitter <= 18.2 deg"  # 17.7
    assert nets.loc["out-of-range/fourway_03", "skew"] == "largest jitter > 18.2 deg"  # 18.3
    for feature in ("lane width", "skew", "junction radius", "lanes", "kind"):
        assert nets[feature].value_counts().tolist() == [4, 4], feature
    assert "in training range" not in set(nets["lane width"]) | set(nets["junction radius"])
