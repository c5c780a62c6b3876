"""Pure per-decision measures of the ego against the road and the other actors.

Everything here is a pure numpy function of poses and actor states, vectorised over
the SUMO steps of one decision and over the actors: the env reads SUMO, calls these,
and hands the results to :mod:`priqn.env.rewards`.

* :func:`off_road_steps` — is the ego footprint off the drivable area at each pose?
* :func:`first_collision` — the first step at which the ego box overlaps an actor box
  (oriented boxes, separating axes; touching is no collision).
* :func:`conflict_times_s` — per step, the time until the ego (on its planned path)
  and an actor (at constant velocity) first come closer than the safety envelope
  (separate longitudinal and lateral safe gaps); the risk reward is built on it.

The risk measure's derivation, with units, is in ``docs/environment.md`` ("Risk:
time to conflict"); the hand-computed cases are in ``tests/test_env_measures.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from priqn.env import geometry, planner
from priqn.env.reads import StepActors


@dataclass(frozen=True)
class EgoPath:
    """The ego's pose at every sample of its plan: ``t = 0, dt, 2·dt, ...`` (arrays [S]).

    Sample 0 is the decision's start; samples past the executed part are where the
    ego *would* be if it kept its plan (the risk look-ahead reads them).
    """

    x_m: np.ndarray
    """[S] centre x (m)."""
    y_m: np.ndarray
    """[S] centre y (m)."""
    heading_rad: np.ndarray
    """[S] yaw, counter-clockwise from +x (rad)."""
    speed_mps: np.ndarray
    """[S] speed along the path (m/s)."""
    dt_s: float
    """Time between samples (s)."""
    length_m: float
    """Ego length (m)."""
    width_m: float
    """Ego width (m)."""

    def cos_sin(self) -> tuple[np.ndarray, np.ndarray]:
        """[S] cosine and sine of the heading at every sample."""
        return np.cos(self.heading_rad), np.sin(self.heading_rad)

    @classmethod
    def of(cls, traj: planner.Trajectory, length_m: float, width_m: float) -> EgoPath:
        """Every sample of a plan (including its ``extend_s`` continuation)."""
        return cls(
            traj.x, traj.y, traj.heading_rad, traj.speed_mps, float(traj.t[1] - traj.t[0]),
            length_m, width_m,
        )  # fmt: skip

    @classmethod
    def straight(
        cls,
        xy: tuple[float, float],
        heading_rad: float,
        speed_mps: float,
        samples: int,
        dt_s: float = 0.1,
        length_m: float = 4.5,
        width_m: float = 1.8,
    ) -> EgoPath:
        """A constant-velocity straight path (tests and hand computations)."""
        t = np.arange(samples) * dt_s
        c, s = math.cos(heading_rad), math.sin(heading_rad)
        return cls(
            xy[0] + c * speed_mps * t,
            xy[1] + s * speed_mps * t,
            np.full(samples, float(heading_rad)),
            np.full(samples, float(speed_mps)),
            dt_s,
            length_m,
            width_m,
        )


@dataclass(frozen=True)
class Envelope:
    """The ego's safety envelope: its box grown by separate longitudinal / lateral gaps.

    RSS-style: ahead of the ego the longitudinal gap grows by the distance the ego
    covers in its response time (``lon_gap_m + reaction_time_s · v_ego``); behind it,
    by the distance a following actor covers in its response time
    (``lon_gap_m + reaction_time_s · max(0, v_actor along the ego heading)``). The
    lateral gap is constant (lateral motion is in the constant-velocity prediction).
    """

    lon_gap_m: float
    """Standstill gap ahead of and behind the ego box, along the ego's heading (m)."""
    lat_gap_m: float
    """Gap beside the ego box, across the ego's heading (m)."""
    reaction_time_s: float
    """Response time ρ (s): the longitudinal gap grows by ρ times the follower's speed."""
    horizon_s: float
    """Look-ahead (s): conflicts later than this are ignored."""


# --------------------------------------------------------------------------- road and collisions


_OUTLINE_FL = np.array(
    [
        [1.0, -1.0],
        [1.0, 1.0],
        [-1.0, 1.0],
        [-1.0, -1.0],
        [1.0, 0.0],
        [0.0, 1.0],
        [-1.0, 0.0],
        [0.0, -1.0],
    ]
)
"""The 4 corners and 4 edge midpoints of a box, in (forward, left) half-extents."""


