"""How NPCs treat the ego (``EnvConfig.traffic``), on cases built by hand.

A priority T-junction drawn by hand: the main road runs west-east through the centre
(0, 0), the minor road comes from the south. The ego drives east on the main road at
8 m/s, moved by ``moveToXY`` exactly as the env moves it; it has priority. One NPC comes up
the minor road and turns left (west), across the ego's lane, timed to reach the junction
about a second before the ego. SUMO runs in a spawned process (one simulation per process).
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import itertools
import multiprocessing
import subprocess
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from priqn.env.path_braking import PathBrakingConfig
from priqn.env.traffic import (
    IGNORE_IDS_PARAM,
    NPC_PREFIX,
    TRAFFIC_SETTINGS,
    Traffic,
    TrafficBehaviour,
    traffic_values,
)
from priqn.errors import PriqnError
from priqn.sim import sumo
from priqn.sim.scenario import TrafficSpec

EGO_SPEED_MPS = 8.0
EGO_LANE_Y_M = -1.6
"""Centre of the eastbound lane (3.2 m lanes, right-hand traffic)."""


def _junction_net(
    d: Path, minor: tuple[str, float], edges: list[tuple[str, str, str, int, int]],
    connections: str = "",
) -> Path:  # fmt: skip
    """A priority junction C at (0, 0) with arms W (x −150), E (x 150) and the ``minor`` one
    (name, y) on the y axis; ``edges``: (id, from, to, priority, lanes); ``connections``: the
    ``<connection>`` elements of a netconvert ``.con.xml`` (none: netconvert's own)."""
    name, y = minor
    (d / "t.nod.xml").write_text(
        '<nodes><node id="W" x="-150" y="0" type="dead_end"/>'
        '<node id="E" x="150" y="0" type="dead_end"/>'
        f'<node id="{name}" x="0" y="{y:g}" type="dead_end"/>'
        '<node id="C" x="0" y="0" type="priority"/></nodes>'
    )
    (d / "t.edg.xml").write_text(
        "<edges>"
        + "".join(
            f'<edge id="{i}" from="{a}" to="{b}" priority="{p}" numLanes="{n}" speed="13.89"/>'
            for i, a, b, p, n in edges
        )
        + "</edges>"
    )
    args = ["-n", str(d / "t.nod.xml"), "-e", str(d / "t.edg.xml")]
    if connections:
        (d / "t.con.xml").write_text(f"<connections>{connections}</connections>")
        args += ["-x", str(d / "t.con.xml")]
    net = d / "t.net.xml"
    subprocess.run(
        [sumo.binary("netconvert"), *args, "-o", str(net), "--offset.disable-normalization",
         "true", "--no-warnings", "true"],
        check=True, capture_output=True, env=sumo.subprocess_env(),
    )  # fmt: skip
    return net


@pytest.fixture(scope="module")
def tjunction(tmp_path_factory: pytest.TempPathFactory) -> Path:
    edges = [("WC", "W", "C", 2, 1), ("CW", "C", "W", 2, 1), ("EC", "E", "C", 2, 1)]
    edges += [("CE", "C", "E", 2, 1), ("SC", "S", "C", 1, 1), ("CS", "C", "S", 1, 1)]
    return _junction_net(tmp_path_factory.mktemp("handmade"), ("S", -150), edges)


@pytest.fixture(scope="module")
def worker() -> Iterator[concurrent.futures.ProcessPoolExecutor]:
    ctx = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        yield pool


def _drive(net: str, yield_prob: float, npc_route: str, ego_speed_mps: float, npc_at: int) -> dict:
    """The ego east through the junction; one NPC on ``npc_route`` inserted at step ``npc_at``.

    Returns per step the ego's x, the NPC's front position and speed (None before it runs).
    """
    import libsumo as sim

    from priqn.sim.sumo import simulation_args

    sim.start(simulation_args(net, seed=1, lateral_resolution_m=0.8))
    try:
        sim.route.add("ego_route", ["WC", "CE"])
        sim.vehicle.add("ego", "ego_route", departPos="20", departSpeed=str(ego_speed_mps))
        sim.vehicle.setSpeedMode("ego", 0)
        sim.vehicle.setLaneChangeMode("ego", 0)
        routes = {"left": ["SC", "CW"], "behind": ["WC", "CE"]}
        traffic = Traffic(
            sim,
            TrafficSpec(lateral_offset_m=(0.0, 0.0)),
            [routes[npc_route]],
            density=0.05,
            rng=np.random.default_rng(0),
            behaviour=TrafficBehaviour(yield_to_ego_prob=yield_prob),
            ego_id="ego",
        )
        traffic.setup()
        sim.simulationStep()  # inserts the ego
        x = -150.0 + 20.0
        rows = []
        for k in range(260):
            x += ego_speed_mps * 0.1
            sim.vehicle.moveToXY("ego", "", -1, x, EGO_LANE_Y_M, 90.0, 3)
            if k == npc_at:
                traffic._add_npc(0, 2.0 if npc_route == "behind" else 60.0)
            sim.simulationStep()
            npc = f"{NPC_PREFIX}0"
            if npc in sim.vehicle.getIDList():
                px, py = sim.vehicle.getPosition(npc)
                rows.append((x, px, py, sim.vehicle.getSpeed(npc)))
            else:
                rows.append((x, None, None, None))
        return {"rows": rows, "rude": sorted(traffic.rude)}
    finally:
        sim.close()


def _run(worker: Any, *args: Any) -> dict:
    return worker.submit(_drive, *args).result(timeout=240)


def test_a_yielding_npc_waits_for_the_ego_with_priority(tjunction, worker) -> None:
    out = _run(worker, str(tjunction), 1.0, "left", EGO_SPEED_MPS, 75)
    assert out["rude"] == []
    # The NPC's front stays south of the ego's lane (y < -3.2 m) until the ego is past the
    # junction centre, and it slows to a crawl (< 2.5 m/s) waiting.
    in_lane = [x for x, _, py, _ in out["rows"] if py is not None and py > -3.2]
    assert in_lane and min(in_lane) > 0.0
    waiting = [v for x, _, py, v in out["rows"] if v is not None and -20.0 < x < 0.0]
    assert min(waiting) < 2.5


def test_an_npc_that_does_not_yield_enters_in_front_of_the_ego(tjunction, worker) -> None:
    out = _run(worker, str(tjunction), 0.0, "left", EGO_SPEED_MPS, 75)
    assert out["rude"] == ["npc.0"]
    # Its front reaches the ego's lane while the ego is still approaching, at speed.
    entered = [(x, v) for x, _, py, v in out["rows"] if py is not None and py > -3.2]
    assert entered and entered[0][0] < 0.0
    assert entered[0][1] > 4.0


def test_an_npc_that_does_not_yield_still_brakes_for_the_ego_ahead_in_its_lane(
    tjunction, worker
) -> None:
    # The ego crawls at 3 m/s; the NPC starts behind it in the same lane and would drive
    # 13.9 m/s: its car-following keeps it behind the ego.
    out = _run(worker, str(tjunction), 0.0, "behind", 3.0, 0)
    assert out["rude"] == ["npc.0"]
    gaps = [x - 4.5 - px for x, px, _, _ in out["rows"] if px is not None and px < 140.0]
    speeds = [v for _, px, _, v in out["rows"] if px is not None]
    assert min(gaps) > 0.5
    assert speeds[-1] < 4.0


class _FakeSim:
    """Just what :meth:`Traffic._add_npc` calls, recording the parameters it sets."""

    def __init__(self) -> None:
        self.params: dict[str, dict[str, str]] = {}
        noop = lambda *a, **k: None  # noqa: E731
        self.vehicle = SimpleNamespace(
            add=noop, setLength=noop, setWidth=noop, setSpeedFactor=noop,
            setParameter=lambda v, k, val: self.params.setdefault(v, {}).__setitem__(k, val),
        )  # fmt: skip


def _insert(n: int, behaviour: TrafficBehaviour, seed: int = 7) -> tuple[Traffic, float]:
    traffic = Traffic(
        _FakeSim(), TrafficSpec(), [["a", "b"]], 0.5, np.random.default_rng(seed), behaviour
    )
    traffic._first_edge_len["a"] = 100.0
    for _ in range(n):
        traffic._add_npc(0, 10.0)
    return traffic, float(traffic.rng.random())


def test_yield_probability_draws_its_own_stream_and_the_default_draws_nothing() -> None:
    default, after_default = _insert(200, TrafficBehaviour())
    half, after_half = _insert(200, TrafficBehaviour(yield_to_ego_prob=0.5))
    assert default.rude == set() and default.sim.params == {}
    # The traffic's own draws (sizes, speeds, offsets) are the same with or without it.
    assert after_half == after_default
    assert 70 <= len(half.rude) <= 130  # Binomial(200, 0.5): 5 SD either side
    assert all(half.sim.params[v] == {IGNORE_IDS_PARAM: "ego"} for v in half.rude)
    assert _insert(200, TrafficBehaviour(yield_to_ego_prob=0.5))[0].rude == half.rude
    assert len(_insert(50, TrafficBehaviour(yield_to_ego_prob=0.0))[0].rude) == 50


def test_no_top_up_adds_nothing() -> None:
    traffic, _ = _insert(0, TrafficBehaviour(top_up=False))
    assert traffic.top_up() == 0


def test_behaviour_and_setting_errors_are_one_line() -> None:
    with pytest.raises(ValueError, match=r"yield_to_ego_prob: expected a probability in \[0, 1\]"):
        TrafficBehaviour(yield_to_ego_prob=1.5)
    with pytest.raises(ValueError, match="impatience"):
        TrafficBehaviour(impatience=-0.1)
    with pytest.raises(PriqnError, match="unknown setting 'polite' \\(valid: sumo, rude"):
        traffic_values("polite")
    with pytest.raises(
        PriqnError, match=r"unknown setting 'tm-carl' .*; did you mean 'tm-carla'\?"
    ):
        traffic_values("tm-carl")
    assert traffic_values("sumo") == ()
    assert traffic_values("rude-finite-long") == (
        ("env.traffic.yield_to_ego_prob", 0.0),
        ("env.traffic.top_up", False),
        ("env.max_episode_steps", 200),
    )
    # Path braking at its defaults is `true`, as before its table: a cell run at an older
    # commit (priqn sweep --code) reads the same values.
    assert traffic_values("tm-long") == (
        ("env.traffic.yield_to_ego_prob", 0.0),
        ("env.traffic.path_braking", True),
        ("env.max_episode_steps", 200),
    )


def test_every_named_setting_builds_a_train_config() -> None:
    from priqn.run.train_config import resolve_config

    for name in TRAFFIC_SETTINGS:
        cfg = resolve_config(values=traffic_values(name))
        assert cfg.env.traffic == TRAFFIC_SETTINGS[name].behaviour
        assert cfg.env.max_episode_steps == (TRAFFIC_SETTINGS[name].max_episode_steps or 100)
        assert TRAFFIC_SETTINGS[name].name == name


def test_a_run_config_names_its_own_setting() -> None:
    """Every named setting's config is named back as itself, although ``tm-long`` has ``tm``'s
    NPCs (it differs by episode length only); a config of no setting is ''."""
    from priqn.env.traffic import setting_name
    from priqn.run.train_config import resolve_config

    for name in TRAFFIC_SETTINGS:
        assert setting_name(resolve_config(values=traffic_values(name)).env) == name
    odd = resolve_config(values=(("env.traffic.impatience", 0.5),))
    assert setting_name(odd.env) == ""
    assert setting_name(resolve_config().env) == "sumo"


def test_a_run_is_named_by_the_setting_it_records() -> None:
    """meta.json's ``traffic`` (the name chosen) wins over the inference, which names runs
    that recorded none: ``tm`` with 200-decision episodes set by hand stays ``tm``."""
    from priqn.env.traffic import run_setting_name
    from priqn.run.train_config import resolve_config

    env = resolve_config(values=traffic_values("tm"), overrides=["env.max_episode_steps=200"]).env
    assert run_setting_name({"traffic": "tm"}, env) == "tm"
    assert run_setting_name({}, env) == "tm-long"
    assert run_setting_name({"traffic": ""}, resolve_config().env) == "sumo"


# ------------------------------------------------------------- the Traffic-Manager-like setting
# ``tm``: no NPC gives way to the ego, but each brakes for an ego in its path ahead
# (priqn/env/path_braking.py). The ego is moved exactly as above (front bumper at ``x``,
# east along its lane); the stage is checked before every step with the ego's box there.

EGO_LENGTH_M, EGO_WIDTH_M = 5.0, 1.8
"""SUMO's default car, which the hand-built ego is."""


def _stage_scene(
    sim: Any, net: str, behaviour: TrafficBehaviour, ego_edges: list[str],
    npc_edges: list[str], **ego_depart: str,
) -> Traffic:  # fmt: skip
    """In a started simulation: the standing ego on ``ego_edges`` (``ego_depart``: its
    ``vehicle.add`` options), moved by the caller; the traffic of ``behaviour`` with one NPC
    route and the net's paths for its stage; the ego inserted and subscribed to."""
    from priqn.env import reads
    from priqn.env.path_braking import NpcPaths
    from priqn.sim.roadmap import RoadMap

    sim.route.add("ego_route", ego_edges)
    sim.vehicle.add("ego", "ego_route", departSpeed="0", **ego_depart)
    sim.vehicle.setSpeedMode("ego", 0)
    sim.vehicle.setLaneChangeMode("ego", 0)
    traffic = Traffic(
        sim, TrafficSpec(lateral_offset_m=(0.0, 0.0)), [npc_edges], density=0.05,
        rng=np.random.default_rng(0), behaviour=behaviour, ego_id="ego",
        paths=NpcPaths(RoadMap.load(net)), step_s=0.1,
    )  # fmt: skip
    traffic.setup()
    sim.simulationStep()  # inserts the ego
    reads.subscribe_actors(sim, "ego", 65.0)
    return traffic


def _drive_stage(
    net: str, setting: str, ego_xs: list[float], npc_route: str, npc_at: int, npc_pos: float,
    reaction_s: float = 0.0,
) -> dict:  # fmt: skip
    """The ego's front at ``ego_xs[k]`` after step k; one NPC on ``npc_route`` inserted at
    step ``npc_at`` at ``npc_pos`` m along its first edge, under traffic ``setting``.

    Per step: the NPC's x, y, speed, the stage's hazard distance for it (None: the ego is
    not in its path) and whether its box overlaps the ego's (our own oriented-box test).
    """
    import libsumo as sim

    from priqn.env import geometry, reads
    from priqn.sim.sumo import simulation_args

    behaviour = TRAFFIC_SETTINGS[setting].behaviour
    if behaviour.path_braking is not None:  # `rude` has no stage to delay
        braking = dataclasses.replace(behaviour.path_braking, reaction_time_s=reaction_s)
        behaviour = dataclasses.replace(behaviour, path_braking=braking)
    sim.start(simulation_args(net, seed=1, lateral_resolution_m=0.8))
    try:
        routes = {"left": ["SC", "CW"], "right": ["SC", "CE"], "behind": ["WC", "CE"]}
        traffic = _stage_scene(
            sim, net, behaviour, ["WC", "CE"], routes[npc_route],
            departPos=f"{ego_xs[0] + 150.0:.2f}",
        )  # fmt: skip
        npc, rows = f"{NPC_PREFIX}0", []
        prev_x = ego_xs[0]
        for k, x in enumerate(ego_xs):
            stage = traffic.path_braking
            if stage is not None:
                centre = (prev_x - EGO_LENGTH_M / 2, EGO_LANE_Y_M)
                stage.check(reads.read_actors(sim, "ego"), centre, 0.0, EGO_LENGTH_M, EGO_WIDTH_M)
            hazard = stage.hazard_m.get(npc) if stage is not None else None
            sim.vehicle.moveToXY("ego", "", -1, x, EGO_LANE_Y_M, 90.0, 3)
            if k == npc_at:
                traffic._add_npc(0, npc_pos)
            sim.simulationStep()
            prev_x = x
            if npc not in sim.vehicle.getIDList():
                rows.append((x, None, None, None, hazard, False))
                continue
            front, angle = sim.vehicle.getPosition(npc), sim.vehicle.getAngle(npc)
            length, width = sim.vehicle.getLength(npc), sim.vehicle.getWidth(npc)
            centre, heading = geometry.center_from_sumo(np.array(front), angle, length)
            hit = geometry.obb_overlap(
                geometry.Boxes.make([(x - EGO_LENGTH_M / 2, EGO_LANE_Y_M)], 0.0, EGO_LENGTH_M, EGO_WIDTH_M),
                geometry.Boxes.make([centre], heading, length, width),
            )[0]  # fmt: skip
            rows.append((x, front[0], front[1], sim.vehicle.getSpeed(npc), hazard, bool(hit)))
        return {"rows": rows, "decel": sim.vehicletype.getDecel("priqn_npc"),
                "emergency_decel": sim.vehicletype.getEmergencyDecel("priqn_npc")}  # fmt: skip
    finally:
        sim.close()


def _stand(at_x: float, steps: int = 300, from_x: float = -20.0, speed: float = 8.0) -> list[float]:
    """Front-bumper x per step: from ``from_x`` east at ``speed`` m/s to ``at_x``, then standing."""
    xs, x = [], from_x
    for _ in range(steps):
        x = min(x + speed * 0.1, at_x)
        xs.append(x)
    return xs


def _stage(worker: Any, *args: Any) -> dict:
    return worker.submit(_drive_stage, *args).result(timeout=240)


def _decels(rows: list) -> list[float]:
    """The NPC's deceleration in each step it ran [m/s²] (positive = braking)."""
    speeds = [r[3] for r in rows if r[3] is not None]
    return [(a - b) / 0.1 for a, b in itertools.pairwise(speeds)]


STANDING_X_M = 4.0
"""The standing ego's front: its box covers x 1.5..4 m of its lane, across the left turner's
path from the south (which crosses the ego's lane at x ~ 1.3 m)."""


def test_tm_npc_stops_for_an_ego_standing_across_its_path(tjunction, worker) -> None:
    # The ego drives in and stands inside the junction before the NPC, 40 m up the minor
    # road at 11 m/s, comes within its look-ahead (2.5 m + 4.35 s x 11.2 m/s = 51 m, capped
    # at 50): it sees the ego at 46.5 m, far beyond its stopping distance (14 m at decel).
    out = _stage(worker, str(tjunction), "tm", _stand(STANDING_X_M), "left", 0, 40.0)
    rows = out["rows"]
    seen = [r for r in rows if r[4] is not None]
    assert seen and seen[0][4] > 40.0
    assert not any(r[5] for r in rows)  # no collision
    assert rows[-1][3] == 0.0  # it stands, waiting
    # ... 2 m short of the ego (the gap it aims for), having braked gently: never harder
    # than its vType's decel (4.5 m/s²).
    assert seen[-1][4] == pytest.approx(2.0, abs=0.5)
    assert max(_decels(rows)) <= out["decel"] + 1e-6


def test_rude_npc_drives_into_the_same_standing_ego(tjunction, worker) -> None:
    # The same case without the stage: junctionModel.ignoreIDs drops the ego as a foe inside
    # the junction too, and the NPC drives into it.
    out = _stage(worker, str(tjunction), "rude", _stand(STANDING_X_M), "left", 0, 40.0)
    assert any(r[5] for r in out["rows"])
    assert all(r[4] is None for r in out["rows"])  # no stage in `rude`


def test_tm_npc_brakes_at_its_limit_for_an_ego_that_cuts_in(tjunction, worker) -> None:
    # The ego drives through at 8 m/s and enters the path of the NPC (inserted at step 75,
    # 60 m up the minor road) 4.5 m ahead of it at 5.6 m/s: stopping 2 m short would need
    # 6.3 m/s², stopping at all 3.5 m/s² over 4.5 m... the NPC brakes as hard as its
    # emergencyDecel (9 m/s²) allows, never harder, and the two still touch.
    xs = [-130.0 + 8.0 * 0.1 * (k + 1) for k in range(260)]
    out = _stage(worker, str(tjunction), "tm", xs, "left", 75, 60.0)
    rows = out["rows"]
    first = next(r for r in rows if r[4] is not None)
    speed, hazard = first[3], first[4]
    assert hazard - 2.0 < speed**2 / (2 * out["decel"])  # inside its comfortable stop
    decels = _decels(rows)
    assert max(decels) > out["decel"] + 1.0
    assert max(decels) <= out["emergency_decel"] + 1e-6
    assert any(r[5] for r in rows)


def test_tm_npc_that_arrives_first_does_not_wait_for_the_approaching_ego(tjunction, worker) -> None:
    # As for `rude` above: the NPC reaches the junction about a second before the ego, which
    # has priority under SUMO's rules; the TM gives the ego none. The ego is never in the
    # NPC's path ahead before the NPC is in the ego's lane, so it does not brake for it.
    xs = [-130.0 + EGO_SPEED_MPS * 0.1 * (k + 1) for k in range(260)]
    out = _stage(worker, str(tjunction), "tm", xs, "left", 75, 60.0 + 20.0)
    rows = out["rows"]
    entered = [(k, r) for k, r in enumerate(rows) if r[2] is not None and r[2] > -3.2]
    assert entered and entered[0][1][0] < 0.0 and entered[0][1][3] > 4.0
    assert all(r[4] is None for r in rows[: entered[0][0]])


def test_tm_carla_npc_does_not_brake_for_an_ego_30_m_ahead_and_tm_does(tjunction, worker) -> None:
    # The standing-ego case above under both look-aheads. At about 11 m/s `tm` looks 50 m
    # ahead (2.5 + 4.35 x 11, capped), so it is braking for the ego by the time the ego is
    # 30 m along its path; `tm-carla` looks 2.5 + (0.36 x 11)^2 = 18.2 m ahead, so at 30 m it
    # has not seen the ego and still drives at its own speed. It sees the ego about 18 m
    # ahead, beyond its comfortable stopping distance (11^2 / (2 x 4.5) = 13.4 m, + 2 m gap),
    # and still stops short of it.
    tm = _stage(worker, str(tjunction), "tm", _stand(STANDING_X_M), "left", 0, 40.0)["rows"]
    at_30 = next(r for r in tm if r[4] is not None and r[4] <= 30.0)
    top = max(r[3] for r in tm if r[3] is not None)
    assert top > 10.5 and at_30[3] < top - 1.0  # braking at 30 m under `tm`
    out = _stage(worker, str(tjunction), "tm-carla", _stand(STANDING_X_M), "left", 0, 40.0)
    rows = out["rows"]
    seen = [r for r in rows if r[4] is not None]
    assert seen and 15.0 < seen[0][4] <= 2.5 + (0.36 * seen[0][3]) ** 2 + 0.5
    assert seen[0][3] > 10.5  # nothing braked it before: not at 30 m, nor at 20 m
    assert not any(r[5] for r in rows)  # no collision
    assert rows[-1][3] == 0.0 and seen[-1][4] == pytest.approx(2.0, abs=0.5)
    assert max(_decels(rows)) <= out["decel"] + 1e-6


def test_path_braking_defaults_leave_sumo_and_rude_without_a_stage() -> None:
    assert TrafficBehaviour().path_braking is None
    for name, setting in TRAFFIC_SETTINGS.items():
        on = setting.behaviour.path_braking is not None
        assert on == (name == "tm" or name.startswith("tm-")), name
        assert (setting.max_episode_steps == 200) == name.endswith("-long"), name


def test_braking_speed_by_hand() -> None:
    from priqn.env.path_braking import braking_speed_mps

    # 10 m/s with 25 m of room: 10² / (2 x 25) = 2 m/s², so 9.8 m/s after 0.1 s.
    assert braking_speed_mps(10.0, 25.0, 9.0, 0.1) == pytest.approx(9.8)
    # 5 m of room: 10 m/s² needed, bounded by 9: 9.1 m/s. None left: the bound again.
    assert braking_speed_mps(10.0, 5.0, 9.0, 0.1) == pytest.approx(9.1)
    assert braking_speed_mps(10.0, -1.0, 9.0, 0.1) == pytest.approx(9.1)
    assert braking_speed_mps(0.5, 0.0, 9.0, 0.1) == 0.0  # never below 0


def test_look_ahead_grows_with_speed_up_to_its_cap() -> None:
    from priqn.env.path_braking import PathBraking

    stage = PathBraking(None, None, PathBrakingConfig(), 0.1, 9.0, "npc.")
    assert stage.look_ahead_m(0.0) == pytest.approx(2.5)
    assert stage.look_ahead_m(5.0) == pytest.approx(2.5 + 4.35 * 5.0)
    assert stage.look_ahead_m(20.0) == pytest.approx(50.0)
    # CARLA's form (`tm-carla`): 2.5 m + (0.36 x v)^2, at least the 2 m lead distance.
    carla = PathBrakingConfig(look_ahead_form="carla")
    stage = PathBraking(None, None, carla, 0.1, 9.0, "npc.")
    assert stage.look_ahead_m(0.0) == pytest.approx(2.5)
    assert stage.look_ahead_m(5.0) == pytest.approx(2.5 + 1.8**2)  # 5.74 m
    assert stage.look_ahead_m(11.0) == pytest.approx(2.5 + 3.96**2)  # 18.18 m
    assert stage.look_ahead_m(30.0) == pytest.approx(50.0)  # the cap: 2.5 + 10.8^2 = 119 m
    floor = dataclasses.replace(carla, look_ahead_min_m=0.5, stop_gap_m=3.0)
    stage = PathBraking(None, None, floor, 0.1, 9.0, "npc.")
    assert stage.look_ahead_m(0.0) == pytest.approx(3.0)  # max(3.0, 0.5)
    assert stage.look_ahead_m(5.0) == pytest.approx(3.74)  # max(3.0, 0.5 + 3.24)


def test_path_braking_knob_errors_are_one_line() -> None:
    with pytest.raises(ValueError, match=r"^reaction_time_s: expected >= 0"):
        PathBrakingConfig(reaction_time_s=-0.1)
    with pytest.raises(ValueError, match=r"^margin_m: expected >= 0"):
        PathBrakingConfig(margin_m=-0.5)
    with pytest.raises(ValueError, match=r"look_ahead_max_m: expected >= look_ahead_min_m"):
        PathBrakingConfig(look_ahead_min_m=10.0, look_ahead_max_m=5.0)
    with pytest.raises(
        ValueError, match=r"look_ahead_form: expected one of linear, carla, got 'x'"
    ):
        PathBrakingConfig(look_ahead_form="x")
    with pytest.raises(ValueError, match=r"look_ahead_vel_factor: expected >= 0"):
        PathBrakingConfig(look_ahead_vel_factor=-0.1)
    from priqn.run.train_config import resolve_config

    # Through --set, named by their key; the flat keys of before the table name the new one.
    with pytest.raises(
        PriqnError, match=r"^--set env.traffic.path_braking.margin_m: expected >= 0, got -0.5$"
    ):
        resolve_config(
            values=traffic_values("tm"), overrides=["env.traffic.path_braking.margin_m=-0.5"]
        )
    with pytest.raises(
        PriqnError,
        match=r"'env.traffic.path_margin_m' is now 'env.traffic.path_braking.margin_m'$",
    ):
        resolve_config(overrides=["env.traffic.path_margin_m=0.5"])
    with pytest.raises(PriqnError, match=r"'env.traffic.path_braking' is off; .*=\{\}"):
        resolve_config(overrides=["env.traffic.path_braking.margin_m=0.5"])


def test_path_braking_on_the_command_line() -> None:
    """``path_braking=true`` is its defaults (as in the flat form), ``false`` off, a table its
    knobs; a knob set after ``true`` or a setting that has it on is set on its defaults."""
    from priqn.run.train_config import resolve_config

    def braking(*overrides: str, traffic: str | None = None) -> Any:
        return resolve_config(values=traffic_values(traffic), overrides=overrides).env.traffic

    assert braking("env.traffic.path_braking=true").path_braking == PathBrakingConfig()
    assert braking("env.traffic.path_braking=false", traffic="tm").path_braking is None
    assert braking("env.traffic.path_braking={margin_m = 0.5}").path_braking == PathBrakingConfig(
        margin_m=0.5
    )
    on = braking("env.traffic.path_braking=true", "env.traffic.path_braking.follows_offset=true")
    assert on.path_braking == PathBrakingConfig(follows_offset=True)
    carla = braking("env.traffic.path_braking.look_ahead_form=carla", traffic="tm")
    assert carla == TRAFFIC_SETTINGS["tm-carla"].behaviour


def test_old_flat_traffic_tables_load_as_they_were() -> None:
    """A run folder's ``[env.traffic]`` of before :class:`PathBrakingConfig` (flat ``path_*``
    keys, some of them missing in older ones) loads as the table it meant, and is named as
    before; ``path_braking = false`` is off whatever its knobs."""
    from priqn.config import from_dict
    from priqn.env.traffic import setting_name
    from priqn.run.train_config import TrainConfig

    knobs = {"path_look_ahead_max_m": 50.0, "path_look_ahead_min_m": 2.5,
             "path_look_ahead_s": 4.35, "path_reaction_time_s": 0.0, "path_stop_gap_m": 2.0}  # fmt: skip
    old = {"yield_to_ego_prob": 0.0, "top_up": True, "impatience": 0.0, "path_braking": True}
    cfg = from_dict(
        TrainConfig, {"env": {"traffic": {**old, **knobs}, "max_episode_steps": 200}}, "x"
    )
    assert cfg.env.traffic == TRAFFIC_SETTINGS["tm"].behaviour
    assert setting_name(cfg.env) == "tm-long"
    off = from_dict(TrainConfig, {"env": {"traffic": {**old, **knobs, "path_braking": False}}}, "x")
    assert off.env.traffic == TRAFFIC_SETTINGS["rude"].behaviour and setting_name(off.env) == "rude"
    carla = {**old, **knobs, "path_look_ahead_form": "carla", "path_margin_m": 0.0}
    cfg = from_dict(TrainConfig, {"env": {"traffic": carla}}, "x")
    assert setting_name(cfg.env) == "tm-carla"
    oldest = from_dict(TrainConfig, {"env": {"traffic": {"top_up": True}}}, "x")  # no path_*
    assert oldest.env.traffic == TrafficBehaviour() and setting_name(oldest.env) == "sumo"


COMMITTED_SETTINGS = {
    "paper-point-tm": "tm-long",
    "budget-tm": "tm-long",
    "paper-point": "rude",
    "headline": "sumo",
}
"""Committed grids under results/ (run folders of the flat ``[env.traffic]`` form, recording
no setting name) -> the setting every one of their cells trained under."""


@pytest.mark.parametrize("grid", sorted(COMMITTED_SETTINGS))
def test_committed_run_folders_load_and_name_their_setting(grid: str) -> None:
    """Every committed cell of a grid written before :class:`PathBrakingConfig` and before
    runs recorded their setting loads through the run folder, and is named the setting its
    grid trained under (inferred from its config, as it records none)."""
    from priqn.env.traffic import run_setting_name
    from priqn.run.folder import RunFolder

    cells = sorted(
        (Path(__file__).resolve().parent.parent / "results" / grid).glob("*/config.toml")
    )
    assert cells, grid
    names = {}
    for config in cells:
        folder = RunFolder(config.parent)
        assert "traffic" not in folder.meta()  # an old run: the name is inferred
        names[config.parent.name] = run_setting_name(folder.meta(), folder.config().env)
    assert set(names.values()) == {COMMITTED_SETTINGS[grid]}, names


# ------------------------------------------------ an NPC straddling two lanes (issue 62)


@pytest.fixture(scope="module")
def two_lanes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A priority junction at (0, 0): the main road west-east has two lanes each way, the
    minor road goes north. From the west, the left lane (y −1.6) turns left only and the
    right lane (y −4.8) goes straight, so an NPC going straight from the left lane must
    change lanes before the junction."""
    edges = [("WC", "W", "C", 2, 2), ("CW", "C", "W", 2, 2), ("CE", "C", "E", 2, 2)]
    edges += [("EC", "E", "C", 2, 2), ("CN", "C", "N", 1, 1), ("NC", "N", "C", 1, 1)]
    connections = (
        '<connection from="WC" to="CE" fromLane="0" toLane="0"/>'
        '<connection from="WC" to="CE" fromLane="0" toLane="1"/>'
        '<connection from="WC" to="CN" fromLane="1" toLane="0"/>'
    )
    return _junction_net(tmp_path_factory.mktemp("two_lanes"), ("N", 150), edges, connections)


TURN_DEG = 10.0
"""The standing ego's heading, left of east: it has begun its left turn, so its rear
reaches into the right lane."""


def _drive_straddling(net: str, setting: str, **knobs: Any) -> dict:
    """The ego stands at the junction in the left lane, turned ``TURN_DEG`` to the left; one
    NPC of traffic ``setting`` (``knobs`` over it) comes from 60 m behind it in the same lane,
    going straight (so it must move to the right lane). Per step: the NPC's lateral position
    in its lane, its speed, the stage's hazard distance for it, whether its box overlaps the
    ego's, and its front's x [m]."""
    import libsumo as sim

    from priqn.env import geometry, reads
    from priqn.env.traffic import NPC_TYPE
    from priqn.sim.sumo import simulation_args

    tm = TRAFFIC_SETTINGS[setting].behaviour
    behaviour = dataclasses.replace(tm, path_braking=dataclasses.replace(tm.path_braking, **knobs))
    sim.start(simulation_args(net, seed=1, lateral_resolution_m=0.8))
    try:
        traffic = _stage_scene(
            sim, net, behaviour, ["WC", "CN"], ["WC", "CE"], departPos="100", departLane="1"
        )
        heading = np.radians(TURN_DEG)
        front = np.array([-1.0, EGO_LANE_Y_M])  # just past the stop line (x −7.2)
        centre = front - EGO_LENGTH_M / 2 * np.array([np.cos(heading), np.sin(heading)])
        angle = float(geometry.sumo_from_center(centre, heading, EGO_LENGTH_M)[1])
        ego_box = geometry.Boxes.make([centre], heading, EGO_LENGTH_M, EGO_WIDTH_M)
        npc = f"{NPC_PREFIX}0"
        sim.vehicle.add(npc, "priqn_route.0", typeID=NPC_TYPE, departLane="1",
                        departPos="89", departSpeed="max")  # fmt: skip
        rows = []
        for _ in range(200):
            stage = traffic.path_braking
            stage.check(reads.read_actors(sim, "ego"), tuple(centre), float(heading),
                        EGO_LENGTH_M, EGO_WIDTH_M)  # fmt: skip
            hazard = stage.hazard_m.get(npc)
            sim.vehicle.moveToXY("ego", "", -1, float(front[0]), float(front[1]), angle, 3)
            sim.simulationStep()
            if npc not in sim.vehicle.getIDList():
                continue
            length, npc_front = sim.vehicle.getLength(npc), np.array(sim.vehicle.getPosition(npc))
            c, h = geometry.center_from_sumo(npc_front, sim.vehicle.getAngle(npc), length)
            box = geometry.Boxes.make([c], h, length, sim.vehicle.getWidth(npc))
            rows.append((sim.vehicle.getLateralLanePosition(npc), sim.vehicle.getSpeed(npc),
                         hazard, bool(geometry.obb_overlap(ego_box, box)[0]), npc_front[0]))  # fmt: skip
        return {"rows": rows}
    finally:
        sim.close()


def test_tm_npc_straddling_two_lanes_misses_the_ego_on_the_lane_centre(two_lanes, worker) -> None:
    # `tm` as the calibration and paper-point-tm measured it: SUMO moves the NPC only as far
    # as the lane boundary (1.55 m left of the right lane's centre), the stage looks along
    # the right lane's centre line, where the ego's rear does not reach, and the NPC drives
    # through the junction into the ego's rear without braking.
    rows = worker.submit(_drive_straddling, str(two_lanes), "tm").result(timeout=240)["rows"]
    assert any(lat > 1.0 for lat, *_ in rows)  # it straddles
    assert any(r[3] for r in rows)
    assert all(r[2] is None for r in rows)  # the stage never saw the ego


def _straddle(worker: Any, net: Path, setting: str, **knobs: Any) -> list:
    return worker.submit(_drive_straddling, str(net), setting, **knobs).result(timeout=240)["rows"]


def test_tm_npc_looking_along_its_own_offset_stops_for_the_ego(two_lanes, worker) -> None:
    # follows_offset: the same NPC looks along its own lateral position, sees the
    # ego's rear in its path and stops 2 m short of it; no collision.
    rows = _straddle(worker, two_lanes, "tm", follows_offset=True)
    assert not any(r[3] for r in rows)
    seen = [r for r in rows if r[2] is not None]
    assert seen and min(r[1] for r in seen) == 0.0
    assert min(r[2] for r in seen) == pytest.approx(2.0, abs=0.5)


def test_tm_strict_keeps_its_margin_clear_of_the_ego(two_lanes, worker) -> None:
    # tm-strict adds a 0.5 m margin around the ego's box: the same NPC stops about 0.5 m
    # further back than with the offset alone (the ego's rear face, turned 10°, is met
    # about 0.5 / cos 10° = 0.51 m sooner along the path), and nothing touches.
    offset = _straddle(worker, two_lanes, "tm", follows_offset=True)
    strict = _straddle(worker, two_lanes, "tm-strict")
    assert not any(r[3] for r in strict)
    stop_x = [
        next(r[4] for r in rows if r[2] is not None and r[1] == 0.0) for rows in (offset, strict)
    ]
    assert stop_x[0] - stop_x[1] == pytest.approx(0.5, abs=0.15)


def test_a_path_shifted_to_the_left_by_hand() -> None:
    from priqn.env.path_braking import LanePath

    # A path east along y = 0, then north from (10, 0): 1 m to the left is y = 1 going
    # east, x = 9 going north.
    xy = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    path = LanePath(xy, np.array([0.0, 10.0, 20.0]), 1.0)
    points, ahead = path.ahead(0.0, 20.0, 5.0, lateral_m=1.0)
    np.testing.assert_allclose(ahead, [0.0, 5.0, 10.0, 15.0, 20.0])
    np.testing.assert_allclose(points[:2], [[0.0, 1.0], [5.0, 1.0]])
    np.testing.assert_allclose(points[3:], [[9.0, 5.0], [9.0, 10.0]])
    np.testing.assert_array_equal(path.ahead(0.0, 20.0, 5.0)[0][:, 1], [0.0, 0.0, 0.0, 5.0, 10.0])
