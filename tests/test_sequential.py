"""A pre-registered sequential experiment (priqn/analysis/sequential.py, priqn sweep on a
[sequential] design): AdaStop replayed from run folders, only the cells a look needs."""

from __future__ import annotations

import dataclasses
import itertools
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from matplotlib.collections import PolyCollection

from priqn.analysis import figures, questions, sequential, sequential_report
from priqn.errors import PriqnError
from priqn.io import atomic_write_json
from priqn.sweep import load_experiment

# Fake cells: one evaluation episode table per cell whose success rate is set by the row
# and seed, so the endpoint of every cell is known by hand.
FAKE = """
import os

import pandas as pd

from priqn.io import atomic_write_json, atomic_write_text

RATES = {
    "good": lambda s: 0.9,
    "bad": lambda s: 0.1,
    "same": lambda s: (0.8, 1.0, 0.9, 0.7, 1.0, 0.8, 0.9, 1.0)[s],
}


def cell(c):
    calls = c.run_dir.parent / "calls"
    calls.mkdir(parents=True, exist_ok=True)
    atomic_write_text(calls / f"{c.policy}__seed{c.seed}", str(os.getpid()))
    rate = RATES[c.policy](c.seed)
    rows = [
        {"density": d, "success": e < round(10 * rate), "collision": e >= round(10 * rate),
         "off_road": False, "timeout": False}
        for d in (0.5, 1.0) for e in range(10)
    ]
    c.run_dir.joinpath("eval").mkdir(parents=True, exist_ok=True)
    atomic_write_text(c.run_dir / "eval" / "episodes.csv", pd.DataFrame(rows).to_csv(index=False))
    atomic_write_json(c.run_dir / "eval" / "meta.json", {"status": "complete"})
    atomic_write_json(
        c.run_dir / "meta.json",
        {"status": "complete", "seed": c.seed, "git_sha": os.environ.get("FAKE_SHA", "abc"),
         "labels": {"label": "IQN" if c.policy == "good" else c.policy},
         "sessions": [{"from_step": 0, "resume": False}]
         + ([{"from_step": 5000, "resume": True}] if c.seed == 3 else [])},
    )
"""


def design(tmp_path: Path, commits: str = "[]") -> Path:
    """Rows good / bad / same; looks at 4 and 8 seeds; good vs bad, good vs same."""
    body = f"""
[experiment]
name = "seq"
seeds = [0, 1, 2, 3, 4, 5, 6, 7]
runs_dir = "{(tmp_path / "runs").as_posix()}"
[resources]
cpus_per_cell = 1
[[policy]]
name = "good"
agent = "iqn"
[[policy]]
name = "bad"
agent = "iqn"
[[policy]]
name = "same"
agent = "iqn"
[sequential]
interims = [4, 8]
alpha = 0.1
permutations = 2000
seed = 1
code_commits = {commits}
[[sequential.comparison]]
name = "good > bad"
family = "primary"
a = "good"
b = "bad"
paper_difference = 0.5
[[sequential.comparison]]
name = "good vs same"
family = "primary"
a = "good"
b = "same"
"""
    path = tmp_path / "seq.toml"
    path.write_text(body)
    return path


