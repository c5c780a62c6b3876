"""The facts of one decision the diagnosis tools share (priqn.tools.decisions), by hand."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from priqn.tools.decisions import decision_key, greedy_actions, greedy_removals, removed_by

LEVELS = ("safety", "risk", "lane_keeping", "progress", "comfort")
ABOVE = ("safety", "risk", "lane_keeping")  # progress chooses from lane_keeping's subset
GO_A = np.array([0.0, 0.0, 3.0, 6.0]) > 0  # actions 0, 1 stop; 2, 3 go


def _subsets(*rows: str) -> np.ndarray:
    """``"TTFF"`` per level → bool [L, A]."""
    return np.array([[c == "T" for c in r] for r in rows])


def test_the_level_that_removed_the_last_go_action() -> None:
    # safety keeps go action 2; risk keeps only stops: risk removed the last go action.
    s = _subsets("TTTF", "TTFF", "TFFF", "TFFF", "TFFF")
    assert removed_by(s, LEVELS, ABOVE, GO_A) == "risk"
    # safety keeps only stops: safety is the remover, whatever the levels below do.
    s = _subsets("TFFF", "TFFF", "TFFF", "TFFF", "TFFF")
    assert removed_by(s, LEVELS, ABOVE, GO_A) == "safety"
    # go action 3 survives down to lane_keeping: progress can still choose to move.
    s = _subsets("TTTT", "FTTT", "FFFT", "FFFT", "FFFT")
    assert removed_by(s, LEVELS, ABOVE, GO_A) == ""


def test_one_action_walked_in_a_given_order_or_at_one_level() -> None:
    # Two roots (a partial order): walked in the order given, not the rows' order.
    s = _subsets("TFTT", "FTTT", "TTTT", "TTFT", "TTTT")
    assert removed_by(s, LEVELS, ("risk", "safety"), 0) == "risk"
    assert removed_by(s, LEVELS, ("safety", "risk"), 0) == "risk"
    assert removed_by(s, LEVELS, ("safety", "risk"), 1) == "safety"
    assert removed_by(s, LEVELS, LEVELS, 2) == "progress"
    assert removed_by(s, LEVELS, LEVELS, 3) == ""
    # One level alone: does it keep the action (priqn mechanism's removals at --top)?
    assert removed_by(s, LEVELS, ("progress",), 1) == ""
    assert removed_by(s, LEVELS, ("progress",), 2) == "progress"
    # The leaf is one more set, walked last (priqn inspect's pruned_by_<objective>).
    with_leaf = np.concatenate([s, _subsets("TFFF")])
    order = (*LEVELS, "leaf")
    assert removed_by(with_leaf, order, order, 3) == "leaf"
    assert removed_by(with_leaf, order, order, 2) == "progress"


def test_greedy_actions_and_their_removals_per_head() -> None:
    q_HKA = np.zeros((2, 2, 4))
    q_HKA[0] = [[0.0, 1.0, 3.0, 0.0], [0.0, 1.0, -1.0, 0.0]]  # means 0, 1, 1, 0: a tie
    q_HKA[1] = [[0.0, 0.0, 0.0, 2.0], [0.0, 0.0, 0.0, 0.0]]  # means 0, 0, 0, 1
    assert greedy_actions(q_HKA).tolist() == [1, 3]  # the first action of a tie
    s = _subsets("TTFF", "FTFF")
    levels = ("safety", "risk")
    assert greedy_removals(q_HKA, levels, s, levels, levels) == {
        "safety": (1, ""),
        "risk": (3, "safety"),
    }
    # Over one level alone: risk's subset leaves out risk's greedy action too.
    assert greedy_removals(q_HKA, levels, s, levels, ("risk",))["risk"] == (3, "risk")


def test_decision_key_names_a_replayed_decision() -> None:
    scene = SimpleNamespace(eval_run=1, net="holdout/fourway_00", density=0.5, episode=2)
    step = SimpleNamespace(scene=scene, step=7, action=4)
    assert decision_key(step) == {
        "eval_run": 1,
        "net": "holdout/fourway_00",
        "density": 0.5,
        "episode": 2,
        "decision": 7,
        "action": 4,
    }
