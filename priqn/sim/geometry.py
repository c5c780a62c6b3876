"""Plane geometry for nets and the env: SUMO angles, headings, polylines, clipping.

Pure numpy maths with no net, no SUMO and no env in it: the net reader
(:mod:`priqn.sim.roadmap`) builds its lanes, markings and reference lines with it, and
the env (:mod:`priqn.env`) converts poses and measures along lines with it. Conventions:

- Positions are SUMO network coordinates in metres: ``x`` east, ``y`` north.
- A *heading* is in radians, counter-clockwise from +x (``atan2(dy, dx)``). SUMO's
  vehicle *angle* is in degrees, clockwise from north: ``angle = (90 - degrees(heading)) mod 360``
  (:func:`sumo_angle_deg`), which ``vehicle.moveToXY`` expects; back again,
  ``heading = radians(90 - angle)`` (:func:`heading_rad_from_sumo`). Every conversion
  between the two goes through these two functions.
- Angle differences are wrapped by :func:`wrap_deg` (to ``(-180, 180]``) and
  :func:`wrap_rad` (to ``[-pi, pi]``).
- Polylines are ``float64 [P, 2]`` arrays of ``(x, y)``; arc length ``s`` starts at 0 at
  the first point, and a positive lateral offset is to the left.
- Polygons are ``float64 [P, 2]`` arrays of ``(x, y)``, open (first point not repeated).
"""

from __future__ import annotations

import math

import numpy as np

# --------------------------------------------------------------------------- angles and polylines


def sumo_angle_deg(heading_rad: float | np.ndarray) -> float | np.ndarray:
    """Heading (rad, CCW from +x) → SUMO angle (deg, clockwise from north) in [0, 360).

    East (heading 0) is 90°, north (π/2) 0°, west (π) 270°, south (−π/2) 180°.
    """
    return np.mod(90.0 - np.degrees(heading_rad), 360.0)


def heading_rad_from_sumo(angle_deg: float | np.ndarray) -> float | np.ndarray:
    """SUMO angle (deg, clockwise from north) → heading (rad, CCW from +x), float64.

    ``radians(90 - angle)``, not wrapped: SUMO's angles in [0, 360) give headings in
    (-3π/2, π/2] (north 0° → π/2, east 90° → 0, south 180° → −π/2, west 270° → −π).
    The inverse of :func:`sumo_angle_deg` up to whole turns.
    """
    return np.radians(90.0 - np.asarray(angle_deg, dtype=float))


def wrap_deg(angle_deg: float) -> float:
    """``angle_deg`` wrapped to (-180, 180] [deg]: 190 → -170, -180 → 180, 540 → 180."""
    wrapped = (angle_deg + 180.0) % 360.0 - 180.0
    return 180.0 if wrapped == -180.0 else wrapped


def wrap_rad(angle_rad: float | np.ndarray) -> float | np.ndarray:
    """``angle_rad`` wrapped to [-π, π] [rad], as the angle of ``exp(i·angle)``.

    Odd multiples of π keep their sign (π → π, −π → −π): the rounding of ``exp`` decides,
    so this is for differences compared by size (``abs``), not for a canonical angle.
    """
    return np.angle(np.exp(1j * angle_rad))


def arc_length(xy: np.ndarray) -> np.ndarray:
    """``[P]`` cumulative length along polyline ``xy [P, 2]`` (0 at the first point)."""
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)])


def polyline_heading(xy: np.ndarray) -> np.ndarray:
    """``[P]`` heading (rad) of polyline ``xy [P, 2]`` by central differences."""
    d = np.gradient(xy, axis=0)
    return np.arctan2(d[:, 1], d[:, 0])


def offset_polyline(xy: np.ndarray, offset_m: float) -> np.ndarray:
    """Shift polyline ``xy [P, 2]`` sideways by ``offset_m`` (positive = left), mitred joints."""
    xy = _dedupe(np.asarray(xy, float))
    if len(xy) < 2:
        return xy.copy()
    seg = np.diff(xy, axis=0)
    seg /= np.linalg.norm(seg, axis=1, keepdims=True)
    normals = np.stack([-seg[:, 1], seg[:, 0]], axis=1)  # left normals [P-1, 2]
    vertex_n = np.empty_like(xy)
    vertex_n[0], vertex_n[-1] = normals[0], normals[-1]
    if len(xy) > 2:
        mid = normals[:-1] + normals[1:]
        mid /= np.maximum(np.linalg.norm(mid, axis=1, keepdims=True), 1e-9)
        cos_half = np.sum(mid * normals[1:], axis=1, keepdims=True)
        vertex_n[1:-1] = mid / np.maximum(cos_half, 0.5)  # mitre, capped at 2x
    return xy + offset_m * vertex_n


def lane_polygon(center_xy: np.ndarray, width_m: float) -> np.ndarray:
    """Footprint ``[2P, 2]`` of a lane from its centre line ``[P, 2]`` and width."""
    left = offset_polyline(center_xy, width_m / 2.0)
    right = offset_polyline(center_xy, -width_m / 2.0)
    return np.concatenate([left, right[::-1]])


def resample(xy: np.ndarray, step_m: float) -> np.ndarray:
    """Points every ``step_m`` along polyline ``xy`` (the last point kept exactly)."""
    xy = _dedupe(xy)
    s = arc_length(xy)
    n = max(int(math.ceil(s[-1] / step_m - 1e-6)), 1)
    t = np.linspace(0.0, s[-1], n + 1)
    return np.stack([np.interp(t, s, xy[:, 0]), np.interp(t, s, xy[:, 1])], axis=1)


