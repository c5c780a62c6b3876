"""``priqn mechanism --standstill``: the counting over hand-made decisions (no SUMO)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import torch

from priqn.agents.policy import Decision
from priqn.analysis.decisions import STANDSTILL_ROWS
from priqn.analysis.standstill import waiting_measures
from priqn.preorder import Preorder, comparator_scores, optimal_subsets
from priqn.tools.standstill import standstill_rows, stop_vs_go

LEVELS = ("safety", "risk", "lane_keeping", "progress", "comfort")
ABOVE = ("safety", "risk", "lane_keeping")  # progress chooses from lane_keeping's subset
SPEEDS_A = np.array([0.0, 0.0, 3.0, 6.0])  # actions 0, 1 stop; 2, 3 go
GO_A = SPEEDS_A > 0


def _subsets(*rows: str) -> np.ndarray:
    """``"TTFF"`` per level → bool [L, A]."""
    return np.array([[c == "T" for c in r] for r in rows])


def test_stop_vs_go_by_hand_and_against_the_comparator() -> None:
    # Safety means (x 1e-3) [0, 0, -1.5, -2.5]: best stop 0 (first of the tie), best go 2,
    # raw difference 1.5e-3. The eight entries have mean -1e-3 and squared deviations
    # (1, 1, 1, 1, 1, 1, 0, 4) x 1e-6, so the population std is sqrt(10 / 8) x 1e-3.
    q_KA = 1e-3 * np.array([[0.0, 0.0, -2.0, -2.0], [0.0, 0.0, -1.0, -3.0]])
    m = stop_vs_go(q_KA, GO_A)
    assert (m["best_stop"], m["best_go"]) == (0, 2)
    assert m["raw_diff"] == pytest.approx(1.5e-3)
    assert m["spread"] == pytest.approx(math.sqrt(1.25) * 1e-3)
    assert m["z_diff"] == pytest.approx(1.5 / math.sqrt(1.25))  # 1.342
    # A raw difference of 0.0015 reward units is > ε = 0.2 once z-scored.
    assert m["z_diff"] > 0.2
    # The same number is the QD score difference the comparator computes...
    scores_A = comparator_scores(torch.tensor(q_KA[None], dtype=torch.float64), "qd")[0]
    assert float(scores_A[0] - scores_A[2]) == pytest.approx(m["z_diff"])
    # ... and Algorithm 1 at ε = 0.2 keeps no go action for safety.
    q_NKA = torch.tensor(np.stack([q_KA, np.zeros_like(q_KA)]), dtype=torch.float64)
    out = optimal_subsets(q_NKA, Preorder.chain(["safety", "progress"]), "qd", 0.2)
    assert out.subset("safety").tolist() == [True, True, False, False]
    # Among a parent's subset without action 2, the best go is 3 (mean -2.5e-3).
    m = stop_vs_go(q_KA, GO_A, candidates_A=np.array([False, True, False, True]))
    assert (m["best_stop"], m["best_go"]) == (1, 3)
    assert m["raw_diff"] == pytest.approx(2.5e-3)
    # No go candidate: no difference.
    m = stop_vs_go(q_KA, GO_A, candidates_A=np.array([True, True, False, False]))
    assert m["best_go"] == -1 and math.isnan(m["z_diff"])


def _step(t: int, action: int, subsets: np.ndarray, q_HKA: np.ndarray, end: dict | None):
    scene = SimpleNamespace(eval_run=0, net="holdout/x", density=0.5, episode=0)
    d = Decision(np.array([action]), LEVELS, subsets[None], subsets[-1][None], q_HKA[None])
    return SimpleNamespace(scene=scene, step=t, action=action, decision=d, episode=end)


def test_rows_and_summary_of_a_hand_made_episode() -> None:
    q_HKA = np.zeros((5, 2, 4))
    q_HKA[0] = 1e-3 * np.array([[0.0, 0.0, -2.0, -2.0], [0.0, 0.0, -1.0, -3.0]])  # safety
    q_HKA[1] = np.array([[0.0, -1.0, -1.0, 0.0], [0.0, -1.0, -1.0, 0.0]])  # risk
    end = {"timeout": True, "success": False}
    steps = [
        _step(0, 0, _subsets("TTFF", "TFFF", "TFFF", "TFFF", "TFFF"), q_HKA, None),  # safety
        _step(1, 1, _subsets("TTTF", "TTFF", "FTFF", "FTFF", "FTFF"), q_HKA, None),  # risk
        _step(2, 3, _subsets("TTTT", "TTTT", "FFFT", "FFFT", "FFFT"), q_HKA, end),  # go left
    ]
    rows = standstill_rows(steps, LEVELS, ABOVE, SPEEDS_A)
    assert STANDSTILL_ROWS.check(pd.DataFrame(rows).assign(replay_matches=True)) == ""
    assert [r["removed_by"] for r in rows] == ["safety", "risk", ""]
    assert [r["stop"] for r in rows] == [True, True, False]
    # Risk at decision 1 chooses among safety's subset {0, 1, 2}: best stop 0 (mean 0),
    # best go 2 (mean -1); its spread is the std of all eight risk entries, 0.5.
    assert (rows[1]["risk_best_stop"], rows[1]["risk_best_go"]) == (0, 2)
    assert rows[1]["risk_spread"] == pytest.approx(0.5)
    assert rows[1]["risk_z_diff"] == pytest.approx(2.0)
    # At decision 0 safety kept no go action, so risk sees none.
    assert math.isnan(rows[0]["risk_z_diff"])
    summary = waiting_measures(pd.DataFrame(rows))
    assert summary["decisions"] == 3 and summary["replay_timeout"] == 1.0
    assert summary["no_go"] == pytest.approx(2 / 3)
    assert summary["no_go_safety"] == pytest.approx(1 / 3)
    assert summary["no_go_risk"] == pytest.approx(1 / 3)
    assert summary["no_go_lane_keeping"] == 0.0
    assert summary["safety_raw_diff_removed"] == pytest.approx(1.5e-3)
    assert summary["risk_z_diff_removed"] == pytest.approx(2.0)


def test_rows_of_a_scalar_agent_count_its_stops() -> None:
    scene = SimpleNamespace(eval_run=0, net="holdout/x", density=0.5, episode=0)
    end = {"timeout": False, "success": True}
    steps = [
        SimpleNamespace(scene=scene, step=t, action=a, decision=Decision(np.array([a])), episode=e)
        for t, (a, e) in enumerate([(0, None), (4 % 4, None), (2, end)])
    ]
    rows = standstill_rows(steps, ("safety",), (), SPEEDS_A)
    assert STANDSTILL_ROWS.check(pd.DataFrame(rows).assign(replay_matches=True)) == ""
    summary = waiting_measures(pd.DataFrame(rows))
    assert summary["stop"] == pytest.approx(2 / 3)
    assert "no_go" not in summary
