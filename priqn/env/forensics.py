"""What kind of collision it was: who struck whom, how fast, and could the NPC have stopped.

The env keeps the last :data:`HISTORY_STEPS` SUMO steps of the ego's box and speed and of
every actor near it (the context-subscription reads, ids included). At a collision,
:func:`classify` looks back over them:

- **who struck whom** — the vehicle whose front bumper touches the other's box is the
  striker (``ego``, ``npc``, or ``both`` when both fronts do); an NPC or obstacle that
  stood (:data:`STANDING_MPS`) struck nothing: the ego did, with its side or rear where
  its front does not touch (a turning ego sweeping into an NPC that stopped for it);
- **could the NPC have stopped** — the first step of the window at which the ego's box
  stood where the NPC's box would later be (the ego *entered the NPC's path*, as the NPC
  then drove it), the NPC's distance along its own track from there to that place, and its
  speed then: it could have stopped if ``speed * reaction + speed**2 / (2 * emergencyDecel)``
  fits in that distance (a Traffic-Manager-like NPC brakes there: ``tm_would_prevent``);
- **the kind** (:data:`priqn.objectives.COLLISION_KINDS`).

Pure functions on arrays; the env (:mod:`priqn.env.intersection`) records the result in the
final ``info`` (``collision_*`` keys) and evaluations write it to ``episodes.csv``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from priqn.env import geometry
from priqn.objectives import COLLISION_COLUMNS

HISTORY_STEPS = 80
"""SUMO steps kept for a look back (8 s at 0.1 s)."""
SLOW_MPS = 2.0
"""Below this the ego is 'standing or slow' [m/s]."""
FRONT_CONTACT_M = 0.3
"""A front bumper within this of the other's box touches it [m]."""
STANDING_MPS = 0.1
"""An NPC or obstacle at most this fast at the collision stood: it struck nothing, the ego
drove into it (with its side or rear, where its front does not touch) [m/s]."""
SAME_DIRECTION_DEG = 30.0
"""Headings closer than this make a collision between a front and a rear a rear-end [deg]."""
OPPOSITE_DEG = 150.0
"""Headings further apart than this make a both-fronts collision head-on [deg]."""


@dataclasses.dataclass(frozen=True)
class Step:
    """One SUMO step of the look-back window."""

    ego_xy: tuple[float, float]
    """The ego's centre [m]."""
    ego_heading_rad: float
    """The ego's heading [rad]."""
    ego_speed_mps: float
    """The ego's speed [m/s]."""
    actors: Mapping[str, Mapping[int, Any]]
    """The context-subscription read of the step (id -> libsumo variables)."""


def no_collision() -> dict[str, Any]:
    """The :data:`COLLISION_COLUMNS` of an episode without a collision: empty strings (a CSV's empty
    cells; every value is text, :func:`_text`)."""
    return dict.fromkeys(COLLISION_COLUMNS, "")


def _box(var: Mapping[int, Any]) -> tuple[np.ndarray, float, float, float, np.ndarray]:
    """Centre, heading, length, width and front of an actor from its libsumo variables."""
    import libsumo

    front = np.asarray(var[libsumo.VAR_POSITION], float)
    length, width = float(var[libsumo.VAR_LENGTH]), float(var[libsumo.VAR_WIDTH])
    centre, heading = geometry.center_from_sumo(front, float(var[libsumo.VAR_ANGLE]), length)
    return centre, float(heading), length, width, front


def point_box_distance_m(
    point: np.ndarray, centre: np.ndarray, heading_rad: float, length_m: float, width_m: float
) -> float:
    """Distance from ``point`` to an oriented box (0 inside it) [m]."""
    d = np.asarray(point, float) - np.asarray(centre, float)
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    along, across = d[0] * c + d[1] * s, -d[0] * s + d[1] * c
    return float(np.hypot(max(abs(along) - length_m / 2, 0.0), max(abs(across) - width_m / 2, 0.0)))


def _overlap(a: tuple, b: tuple) -> bool:
    """Do two (centre, heading, length, width) boxes overlap?"""
    boxes = [geometry.Boxes.make([x[0]], x[1], x[2], x[3]) for x in (a, b)]
    return bool(geometry.obb_overlap(boxes[0], boxes[1])[0])