def smooth_polyline(xy: np.ndarray, sigma_m: float, step_m: float) -> np.ndarray:
    """Gaussian-smooth a polyline resampled at ``step_m``; ends are extended straight.

    The line is padded at both ends by point reflection (``2 p0 - p_k``), which keeps a
    straight end straight and the end points fixed, then convolved with a Gaussian of
    width ``sigma_m`` and resampled at ``step_m`` again.
    """
    pts = resample(xy, step_m)
    sigma = sigma_m / step_m
    half = int(math.ceil(3 * sigma))
    if half == 0 or len(pts) < 3:
        return pts
    k = np.arange(-half, half + 1)
    w = np.exp(-0.5 * (k / sigma) ** 2)
    w /= w.sum()
    idx = np.arange(1, half + 1)
    head = 2 * pts[0] - pts[np.minimum(idx, len(pts) - 1)][::-1]
    tail = 2 * pts[-1] - pts[np.maximum(len(pts) - 1 - idx, 0)]
    padded = np.concatenate([head, pts, tail])
    out = np.stack([np.convolve(padded[:, i], w, mode="valid") for i in range(2)], axis=1)
    return resample(out, step_m)


def project_s(xy: np.ndarray, point: np.ndarray) -> float:
    """Arc length of the point of polyline ``xy`` closest to ``point``."""
    a, b = xy[:-1], xy[1:]
    ab = b - a
    t = np.clip(np.sum((point - a) * ab, axis=1) / np.maximum(np.sum(ab * ab, axis=1), 1e-12), 0, 1)
    proj = a + t[:, None] * ab
    i = int(np.argmin(np.sum((proj - point) ** 2, axis=1)))
    return float(arc_length(xy)[i] + t[i] * np.linalg.norm(ab[i]))


Box = tuple[float, float, float, float]
"""An axis-aligned window ``(xmin, ymin, xmax, ymax)`` [m]."""


def clip_polygon(xy: np.ndarray, box: Box) -> np.ndarray:
    """Polygon ``xy [P, 2]`` cut to ``box`` (Sutherland-Hodgman); ``xy`` itself when inside.

    Returns ``[Q, 2]``, empty (``Q = 0``) when the polygon lies outside the box.
    """
    xy = np.asarray(xy, float)
    if len(xy) == 0 or _inside_box(xy, box):
        return xy
    pts = xy
    for axis, bound, keep_below in (
        (0, box[0], False),
        (0, box[2], True),
        (1, box[1], False),
        (1, box[3], True),
    ):
        if len(pts) == 0:
            break
        v = pts[:, axis] - bound
        inside = v <= 0 if keep_below else v >= 0
        out = []
        for i in range(len(pts)):
            j = i - 1  # the previous vertex (i = 0: the last one)
            if inside[i] != inside[j]:
                out.append(pts[j] + v[j] / (v[j] - v[i]) * (pts[i] - pts[j]))
            if inside[i]:
                out.append(pts[i])
        pts = np.asarray(out, float).reshape(-1, 2)
    return pts


def clip_polyline(xy: np.ndarray, box: Box) -> list[np.ndarray]:
    """The pieces ``[P_i, 2]`` of polyline ``xy`` inside ``box`` (Liang-Barsky per segment).

    ``[xy]`` itself when it lies inside; ``[]`` when nothing of it does.
    """
    xy = np.asarray(xy, float)
    if len(xy) < 2:
        return []
    if _inside_box(xy, box):
        return [xy]
    pieces: list[list[np.ndarray]] = []
    extend = False  # the last piece ends at this segment's start point
    for p0, p1 in zip(xy[:-1], xy[1:], strict=True):
        d = p1 - p0
        t0, t1 = 0.0, 1.0
        for p, q in (
            (-d[0], p0[0] - box[0]),
            (d[0], box[2] - p0[0]),
            (-d[1], p0[1] - box[1]),
            (d[1], box[3] - p0[1]),
        ):
            if p == 0.0:
                if q < 0.0:
                    t0, t1 = 1.0, 0.0  # parallel to this side and outside it
            elif p < 0.0:
                t0 = max(t0, q / p)
            else:
                t1 = min(t1, q / p)
        if t0 > t1:
            extend = False
            continue
        if extend and t0 == 0.0:
            pieces[-1].append(p0 + t1 * d)
        else:
            pieces.append([p0 + t0 * d, p0 + t1 * d])
        extend = t1 == 1.0
    return [np.asarray(pc) for pc in pieces if len(_dedupe(np.asarray(pc))) >= 2]


def point_polyline_distance_m(points_xy: np.ndarray, line_xy: np.ndarray) -> np.ndarray:
    """``[P]`` distance of each point to the polyline ``line_xy [Q, 2]`` [m]."""
    a, b = line_xy[:-1], line_xy[1:]
    ab = b - a  # [Q-1, 2]
    ap = points_xy[:, None, :] - a[None]  # [P, Q-1, 2]
    denom = np.maximum((ab * ab).sum(-1), 1e-12)
    t = np.clip((ap * ab[None]).sum(-1) / denom, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.hypot(*(points_xy[:, None, :] - closest).transpose(2, 0, 1)).min(axis=1)


# --------------------------------------------------------------------------- internals


def _dedupe(xy: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    xy = np.asarray(xy, float)
    if len(xy) < 2:
        return xy
    keep = np.concatenate([[True], np.linalg.norm(np.diff(xy, axis=0), axis=1) > tol])
    return xy[keep]


def _inside_box(xy: np.ndarray, box: Box) -> bool:
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    return bool(lo[0] >= box[0] and lo[1] >= box[1] and hi[0] <= box[2] and hi[1] <= box[3])