@pytest.fixture()
def fake_cell(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    mods = tmp_path / "mods"
    mods.mkdir()
    (mods / "fakeseq.py").write_text(FAKE)
    monkeypatch.setenv(
        "PYTHONPATH", os.pathsep.join(p for p in (str(mods), os.environ.get("PYTHONPATH")) if p)
    )
    return "fakeseq:cell"


def scores_frame(rates: dict[str, list[float]]) -> pd.DataFrame:
    rows = [
        {"policy": p, "seed": s, "score": x, "episodes": 20, "git_sha": "abc", "run_dir": ""}
        for p, xs in rates.items()
        for s, x in enumerate(xs)
    ]
    return pd.DataFrame(rows, columns=["policy", "seed", "score", "episodes", "git_sha", "run_dir"])


SAME = [0.8, 1.0, 0.9, 0.7, 1.0, 0.8, 0.9, 1.0]


def take_looks(exp: Any, scores: pd.DataFrame) -> sequential.Looks:
    """The ``[sequential]`` design's replay on ``scores`` (every row of the grid)."""
    rows = [p.name for p in exp.policies]
    return sequential.take_looks(exp.sequential, sequential.scores_by_policy(scores, rows))


def test_replay_decides_look_by_look_and_names_the_next_cells(tmp_path: Path) -> None:
    exp = load_experiment(design(tmp_path))
    # Before any look: every row needs seeds 0-3.
    empty = take_looks(exp, scores_frame({}))
    assert (empty.looks, empty.next_look) == ((), 1)
    # After look 1: good beats bad in all 4 seeds: of the 70 splits only the observed one
    # and its mirror image are as extreme (two-sided, 2/70 <= α/K = 0.05): decided. good
    # vs same is not (seeds overlap).
    four = scores_frame({"good": [0.9] * 4, "bad": [0.1] * 4, "same": SAME[:4]})
    r = take_looks(exp, four)
    assert [look.k for look in r.looks] == [1]
    assert r.decisions == {"good > bad": "larger", "good vs same": "continue"}
    assert r.open_rows == ("good", "same") and r.next_look == 2
    look = r.looks[0].comparisons[0]
    assert (look.diff, look.n_a, look.n_b, look.decided_at) == (pytest.approx(0.8), 4, 4, 1)
    assert sequential.verdict(exp.sequential, r, exp.sequential.comparisons[0]) == "reproduced"
    # The boundary the open comparison (good - same = 0.90 - 0.85) failed to pass lies
    # between it and the decided one's 0.8.
    assert 0.05 < r.looks[0].needed["primary"] < 0.8
    # Look 2 needs seeds 4-7 of the open rows only.
    eight = scores_frame({"good": [0.9] * 8, "bad": [0.1] * 4, "same": SAME})
    r2 = take_looks(exp, eight)
    assert r2.finished and r2.decisions["good vs same"] == "equal"
    assert r2.looks[1].seeds_per_row == {"good": 8, "bad": 4, "same": 8}
    assert sequential.verdict(exp.sequential, r2, exp.sequential.comparisons[1]) == (
        "no difference found at 8 seeds"
    )
    # The replay is a pure function of the scores: the same frame, the same decisions.
    assert take_looks(exp, eight) == r2


def test_looks_figure_draws_each_looks_band_and_marks_the_decided_dot(tmp_path: Path) -> None:
    exp = load_experiment(design(tmp_path))
    none = take_looks(exp, scores_frame({}))
    assert figures.looks_figure([(exp.sequential, none)], "t") is None
    four = scores_frame({"good": [0.9] * 4, "bad": [0.1] * 4, "same": SAME[:4]})
    r = take_looks(exp, four)
    fig = figures.looks_figure([(exp.sequential, r)], "t")
    good_bad, good_same = fig.axes[:2]
    needed = 100 * r.looks[0].needed["primary"]
    for ax in (good_bad, good_same):
        # Look 1's grey band spans x 1 ± 0.3 and y ± needed, in points.
        (band,) = ax.collections[:1]
        xs, ys = band.get_paths()[0].vertices.T
        assert (xs.min(), xs.max()) == pytest.approx((0.7, 1.3))
        assert (ys.min(), ys.max()) == pytest.approx((-needed, needed))
    # good - bad = +80 points, decided (orange, outside the band); good - same = +5, open.
    (dot,) = good_bad.lines[2:3]
    assert dot.get_ydata()[0] == pytest.approx(80.0) and dot.get_color() == "tab:orange"
    (dot,) = good_same.lines[1:2]  # no paper line: 0 line, then the dot
    assert dot.get_ydata()[0] == pytest.approx(5.0) and dot.get_color() == "black"
    assert good_bad.get_title() == "good > bad: reproduced"
    # The paper's +50 is drawn on its comparison only.
    assert [ln.get_ydata()[0] for ln in good_bad.lines[:2]] == [0, 50.0]
    # At the last look good vs same is "equal" (no difference found): not a difference,
    # so its dot stays black, inside the band drawn for that look.
    r2 = take_looks(exp, scores_frame({"good": [0.9] * 8, "bad": [0.1] * 4, "same": SAME}))
    assert r2.finished and r2.decisions["good vs same"] == "equal"
    good_same = figures.looks_figure([(exp.sequential, r2)], "t").axes[1]
    dots = [ln for ln in good_same.lines if ln.get_marker() == "o"]
    assert [d.get_xdata()[0] for d in dots] == [1, 2]
    assert [d.get_color() for d in dots] == ["black", "black"]
    bands = [c for c in good_same.collections if isinstance(c, PolyCollection)]
    assert len(bands) == 2  # a band at each look


def test_per_seed_figure_marks_where_the_first_row_would_sit_at_the_papers_difference(
    tmp_path: Path,
) -> None:
    exp = load_experiment(design(tmp_path))
    four = scores_frame({"good": [0.9] * 4, "bad": [0.1] * 4, "same": SAME[:4]})
    ax = sequential_report.figure(exp, four).axes[0]
    # good > bad carries the paper's +50 points: a diamond at bad's mean + 0.5, on good's row.
    (diamond,) = [ln for ln in ax.lines if ln.get_marker() == "D"]
    assert diamond.get_xdata()[0] == pytest.approx(0.1 + 0.5)
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "where good would sit at the paper's difference" in labels
    assert not [ln for ln in ax.lines if ln.get_marker() == "s"]
    assert "seed whose training resumed (a session ended)" not in labels
    # A cell whose training resumed is a square, and the legend says what a square is.
    resumed = tmp_path / "resumed"
    sessions = [{"from_step": 0, "resume": False}, {"from_step": 50, "resume": True}]
    atomic_write_json(resumed / "meta.json", {"status": "complete", "sessions": sessions})
    four.loc[(four["policy"] == "bad") & (four["seed"] == 2), "run_dir"] = str(resumed)
    ax = sequential_report.figure(exp, four).axes[0]
    (square,) = [ln for ln in ax.lines if ln.get_marker() == "s"]
    assert list(square.get_xdata()) == [0.1] and list(square.get_ydata()) == [1]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "seed whose training resumed (a session ended)" in labels


def test_undecided_comparison_with_a_paper_value_is_ruled_out_or_inconclusive(
    tmp_path: Path,
) -> None:
    exp = load_experiment(design(tmp_path))
    claim = exp.sequential.comparisons[0]  # good > bad, paper +50 points
    # Precise and far below the paper's +50: ruled out at the last look.
    close = scores_frame(
        {"good": [0.5, 0.52, 0.48, 0.5, 0.51, 0.49, 0.5, 0.5], "bad": [0.5] * 8, "same": SAME}
    )
    r = take_looks(exp, close)
    assert r.decisions[claim.name] == "equal"
    assert sequential.verdict(exp.sequential, r, claim) == "paper's effect ruled out"
    # Wide: inconclusive.
    wide = scores_frame({"good": [0, 1, 1, 1, 0, 1, 1, 0], "bad": [0.2, 0.6] * 4, "same": SAME})
    r = take_looks(exp, wide)
    assert sequential.verdict(exp.sequential, r, claim) == "inconclusive at 8 seeds"


def exact_two_sided_p(a: list[float], b: list[float]) -> float:
    """Share of the splits of a + b into two groups of len(a) whose |mean difference| is at
    least the observed one (the exact two-sided permutation p)."""
    z = np.array(a + b)
    observed = abs(np.mean(a) - np.mean(b))
    splits = list(itertools.combinations(range(z.size), len(a)))
    hits = 0
    for s in splits:
        inside = np.isin(np.arange(z.size), s)
        hits += abs(z[inside].mean() - z[~inside].mean()) >= observed - 1e-12
    return hits / len(splits)


def adastop_decision(comparator_class: type, a: list[float], b: list[float]) -> str:
    """One look (K 1) of a vs b at α 0.05; B 10,000 > 252 splits, so every split is used."""
    comparator = comparator_class(n=5, K=1, B=10_000, alpha=0.05, beta=0.0, seed=0)
    comparator.partial_compare({"a": np.array(a), "b": np.array(b)}, verbose=False)
    return comparator.decisions["[0 1]"]


def test_adastop_boundary_is_two_sided() -> None:
    """a = .5 .7 .8 .9 1 vs b = .1 .2 .3 .6 .8: of the 252 splits, 8 give a mean difference
    at least +0.38 and 8 at most -0.38, so the exact two-sided p is 16/252 = 0.063 > 0.05
    (one-sided 8/252 = 0.032). The two-sided comparator keeps it undecided; adastop's own
    reads its boundary off the signed differences and rejects. a = .6 .7 .8 .9 1 vs
    b = .1 .2 .3 .4 .8 (two-sided 8/252 = 0.032) is rejected by both."""
    from adastop import MultipleAgentsComparator

    fixed = sequential.two_sided_comparator()
    close = ([0.5, 0.7, 0.8, 0.9, 1.0], [0.1, 0.2, 0.3, 0.6, 0.8])
    clear = ([0.6, 0.7, 0.8, 0.9, 1.0], [0.1, 0.2, 0.3, 0.4, 0.8])
    assert exact_two_sided_p(*close) == pytest.approx(16 / 252)
    assert exact_two_sided_p(*clear) == pytest.approx(8 / 252)
    assert adastop_decision(fixed, *close) == "equal"
    assert adastop_decision(fixed, *clear) == "larger"
    assert adastop_decision(fixed, *clear[::-1]) == "smaller"
    # If this fails, adastop has fixed its boundary: two_sided_comparator can go.
    assert adastop_decision(MultipleAgentsComparator, *close) == "larger"


def test_adastop_spends_level_after_the_first_look_when_splits_outnumber_b() -> None:
    """8 seeds a row a look: C(16, 8) = 12,870 splits > B 1,000, so every look draws random
    splits. Look 1: a and b hold the same eight values (difference 0, undecided). Look 2:
    a = .60 .. .95, b = .05 .. .40, every a above every b (difference +0.55). At α 0.3 over
    K 3 looks, the level spent may reach 0.1 at look 1 and 0.2 at look 2. The mended
    comparator spends about 0.2 by look 2 and decides "larger"; adastop's own divides
    look 2's counts by 1, spends nothing more and keeps the largest split sum (the data's
    own split among them) as its boundary, so it cannot decide."""
    from adastop import MultipleAgentsComparator

    same = np.linspace(0.1, 0.8, 8)
    a = np.concatenate([same, np.linspace(0.60, 0.95, 8)])
    b = np.concatenate([same, np.linspace(0.05, 0.40, 8)])

    def two_looks(comparator_class: type) -> Any:
        comparator = comparator_class(n=8, K=3, B=1000, alpha=0.3, beta=0.0, seed=0)
        for k in (1, 2):
            comparator.partial_compare({"a": a[: 8 * k], "b": b[: 8 * k]}, verbose=False)
            if k == 1:
                assert comparator.decisions["[0 1]"] == "continue"
                assert 0.098 <= comparator.level_spent <= 0.1  # a split's 1/B short at most
        return comparator

    mended = two_looks(sequential.two_sided_comparator())
    assert 0.196 <= mended.level_spent <= 0.2
    assert mended.decisions["[0 1]"] == "larger"
    # If these fail, adastop has mended its normalisation: the override can go.
    own = two_looks(MultipleAgentsComparator)
    assert own.level_spent <= 0.1
    assert own.decisions["[0 1]"] == "continue"


@pytest.mark.slow
def test_headline_design_keeps_its_family_wise_error_under_the_null(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The headline design (4 rows, two families of 2, looks at 5/10/15/20 seeds, α 0.05)
    on 400 null data sets (every row's seeds from one normal, SD 0.17 like the rows'):
    the share with any rejection in a family is at most α plus two standard errors with
    the two-sided boundary, and above it with adastop's own (the measurement behind
    docs/statistics.md). B 2,000 instead of 10,000 changes nothing: with n = 5 a look has
    only 252 splits."""
    from adastop import MultipleAgentsComparator

    exp = load_experiment("headline")
    seq = dataclasses.replace(exp.sequential, permutations=2000)
    rows = [p.name for p in exp.policies]
    sims = 400

    def family_error() -> dict[str, float]:
        rng = np.random.default_rng(0)
        any_rejection = {"primary": 0, "secondary": 0}
        for i in range(sims):
            rates = {r: list(rng.normal(0.65, 0.17, 20)) for r in rows}
            scores_S = {r: np.asarray(x) for r, x in rates.items()}
            decisions = sequential.take_looks(dataclasses.replace(seq, seed=i), scores_S).decisions
            for family in any_rejection:
                any_rejection[family] += any(
                    decisions[c.name] in ("larger", "smaller")
                    for c in seq.comparisons
                    if c.family == family
                )
        return {f: n / sims for f, n in any_rejection.items()}

    bound = 0.05 + 2 * np.sqrt(0.05 * 0.95 / sims)
    two_sided = family_error()
    monkeypatch.setattr(sequential, "two_sided_comparator", lambda: MultipleAgentsComparator)
    one_sided = family_error()
    print(f"family-wise error, two-sided {two_sided}, adastop's own {one_sided}")
    assert max(two_sided.values()) <= bound < max(one_sided.values()), (two_sided, one_sided)


@pytest.mark.slow
def test_ten_seeds_a_look_keep_their_error_under_the_null_and_spend_it_at_every_look() -> None:
    """The explain design's safety question at 60k (3 looks of 10 seeds a row, α 0.10
    two-sided), replayed as registered on 400 null data sets (both rows' 30 seeds from one
    normal, SD 0.13 like the rows'): the share with a rejection is at most α plus two
    standard errors, and looks 2 and 3 reject too (adastop's own counts, divided by 1
    after look 1, cannot). B 2,000 instead of 10,000 keeps it quick (C(20, 10) = 184,756
    splits either way)."""
    question = next(q for q in load_experiment("explain").designs if q.name == "safety-60k")
    (comparison,) = question.comparisons
    assert (question.seeds_per_look, len(question.interims), question.alpha) == (10, 3, 0.1)
    design = dataclasses.replace(question, permutations=2000)
    sims = 400
    rejected_at = [0, 0, 0]
    rng = np.random.default_rng(0)
    for i in range(sims):
        rates = {comparison.a: rng.normal(0.25, 0.13, 30), comparison.b: rng.normal(0.25, 0.13, 30)}
        result = sequential.take_looks(dataclasses.replace(design, seed=i), rates)
        if result.decisions[comparison.name] in ("larger", "smaller"):
            rejected_at[len(result.looks) - 1] += 1
    print(f"rejections by look {rejected_at} of {sims}")
    assert sum(rejected_at) / sims <= 0.1 + 2 * np.sqrt(0.1 * 0.9 / sims), rejected_at
    assert rejected_at[1] > 0 and rejected_at[2] > 0, rejected_at


def test_sweep_trains_only_what_each_look_needs_then_reports(
    tmp_path: Path, fake_cell: str
) -> None:
    path = design(tmp_path)
    out = subprocess.run(
        [sys.executable, "-m", "priqn.cli", "sweep", str(path), "--cell-fn", fake_cell],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    trained = sorted(p.name for p in (tmp_path / "runs" / "seq" / "calls").iterdir())
    # Look 1: all three rows, seeds 0-3; look 2: good and same only, seeds 4-7.
    expected = [f"{p}__seed{s}" for p in ("good", "same") for s in range(8)]
    expected += [f"bad__seed{s}" for s in range(4)]
    assert trained == sorted(expected)
    assert "sequential design finished after 2 look(s)" in out.stdout
    report = (tmp_path / "reports" / "seq" / "report.md").read_text()
    assert "| good > bad | primary | +50.0 |" in report and "**a better**" not in report
    assert "**reproduced**" in report and "**no difference found at 8 seeds**" in report
    assert "\n## Verdicts\n" in report and "Verdicts so far" not in report  # finished
    # The report regenerates byte for byte from the same cells.
    first = {p.name: p.read_bytes() for p in (tmp_path / "reports" / "seq").rglob("*.*")}
    assert {"headline.png", "looks.png", "looks.pdf"} <= set(first)
    assert "![each comparison look by look](figures/looks.png)" in report
    again = subprocess.run(
        [
            sys.executable,
            "-m",
            "priqn.cli",
            "report",
            "runs/seq",
            "--out",
            "reports/seq",
            "--experiment",
            str(path),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert again.returncode == 0, again.stderr[-2000:]
    second = {p.name: p.read_bytes() for p in (tmp_path / "reports" / "seq").rglob("*.*")}
    assert set(first) == set(second) and all(
        first[k] == second[k] for k in first if k != "meta.json"
    )
    # Per density, descriptive: good is 0.9 at both densities on all 8 seeds, beside the
    # paper's IQN values (its label); same's 8 seeds at density 1.0 average 0.8875, SD
    # 0.1126, t(7) 2.3646: 95 % interval 0.8875 ± 0.0941. No paper row is labelled "same".
    density = pd.read_csv(tmp_path / "reports" / "seq" / "tables" / "density.csv")
    good = density[density["policy"] == "good"].set_index("density")
    assert list(good["seeds"]) == [8, 8] and list(good["mean"]) == pytest.approx([0.9, 0.9])
    assert list(good["paper"]) == [0.737, 0.434]
    same = density[density["policy"] == "same"].set_index("density").loc[1.0]
    assert (same["mean"], same["lo"], same["hi"]) == pytest.approx(
        (0.8875, 0.7934, 0.9816), abs=2e-4
    )
    assert np.isnan(same["paper"])
    assert "| good | 8 | 0.900 [0.900, 0.900] (paper 0.737) |" in report
    # The Cells table says where a cell's training resumed (seed 3 of each row, at 5k).
    assert "| good | 3 | 0.900 | 20 | `abc` | 5k | `runs/seq/good__seed3` |" in report
    assert "| good | 2 | 0.900 | 20 | `abc` | – | `runs/seq/good__seed2` |" in report
    looks = pd.read_csv(tmp_path / "reports" / "seq" / "tables" / "looks.csv")
    assert list(looks["look"]) == [1, 1, 2, 2]
    meta = json.loads((tmp_path / "reports" / "seq" / "meta.json").read_text())
    assert meta["finished"] and meta["cells"] == 20


def test_cells_at_an_unlisted_commit_are_refused(tmp_path: Path, fake_cell: str) -> None:
    exp = load_experiment(design(tmp_path, commits='["0123456789abcdef"]'))
    run = tmp_path / "runs" / "seq" / "good__seed0"
    (run / "eval").mkdir(parents=True)
    (run / "meta.json").write_text(json.dumps({"status": "complete", "git_sha": "fedcba9876"}))
    (run / "eval" / "meta.json").write_text(json.dumps({"status": "complete"}))
    pd.DataFrame(
        {
            "density": [0.5],
            "success": [True],
            "collision": [False],
            "off_road": [False],
            "timeout": [False],
        }
    ).to_csv(run / "eval" / "episodes.csv", index=False)
    with pytest.raises(PriqnError, match="trained at commit fedcba9876, which .* does not list"):
        questions.collect(exp, exp.sequential)


def test_commit_leaves_cells_at_an_unlisted_commit_uncommitted(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from priqn.sweep import commit_complete_cells

    for who in ("AUTHOR", "COMMITTER"):
        monkeypatch.setenv(f"GIT_{who}_NAME", "t")
        monkeypatch.setenv(f"GIT_{who}_EMAIL", "t@example.org")
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    exp = load_experiment(design(tmp_path, commits='["0123456789abcdef"]'))
    for seed, sha in ((0, "0123456789abcdef"), (1, "fedcba9876"), (2, "0123456789abcdef-dirty")):
        run = tmp_path / "runs" / "seq" / f"good__seed{seed}"
        (run / "eval").mkdir(parents=True)
        (run / "meta.json").write_text(json.dumps({"status": "complete", "git_sha": sha}))
        (run / "eval" / "meta.json").write_text(json.dumps({"status": "complete"}))
    done = commit_complete_cells(exp)
    assert [c.name for c in done.cells] == ["seq/good__seed0"]
    assert [c.name for c in done.refused] == ["seq/good__seed1", "seq/good__seed2"]
    status = subprocess.run(
        ["git", "-C", str(tmp_path), "status", "--porcelain", "--", "runs"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert status == "?? runs/seq/good__seed1/\n?? runs/seq/good__seed2/\n"


def test_one_rule_says_which_code_a_sequential_cell_may_have_trained_at(tmp_path: Path) -> None:
    listed = load_experiment(design(tmp_path, commits='["0123456789abcdef"]')).sequential
    assert listed.code_problem("0123456789abcdef") is None
    assert listed.code_problem("fedcba9876") == "unlisted"
    assert listed.code_problem("fedcba9876-dirty") == "unlisted"
    assert listed.code_problem("0123456789abcdef-dirty") == "dirty"
    (tmp_path / "any").mkdir()
    anything = load_experiment(design(tmp_path / "any")).sequential  # no code_commits
    assert anything.code_problem("fedcba9876") is None
    assert anything.code_problem("fedcba9876-dirty") == "dirty"


def test_scores_use_contiguous_seeds_only() -> None:
    frame = scores_frame({"good": [0.9, 0.8, 0.7]}).drop(index=1)  # seed 1 missing
    got = sequential.scores_by_policy(frame, ["good", "bad"])
    np.testing.assert_array_equal(got["good"], [0.9])
    assert got["bad"].size == 0


RECORD = """
import os

import priqn
from priqn.io import atomic_write_json


def cell(c):
    atomic_write_json(
        c.run_dir / "env.json",
        {"PYTHONPATH": os.environ.get("PYTHONPATH", ""), "priqn": priqn.__file__},
    )
    atomic_write_json(c.run_dir / "meta.json", {"status": "complete"})
    atomic_write_json(c.run_dir / "eval" / "meta.json", {"status": "complete"})
"""


def test_code_dir_goes_first_on_the_cells_path(tmp_path: Path, monkeypatch) -> None:
    """`priqn sweep --code DIR`: each cell's child runs the priqn at DIR."""
    from priqn.sweep import run_sweep
    from priqn.sweep.cli import _code_dir

    mods = tmp_path / "mods"
    mods.mkdir()
    (mods / "recordcell.py").write_text(RECORD)
    monkeypatch.setenv("PYTHONPATH", str(mods))
    exp_path = tmp_path / "x.toml"
    exp_path.write_text(
        f'[experiment]\nname = "x"\nseeds = [0]\nruns_dir = "{(tmp_path / "runs").as_posix()}"\n'
        '[[policy]]\nname = "a"\nagent = "iqn"\n'
    )
    repo = Path(__file__).resolve().parent.parent
    # The snapshot: the same package under another path. The sweep runs from the repository
    # root, whose own priqn/ must not shadow the snapshot's (`python -m` puts the working
    # directory first on sys.path).
    snapshot = tmp_path / "snapshot"
    snapshot.mkdir()
    (snapshot / "priqn").symlink_to(repo / "priqn", target_is_directory=True)
    monkeypatch.chdir(repo)
    result = run_sweep(
        load_experiment(exp_path),
        cell_fn="recordcell:cell",
        report=False,
        progress=False,
        log=lambda m: None,
        code_dir=snapshot,
    )
    assert result.completed == ["x/a__seed0"]
    env = json.loads((tmp_path / "runs" / "x" / "a__seed0" / "env.json").read_text())
    assert env["PYTHONPATH"].split(os.pathsep) == [str(snapshot), str(mods)]
    assert env["priqn"] == str(snapshot / "priqn" / "__init__.py")
    with pytest.raises(PriqnError, match="--code nowhere: no priqn package there"):
        _code_dir("nowhere")


def test_forecast_completes_the_committed_seeds_and_tallies_the_verdicts(tmp_path: Path) -> None:
    from priqn.analysis import forecast

    exp = load_experiment(design(tmp_path))
    scores = scores_frame(
        {"good": [0.9, 0.8, 0.9, 0.85], "bad": [0.1, 0.2, 0.1, 0.15], "same": SAME[:4]}
    )
    observed = {"good": 0.8625, "bad": 0.1375, "same": 0.85}
    # The paper says good - bad = +0.5: bad's future seeds sit 0.5 below good's mean.
    seq, rows = exp.sequential, [p.name for p in exp.policies]
    assert forecast.scenario_means(seq, observed, "paper")["bad"] == pytest.approx(0.3625)
    assert forecast.scenario_means(seq, observed, "observed") == observed
    table = forecast.forecast(seq, forecast.committed_rows(scores, rows), sims=4, permutations=200)
    assert list(table.columns) == list(forecast.FORECAST_COLUMNS)
    # good beats bad in every committed seed (two-sided 2/70 <= α/K = 0.05): decided at
    # look 1 in every simulated experiment, whatever the future draws are.
    good_bad = table[table["comparison"] == "good > bad"]
    assert good_bad[["verdict", "share", "mean_seeds"]].values.tolist() == [
        ["reproduced", 1.0, 4.0],
        ["reproduced", 1.0, 4.0],
    ]
    # Every simulated experiment ends with one verdict per comparison.
    assert table.groupby(["scenario", "comparison"])["share"].sum().tolist() == [1.0] * 4
    with pytest.raises(PriqnError, match=r"need at least 2 committed seeds per row: bad \(1\)"):
        forecast.committed_rows(scores_frame({"good": [0.9] * 4, "bad": [0.1], "same": SAME}), rows)


def test_sweep_forecast_prints_the_verdict_shares_and_trains_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from priqn.cli import main

    path = design(tmp_path)
    # Two seeds of every row, written as complete fake cells.
    for policy, rate in (("good", 0.9), ("bad", 0.1), ("same", 0.8)):
        for seed in (0, 1):
            run = tmp_path / "runs" / "seq" / f"{policy}__seed{seed}"
            (run / "eval").mkdir(parents=True)
            (run / "meta.json").write_text(json.dumps({"status": "complete", "git_sha": "abc"}))
            (run / "eval" / "meta.json").write_text(json.dumps({"status": "complete"}))
            success = [e < 10 * (rate + 0.05 * seed) for e in range(10)]
            outcomes = {"collision": False, "off_road": False, "timeout": False}
            pd.DataFrame({"density": 0.5, "success": success, **outcomes}).to_csv(
                run / "eval" / "episodes.csv", index=False
            )
    assert main(["sweep", str(path), "--forecast", "3"]) == 0
    out = capsys.readouterr().out
    assert "seq: if the seeds still to train (up to 8 per row)" in out
    assert "good > bad: reproduced 100%" in out
    assert sorted(p.name for p in (tmp_path / "runs" / "seq").iterdir()) == sorted(
        f"{p}__seed{s}" for p in ("good", "bad", "same") for s in (0, 1)
    )
    assert main(["sweep", str(path), "--forecast", "0"]) == 2
    assert "--forecast 0: expected a positive number" in capsys.readouterr().err


def test_the_papers_training_budget_is_the_paper_presets() -> None:
    from priqn.run.train_config import resolve_config

    assert resolve_config(preset="paper").total_steps == sequential_report.PAPER_TRAINING_DECISIONS
