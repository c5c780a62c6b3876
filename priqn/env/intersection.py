"""``IntersectionEnv``: the ego crosses an unsignalised SUMO junction among traffic.

One decision every ``decision_interval_s`` (0.5 s): the action picks a target speed
``v_f`` at the end of the planning horizon and a lateral offset ``d_f`` from the lane
centre; a Frenet planner plans from the ego's current state (speed and lateral
position stay continuous); the ego follows the plan with ``moveToXY`` for
``decision_interval_s / sim_step_s`` SUMO steps. After every SUMO step our own
oriented-box collision test and footprint-on-road test decide the episode's end.
The reward is a ``float32 [5]`` vector in :data:`priqn.objectives.OBJECTIVES` order.

All randomness of an episode flows from ``reset(seed=...)``: the net, the requested
density, the command and route, the traffic (vehicle sizes, speed factors, offsets,
obstacles) and SUMO's own ``--seed`` are drawn from the env's generator. See
``docs/environment.md`` for every definition (rewards with units and ranges,
termination, realised density).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from priqn.config import from_dict
from priqn.env import geometry, measures, planner, sensors
from priqn.env import rewards as R
from priqn.env.traffic import ObstacleSite, Traffic, check_density
from priqn.errors import PriqnError
from priqn.objectives import OBJECTIVES
from priqn.sim.roadmap import COMMANDS, EgoRoute, RoadMap
from priqn.sim.scenario import TrafficSpec
from priqn.sim.session import SumoSession, check_net

FAMILIES: dict[str, tuple[str, ...]] = {
    "tjunction": ("tjunction",),
    "fourway": ("fourway",),
    "all": ("tjunction", "fourway"),
    "holdout": ("holdout",),
}
"""Net pools by ``EnvConfig.family``: 'all' joins both training pools."""

EGO_ID = "ego"
"""SUMO vehicle id of the ego."""
EGO_TYPE = "priqn_ego"
"""SUMO vehicle type of the ego."""
RESET_OPTIONS = ("net", "density", "command")
"""Keys ``reset(options=...)`` accepts."""
KIN_LIMIT = 100.0
"""Kinematics are clipped to [-KIN_LIMIT, KIN_LIMIT] (m/s, m/s^2) so the space is bounded."""
EGO_HEIGHT_M = 1.5
"""Ego height [m] (LiDAR)."""
NPC_HEIGHT_M = 1.5
"""Height of NPCs and obstacles [m] (LiDAR)."""


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Configuration of :class:`IntersectionEnv` (units in names; see docs/environment.md)."""

    family: str = "tjunction"
    """Net pool: 'tjunction', 'fourway', 'all' (both training pools) or 'holdout'."""
    nets_dir: str = ""
    """Folder holding ``<family>/manifest.json`` and the nets ('' = the repository's sumo_nets/)."""
    obs_size_px: int = 128
    """Side of the square BEV and LiDAR grids [px] (the paper uses 128)."""
    bev_range_m: float = 64.0
    """Side of the square area the BEV and LiDAR grids cover [m] (ego heading up)."""
    bev_behind_m: float = 16.0
    """Distance from the ego centre to the rear edge of the grids [m] (48 m ahead by default)."""
    bev_channels: tuple[str, ...] = ("drivable", "lane_markings", "route", "actors")
    """BEV channels in order (names from priqn.env.sensors.BEV_CHANNELS)."""
    densities: tuple[float, ...] = (0.5, 0.75, 1.0)
    """Requested traffic densities (active NPCs / max NPCs), one drawn uniformly per episode."""
    commands: tuple[str, ...] = ("left", "straight", "right")
    """Navigation commands drawn per episode (uniformly among those the net offers)."""
    n_speeds: int = 5
    """Number of target speeds ``v_f`` in the action grid."""
    n_offsets: int = 5
    """Number of lateral offsets ``d_f`` in the action grid."""
    max_speed_mps: float = 12.0
    """Largest target speed [m/s]; the grid is linspace(0, max_speed_mps, n_speeds)."""
    max_offset_m: float = 1.5
    """Largest |lateral offset| [m]; the grid is linspace(-max_offset_m, max_offset_m, n_offsets)."""
    decision_interval_s: float = 0.5
    """Time between decisions [s]; a whole multiple of ``sim_step_s``."""
    sim_step_s: float = 0.1
    """SUMO step length [s]."""
    planning_horizon_s: float = 3.0
    """Horizon of each Frenet plan [s]; only the first ``decision_interval_s`` is executed."""
    max_episode_steps: int = 100
    """Decisions before the episode is truncated (timeout); 100 x 0.5 s = 50 s."""
    ego_start_speed_mps: tuple[float, float] = (4.0, 8.0)
    """Range the ego's initial speed is drawn from [m/s]."""
    ego_length_m: float = 4.5
    """Ego length [m]."""
    ego_width_m: float = 1.8
    """Ego width [m]."""
    lateral_resolution_m: float = 0.8
    """SUMO sublane width [m] (traffic needs it for lateral offsets and passing obstacles)."""
    obstacles_per_episode: tuple[int, int] | None = None
    """[lo, hi] static obstacles per episode (uniform); None = the net family's TrafficSpec range."""
    obstacle_clearance_m: float = 25.0
    """Obstacles stand at least this far from the junction and ahead of the ego's start [m]."""
    sensor_query_range_m: float = 65.0
    """Radius around the ego within which actors are read from SUMO each step [m]."""
    reward: R.RewardConfig = dataclasses.field(default_factory=R.RewardConfig)
    """Reward term parameters."""

    def __post_init__(self) -> None:
        if self.family not in FAMILIES:
            raise ValueError(f"family: unknown pool {self.family!r} (valid: {', '.join(FAMILIES)})")
        if self.obs_size_px < 16:
            raise ValueError(f"obs_size_px: expected >= 16, got {self.obs_size_px}")
        if not self.bev_range_m > 0 or not 0 <= self.bev_behind_m <= self.bev_range_m:
            raise ValueError(
                f"bev_range_m / bev_behind_m: expected bev_range_m > 0 and 0 <= bev_behind_m "
                f"<= bev_range_m, got {self.bev_range_m} / {self.bev_behind_m}"
            )
        for c in self.bev_channels:
            if c not in sensors.BEV_CHANNELS:
                raise ValueError(
                    f"bev_channels: unknown channel {c!r} (valid: {', '.join(sensors.BEV_CHANNELS)})"
                )
        if not self.densities:
            raise ValueError("densities: expected at least one density in (0, 1]")
        for d in self.densities:
            if not 0.0 < d <= 1.0:
                raise ValueError(f"densities: {d} is out of range; expected values in (0, 1]")
        if not self.commands:
            raise ValueError("commands: expected at least one of left, straight, right")
        for c in self.commands:
            if c not in COMMANDS:
                raise ValueError(f"commands: unknown command {c!r} (valid: {', '.join(COMMANDS)})")
        if self.n_speeds < 1 or self.n_offsets < 1:
            raise ValueError("n_speeds, n_offsets: expected >= 1")
        if not self.max_speed_mps > 0 or self.max_offset_m < 0:
            raise ValueError("max_speed_mps: expected > 0; max_offset_m: expected >= 0")
        if not self.sim_step_s > 0 or not self.decision_interval_s > 0:
            raise ValueError("sim_step_s and decision_interval_s: expected > 0")
        ratio = self.decision_interval_s / self.sim_step_s
        if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
            raise ValueError(
                f"decision_interval_s: {self.decision_interval_s} s is not a whole multiple of "
                f"sim_step_s {self.sim_step_s} s"
            )
        if self.planning_horizon_s < self.decision_interval_s:
            raise ValueError(
                f"planning_horizon_s: {self.planning_horizon_s} s is shorter than "
                f"decision_interval_s {self.decision_interval_s} s"
            )
        if self.max_episode_steps < 1:
            raise ValueError("max_episode_steps: expected >= 1")
        if self.obstacles_per_episode is not None:
            lo, hi = self.obstacles_per_episode
            if not 0 <= lo <= hi:
                raise ValueError(
                    f"obstacles_per_episode: expected 0 <= lo <= hi, got {self.obstacles_per_episode}"
                )
        lo, hi = self.ego_start_speed_mps
        if not 0 <= lo <= hi:
            raise ValueError("ego_start_speed_mps: expected 0 <= lo <= hi")

    def sensor_config(self) -> sensors.SensorConfig:
        """The :class:`~priqn.env.sensors.SensorConfig` for this observation size and range."""
        return sensors.SensorConfig(
            size_px=self.obs_size_px,
            extent_m=self.bev_range_m,
            behind_m=self.bev_behind_m,
            bev_channels=tuple(self.bev_channels),
        )

    @property
    def substeps(self) -> int:
        """SUMO steps per decision."""
        return int(round(self.decision_interval_s / self.sim_step_s))


