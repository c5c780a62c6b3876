"""Oriented-box collisions and the off-road test on hand-built cases."""

from __future__ import annotations

import numpy as np
import pytest

from priqn.env.geometry import (
    DRIVABLE,
    MARKING,
    ROUTE,
    Boxes,
    MapRaster,
    boxes_corners,
    footprint_points,
    is_off_road,
    obb_overlap,
    off_road,
    off_road_fraction,
)
from priqn.errors import PriqnError

CAR_L, CAR_W = 4.5, 1.8


def car(
    x: float, y: float, heading: float = 0.0, length: float = CAR_L, width: float = CAR_W
) -> Boxes:
    return Boxes.make([x, y], heading, length, width)


def overlaps(a: Boxes, b: Boxes) -> bool:
    out = obb_overlap(a, b)
    assert out.shape == (1,)
    return bool(out[0])


# ----------------------------------------------------------------------------- boxes


def test_corners_counter_clockwise_from_front_right():
    c = boxes_corners(
        np.array([[1.0, 2.0]]), np.array([np.pi / 2]), np.array([4.0]), np.array([2.0])
    )
    # Heading north: front is +y, right is +x.
    np.testing.assert_allclose(c[0], [[2, 4], [0, 4], [0, 0], [2, 0]], atol=1e-12)


def test_adjacent_lanes_overlap_by_10cm_collides_and_10cm_apart_does_not():
    ego = car(0.0, 0.0)
    assert overlaps(ego, car(1.0, CAR_W - 0.1))  # side by side, 10 cm into each other
    assert not overlaps(ego, car(1.0, CAR_W + 0.1))  # 10 cm gap
    assert not overlaps(ego, car(0.0, CAR_W))  # exactly touching is not a collision


def test_head_on_in_the_opposite_lane():
    ego = car(0.0, 0.0)
    assert overlaps(ego, car(CAR_L - 0.1, 0.0, np.pi))
    assert not overlaps(ego, car(CAR_L + 0.1, 0.0, np.pi))
    # Ego half in the opposite lane, oncoming car centred in it (3.5 m lanes).
    assert overlaps(car(0.0, 1.75), car(4.0, 3.5, np.pi))
    assert not overlaps(car(0.0, 0.0), car(4.0, 3.5, np.pi))


def test_rotated_boxes_where_axis_aligned_boxes_would_be_wrong():
    # Two long thin boxes along the diagonal, 1.2 m apart centre to centre across it
    # (width 1 m each -> 0.2 m gap): their axis-aligned bounds overlap a lot.
    d = np.array([np.sqrt(0.5), -np.sqrt(0.5)])  # unit normal of the diagonal
    a = Boxes.make([0.0, 0.0], np.pi / 4, 6.0, 1.0)
    b = Boxes.make(1.2 * d, np.pi / 4, 6.0, 1.0)
    assert not overlaps(a, b)
    assert overlaps(a, Boxes.make(0.9 * d, np.pi / 4, 6.0, 1.0))
    # T-bone at 90° near a corner: the corner of the crossing car just inside.
    ego = car(0.0, 0.0)
    assert overlaps(ego, car(CAR_L / 2 + CAR_W / 2 - 0.05, CAR_W / 2 + CAR_L / 2 - 0.05, np.pi / 2))
    assert not overlaps(ego, car(CAR_L / 2 + CAR_W / 2 + 0.05, 0.0, np.pi / 2))
    # A box rotated by 45° whose corner points at the ego's side, 5 cm away / 5 cm in.
    half_diag = np.hypot(1.0, 1.0)
    assert not overlaps(ego, Boxes.make([0.0, CAR_W / 2 + half_diag + 0.05], np.pi / 4, 2.0, 2.0))
    assert overlaps(ego, Boxes.make([0.0, CAR_W / 2 + half_diag - 0.05], np.pi / 4, 2.0, 2.0))


def _reference_overlap(p: np.ndarray, q: np.ndarray) -> bool:
    """Convex polygons overlap iff an edge pair crosses or a vertex lies inside the other."""

    def inside(pt, poly):
        cross = [
            (poly[(i + 1) % 4][0] - poly[i][0]) * (pt[1] - poly[i][1])
            - (poly[(i + 1) % 4][1] - poly[i][1]) * (pt[0] - poly[i][0])
            for i in range(4)
        ]
        return all(c > 0 for c in cross)

    def crosses(a, b, c, d):
        def orient(p1, p2, p3):
            return (p2[0] - p1[0]) * (p3[1] - p1[1]) - (p2[1] - p1[1]) * (p3[0] - p1[0])

        return orient(a, b, c) * orient(a, b, d) < 0 and orient(c, d, a) * orient(c, d, b) < 0

    if any(inside(v, q) for v in p) or any(inside(v, p) for v in q):
        return True
    return any(
        crosses(p[i], p[(i + 1) % 4], q[j], q[(j + 1) % 4]) for i in range(4) for j in range(4)
    )


def test_sat_agrees_with_an_independent_polygon_test():
    rng = np.random.default_rng(0)
    m = 400
    others = Boxes.make(
        rng.uniform(-6, 6, (m, 2)),
        rng.uniform(-np.pi, np.pi, m),
        rng.uniform(0.5, 8, m),
        rng.uniform(0.5, 3, m),
    )
    ego = Boxes.make([0.3, -0.2], 0.7, CAR_L, CAR_W)
    got = obb_overlap(ego, others)
    want = [_reference_overlap(ego.corners()[0], c) for c in others.corners()]
    assert 50 < got.sum() < m - 50  # both outcomes well represented
    np.testing.assert_array_equal(got, want)


