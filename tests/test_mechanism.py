"""priqn mechanism: the counting on hand-made rollout records, and a smoke replay of a
committed headline cell (2 episodes, SUMO in a worker process)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from fake_runs import tiny_grid

from priqn.agents.policy import Decision
from priqn.analysis.decisions import MECHANISM_ROWS, CellRows, DecisionCache, seed_table
from priqn.analysis.mechanism import (
    MechanismConfig,
    mechanism_measure,
    reliability_table,
    removal_measures,
)
from priqn.evaluation.protocol import EvalScene
from priqn.evaluation.rollout import RolloutStep
from priqn.objectives import OBJECTIVES
from priqn.tools.mechanism import decision_rows

A, K = 4, 4
SPEEDS_A = np.array([0.0, 0.0, 3.0, 6.0])  # target speed of each action [m/s]
SAFETY, LANE = OBJECTIVES.index("safety"), OBJECTIVES.index("lane_keeping")
CFG = MechanismConfig(horizon=2)
CELL = Path(__file__).resolve().parents[1] / "results" / "headline" / "pr-iqn-qd-tp-eps0.2__seed19"


def step(
    scene: EvalScene,
    t: int,
    action: int,
    safety_keeps: list[int],
    lane_greedy: int,
    safety_quantiles: list[float],
    reward_safety: float = 0.0,
    end: dict | None = None,
) -> RolloutStep:
    """One decision: safety's subset, lane keeping's greedy action (its head's mean is
    highest there) and the safety head's K quantiles at the executed action."""
    q_HKA = np.zeros((len(OBJECTIVES), K, A), np.float32)
    q_HKA[LANE, :, lane_greedy] = 1.0
    q_HKA[SAFETY, :, action] = safety_quantiles
    subsets_LA = np.ones((len(OBJECTIVES), A), bool)
    subsets_LA[SAFETY] = [a in safety_keeps for a in range(A)]
    reward_N = np.zeros(len(OBJECTIVES))
    reward_N[SAFETY] = reward_safety
    d = Decision(
        np.array([action]), OBJECTIVES, subsets_LA[None], subsets_LA[SAFETY][None], q_HKA[None]
    )
    return RolloutStep(scene, t, action, d, reward_N, None, end)


def scene(episode: int) -> EvalScene:
    return EvalScene(0, "holdout/fourway_00", 0.5, episode, 100 + episode, 200 + episode, None)


def outcome(collision: bool = False, off_road: bool = False) -> dict:
    success = not (collision or off_road)
    return {"success": success, "collision": collision, "off_road": off_road, "timeout": False}


def episodes() -> list[list[RolloutStep]]:
    """Episode 0: safety removes lane keeping's greedy action (3) at decisions 1 and 2, and
    the episode ends off-road at decision 3 (penalty 10). Episode 1: no removal, success."""
    s0, s1 = scene(0), scene(1)
    bad = [-10.0, -10.0, -1.0, 0.0]  # 2 of 4 quantiles at or below -penalty/2
    good = [0.0, 0.0, 0.0, 0.0]
    off = outcome(off_road=True)
    first = [
        step(s0, 0, 0, [0, 1, 2, 3], 3, good),
        step(s0, 1, 0, [0, 1], 3, bad),
        step(s0, 2, 1, [0, 1], 3, bad),
        step(s0, 3, 1, [0, 1, 3], 3, good, reward_safety=-10.0, end=off),
    ]
    second = [step(s1, 0, 2, [2, 3], 2, good), step(s1, 1, 2, [2], 2, good, end=outcome())]
    return [first, second]


def rows() -> pd.DataFrame:
    out = []
    for ep in episodes():
        out += decision_rows(ep, OBJECTIVES, OBJECTIVES, CFG, 10.0, 0.5, SPEEDS_A)
    return pd.DataFrame(out)


def test_decision_rows_count_removals_outcomes_and_predictions_by_hand():
    d = rows()
    assert d["removes_lane_keeping"].tolist() == [False, True, True, False, False, False]
    # Risk's head is flat (all means 0): its greedy action is 0, which safety always keeps
    # in episode 0 but not in episode 1 ([2, 3] and [2]).
    assert d["removes_risk"].tolist() == [False, False, False, False, True, True]
    assert d["removes_any"].tolist() == [False, True, True, False, True, True]
    assert d["episode_violation"].tolist() == [True] * 4 + [False] * 2
    # horizon 2: the last two decisions of the off-road episode are "within".
    assert d["violation_within"].tolist() == [False, False, True, True, False, False]
    assert d["off_road_within"].tolist() == d["violation_within"].tolist()
    assert d["pred_violation"].tolist() == [0.0, 0.5, 0.5, 0.0, 0.0, 0.0]
    assert d["pred_return"].tolist() == [0.0, -5.25, -5.25, 0.0, 0.0, 0.0]
    # Realised discounted safety return-to-go with γ = 0.5: -10 at the last decision.
    assert d["return_to_go"].tolist() == [-1.25, -2.5, -5.0, -10.0, 0.0, 0.0]
    assert d["size_top"].tolist() == [4, 2, 2, 3, 2, 1]


