"""Several pre-registered questions over one grid (``[[question]]``, priqn/analysis/questions.py):
endpoints read at a budget from a cell or a longer cell's kept snapshot, AdaStop replayed per
question, violation verdict words, the cells the next looks need, and the report."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from priqn.analysis import (
    figures,
    questions,
    questions_outcomes,
    questions_report,
    sequential,
)
from priqn.analysis.artifacts import render
from priqn.analysis.load import resumed_before
from priqn.errors import PriqnError
from priqn.evaluation.protocol import EPISODE_COLUMNS
from priqn.io import atomic_write_json, atomic_write_text
from priqn.objectives import OUTCOMES
from priqn.sweep import load_experiment

DESIGN = """
[experiment]
name = "qx"
net = "tjunction"
steps = 200
set = ["exploration.decay_steps=60"]
runs_dir = "{runs}"
[[policy]]
name = "a-long"
group = "a"
agent = "iqn"
seeds = [0, 1, 2, 3]
steps = 400
keep_at = [200]
[[policy]]
name = "a"
agent = "iqn"
seeds = [4, 5, 6, 7]
[[policy]]
name = "b-long"
group = "b"
agent = "iqn"
seeds = [0, 1, 2, 3]
steps = 400
keep_at = [200]
[[policy]]
name = "b"
agent = "iqn"
seeds = [4, 5, 6, 7]
[[question]]
name = "safety"
question = "Does a violate more than b at 200?"
endpoint = "violation"
budget = 200
seeds = [0, 1, 2, 3, 4, 5, 6, 7]
interims = [4, 8]
alpha = 0.1
permutations = 200
code_commits = {commits}
[[question.comparison]]
name = "a vs b"
family = "safety"
a = "a"
b = "b"
[[question]]
name = "long"
question = "Does a beat b at 400?"
endpoint = "success"
budget = 400
seeds = [0, 1, 2, 3]
interims = [2, 4]
alpha = 0.1
permutations = 200
[[question.comparison]]
name = "a > b"
family = "long"
a = "a"
b = "b"
paper_difference = 0.1
"""


def write_evaluation(eval_dir: Path, success: int, violations: int, seed: int = 0) -> None:
    """10 IQN episodes of 10 decisions per density (0.5, 1.0) of training seed ``seed``:
    ``success`` succeed, then ``violations`` crash (even episodes) or leave the road (odd),
    the rest time out; the safety return is -1 in a violation, 0 otherwise. Even episodes
    turn left, odd ones right; episode e ends at route progress e / 10."""
    rows = []
    for density in (0.5, 1.0):
        for e in range(10):
            bad = success <= e < success + violations
            row = dict.fromkeys(EPISODE_COLUMNS, 0.0)
            row.update(
                {
                    "run": eval_dir.parent.name,
                    "label": "IQN",
                    "agent": "iqn",
                    "comparator": "",
                    "train_preorder": "",
                    "eps": "",
                    "partial_order": "",
                    "train_seed": seed,
                    "eval_run": 0,
                    "net": "tj",
                    "episode": e,
                    "density": density,
                    "holdout_hash": "h",
                    "steps": 10,
                    "success": e < success,
                    "collision": bad and e % 2 == 0,
                    "off_road": bad and e % 2 == 1,
                    "timeout": e >= success + violations,
                    "return_safety": -1.0 if bad else 0.0,
                    "command": ("left", "right")[e % 2],
                    "route_progress": e / 10,
                }  # fmt: skip
            )
            rows.append(row)
    atomic_write_text(eval_dir / "episodes.csv", pd.DataFrame(rows).to_csv(index=False))
    atomic_write_json(eval_dir / "meta.json", {"status": "complete", "holdout_hash": "h"})


def make_cell(run: Path, sha: str, at200: tuple[int, int], final: tuple[int, int] | None) -> None:
    """A complete cell: ``eval-at200/`` from ``at200`` and, for a long one, ``eval/`` from
    ``final`` (a short cell's ``eval/`` is its 200-decision evaluation)."""
    atomic_write_json(run / "meta.json", {"status": "complete", "git_sha": sha})
    seed = int(run.name.rpartition("seed")[2])
    if final is None:
        write_evaluation(run / "eval", *at200, seed)
    else:
        write_evaluation(run / "eval-at200", *at200, seed)
        write_evaluation(run / "eval", *final, seed)


def grid(tmp_path: Path, commits: str = "[]", sha: str = "abc", seeds=range(8)) -> object:
    """a violates in 8 of 10 episodes at 200, b in 2; at 400 a succeeds 9 / 10, b 3 / 10."""
    path = tmp_path / "qx.toml"
    path.write_text(DESIGN.format(runs=(tmp_path / "runs").as_posix(), commits=commits))
    exp = load_experiment(path)
    for seed in seeds:
        for group, at200, final in (("a", (1, 8), (9, 1)), ("b", (6, 2), (3, 1))):
            row = f"{group}-long" if seed < 4 else group
            make_cell(exp.cell_dir(row, seed), sha, at200, final if seed < 4 else None)
    return exp


def test_endpoints_are_read_at_the_budget_from_cells_and_snapshots(tmp_path: Path) -> None:
    exp = grid(tmp_path)
    safety, long = exp.designs
    scores = questions.collect(exp, safety)
    a = scores[scores["policy"] == "a"]
    assert list(a["train_seed"]) == list(range(8)) and list(a["seed"]) == list(range(8))
    assert list(a["evaluation"]) == ["at200"] * 4 + [""] * 4
    assert a["score"].tolist() == pytest.approx([0.8] * 8)  # 8 of 10 violate, both densities
    assert scores[scores["policy"] == "b"]["score"].tolist() == pytest.approx([0.2] * 8)
    assert (scores["episodes"] == 20).all()
    success = questions.collect(exp, long)
    assert success[success["policy"] == "a"]["score"].tolist() == pytest.approx([0.9] * 4)


def test_each_question_is_replayed_with_its_own_words(tmp_path: Path) -> None:
    exp = grid(tmp_path)
    safety, long = exp.designs
    _, result = questions.take_looks(exp, safety)
    assert result.decisions == {"a vs b": "larger"}
    assert sequential.verdict(safety, result, safety.comparisons[0]) == "a violates more"
    _, result = questions.take_looks(exp, long)
    assert result.decisions == {"a > b": "larger"}
    assert sequential.verdict(long, result, long.comparisons[0]) == "reproduced"
    assert questions.next_cells(exp) == []


def test_next_cells_are_the_grids_own_cells_the_next_looks_need(tmp_path: Path) -> None:
    exp = grid(tmp_path, seeds=[0, 1])
    assert questions.next_cells(exp) == [
        ("a-long", 2), ("b-long", 2), ("a-long", 3), ("b-long", 3),
    ]  # fmt: skip


def forecast(exp: Any, question: Any) -> pd.DataFrame:
    """:func:`priqn.analysis.forecast.forecast` of ``question`` from its complete cells."""
    from priqn.analysis import forecast

    rows = questions.rows_of(exp, question)
    have = forecast.committed_rows(questions.collect(exp, question), rows)
    return forecast.forecast(question, have, sims=3)


def test_forecast_of_each_question_in_its_own_words(tmp_path: Path, capsys) -> None:
    """Two complete seeds per group (no spread): every simulated completion repeats them,
    so the forecast is certain; violation words, and no paper scenario without a paper
    difference. A question short of two seeds per group is named and skipped."""
    from priqn.cli import main

    exp = grid(tmp_path, seeds=[0, 1])
    safety, long = exp.designs
    table = forecast(exp, safety)
    assert table[["scenario", "verdict", "share"]].values.tolist() == [
        ["observed", "a violates more", 1.0]
    ]
    table = forecast(exp, long)
    assert list(table["scenario"].unique()) == ["observed", "paper"]
    observed = table[table["scenario"] == "observed"]
    assert observed[["verdict", "share"]].values.tolist() == [["reproduced", 1.0]]
    assert main(["sweep", str(exp.path), "--forecast", "2"]) == 0
    out = capsys.readouterr().out
    assert "qx safety: if the seeds still to train (up to 8 per row)" in out
    assert "a vs b: a violates more 100%" in out
    (tmp_path / "one").mkdir()
    grid(tmp_path / "one", seeds=[0])
    assert main(["sweep", str(tmp_path / "one" / "qx.toml"), "--forecast", "2"]) == 0
    assert (
        "qx safety: not forecast (need at least 2 committed seeds per row: a (1), b (1))"
        in capsys.readouterr().out
    )


def test_a_cell_at_another_commit_is_refused_in_one_line(tmp_path: Path) -> None:
    exp = grid(tmp_path, commits='["0123456789abcdef"]', sha="fedcba9876543210")
    with pytest.raises(PriqnError, match=r"trained at commit fedcba987654, which .* does not list"):
        questions.collect(exp, exp.designs[0])


def test_a_seed_no_row_reaches_at_the_budget_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "qx.toml"
    body = DESIGN.format(runs=tmp_path.as_posix(), commits="[]").replace(
        "keep_at = [200]", "keep_at = [100]"
    )
    path.write_text(body)
    with pytest.raises(PriqnError, match="group 'a' has no row with seed 0 at 200 decisions"):
        load_experiment(path)


def test_report_states_verdicts_budgets_and_regenerates_byte_identically(tmp_path: Path) -> None:
    exp = grid(tmp_path)
    first = render(tmp_path / "r1", questions_report.questions_report(exp, "cmd"))
    second = render(tmp_path / "r2", questions_report.questions_report(exp, "cmd"))
    for f in sorted((tmp_path / "r1").rglob("*")):
        if f.is_file():
            assert (
                f.read_bytes() == (tmp_path / "r2" / f.relative_to(tmp_path / "r1")).read_bytes()
            ), f
    text = first.read_text()
    assert "**a violates more**" in text and "**reproduced**" in text
    changes = pd.read_csv(tmp_path / "r1" / "tables" / "budget_changes.csv")
    success = changes[changes["endpoint"] == "success"].iloc[0]
    # a: 0.1 -> 0.9 (+0.8), b: 0.6 -> 0.3 (-0.3): the difference grows by 1.1.
    assert (success["from"], success["to"], success["seeds"]) == (200, 400, 4)
    assert success["change"] == pytest.approx(1.1)
    # Both questions compare a with b over the same long seeds: one row per endpoint, each
    # naming both comparisons (not the same numbers twice).
    assert len(changes) == 2 and set(changes["comparisons"]) == {"a vs b; a > b"}
    assert "| a − b | success | 200 | 400 | 4 | +110.0 | [+110.0, +110.0] | a vs b; a > b |" in text
    # Every budget: the three outcomes of each group's episodes, summing to 1 (a at 200:
    # 1 success, 8 violations, 1 timeout in 10; b at 400: 3, 1 and 6).
    assert (
        "| group | budget | training seeds | success | violations | timeouts |\n"
        "|---|---|---|---|---|---|\n"
        "| a | 200 | 8 (0–7) | 0.100 | 0.800 | 0.100 |\n| a | 400 | 4 (0–3) | 0.900 | 0.100 | 0.000 |\n"
        "| b | 200 | 8 (0–7) | 0.600 | 0.200 | 0.200 |\n| b | 400 | 4 (0–3) | 0.300 | 0.100 | 0.600 |\n"
    ) in text
    # The difference at every budget over each question's seeds complete there (a − b):
    # success 0.1 − 0.6 at 200 (the safety question's 8 seeds; the long one's 4), 0.9 − 0.3
    # at 400 over 4 (both questions: one row naming both); no spread, a point interval.
    assert "| a − b | success | 200 | 8 / 8 | -50.0 | [-50.0, -50.0] | a vs b |" in text
    assert "| a − b | success | 200 | 4 / 4 | -50.0 | [-50.0, -50.0] | a > b |" in text
    assert "| a − b | success | 400 | 4 / 4 | +60.0 | [+60.0, +60.0] | a vs b; a > b |" in text
    differences = pd.read_csv(tmp_path / "r1" / "tables" / "budget_differences.csv")
    assert len(differences) == 6 and set(differences["endpoint"]) == {"success", "violation"}
    assert "![outcomes by budget](figures/outcomes_by_budget.png)" in text
    assert (tmp_path / "r1" / "figures" / "outcomes_by_budget.png").stat().st_size > 0
    assert second.read_text() == text


def test_outcome_mix_at_a_budget_no_question_asks(tmp_path: Path) -> None:
    """A budget the groups reach only as kept snapshots gets its outcome mix too, over the
    seeds whose snapshot there is evaluated (here: 200, taken as if no question asked)."""
    from priqn.analysis.questions_outcomes import _mix_section, budget_episodes

    exp = grid(tmp_path)
    t = questions_report.design_tables(exp)
    at = budget_episodes(exp, t.budgets, skip={400})
    assert list(at) == [200]
    assert sorted(at[200].groupby("label")["train_seed"].nunique().items()) == [
        ("IQN a", 8),
        ("IQN b", 8),
    ]  # both groups are IQN: the label gets the group's name
    # a at 200: 1 success in 10 (each seed plays the same episodes).
    assert at[200].loc[at[200]["label"] == "IQN a", "success"].mean() == pytest.approx(0.1)
    text = "\n".join(_mix_section(at, others=[200]).lines)
    assert "At 200, where no question asks" in text and "### At 200 decisions" in text
    assert budget_episodes(exp, t.budgets, skip={200, 400}) == {}


def report_section(tmp_path: Path, start: str, end: str) -> tuple[str, str]:
    """The report of :func:`grid` (written to ``tmp_path / "r"``): the section from the
    heading ``start`` to ``end``, split into its 200- and 400-decision parts."""
    text = render(
        tmp_path / "r", questions_report.questions_report(grid(tmp_path), "c")
    ).read_text()
    section = text[text.index(start) : text.index(end)]
    at200, at400 = section.split("### At 200 decisions")[1].split("### At 400 decisions")
    return at200, at400


def test_report_has_table_one_at_each_question_budget(tmp_path: Path) -> None:
    """Table I over the counted cells, one table per budget: a violates in 8 of 10 episodes
    at 200 (safety return -0.8 a episode), b in 2 (-0.2, +75 % relative to a, the first
    IQN); at 400 both in 1 (-0.1, +0 %). Both rows are IQN, so each is named by its group."""
    at200, at400 = report_section(tmp_path, "## Returns per objective", "## Sample efficiency")
    row = "| IQN ({}) | – | – | – | – | {} ± 0.00 | {} |"
    assert at200.count(row.format("a", "-0.80", "+0.0%")) == 2  # densities 0.5 and 1.0
    assert at200.count(row.format("b", "-0.20", "+75.0%")) == 2
    assert at400.count(row.format("a", "-0.10", "+0.0%")) == 2
    assert at400.count(row.format("b", "-0.10", "+0.0%")) == 2
    table = pd.read_csv(tmp_path / "r" / "tables" / "table1_200.csv")
    assert list(table["safety_mean"]) == pytest.approx([-0.8, -0.2, -0.8, -0.2])
    assert set(table["safety_n"]) == {8}  # 8 training seeds x 1 evaluation run


def test_report_has_the_outcome_mix_beside_the_papers(tmp_path: Path) -> None:
    """At 200 decisions a succeeds in 1 of 10 episodes, violates in 8 (4 collisions, 4
    off the road: even and odd episodes) and times out in 1; b: 6 / 1 / 1 / 2. Both are
    IQN, so each is named by its group too, and neither
    label is a row of the paper's Table II, so no bracket and no L1."""
    at200, _ = report_section(tmp_path, "## Outcome mix beside", "## Outcome by manoeuvre")
    assert "| IQN a | 8 | success | 0.100 | 0.100 |  |" in at200
    assert "|  |  | off-road | 0.400 | 0.400 |  |" in at200
    assert "| IQN b | 8 | success | 0.600 | 0.600 |  |" in at200
    assert "|  |  | timeout | 0.200 | 0.200 |  |" in at200
    mix = pd.read_csv(tmp_path / "r" / "tables" / "outcome_mix_200.csv")
    a = mix[mix["label"] == "IQN a"].set_index(["outcome", "density"])["rate"]
    assert a[("collision", 0.5)] == pytest.approx(0.4) and a.sum() == pytest.approx(2.0)


def test_report_has_the_outcome_by_manoeuvre(tmp_path: Path) -> None:
    """At 200 decisions a's even (left) episodes are 0 success, then collisions 2, 4, 6, 8;
    its odd (right) ones leave the road (1, 3, 5, 7) or time out (9, at progress 0.9).
    b's left: 0, 2, 4 succeed, 6 collides, 8 times out (0.8); right: 1, 3, 5 succeed, 7
    leaves the road, 9 times out. 5 episodes a manoeuvre at each of 2 densities, the same
    for every seed."""
    at200, _ = report_section(tmp_path, "## Outcome by manoeuvre", "## Returns per objective")
    expected = {  # (label, manoeuvre): success, collision, off-road, timeout, progress
        ("a", "left"): "0.200 | 0.800 | 0.000 | 0.000 | –",
        ("a", "right"): "0.000 | 0.000 | 0.800 | 0.200 | 0.90",
        ("b", "left"): "0.600 | 0.200 | 0.000 | 0.200 | 0.80",
        ("b", "right"): "0.600 | 0.000 | 0.200 | 0.200 | 0.90",
    }
    for (group, manoeuvre), shares in expected.items():  # 8 seeds x 2 densities x 5
        assert f"| IQN {group} | {manoeuvre} | 8 | 80 | {shares} |" in at200
    assert "![outcome by manoeuvre at 200](figures/outcome_by_manoeuvre_200.png)" in at200
    assert (tmp_path / "r" / "figures" / "outcome_by_manoeuvre_200.png").stat().st_size > 0
    table = pd.read_csv(tmp_path / "r" / "tables" / "outcome_by_manoeuvre_200.csv")
    assert list(table["command"]) == ["left", "right", "left", "right"]
    assert table[list(OUTCOMES)].sum(axis=1).tolist() == pytest.approx([1.0] * 4)


def test_outcome_by_manoeuvre_counts_seeds_and_the_timeouts_progress() -> None:
    """One label, left turns: seed 0 times out at progress 0.2 and 0.6, seed 1 succeeds
    twice; right turns never time out, and one episode has no command recorded."""

    def episode(seed: int, command: Any, outcome: str, progress: float) -> dict:
        return {"label": "x", "train_seed": seed, "command": command,
                "route_progress": progress, **{o: o == outcome for o in OUTCOMES}}  # fmt: skip

    rows = [episode(0, "left", "timeout", 0.2), episode(0, "left", "timeout", 0.6),
            episode(1, "left", "success", 1.0), episode(1, "left", "success", 1.0),
            episode(0, "right", "collision", 0.5), episode(1, None, "timeout", 0.3)]  # fmt: skip
    table = questions_outcomes.manoeuvre_table(pd.DataFrame(rows)).set_index("command")
    assert list(table.index) == ["left", "right", "unknown"]
    assert (table.loc["left", "timeout"], table.loc["left", "episodes"]) == (0.5, 4)
    assert table.loc["left", "timeout_progress"] == pytest.approx(0.4)
    assert math.isnan(table.loc["right", "timeout_progress"])
    assert table.loc["unknown", "timeout_progress"] == pytest.approx(0.3)
    assert set(table["seeds"]) == {2}


def test_outcome_mix_is_each_seeds_share_first_and_its_l1_to_the_paper() -> None:
    """Two IQN seeds at the paper's three densities. Seed 0 ends every episode as the
    paper's IQN row would at its rounding, seed 1 too but with success 0.2 higher and
    collisions 0.2 lower at density 0.5 (it has 2,000 episodes a density, seed 0 1,000: each
    seed's share counts once). Their mean is 0.1 off on two of the 12 numbers: L1 0.2; each
    seed alone is at L1 0 and 0.4."""
    from priqn.analysis.paper import IQN, paper_outcomes

    paper = paper_outcomes(IQN.render())
    rows = []
    for seed, n in ((0, 1000), (1, 2000)):
        for i, density in enumerate((0.5, 0.75, 1.0)):
            shares = {o: paper[o][i] for o in OUTCOMES}
            if seed == 1 and density == 0.5:
                shares["success"] += 0.2
                shares["collision"] -= 0.2
            counts = {o: round(v * n) for o, v in shares.items()}
            counts["timeout"] = n - sum(c for o, c in counts.items() if o != "timeout")
            for outcome, count in counts.items():
                rows += [
                    {"label": "IQN", "train_seed": seed, "density": density,
                     **{o: o == outcome for o in OUTCOMES}}
                ] * count  # fmt: skip
    md_rows, records, seed_records = questions_outcomes.mix_rows(pd.DataFrame(rows))
    assert md_rows[0][:3] == ["IQN", "2", "success"]
    assert md_rows[0][3] == f"{paper['success'][0] + 0.1:.3f} ({paper['success'][0]:.3f})"
    assert md_rows[0][-2:] == ["0.200", "0.20 [0.00, 0.40]"]  # seed 0 at 0, seed 1 0.2 + 0.2
    assert {round(r["l1_to_paper"], 9) for r in records} == {0.2}
    assert [round(r["l1_to_paper"], 9) for r in seed_records] == [0.0, 0.4]


def test_report_lists_each_cell_once_and_where_it_resumed(tmp_path: Path) -> None:
    """The Cells section: a long cell counted at both budgets is one row naming both
    evaluations; a cell whose meta.json records a resume says at which decision."""
    exp = grid(tmp_path)
    run = exp.cell_dir("a-long", 1)
    sessions = [{"from_step": 0, "resume": False}, {"from_step": 100, "resume": True}]
    atomic_write_json(
        run / "meta.json", {"status": "complete", "git_sha": "abc", "sessions": sessions}
    )
    text = render(tmp_path / "r", questions_report.questions_report(exp, "cmd")).read_text()
    cells = text[text.index("## Cells") :].splitlines()
    rows = [line for line in cells if line.startswith("| `")]
    assert len(rows) == 16  # 8 seeds x 2 groups, each once
    (resumed,) = [line for line in rows if "a-long__seed1`" in line]
    assert resumed.endswith("| 100 |")
    assert "safety: eval-at200/" in resumed and "long: eval/" in resumed
    assert sum(line.endswith("| – |") for line in rows) == 15
    # The figure: that cell's dot is a square at 400 (resumed at 100, before it) and at 200.
    assert resumed_before(run, 200) and resumed_before(run, 400) and resumed_before(run)
    assert not resumed_before(run, 100)  # its policy at 100 came before the resume
    assert not resumed_before(exp.cell_dir("a-long", 0), 400)
    scores = {q.name: questions.collect(exp, q) for q in exp.designs}
    fig = questions_report.figure(exp, scores)
    squares = [
        (ax.get_title(loc="left").split(":")[0], line.get_xdata().size)
        for ax in fig.axes
        for line in ax.get_lines()
        if line.get_marker() == "s"
    ]
    assert squares == [("safety", 1), ("long", 1)]


def test_seeds_are_written_as_ranges() -> None:
    from priqn.agents.labels import seeds_text

    assert seeds_text([3, 0, 1, 2, 7, 9, 10, 1]) == "0–3, 7, 9–10"
    assert seeds_text([20, 21, *range(19, -1, -1)]) == "0–21"
    assert seeds_text([5]) == "5" and seeds_text([]) == ""


def test_budget_outcomes_figure_stacks_each_groups_outcomes_per_budget(tmp_path: Path) -> None:
    """One panel per group, one bar per budget (n seeds under it), its four outcomes
    stacked to 1: a at 200 succeeds in 1 of 10 episodes, collides in 4 (even episodes
    among the 8 violations), leaves the road in 4 and times out in 1."""
    exp = grid(tmp_path)
    budgets = pd.concat(
        [questions_report.budget_frame(exp, q) for q in exp.designs], ignore_index=True
    ).drop_duplicates(["group", "budget", "train_seed"])
    fig = questions_report.budget_outcomes_figure(budgets)
    a, b = fig.axes
    assert (a.get_title(), b.get_title()) == ("a", "b")
    assert [t.get_text() for t in a.get_xticklabels()] == ["200\nn = 8", "400\nn = 4"]
    heights = [round(p.get_height(), 6) for p in a.patches]  # success, collision, off-road, timeout
    assert heights == [0.1, 0.9, 0.4, 0.0, 0.4, 0.1, 0.1, 0.0]
    assert sum(heights[::2]) == pytest.approx(1.0) and sum(heights[1::2]) == pytest.approx(1.0)


def test_report_tables_each_questions_looks_and_draws_them_look_by_look(tmp_path: Path) -> None:
    exp = grid(tmp_path)
    text = render(tmp_path / "r", questions_report.questions_report(exp, "c")).read_text()
    looks = pd.read_csv(tmp_path / "r" / "tables" / "looks.csv")
    # a violates in 8 of 10 episodes, b in 2, at every seed: +60 points, no spread, so the
    # Welch interval is the point itself, and AdaStop decides at the first look (4 seeds).
    first = looks[looks["question"] == "safety"].iloc[0]
    assert (first["look"], first["seeds_a"], first["decision"]) == (1, 4, "larger")
    assert (first["difference"], first["lo"], first["hi"]) == pytest.approx((0.6, 0.6, 0.6))
    needed = f"{100 * first['needed']:.1f}"
    assert f"| 1 | a vs b | 4 vs 4 | +60.0 | [+60.0, +60.0] | {needed} | larger |" in text
    assert "![each comparison look by look](figures/looks.png)" in text
    fig = figures.looks_figure([(q, questions.take_looks(exp, q)[1]) for q in exp.designs], "t")
    titles = [ax.get_title() for ax in fig.axes]
    assert titles == ["safety: a vs b: a violates more", "long: a > b: reproduced"]
    assert (tmp_path / "r" / "figures" / "looks.png").stat().st_size > 0


def test_verdict_words_name_the_row(monkeypatch: pytest.MonkeyPatch) -> None:
    """``a better`` / ``a violates more``: every report prints the comparison's first row
    by its name; other verdict words stay as they are."""
    from priqn.experiment import ComparisonSpec

    c = ComparisonSpec("pr vs iqn", "safety", "pr-iqn-qd", "iqn")
    for words, printed in (("a violates more", "pr-iqn-qd violates more"),
                           ("a better", "pr-iqn-qd better"), ("reproduced", "reproduced"),
                           ("no difference found at 5 seeds", "no difference found at 5 seeds")):  # fmt: skip
        monkeypatch.setattr(sequential, "verdict", lambda d, r, x, w=words: w)
        assert sequential.row_verdict(None, None, c) == printed
