"""Risk as time to conflict: scripted geometries computed by hand (no SUMO).

Every case uses the default envelope (standstill gap 1.0 m along, 0.5 m across,
response time 0.5 s, 3 s look-ahead), an ego box 4.5 m x 1.8 m and actor boxes of
the same size unless stated. Numbers in comments are the hand computation.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from priqn.env import geometry, measures
from priqn.env import rewards as R
from priqn.env.reads import Actors, StepActors

CFG = R.RewardConfig()
ENV = measures.Envelope(
    CFG.lon_safe_gap_m, CFG.lat_safe_gap_m, CFG.reaction_time_s, CFG.conflict_time_safe_s
)
DT = 0.1
LOOK = measures.look_ahead_samples(ENV.horizon_s, DT)  # 30 samples after "now"


def actors(*rows: tuple[float, float, float, float], length: float = 4.5, width: float = 1.8):
    """Actors from (x, y, heading_rad, speed_mps) rows."""
    a = np.array(rows, dtype=float).reshape(-1, 4)
    boxes = geometry.Boxes.make(a[:, :2], a[:, 2], length, width)
    return Actors(boxes, a[:, 3])


def time_to_conflict(ego: measures.EgoPath, *rows, **kw) -> float:
    """Conflict time seen from the ego path's first sample, actors at constant velocity."""
    return float(
        measures.conflict_times_s(ego, np.array([0]), StepActors.of([actors(*rows, **kw)]), ENV)[0]
    )


def level(t: float) -> float:
    """The per-step risk level the reward averages: clip(1 - t / 3 s, 0, 1)."""
    return -R.risk(np.array([t]), CFG)


def ego_at(x: float, y: float, heading: float, speed: float, extra: int = 0):
    return measures.EgoPath.straight((x, y), heading, speed, LOOK + 1 + extra, DT)


# --------------------------------------------------------------------------- the six cases


@pytest.mark.parametrize("lane_m", [3.0, 3.6])
def test_oncoming_car_in_the_opposite_lane_is_no_risk(lane_m: float) -> None:
    # Lateral gap 3.0 - 0.9 - 1.0 = 1.1 m (a 2.0 m wide car on 3.0 m lanes) > 0.5 m,
    # whatever the closing speed: the envelope is never entered.
    ego = ego_at(0.0, 0.0, 0.0, 9.0)
    for x0 in (40.0, 20.0, 5.0, 0.0, -5.0):
        t = time_to_conflict(ego, (x0, lane_m, math.pi, 9.0), width=2.0)
        assert t == math.inf and level(t) == 0.0


def test_car_abreast_in_the_adjacent_lane_at_equal_speed_is_no_risk() -> None:
    ego = ego_at(0.0, 0.0, 0.0, 9.0)
    for dx in (-4.0, 0.0, 3.0):  # beside, slightly ahead, slightly behind
        assert time_to_conflict(ego, (dx, 3.2, 0.0, 9.0), (dx, -3.2, 0.0, 9.0)) == math.inf


def test_stopped_car_ahead_while_approaching_at_9_mps_from_28_m() -> None:
    # Centre distance 28 m: box gap 28 - 4.5 = 23.5 m; the ego's gap ahead is
    # 1.0 + 0.5 s x 9 m/s = 5.5 m, entered when 23.5 - 9 t = 5.5, t = 2.0 s -> level 1/3.
    ego = ego_at(0.0, 0.0, 0.0, 9.0, extra=10)
    assert time_to_conflict(ego, (28.0, 0.0, 0.0, 0.0)) == pytest.approx(2.0)
    assert level(2.0) == pytest.approx(1 / 3)
    # Per decision (steps at 0.1..0.5 s, then 0.6..1.0 s): conflict times 1.9..1.5 s,
    # mean level 1 - 1.7/3 = 0.433; then 1.4..1.0 s, mean 1 - 1.2/3 = 0.6.
    still = [actors((28.0, 0.0, 0.0, 0.0))] * 5
    first = measures.conflict_times_s(ego, np.arange(1, 6), StepActors.of(still), ENV)
    np.testing.assert_allclose(first, [1.9, 1.8, 1.7, 1.6, 1.5])
    assert R.risk(first, CFG) == pytest.approx(-(1 - 1.7 / 3))
    second = measures.conflict_times_s(ego, np.arange(6, 11), StepActors.of(still), ENV)
    assert R.risk(second, CFG) == pytest.approx(-(1 - 1.2 / 3))
    assert R.risk(first, CFG) < -0.3  # "clearly negative" well before contact (at 2.6 s)


