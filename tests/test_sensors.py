"""BEV and LiDAR grids: known poses land on hand-computed cells; alignment; occlusion."""

from __future__ import annotations

import numpy as np
import pytest

from priqn.env import sensor_kernels
from priqn.env.geometry import Boxes, MapRaster
from priqn.env.sensors import (
    BEV_CHANNELS,
    SensorConfig,
    Sensors,
    benchmark_observation,
    synthetic_crossroads,
)

# Default grid: 128 cells over 64 m -> 0.5 m per cell; 48 m ahead, 16 m behind, 32 m each side.
# Cell of ego-frame point (fwd, left): row = floor((48 - fwd) / 0.5), col = floor((32 - left) / 0.5).

EGO_XY = np.array([100.0, 50.0])
EGO_H = np.radians(30.0)


def to_world(fwd: float, left: float) -> np.ndarray:
    c, s = np.cos(EGO_H), np.sin(EGO_H)
    return EGO_XY + fwd * np.array([c, s]) + left * np.array([-s, c])


def ego_box(xy=EGO_XY, heading=EGO_H) -> Boxes:
    return Boxes.make(xy, heading, 4.5, 1.8, 1.5)


def big_plaza() -> MapRaster:
    """Everything within 100 m of the ego is drivable."""
    sq = np.array([[-100, -100], [100, -100], [100, 100], [-100, 100]], float) + EGO_XY
    return MapRaster.from_roadmap_arrays([sq], [], resolution_m=0.25)


def cells(mask: np.ndarray) -> set[tuple[int, int]]:
    return {(int(r), int(c)) for r, c in zip(*np.nonzero(mask), strict=True)}


def block(rows: range, cols: range) -> set[tuple[int, int]]:
    return {(r, c) for r in rows for c in cols}


def test_vehicle_at_known_relative_pose_in_bev_and_lidar():
    sensors = Sensors(SensorConfig())
    # 4 m x 2 m car, 10.1 m ahead and 3.6 m to the left, same heading as the ego:
    # footprint fwd in [8.1, 12.1], left in [2.6, 4.6].
    actor = Boxes.make(to_world(10.1, 3.6), EGO_H, 4.0, 2.0, 1.5)
    bev, lidar = sensors.observe(big_plaza(), ego_box(), actor)
    assert bev.shape == (4, 128, 128) and bev.dtype == np.uint8
    assert lidar.shape == (2, 128, 128) and lidar.dtype == np.uint8
    actors = bev[sensors.cfg.bev_channels.index("actors")]
    # Cell centres inside: fwd = 48 - (r + .5)/2 in [8.1, 12.1] -> r = 72..79;
    # left = 32 - (c + .5)/2 in [2.6, 4.6] -> c = 55..58.
    assert cells(actors == 255) == block(range(72, 80), range(55, 59))
    assert set(np.unique(actors)) == {0, 255}
    # LiDAR face returns lie on the visible faces: the rear face fwd = 8.1 (row 79,
    # cols 54..58) and the right face left = 2.6 (col 58, rows 71..79).
    high = cells(lidar[1] > 0)
    assert high and high <= block(range(71, 80), range(54, 59))
    assert (79, 56) in high and (75, 58) in high
    # Nothing sees the ground under the car or behind it (cells strictly inside).
    assert lidar[0, 73:79, 55:58].sum() == 0 and lidar[1, 73:79, 55:58].sum() == 0
    # The road all around gets ground returns in the low bin only.
    assert lidar[0].sum() > 1000 and lidar[1][~actors.astype(bool)].sum() <= lidar[1].sum()


def test_map_channels_at_known_pixels():
    sensors = Sensors(SensorConfig())
    # A 10 m wide road along the ego heading (|left| <= 5), markings on its centre line.
    corners = [to_world(f, lft) for f, lft in ((-40, -5), (60, -5), (60, 5), (-40, 5))]
    centre = np.array([to_world(-40, 0), to_world(60, 0)])
    raster = MapRaster.from_roadmap_arrays(
        [np.array(corners)], [centre], resolution_m=0.1, marking_width_m=sensors.cfg.marking_width_m
    )
    raster = raster.with_route(np.array([to_world(0, -1.75), to_world(60, -1.75)]), 3.5)
    bev = sensors.bev(raster, ego_box(), Boxes.empty())
    drivable, markings, route, actors = bev
    # Column centres: left = 32 - (c + .5)/2; |left| < 5 for c = 54..73.
    assert (drivable[:, 54:74] == 255).all()
    assert (drivable[:, :53] == 0).all() and (drivable[:, 75:] == 0).all()
    # Centre line left = 0 between columns 63 and 64; drawn 1.25 cells = 0.625 m wide.
    assert (markings[:, 63:65].max(axis=1) == 255).all()
    assert (markings[:, :62] == 0).all() and (markings[:, 66:] == 0).all()
    # Route: left in [-3.5, 0] -> columns 64..71, only ahead of fwd = 0 (row 96 and up).
    assert (route[:90, 65:71] == 255).all() and (route[100:, :] == 0).all()
    assert (route[:, :63] == 0).all() and (route[:, 73:] == 0).all()
    assert not actors.any()


