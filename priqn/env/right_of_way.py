"""The ``right_of_way`` objective: do not block a conflict area a priority vehicle is due at.

SUMO's junction logic says, for every pair of links (connections) through a junction,
whether one must yield to the other (the ``response`` bits of the net's ``<request>``
rows; sumolib ``Node.forbids``). The ego drives one link. For each link ``F`` it must
yield to, the **conflict area** is where ``F``'s lane crosses or merges into the ego's
lane inside the junction: the points ``c_j`` of ``F``'s centre line (every
:data:`SAMPLE_STEP_M`) whose distance to the ego link's internal centre line is at most
``w_F/2 + w_E/2`` (the two lanes overlap there), each with radius ``r = w_F/2``; it spans
``[σ_in, σ_out]`` in arc length along ``F``.

At each SUMO step ``k`` of a decision:

* the ego **occupies** the area when its footprint box comes closer than ``r`` to some ``c_j``;
* a **priority foe** is due there when some actor lies on ``F`` (its centre within
  ``w_F/2`` of ``F``'s centre line, heading within :data:`MATCH_HEADING_RAD` of the line's)
  and is inside the area (front ``σ + L/2 ≥ σ_in`` and rear ``σ − L/2 ≤ σ_out``) or will
  reach it within ``T = reward.right_of_way_horizon_s`` at its speed ``v``:
  ``(σ_in − (σ + L/2)) / v ≤ T``.

The decision's reward is −1 if at some counted step the ego occupies a conflict area while
a priority foe of that area is due, else 0 (range [−1, 0]; docs/environment.md).

:func:`conflict_areas` reads the net once per (net, junction, route) with sumolib;
:func:`violation_steps` is the pure measure; :func:`measure` / :func:`reward` are the
functions the objective declaration names (:data:`priqn.objectives.BUILTIN_OBJECTIVES`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from priqn.env import geometry
from priqn.env.reads import StepActors
from priqn.sim.geometry import point_polyline_distance_m, wrap_rad

SAMPLE_STEP_M = 0.5
"""Spacing of the points of a foe link's centre line [m]."""
APPROACH_TAIL_M = 80.0
"""How much of a foe's approach lane, before its stop line, counts as being on the link [m]."""
MATCH_HEADING_RAD = math.pi / 4
"""An actor is on a foe link only when its heading is within this of the link's [rad]."""


@dataclasses.dataclass(frozen=True, eq=False)
class ConflictArea:
    """Where the ego's link meets one link it must yield to (arrays over the foe's centre line)."""

    foe_link: str
    """``"<from lane>-><to lane>"`` of the priority link."""
    path_xy: np.ndarray
    """``float64 [P, 2]``: the foe link's centre line (approach tail, then its internal lanes)."""
    path_s_m: np.ndarray
    """``float64 [P]``: arc length along ``path_xy`` [m]."""
    path_heading_rad: np.ndarray
    """``float64 [P]``: heading of ``path_xy`` at each point [rad]."""
    half_width_m: float
    """Half the foe lane's width [m]: the disc radius ``r`` and the on-link tolerance."""
    enter_s_m: float
    """σ_in: arc length where the area starts along the foe link [m]."""
    leave_s_m: float
    """σ_out: arc length where it ends [m]."""

    @property
    def centers_xy(self) -> np.ndarray:
        """``float64 [D, 2]``: the area's disc centres (foe centre line inside [σ_in, σ_out])."""
        inside = (self.path_s_m >= self.enter_s_m) & (self.path_s_m <= self.leave_s_m)
        return self.path_xy[inside]

    @classmethod
    def of(
        cls, foe_link: str, path_xy: np.ndarray, half_width_m: float, ego_line_xy: np.ndarray,
        ego_half_width_m: float, from_s_m: float = 0.0,
    ) -> ConflictArea | None:  # fmt: skip
        """The area where a foe centre line ``path_xy`` comes within ``half_width_m +
        ego_half_width_m`` of the ego's centre line (only at arc length ≥ ``from_s_m``:
        inside the junction); None when the lanes never overlap."""
        path_xy = np.asarray(path_xy, float)
        seg = np.diff(path_xy, axis=0)
        s = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
        heading = np.arctan2(seg[:, 1], seg[:, 0])
        heading = np.concatenate([heading, heading[-1:]])
        near = point_polyline_distance_m(path_xy, np.asarray(ego_line_xy, float))
        hit = (near <= half_width_m + ego_half_width_m) & (s >= from_s_m)
        if not hit.any():
            return None
        return cls(foe_link, path_xy, s, heading, float(half_width_m), float(s[hit].min()),
                   float(s[hit].max()))  # fmt: skip


