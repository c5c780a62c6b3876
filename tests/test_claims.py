"""The paper's claims and the verdict rule (priqn/analysis/claims.py), on hand-made tables."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from priqn.analysis import claims
from priqn.analysis.claims import (
    CLAIMS,
    IQN,
    PAPER_ROWS,
    PR_IQN_STAR,
    Claim,
    Comparison,
    bootstrap_means,
    evaluate_claim,
    outcome,
    run_means,
    verdict,
)
from priqn.errors import PriqnError

STAR, BASE = PR_IQN_STAR.render(), IQN.render()


def episodes(label: str, rate, seeds=(0, 1), runs=(0, 1), densities=(0.5, 0.75, 1.0), n=4):
    """``n`` episodes per (seed, run, density, net); ``rate(seed, run, density)`` succeed."""
    rows = []
    for s in seeds:
        for r in runs:
            for d in densities:
                for net in ("holdout/a", "holdout/b"):
                    k = round(rate(s, r, d) * n)
                    for e in range(n):
                        rows.append(
                            {
                                "label": label,
                                "train_seed": s,
                                "eval_run": r,
                                "density": d,
                                "net": net,
                                "success": e < k,
                                "return_safety": -1.0 if e >= k else 0.0,
                                "return_risk": 0.0,
                                "return_lane_keeping": 0.0,
                            }
                        )
    return pd.DataFrame(rows)


def test_run_means_by_hand() -> None:
    # seed 0: run 0 -> 1/4, run 1 -> 2/4; seed 1: 3/4 and 4/4, at density 0.5 only.
    table = episodes(BASE, lambda s, r, d: (1 + r + 2 * s) / 4 if d == 0.5 else 0.0)
    np.testing.assert_allclose(run_means(table, BASE, "success", 0.5), [[0.25, 0.5], [0.75, 1.0]])
    # Over all three densities the 0.5 column is diluted by two zero densities: ÷ 3.
    np.testing.assert_allclose(
        run_means(table, BASE, "success", None), np.array([[0.25, 0.5], [0.75, 1.0]]) / 3
    )
    assert run_means(table, BASE, "success", 0.6).size == 0


def test_bootstrap_is_two_level_and_seeded() -> None:
    constant = np.full((3, 3), 0.4)
    assert np.allclose(bootstrap_means(constant, 50, np.random.default_rng(0)), 0.4)
    # Seeds differ, runs within a seed do not: every bootstrap mean is an average of
    # two drawn seed values, so only 0, 0.5 and 1 can occur.
    two_seeds = np.array([[0.0, 0.0], [1.0, 1.0]])
    means = bootstrap_means(two_seeds, 2000, np.random.default_rng(1))
    assert set(np.round(means, 9)) == {0.0, 0.5, 1.0}
    assert abs((means == 0.5).mean() - 0.5) < 0.05  # P(one of each) = 1/2
    again = bootstrap_means(two_seeds, 2000, np.random.default_rng(1))
    np.testing.assert_array_equal(means, again)


@pytest.mark.parametrize(
    ("kind", "lo", "hi", "margin", "expected"),
    [
        ("better", 0.01, 0.30, 0.05, "holds"),  # CI above 0
        ("better", 0.01, 0.03, 0.05, "holds"),  # small but certain: still the claimed side
        ("better", -0.30, -0.01, 0.05, "contradicted"),  # the opposite holds
        ("better", -0.03, 0.04, 0.05, "contradicted"),  # within ±5 points: no effect
        ("better", -0.10, 0.20, 0.05, "unclear"),  # too wide to tell
        ("better", -0.01, 0.01, 0.0, "unclear"),  # returns: no margin, sign unknown
        ("equivalent", -0.03, 0.04, 0.05, "holds"),
        ("equivalent", 0.01, 0.20, 0.05, "contradicted"),  # a real difference
        ("equivalent", -0.10, 0.02, 0.05, "unclear"),
    ],
)
def test_outcome_rule(kind, lo, hi, margin, expected) -> None:
    assert outcome(kind, lo, hi, margin) == expected


def test_verdict_rule() -> None:
    assert verdict(["holds", "holds"]) == "reproduced"
    assert verdict(["holds", "unclear"]) == "inconclusive at this budget"
    assert verdict(["holds", "unclear", "contradicted"]) == "not reproduced"


def test_claims_name_the_papers_rows() -> None:
    labels = [row.render() for row in PAPER_ROWS]
    assert len(set(labels)) == 11
    assert STAR == "Pr-IQN QD ✓ 0.2 ✗"
    assert "Pr-IQN QD ✗ 0.2 ✓" in labels  # partial order, training preorder off
    worst = next(c for c in CLAIMS if c.key == "ma-iqn-worst")
    assert len(worst.comparisons) == 10
    star = next(c for c in CLAIMS if c.key == "star-vs-iqn")
    assert [(c.density, c.paper) for c in star.comparisons] == [
        (0.5, 0.077),
        (0.75, 0.166),
        (1.0, 0.203),
    ]


def star_vs_iqn() -> Claim:
    return next(c for c in CLAIMS if c.key == "star-vs-iqn")


def test_a_clear_gain_is_reproduced_with_its_difference() -> None:
    # Pr-IQN* succeeds 3 of 4, IQN 1 of 4, in every run: +50 points, CI [+50, +50].
    table = pd.concat([episodes(STAR, lambda s, r, d: 0.75), episodes(BASE, lambda s, r, d: 0.25)])
    result = evaluate_claim(star_vs_iqn(), table, reps=200, seed=0)
    assert result.verdict == "reproduced"
    for x in result.results:
        assert (x.diff, x.lo, x.hi, x.outcome) == pytest.approx((0.5, 0.5, 0.5, "holds"))


def test_no_difference_is_not_reproduced_and_a_reversal_too() -> None:
    same = pd.concat([episodes(STAR, lambda s, r, d: 0.5), episodes(BASE, lambda s, r, d: 0.5)])
    assert evaluate_claim(star_vs_iqn(), same, reps=200).verdict == "not reproduced"
    worse = pd.concat([episodes(STAR, lambda s, r, d: 0.0), episodes(BASE, lambda s, r, d: 1.0)])
    result = evaluate_claim(star_vs_iqn(), worse, reps=200)
    assert result.verdict == "not reproduced"
    assert {x.outcome for x in result.results} == {"contradicted"}


def test_seed_noise_makes_it_inconclusive() -> None:
    # Pr-IQN*'s seed 0 never succeeds, seed 1 always; IQN sits at 0.5: the seed bootstrap
    # straddles 0 far beyond ±5 points.
    table = pd.concat(
        [episodes(STAR, lambda s, r, d: float(s)), episodes(BASE, lambda s, r, d: 0.5)]
    )
    result = evaluate_claim(star_vs_iqn(), table, reps=500)
    assert result.verdict == "inconclusive at this budget"
    assert all(x.lo < -0.05 and x.hi > 0.05 for x in result.results)


def test_pending_when_rows_seeds_or_densities_are_missing() -> None:
    star = episodes(STAR, lambda s, r, d: 0.75)
    result = evaluate_claim(star_vs_iqn(), star)
    assert (result.verdict, result.missing) == ("pending", ("IQN",))
    one_seed = pd.concat([star, episodes(BASE, lambda s, r, d: 0.25, seeds=(0,))])
    result = evaluate_claim(star_vs_iqn(), one_seed)
    assert result.verdict == "pending" and "fewer than 2 training seeds: IQN (1)" in result.why
    no_075 = pd.concat([star, episodes(BASE, lambda s, r, d: 0.25, densities=(0.5, 1.0))])
    result = evaluate_claim(star_vs_iqn(), no_075)
    assert result.verdict == "pending" and "density 0.75" in result.why


def test_equivalence_claim_and_returns() -> None:
    partial = claims.pr_iqn("qd", True, 0.2, True).render()
    claim = next(c for c in CLAIMS if c.key == "partial-trained")
    close = pd.concat([episodes(STAR, lambda s, r, d: 0.5), episodes(partial, lambda s, r, d: 0.5)])
    assert evaluate_claim(claim, close, reps=200).verdict == "reproduced"
    apart = pd.concat([episodes(STAR, lambda s, r, d: 1.0), episodes(partial, lambda s, r, d: 0.5)])
    assert evaluate_claim(claim, apart, reps=200).verdict == "not reproduced"
    # A return metric: safety −1 per failed episode; 3/4 vs 1/4 success is −0.25 vs −0.75.
    safety = Claim("s", "safety", "", "better", (Comparison(PR_IQN_STAR, IQN, "return_safety"),))
    table = pd.concat([episodes(STAR, lambda s, r, d: 0.75), episodes(BASE, lambda s, r, d: 0.25)])
    (x,) = evaluate_claim(safety, table, reps=200).results
    assert x.diff == pytest.approx(0.5) and x.outcome == "holds"


def test_markdown_and_frame() -> None:
    table = pd.concat([episodes(STAR, lambda s, r, d: 0.75), episodes(BASE, lambda s, r, d: 0.25)])
    results = claims.evaluate_claims(table, reps=100, seed=3)
    md = claims.to_markdown(results, reps=100, seed=3)
    assert "Pr-IQN QD ✓ 0.2 ✗ − IQN, SR, d 0.5: +50.0 [+50.0, +50.0] (holds)" in md
    assert "**reproduced**" in md and "default_rng(3)" in md
    assert "Not checked here (rows not in this report): star-vs-ensemble" in md
    frame = claims.to_frame(results)
    star = frame[frame["claim"] == "star-vs-iqn"]
    assert list(star["density"]) == [0.5, 0.75, 1.0] and (star["diff"] == 0.5).all()
    assert (frame[frame["claim"] == "ours-fsd"]["verdict"] == "pending").all()


def test_seeds_with_different_evaluation_runs_are_one_line() -> None:
    ragged = pd.concat(
        [
            episodes(BASE, lambda s, r, d: 0.5, seeds=(0,), runs=(0, 1)),
            episodes(BASE, lambda s, r, d: 0.5, seeds=(1,), runs=(0,)),
        ]
    )
    with pytest.raises(PriqnError, match="IQN: training seeds were evaluated on different"):
        run_means(ragged, BASE, "success", 0.5)


def test_control_rows_of_the_claims_are_the_labels_evaluation_writes() -> None:
    """The acting-control claims name rows as `priqn evaluate --acting near-greedy` labels
    them (Policy.near_greedy -> labels.near_greedy), and the label reads back from a CSV row."""
    from priqn.analysis.claims import ENSEMBLE, IQN
    from priqn.labels import PolicyLabel, near_greedy

    rows = {
        c.second.render()
        for claim in CLAIMS
        if claim.key.startswith("ours-acting")
        for c in claim.comparisons
    }
    assert rows == {
        "IQN near-greedy ε=0.2",
        "Ensemble near-greedy ε=0.2",
        "IQN near-greedy ε=0.005",
        "Ensemble near-greedy ε=0.005",
    }
    for row in (near_greedy(IQN, 0.005), near_greedy(ENSEMBLE, 0.2)):
        assert PolicyLabel.from_row(row.to_row()) == row


def test_seed_interval_by_hand() -> None:
    # Per-seed means 0.6 / 0.8 / 1.0 (s² = 0.04) against a constant 0.5: difference 0.3,
    # se = √(0.04 / 3) = 0.11547, Welch dof = 2 (all variance on one side), t₀.₉₇₅(2) = 4.3027.
    first_SR = np.array([[0.5, 0.7], [0.8, 0.8], [1.0, 1.0]])
    second_SR = np.full((3, 2), 0.5)
    lo, hi = claims.seed_interval(first_SR, second_SR)
    assert (lo, hi) == pytest.approx((0.3 - 0.49683, 0.3 + 0.49683), abs=1e-5)
    # Evaluation runs are averaged first: spreading them within a seed changes nothing.
    assert claims.seed_interval(first_SR.mean(axis=1, keepdims=True).repeat(2, 1), second_SR) == (
        pytest.approx((lo, hi))
    )
    # Seeds that agree exactly: a zero-width interval at the difference.
    assert claims.seed_interval(np.full((3, 2), 0.75), second_SR) == (0.25, 0.25)


def test_seeds_needed_by_hand() -> None:
    # (z₀.₉₇₅ + z₀.₈)² = (1.95996 + 0.84162)² = 7.8489; spread 0.04 + 0; effect 0.077:
    # 7.8489 × 0.04 / 0.077² = 52.95 -> 53 seeds per row.
    first_SR = np.array([[0.6], [0.8], [1.0]])
    second_SR = np.full((3, 1), 0.5)
    assert claims.seeds_needed(first_SR, second_SR, 0.077) == 53
    assert claims.seeds_needed(first_SR, second_SR, 0.5) == 2  # 1.26 -> at least MIN_SEEDS
    assert claims.seeds_needed(second_SR, second_SR, 0.077) == claims.MIN_SEEDS


def test_the_second_look_reports_where_it_disagrees() -> None:
    # 3 seeds, every seed of Pr-IQN* succeeds at least as often as IQN's best seed but
    # one seed much more: the seed bootstrap is all positive, the t-interval is not.
    table = pd.concat(
        [
            episodes(STAR, lambda s, r, d: (0.5, 0.5, 1.0)[s], seeds=(0, 1, 2)),
            episodes(BASE, lambda s, r, d: 0.25, seeds=(0, 1, 2)),
        ]
    )
    result = evaluate_claim(star_vs_iqn(), table, reps=500)
    assert result.verdict == "reproduced"
    for x in result.results:
        # per-seed differences 0.25, 0.25, 0.75: mean 5/12, s² = 1/12, dof 2.
        half = 4.302653 * np.sqrt(1 / 12 / 3)
        assert (x.seed_lo, x.seed_hi) == pytest.approx((5 / 12 - half, 5 / 12 + half), abs=1e-5)
        assert x.seed_outcome == "unclear"
    assert result.seed_verdict == "inconclusive at this budget"
    md = claims.to_markdown([result], reps=500, seed=0)
    assert "star-vs-iqn (reproduced → inconclusive at this budget)" in md
    frame = claims.to_frame([result])
    assert (frame["seed_verdict"] == "inconclusive at this budget").all()
    assert list(frame["seeds_needed"]) == [
        claims.seeds_needed(
            run_means(table, STAR, "success", d), run_means(table, BASE, "success", d), p
        )
        for d, p in ((0.5, 0.077), (0.75, 0.166), (1.0, 0.203))
    ]


def test_claims_figure_draws_each_measured_success_comparison() -> None:
    from priqn.analysis import figures

    table = pd.concat([episodes(STAR, lambda s, r, d: 0.75), episodes(BASE, lambda s, r, d: 0.25)])
    results = claims.evaluate_claims(table, reps=100)
    fig = figures.claims_figure(results)
    (ax,) = fig.axes
    # star-vs-iqn at three densities; table1 compares returns and is not drawn.
    labels = [t.get_text() for t in ax.get_yticklabels()]
    assert labels == [f"star-vs-iqn: {STAR} − IQN, d {d}" for d in ("0.5", "0.75", "1")]
    assert ax.get_xlim() == (-100, 100)
    figures.plt.close(fig)
    returns_only = [r for r in results if r.claim.key == "table1"]
    assert returns_only[0].results and figures.claims_figure(returns_only) is None
