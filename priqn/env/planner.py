"""Frenet planner: quartic longitudinal / quintic lateral trajectories on a reference line.

The agent picks two boundary conditions per decision, a target speed ``v_f`` and a
lateral offset ``d_f`` from the route's centre line; :func:`plan` turns them into a
trajectory over a ~3 s horizon that starts exactly at the current Frenet state, so that
position, speed, acceleration, lateral offset and its slope stay continuous from one
decision (0.5 s) to the next. The env follows the first decision interval of each plan
with SUMO's ``moveToXY`` and then replans from :meth:`Trajectory.state_at`.

Our reading of the Frenet planner (Werling et al. 2010), and where we deviate:

* **Longitudinal, quartic in time.** ``s(t)`` with ``s(0)=s0, ṡ(0)=v0, s̈(0)=a0`` and
  ``ṡ(T)=v_f, s̈(T)=0``. Because the conditions are linear, ``ṡ`` splits into a part that
  brings the current motion ``(v0, a0)`` to rest and a part ``v_f·φ(t/T)`` with
  ``φ(τ) = 3τ² − 2τ³ ≥ 0``. The rest part is non-negative iff ``a0 ≥ −3·v0/T``; when the
  ego brakes harder than that (near a stop), the rest part uses the shorter horizon
  ``T' = 3·v0/(−a0)`` (a cubic speed ``∝ (T'−t)³`` that reaches rest with zero
  acceleration and jerk) and stays at rest after it. So the speed is never negative
  (no reversing, no backwards creep), ``v_f = 0`` stops and stays stopped, and the
  acceleration at ``t=0`` is still exactly ``a0``. When ``T' = T`` this is the plain
  quartic.
* **Lateral, quintic in arc length** ``d(s)`` with ``d, d', d''`` continuous at
  ``s0`` and ``d(s0+L)=d_f, d'=d''=0`` with ``L = max(Δs, min_lateral_distance_m)``
  (``Δs`` the longitudinal distance of the horizon). At constant speed this equals the
  time quintic ``d(t)`` over ``T`` (``s`` is linear in ``t``); unlike ``d(t)`` it cannot
  move the car sideways while it stands or crawls (a time quintic at ``ṡ = 0`` turns the
  car 90° and crabs it across the lane). The price: below ``min_lateral_distance_m / T``
  the offset ``d_f`` is reached beyond the horizon, as a real car would.
* Heading, speed, accelerations and jerk of the Cartesian trajectory follow
  analytically from ``s(t)`` and ``d(s)`` (Werling's Frenet→Cartesian formulas with the
  reference curvature's derivative taken as 0 inside a segment).
* Beyond the reference line's ends the line is extrapolated straight.

Conventions: x/y in metres (SUMO network coordinates), headings in radians
counter-clockwise from +x, ``d`` positive to the left of the reference line.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from priqn.sim.geometry import wrap_rad

_EPS = 1e-9


# --------------------------------------------------------------------------- reference line


class ReferenceLine:
    """A polyline with arc length, smooth heading and curvature, and Frenet conversions.

    ``xy_P2`` is the route's (already smoothed) centre line, points ~0.5 m apart.
    Positions are linear along segments; the heading is interpolated linearly in ``s``
    between vertex headings (central differences), so it is continuous and the
    curvature ``κ = dθ/ds`` is piecewise constant. Beyond both ends the line continues
    straight along the end headings.
    """

    def __init__(self, xy_P2: np.ndarray) -> None:
        xy = np.asarray(xy_P2, dtype=float)
        if xy.ndim != 2 or xy.shape[1] != 2:
            raise ValueError(f"reference line must be [P, 2], got shape {xy.shape}")
        if not np.all(np.isfinite(xy)):
            raise ValueError("reference line has non-finite points")
        # Drop repeated points (zero-length segments have no direction).
        keep = np.ones(len(xy), dtype=bool)
        keep[1:] = np.hypot(*np.diff(xy, axis=0).T) > 1e-6
        xy = xy[keep]
        if len(xy) < 2:
            raise ValueError("reference line needs at least two distinct points")
        seg = np.diff(xy, axis=0)
        seg_len = np.hypot(seg[:, 0], seg[:, 1])
        self.xy_P2: np.ndarray = xy
        """Vertices [P, 2] (m)."""
        self.s_P: np.ndarray = np.concatenate([[0.0], np.cumsum(seg_len)])
        """Arc length at each vertex (m)."""
        self.length_m: float = float(self.s_P[-1])
        """Total arc length (m)."""
        self._seg_len = seg_len
        self._seg_dir = seg / seg_len[:, None]
        seg_heading = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
        heading = np.empty(len(xy))
        heading[0] = seg_heading[0]
        heading[-1] = seg_heading[-1]
        if len(xy) > 2:
            chord = xy[2:] - xy[:-2]
            mid = np.arctan2(chord[:, 1], chord[:, 0])
            # Put each chord heading on the same branch as the neighbouring segments.
            mid = seg_heading[:-1] + wrap_rad(mid - seg_heading[:-1])
            heading[1:-1] = mid
        self.heading_P: np.ndarray = heading
        """Unwrapped heading at each vertex (rad)."""
        self.curvature_S: np.ndarray = np.diff(heading) / seg_len
        """Curvature of each segment (1/m, positive = turning left)."""

    def _segment(self, s: np.ndarray) -> np.ndarray:
        i = np.searchsorted(self.s_P, s, side="right") - 1
        return np.minimum(np.maximum(i, 0), len(self._seg_len) - 1)  # (np.clip is slower)

    def heading_at(self, s_m: np.ndarray | float) -> np.ndarray:
        """Heading of the line at arc length ``s_m`` (rad, unwrapped, constant beyond the ends)."""
        return np.interp(s_m, self.s_P, self.heading_P)

    def curvature_at(self, s_m: np.ndarray | float) -> np.ndarray:
        """Curvature at ``s_m`` (1/m; 0 beyond the ends)."""
        s = np.asarray(s_m, dtype=float)
        k = self.curvature_S[self._segment(s)]
        return np.where((s < 0.0) | (s > self.length_m), 0.0, k)

    def point_at(self, s_m: np.ndarray | float) -> np.ndarray:
        """Point on the line at ``s_m`` ([..., 2]); straight extrapolation beyond the ends."""
        s = np.asarray(s_m, dtype=float)
        i = self._segment(s)
        # Beyond the ends, continue along the end *vertex* heading (= end segment heading).
        return self.xy_P2[i] + (s - self.s_P[i])[..., None] * self._seg_dir[i]

    def to_cartesian(
        self, s_m: np.ndarray | float, d_m: np.ndarray | float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Frenet ``(s, d)`` → (points [..., 2], reference heading [...] in rad)."""
        s = np.asarray(s_m, dtype=float)
        d = np.asarray(d_m, dtype=float)
        th = self.heading_at(s)
        p = self.point_at(s)
        normal = np.stack([-np.sin(th), np.cos(th)], axis=-1)
        return p + d[..., None] * normal, th

    def _frame(self, s: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``to_cartesian(s, d)`` and ``curvature_at(s)`` with one segment lookup."""
        i = self._segment(s)
        th = np.interp(s, self.s_P, self.heading_P)
        xy = self.xy_P2[i] + (s - self.s_P[i])[:, None] * self._seg_dir[i]
        xy[:, 0] -= d * np.sin(th)
        xy[:, 1] += d * np.cos(th)
        kappa = np.where((s < 0.0) | (s > self.length_m), 0.0, self.curvature_S[i])
        return xy, th, kappa

    def to_frenet(
        self, xy: np.ndarray, s_range_m: tuple[float, float] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Points ``xy`` [..., 2] → ``(s, d)`` [...], the inverse of :meth:`to_cartesian`.

        The nearest segment is found by brute force over all segments (or only those
        overlapping ``s_range_m``, to keep a point on the right branch of a route that
        passes near itself); then a few Newton steps make ``s`` the foot point of the
        smooth-heading normal, so that ``to_cartesian(to_frenet(p)) == p``. Points
        beyond the ends get ``s < 0`` or ``s > length_m``.
        """
        p = np.asarray(xy, dtype=float)
        shape = p.shape[:-1]
        p = p.reshape(-1, 2)
        a = self.xy_P2[:-1]
        u = self._seg_dir
        seg_idx = np.arange(len(a))
        if s_range_m is not None:
            lo, hi = s_range_m
            sel = (self.s_P[1:] >= lo) & (self.s_P[:-1] <= hi)
            if not sel.any():
                sel[self._segment(np.clip(np.array([lo]), 0, self.length_m))] = True
            seg_idx = seg_idx[sel]
        ux, uy = u[seg_idx, 0], u[seg_idx, 1]
        rx = p[:, 0:1] - a[seg_idx, 0]  # [N, S]
        ry = p[:, 1:2] - a[seg_idx, 1]
        t = rx * ux + ry * uy
        lo_t = np.where(seg_idx == 0, -np.inf, 0.0)
        hi_t = np.where(seg_idx == len(a) - 1, np.inf, self._seg_len[seg_idx])
        np.clip(t, lo_t, hi_t, out=t)
        rx -= t * ux
        ry -= t * uy
        best = np.argmin(rx * rx + ry * ry, axis=1)
        s = self.s_P[seg_idx[best]] + t[np.arange(len(p)), best]
        for _ in range(6):
            i = self._segment(s)
            t_in = s - self.s_P[i]
            th = self.heading_at(s)
            ct, st = np.cos(th), np.sin(th)
            r = p - (self.xy_P2[i] + t_in[:, None] * self._seg_dir[i])
            along = r[:, 0] * ct + r[:, 1] * st
            if np.all(np.abs(along) < 1e-10):
                break
            d = r[:, 1] * ct - r[:, 0] * st
            kappa = np.where((s < 0.0) | (s > self.length_m), 0.0, self.curvature_S[i])
            slope = self._seg_dir[i, 0] * ct + self._seg_dir[i, 1] * st - kappa * d
            s = s + along / np.maximum(slope, 0.1)
        th = self.heading_at(s)
        r = p - self.point_at(s)
        d = -r[:, 0] * np.sin(th) + r[:, 1] * np.cos(th)
        return s.reshape(shape), d.reshape(shape)

    def frenet_state(
        self,
        xy: np.ndarray,
        heading_rad: float,
        speed_mps: float,
        accel_mps2: float = 0.0,
        s_range_m: tuple[float, float] | None = None,
    ) -> FrenetState:
        """Frenet state of a car at ``xy`` moving along ``heading_rad`` at ``speed_mps``.

        Used once per episode (later states come from the previous plan). The heading
        relative to the line gives ``d' = (1 − κd)·tan Δθ`` and ``ṡ = v·cos Δθ / (1 − κd)``;
        ``d''`` is taken as 0.
        """
        s, d = self.to_frenet(np.asarray(xy, dtype=float).reshape(1, 2), s_range_m)
        s, d = float(s[0]), float(d[0])
        dth = float(wrap_rad(heading_rad - self.heading_at(s)))
        one_kd = max(1.0 - float(self.curvature_at(s)) * d, 0.05)
        cos_t = np.cos(dth)
        return FrenetState(
            s=s,
            s_dot=max(speed_mps * cos_t / one_kd, 0.0),
            s_ddot=accel_mps2 * cos_t / one_kd,
            d=d,
            d_prime=one_kd * float(np.tan(np.clip(dth, -1.2, 1.2))),
            d_pprime=0.0,
        )


# --------------------------------------------------------------------------- state, config


@dataclass(frozen=True)
class FrenetState:
    """The planner's state: longitudinal in time, lateral in arc length.

    The lateral derivatives are with respect to ``s`` (not time): ``ḋ = d'·ṡ`` and
    ``d̈ = d''·ṡ² + d'·s̈``; see :class:`Trajectory` for the time derivatives.
    """

    s: float
    """Arc length along the reference line (m)."""
    s_dot: float
    """Longitudinal speed ds/dt (m/s)."""
    s_ddot: float
    """Longitudinal acceleration (m/s²)."""
    d: float
    """Lateral offset, positive left (m)."""
    d_prime: float
    """Lateral slope dd/ds (-)."""
    d_pprime: float
    """Lateral curvature d²d/ds² (1/m)."""


@dataclass(frozen=True)
class PlannerConfig:
    """Frenet planner parameters."""

    horizon_s: float = 3.0
    """Planning horizon T (s)."""
    dt_s: float = 0.1
    """Sampling step of the returned trajectory (s); T must be a whole number of steps."""
    min_lateral_distance_m: float = 10.0
    """Shortest arc length over which the lateral offset changes (m); see module docs."""
    extend_s: float = 0.0
    """Samples continue this long past the horizon (s), along the plan's own continuation
    (speed ``v_f``, offset ``d_f`` once reached); the env's risk look-ahead reads them."""

    def __post_init__(self) -> None:
        if not self.horizon_s > 0 or not self.dt_s > 0:
            raise ValueError("planner.horizon_s and planner.dt_s must be > 0")
        for name in ("horizon_s", "extend_s"):
            n = getattr(self, name) / self.dt_s
            if abs(n - round(n)) > 1e-6:
                raise ValueError(
                    f"planner.{name} ({getattr(self, name)}) must be a multiple of dt_s ({self.dt_s})"
                )
        if self.extend_s < 0:
            raise ValueError("planner.extend_s must be >= 0")
        if not self.min_lateral_distance_m > 0:
            raise ValueError("planner.min_lateral_distance_m must be > 0")


# --------------------------------------------------------------------------- polynomials


def _powers(x: np.ndarray, degree: int) -> np.ndarray:
    """``[..., degree + 1]``: x⁰, x¹, ..., x^degree."""
    out = np.empty((*np.shape(x), degree + 1))
    out[..., 0] = 1.0
    out[..., 1] = x
    for k in range(2, degree + 1):
        np.multiply(out[..., k - 1], x, out=out[..., k])
    return out


@functools.lru_cache(maxsize=16)
def _time_grid(horizon_s: float, dt_s: float, extend_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The sample times ``[S]`` of a plan and their :func:`_go_profile` (shared, read-only)."""
    n = int(round(horizon_s / dt_s))
    n_ext = int(round(extend_s / dt_s))
    t = np.arange(n + n_ext + 1) * dt_s
    t[n] = horizon_s  # exact end of the horizon
    t.flags.writeable = False
    return t, _go_profile(horizon_s, tuple(t.tolist()))


@functools.lru_cache(maxsize=16)
def _go_profile(horizon_s: float, t_key: tuple[float, ...]) -> np.ndarray:
    """``[S, 4]`` (position, speed, acceleration, jerk) of the unit "go" part ``Φ(t)``.

    Speed ``φ(t/T)``, ``φ(τ) = 3τ² − 2τ³``, frozen at 1 after ``T``; cached per time grid
    (every plan of an env samples the same one).
    """
    t = np.array(t_key)
    T = horizon_s
    tau = np.minimum(t, T) / T
    before = t <= T
    out = np.empty((len(t), 4))
    out[:, 0] = T * tau**3 * (1.0 - 0.5 * tau) + (t - T) * ~before
    out[:, 1] = tau**2 * (3.0 - 2.0 * tau)
    out[:, 2] = before * (6.0 / T) * tau * (1.0 - tau)
    out[:, 3] = before * (6.0 - 12.0 * tau) / T**2
    out.flags.writeable = False
    return out


class _Longitudinal:
    """``s(t) = s0 + rest(t) + v_f·Φ(t)``; see the module docstring."""

    def __init__(self, s0: float, v0: float, a0: float, v_f: float, horizon_s: float) -> None:
        self.s0, self.v_f, self.T = s0, v_f, horizon_s
        v0 = max(v0, 0.0)
        # Horizon of the "come to rest" part: shorter when braking harder than -3 v0 / T.
        if v0 <= _EPS:
            t_rest = 0.0
        elif a0 < -3.0 * v0 / horizon_s:
            t_rest = -3.0 * v0 / a0
        else:
            t_rest = horizon_s
        self.t_rest = t_rest
        if t_rest > 0.0:
            c4 = (v0 + 0.5 * a0 * t_rest) / (2.0 * t_rest**3)
            c3 = -(a0 + 12.0 * c4 * t_rest**2) / (6.0 * t_rest)
            self.rest = np.array([0.0, v0, 0.5 * a0, c3, c4])  # ascending powers
        else:
            self.rest = np.zeros(5)
        c1, c2, c3, c4 = self.rest[1:]
        # Columns: position, speed, acceleration, jerk of the rest part, as polynomials
        # in t (rows: ascending powers).
        self._rest_54 = np.array(
            [
                [0.0, c1, 2 * c2, 6 * c3],
                [c1, 2 * c2, 6 * c3, 24 * c4],
                [c2, 3 * c3, 12 * c4, 0.0],
                [c3, 4 * c4, 0.0, 0.0],
                [c4, 0.0, 0.0, 0.0],
            ]
        )

    def s_end(self) -> float:
        """s(T), without evaluating arrays."""
        tr = min(self.T, self.t_rest)
        c = self.rest
        rest = tr * (c[1] + tr * (c[2] + tr * (c[3] + tr * c[4])))
        return float(self.s0 + rest + self.v_f * 0.5 * self.T)  # Φ(T) = T/2

    def __call__(self, t: np.ndarray, go: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
        """Position, speed, acceleration and jerk at times ``t``.

        ``go``: :func:`_go_profile` of these times when the caller has it.
        """
        t = np.asarray(t, dtype=float)
        if go is None:
            flat = np.atleast_1d(t).ravel()
            go = _go_profile(self.T, tuple(flat.tolist())).reshape(*t.shape, 4)
        # Rest part, frozen after t_rest (its speed, acceleration and jerk are 0 there).
        tr = np.minimum(t, self.t_rest)
        rest = _powers(tr, 4) @ self._rest_54
        rest[..., 1:] *= (t <= self.t_rest)[..., None]
        out = rest + self.v_f * go
        return (
            self.s0 + out[..., 0],
            np.maximum(out[..., 1], 0.0),  # exact algebra is >= 0; clip rounding only
            out[..., 2],
            out[..., 3],
        )


class _Lateral:
    """Quintic ``d(u)``, ``u = s − s0`` in [0, L], constant ``d_f`` beyond ``L``."""

    def __init__(self, d0: float, d1: float, d2: float, d_f: float, length_m: float) -> None:
        L = length_m
        self.L = L
        self.d_f = d_f
        b0 = d_f - d0 - d1 * L - 0.5 * d2 * L**2
        b1 = -d1 - d2 * L
        b2 = -d2
        c3 = (20 * b0 - 8 * b1 * L + b2 * L**2) / (2 * L**3)
        c4 = (-30 * b0 + 14 * b1 * L - 2 * b2 * L**2) / (2 * L**4)
        c5 = (12 * b0 - 6 * b1 * L + b2 * L**2) / (2 * L**5)
        self.c = c = np.array([d0, d1, 0.5 * d2, c3, c4, c5])
        # Columns: d and its first three derivatives in u, as polynomials in u (rows:
        # ascending powers).
        self._m_64 = np.array(
            [
                [c[0], c[1], 2 * c[2], 6 * c[3]],
                [c[1], 2 * c[2], 6 * c[3], 24 * c[4]],
                [c[2], 3 * c[3], 12 * c[4], 60 * c[5]],
                [c[3], 4 * c[4], 20 * c[5], 0.0],
                [c[4], 5 * c[5], 0.0, 0.0],
                [c[5], 0.0, 0.0, 0.0],
            ]
        )

    def __call__(self, u: np.ndarray) -> tuple[np.ndarray, ...]:
        u = np.asarray(u, dtype=float)
        x = np.minimum(np.maximum(u, 0.0), self.L)
        out = _powers(x, 5) @ self._m_64
        out[u >= self.L] = (self.d_f, 0.0, 0.0, 0.0)
        return out[..., 0], out[..., 1], out[..., 2], out[..., 3]


# --------------------------------------------------------------------------- trajectory


@dataclass(frozen=True)
class Trajectory:
    """A planned trajectory sampled at ``t = 0, dt, ..., T + extend_s`` (all arrays [N+1]).

    ``heading_rad`` is the car's yaw (tangent of the Cartesian path); ``accel_lon_mps2``
    is d(speed)/dt, ``accel_lat_mps2`` the centripetal acceleration speed² · path
    curvature, ``jerk_lon_mps3`` d(accel_lon)/dt — what the comfort reward uses.
    """

    t: np.ndarray
    """Time since the plan started (s)."""
    s: np.ndarray
    """Arc length (m)."""
    s_dot: np.ndarray
    """ds/dt (m/s)."""
    s_ddot: np.ndarray
    """d²s/dt² (m/s²)."""
    s_dddot: np.ndarray
    """d³s/dt³ (m/s³)."""
    d: np.ndarray
    """Lateral offset (m)."""
    d_prime: np.ndarray
    """dd/ds (-)."""
    d_pprime: np.ndarray
    """d²d/ds² (1/m)."""
    d_dot: np.ndarray
    """dd/dt (m/s)."""
    d_ddot: np.ndarray
    """d²d/dt² (m/s²)."""
    x: np.ndarray
    """Centre x (m)."""
    y: np.ndarray
    """Centre y (m)."""
    heading_rad: np.ndarray
    """Yaw, counter-clockwise from +x (rad, unwrapped)."""
    speed_mps: np.ndarray
    """Speed along the path (m/s), >= 0."""
    accel_lon_mps2: np.ndarray
    """Longitudinal acceleration (m/s²)."""
    accel_lat_mps2: np.ndarray
    """Lateral (centripetal) acceleration, positive to the left (m/s²)."""
    jerk_lon_mps3: np.ndarray
    """Longitudinal jerk (m/s³)."""
    _lon: _Longitudinal = field(repr=False)
    _lat: _Lateral = field(repr=False)

    def state_at(self, t_s: float) -> FrenetState:
        """Exact Frenet state at time ``t_s`` after the plan start (the next plan's start)."""
        s, v, a, _ = self._lon(np.array(t_s))
        d, d1, d2, _ = self._lat(s - self._lon.s0)
        return FrenetState(float(s), float(v), float(a), float(d), float(d1), float(d2))

    def state_at_sample(self, index: int) -> FrenetState:
        """The Frenet state at sample ``index``, read from the sampled arrays.

        Equal to ``state_at(t[index])`` (the same polynomials at the same time) without
        evaluating them again.
        """
        i = index
        return FrenetState(
            float(self.s[i]),
            float(self.s_dot[i]),
            float(self.s_ddot[i]),
            float(self.d[i]),
            float(self.d_prime[i]),
            float(self.d_pprime[i]),
        )

    def index_at(self, t_s: float) -> int:
        """Index of the sample at time ``t_s`` (must be a sample time)."""
        i = int(round(t_s / (self.t[1] - self.t[0])))
        if not 0 <= i < len(self.t) or abs(self.t[i] - t_s) > 1e-6:
            raise ValueError(f"t={t_s} is not a sample time of this trajectory")
        return i


def plan(
    ref: ReferenceLine,
    state: FrenetState,
    v_f_mps: float,
    d_f_m: float,
    cfg: PlannerConfig | None = None,
) -> Trajectory:
    """Plan from ``state`` to speed ``v_f_mps`` and lateral offset ``d_f_m`` over the horizon."""
    cfg = cfg or PlannerConfig()
    if not v_f_mps >= 0 or not np.isfinite(v_f_mps):
        raise ValueError(f"target speed must be finite and >= 0, got {v_f_mps!r}")
    if not np.isfinite(d_f_m):
        raise ValueError(f"target lateral offset must be finite, got {d_f_m!r}")
    T = cfg.horizon_s
    t, go = _time_grid(T, cfg.dt_s, cfg.extend_s)
    lon = _Longitudinal(state.s, state.s_dot, state.s_ddot, v_f_mps, T)
    s_T = lon.s_end()
    lat = _Lateral(
        state.d,
        state.d_prime,
        state.d_pprime,
        d_f_m,
        max(s_T - state.s, cfg.min_lateral_distance_m),
    )
    s, sd, sdd, sddd = lon(t, go)  # time derivatives of s
    d, d1, d2, d3 = lat(s - state.s)  # arc-length derivatives of d
    # Cartesian path X(s) = P(s) + d(s)·N(s): |dX/ds| = g = hypot(1 − κd, d'), yaw = θ + φ
    # with φ = atan2(d', 1 − κd); speed = ṡ·g; a_lon = s̈·g + ṡ²·g'; a_lat = ṡ²·g·(κ + φ').
    xy, theta, kappa = ref._frame(s, d)
    A = np.maximum(1.0 - kappa * d, 1e-3)  # 1 - κd (> 0 unless beyond the centre of a curve)
    B = d1
    g = np.hypot(A, B)  # |dP/ds|
    A1, B1 = -kappa * d1, d2
    A2, B2 = -kappa * d2, d3
    g1 = (A * A1 + B * B1) / g
    g2 = (A1**2 + A * A2 + B1**2 + B * B2) / g - g1**2 / g
    phi = np.arctan2(B, A)
    phi1 = (B1 * A - A1 * B) / g**2
    speed = sd * g
    return Trajectory(
        t=t,
        s=s,
        s_dot=sd,
        s_ddot=sdd,
        s_dddot=sddd,
        d=d,
        d_prime=d1,
        d_pprime=d2,
        d_dot=d1 * sd,
        d_ddot=d2 * sd**2 + d1 * sdd,
        x=xy[:, 0],
        y=xy[:, 1],
        heading_rad=theta + phi,
        speed_mps=speed,
        accel_lon_mps2=sdd * g + sd**2 * g1,
        accel_lat_mps2=sd**2 * g * (kappa + phi1),
        jerk_lon_mps3=sddd * g + 3 * sd * sdd * g1 + sd**3 * g2,
        _lon=lon,
        _lat=lat,
    )
