"""A Traffic-Manager-like collision stage: NPCs brake for the ego in their path ahead.

CARLA's Traffic Manager (TM), which drove the paper's NPCs, does not know the ego (it is
not registered with the TM), so it gives the ego no right of way. But every tick its
*collision stage* extends each TM vehicle's box along the vehicle's own path ahead, by a
length that grows with its speed (the "geodesic boundary": 2.5 m + (0.36 x speed)^2 in
current CARLA releases, ``CollisionStage::GetBoundingBoxExtention``; 2 m + 1.73 s x speed,
capped at 50 m, in CARLA 0.9.10; ``tm`` was measured with
2.5 m + 4.35 s x speed, see
:attr:`PathBrakingConfig.look_ahead_form`), and
when any vehicle's box overlaps that boundary, the ego included
(``ignore_vehicles_percentage`` defaults to 0), its motion planner brakes for it. So a TM
NPC drives into the junction by its own right of way, but does not drive into an ego that
is already across its path, unless the ego cut in too late for it to stop.

SUMO's junction model cannot say that: ``junctionModel.ignoreIDs`` (``rude`` traffic) drops
the ego as a foe both in the approach and inside the junction. :class:`PathBraking` adds
the TM's stage on top of SUMO's drivers, once per SUMO step:

1. Each NPC near the ego looks along its own lane chain (approach lane, internal junction
   lanes, exit lane: :class:`NpcPaths`) from its front bumper, for
   :meth:`PathBraking.look_ahead_m` (``look_ahead_form``: ``"linear"``,
   ``min(look_ahead_max_m, look_ahead_min_m + look_ahead_s * speed)``, or ``"carla"``,
   ``look_ahead_min_m + (look_ahead_vel_factor * speed)**2``, at least ``stop_gap_m``, at
   most ``look_ahead_max_m``; the knobs are :class:`PathBrakingConfig`'s).
2. The ego is in that path when a point of the path lies inside the ego's box grown by
   half the NPC's width (the NPC's front sweeping the path would touch the ego there).
   The distance along the path to the first such point is the *hazard distance* ``d``.
3. From the first check at least ``reaction_time_s`` after the one that first saw the
   hazard, the NPC brakes to stop ``stop_gap_m`` short of it: with the least
   deceleration that does (``v**2 / (2 * (d - gap))``), at most its vType's
   ``emergencyDecel``. From beyond its stopping distance that is below its ``decel``, so
   it stops comfortably; an ego that cuts in closer gets the emergency brake, and may be
   hit. A check acts on the next SUMO step, as SUMO's own drivers do (``setSpeed`` with
   the speed mode's deceleration bound lifted; its safe speed, car-following included,
   still applies). When the ego has left its path, SUMO drives the NPC again.

The path is the lane's centre line unless ``follows_offset``: then it is shifted to the
NPC's own lateral position in its lane (SUMO's sublane model: a random offset that fades
before the junction, or a lane change under way). On the centre line, an NPC that straddles
two lanes (SUMO moves a vehicle only as far as it must to be in its target lane) looks
along the new lane's centre and can miss an ego its body will sweep. ``margin_m``
grows the ego's box further: an NPC pulling past a standing ego in a sublane lane change
turns its body off its path, and its corners reach beyond half its width.

The NPC-to-NPC behaviour stays SUMO's (its junction model orders NPCs by priority; the TM
orders its vehicles first-come-first-served at stop signs only, and at unsigned junctions
only its collision stage's negotiation orders them).
docs/environment.md lists every knob with its CARLA counterpart.
"""

from __future__ import annotations

import dataclasses
from types import ModuleType
from typing import Any

import numpy as np

from priqn.sim.geometry import arc_length
from priqn.sim.roadmap import RoadMap

SAMPLE_STEP_M = 0.5
"""Spacing of the points along an NPC's path tested against the ego's box [m]."""
REFINE_STEP_M = 0.05
"""Spacing the first hit is refined to, between the last point outside and the first
inside [m]: the hazard distance is exact to this."""
SPEED_MODE_NO_DECEL_BOUND = 0b11011
"""SUMO speed mode while an NPC brakes for the ego: SUMO's default (31) without bit 2, so a
commanded speed may fall faster than ``decel`` (:class:`PathBraking` bounds it by
``emergencyDecel`` itself); safe speed, acceleration bound and right of way still apply."""


