"""Collision forensics (priqn/env/forensics.py) on windows built by hand: boxes moving at
constant speed, one step per 0.1 s, the collision in the last step. The ego is 4.5 x 1.8 m,
the NPC 5 x 2 m; SUMO reads an actor's front bumper and its angle clockwise from north."""

from __future__ import annotations

import libsumo
import numpy as np
import pytest

from priqn.env.forensics import Step, classify, point_box_distance_m
from priqn.objectives import COLLISION_KINDS

DT = 0.1
EGO_L, EGO_W = 4.5, 1.8


def _npc(front_xy, heading_rad, speed):
    angle = (90.0 - np.degrees(heading_rad)) % 360.0
    return {libsumo.VAR_POSITION: tuple(front_xy), libsumo.VAR_ANGLE: angle,
            libsumo.VAR_SPEED: speed, libsumo.VAR_LENGTH: 5.0, libsumo.VAR_WIDTH: 2.0}  # fmt: skip


def _window(
    ego_at, ego_heading, ego_speed, npc_front_at, npc_heading, npc_speed, steps, vid="npc.3"
):
    """``ego_at(t)`` the ego's centre, ``npc_front_at(t)`` the NPC's front at step t."""
    return [
        Step(
            tuple(ego_at(t)),
            ego_heading,
            ego_speed,
            {vid: _npc(npc_front_at(t), npc_heading, npc_speed)},
        )  # fmt: skip
        for t in range(steps)
    ]


def _classify(window):
    return classify(window, EGO_L, EGO_W, "npc.", emergency_decel_mps2=9.0, reaction_s=DT)


def test_an_npc_from_40_m_into_a_standing_ego_could_have_stopped() -> None:
    # The ego stands across x = 0 (centre at the origin, heading east); the NPC drives north
    # along x = 0 at 10 m/s from 40 m away; its front reaches the ego's side (y = -0.9) at
    # step 39 and overlaps it at step 40. It needed 1 + 5.6 m to stop and had 39 m.
    w = _window(lambda t: (0, 0), 0.0, 0.0, lambda t: (0, -40 + 10 * DT * t), np.pi / 2, 10.0, 42)
    out = _classify(w)
    assert out["collision_kind"] == "ego-standing-in-path"
    assert out["collision_striker"] == "npc" and out["collision_other"] == "npc"
    assert out["collision_npc_could_stop"] == "True" and out["collision_tm_would_prevent"] == "True"
    assert out["collision_ego_speed_mps"] == "0.000" and out["collision_npc_speed_mps"] == "10.000"
    # Every value is text, so that a vector env can stack workers with and without one.
    assert all(isinstance(v, str) for v in out.values())


def test_an_ego_that_cuts_in_front_of_an_npc_it_could_not_stop_for() -> None:
    # The NPC drives north along x = 0 at 10 m/s, its front 0.3 m into the ego's side
    # (y = -3.6) at the last step (11); the ego drives east at 8 m/s, centre (-0.5, -3). Its
    # box first reaches where the NPC will be at step 8 (x from -5.15 to -0.65): the NPC then
    # had 3 m to go, and needed 1 m (reaction) + 5.6 m (10² / (2 x 9)).
    steps = 12
    w = _window(lambda t: (-8 * DT * (steps - 1 - t) - 0.5, -3.0), 0.0, 8.0,
                lambda t: (0, -3.6 - 10 * DT * (steps - 1 - t)), np.pi / 2, 10.0, steps)  # fmt: skip
    out = _classify(w)
    assert out["collision_striker"] == "npc"
    assert out["collision_kind"] == "ego-cut-in"
    assert (
        out["collision_npc_could_stop"] == "False" and out["collision_tm_would_prevent"] == "False"
    )


