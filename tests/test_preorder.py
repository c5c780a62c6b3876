"""Tests of the preorder core (public as priqn.preorder): preorders (priqn.agents.preorder),
comparators (priqn.agents.comparators) and Algorithm 1 (priqn.agents.subsets), checked
against its slow reference (priqn.bench.references.subsets); docs/preorder.md."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from priqn.agents.comparators import (
    COMPARATOR_FUNCTIONS,
    RunningScale,
    comparator_scores,
    fsd_relations,
    quantile_grid,
    zscore,
)
from priqn.agents.preorder import Preorder
from priqn.agents.subsets import _optimal_subsets, optimal_subsets, select
from priqn.bench.references.subsets import reference_optimal_subsets
from priqn.errors import PriqnError
from priqn.objectives import OBJECTIVES

FIVE = list(OBJECTIVES)
SQ2 = math.sqrt(2.0)


def q_of(rows: dict[str, list[list[float]]], po: Preorder) -> torch.Tensor:
    """Quantiles [N, K, A] (float64) from {objective: [[a0, a1, ...] per quantile k]}."""
    return torch.tensor([rows[name] for name in po.objectives], dtype=torch.float64)


def members(mask: torch.Tensor) -> set[int]:
    return {int(i) for i in torch.nonzero(mask).flatten()}


# ============================================================================ Preorder


def test_chain_and_presets():
    total = Preorder.preset("total")
    assert total == Preorder.chain(FIVE)
    assert total.objectives == tuple(FIVE)
    assert total.topological_order() == tuple(FIVE)
    assert total.parents("progress") == ("lane_keeping",)
    assert total.leaves() == ("comfort",) and total.roots() == ("safety",)
    assert total.is_chain()

    partial = Preorder.preset("partial")
    assert partial.parents("progress") == ("risk", "lane_keeping")
    assert partial.children("safety") == ("risk", "lane_keeping")
    assert partial.leaves() == ("comfort",)
    assert not partial.is_chain()
    order = partial.topological_order()
    for hi, lo in partial.edges:
        assert order.index(hi) < order.index(lo)


def test_topological_order_respects_edges_not_list_order():
    po = Preorder(["c", "b", "a"], [("a", "b"), ("b", "c")])
    assert po.topological_order() == ("a", "b", "c")
    assert po.objectives == ("c", "b", "a")  # N axis order unchanged


def test_several_leaves_and_roots():
    po = Preorder(["s", "x", "y"], [("s", "x"), ("s", "y")])
    assert po.leaves() == ("x", "y")
    po2 = Preorder(["a", "b"])  # no edges: two incomparable roots and leaves
    assert po2.roots() == ("a", "b") == po2.leaves()


@pytest.mark.parametrize(
    ("objectives", "edges", "match"),
    [
        (
            ["a", "b", "c"],
            [("a", "b"), ("b", "c"), ("c", "a")],
            r"cyclic preorder: a -> b -> c -> a",
        ),
        (["a", "b"], [("a", "a")], r"cyclic preorder: a -> a"),
        (["a", "b"], [("a", "x")], r"unknown objective 'x' \(valid: a, b\)"),
        (["a", "b", "a"], [], r"objective 'a' is listed twice"),
        (["a", "b"], [("a", "b"), ("a", "b")], r"edge \['a', 'b'\] is listed twice"),
        ([], [], r"at least one objective"),
        (["a", ""], [], r"non-empty strings"),
        (["a", "b"], [("a", "b", "c")], r"pair \[higher, lower\]"),
    ],
)
def test_invalid_preorders(objectives, edges, match):
    with pytest.raises(PriqnError, match=match):
        Preorder(objectives, edges)


def test_from_toml_round_trip_and_errors(tmp_path):
    good = tmp_path / "mine.toml"
    good.write_text(
        '[preorder]\nobjectives = ["safety", "progress"]\nedges = [["safety", "progress"]]\n'
    )
    po = Preorder.from_toml(good)
    assert po == Preorder.chain(["safety", "progress"])
    assert Preorder.resolve(str(good)) == po
    assert Preorder.from_dict(po.to_dict()) == po

    cyclic = tmp_path / "cyclic.toml"
    cyclic.write_text('[preorder]\nobjectives = ["a", "b"]\nedges = [["a", "b"], ["b", "a"]]\n')
    with pytest.raises(PriqnError, match=r"cyclic\.toml: cyclic preorder: a -> b -> a"):
        Preorder.from_toml(cyclic)

    unknown = tmp_path / "unknown.toml"
    unknown.write_text('[preorder]\nobjectives = ["a", "b"]\nedges = [["a", "speed"]]\n')
    with pytest.raises(
        PriqnError, match=r"unknown\.toml: .*unknown objective 'speed' \(valid: a, b\)"
    ):
        Preorder.from_toml(unknown)

    typo = tmp_path / "typo.toml"
    typo.write_text('[preorder]\nobjective = ["a"]\n')
    with pytest.raises(PriqnError, match=r"typo\.toml \[preorder\]: unknown key 'objective'"):
        Preorder.from_toml(typo)

    missing = tmp_path / "missing.toml"
    missing.write_text("[other]\nx = 1\n")
    with pytest.raises(PriqnError, match=r"missing\.toml: missing \[preorder\] table"):
        Preorder.from_toml(missing)

    with pytest.raises(PriqnError, match=r"unknown preorder 'nope'"):
        Preorder.resolve("nope")
    with pytest.raises(
        PriqnError, match=r"unknown preorder preset 'nope' \(valid: total, partial, right-of-way\)"
    ):
        Preorder.preset("nope")


def test_reordered_to_reward_order():
    po = Preorder(["comfort", "safety"], [("safety", "comfort")])
    assert Preorder.resolve(po, objectives=["safety", "comfort"]).objectives == (
        "safety",
        "comfort",
    )
    with pytest.raises(PriqnError, match=r"missing: risk; extra: comfort"):
        po.reordered(["safety", "risk"])


# ============================================================================ comparators


def test_quantile_grid():
    assert quantile_grid(4).tolist() == [0.125, 0.375, 0.625, 0.875]


@pytest.mark.parametrize("comparator", sorted(COMPARATOR_FUNCTIONS))
def test_scores_match_literal_definitions(comparator):
    gen = torch.Generator().manual_seed(3)
    q = torch.randn(6, 3, 8, 5, generator=gen, dtype=torch.float64) * 4 + 10
    z = zscore(q)  # literal Z̃ over all K·A entries, population std
    if comparator == "qd":
        ideal = z.amax(dim=-1, keepdim=True)
        expected = -(z - ideal).abs().mean(dim=-2)
    elif comparator == "mv":
        expected = z.mean(dim=-2) - 0.7 * z.std(dim=-2, correction=0)
    elif comparator == "fsd":  # shown score only: the mean (relations are pairwise)
        expected = z.mean(dim=-2)
    else:  # K = 8, alpha = 0.3: tau = 0.0625, 0.1875 (<= 0.3), 0.3125 (> 0.3) -> 2 quantiles
        expected = z[..., :2, :].mean(dim=-2)
    got = comparator_scores(q, comparator, mv_lambda=0.7, cvar_alpha=0.3)
    torch.testing.assert_close(got, expected)


def test_scores_hand_values_k4():
    # One objective, K = 4, A = 2. a0 = [0, 1, 2, 3], a1 = [1, 1, 1, 1]:
    # 8 entries, mean 10/8 = 1.25; squared deviations a0: 1.5625 .0625 .5625 3.0625,
    # a1: .0625 x 4 -> sum 5.5, population var 5.5/8 = 0.6875, std 0.8292.
    # QD: ideal_k = max(a0, a1) = [1, 1, 2, 3]; |a0 - ideal| = [1, 0, 0, 0] -> mean 0.25;
    #     |a1 - ideal| = [0, 0, 1, 2] -> mean 0.75; scores -0.3015, -0.9045.
    # MV (lambda 1): a0 mean 1.5, std sqrt(1.25) = 1.1180; a1 mean 1, std 0;
    #     scores ((1.5 - 1.25) - 1.1180)/0.8292 = -1.0469, (1 - 1.25)/0.8292 = -0.3015.
    # CVaR (alpha 0.5): tau = .125, .375 -> first two quantiles: a0 0.5, a1 1;
    #     scores (0.5 - 1.25)/0.8292 = -0.9045, (1 - 1.25)/0.8292 = -0.3015.
    q = torch.tensor([[[0, 1], [1, 1], [2, 1], [3, 1]]], dtype=torch.float64)  # [N=1, K=4, A=2]
    std = math.sqrt(0.6875)
    torch.testing.assert_close(
        comparator_scores(q, "qd"), torch.tensor([[-0.25, -0.75]], dtype=torch.float64) / std
    )
    mv = comparator_scores(q, "mv", mv_lambda=1.0)
    torch.testing.assert_close(
        mv, torch.tensor([[(0.25 - math.sqrt(1.25)) / std, -0.25 / std]], dtype=torch.float64)
    )
    cvar = comparator_scores(q, "cvar", cvar_alpha=0.5)
    torch.testing.assert_close(
        cvar, torch.tensor([[-0.75 / std, -0.25 / std]], dtype=torch.float64)
    )
    torch.testing.assert_close(
        mv, torch.tensor([[-1.0469, -0.3015]], dtype=torch.float64), atol=1e-4, rtol=0
    )


def test_constant_objective_is_all_indifferent():
    # std 0 -> clamped to 1e-6; Z - mean = 0 -> every score 0 -> nothing dominates.
    q = torch.full((2, 3, 4), 7.0)
    out = optimal_subsets(q, Preorder.chain(["a", "b"]), eps=0.0)
    assert out.per_objective.all() and out.leaf.all()


# ============================================================================ hand-worked cases


def test_chain_rejects_the_fastest_action_when_it_is_unsafe():
    """Total order; a0 = stop, a1 = cruise, a2 = fast but crashes; K = 2, eps = 0.2."""
    po = Preorder.preset("total")
    zeros = [[0, 0, 0], [0, 0, 0]]
    q = q_of(
        {
            # safety Z = [[1, 1, -2], [1, 1, -2]]: mean 0, population std sqrt(12/6) = sqrt 2,
            # Z~ = 1/sqrt2 (a0, a1), -sqrt2 (a2); ideal_k = 1/sqrt2;
            # W1 = 0, 0, 3/sqrt2 = 2.1213 -> scores 0, 0, -2.1213.
            # a0, a1 beat a2 (2.12 > 0.2); a0 ~ a1. S_safety = {a0, a1}.
            "safety": [[1, 1, -2], [1, 1, -2]],
            # risk, lane keeping, comfort constant: every score 0, every pair indifferent.
            "risk": zeros,
            "lane_keeping": zeros,
            # progress Z = [[0, 1, 2]] x 2: mean 1, std sqrt(2/3) = 0.8165,
            # Z~ = -1.2247, 0, 1.2247 -> scores -2.4495, -1.2247, 0 (a2 best).
            # Undecided pairs within S_up = {a0, a1}: a1 - a0 = 1.22 > 0.2 -> a1 beats a0.
            # (a2's pairs were decided by safety and cannot be overridden.)
            "progress": [[0, 1, 2], [0, 1, 2]],
            "comfort": zeros,
        },
        po,
    )
    out = optimal_subsets(q, po, eps=0.2)
    torch.testing.assert_close(
        out.scores[0], torch.tensor([0.0, 0.0, -3 / SQ2], dtype=torch.float64)
    )
    torch.testing.assert_close(
        out.scores[3], torch.tensor([-2 * 1.5**0.5, -(1.5**0.5), 0.0], dtype=torch.float64)
    )
    expected = [{0, 1}, {0, 1}, {0, 1}, {1}, {1}]
    assert [members(s) for s in out.per_objective] == expected
    assert members(out.leaf) == {1}  # cruise
    # Progress alone would pick the fast, unsafe action.
    alone = optimal_subsets(q[3:4], Preorder(["progress"]), eps=0.2)
    assert members(alone.leaf) == {2}


def test_partial_order_keeps_an_incomparable_pair():
    """Paper's partial order; risk and lane keeping disagree on (a0, a1); K = 1, eps = 0.2."""
    po = Preorder.preset("partial")
    rows = {
        "safety": [[0, 0, 0]],  # constant: all indifferent, S_safety = {a0, a1, a2}
        # risk Z = [2, 0, 0]: mean 2/3, var (16/9 + 4/9 + 4/9)/3 = 8/9, std 0.9428;
        # Z~ = 1.4142, -0.7071, -0.7071; K = 1 so ideal = 1.4142, scores 0, -2.1213, -2.1213.
        # a0 beats a1 and a2; a1 ~ a2. S_risk = {a0}.
        "risk": [[2, 0, 0]],
        # lane keeping, mirrored: scores -2.1213, 0, -2.1213. S_lane = {a1}.
        "lane_keeping": [[0, 2, 0]],
        # progress scores -2.4495, -1.2247, 0: prefers a2, then a1 -- but every pair is
        # already decided by its parents: (a0, a1) incomparable (risk says a0, lane a1),
        # (a0, a2) a0 by risk, (a1, a2) a1 by lane. Nothing is left for progress.
        "progress": [[0, 1, 2]],
        "comfort": [[0, 0, 0]],
    }
    q = q_of(rows, po)
    out = optimal_subsets(q, po, eps=0.2)
    # Agg at progress: C = S_risk | S_lane = {a0, a1}; neither beats the other
    # (incomparable), so both survive, and progress cannot break the tie.
    assert [members(s) for s in out.per_objective] == [{0, 1, 2}, {0}, {1}, {0, 1}, {0, 1}]
    assert members(out.leaf) == {0, 1}
    # The total order ranks risk above lane keeping, so there a0 wins outright.
    total = Preorder.preset("total")
    out_total = optimal_subsets(q_of(rows, total), total, eps=0.2)
    assert members(out_total.leaf) == {0}