def test_footprints_not_centre_cells_and_thin_obstacles_stay_visible():
    sensors = Sensors(SensorConfig(size_px=64))  # 1 m per cell
    bus = Boxes.make(to_world(20.0, 0.0), EGO_H, 12.0, 2.5)
    bev = sensors.bev(big_plaza(), ego_box(), bus)
    assert (bev[3] > 0).sum() >= 12 * 2  # a whole footprint, not one cell
    post = Boxes.make(to_world(10.3, -5.3), 0.4, 0.3, 0.3)  # a 30 cm bollard
    bev = sensors.bev(big_plaza(), ego_box(), post)
    # Cell of (10.3, -5.3): row floor(37.7) = 37, col floor(37.3) = 37.
    assert cells(bev[3] > 0) >= {(37, 37)} and (bev[3] > 0).sum() <= 4


def scene(rng: np.random.Generator, n: int = 25):
    polys, marks, centres = synthetic_crossroads()
    lane = rng.integers(0, len(centres), n)
    frac = rng.uniform(0.0, 0.5, n)
    p0 = np.array([centres[i][0] for i in lane])
    p1 = np.array([centres[i][1] for i in lane])
    xy = p0 + (p1 - p0) * frac[:, None]
    heading = np.arctan2((p1 - p0)[:, 1], (p1 - p0)[:, 0])
    actors = Boxes.make(
        xy, heading, rng.uniform(4, 12, n), rng.uniform(1.7, 2.5, n), rng.uniform(1.4, 3.5, n)
    )
    ego = Boxes.make([1.75, -15.0], np.pi / 2 + 0.1, 4.5, 1.8, 1.5)
    return polys, marks, actors, ego


def dilate(mask: np.ndarray) -> np.ndarray:
    """3x3 binary dilation."""
    p = np.pad(mask, 1)
    h, w = mask.shape
    return np.any([p[i : i + h, j : j + w] for i in range(3) for j in range(3)], axis=0)


def transform(xy, angle, shift):
    c, s = np.cos(angle), np.sin(angle)
    return np.asarray(xy) @ np.array([[c, s], [-s, c]]) + shift


def test_ego_alignment_rotating_the_world_and_ego_together():
    rng = np.random.default_rng(3)
    polys, marks, actors, ego = scene(rng)
    sensors = Sensors(SensorConfig())
    cfg = sensors.cfg
    route = np.array([[1.75, -60.0], [1.75, -4.0], [-1.0, 0.5], [-4.0, 1.75], [-60.0, 1.75]])
    raster0 = MapRaster.from_roadmap_arrays(polys, marks, 0.1, cfg.marking_width_m)
    bev0, lid0 = sensors.observe(raster0.with_route(route, 3.5), ego, actors)
    angle, shift = 1.234, np.array([523.0, -87.0])

    def moved(b: Boxes) -> Boxes:
        return Boxes.make(
            transform(b.center_xy, angle, shift),
            b.heading_rad + angle,
            b.length_m,
            b.width_m,
            b.height_m,
        )

    raster1 = MapRaster.from_roadmap_arrays(
        [transform(p, angle, shift) for p in polys],
        [transform(m, angle, shift) for m in marks],
        0.1,
        cfg.marking_width_m,
    )
    raster1 = raster1.with_route(transform(route, angle, shift), 3.5)
    bev1, lid1 = sensors.observe(raster1, moved(ego), moved(actors))
    # Pure geometry is identical; map channels differ only where the world raster aliases.
    np.testing.assert_array_equal(bev1[3], bev0[3])
    np.testing.assert_array_equal(lid1[1], lid0[1])
    for ch in range(3):
        a, b = bev0[ch] > 0, bev1[ch] > 0
        assert a.sum() > 100, cfg.bev_channels[ch]
        assert np.mean(a != b) < 0.02, cfg.bev_channels[ch]
        # Every difference lies within one cell of the same content in the other image.
        assert not (a & ~dilate(b)).any() and not (b & ~dilate(a)).any(), cfg.bev_channels[ch]
    assert np.mean(lid1[0] != lid0[0]) < 0.01
    assert (bev0[3] > 0).sum() > 100  # the scene really has actors in view