# ----------------------------------------------------------------------------- pure geometry


def box_point_distance_m(boxes: geometry.Boxes, points_xy: np.ndarray) -> np.ndarray:
    """``[M, D]`` distance from each box's footprint to each point (0 inside) [m]."""
    d = points_xy[None, :, :] - boxes.center_xy[:, None, :]  # [M, D, 2]
    c, s = np.cos(boxes.heading_rad)[:, None], np.sin(boxes.heading_rad)[:, None]
    along = np.abs(d[..., 0] * c + d[..., 1] * s) - 0.5 * boxes.length_m[:, None]
    across = np.abs(-d[..., 0] * s + d[..., 1] * c) - 0.5 * boxes.width_m[:, None]
    return np.hypot(np.maximum(along, 0.0), np.maximum(across, 0.0))


def foe_due(area: ConflictArea, actors: StepActors, horizon_s: float) -> np.ndarray:
    """``bool [K]``: at step k some actor on the foe link is inside the area or reaches it
    within ``horizon_s`` at its current speed."""
    out = np.zeros(actors.n_steps, dtype=bool)
    a = actors.actors
    if len(a) == 0:
        return out
    xy = a.boxes.center_xy
    dist = np.hypot(*(xy[:, None, :] - area.path_xy[None]).transpose(2, 0, 1))  # [M, P]
    j = dist.argmin(axis=1)
    lateral = dist[np.arange(len(j)), j]
    dh = wrap_rad(a.boxes.heading_rad - area.path_heading_rad[j])
    on_link = (lateral <= area.half_width_m) & (np.abs(dh) <= MATCH_HEADING_RAD)
    sigma = area.path_s_m[j]
    front, rear = sigma + 0.5 * a.boxes.length_m, sigma - 0.5 * a.boxes.length_m
    inside = (front >= area.enter_s_m) & (rear <= area.leave_s_m)
    with np.errstate(divide="ignore"):
        tau = np.where(a.speed_mps > 0, (area.enter_s_m - front) / a.speed_mps, np.inf)
    due = on_link & (inside | ((front < area.enter_s_m) & (tau <= horizon_s)))
    out[np.unique(actors.step[due])] = True
    return out


def violation_steps(
    ego: geometry.Boxes, actors: StepActors, areas: Sequence[ConflictArea], horizon_s: float
) -> np.ndarray:
    """``bool [T]``: at step k the ego box (``ego[k]``) occupies a conflict area (closer than
    ``r`` to one of its disc centres) while a priority foe of that area is due there."""
    out = np.zeros(len(ego.heading_rad), dtype=bool)
    for area in areas:
        occupied = (box_point_distance_m(ego, area.centers_xy) < area.half_width_m).any(axis=1)
        if occupied.any():
            out |= occupied & foe_due(area, actors, horizon_s)[: len(out)]
    return out


# ----------------------------------------------------------------------------- from the net


@functools.lru_cache(maxsize=4)
def _read_net(net_path: str) -> Any:
    import sumolib

    return sumolib.net.readNet(net_path, withInternal=True)