def test_eps_turns_a_dominance_into_an_indifference():
    """Chain safety > progress, K = 1, A = 2."""
    po = Preorder.chain(["safety", "progress"])
    # safety Z = [1, 0]: mean 0.5, std 0.5, Z~ = 1, -1; scores 0, -2 (difference 2).
    # progress Z = [0, 1]: scores -2, 0 (a1 better by 2).
    q = q_of({"safety": [[1, 0]], "progress": [[0, 1]]}, po)
    strict = optimal_subsets(q, po, eps=1.5)  # 2 > 1.5: a0 dominates a1 on safety
    assert members(strict.subset("safety")) == {0} and members(strict.leaf) == {0}
    # eps_safety = 2.5: |2| <= 2.5, the pair is indifferent on safety, so progress decides.
    tolerant = optimal_subsets(q, po, eps={"safety": 2.5, "progress": 0.2})
    assert members(tolerant.subset("safety")) == {0, 1} and members(tolerant.leaf) == {1}
    assert members(optimal_subsets(q, po, eps=[2.5, 0.2]).leaf) == {1}
    assert optimal_subsets(q, po, eps=math.inf).per_objective.all()


def _cycle_rows() -> dict[str, list[list[float]]]:
    # K = 1, A = 3. Each root decides exactly one pair of the triple with eps = 1.5:
    # values (0, 1.5, 0.75) -> mean 0.75, std sqrt(0.375) = 0.6124,
    # Z~ = -1.2247, 1.2247, 0: the extreme pair differs by 2.449 > 1.5 (decided), the two
    # pairs with the middle value by 1.2247 <= 1.5 (indifferent).
    return {
        "x": [[0, 1.5, 0.75]],  # a1 beats a0
        "y": [[0.75, 0, 1.5]],  # a2 beats a1
        "z": [[1.5, 0.75, 0]],  # a0 beats a2
        "w": [[0, 0, 0]],
    }


