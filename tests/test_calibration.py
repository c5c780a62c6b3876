"""The calibration rule (``[calibration]``, priqn.analysis.calibration) on a grid built by hand.

Two rows, two seeds each, densities 0.5 and 1.0, 8 episodes per density and cell
(``fake_runs.write_run``: 2 runs x 2 nets x 2 episodes):

- row ``near``: at 0.5, seed 0 always succeeds and seed 1 collides in episode 0 (half);
  at 1.0 both collide in episode 0. Its mix: success .75 / .5, collision .25 / .5.
- row ``far``: at both densities episode 0 collides and episode 1 times out.
  Its mix: success 0 / 0, collision .5 / .5, timeout .5 / .5.

Target: success .75 / .5, collision .25 / .5, off-road 0 / 0, timeout 0 / 0. So the L1
distance of ``near`` is 0; of ``far`` (.75 + .5) + (.25 + 0) + (.5 + .5) = 2.5.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from fake_runs import IQN, write_run

from priqn.analysis import calibration
from priqn.analysis.artifacts import render
from priqn.analysis.mixes import mean_mix
from priqn.errors import PriqnError
from priqn.experiment import CalibrationSpec, load_experiment

SHA = "c" * 40
DESIGN = """
[experiment]
name = "cal"
seeds = [0, 1]
steps = 1000
runs_dir = "{runs}"

[evaluate]
densities = [0.5, 1.0]
eval_runs = 2
episodes_per_cell = 2

[[policy]]
name = "far"
agent = "iqn"
traffic = "rude"

[[policy]]
name = "near"
agent = "iqn"