def off_road_steps(
    raster: geometry.MapRaster,
    x_m: np.ndarray,
    y_m: np.ndarray,
    heading_rad: np.ndarray,
    length_m: float,
    width_m: float,
) -> np.ndarray:
    """bool [T]: is the ego footprint off the road at each of T poses?

    Same test as :func:`priqn.env.geometry.is_off_road` (corners and edge midpoints,
    any point off the drivable area), vectorised over the poses.
    """
    fwd = _OUTLINE_FL[:, 0] * (0.5 * length_m)  # [8]
    left = _OUTLINE_FL[:, 1] * (0.5 * width_m)
    c, s = np.cos(heading_rad)[:, None], np.sin(heading_rad)[:, None]
    points = np.empty((len(x_m), len(fwd), 2))
    points[..., 0] = x_m[:, None] + c * fwd - s * left
    points[..., 1] = y_m[:, None] + s * fwd + c * left
    return ~raster.drivable(points).all(axis=1)


def first_collision(ego: geometry.Boxes, seen: StepActors) -> int | None:
    """Index of the first step ``k`` whose ego box ``ego[k]`` overlaps an actor of that step.

    ``ego`` holds one box per step of ``seen``; None when no step collides. A
    bounding-circle broad phase over all (step, actor) pairs, then the separating-axis
    test on the rest.
    """
    every = seen.actors
    if len(every) == 0:
        return None
    step_of = seen.step
    ego_radius = 0.5 * np.hypot(ego.length_m, ego.width_m)
    delta = every.boxes.center_xy - ego.center_xy[step_of]
    gap = np.hypot(delta[:, 0], delta[:, 1]) - every.radius_m - ego_radius[step_of]
    near = np.flatnonzero(gap < 0.0)
    if len(near) == 0:
        return None
    hit = geometry.obb_overlap_pairs(ego[step_of[near]], every.boxes[near])
    return int(step_of[near][hit].min()) if hit.any() else None


# --------------------------------------------------------------------------- risk: time to conflict


def look_ahead_samples(horizon_s: float, dt_s: float) -> int:
    """Number J of path samples after the current one that cover ``horizon_s``."""
    return int(math.ceil(horizon_s / dt_s - 1e-9))


def envelope_slack_m(
    rel_xy: np.ndarray,
    ego_heading_rad: np.ndarray,
    ego_speed_mps: np.ndarray,
    actor_heading_rad: np.ndarray,
    actor_speed_mps: np.ndarray,
    ego_half_m: tuple[float, float],
    actor_half_length_m: np.ndarray,
    actor_half_width_m: np.ndarray,
    envelope: Envelope,
) -> np.ndarray:
    """Signed distance (m) of an actor box outside the ego's safety envelope (< 0: inside).

    ``rel_xy`` [..., 2] is the actor centre minus the ego centre (world frame). In the
    ego frame (x forward, y left) the actor box's extent is its axis-aligned hull,
    half-sizes ``e_lon = l_a|cos φ| + w_a|sin φ|``, ``e_lat = l_a|sin φ| + w_a|cos φ|``
    (``l_a, w_a`` half length / width, ``φ`` the relative heading). The box gaps are
    ``g_lon = |Δx| − l_e − e_lon`` and ``g_lat = |Δy| − w_e − e_lat``; the actor is in
    the envelope iff ``g_lon < G_lon`` **and** ``g_lat < lat_gap``, with ``G_lon`` the
    RSS-style longitudinal gap of :class:`Envelope` (ego speed for an actor ahead, the
    actor's speed along the ego heading for one behind). The slack is
    ``max(g_lon − G_lon, g_lat − lat_gap)``. Broadcasts over all leading dimensions.
    """
    ego_c, ego_s = np.cos(ego_heading_rad), np.sin(ego_heading_rad)
    act_c, act_s = np.cos(actor_heading_rad), np.sin(actor_heading_rad)
    return _slack(
        rel_xy[..., 0], rel_xy[..., 1], ego_c, ego_s, ego_speed_mps, act_c, act_s,
        actor_speed_mps, ego_half_m, actor_half_length_m, actor_half_width_m, envelope,
    )  # fmt: skip


def _slack(
    rx: np.ndarray,
    ry: np.ndarray,
    ego_c: np.ndarray,
    ego_s: np.ndarray,
    ego_v: np.ndarray,
    act_c: np.ndarray,
    act_s: np.ndarray,
    act_v: np.ndarray,
    ego_half_m: tuple[float, float],
    act_hl: np.ndarray,
    act_hw: np.ndarray,
    envelope: Envelope,
) -> np.ndarray:
    """:func:`envelope_slack_m` from cosines and sines of the headings (no trigonometry)."""
    dx = rx * ego_c + ry * ego_s
    dy = ry * ego_c - rx * ego_s
    cos_phi = act_c * ego_c + act_s * ego_s  # cos(ψ_a - ψ_e)
    sin_phi = act_s * ego_c - act_c * ego_s
    ac, as_ = np.abs(cos_phi), np.abs(sin_phi)
    g_lon = np.abs(dx) - (ego_half_m[0] + act_hl * ac + act_hw * as_)
    g_lat = np.abs(dy) - (ego_half_m[1] + act_hl * as_ + act_hw * ac)
    follower_mps = np.where(dx >= 0.0, ego_v, np.maximum(act_v * cos_phi, 0.0))
    g_lon -= envelope.lon_gap_m + envelope.reaction_time_s * follower_mps
    g_lat -= envelope.lat_gap_m
    return np.maximum(g_lon, g_lat)