def test_three_roots_form_a_cycle_plain_rule_empties():
    """x, y, z -> w: the inherited "beaten by" relation is the cycle a0 < a1 < a2 < a0."""
    po = Preorder(["x", "y", "z", "w"], [("x", "w"), ("y", "w"), ("z", "w")])
    q = q_of(_cycle_rows(), po)
    out = optimal_subsets(q, po, eps=1.5)
    assert [members(s) for s in out.per_objective[:3]] == [{1, 2}, {0, 2}, {0, 1}]
    # Agg at w: C = {a0, a1, a2}; every element is beaten by another, so the plain rule
    # {a : no b in C beats a} is EMPTY; the top strongly connected component is all three.
    assert members(out.subset("w")) == {0, 1, 2} and members(out.leaf) == {0, 1, 2}
    plain = optimal_subsets(q, po, eps=1.5, select_rule="plain")
    assert members(plain.subset("w")) == set() and members(plain.leaf) == set()


def test_three_leaves_virtual_leaf_cycle():
    po = Preorder(["x", "y", "z"])  # three incomparable objectives: the virtual leaf aggregates
    rows = _cycle_rows()
    q = q_of({k: rows[k] for k in "xyz"}, po)
    assert members(optimal_subsets(q, po, eps=1.5).leaf) == {0, 1, 2}
    assert members(optimal_subsets(q, po, eps=1.5, select_rule="plain").leaf) == set()


