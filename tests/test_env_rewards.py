"""Reward terms, risk geometry, EnvConfig and option validation — no SUMO needed."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from priqn.config import from_dict
from priqn.env import rewards as R
from priqn.env.config import EnvConfig
from priqn.env.intersection import IntersectionEnv
from priqn.env.traffic import check_density
from priqn.errors import PriqnError
from priqn.objectives import OBJECTIVES

CFG = R.RewardConfig()


def test_safety_is_the_event_penalty_or_zero() -> None:
    assert R.safety(False, False, CFG) == 0.0
    assert R.safety(True, False, CFG) == -10.0
    assert R.safety(False, True, CFG) == -10.0
    assert R.safety(True, True, dataclasses.replace(CFG, collision_penalty=3.0)) == -3.0


def test_risk_by_hand() -> None:
    # time to conflict 1.5 s of 3 s -> 0.5; 0.75 s -> 0.75; 3 s or more -> 0; 0 -> 1
    assert R.risk(np.array([1.5]), CFG) == pytest.approx(-0.5)
    assert R.risk(np.array([0.75]), CFG) == pytest.approx(-0.75)
    assert R.risk(np.array([10.0, 0.0]), CFG) == pytest.approx(-0.5)
    assert R.risk(np.array([3.0, np.inf]), CFG) == 0.0


def test_lane_keeping_by_hand() -> None:
    # |d| = 0.75 of 1.5 -> 0.5 * 0.7; heading 0.35 rad = full -> 1 * 0.3
    got = R.lane_keeping(np.array([0.75]), np.array([-0.35]), CFG)
    assert got == pytest.approx(-(0.7 * 0.5 + 0.3 * 1.0))
    assert R.lane_keeping(np.zeros(5), np.zeros(5), CFG) == 0.0
    assert R.lane_keeping(np.array([9.0]), np.array([3.0]), CFG) == pytest.approx(-1.0)


def test_progress_by_hand() -> None:
    # 5 m in 0.5 s at v* = 10 m/s -> advance 1; speeds 10 -> adherence 1
    assert R.progress(5.0, np.full(5, 10.0), 10.0, 0.5, False, CFG) == pytest.approx(1.0)
    assert R.progress(0.0, np.zeros(5), 10.0, 0.5, False, CFG) == 0.0
    # half speed: advance 2.5/5 = 0.5, adherence 0.5 -> 0.5
    assert R.progress(2.5, np.full(5, 5.0), 10.0, 0.5, False, CFG) == pytest.approx(0.5)
    # speeding 2x: advance clipped at 1, adherence 0 -> 0.5; success adds the bonus
    assert R.progress(10.0, np.full(5, 20.0), 10.0, 0.5, True, CFG) == pytest.approx(1.5)


def test_comfort_by_hand() -> None:
    got = R.comfort(np.array([3.0]), np.array([-2.0]), CFG)  # 0.5 * 0.5 + 0.5 * 0.5
    assert got == pytest.approx(-0.5)
    assert R.comfort(np.zeros(3), np.zeros(3), CFG) == 0.0


def test_reward_vector_order_and_dtype() -> None:
    v = R.reward_vector(1, 2, 3, 4, 5)
    assert v.dtype == np.float32 and v.shape == (len(OBJECTIVES),)
    assert list(v) == [1, 2, 3, 4, 5]


def test_reward_config_rejects_bad_values() -> None:
    with pytest.raises(PriqnError, match="reward.conflict_time_safe_s"):
        from_dict(EnvConfig, {"reward": {"conflict_time_safe_s": 0.0}}, where="env.toml [env]")
    with pytest.raises(PriqnError, match="reward.lat_safe_gap_m"):
        from_dict(EnvConfig, {"reward": {"lat_safe_gap_m": -0.1}}, where="env.toml [env]")
    with pytest.raises(PriqnError, match="advance_weight"):
        from_dict(EnvConfig, {"reward": {"advance_weight": 2.0}}, where="env.toml [env]")


@pytest.mark.parametrize(
    ("data", "match"),
    [
        ({"decision_interval_s": 0.45}, "not a whole multiple of sim_step_s"),
        ({"densities": [0.5, 1.5]}, "densities: 1.5 is out of range"),
        ({"family": "city"}, "unknown pool 'city'"),
        ({"commands": ["uturn"]}, "unknown command 'uturn'"),
        ({"bev_channels": ["colour"]}, "unknown channel 'colour'"),
        ({"planning_horizon_s": 0.2}, "shorter than decision_interval_s"),
        ({"n_speeds": "five"}, "expected an integer"),
    ],
)
def test_env_config_errors_are_one_line(data: dict, match: str) -> None:
    with pytest.raises(PriqnError, match=match) as exc:
        from_dict(EnvConfig, data, where="cfg.toml [env]")
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize(
    ("densities", "match"),
    [
        (["abc"], r"densities: 'abc' is not a number; expected values in \(0, 1\]"),
        ([0.5, None], r"densities: None is not a number"),
        (0.5, r"densities: expected a list of numbers in \(0, 1\], got 0.5"),
        ("0.5", r"densities: expected a list of numbers"),
        ([True], r"densities: True is not a number"),
    ],
)
def test_env_config_densities_of_the_wrong_type_are_one_line(densities, match) -> None:
    # issue 10: EnvConfig(densities=["abc"]) raised a bare TypeError from a comparison.
    with pytest.raises(ValueError, match=match) as exc:
        EnvConfig(densities=densities)
    assert "\n" not in str(exc.value)


def test_nets_dir_errors_describe_that_folder(tmp_path) -> None:
    # issue 10: an empty nets_dir listed the repository's families instead.
    with pytest.raises(PriqnError) as exc:
        IntersectionEnv(EnvConfig(family="all", nets_dir=str(tmp_path)))
    assert str(exc.value) == (
        f"env.nets_dir: {tmp_path} has no tjunction/manifest.json (it holds no family); "
        f"generate nets there with 'priqn scenario generate --family tjunction --out {tmp_path}'"
    )
    (tmp_path / "fourway").mkdir()
    (tmp_path / "fourway" / "manifest.json").write_text('{"family": "fourway", "nets": []}')
    with pytest.raises(PriqnError, match=r"has no tjunction/manifest.json \(it holds fourway\)"):
        IntersectionEnv(EnvConfig(family="all", nets_dir=str(tmp_path)))
    with pytest.raises(PriqnError, match=r"fourway: the manifest lists no nets"):
        IntersectionEnv(EnvConfig(family="fourway", nets_dir=str(tmp_path)))
    missing = tmp_path / "nowhere"
    with pytest.raises(PriqnError, match=f"env.nets_dir: {missing} is not a folder"):
        IntersectionEnv(EnvConfig(nets_dir=str(missing)))


@pytest.mark.parametrize("bad", [0.0, -0.5, 1.01, float("nan"), "lots", None])
def test_density_out_of_range(bad: object) -> None:
    with pytest.raises(PriqnError, match="density"):
        check_density(bad)  # type: ignore[arg-type]


def test_action_table_and_spaces_without_sumo() -> None:
    env = IntersectionEnv(EnvConfig(family="tjunction", obs_size_px=32, n_speeds=3, n_offsets=2))
    table = env.action_table()
    assert table.shape == (6, 2)
    # index = i_speed * n_offsets + i_offset
    np.testing.assert_allclose(table[0], [0.0, -1.5])
    np.testing.assert_allclose(table[1], [0.0, 1.5])
    np.testing.assert_allclose(table[5], [12.0, 1.5])
    assert env.action_space.n == 6
    assert env.observation_space["bev"].shape == (4, 32, 32)
    assert env.observation_space["lidar"].shape == (2, 32, 32)
    assert env.observation_space["kinematics"].shape == (4,)
    env.close()


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"colour": "red"}, "unknown key 'colour'"),
        ({"density": 2.0}, "out of range"),
        ({"command": "uturn"}, "expected one of left, straight, right"),
        ({"net": "tjunction/nope_99"}, "no such net"),
        ({"net": "nope"}, "expected 'family/net_id'"),
    ],
)
def test_reset_option_errors_before_sumo_starts(options: dict, match: str) -> None:
    env = IntersectionEnv(EnvConfig(family="tjunction", obs_size_px=32))
    with pytest.raises(PriqnError, match=match) as exc:
        env.reset(seed=0, options=options)
    assert "\n" not in str(exc.value)
    assert not env._session.is_open  # nothing was started
    env.close()


def test_step_before_reset_is_a_clear_error() -> None:
    env = IntersectionEnv(EnvConfig(family="tjunction", obs_size_px=32))
    with pytest.raises(PriqnError, match="before reset"):
        env.step(0)
    env.close()


def test_vectorised_off_road_matches_geometry() -> None:
    from priqn.env import geometry
    from priqn.env.measures import off_road_steps
    from priqn.env.sensors import synthetic_crossroads

    polys, marks, _ = synthetic_crossroads(lane_width_m=3.5)
    raster = geometry.MapRaster.from_roadmap_arrays(polys, marks)
    rng = np.random.default_rng(0)
    x = rng.uniform(-12.0, 12.0, 200)
    y = rng.uniform(-12.0, 12.0, 200)
    head = rng.uniform(-np.pi, np.pi, 200)
    got = off_road_steps(raster, x, y, head, 4.5, 1.8)
    want = [
        geometry.is_off_road(raster, geometry.Boxes.make((a, b), h, 4.5, 1.8))
        for a, b, h in zip(x, y, head, strict=True)
    ]
    assert got.tolist() == want
    assert 10 < got.sum() < 190  # the sample covers both cases
