"""Frenet planner: reference line, boundary conditions, continuity, stopping, SUMO poses."""

from __future__ import annotations

import numpy as np
import pytest

from priqn.env.geometry import center_from_sumo, sumo_from_center
from priqn.env.planner import FrenetState, PlannerConfig, ReferenceLine, plan


def straight(length_m: float = 100.0, step_m: float = 0.5) -> ReferenceLine:
    x = np.arange(0.0, length_m + 1e-9, step_m)
    return ReferenceLine(np.c_[x, np.zeros_like(x)])


def left_turn(radius_m: float = 15.0) -> ReferenceLine:
    """30 m straight north, a quarter circle to the left, 30 m straight west (0.5 m steps)."""
    y_in = np.arange(-30.0, 0.0, 0.5)
    arc = np.linspace(0.0, np.pi / 2, int(np.pi / 2 * radius_m / 0.5) + 1)
    x_arc, y_arc = radius_m * (np.cos(arc) - 1.0), radius_m * np.sin(arc)
    x_out = np.arange(-radius_m - 0.5, -radius_m - 30.0, -0.5)
    xy = np.r_[
        np.c_[np.zeros_like(y_in), y_in],
        np.c_[x_arc, y_arc],
        np.c_[x_out, np.full_like(x_out, radius_m)],
    ]
    return ReferenceLine(xy)


# ----------------------------------------------------------------------------- reference line


def test_reference_line_arc_length_heading_and_curvature():
    ref = left_turn(15.0)
    assert ref.length_m == pytest.approx(30 + np.pi / 2 * 15 + 29.5, abs=0.01)
    assert ref.heading_at(5.0) == pytest.approx(np.pi / 2)  # north on the straight
    assert ref.heading_at(ref.length_m - 5) == pytest.approx(np.pi)  # west after the turn
    s_mid = 30 + np.pi / 4 * 15
    assert ref.curvature_at(s_mid) == pytest.approx(1 / 15, rel=0.02)
    assert ref.curvature_at(10.0) == pytest.approx(0.0, abs=1e-12)


def test_frenet_round_trip_is_exact():
    ref = left_turn(15.0)
    rng = np.random.default_rng(1)
    s = rng.uniform(-5, ref.length_m + 5, 500)  # includes both extrapolated ends
    d = rng.uniform(-4, 4, 500)
    xy, _ = ref.to_cartesian(s, d)
    s2, d2 = ref.to_frenet(xy)
    np.testing.assert_allclose(s2, s, atol=1e-7)
    np.testing.assert_allclose(d2, d, atol=1e-7)


def test_straight_extrapolation_beyond_the_ends():
    ref = straight(10.0)
    xy, th = ref.to_cartesian(np.array([-3.0, 15.0]), np.array([1.0, -2.0]))
    np.testing.assert_allclose(xy, [[-3.0, 1.0], [15.0, -2.0]], atol=1e-12)
    np.testing.assert_allclose(th, 0.0, atol=1e-12)


def test_to_frenet_signs_left_positive():
    s, d = straight().to_frenet(np.array([[12.0, 1.5], [40.0, -2.0]]))
    np.testing.assert_allclose(s, [12.0, 40.0], atol=1e-12)
    np.testing.assert_allclose(d, [1.5, -2.0], atol=1e-12)


def test_s_range_keeps_the_right_branch():
    # A hairpin: two parallel legs 4 m apart; a point between them belongs to either.
    x = np.arange(0, 50.01, 0.5)
    arc = np.linspace(-np.pi / 2, np.pi / 2, 26)
    xy = np.r_[
        np.c_[x, np.zeros_like(x)],
        np.c_[50 + 2 * np.cos(arc), 2 + 2 * np.sin(arc)],
        np.c_[x[::-1], 4 + 0 * x],
    ]
    ref = ReferenceLine(xy)
    p = np.array([[20.0, 1.5]])
    s_near, _ = ref.to_frenet(p)
    assert s_near[0] == pytest.approx(20.0, abs=1e-6)
    s_far, d_far = ref.to_frenet(p, s_range_m=(60.0, ref.length_m))
    assert s_far[0] > 60.0 and d_far[0] == pytest.approx(2.5, abs=1e-6)