def test_select_rule_on_explicit_relations():
    # a0 beaten by a1, a1 by a2, a2 by a0 (a cycle), and a3 beaten by a0; C = everything.
    dom = torch.zeros(1, 4, 4, dtype=torch.bool)
    for winner, loser in [(1, 0), (2, 1), (0, 2), (0, 3)]:
        dom[0, winner, loser] = True
    c = torch.ones(1, 4, dtype=torch.bool)
    assert members(select(c, dom)[0]) == {0, 1, 2}
    assert members(select(c, dom, rule="plain")[0]) == set()
    # Restricted to C = {a0, a3}, only a0 -> a3 remains: a0 survives.
    c2 = torch.tensor([[True, False, False, True]])
    assert members(select(c2, dom)[0]) == {0}
    # An incomparable pair (both directions) is not a "beats" edge.
    both = torch.zeros(1, 2, 2, dtype=torch.bool)
    both[0, 0, 1] = both[0, 1, 0] = True
    assert members(select(torch.ones(1, 2, dtype=torch.bool), both)[0]) == {0, 1}


# ============================================================================ input checks


def test_input_errors():
    po = Preorder.preset("total")
    q = torch.zeros(2, 5, 4, 3)
    with pytest.raises(PriqnError, match=r"N = 4 objectives .* preorder has 5"):
        optimal_subsets(torch.zeros(2, 4, 4, 3), po)
    with pytest.raises(PriqnError, match=r"expected shape \[B, N, K, A\]"):
        optimal_subsets(torch.zeros(5, 4), po)
    with pytest.raises(PriqnError, match=r"float tensor"):
        optimal_subsets(torch.zeros(2, 5, 4, 3, dtype=torch.int64), po)
    with pytest.raises(PriqnError, match=r"unknown comparator 'wd' \(valid: qd, mv, cvar, fsd\)"):
        optimal_subsets(q, po, comparator="wd")
    with pytest.raises(PriqnError, match=r"eps\[risk\]: expected a number >= 0"):
        optimal_subsets(q, po, eps=[0.2, -0.1, 0.2, 0.2, 0.2])
    with pytest.raises(PriqnError, match=r"one value per objective"):
        optimal_subsets(q, po, eps=[0.2, 0.2])
    with pytest.raises(PriqnError, match=r"missing: comfort"):
        optimal_subsets(q, po, eps={n: 0.1 for n in FIVE[:4]})
    with pytest.raises(PriqnError, match=r"cvar_alpha=0.1 selects no quantile of the K=4 grid"):
        optimal_subsets(q, po, comparator="cvar", cvar_alpha=0.1)
    with pytest.raises(PriqnError, match=r"cvar_alpha: expected a number in \(0, 1\]"):
        optimal_subsets(q, po, comparator="cvar", cvar_alpha=1.5)
    bad = q.clone()
    bad[1, 2, 0, 0] = float("nan")
    with pytest.raises(PriqnError, match=r"NaN or inf"):
        optimal_subsets(bad, po)
    with pytest.raises(PriqnError, match=r"unknown select rule"):
        optimal_subsets(q, po, select_rule="best")


