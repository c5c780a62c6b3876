"""Compiled loops (numba) for the three per-observation parts of :mod:`priqn.env.sensors`.

Why compiled: once the sensors were vectorised, what was left of their cost was numpy's
per-call overhead (about 150 calls per observation on arrays of tens to a few thousand
elements, 1–3 µs each), not arithmetic. One loop per part removes it.

The loops repeat the numpy path's arithmetic operation for operation, in the same order
and precision, so the grids are byte-identical: ``tests/test_sensors.py`` checks both
paths against :class:`~priqn.bench.references.sensors.ReferenceSensors` on synthetic scenes
and on seeded env episodes at every density. Two rules keep it so:

* trigonometry (``cos``, ``sin``, ``arctan2``, ``hypot``) stays in numpy, outside the
  loops: numpy's and LLVM's math libraries may round differently;
* ``fastmath`` stays off, so LLVM neither reassociates nor fuses a multiply and an add:
  every float operation rounds exactly as numpy's does.

``cache=True``: a machine compiles the loops once (seconds, on the first observation)
and every later process, env workers included, loads them from ``__pycache__`` (or from
numba's per-user cache where the package folder is read-only).

Without numba (``AVAILABLE`` false) :class:`~priqn.env.sensors.Sensors` runs its numpy
path, which gives the same grids in about twice the time.
"""

from __future__ import annotations

import numpy as np

try:
    import numba
except ImportError:  # pragma: no cover - numba is a dependency; the numpy path remains
    numba = None

AVAILABLE = numba is not None
"""Whether the compiled loops can be used (numba imports)."""


def _njit(fn):  # type: ignore[no-untyped-def]
    return numba.njit(cache=True, nogil=True)(fn) if AVAILABLE else fn


@_njit
def sample_map(
    pix_fwd_Q: np.ndarray,
    pix_left_Q: np.ndarray,
    cos_res: np.float32,
    sin_res: np.float32,
    x0_cells: np.float32,
    y0_cells: np.float32,
    bits_YX: np.ndarray,
) -> np.ndarray:
    """Map bits at each grid cell centre, ``uint8 [H·W]`` (``Sensors._sample_map``).

    ``cos_res``/``sin_res``: cos and sin of the ego heading over the raster resolution;
    ``x0_cells``/``y0_cells``: the ego centre in raster cells; all float32, like the
    numpy path's arithmetic.
    """
    hgt, wid = bits_YX.shape
    x_max = np.float32(wid - 1)
    y_max = np.float32(hgt - 1)
    zero = np.float32(0.0)
    out_Q = np.empty(pix_fwd_Q.shape[0], np.uint8)
    for i in range(pix_fwd_Q.shape[0]):
        fx = pix_fwd_Q[i] * cos_res - pix_left_Q[i] * sin_res
        fx += x0_cells
        fy = pix_fwd_Q[i] * sin_res + pix_left_Q[i] * cos_res
        fy += y0_cells
        fx = min(max(fx, zero), x_max)  # np.clip, then truncation == floor (>= 0)
        fy = min(max(fy, zero), y_max)
        out_Q[i] = bits_YX[int(fy), int(fx)]
    return out_Q


@_njit
def fill_boxes(
    canvas_Q: np.ndarray,
    value: np.uint8,
    cx_M: np.ndarray,
    cy_M: np.ndarray,
    cos_M: np.ndarray,
    sin_M: np.ndarray,
    half_len_M: np.ndarray,
    half_wid_M: np.ndarray,
    k: int,
    centre_fwd_P: np.ndarray,
    centre_left_P: np.ndarray,
    fwd_max: float,
    left_max: float,
    res: float,
) -> None:
    """Set ``value`` in every padded-canvas cell whose centre lies inside a box
    (``Sensors._box_cells``: the same ``[2k+1, 2k+1]`` patch around each box's centre
    cell, the same tests). ``centre_*_P``: cell-centre coordinates of padded rows and
    columns -1..n (m)."""
    last = centre_fwd_P.shape[0] - 1  # padded index n + 1
    width = centre_left_P.shape[0]
    for m in range(cx_M.shape[0]):
        row0 = int(np.floor((fwd_max - cx_M[m]) / res))
        col0 = int(np.floor((left_max - cy_M[m]) / res))
        ch, sh = cos_M[m], sin_M[m]
        for a in range(1 - k, k + 2):
            row = min(max(row0 + a, 0), last)
            dfwd = centre_fwd_P[row] - cx_M[m]
            for b in range(1 - k, k + 2):
                col = min(max(col0 + b, 0), last)
                dleft = centre_left_P[col] - cy_M[m]
                if abs(dfwd * ch + dleft * sh) <= half_len_M[m] and (
                    abs(-dfwd * sh + dleft * ch) <= half_wid_M[m]
                ):
                    canvas_Q[row * width + col] = value


