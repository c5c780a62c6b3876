"""Road geometry of one generated net, read with sumolib: drivable area, markings, ego routes.

Coordinates and angles (everything in this module):

- Positions are SUMO network coordinates in metres: ``x`` east, ``y`` north. Nets
  from :mod:`priqn.sim.netgen` keep the junction centre at ``(0, 0)``.
- A *heading* is in radians, counter-clockwise from +x (``atan2(dy, dx)``). SUMO's
  vehicle *angle* is in degrees, clockwise from north: ``angle = (90 - degrees(heading)) mod 360``
  (:func:`sumo_angle_deg`), which ``vehicle.moveToXY`` expects.
- ``s`` is arc length along a route's reference line in metres, starting at the
  first point of the approach lane. Positive lateral offset ``d`` is to the left.
- Polygons are ``float64 [P, 2]`` arrays of ``(x, y)``, open (first point not repeated).

Traffic drives on the right (SUMO's default): lane 0 of an edge is its rightmost lane.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path
from typing import Literal

import numpy as np

from priqn.errors import PriqnError

Command = Literal["left", "straight", "right"]
COMMANDS: tuple[str, ...] = ("left", "straight", "right")
"""Route commands, in the order of the environment's one-hot ``command`` vector."""

TURN_THRESHOLD_DEG = 45.0
"""A route turning more than this (counter-clockwise) is 'left', less than minus this 'right'."""

REFERENCE_STEP_M = 0.5
"""Spacing of the points of a route's reference line [m]."""

SMOOTHING_SIGMA_M = 2.0
"""Gaussian smoothing width applied to the joined lane centre lines [m]."""

START_BEFORE_JUNCTION_M = 70.0
"""The ego is inserted this far before the junction (or at the lane start if shorter) [m]."""

GOAL_AFTER_JUNCTION_M = 25.0
"""The route's goal lies this far past the junction on the exit lane [m]."""


@dataclasses.dataclass(frozen=True, eq=False)
class LaneInfo:
    """One SUMO lane (normal or internal) as the traffic and sensor code needs it."""

    lane_id: str
    """SUMO lane id, e.g. ``"a0_in_1"`` or ``":J_3_0"``."""
    edge_id: str
    """Edge the lane belongs to."""
    index: int
    """Lane index on its edge (0 = rightmost)."""
    internal: bool
    """True for lanes inside the junction (ids starting with ':')."""
    width_m: float
    """Lane width [m]."""
    length_m: float
    """Lane length as SUMO counts lane positions [m]."""
    speed_limit_mps: float
    """Lane speed limit [m/s]."""
    centre_xy: np.ndarray
    """``float64 [P, 2]`` centre line as written in the net (not resampled)."""
    towards_junction: bool
    """True for lanes of an approach (``*_in``) edge, i.e. lanes that end at the junction."""