def first_conflict_time_s(slack_PJ: np.ndarray, dt_s: float) -> np.ndarray:
    """[P] time (s) of the first sample with negative slack, ``inf`` if none.

    ``slack_PJ[p, j]`` is the slack at ``t = j·dt``. Between the last sample outside
    and the first inside, the crossing is interpolated linearly (exact when the
    slack is linear in time there, as for straight constant-velocity motion).
    """
    inside = slack_PJ < 0.0
    hit = inside.any(axis=1)
    j = np.argmax(inside, axis=1)
    out = np.full(len(slack_PJ), np.inf)
    rows = np.flatnonzero(hit)
    jr = j[rows]
    at_start = jr == 0
    out[rows[at_start]] = 0.0
    r, k = rows[~at_start], jr[~at_start]
    before, after = slack_PJ[r, k - 1], slack_PJ[r, k]
    out[r] = (k - 1 + before / (before - after)) * dt_s
    return out


def conflict_times_s(
    ego: EgoPath, steps: np.ndarray, seen: StepActors, envelope: Envelope
) -> np.ndarray:
    """[K] time to the first conflict (s) seen from each executed step, ``inf`` if none.

    ``steps`` [K] are the ego path's sample indices of the executed SUMO steps and
    ``seen.at(i)`` the actors read after step ``steps[i]``. From each step the ego
    follows its path (samples ``steps[i] + j``, ``j = 0..J``, ``J·dt`` = the
    look-ahead) and each actor keeps its velocity; the result is the minimum over
    actors of :func:`first_conflict_time_s` of the :func:`envelope_slack_m`.
    ``ego`` must have at least ``max(steps) + J + 1`` samples.

    Pairs (step, actor) that cannot meet within the look-ahead (bounding circles of
    the envelope and the actor, closing at most at ``v_actor + max ego speed``) are
    skipped before the per-sample work.
    """
    k_steps = len(steps)
    out = np.full(k_steps, np.inf)
    every = seen.actors
    if len(every) == 0:
        return out
    n_look = look_ahead_samples(envelope.horizon_s, ego.dt_s)
    if int(np.max(steps)) + n_look >= len(ego.x_m):
        raise ValueError(
            f"ego path has {len(ego.x_m)} samples; the look-ahead needs {int(np.max(steps)) + n_look + 1}"
        )
    step_of = seen.step
    sample = np.asarray(steps, dtype=np.intp)[step_of]  # [M] ego sample of each pair
    boxes, speed = every.boxes, every.speed_mps
    half_len, half_wid = 0.5 * boxes.length_m, 0.5 * boxes.width_m

    # Broad phase: the distance now, less the radius of the largest envelope and the
    # actor's, must be coverable within the look-ahead at the largest closing speed.
    hl_e, hw_e = 0.5 * ego.length_m, 0.5 * ego.width_m
    v_ego_max = np.maximum.accumulate(ego.speed_mps[::-1])[::-1]  # max over the rest of the path
    v_ego_max = v_ego_max[sample]
    lon_max = hl_e + envelope.lon_gap_m + envelope.reaction_time_s * np.maximum(v_ego_max, speed)
    r_env = np.hypot(lon_max, hw_e + envelope.lat_gap_m)
    delta = boxes.center_xy - np.stack([ego.x_m[sample], ego.y_m[sample]], axis=1)
    dist = np.hypot(delta[:, 0], delta[:, 1])
    reach = (speed + v_ego_max) * envelope.horizon_s
    keep = np.flatnonzero(dist - r_env - (half_len + half_wid) < reach)
    if len(keep) == 0:
        return out

    # Narrow phase over [P pairs, J + 1 samples], trigonometry done once per sample.
    window = sample[keep, None] + np.arange(n_look + 1)[None, :]  # [P, J+1]
    t_J = np.arange(n_look + 1) * ego.dt_s
    act_c, act_s = np.cos(boxes.heading_rad[keep]), np.sin(boxes.heading_rad[keep])
    v = speed[keep]
    rx = boxes.center_xy[keep, 0, None] + (v * act_c)[:, None] * t_J - ego.x_m[window]
    ry = boxes.center_xy[keep, 1, None] + (v * act_s)[:, None] * t_J - ego.y_m[window]
    ego_c, ego_s = ego.cos_sin()
    slack = _slack(
        rx, ry, ego_c[window], ego_s[window], ego.speed_mps[window], act_c[:, None],
        act_s[:, None], v[:, None], (hl_e, hw_e), half_len[keep, None], half_wid[keep, None],
        envelope,
    )  # fmt: skip
    np.minimum.at(out, step_of[keep], first_conflict_time_s(slack, ego.dt_s))
    return out