def _resample(xy: np.ndarray) -> np.ndarray:
    seg = np.hypot(*np.diff(xy, axis=0).T)
    keep = np.concatenate([[True], seg > 1e-6])
    xy = xy[keep]
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    grid = np.arange(0.0, s[-1] + 1e-9, SAMPLE_STEP_M)
    return np.stack([np.interp(grid, s, xy[:, 0]), np.interp(grid, s, xy[:, 1])], axis=1)


def _link_path(net: Any, conn: Any) -> tuple[np.ndarray, float]:
    """A link's centre line: its approach lane's last APPROACH_TAIL_M, then its internal
    lanes; and the arc length of the stop line on it."""
    from_shape = np.asarray(conn.getFromLane().getShape(), float)
    tail = _resample(from_shape)[::-1][: int(APPROACH_TAIL_M / SAMPLE_STEP_M) + 1][::-1]
    stop_s = SAMPLE_STEP_M * (len(tail) - 1)
    parts, lane = [tail], conn.getViaLaneID()
    for _ in range(10):
        if not lane:
            break
        ln = net.getLane(lane)
        parts.append(np.asarray(ln.getShape(), float))
        nxt = [c.getToLane() for c in ln.getOutgoing()]
        lane = nxt[0].getID() if nxt and nxt[0].getID().startswith(":") else None
    return _resample(np.concatenate(parts)), stop_s


@functools.lru_cache(maxsize=256)
def conflict_areas(
    net_path: str, junction_id: str, lane_ids: tuple[str, ...]
) -> tuple[ConflictArea, ...]:
    """The conflict areas of the ego link ``lane_ids[0] → lane_ids[-1]`` (an
    :class:`~priqn.sim.roadmap.EgoRoute`'s lanes) with every link it must yield to."""
    net = _read_net(net_path)
    node = net.getNode(junction_id)
    from_lane, to_lane = net.getLane(lane_ids[0]), lane_ids[-1]
    ego_conn = next((c for c in from_lane.getOutgoing() if c.getToLane().getID() == to_lane), None)
    if ego_conn is None:
        return ()
    internal = [np.asarray(net.getLane(i).getShape(), float) for i in lane_ids if i[:1] == ":"]
    if not internal:
        return ()
    ego_line = np.concatenate(internal)
    ego_half = 0.5 * float(from_lane.getWidth())
    areas = []
    for conn in node.getConnections():
        if conn.getFromLane() is from_lane or not node.forbids(conn, ego_conn):
            continue
        path, stop_s = _link_path(net, conn)
        name = f"{conn.getFromLane().getID()}->{conn.getToLane().getID()}"
        area = ConflictArea.of(
            name, path, 0.5 * float(conn.getFromLane().getWidth()), ego_line, ego_half, stop_s
        )
        if area is not None:
            areas.append(area)
    return tuple(areas)


# ----------------------------------------------------------------------------- the objective


def measure(ctx: Any) -> bool:
    """Whether the ego blocked a priority foe's conflict area at some counted step of the
    decision (``ctx``: :class:`priqn.env.objective_terms.DecisionContext`)."""
    roadmap = ctx.scene.roadmap
    areas = conflict_areas(str(roadmap.net_path), roadmap.junction_id, tuple(ctx.route.lane_ids))
    if not areas:
        return False
    cfg, traj, k = ctx.config, ctx.trajectory, ctx.steps
    n = len(k)
    ego = geometry.Boxes(
        np.stack([traj.x[k], traj.y[k]], axis=1), traj.heading_rad[k],
        np.full(n, cfg.ego_length_m), np.full(n, cfg.ego_width_m), np.full(n, 1.5),
    )  # fmt: skip
    return bool(violation_steps(ego, ctx.actors, areas, cfg.reward.right_of_way_horizon_s).any())


def reward(violated: bool, rc: Any) -> float:
    """−1 for a decision that blocked a priority foe's conflict area, else 0. Range [−1, 0]."""
    return -1.0 if violated else 0.0