@dataclasses.dataclass(frozen=True, eq=False)
class EgoRoute:
    """One way the ego can cross the junction: approach arm → exit arm.

    ``reference_xy`` joins the centre lines of ``lane_ids`` (internal ``:J_..`` lanes
    included), resampled every :data:`REFERENCE_STEP_M` and smoothed, so a Frenet
    planner can follow it. All ``*_s_m`` values are arc lengths along it.
    """

    name: str
    """``"<approach edge>-><exit edge>"``, e.g. ``"a1_in->a0_out"``."""
    command: str
    """'left' | 'straight' | 'right', from the turning angle."""
    turn_angle_deg: float
    """Exit heading minus approach heading, wrapped to (-180, 180]; positive = left."""
    edges: tuple[str, ...]
    """SUMO edge ids of the route (approach edge, exit edge); a route for ``vehicle.add``."""
    lane_ids: tuple[str, ...]
    """Lanes followed: approach lane, internal junction lanes, exit lane."""
    reference_xy: np.ndarray
    """``float64 [P, 2]`` smoothed centre line, points :data:`REFERENCE_STEP_M` apart."""
    s_junction_entry_m: float
    """Arc length where the approach lane ends (stop line / junction entry)."""
    s_junction_exit_m: float
    """Arc length where the exit lane starts (junction exit)."""
    goal_s_m: float
    """Arc length of the goal point on the exit lane (success when reached)."""
    lane_width_m: float
    """Width of the approach lane [m]."""
    speed_limit_mps: float
    """Speed limit of the approach lane [m/s]."""
    start_lane_id: str
    """Lane the ego is inserted on (the approach lane)."""
    start_pos_m: float
    """Insertion position along ``start_lane_id`` [m] (SUMO lane position)."""
    start_s_m: float
    """Arc length of the insertion point on ``reference_xy``."""

    @property
    def length_m(self) -> float:
        """Arc length of the whole reference line [m]."""
        return float(self.s_m[-1])

    @functools.cached_property
    def s_m(self) -> np.ndarray:
        """``float64 [P]`` arc length of every reference point."""
        return arc_length(self.reference_xy)

    @functools.cached_property
    def heading_rad(self) -> np.ndarray:
        """``float64 [P]`` heading of the reference line at every point (see module docstring)."""
        return polyline_heading(self.reference_xy)

    def point_at(self, s_m: float) -> np.ndarray:
        """``float64 [2]`` reference point at arc length ``s_m`` (clamped to the line)."""
        s = self.s_m
        return np.array(
            [np.interp(s_m, s, self.reference_xy[:, 0]), np.interp(s_m, s, self.reference_xy[:, 1])]
        )


