"""analysis/: loading, Tables I/II, rliable statistics, report — on hand-checkable tables."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from fake_runs import ENS, EVAL_CONFIG, HASH, IQN, PR, iqn_value, pr_value, write_run

from priqn.analysis import tables
from priqn.analysis.claims import CLAIMS, evaluate_claims
from priqn.analysis.load import check_seeds, load_evaluation
from priqn.analysis.report import make_report
from priqn.analysis.stats import (
    SEED_RUN_AXIS,
    aggregate_estimates,
    probability_of_improvement,
    score_matrices,
)
from priqn.errors import PriqnError


def test_load_sorts_and_checks(runs) -> None:
    ev = load_evaluation(runs)
    assert len(ev.episodes) == 4 * 2 * 2 * 2 * 2
    assert ev.holdout_hash == HASH and [r.name for r in ev.runs] == [
        "iqn_s0",
        "iqn_s1",
        "pr_s0",
        "pr_s1",
    ]
    assert tables.policy_order(ev.episodes) == ["IQN", "Pr-IQN QD ✓ 0.2 ✗"]


def test_table2_means_stds_by_hand(runs) -> None:
    long = tables.table2(load_evaluation(runs).episodes).long.set_index(
        ["density", "label", "metric"]
    )
    sr = long.loc[(0.5, "IQN", "SR")]
    assert sr["mean"] == pytest.approx(0.5) and sr["std"] == pytest.approx(math.sqrt(1 / 6))
    assert sr["n"] == 4
    assert long.loc[(0.5, "IQN", "CR"), "mean"] == pytest.approx(0.5)
    assert long.loc[(0.5, "IQN", "RP"), "mean"] == pytest.approx(0.75)
    # Pr-IQN at 1.0: 1 off-road episode out of 4 per unit -> OR 0.25 exactly, std 0.
    pr = long.loc[(1.0, "Pr-IQN QD ✓ 0.2 ✗", "OR")]
    assert (pr["mean"], pr["std"]) == (pytest.approx(0.25), pytest.approx(0.0))
    assert long.loc[(1.0, "Pr-IQN QD ✓ 0.2 ✗", "SR"), "mean"] == pytest.approx(0.75)


def test_best_and_second_marks(runs) -> None:
    long = tables.table2(load_evaluation(runs).episodes).long.set_index(
        ["density", "label", "metric"]
    )
    assert long.loc[(0.5, "Pr-IQN QD ✓ 0.2 ✗", "SR"), "mark"] == "best"
    assert long.loc[(0.5, "IQN", "SR"), "mark"] == "second"
    assert long.loc[(0.5, "Pr-IQN QD ✓ 0.2 ✗", "CR"), "mark"] == "best"  # 0 < 0.5, lower is better
    assert long.loc[(1.0, "IQN", "OR"), "mark"] == "best"  # IQN never off road
    # Ties share: both have OR 0 at density 0.5 -> both best, nobody second.
    assert (
        long.loc[(0.5, "IQN", "OR"), "mark"]
        == long.loc[(0.5, "Pr-IQN QD ✓ 0.2 ✗", "OR"), "mark"]
        == "best"
    )
    m = tables.MetricColumn("X", "x", False, 3)
    assert tables.best_marks(np.array([0.3, 0.1, 0.2, 0.1, np.nan, 0.10004]), m) == [
        "",
        "best",
        "second",
        "best",
        "",
        "best",
    ]


def test_table1_delta_relative_to_iqn(runs) -> None:
    long = tables.table1(load_evaluation(runs).episodes).long.set_index(
        ["density", "label", "metric"]
    )
    # safety at 0.5: IQN -10, Pr-IQN -5 -> +50%; risk: -2 vs -3 -> -50%; lane: 1 vs mean(1, 2) -> +50%.
    assert long.loc[(0.5, "Pr-IQN QD ✓ 0.2 ✗", "Safety"), "delta_pct"] == pytest.approx(50.0)
    assert long.loc[(0.5, "Pr-IQN QD ✓ 0.2 ✗", "Risk"), "delta_pct"] == pytest.approx(-50.0)
    assert long.loc[(1.0, "Pr-IQN QD ✓ 0.2 ✗", "Lane keeping"), "delta_pct"] == pytest.approx(50.0)
    assert long.loc[(1.0, "Pr-IQN QD ✓ 0.2 ✗", "Safety"), "delta_pct"] == pytest.approx(0.0)
    assert long.loc[(0.5, "IQN", "Safety"), "delta_pct"] == pytest.approx(0.0)
    lane = long.loc[(0.5, "Pr-IQN QD ✓ 0.2 ✗", "Lane keeping")]
    assert lane["std"] == pytest.approx(math.sqrt(4 * 0.25 / 3))  # units 1, 1, 2, 2


def test_table1_per_decision_and_length(runs) -> None:
    long = tables.table1(load_evaluation(runs).episodes).long.set_index(
        ["density", "label", "metric"]
    )
    # Every episode has 10 steps: per-decision = return / 10; IQN risk -2 -> -0.2.
    assert long.loc[(0.5, "IQN", "Risk / decision"), "mean"] == pytest.approx(-0.2)
    assert long.loc[(0.5, "Pr-IQN QD ✓ 0.2 ✗", "Lane / decision"), "mean"] == pytest.approx(0.15)
    assert long.loc[(0.5, "IQN", "Length"), "mean"] == pytest.approx(10.0)
    assert (long.xs("Length", level="metric")["mark"] == "").all()  # descriptive, not ranked


def test_renderings(runs) -> None:
    t2 = tables.table2(load_evaluation(runs).episodes)
    md, tex, csv = tables.to_markdown(t2), tables.to_latex(t2), tables.to_csv(t2)
    # Two policies: the worse one is second (underlined); equal OR 0 is best for both.
    row = (
        "| IQN | – | – | – | – | <u>0.500 ± 0.408</u> | **0.000 ± 0.000** | <u>0.500 ± 0.408</u> |"
    )
    assert row in md
    assert "| Pr-IQN | QD | ✓ | 0.2 | ✗ | **0.000 ± 0.000** |" in md
    assert "*Traffic density 0.5*" in md and "*Traffic density 1.0*" in md
    assert r"\textbf{1.000 $\pm$ 0.000}" in tex and r"\underline{0.500 $\pm$ 0.408}" in tex
    assert r"\toprule" in tex and r"\checkmark" in tex and r"$\times$" in tex
    frame = pd.read_csv(pd.io.common.StringIO(csv))
    row = frame[(frame["label"] == "IQN") & (frame["density"] == 0.5)].iloc[0]
    assert row["sr_mean"] == pytest.approx(0.5) and row["sr_std"] == pytest.approx(math.sqrt(1 / 6))
    assert row["sr_mark"] == "second"


def test_iqm_of_known_array() -> None:
    scores_RT = np.arange(1.0, 9.0).reshape(4, 2)  # 1..8: middle half 3..6 -> IQM 4.5
    agg = aggregate_estimates({"A": scores_RT / 10}, reps=50, seed=0).iloc[0]
    assert agg["iqm"] == pytest.approx(0.45)
    assert agg["og"] == pytest.approx(np.mean(1 - scores_RT / 10))
    assert agg["iqm_lo"] <= agg["iqm"] <= agg["iqm_hi"]


def test_probability_of_improvement_self_and_dominated() -> None:
    rng = np.random.default_rng(0)
    a_RT = rng.uniform(0.5, 1.0, size=(6, 3))
    poi = probability_of_improvement(
        {"A": a_RT, "A copy": a_RT.copy(), "worse": a_RT - 0.6}, reps=100, seed=1
    )
    p = poi.set_index(["x", "y"])["p"]
    assert p[("A", "A copy")] == pytest.approx(0.5) and p[("A copy", "A")] == pytest.approx(0.5)
    assert p[("A", "worse")] == pytest.approx(1.0) and p[("worse", "A")] == pytest.approx(0.0)
    assert len(poi) == 6  # every ordered pair


def test_score_matrices_axes(runs) -> None:
    episodes = load_evaluation(runs).episodes
    # Default run axis: one run per training seed, evaluation runs averaged within it.
    scores, runs_idx, tasks = score_matrices(episodes, "success", ["IQN", "Pr-IQN QD ✓ 0.2 ✗"])
    assert scores["IQN"].shape == (2, 4)  # 2 seeds x (2 densities x 2 nets)
    assert tasks[0] == (0.5, "holdout/a") and runs_idx == [0, 1]
    np.testing.assert_allclose(scores["IQN"][:, 0], [0.25, 0.75])  # (0 + .5)/2, (.5 + 1)/2
    # The paper's axis (seed x evaluation run), kept for comparison only.
    pairs, pair_idx, _ = score_matrices(episodes, "success", ["IQN"], run_axis=SEED_RUN_AXIS)
    assert pairs["IQN"].shape == (4, 4) and pair_idx[0] == (0, 0)
    np.testing.assert_allclose(pairs["IQN"][:, 0], [0.0, 0.5, 0.5, 1.0])


def test_report_files_and_reproducibility(runs, tmp_path) -> None:
    out1, out2, out3 = tmp_path / "r1", tmp_path / "r2", tmp_path / "r3"
    make_report(runs, out1, seed=3, reps=60)
    make_report(runs, out2, seed=3, reps=60)
    make_report(runs, out3, seed=4, reps=60)
    names = [f"tables/{t}.{e}" for t in ("table1", "table2") for e in ("md", "tex", "csv")]
    names += [
        "tables/rliable_aggregates.csv",
        "tables/probability_of_improvement.csv",
        "tables/performance_profiles.csv",
    ]
    for name in names:
        assert (out1 / name).read_bytes() == (out2 / name).read_bytes(), name
    assert (out1 / "report.md").read_text() == (out2 / "report.md").read_text().replace(
        str(out2), str(out1)
    )
    for fig in ("probability_of_improvement", "iqm_optimality_gap", "performance_profile"):
        for ext in ("png", "pdf"):
            assert (out1 / "figures" / f"{fig}.{ext}").stat().st_size > 1000
    assert (out1 / "tables/rliable_aggregates.csv").read_bytes() != (
        out3 / "tables/rliable_aggregates.csv"
    ).read_bytes()
    report = (out1 / "report.md").read_text()
    assert "np.random.seed(3)" in report and HASH in report
    assert "iqn_s0: no metrics.csv, so no in-training evaluation on its curve" in report
    assert "**1.000 ± 0.000**" in report
    meta = json.loads((out1 / "meta.json").read_text())
    assert meta["seed"] == 3 and meta["holdout_hash"] == HASH and len(meta["runs"]) == 4


def test_inputs_name_each_runs_commit_and_resumes(runs, tmp_path) -> None:
    """The Inputs table: the commit a run trained at and where its training resumed
    (meta.json); a run without a meta.json shows neither."""
    sessions = [{"from_step": 0, "resume": False}, {"from_step": 40000, "resume": True},
                {"from_step": 170000, "resume": True}]  # fmt: skip
    (runs / "pr_s1" / "meta.json").write_text(
        json.dumps({"status": "complete", "git_sha": "0123456789abcdef", "sessions": sessions})
    )
    report = make_report(runs, tmp_path / "rep", seed=0, reps=20).read_text()
    inputs = report[report.index("## Inputs") :].splitlines()
    (pr1,) = [line for line in inputs if line.startswith("| pr_s1 |")]
    assert pr1.endswith("| `0123456789ab` | 40k, 170k |")
    (iqn0,) = [line for line in inputs if line.startswith("| iqn_s0 |")]
    assert iqn0.endswith("| – | – |")


def test_sample_efficiency_curves_in_the_report(runs, tmp_path) -> None:
    for i, run in enumerate(sorted(runs.iterdir())):
        evals = [{"kind": "eval", "step": 100, "success": int(e < i)} for e in range(6)]
        pd.DataFrame([{"kind": "train", "step": 50, "success": 0}, *evals]).to_csv(
            run / "metrics.csv", index=False
        )
        (run / "meta.json").write_text(json.dumps({"total_steps": 200}))
    make_report(runs, tmp_path / "rep", seed=0, reps=20)
    assert (tmp_path / "rep/figures/learning_curves.png").stat().st_size > 1000
    report = (tmp_path / "rep/report.md").read_text()
    assert "no metrics.csv" not in report and "np.random.seed(0)` before each point" in report
    curve = pd.read_csv(tmp_path / "rep/tables/sample_efficiency.csv").set_index(["row", "source"])
    # Runs in name order iqn_s0, iqn_s1, pr_s0, pr_s1 succeed in 0, 1, 2, 3 of 6 episodes.
    np.testing.assert_allclose(curve.loc[("IQN", "periodic"), "mean"], (0 + 1 / 6) / 2)
    np.testing.assert_allclose(curve.loc[("Pr-IQN QD ✓ 0.2 ✗", "periodic"), "mean"], 5 / 12)
    assert list(curve.loc[("IQN", "snapshot"), ["budget", "seeds", "episodes_max"]]) == [200, 2, 16]


def test_errors_are_one_line(tmp_path, runs) -> None:
    with pytest.raises(PriqnError, match="no such folder"):
        load_evaluation(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(PriqnError, match="no runs here"):
        load_evaluation(tmp_path / "empty")
    with pytest.raises(PriqnError, match="fewer|has 2 training seed"):
        check_seeds(load_evaluation(runs).episodes, 3)

    (runs / "trained_only").mkdir()
    (runs / "trained_only" / "config.toml").write_text("")
    with pytest.raises(PriqnError, match="1 of 5 evaluations not complete: trained_only"):
        load_evaluation(runs)
    (runs / "trained_only" / "config.toml").unlink()
    (runs / "trained_only").rmdir()

    write_run(runs, "ens_other_holdout", "Ensemble", ENS, 0, iqn_value, holdout="b" * 64)
    with pytest.raises(PriqnError, match="different hold-out sets"):
        load_evaluation(runs)


def test_mixed_inputs_refused(tmp_path) -> None:
    root = tmp_path / "dup"
    write_run(root, "a", "IQN", IQN, 0, iqn_value)
    write_run(root, "b", "IQN", IQN, 0, iqn_value)
    with pytest.raises(PriqnError, match="both policy 'IQN' with training seed 0"):
        load_evaluation(root)
    root = tmp_path / "twocfg"
    write_run(root, "a", "X", IQN, 0, iqn_value)
    write_run(root, "b", "X", PR, 1, iqn_value)
    with pytest.raises(PriqnError, match="names two configurations"):
        load_evaluation(root)
    root = tmp_path / "evalcfg"
    write_run(root, "a", "IQN", IQN, 0, iqn_value)
    write_run(root, "b", "IQN", IQN, 1, iqn_value, eval_config={**EVAL_CONFIG, "seed": 1})
    with pytest.raises(PriqnError, match="different seed"):
        load_evaluation(root)


def test_cli_report(runs, tmp_path, capsys) -> None:
    from priqn.cli import main

    assert (
        main(["report", str(runs), "--out", str(tmp_path / "cli"), "--reps", "20", "--seeds", "2"])
        == 0
    )
    assert (tmp_path / "cli" / "report.md").is_file()
    assert main(["report", str(runs), "--out", str(tmp_path / "cli2"), "--seeds", "3"]) == 2
    assert "training seed" in capsys.readouterr().err


def test_vectorised_improvement_equals_rliable() -> None:
    from rliable import metrics

    from priqn.analysis.stats import mann_whitney_improvement

    rng = np.random.default_rng(3)
    for _ in range(20):
        x_RT = rng.integers(0, 4, size=(rng.integers(1, 6), 3)) / 3  # many ties
        y_RT = rng.integers(0, 4, size=(rng.integers(1, 6), 3)) / 3
        assert mann_whitney_improvement(x_RT, y_RT) == pytest.approx(
            metrics.probability_of_improvement(x_RT, y_RT)
        )


def test_config_cells_and_order() -> None:
    pr = ("pr-iqn", "qd", True, "[0.2, 0.4]", False)
    assert tables.config_cells(pr) == ["Pr-IQN", "QD", "✓", "0.2/0.4", "✗"]
    assert tables.config_cells(("iqn", None, None, None, None)) == ["IQN", "–", "–", "–", "–"]
    keys = [
        ("pr-iqn", "qd", True, 0.2, True),
        ("pr-iqn", "qd", False, 0.2, False),
        ("pr-iqn", "qd", True, 0.4, False),
        ("pr-iqn", "mv", True, 0.4, False),
        ("ensemble-iqn", None, None, None, None),
        ("iqn", None, None, None, None),
    ]
    ordered = sorted(keys, key=tables.policy_sort_key)
    assert ordered == [keys[5], keys[4], keys[3], keys[2], keys[1], keys[0]]


def test_one_seed_report_ranks_nothing_and_prints_no_ci(tmp_path) -> None:
    root = tmp_path / "runs"
    write_run(root, "iqn_s0", "IQN", IQN, 0, iqn_value)
    write_run(root, "pr_s0", "Pr-IQN QD ✓ 0.2 ✗", PR, 0, pr_value)
    report = make_report(root, tmp_path / "out", seed=0, reps=20).read_text()
    assert (
        "No best/second marks and no confidence intervals: 'IQN' has 1 training seed(s)" in report
    )
    for table in ("table2", "table1"):  # the caption is bold; no value is
        lines = (tmp_path / "out" / "tables" / f"{table}.md").read_text().splitlines()
        assert not any("**" in line or "<u>" in line for line in lines if line.startswith("|"))
    assert not (tmp_path / "out" / "tables" / "rliable_aggregates.csv").exists()
    t2 = tables.table2(load_evaluation(root).episodes, ranked=False)
    assert (t2.long["mark"] == "").all()


def test_partial_report_leaves_out_unevaluated_runs_and_names_them(runs, tmp_path, capsys) -> None:
    """A grid still running: --partial reports the evaluated runs, names the rest."""
    from priqn.cli import main

    (runs / "still_training").mkdir()
    (runs / "still_training" / "config.toml").write_text("")
    with pytest.raises(PriqnError, match="or report the evaluated ones with --partial"):
        load_evaluation(runs)
    full = load_evaluation(runs, partial=True)
    assert full.left_out == ("still_training",)
    assert "still_training" not in set(full.episodes["run"])

    out = tmp_path / "partial"
    assert main(["report", str(runs), "--out", str(out), "--reps", "20", "--partial"]) == 0
    report = (out / "report.md").read_text()
    assert report.startswith("# priqn evaluation report (partial)")
    assert "left out: still_training." in report
    assert "--partial" in report  # the command that remakes it
    assert json.loads((out / "meta.json").read_text())["left_out"] == ["still_training"]

    (runs / "still_training" / "config.toml").unlink()  # nothing left out: no banner
    complete = make_report(runs, tmp_path / "whole", seed=0, reps=20, partial=True).read_text()
    assert "(partial)" not in complete and "left out" not in complete


def test_control_evaluations_are_their_own_rows(runs, tmp_path) -> None:
    """eval-near-greedy/ beside eval/: the same network acting otherwise is its own policy
    row (label with the control's words), named "<run>/eval-near-greedy"; a control that
    is not complete is refused, or left out with --partial, like a run."""
    control = "IQN near-greedy ε=0.2"
    for seed in (0, 1):
        write_run(
            runs, f"iqn_s{seed}", control, IQN, seed, pr_value, eval_dir_name="eval-near-greedy"
        )
    ev = load_evaluation(runs)
    assert [r.name for r in ev.runs] == [
        "iqn_s0",
        "iqn_s0/eval-near-greedy",
        "iqn_s1",
        "iqn_s1/eval-near-greedy",
        "pr_s0",
        "pr_s1",
    ]
    assert tables.policy_order(ev.episodes) == ["IQN", control, "Pr-IQN QD ✓ 0.2 ✗"]
    means = ev.episodes.groupby("label")["success"].mean()
    assert means[control] == means["Pr-IQN QD ✓ 0.2 ✗"]  # its own episodes, not IQN's
    report = make_report(runs, tmp_path / "rep", seed=0, reps=20).read_text()
    assert "| iqn_s0/eval-near-greedy | IQN near-greedy ε=0.2 | 0 |" in report
    assert "acting-randomness control" in report
    assert "IQN (near-greedy ε=0.2)" in (tmp_path / "rep/tables/table2.md").read_text()

    write_run(runs, "pr_s0", "x", PR, 0, pr_value, eval_dir_name="eval-other", status="running")
    with pytest.raises(PriqnError, match="1 of 7 evaluations not complete: pr_s0/eval-other"):
        load_evaluation(runs)
    assert load_evaluation(runs, partial=True).left_out == ("pr_s0/eval-other",)


def test_kept_snapshots_are_rows_of_their_budget(runs, tmp_path) -> None:
    """eval-at<N>/ (the policy a run kept at N decisions, checkpoint.keep_at) is a row of
    its own, labelled with its budget, whatever label its episode table carries."""
    for seed in (0, 1):
        write_run(
            runs,
            f"pr_s{seed}",
            "Pr-IQN QD ✓ 0.2 ✗",
            PR,
            seed,
            iqn_value,
            eval_dir_name="eval-at60000",
        )
    ev = load_evaluation(runs)
    assert "pr_s0/eval-at60000" in [r.name for r in ev.runs]
    assert tables.policy_order(ev.episodes) == [
        "IQN",
        "Pr-IQN QD ✓ 0.2 ✗",
        "Pr-IQN QD ✓ 0.2 ✗ @60k",
    ]
    means = ev.episodes.groupby("label")["success"].mean()
    assert means["Pr-IQN QD ✓ 0.2 ✗ @60k"] == means["IQN"]  # its own episodes (iqn_value)


def test_partial_report_with_nothing_evaluated_is_one_line(tmp_path) -> None:
    (tmp_path / "grid" / "cell").mkdir(parents=True)
    (tmp_path / "grid" / "cell" / "config.toml").write_text("")
    with pytest.raises(PriqnError, match="none of its 1 runs is fully evaluated yet"):
        load_evaluation(tmp_path / "grid", partial=True)


def test_report_checks_the_papers_claims_its_rows_allow(runs, tmp_path) -> None:
    """IQN and Pr-IQN* (2 seeds each): the claims on those two rows are in the report."""
    report = make_report(runs, tmp_path / "out", seed=0, reps=50).read_text()
    assert "## The paper's claims" in report
    # Table I by hand: safety −10 (IQN) vs −5 (Pr-IQN) at 0.5, −4 vs −4 at 1.0 → +2.50 in
    # every seed, yet 2 vs 2 seeds cannot be significant (min p 2/6): inconclusive.
    assert "Pr-IQN QD ✓ 0.2 ✗ − IQN, safety, endpoint | +2.50 [+2.50, +2.50], 2 vs 2" in report
    assert "(0.333)" in report
    assert "Not checked here (rows not in this report): star-vs-ensemble" in report
    frame = pd.read_csv(tmp_path / "out" / "tables" / "claims.csv")
    assert set(frame["claim"]) == {c.key for c in CLAIMS}
    # Risk −3 (Pr-IQN) vs −2 (IQN) everywhere: the opposite of the claim, at 2 seeds per
    # row still only inconclusive; the report says what it would take (MDD ∞ at 2 seeds).
    table1 = frame[frame["claim"] == "table1"]
    assert set(table1["verdict"]) == {"inconclusive"}
    assert set(table1["mdd"]) == {math.inf}
    # The fixture evaluates densities 0.5 and 1.0 only: the endpoint averages those two, and
    # no descriptive row is printed for 0.75.
    star = frame[(frame["claim"] == "star-vs-iqn") & (frame["role"] == "descriptive")]
    assert list(star["density"]) == [0.5, 1.0]
    assert (tmp_path / "out" / "figures" / "seeds.png").is_file()
    assert (tmp_path / "out" / "figures" / "claims.png").is_file()


def test_outcomes_by_command_by_hand(runs, tmp_path) -> None:
    """IQN: half succeed, half collide; Pr-IQN: 1 of 8 episodes per unit off-road."""
    episodes = load_evaluation(runs).episodes
    frame = tables.outcomes_by_command(episodes, ["IQN", "Pr-IQN QD ✓ 0.2 ✗"])
    assert list(frame["command"]) == ["left", "left"]
    iqn, pr = frame.to_dict("records")
    assert (iqn["episodes"], iqn["success"], iqn["collision"], iqn["timeout"]) == (32, 0.5, 0.5, 0)
    assert (pr["success"], pr["off_road"]) == (7 / 8, 1 / 8)
    for row in (iqn, pr):  # exactly one outcome per episode
        assert sum(row[o] for o in tables.OUTCOMES) == pytest.approx(1.0)
    assert "| IQN | left | 32 | 50 % | 50 % | 0 % | 0 % |" in tables.outcomes_markdown(frame)
    make_report(runs, tmp_path / "out", seed=0, reps=20)
    assert (tmp_path / "out" / "figures" / "outcomes_by_command.png").is_file()
    assert "## How episodes end, by route command" in (tmp_path / "out" / "report.md").read_text()


def test_seed_success_figure_by_hand() -> None:
    from priqn.analysis import figures

    # A: seed 0 succeeds 1 of 4 episodes, seed 1 2 of 4 -> dots at 0.25 and 0.5, mean 0.375.
    # B: one seed, 4 of 4. Order puts B first; C is in the order but has no episodes.
    rows = [("A", 0, e < 1) for e in range(4)] + [("A", 1, e < 2) for e in range(4)]
    rows += [("B", 0, True) for _ in range(4)]
    episodes = pd.DataFrame(rows, columns=["label", "train_seed", "success"])
    fig = figures.seed_success_figure(episodes, ["B", "C", "A"])
    (ax,) = fig.axes
    assert [t.get_text() for t in ax.get_yticklabels()] == ["B", "A"]
    dots = sorted(
        (float(x), float(y))
        for ln in ax.lines
        if ln.get_marker() == "o"
        for x, y in ln.get_xydata()
    )
    assert dots == [(0.25, 1.0), (0.5, 1.0), (1.0, 0.0)]
    means = sorted({float(ln.get_xdata()[0]) for ln in ax.lines if ln.get_marker() != "o"})
    assert means == [0.375, 1.0]
    figures.plt.close(fig)


def test_a_report_over_runs_with_their_own_objective_list(tmp_path) -> None:
    """Runs that drive with only safety and progress (``env.objectives``) get a report whose
    Table I shows the returns they have, and no column for the objectives they lack."""
    root = tmp_path / "runs"
    own = ("safety", "progress")
    for seed in (0, 1):
        write_run(root, f"iqn_s{seed}", "IQN", IQN, seed, iqn_value, objectives=own)
        write_run(root, f"pr_s{seed}", "Pr-IQN QD ✓ 0.2 ✗", PR, seed, pr_value, objectives=own)
    ev = load_evaluation(root)
    t1 = tables.table1(ev.episodes)
    assert [m.name for m in t1.metrics] == ["Safety", "Length"]
    # IQN's safety return at density 0.5 is -10 in every episode, Pr-IQN's -5: Δ +50 %.
    pr = t1.long[(t1.long["label"] == "Pr-IQN QD ✓ 0.2 ✗") & (t1.long["density"] == 0.5)]
    assert pr.set_index("metric").loc["Safety", "delta_pct"] == pytest.approx(50.0)
    # The claim on risk and lane-keeping returns waits, saying why; the others are checked.
    results = {r.claim.key: r for r in evaluate_claims(ev.episodes)}
    assert results["table1"].verdict == "pending"
    assert results["table1"].why == "no return_lane_keeping, return_risk in these runs' episodes"
    make_report(root, tmp_path / "report", seed=0, reps=20, command="c")
    assert "Risk" not in (tmp_path / "report/tables/table1.md").read_text()