[calibration]
target = "a hand-made target"
densities = [0.5, 1.0]
success = [0.75, 0.5]
collision = [0.25, 0.5]
off_road = [0.0, 0.0]
timeout = [0.0, 0.0]
code_commits = ["{sha}"]
"""


def _near(seed, r, d, net, e):
    crash = e == 0 and (d == 1.0 or seed == 1)
    return {"success": not crash, "collision": crash}


def _far(seed, r, d, net, e):
    return {"collision": e == 0, "timeout": e == 1}


def _grid(tmp_path: Path, rows=("far", "near"), sha: str = SHA):
    runs = tmp_path / "results"
    design = tmp_path / "cal.toml"
    design.write_text(DESIGN.format(runs=runs, sha=SHA))
    value = {"far": _far, "near": _near}
    for row in rows:
        for seed in (0, 1):
            name = f"{row}__seed{seed}"
            write_run(runs / "cal", name, "IQN", IQN, seed, value[row],
                      eval_config={"densities": [0.5, 1.0], "eval_runs": 2,
                                   "episodes_per_cell": 2})  # fmt: skip
            meta = {"status": "complete", "git_sha": sha}
            (runs / "cal" / name / "meta.json").write_text(json.dumps(meta))
    return load_experiment(design)


def test_the_rule_picks_the_row_nearest_the_target_by_l1(tmp_path: Path) -> None:
    exp = _grid(tmp_path)
    mixes, missing = calibration.setting_mixes(exp)
    assert missing == []
    mean = mean_mix(mixes)
    near = mean[mean.row == "near"].set_index(["outcome", "density"]).rate
    assert near[("success", 0.5)] == pytest.approx(0.75)
    assert near[("collision", 1.0)] == pytest.approx(0.5)
    dist = calibration.distances(mean, exp.calibration, ["far", "near"])
    by_row = dist.set_index("row")
    assert by_row.loc["near", "l1"] == pytest.approx(0.0)
    assert by_row.loc["far", "l1"] == pytest.approx(2.5)
    assert by_row.loc["far", "timeout"] == pytest.approx(1.0)
    assert calibration.choose(dist) == "near"


def test_each_seed_alone_has_its_own_distance(tmp_path: Path) -> None:
    """``near``'s seeds differ from the target by .25 in success and .25 in collision at
    one density each (seed 0 at 0.5 always succeeds; seed 1 at 0.5 collides half the
    time, as at 1.0), so each seed alone is at L1 0.5 while their mean is at 0. ``far``'s
    seeds are equal: 2.5 each."""
    exp = _grid(tmp_path)
    mixes, _ = calibration.setting_mixes(exp)
    by_row = calibration.seed_mixes(mixes, exp.calibration, ["far", "near"])
    assert by_row["near"].shape == (2, 8)
    target = calibration.target_vector(exp.calibration)
    per_seed = calibration.seed_distances(by_row, target)
    assert per_seed["near"] == pytest.approx([0.5, 0.5])
    assert per_seed["far"] == pytest.approx([2.5, 2.5])
    boot = calibration.choice_bootstrap(by_row, target, 2000, seed=0).set_index("row")
    # near's resamples: (0, 0) or (1, 1) at L1 0.5, a mixed pair at 0: always under 2.5
    assert boot.loc["near", "chosen"] == 1.0 and boot.loc["far", "chosen"] == 0.0
    assert (boot.loc["near", "l1_low"], boot.loc["near", "l1_high"]) == pytest.approx((0, 0.5))


def test_a_seed_without_a_target_density_is_named(tmp_path: Path) -> None:
    exp = _grid(tmp_path)
    mixes, _ = calibration.setting_mixes(exp)
    gap = (mixes["row"] == "near") & (mixes["seed"] == 1) & (mixes["density"] == 1.0)
    with pytest.raises(PriqnError, match=r"near__seed1: no episodes at a density the target"):
        calibration.seed_mixes(mixes[~gap], exp.calibration, ["far", "near"])


def test_the_bootstrap_choice_flips_with_the_resampled_seeds() -> None:
    """One key, target 0.5. Row ``a``: one seed at 0.8 (L1 0.3 in every resample). Row
    ``b``: seeds at 0 and 1, so a resample of two is (0, 0) or (1, 1) with probability
    1/2 (L1 0.5: ``a`` is chosen) and a mixed pair otherwise (L1 0: ``b``)."""
    by_row = {"a": np.array([[0.8]]), "b": np.array([[0.0], [1.0]])}
    boot = calibration.choice_bootstrap(by_row, np.array([0.5]), 10_000, seed=1)
    chosen = boot.set_index("row")["chosen"]
    assert chosen["a"] + chosen["b"] == pytest.approx(1.0)
    assert chosen["b"] == pytest.approx(0.5, abs=0.02)
    again = calibration.choice_bootstrap(by_row, np.array([0.5]), 10_000, seed=1)
    pd.testing.assert_frame_equal(boot, again)
    with pytest.raises(ValueError, match="resamples >= 1"):
        calibration.choice_bootstrap(by_row, np.array([0.5]), 0, seed=1)


def test_a_tie_goes_to_the_row_first_in_the_file() -> None:
    dist = pd.DataFrame({"row": ["b", "a", "c"], "l1": [0.3, 0.3, 0.5]})
    assert calibration.choose(dist) == "b"


def test_report_names_the_choice_and_regenerates_identically(tmp_path: Path) -> None:
    exp = _grid(tmp_path)
    out = tmp_path / "report"
    path = render(out, calibration.calibration_report(exp, "priqn report results/cal --out report"))
    text = path.read_text()
    assert "**chosen: near** (L1 0.000)" in text
    assert "| near | 0: 0.50, 1: 0.50 | [0.00, 0.50] | 100.0% |" in text
    assert "| far | rude | 2 |" in text
    assert "| **paper** |" not in text and "| **target** |" in text
    meta = json.loads((out / "meta.json").read_text())
    assert meta["chosen"] == "near" and meta["final"] and meta["distances"]["far"] == 2.5
    assert meta["bootstrap"] == {"resamples": 10_000, "seed": 2026,
                                 "chosen": {"far": 0.0, "near": 1.0}}  # fmt: skip
    assert meta["command"] == "priqn report results/cal --out report"
    assert (meta["schema"], meta["kind"], meta["experiment"]) == (1, "calibration", "cal")
    first = {p.relative_to(out).as_posix(): p.read_bytes() for p in out.rglob("*.*")}
    render(out, calibration.calibration_report(exp, "priqn report results/cal --out report"))
    assert {p.relative_to(out).as_posix(): p.read_bytes() for p in out.rglob("*.*")} == first
    assert set(first) == {"report.md", "meta.json", "figures/calibration.png",
                          "figures/calibration.pdf", "tables/mix.csv", "tables/distances.csv",
                          "tables/seed_distances.csv", "tables/choice_bootstrap.csv"}  # fmt: skip
    assert "![outcome mix per density](figures/calibration.png)" in text


def test_missing_cells_make_the_choice_provisional(tmp_path: Path) -> None:
    exp = _grid(tmp_path, rows=("far",))
    text = render(tmp_path / "r", calibration.calibration_report(exp, "c")).read_text()
    assert "provisionally nearest (cells missing): far" in text
    assert "- near__seed0: not complete" in text


def test_a_design_of_one_row_is_a_check_with_nothing_to_choose(tmp_path: Path) -> None:
    """A fresh check of a chosen setting (calibrate-tm-check.toml) has one row: the report
    gives its distance, not a choice."""
    exp = _grid(tmp_path, rows=("far",))
    design = exp.path.read_text()
    head, tail = design.split('[[policy]]\nname = "near"')
    exp.path.write_text(head + tail.split("\n\n", 1)[1])
    text = render(
        tmp_path / "r", calibration.calibration_report(load_experiment(exp.path), "c")
    ).read_text()
    assert "**far: L1 2.500** (one row: a check of its setting, nothing to choose)." in text
    assert "chosen: far" not in text


def test_a_cell_from_an_unlisted_commit_is_refused(tmp_path: Path) -> None:
    exp = _grid(tmp_path, sha="d" * 40)
    with pytest.raises(PriqnError, match=r"trained at commit dddddddddddd, which .* does not list"):
        calibration.setting_mixes(exp)


def test_a_target_whose_rates_do_not_sum_to_one_is_refused() -> None:
    with pytest.raises(ValueError, match="density 0.5: the four rates sum to 0.9000"):
        CalibrationSpec("t", (0.5,), (0.5,), (0.3,), (0.1,), (0.0,))
    with pytest.raises(ValueError, match="collision: expected 2 rates"):
        CalibrationSpec("t", (0.5, 1.0), (0.5, 0.5), (0.5,), (0.0, 0.0), (0.0, 0.5))


def test_the_design_must_evaluate_the_target_densities(tmp_path: Path) -> None:
    design = tmp_path / "cal.toml"
    design.write_text(
        DESIGN.format(runs=tmp_path, sha=SHA).replace("[0.5, 1.0]\neval", "[0.5]\neval")
    )
    with pytest.raises(PriqnError, match=r"\[calibration\].densities: \[0.5, 1.0\] are not"):
        load_experiment(design)


def test_the_shipped_design_parses_and_its_target_is_the_papers_iqn_row() -> None:
    exp = load_experiment("calibrate")
    cal = exp.calibration
    assert cal.collision == (0.248, 0.472, 0.538) and cal.success == (0.737, 0.513, 0.434)
    assert len(exp.policies) <= 6 and {p.agent for p in exp.policies} == {"iqn"}
    assert all(len(exp.row_seeds(p)) == 3 and exp.row_steps(p) == 60000 for p in exp.policies)
