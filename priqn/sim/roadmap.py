"""Road geometry of one generated net, read with sumolib: drivable area, markings, ego routes.

Coordinates and angles (everything in this module) are those of :mod:`priqn.sim.geometry`,
which holds the polyline, clipping and angle maths this reader builds the map with:

- Positions are SUMO network coordinates in metres: ``x`` east, ``y`` north. Nets
  from :mod:`priqn.sim.netgen` keep the junction centre at ``(0, 0)``.
- A *heading* is in radians, counter-clockwise from +x; SUMO's vehicle *angle* (degrees,
  clockwise from north) converts only through :func:`~priqn.sim.geometry.sumo_angle_deg`
  and :func:`~priqn.sim.geometry.heading_rad_from_sumo`.
- ``s`` is arc length along a route's reference line in metres, starting at the
  first point of the approach lane. Positive lateral offset ``d`` is to the left.
- Polygons are ``float64 [P, 2]`` arrays of ``(x, y)``, open (first point not repeated).

Traffic drives on the right (SUMO's default): lane 0 of an edge is its rightmost lane.

Nets that were not generated here (docs/your-own-net.md): only *car roads* count —
normal edges with a lane allowing SUMO's :data:`CAR_CLASS` — so footways, cycleways,
sidewalk lanes and rails are neither junction arms, drivable area nor routes. The map
of a net with several intersections covers one junction (:func:`find_junction`), its
arms and internal lanes, clipped to a square window :data:`CROP_MARGIN_M` around the
junction's shape, so a long arm of a street map does not make a huge raster.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path
from typing import Literal

import numpy as np

from priqn.errors import PriqnError
from priqn.sim.geometry import (
    Box,
    _dedupe,
    arc_length,
    clip_polygon,
    clip_polyline,
    lane_polygon,
    offset_polyline,
    polyline_heading,
    project_s,
    smooth_polyline,
    wrap_deg,
)

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
"""The ego is inserted this far before the junction [m] (shorter approaches:
:data:`START_MIN_LANE_POS_M`)."""

GOAL_AFTER_JUNCTION_M = 25.0
"""The route's goal lies this far past the junction on the exit lane [m]."""

START_MIN_LANE_POS_M = 5.0
"""On an approach shorter than :data:`START_BEFORE_JUNCTION_M` the ego starts this far into
the lane (or half-way along a shorter one), so that its rear stays on the road [m]."""

CAR_CLASS = "passenger"
"""SUMO vehicle class of the ego and the traffic: lanes that do not allow it (sidewalks,
bike lanes, rails) are neither drivable area, junction arms nor routes."""

CROP_MARGIN_M = 150.0
"""The map covers the junction's shape grown by this much on every side [m]; lanes reaching
further are clipped. The ego starts at most 70 m before the stop line and its grids reach
48 m ahead, 16 m behind and 32 m to each side, so it never sees past ~115 m; nets from
priqn.sim.netgen (arms <= 150 m from the junction centre) fit inside unclipped."""

MIN_ARMS = 3
"""A node is an intersection when its car roads lead to at least this many other nodes."""


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
    """True for lanes of an approach edge, i.e. lanes that end at the map's junction."""