def test_frenet_state_from_cartesian():
    ref = straight()
    st = ref.frenet_state(np.array([10.0, -1.0]), heading_rad=np.radians(10), speed_mps=5.0)
    assert st.s == pytest.approx(10.0) and st.d == pytest.approx(-1.0)
    assert st.s_dot == pytest.approx(5 * np.cos(np.radians(10)))
    assert st.d_prime == pytest.approx(np.tan(np.radians(10)))


# ----------------------------------------------------------------------------- boundary conditions


@pytest.mark.parametrize("ref", [straight(200.0), left_turn(12.0)], ids=["straight", "left_turn"])
def test_boundary_conditions_exact(ref: ReferenceLine):
    state = FrenetState(s=3.0, s_dot=6.0, s_ddot=0.8, d=0.4, d_prime=-0.05, d_pprime=0.01)
    cfg = PlannerConfig(horizon_s=3.0, dt_s=0.1)
    tr = plan(ref, state, v_f_mps=9.0, d_f_m=-1.2, cfg=cfg)
    assert len(tr.t) == 31 and tr.t[-1] == 3.0
    # t = 0: the current state exactly.
    assert tr.s[0] == pytest.approx(3.0, abs=1e-9)
    assert tr.s_dot[0] == pytest.approx(6.0, abs=1e-9)
    assert tr.s_ddot[0] == pytest.approx(0.8, abs=1e-9)
    assert tr.d[0] == pytest.approx(0.4, abs=1e-9)
    assert tr.d_prime[0] == pytest.approx(-0.05, abs=1e-9)
    assert tr.d_pprime[0] == pytest.approx(0.01, abs=1e-9)
    # t = T: the requested speed and offset, at rest in acceleration and lateral motion.
    assert tr.s_dot[-1] == pytest.approx(9.0, abs=1e-9)
    assert tr.s_ddot[-1] == pytest.approx(0.0, abs=1e-9)
    assert tr.d[-1] == pytest.approx(-1.2, abs=1e-9)  # Δs ≈ 22 m > min_lateral_distance_m
    assert tr.d_prime[-1] == pytest.approx(0.0, abs=1e-9)
    assert tr.d_pprime[-1] == pytest.approx(0.0, abs=1e-9)
    assert tr.d_dot[-1] == pytest.approx(0.0, abs=1e-9)
    # The Cartesian start is the Frenet start.
    xy0, _ = ref.to_cartesian(3.0, 0.4)
    np.testing.assert_allclose([tr.x[0], tr.y[0]], xy0, atol=1e-9)


def test_longitudinal_is_a_quartic_when_not_braking_hard():
    tr = plan(straight(), FrenetState(0.0, 4.0, 0.5, 0.0, 0.0, 0.0), 10.0, 0.0)
    # A quartic has a linear jerk; check it against the closed form.
    T, v0, a0, vf = 3.0, 4.0, 0.5, 10.0
    c4 = (v0 - vf + 0.5 * a0 * T) / (2 * T**3)
    c3 = -(a0 + 12 * c4 * T**2) / (6 * T)
    np.testing.assert_allclose(tr.s_dddot, 6 * c3 + 24 * c4 * tr.t, atol=1e-9)
    np.testing.assert_allclose(
        tr.s, v0 * tr.t + 0.5 * a0 * tr.t**2 + c3 * tr.t**3 + c4 * tr.t**4, atol=1e-9
    )


def test_straight_lane_change_kinematics():
    tr = plan(straight(), FrenetState(0.0, 10.0, 0.0, 0.0, 0.0, 0.0), 10.0, 3.0)
    # Constant speed: d(s(t)) is the time quintic 3·(10τ³ − 15τ⁴ + 6τ⁵).
    tau = tr.t / 3.0
    np.testing.assert_allclose(tr.d, 3.0 * (10 * tau**3 - 15 * tau**4 + 6 * tau**5), atol=1e-9)
    np.testing.assert_allclose(tr.x, tr.s, atol=1e-12)
    np.testing.assert_allclose(tr.y, tr.d, atol=1e-12)
    np.testing.assert_allclose(tr.heading_rad, np.arctan(tr.d_prime), atol=1e-12)
    np.testing.assert_allclose(tr.speed_mps, 10.0 * np.hypot(1.0, tr.d_prime), atol=1e-9)


