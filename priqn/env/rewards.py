"""The five reward terms, in ``OBJECTIVES`` order: safety, risk, lane keeping, progress, comfort.

Each term is a pure function of quantities the env measures over one decision
(0.5 s = several SUMO steps); per-step values are averaged over the decision's sim
steps. Per-decision terms lie in [-1, 1]; only the safety event (collision / off-road)
and the success bonus are larger, so that the weighted-sum baseline and the
per-objective heads see sane scales. ``docs/environment.md`` has the table of units
and ranges; the tests in ``tests/test_env_rewards.py`` check every formula by hand.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from priqn.objectives import OBJECTIVES


@dataclass(frozen=True)
class RewardConfig:
    """Parameters of the five reward terms."""

    collision_penalty: float = 10.0
    """Safety reward on a collision with a vehicle or obstacle is -collision_penalty [-]."""
    off_road_penalty: float = 10.0
    """Safety reward when the ego footprint leaves the drivable area is -off_road_penalty [-]."""
    clearance_safe_m: float = 4.0
    """Risk: clearance [m] (gap between ego box and the nearest actor box) below which risk grows."""
    ttc_safe_s: float = 3.0
    """Risk: time-to-collision [s] below which risk grows."""
    lateral_offset_scale_m: float = 1.5
    """Lane keeping: lateral offset from the lane centre [m] that costs the full lateral part."""
    heading_error_scale_rad: float = 0.35
    """Lane keeping: heading error w.r.t. the lane direction [rad] that costs the full heading part."""
    lane_offset_weight: float = 0.7
    """Lane keeping: weight of the lateral part (the heading part gets 1 - this) [-]."""
    target_speed_mps: float = 10.0
    """Progress: desired speed [m/s]; the route's speed limit caps it."""
    advance_weight: float = 0.5
    """Progress: weight of route advance (target-speed adherence gets 1 - this) [-]."""
    success_bonus: float = 1.0
    """Progress reward added once when the goal is reached [-]."""
    jerk_scale_mps3: float = 6.0
    """Comfort: |jerk| [m/s^3] that costs the full jerk part."""
    lateral_accel_scale_mps2: float = 4.0
    """Comfort: |lateral acceleration| [m/s^2] that costs the full lateral part."""
    jerk_weight: float = 0.5
    """Comfort: weight of the jerk part (lateral acceleration gets 1 - this) [-]."""

    def __post_init__(self) -> None:
        positive = (
            "clearance_safe_m",
            "ttc_safe_s",
            "lateral_offset_scale_m",
            "heading_error_scale_rad",
            "target_speed_mps",
            "jerk_scale_mps3",
            "lateral_accel_scale_mps2",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"reward.{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("lane_offset_weight", "advance_weight", "jerk_weight"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"reward.{name} must be in [0, 1], got {getattr(self, name)!r}")
        for name in ("collision_penalty", "off_road_penalty", "success_bonus"):
            if getattr(self, name) < 0:
                raise ValueError(f"reward.{name} must be >= 0, got {getattr(self, name)!r}")


def safety(collision: bool, off_road: bool, cfg: RewardConfig) -> float:
    """-collision_penalty on a collision, else -off_road_penalty when off-road, else 0."""
    if collision:
        return -cfg.collision_penalty
    if off_road:
        return -cfg.off_road_penalty
    return 0.0


def risk(clearance_m: np.ndarray, ttc_s: np.ndarray, cfg: RewardConfig) -> float:
    """-mean over sim steps of max(1 - clearance/clearance_safe, 1 - ttc/ttc_safe), clipped to [0, 1].

    ``clearance_m`` / ``ttc_s``: [T] per sim step, to the nearest actor (inf = none).
    Range [-1, 0]: 0 with no actor closer than ``clearance_safe_m`` and no TTC under
    ``ttc_safe_s``; -1 when touching or about to collide.
    """
    c = np.clip(1.0 - np.asarray(clearance_m, float) / cfg.clearance_safe_m, 0.0, 1.0)
    t = np.clip(1.0 - np.asarray(ttc_s, float) / cfg.ttc_safe_s, 0.0, 1.0)
    return -float(np.mean(np.maximum(c, t)))


def lane_keeping(
    lateral_offset_m: np.ndarray, heading_error_rad: np.ndarray, cfg: RewardConfig
) -> float:
    """-mean of w·min(|d|/d_scale, 1) + (1-w)·min(|Δψ|/ψ_scale, 1). Range [-1, 0]."""
    d = np.minimum(np.abs(np.asarray(lateral_offset_m, float)) / cfg.lateral_offset_scale_m, 1.0)
    h = np.minimum(np.abs(np.asarray(heading_error_rad, float)) / cfg.heading_error_scale_rad, 1.0)
    w = cfg.lane_offset_weight
    return -float(np.mean(w * d + (1.0 - w) * h))


def progress(
    advance_m: float,
    speed_mps: np.ndarray,
    target_speed_mps: float,
    duration_s: float,
    success: bool,
    cfg: RewardConfig,
) -> float:
    """Route advance and target-speed adherence; + success_bonus at the goal.

    ``w·clip(Δs / (v*·Δt), 0, 1) + (1-w)·mean(1 - min(|v - v*| / v*, 1))`` with ``Δs`` the
    advance along the route [m] during the decision, ``v`` the ego speed per sim step and
    ``v*`` the target speed. Range [0, 1] (+ success_bonus): 0 standing still, 1 at v*.
    """
    v_star = float(target_speed_mps)
    adv = float(np.clip(advance_m / (v_star * duration_s), 0.0, 1.0))
    v = np.asarray(speed_mps, float)
    adherence = float(np.mean(1.0 - np.minimum(np.abs(v - v_star) / v_star, 1.0)))
    w = cfg.advance_weight
    return w * adv + (1.0 - w) * adherence + (cfg.success_bonus if success else 0.0)


def comfort(jerk_mps3: np.ndarray, lateral_accel_mps2: np.ndarray, cfg: RewardConfig) -> float:
    """-mean of w·min(|j|/j_scale, 1) + (1-w)·min(|a_lat|/a_scale, 1). Range [-1, 0]."""
    j = np.minimum(np.abs(np.asarray(jerk_mps3, float)) / cfg.jerk_scale_mps3, 1.0)
    a = np.minimum(
        np.abs(np.asarray(lateral_accel_mps2, float)) / cfg.lateral_accel_scale_mps2, 1.0
    )
    w = cfg.jerk_weight
    return -float(np.mean(w * j + (1.0 - w) * a))


def reward_vector(
    safety_r: float, risk_r: float, lane_r: float, progress_r: float, comfort_r: float
) -> np.ndarray:
    """The five terms as ``float32 [5]`` in ``OBJECTIVES`` order."""
    out = np.array([safety_r, risk_r, lane_r, progress_r, comfort_r], dtype=np.float32)
    assert out.shape == (len(OBJECTIVES),)
    return out


def box_clearance_m(ego_corners_42: np.ndarray, corners_N42: np.ndarray) -> np.ndarray:
    """Gap [m] between the ego box and each of N boxes (0 where they overlap or touch).

    ``ego_corners_42`` is one box [4, 2] or one ego box per row [N, 4, 2].

    Boxes are given by their 4 corners in order around the box. The gap between two
    convex polygons that do not overlap is the smallest corner-to-edge distance, in
    either direction; overlapping boxes (decided by the caller's collision test or by
    a corner inside the other box) get 0.
    """
    corners_N42 = np.asarray(corners_N42, float).reshape(-1, 4, 2)
    n = corners_N42.shape[0]
    if n == 0:
        return np.zeros(0)
    ego = np.broadcast_to(np.asarray(ego_corners_42, float).reshape(-1, 4, 2), (n, 4, 2))
    d1 = _points_to_edges(ego, corners_N42)
    d2 = _points_to_edges(corners_N42, ego)
    gap = np.minimum(d1, d2)
    inside = _any_corner_inside(ego, corners_N42) | _any_corner_inside(corners_N42, ego)
    return np.where(inside, 0.0, gap)


def _points_to_edges(points_N42: np.ndarray, poly_N42: np.ndarray) -> np.ndarray:
    a = poly_N42[:, None, :, :]  # [N,1,4,2] edge starts
    b = np.roll(poly_N42, -1, axis=1)[:, None, :, :]
    p = points_N42[:, :, None, :]  # [N,4,1,2]
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-12), 0.0, 1.0)
    proj = a + t[..., None] * ab
    return np.sqrt(np.sum((p - proj) ** 2, -1)).min(axis=(1, 2))