@dataclasses.dataclass(frozen=True, eq=False)
class RoadMap:
    """Everything the environment needs to know about one net's roads.

    Build with :meth:`RoadMap.load`. The drivable area is the union of
    ``lane_polygons_xy`` (normal and internal lanes) and ``junction_polygon_xy``.
    """

    net_path: Path
    """The ``.net.xml`` file read."""
    net_id: str
    """Net id (file stem), e.g. ``"fourway_00"``."""
    family: str
    """Folder name the net lives in (its family), e.g. ``"holdout"``."""
    bounds_m: tuple[float, float, float, float]
    """``(xmin, ymin, xmax, ymax)`` of all lane polygons and the junction [m]."""
    junction_id: str
    """SUMO id of the (single) intersection node."""
    junction_type: str
    """SUMO junction type ('priority', 'right_before_left', ...)."""
    junction_polygon_xy: np.ndarray
    """``float64 [P, 2]`` junction shape."""
    lane_ids: tuple[str, ...]
    """Lane id of each entry in ``lane_polygons_xy`` (internal lanes start with ':')."""
    lane_polygons_xy: list[np.ndarray]
    """Footprint ``float64 [P, 2]`` of every lane, from its centre line and width."""
    marking_polylines_xy: list[np.ndarray]
    """Lane markings ``float64 [P, 2]``: road edges, lane boundaries and centre lines of normal edges."""
    marking_kinds: tuple[str, ...]
    """Kind of each marking: 'edge' (road boundary), 'lane' (between lanes of one direction), 'centre'."""
    ego_routes: list[EgoRoute]
    """Every (approach arm, exit arm) pair the ego can drive, U-turns excluded."""
    npc_routes: list[tuple[str, ...]]
    """Edge-id routes for traffic: every connected (approach edge, exit edge) pair."""
    lanes: dict[str, LaneInfo]
    """Every lane (normal and internal) by id, in ``lane_ids`` order."""

    @property
    def drivable_polygons_xy(self) -> list[np.ndarray]:
        """Lane polygons plus the junction polygon: their union is the drivable area."""
        return [*self.lane_polygons_xy, self.junction_polygon_xy]

    @property
    def net_ref(self) -> str:
        """``"<family>/<net_id>"``, the name :func:`priqn.sim.scenario.net_path` accepts."""
        return f"{self.family}/{self.net_id}"

    def routes_for(self, command: str) -> list[EgoRoute]:
        """Ego routes with this command (may be empty, e.g. no 'straight' from a T's stem)."""
        if command not in COMMANDS:
            raise PriqnError(f"command {command!r}: expected one of {', '.join(COMMANDS)}")
        return [r for r in self.ego_routes if r.command == command]

    def commands(self) -> tuple[str, ...]:
        """Commands that have at least one route, in :data:`COMMANDS` order."""
        have = {r.command for r in self.ego_routes}
        return tuple(c for c in COMMANDS if c in have)

    def route(self, name: str) -> EgoRoute:
        """The ego route called ``name`` (e.g. ``"a1_in->a0_out"``)."""
        for r in self.ego_routes:
            if r.name == name:
                return r
        raise PriqnError(
            f"{self.net_ref}: no ego route {name!r} (have: {', '.join(r.name for r in self.ego_routes)})"
        )

    @classmethod
    def load(cls, net_path: str | Path, junction: str | None = None) -> RoadMap:
        """Read a ``.net.xml`` with sumolib (internal lanes included) and derive the road map
        around one junction (:func:`find_junction`: ``junction`` by id, else the one with
        the most approaches). Only that junction's arms and internal lanes are kept, so a
        net with many junctions (a grid, an OSM extract) gives a map of one intersection."""
        import sumolib  # lazy: pure-python but slow-ish to import

        path = Path(net_path)
        if not path.is_file():
            raise PriqnError(f"{path}: no such net; run 'priqn scenario generate'")
        try:
            net = sumolib.net.readNet(str(path), withInternal=True)
        except Exception as exc:  # sumolib raises a mix of SAX / Value errors
            raise PriqnError(f"{path}: not a readable SUMO net ({exc})") from exc

        junction = find_junction(net, path, junction)
        junction_xy = np.asarray(junction.getShape(), dtype=float)
        edges = _junction_edges(net, junction)

        lane_ids, polygons, lanes = [], [], {}
        for edge in edges:
            for lane in edge.getLanes():
                centre = np.asarray(lane.getShape(), float)
                lane_ids.append(lane.getID())
                polygons.append(lane_polygon(centre, lane.getWidth()))
                lanes[lane.getID()] = LaneInfo(
                    lane_id=lane.getID(),
                    edge_id=edge.getID(),
                    index=lane.getIndex(),
                    internal=edge.getFunction() == "internal",
                    width_m=float(lane.getWidth()),
                    length_m=float(lane.getLength()),
                    speed_limit_mps=float(lane.getSpeed()),
                    centre_xy=centre,
                    towards_junction=edge.getFunction() != "internal"
                    and edge.getToNode().getID() == junction.getID(),
                )

        normal = [e for e in edges if e.getFunction() != "internal"]
        markings, kinds = _markings(normal)
        ego_routes, npc_routes = _routes(normal, junction, net, path)
        if not ego_routes:
            raise PriqnError(
                f"{path}: junction {junction.getID()!r} has no drivable route through it "
                "(no connection from an approach edge to an exit edge)"
            )

        pts = np.concatenate([junction_xy, *polygons]) if polygons else junction_xy
        bounds = (
            float(pts[:, 0].min()),
            float(pts[:, 1].min()),
            float(pts[:, 0].max()),
            float(pts[:, 1].max()),
        )
        return cls(
            net_path=path,
            net_id=path.name.removesuffix(".net.xml"),
            family=path.parent.name,
            bounds_m=bounds,
            junction_id=junction.getID(),
            junction_type=junction.getType(),
            junction_polygon_xy=junction_xy,
            lane_ids=tuple(lane_ids),
            lane_polygons_xy=polygons,
            marking_polylines_xy=markings,
            marking_kinds=tuple(kinds),
            ego_routes=ego_routes,
            npc_routes=npc_routes,
            lanes=lanes,
        )


# --------------------------------------------------------------------------- geometry helpers


def sumo_angle_deg(heading_rad: float | np.ndarray) -> float | np.ndarray:
    """Heading (rad, CCW from +x) → SUMO angle (deg, clockwise from north) in [0, 360)."""
    return np.mod(90.0 - np.degrees(heading_rad), 360.0)


