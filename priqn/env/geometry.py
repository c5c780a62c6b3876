"""Our own ground truth for collisions and off-road events, in pure numpy.

SUMO's collision list misses ego crashes (ego partly in the next lane, head-on in the
opposite lane) and reports false ones, so the env decides both termination events
here:

* **Collision** — oriented bounding boxes (OBB) overlap, by the separating axis
  theorem (4 candidate axes for two rectangles), vectorised over all actors.
  Touching boxes (gap exactly 0) do not collide.
* **Off-road** — points sampled on the ego footprint (corners + points along the
  edges) are looked up in a :class:`MapRaster` of the drivable area (all lanes of
  every edge, internal junction lanes and the junction polygon), rasterised once per
  net. Straddling two lanes, or driving in the opposite lane, is *on* the road; a
  corner over the kerb is *off* it.

Boxes are centre-based (``center_xy``, ``heading_rad`` CCW from +x, ``length_m``,
``width_m``, ``height_m``). SUMO reports a vehicle's *front bumper* and a compass angle:
:func:`center_from_sumo` / :func:`sumo_from_center` convert.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageDraw

from priqn.errors import PriqnError
from priqn.sim.geometry import heading_rad_from_sumo, sumo_angle_deg

# --------------------------------------------------------------------------- SUMO poses


def sumo_from_center(
    center_xy: np.ndarray, heading_rad: np.ndarray | float, length_m: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """Centre pose → SUMO's ``(front-bumper xy [..., 2], angle_deg [...])`` for ``moveToXY``.

    SUMO's angle is in degrees clockwise from north (:func:`~priqn.sim.geometry.sumo_angle_deg`);
    its position is the front bumper, ``length/2`` ahead of the centre along the heading.
    """
    c = np.asarray(center_xy, dtype=float)
    h = np.asarray(heading_rad, dtype=float)
    half = 0.5 * np.asarray(length_m, dtype=float)
    front = c + np.stack([np.cos(h), np.sin(h)], axis=-1) * half[..., None]
    return front, sumo_angle_deg(h)


def center_from_sumo(
    front_xy: np.ndarray, angle_deg: np.ndarray | float, length_m: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """SUMO's ``(front-bumper xy, angle_deg)`` → ``(centre xy [..., 2], heading_rad [...])``."""
    f = np.asarray(front_xy, dtype=float)
    h = heading_rad_from_sumo(angle_deg)
    half = 0.5 * np.asarray(length_m, dtype=float)
    return f - np.stack([np.cos(h), np.sin(h)], axis=-1) * half[..., None], h


# --------------------------------------------------------------------------- boxes


@dataclass(frozen=True)
class Boxes:
    """M oriented boxes (vehicles or obstacles); every array has leading dimension M."""

    center_xy: np.ndarray
    """[M, 2] centre (m)."""
    heading_rad: np.ndarray
    """[M] yaw, counter-clockwise from +x (rad)."""
    length_m: np.ndarray
    """[M] extent along the heading (m)."""
    width_m: np.ndarray
    """[M] extent across the heading (m)."""
    height_m: np.ndarray
    """[M] height above the road (m); used by the LiDAR."""

    @classmethod
    def make(
        cls,
        center_xy: np.ndarray | Sequence,
        heading_rad: np.ndarray | float,
        length_m: np.ndarray | float,
        width_m: np.ndarray | float,
        height_m: np.ndarray | float = 1.5,
    ) -> Boxes:
        """Boxes from arrays or scalars (scalars are broadcast to all M boxes)."""
        c = np.asarray(center_xy, dtype=float).reshape(-1, 2)
        m = len(c)

        def col(v: np.ndarray | float, name: str) -> np.ndarray:
            a = np.asarray(v, dtype=float)
            if a.shape != (m,):
                a = np.broadcast_to(a, (m,)).copy()
            if m and name != "heading_rad" and a.min() < 0:
                raise ValueError(f"Boxes.{name} must be >= 0")
            return a

        return cls(
            c,
            col(heading_rad, "heading_rad"),
            col(length_m, "length_m"),
            col(width_m, "width_m"),
            col(height_m, "height_m"),
        )

    @classmethod
    def empty(cls) -> Boxes:
        """No boxes."""
        z = np.zeros(0)
        return cls(np.zeros((0, 2)), z, z, z, z)

    def __len__(self) -> int:
        return len(self.center_xy)

    def __getitem__(self, index: np.ndarray | slice | int) -> Boxes:
        if isinstance(index, (int, np.integer)):
            index = slice(int(index), int(index) + 1)
        return Boxes(
            self.center_xy[index],
            self.heading_rad[index],
            self.length_m[index],
            self.width_m[index],
            self.height_m[index],
        )

    def corners(self) -> np.ndarray:
        """[M, 4, 2] corners, counter-clockwise: front-right, front-left, rear-left, rear-right."""
        return boxes_corners(self.center_xy, self.heading_rad, self.length_m, self.width_m)


