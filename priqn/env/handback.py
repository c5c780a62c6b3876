"""The ego handed back to SUMO (``EnvConfig.ego_driver = "sumo"``): what SUMO did, as a plan.

With the SUMO driver the ego is an ordinary SUMO vehicle on its route: SUMO's own
car-following (Krauss), junction (right of way) and lane-change models drive it, with
SUMO's default speed and lane-change modes; no planner, no ``moveToXY``, and the env's
action is ignored. To measure such a decision with exactly the code that measures a
planned one (collision, off-road, goal, risk, lane keeping, progress, comfort), the poses
SUMO reports after each step are turned into a :class:`priqn.env.planner.Trajectory`:
sample 0 is the ego at the decision's start, samples ``1..n`` its pose after each SUMO
step, and the samples after those continue at the last speed and lateral offset along
the route's reference line (the constant-velocity guess the risk look-ahead reads where a
planned ego would read the rest of its plan). Derivatives are backward differences.

Nothing here decides anything; :mod:`priqn.env.intersection` reads the poses and asks.
"""

from __future__ import annotations

import dataclasses
from types import ModuleType

import numpy as np

from priqn.env import planner
from priqn.env.reads import EgoState
from priqn.sim.geometry import heading_rad_from_sumo

S_WINDOW_M = (5.0, 30.0)
"""A pose is projected on the route's reference line within this arc length [m] behind and
ahead of the decision's start (keeps it on the right branch of a route near itself)."""
MIN_S_DOT_MPS = 0.1
"""Floor of ds/dt when dividing by it (``d' = ḋ / ṡ``) [m/s]."""


@dataclasses.dataclass(frozen=True)
class Pose:
    """The ego after one SUMO step, centre-based: as SUMO reports it (or, for the planner's
    ego, the plan sample ``moveToXY`` put it at)."""

    x_m: float
    """Centre x [m]."""
    y_m: float
    """Centre y [m]."""
    heading_rad: float
    """Yaw, counter-clockwise from +x [rad]."""
    speed_mps: float
    """Speed [m/s]."""
    accel_mps2: float
    """Longitudinal acceleration [m/s²]."""


def read_pose(sim: ModuleType, vehicle_id: str, length_m: float) -> Pose:
    """The pose of ``vehicle_id`` after the last SUMO step (SUMO gives its front bumper)."""
    fx, fy = sim.vehicle.getPosition(vehicle_id)
    heading = float(heading_rad_from_sumo(sim.vehicle.getAngle(vehicle_id)))
    return Pose(
        float(fx - 0.5 * length_m * np.cos(heading)),
        float(fy - 0.5 * length_m * np.sin(heading)),
        heading,
        float(sim.vehicle.getSpeed(vehicle_id)),
        float(sim.vehicle.getAcceleration(vehicle_id)),
    )


def driven_trajectory(
    ref: planner.ReferenceLine,
    start: EgoState,
    poses: list[Pose],
    dt_s: float,
    extra_samples: int,
) -> planner.Trajectory:
    """A :class:`~priqn.env.planner.Trajectory` through ``start`` and ``poses`` (one per SUMO
    step), continued for ``extra_samples`` samples at the last speed and lateral offset.

    Its ``_lon`` / ``_lat`` are None: only the sampled arrays (and ``state_at_sample``) exist.
    """
    n = len(poses)
    xy = np.array([[p.x_m, p.y_m] for p in poses], float).reshape(n, 2)
    s0 = start.frenet.s
    s_run, d_run = ref.to_frenet(xy, (s0 - S_WINDOW_M[0], s0 + S_WINDOW_M[1]))
    s_last = float(s_run[-1]) if n else s0
    d_last = float(d_run[-1]) if n else start.frenet.d
    v_last = poses[-1].speed_mps if n else float(start.kinematics[0])
    s_ext = s_last + v_last * dt_s * np.arange(1, extra_samples + 1)
    d_ext = np.full(extra_samples, d_last)
    xy_ext, heading_ext = ref.to_cartesian(s_ext, d_ext)

    x = np.concatenate([[start.x_m], xy[:, 0], xy_ext[:, 0]])
    y = np.concatenate([[start.y_m], xy[:, 1], xy_ext[:, 1]])
    s = np.concatenate([[s0], s_run, s_ext])
    d = np.concatenate([[start.frenet.d], d_run, d_ext])
    heading = np.unwrap(
        np.concatenate([[start.heading_rad], [p.heading_rad for p in poses], heading_ext])
    )
    speed = np.concatenate(
        [[start.kinematics[0]], [p.speed_mps for p in poses], [v_last] * extra_samples]
    )
    accel = np.concatenate(
        [[start.kinematics[2]], [p.accel_mps2 for p in poses], np.zeros(extra_samples)]
    )

    def rate(values: np.ndarray, first: float) -> np.ndarray:
        """Backward difference per second; ``first`` at sample 0."""
        return np.concatenate([[first], np.diff(values) / dt_s])

    s_dot = rate(s, start.frenet.s_dot)
    s_ddot = rate(s_dot, start.frenet.s_ddot)
    d_dot = rate(d, float(start.kinematics[1]))
    return planner.Trajectory(
        t=np.arange(len(s)) * dt_s,
        s=s,
        s_dot=s_dot,
        s_ddot=s_ddot,
        s_dddot=rate(s_ddot, 0.0),
        d=d,
        d_prime=d_dot / np.maximum(s_dot, MIN_S_DOT_MPS),
        d_pprime=np.zeros(len(s)),
        d_dot=d_dot,
        d_ddot=rate(d_dot, 0.0),
        x=x,
        y=y,
        heading_rad=heading,
        speed_mps=speed,
        accel_lon_mps2=accel,
        accel_lat_mps2=speed * rate(heading, float(start.kinematics[3]) / max(speed[0], 1e-6)),
        jerk_lon_mps3=rate(accel, 0.0),
        _lon=None,
        _lat=None,
    )