@pytest.mark.parametrize("front_height_m, behind_seen", [(3.5, False), (1.5, True)])
def test_occlusion(front_height_m: float, behind_seen: bool):
    sensors = Sensors(SensorConfig())
    front = Boxes.make(to_world(10.0, 0.0), EGO_H, 4.5, 1.8, front_height_m)
    behind = Boxes.make(to_world(20.0, 0.0), EGO_H, 4.5, 1.8, 1.5)
    both = Boxes.make(
        np.r_[front.center_xy, behind.center_xy], EGO_H, 4.5, 1.8, [front_height_m, 1.5]
    )
    lidar = sensors.lidar(big_plaza(), ego_box(), both)
    # Behind: fwd in [17.75, 22.25] -> rows 51..60; left in [-0.9, 0.9] -> cols 62..65.
    region = (slice(50, 62), slice(61, 67))
    assert lidar[0][region].sum() == 0  # no ground, no low face returns behind the front car
    if behind_seen:
        # Beams passing over a car as tall as... lower than the sensor hit the upper part of the
        # one behind: high bin only, and fewer than on the front car.
        assert 0 < lidar[1][region].sum() < lidar[1].sum() - lidar[1][region].sum()
    else:
        assert lidar[1][region].sum() == 0
    alone = sensors.lidar(big_plaza(), ego_box(), behind)
    assert alone[1][region].sum() > lidar[1][region].sum()


def test_lidar_grid_bins_the_point_cloud_and_saturates():
    rng = np.random.default_rng(5)
    polys, marks, actors, ego = scene(rng)
    sensors = Sensors(SensorConfig(size_px=64))
    cfg = sensors.cfg
    raster = MapRaster.from_roadmap_arrays(polys, marks, 0.2, cfg.marking_width_m)
    grid = sensors.lidar(raster, ego, actors)
    pts = sensors.lidar_points(raster, ego, actors)
    row, col = cfg.cell_of(pts[:, 0], pts[:, 1])
    row, col = np.floor(row).astype(int), np.floor(col).astype(int)
    ok = (row >= 0) & (row < 64) & (col >= 0) & (col < 64)
    want = np.zeros((2, 64, 64), int)
    np.add.at(want, ((pts[ok, 2] >= cfg.lidar_split_height_m).astype(int), row[ok], col[ok]), 1)
    np.testing.assert_array_equal(grid, np.minimum(want, 255))
    assert np.all(pts[:, 2] >= 0) and np.all(np.hypot(pts[:, 0], pts[:, 1]) <= cfg.lidar_range_m)
    # A tall wall 3 m ahead: hundreds of returns per cell saturate at 255 (no uint8 wrap).
    wall = Boxes.make(to_world(3.0, 0.0), EGO_H + np.pi / 2, 10.0, 0.5, 10.0)
    lidar = Sensors(SensorConfig()).lidar(big_plaza(), ego_box(), wall)
    assert lidar[1].max() == 255


def test_actor_speed_channel_and_render():
    cfg = SensorConfig(
        size_px=64, bev_channels=("drivable", "route", "actors", "actor_speed", "ego")
    )
    sensors = Sensors(cfg)
    actors = Boxes.make(np.array([to_world(10, 0), to_world(10, -8)]), EGO_H, 4.5, 1.8)
    bev, lidar = sensors.observe(
        big_plaza(), ego_box(), actors, actor_speed_mps=np.array([5.0, 40.0])
    )
    speed = bev[3]
    # Cells: fwd 10 -> row 38; left 0 / -8 -> col 32 / 40.
    assert speed[38, 32] == 1 + int(254 * 5 / 20) and speed[38, 40] == 255
    assert (bev[4] > 0).sum() == 4 * 2  # the ego: 4.5 x 1.8 m at 1 m cells -> 4 x 2 centres
    frame = sensors.render_rgb(bev, lidar, scale=2)
    assert frame.shape == (128, 256, 3) and frame.dtype == np.uint8
    assert tuple(frame[2 * 38, 2 * 32]) == (235, 70, 55)  # actor red
    with pytest.raises(ValueError, match="actor_speed_mps"):
        sensors.observe(big_plaza(), ego_box(), actors)


