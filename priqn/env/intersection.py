"""``IntersectionEnv``: the ego crosses an unsignalised SUMO junction among traffic.

One decision every ``decision_interval_s`` (0.5 s): the action picks a target speed
``v_f`` at the end of the planning horizon and a lateral offset ``d_f`` from the lane
centre; a Frenet planner plans from the ego's current state (speed and lateral
position stay continuous); the ego follows the plan with ``moveToXY`` for
``decision_interval_s / sim_step_s`` SUMO steps. Our own oriented-box collision
test and footprint-on-road test, at every SUMO step, decide the episode's end. The
reward is a ``float32 [N]`` vector over the declared objectives (``EnvConfig.objectives``,
default :data:`priqn.objectives.OBJECTIVES`), in that order.

``step()`` reads plan → simulate → measures → rewards → observation; the concepts
live in their own modules: the pool of nets and what is cached per net
(:mod:`priqn.env.scenes`), the typed ego and actor reads (:mod:`priqn.env.reads`),
the pure measures — off-road, first collision, risk (:mod:`priqn.env.measures`) —
the reward terms (:mod:`priqn.env.rewards`), the sensors, the planner and the
traffic, the episode's state (:mod:`priqn.env.episode`). This module sets episodes up in
SUMO and drives the ego: one loop of SUMO steps, in which the planner's plan or SUMO
itself moves the ego (``EnvConfig.ego_driver``).

All randomness of an episode flows from ``reset(seed=...)``: the net, the requested
density, the command and route, the traffic (vehicle sizes, speed factors, offsets,
obstacles) and SUMO's own ``--seed`` are drawn from the env's generator. See
``docs/environment.md`` for every definition (rewards with units and ranges,
termination, realised density).
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
from collections.abc import Iterator, Mapping
from types import ModuleType
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from priqn.checks import check_density
from priqn.env import forensics, geometry, handback, measures, planner, reads, sensors
from priqn.env.config import EnvConfig
from priqn.env.episode import DecisionPlan, Episode, Measures, SumoSteps
from priqn.env.objective_terms import DecisionContext, EnvObjectives
from priqn.env.reads import KIN_LIMIT, Actors, EgoState
from priqn.env.scenes import FAMILIES, Scene, ScenePool
from priqn.env.traffic import NPC_PREFIX, Traffic
from priqn.errors import PriqnError
from priqn.sim.geometry import wrap_rad
from priqn.sim.roadmap import COMMANDS, EgoRoute
from priqn.sim.session import SumoSession

__all__ = ["FAMILIES", "KIN_LIMIT", "IntersectionEnv"]

EGO_ID = "ego"
"""SUMO vehicle id of the ego."""
EGO_TYPE = "priqn_ego"
"""SUMO vehicle type of the ego."""
RESET_OPTIONS = ("net", "density", "command")
"""Keys ``reset(options=...)`` accepts."""
EGO_HEIGHT_M = 1.5
"""Ego height [m] (LiDAR)."""


class _PlanFollower:
    """The planner's ego (``ego_driver = "planner"``): before SUMO step k it is moved with
    ``moveToXY`` (front bumper, SUMO angle) to plan sample k + 1, where it then stands. It
    runs all ``plan.steps`` steps: the plan is already cut at its first off-road or goal step.
    """

    def __init__(self, plan: DecisionPlan, length_m: float) -> None:
        self.plan, self.steps = plan, plan.steps
        traj, sl = plan.traj, slice(1, plan.steps + 1)
        self._front, self._angles = geometry.sumo_from_center(
            np.stack([traj.x[sl], traj.y[sl]], axis=1), traj.heading_rad[sl], length_m
        )

    def pose_before(self, k: int) -> tuple[tuple[float, float], float]:
        """The ego's centre and heading before SUMO step k: plan sample k."""
        traj = self.plan.traj
        return (float(traj.x[k]), float(traj.y[k])), float(traj.heading_rad[k])

    def move(self, sim: ModuleType, k: int) -> None:
        front, angles = self._front, self._angles
        sim.vehicle.moveToXY(
            EGO_ID, "", -1, float(front[k, 0]), float(front[k, 1]), float(angles[k]), 3
        )

    def pose_after(self, sim: ModuleType, k: int, arrived: tuple[str, ...]) -> handback.Pose:
        """Plan sample k + 1 (where ``moveToXY`` put the ego)."""
        traj, j = self.plan.traj, k + 1
        return handback.Pose(
            float(traj.x[j]), float(traj.y[j]), float(traj.heading_rad[j]),
            float(traj.speed_mps[j]), float(traj.accel_lon_mps2[j]),
        )  # fmt: skip

    def done(self) -> bool:
        """Never early: the plan ends at its first event."""
        return False

    def decision_plan(self) -> DecisionPlan:
        return self.plan


