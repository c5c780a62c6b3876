"""How NPCs treat the ego (``EnvConfig.traffic``), on cases built by hand.

A priority T-junction drawn by hand: the main road runs west-east through the centre
(0, 0), the minor road comes from the south. The ego drives east on the main road at
8 m/s, moved by ``moveToXY`` exactly as the env moves it; it has priority. One NPC comes up
the minor road and turns left (west), across the ego's lane, timed to reach the junction
about a second before the ego. SUMO runs in a spawned process (one simulation per process).
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import subprocess
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

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


@pytest.fixture(scope="module")
def tjunction(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("handmade")
    (d / "t.nod.xml").write_text(
        '<nodes><node id="W" x="-150" y="0" type="dead_end"/>'
        '<node id="E" x="150" y="0" type="dead_end"/>'
        '<node id="S" x="0" y="-150" type="dead_end"/>'
        '<node id="C" x="0" y="0" type="priority"/></nodes>'
    )
    edges = [("WC", "W", "C", 2), ("CW", "C", "W", 2), ("EC", "E", "C", 2)]
    edges += [("CE", "C", "E", 2), ("SC", "S", "C", 1), ("CS", "C", "S", 1)]
    (d / "t.edg.xml").write_text(
        "<edges>"
        + "".join(
            f'<edge id="{i}" from="{a}" to="{b}" priority="{p}" numLanes="1" speed="13.89"/>'
            for i, a, b, p in edges
        )
        + "</edges>"
    )
    net = d / "t.net.xml"
    subprocess.run(
        [sumo.binary("netconvert"), "-n", str(d / "t.nod.xml"), "-e", str(d / "t.edg.xml"),
         "-o", str(net), "--offset.disable-normalization", "true", "--no-warnings", "true"],
        check=True, capture_output=True, env=sumo.subprocess_env(),
    )  # fmt: skip
    return net


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
    assert traffic_values("sumo") == ()
    assert traffic_values("rude-finite-long") == (
        ("env.traffic.yield_to_ego_prob", 0.0),
        ("env.traffic.top_up", False),
        ("env.max_episode_steps", 200),
    )


def test_every_named_setting_builds_a_train_config() -> None:
    from priqn.run.train_config import resolve_config

    for name in TRAFFIC_SETTINGS:
        cfg = resolve_config(values=traffic_values(name))
        assert cfg.env.traffic == TrafficBehaviour(**{
            k.removeprefix("traffic."): v
            for k, v in TRAFFIC_SETTINGS[name].env if k.startswith("traffic.")
        })  # fmt: skip