def boxes_corners(
    center_xy: np.ndarray, heading_rad: np.ndarray, length_m: np.ndarray, width_m: np.ndarray
) -> np.ndarray:
    """[M, 4, 2] corners of M boxes, counter-clockwise from the front-right corner."""
    c = np.asarray(center_xy, dtype=float).reshape(-1, 2)
    h = np.asarray(heading_rad, dtype=float).reshape(-1)
    hl = 0.5 * np.asarray(length_m, dtype=float).reshape(-1)
    hw = 0.5 * np.asarray(width_m, dtype=float).reshape(-1)
    fwd = np.stack([np.cos(h), np.sin(h)], axis=-1) * hl[:, None]  # [M, 2]
    left = np.stack([-np.sin(h), np.cos(h)], axis=-1) * hw[:, None]
    signs = np.array([[1, -1], [1, 1], [-1, 1], [-1, -1]], dtype=float)  # (fwd, left)
    return (
        c[:, None, :]
        + signs[None, :, 0:1] * fwd[:, None, :]
        + signs[None, :, 1:2] * left[:, None, :]
    )


def obb_overlap(ego: Boxes, others: Boxes) -> np.ndarray:
    """bool [M]: does the (single) ``ego`` box overlap each of the M ``others``?

    Separating axis theorem: two rectangles are disjoint iff their projections are
    disjoint on one of the four edge normals (two per box). Touching is no overlap.
    """
    if len(ego) != 1:
        raise ValueError(f"obb_overlap expects one ego box, got {len(ego)}")
    return obb_overlap_pairs(ego, others)


def obb_overlap_pairs(a: Boxes, b: Boxes) -> np.ndarray:
    """bool [M]: does box ``a[i]`` overlap box ``b[i]``? (``a`` may hold one box for all.)

    The separating-axis test of :func:`obb_overlap`, pair by pair.
    """
    m = len(b)
    if m == 0:
        return np.zeros(0, dtype=bool)
    h0 = a.heading_rad
    c0, s0 = np.cos(h0), np.sin(h0)
    hl0, hw0 = 0.5 * a.length_m, 0.5 * a.width_m
    # Work in a's frame: b's centre (dx, dy) and axes u = (c, s), v = (-s, c).
    delta = b.center_xy - a.center_xy
    dx = delta[:, 0] * c0 + delta[:, 1] * s0
    dy = delta[:, 1] * c0 - delta[:, 0] * s0
    rel = b.heading_rad - h0
    c, s = np.cos(rel), np.sin(rel)
    ac, as_ = np.abs(c), np.abs(s)
    hl, hw = 0.5 * b.length_m, 0.5 * b.width_m
    sep = np.abs(dx) >= hl0 + hl * ac + hw * as_  # a's forward axis
    sep |= np.abs(dy) >= hw0 + hl * as_ + hw * ac  # a's left axis
    sep |= np.abs(dx * c + dy * s) >= hl + hl0 * ac + hw0 * as_  # b's forward axis
    sep |= np.abs(dy * c - dx * s) >= hw + hl0 * as_ + hw0 * ac  # b's left axis
    return ~sep


# --------------------------------------------------------------------------- map raster

DRIVABLE = np.uint8(1)
"""Bit of :attr:`MapRaster.bits` set on the drivable area."""
MARKING = np.uint8(2)
"""Bit set on lane markings (drawn ``marking_width_m`` wide)."""
ROUTE = np.uint8(4)
"""Bit set on the ego route (see :meth:`MapRaster.with_route`)."""

_MAX_RASTER_PX = 60_000_000


