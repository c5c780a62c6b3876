"""The state of a running :class:`~priqn.env.intersection.IntersectionEnv` episode and what
one decision produces: its plan, its SUMO steps and its measures.

Plain dataclasses, no SUMO: :mod:`priqn.env.intersection` fills them, step by step.
"""

from __future__ import annotations

import collections
import dataclasses
from typing import Any

import numpy as np

from priqn.env import forensics, geometry, planner
from priqn.env.reads import Actors, EgoState, StepActors
from priqn.env.scenes import Scene
from priqn.env.traffic import Traffic
from priqn.sim.roadmap import EgoRoute


@dataclasses.dataclass
class Outcome:
    """How the episode stands: the termination flags ``info`` reports."""

    success: bool = False
    """The ego reached its goal (no collision or off-road in that step)."""
    collision: bool = False
    """The ego box overlapped an actor box."""
    off_road: bool = False
    """The ego footprint left the drivable area."""
    timeout: bool = False
    """``max_episode_steps`` decisions without one of the above."""

    @property
    def terminated(self) -> bool:
        """The episode ended by an event (not by the time limit)."""
        return self.success or self.collision or self.off_road


@dataclasses.dataclass
class Episode:
    """State of the running episode."""

    scene: Scene
    route: EgoRoute
    ref: planner.ReferenceLine
    command: str
    density: float
    traffic: Traffic
    raster: geometry.MapRaster
    """The scene's raster with this route's bit (shared, read-only)."""
    target_speed_mps: float
    """Progress reward's target speed v* [m/s]."""
    ego: EgoState
    """The ego at the current decision."""
    actors: Actors
    """Actors read after the last SUMO step."""
    steps: int = 0
    returns: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.float32))
    """Undiscounted return per objective so far (``float32 [N]``)."""
    outcome: Outcome = dataclasses.field(default_factory=Outcome)
    done: bool = False
    history: collections.deque = dataclasses.field(
        default_factory=lambda: collections.deque(maxlen=forensics.HISTORY_STEPS)
    )
    """The last SUMO steps (:class:`~priqn.env.forensics.Step`): the ego and the actors read."""
    forensics: dict[str, Any] = dataclasses.field(default_factory=forensics.no_collision)
    """The collision's kind, striker, speeds (:data:`~priqn.objectives.COLLISION_COLUMNS`; empty
    without a collision), in the final ``info``."""

    @property
    def net(self) -> str:
        """``"family/net_id"``."""
        return self.scene.net


@dataclasses.dataclass(frozen=True)
class DecisionPlan:
    """A decision's plan and what it implies before SUMO runs (arrays [n] over its steps)."""

    traj: planner.Trajectory
    """The Frenet plan; sample k (k = 1..n) is where the ego is after SUMO step k."""
    off_road: np.ndarray
    """bool [n]: the ego footprint is off the road after step k."""
    at_goal: np.ndarray
    """bool [n]: the ego has reached its goal after step k."""
    steps: int
    """SUMO steps to run: up to the first off-road or goal step, else n."""


@dataclasses.dataclass(frozen=True)
class Measures:
    """What one decision measured over its executed SUMO steps (arrays [T])."""

    steps: int
    """T: SUMO steps that count (up to and including the first event)."""
    collision: bool
    off_road: bool
    success: bool
    conflict_time_s: np.ndarray
    """Time to the first conflict seen from each step [s] (risk)."""
    lateral_offset_m: np.ndarray
    """Frenet lateral offset from the route's centre line [m]."""
    heading_error_rad: np.ndarray
    """Heading minus the centre line's heading [rad]."""
    end: EgoState
    """The ego after the last counted step (the next decision starts from it)."""
    advance_m: float
    """Arc length gained along the route in the decision [m]."""
    speed_mps: np.ndarray
    jerk_mps3: np.ndarray
    """Longitudinal jerk [m/s³]."""
    lateral_accel_mps2: np.ndarray
    """Lateral (centripetal) acceleration [m/s²]."""


@dataclasses.dataclass(frozen=True)
class SumoSteps:
    """What one decision's SUMO steps produced, step by step (arrays [T], T = steps run)."""

    seen: StepActors
    """Actors read after each SUMO step."""
    departed: list[tuple[str, ...]]
    """Vehicles SUMO inserted in each step."""
    arrived: list[tuple[str, ...]]
    """Vehicles SUMO removed in each step."""