def test_single_state_and_dtypes():
    po = Preorder.preset("partial")
    gen = torch.Generator().manual_seed(1)
    q = torch.randn(3, 5, 8, 6, generator=gen)
    ref = optimal_subsets(q, po)
    one = optimal_subsets(q[1], po)
    assert one.per_objective.shape == (5, 6) and one.leaf.shape == (6,)
    assert torch.equal(one.per_objective, ref.per_objective[1])
    for dtype in (torch.float64, torch.float16, torch.bfloat16):
        out = optimal_subsets(q.to(dtype), po)
        assert out.leaf.dtype == torch.bool and out.leaf.any(-1).all()
    assert torch.equal(optimal_subsets(q.double(), po).leaf, ref.leaf)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_matches_cpu():
    po = Preorder.preset("partial")
    gen = torch.Generator().manual_seed(2)
    q = torch.randn(64, 5, 16, 25, generator=gen, dtype=torch.float64)
    cpu = optimal_subsets(q, po)
    gpu = optimal_subsets(q.cuda(), po)
    assert torch.equal(cpu.per_objective, gpu.per_objective.cpu())
    assert torch.equal(cpu.leaf, gpu.leaf.cpu())


# ============================================================================ fsd, scale-aware normalisation


def _one_objective(values_AK):
    """Quantiles [N=1, K, A] from per-action quantile lists."""
    return torch.tensor(values_AK, dtype=torch.float64).T.unsqueeze(0)


