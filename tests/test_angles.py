"""SUMO angle <-> heading and angle wrapping: one home each (priqn.sim.geometry), hand-checked.

SUMO's angle: degrees clockwise from north. priqn's heading: radians counter-clockwise
from +x (east). So north is angle 0 / heading π/2, east 90 / 0, south 180 / -π/2,
west 270 / π (or -π).
"""

from __future__ import annotations

import inspect
import math
import re
from pathlib import Path

import numpy as np
import pytest

import priqn
from priqn.env import geometry
from priqn.sim.geometry import heading_rad_from_sumo, sumo_angle_deg, wrap_deg, wrap_rad

PI = math.pi

COMPASS = [  # (name, SUMO angle [deg], heading [rad])
    ("north", 0.0, PI / 2),
    ("east", 90.0, 0.0),
    ("south", 180.0, -PI / 2),
    ("west", 270.0, -PI),
    ("north-east", 45.0, PI / 4),
]


@pytest.mark.parametrize(("name", "angle_deg", "heading_rad"), COMPASS)
def test_sumo_angle_to_heading(name: str, angle_deg: float, heading_rad: float) -> None:
    assert heading_rad_from_sumo(angle_deg) == pytest.approx(heading_rad, abs=1e-15), name


@pytest.mark.parametrize(("name", "angle_deg", "heading_rad"), COMPASS)
def test_heading_to_sumo_angle(name: str, angle_deg: float, heading_rad: float) -> None:
    assert sumo_angle_deg(heading_rad) == pytest.approx(angle_deg, abs=1e-12), name


def test_sumo_angle_is_in_0_360() -> None:
    # North-west: 90 - 135 = -45 before the mod; SUMO's own range is [0, 360).
    assert sumo_angle_deg(3 * PI / 4) == pytest.approx(315.0)
    assert sumo_angle_deg(PI) == pytest.approx(270.0)
    assert sumo_angle_deg(-PI) == pytest.approx(270.0)
    angles = sumo_angle_deg(np.linspace(-3 * PI, 3 * PI, 101))
    assert angles.shape == (101,) and angles.min() >= 0.0 and angles.max() < 360.0


def test_heading_from_sumo_on_arrays_is_float64() -> None:
    out = heading_rad_from_sumo(np.array([0, 90, 180], dtype=np.float32))
    assert out.dtype == np.float64
    np.testing.assert_allclose(out, [PI / 2, 0.0, -PI / 2], atol=1e-15)


def test_round_trip_up_to_whole_turns() -> None:
    h = np.linspace(-2 * PI, 2 * PI, 37)
    back = heading_rad_from_sumo(sumo_angle_deg(h))
    np.testing.assert_allclose(np.cos(back), np.cos(h), atol=1e-12)
    np.testing.assert_allclose(np.sin(back), np.sin(h), atol=1e-12)


def test_geometry_poses_use_the_convention() -> None:
    # A 4 m car facing north with its front bumper at (0, 10): centre 2 m south of it.
    centre, heading = geometry.center_from_sumo(np.array([0.0, 10.0]), 0.0, 4.0)
    np.testing.assert_allclose(centre, [0.0, 8.0], atol=1e-12)
    assert heading == pytest.approx(PI / 2)
    front, angle = geometry.sumo_from_center(centre, heading, 4.0)
    np.testing.assert_allclose(front, [0.0, 10.0], atol=1e-12)
    assert angle == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize(
    ("angle_deg", "wrapped"),
    [
        (0.0, 0.0),
        (179.5, 179.5),
        (180.0, 180.0),
        (-180.0, 180.0),  # the interval is (-180, 180]
        (190.0, -170.0),
        (-190.0, 170.0),
        (359.0, -1.0),
        (540.0, 180.0),
        (-540.0, 180.0),
        (720.0, 0.0),
    ],
)
def test_wrap_deg(angle_deg: float, wrapped: float) -> None:
    assert wrap_deg(angle_deg) == wrapped


@pytest.mark.parametrize(
    ("angle_rad", "wrapped"),
    [
        (0.25, 0.25),
        (PI, PI),
        (-PI, -PI),  # odd multiples of π keep their sign
        (1.5 * PI, -PI / 2),
        (-1.5 * PI, PI / 2),
        (2 * PI, 0.0),
        (2 * PI + 0.5, 0.5),
    ],
)
def test_wrap_rad(angle_rad: float, wrapped: float) -> None:
    assert wrap_rad(angle_rad) == pytest.approx(wrapped, abs=1e-12)


def test_wrap_rad_on_arrays() -> None:
    out = wrap_rad(np.array([3 * PI / 2, -3 * PI / 2, 0.1]))
    np.testing.assert_allclose(out, [-PI / 2, PI / 2, 0.1], atol=1e-12)


SUMO_CONVERSION = re.compile(
    r"90(\.0)?\s*-\s*(np\.|math\.)?(degrees|rad2deg)\(|(radians|deg2rad)\(\s*90(\.0)?\s*-"
)
"""The SUMO angle <-> heading conversion written out instead of called."""


def test_the_sumo_conversion_is_written_once() -> None:
    root = Path(priqn.__file__).resolve().parent
    home = root / "sim" / "geometry.py"
    for home_fn in (sumo_angle_deg, heading_rad_from_sumo):  # the pattern finds the real thing
        assert SUMO_CONVERSION.search(inspect.getsource(home_fn).splitlines()[-1])
    elsewhere = [
        f"{path.relative_to(root.parent)}:{n}"
        for path in sorted(root.rglob("*.py"))
        if path != home
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if SUMO_CONVERSION.search(line)
    ]
    assert not elsewhere, (
        f"call priqn.sim.geometry.sumo_angle_deg / heading_rad_from_sumo: {elsewhere}"
    )