def test_cartesian_derivatives_match_finite_differences():
    ref = left_turn(15.0)
    state = FrenetState(s=28.0, s_dot=7.0, s_ddot=-0.5, d=0.3, d_prime=0.02, d_pprime=0.0)
    fine = PlannerConfig(horizon_s=3.0, dt_s=0.001)
    tr = plan(ref, state, 5.0, -0.8, fine)
    dt = 0.001
    vx, vy = np.gradient(tr.x, dt), np.gradient(tr.y, dt)
    # Finite differences straddling a vertex of the polyline (where the piecewise-constant
    # reference curvature jumps) average two one-sided derivatives: leave those out.
    seg = ref._segment(tr.s)
    ok = np.ones(len(tr.t), dtype=bool)
    ok[1:] &= seg[1:] == seg[:-1]
    ok[:-1] &= seg[1:] == seg[:-1]
    ok[:3] = ok[-3:] = False
    ok_j = ok.copy()
    ok_j[1:-1] &= ok[2:] & ok[:-2]  # jerk is a difference of a difference
    assert ok_j.mean() > 0.9
    # Speed: the polyline direction differs from the smooth heading by < half a kink (1°).
    np.testing.assert_allclose(np.hypot(vx, vy)[ok], tr.speed_mps[ok], rtol=3e-3)
    yaw = np.unwrap(np.arctan2(vy, vx))
    # The polyline's segment direction differs from the smooth heading by < half a kink.
    np.testing.assert_allclose(yaw[ok], tr.heading_rad[ok], atol=0.02)
    a_lat = tr.speed_mps * np.gradient(np.unwrap(tr.heading_rad), dt)
    np.testing.assert_allclose(a_lat[ok], tr.accel_lat_mps2[ok], atol=1e-4)
    a_lon = np.gradient(tr.speed_mps, dt)
    np.testing.assert_allclose(a_lon[ok], tr.accel_lon_mps2[ok], atol=1e-5)
    jerk = np.gradient(tr.accel_lon_mps2, dt)
    np.testing.assert_allclose(jerk[ok_j], tr.jerk_lon_mps3[ok_j], atol=1e-4)


# ----------------------------------------------------------------------------- replanning


def drive(ref, state, actions, decision_s=0.5):
    """Replan every decision from the previous plan's state; return the plans."""
    plans = []
    for v_f, d_f in actions:
        tr = plan(ref, state, v_f, d_f)
        plans.append(tr)
        state = tr.state_at(decision_s)
    return plans


def test_replanning_is_continuous():
    ref = left_turn(12.0)
    rng = np.random.default_rng(0)
    actions = list(
        zip(
            rng.choice([0.0, 2.5, 5.0, 7.5, 10.0], 40),
            rng.choice([-1, -0.5, 0, 0.5, 1], 40),
            strict=True,
        )
    )
    plans = drive(ref, FrenetState(0.0, 6.0, 0.0, 0.0, 0.0, 0.0), actions)
    for a, b in zip(plans[:-1], plans[1:], strict=True):
        i = a.index_at(0.5)
        for name in (
            "x",
            "y",
            "heading_rad",
            "speed_mps",
            "accel_lon_mps2",
            "d",
            "d_dot",
            "s_ddot",
        ):
            assert getattr(a, name)[i] == pytest.approx(getattr(b, name)[0], abs=1e-9), name
        assert np.all(a.speed_mps >= 0.0)


def test_stop_and_stay_stopped_without_creeping_back():
    ref = straight(300.0)
    plans = drive(ref, FrenetState(0.0, 12.0, 0.0, 0.0, 0.0, 0.0), [(0.0, 0.0)] * 20)
    s = np.concatenate([p.s[:6] for p in plans])
    v = np.concatenate([p.speed_mps[:6] for p in plans])
    assert np.all(v >= 0.0)
    assert np.all(np.diff(s) >= -1e-12)  # never backwards
    assert v[-1] == pytest.approx(0.0, abs=1e-6)
    final = plans[-1]
    np.testing.assert_allclose(final.s, final.s[0], atol=1e-6)  # stays put over the horizon