@dataclasses.dataclass(frozen=True)
class Junction:
    """An intersection of a net, as :func:`list_junctions` reports it."""

    node_id: str
    """SUMO node (junction) id: what ``EnvConfig.junction`` names."""
    node_type: str
    """SUMO junction type ('priority', 'traffic_light', ...)."""
    arms: int
    """Other nodes its car roads lead to (either direction): >= :data:`MIN_ARMS`."""
    approaches: int
    """Car roads leading into it (the default junction is the one with the most)."""
    xy: tuple[float, float]
    """Node position [m]."""


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
    """``(xmin, ymin, xmax, ymax)`` of the (clipped) lane polygons and the junction [m]."""
    junction_id: str
    """SUMO id of the intersection node the map is built around (:func:`find_junction`)."""
    junction_type: str
    """SUMO junction type ('priority', 'right_before_left', ...)."""
    junction_polygon_xy: np.ndarray
    """``float64 [P, 2]`` junction shape."""
    lane_ids: tuple[str, ...]
    """Lane id of each entry in ``lane_polygons_xy`` (internal lanes start with ':'): the car
    lanes of the junction's arms and its internal lanes that reach into the window."""
    lane_polygons_xy: list[np.ndarray]
    """Footprint ``float64 [P, 2]`` of every lane, from its centre line and width, clipped to
    the :data:`CROP_MARGIN_M` window."""
    marking_polylines_xy: list[np.ndarray]
    """Lane markings ``float64 [P, 2]``: road edges, lane boundaries and centre lines of normal edges."""
    marking_kinds: tuple[str, ...]
    """Kind of each marking: 'edge' (road boundary), 'lane' (between lanes of one direction), 'centre'."""
    ego_routes: list[EgoRoute]
    """Every (approach arm, exit arm) pair the ego can drive, U-turns excluded."""
    npc_routes: list[tuple[str, ...]]
    """Edge-id routes for traffic: every connected (approach edge, exit edge) pair."""
    npc_lane_chains: tuple[tuple[str, ...], ...]
    """Lane ids of every connection of :attr:`npc_routes`: approach lane, the internal
    lanes it crosses the junction on, exit lane (the paths NPCs drive; a Traffic-Manager-like
    NPC looks along them for the ego, :mod:`priqn.env.path_braking`)."""
    lanes: dict[str, LaneInfo]
    """Every lane of ``lane_ids`` by id, in that order (centre lines unclipped)."""

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
        the most approaches). Only that junction's car roads (its arms) and internal lanes are
        kept, clipped to the :data:`CROP_MARGIN_M` window, so a net with many junctions (a
        grid, an OSM extract) gives a map of one intersection."""
        path = Path(net_path)
        net = _read_net(path)
        junction = find_junction(net, path, junction)
        junction_xy = np.asarray(junction.getShape(), dtype=float).reshape(-1, 2)
        anchor = junction_xy if len(junction_xy) else np.asarray([junction.getCoord()[:2]], float)
        window = (*(anchor.min(axis=0) - CROP_MARGIN_M), *(anchor.max(axis=0) + CROP_MARGIN_M))
        edges = _junction_edges(net, junction)

        lane_ids, polygons, lanes = [], [], {}
        for edge in edges:
            for lane in _car_lanes(edge):
                centre = np.asarray(lane.getShape(), float)
                polygon = clip_polygon(lane_polygon(centre, lane.getWidth()), window)
                if len(polygon) < 3:
                    continue  # outside the window
                lane_ids.append(lane.getID())
                polygons.append(polygon)
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
        markings, kinds = _markings(normal, window)
        ego_routes, npc_routes, npc_lane_chains = _routes(normal, junction, net, path)
        if not ego_routes:
            raise PriqnError(
                f"{path}: junction {junction.getID()!r} has no drivable route through it "
                "(no connection from an approach edge to an exit edge on lanes cars may use, "
                "U-turns excluded)"
            )

        pts = np.concatenate([anchor, *polygons]) if polygons else anchor
        bounds = (
            float(pts[:, 0].min()),
            float(pts[:, 1].min()),
            float(pts[:, 0].max()),
            float(pts[:, 1].max()),
        )
        return cls(
            net_path=path,
            net_id=path.name.removesuffix(".net.xml"),
            family=path.absolute().parent.name,
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
            npc_lane_chains=npc_lane_chains,
            lanes=lanes,
        )


def list_junctions(net_path: str | Path) -> list[Junction]:
    """The intersections of a ``.net.xml``, the default one first (what ``junction`` may name)."""
    net = _read_net(Path(net_path))
    out = []
    for node in _intersections(net):
        x, y = node.getCoord()[:2]
        out.append(
            Junction(
                node.getID(),
                node.getType(),
                len(arms(node)),
                _approaches(node),
                (float(x), float(y)),
            )
        )
    return out


# --------------------------------------------------------------------------- internals


def _read_net(path: Path):
    """The sumolib net with internal lanes; a missing or unreadable file is one line."""
    import sumolib  # lazy: pure-python but slow-ish to import

    if not path.is_file():
        raise PriqnError(f"{path}: no such net; run 'priqn scenario generate'")
    try:
        return sumolib.net.readNet(str(path), withInternal=True)
    except Exception as exc:  # sumolib raises a mix of SAX / Value errors
        raise PriqnError(f"{path}: not a readable SUMO net ({exc})") from exc


def _is_car_road(edge) -> bool:
    """A normal edge with a lane that :data:`CAR_CLASS` may use."""
    return edge.getFunction() == "" and edge.allows(CAR_CLASS)


def _car_lanes(edge) -> list:
    """The lanes of ``edge`` that :data:`CAR_CLASS` may use, rightmost first."""
    lanes = [ln for ln in edge.getLanes() if ln.allows(CAR_CLASS)]
    return sorted(lanes, key=lambda ln: ln.getIndex())


def arms(node) -> set[str]:
    """Ids of the other nodes ``node``'s car roads lead to or come from."""
    ends = {e.getFromNode().getID() for e in node.getIncoming() if _is_car_road(e)}
    ends |= {e.getToNode().getID() for e in node.getOutgoing() if _is_car_road(e)}
    ends.discard(node.getID())
    return ends