def test_fsd_keeps_a_better_tail_that_qd_prunes():
    po = Preorder(["progress"])
    # a: mean 2.00, lower tail -1; b: mean 1.75 (slightly lower), lower tail +1 (much better).
    # All 8 entries: mean 1.875, population std sqrt(21.375 / 8) = 1.6346.
    # QD/mean difference a - b = 0.25 / 1.6346 = 0.153 > eps = 0.1: qd prunes b.
    # FSD: d_k = (a_k - b_k) / 1.6346 = [-1.22, -0.31, 0.61, 1.53]; min -1.22 < -0.1, so a
    # does not dominate b (and mean(b - a) = -0.153 < 0.1): incomparable, both survive.
    q = _one_objective([[-1.0, 1.0, 3.0, 5.0], [1.0, 1.5, 2.0, 2.5]])
    assert members(optimal_subsets(q, po, "qd", 0.1).leaf) == {0}
    assert members(optimal_subsets(q, po, "fsd", 0.1).leaf) == {0, 1}


def test_worse_at_every_quantile_by_a_margin_is_pruned_by_both():
    po = Preorder(["progress"])
    # c = a - 1 everywhere. Entries [0,1,2,3,-1,0,1,2]: mean 1, std sqrt(12/8) = 1.2247, so
    # d_k = 1 / 1.2247 = 0.8165 at every k: min 0.8165 >= -0.2 and mean 0.8165 > 0.2.
    q = _one_objective([[0.0, 1.0, 2.0, 3.0], [-1.0, 0.0, 1.0, 2.0]])
    for comparator in ("qd", "fsd"):
        assert members(optimal_subsets(q, po, comparator, 0.2).leaf) == {0}


def test_fsd_relations_hand_values():
    c = torch.tensor([[[-2.875, -0.875, 1.125, 3.125], [-0.875, -0.375, 0.125, 0.625]]])
    dom, domby = fsd_relations(c, torch.tensor([[1.0]]), 0.2)
    # a vs b: d = [-2, -0.5, 1, 2.5]: mean 0.25 > 0.2 but min -2 < -0.2 -> no dominance.
    assert not dom.any() and not domby.any()
    dom, _ = fsd_relations(c, torch.tensor([[1.0]]), 2.0)  # min -2 >= -2, mean 0.25 <= 2
    assert not dom.any()
    c2 = torch.tensor([[[1.0, 2.0], [0.0, 0.5]]])  # d = [1, 1.5]: min 1, mean 1.25
    dom, domby = fsd_relations(c2, torch.tensor([[1.0]]), 1.0)
    assert dom.tolist() == [[[False, True], [False, False]]] and torch.equal(domby, dom.mT)


def test_scale_aware_normalisation_lets_tiny_safety_noise_pass():
    po = Preorder.chain(["safety", "progress"])
    a = 25
    q = torch.zeros(2, 4, a, dtype=torch.float64)
    q[0, :, 2:] = -1e-4  # safety: two actions 1e-4 better than the other 23 (on a -10 scale)
    q[1, :, :] = torch.arange(a, dtype=torch.float64) * 0.01
    q[1, :, a - 1] = 5.0  # progress: the last action is better by 5
    literal = optimal_subsets(q, po, "qd", 0.2)
    assert members(literal.subset("safety")) == {0, 1}  # the per-state z-score blows 1e-4 up
    assert members(literal.leaf) == {0, 1}  # the action better by 5 on progress is gone
    floor = torch.tensor([2.0, 1.0])  # typical spreads of the two objectives
    for comparator in COMPARATOR_FUNCTIONS:
        scaled = optimal_subsets(q, po, comparator, 0.2, spread_floor=floor)
        assert scaled.subset("safety").all(), comparator  # 1e-4 / 2 is inside eps
        assert members(scaled.leaf) == {a - 1}, comparator
    with pytest.raises(PriqnError, match=r"spread_floor: expected one value per objective"):
        optimal_subsets(q, po, "qd", 0.2, spread_floor=[1.0])


def test_running_scale_is_an_ema_of_the_per_state_spread():
    scale = RunningScale(2, momentum=0.25, fraction=0.5)
    assert scale.floor().tolist() == [0.0, 0.0]  # no data yet: the paper-literal setting
    q = torch.zeros(2, 2, 1, 2, dtype=torch.float64)  # [B, N, K, A]
    q[0, 0, 0] = torch.tensor([-1.0, 1.0])  # std 1
    q[1, 0, 0] = torch.tensor([-3.0, 3.0])  # std 3 -> batch mean 2
    q[:, 1, 0] = torch.tensor([0.0, 8.0])  # std 4
    scale.update(q)
    assert scale.scale_N.tolist() == [2.0, 4.0] and scale.floor().tolist() == [1.0, 2.0]
    scale.update(q * 3)  # batch spreads 6 and 12: 0.75 * old + 0.25 * new
    assert scale.scale_N.tolist() == [3.0, 6.0]
    restored = RunningScale(2, momentum=0.25, fraction=0.5)
    restored.load_state_dict(scale.state_dict())
    assert restored.scale_N.tolist() == [3.0, 6.0] and restored.count == 2


