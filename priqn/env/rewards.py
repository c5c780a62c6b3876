"""The five built-in reward terms: safety, risk, lane keeping, progress, comfort.

The env's reward vector follows its declared objectives (``EnvConfig.objectives``,
:mod:`priqn.objectives`); these are the built-ins' reward functions
(:mod:`priqn.env.objective_terms` wires them to their measures).

Each term is a pure function of quantities the env measures over one decision
(0.5 s = several SUMO steps, see :mod:`priqn.env.measures`); per-step values are
averaged over the decision's sim steps. Ranges per decision (see :class:`RewardConfig`):
risk, lane keeping and comfort in [-1, 0], progress in [0, 1] (plus the one-off
success bonus), safety 0 or the one-off event penalty. ``docs/environment.md`` has the
table of units and ranges; ``tests/test_env_rewards.py`` checks every formula by hand.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from priqn.objectives import OBJECTIVES


@dataclass(frozen=True)
class RewardConfig:
    """Parameters of the five reward terms.

    Ranges, per decision, that weighting schemes may rely on (tested): ``risk``,
    ``lane_keeping`` and ``comfort`` lie in [-1, 0]; ``progress`` lies in [0, 1] except on
    the goal decision, which adds ``success_bonus`` once; ``safety`` is 0 except on the
    last decision of a crash, ``-collision_penalty`` or ``-off_road_penalty`` once.
    """

    collision_penalty: float = 10.0
    """Safety reward on a collision with a vehicle or obstacle is -collision_penalty [-]."""
    off_road_penalty: float = 10.0
    """Safety reward when the ego footprint leaves the drivable area is -off_road_penalty [-]."""
    conflict_time_safe_s: float = 3.0
    """Risk: time to conflict [s] below which risk grows (also the look-ahead of the measure)."""
    lon_safe_gap_m: float = 1.0
    """Risk: standstill safe gap ahead of / behind the ego box along its heading [m]."""
    lat_safe_gap_m: float = 0.5
    """Risk: safe gap beside the ego box [m] (the envelope's width); below a normal
    lane-neighbour gap (about 1.1-1.7 m on 3.0-3.6 m lanes), above a scrape."""
    reaction_time_s: float = 0.5
    """Risk: RSS-style response time [s]; the follower's speed times this lengthens the
    longitudinal safe gap (the ego's speed ahead of it, a following actor's behind it)."""
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
    right_of_way_horizon_s: float = 3.0
    """Right of way (the optional ``right_of_way`` objective): a priority foe that reaches
    the conflict area within this time counts as due there [s] (docs/environment.md)."""

    def __post_init__(self) -> None:
        positive = (
            "conflict_time_safe_s",
            "lateral_offset_scale_m",
            "heading_error_scale_rad",
            "target_speed_mps",
            "jerk_scale_mps3",
            "lateral_accel_scale_mps2",
            "right_of_way_horizon_s",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"reward.{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("lane_offset_weight", "advance_weight", "jerk_weight"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"reward.{name} must be in [0, 1], got {getattr(self, name)!r}")
        for name in ("lon_safe_gap_m", "lat_safe_gap_m", "reaction_time_s"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"reward.{name} must be >= 0, got {getattr(self, name)!r}")
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


def risk(conflict_time_s: np.ndarray, cfg: RewardConfig) -> float:
    """-mean over sim steps of clip(1 - τ / conflict_time_safe_s, 0, 1). Range [-1, 0].

    ``conflict_time_s``: [T] per sim step, the time until the ego on its planned path
    and the nearest-in-time actor at constant velocity enter each other's safety
    envelope (:func:`priqn.env.measures.conflict_times_s`; inf = no conflict ahead).
    0 when no conflict is due within ``conflict_time_safe_s``; -1 inside the envelope.
    """
    t = np.asarray(conflict_time_s, float)
    return -float(np.mean(np.minimum(np.maximum(1.0 - t / cfg.conflict_time_safe_s, 0.0), 1.0)))


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
    adv = min(max(float(advance_m) / (v_star * duration_s), 0.0), 1.0)
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