@_njit
def face_hits(
    px_F: np.ndarray,
    py_F: np.ndarray,
    ex_F: np.ndarray,
    ey_F: np.ndarray,
    cpe_F: np.ndarray,
    height_F: np.ndarray,
    k0_F: np.ndarray,
    n_F: np.ndarray,
    ray_cos_R: np.ndarray,
    ray_sin_R: np.ndarray,
    range_m: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(ray_N, range_N, height_N)`` as ``Sensors._face_hits`` after its trigonometry:
    every (ray, edge) intersection within range, by ray, nearest face first.

    Edge f runs from corner ``(px, py)`` along ``(ex, ey)``; ``cpe`` = cross(corner,
    edge); rays ``k0[f] .. k0[f] + n[f] - 1`` (mod R) lie in its angular span.
    """
    rays = ray_cos_R.shape[0]
    total = 0
    for f in range(n_F.shape[0]):
        total += n_F[f]
    ray_N = np.empty(total, np.int64)
    t_N = np.empty(total)
    h_N = np.empty(total)
    hits = 0
    for f in range(px_F.shape[0]):
        for j in range(n_F[f]):
            r = (k0_F[f] + j) % rays
            ux, uy = ray_cos_R[r], ray_sin_R[r]
            den = ux * ey_F[f] - uy * ex_F[f]  # cross(u, e)
            num = px_F[f] * uy - py_F[f] * ux  # cross(p, u)
            if den < 0 and num <= 0 and num >= den:
                t = cpe_F[f] / den
                if t <= range_m:
                    ray_N[hits] = r
                    t_N[hits] = t
                    h_N[hits] = height_F[f]
                    hits += 1
    ray_N, t_N, h_N = ray_N[:hits], t_N[:hits], h_N[:hits]
    # By ray, nearest face first; ties in (edge, ray) order (np.lexsort's).
    by_t = np.argsort(t_N, kind="mergesort")
    order = by_t[np.argsort(ray_N[by_t], kind="mergesort")]
    return ray_N[order], t_N[order], h_N[order]


@_njit
def lidar_grid(
    ray_N: np.ndarray,
    t_N: np.ndarray,
    h_N: np.ndarray,
    ray_cos_R: np.ndarray,
    ray_sin_R: np.ndarray,
    tan_el_K: np.ndarray,
    ground_pad_RK: np.ndarray,
    ground_count_Q: np.ndarray,
    bits_Q: np.ndarray,
    drivable_bit: np.uint8,
    n: int,
    sensor_h_m: float,
    split_m: float,
    fwd_max: float,
    left_max: float,
    res: float,
) -> np.ndarray:
    """``lidar uint8 [2, n, n]`` from the face hits of :func:`face_hits` (ray, range and
    box height, by ray, nearest first): ``Sensors._claims`` and ``_lidar_from`` in one
    pass. ``split_m`` is the split height less the sensor height.
    """
    beams = tan_el_K.shape[0]
    side = n + 2
    blocked_Q = np.zeros(side * side, np.int64)
    low_Q = np.zeros(side * side, np.int64)
    high_Q = np.zeros(side * side, np.int64)
    ray_prev, best = -1, 0
    for i in range(ray_N.shape[0]):
        r, t = ray_N[i], t_N[i]
        if r != ray_prev:  # the running maximum of k_hi restarts on each ray
            ray_prev, best = r, 0
        k_lo = np.searchsorted(tan_el_K, -sensor_h_m / t, side="left")
        k_hi = np.searchsorted(tan_el_K, (h_N[i] - sensor_h_m) / t, side="right")
        lo = max(k_lo, best)
        best = max(best, k_hi)
        if k_hi <= lo:
            continue
        k_split = np.searchsorted(tan_el_K, split_m / t)
        n_low = max(min(k_hi, k_split) - lo, 0)
        for k in range(lo, k_hi):
            blocked_Q[ground_pad_RK[r * beams + k]] += 1
        row = np.floor((fwd_max - ray_cos_R[r] * t) / res)
        col = np.floor((left_max - ray_sin_R[r] * t) / res)
        cell = (int(min(max(row, -1.0), n)) + 1) * side + int(min(max(col, -1.0), n)) + 1
        low_Q[cell] += n_low
        high_Q[cell] += k_hi - lo - n_low
    out = np.empty((2, n, n), np.uint8)
    for row in range(n):
        for col in range(n):
            q = (row + 1) * side + col + 1
            low = low_Q[q]
            if bits_Q[row * n + col] & drivable_bit:
                low += ground_count_Q[row * n + col] - blocked_Q[q]
            out[0, row, col] = min(low, 255)
            out[1, row, col] = min(high_Q[q], 255)
    return out
