"""NPC traffic at a requested density, random vehicles, lateral offsets and static obstacles.

Density is ``active NPCs / TrafficSpec.max_actors`` with ``active`` = NPC vehicles
running in SUMO (inserted, not yet arrived; the ego and static obstacles do not
count). :class:`Traffic` fills the scene to the target count at reset (vehicles
spread along their first edge) and tops it up every step with new vehicles at the
start of an incoming arm. SUMO inserts a vehicle only where it fits, so the
*realised* density (mean over the episode's sim steps) can be below the requested
one; the env reports both.

Each NPC gets a random length, width and speed factor (``TrafficSpec`` ranges) and
a random lateral offset from its lane centre that fades linearly to zero over the
last ``lateral_offset_fade_m`` before the junction (offset traffic colliding inside
the junction is a known SUMO artefact). Offsets need SUMO's sublane model
(``--lateral-resolution``), which the session turns on.

Static obstacles are stopped vehicles (speed 0, lane-change and speed modes 0)
parked towards the right edge of a lane so that in-lane traffic can squeeze past
(sublane model) while a centred car cannot pass without an offset to the left.

How the NPCs treat the ego is :class:`TrafficBehaviour` (``EnvConfig.traffic``): whether
each gives way to it at the junction, whether the scene is topped up, SUMO's impatience.
:data:`TRAFFIC_SETTINGS` names whole settings a user picks (``priqn train --traffic``);
docs/environment.md says which CARLA behaviour each knob stands in for.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from types import ModuleType
from typing import Any, ClassVar

import numpy as np

from priqn.checks import check_density
from priqn.env.path_braking import NpcPaths, PathBraking, PathBrakingConfig
from priqn.errors import PriqnError, did_you_mean
from priqn.sim.geometry import sumo_angle_deg
from priqn.sim.scenario import TrafficSpec

NPC_PREFIX = "npc."
"""SUMO id prefix of traffic vehicles."""
OBSTACLE_PREFIX = "obstacle."
"""SUMO id prefix of static obstacles."""
NPC_TYPE = "priqn_npc"
"""SUMO vehicle type of traffic vehicles (a copy of SUMO's default car)."""
OBSTACLE_TYPE = "priqn_obstacle"
"""SUMO vehicle type of static obstacles."""
IGNORE_IDS_PARAM = "junctionModel.ignoreIDs"
"""SUMO vehicle parameter: foes (space-separated ids) its junction model ignores."""


LEGACY_PATH_KNOBS: dict[str, str] = {
    f"path_{f.name}": f.name for f in dataclasses.fields(PathBrakingConfig)
}
"""The flat ``[env.traffic]`` keys of run folders written before
:class:`PathBrakingConfig` (``path_look_ahead_s = 4.35``) -> its fields
(:func:`upgrade_traffic_table`)."""


def upgrade_traffic_table(table: Mapping[str, Any]) -> dict[str, Any]:
    """An ``[env.traffic]`` table of any recorded form as the current one: the flat form of
    older run folders (``path_braking = true`` beside ``path_look_ahead_s = 4.35``, ...)
    becomes ``path_braking = {look_ahead_s = 4.35, ...}``; ``path_braking = false`` (or
    absent) is off, its flat knobs dropped (they did nothing). ``path_braking = true`` is
    the table of defaults, also in the current form (``--set env.traffic.path_braking=true``).
    A table of the current form comes back as it is."""
    out = {k: v for k, v in table.items() if k not in LEGACY_PATH_KNOBS}
    knobs = {LEGACY_PATH_KNOBS[k]: v for k, v in table.items() if k in LEGACY_PATH_KNOBS}
    braking = table.get("path_braking")
    if braking is True:
        out["path_braking"] = knobs
    elif braking is False:
        out["path_braking"] = None
    elif isinstance(braking, Mapping) and knobs:
        out["path_braking"] = {**braking, **knobs}
    return out


@dataclasses.dataclass(frozen=True)
class TrafficBehaviour:
    """How the NPCs drive with respect to the ego (``EnvConfig.traffic``, docs/environment.md).

    The defaults are SUMO's drivers (the ``sumo`` setting): each NPC gives way to the ego
    wherever the junction gives the ego priority, the scene is topped up to its density
    every decision, no impatience, no path braking. A non-default value draws from its own
    generator (path braking draws nothing), so the defaults leave every episode bit for bit
    as it was. :data:`TRAFFIC_SETTINGS` names whole settings; ``tm`` is the
    Traffic-Manager-like one. Run folders written before :class:`PathBrakingConfig` record
    its knobs flat (``path_look_ahead_s``); they load as they were
    (:func:`upgrade_traffic_table`)."""

    MOVED_KEYS: ClassVar[dict[str, str]] = {
        old: f"path_braking.{new}" for old, new in LEGACY_PATH_KNOBS.items()
    }
    """Keys of the flat form -> where they are now (``--set`` errors name the new key)."""

    yield_to_ego_prob: float = 1.0
    """Probability that an NPC gives way to the ego at the junction, drawn once per NPC at
    its insertion. An NPC that does not (``0`` = none does) has the ego in its SUMO
    ``junctionModel.ignoreIDs``: it takes its right of way, or a gap, as if the ego were not
    there, in the approach *and* inside the junction. Its car-following still brakes for an
    ego ahead of it in its own lane. That is ruder than CARLA's Traffic Manager, whose NPCs
    also brake for an ego already across their path: add ``path_braking`` for that."""
    top_up: bool = True
    """Keep the requested density by adding NPCs at the arm starts as others leave. False:
    the scene's NPCs are the ones placed at reset, so a waiting ego eventually finds the
    junction clear (the realised density then falls during the episode)."""
    impatience: float = 0.0
    """SUMO's vType ``impatience`` of the NPCs in [0, 1] (0 = SUMO's default): how readily an
    NPC that has waited forces its way past vehicles with priority, the ego included."""
    path_braking: PathBrakingConfig | None = None
    """CARLA Traffic Manager's collision stage with its knobs (:class:`PathBrakingConfig`,
    a ``[env.traffic.path_braking]`` table; ``true`` is its defaults, ``tm``'s), or None
    (``false``, absent): off, SUMO's drivers alone."""

    @classmethod
    def upgrade_table(cls, data: Mapping[str, Any]) -> dict[str, Any]:
        """Its table of any recorded form as the current one (:func:`priqn.config.from_dict`
        calls it: :func:`upgrade_traffic_table`)."""
        return upgrade_traffic_table(data)

    def __post_init__(self) -> None:
        if not 0.0 <= self.yield_to_ego_prob <= 1.0:
            raise ValueError(
                f"traffic.yield_to_ego_prob: expected a probability in [0, 1], got "
                f"{self.yield_to_ego_prob}"
            )
        if not 0.0 <= self.impatience <= 1.0:
            raise ValueError(
                f"traffic.impatience: expected a value in [0, 1], got {self.impatience}"
            )


LONG_EPISODE_STEPS = 200
"""Decisions per training episode of the ``-long`` settings (100 s; the default is 100)."""


@dataclasses.dataclass(frozen=True)
class TrafficSetting:
    """A named traffic setting (``priqn train --traffic NAME``): how the NPCs treat the ego
    and, apart from it, how long a training episode is. A run records the name it was
    trained with (meta.json ``traffic``: :func:`run_setting_name`)."""

    name: str
    """What ``--traffic`` and experiment files call it (``tm-long``)."""
    description: str
    """What it is, in one line (``priqn train --help`` lists them)."""
    behaviour: TrafficBehaviour = dataclasses.field(default_factory=TrafficBehaviour)
    """How its NPCs treat the ego (``EnvConfig.traffic``)."""
    max_episode_steps: int | None = None
    """Decisions per training episode it sets (``EnvConfig.max_episode_steps``; the
    ``-long`` settings: :data:`LONG_EPISODE_STEPS`); None keeps the config's."""

    def values(self) -> tuple[tuple[str, Any], ...]:
        """The setting as typed TrainConfig values (:func:`priqn.config.apply_values`):
        ``(env.traffic.<field>, value)`` for each field of its behaviour that is not the
        default, ``env.max_episode_steps`` if it sets one. Path braking with its defaults is
        ``true``, as the flat form had it, so a cell run at a commit before
        :class:`PathBrakingConfig` (``priqn sweep --code``) reads the same values."""
        b, default = self.behaviour, TrafficBehaviour()
        pairs: list[tuple[str, Any]] = []
        for f in dataclasses.fields(b):
            value = getattr(b, f.name)
            if value == getattr(default, f.name):
                continue
            if isinstance(value, PathBrakingConfig):
                value = True if value == PathBrakingConfig() else dataclasses.asdict(value)
            pairs.append((f"env.traffic.{f.name}", value))
        if self.max_episode_steps is not None:
            pairs.append(("env.max_episode_steps", self.max_episode_steps))
        return tuple(pairs)

    def apply(self, env_cfg: Any) -> Any:
        """``env_cfg`` (an :class:`~priqn.env.config.EnvConfig`) with this setting's NPC
        behaviour and, if it sets one, its episode length."""
        steps = self.max_episode_steps or env_cfg.max_episode_steps
        return dataclasses.replace(env_cfg, traffic=self.behaviour, max_episode_steps=steps)

    def plays(self, env_cfg: Any) -> bool:
        """Whether ``env_cfg`` plays this setting: its NPC behaviour, and its episode length
        if it sets one."""
        return self.behaviour == env_cfg.traffic and self.max_episode_steps in (
            None,
            env_cfg.max_episode_steps,
        )


_SUMO = TrafficBehaviour()
_RUDE = TrafficBehaviour(yield_to_ego_prob=0.0)
_RUDE_FINITE = dataclasses.replace(_RUDE, top_up=False)
_TM = dataclasses.replace(_RUDE, path_braking=PathBrakingConfig())
_TM_CARLA = dataclasses.replace(_TM, path_braking=PathBrakingConfig(look_ahead_form="carla"))
_TM_STRICT = dataclasses.replace(
    _TM, path_braking=PathBrakingConfig(follows_offset=True, margin_m=0.5)
)
_LONG = LONG_EPISODE_STEPS
TRAFFIC_SETTINGS: dict[str, TrafficSetting] = {
    s.name: s
    for s in (
        TrafficSetting("sumo", "SUMO's drivers: every NPC gives way to the ego (the default)"),
        TrafficSetting("rude", "no NPC gives way to the ego at the junction", _RUDE),
        TrafficSetting("rude-long", "rude, episodes of 200 decisions (100 s)", _RUDE, _LONG),
        TrafficSetting("rude-finite", "rude, no top-up: the reset's NPCs only", _RUDE_FINITE),
        TrafficSetting("rude-finite-long", "rude, no top-up, 200 decisions", _RUDE_FINITE, _LONG),
        TrafficSetting(
            "sumo-finite-long",
            "polite NPCs, no top-up, 200 decisions",
            dataclasses.replace(_SUMO, top_up=False),
            _LONG,
        ),
        TrafficSetting(
            "tm",
            "CARLA Traffic Manager-like: no NPC gives way to the ego, but each brakes for an "
            "ego in its path ahead",
            _TM,
        ),
        TrafficSetting(
            "tm-finite",
            "tm, no top-up: the reset's NPCs only",
            dataclasses.replace(_TM, top_up=False),
        ),
        TrafficSetting("tm-long", "tm, training episodes of 200 decisions (100 s)", _TM, _LONG),
        TrafficSetting(
            "tm-carla",
            "tm with the look-ahead of CARLA's current Traffic Manager: 2.5 m + (0.36 x speed)^2",
            _TM_CARLA,
        ),
        TrafficSetting(
            "tm-carla-long",
            "tm-carla, training episodes of 200 decisions (100 s)",
            _TM_CARLA,
            _LONG,
        ),
        TrafficSetting(
            "tm-strict",
            "tm, each NPC looking along its own lateral position and keeping 0.5 m clear of "
            "the ego",
            _TM_STRICT,
        ),
    )
}
"""Named traffic settings (issue 48's calibration candidates, issue 62's ``tm`` family;
``tm-carla`` looks ahead as CARLA's TM does, and ``tm-strict`` mends what ``tm`` missed, both
added after ``tm``'s cells were measured; docs/environment.md)."""


def traffic_setting(name: str) -> TrafficSetting:
    """The named traffic setting; an unknown name is a one-line error listing the valid ones."""
    if name not in TRAFFIC_SETTINGS:
        raise PriqnError(
            f"traffic: unknown setting {name!r} (valid: {', '.join(TRAFFIC_SETTINGS)})"
            + did_you_mean(name, TRAFFIC_SETTINGS)
        )
    return TRAFFIC_SETTINGS[name]


def traffic_names(text: str, where: str = "--traffic") -> list[str]:
    """Comma-separated setting names (``sumo,rude,tm``); an unknown or missing one is a
    one-line error naming ``where`` and the valid ones."""
    names = [n.strip() for n in str(text).split(",") if n.strip()]
    if not names:
        raise PriqnError(f"{where}: expected one or more setting names, e.g. sumo,tm")
    for name in names:
        traffic_setting(name)
    return names


def traffic_values(name: str | None) -> tuple[tuple[str, Any], ...]:
    """The typed TrainConfig values of the named traffic setting (:meth:`TrafficSetting.values`;
    none for None); an unknown name is a one-line error listing the valid ones."""
    return () if name is None else traffic_setting(name).values()


def setting_name(env_cfg: Any) -> str:
    """The named traffic setting an env config plays ('' for none), inferred from its values:
    for a run that recorded no name (:func:`run_setting_name`). Of the settings it plays
    (:meth:`TrafficSetting.plays`), one that sets the episode length wins over one that
    does not (a ``tm`` run with 200-decision episodes is ``tm-long``, not ``tm``)."""
    fits = [s for s in TRAFFIC_SETTINGS.values() if s.plays(env_cfg)]
    fits.sort(key=lambda s: s.max_episode_steps is None)  # stable: file order among equals
    return fits[0].name if fits else ""


def run_setting_name(meta: Mapping[str, Any], env_cfg: Any) -> str:
    """The traffic setting a run was trained with: the name its meta.json records
    (``traffic``, written since runs record it), else the one its env config plays
    (:func:`setting_name`; '' for none)."""
    recorded = meta.get("traffic")
    return recorded if isinstance(recorded, str) and recorded else setting_name(env_cfg)


@dataclasses.dataclass(frozen=True)
class Obstacle:
    """One static obstacle (a parked car) as placed in SUMO."""

    vehicle_id: str
    """SUMO vehicle id."""
    lane_id: str
    """SUMO lane it stands on."""
    lane_pos_m: float
    """Position of its front along the lane [m]."""
    lateral_offset_m: float
    """Offset of its centre from the lane centre [m] (negative = right)."""
    length_m: float
    """Length [m]."""
    width_m: float
    """Width [m]."""
    center_xy: tuple[float, float]
    """Centre of its footprint [m]."""
    heading_rad: float
    """Heading, counter-clockwise from +x [rad]."""


@dataclasses.dataclass(frozen=True)
class ObstacleSite:
    """A lane stretch where an obstacle may stand."""

    lane_id: str
    """SUMO lane id (non-internal)."""
    edge_id: str
    """Its edge."""
    lane_index: int
    """Index of the lane on its edge."""
    s_min_m: float
    """First allowed lane position [m]."""
    s_max_m: float
    """Last allowed lane position [m]."""
    width_m: float
    """Lane width [m]."""


class Traffic:
    """The NPCs and obstacles of one episode in the running SUMO simulation.

    ``routes``: NPC routes as edge-id lists (first edge = an incoming arm, whose end is
    the junction: lateral offsets fade out before it). ``rng`` draws everything random
    about the traffic (the env derives it from the episode seed). ``behaviour``: how the
    NPCs treat the ego (``ego_id``); with ``behaviour.path_braking``, ``paths`` are the
    net's NPC paths and ``step_s`` the SUMO step (:attr:`path_braking`).
    """

    def __init__(
        self,
        sim: ModuleType,
        spec: TrafficSpec,
        routes: Sequence[Sequence[str]],
        density: float,
        rng: np.random.Generator,
        behaviour: TrafficBehaviour = TrafficBehaviour(),
        ego_id: str = "ego",
        paths: NpcPaths | None = None,
        step_s: float = 0.1,
    ) -> None:
        if not routes:
            raise PriqnError("traffic: the net has no NPC routes")
        if spec.max_actors < 1:
            raise PriqnError(f"traffic.max_actors: expected >= 1, got {spec.max_actors}")
        self.sim = sim
        self.spec = spec
        self.density = check_density(density)
        self.target_count = int(round(self.density * spec.max_actors))
        """Number of NPCs the density asks for (round(density * max_actors); 0 for tiny densities)."""
        self.rng = rng
        self.behaviour = behaviour
        self.ego_id = ego_id
        self.rude: set[str] = set()
        """NPCs inserted so far that do not give way to the ego (``yield_to_ego_prob``)."""
        # Its own stream, spawned only when used: the default draws nothing from ``rng``.
        self._yield_rng = rng.spawn(1)[0] if behaviour.yield_to_ego_prob < 1.0 else None
        self.routes = [tuple(r) for r in routes]
        self._route_ids = [f"priqn_route.{i}" for i in range(len(self.routes))]
        self._first_edge_len: dict[str, float] = {}
        # NPC id -> (first edge, lateral offset [m], first lane length [m]) while on it
        self._offsets: dict[str, tuple[str, float, float]] = {}
        self._next_id = 0
        self._density_sum = 0.0
        self._density_steps = 0
        self.obstacles: list[Obstacle] = []
        if behaviour.path_braking is not None and paths is None:
            raise PriqnError("traffic.path_braking: the traffic was given no NPC paths")
        self._paths = paths
        self._step_s = step_s
        self.emergency_decel_mps2 = 9.0
        """The NPCs' vType ``emergencyDecel`` [m/s²] (read from SUMO in :meth:`setup`)."""
        self.path_braking: PathBraking | None = None
        """The collision stage braking NPCs for the ego (``behaviour.path_braking``; from
        :meth:`setup`), else None."""
        self.active = 0
        """NPCs running in SUMO now (kept by :meth:`record_step`)."""

    # ------------------------------------------------------------------ setup

    def setup(self) -> None:
        """Register routes and vehicle types in the (freshly loaded) simulation."""
        sim = self.sim
        for rid, edges in zip(self._route_ids, self.routes, strict=True):
            sim.route.add(rid, list(edges))
            first = edges[0]
            if first not in self._first_edge_len:
                self._first_edge_len[first] = sim.lane.getLength(f"{first}_0")
        sim.vehicletype.copy("DEFAULT_VEHTYPE", NPC_TYPE)
        sim.vehicletype.setLateralAlignment(NPC_TYPE, "arbitrary")
        sim.vehicletype.setMinGapLat(NPC_TYPE, 0.3)
        sim.vehicletype.setMaxSpeedLat(NPC_TYPE, 1.0)
        if self.behaviour.impatience:
            sim.vehicletype.setImpatience(NPC_TYPE, self.behaviour.impatience)
        sim.vehicletype.copy("DEFAULT_VEHTYPE", OBSTACLE_TYPE)
        sim.vehicletype.setColor(OBSTACLE_TYPE, (200, 40, 40, 255))
        self.emergency_decel_mps2 = float(sim.vehicletype.getEmergencyDecel(NPC_TYPE))
        if self._paths is not None and self.behaviour.path_braking is not None:
            self.path_braking = PathBraking(
                sim,
                self._paths,
                self.behaviour.path_braking,
                self._step_s,
                emergency_decel_mps2=self.emergency_decel_mps2,
                npc_prefix=NPC_PREFIX,
            )

    def populate(self, avoid: tuple[str, float, float] | None = None) -> None:
        """Spread ``target_count`` NPCs along the first edges of random routes.

        ``avoid = (edge_id, s_lo, s_hi)``: keep that stretch free (the ego's start).
        """
        for _ in range(self.target_count):
            r = int(self.rng.integers(len(self.routes)))
            first = self.routes[r][0]
            length = self._first_edge_len[first]
            pos = float(self.rng.uniform(0.0, max(0.0, length - 10.0)))
            if avoid is not None and first == avoid[0] and avoid[1] <= pos <= avoid[2]:
                continue
            self._add_npc(r, pos)

    def _add_npc(self, route_index: int, depart_pos_m: float | None) -> None:
        sim, spec, rng = self.sim, self.spec, self.rng
        vid = f"{NPC_PREFIX}{self._next_id}"
        self._next_id += 1
        sim.vehicle.add(
            vid,
            self._route_ids[route_index],
            typeID=NPC_TYPE,
            departLane="best",
            departPos="base" if depart_pos_m is None else f"{depart_pos_m:.2f}",
            departSpeed="max",
        )
        sim.vehicle.setLength(vid, float(rng.uniform(*spec.vehicle_length_m)))
        sim.vehicle.setWidth(vid, float(rng.uniform(*spec.vehicle_width_m)))
        sim.vehicle.setSpeedFactor(vid, float(rng.uniform(*spec.speed_factor)))
        if self._yield_rng is not None:
            if self._yield_rng.random() >= self.behaviour.yield_to_ego_prob:
                sim.vehicle.setParameter(vid, IGNORE_IDS_PARAM, self.ego_id)
                self.rude.add(vid)
        offset = float(rng.uniform(*spec.lateral_offset_m))
        if offset != 0.0:
            first = self.routes[route_index][0]
            self._offsets[vid] = (first, offset, self._first_edge_len[first])

    def place_obstacles(self, sites: Sequence[ObstacleSite], count: int) -> list[Obstacle]:
        """Park ``count`` obstacles at random positions of random ``sites`` (one per site)."""
        sim, spec, rng = self.sim, self.spec, self.rng
        count = min(int(count), len(sites))
        chosen = rng.choice(len(sites), size=count, replace=False) if count else []
        max_npc_width = spec.vehicle_width_m[1]
        for k, i in enumerate(chosen):
            site = sites[int(i)]
            length = float(rng.uniform(*spec.obstacle_length_m))
            width = float(rng.uniform(*spec.obstacle_width_m))
            pos = float(
                rng.uniform(site.s_min_m + length, max(site.s_min_m + length, site.s_max_m))
            )
            # Inner edge leaves max NPC width + 0.5..1.0 m free in the lane.
            free = max_npc_width + float(rng.uniform(0.5, 1.0))
            inner = site.width_m / 2.0 - free
            lat = min(inner - width / 2.0, 0.0)
            vid = f"{OBSTACLE_PREFIX}{k}"
            rid = f"priqn_obstacle_route.{k}"
            sim.route.add(rid, [site.edge_id])
            sim.vehicle.add(
                vid,
                rid,
                typeID=OBSTACLE_TYPE,
                departLane=str(site.lane_index),
                departPos=f"{pos:.2f}",
                departSpeed="0",
            )
            sim.vehicle.setLength(vid, length)
            sim.vehicle.setWidth(vid, width)
            sim.vehicle.setSpeedMode(vid, 0)
            sim.vehicle.setLaneChangeMode(vid, 0)
            x, y = sim.simulation.convert2D(site.edge_id, pos, site.lane_index)
            heading = _lane_heading(sim, site.lane_id, pos)
            nx, ny = -np.sin(heading), np.cos(heading)  # left normal
            fx, fy = x + lat * nx, y + lat * ny
            # In [0, 360); until issue 36 this angle was not taken mod 360, but SUMO's moveToXY
            # wraps it into [0, 360) itself: the simulation is the same either way.
            sim.vehicle.moveToXY(
                vid, site.edge_id, site.lane_index, fx, fy, sumo_angle_deg(heading), 1
            )
            sim.vehicle.setSpeed(vid, 0.0)
            cx, cy = fx - np.cos(heading) * length / 2.0, fy - np.sin(heading) * length / 2.0
            self.obstacles.append(
                Obstacle(
                    vid,
                    site.lane_id,
                    pos,
                    lat,
                    length,
                    width,
                    (float(cx), float(cy)),
                    float(heading),
                )
            )
        return self.obstacles

    # ------------------------------------------------------------------ per step

    def record_step(self, departed: Sequence[str], arrived: Sequence[str]) -> None:
        """Book one sim step: the vehicles SUMO inserted and removed in it (for the density)."""
        for v in departed:
            if v.startswith(NPC_PREFIX):
                self.active += 1
        for v in arrived:
            if v.startswith(NPC_PREFIX):
                self.active -= 1
        self._density_sum += self.active / self.spec.max_actors
        self._density_steps += 1

    def top_up(self) -> int:
        """Add NPCs at arm starts until running + waiting NPCs reach the target; returns how
        many (none with ``behaviour.top_up`` off)."""
        if not self.behaviour.top_up:
            return 0
        missing = self.target_count - self.active - self._pending()
        for _ in range(max(0, missing)):
            self._add_npc(int(self.rng.integers(len(self.routes))), None)
        return max(0, missing)

    def update_offsets(self) -> None:
        """Steer offset NPCs towards their faded lateral offset (call once per decision)."""
        if not self._offsets:
            return
        sim = self.sim
        fade = self.spec.lateral_offset_fade_m
        done = []
        running = set(sim.vehicle.getIDList())
        pending = set(sim.simulation.getPendingVehicles())
        for vid, (first, offset, length) in self._offsets.items():
            if vid not in running:
                if vid not in pending:  # arrived
                    done.append(vid)
                continue
            if sim.vehicle.getRoadID(vid) != first:
                done.append(vid)
                continue
            to_end = length - sim.vehicle.getLanePosition(vid)
            want = offset * min(max((to_end - 2.0) / fade, 0.0), 1.0) if fade > 0 else 0.0
            now = sim.vehicle.getLateralLanePosition(vid)
            if abs(want - now) > 0.05:
                sim.vehicle.changeSublane(vid, want - now)
        for vid in done:
            del self._offsets[vid]

    def _pending(self) -> int:
        return sum(1 for v in self.sim.simulation.getPendingVehicles() if v.startswith(NPC_PREFIX))

    @property
    def density_realised(self) -> float:
        """Mean of active NPCs / max_actors over the sim steps so far (0 before the first)."""
        return self._density_sum / self._density_steps if self._density_steps else 0.0


def _lane_heading(sim: ModuleType, lane_id: str, pos: float) -> float:
    shape = np.asarray(sim.lane.getShape(lane_id), float)
    seg = np.diff(shape, axis=0)
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(seg, axis=1))])
    i = int(np.clip(np.searchsorted(cum, pos) - 1, 0, len(seg) - 1))
    return float(np.arctan2(seg[i, 1], seg[i, 0]))