def test_rear_end_and_ego_into_npc_and_obstacle() -> None:
    # An NPC at 12 m/s catches the ego at 4 m/s from behind, both going east: its front is
    # 0.3 m into the ego's rear (x = -0.25) at the last step (5), 1.2 m behind it before.
    w = _window(lambda t: (4 * DT * t, 0), 0.0, 4.0,
                lambda t: (0.05 - 12 * DT * (5 - t), 0), 0.0, 12.0, 6)  # fmt: skip
    out = _classify(w)
    assert out["collision_kind"] == "rear-end" and out["collision_striker"] == "npc"
    # The ego's front into the side of an NPC crossing in front of it (north, slowly).
    w = _window(lambda t: (-3.5 + 8 * DT * t, 0), 0.0, 8.0,
                lambda t: (0, 2.5), np.pi / 2, 1.0, 4)  # fmt: skip
    out = _classify(w)
    assert out["collision_kind"] == "ego-into-npc" and out["collision_striker"] == "ego"
    assert out["collision_npc_could_stop"] == "" and out["collision_tm_would_prevent"] == "False"
    w = _window(lambda t: (-3.5 + 8 * DT * t, 0), 0.0, 8.0, lambda t: (2.5, 0), 0.0, 0.0, 4,
                vid="obstacle.0")  # fmt: skip
    assert _classify(w)["collision_kind"] == "obstacle"


def test_a_standing_npc_whose_front_the_turning_ego_sweeps_into_struck_nothing() -> None:
    # An NPC stopped facing north, its front at (0, -0.85), just short of where the ego
    # passes; the ego drives east at 3 m/s along y = 0, and its side (y = -0.9) reaches the
    # NPC's front in the last step. By the bumpers alone the NPC's front touches the ego's
    # side (the NPC would be the striker); but it stood, so the ego drove into it.
    w = _window(lambda t: (-3.0 + 3 * DT * t, 0.0), 0.0, 3.0,
                lambda t: (0.0, -0.85), np.pi / 2, 0.0, 11)  # fmt: skip
    out = _classify(w)
    assert out["collision_striker"] == "ego" and out["collision_kind"] == "ego-into-npc"
    assert out["collision_npc_could_stop"] == "" and out["collision_tm_would_prevent"] == "False"
    # The same NPC moving at 1 m/s (its front reaching (0, -0.85) at the last step) struck.
    w = _window(lambda t: (-3.0 + 3 * DT * t, 0.0), 0.0, 3.0,
                lambda t: (0.0, -0.85 - 1 * DT * (10 - t)), np.pi / 2, 1.0, 11)  # fmt: skip
    assert _classify(w)["collision_striker"] == "npc"
    # A standing NPC facing east behind the ego, its front 0.05 m into the ego's rear: by the
    # bumpers a rear-end the NPC struck; it stood, so the ego's rear went into it.
    w = _window(lambda t: (0.0, 0.0), 0.0, 0.5, lambda t: (-2.2, 0.0), 0.0, 0.0, 11)
    out = _classify(w)
    assert out["collision_striker"] == "ego" and out["collision_kind"] == "ego-into-npc"


def test_point_to_box_distance_by_hand() -> None:
    # A 4 x 2 box at the origin heading east: (3, 0) is 1 m beyond its front, (0, 2) 1 m
    # beside it, (3, 2) sqrt(2) from its corner, (1, 0.5) inside.
    assert point_box_distance_m(np.array([3.0, 0.0]), np.zeros(2), 0.0, 4.0, 2.0) == 1.0
    assert point_box_distance_m(np.array([0.0, 2.0]), np.zeros(2), 0.0, 4.0, 2.0) == 1.0
    assert point_box_distance_m(np.array([3.0, 2.0]), np.zeros(2), 0.0, 4.0, 2.0) == pytest.approx(
        2**0.5
    )
    assert point_box_distance_m(np.array([1.0, 0.5]), np.zeros(2), 0.0, 4.0, 2.0) == 0.0
    assert set(COLLISION_KINDS) >= {"obstacle", "rear-end", "ego-cut-in", "ego-standing-in-path"}


def test_the_ego_in_the_reads_is_not_its_own_collision() -> None:
    # The context subscription reads the ego too: it overlaps itself, and is left out.
    w = _window(lambda t: (0, 0), 0.0, 0.0, lambda t: (0, -40 + 10 * DT * t), np.pi / 2, 10.0, 42)
    ego = _npc((EGO_L / 2, 0.0), 0.0, 0.0)
    w = [Step(s.ego_xy, s.ego_heading_rad, s.ego_speed_mps, {"ego": ego, **s.actors}) for s in w]
    assert _classify(w)["collision_kind"] == "ego-standing-in-path"