class _SumoDriver:
    """SUMO drives the ego (``ego_driver = "sumo"``); its pose is read after each step.

    Stops after the first step that reaches the goal or leaves the road (as a plan is cut
    there), or when the ego has finished its route (counted as reaching the goal). What
    happened becomes a :class:`DecisionPlan` (:func:`priqn.env.handback.driven_trajectory`),
    measured exactly as a planned decision.
    """

    def __init__(self, ep: Episode, cfg: EnvConfig) -> None:
        self.ep, self.cfg, self.steps = ep, cfg, cfg.substeps
        s0 = ep.ego.frenet.s
        self._window = (s0 - handback.S_WINDOW_M[0], s0 + handback.S_WINDOW_M[1])
        self.poses: list[handback.Pose] = []
        self.off_road: list[bool] = []
        self.at_goal: list[bool] = []

    def pose_before(self, k: int) -> tuple[tuple[float, float], float]:
        """The ego's centre and heading before the step: last read, or the decision's start."""
        e = self.poses[-1] if self.poses else self.ep.ego
        return (e.x_m, e.y_m), e.heading_rad

    def move(self, sim: ModuleType, k: int) -> None:
        pass  # SUMO's own models move it

    def pose_after(self, sim: ModuleType, k: int, arrived: tuple[str, ...]) -> handback.Pose | None:
        """The pose SUMO reports, with its off-road and goal tests; None if the ego arrived."""
        cfg, ep = self.cfg, self.ep
        if EGO_ID in arrived:  # the end of its route: past the goal, where it stopped
            e = ep.ego
            self.poses.append(
                self.poses[-1] if self.poses else handback.Pose(e.x_m, e.y_m, e.heading_rad, 0, 0)
            )
            self.off_road.append(False)
            self.at_goal.append(True)
            return None
        pose = handback.read_pose(sim, EGO_ID, cfg.ego_length_m)
        self.poses.append(pose)
        x, y, h = np.array([pose.x_m]), np.array([pose.y_m]), np.array([pose.heading_rad])
        off = measures.off_road_steps(ep.raster, x, y, h, cfg.ego_length_m, cfg.ego_width_m)
        s, _ = ep.ref.to_frenet(np.stack([x, y], axis=1), self._window)
        self.off_road.append(bool(off[0]))
        self.at_goal.append(bool(s[0] >= ep.route.goal_s_m))
        return pose

    def done(self) -> bool:
        """The ego left the road or reached its goal in the last step."""
        return self.off_road[-1] or self.at_goal[-1]

    def decision_plan(self) -> DecisionPlan:
        """The steps run as a plan, continued at the last speed for the risk look-ahead."""
        cfg, ep = self.cfg, self.ep
        n_look = measures.look_ahead_samples(cfg.reward.conflict_time_safe_s, cfg.sim_step_s)
        traj = handback.driven_trajectory(ep.ref, ep.ego, self.poses, cfg.sim_step_s, n_look + 1)
        return DecisionPlan(traj, np.array(self.off_road), np.array(self.at_goal), len(self.poses))


