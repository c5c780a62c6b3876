"""IntersectionEnv in SUMO: scripted episodes, determinism, check_env, collisions, faults.

libsumo allows one simulation per process, so every test here runs its script in one
spawned worker process shared by the module (each script closes its env when done).
The scripts use the committed nets in ``sumo_nets/`` (generated from scenarios/*.toml).
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import warnings
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from priqn.errors import PriqnError

NET = "tjunction/tjunction_00"
SPEED_6 = 2  # index of 6 m/s in the default speed grid linspace(0, 12, 5)
SPEED_9 = 3  # index of 9 m/s


@pytest.fixture(scope="module")
def worker() -> Iterator[concurrent.futures.ProcessPoolExecutor]:
    ctx = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        yield pool


def run_in(worker: concurrent.futures.ProcessPoolExecutor, fn: Any, *args: Any) -> Any:
    return worker.submit(fn, *args).result(timeout=240)


# --------------------------------------------------------------------------- scripts (worker side)


def _make_env(**kw: Any):  # noqa: ANN202
    from priqn.env.config import EnvConfig
    from priqn.env.intersection import IntersectionEnv

    kw.setdefault("family", "tjunction")
    kw.setdefault("obs_size_px", 64)
    return IntersectionEnv(EnvConfig(**kw))


def _episode(cfg_kw: dict, seed: int, options: dict | None, actions: list[int]) -> dict:
    env = _make_env(**cfg_kw)
    try:
        obs, info = env.reset(seed=seed, options=options)
        out = {"obs": [obs], "rewards": [], "infos": [info], "ended": False}
        for a in actions:
            obs, r, term, trunc, info = env.step(a)
            out["obs"].append(obs)
            out["rewards"].append(r)
            out["infos"].append(info)
            if term or trunc:
                out["ended"] = True
                out["terminated"], out["truncated"] = term, trunc
                break
        return out
    finally:
        env.close()


def _add_parked_car(
    sim: Any, vid: str, edge: str, lane_index: int, pos_m: float, speed: float
) -> None:
    sim.route.add(f"{vid}_route", [edge])
    sim.vehicle.add(
        vid,
        f"{vid}_route",
        departLane=str(lane_index),
        departPos=f"{pos_m:.2f}",
        departSpeed=str(speed),
    )
    sim.vehicle.setWidth(vid, 2.0)
    sim.vehicle.setLaneChangeMode(vid, 0)
    if speed == 0.0:
        sim.vehicle.setSpeedMode(vid, 0)
        sim.vehicle.setSpeed(vid, 0.0)


def _scripted(case: str) -> dict:
    """Straight route, no traffic, no obstacles; ``case`` adds one scripted vehicle.

    'calm': nothing added. 'ahead': a stopped car 30 m ahead in the ego lane.
    'ahead9': the ego at 9 m/s, a stopped car 28 m ahead (front to front) in its lane.
    'partial': a stopped car in the opposite lane; the ego drives with an offset that puts
    ~1 m of it into that lane. 'head_on': a car driving towards the ego in the opposite
    lane, the ego fully in that lane. 'oncoming': the same car, the ego in its own lane.
    """
    import sumolib

    from priqn.sim.roadmap import RoadMap
    from priqn.sim.scenario import net_path

    roadmap = RoadMap.load(net_path(NET))
    route = roadmap.routes_for("straight")[0]
    net = sumolib.net.readNet(str(net_path(NET)))
    approach = net.getEdge(route.edges[0])
    lane_w = approach.getLane(0).getWidth()
    lane_index = int(route.start_lane_id.rsplit("_", 1)[1])
    opposite = next(
        e for e in approach.getToNode().getOutgoing() if e.getToNode() is approach.getFromNode()
    )
    # Lateral distance from the ego lane centre to the nearest opposite lane's centre.
    x_opp = (approach.getLaneNumber() - lane_index) * lane_w
    offset = {"partial": x_opp - 1.4, "head_on": x_opp}.get(case, 1.0)
    speed = (9.0, 9.0) if case == "ahead9" else (4.0, 8.0)
    env = _make_env(
        n_offsets=3, max_offset_m=offset, obstacles_per_episode=(0, 0), max_episode_steps=60,
        ego_start_speed_mps=speed,
    )  # fmt: skip
    try:
        env.reset(seed=1, options={"net": NET, "density": 0.01, "command": "straight"})
        sim = env._session.sim
        to_junction = approach.getLength() - route.start_pos_m
        if case == "ahead":
            _add_parked_car(
                sim, "blocker", route.edges[0], lane_index, route.start_pos_m + 30.0, 0.0
            )
        elif case == "ahead9":
            # SUMO refuses to insert a stopped car 28 m ahead of a car doing 9 m/s: insert it
            # at the end of the lane, then move it to 28 m ahead of the ego's front.
            edge = route.edges[0]
            _add_parked_car(sim, "blocker", edge, lane_index, approach.getLength() - 1.0, 0.0)
            sim.simulationStep()  # inserts it (the env moves the ego from its own state)
            x, y = sim.simulation.convert2D(edge, route.start_pos_m + 28.0, lane_index)
            angle = sim.vehicle.getAngle("blocker")
            sim.vehicle.moveToXY("blocker", edge, lane_index, x, y, angle, 1)
        elif case in ("partial", "head_on", "oncoming"):
            opp_lane = opposite.getLaneNumber() - 1  # nearest the centre line
            pos = to_junction - (30.0 if case == "partial" else 45.0)
            _add_parked_car(
                sim, "other", opposite.getID(), opp_lane, pos, 0.0 if case == "partial" else 8.0
            )
        in_lane = case in ("calm", "ahead", "ahead9", "oncoming")
        action = (SPEED_9 if case == "ahead9" else SPEED_6) * 3 + (1 if in_lane else 2)
        rewards, infos = [], []
        while True:
            _, r, term, trunc, info = env.step(action)
            rewards.append(r)
            infos.append(info)
            if term or trunc:
                break
        return {"rewards": np.array(rewards), "info": info, "terminated": term, "truncated": trunc}
    finally:
        env.close()


def _check_env() -> list[str]:
    import gymnasium
    from gymnasium.utils.env_checker import check_env

    import priqn  # noqa: F401 - registers priqn/Intersection-v0
    from priqn.env.config import EnvConfig

    made = gymnasium.make(
        "priqn/Intersection-v0", config=EnvConfig(obs_size_px=32), render_mode="rgb_array"
    )
    env = made.unwrapped
    # check_env makes an env per listed render mode; "human" opens sumo-gui, which needs a
    # display: tests/test_play.py checks that mode under Xvfb.
    env.metadata = {**env.metadata, "render_modes": ["rgb_array"]}
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(env, skip_render_check=False)
        frame = env.render()
        assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
        return [str(w.message) for w in caught]
    finally:
        env.close()


def _bad_actions() -> list[str]:
    env = _make_env()
    try:
        env.reset(seed=0)
        msgs = []
        for bad in (-1, 25, 1.5, "3", np.array([1, 2])):
            try:
                env.step(bad)
            except PriqnError as exc:
                msgs.append(str(exc))
        return msgs
    finally:
        env.close()


def _sumo_start_failure(path: str) -> str:
    from priqn.sim.session import SumoSession

    session = SumoSession()
    try:
        session.start(path, seed=0)
    except PriqnError as exc:
        return str(exc)
    finally:
        session.close()
    return "no error"


def _density_episode(density: float) -> tuple[float, int]:
    env = _make_env(obstacles_per_episode=(0, 0))
    try:
        env.reset(seed=3, options={"net": NET, "density": density, "command": "straight"})
        info = {}
        for _ in range(20):
            _, _, term, trunc, info = env.step(SPEED_6 * 5 + 2)
            if term or trunc:
                break
        return info["density_realised"], env._episode.traffic.target_count
    finally:
        env.close()


def _traffic_checks() -> dict:
    """Obstacles stand still; NPC lateral offsets are faded out inside the junction."""
    from priqn.env.traffic import NPC_PREFIX, OBSTACLE_PREFIX

    env = _make_env(family="fourway", obstacles_per_episode=(2, 2), max_episode_steps=80)
    try:
        out = {"obstacles": [], "junction_lat": [], "arm_lat": [], "obstacle_speed": []}
        for seed in range(3):
            _, info = env.reset(seed=seed, options={"density": 1.0})
            out["obstacles"].append(info["obstacles"])
            sim = env._session.sim
            for _ in range(40):
                _, _, term, trunc, _ = env.step(2)  # the ego stops in its lane; traffic flows
                for v in sim.vehicle.getIDList():
                    if v.startswith(OBSTACLE_PREFIX):
                        out["obstacle_speed"].append(sim.vehicle.getSpeed(v))
                    elif v.startswith(NPC_PREFIX):
                        lat = abs(sim.vehicle.getLateralLanePosition(v))
                        on_junction = sim.vehicle.getRoadID(v).startswith(":")
                        out["junction_lat" if on_junction else "arm_lat"].append(lat)
                if term or trunc:
                    break
        return out
    finally:
        env.close()


def _sumo_fails_mid_episode(where: str) -> list[str]:
    """Inject a libsumo exception at decision 2: after a SUMO step or in the traffic top-up."""
    import libsumo

    env = _make_env(obstacles_per_episode=(0, 0))
    try:
        env.reset(seed=0, options={"net": NET, "density": 0.5, "command": "straight"})
        env.step(SPEED_6 * 5 + 2)
        env.step(SPEED_6 * 5 + 2)
        owner, name = {
            "step": (libsumo, "simulationStep"),
            "top_up": (libsumo.simulation, "getPendingVehicles"),
        }[where]
        real = getattr(owner, name)

        def broken(*args: Any, **kwargs: Any) -> Any:
            real(*args, **kwargs)
            raise libsumo.TraCIException("injected failure")

        setattr(owner, name, broken)
        msgs = []
        try:
            env.step(SPEED_6 * 5 + 2)
        except PriqnError as exc:
            msgs.append(str(exc))
        finally:
            setattr(owner, name, real)
        try:
            env.step(SPEED_6 * 5 + 2)
        except PriqnError as exc:
            msgs.append(str(exc))
        env.reset(seed=1)  # the env recovers with a new episode
        env.step(SPEED_6 * 5 + 2)
        return msgs
    finally:
        env.close()


def _two_envs_one_process() -> tuple[bool, bool, str]:
    first, second = _make_env(), _make_env()
    try:
        first.reset(seed=0)
        second.reset(seed=1)  # takes libsumo over
        try:
            first.step(12)
            msg = "no error"
        except PriqnError as exc:
            msg = str(exc)
        second.step(12)  # the new owner keeps working
        return first._session.is_open, first._session.taken_over, msg
    finally:
        first.close()
        second.close()


def _unseeded_first_episodes() -> tuple[list[str], tuple[str, str]]:
    """Scene keys of the first reset of three fresh envs without a seed, and of two
    fresh envs built with seed=5 (each closed before the next: one SUMO per process)."""

    def key(env: Any) -> str:
        _, info = env.reset()
        return f"{info['net']} {info['command']} {env.np_random.integers(1 << 30)}"

    from priqn.env.config import EnvConfig
    from priqn.env.intersection import IntersectionEnv

    fresh, fixed = [], []
    for seed, out in ((None, fresh), (None, fresh), (None, fresh), (5, fixed), (5, fixed)):
        env = IntersectionEnv(EnvConfig(obs_size_px=32), seed=seed)
        try:
            out.append(key(env))
        finally:
            env.close()
    return fresh, (fixed[0], fixed[1])


def _render_sizes() -> tuple[tuple[int, ...], tuple[int, ...], tuple[int, ...]]:
    from priqn.env.config import EnvConfig
    from priqn.env.intersection import IntersectionEnv

    env = IntersectionEnv(EnvConfig(obs_size_px=32, render_size_px=96), render_mode="rgb_array")
    try:
        obs, _ = env.reset(seed=0)
        first = env.render().shape
        obs, *_ = env.step(12)
        return obs["bev"].shape, first, env.render().shape
    finally:
        env.close()


# --------------------------------------------------------------------------- tests


def test_calm_straight_crossing_succeeds(worker) -> None:
    out = run_in(worker, _scripted, "calm")
    assert out["terminated"] and out["info"]["success"]
    assert not out["info"]["collision"] and not out["info"]["off_road"]
    assert out["info"]["route_progress"] == 1.0
    safety, progress = out["rewards"][:, 0], out["rewards"][:, 3]
    assert np.all(safety == 0.0)
    assert np.all(progress > 0.0) and progress[-1] > 1.0  # success bonus on the last step
    assert out["info"]["density_realised"] == 0.0


def test_driving_into_a_stopped_car_collides(worker) -> None:
    out = run_in(worker, _scripted, "ahead")
    assert out["terminated"] and out["info"]["collision"] and not out["info"]["success"]
    assert out["rewards"][-1, 0] < 0.0  # safety
    assert np.all(out["rewards"][:-1, 0] == 0.0)
    assert out["rewards"][-1, 1] < 0.0  # risk: touching at the end
    assert np.all(out["info"]["returns"] == pytest.approx(out["rewards"].sum(0), abs=1e-4))


def test_risk_fires_well_before_hitting_a_stopped_car(worker) -> None:
    # issue 9: approaching a stopped car at 9 m/s from 28 m must be clearly risky
    # (below -0.3 at some decision before contact), growing towards the contact.
    out = run_in(worker, _scripted, "ahead9")
    assert out["info"]["collision"]
    risk = out["rewards"][:, 1]
    assert len(risk) >= 4
    assert risk[:-1].min() < -0.3
    assert np.all(np.diff(risk) <= 1e-6)  # never decreasing risk on the way in
    assert risk[-1] == pytest.approx(-1.0, abs=0.25)  # inside the envelope at the end


def test_oncoming_car_in_the_opposite_lane_costs_no_risk(worker) -> None:
    # issue 9: the old clearance + centre-distance TTC charged -0.4..-0.96 per decision here.
    out = run_in(worker, _scripted, "oncoming")
    assert not out["info"]["collision"] and not out["info"]["off_road"]
    assert np.all(out["rewards"][:, 1] == 0.0)


def test_ego_partly_in_the_opposite_lane_collides(worker) -> None:
    out = run_in(worker, _scripted, "partial")
    assert out["info"]["collision"] and not out["info"]["off_road"]
    assert out["rewards"][-1, 0] < 0.0


def test_head_on_in_the_opposite_lane_collides(worker) -> None:
    out = run_in(worker, _scripted, "head_on")
    assert out["info"]["collision"] and not out["info"]["off_road"]
    assert out["rewards"][-1, 0] < 0.0
    assert np.all(out["rewards"][:, 2] <= 0.0)  # lane keeping pays for the offset


def test_same_seed_same_episode_bit_for_bit(worker) -> None:
    actions = [17, 12, 22, 7, 17, 18, 16, 17, 13, 17] * 3
    a = run_in(worker, _episode, {}, 11, None, actions)
    b = run_in(worker, _episode, {}, 11, None, actions)
    c = run_in(worker, _episode, {}, 12, None, actions)
    assert len(a["obs"]) == len(b["obs"]) > 5
    for oa, ob in zip(a["obs"], b["obs"], strict=True):
        for key in oa:
            np.testing.assert_array_equal(oa[key], ob[key])
    np.testing.assert_array_equal(np.array(a["rewards"]), np.array(b["rewards"]))
    assert a["infos"][-1]["density_realised"] == b["infos"][-1]["density_realised"]
    differs = (a["infos"][0]["net"], a["infos"][0]["command"]) != (
        c["infos"][0]["net"],
        c["infos"][0]["command"],
    ) or any(
        not np.array_equal(x["bev"], y["bev"]) for x, y in zip(a["obs"], c["obs"], strict=False)
    )
    assert differs


def test_info_has_everything_tables_need(worker) -> None:
    out = run_in(
        worker, _episode, {}, 5, {"net": NET, "density": 0.75, "command": "left"}, [17] * 200
    )
    assert out["ended"]
    info = out["infos"][-1]
    for key in ("success", "collision", "off_road", "timeout", "route_progress", "density_requested",
                "density_realised", "net", "command", "returns", "episode_steps", "reward_names"):  # fmt: skip
        assert key in info, key
    assert info["net"] == NET and info["command"] == "left" and info["density_requested"] == 0.75
    assert info["reward_names"] == ("safety", "risk", "lane_keeping", "progress", "comfort")
    assert sum(bool(info[k]) for k in ("success", "collision", "off_road", "timeout")) == 1
    assert 0.0 <= info["route_progress"] <= 1.0
    assert info["episode_steps"] == len(out["rewards"])
    obs = out["obs"][-1]
    assert obs["command"].tolist() == [1.0, 0.0, 0.0]
    assert obs["bev"].dtype == np.uint8 and obs["bev"].shape == (4, 64, 64)
    assert obs["lidar"].shape == (2, 64, 64) and obs["lidar"].any()


def test_gymnasium_check_env_passes(worker) -> None:
    msgs = run_in(worker, _check_env)
    # The vector reward is the contract; gymnasium's only complaint may be about that.
    others = [m for m in msgs if "reward" not in m.lower()]
    assert not others, others


def test_out_of_range_actions_are_one_line_errors(worker) -> None:
    msgs = run_in(worker, _bad_actions)
    assert len(msgs) == 5
    for m in msgs:
        assert m.startswith("action ") and "expected an integer in [0, 24]" in m and "\n" not in m


def test_sumo_start_failure_names_the_net(worker, tmp_path) -> None:
    bad = tmp_path / "broken.net.xml"
    bad.write_text("<net>not a network</net>\n")
    msg = run_in(worker, _sumo_start_failure, str(bad))
    assert msg.startswith(f"{bad}: SUMO failed to start:") and "\n" not in msg
    missing = run_in(worker, _sumo_start_failure, str(tmp_path / "missing.net.xml"))
    assert "missing.net.xml" in missing and "not found" in missing


def test_realised_density_follows_the_request(worker) -> None:
    low, low_target = run_in(worker, _density_episode, 0.25)
    high, high_target = run_in(worker, _density_episode, 1.0)
    assert low_target < high_target
    assert 0.0 < low < high <= 1.0


def test_obstacles_stand_and_offsets_fade_before_the_junction(worker) -> None:
    out = run_in(worker, _traffic_checks)
    assert out["obstacles"] == [2, 2, 2]
    assert out["obstacle_speed"] and max(out["obstacle_speed"]) == 0.0
    assert len(out["junction_lat"]) > 20
    assert max(out["junction_lat"]) < 0.15  # faded to the lane centre in the junction
    assert max(out["arm_lat"]) > 0.2  # while offsets exist on the arms


@pytest.mark.parametrize("where", ["step", "top_up"])
def test_sumo_failure_mid_episode_is_one_line_naming_net_and_decision(worker, where) -> None:
    # issue 10: this path used to raise TypeError ('_Episode' object is not subscriptable).
    failed, after = run_in(worker, _sumo_fails_mid_episode, where)
    assert failed == f"{NET}: SUMO failed at decision 2 (TraCIException: injected failure)"
    assert "after the episode ended" in after


def test_second_env_in_one_process_takes_sumo_over_cleanly(worker) -> None:
    is_open, taken_over, msg = run_in(worker, _two_envs_one_process)
    assert not is_open and taken_over
    assert "taken over by another env" in msg and "\n" not in msg


def test_reset_without_seed_draws_fresh_entropy(worker) -> None:
    fresh, fixed = run_in(worker, _unseeded_first_episodes)
    assert len(set(fresh)) == 3  # gymnasium's convention: no seed, fresh entropy
    assert fixed[0] == fixed[1]  # a constructor seed still fixes the first episode


def test_render_size_is_separate_from_the_observation_size(worker) -> None:
    bev, first, after = run_in(worker, _render_sizes)
    assert bev == (4, 32, 32)
    assert first == after == (96, 192, 3)  # BEV | LiDAR side by side at 96 px


def _episode_after(preload: bool) -> dict:
    """Reset (seed 5) and three steps, with or without ``preload_nets`` first (worker side)."""
    import hashlib

    from priqn.env.config import EnvConfig
    from priqn.env.intersection import IntersectionEnv

    env = IntersectionEnv(EnvConfig(obs_size_px=32))
    try:
        if preload:
            assert env.preload_nets() == len(env.net_pool)
        obs, _ = env.reset(seed=5)
        digest = hashlib.sha256(obs["bev"].tobytes() + obs["lidar"].tobytes())
        rewards = []
        for action in (7, 12, 12):
            obs, reward, *_ = env.step(action)
            digest.update(obs["bev"].tobytes())
            rewards.append(reward.tolist())
        return {"obs": digest.hexdigest(), "rewards": rewards,
                "rng": env.np_random.bit_generator.state}  # fmt: skip
    finally:
        env.close()


def _generators_around_preload() -> tuple[bool, bool, bool]:
    """Whether ``preload_nets`` left Python's and numpy's global generators as they were,
    and created no env generator (worker side; before any reset, so nothing reseeds)."""
    import random

    import numpy as np

    from priqn.env.config import EnvConfig
    from priqn.env.intersection import IntersectionEnv

    random.seed(11)
    np.random.seed(11)
    py_before, np_before = random.getstate(), np.random.get_state()
    env = IntersectionEnv(EnvConfig(obs_size_px=32))
    try:
        env.preload_nets()
        np_after = np.random.get_state()
        same_np = all(np.array_equal(a, b) for a, b in zip(np_before, np_after, strict=True))
        return random.getstate() == py_before, same_np, env._np_random is None
    finally:
        env.close()


def test_preloading_draws_no_random_number(worker) -> None:
    assert run_in(worker, _generators_around_preload) == (True, True, True)


def test_preloading_the_nets_changes_no_episode(worker) -> None:
    # Training and evaluation preload every worker's nets (and the sensors' compiled
    # loops) before the first reset: the same observations, rewards and generator after.
    assert run_in(worker, _episode_after, True) == run_in(worker, _episode_after, False)