def test_config_validation_lists_valid_channels():
    with pytest.raises(ValueError, match="valid: " + ", ".join(BEV_CHANNELS)):
        SensorConfig(bev_channels=("drivable", "camera"))
    with pytest.raises(ValueError):
        SensorConfig(behind_m=100.0)


def test_no_actors_and_benchmark_smoke():
    sensors = Sensors(SensorConfig(size_px=32))
    bev, lidar = sensors.observe(big_plaza(), ego_box(), Boxes.empty())
    assert not bev[3].any() and not lidar[1].any() and lidar[0].any()
    out = benchmark_observation(size_px=32, n_actors=5, repeats=3)
    assert out["observe_ms_median"] > 0 and out["size_px"] == 32


def test_ray_casting_matches_a_naive_loop():
    rng = np.random.default_rng(11)
    polys, marks, actors, ego = scene(rng, n=30)
    sensors = Sensors(SensorConfig(size_px=64, lidar_rays=360))
    rel, _ = sensors._to_ego_frame(ego, actors, in_grid=False)
    hit_ray, hit_t, _ = sensors._face_hits(rel)
    got = np.full(360, np.inf)
    np.minimum.at(got, hit_ray, hit_t)
    want = np.full(360, np.inf)
    for k in range(360):
        u = np.array([np.cos(2 * np.pi * k / 360), np.sin(2 * np.pi * k / 360)])
        for box in rel.corners():
            for a, b in zip(box, np.roll(box, -1, axis=0), strict=True):
                m = np.array([u, a - b]).T  # t·u = a + s·(b − a)
                if abs(np.linalg.det(m)) < 1e-12:
                    continue
                t, s = np.linalg.solve(m, a)
                if t > 0 and 0 <= s <= 1 and t <= sensors.cfg.lidar_range_m:
                    want[k] = min(want[k], t)
    assert np.isfinite(want).sum() > 30
    np.testing.assert_allclose(got, want, rtol=1e-9)


# ----------------------------------------------------------------------------- fast == reference
# The sensors were rewritten for speed (issue 38); their first implementation is kept in
# priqn/bench/references/sensors.py. Observations must not change: byte for byte, on
# synthetic scenes of every kind and on real env states at every density, on the numpy
# path and on the compiled one (priqn/env/sensor_kernels.py, numba).

PATHS = [
    pytest.param(False, id="numpy"),
    pytest.param(
        True,
        id="compiled",
        marks=pytest.mark.skipif(not sensor_kernels.AVAILABLE, reason="numba not installed"),
    ),
]


def _assert_same_observation(new: Sensors, ref, raster, ego, actors, speed=None) -> None:
    bev, lidar = new.observe(raster, ego, actors, speed)
    bev_ref, lidar_ref = ref.observe(raster, ego, actors, speed)
    assert bev.dtype == bev_ref.dtype == lidar.dtype == lidar_ref.dtype == np.uint8
    assert bev.shape == bev_ref.shape and lidar.shape == lidar_ref.shape
    assert np.array_equal(bev, bev_ref), "BEV differs from the reference"
    assert np.array_equal(lidar, lidar_ref), "LiDAR grid differs from the reference"