@dataclasses.dataclass
class _Scene:
    """Per-net data built once and cached (road map, raster, obstacle sites)."""

    roadmap: RoadMap
    raster: geometry.MapRaster
    references: dict[str, planner.ReferenceLine]
    traffic: TrafficSpec
    sites: list[ObstacleSite] | None = None


@dataclasses.dataclass
class _Episode:
    """State of the running episode."""

    net: str
    scene: _Scene
    route: EgoRoute
    ref: planner.ReferenceLine
    command: str
    density: float
    traffic: Traffic
    sim: Any
    raster: geometry.MapRaster
    state: planner.FrenetState
    """Frenet state of the ego at the current decision."""
    target_speed: float
    """Progress reward's target speed v* [m/s]."""
    kin: np.ndarray
    """Kinematics observation (v_lon, v_lat, a_lon, a_lat)."""
    pose: tuple[float, float, float]
    """Ego centre x, y [m] and heading [rad]."""
    actors: dict[str, Any] = dataclasses.field(default_factory=dict)
    """Actors read after the last SUMO step."""
    steps: int = 0
    returns: np.ndarray = dataclasses.field(
        default_factory=lambda: np.zeros(len(OBJECTIVES), np.float32)
    )
    done: bool = False
    flags: dict[str, bool] = dataclasses.field(
        default_factory=lambda: {
            "success": False,
            "collision": False,
            "off_road": False,
            "timeout": False,
        }
    )