def test_hard_braking_near_standstill_uses_a_shorter_stop():
    # Braking harder than -3 v0 / T: a plain quartic would reverse; ours stops in T' = 3 v0 / -a0.
    state = FrenetState(0.0, 1.0, -3.0, 0.0, 0.0, 0.0)
    tr = plan(straight(), state, 0.0, 0.0)
    assert tr.s_ddot[0] == pytest.approx(-3.0, abs=1e-12)  # acceleration still continuous
    assert np.all(tr.speed_mps >= 0)
    t_stop = 1.0  # 3 · 1 / 3
    after = tr.t >= t_stop
    np.testing.assert_allclose(tr.speed_mps[after], 0.0, atol=1e-12)
    assert tr.s[-1] == pytest.approx(1.0 * t_stop / 4, abs=1e-9)  # ∫ v0 (1 − t/T')³ dt = v0 T'/4
    # Re-accelerating from that state never dips below zero either.
    tr2 = plan(straight(), state, 3.0, 0.0)
    assert np.all(tr2.speed_mps >= 0) and tr2.s_dot[-1] == pytest.approx(3.0)


def test_no_sideways_motion_while_standing():
    ref = straight()
    tr = plan(ref, FrenetState(5.0, 0.0, 0.0, 0.0, 0.0, 0.0), 0.0, 2.0)
    np.testing.assert_allclose(tr.d, 0.0, atol=1e-12)
    np.testing.assert_allclose(tr.heading_rad, 0.0, atol=1e-12)
    # Pulling away, the offset grows with distance and the car never points sideways.
    tr = plan(ref, FrenetState(5.0, 0.0, 0.0, 0.0, 0.0, 0.0), 4.0, 2.0)
    assert 0 < tr.d[-1] < 2.0
    assert np.max(np.abs(tr.heading_rad)) < np.radians(25)


def test_invalid_arguments():
    with pytest.raises(ValueError, match="target speed"):
        plan(straight(), FrenetState(0, 1, 0, 0, 0, 0), -1.0, 0.0)
    with pytest.raises(ValueError, match="multiple"):
        PlannerConfig(horizon_s=3.0, dt_s=0.7)
    with pytest.raises(ValueError, match="two distinct"):
        ReferenceLine(np.array([[1.0, 2.0], [1.0, 2.0]]))
    with pytest.raises(ValueError, match="sample time"):
        plan(straight(), FrenetState(0, 1, 0, 0, 0, 0), 1.0, 0.0).index_at(0.55)


# ----------------------------------------------------------------------------- SUMO poses


def test_sumo_pose_convention():
    front, angle = sumo_from_center(
        np.array([[0.0, 0.0], [10.0, 5.0]]), np.array([np.pi / 2, 0.0]), 4.0
    )
    np.testing.assert_allclose(angle, [0.0, 90.0])  # north = 0°, east = 90° (clockwise)
    np.testing.assert_allclose(front, [[0.0, 2.0], [12.0, 5.0]], atol=1e-12)
    _, angle = sumo_from_center(np.zeros((2, 2)), np.array([np.pi, -np.pi / 2]), 4.0)
    np.testing.assert_allclose(angle, [270.0, 180.0])  # west, south
    center, heading = center_from_sumo(front, np.array([0.0, 90.0]), 4.0)
    np.testing.assert_allclose(center, [[0.0, 0.0], [10.0, 5.0]], atol=1e-12)
    np.testing.assert_allclose(heading, [np.pi / 2, 0.0], atol=1e-12)


def test_state_at_a_sample_equals_evaluating_the_polynomials_there():
    ref = left_turn(15.0)
    cfg = PlannerConfig(horizon_s=3.0, dt_s=0.1, extend_s=0.5)
    for state, v_f, d_f in [
        (FrenetState(20.0, 6.0, 0.5, 0.3, 0.02, 0.001), 9.0, -0.75),
        (FrenetState(25.0, 4.0, -6.0, 0.0, 0.0, 0.0), 0.0, 1.5),  # braking hard: t_rest < T
    ]:
        tr = plan(ref, state, v_f, d_f, cfg)
        assert len(tr.t) == 36 and tr.t[30] == 3.0 and tr.t[-1] == pytest.approx(3.5)
        for j in (0, 1, 5, 30, 35):
            a, b = tr.state_at_sample(j), tr.state_at(float(tr.t[j]))
            np.testing.assert_allclose(
                [a.s, a.s_dot, a.s_ddot, a.d, a.d_prime, a.d_pprime],
                [b.s, b.s_dot, b.s_ddot, b.d, b.d_prime, b.d_pprime],
                rtol=1e-12,
                atol=1e-12,
            )
        # Past the horizon the plan continues at v_f with the lateral offset it reached.
        np.testing.assert_allclose(tr.s_dot[31:], v_f, atol=1e-9)
        np.testing.assert_allclose(np.diff(tr.s[30:]), v_f * 0.1, atol=1e-9)