def test_waiting_measures_by_hand():
    """Target speeds (actions 0, 1 stand still, 2 = 3 m/s, 3 = 6 m/s): episode 0 stands
    still at every decision; at decisions 1 and 2 safety keeps only standing actions
    ({0, 1}), at 0 and 3 it allows 6 m/s, lane keeping wanting 6 m/s throughout. Episode 1
    drives at 3 m/s. A third episode, one decision, times out."""
    d = rows()
    assert d["speed_mps"].tolist() == [0.0, 0.0, 0.0, 0.0, 3.0, 3.0]
    assert d["top_max_speed_mps"].tolist() == [6.0, 0.0, 0.0, 6.0, 6.0, 3.0]
    assert d["lower_greedy_speed_mps"].tolist() == [6.0] * 4 + [3.0] * 2
    s = removal_measures(d, CFG)
    assert s["standstill"] == pytest.approx(4 / 6)
    assert s["top_only_standstill"] == pytest.approx(2 / 6)  # safety forces the wait
    assert s["standstill_top_allowed_moving"] == pytest.approx(2 / 6)  # chosen below it
    assert s["standstill_lane_keeping_moving"] == pytest.approx(4 / 6)
    assert s["timeout_episodes"] == 0.0
    end = {"success": False, "collision": False, "off_road": False, "timeout": True}
    waited = [step(scene(2), 0, 0, [0, 1, 2, 3], 3, [0.0] * K, end=end)]
    d = pd.concat(
        [d, pd.DataFrame(decision_rows(waited, OBJECTIVES, OBJECTIVES, CFG, 10.0, 0.5, SPEEDS_A))]
    )
    assert removal_measures(d, CFG)["timeout_episodes"] == pytest.approx(1 / 3)


def test_seed_summary_and_reliability_by_hand():
    s = removal_measures(rows(), CFG)
    assert s["episodes"] == 2 and s["decisions"] == 6
    assert s["removes_lane_keeping"] == pytest.approx(2 / 6)
    assert s["violation_after_removal"] == pytest.approx(1 / 2)  # decisions 1, 2: only 2 within
    assert s["violation_otherwise"] == pytest.approx(1 / 4)  # decisions 0, 3, e1: only 3
    assert s["episodes_with_removal"] == 0.5
    assert s["violation_episodes_with_removal"] == 1.0
    assert s["violation_episodes_without"] == 0.0
    assert s["observed_violation"] == pytest.approx(4 / 6)
    assert s["pred_violation"] == pytest.approx(1 / 6)
    # Brier: (0-1)^2 at decisions 0 and 3, (0.5-1)^2 at 1 and 2, 0 in episode 1.
    assert s["brier"] == pytest.approx((1 + 0.25 + 0.25 + 1) / 6)
    table = reliability_table(rows())
    assert table["n"].sum() == 6
    low, mid = table.iloc[0], table.iloc[5]
    assert low["n"] == 4 and low["observed_violation"] == pytest.approx(2 / 4)
    assert mid["bin"] == "[0.5, 0.6)" and mid["n"] == 2 and mid["observed_violation"] == 1.0
    assert table.iloc[-1]["bin"] == "[0.9, 1.0]" and table.iloc[-1]["n"] == 0


def test_group_rows_average_each_group_over_its_seeds():
    """Three seeds (hold-out success 0.2: collapsed; 0.5 and 0.8: healthy), each its rows
    with a different share of removals; the group rows average the seed rows."""
    d = rows()
    cells = []
    for i, (success, removes) in enumerate([(0.2, 0.4), (0.5, 0.1), (0.8, 0.2)]):
        evaluated = pd.DataFrame(
            {"success": [1.0] * int(10 * success) + [0.0] * (10 - int(10 * success))}
        )
        own = d.assign(
            removes_lane_keeping=np.arange(len(d)) < removes * len(d), replay_matches=True
        )
        cells.append(CellRows(f"r__seed{i}", i, evaluated, own))
    table = seed_table(mechanism_measure(CFG), cells)
    assert table["run"].tolist()[:3] == ["r__seed0", "r__seed1", "r__seed2"]
    assert table["collapsed"].tolist()[:3] == [True, False, False]
    seeds = table.iloc[:3]["removes_lane_keeping"].astype(float).tolist()
    groups = table.iloc[3:].set_index("collapsed")
    assert groups.loc["collapsed", "removes_lane_keeping"] == pytest.approx(seeds[0])
    assert groups.loc["healthy", "removes_lane_keeping"] == pytest.approx(np.mean(seeds[1:]))
    assert groups.loc["all", "removes_lane_keeping"] == pytest.approx(np.mean(seeds))
    assert groups.loc["healthy", "seed"] == 2