def test_crossing_car_meeting_the_ego_at_the_conflict_point_is_risk() -> None:
    # Ego from (-20, 0) east at 10 m/s, actor from (0, -20) north at 10 m/s: both reach
    # (0, 0) at 2 s. Ego frame: dx = 20 - 10t, dy = 10t - 20, relative heading 90° so the
    # actor's hull is 1.8 m long and 4.5 m wide: g_lon = g_lat = |20 - 10t| - 3.15 m.
    # Slack = max(g - (1 + 0.5 x 10), g - 0.5) = |20 - 10t| - 3.65 < 0 from t = 1.635 s.
    ego = ego_at(-20.0, 0.0, 0.0, 10.0)
    t = time_to_conflict(ego, (0.0, -20.0, math.pi / 2, 10.0))
    assert t == pytest.approx(1.635)
    assert -R.risk(np.array([t]), CFG) == pytest.approx(1 - 1.635 / 3)  # level 0.455


def test_crossing_car_that_clears_the_conflict_point_well_before_is_no_risk() -> None:
    # Same ego; the actor starts at (0, -5) and is at the conflict point at 0.5 s, 1.5 s
    # before the ego. Inside the envelope laterally only while |10t - 5| < 3.65
    # (0.135 s < t < 0.865 s), longitudinally only once 20 - 10t < 9.15 (t > 1.085 s).
    ego = ego_at(-20.0, 0.0, 0.0, 10.0)
    assert time_to_conflict(ego, (0.0, -5.0, math.pi / 2, 10.0)) == math.inf
    # Half a second earlier for the actor (conflict point at 1.0 s) still clears it:
    # lateral window (0.635, 1.365) s overlaps the longitudinal one (t > 1.085 s).
    assert time_to_conflict(ego, (0.0, -10.0, math.pi / 2, 10.0)) == pytest.approx(1.085)


def test_stopped_ego_with_traffic_passing_on_other_lanes_is_no_risk() -> None:
    ego = ego_at(0.0, 0.0, 0.0, 0.0)
    passing = [
        (-30.0, 3.3, 0.0, 12.0),  # overtaking in the adjacent lane
        (30.0, 3.3, math.pi, 12.0),  # oncoming in the opposite lane
        (-10.0, -3.3, 0.0, 8.0),  # the lane to the right
        # crossing road in front: its near lane centre 3 m + half widths beyond the ego's
        # front (g_lon = 6.15 - 2.25 - 0.9 = 3.0 m > 1.0 m standstill gap)
        (6.15, -25.0, math.pi / 2, 10.0),
        (9.45, 25.0, -math.pi / 2, 10.0),
    ]
    assert time_to_conflict(ego, *passing) == math.inf


# --------------------------------------------------------------------------- parts


