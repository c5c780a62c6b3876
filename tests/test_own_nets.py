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
    from priqn.env.intersection import EnvConfig, IntersectionEnv

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

    from priqn.runs import RunFolder
    from priqn.train_config import default_run_name, resolve_config

    cfg = resolve_config(net=str(own / "grid.net.xml"), overrides=["env.junction=B"])
    assert cfg.env.nets == (str((own / "grid.net.xml").resolve()),)
    assert default_run_name(cfg).startswith("grid_pr-iqn_")
    run = RunFolder(tmp_path / "run")
    meta = run.prepare(cfg, resume=False, force=False)
    manifest = json.loads(run.nets_manifest_path.read_text())
    sha = hashlib.sha256((own / "grid.net.xml").read_bytes()).hexdigest()
    assert manifest["junction"] == "B"
    assert manifest["nets"] == [
        {"id": f"{own.name}/grid", "path": cfg.env.nets[0], "files": {"grid.net.xml": sha}}
    ]
    assert len(meta["manifest_hashes"]["own"]) == 64
    with pytest.raises(PriqnError, match="--net: .*nope.net.xml: no such file or folder"):
        resolve_config(net=str(tmp_path / "nope.net.xml"))