def test_rows_follow_the_declared_schema_and_the_cache_keys_its_version(tmp_path):
    """decision_rows' columns are MECHANISM_ROWS' (no unknown one, none missing); the cache
    gives back what it saved, and nothing under another schema version or parameters."""
    import dataclasses

    d = rows().assign(replay_matches=True)
    assert MECHANISM_ROWS.check(d) == ""
    assert "unknown columns ['stray']" in MECHANISM_ROWS.check(d.assign(stray=1))
    cache = DecisionCache(tmp_path)
    params = {"run": "/x", "episodes": 2}
    cache.save(MECHANISM_ROWS, "cell", params, d)
    back = cache.load(MECHANISM_ROWS, "cell", params, 2)
    assert back is not None and back.shape == d.shape
    assert cache.load(MECHANISM_ROWS, "cell", {**params, "run": "/y"}, 2) is None
    newer = dataclasses.replace(MECHANISM_ROWS, version=MECHANISM_ROWS.version + 1)
    assert cache.load(newer, "cell", params, 2) is None
    replayed = []
    again = cache.rows(newer, "cell", params, 2, lambda: replayed.append(1) or d)
    assert replayed == [1] and again.shape == d.shape
    with pytest.raises(ValueError, match="not mechanism rows"):
        cache.save(MECHANISM_ROWS, "cell", params, d.drop(columns=["speed_mps"]))


def test_top_risk_counts_risk_removals_but_calibrates_the_safety_head():
    """With --top risk the removals and S_top are risk's (all actions kept here: its subset
    row is all ones), but the predictions stay the safety head's: the same numbers as with
    --top safety, and the risk head's own quantiles (all -10, a certain "violation" if read
    as safety's) are ignored."""
    risk = OBJECTIVES.index("risk")
    cfg = MechanismConfig(horizon=2, top="risk")
    out = []
    for ep in episodes():
        for s in ep:
            s.decision.quantiles_BHKA[0, risk] = -10.0
        out += decision_rows(ep, OBJECTIVES, OBJECTIVES, cfg, 10.0, 0.5, SPEEDS_A)
    d = pd.DataFrame(out)
    assert d["removes_lane_keeping"].tolist() == [False] * 6
    assert d["size_top"].tolist() == [4] * 6
    assert d["pred_violation"].tolist() == [0.0, 0.5, 0.5, 0.0, 0.0, 0.0]
    assert d["return_to_go"].tolist() == [-1.25, -2.5, -5.0, -10.0, 0.0, 0.0]
    assert set(d["calibrated_head"]) == {"safety"}


def test_an_unfinished_episode_is_refused():
    with pytest.raises(ValueError, match="whole episode"):
        decision_rows(episodes()[0][:2], OBJECTIVES, OBJECTIVES, CFG, 10.0, 0.99, SPEEDS_A)


