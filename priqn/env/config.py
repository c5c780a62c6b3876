"""``EnvConfig``: the configuration of :class:`~priqn.env.intersection.IntersectionEnv`.

Its fields are what ``[env]`` in a ``config.toml`` (and ``--set env.<field>=...``) names, in
the order written there; :meth:`EnvConfig.__post_init__` checks every one of them, so a bad
value is a ``ValueError`` naming the field. See ``docs/environment.md`` for what each field
means and :func:`priqn.env.intersection.make_config` for building one from a dict.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

from priqn.checks import check_density
from priqn.config import NAMED_HINT
from priqn.env import rewards as R
from priqn.env import sensors
from priqn.env.scenes import FAMILIES, known_pools
from priqn.env.traffic import TrafficBehaviour
from priqn.errors import did_you_mean
from priqn.objectives import OBJECTIVES
from priqn.sim.roadmap import COMMANDS

EGO_DRIVERS = ("planner", "sumo")
"""Values of ``EnvConfig.ego_driver``."""


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Configuration of :class:`~priqn.env.intersection.IntersectionEnv` (units in names; see docs/environment.md)."""

    family: str = "tjunction"
    """Net pool: 'tjunction', 'fourway', 'all' (both training pools), 'holdout', or any other generated scenario family on its own (e.g. 'out-of-range', an evaluation family)."""
    nets_dir: str = ""
    """Folder holding ``<family>/manifest.json`` and the nets ('' = ./sumo_nets if it has the family, else the nets shipped with priqn)."""
    nets: str | os.PathLike | tuple[str, ...] = ()
    """Your own nets: ``.net.xml`` files and/or folders of them, no manifest needed (docs/your-own-net.md). When given, reset draws from these and ``family`` / ``nets_dir`` are not used. One path (also a bare string from ``--set env.nets=...``) or a list; stored as a tuple of strings."""
    junction: str = ""
    """With ``nets``: the id of the junction to drive through ('' = each net's junction with the most approaches)."""
    obs_size_px: int = 128
    """Side of the square BEV and LiDAR grids [px] (the paper uses 128)."""
    render_size_px: int = 0
    """Side of the grids ``render()`` draws [px] (0 = obs_size_px); the same area and
    scene, sampled at this resolution for people (the observation is unchanged)."""
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
    """Radius around the ego within which actors are read from SUMO each step [m]; > 0.
    Path braking (the ``tm`` traffic settings, :mod:`priqn.env.path_braking`) reads its NPCs
    from this same read: it looks up to ``traffic.path_braking.look_ahead_max_m`` (50 m) plus
    half the ego's diagonal, half an NPC's width and ``traffic.path_braking.margin_m``, about
    54 m, so a range below that silently shortens the ``tm`` NPCs' look-ahead too."""
    reward: R.RewardConfig = dataclasses.field(default_factory=R.RewardConfig)
    """Reward term parameters."""
    traffic: TrafficBehaviour = dataclasses.field(
        default_factory=TrafficBehaviour,
        metadata={NAMED_HINT: "to pick a named setting use --traffic {value}"},
    )
    """How the NPCs treat the ego: giving way at the junction, top-up, impatience (the
    defaults are SUMO's polite drivers; named settings: ``priqn train --traffic``)."""
    objectives: tuple[str, ...] = OBJECTIVES
    """The objectives, in reward-vector / head order: built-in names (safety, risk,
    lane_keeping, progress, comfort, right_of_way), ``package.module:NAME`` of your own
    :class:`priqn.objectives.Objective`, or entry points of group ``priqn.objectives``
    (docs/your-own-objective.md). Weighted-sum schemes read the order as priority."""
    ego_driver: str = "planner"
    """Who drives the ego: "planner" (the action, through the Frenet planner and
    ``moveToXY``) or "sumo" (the ego handed back to SUMO's own car-following, junction and
    lane-change models on its route; the action is ignored: the ``sumo`` reference driver,
    :mod:`priqn.env.handback`). Everything else (scenes, measures, rewards) is the same."""

    def __post_init__(self) -> None:
        """Normalise ``nets`` and ``objectives``; check every field (a bad one is a
        ``ValueError`` naming it, which :func:`priqn.config.from_dict` makes one line)."""
        self._check_names()
        self._check_observation()
        self._check_scenes()
        self._check_actions_and_time()

    def _check_names(self) -> None:
        """``nets`` as entries; objectives, the ego driver and the training pool by name."""
        object.__setattr__(self, "nets", _net_entries(self.nets))
        if isinstance(self.objectives, str) or not all(
            isinstance(o, str) and o for o in self.objectives
        ):
            raise ValueError(
                "objectives: expected a list of objective names or 'package.module:NAME' "
                f"entries, got {self.objectives!r}"
            )
        object.__setattr__(self, "objectives", tuple(self.objectives))
        if not self.objectives:
            raise ValueError("objectives: expected at least one objective")
        if self.ego_driver not in EGO_DRIVERS:
            raise ValueError(
                f"ego_driver: {self.ego_driver!r} is not one of {', '.join(EGO_DRIVERS)}"
            )
        if self.family not in FAMILIES:
            valid = known_pools(self.nets_dir)
            if self.family not in valid:
                raise ValueError(
                    f"family: unknown pool {self.family!r} (valid: {', '.join(valid)})"
                    + did_you_mean(self.family, valid)
                )

    def _check_observation(self) -> None:
        """Observation and render sizes, the range actors are read in, the BEV's range and
        channels."""
        if self.obs_size_px < 16:
            raise ValueError(f"obs_size_px: expected >= 16, got {self.obs_size_px}")
        if self.render_size_px and self.render_size_px < 16:
            raise ValueError(f"render_size_px: expected 0 or >= 16, got {self.render_size_px}")
        if not self.sensor_query_range_m > 0:
            raise ValueError(
                f"sensor_query_range_m: expected a radius > 0 m, got {self.sensor_query_range_m}"
            )
        if not self.bev_range_m > 0 or not 0 <= self.bev_behind_m <= self.bev_range_m:
            raise ValueError(
                f"bev_range_m / bev_behind_m: expected bev_range_m > 0 and 0 <= bev_behind_m "
                f"<= bev_range_m, got {self.bev_range_m} / {self.bev_behind_m}"
            )
        for c in self.bev_channels:
            if c not in sensors.BEV_CHANNELS:
                raise ValueError(
                    f"bev_channels: unknown channel {c!r} "
                    f"(valid: {', '.join(sensors.BEV_CHANNELS)})"
                    + did_you_mean(c, sensors.BEV_CHANNELS)
                )

    def _check_scenes(self) -> None:
        """The traffic densities and route commands episodes draw from."""
        if isinstance(self.densities, (str, bytes)) or not hasattr(self.densities, "__len__"):
            raise ValueError(
                f"densities: expected a list of numbers in (0, 1], got {self.densities!r}"
            )
        if not self.densities:
            raise ValueError("densities: expected at least one density in (0, 1]")
        for d in self.densities:
            check_density(d, "densities", error=ValueError)
        if not self.commands:
            raise ValueError("commands: expected at least one of left, straight, right")
        for c in self.commands:
            if c not in COMMANDS:
                raise ValueError(f"commands: unknown command {c!r} (valid: {', '.join(COMMANDS)})")

    def _check_actions_and_time(self) -> None:
        """The action grid, the simulation and decision steps, the planning horizon and
        the episode: its length, obstacles and the ego's start speed."""
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


def _net_entries(nets: Any) -> tuple[str, ...]:
    """``EnvConfig.nets`` as a tuple of strings (one path, or a list of paths / strings)."""
    if isinstance(nets, (str, os.PathLike)):
        nets = (nets,) if os.fspath(nets) else ()
    if not isinstance(nets, (list, tuple)) or not all(
        isinstance(n, (str, os.PathLike)) and os.fspath(n) for n in nets
    ):
        raise ValueError(
            f"nets: expected a .net.xml file, a folder of them, or a list of those; got {nets!r}"
        )
    return tuple(os.fspath(n) for n in nets)
