"""Objectives as declarations: resolution, the default list unchanged, the right-of-way
measure on hand-built scenes, and a run with an objective declared in a test module."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from priqn.agents.scalarise import crash_margin, scheme_weights
from priqn.env import geometry
from priqn.env.reads import Actors, StepActors
from priqn.env.right_of_way import ConflictArea, conflict_areas, foe_due, violation_steps
from priqn.errors import PriqnError
from priqn.evaluation.protocol import EPISODE_COLUMNS, episode_columns
from priqn.objectives import (
    BUILTIN_OBJECTIVES,
    OBJECTIVES,
    Objective,
    objective_names,
    resolve_objectives,
)
from priqn.run.metrics import METRIC_COLUMNS, metric_columns

ROOT = Path(__file__).resolve().parents[1]
SIX = ("safety", "right_of_way", "risk", "lane_keeping", "progress", "comfort")
OWN = (*OBJECTIVES, "tests.objective_example:CONSTANT")


# ---------------------------------------------------------------------------- declarations


def test_the_five_builtins_are_declared_and_the_default_list_is_theirs():
    declared = resolve_objectives(OBJECTIVES)
    assert tuple(o.name for o in declared) == OBJECTIVES
    assert [o.cost_only for o in declared] == [True, True, True, False, True]
    assert "right_of_way" in BUILTIN_OBJECTIVES and "right_of_way" not in OBJECTIVES
    # The default columns are exactly the ones before objectives were declared.
    assert metric_columns() == METRIC_COLUMNS and episode_columns() == EPISODE_COLUMNS
    assert METRIC_COLUMNS[7:12] == tuple(f"return_{o}" for o in OBJECTIVES)


def test_an_objective_from_a_dotted_path_and_one_line_errors():
    assert objective_names(OWN)[-1] == "constant_cost"
    assert objective_names([*OBJECTIVES, "tests.objective_example:IDLE"])[-1] == "idle"
    for entries, msg in (
        ([*OBJECTIVES, "no_such_term"], r"env.objectives: unknown objective 'no_such_term'"),
        ([*OBJECTIVES, "tests.objective_example:nope"], r"has no 'nope'"),
        ([*OBJECTIVES, "tests.objective_example:IDLE_SPEED_MPS"], r"expected a priqn.objec"),
        (["safety", "safety"], r"objective 'safety' is listed twice"),
        ([], r"expected a non-empty list"),
    ):
        with pytest.raises(PriqnError, match=msg) as err:
            resolve_objectives(entries)
        assert "\n" not in str(err.value)
    with pytest.raises(PriqnError, match="cost_only = true but bounds allow rewards > 0"):
        Objective("x", "a:b", "a:c", (-1.0, 1.0), cost_only=True)


def test_the_env_reward_space_follows_the_declared_list():
    from priqn.env.intersection import IntersectionEnv

    env = IntersectionEnv(objectives=[*SIX, "tests.objective_example:IDLE"], obs_size_px=32)
    assert env.objectives.names == (*SIX, "idle")
    assert env.reward_space.low.tolist() == [-10.0, -1.0, -1.0, -1.0, 0.0, -1.0, -0.5]
    assert env.reward_space.high.tolist() == [0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0]
    default = IntersectionEnv(obs_size_px=32).reward_space  # unchanged
    assert default.low.tolist() == [-10.0, -1.0, -1.0, 0.0, -1.0]
    assert default.high.tolist() == [0.0, 0.0, 0.0, 2.0, 0.0]
    with pytest.raises(PriqnError, match=r"^env.objectives: unknown objective 'nope'"):
        IntersectionEnv(objectives=["safety", "nope"])


def test_the_crash_bound_counts_every_cost_only_objective():
    # right_of_way ([-1, 0], cost only) sits at level 1: hln-2 keeps its margin of 2.
    w = scheme_weights("hln-2", objectives=SIX)
    assert len(w) == 6 and crash_margin(w, objectives=SIX) == pytest.approx(2.0)
    # By hand: share = Σ ρ^-(level-1) over right_of_way 1, risk 2, lane 3, comfort 5.
    c = 10.0 / (2.0 * (1 - 0.99**100) / 0.01 * (1 + 0.5 + 0.25 + 0.0625))
    assert w[1] == pytest.approx(c) and w[2] == pytest.approx(c / 2)
    # A test-module objective of range [-0.25, 0] weighs a quarter of a unit penalty.
    w_own = scheme_weights("hln-2-task", objectives=OWN)
    assert crash_margin(w_own, objectives=OWN) == pytest.approx(2.0)
    with pytest.raises(PriqnError, match="fixed weights for the 5 default objectives"):
        scheme_weights("halving", objectives=SIX)
    with pytest.raises(PriqnError, match="need 'safety' first in env.objectives"):
        scheme_weights("hln-2", objectives=("risk", "safety"))


def test_a_run_config_follows_its_objectives():
    from priqn.agents.registry import make_agent
    from priqn.run.train_config import resolve_config

    cfg = resolve_config(preset="right-of-way", agent="pr-iqn", steps=100)
    assert cfg.objective_names == SIX and len(cfg.reward_weights) == 6
    agent = make_agent("pr-iqn", cfg.resolved_agent, cfg.objective_names)
    assert agent.num_heads == 6 and agent.subsets.preorder.objectives == SIX
    assert agent.subsets.preorder.is_chain()
    iqn = make_agent("iqn", cfg.resolved_agent, cfg.objective_names)
    assert iqn.num_heads == 1 and iqn.reward_weights_O.shape == (6,)
    # 'total' with other objectives is the chain of env.objectives in their order.
    own = resolve_config(agent="pr-iqn", overrides=[f"env.objectives={list(OWN)}"])
    po = make_agent("pr-iqn", own.resolved_agent, own.objective_names).subsets.preorder
    assert po.topological_order() == (*OBJECTIVES, "constant_cost")
    with pytest.raises(PriqnError, match=r"agent.preorder: .*extra: right_of_way"):
        resolve_config(agent="pr-iqn", overrides=["agent.preorder=right-of-way"])
    with pytest.raises(PriqnError, match=r"eps: expected one number or 6 numbers"):
        resolve_config(preset="right-of-way", overrides=["agent.eps=[0.1, 0.1, 0.1, 0.1, 0.1]"])


# ---------------------------------------------------------------------------- right of way


def crossing_area() -> ConflictArea:
    """Foe link: straight north along x = 0 from y = -20 to y = 20 (lane 3 m wide); the ego
    lane runs east along y = 0 (3 m wide). The lanes overlap where |y| <= 1.5 + 1.5 = 3 m,
    i.e. at foe arc length σ = y + 20 in [17, 23] m."""
    path = np.stack([np.zeros(81), np.linspace(-20.0, 20.0, 81)], axis=1)
    ego_line = np.array([[-10.0, 0.0], [10.0, 0.0]])
    area = ConflictArea.of("north", path, 1.5, ego_line, 1.5)
    assert area is not None
    return area


def ego_boxes(*xs: float) -> geometry.Boxes:
    """The ego (4.5 m x 1.8 m) heading east at (x, 0), one box per step."""
    return geometry.Boxes.make([(x, 0.0) for x in xs], 0.0, 4.5, 1.8)


def one_actor(x: float, y: float, heading: float, speed: float, length: float = 4.0) -> Actors:
    return Actors(geometry.Boxes.make([(x, y)], heading, length, 1.8), np.array([speed]))


def test_the_conflict_area_is_where_the_lanes_overlap():
    area = crossing_area()
    assert (area.enter_s_m, area.leave_s_m) == pytest.approx((17.0, 23.0))
    assert np.allclose(area.centers_xy[:, 1], np.arange(-3.0, 3.01, 0.5))


def test_the_foe_is_due_when_it_reaches_the_area_within_the_horizon():
    area, north, south = crossing_area(), math.pi / 2, -math.pi / 2
    cases = [
        # (actor, due?) with T = 3 s; the foe's front is σ + 2 (length 4 m)
        (one_actor(0.0, -12.0, north, 5.0), True),  # front σ 10: (17 - 10) / 5 = 1.4 s
        (one_actor(0.0, -12.0, north, 2.0), False),  # 7 / 2 = 3.5 s > 3 s
        (one_actor(0.0, -12.0, north, 0.0), False),  # standing before the area
        (one_actor(0.0, 1.0, north, 0.0), True),  # inside the area (σ 21)
        (one_actor(0.0, 12.0, north, 5.0), False),  # past it: rear σ 30 > 23
        (one_actor(0.0, -12.0, south, 5.0), False),  # wrong way: not on the link
        (one_actor(2.0, -12.0, north, 5.0), False),  # 2 m beside the centre line > 1.5 m
    ]
    for actor, due in cases:
        assert foe_due(area, StepActors.of([actor]), 3.0).tolist() == [due]


def test_a_violation_needs_the_ego_in_the_area_and_a_priority_foe_due():
    area, north = crossing_area(), math.pi / 2
    foe = one_actor(0.0, -12.0, north, 5.0)
    # Ego centre x: 0 (on the area), -3.5 (front bumper at -1.25: 1.25 m from the centre
    # line < r = 1.5 m), -4 (front at -1.75 m: outside), -6 (front at -3.75 m: outside).
    ego = ego_boxes(0.0, -3.5, -4.0, -6.0)
    steps = StepActors.of([foe, foe, foe, foe])
    assert violation_steps(ego, steps, [area], 3.0).tolist() == [True, True, False, False]
    # No foe at the second step, a slow one at the first: no violation.
    quiet = StepActors.of([one_actor(0.0, -12.0, north, 2.0), Actors.empty()])
    assert violation_steps(ego_boxes(0.0, 0.0), quiet, [area], 3.0).tolist() == [False, False]
    from priqn.env.right_of_way import reward

    assert (reward(True, None), reward(False, None)) == (-1.0, 0.0)


def test_conflict_areas_follow_the_nets_right_before_left_rule():
    """tjunction_00 (right_before_left): a left turn from the stem a1 yields to the links
    from a2 (on its right); right turns yield to nobody."""
    from priqn.sim.roadmap import RoadMap

    rm = RoadMap.load(ROOT / "priqn/data/sumo_nets/tjunction/tjunction_00.net.xml")
    areas = {r.name: conflict_areas(str(rm.net_path), rm.junction_id, r.lane_ids)
             for c in ("left", "straight", "right") for r in rm.routes_for(c)}  # fmt: skip
    assert {a.foe_link.split("->")[0] for a in areas["a1_in->a0_out"]} == {"a2_in_1"}
    assert all(not areas[r.name] for r in rm.routes_for("right"))
    for a in areas["a1_in->a0_out"]:  # inside the junction: past the foe's stop line (80 m)
        assert 80.0 <= a.enter_s_m < a.leave_s_m


# ---------------------------------------------------------------------------- a real run

TINY = [
    "--steps", "120", "--device", "cpu", "--seed", "3",
    "--set", "env.obs_size_px=32", "--set", "env.max_episode_steps=25",
    "--set", "replay.learning_starts=64", "--set", "replay.capacity=4000",
    "--set", "network.latent_dim=64", "--set", "network.hidden_dim=64",
    "--set", "learner.num_tau_samples=8", "--set", "learner.num_tau_prime_samples=8",
    "--set", "learner.num_quantiles=8", "--set", "log_interval_steps=50",
    "--set", "evaluation.interval_steps=0",
]  # fmt: skip


def cli(*args: str, ok: bool = True) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg", PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-m", "priqn.cli", *args], capture_output=True,
                         text=True, timeout=600, cwd=ROOT, env=env)  # fmt: skip
    assert (out.returncode == 0) == ok, out.stderr[-3000:]
    return out


@pytest.fixture(scope="module")
def own_objective_run(tmp_path_factory) -> Path:
    """Pr-IQN with a sixth objective from tests/objective_example.py, trained and evaluated."""
    root = tmp_path_factory.mktemp("objective")
    cli("train", "--agent", "pr-iqn", "--runs-dir", str(root), "--name", "own", *TINY,
        "--set", f"env.objectives={json.dumps(list(OWN))}")  # fmt: skip
    cli("evaluate", str(root / "own"), "--episodes", "1", "--eval-runs", "1",
        "--densities", "0.5")  # fmt: skip
    return root / "own"


def test_an_objective_from_a_test_module_trains_evaluates_and_shows(own_objective_run, tmp_path):
    run = own_objective_run
    meta = json.loads((run / "meta.json").read_text())
    assert meta["status"] == "complete" and meta["objectives"][-1] == "constant_cost"
    assert meta["objective_declarations"][-1]["reward"] == "tests.objective_example:reward_constant"
    metrics = pd.read_csv(run / "metrics.csv")
    assert tuple(metrics.columns) == metric_columns((*OBJECTIVES, "constant_cost"))
    train = metrics[metrics["kind"] == "train"]
    assert len(train) and np.allclose(train["return_constant_cost"], -0.25 * train["length"])
    import torch

    state = torch.load(run / "policy.pt", weights_only=True)
    assert state["objectives"][-1] == "constant_cost"
    assert state["online"]["head_out.weight"].shape[0] == 6 * 25  # six heads x 25 actions
    episodes = pd.read_csv(run / "eval" / "episodes.csv")
    assert np.allclose(episodes["return_constant_cost"], -0.25 * episodes["steps"])
    assert episodes["subset_constant_cost"].notna().all()
    # Table I shows the declared objective's column.
    from priqn.analysis.load import load_evaluation
    from priqn.analysis.tables import table1

    table = table1(load_evaluation(run.parent).episodes, ranked=False)
    assert "return_constant_cost" in [m.column for m in table.metrics]
    # priqn inspect shows it decision by decision.
    scene = episodes.iloc[0]
    cli("inspect", str(run), "--net", scene["net"], "--density", "0.5", "--out", str(tmp_path))
    decisions = pd.read_csv(tmp_path / "decisions.csv")
    assert (decisions["reward_constant_cost"] == -0.25).all()
    assert "size_constant_cost" in decisions.columns


def test_a_policy_or_resume_with_another_objective_list_is_refused(own_objective_run, tmp_path):
    import shutil

    from priqn.run.checkpointer import load_policy

    copy = tmp_path / "copy"
    shutil.copytree(own_objective_run, copy)
    cfg = (copy / "config.toml").read_text()
    (copy / "config.toml").write_text(
        cfg.replace("tests.objective_example:CONSTANT", "tests.objective_example:IDLE")
    )
    with pytest.raises(PriqnError, match=r"trained for objectives .*constant_cost.* lists .*idle"):
        load_policy(copy)
    # Resuming it: the checkpoint's objectives are not those config.toml now lists.
    out = cli("train", "--resume", str(copy), "--steps", "240", ok=False)
    assert "--resume: the run was trained for objectives" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1


def test_right_of_way_preset_trains_six_heads(tmp_path):
    """A short seeded smoke (120 decisions, ~15 s): six heads, the preset's preorder."""
    cli("train", "--preset", "right-of-way", "--agent", "pr-iqn", "--runs-dir", str(tmp_path),
        "--name", "row", *TINY, "--set", "env.family=fourway")  # fmt: skip
    meta = json.loads((tmp_path / "row" / "meta.json").read_text())
    assert meta["status"] == "complete" and meta["objectives"] == list(SIX)
    rows = pd.read_csv(tmp_path / "row" / "metrics.csv")
    assert (rows["return_right_of_way"] <= 0).all() and "subset_right_of_way" in rows.columns