def could_stop(
    ego_boxes: Sequence[tuple], npc_track: Sequence[tuple | None], npc_speeds: Sequence[float],
    emergency_decel_mps2: float, reaction_s: float,
) -> bool:  # fmt: skip
    """Could the NPC have stopped before the place where the ego entered its path?

    ``ego_boxes[t]`` and ``npc_track[t]`` (None where the NPC was not read) are
    (centre, heading, length, width) boxes of the window's steps, the collision last;
    ``npc_speeds[t]`` its speed [m/s]. The ego entered the NPC's path at the first step
    ``t0`` whose ego box overlaps the NPC's box at a step ``j >= t0``; the NPC's track
    length from ``t0`` to ``j`` is the room it had."""
    seen = [t for t, b in enumerate(npc_track) if b is not None]
    fronts = {t: np.asarray(npc_track[t][0]) for t in seen}
    for t0 in seen:
        later = [j for j in seen if j >= t0 and _overlap(ego_boxes[t0], npc_track[j])]
        if not later:
            continue
        path = [j for j in seen if t0 <= j <= later[0]]
        room = sum(float(np.hypot(*(fronts[b] - fronts[a]))) for a, b in zip(path, path[1:]))  # noqa: B905
        v = float(npc_speeds[t0])
        return v * reaction_s + v * v / (2.0 * emergency_decel_mps2) <= room
    return False


def classify(
    window: Sequence[Step], ego_length_m: float, ego_width_m: float, npc_prefix: str,
    emergency_decel_mps2: float, reaction_s: float, ego_id: str = "ego",
) -> dict[str, Any]:  # fmt: skip
    """The forensics (:data:`COLLISION_COLUMNS`) of the collision in the window's last step (the
    reads hold the ego itself too, as ``ego_id``: it is left out)."""
    last = window[-1]
    ego = (np.asarray(last.ego_xy), last.ego_heading_rad, ego_length_m, ego_width_m)
    ego_front = ego[0] + np.array([np.cos(ego[1]), np.sin(ego[1])]) * ego_length_m / 2
    hit = None
    for vid, var in last.actors.items():
        if vid == ego_id:
            continue
        other = _box(var)
        if _overlap(ego, other[:4]):
            hit = (vid, var, other)
            break
    if hit is None:  # the decision's own test saw one; the read holds none (should not happen)
        return no_collision()
    import libsumo

    vid, var, (centre, heading, length, width, front) = hit
    npc_gap = point_box_distance_m(front, *ego[:2], ego_length_m, ego_width_m)
    ego_gap = point_box_distance_m(ego_front, centre, heading, length, width)
    striker = {(True, True): "both", (True, False): "npc", (False, True): "ego"}.get(
        (npc_gap <= FRONT_CONTACT_M, ego_gap <= FRONT_CONTACT_M),
        "npc" if npc_gap < ego_gap else "ego",  # neither front touches: the nearer one
    )
    stood = float(var[libsumo.VAR_SPEED]) <= STANDING_MPS
    swept = stood and striker == "npc"  # only its front touches: the ego's side or rear did it
    if stood:
        striker = "ego"  # it did not move in the last step (SUMO's Euler update): the ego did
    is_npc = vid.startswith(npc_prefix)
    out = {
        "collision_striker": striker,
        "collision_other": "npc" if is_npc else "obstacle",
        "collision_ego_speed_mps": float(last.ego_speed_mps),
        "collision_npc_speed_mps": float(var[libsumo.VAR_SPEED]),
        "collision_npc_could_stop": "",
        "collision_tm_would_prevent": False,
    }
    turn = abs(np.degrees(np.angle(np.exp(1j * (heading - ego[1])))))
    npc_struck = striker in ("npc", "both")
    if not is_npc:
        kind = "obstacle"
    elif swept:
        kind = "ego-into-npc"
    elif striker == "both" and turn > OPPOSITE_DEG:
        kind = "head-on"
    elif turn < SAME_DIRECTION_DEG and striker != "both":
        kind = "rear-end"
    elif striker == "ego":
        kind = "ego-into-npc"
    else:
        kind = ""  # the NPC drove into the ego: decided by whether it could have stopped
    if is_npc and npc_struck and kind != "head-on":
        egos = [
            (np.asarray(s.ego_xy), s.ego_heading_rad, ego_length_m, ego_width_m) for s in window
        ]
        track = [_box(s.actors[vid])[:4] if vid in s.actors else None for s in window]
        speeds = [
            float(s.actors[vid][libsumo.VAR_SPEED]) if vid in s.actors else 0.0 for s in window
        ]
        stop = could_stop(egos, track, speeds, emergency_decel_mps2, reaction_s)
        out["collision_npc_could_stop"] = stop
        out["collision_tm_would_prevent"] = stop
        if not kind:
            slow = last.ego_speed_mps < SLOW_MPS
            kind = ("ego-standing-in-path" if slow else "ego-in-path") if stop else "ego-cut-in"
    out["collision_kind"] = kind
    return {k: _text(out[k]) for k in COLLISION_COLUMNS}


def _text(value: Any) -> str:
    """A forensics value as the text ``episodes.csv`` holds. Every value is a string, with or
    without a collision: a vector env stacks each ``info`` key of its workers into one array
    typed by the first value, so a float in one worker and ``""`` in another would fail."""
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, float):
        return f"{value:.3f}"
    return str(value)