def test_empty_and_bad_inputs():
    assert obb_overlap(car(0, 0), Boxes.empty()).shape == (0,)
    with pytest.raises(ValueError, match="one ego box"):
        obb_overlap(Boxes.empty(), car(0, 0))
    with pytest.raises(ValueError, match="length_m"):
        Boxes.make([0, 0], 0.0, -1.0, 1.0)


# ----------------------------------------------------------------------------- map raster


def two_way_road(res: float = 0.1) -> MapRaster:
    """A straight road along x in [0, 100]: two lanes each way, 3.5 m wide, y in [-7, 7]."""
    lanes = [
        np.array([[0, y0], [100, y0], [100, y0 + 3.5], [0, y0 + 3.5]]) for y0 in (-7, -3.5, 0, 3.5)
    ]
    marks = [np.array([[0, y], [100, y]]) for y in (-7, -3.5, 0, 3.5, 7)]
    return MapRaster.from_roadmap_arrays(lanes, marks, resolution_m=res, marking_width_m=0.2)


def test_raster_resolution_at_the_kerb():
    road = two_way_road(0.1)
    assert road.drivable(np.array([[50.0, 6.85], [50.0, -6.85], [0.15, 0.0]])).all()
    assert not road.drivable(
        np.array([[50.0, 7.15], [50.0, -7.15], [-0.15, 0.0], [500.0, 0.0]])
    ).any()
    bits = road.lookup(np.array([[50.0, 3.5], [50.0, 2.0]]))
    assert bits[0] & MARKING and bits[0] & DRIVABLE and not bits[1] & MARKING


def test_straddling_two_lanes_and_the_opposite_lane_are_on_road():
    road = two_way_road()
    assert not is_off_road(road, car(50.0, -3.5))  # across the two right-hand lanes
    assert not is_off_road(road, car(50.0, 1.75, np.pi))  # wrong way in the opposite lane
    assert not is_off_road(road, car(50.0, 0.0, 0.3))  # at an angle across the centre line


def test_one_corner_over_the_kerb_is_off_road():
    road = two_way_road()
    ego = car(50.0, -6.0, -0.15)  # rotated right: the front-right corner pokes over y = -7
    corners = ego.corners()[0]
    assert corners[:, 1].min() < -7.1 and np.sum(corners[:, 1] < -7.0) == 1
    assert is_off_road(road, ego)
    assert off_road_fraction(road, ego, samples_per_edge=1)[0] == pytest.approx(1 / 8)
    # Tolerating one point in eight keeps it on the road; fully off is off either way.
    assert not is_off_road(road, ego, max_off_fraction=0.2)
    assert is_off_road(road, car(50.0, -12.0), max_off_fraction=0.2)


def test_edge_samples_catch_a_concave_kerb_between_the_corners():
    from priqn.env.sensors import synthetic_crossroads

    polys, marks, _ = synthetic_crossroads(lane_width_m=3.5)
    junction = MapRaster.from_roadmap_arrays(polys, marks, resolution_m=0.1)
    # A 12 m long box across the kerb corner at (3.5, 3.5): corners on the east and north
    # arms, the middle of both long edges over the pavement.
    box = Boxes.make([4.0, 4.0], -np.pi / 4, 12.0, 0.5)
    assert junction.drivable(box.corners()[0]).all()
    assert footprint_points(box, samples_per_edge=0).shape == (1, 4, 2)
    assert not is_off_road(junction, box, samples_per_edge=0)
    assert is_off_road(junction, box, samples_per_edge=1)


def test_junction_corner_cut_is_off_road():
    from priqn.env.sensors import synthetic_crossroads

    polys, marks, _ = synthetic_crossroads(lane_width_m=3.5)
    junction = MapRaster.from_roadmap_arrays(polys, marks, resolution_m=0.1)
    assert not is_off_road(junction, car(0.0, 0.0, np.pi / 4))  # diagonal in the junction box
    assert not is_off_road(junction, car(-1.75, 10.0, np.pi / 2))  # on an arm
    assert is_off_road(junction, car(4.2, 4.2, np.pi / 4))  # cutting the kerb corner


def test_route_bit_on_a_copy():
    road = two_way_road(0.2)
    routed = road.with_route(np.array([[0.0, -1.75], [100.0, -1.75]]), width_m=3.5)
    assert not (road.bits & ROUTE).any()
    on = routed.lookup(np.array([[50.0, -1.75], [50.0, -0.2], [50.0, -3.3]]))
    off = routed.lookup(np.array([[50.0, 1.75], [50.0, -5.0]]))
    assert (on & ROUTE).all() and not (off & ROUTE).any()
    np.testing.assert_array_equal(routed.bits & ~ROUTE, road.bits)


def test_empty_map_is_a_user_error():
    with pytest.raises(PriqnError, match="no lane polygon"):
        MapRaster.from_roadmap_arrays([np.zeros((2, 2))], [])
    with pytest.raises(PriqnError, match="too large"):
        MapRaster.from_roadmap_arrays(
            [np.array([[0, 0], [1e5, 0], [1e5, 1e5]])], [], resolution_m=0.1
        )


def test_off_road_vectorised_over_poses_matches_single_calls():
    road = two_way_road()
    rng = np.random.default_rng(2)
    m = 200
    poses = Boxes.make(
        np.c_[rng.uniform(-2, 102, m), rng.uniform(-9, 9, m)],
        rng.uniform(-np.pi, np.pi, m),
        CAR_L,
        CAR_W,
    )
    batch = off_road(road, poses)
    single = [is_off_road(road, poses[i]) for i in range(m)]
    np.testing.assert_array_equal(batch, single)
    assert 20 < batch.sum() < m - 20
    pts = footprint_points(poses[:3], samples_per_edge=2)
    assert pts.shape == (3, 12, 2)
    np.testing.assert_allclose(pts[:, ::3], poses[:3].corners(), atol=1e-12)  # corners first
