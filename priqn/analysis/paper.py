"""What the paper reports, transcribed once: its Table II rows and success rates, and the
gains its text quotes, each with where it comes from.

Source: "Beyond Scalar Rewards: Distributional Reinforcement Learning with Preordered
Objectives for Safe and Reliable Autonomous Driving" (arXiv 2603.20230v1; the text in
``shared/seed``). Table II: success, collision and off-road rates per row at traffic
densities 0.5 / 0.75 / 1.0;
Sec. V quotes some of its differences, rounded differently in places (Pr-IQN* over IQN at
0.5: +7.7 in the text, +7.9 in the table; over Ensemble-IQN: +11.0 and +11.2). Table I
(objective returns) is not transcribed: its claim here is directional (Sec. V: "Pr-IQN*
consistently increases rewards", up to 61 % / 41 % / 37 % on safety / risk /
lane-keeping).

Rates and differences are fractions (0.079 is 7.9 points). :mod:`priqn.analysis.claims`
turns these numbers into claims; :mod:`priqn.analysis.sequential_report` prints Table II
beside a sequential experiment's per-density success.
"""

from __future__ import annotations

from priqn.agents.labels import PolicyLabel

IQN = PolicyLabel("iqn")
ENSEMBLE = PolicyLabel("ensemble-iqn")
MA_IQN = PolicyLabel("ma-iqn")


def pr_iqn(
    comparator: str = "qd",
    train_preorder: bool = True,
    eps: float = 0.2,
    partial_order: bool = False,
    extra: tuple[str, ...] = (),
) -> PolicyLabel:
    """A Pr-IQN row; the defaults are the paper's best configuration, Pr-IQN*."""
    return PolicyLabel("pr-iqn", comparator, train_preorder, eps, partial_order, extra)


PR_IQN_STAR = pr_iqn()
"""Pr-IQN*: QD, total preorder enforced during training, ε 0.2 (Sec. V)."""

PAPER_ROWS: tuple[PolicyLabel, ...] = (
    IQN,
    ENSEMBLE,
    MA_IQN,
    pr_iqn("mv", True, 0.4),
    pr_iqn("cvar", True, 0.4),
    pr_iqn("qd", False, 0.4),
    pr_iqn("qd", True, 0.4),
    pr_iqn("qd", False, 0.2),
    PR_IQN_STAR,
    pr_iqn("qd", False, 0.2, True),
    pr_iqn("qd", True, 0.2, True),
)
"""The paper's 11 Table II rows."""

PAPER_DENSITIES: tuple[float, float, float] = (0.5, 0.75, 1.0)
"""The traffic densities of the paper's Table II columns (the order of PAPER_SUCCESS)."""


def _by_row(
    rates: tuple[tuple[float, float, float], ...],
) -> dict[str, tuple[float, float, float]]:
    """Table II's rates of one column, given in :data:`PAPER_ROWS` order, by row label."""
    return {row.render(): r for row, r in zip(PAPER_ROWS, rates, strict=True)}


PAPER_SUCCESS: dict[str, tuple[float, float, float]] = _by_row(
    (
        (0.737, 0.513, 0.434),
        (0.704, 0.532, 0.498),
        (0.594, 0.374, 0.391),
        (0.635, 0.400, 0.365),
        (0.518, 0.275, 0.224),
        (0.722, 0.567, 0.463),
        (0.763, 0.580, 0.455),
        (0.816, 0.646, 0.612),
        (0.816, 0.679, 0.637),
        (0.692, 0.514, 0.503),
        (0.797, 0.630, 0.642),
    )
)
"""The paper's Table II success rates at densities 0.5 / 0.75 / 1.0, per row label."""

PAPER_COLLISION: dict[str, tuple[float, float, float]] = _by_row(
    (
        (0.248, 0.472, 0.538),
        (0.272, 0.451, 0.485),
        (0.403, 0.617, 0.604),
        (0.333, 0.570, 0.616),
        (0.448, 0.692, 0.738),
        (0.245, 0.416, 0.507),
        (0.217, 0.403, 0.512),
        (0.136, 0.277, 0.335),
        (0.175, 0.314, 0.353),
        (0.250, 0.440, 0.453),
        (0.161, 0.337, 0.343),
    )
)
"""The paper's Table II collision rates (CR) at densities 0.5 / 0.75 / 1.0, per row label."""

PAPER_OFF_ROAD: dict[str, tuple[float, float, float]] = _by_row(
    (
        (0.013, 0.014, 0.026),
        (0.023, 0.016, 0.015),
        (0.002, 0.008, 0.004),
        (0.031, 0.030, 0.017),
        (0.032, 0.032, 0.036),
        (0.032, 0.015, 0.028),
        (0.018, 0.016, 0.032),
        (0.022, 0.032, 0.013),
        (0.010, 0.005, 0.007),
        (0.034, 0.028, 0.034),
        (0.032, 0.027, 0.014),
    )
)
"""The paper's Table II off-road rates (OR) at densities 0.5 / 0.75 / 1.0, per row label."""


def paper_outcomes(label: str) -> dict[str, tuple[float, ...]] | None:
    """Row ``label``'s outcome mix in Table II, per outcome a rate at each of
    :data:`PAPER_DENSITIES`: success, collision, off-road and the timeouts they leave
    (1 − the three, at least 0; the paper does not report them); None for a label that
    is not one of its rows."""
    if label not in PAPER_SUCCESS:
        return None
    sr, cr, off = PAPER_SUCCESS[label], PAPER_COLLISION[label], PAPER_OFF_ROAD[label]
    timeout = tuple(round(max(0.0, 1 - a - b - c), 3) for a, b, c in zip(sr, cr, off, strict=True))
    return {"success": sr, "collision": cr, "off_road": off, "timeout": timeout}


TEXT_STAR_OVER_IQN: tuple[float, float, float] = (0.077, 0.166, 0.203)
"""Sec. V: Pr-IQN* "improves success rate by (+7.7 %, +16.6 %, +20.3 %) over IQN" at
densities 0.5 / 0.75 / 1.0 (Table II: +7.9 at 0.5)."""

TEXT_STAR_OVER_ENSEMBLE: tuple[float, float, float] = (0.110, 0.147, 0.139)
"""Sec. V: "... and (+11.0 %, +14.7 %, +13.9 %) over Ensemble-IQN" (Table II: +11.2 at
0.5); their mean, +13.2, is ``headline.toml``'s paper difference."""

TEXT_TRAINING_PREORDER_GAIN: dict[float, float] = {0.75: 0.033, 1.0: 0.025}
"""Sec. V: "Incorporating the preorder during training further improves the success rate
by +3.3 % and +2.5 % at densities 0.75 and 1.0" (Pr-IQN* over QD ε 0.2 without it; Table
II: +0.0 at 0.5)."""


def table_gains(first: PolicyLabel, second: PolicyLabel) -> tuple[float, ...]:
    """Table II's success-rate difference first − second at each of
    :data:`PAPER_DENSITIES`, rounded to 0.1 points."""
    a, b = PAPER_SUCCESS[first.render()], PAPER_SUCCESS[second.render()]
    return tuple(round(x - y, 3) for x, y in zip(a, b, strict=True))


def paper_difference(first: PolicyLabel, second: PolicyLabel) -> float:
    """The paper's success-rate difference first − second on the endpoint (mean over its
    three densities), from Table II, rounded to 0.1 points."""
    a, b = PAPER_SUCCESS[first.render()], PAPER_SUCCESS[second.render()]
    return round(sum(a) / 3 - sum(b) / 3, 3)