class IntersectionEnv(gymnasium.Env):
    """Gymnasium env ``priqn/Intersection-v0`` (see module docstring and docs/environment.md)."""

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 2}

    # long: builds the env's parts in dependency order (config, action table, objectives and
    # reward space, sensors and observation space, risk envelope, planner, scenes, the
    # simulator backend), a few lines each; the order is the documentation.
    def __init__(
        self,
        config: EnvConfig | Mapping[str, Any] | None = None,
        render_mode: str | None = None,
        seed: int | None = None,
        *,
        gui: Any = None,
        **overrides: Any,
    ) -> None:
        """``config``: an :class:`EnvConfig`, a dict of its fields (nested ``reward``
        too), or None; keyword ``overrides`` replace fields on top, e.g.
        ``gymnasium.make("priqn/Intersection-v0", family="fourway", obs_size_px=64)``.
        ``seed`` fixes the first ``reset()`` without a seed (the vector env passes one per
        worker); without it a fresh env draws fresh entropy, as gymnasium's envs do.
        ``render_mode="human"`` runs the episode in SUMO's own GUI through TraCI instead of
        libsumo (:mod:`priqn.sim.gui`; the same episode, docs/play.md); ``gui`` is then a
        :class:`priqn.sim.gui.GuiOptions` or a dict of its fields (delay, window, zoom)."""
        self.config = cfg = make_config(config, overrides)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise PriqnError(
                f"render_mode: expected 'rgb_array', 'human' or None, got {render_mode!r}"
            )
        self.render_mode = render_mode
        self._default_seed = None if seed is None else int(seed)
        self._seeded = False

        self._table = action_grid(cfg)
        self.action_space = spaces.Discrete(len(self._table))
        self.objectives = EnvObjectives(cfg.objectives, cfg.reward)
        """The declared objectives, resolved (names, bounds, reward vector)."""
        # Per-decision bounds of the reward vector (declared order; docs/environment.md),
        # for multi-objective libraries (MO-Gymnasium reads env.unwrapped.reward_space).
        self.reward_space = spaces.Box(
            low=self.objectives.low, high=self.objectives.high, dtype=np.float32
        )

        self._sensors = sensors.Sensors(cfg.sensor_config())
        self._render_sensors = self._sensors
        if render_mode == "rgb_array" and cfg.render_size_px not in (0, cfg.obs_size_px):
            self._render_sensors = sensors.Sensors(
                dataclasses.replace(cfg.sensor_config(), size_px=cfg.render_size_px)
            )
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
        self._scenes = ScenePool(
            cfg.family,
            cfg.nets_dir,
            marking_width_m=max(0.5, self._sensors.cfg.metres_per_px),
            nets=cfg.nets,
            junction=cfg.junction,
        )
        self._session: Any = SumoSession(cfg.sim_step_s, cfg.lateral_resolution_m)
        self.gui: Any = None
        """``render_mode="human"``: the :class:`priqn.sim.gui.GuiView` of sumo-gui (else None)."""
        if render_mode == "human":
            self.gui = _gui_view(cfg, gui)
            self._session = self.gui.session
        self._episode: Episode | None = None
        self._last_obs: dict[str, np.ndarray] | None = None
        self._record: dict[str, Any] | None = None
        """How the running episode came about: :meth:`episode_record`."""
        self.pending_episode: dict[str, Any] | None = None
        """A record for :meth:`restore_pending_episode` to play (vector envs set it)."""

    # ------------------------------------------------------------------ public

    def action_table(self) -> np.ndarray:
        """``float64 [A, 2]``: ``(v_f [m/s], d_f [m])`` of every action index."""
        return self._table.copy()

    def preload_nets(self) -> int:
        """Parse every net of the pool now (road map, raster, SUMO check, every route drawn)
        and make one observation of the first route's start with no actors, so that the
        sensors' compiled loops are loaded (or compiled) too; returns how many nets.

        Otherwise each net is parsed at its first reset (~0.1-0.3 s) and the loops load at
        the first observation; training and evaluation call this in every worker before
        their first reset (``venv.call("preload_nets")``). It draws no random number and
        leaves no episode, so what follows is the same as without it.
        """
        count = self._scenes.preload()
        scene = self._scenes.scene(self._scenes.refs[0])
        route = scene.roadmap.ego_routes[0]
        ref = scene.references[route.name]
        ego = EgoState.start(ref, route.start_s_m, 0.0)
        box = ego.box(self.config.ego_length_m, self.config.ego_width_m, EGO_HEIGHT_M)
        empty = Actors.empty()
        self._sensors.observe(scene.route_raster(route), box, empty.boxes, empty.speed_mps)
        return count

    @property
    def net_pool(self) -> tuple[str, ...]:
        """The nets ``reset`` draws from, as ``"family/net_id"``."""
        return self._scenes.refs

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        if seed is None and not self._seeded:
            seed = self._default_seed
        super().reset(seed=seed)
        self._seeded = True
        return self._begin_episode(options)

    def episode_record(self) -> dict[str, Any] | None:
        """The running episode as plain data: the generator state its reset drew from, its
        reset options and every action since (None before the first reset). With
        :meth:`restore_episode` it restores the episode at the very decision: a training
        checkpoint keeps one per worker, so a resumed run goes on as if never stopped."""
        if self._record is None:
            return None
        return {
            "rng": copy.deepcopy(self._record["rng"]),
            "options": dict(self._record["options"]),
            "actions": list(self._record["actions"]),
        }

    def restore_episode(self, record: Mapping[str, Any]) -> dict[str, np.ndarray]:
        """Play the episode of an :meth:`episode_record` again, from its reset through its
        actions, and return the observation it stands at; the env then goes on exactly as
        the one that made the record (SUMO and the env are deterministic per seed)."""
        self._seeded = True
        self.np_random = np.random.Generator(np.random.PCG64())
        self.np_random.bit_generator.state = copy.deepcopy(record["rng"])
        obs, _ = self._begin_episode(dict(record["options"]) or None)
        for action in record["actions"]:
            obs, *_ = self.step(int(action))
        return obs

    def restore_pending_episode(self) -> dict[str, np.ndarray]:
        """:meth:`restore_episode` of the record in ``self.pending_episode`` (set per worker
        by :func:`priqn.env.vector.restore_episodes`, since a vector env's ``call`` gives
        every worker the same arguments)."""
        record, self.pending_episode = self.pending_episode, None
        return self.restore_episode(record)

    def _begin_episode(
        self, options: dict[str, Any] | None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """The part of :meth:`reset` after seeding: every draw from ``self.np_random``."""
        self._episode = None
        cfg, rng = self.config, self.np_random
        opts = self._check_options(options)
        self._record = {
            "rng": copy.deepcopy(rng.bit_generator.state),
            "options": dict(options or {}),
            "actions": [],
        }

        # Draws in a fixed order so a seed fixes the episode.
        pool = self._scenes.refs
        net_draw = pool[int(rng.integers(len(pool)))]
        density_draw = float(cfg.densities[int(rng.integers(len(cfg.densities)))])
        command_u = float(rng.random())
        route_u = float(rng.random())
        v0 = float(rng.uniform(*cfg.ego_start_speed_mps))
        sumo_seed = int(rng.integers(0, 2**31 - 1))
        traffic_seed = int(rng.integers(0, 2**63 - 1))

        net = opts.get("net", net_draw)
        density = (
            check_density(opts["density"], "reset options 'density'")
            if "density" in opts
            else density_draw
        )
        scene = self._scenes.scene(net)
        route = self._pick_route(scene, opts.get("command"), command_u, route_u)

        self._session.start(scene.roadmap.net_path, sumo_seed)
        try:
            traffic = self._setup_episode(
                scene, route, density, v0, np.random.default_rng(traffic_seed)
            )
            raw = reads.read_actors(self._session.sim, EGO_ID)
            actors = reads.decode_actors([raw], EGO_ID).at(0)
            if self.gui is not None:
                self.gui.on_reset()
        except _sumo_errors() as exc:
            raise PriqnError(f"{net}: SUMO failed while setting up the episode: {exc}") from exc

        ref = scene.references[route.name]
        self._episode = Episode(
            scene=scene,
            route=route,
            ref=ref,
            command=route.command,
            density=density,
            traffic=traffic,
            raster=scene.route_raster(route),
            target_speed_mps=min(cfg.reward.target_speed_mps, route.speed_limit_mps),
            ego=EgoState.start(ref, route.start_s_m, v0),
            actors=actors,
            returns=np.zeros(len(self.objectives), np.float32),
        )
        return self._observe(), self._info()

    def step(
        self, action: Any
    ) -> tuple[dict[str, np.ndarray], np.ndarray, bool, bool, dict[str, Any]]:
        ep = self._running_episode()
        action = self._check_action(action)
        self._record["actions"].append(action)
        if self.config.ego_driver == "sumo":  # SUMO drives; what it did is measured as a plan
            driver: _PlanFollower | _SumoDriver = _SumoDriver(ep, self.config)
        else:
            driver = _PlanFollower(self._plan(ep, action), self.config.ego_length_m)
        with self._sumo_failure(ep):
            if self.gui is not None and isinstance(driver, _PlanFollower):
                self._show_plan(driver.plan, action)
            sim = self._sumo_steps(ep, driver)
        plan = driver.decision_plan()
        m = self._measure(ep, plan, sim)
        with self._sumo_failure(ep):
            self._advance(ep, sim, m)
        reward = self._reward(ep, plan, sim, m)
        ep.returns += reward
        return self._observe(), reward, ep.outcome.terminated, ep.outcome.timeout, self._info()

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._last_obs is None:
            raise PriqnError("render() before reset(): call env.reset() first")
        if self._render_sensors is self._sensors or self._episode is None:
            return self._sensors.render_rgb(self._last_obs["bev"], self._last_obs["lidar"])
        bev, lidar = self._sense(self._render_sensors)
        return self._render_sensors.render_rgb(bev, lidar)

    def close(self) -> None:
        self._session.close()
        self._episode = None

    def _show_plan(self, plan: DecisionPlan, action: int) -> None:
        """``render_mode="human"``: draw the decision's plan and chosen action in sumo-gui."""
        v_f, d_f = self._table[action]
        xy = np.stack([plan.traj.x, plan.traj.y], axis=1)
        self.gui.show_plan(xy, f"a={action}: v_f {v_f:.1f} m/s, d_f {d_f:+.2f} m")

    # ------------------------------------------------------------------ validation

    @contextlib.contextmanager
    def _sumo_failure(self, ep: Episode) -> Iterator[None]:
        """Turn a libsumo error inside the block into one line naming the net and decision."""
        try:
            yield
        except _sumo_errors() as exc:
            ep.done = True
            self._session.close_after_failure()  # the next reset starts SUMO afresh
            raise PriqnError(
                f"{ep.net}: SUMO failed at decision {ep.steps} ({type(exc).__name__}: {exc})"
            ) from exc

    def _running_episode(self) -> Episode:
        ep = self._episode
        if ep is None:
            raise PriqnError("step() before reset(): call env.reset() first")
        if ep.done:
            raise PriqnError("step() after the episode ended: call env.reset() first")
        if not self._session.is_open:
            raise PriqnError(
                "this env's SUMO simulation was taken over by another env in this process "
                "(libsumo runs one per process): reset() this env, or for several envs use "
                "gymnasium.make_vec('priqn/Intersection-v0', num_envs=N) (worker processes; "
                "not vectorization_mode='sync')"
            )
        return ep

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
            self._scenes.net_file(out["net"])  # raises a one-line error for a missing net
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

    def _pick_route(
        self, scene: Scene, command: str | None, command_u: float, route_u: float
    ) -> EgoRoute:
        """The episode's route: for ``command`` (or one drawn by ``command_u``), then by ``route_u``."""
        roadmap, cfg = scene.roadmap, self.config
        if command is not None:
            if not roadmap.routes_for(command):
                raise PriqnError(
                    f"reset options 'command': net {scene.net} has no {command!r} route "
                    f"(it offers: {', '.join(roadmap.commands())})"
                )
        else:
            offered = [c for c in cfg.commands if roadmap.routes_for(c)]
            if not offered:
                raise PriqnError(
                    f"net {scene.net}: none of the configured commands {cfg.commands} is possible here"
                )
            command = offered[min(int(command_u * len(offered)), len(offered) - 1)]
        routes = roadmap.routes_for(command)
        return routes[min(int(route_u * len(routes)), len(routes) - 1)]

    def _setup_episode(
        self, scene: Scene, route: EgoRoute, density: float, v0: float, trng: np.random.Generator
    ) -> Traffic:
        """Ego, obstacles and traffic into the freshly loaded simulation; returns the traffic."""
        cfg, sim = self.config, self._session.sim
        spec = scene.traffic
        traffic = Traffic(
            sim, spec, scene.roadmap.npc_routes, density, trng, cfg.traffic, ego_id=EGO_ID,
            paths=scene.npc_paths if cfg.traffic.path_braking is not None else None,
            step_s=cfg.sim_step_s,
        )  # fmt: skip
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
        if cfg.ego_driver == "planner":  # the planner moves it; SUMO's driver keeps its modes
            sim.vehicle.setSpeedMode(EGO_ID, 0)
            sim.vehicle.setLaneChangeMode(EGO_ID, 0)
        lo, hi = cfg.obstacles_per_episode or spec.obstacles_per_episode
        n_obstacles = int(trng.integers(lo, hi + 1))
        sim.simulationStep()  # inserts the ego (obstacles are moved into place after insertion)
        traffic.place_obstacles(scene.obstacle_sites(route, cfg.obstacle_clearance_m), n_obstacles)
        traffic.populate(avoid=(route.edges[0], route.start_pos_m - 40.0, route.start_pos_m + 15.0))
        reads.subscribe_actors(sim, EGO_ID, cfg.sensor_query_range_m)
        return traffic

    # ------------------------------------------------------------------ per step

    def _plan(self, ep: Episode, action: int) -> DecisionPlan:
        """Plan from the ego's state; the ego follows the plan exactly, so the steps at which
        it leaves the road or reaches its goal are known before SUMO runs."""
        cfg, n = self.config, self.config.substeps
        v_f, d_f = (float(v) for v in self._table[action])
        traj = planner.plan(ep.ref, ep.ego.frenet, v_f, d_f, self._planner_cfg)
        sl = slice(1, n + 1)
        off_road = measures.off_road_steps(
            ep.raster, traj.x[sl], traj.y[sl], traj.heading_rad[sl], cfg.ego_length_m,
            cfg.ego_width_m,
        )  # fmt: skip
        at_goal = traj.s[sl] >= ep.route.goal_s_m
        events = np.flatnonzero(off_road | at_goal)
        return DecisionPlan(traj, off_road, at_goal, int(events[0]) + 1 if len(events) else n)

    def _sumo_steps(self, ep: Episode, driver: _PlanFollower | _SumoDriver) -> SumoSteps:
        """Run the decision's SUMO steps; ``driver`` moves the ego (or lets SUMO move it).

        Per step: the path-braking check with the ego where it stands, the driver's move,
        one ``simulationStep``, the departed and arrived lists, the ego's pose after the step,
        one bulk actor read and its forensics record; then the driver may stop early.
        """
        cfg, sim = self.config, self._session.sim
        raw, departed, arrived = [], [], []
        stage = ep.traffic.path_braking
        for k in range(driver.steps):
            if stage is not None:  # NPCs see the ego where it stands before this step
                xy, heading_rad = driver.pose_before(k)
                stage.check(
                    raw[-1] if raw else reads.read_actors(sim, EGO_ID), xy, heading_rad,
                    cfg.ego_length_m, cfg.ego_width_m,
                )  # fmt: skip
            driver.move(sim, k)
            sim.simulationStep()
            departed.append(sim.simulation.getDepartedIDList())
            arrived.append(sim.simulation.getArrivedIDList())
            pose = driver.pose_after(sim, k, arrived[-1])
            if pose is None:  # the ego finished its route and left SUMO: nothing to read
                raw.append({})
                break
            raw.append(reads.read_actors(sim, EGO_ID))
            ep.history.append(
                forensics.Step((pose.x_m, pose.y_m), pose.heading_rad, pose.speed_mps, raw[-1])
            )
            if driver.done():
                break
        return SumoSteps(reads.decode_actors(raw, EGO_ID), departed, arrived)

    def _measure(self, ep: Episode, plan: DecisionPlan, sim: SumoSteps) -> Measures:
        """Termination events and the reward inputs; the first collision ends the decision."""
        cfg, traj, n = self.config, plan.traj, plan.steps
        sl = slice(1, n + 1)
        ego = geometry.Boxes(
            np.stack([traj.x[sl], traj.y[sl]], axis=1), traj.heading_rad[sl],
            np.full(n, cfg.ego_length_m), np.full(n, cfg.ego_width_m), np.full(n, EGO_HEIGHT_M),
        )  # fmt: skip
        hit = measures.first_collision(ego, sim.seen)
        done_at = n if hit is None else hit + 1
        steps = np.arange(1, done_at + 1)  # plan samples of the executed SUMO steps
        off_road = bool(plan.off_road[done_at - 1])
        success = bool(plan.at_goal[done_at - 1]) and hit is None and not off_road
        ref_heading = ep.ref.heading_at(traj.s[steps])
        end = EgoState.from_plan(traj, done_at)
        return Measures(
            steps=done_at,
            collision=hit is not None,
            off_road=off_road,
            success=success,
            conflict_time_s=measures.conflict_times_s(
                measures.EgoPath.of(traj, cfg.ego_length_m, cfg.ego_width_m),
                steps,
                sim.seen.first(done_at),
                self._envelope,
            ),
            lateral_offset_m=traj.d[steps],
            heading_error_rad=wrap_rad(traj.heading_rad[steps] - ref_heading),
            end=end,
            advance_m=end.frenet.s - ep.ego.frenet.s,
            speed_mps=traj.speed_mps[steps],
            jerk_mps3=traj.jerk_lon_mps3[steps],
            lateral_accel_mps2=traj.accel_lat_mps2[steps],
        )

    def _advance(self, ep: Episode, sim: SumoSteps, m: Measures) -> None:
        """Move the episode to the end of the decision; top the traffic up if it goes on."""
        for k in range(m.steps):
            ep.traffic.record_step(sim.departed[k], sim.arrived[k])
        out = ep.outcome
        out.collision, out.off_road, out.success = m.collision, m.off_road, m.success
        if m.collision:  # the window ends at the colliding step
            end = len(ep.history) - sim.seen.n_steps + m.steps
            ep.forensics = forensics.classify(
                list(ep.history)[:end], self.config.ego_length_m, self.config.ego_width_m,
                NPC_PREFIX, ep.traffic.emergency_decel_mps2, self.config.sim_step_s, EGO_ID,
            )  # fmt: skip
        out.timeout = not out.terminated and ep.steps + 1 >= self.config.max_episode_steps
        if not out.terminated:
            ep.traffic.top_up()
            ep.traffic.update_offsets()
        ep.ego = m.end
        ep.actors = sim.seen.at(m.steps - 1)
        ep.steps += 1
        ep.done = out.terminated or out.timeout

    def _reward(self, ep: Episode, plan: DecisionPlan, sim: SumoSteps, m: Measures) -> np.ndarray:
        """The reward vector of the decision (``float32 [N]``, declared objectives' order)."""
        ctx = DecisionContext(
            config=self.config,
            measures=m,
            trajectory=plan.traj,
            steps=np.arange(1, m.steps + 1),
            actors=sim.seen.first(m.steps),
            route=ep.route,
            scene=ep.scene,
            target_speed_mps=ep.target_speed_mps,
        )
        return self.objectives.reward_vector(ctx)

    def _sense(self, sensor: sensors.Sensors) -> tuple[np.ndarray, np.ndarray]:
        """BEV and LiDAR grids of the current state from ``sensor`` (its resolution)."""
        cfg, ep = self.config, self._episode
        ego = ep.ego.box(cfg.ego_length_m, cfg.ego_width_m, EGO_HEIGHT_M)
        return sensor.observe(ep.raster, ego, ep.actors.boxes, ep.actors.speed_mps)

    def _observe(self) -> dict[str, np.ndarray]:
        ep = self._episode
        bev, lidar = self._sense(self._sensors)
        command = np.zeros(len(COMMANDS), np.float32)
        command[COMMANDS.index(ep.command)] = 1.0
        obs = {
            "bev": bev,
            "lidar": lidar,
            "command": command,
            "kinematics": ep.ego.kinematics.copy(),
        }
        self._last_obs = obs
        return obs

    def _info(self) -> dict[str, Any]:
        ep = self._episode
        route, out = ep.route, ep.outcome
        span = max(route.goal_s_m - route.start_s_m, 1e-6)
        progress = (ep.ego.frenet.s - route.start_s_m) / span
        return {
            "reward_names": self.objectives.names,
            "success": out.success,
            "collision": out.collision,
            "off_road": out.off_road,
            "timeout": out.timeout,
            "route_progress": float(min(max(progress, 0.0), 1.0)),
            "density_requested": float(ep.density),
            "density_realised": float(ep.traffic.density_realised),
            "net": ep.net,
            "command": ep.command,
            "route": route.name,
            "obstacles": len(ep.traffic.obstacles),
            "returns": ep.returns.copy(),
            "episode_steps": int(ep.steps),
            **ep.forensics,
        }


def action_grid(cfg: EnvConfig) -> np.ndarray:
    """``float64 [A, 2]``: ``(v_f [m/s], d_f [m])`` of every action index, speed-major
    (action ``i`` has target speed index ``i // n_offsets``)."""
    speeds = np.linspace(0.0, cfg.max_speed_mps, cfg.n_speeds)
    offsets = (
        np.linspace(-cfg.max_offset_m, cfg.max_offset_m, cfg.n_offsets)
        if cfg.n_offsets > 1
        else np.zeros(1)
    )
    return np.stack(np.meshgrid(speeds, offsets, indexing="ij"), axis=-1).reshape(-1, 2)


def make_config(
    config: EnvConfig | Mapping[str, Any] | None, overrides: Mapping[str, Any]
) -> EnvConfig:
    """An :class:`EnvConfig` from an EnvConfig, a dict of fields or None, plus overrides.

    Unknown or mistyped fields are one-line errors listing the valid keys.
    """
    from priqn.config import from_dict, to_dict

    if config is None:
        base: dict[str, Any] = {}
    elif isinstance(config, EnvConfig):
        if not overrides:
            return config
        base = to_dict(config)
    elif isinstance(config, Mapping):
        base = dict(config)
    else:
        raise PriqnError(
            f"config: expected an EnvConfig, a dict of its fields or None, got {type(config).__name__}"
        )
    merged = {**base, **overrides}
    try:
        return from_dict(EnvConfig, merged, "env config")
    except ValueError as exc:  # __post_init__ checks
        raise PriqnError(f"env config: {exc}") from None


def _gui_view(cfg: EnvConfig, options: Any) -> Any:
    """The sumo-gui session and its view for ``render_mode="human"``."""
    from priqn.config import from_dict
    from priqn.sim.gui import GuiOptions, GuiSession, GuiView

    if isinstance(options, Mapping):
        options = from_dict(GuiOptions, dict(options), "gui options")
    elif options is not None and not isinstance(options, GuiOptions):
        raise PriqnError(
            f"gui: expected GuiOptions, a dict of its fields or None, got {type(options).__name__}"
        )
    session = GuiSession(cfg.sim_step_s, cfg.lateral_resolution_m, options)
    return GuiView(session, EGO_ID)


def _sumo_errors() -> tuple[type[BaseException], ...]:
    import libsumo
    import traci.exceptions  # render_mode="human" runs SUMO through TraCI

    return (
        libsumo.TraCIException,
        libsumo.FatalTraCIError,
        traci.exceptions.TraCIException,
        traci.exceptions.FatalTraCIError,
    )