def _approaches(node) -> int:
    return sum(_is_car_road(e) for e in node.getIncoming())


def _intersections(net) -> list:
    """Nodes with >= :data:`MIN_ARMS` arms, the default first (most approaches, then id)."""
    found = [n for n in net.getNodes() if n.getType() != "internal" and len(arms(n)) >= MIN_ARMS]
    return sorted(found, key=lambda n: (-_approaches(n), n.getID()))


def find_junction(net, path: Path, junction: str | None = None):
    """The intersection node the env drives through.

    A node is an intersection iff its car roads join it to three or more other nodes
    (arms): the dead ends and turnaround nodes at the tips of a plain netconvert net's
    arms join one, a node in the middle of a road two, a footway or a rail line is no
    arm. ``junction`` picks one by id; otherwise the one with the most approach edges
    (ties: the smallest id), so a generated net's single junction is found as before.
    """
    candidates = _intersections(net)
    if junction:
        node = next((n for n in candidates if n.getID() == junction), None)
        if node is None:
            shown = ", ".join(n.getID() for n in candidates[:10]) or "none"
            more = f" and {len(candidates) - 10} more" if len(candidates) > 10 else ""
            raise PriqnError(
                f"{path}: junction {junction!r} is not an intersection of this net "
                f"(intersections, >= 3 arms, most approaches first: {shown}{more})"
            )
        return node
    if not candidates:
        raise PriqnError(
            f"{path}: no intersection (a node joining 3 or more roads cars may use); priqn "
            "drives through one junction: build the net around a T-junction or a crossing "
            "(docs/your-own-net.md)"
        )
    return candidates[0]


def _junction_edges(net, junction) -> list:
    """The car roads into and out of ``junction`` and its internal edges, in net order."""
    jid = junction.getID()
    out = []
    for edge in net.getEdges(withInternal=True):
        if edge.getFunction() == "internal":
            if edge.getID().rsplit("_", 1)[0] == f":{jid}":  # ':<junction>_<index>'
                out.append(edge)
        elif _is_car_road(edge) and jid in (edge.getFromNode().getID(), edge.getToNode().getID()):
            out.append(edge)
    return out