def arc_length(xy: np.ndarray) -> np.ndarray:
    """``[P]`` cumulative length along polyline ``xy [P, 2]`` (0 at the first point)."""
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)])


def polyline_heading(xy: np.ndarray) -> np.ndarray:
    """``[P]`` heading (rad) of polyline ``xy [P, 2]`` by central differences."""
    d = np.gradient(xy, axis=0)
    return np.arctan2(d[:, 1], d[:, 0])


def offset_polyline(xy: np.ndarray, offset_m: float) -> np.ndarray:
    """Shift polyline ``xy [P, 2]`` sideways by ``offset_m`` (positive = left), mitred joints."""
    xy = _dedupe(np.asarray(xy, float))
    if len(xy) < 2:
        return xy.copy()
    seg = np.diff(xy, axis=0)
    seg /= np.linalg.norm(seg, axis=1, keepdims=True)
    normals = np.stack([-seg[:, 1], seg[:, 0]], axis=1)  # left normals [P-1, 2]
    vertex_n = np.empty_like(xy)
    vertex_n[0], vertex_n[-1] = normals[0], normals[-1]
    if len(xy) > 2:
        mid = normals[:-1] + normals[1:]
        mid /= np.maximum(np.linalg.norm(mid, axis=1, keepdims=True), 1e-9)
        cos_half = np.sum(mid * normals[1:], axis=1, keepdims=True)
        vertex_n[1:-1] = mid / np.maximum(cos_half, 0.5)  # mitre, capped at 2x
    return xy + offset_m * vertex_n


def lane_polygon(center_xy: np.ndarray, width_m: float) -> np.ndarray:
    """Footprint ``[2P, 2]`` of a lane from its centre line ``[P, 2]`` and width."""
    left = offset_polyline(center_xy, width_m / 2.0)
    right = offset_polyline(center_xy, -width_m / 2.0)
    return np.concatenate([left, right[::-1]])


def resample(xy: np.ndarray, step_m: float) -> np.ndarray:
    """Points every ``step_m`` along polyline ``xy`` (the last point kept exactly)."""
    xy = _dedupe(xy)
    s = arc_length(xy)
    n = max(int(math.ceil(s[-1] / step_m - 1e-6)), 1)
    t = np.linspace(0.0, s[-1], n + 1)
    return np.stack([np.interp(t, s, xy[:, 0]), np.interp(t, s, xy[:, 1])], axis=1)


def smooth_polyline(xy: np.ndarray, sigma_m: float, step_m: float) -> np.ndarray:
    """Gaussian-smooth a polyline resampled at ``step_m``; ends are extended straight.

    The line is padded at both ends by point reflection (``2 p0 - p_k``), which keeps a
    straight end straight and the end points fixed, then convolved with a Gaussian of
    width ``sigma_m`` and resampled at ``step_m`` again.
    """
    pts = resample(xy, step_m)
    sigma = sigma_m / step_m
    half = int(math.ceil(3 * sigma))
    if half == 0 or len(pts) < 3:
        return pts
    k = np.arange(-half, half + 1)
    w = np.exp(-0.5 * (k / sigma) ** 2)
    w /= w.sum()
    idx = np.arange(1, half + 1)
    head = 2 * pts[0] - pts[np.minimum(idx, len(pts) - 1)][::-1]
    tail = 2 * pts[-1] - pts[np.maximum(len(pts) - 1 - idx, 0)]
    padded = np.concatenate([head, pts, tail])
    out = np.stack([np.convolve(padded[:, i], w, mode="valid") for i in range(2)], axis=1)
    return resample(out, step_m)


def project_s(xy: np.ndarray, point: np.ndarray) -> float:
    """Arc length of the point of polyline ``xy`` closest to ``point``."""
    a, b = xy[:-1], xy[1:]
    ab = b - a
    t = np.clip(np.sum((point - a) * ab, axis=1) / np.maximum(np.sum(ab * ab, axis=1), 1e-12), 0, 1)
    proj = a + t[:, None] * ab
    i = int(np.argmin(np.sum((proj - point) ** 2, axis=1)))
    return float(arc_length(xy)[i] + t[i] * np.linalg.norm(ab[i]))


