"""What the env knows about the ego and the other actors, as typed values.

* :class:`EgoState` — the ego at a decision: Frenet state, pose, kinematics. The ego
  follows its plan exactly (``moveToXY``), so its state comes from the plan, never
  from SUMO.
* :class:`Actors` — every other vehicle and obstacle near the ego at one instant,
  from ONE libsumo context-subscription read per SUMO step (:func:`read_actors`, after
  :func:`subscribe_actors` at the episode's set-up); the raw results of a decision's
  steps are decoded together (:func:`decode_actors`) into :class:`StepActors`.

SUMO reports a vehicle's front bumper and a compass angle; :class:`Actors` holds
centre-based :class:`~priqn.env.geometry.Boxes`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from priqn.env import geometry, planner

KIN_LIMIT = 100.0
"""Kinematics are clipped to [-KIN_LIMIT, KIN_LIMIT] (m/s, m/s^2) so the space is bounded."""
ACTOR_HEIGHT_M = 1.5
"""Height of NPCs and obstacles [m] (LiDAR)."""


@dataclass(frozen=True)
class EgoState:
    """The ego at a decision boundary."""

    frenet: planner.FrenetState
    """Frenet state on the route's reference line (the next plan starts from it)."""
    x_m: float
    """Centre x [m]."""
    y_m: float
    """Centre y [m]."""
    heading_rad: float
    """Yaw, counter-clockwise from +x [rad]."""
    kinematics: np.ndarray
    """``float32 [4]`` observation: v_lon [m/s], v_lat [m/s] (Frenet ḋ), a_lon, a_lat [m/s²]."""

    @classmethod
    def start(cls, ref: planner.ReferenceLine, s_m: float, speed_mps: float) -> EgoState:
        """At rest laterally on the centre line at arc length ``s_m``, driving ``speed_mps``."""
        xy, heading = ref.to_cartesian(s_m, 0.0)
        return cls(
            planner.FrenetState(
                s=s_m, s_dot=speed_mps, s_ddot=0.0, d=0.0, d_prime=0.0, d_pprime=0.0
            ),
            float(xy[0]),
            float(xy[1]),
            float(heading),
            np.array([speed_mps, 0.0, 0.0, 0.0], np.float32),
        )

    @classmethod
    def from_plan(cls, traj: planner.Trajectory, index: int) -> EgoState:
        """Where the plan has the ego at sample ``index``.

        ``v_lat`` is the lateral speed relative to the lane centre (Frenet ḋ): the ego
        does not slip, so its body-frame lateral speed would always be 0.
        """
        j = index
        kin = [traj.speed_mps[j], traj.d_dot[j], traj.accel_lon_mps2[j], traj.accel_lat_mps2[j]]
        return cls(
            traj.state_at_sample(j),
            float(traj.x[j]),
            float(traj.y[j]),
            float(traj.heading_rad[j]),
            np.minimum(np.maximum(np.array(kin, np.float32), -KIN_LIMIT), KIN_LIMIT),
        )

    def box(self, length_m: float, width_m: float, height_m: float) -> geometry.Boxes:
        """The ego's footprint as one box."""
        return geometry.Boxes(
            np.array([[self.x_m, self.y_m]]),
            np.array([self.heading_rad]),
            np.array([length_m]),
            np.array([width_m]),
            np.array([height_m]),
        )


@dataclass(frozen=True)
class Actors:
    """The other vehicles and obstacles at one instant (arrays [M])."""

    boxes: geometry.Boxes
    """Their footprints (centre-based)."""
    speed_mps: np.ndarray
    """[M] speed along their heading (m/s)."""

    @classmethod
    def empty(cls) -> Actors:
        """No actors."""
        return cls(geometry.Boxes.empty(), np.zeros(0))

    def __len__(self) -> int:
        return len(self.speed_mps)

    @property
    def radius_m(self) -> np.ndarray:
        """[M] bounding-circle radius (m)."""
        return 0.5 * np.hypot(self.boxes.length_m, self.boxes.width_m)

    def __getitem__(self, index: np.ndarray | slice) -> Actors:
        return Actors(self.boxes[index], self.speed_mps[index])