LOOK_AHEAD_FORMS = ("linear", "carla")
"""Values of :attr:`PathBrakingConfig.look_ahead_form`."""


@dataclasses.dataclass(frozen=True)
class PathBrakingConfig:
    """CARLA Traffic Manager's collision stage (:mod:`priqn.env.path_braking`), the knobs of
    :attr:`priqn.env.traffic.TrafficBehaviour.path_braking` (``[env.traffic.path_braking]``;
    docs/environment.md): every NPC brakes for the ego when the ego's box overlaps its own path ahead, within a
    look-ahead that grows with its speed, after ``reaction_time_s``, at no more than its
    vType's ``emergencyDecel``. The defaults are ``tm``'s, as it was measured."""

    look_ahead_form: str = "linear"
    """How the look-ahead grows with the NPC's speed v [m/s]: ``"linear"``,
    ``min(look_ahead_max_m, look_ahead_min_m + look_ahead_s * v)``, as ``tm`` was measured
    (no CARLA release uses it: 2.5 m + 4.35 s x v); ``"carla"``, CARLA's TM in current
    releases (``CollisionStage::GetBoundingBoxExtention`` and ``GetGeodesicBoundary``):
    ``look_ahead_min_m + (look_ahead_vel_factor * v)**2``, at least ``stop_gap_m`` (the lead
    distance), at most ``look_ahead_max_m``
    (:meth:`priqn.env.path_braking.PathBraking.look_ahead_m`, docs/environment.md)."""
    look_ahead_min_m: float = 2.5
    """Look-ahead along the path at standstill [m] (TM ``BOUNDARY_EXTENSION_MINIMUM``)."""
    look_ahead_s: float = 4.35
    """``"linear"`` form: look-ahead added per m/s of the NPC's speed [s] (TM
    ``BOUNDARY_EXTENSION_RATE``, which CARLA declares in ``Constants.h`` but does not use)."""
    look_ahead_vel_factor: float = 0.36
    """``"carla"`` form: the factor whose product with the speed is squared [s/m^0.5], so that
    ``(0.36 * v)**2`` is in metres for v in m/s (TM ``VEL_EXT_FACTOR``)."""
    look_ahead_max_m: float = 50.0
    """Longest look-ahead [m] (TM ``BOUNDARY_EXTENSION_MAXIMUM`` of CARLA 0.9.10; later
    releases have no cap, and the ``"carla"`` form stays below it at the NPCs' speeds)."""
    reaction_time_s: float = 0.0
    """Delay from the check that first sees the ego in the path to the first braking check
    [s]. Even at 0 a check acts on the next SUMO step (0.1 s), as SUMO's own drivers do;
    CARLA's TM acts on the tick that sees the hazard, so ours lags it by one SUMO step."""
    stop_gap_m: float = 2.0
    """Where the NPC aims to stop, short of the ego [m] (TM ``MIN_FOLLOW_LEAD_DISTANCE``; the
    ``"carla"`` look-ahead form's floor, the TM's distance to the leading vehicle, 2 m)."""
    follows_offset: bool = False
    """Look along the path at the NPC's own lateral position in its lane (its sublane offset,
    or a lane change under way), not along the lane's centre line. False, as ``tm`` was
    measured: an NPC straddling two lanes can miss an ego its body will sweep
    (docs/environment.md)."""
    margin_m: float = 0.0
    """Clearance an NPC keeps from the ego beyond touching [m]: the ego's box is grown by
    it, besides half the NPC's width, in the path test. 0, as ``tm`` was measured."""

    def __post_init__(self) -> None:
        if self.look_ahead_form not in LOOK_AHEAD_FORMS:
            raise ValueError(
                f"look_ahead_form: expected one of {', '.join(LOOK_AHEAD_FORMS)}, "
                f"got {self.look_ahead_form!r}"
            )
        for name in ("look_ahead_min_m", "look_ahead_s", "look_ahead_vel_factor",
                     "reaction_time_s", "stop_gap_m", "margin_m"):  # fmt: skip
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"{name}: expected >= 0, got {getattr(self, name)}")
        if not self.look_ahead_max_m >= self.look_ahead_min_m:
            raise ValueError(
                f"look_ahead_max_m: expected >= look_ahead_min_m "
                f"({self.look_ahead_min_m}), got {self.look_ahead_max_m}"
            )