class IntersectionEnv(gymnasium.Env):
    """Gymnasium env ``priqn/Intersection-v0`` (see module docstring and docs/environment.md)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(
        self,
        config: EnvConfig | None = None,
        render_mode: str | None = None,
        seed: int | None = None,
    ) -> None:
        self.config = cfg = config if config is not None else EnvConfig()
        if not isinstance(cfg, EnvConfig):
            raise PriqnError(f"config: expected an EnvConfig, got {type(cfg).__name__}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise PriqnError(f"render_mode: expected 'rgb_array' or None, got {render_mode!r}")
        self.render_mode = render_mode
        self._default_seed = 0 if seed is None else int(seed)
        self._seeded = False

        self._speeds = np.linspace(0.0, cfg.max_speed_mps, cfg.n_speeds)
        self._offsets = (
            np.linspace(-cfg.max_offset_m, cfg.max_offset_m, cfg.n_offsets)
            if cfg.n_offsets > 1
            else np.zeros(1)
        )
        self._table = np.stack(
            np.meshgrid(self._speeds, self._offsets, indexing="ij"), axis=-1
        ).reshape(-1, 2)
        self.action_space = spaces.Discrete(len(self._table))

        self._sensors = sensors.Sensors(cfg.sensor_config())
        self.observation_space = spaces.Dict(
            {
                "bev": spaces.Box(0, 255, self._sensors.bev_shape, np.uint8),
                "lidar": spaces.Box(0, 255, self._sensors.lidar_shape, np.uint8),
                "command": spaces.Box(0.0, 1.0, (len(COMMANDS),), np.float32),
                "kinematics": spaces.Box(-KIN_LIMIT, KIN_LIMIT, (4,), np.float32),
            }
        )

        rc = cfg.reward
        self._envelope = measures.Envelope(
            rc.lon_safe_gap_m, rc.lat_safe_gap_m, rc.reaction_time_s, rc.conflict_time_safe_s
        )
        # The risk look-ahead from the decision's last step reads the plan beyond its horizon.
        n_plan = int(round(cfg.planning_horizon_s / cfg.sim_step_s))
        n_look = measures.look_ahead_samples(rc.conflict_time_safe_s, cfg.sim_step_s)
        self._planner_cfg = planner.PlannerConfig(
            horizon_s=cfg.planning_horizon_s,
            dt_s=cfg.sim_step_s,
            extend_s=max(0, cfg.substeps + n_look - n_plan) * cfg.sim_step_s,
        )
        self._pool = self._net_pool()
        self._scenes: dict[str, _Scene] = {}
        self._session = SumoSession(cfg.sim_step_s, cfg.lateral_resolution_m)
        self._episode: _Episode | None = None
        self._last_obs: dict[str, np.ndarray] | None = None

    # ------------------------------------------------------------------ public

    def action_table(self) -> np.ndarray:
        """``float64 [A, 2]``: ``(v_f [m/s], d_f [m])`` of every action index."""
        return self._table.copy()

    def preload_nets(self) -> int:
        """Parse every net of the pool now (road map, raster, SUMO check); returns how many.

        Otherwise each net is parsed at its first reset (~0.1-0.3 s); call this to move
        that cost out of timed or latency-sensitive loops (``venv.call("preload_nets")``).
        """
        for net in self._pool:
            self._scene(net)
        return len(self._pool)

    @property
    def net_pool(self) -> tuple[str, ...]:
        """The nets ``reset`` draws from, as ``"family/net_id"``."""
        return tuple(self._pool)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        if seed is None and not self._seeded:
            seed = self._default_seed
        super().reset(seed=seed)
        self._seeded = True
        self._episode = None
        cfg, rng = self.config, self.np_random
        opts = self._check_options(options)

        # Draws in a fixed order so a seed fixes the episode.
        net_draw = self._pool[int(rng.integers(len(self._pool)))]
        density_draw = float(cfg.densities[int(rng.integers(len(cfg.densities)))])
        command_u = float(rng.random())
        route_u = float(rng.random())
        v0 = float(rng.uniform(*cfg.ego_start_speed_mps))
        sumo_seed = int(rng.integers(0, 2**31 - 1))
        traffic_seed = int(rng.integers(0, 2**63 - 1))

        net_ref = opts.get("net", net_draw)
        density = (
            check_density(opts["density"], "reset options 'density'")
            if "density" in opts
            else density_draw
        )
        scene = self._scene(net_ref)
        offered = [c for c in cfg.commands if scene.roadmap.routes_for(c)]
        if "command" in opts:
            command = opts["command"]
            if not scene.roadmap.routes_for(command):
                raise PriqnError(
                    f"reset options 'command': net {net_ref} has no {command!r} route "
                    f"(it offers: {', '.join(scene.roadmap.commands())})"
                )
        else:
            if not offered:
                raise PriqnError(
                    f"net {net_ref}: none of the configured commands {cfg.commands} is possible here"
                )
            command = offered[min(int(command_u * len(offered)), len(offered) - 1)]
        routes = scene.roadmap.routes_for(command)
        route = routes[min(int(route_u * len(routes)), len(routes) - 1)]

        self._session.start(scene.roadmap.net_path, sumo_seed)
        sim = self._session.sim
        try:
            traffic = self._setup_episode(
                scene, route, density, v0, np.random.default_rng(traffic_seed)
            )
        except _sumo_errors() as exc:
            raise PriqnError(f"{net_ref}: SUMO failed while setting up the episode: {exc}") from exc

        ref = scene.references[route.name]
        xy, heading = ref.to_cartesian(route.start_s_m, 0.0)
        self._episode = ep = _Episode(
            net=net_ref,
            scene=scene,
            route=route,
            ref=ref,
            command=command,
            density=density,
            traffic=traffic,
            sim=sim,
            raster=scene.raster.with_route(route.reference_xy, route.lane_width_m),
            state=planner.FrenetState(
                s=route.start_s_m, s_dot=v0, s_ddot=0.0, d=0.0, d_prime=0.0, d_pprime=0.0
            ),
            target_speed=min(cfg.reward.target_speed_mps, route.speed_limit_mps),
            kin=np.array([v0, 0.0, 0.0, 0.0], np.float32),
            pose=(float(xy[0]), float(xy[1]), float(heading)),
        )
        ep.actors = self._read_actors()
        obs = self._observe()
        return obs, self._info()

    def step(
        self, action: Any
    ) -> tuple[dict[str, np.ndarray], np.ndarray, bool, bool, dict[str, Any]]:
        ep = self._episode
        if ep is None:
            raise PriqnError("step() before reset(): call env.reset() first")
        if ep.done:
            raise PriqnError("step() after the episode ended: call env.reset() first")
        if not self._session.is_open:
            raise PriqnError(
                "this env's SUMO simulation was taken over by another env in this process "
                "(libsumo runs one per process): reset() this env, or use "
                "priqn.env.vector.make_vector_env for several envs"
            )
        a = self._check_action(action)
        cfg = self.config
        v_f, d_f = self._table[a]
        traj = self._plan(float(v_f), float(d_f))
        try:
            meas = self._execute(traj)
        except _sumo_errors() as exc:
            ep.done = True
            raise PriqnError(
                f"{ep['net']}: SUMO failed at decision {ep['steps']} ({type(exc).__name__}: {exc})"
            ) from exc
        ep.steps += 1
        flags = ep.flags
        success = flags["success"]
        terminated = flags["collision"] or flags["off_road"] or success
        truncated = (not terminated) and ep.steps >= cfg.max_episode_steps
        flags["timeout"] = truncated
        rc = cfg.reward
        reward = R.reward_vector(
            R.safety(flags["collision"], flags["off_road"], rc),
            R.risk(meas["conflict_time"], rc),
            R.lane_keeping(meas["lat_offset"], meas["heading_err"], rc),
            R.progress(
                meas["advance"],
                meas["speed"],
                ep.target_speed,
                cfg.decision_interval_s,
                success,
                rc,
            ),
            R.comfort(meas["jerk"], meas["lat_acc"], rc),
        )
        ep.returns += reward
        ep.done = terminated or truncated
        obs = self._observe()
        return obs, reward, bool(terminated), bool(truncated), self._info()

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._last_obs is None:
            raise PriqnError("render() before reset(): call env.reset() first")
        return self._sensors.render_rgb(self._last_obs["bev"], self._last_obs["lidar"])

    def close(self) -> None:
        self._session.close()
        self._episode = None

    # ------------------------------------------------------------------ nets

    def _nets_root(self) -> Path | None:
        return Path(self.config.nets_dir) if self.config.nets_dir else None

    def _net_pool(self) -> list[str]:
        from priqn.sim.scenario import family_net_refs

        pool: list[str] = []
        for fam in FAMILIES[self.config.family]:
            pool += family_net_refs(fam, self._nets_root())
        if not pool:
            raise PriqnError(f"family {self.config.family!r}: the manifest lists no nets")
        return pool

    def _net_file(self, net_ref: str) -> Path:
        from priqn.sim.scenario import net_path

        root = self._nets_root()
        if root is None:
            return net_path(net_ref)
        parts = Path(net_ref).parts
        if len(parts) != 2:
            raise PriqnError(f"net {net_ref!r}: expected 'family/net_id' (e.g. holdout/fourway_00)")
        path = root / parts[0] / f"{parts[1]}.net.xml"
        if not path.is_file():
            raise PriqnError(
                f"{path}: no such net (nets_dir {root}); pick one of: {', '.join(self._pool)}"
            )
        return path

    def _scene(self, net_ref: str) -> _Scene:
        scene = self._scenes.get(net_ref)
        if scene is None:
            path = self._net_file(net_ref)
            check_net(path)  # a malformed net would crash libsumo (and the process)
            roadmap = RoadMap.load(path)
            raster = geometry.MapRaster.from_roadmap(
                roadmap, marking_width_m=max(0.5, self._sensors.cfg.metres_per_px)
            )
            refs = {r.name: planner.ReferenceLine(r.reference_xy) for r in roadmap.ego_routes}
            scene = _Scene(roadmap, raster, refs, _traffic_spec(roadmap))
            self._scenes[net_ref] = scene
        return scene

    # ------------------------------------------------------------------ validation

    def _check_options(self, options: dict[str, Any] | None) -> dict[str, Any]:
        if options is None:
            return {}
        if not isinstance(options, dict):
            raise PriqnError(f"reset options: expected a dict, got {type(options).__name__}")
        unknown = sorted(set(options) - set(RESET_OPTIONS))
        if unknown:
            raise PriqnError(
                f"reset options: unknown key {unknown[0]!r} (valid: {', '.join(RESET_OPTIONS)})"
            )
        out = {k: v for k, v in options.items() if v is not None}
        if "net" in out:
            if not isinstance(out["net"], str):
                raise PriqnError(
                    f"reset options 'net': expected 'family/net_id', got {out['net']!r}"
                )
            self._net_file(out["net"])  # raises a one-line error for a missing net
        if "density" in out:
            check_density(out["density"], "reset options 'density'")
        if "command" in out and out["command"] not in COMMANDS:
            raise PriqnError(
                f"reset options 'command': expected one of {', '.join(COMMANDS)}, got {out['command']!r}"
            )
        return out

    def _check_action(self, action: Any) -> int:
        arr = np.asarray(action)
        ok = arr.size == 1 and (np.issubdtype(arr.dtype, np.integer) and arr.dtype != np.bool_)
        a = int(arr.reshape(())) if ok else -1
        if not ok or not 0 <= a < len(self._table):
            raise PriqnError(
                f"action {action!r}: expected an integer in [0, {len(self._table) - 1}] "
                f"({self.config.n_speeds} speeds x {self.config.n_offsets} offsets)"
            )
        return a

    # ------------------------------------------------------------------ episode set-up

    def _obstacle_sites(self, scene: _Scene, route: EgoRoute) -> list[ObstacleSite]:
        """Rightmost lane of every arm edge, away from the junction and ahead of the ego start."""
        sim, gap = self._session.sim, self.config.obstacle_clearance_m
        if scene.sites is None:
            incoming = {r[0] for r in scene.roadmap.npc_routes}
            outgoing = {r[-1] for r in scene.roadmap.npc_routes}
            sites = []
            for edge in sorted(incoming | outgoing):
                lane = f"{edge}_0"
                length = sim.lane.getLength(lane)
                lo, hi = (5.0, length - gap) if edge in incoming else (gap, length - 5.0)
                if hi - lo > 10.0:
                    sites.append(ObstacleSite(lane, edge, 0, lo, hi, sim.lane.getWidth(lane)))
            scene.sites = sites
        out = []
        for site in scene.sites:
            if site.edge_id == route.edges[0]:
                lo = max(site.s_min_m, route.start_pos_m + gap)
                if site.s_max_m - lo <= 10.0:
                    continue
                site = dataclasses.replace(site, s_min_m=lo)
            out.append(site)
        return out

    def _setup_episode(
        self, scene: _Scene, route: EgoRoute, density: float, v0: float, trng: np.random.Generator
    ) -> Traffic:
        """Ego, obstacles and traffic into the freshly loaded simulation; returns the traffic."""
        import libsumo

        cfg, sim = self.config, self._session.sim
        spec = scene.traffic
        traffic = Traffic(sim, spec, scene.roadmap.npc_routes, density, trng)
        traffic.setup()
        sim.vehicletype.copy("DEFAULT_VEHTYPE", EGO_TYPE)
        sim.vehicletype.setLength(EGO_TYPE, cfg.ego_length_m)
        sim.vehicletype.setWidth(EGO_TYPE, cfg.ego_width_m)
        sim.vehicletype.setColor(EGO_TYPE, (40, 120, 255, 255))
        sim.route.add("priqn_ego_route", list(route.edges))
        lane_index = int(route.start_lane_id.rsplit("_", 1)[1])
        sim.vehicle.add(
            EGO_ID,
            "priqn_ego_route",
            typeID=EGO_TYPE,
            departLane=str(lane_index),
            departPos=f"{route.start_pos_m:.3f}",
            departSpeed=f"{v0:.3f}",
        )
        sim.vehicle.setSpeedMode(EGO_ID, 0)
        sim.vehicle.setLaneChangeMode(EGO_ID, 0)
        lo, hi = cfg.obstacles_per_episode or spec.obstacles_per_episode
        n_obstacles = int(trng.integers(lo, hi + 1))
        sim.simulationStep()  # inserts the ego (obstacles are moved into place after insertion)
        traffic.place_obstacles(self._obstacle_sites(scene, route), n_obstacles)
        traffic.populate(avoid=(route.edges[0], route.start_pos_m - 40.0, route.start_pos_m + 15.0))
        sim.vehicle.subscribeContext(
            EGO_ID,
            libsumo.CMD_GET_VEHICLE_VARIABLE,
            cfg.sensor_query_range_m,
            [
                libsumo.VAR_POSITION,
                libsumo.VAR_ANGLE,
                libsumo.VAR_SPEED,
                libsumo.VAR_LENGTH,
                libsumo.VAR_WIDTH,
            ],
        )
        return traffic

    # ------------------------------------------------------------------ per step

    def _plan(self, v_f: float, d_f: float) -> planner.Trajectory:
        ep = self._episode
        return planner.plan(ep.ref, ep.state, v_f, d_f, self._planner_cfg)

    def _execute(self, traj: planner.Trajectory) -> dict[str, Any]:
        """Drive the first decision interval of ``traj`` in SUMO, testing after every step.

        Collision (oriented boxes, after a bounding-circle broad phase) and off-road are
        tested after every SUMO step so the episode ends at the step they happen; the
        risk measure (time to conflict) is computed once for all steps, vectorised.
        """
        cfg, ep = self.config, self._episode
        sim, traffic, route = ep.sim, ep.traffic, ep.route
        flags = ep.flags
        n = cfg.substeps
        x, y, head = traj.x[1 : n + 1], traj.y[1 : n + 1], traj.heading_rad[1 : n + 1]
        front, angles = geometry.sumo_from_center(np.stack([x, y], axis=1), head, cfg.ego_length_m)
        ego_radius = 0.5 * math.hypot(cfg.ego_length_m, cfg.ego_width_m)
        # The ego follows the plan exactly, so off-road and goal steps are known before
        # SUMO runs: test all sub-step poses at once.
        off_road = _off_road_steps(ep.scene.raster, x, y, head, cfg.ego_length_m, cfg.ego_width_m)
        at_goal = traj.s[1 : n + 1] >= route.goal_s_m
        ends = np.flatnonzero(off_road | at_goal)
        last = int(ends[0]) + 1 if len(ends) else n
        ego_l, ego_w = np.array([cfg.ego_length_m]), np.array([cfg.ego_width_m])
        ego_h = np.array([EGO_HEIGHT_M])
        per_step = []
        done_at = last
        for k in range(last):
            sim.vehicle.moveToXY(
                EGO_ID, "", -1, float(front[k, 0]), float(front[k, 1]), float(angles[k]), 3
            )
            sim.simulationStep()
            traffic.record_step(
                sim.simulation.getDepartedIDList(), sim.simulation.getArrivedIDList()
            )
            actors = self._read_actors()
            per_step.append(actors)
            others = actors["boxes"]
            if len(others):
                dist = np.hypot(others.center_xy[:, 0] - x[k], others.center_xy[:, 1] - y[k])
                near = np.flatnonzero(dist < ego_radius + actors["radius"])
                if len(near):
                    ego = geometry.Boxes(
                        np.array([[x[k], y[k]]]), head[k : k + 1], ego_l, ego_w, ego_h
                    )
                    if geometry.obb_overlap(ego, others[near]).any():
                        flags["collision"] = True
                        done_at = k + 1
                        break
        k_end = done_at - 1
        if off_road[k_end]:
            flags["off_road"] = True
        elif at_goal[k_end] and not flags["collision"]:
            flags["success"] = True
        ep.actors = per_step[-1]
        ep.pose = (float(x[done_at - 1]), float(y[done_at - 1]), float(head[done_at - 1]))
        s_before = ep.state.s
        ep.state = traj.state_at(done_at * cfg.sim_step_s)
        j = done_at
        # v_lat is the lateral speed relative to the lane centre (Frenet ḋ): the ego does
        # not slip, so its body-frame lateral speed would always be 0.
        kin = [traj.speed_mps[j], traj.d_dot[j], traj.accel_lon_mps2[j], traj.accel_lat_mps2[j]]
        ep.kin = np.clip(np.array(kin, np.float32), -KIN_LIMIT, KIN_LIMIT)
        if not (flags["collision"] or flags["off_road"] or flags["success"]):
            traffic.top_up()
            traffic.update_offsets()
        sl = slice(1, done_at + 1)
        ego_path = measures.EgoPath(
            traj.x, traj.y, traj.heading_rad, traj.speed_mps, cfg.sim_step_s,
            cfg.ego_length_m, cfg.ego_width_m,
        )  # fmt: skip
        actors = [measures.Actors(a["boxes"], a["speed"]) for a in per_step]
        conflict = measures.conflict_times_s(
            ego_path, np.arange(1, done_at + 1), actors, self._envelope
        )
        ref_heading = ep.ref.heading_at(traj.s[sl])
        return {
            "conflict_time": conflict,
            "lat_offset": traj.d[sl],
            "heading_err": np.angle(np.exp(1j * (traj.heading_rad[sl] - ref_heading))),
            "advance": float(ep.state.s - s_before),
            "speed": traj.speed_mps[sl],
            "jerk": traj.jerk_lon_mps3[sl],
            "lat_acc": traj.accel_lat_mps2[sl],
        }

    def _read_actors(self) -> dict[str, Any]:
        """Vehicles within ``sensor_query_range_m`` of the ego (NPCs and obstacles).

        One context-subscription read per step (SUMO reports front bumpers and compass
        angles; converted here to centre-based :class:`~priqn.env.geometry.Boxes`),
        plus bounding radii [m] and speeds [m/s].
        """
        import libsumo

        res = self._episode.sim.vehicle.getContextSubscriptionResults(EGO_ID)
        pos, ang, spd = libsumo.VAR_POSITION, libsumo.VAR_ANGLE, libsumo.VAR_SPEED
        length, width = libsumo.VAR_LENGTH, libsumo.VAR_WIDTH
        rows = [
            (*d[pos], d[ang], d[spd], d[length], d[width]) for v, d in res.items() if v != EGO_ID
        ]
        if not rows:
            return {"boxes": geometry.Boxes.empty(), "radius": np.zeros(0), "speed": np.zeros(0)}
        vals = np.array(rows)
        heading = np.radians(90.0 - vals[:, 2])
        cos_h, sin_h = np.cos(heading), np.sin(heading)
        half = 0.5 * vals[:, 4]
        centre = np.stack([vals[:, 0] - half * cos_h, vals[:, 1] - half * sin_h], axis=1)
        height = np.full(len(rows), NPC_HEIGHT_M)
        boxes = geometry.Boxes(centre, heading, vals[:, 4], vals[:, 5], height)
        return {
            "boxes": boxes,
            "radius": 0.5 * np.hypot(vals[:, 4], vals[:, 5]),
            "speed": vals[:, 3],
        }

    def _observe(self) -> dict[str, np.ndarray]:
        cfg, ep = self.config, self._episode
        x, y, h = ep.pose
        ego = geometry.Boxes.make((x, y), h, cfg.ego_length_m, cfg.ego_width_m, EGO_HEIGHT_M)
        actors = ep.actors
        bev, lidar = self._sensors.observe(ep.raster, ego, actors["boxes"], actors["speed"])
        command = np.zeros(len(COMMANDS), np.float32)
        command[COMMANDS.index(ep.command)] = 1.0
        obs = {"bev": bev, "lidar": lidar, "command": command, "kinematics": ep.kin.copy()}
        self._last_obs = obs
        return obs

    def _info(self) -> dict[str, Any]:
        ep = self._episode
        route, flags = ep.route, ep.flags
        span = max(route.goal_s_m - route.start_s_m, 1e-6)
        return {
            "reward_names": OBJECTIVES,
            "success": flags["success"],
            "collision": flags["collision"],
            "off_road": flags["off_road"],
            "timeout": flags["timeout"],
            "route_progress": float(np.clip((ep.state.s - route.start_s_m) / span, 0.0, 1.0)),
            "density_requested": float(ep.density),
            "density_realised": float(ep.traffic.density_realised),
            "net": ep.net,
            "command": ep.command,
            "route": route.name,
            "obstacles": len(ep.traffic.obstacles),
            "returns": ep.returns.copy(),
            "episode_steps": int(ep.steps),
        }


def _off_road_steps(
    raster: geometry.MapRaster,
    x: np.ndarray,
    y: np.ndarray,
    heading: np.ndarray,
    length: float,
    width: float,
) -> np.ndarray:
    """bool [T]: is the ego footprint off the road at each pose?

    Same test as :func:`priqn.env.geometry.is_off_road` (corners and edge midpoints,
    any point off the drivable area), vectorised over the T poses of one decision.
    """
    t = len(x)
    corners = geometry.boxes_corners(
        np.stack([x, y], axis=1), heading, np.full(t, length), np.full(t, width)
    )
    mids = 0.5 * (corners + np.roll(corners, -1, axis=1))
    points = np.concatenate([corners, mids], axis=1)  # [T, 8, 2]
    return ~raster.drivable(points).all(axis=1)


def _sumo_errors() -> tuple[type[BaseException], ...]:
    import libsumo

    return (libsumo.TraCIException, libsumo.FatalTraCIError)


def _traffic_spec(roadmap: RoadMap) -> TrafficSpec:
    """The family's TrafficSpec from the manifest beside the net (defaults if it has none)."""
    manifest = roadmap.net_path.parent / "manifest.json"
    try:
        data = json.loads(manifest.read_text(encoding="utf-8")).get("traffic")
    except (OSError, ValueError):
        data = None
    if not data:
        return TrafficSpec()
    return from_dict(TrafficSpec, data, where=f"{manifest} [traffic]")
