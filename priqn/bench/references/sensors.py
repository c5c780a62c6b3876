"""The sensors' first implementation, kept as the reference that the fast path must equal.

:class:`ReferenceSensors` is :class:`~priqn.env.sensors.Sensors` with the internals it had
before issue 38 (BEV footprints as a ``[M, K, K]`` test with ``np.nonzero`` over three
axes, LiDAR claims as ``[hits, beams]`` boolean matrices with a cumulative sum per beam,
one lookup per map channel; the map sampling, unchanged, is inherited). It is kept,
unchanged and slower, for two reasons:

* ``tests/test_sensors.py`` compares the fast path to it byte for byte on synthetic
  scenes and on real env states at every density: the observations, and with them every
  training run, must not change when the sensors get faster;
* ``priqn bench env`` times both on the same states in one command (``sensors ref ms``),
  so that the speed-up is a ratio measured on the same machine at the same time.

Do not use it in the env: it is the specification, not the implementation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from priqn.env.geometry import DRIVABLE, Boxes, MapRaster, boxes_corners
from priqn.env.sensors import SensorConfig, Sensors


class ReferenceSensors(Sensors):
    """:class:`Sensors` computed the pre-issue-38 way (same config, same outputs, slower)."""

    def __init__(self, cfg: SensorConfig | None = None) -> None:
        super().__init__(cfg)
        # The ground return (index into the precomputed ones, -1 if none) of each (ray, beam).
        self._rk_to_g = np.full(self.cfg.lidar_rays * len(self._tan_el), -1, np.intp)
        self._rk_to_g[self._g_rk] = np.arange(len(self._g_rk))

    def lidar_points(self, map_raster: MapRaster, ego: Boxes, actors: Boxes) -> np.ndarray:
        """The synthesised point cloud ``[N, 3]`` (fwd, left, height) in the ego frame (m).

        Same model as :meth:`lidar` (which bins these points), for pictures and checks;
        ground returns are traced only inside the grid, face returns up to the range.
        """
        bits = self._sample_map(map_raster, ego)
        ret = self._returns(bits, self._to_ego_frame(ego, actors)[0])
        ground = self._ground(bits, ret)
        gi = self._g_ray[ground]
        rng = self._g_range[ground]
        ground = np.stack([rng * self._ray_cos[gi], rng * self._ray_sin[gi], 0 * rng], axis=1)
        i, k = np.nonzero(ret.claimed)
        t, ray = ret.hit_t[i], ret.hit_ray[i]
        z = self.cfg.lidar_height_m + t * self._tan_el[k]
        boxes = np.stack([t * self._ray_cos[ray], t * self._ray_sin[ray], z], axis=1)
        return np.concatenate([ground, boxes])

    def _to_ego_frame(self, ego: Boxes, actors: Boxes) -> tuple[Boxes, np.ndarray]:
        """Actors in the ego frame (x forward, y left) without those that cannot be seen,
        and the indices of the kept ones."""
        if len(actors) == 0:
            return actors, np.zeros(0, np.intp)
        h0 = ego.heading_rad[0]
        c, s = np.cos(h0), np.sin(h0)
        d = actors.center_xy - ego.center_xy[0]
        fwd = d[:, 0] * c + d[:, 1] * s
        left = -d[:, 0] * s + d[:, 1] * c
        half_diag = 0.5 * np.hypot(actors.length_m, actors.width_m)
        cfg = self.cfg
        visible = (
            (fwd - half_diag < self._fwd_max)
            & (fwd + half_diag > -cfg.behind_m)
            & (np.abs(left) - half_diag < self._left_max)
        ) | (np.hypot(fwd, left) - half_diag < cfg.lidar_range_m)
        idx = np.flatnonzero(visible)
        rel = Boxes(
            np.stack([fwd, left], axis=1)[idx],
            (actors.heading_rad - h0)[idx],
            actors.length_m[idx],
            actors.width_m[idx],
            actors.height_m[idx],
        )
        return rel, idx

    def _box_cells(self, rel: Boxes) -> tuple[np.ndarray, np.ndarray]:
        """(flat cell index, box index) of every cell whose centre lies inside a box."""
        n = self.cfg.size_px
        res = self._res
        m = len(rel)
        if m == 0:
            return np.zeros(0, np.intp), np.zeros(0, np.intp)
        min_half = res / np.sqrt(2.0)
        hl = np.maximum(0.5 * rel.length_m, min_half)
        hw = np.maximum(0.5 * rel.width_m, min_half)
        k = int(np.ceil(np.max(np.hypot(hl, hw)) / res)) + 1
        off = np.arange(-k, k + 1)
        row_c, col_c = self.cfg.cell_of(rel.center_xy[:, 0], rel.center_xy[:, 1])
        r0 = np.floor(row_c).astype(np.intp)
        c0 = np.floor(col_c).astype(np.intp)
        rows = r0[:, None, None] + off[None, :, None]  # [M, K, 1]
        cols = c0[:, None, None] + off[None, None, :]  # [M, 1, K]
        # Cell-centre offsets from the box centre in the ego frame (fwd, left).
        dfwd = (self._fwd_max - (rows + 0.5) * res) - rel.center_xy[:, 0, None, None]
        dleft = (self._left_max - (cols + 0.5) * res) - rel.center_xy[:, 1, None, None]
        ch = np.cos(rel.heading_rad)[:, None, None]
        sh = np.sin(rel.heading_rad)[:, None, None]
        inside = np.abs(dfwd * ch + dleft * sh) <= hl[:, None, None]
        inside &= np.abs(-dfwd * sh + dleft * ch) <= hw[:, None, None]
        inside &= (rows >= 0) & (rows < n) & (cols >= 0) & (cols < n)
        b, i, j = np.nonzero(inside)
        return rows[b, i, 0] * n + cols[b, 0, j], b

    def _ego_cells(self, ego: Boxes) -> np.ndarray:
        key = (float(ego.length_m[0]), float(ego.width_m[0]))
        if key != self._ego_mask_key:
            rel = Boxes.make([0.0, 0.0], 0.0, key[0], key[1])
            cells, _ = self._box_cells(rel)
            self._ego_mask = np.zeros(self.cfg.size_px**2, dtype=bool)
            self._ego_mask[cells] = True
            self._ego_mask_key = key
        return self._ego_mask

    def _bev_from(
        self,
        bits: np.ndarray,
        ego: Boxes,
        rel: Boxes,
        visible: np.ndarray,
        actor_speed_mps: np.ndarray | None,
    ) -> np.ndarray:
        cfg = self.cfg
        n = cfg.size_px
        out = np.zeros((len(cfg.bev_channels), n * n), dtype=np.uint8)
        ego_mask = self._ego_cells(ego)
        cells = boxes = None
        for ci, name in enumerate(cfg.bev_channels):
            if name in self._luts:
                self._luts[name].take(bits, out=out[ci])
            elif name == "ego":
                out[ci][ego_mask] = 255
            else:
                if cells is None:
                    cells, boxes = self._box_cells(rel)
                if name == "actors":
                    out[ci][cells] = 255
                else:  # actor_speed
                    if actor_speed_mps is None:
                        raise ValueError("the actor_speed channel needs actor_speed_mps")
                    speed = np.asarray(actor_speed_mps, dtype=float).reshape(-1)[visible]
                    val = np.clip(speed / cfg.speed_scale_mps, 0.0, 1.0) * 254 + 1
                    order = np.argsort(val[boxes], kind="stable")  # faster actors on top
                    out[ci][cells[order]] = val[boxes][order].astype(np.uint8)
        return out.reshape(len(cfg.bev_channels), n, n)

    def _returns(self, bits: np.ndarray, rel: Boxes) -> _Returns:
        """Trace every beam: which box face it hits first, or whether it reaches the road."""
        cfg = self.cfg
        rays, beams = cfg.lidar_rays, len(self._tan_el)
        blocked_rk = np.zeros(0, np.intp)
        hit_t = np.zeros(0)
        hit_ray = np.zeros(0, np.intp)
        claimed = np.zeros((0, beams), dtype=bool)
        if len(rel):
            corners = boxes_corners(rel.center_xy, rel.heading_rad, rel.length_m, rel.width_m)
            p = corners.reshape(-1, 2)
            e = (np.roll(corners, -1, axis=1) - corners).reshape(-1, 2)
            cpe = p[:, 0] * e[:, 1] - p[:, 1] * e[:, 0]
            front = cpe < 0  # edges facing the sensor (boxes are counter-clockwise)
            p, e, cpe = p[front], e[front], cpe[front]
            box_of_edge = np.repeat(np.arange(len(rel)), 4)[front]
            # Only the rays inside each edge's angular span can meet it: list those
            # (ray, edge) pairs instead of testing all rays against all edges.
            dth = 2 * np.pi / rays
            az_p = np.arctan2(p[:, 1], p[:, 0])
            q = p + e
            az_q = np.arctan2(q[:, 1], q[:, 0])  # front edges run clockwise: span [az_q, az_p]
            width = np.mod(az_p - az_q, 2 * np.pi)
            k0 = np.ceil(az_q / dth - 1e-9).astype(np.intp)
            k1 = np.floor((az_q + width) / dth + 1e-9).astype(np.intp)
            n_e = np.maximum(k1 - k0 + 1, 0)
            e_i = np.repeat(np.arange(len(p)), n_e)
            first = np.cumsum(n_e) - n_e
            r_i = np.mod(np.repeat(k0 - first, n_e) + np.arange(len(e_i)), rays)
            ux, uy = self._ray_cos[r_i], self._ray_sin[r_i]
            den = ux * e[e_i, 1] - uy * e[e_i, 0]  # cross(u, e)
            num = p[e_i, 0] * uy - p[e_i, 1] * ux  # cross(p, u)
            # The ray meets the face iff den < 0 and 0 <= num/den <= 1; then t = cpe/den.
            ok = (den < 0) & (num <= 0) & (num >= den)
            r_i, e_i, den = r_i[ok], e_i[ok], den[ok]
            t = cpe[e_i] / den
            keep = t <= cfg.lidar_range_m
            r_i, e_i, t = r_i[keep], e_i[keep], t[keep]
            if len(t):
                order = np.lexsort((t, r_i))  # by ray, nearest face first
                r_i, t = r_i[order], t[order]
                height = rel.height_m[box_of_edge[e_i[order]]]
                h = cfg.lidar_height_m
                # Beams whose height at the face, h + t·tan(el), lies in [0, height].
                k_lo = np.searchsorted(self._tan_el, -h / t, side="left")
                k_hi = np.searchsorted(self._tan_el, (height - h) / t, side="right")
                k = np.arange(beams)
                span = (k >= k_lo[:, None]) & (k < k_hi[:, None])  # [n, K]
                # A beam stops at the first face (in range order) on its ray that spans it.
                cum = np.cumsum(span, axis=0, dtype=np.int32)
                first = np.flatnonzero(np.r_[True, r_i[1:] != r_i[:-1]])
                start = np.repeat(first, np.diff(np.r_[first, len(r_i)]))
                base = cum[start - 1] * (start > 0)[:, None]
                claimed = span & (cum - span == base)
                ii, kk = np.nonzero(claimed)
                blocked_rk = r_i[ii] * beams + kk
                hit_t, hit_ray = t, r_i
        return _Returns(hit_t, hit_ray, claimed, blocked_rk)

    def _ground(self, bits: np.ndarray, ret: _Returns) -> np.ndarray:
        """bool [G]: which precomputed ground returns exist (on the road, not blocked)."""
        free = np.ones(len(self._rk_to_g), dtype=bool)
        free[ret.blocked_rk] = False
        return free.take(self._g_rk) & ((bits.take(self._g_cell) & DRIVABLE) != 0)

    def _lidar_from(self, bits: np.ndarray, rel: Boxes) -> np.ndarray:
        cfg = self.cfg
        n = cfg.size_px
        hw = n * n
        ret = self._returns(bits, rel)
        # Ground returns: all of a drivable cell's, less those a face blocks.
        drivable = (bits & DRIVABLE) != 0
        low = self._g_count * drivable
        g = self._rk_to_g[ret.blocked_rk]
        blocked_cells = self._g_cell[g[g >= 0]]
        low -= np.bincount(blocked_cells[drivable[blocked_cells]], minlength=hw)
        high = np.zeros(hw, np.int64)
        if len(ret.hit_t):
            # All beams of one (ray, face) hit land in the same cell: count them per hit.
            h = cfg.lidar_height_m
            k_split = np.searchsorted(self._tan_el, (cfg.lidar_split_height_m - h) / ret.hit_t)
            below = np.arange(len(self._tan_el))[None, :] < k_split[:, None]
            n_low = np.count_nonzero(ret.claimed & below, axis=1)
            n_high = np.count_nonzero(ret.claimed & ~below, axis=1)
            row, col = cfg.cell_of(
                ret.hit_t * self._ray_cos[ret.hit_ray], ret.hit_t * self._ray_sin[ret.hit_ray]
            )
            row, col = np.floor(row).astype(np.intp), np.floor(col).astype(np.intp)
            inside = (row >= 0) & (row < n) & (col >= 0) & (col < n)
            cell = (row * n + col)[inside]
            low += np.bincount(cell, weights=n_low[inside], minlength=hw).astype(np.int64)
            high += np.bincount(cell, weights=n_high[inside], minlength=hw).astype(np.int64)
        out = np.empty((2, hw), dtype=np.uint8)
        np.minimum(low, 255, out=out[0], casting="unsafe")
        np.minimum(high, 255, out=out[1], casting="unsafe")
        return out.reshape(2, n, n)


@dataclass(frozen=True)
class _Returns:
    hit_t: np.ndarray
    """[n] range of each (ray, face) intersection, sorted by ray then range."""
    hit_ray: np.ndarray
    """[n] ray index of each intersection."""
    claimed: np.ndarray
    """bool [n, K]: beams (sorted by elevation) that stop on that face."""
    blocked_rk: np.ndarray
    """int: ``ray · K + beam`` of every beam that stops on a face (each at most once)."""