@dataclasses.dataclass(frozen=True)
class LanePath:
    """The centre line an NPC drives from the start of one lane to the end of its route."""

    xy: np.ndarray
    """``float64 [P, 2]`` centre line: the lane, then the lanes after it in its chain [m]."""
    s_m: np.ndarray
    """``float64 [P]`` arc length of every point [m]."""
    pos_scale: float
    """Geometric length / SUMO length of the first lane: SUMO lane positions times this are
    arc lengths along :attr:`xy` (the two differ on some nets)."""

    def ahead(
        self, lane_pos_m: float, reach_m: float, step_m: float, lateral_m: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Points every ``step_m`` from lane position ``lane_pos_m`` for ``reach_m``
        (clipped to the path's end), ``lateral_m`` to the left of the centre line (0: on it):
        ``float64 [Q, 2]`` points and their distance ahead ``[Q]`` [m]."""
        s0 = lane_pos_m * self.pos_scale
        ahead_m = np.arange(0.0, max(min(reach_m, self.s_m[-1] - s0), 0.0) + 1e-9, step_m)
        s = s0 + ahead_m
        xy = np.stack(
            [np.interp(s, self.s_m, self.xy[:, 0]), np.interp(s, self.s_m, self.xy[:, 1])]
        ).T
        if lateral_m:
            seg = np.clip(np.searchsorted(self.s_m, s, side="right") - 1, 0, len(self.s_m) - 2)
            tangent = self.xy[seg + 1] - self.xy[seg]
            tangent /= np.maximum(np.hypot(tangent[:, 0], tangent[:, 1]), 1e-9)[:, None]
            xy = xy + lateral_m * np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
        return xy, ahead_m


class NpcPaths:
    """The paths NPCs drive through one net's junction, by (lane, exit edge).

    Built from :attr:`RoadMap.npc_lane_chains`: for every lane of every chain, the centre
    line from that lane's start to the chain's end. An NPC on an approach lane that has no
    connection to its exit edge (it will change lanes first) is given the path of the
    nearest lane of its edge that has one. Lanes outside the road map's window have no path.
    """

    def __init__(self, roadmap: RoadMap) -> None:
        lanes = roadmap.lanes
        self._paths: dict[tuple[str, str], LanePath] = {}
        self._by_edge: dict[tuple[str, str], list[tuple[int, LanePath]]] = {}
        for chain in roadmap.npc_lane_chains:
            if any(lane not in lanes for lane in chain):
                continue
            exit_edge = lanes[chain[-1]].edge_id
            for i, lane_id in enumerate(chain):
                key = (lane_id, exit_edge)
                if key in self._paths:
                    continue
                path = _lane_path([lanes[x] for x in chain[i:]])
                self._paths[key] = path
                if i == 0:
                    first = lanes[lane_id]
                    self._by_edge.setdefault((first.edge_id, exit_edge), []).append(
                        (first.index, path)
                    )

    def __len__(self) -> int:
        return len(self._paths)

    def find(self, lane_id: str, lane_index: int, edge_id: str, exit_edge: str) -> LanePath | None:
        """The path of an NPC on ``lane_id`` (index ``lane_index`` of ``edge_id``) bound for
        ``exit_edge``; None where the map has none."""
        path = self._paths.get((lane_id, exit_edge))
        if path is not None:
            return path
        near = self._by_edge.get((edge_id, exit_edge))
        if not near:
            return None
        return min(near, key=lambda item: abs(item[0] - lane_index))[1]


def _lane_path(chain: list[Any]) -> LanePath:
    """The joined centre lines of ``chain`` (LaneInfo values), joints deduplicated."""
    parts = [chain[0].centre_xy]
    for lane in chain[1:]:
        xy = lane.centre_xy
        if np.allclose(xy[0], parts[-1][-1]):
            xy = xy[1:]
        parts.append(xy)
    xy = np.concatenate(parts).astype(np.float64)
    s = arc_length(xy)
    first_len = float(arc_length(chain[0].centre_xy)[-1])
    scale = first_len / chain[0].length_m if chain[0].length_m > 0 else 1.0
    return LanePath(xy, s, scale)


@dataclasses.dataclass
class _Braking:
    """What the stage remembers about one NPC that has the ego in its path."""

    first_seen_s: float
    """Stage time of the check that first saw the hazard [s]."""
    speed_mode: int | None = None
    """The NPC's own SUMO speed mode while it is braked (None: not braking yet)."""


class PathBraking:
    """The collision stage of one episode (module docstring); :meth:`check` once per SUMO step.

    ``config``: its knobs (:class:`PathBrakingConfig`, ``EnvConfig.traffic.path_braking``);
    ``emergency_decel_mps2``: the NPCs' vType bound on braking; ``step_s``: the SUMO
    step length.
    """

    def __init__(
        self,
        sim: ModuleType,
        paths: NpcPaths,
        config: PathBrakingConfig,
        step_s: float,
        emergency_decel_mps2: float,
        npc_prefix: str,
    ) -> None:
        self.sim = sim
        self.paths = paths
        self.config = config
        self.step_s = float(step_s)
        self.emergency_decel_mps2 = float(emergency_decel_mps2)
        """The NPCs' hardest braking (vType ``emergencyDecel``) [m/s²]."""
        self.npc_prefix = npc_prefix
        self.time_s = 0.0
        """Stage time: checks so far times ``step_s`` [s]."""
        self.hazard_m: dict[str, float] = {}
        """NPC id -> hazard distance [m] at the last check, for NPCs with the ego in their path."""
        self._braking: dict[str, _Braking] = {}
        self._exit_edge: dict[str, str] = {}

    def look_ahead_m(self, speed_mps: float) -> float:
        """How far along its path an NPC at ``speed_mps`` looks for the ego [m]: the
        config's ``look_ahead_form`` (``"linear"``, as ``tm`` was measured, or ``"carla"``,
        CARLA's current TM), at most ``look_ahead_max_m``."""
        c = self.config
        if c.look_ahead_form == "carla":
            grown = c.look_ahead_min_m + (c.look_ahead_vel_factor * speed_mps) ** 2
            reach = max(c.stop_gap_m, grown)
        else:
            reach = c.look_ahead_min_m + c.look_ahead_s * speed_mps
        return min(c.look_ahead_max_m, reach)

    def check(
        self,
        actors: dict[str, dict[int, Any]],
        ego_xy: tuple[float, float],
        ego_heading_rad: float,
        ego_length_m: float,
        ego_width_m: float,
    ) -> None:
        """One check: ``actors`` = the context-subscription read of the last step
        (:func:`priqn.env.reads.read_actors`), the ego's centre, heading and size now.
        Commands braking NPCs for the next step and hands the others back to SUMO."""
        import libsumo

        sim, c = self.sim, self.config
        cos_h, sin_h = float(np.cos(ego_heading_rad)), float(np.sin(ego_heading_rad))
        half_diag = 0.5 * float(np.hypot(ego_length_m, ego_width_m))
        hazards: dict[str, float] = {}
        for vid, var in actors.items():
            if not vid.startswith(self.npc_prefix):
                continue
            x, y = var[libsumo.VAR_POSITION]
            speed = float(var[libsumo.VAR_SPEED])
            half_w = 0.5 * float(var[libsumo.VAR_WIDTH])
            reach = self.look_ahead_m(speed)
            near_m = reach + half_diag + half_w + c.margin_m
            if np.hypot(x - ego_xy[0], y - ego_xy[1]) > near_m:
                continue
            d = self._hazard_m(vid, reach, half_w, ego_xy, cos_h, sin_h, ego_length_m, ego_width_m)
            if d is not None:
                hazards[vid] = d
        self.time_s += self.step_s
        now = self.time_s
        for vid in [v for v in self._braking if v not in hazards]:
            self._release(vid)
        self.hazard_m = hazards
        for vid, d in hazards.items():
            state = self._braking.setdefault(vid, _Braking(first_seen_s=now))
            if now - state.first_seen_s < c.reaction_time_s - 1e-9:
                continue
            speed = float(actors[vid][libsumo.VAR_SPEED])
            target = braking_speed_mps(
                speed, d - c.stop_gap_m, self.emergency_decel_mps2, self.step_s
            )
            if state.speed_mode is None:
                state.speed_mode = int(sim.vehicle.getSpeedMode(vid))
                sim.vehicle.setSpeedMode(vid, SPEED_MODE_NO_DECEL_BOUND)
            sim.vehicle.setSpeed(vid, target)

    def _hazard_m(
        self,
        vid: str,
        reach_m: float,
        npc_half_width_m: float,
        ego_xy: tuple[float, float],
        cos_h: float,
        sin_h: float,
        ego_length_m: float,
        ego_width_m: float,
    ) -> float | None:
        """Distance along ``vid``'s path to the first point inside the ego's grown box, or None."""
        sim = self.sim
        exit_edge = self._exit_edge.get(vid)
        if exit_edge is None:
            exit_edge = self._exit_edge[vid] = sim.vehicle.getRoute(vid)[-1]
        lane_id = sim.vehicle.getLaneID(vid)
        edge_id, _, index = lane_id.rpartition("_")
        path = self.paths.find(lane_id, int(index) if index.isdigit() else 0, edge_id, exit_edge)
        if path is None:
            return None
        margin = self.config.margin_m
        half_len = 0.5 * ego_length_m + npc_half_width_m + margin
        half_wid = 0.5 * ego_width_m + npc_half_width_m + margin

        def first_inside(xy: np.ndarray) -> np.ndarray:
            dx, dy = xy[:, 0] - ego_xy[0], xy[:, 1] - ego_xy[1]
            inside = (np.abs(dx * cos_h + dy * sin_h) <= half_len) & (
                np.abs(-dx * sin_h + dy * cos_h) <= half_wid
            )
            return np.flatnonzero(inside)

        lane_pos = sim.vehicle.getLanePosition(vid)
        lateral = sim.vehicle.getLateralLanePosition(vid) if self.config.follows_offset else 0.0
        xy, ahead_m = path.ahead(lane_pos, reach_m, SAMPLE_STEP_M, lateral)
        hit = first_inside(xy)
        if not len(hit):
            return None
        if hit[0] == 0:
            return 0.0
        # Between the last point outside and the first inside, to REFINE_STEP_M.
        lo = float(ahead_m[hit[0] - 1])
        xy, fine_m = path.ahead(
            lane_pos + lo / path.pos_scale, SAMPLE_STEP_M, REFINE_STEP_M, lateral
        )
        fine = first_inside(xy)
        return lo + float(fine_m[fine[0]]) if len(fine) else float(ahead_m[hit[0]])

    def _release(self, vid: str) -> None:
        """Hand ``vid`` back to SUMO's driver (if the stage was braking it)."""
        import libsumo

        state = self._braking.pop(vid)
        if state.speed_mode is None:
            return
        try:
            self.sim.vehicle.setSpeed(vid, -1.0)
            self.sim.vehicle.setSpeedMode(vid, state.speed_mode)
        except libsumo.TraCIException:
            pass  # it has left the simulation


def braking_speed_mps(
    speed_mps: float, room_m: float, max_decel_mps2: float, step_s: float
) -> float:
    """The speed after one step of braking to stop within ``room_m`` [m/s].

    The least constant deceleration that stops in ``room_m`` is ``speed**2 / (2 * room)``;
    it is applied for one step, bounded by ``max_decel_mps2``. No room left (``room_m <= 0``):
    the hardest braking. Never below 0.
    """
    if room_m <= 0.0:
        decel = max_decel_mps2
    else:
        decel = min(speed_mps * speed_mps / (2.0 * room_m), max_decel_mps2)
    return max(0.0, speed_mps - decel * step_s)