@dataclass(frozen=True)
class StepActors:
    """The actors read after each SUMO step of a decision, stacked step after step.

    Row ``i`` of :attr:`actors` was read after step :attr:`step` ``[i]``; the rows of step
    ``k`` are ``offsets[k]:offsets[k + 1]``. Stacked so that the measures of a decision
    run once over all its (step, actor) pairs.
    """

    actors: Actors
    """[M] every actor of every step."""
    offsets: np.ndarray
    """int [K + 1]: first row of each step, then M."""
    step: np.ndarray = dataclasses.field(init=False, repr=False)
    """int [M]: the step of each row."""

    def __post_init__(self) -> None:
        step = np.repeat(np.arange(len(self.offsets) - 1), np.diff(self.offsets))
        object.__setattr__(self, "step", step)

    @classmethod
    def of(cls, per_step: Sequence[Actors]) -> StepActors:
        """Stack the actors of K steps."""
        counts = [len(a) for a in per_step]
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.intp)
        seen = [a for a in per_step if len(a)]
        if not seen:
            return cls(Actors.empty(), offsets)
        b = [a.boxes for a in seen]
        boxes = geometry.Boxes(
            np.concatenate([x.center_xy for x in b]),
            np.concatenate([x.heading_rad for x in b]),
            np.concatenate([x.length_m for x in b]),
            np.concatenate([x.width_m for x in b]),
            np.concatenate([x.height_m for x in b]),
        )
        return cls(Actors(boxes, np.concatenate([a.speed_mps for a in seen])), offsets)

    @property
    def n_steps(self) -> int:
        """K, the number of steps."""
        return len(self.offsets) - 1

    def at(self, k: int) -> Actors:
        """The actors read after step ``k``."""
        return self.actors[self.offsets[k] : self.offsets[k + 1]]

    def first(self, k: int) -> StepActors:
        """Steps ``0..k-1`` only."""
        return StepActors(self.actors[: self.offsets[k]], self.offsets[: k + 1])


def subscribe_actors(sim: ModuleType, ego_id: str, range_m: float) -> None:
    """Subscribe to position, angle, speed, length and width of every vehicle within ``range_m``."""
    import libsumo

    sim.vehicle.subscribeContext(
        ego_id,
        libsumo.CMD_GET_VEHICLE_VARIABLE,
        range_m,
        [
            libsumo.VAR_POSITION,
            libsumo.VAR_ANGLE,
            libsumo.VAR_SPEED,
            libsumo.VAR_LENGTH,
            libsumo.VAR_WIDTH,
        ],
    )


def read_actors(sim: ModuleType, ego_id: str) -> dict[str, dict[int, Any]]:
    """The raw result of :func:`subscribe_actors` after the last SUMO step (one libsumo call).

    Decode the results of one or several steps with :func:`decode_actors`.
    """
    return sim.vehicle.getContextSubscriptionResults(ego_id)


def decode_actors(raw_per_step: Sequence[dict[str, dict[int, Any]]], ego_id: str) -> StepActors:
    """The actors of :func:`read_actors` results, one per step, decoded in one go (ego left out)."""
    import libsumo

    pos, ang, spd = libsumo.VAR_POSITION, libsumo.VAR_ANGLE, libsumo.VAR_SPEED
    length, width = libsumo.VAR_LENGTH, libsumo.VAR_WIDTH
    rows: list[tuple[float, ...]] = []
    offsets = [0]
    for res in raw_per_step:
        rows += [
            (*d[pos], d[ang], d[spd], d[length], d[width]) for v, d in res.items() if v != ego_id
        ]
        offsets.append(len(rows))
    offsets_k = np.array(offsets, dtype=np.intp)
    if not rows:
        return StepActors(Actors.empty(), offsets_k)
    vals = np.array(rows)
    centre, heading = geometry.center_from_sumo(vals[:, 0:2], vals[:, 2], vals[:, 4])
    height = np.full(len(rows), ACTOR_HEIGHT_M)
    boxes = geometry.Boxes(centre, heading, vals[:, 4], vals[:, 5], height)
    return StepActors(Actors(boxes, vals[:, 3]), offsets_k)