@pytest.mark.skipif(not (CELL / "policy.pt").is_file(), reason="headline cell not committed")
def test_smoke_replay_of_a_committed_cell_matches_its_evaluation(tmp_path):
    """Two hold-out episodes of a committed Pr-IQN* cell replay as eval/episodes.csv
    recorded them; the table, the markdown, the reliability table and the figure appear."""
    out = tmp_path / "mech"
    res = subprocess.run(
        [sys.executable, "-m", "priqn.cli", "mechanism", str(CELL), "--episodes", "2",
         "--out", str(out), "--decisions", str(tmp_path / "cache")],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    table = pd.read_csv(out / "tables" / "mechanism.csv")
    seed = table.iloc[0]
    assert seed["run"] == CELL.name and seed["episodes"] == 2 and seed["decisions"] > 0
    assert seed["replay_matches"] == 1.0
    assert list(table["collapsed"].iloc[1:]) == ["collapsed", "healthy", "all"]
    (cached,) = (tmp_path / "cache" / "mechanism").glob(f"{CELL.name}.*.csv")
    decisions = pd.read_csv(cached)
    key = ["eval_run", "net", "density", "episode"]
    played = decisions.groupby(key).size()
    # The first two scenes by (eval run, episode, net, density): episode 0 of the first
    # net at its first two densities; each as long as its evaluated episode.
    assert [k[1:] for k in played.index] == [
        ("holdout/fourway_00", 0.5, 0),
        ("holdout/fourway_00", 0.75, 0),
    ]
    evaluated = pd.read_csv(CELL / "eval" / "episodes.csv").set_index(key)["steps"]
    assert all(evaluated.loc[k] == n for k, n in played.items())
    for name in ("figures/mechanism.png", "figures/mechanism.pdf", "tables/reliability.csv"):
        assert (out / name).stat().st_size > 0
    assert "| run |" in (out / "report.md").read_text()
    meta = json.loads((out / "meta.json").read_text())
    assert meta["kind"] == "mechanism" and meta["command"] == (
        f"priqn mechanism {CELL} --episodes 2 --out {out}"
    )


SNAPSHOT_GRID = (
    tiny_grid("mech", 400)
    + """
[[policy]]
name = "pr-iqn"
agent = "pr-iqn"
seeds = [1]
keep_at = [200]
"""
)


def test_a_kept_snapshot_replays_on_its_own_evaluation(tmp_path):
    """--snapshot N replays the policy kept at N on the scenes of eval-at<N>/, and its
    episodes end as that evaluation recorded; a budget never evaluated is one line."""
    from priqn.sweep import expand, load_experiment
    from priqn.sweep.child import train_and_evaluate

    path = tmp_path / "mech.toml"
    path.write_text(SNAPSHOT_GRID)
    (cell,) = expand(load_experiment(path, runs_dir=tmp_path / "runs"))
    train_and_evaluate(cell)
    out = tmp_path / "mech"

    def mechanism(*extra: str) -> subprocess.CompletedProcess:
        cmd = [sys.executable, "-m", "priqn.cli", "mechanism", str(cell.run_dir), "--out", str(out),
               "--decisions", str(tmp_path / "cache")]  # fmt: skip
        return subprocess.run([*cmd, *extra], capture_output=True, text=True, timeout=300)

    res = mechanism("--snapshot", "200", "--episodes", "2")
    assert res.returncode == 0, res.stderr[-3000:]
    seed = pd.read_csv(out / "tables" / "mechanism.csv").iloc[0]
    assert seed["run"] == "pr-iqn__seed1@200" and seed["episodes"] == 2
    assert seed["replay_matches"] == 1.0
    evaluated = pd.read_csv(cell.run_dir / "eval-at200" / "episodes.csv")
    assert seed["holdout_success"] == pytest.approx(evaluated["success"].astype(float).mean())
    assert "eval-at200/ scenes" in (out / "report.md").read_text()
    res = mechanism("--snapshot", "300")
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1
    assert "kept no policy at 300 decisions (checkpoint.keep_at = [200])" in res.stderr
    (cell.run_dir / "eval-at200" / "meta.json").unlink()
    res = mechanism("--snapshot", "200")
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1
    assert "eval-at200 not evaluated; run priqn evaluate" in res.stderr


BUDGET_CELL = CELL.parents[1] / "budget-tm" / "iqn__seed80"
SAME_NAME_CELL = CELL.parents[1] / "paper-point-tm" / "iqn__seed80"


@pytest.mark.skipif(
    not (BUDGET_CELL / "eval").is_dir() or not (SAME_NAME_CELL / "eval").is_dir(),
    reason="budget-tm or paper-point-tm cell not committed",
)
def test_cells_of_the_same_name_from_two_designs_are_named_apart(tmp_path):
    """Seed 80 of IQN at 240k (budget-tm) and at 60k (paper-point-tm) share a name; a
    report groups by the row before __seed, so each is named <design>/<name> and forms
    its own row (they were one group of two 'seeds'); alone, a cell keeps its name. Two
    such cells of one design folder name are one line."""
    import shutil

    from priqn.analysis.decisions import CellRows
    from priqn.errors import PriqnError
    from priqn.tools.cells import load_cells

    assert [c.name for c in load_cells([BUDGET_CELL])] == ["iqn__seed80"]
    cells = load_cells([BUDGET_CELL, SAME_NAME_CELL])
    assert [c.name for c in cells] == ["budget-tm/iqn__seed80", "paper-point-tm/iqn__seed80"]
    rows = {CellRows(c.name, 80, c.episodes, None).row for c in cells}
    assert rows == {"budget-tm/iqn", "paper-point-tm/iqn"}
    for where in ("a", "b"):
        copy = tmp_path / where / "budget-tm" / "iqn__seed80"
        shutil.copytree(BUDGET_CELL, copy, ignore=shutil.ignore_patterns("*.pt", "eval-*"))
    with pytest.raises(PriqnError, match="report them separately"):
        load_cells([tmp_path / "a" / "budget-tm", tmp_path / "b" / "budget-tm"])