class MapRaster:
    """World raster of the road, one uint8 bit field per cell (:data:`DRIVABLE`, ...).

    Cell ``bits[iy, ix]`` covers ``x ∈ origin_x + [ix, ix+1)·res`` and
    ``y ∈ origin_y + [iy, iy+1)·res`` (row index grows with y). A one-cell border of
    zeros surrounds the road, so lookups clipped to the raster read "nothing" outside.
    Built once per net (rasterising ~50 polygons at 0.2 m takes a few ms); the route
    bit is added per episode by :meth:`with_route` on a copy.
    """

    def __init__(self, bits: np.ndarray, origin_xy: tuple[float, float], resolution_m: float):
        self.bits: np.ndarray = np.ascontiguousarray(bits, dtype=np.uint8)
        """[H, W] bit fields."""
        self.origin_xy: tuple[float, float] = (float(origin_xy[0]), float(origin_xy[1]))
        """World position of the lower-left corner of cell [0, 0] (m)."""
        self.resolution_m: float = float(resolution_m)
        """Cell size (m)."""

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) in cells."""
        return self.bits.shape  # type: ignore[return-value]

    @classmethod
    def from_roadmap_arrays(
        cls,
        lane_polygons_xy: Sequence[np.ndarray],
        marking_polylines_xy: Sequence[np.ndarray] = (),
        resolution_m: float = 0.2,
        marking_width_m: float = 0.5,
        margin_m: float = 2.0,
    ) -> MapRaster:
        """Rasterise lane (and junction) polygons and marking polylines.

        ``marking_width_m``: markings are drawn this wide so that a BEV sampling the
        raster at its own cell size sees unbroken lines — pass
        :attr:`priqn.env.sensors.SensorConfig.marking_width_m` (1.25 BEV cells).
        """
        if not resolution_m > 0:
            raise ValueError(f"resolution_m must be > 0, got {resolution_m!r}")
        polys = [np.asarray(p, dtype=float).reshape(-1, 2) for p in lane_polygons_xy]
        polys = [p for p in polys if len(p) >= 3]
        if not polys:
            raise PriqnError("road map: no lane polygon with >= 3 points; cannot rasterise")
        lines = [np.asarray(p, dtype=float).reshape(-1, 2) for p in marking_polylines_xy]
        pts = np.concatenate(polys)
        lo = pts.min(axis=0) - margin_m - resolution_m
        hi = pts.max(axis=0) + margin_m + resolution_m
        w, h = (int(np.ceil(v)) for v in (hi - lo) / resolution_m)
        if w * h > _MAX_RASTER_PX:
            raise PriqnError(
                f"road map: {w}x{h} cells at {resolution_m} m/cell is too large; "
                "use a coarser resolution_m"
            )
        raster = cls(np.zeros((h, w), np.uint8), (lo[0], lo[1]), resolution_m)
        drivable = raster._draw_polygons(polys)
        markings = raster._draw_lines(lines, marking_width_m)
        raster.bits = drivable * DRIVABLE | markings * MARKING
        raster._clear_border()
        return raster

    @classmethod
    def from_roadmap(
        cls, roadmap: object, resolution_m: float = 0.2, marking_width_m: float = 0.5
    ) -> MapRaster:
        """From a :class:`priqn.sim.roadmap.RoadMap` (lane polygons + junction polygon)."""
        polys = list(roadmap.lane_polygons_xy)  # type: ignore[attr-defined]
        junction = getattr(roadmap, "junction_polygon_xy", None)
        if junction is not None and len(junction) >= 3:
            polys.append(junction)
        return cls.from_roadmap_arrays(
            polys,
            roadmap.marking_polylines_xy,  # type: ignore[attr-defined]
            resolution_m=resolution_m,
            marking_width_m=marking_width_m,
        )

    def with_route(self, route_xy: np.ndarray, width_m: float) -> MapRaster:
        """A copy with the :data:`ROUTE` bit set along ``route_xy`` [P, 2], ``width_m`` wide."""
        out = MapRaster(self.bits.copy(), self.origin_xy, self.resolution_m)
        route = out._draw_lines([np.asarray(route_xy, dtype=float)], width_m)
        out.bits = (out.bits & ~ROUTE) | route * ROUTE
        out._clear_border()
        return out

    def cell_index(self, xy: np.ndarray) -> np.ndarray:
        """Flat cell index of points ``xy`` [..., 2], clipped into the raster (border = 0)."""
        h, w = self.bits.shape
        q = (np.asarray(xy, dtype=float) - self.origin_xy) * (1.0 / self.resolution_m)
        np.clip(q, 0.0, (w - 1, h - 1), out=q)  # then truncation == floor
        q = q.astype(np.intp)
        return q[..., 1] * w + q[..., 0]

    def lookup(self, xy: np.ndarray) -> np.ndarray:
        """Bit fields at points ``xy`` [..., 2] (0 outside the raster)."""
        return self.bits.ravel()[self.cell_index(np.asarray(xy, dtype=float))]

    def drivable(self, xy: np.ndarray) -> np.ndarray:
        """bool [...]: is each point on the drivable area?"""
        return (self.lookup(xy) & DRIVABLE) != 0

    # -- drawing helpers (PIL, integer pixel coordinates are cell centres)
    def _to_px(self, xy: np.ndarray) -> list[tuple[float, float]]:
        p = (xy - np.asarray(self.origin_xy)) / self.resolution_m - 0.5
        return [(float(a), float(b)) for a, b in p]

    def _draw_polygons(self, polys: Sequence[np.ndarray]) -> np.ndarray:
        h, w = self.bits.shape
        img = Image.new("L", (w, h), 0)
        draw = ImageDraw.Draw(img)
        for p in polys:
            draw.polygon(self._to_px(p), fill=1, outline=1)
        return np.asarray(img, dtype=np.uint8)

    def _draw_lines(self, lines: Sequence[np.ndarray], width_m: float) -> np.ndarray:
        h, w = self.bits.shape
        img = Image.new("L", (w, h), 0)
        draw = ImageDraw.Draw(img)
        px = max(1, int(round(width_m / self.resolution_m)))
        for line in lines:
            if len(line) < 2:
                continue
            pts = self._to_px(line)
            draw.line(pts, fill=1, width=px, joint="curve" if px > 2 else None)
            if px > 2:  # round caps
                r = 0.5 * px
                for x, y in (pts[0], pts[-1]):
                    draw.ellipse((x - r, y - r, x + r, y + r), fill=1)
        return np.asarray(img, dtype=np.uint8)

    def _clear_border(self) -> None:
        self.bits[0, :] = 0
        self.bits[-1, :] = 0
        self.bits[:, 0] = 0
        self.bits[:, -1] = 0


# --------------------------------------------------------------------------- off-road


@functools.lru_cache(maxsize=8)
def _outline_template(samples_per_edge: int) -> np.ndarray:
    """Outline points of the box [-1, 1]² in (forward, left) units, corners first per edge."""
    corners = np.array([[1.0, -1.0], [1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0]])
    nxt = np.roll(corners, -1, axis=0)
    frac = np.arange(samples_per_edge + 1) / (samples_per_edge + 1)  # 0 = the corner itself
    pts = corners[:, None, :] + frac[None, :, None] * (nxt - corners)[:, None, :]
    out = pts.reshape(-1, 2)
    out.flags.writeable = False
    return out


def footprint_points(boxes: Boxes, samples_per_edge: int = 1) -> np.ndarray:
    """[M, 4·(1 + samples_per_edge), 2] outline points of M boxes: corners + edge points.

    Per edge: its first corner, then ``samples_per_edge`` evenly spaced interior points.
    """
    if samples_per_edge < 0:
        raise ValueError(f"samples_per_edge must be >= 0, got {samples_per_edge}")
    c, s = np.cos(boxes.heading_rad), np.sin(boxes.heading_rad)
    hl, hw = 0.5 * boxes.length_m, 0.5 * boxes.width_m
    tpl = _outline_template(samples_per_edge)  # [P, 2] in (forward, left) half-extent units
    f = tpl[None, :, 0] * hl[:, None]  # [M, P] forward offsets
    lft = tpl[None, :, 1] * hw[:, None]
    x = boxes.center_xy[:, 0:1] + f * c[:, None] - lft * s[:, None]
    y = boxes.center_xy[:, 1:2] + f * s[:, None] + lft * c[:, None]
    return np.stack([x, y], axis=-1)


def off_road_fraction(map_raster: MapRaster, boxes: Boxes, samples_per_edge: int = 1) -> np.ndarray:
    """[M] fraction of each box's outline points (:func:`footprint_points`) off the road."""
    pts = footprint_points(boxes, samples_per_edge)
    return np.mean(~map_raster.drivable(pts), axis=1)


def off_road(
    map_raster: MapRaster,
    boxes: Boxes,
    samples_per_edge: int = 1,
    max_off_fraction: float = 0.0,
) -> np.ndarray:
    """bool [M]: more than ``max_off_fraction`` of the outline points off the drivable area.

    Vectorised over M boxes (e.g. the ego's poses over one decision). Default: any
    corner or edge midpoint off the road. Precision: ± half a raster cell.
    """
    return off_road_fraction(map_raster, boxes, samples_per_edge) > max_off_fraction


def is_off_road(
    map_raster: MapRaster, ego: Boxes, samples_per_edge: int = 1, max_off_fraction: float = 0.0
) -> bool:
    """:func:`off_road` for one box, as a Python bool."""
    if len(ego) != 1:
        raise ValueError(f"is_off_road expects one box, got {len(ego)}; use off_road")
    return bool(off_road(map_raster, ego, samples_per_edge, max_off_fraction)[0])
