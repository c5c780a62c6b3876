"""Evaluating a trained run under another traffic setting's NPCs (issue 68: the committed
``tm-long`` cells played under ``tm-carla``): the folder it goes to (``eval-traffic-<name>/``,
never ``eval/``), the env it plays (only ``env.traffic`` replaced), and Table II leaving it
out (tests/test_out_of_range.py, with the family evaluations). No SUMO runs here."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import pytest

from priqn.env.traffic import TRAFFIC_SETTINGS, traffic_values
from priqn.errors import PriqnError
from priqn.evaluation.cli import config_from_args, configure_parser
from priqn.evaluation.protocol import (
    EvalConfig,
    eval_dir_of,
    evaluation_name,
    is_family_evaluation,
    is_traffic_evaluation,
)
from priqn.evaluation.targets import evaluation_env
from priqn.run.folder import RunFolder
from priqn.run.train_config import resolve_config


def test_another_traffic_evaluates_beside_eval() -> None:
    own = EvalConfig(max_episode_steps=200)
    carla = dataclasses.replace(own, traffic="tm-carla")
    assert evaluation_name(own) == "" and evaluation_name(carla) == "traffic-tm-carla"
    assert eval_dir_of(RunFolder("r"), carla) == Path("r/eval-traffic-tm-carla")
    both = dataclasses.replace(carla, snapshot=60000, family="out-of-range", acting="near-greedy")
    assert evaluation_name(both) == "at60000-family-out-of-range-traffic-tm-carla-near-greedy"
    assert is_traffic_evaluation("traffic-tm-carla") and is_traffic_evaluation(
        evaluation_name(both)
    )
    assert not is_traffic_evaluation("") and not is_traffic_evaluation("near-greedy")
    assert not is_traffic_evaluation("family-out-of-range") and is_family_evaluation(
        evaluation_name(both)
    )


def test_cli_traffic_flag_checks_the_name_first() -> None:
    parser = argparse.ArgumentParser()
    configure_parser(parser)
    cfg = config_from_args(parser.parse_args(["r", "--traffic", "tm-carla"]))
    assert cfg.traffic == "tm-carla"
    with pytest.raises(PriqnError, match=r"unknown setting 'tm-carl' .*did you mean 'tm-carla'"):
        config_from_args(parser.parse_args(["r", "--traffic", "tm-carl"]))


def test_only_the_npcs_change() -> None:
    """A tm-long run played under tm-carla: its NPC behaviour is tm-carla's, everything
    else (the episode limit of 200 included) the run's own; no traffic: the run's own."""
    run_env = resolve_config(values=traffic_values("tm-long")).env
    env = evaluation_env(run_env, EvalConfig(traffic="tm-carla"), None)
    assert env.traffic == TRAFFIC_SETTINGS["tm-carla"].behaviour
    assert (
        env.traffic.path_braking.look_ahead_form == "carla"
        and run_env.traffic.path_braking.look_ahead_form == "linear"
    )
    assert env.max_episode_steps == run_env.max_episode_steps == 200
    assert dataclasses.replace(env, traffic=run_env.traffic) == evaluation_env(
        run_env, EvalConfig(), None
    )
    assert evaluation_env(run_env, EvalConfig(), None).traffic == run_env.traffic