def _any_corner_inside(points_N42: np.ndarray, poly_N42: np.ndarray) -> np.ndarray:
    a = poly_N42[:, None, :, :]
    b = np.roll(poly_N42, -1, axis=1)[:, None, :, :]
    p = points_N42[:, :, None, :]
    cross = (b[..., 0] - a[..., 0]) * (p[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (
        p[..., 0] - a[..., 0]
    )
    inside = np.all(cross >= 0, axis=2) | np.all(cross <= 0, axis=2)
    return inside.any(axis=1)


def time_to_collision_s(
    ego_xy: np.ndarray,
    ego_vel_xy: np.ndarray,  # [2] or [N, 2]
    actor_xy_N2: np.ndarray,
    actor_vel_N2: np.ndarray,
    clearance_N: np.ndarray,
) -> np.ndarray:
    """Constant-velocity time-to-collision [s] per actor: clearance / closing speed.

    The closing speed is the rate at which the centre distance shrinks,
    ``-(Δp·Δv)/|Δp|``; actors that are not closing get ``inf``.
    """
    dp = np.asarray(actor_xy_N2, float) - np.asarray(ego_xy, float)
    dv = np.asarray(actor_vel_N2, float) - np.asarray(ego_vel_xy, float)
    dist = np.maximum(np.linalg.norm(dp, axis=-1), 1e-6)
    closing = -np.sum(dp * dv, axis=-1) / dist
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(closing > 1e-3, np.asarray(clearance_N, float) / closing, np.inf)
    return ttc