def test_subset_sizes():
    po = Preorder.chain(["safety", "progress"])
    q = torch.zeros(2, 2, 1, 3)
    q[0, 0, 0] = torch.tensor([1.0, 1.0, 0.0])  # state 0: safety keeps {0, 1}
    q[0, 1, 0] = torch.tensor([0.0, 1.0, 0.0])  # then progress keeps {1}
    sizes = optimal_subsets(q, po, "qd", 0.1).sizes()
    # state 1 is all-equal: 3 and 3 -> means (2 + 3) / 2 and (1 + 3) / 2
    assert sizes == {"safety": 2.5, "progress": 2.0, "leaf": 2.0}


# ============================================================================ properties


def reference_members(
    out, q: torch.Tensor, po: Preorder, eps, comparator: str
) -> list[tuple[list[set[int]], set[int]]]:
    """The oracle's subsets of every state of ``q`` as sets: ``[(per objective, leaf)]``.

    The score comparators relate actions by the batched core's own scores
    (``out.scores``), so rounding cannot flip a relation that sits exactly at ε."""
    sets, leaf = reference_optimal_subsets(
        q.numpy(), po, eps, comparator, cvar_alpha=1.0, scores_BNA=out.scores.numpy()
    )
    sets_BNA, leaf_BA = torch.from_numpy(sets), torch.from_numpy(leaf)
    return [([members(row) for row in sets_BNA[b]], members(leaf_BA[b])) for b in range(q.shape[0])]


@st.composite
def dags(draw, max_n: int = 5) -> Preorder:
    n = draw(st.integers(1, max_n))
    names = [f"o{i}" for i in range(n)]
    order = draw(st.permutations(names))  # hidden priority order; edges go down it
    edges = [(order[i], order[j]) for i in range(n) for j in range(i + 1, n) if draw(st.booleans())]
    return Preorder(names, draw(st.permutations(edges)) if edges else [])


@st.composite
def problems(draw, preorders=None):
    po = draw(preorders if preorders is not None else dags())
    b, k, a = draw(st.integers(1, 3)), draw(st.integers(1, 4)), draw(st.integers(1, 6))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    if draw(st.booleans()):  # small integers: many ties and exact indifferences
        values = rng.integers(-2, 3, size=(b, len(po), k, a)).astype(np.float64)
    else:
        values = rng.normal(size=(b, len(po), k, a)) * rng.uniform(0.1, 5)
    eps_value = st.one_of(st.sampled_from([0.0, math.inf]), st.floats(0.0, 3.0))
    eps = draw(st.one_of(eps_value, st.lists(eps_value, min_size=len(po), max_size=len(po))))
    comparator = draw(st.sampled_from(["qd", "mv", "cvar", "fsd"]))
    return po, torch.from_numpy(values), eps, comparator


FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _run(po, q, eps, comparator, **kw):
    return optimal_subsets(q, po, comparator=comparator, eps=eps, cvar_alpha=1.0, **kw)


@FAST
@given(problems())
def test_property_nonempty_and_matches_set_reference(problem):
    po, q, eps, comparator = problem
    out = _run(po, q, eps, comparator)
    assert out.per_objective.any(-1).all() and out.leaf.any(-1).all()
    for b, (subsets, leaf) in enumerate(reference_members(out, q, po, eps, comparator)):
        assert [members(s) for s in out.per_objective[b]] == subsets
        assert members(out.leaf[b]) == leaf
    # The O(A) threshold shortcut for tree objectives changes nothing.
    dense = _optimal_subsets(
        q,
        po,
        comparator,
        eps,
        mv_lambda=0.5,
        cvar_alpha=1.0,
        select_rule="top-scc",
        check_finite=True,
        dense_only=True,
    )
    assert torch.equal(dense.per_objective, out.per_objective)
    assert torch.equal(dense.leaf, out.leaf)
    # Each subset lies inside the union of its parents' subsets.
    for r in po.objectives:
        parents = po.parents(r)
        if parents:
            union = torch.stack([out.subset(p) for p in parents]).any(0)
            assert not (out.subset(r) & ~union).any()


