"""The scene pool: one parse per net, cached route rasters, obstacle sites (no libsumo)."""

from __future__ import annotations

import numpy as np
import pytest

from priqn.env.geometry import ROUTE
from priqn.env.scenes import ScenePool
from priqn.errors import PriqnError

NET = "tjunction/tjunction_00"


@pytest.fixture(scope="module")
def pool() -> ScenePool:
    return ScenePool("tjunction", "", marking_width_m=0.5)


def test_a_scene_is_built_once_and_its_routes_drawn_once(pool, monkeypatch) -> None:
    scene = pool.scene(NET)
    assert pool.scene(NET) is scene
    route, other = scene.roadmap.ego_routes[:2]
    raster = scene.route_raster(route)
    assert not np.array_equal(scene.route_raster(other).bits, raster.bits)
    want = scene.raster.with_route(route.reference_xy, route.lane_width_m)
    np.testing.assert_array_equal(raster.bits, want.bits)
    assert (raster.bits & ROUTE).any() and not (scene.raster.bits & ROUTE).any()
    # Drawn once per (net, route): later calls only copy and set the cached cells.
    monkeypatch.setattr(type(scene.raster), "with_route", lambda *a, **k: 1 / 0)
    again = scene.route_raster(route)
    assert again is not raster and again.bits is not raster.bits
    np.testing.assert_array_equal(again.bits, want.bits)


def test_obstacle_sites_keep_clear_of_the_junction_and_the_ego_start(pool) -> None:
    scene = pool.scene(NET)
    route = scene.roadmap.ego_routes[0]
    sites = scene.obstacle_sites(route, 25.0)
    assert sites
    for site in sites:
        lane = scene.roadmap.lanes[site.lane_id]
        assert site.lane_index == 0 and site.width_m == lane.width_m
        assert 0.0 <= site.s_min_m < site.s_max_m <= lane.length_m
        assert site.s_max_m - site.s_min_m > 10.0
        if site.edge_id == route.edges[0]:
            assert site.s_min_m >= route.start_pos_m + 25.0
            assert site.s_max_m <= lane.length_m - 25.0


def test_an_unknown_net_in_the_pool_is_one_line(pool) -> None:
    with pytest.raises(PriqnError, match="no such net") as exc:
        pool.scene("tjunction/nope_99")
    assert "\n" not in str(exc.value)