def test_slack_by_hand_with_a_rotated_actor() -> None:
    # Actor 10 m ahead, 1 m left, turned 90°: hull 1.8 m long x 4.5 m wide.
    # g_lon = 10 - 2.25 - 0.9 = 6.85, gap ahead at 4 m/s = 1 + 2 = 3 -> 3.85;
    # g_lat = 1 - 0.9 - 2.25 = -2.15 -> -2.65; slack = 3.85.
    got = measures.envelope_slack_m(
        np.array([10.0, 1.0]), 0.0, 4.0, math.pi / 2, 7.0, (2.25, 0.9), 2.25, 0.9, ENV
    )
    assert got == pytest.approx(3.85)
    # Same actor behind (dx = -10): the gap behind uses the actor's speed along the ego
    # heading, 7 cos 90° = 0 -> 1.0 m: slack = 6.85 - 1.0 = 5.85.
    got = measures.envelope_slack_m(
        np.array([-10.0, 1.0]), 0.0, 4.0, math.pi / 2, 7.0, (2.25, 0.9), 2.25, 0.9, ENV
    )
    assert got == pytest.approx(5.85)
    # A follower driving at 8 m/s 10 m behind (centre): g_lon = 10 - 4.5 = 5.5 m, its gap
    # 1 + 0.5 x 8 = 5 m: outside by 0.5 m.
    got = measures.envelope_slack_m(
        np.array([-10.0, 0.0]), 0.0, 4.0, 0.0, 8.0, (2.25, 0.9), 2.25, 0.9, ENV
    )
    assert got == pytest.approx(0.5)


def test_first_conflict_time_interpolates_the_crossing() -> None:
    slack = np.array([[3.0, 1.0, -1.0, -2.0], [-0.5, 1.0, 2.0, 3.0], [1.0, 1.0, 1.0, 1.0]])
    np.testing.assert_allclose(measures.first_conflict_time_s(slack, 0.1), [0.15, 0.0, np.inf])


def test_broad_phase_skips_only_pairs_that_cannot_meet() -> None:
    rng = np.random.default_rng(4)
    n_steps = 5
    ego = measures.EgoPath.straight((0.0, 0.0), 0.3, 8.0, n_steps + LOOK + 1, DT)
    per_step = []
    for _ in range(n_steps):
        m = 30
        rows = np.c_[
            rng.uniform(-60, 60, (m, 2)), rng.uniform(-np.pi, np.pi, m), rng.uniform(0, 14, m)
        ]
        per_step.append(actors(*map(tuple, rows)))
    got = measures.conflict_times_s(ego, np.arange(1, n_steps + 1), StepActors.of(per_step), ENV)
    want = np.full(n_steps, np.inf)
    t_J = np.arange(LOOK + 1) * DT
    for i, a in enumerate(per_step):
        k = i + 1
        w = k + np.arange(LOOK + 1)
        vel = a.speed_mps[:, None] * np.c_[np.cos(a.boxes.heading_rad), np.sin(a.boxes.heading_rad)]
        pos = a.boxes.center_xy[:, None, :] + vel[:, None, :] * t_J[None, :, None]
        rel = pos - np.stack([ego.x_m[w], ego.y_m[w]], axis=-1)[None]
        slack = measures.envelope_slack_m(
            rel, ego.heading_rad[w], ego.speed_mps[w], a.boxes.heading_rad[:, None],
            a.speed_mps[:, None], (2.25, 0.9), 2.25, 0.9, ENV,
        )  # fmt: skip
        want[i] = measures.first_conflict_time_s(slack, DT).min()
    np.testing.assert_array_equal(got, want)
    assert np.isfinite(got).any()  # the sample has conflicts


def test_risk_stays_in_minus_one_to_zero() -> None:
    rng = np.random.default_rng(0)
    for _ in range(200):
        t = rng.choice([0.0, np.inf, 1.0, 5.0], size=5) * rng.uniform(0, 2, 5)
        r = R.risk(t, CFG)
        assert -1.0 <= r <= 0.0
    assert R.risk(np.zeros(5), CFG) == -1.0  # inside the envelope all decision long
    assert R.risk(np.full(5, np.inf), CFG) == 0.0


def test_look_ahead_longer_than_the_path_is_an_error() -> None:
    ego = measures.EgoPath.straight((0.0, 0.0), 0.0, 5.0, 10, DT)
    with pytest.raises(ValueError, match="look-ahead"):
        measures.conflict_times_s(
            ego, np.array([1]), StepActors.of([actors((5.0, 0.0, 0.0, 0.0))]), ENV
        )
