"""Sample-efficiency curves (priqn.analysis.curves) on tiny run folders with hand-checkable rates."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
from fake_runs import IQN, PR, write_run

from priqn.analysis import curves
from priqn.analysis.figures import efficiency_figure, row_colors, sample_efficiency_figure
from priqn.experiment import load_experiment


def _rate_value(rates: dict[float, float]):
    """Episode values whose success rate at density d is rates[d] (2 episodes per cell)."""

    def value(seed, r, d, net, e):
        return {"success": e < round(rates[d] * 2)}

    return value


def _write_metrics(run: Path, evals: dict[int, list[int]]) -> None:
    """metrics.csv with training rows and the in-training evaluation successes per step."""
    rows = [{"kind": "train", "step": 5, "success": 1, "return_weighted": 0.0}]
    for step, successes in evals.items():
        rows += [{"kind": "eval", "step": step, "success": s} for s in successes]
    pd.DataFrame(rows).to_csv(run / "metrics.csv", index=False)


def _cell(root: Path, name: str, label: str, config: dict, seed: int, total: int) -> Path:
    """One run: final eval/ success 0.5 at density 0.5 and 1.0 at 1.0 (mean 0.75)."""
    write_run(root, name, label, config, seed, _rate_value({0.5: 0.5, 1.0: 1.0}))
    (root / name / "meta.json").write_text(json.dumps({"total_steps": total}))
    return root / name


def test_points_by_hand_and_snapshots_from_eval_at(tmp_path: Path) -> None:
    a = _cell(tmp_path, "a", "IQN", IQN, 0, 20)
    _write_metrics(a, {10: [0, 0, 1, 1, 1, 1], 20: [1, 1, 1, 1, 1, 1]})  # 4/6, 6/6
    # The policy kept at 10 decisions: success 0 at density 0.5, 0.5 at 1.0 -> 0.25.
    write_run(
        tmp_path, "a", "IQN", IQN, 0, _rate_value({0.5: 0.0, 1.0: 0.5}), eval_dir_name="eval-at10"
    )
    # Neither a control of the snapshot nor an unfinished snapshot is a point.
    write_run(
        tmp_path,
        "a",
        "IQN",
        IQN,
        0,
        _rate_value({0.5: 1, 1.0: 1}),
        eval_dir_name="eval-at10-near-greedy",
    )
    write_run(
        tmp_path,
        "a",
        "IQN",
        IQN,
        0,
        _rate_value({0.5: 1, 1.0: 1}),
        eval_dir_name="eval-at15",
        status="running",
    )
    b = _cell(tmp_path, "b", "IQN", IQN, 1, 20)
    _write_metrics(b, {10: [0, 0, 0, 0, 0, 1], 20: [0, 0, 0, 1, 1, 1]})  # 1/6, 3/6
    points, notes = curves.curve_points([("IQN", 0, a), ("IQN", 1, b)])
    assert notes == []
    snap = points[points["source"] == curves.SNAPSHOT]
    assert list(
        zip(snap["run"], snap["budget"], snap["success"], snap["episodes"], strict=True)
    ) == [
        ("a", 10, 0.25, 16),
        ("a", 20, 0.75, 16),
        ("b", 20, 0.75, 16),
    ]
    curve = curves.sample_efficiency(points, reps=200, seed=0)
    periodic = curve[curve["source"] == curves.PERIODIC].set_index("budget")
    np.testing.assert_allclose(periodic["mean"], [(4 / 6 + 1 / 6) / 2, (1 + 3 / 6) / 2])
    assert (periodic["seeds"] == 2).all() and (periodic["episodes_max"] == 6).all()
    # Two seeds: the bootstrap mean can only be one seed's, the other's or their mean.
    assert periodic.loc[10, "lo"] >= 1 / 6 - 1e-12 and periodic.loc[10, "hi"] <= 4 / 6 + 1e-12
    at = curve[curve["source"] == curves.SNAPSHOT].set_index("budget")
    assert at.loc[10, "seeds"] == 1 and np.isnan(at.loc[10, "lo"])  # one seed: no interval
    assert at.loc[20, "mean"] == 0.75 and at.loc[20, "lo"] == at.loc[20, "hi"] == 0.75
    pd.testing.assert_frame_equal(curve, curves.sample_efficiency(points, reps=200, seed=0))


def test_missing_estimators_are_notes(tmp_path: Path) -> None:
    write_run(tmp_path, "c", "IQN", IQN, 0, _rate_value({0.5: 1.0, 1.0: 1.0}))
    points, notes = curves.curve_points([("IQN", 0, tmp_path / "c")])
    assert points.empty
    assert notes == [
        "c: no metrics.csv, so no in-training evaluation on its curve",
        "c: no complete evaluation with a known budget (meta.json total_steps), "
        "so no full hold-out evaluation on its curve",
    ]


def test_group_of_rows_with_different_budgets(tmp_path: Path) -> None:
    exp_path = tmp_path / "g.toml"
    exp_path.write_text(
        '[experiment]\nname = "g"\nsteps = 20\n'
        '[[policy]]\nname = "iqn-40"\ngroup = "iqn"\nagent = "iqn"\nseeds = [1]\nsteps = 40\n'
        "keep_at = [20]\n"
        '[[policy]]\nname = "iqn"\nagent = "iqn"\nseeds = [2, 3]\n'
        '[[policy]]\nname = "pr"\nagent = "pr-iqn"\ncomparator = "qd"\nseeds = [2]\n'
    )
    exp = load_experiment(exp_path, runs_dir=tmp_path)
    root = exp.runs_dir
    long = _cell(root, "iqn-40__seed1", "IQN", IQN, 1, 40)
    write_run(
        root, long.name, "IQN", IQN, 1, _rate_value({0.5: 0.0, 1.0: 0.0}), eval_dir_name="eval-at20"
    )
    _write_metrics(long, {20: [1] * 6, 40: [1] * 6})
    for seed in (2, 3):
        _write_metrics(_cell(root, f"iqn__seed{seed}", "IQN", IQN, seed, 20), {20: [0] * 6})
    _write_metrics(_cell(root, "pr__seed2", "Pr", PR, 2, 20), {20: [1] * 6})
    cells = curves.experiment_cells(exp)  # seed 3 of nothing else; no folder, no cell
    assert [(g, s, p.name) for g, s, p in cells] == [
        ("iqn", 1, "iqn-40__seed1"),
        ("iqn", 2, "iqn__seed2"),
        ("iqn", 3, "iqn__seed3"),
        ("pr", 2, "pr__seed2"),
    ]
    points, _ = curves.curve_points(cells)
    curve = curves.sample_efficiency(points, reps=100, seed=0).set_index(
        ["row", "source", "budget"]
    )
    # At 20: the 40-decision seed's kept snapshot (0.0) beside two 20-decision runs (0.75).
    assert curve.loc[("iqn", curves.SNAPSHOT, 20), "seeds"] == 3
    np.testing.assert_allclose(curve.loc[("iqn", curves.SNAPSHOT, 20), "mean"], 0.5)
    np.testing.assert_allclose(curve.loc[("iqn", curves.PERIODIC, 20), "mean"], 1 / 3)
    assert curve.loc[("iqn", curves.PERIODIC, 40), "seeds"] == 1
    assert curves.seed_counts(curve.reset_index(), "iqn") == "1–3 seeds"
    assert curves.seed_counts(curve.reset_index(), "pr") == "1 seed"

    kinds = curves.row_kinds({"iqn": "iqn", "pr": "pr-iqn"})
    panel_rows = curves.panels(["iqn", "pr"], kinds)
    assert panel_rows == [("Baselines", ["iqn"]), ("Pr-IQN variants", ["pr"])]
    fig = sample_efficiency_figure(
        curve.reset_index(), panel_rows, row_colors(["iqn", "pr"]), "iqn"
    )
    legends = [[t.get_text() for t in ax.get_legend().get_texts()] for ax in fig.axes]
    assert legends == [["iqn (1–3 seeds)"], ["iqn (for reference)", "pr (1 seed)"]]
    styles = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "(6 episodes per seed)" in styles[0] and "(16 episodes per seed)" in styles[1]


def test_panels_cut_long_kinds_into_balanced_chunks() -> None:
    rows = ["b1", *[f"p{i}" for i in range(10)]]
    kinds = {r: "P" if r.startswith("p") else "B" for r in rows}
    got = curves.panels(rows, kinds, per_panel=4)
    assert [(t, len(r)) for t, r in got] == [
        ("B", 1),
        ("P (1/3)", 4),
        ("P (2/3)", 3),
        ("P (3/3)", 3),
    ]
    assert sum((r for _, r in got), []) == rows


def test_the_reference_line_is_the_iqn_group_that_reaches_furthest() -> None:
    """A design with IQN at 60k (first in file order) and IQN at 240k: the Pr-IQN panel's
    dotted IQN is the 240k one, the curve a 240k Pr-IQN* is compared with."""
    agents = {"iqn-halving": "iqn", "iqn": "iqn", "pr": "pr-iqn"}
    reach = {"iqn-halving": 60_000, "iqn": 240_000, "pr": 240_000}
    curve = pd.DataFrame(
        [
            {
                "row": row,
                "source": curves.PERIODIC,
                "budget": budget,
                "mean": 0.5,
                "lo": 0.4,
                "hi": 0.6,
                "seeds": 2,
                "episodes_min": 6,
                "episodes_max": 6,
            }
            for row, top in reach.items()
            for budget in (top // 2, top)
        ]
    )
    fig = efficiency_figure(curve, agents)
    legends = [[t.get_text() for t in ax.get_legend().get_texts()] for ax in fig.axes]
    assert legends[1] == ["iqn (for reference)", "pr (2 seeds)"]
    dotted = fig.axes[1].get_lines()[0]
    assert dotted.get_linestyle() == ":" and max(dotted.get_xdata()) == 240_000
    # Among equals, the first in file order (the headline: one IQN row).
    reach["iqn"] = 60_000
    curve.loc[curve["row"] == "iqn", "budget"] = [30_000, 60_000]
    fig = efficiency_figure(curve, agents)
    assert fig.axes[1].get_legend().get_texts()[0].get_text() == "iqn-halving (for reference)"


def test_a_figure_of_full_evaluations_only(tmp_path: Path) -> None:
    """Runs without in-training evaluations (e.g. a short run): markers only, one style entry."""
    cells = [("IQN", s, _cell(tmp_path, f"r{s}", "IQN", IQN, s, 20)) for s in (0, 1)]
    points, notes = curves.curve_points(cells)
    assert set(points["source"]) == {curves.SNAPSHOT} and len(notes) == 2
    curve = curves.sample_efficiency(points, reps=50, seed=0)
    fig = sample_efficiency_figure(curve, [("Baselines", ["IQN"])], row_colors(["IQN"]), "IQN")
    assert [t.get_text() for t in fig.axes[0].get_legend().get_texts()] == ["IQN (2 seeds)"]
    styles = [t.get_text() for t in fig.legends[0].get_texts()]
    assert len(styles) == 1 and styles[0].startswith("full hold-out evaluation (16 episodes")


def test_derived_rows_are_shades_of_their_trained_row() -> None:
    """A near-greedy control and a kept budget are the trained row's network: they get a
    shade of its colour (mixed half with white, then 35 % with black), and the trained
    rows take tab10 in order without the derived rows using up its colours."""
    from matplotlib.colors import to_rgb

    from priqn.agents.labels import PolicyLabel, at_budget, near_greedy, trained_row

    iqn = PolicyLabel("iqn")
    pr = PolicyLabel("pr-iqn", "qd", True, 0.2, False)
    rows = [
        iqn.render(),
        near_greedy(iqn, 0.005).render(),
        at_budget(near_greedy(iqn, 0.2), 60_000).render(),
        pr.render(),
        at_budget(pr, 60_000).render(),
        "Ensemble @60k",  # its trained row is not in the report: a row of its own
    ]
    assert [trained_row(r) for r in rows] == [
        "IQN",
        "IQN",
        "IQN",
        pr.render(),
        pr.render(),
        "Ensemble",
    ]
    colors = {k: np.round(v[:3], 6) for k, v in row_colors(rows).items()}
    blue, orange, green = (np.array(to_rgb(c)) for c in ("#1f77b4", "#ff7f0e", "#2ca02c"))
    np.testing.assert_allclose(colors["IQN"], blue.round(6))
    np.testing.assert_allclose(colors[rows[1]], (blue + 1) / 2, atol=1e-6)
    np.testing.assert_allclose(colors[rows[2]], 0.65 * blue, atol=1e-6)
    np.testing.assert_allclose(colors[rows[3]], orange.round(6))
    np.testing.assert_allclose(colors[rows[4]], (orange + 1) / 2, atol=1e-6)
    np.testing.assert_allclose(colors["Ensemble @60k"], green.round(6))
    many = [f"row {i}" for i in range(18)]
    assert len({row_colors(many)[r] for r in many}) == 18
