"""Bring your own net: plain netconvert nets, several junctions, EnvConfig(nets=...), --net FILE.

The example nets are built from ``examples/own_net/*.{nod,edg}.xml`` with the
``netconvert`` of the ``eclipse-sumo`` package, as docs/your-own-net.md shows.
"""

from __future__ import annotations

import json
import multiprocessing
import subprocess
from pathlib import Path

import pytest
import sumolib

from priqn.env.scenes import own_net_files
from priqn.errors import PriqnError
from priqn.sim import sumo
from priqn.sim.roadmap import RoadMap, arms, find_junction
from priqn.sim.scenario import list_nets, net_path

EXAMPLES = Path(__file__).resolve().parent.parent / "examples" / "own_net"


def netconvert(name: str, out_dir: Path) -> Path:
    out = out_dir / f"{name}.net.xml"
    subprocess.run(
        [
            str(sumo.binary("netconvert")),
            "--node-files", str(EXAMPLES / f"{name}.nod.xml"),
            "--edge-files", str(EXAMPLES / f"{name}.edg.xml"),
            "-o", str(out),
        ],
        check=True,
        capture_output=True,
    )  # fmt: skip
    return out


@pytest.fixture(scope="module")
def own(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("own")
    for name in ("tjunction", "grid"):
        netconvert(name, d)
    # A straight road: two nodes, no intersection.
    (d / "road.nod.xml").write_text(
        '<nodes><node id="a" x="0" y="0"/><node id="b" x="200" y="0"/></nodes>'
    )
    (d / "road.edg.xml").write_text(
        '<edges><edge id="ab" from="a" to="b"/><edge id="ba" from="b" to="a"/></edges>'
    )
    subprocess.run(
        [str(sumo.binary("netconvert")), "-n", str(d / "road.nod.xml"), "-e",
         str(d / "road.edg.xml"), "-o", str(d / "road.net.xml")],
        check=True, capture_output=True,
    )  # fmt: skip
    return d


def test_plain_netconvert_t_junction_is_accepted(own: Path) -> None:
    net = sumolib.net.readNet(str(own / "tjunction.net.xml"))
    # netconvert makes the arm tips 'priority' nodes, not dead ends: they still are no junction.
    assert {n.getID(): n.getType() for n in net.getNodes()}["W"] == "priority"
    rm = RoadMap.load(own / "tjunction.net.xml")
    assert rm.junction_id == "C"
    assert sorted(r.name for r in rm.ego_routes) == [
        "E2C->C2S", "E2C->C2W", "S2C->C2E", "S2C->C2W", "W2C->C2E", "W2C->C2S",
    ]  # fmt: skip
    assert set(rm.commands()) == {"left", "straight", "right"}


def test_several_junctions_pick_the_busiest_or_the_given_one(own: Path) -> None:
    rm = RoadMap.load(own / "grid.net.xml")
    assert rm.junction_id == "A"  # 4 approaches beat B's 3
    assert {r.edges[0] for r in rm.ego_routes} == {"W2A", "N2A", "S2A", "B2A"}
    assert not any(lane.startswith(":B_") for lane in rm.lane_ids)  # only A's internal lanes
    b = RoadMap.load(own / "grid.net.xml", junction="B")
    assert b.junction_id == "B" and {r.edges[0] for r in b.ego_routes} == {"A2B", "E2B", "BS2B"}
    with pytest.raises(PriqnError) as info:
        RoadMap.load(own / "grid.net.xml", junction="W")
    msg = str(info.value)
    assert "\n" not in msg and "junction 'W' is not an intersection" in msg and "A, B" in msg


def test_a_net_without_an_intersection_is_one_line(own: Path) -> None:
    with pytest.raises(PriqnError, match=r"road\.net\.xml: no intersection \(a node joining 3"):
        RoadMap.load(own / "road.net.xml")


@pytest.mark.parametrize("ref", list_nets())
def test_shipped_nets_keep_their_single_junction_and_every_edge(ref: str) -> None:
    path = net_path(ref)
    net = sumolib.net.readNet(str(path), withInternal=True)
    junction = find_junction(net, path)
    assert [n.getID() for n in net.getNodes() if len(arms(n)) >= 3] == [junction.getID()]
    rm = RoadMap.load(path)
    every_lane = {ln.getID() for e in net.getEdges(withInternal=True) for ln in e.getLanes()}
    assert set(rm.lane_ids) == every_lane


def test_env_nets_entries_are_checked(own: Path, tmp_path: Path) -> None:
    refs = own_net_files([str(own)])
    assert set(refs) == {f"{own.name}/tjunction", f"{own.name}/grid", f"{own.name}/road"}
    assert own_net_files([str(own / "grid.net.xml")]) == {f"{own.name}/grid": own / "grid.net.xml"}
    with pytest.raises(PriqnError, match="env.nets: .*nope.net.xml: no such file or folder"):
        own_net_files([str(tmp_path / "nope.net.xml")])
    with pytest.raises(PriqnError, match="holds no .net.xml file"):
        own_net_files([str(tmp_path)])
    (tmp_path / "x.txt").write_text("")
    with pytest.raises(PriqnError, match="is not a .net.xml file or a folder of them"):
        own_net_files([str(tmp_path / "x.txt")])


def _drive(net_file: str, queue: multiprocessing.Queue) -> None:
    from priqn.env.config import EnvConfig
    from priqn.env.intersection import IntersectionEnv

    env = IntersectionEnv(EnvConfig(nets=(net_file,), obs_size_px=32))
    obs, info = env.reset(seed=3)
    nets, steps = {info["net"]}, 0
    for _ in range(4):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        steps += 1
        if terminated or truncated:
            break
    env.close()
    queue.put((sorted(nets), steps, reward.shape, obs["bev"].shape))


def test_env_drives_an_own_net(own: Path) -> None:
    ctx = multiprocessing.get_context("spawn")  # libsumo: one simulation per process
    queue = ctx.Queue()
    proc = ctx.Process(target=_drive, args=(str(own / "tjunction.net.xml"), queue))
    proc.start()
    nets, steps, reward_shape, bev_shape = queue.get(timeout=120)
    proc.join(timeout=30)
    assert nets == [f"{own.name}/tjunction"] and steps >= 1
    assert reward_shape == (5,) and bev_shape[-1] == 32


def test_train_net_file_records_the_nets_with_their_hashes(own: Path, tmp_path: Path) -> None:
    import hashlib

    from priqn.run.folder import RunFolder
    from priqn.run.provenance import gather, own_nets_manifest
    from priqn.run.session import start_session
    from priqn.run.train_config import default_run_name, policy_labels, resolve_config

    def prepare(run: RunFolder, cfg, resume: bool) -> dict:
        return start_session(run, cfg, resume, False, gather(cfg), policy_labels(cfg))

    cfg = resolve_config(net=str(own / "grid.net.xml"), overrides=["env.junction=B"])
    assert cfg.env.nets == (str((own / "grid.net.xml").resolve()),)
    assert default_run_name(cfg).startswith("grid_pr-iqn_")
    run = RunFolder(tmp_path / "run")
    meta = prepare(run, cfg, resume=False)
    manifest = json.loads(run.nets_manifest_path.read_text())
    sha = hashlib.sha256((own / "grid.net.xml").read_bytes()).hexdigest()
    assert manifest["junction"] == "B"
    assert manifest["nets"] == [
        {
            "id": f"{own.name}/grid",
            "path": cfg.env.nets[0],
            "files": {"grid.net.xml": sha},
            "junction": "B",
        }
    ]
    assert len(meta["manifest_hashes"]["own"]) == 64
    # The junction used is recorded also when it is the default one.
    default = resolve_config(net=str(own / "grid.net.xml"))
    assert own_nets_manifest(default.env.nets, "")["nets"][0]["junction"] == "A"
    # A net that cannot be used stops the run before its folder is made.
    with pytest.raises(PriqnError, match=r"road\.net\.xml: no intersection"):
        prepare(RunFolder(tmp_path / "bad"), resolve_config(net=str(own / "road.net.xml")), False)
    assert not (tmp_path / "bad").exists()
    # A resume after a net file changed is refused in one line.
    run.latest_checkpoint.parent.mkdir(parents=True, exist_ok=True)
    run.latest_checkpoint.write_bytes(b"x")
    original = (own / "grid.net.xml").read_bytes()
    (own / "grid.net.xml").write_bytes(original + b"\n")
    try:
        with pytest.raises(PriqnError, match="a net of env.nets changed since the run started"):
            prepare(run, cfg, resume=True)
    finally:
        (own / "grid.net.xml").write_bytes(original)
    with pytest.raises(PriqnError, match="--net: .*nope.net.xml: no such file or folder"):
        resolve_config(net=str(tmp_path / "nope.net.xml"))


# --------------------------------------------------------------------------- car roads, the window, errors


def run_netconvert(out: Path, *args: str) -> Path:
    """The eclipse-sumo netconvert (found through the sumo package, no SUMO_HOME) → ``out``."""
    cmd = [sumo.binary("netconvert"), *args, "-o", str(out), "--no-warnings", "true"]
    res = subprocess.run(
        cmd, capture_output=True, text=True, env=sumo.subprocess_env(), timeout=120
    )
    assert res.returncode == 0, res.stderr
    return out


def write_net(folder: Path, stem: str, nodes: str, edges: str) -> Path:
    (folder / f"{stem}.nod.xml").write_text(f"<nodes>{nodes}</nodes>", encoding="utf-8")
    (folder / f"{stem}.edg.xml").write_text(f"<edges>{edges}</edges>", encoding="utf-8")
    nod, edg = str(folder / f"{stem}.nod.xml"), str(folder / f"{stem}.edg.xml")
    return run_netconvert(folder / f"{stem}.net.xml", "-n", nod, "-e", edg)


OSM_OPTIONS = (
    "--geometry.remove", "--roundabouts.guess", "--ramps.guess", "--junctions.join",
    "--tls.discard-loaded", "--remove-edges.isolated", "--keep-edges.by-vclass", "passenger",
    "--no-turnarounds", "--osm.sidewalks", "false",
)  # fmt: skip
"""The OSM options docs/your-own-net.md gives."""


def test_clip_polygon_and_polyline_to_a_box() -> None:
    import numpy as np

    from priqn.sim.geometry import clip_polygon, clip_polyline

    box = (0.0, 0.0, 10.0, 10.0)
    inside = np.array([[1.0, 1.0], [9.0, 1.0], [9.0, 9.0]])
    assert clip_polygon(inside, box) is inside  # untouched inside (generated nets)
    square = np.array([[5.0, 5.0], [15.0, 5.0], [15.0, 15.0], [5.0, 15.0]])
    assert {tuple(p) for p in clip_polygon(square, box)} == {(5, 5), (10, 5), (10, 10), (5, 10)}
    assert len(clip_polygon(square + 20.0, box)) == 0
    # Out and back in: two pieces, cut at the side.
    pieces = clip_polyline(np.array([[2.0, 5.0], [12.0, 5.0], [12.0, 8.0], [2.0, 8.0]]), box)
    assert len(pieces) == 2
    np.testing.assert_allclose(pieces[0], [[2, 5], [10, 5]])
    np.testing.assert_allclose(pieces[1], [[10, 8], [2, 8]])
    crossing = clip_polyline(np.array([[-5.0, 3.0], [15.0, 3.0]]), box)
    np.testing.assert_allclose(crossing[0], [[0, 3], [10, 3]])
    assert clip_polyline(np.array([[-5.0, -1.0], [15.0, -1.0]]), box) == []


def test_a_long_arm_is_clipped_to_the_window(tmp_path: Path) -> None:
    import numpy as np

    from priqn.sim.roadmap import CROP_MARGIN_M

    tips = (("E", 2000, 0), ("N", 0, 120), ("W", -120, 0))
    nodes = '<node id="C" x="0" y="0"/>' + "".join(
        f'<node id="{n}" x="{x}" y="{y}"/>' for n, x, y in tips
    )
    edges = "".join(
        f'<edge id="{n}2C" from="{n}" to="C"/><edge id="C2{n}" from="C" to="{n}"/>'
        for n, _, _ in tips
    )
    rm = RoadMap.load(write_net(tmp_path, "long", nodes, edges))
    lo = rm.junction_polygon_xy.min(axis=0) - CROP_MARGIN_M - 1e-6
    hi = rm.junction_polygon_xy.max(axis=0) + CROP_MARGIN_M + 1e-6
    for poly in [*rm.lane_polygons_xy, *rm.marking_polylines_xy]:
        assert (poly >= lo).all() and (poly <= hi).all()
    assert rm.bounds_m[2] == pytest.approx(hi[0], abs=1e-3)  # the 2 km arm ends at the window
    assert rm.lanes["E2C_0"].length_m > 1900  # SUMO's lane, unclipped, for the traffic
    start = rm.route("E2C->C2W").point_at(rm.route("E2C->C2W").start_s_m)
    assert (start >= lo).all() and (start <= hi).all()
    # Obstacles on the long arm stand within reach of the junction.
    from priqn.env.scenes import SITE_REACH_M, Scene
    from priqn.sim.scenario import TrafficSpec

    scene = Scene("x/long", rm, raster=None, references={}, traffic=TrafficSpec())
    for site in scene.obstacle_sites(rm.route("N2C->C2W"), 25.0):
        if site.edge_id == "E2C":
            assert site.s_min_m >= rm.lanes["E2C_0"].length_m - SITE_REACH_M
        if site.edge_id == "C2E":
            assert site.s_max_m <= SITE_REACH_M
    assert np.isfinite(rm.bounds_m).all()


def test_sidewalks_and_footways_are_no_road_for_cars(own: Path, tmp_path: Path) -> None:
    from priqn.env.scenes import Scene
    from priqn.sim.scenario import TrafficSpec

    sw = run_netconvert(
        tmp_path / "sidewalks.net.xml", "--node-files", str(EXAMPLES / "tjunction.nod.xml"),
        "--edge-files", str(EXAMPLES / "tjunction.edg.xml"), "--sidewalks.guess", "true",
    )  # fmt: skip
    net = sumolib.net.readNet(str(sw))
    assert not net.getEdge("W2C").getLanes()[0].allows("passenger")  # lane 0 is a sidewalk
    rm = RoadMap.load(sw)
    assert rm.junction_id == "C" and len(rm.ego_routes) == 6
    assert "W2C_0" not in rm.lane_ids and "W2C_1" in rm.lane_ids
    assert {r.start_lane_id for r in rm.ego_routes} == {"W2C_1", "E2C_1", "S2C_1"}
    scene = Scene("x/sidewalks", rm, raster=None, references={}, traffic=TrafficSpec())
    sites = scene.obstacle_sites(rm.ego_routes[0], 25.0)
    assert sites and all(s.lane_index == 1 and s.lane_id.endswith("_1") for s in sites)
    # A footway meeting a road is no junction arm: the road's node stays a mere bend.
    nodes = (
        '<node id="a" x="0" y="0"/><node id="b" x="100" y="0"/><node id="c" x="200" y="0"/>'
        '<node id="f" x="100" y="80"/>'
    )
    edges = (
        '<edge id="ab" from="a" to="b"/><edge id="ba" from="b" to="a"/>'
        '<edge id="bc" from="b" to="c"/><edge id="cb" from="c" to="b"/>'
        '<edge id="fb" from="f" to="b" allow="pedestrian"/>'
    )
    with pytest.raises(PriqnError, match=r"path\.net\.xml: no intersection"):
        RoadMap.load(write_net(tmp_path, "path", nodes, edges))


def test_ties_go_to_the_smallest_id_and_nets_that_cannot_be_used_are_one_line(
    own: Path, tmp_path: Path
) -> None:
    from priqn.sim.roadmap import list_junctions

    spots = (
        ("Q", 0, 0),
        ("P", 200, 0),
        ("a", -100, 0),
        ("b", 0, 100),
        ("c", 200, 100),
        ("d", 300, 0),
    )
    nodes = "".join(f'<node id="{n}" x="{x}" y="{y}"/>' for n, x, y in spots)
    pairs = (("a", "Q"), ("b", "Q"), ("Q", "P"), ("c", "P"), ("d", "P"))
    edges = "".join(
        f'<edge id="{u}{v}" from="{u}" to="{v}"/><edge id="{v}{u}" from="{v}" to="{u}"/>'
        for u, v in pairs
    )
    tie = write_net(tmp_path, "tie", nodes, edges)
    assert [(j.node_id, j.approaches) for j in list_junctions(tie)] == [("P", 3), ("Q", 3)]
    assert RoadMap.load(tie).junction_id == "P"
    assert [(j.node_id, j.arms) for j in list_junctions(own / "grid.net.xml")] == [
        ("A", 4),
        ("B", 3),
    ]

    star = '<node id="C" x="0" y="0"/><node id="E" x="100" y="0"/><node id="N" x="0" y="100"/><node id="W" x="-100" y="0"/>'
    outward = write_net(  # three one-way roads all leaving C: nobody can drive through it
        tmp_path, "outward", star,
        '<edge id="CE" from="C" to="E"/><edge id="CN" from="C" to="N"/><edge id="CW" from="C" to="W"/>',
    )  # fmt: skip
    bikes = write_net(  # a T of bike paths: no road a car may use
        tmp_path, "bikes", star,
        "".join(f'<edge id="{a}{b}" from="{a}" to="{b}" allow="bicycle"/>'
                for a, b in (("E", "C"), ("C", "E"), ("N", "C"), ("C", "N"), ("W", "C"), ("C", "W"))),
    )  # fmt: skip
    cases = [
        (bikes, "", r"bikes\.net\.xml: no intersection \(a node joining 3 or more roads cars may use\)"),
        (outward, "", r"outward\.net\.xml: junction 'C' has no drivable route through it"),
        (own / "grid.net.xml", "Z", r"junction 'Z' is not an intersection .*most approaches first: A, B\)"),
    ]  # fmt: skip
    for path, junction, match in cases:
        with pytest.raises(PriqnError, match=match) as exc:
            RoadMap.load(path, junction=junction)
        assert "\n" not in str(exc.value)


def test_an_osm_extract_with_the_documented_options(tmp_path: Path) -> None:
    from priqn.sim.roadmap import list_junctions

    osm = str(EXAMPLES / "corner.osm")
    net = run_netconvert(tmp_path / "corner.net.xml", "--osm-files", osm, *OSM_OPTIONS)
    found = list_junctions(net)
    assert [(j.node_id, j.node_type, j.approaches) for j in found] == [
        ("10", "priority", 4),
        ("20", "priority", 3),
    ]  # fmt: skip  (the signals at node 10 discarded)
    rm = RoadMap.load(net)
    assert rm.junction_id == "10" and len(rm.ego_routes) == 12
    assert rm.commands() == ("left", "straight", "right")
    assert len(RoadMap.load(net, junction="20").ego_routes) == 6
    # Imported without options it still loads: the footway (way 400) is neither an arm of
    # node 20 nor drivable area, and node 10 keeps its traffic light.
    plain = run_netconvert(tmp_path / "plain.net.xml", "--osm-files", osm)
    assert [j.node_id for j in list_junctions(plain)] == ["10", "20"]
    rm = RoadMap.load(plain, junction="20")
    assert len(rm.ego_routes) == 6 and not any(lane.startswith("400") for lane in rm.lane_ids)
    assert RoadMap.load(plain).junction_type == "traffic_light"


# --------------------------------------------------------------------------- generated nets unchanged


def _old_roadmap_facts(path: Path) -> dict:
    """What RoadMap.load gave a generated net before own nets: the one non-dead-end node,
    every lane and edge of the net unclipped, the ego ``max(length - 70, 0)`` before the line."""
    import numpy as np

    from priqn.sim.geometry import lane_polygon

    net = sumolib.net.readNet(str(path), withInternal=True)
    (junction,) = [n for n in net.getNodes() if n.getType() not in ("dead_end", "internal")]
    lanes = [ln for e in net.getEdges(withInternal=True) for ln in e.getLanes()]
    polys = [lane_polygon(np.asarray(ln.getShape(), float), ln.getWidth()) for ln in lanes]
    pts = np.concatenate([np.asarray(junction.getShape(), float), *polys])
    npc = [
        (e.getID(), t.getID())
        for e in sorted(net.getEdges(withInternal=False), key=lambda e: e.getID())
        for t in sorted(e.getOutgoing(), key=lambda t: t.getID())
        if t.getToNode() is not e.getFromNode()
    ]
    n_markings = 0  # right edge, lane boundaries, left edge / centre line once per pair
    for e in net.getEdges(withInternal=False):
        back = [o.getID() for o in e.getToNode().getOutgoing() if o.getToNode() is e.getFromNode()]
        n_markings += len(e.getLanes()) + (not back or e.getID() < back[0])
    return {
        "junction": junction.getID(),
        "lane_ids": [ln.getID() for ln in lanes],
        "polygons": polys,
        "bounds": (*pts.min(axis=0), *pts.max(axis=0)),
        "npc": npc,
        "n_markings": n_markings,
    }


def test_generated_nets_give_the_same_roadmap_as_before() -> None:
    import numpy as np

    from priqn.env.scenes import Scene
    from priqn.sim.scenario import TrafficSpec

    refs = list_nets()
    assert len(refs) >= 20
    for ref in refs:
        path = net_path(ref)
        rm, old = RoadMap.load(path), _old_roadmap_facts(path)
        assert rm.junction_id == old["junction"] == "J", ref
        assert list(rm.lane_ids) == old["lane_ids"], ref
        for got, want in zip(rm.lane_polygons_xy, old["polygons"], strict=True):
            np.testing.assert_array_equal(got, want)
        assert rm.bounds_m == old["bounds"], ref
        assert rm.npc_routes == old["npc"] == [r.edges for r in rm.ego_routes], ref
        assert len(rm.marking_polylines_xy) == old["n_markings"], ref
        for r in rm.ego_routes:
            assert r.start_pos_m == max(rm.lanes[r.start_lane_id].length_m - 70.0, 0.0), ref
        # Obstacle sites as before: lane 0 of every arm edge, the same stretches.
        scene = Scene(ref, rm, raster=None, references={}, traffic=TrafficSpec())
        first = rm.ego_routes[0]
        incoming = {e for e, _ in old["npc"]}
        sites = scene.obstacle_sites(first, 25.0)
        assert len(sites) >= 4, ref
        for site in sites:
            length = rm.lanes[f"{site.edge_id}_0"].length_m
            assert site.lane_id == f"{site.edge_id}_0" and site.lane_index == 0
            if site.edge_id not in incoming:
                assert (site.s_min_m, site.s_max_m) == (25.0, length - 5.0)
            elif site.edge_id != first.edges[0]:
                assert (site.s_min_m, site.s_max_m) == (5.0, length - 25.0)


# --------------------------------------------------------------------------- env.nets values, env, train CLI


def test_env_nets_from_python_toml_and_set(own: Path) -> None:
    from priqn.config import apply_overrides, from_dict
    from priqn.env.config import EnvConfig
    from priqn.env.intersection import make_config

    t = str(own / "tjunction.net.xml")
    assert EnvConfig(nets=own / "tjunction.net.xml").nets == (t,)  # a Path
    assert from_dict(EnvConfig, {"nets": t}, "x.toml [env]").nets == (t,)  # a TOML string
    assert from_dict(EnvConfig, {"nets": [t, str(own)]}, "x.toml [env]").nets == (t, str(own))
    assert apply_overrides(EnvConfig(), [f"nets={t}"]).nets == (t,)  # --set bare word
    assert apply_overrides(EnvConfig(), [f'nets=["{t}"]', "junction=C"]).junction == "C"
    for bad in (5, [3], [""]):
        with pytest.raises(PriqnError, match=r"^env config: nets: expected a .net.xml file") as e:
            make_config({"nets": bad}, {})
        assert "\n" not in str(e.value)


def _drive_grid(net_file: str, queue: multiprocessing.Queue) -> None:
    from priqn.env.config import EnvConfig
    from priqn.env.intersection import IntersectionEnv

    env = IntersectionEnv(EnvConfig(nets=net_file, junction="B", obs_size_px=32))
    routes = []
    for seed in range(3):
        obs, info = env.reset(seed=seed)
        routes.append(info["route"])
        for _ in range(3):
            obs, reward, terminated, truncated, info = env.step(17)  # 9 m/s, centred
            if terminated or truncated:
                break
    env.close()
    queue.put((env.net_pool, routes, float(reward.sum())))


def test_env_drives_through_the_named_junction_of_a_grid(own: Path) -> None:
    import math

    ctx = multiprocessing.get_context("spawn")  # libsumo: one simulation per process
    queue = ctx.Queue()
    proc = ctx.Process(target=_drive_grid, args=(str(own / "grid.net.xml"), queue))
    proc.start()
    pool, routes, reward_sum = queue.get(timeout=120)
    proc.join(timeout=30)
    assert pool == (f"{own.name}/grid",) and math.isfinite(reward_sum)
    assert all(r.split("->")[0] in {"A2B", "E2B", "BS2B"} for r in routes)


def test_train_cli_on_a_net_file_then_evaluate(own: Path, tmp_path: Path) -> None:
    import hashlib
    import os
    import sys

    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    tiny = [
        "--set", "evaluation.interval_steps=0", "--set", "env.obs_size_px=32",
        "--set", "env.max_episode_steps=25", "--set", "replay.learning_starts=32",
        "--set", "network.latent_dim=64", "--set", "network.hidden_dim=64",
        "--set", "learner.num_tau_samples=8", "--set", "learner.num_tau_prime_samples=8",
        "--set", "learner.num_quantiles=8",
    ]  # fmt: skip
    net = own / "tjunction.net.xml"
    res = subprocess.run(
        [sys.executable, "-m", "priqn.cli", "train", "--net", str(net), "--agent", "iqn",
         "--steps", "60", "--num-envs", "1", "--runs-dir", str(tmp_path), *tiny],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    (run,) = tmp_path.iterdir()
    assert run.name == "tjunction_iqn_s0"
    (entry,) = json.loads((run / "nets.json").read_text())["nets"]
    assert entry["files"] == {"tjunction.net.xml": hashlib.sha256(net.read_bytes()).hexdigest()}
    assert entry["junction"] == "C"
    meta = json.loads((run / "meta.json").read_text())
    assert meta["status"] == "complete" and len(meta["manifest_hashes"]["own"]) == 64
    assert f"{own.name}/tjunction" in (run / "metrics.csv").read_text()
    # priqn evaluate runs the hold-out protocol on the generated hold-out family.
    res = subprocess.run(
        [sys.executable, "-m", "priqn.cli", "evaluate", str(run), "--episodes", "1",
         "--eval-runs", "1", "--densities", "0.5", "--workers", "1", "--set", "max_episode_steps=5"],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    episodes = (run / "eval" / "episodes.csv").read_text()
    assert "holdout/" in episodes and f"{own.name}/tjunction" not in episodes