@pytest.mark.parametrize(
    "cfg",
    [
        SensorConfig(size_px=64),
        SensorConfig(size_px=128),
        SensorConfig(size_px=32, bev_channels=tuple(BEV_CHANNELS)),
        SensorConfig(size_px=48, lidar_rays=360, lidar_beams=80, lidar_split_height_m=1.2),
        SensorConfig(size_px=64, extent_m=40.0, behind_m=0.0, lidar_range_m=25.0),
    ],
    ids=["64px", "128px", "32px-all-channels", "80-beams", "short-range"],
)
@pytest.mark.parametrize("compiled", PATHS)
def test_fast_sensors_equal_the_reference_on_synthetic_scenes(
    cfg: SensorConfig, compiled: bool
) -> None:
    from priqn.bench.references.sensors import ReferenceSensors

    rng = np.random.default_rng(38)
    new, ref = Sensors(cfg, compiled=compiled), ReferenceSensors(cfg)
    assert new.compiled == compiled
    polys, marks, centres = synthetic_crossroads()
    raster = MapRaster.from_roadmap_arrays(polys, marks, 0.2, cfg.marking_width_m)
    raster = raster.with_route(np.array([[-60.0, -1.75], [60.0, -1.75]]), 3.5)
    for trial in range(40):
        n = int(rng.integers(0, 40))
        ego = Boxes.make(rng.uniform(-20, 20, 2), rng.uniform(-np.pi, np.pi), 4.5, 1.8, 1.5)
        # Anywhere around the ego (on top of it, touching it, far away), any size; a few
        # thin bollards and tall trucks.
        xy = ego.center_xy[0] + rng.uniform(-70, 70, (n, 2)) * rng.uniform(0.05, 1.0, (n, 1))
        length = np.where(rng.random(n) < 0.1, 0.2, rng.uniform(3.0, 14.0, n))
        actors = Boxes.make(
            xy, rng.uniform(-np.pi, np.pi, n), length, rng.uniform(0.2, 2.6, n),
            rng.choice([0.3, 1.5, 2.0, 4.0], n),
        )  # fmt: skip
        if trial % 5 == 0 and n:  # axis-aligned, on the ego's own heading: exact ties
            actors = Boxes.make(
                np.round(actors.center_xy), ego.heading_rad[0], 4.0, 2.0, actors.height_m
            )
        _assert_same_observation(new, ref, raster, ego, actors, rng.uniform(0, 25, n))
        if trial % 8 == 0:
            np.testing.assert_array_equal(
                new.lidar_points(raster, ego, actors), ref.lidar_points(raster, ego, actors)
            )


@pytest.mark.parametrize("compiled", PATHS)
def test_footprint_edges_through_cell_centres_count_as_inside(compiled: bool) -> None:
    """A box is closed: cell centres on its edges are inside, on both paths."""
    from priqn.bench.references.sensors import ReferenceSensors

    cfg = SensorConfig(size_px=64)  # 1 m cells; centres at fwd 48 - (r + .5), left 32 - (c + .5)
    ego = Boxes.make([0.0, 0.0], 0.0, 4.5, 1.8, 1.5)  # heading 0: the ego frame is exact
    # 4 m x 2 m at fwd 10.5, left 0.5: edges at fwd 8.5 / 12.5 (rows 39 / 35) and left
    # -0.5 / 1.5 (columns 32 / 30), each through a row or column of cell centres.
    car = Boxes.make([10.5, 0.5], 0.0, 4.0, 2.0, 1.5)
    for sensors in (Sensors(cfg, compiled=compiled), ReferenceSensors(cfg)):
        bev = sensors.bev(big_plaza(), ego, car)
        assert cells(bev[3] == 255) == block(range(35, 40), range(30, 33))


@pytest.mark.parametrize("density", [0.5, 0.75, 1.0])
@pytest.mark.parametrize("compiled", PATHS)
def test_fast_sensors_equal_the_reference_on_env_states(density: float, compiled: bool) -> None:
    """Seeded episodes of the real env: every observation of every step, both ways."""
    from priqn.bench.references.sensors import ReferenceSensors
    from priqn.env.config import EnvConfig
    from priqn.env.intersection import IntersectionEnv

    env = IntersectionEnv(EnvConfig(family="all", obs_size_px=64, max_episode_steps=30))
    new = Sensors(env._sensors.cfg, compiled=compiled)
    ref = ReferenceSensors(env._sensors.cfg)
    fast = env._sensors.observe
    seen = []

    def both(raster, ego, actors, speed=None):
        _assert_same_observation(new, ref, raster, ego, actors, speed)
        seen.append(len(actors))
        return fast(raster, ego, actors, speed)

    env._sensors.observe = both
    policy = np.random.default_rng(int(density * 100))
    try:
        for seed, net in enumerate(env.net_pool[:3]):
            env.reset(seed=seed, options={"net": net, "density": density})
            for _ in range(30):
                _, _, term, trunc, _ = env.step(int(policy.integers(env.action_space.n)))
                if term or trunc:
                    break
    finally:
        env.close()
    assert len(seen) >= 15 and max(seen) >= 3  # observations with traffic in them


def test_without_numba_the_numpy_path_runs(monkeypatch) -> None:
    """numba missing: the default is the numpy path; asking for the compiled one says why."""
    monkeypatch.setattr(sensor_kernels, "AVAILABLE", False)
    assert Sensors(SensorConfig(size_px=16)).compiled is False
    with pytest.raises(ImportError, match="needs numba: pip install numba"):
        Sensors(SensorConfig(size_px=16), compiled=True)