def _markings(edges, window: Box) -> tuple[list[np.ndarray], list[str]]:
    """Road edges, lane boundaries and centre lines of the given car roads, clipped to ``window``."""
    lines, kinds = [], []

    def add(lane, side: float, kind: str) -> None:
        line = offset_polyline(np.asarray(lane.getShape(), float), side * lane.getWidth() / 2)
        for piece in clip_polyline(line, window):
            lines.append(piece)
            kinds.append(kind)

    for edge in edges:
        lanes = _car_lanes(edge)
        add(lanes[0], -1.0, "edge")
        for lane in lanes[1:]:
            add(lane, -1.0, "lane")
        opposite = _has_opposite(edge)
        # The left border of an edge with an opposite edge is the centre line; draw it once.
        if not opposite or edge.getID() < opposite:
            add(lanes[-1], 1.0, "centre" if opposite else "edge")
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
    """Lanes of one connection: from-lane, internal lanes (via), to-lane.

    An internal lane's own ``via`` is not followed, so a left turn that waits at an internal
    junction keeps its first internal lane only (a known deviation, kept: docs/scenarios.md,
    "Reading a net"; :func:`_npc_chains` follows both)."""
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


def _routes(
    edges, junction, net, path: Path
) -> tuple[list[EgoRoute], list[tuple[str, ...]], tuple[tuple[str, ...], ...]]:
    """Ego and NPC routes through ``junction``: every connected (approach, exit) edge pair;
    and the lane chain of each of their connections (:attr:`RoadMap.npc_lane_chains`)."""
    ego, npc, chains = [], [], []
    approaches = [e for e in edges if e.getToNode() is junction]
    for edge in sorted(approaches, key=lambda e: e.getID()):
        for to_edge, conns in sorted(edge.getOutgoing().items(), key=lambda kv: kv[0].getID()):
            if to_edge.getToNode() is edge.getFromNode() or not _is_car_road(to_edge):
                continue  # U-turn (netgen builds none; be safe with other nets), footway, rail
            conns = [
                c
                for c in conns
                if c.getFromLane().allows(CAR_CLASS) and c.getToLane().allows(CAR_CLASS)
            ]
            if not conns:
                continue
            npc.append((edge.getID(), to_edge.getID()))
            chains += _npc_chains(net, conns)
            in_shape = np.asarray(_car_lanes(edge)[0].getShape(), float)
            out_shape = np.asarray(_car_lanes(to_edge)[0].getShape(), float)
            turn = wrap_deg(math.degrees(_heading_at_start(out_shape) - _heading_at_end(in_shape)))
            command = _command(turn)
            # Left turns from the leftmost lane, others from the rightmost (SUMO's lane 0).
            pick = max if command == "left" else min
            conn = pick(conns, key=lambda c: c.getFromLane().getIndex())
            ego.append(_ego_route(net, edge, to_edge, conn, command, turn, path))
    return ego, npc, tuple(chains)


def _npc_chains(net, conns) -> list[tuple[str, ...]]:
    """Lane-id chains of ``conns``: from-lane, every internal lane, to-lane.

    Unlike :func:`_lane_chain` (the ego's reference lines, kept as they are), an internal
    lane's own ``via`` is followed too: a left turn that waits at an internal junction
    crosses it on two internal lanes (``:J_5_0`` then ``:J_8_0``). A chain that cannot be
    followed within the junction is left out."""
    chains = []
    for conn in conns:
        chain, target = [conn.getFromLane().getID()], conn.getToLane().getID()
        via = conn.getViaLaneID()
        for _ in range(10):
            if not via or via == target:
                break
            chain.append(via)
            out = net.getLane(via).getOutgoing()
            if not out:
                break
            via = out[0].getViaLaneID() or out[0].getToLane().getID()
        if via == target or not conn.getViaLaneID():
            chains.append((*chain, target))
    return chains


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
    start_pos = max(lane_len - START_BEFORE_JUNCTION_M, min(START_MIN_LANE_POS_M, lane_len / 2))
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