# --------------------------------------------------------------------------- internals


def _dedupe(xy: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    xy = np.asarray(xy, float)
    if len(xy) < 2:
        return xy
    keep = np.concatenate([[True], np.linalg.norm(np.diff(xy, axis=0), axis=1) > tol])
    return xy[keep]


def arms(node) -> set[str]:
    """Ids of the other nodes ``node`` is joined to by an edge (either direction)."""
    ends = {e.getFromNode().getID() for e in node.getIncoming()}
    ends |= {e.getToNode().getID() for e in node.getOutgoing()}
    ends.discard(node.getID())
    return ends


def find_junction(net, path: Path, junction: str | None = None):
    """The intersection node the env drives through.

    A node is an intersection iff it joins three or more other nodes (arms): the dead
    ends and turnaround nodes at the tips of a plain netconvert net's arms join one, a
    node in the middle of a road two. ``junction`` picks one by id; otherwise the one
    with the most approach edges (ties: the smallest id), so a generated net's single
    junction is found as before.
    """
    candidates = [n for n in net.getNodes() if n.getType() != "internal" and len(arms(n)) >= 3]
    if junction:
        try:
            node = net.getNode(junction)
        except KeyError:
            node = None
        if node is None or node not in candidates:
            valid = ", ".join(sorted(n.getID() for n in candidates)) or "none"
            raise PriqnError(
                f"{path}: junction {junction!r} is not an intersection of this net "
                f"(intersections, >= 3 arms: {valid})"
            )
        return node
    if not candidates:
        raise PriqnError(
            f"{path}: no intersection (a node joining 3 or more roads); priqn drives through "
            "one junction: build the net around a T-junction or a crossing (docs/your-own-net.md)"
        )
    incoming = lambda n: sum(e.getFunction() != "internal" for e in n.getIncoming())  # noqa: E731
    return min(candidates, key=lambda n: (-incoming(n), n.getID()))


def _junction_edges(net, junction) -> list:
    """The normal edges into and out of ``junction`` and its internal edges, in net order."""
    jid = junction.getID()
    out = []
    for edge in net.getEdges(withInternal=True):
        if edge.getFunction() == "internal":
            if edge.getID().startswith(f":{jid}_"):
                out.append(edge)
        elif jid in (edge.getFromNode().getID(), edge.getToNode().getID()):
            out.append(edge)
    return out


def _markings(edges) -> tuple[list[np.ndarray], list[str]]:
    """Road edges, lane boundaries and centre lines of the given normal edges."""
    lines, kinds = [], []
    for edge in edges:
        lanes = sorted(edge.getLanes(), key=lambda ln: ln.getIndex())
        first = lanes[0]
        lines.append(offset_polyline(np.asarray(first.getShape(), float), -first.getWidth() / 2))
        kinds.append("edge")
        for lane in lanes[1:]:
            lines.append(offset_polyline(np.asarray(lane.getShape(), float), -lane.getWidth() / 2))
            kinds.append("lane")
        top = lanes[-1]
        opposite = _has_opposite(edge)
        # The left border of an edge with an opposite edge is the centre line; draw it once.
        if not opposite or edge.getID() < opposite:
            lines.append(offset_polyline(np.asarray(top.getShape(), float), top.getWidth() / 2))
            kinds.append("centre" if opposite else "edge")
    return lines, kinds


def _has_opposite(edge) -> str:
    """Id of the edge running the other way between the same two nodes ('' if none)."""
    for other in edge.getToNode().getOutgoing():
        if other.getToNode() is edge.getFromNode():
            return other.getID()
    return ""


def _heading_at_end(shape: np.ndarray) -> float:
    d = shape[-1] - shape[-2]
    return math.atan2(d[1], d[0])


def _heading_at_start(shape: np.ndarray) -> float:
    d = shape[1] - shape[0]
    return math.atan2(d[1], d[0])


def _command(turn_deg: float) -> str:
    if turn_deg > TURN_THRESHOLD_DEG:
        return "left"
    if turn_deg < -TURN_THRESHOLD_DEG:
        return "right"
    return "straight"


def _lane_chain(net, conn, path: Path) -> list:
    """Lanes of one connection: from-lane, internal lanes (via), to-lane."""
    chain = [conn.getFromLane()]
    via_id = conn.getViaLaneID()
    target = conn.getToLane()
    lane = net.getLane(via_id) if via_id else None
    for _ in range(10):
        if lane is None:
            break
        chain.append(lane)
        nxt = [c.getToLane() for c in lane.getOutgoing()]
        if not nxt:
            raise PriqnError(f"{path}: internal lane {lane.getID()} leads nowhere")
        lane = None if nxt[0].getID() == target.getID() else nxt[0]
        if lane is not None and not lane.getID().startswith(":"):
            raise PriqnError(f"{path}: internal lane chain {via_id} leaves the junction early")
    chain.append(target)
    return chain


def _routes(edges, junction, net, path: Path) -> tuple[list[EgoRoute], list[tuple[str, ...]]]:
    """Ego and NPC routes through ``junction``: every connected (approach, exit) edge pair."""
    ego, npc = [], []
    approaches = [e for e in edges if e.getToNode() is junction]
    for edge in sorted(approaches, key=lambda e: e.getID()):
        for to_edge, conns in sorted(edge.getOutgoing().items(), key=lambda kv: kv[0].getID()):
            if to_edge.getToNode() is edge.getFromNode():
                continue  # U-turn (netgen builds none; be safe with other nets)
            npc.append((edge.getID(), to_edge.getID()))
            in_shape = np.asarray(edge.getLanes()[0].getShape(), float)
            out_shape = np.asarray(to_edge.getLanes()[0].getShape(), float)
            turn = math.degrees(_heading_at_start(out_shape) - _heading_at_end(in_shape))
            turn = (turn + 180.0) % 360.0 - 180.0
            if turn == -180.0:
                turn = 180.0
            command = _command(turn)
            # Left turns from the leftmost lane, others from the rightmost (SUMO's lane 0).
            pick = max if command == "left" else min
            conn = pick(conns, key=lambda c: c.getFromLane().getIndex())
            ego.append(_ego_route(net, edge, to_edge, conn, command, turn, path))
    return ego, npc


def _ego_route(net, edge, to_edge, conn, command: str, turn: float, path: Path) -> EgoRoute:
    lanes = _lane_chain(net, conn, path)
    shapes = [_dedupe(np.asarray(ln.getShape(), float)) for ln in lanes]
    raw = _dedupe(np.concatenate(shapes))
    ref = smooth_polyline(raw, SMOOTHING_SIGMA_M, REFERENCE_STEP_M)
    approach = lanes[0]
    s_entry = project_s(ref, shapes[0][-1])
    s_exit = project_s(ref, shapes[-1][0])
    exit_len = float(arc_length(shapes[-1])[-1])
    goal = s_exit + min(GOAL_AFTER_JUNCTION_M, max(exit_len - 2.0, 0.0))
    lane_len = float(approach.getLength())
    start_pos = max(lane_len - START_BEFORE_JUNCTION_M, 0.0)
    start_xy = np.asarray(
        [np.interp(start_pos, arc_length(shapes[0]), shapes[0][:, i]) for i in range(2)]
    )
    return EgoRoute(
        name=f"{edge.getID()}->{to_edge.getID()}",
        command=command,
        turn_angle_deg=round(turn, 3),
        edges=(edge.getID(), to_edge.getID()),
        lane_ids=tuple(ln.getID() for ln in lanes),
        reference_xy=ref,
        s_junction_entry_m=s_entry,
        s_junction_exit_m=s_exit,
        goal_s_m=goal,
        lane_width_m=float(approach.getWidth()),
        speed_limit_mps=float(approach.getSpeed()),
        start_lane_id=approach.getID(),
        start_pos_m=start_pos,
        start_s_m=project_s(ref, start_xy),
    )