@st.composite
def merge_heavy_problems(draw):
    """Deeper DAGs (3-6 objectives, dense edges), continuous values, mid-range eps: about
    one example in twenty-five has a cycle in some "beaten by" relation."""
    n = draw(st.integers(3, 6))
    names = [f"o{i}" for i in range(n)]
    order = draw(st.permutations(names))
    edges = [(order[i], order[j]) for i in range(n) for j in range(i + 1, n) if draw(st.booleans())]
    po = Preorder(names, edges)
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    q = torch.from_numpy(rng.normal(size=(8, n, draw(st.integers(1, 2)), draw(st.integers(3, 6)))))
    return po, q, draw(st.floats(0.3, 2.0)), "qd"


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(merge_heavy_problems())
def test_property_deep_dags_nonempty_and_match_reference(problem):
    po, q, eps, comparator = problem
    out = _run(po, q, eps, comparator)
    assert out.per_objective.any(-1).all() and out.leaf.any(-1).all()
    for b, (subsets, leaf) in enumerate(reference_members(out, q, po, eps, comparator)):
        assert [members(s) for s in out.per_objective[b]] == subsets
        assert members(out.leaf[b]) == leaf


@FAST
@given(problems(preorders=st.sampled_from([Preorder.preset("total"), Preorder.preset("partial")])))
def test_property_plain_rule_equals_top_scc_on_paper_preorders(problem):
    po, q, eps, comparator = problem
    # dense_only: every select() builds the matrices and runs the closure (no shortcut),
    # so this really compares the top-SCC rule with the literal line 23.
    kw = dict(mv_lambda=0.5, cvar_alpha=1.0, check_finite=True, dense_only=True)
    top = _optimal_subsets(q, po, comparator, eps, select_rule="top-scc", **kw)
    plain = _optimal_subsets(q, po, comparator, eps, select_rule="plain", **kw)
    assert torch.equal(top.per_objective, plain.per_objective)
    assert torch.equal(top.leaf, plain.leaf)


@FAST
@given(
    problems(preorders=st.integers(1, 5).map(lambda n: Preorder.chain([f"o{i}" for i in range(n)])))
)
def test_property_chain_sets_are_nested(problem):
    po, q, eps, comparator = problem
    out = _run(po, q, eps, comparator)
    sets = out.per_objective
    for child in range(1, len(po)):
        assert not (sets[:, child] & ~sets[:, child - 1]).any()
    assert torch.equal(out.leaf, sets[:, -1])


@FAST
@given(problems())
def test_property_infinite_eps_keeps_everything(problem):
    po, q, _, comparator = problem
    out = _run(po, q, math.inf, comparator)
    assert out.per_objective.all() and out.leaf.all()


@FAST
@given(problems(), st.data())
def test_property_strictly_best_root_action_is_the_only_survivor(problem, data):
    po, q, _, comparator = problem
    root = data.draw(st.sampled_from(po.roots()))
    star = data.draw(st.integers(0, q.shape[-1] - 1))
    q = q.clone()
    r = po.index(root)
    # Strictly better than every other action at every quantile of the root objective.
    q[:, r, :, star] = q[:, r].amax(dim=-1) + 1.0
    comparator = "qd" if comparator == "mv" else comparator  # MV also weighs the spread
    out = _run(po, q, 0.0, comparator)
    assert (out.subset(root).sum(-1) == 1).all() and out.subset(root)[:, star].all()
    if po.is_chain():
        assert out.per_objective[:, :, star].all() and (out.leaf.sum(-1) == 1).all()


@FAST
@given(problems())
def test_property_rows_do_not_depend_on_the_batch(problem):
    po, q, eps, comparator = problem
    for dtype in (torch.float64, torch.float32):
        batch = _run(po, q.to(dtype), eps, comparator)
        for b in range(q.shape[0]):
            alone = _run(po, q[b : b + 1].to(dtype), eps, comparator)
            assert torch.equal(alone.per_objective[0], batch.per_objective[b])
            assert torch.equal(alone.leaf[0], batch.leaf[b])


# ============================================================================ benchmark


@pytest.mark.parametrize("comparator", ["qd", "fsd"])
def test_bench_smoke(comparator):
    code = (
        "import argparse, sys\n"
        "from priqn.bench import preorder as m\n"
        "p = argparse.ArgumentParser(); m.configure_parser(p)\n"
        "sys.exit(m.run(p.parse_args(['-B', '8', '-K', '8', '-A', '6', '--repeats', '2',"
        " '--reference-repeats', '1', '--obs-size', '64', '--threads', '1', '--preorder', 'partial',"
        f" '--comparator', '{comparator}'])))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr + res.stdout
    assert "same subsets as the reference:  yes" in res.stdout
    assert "speed-up batched vs reference" in res.stdout
