"""priqn play: a committed policy in sumo-gui (TraCI), recorded headless under Xvfb.

The GUI tests need the ``Xvfb`` program (Debian/Ubuntu: ``apt-get install -y xvfb``) and
imageio (the ``gui`` / ``test`` extras); without them they skip with the reason. They
never need a real screen: ``priqn play --record`` starts its own virtual display.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from priqn.objectives import OBJECTIVES

ROOT = Path(__file__).resolve().parents[1]
CELL = ROOT / "results" / "headline" / "pr-iqn-qd-tp-eps0.2__seed4"
# The shortest evaluated episode of the cell (10 decisions, ends in a collision).
SCENE = ["--net", "holdout/tjunction_00", "--density", "0.75", "--eval-run", "2"]
# A longer one (35 decisions), for the slow check.
LONG_SCENE = ["--net", "holdout/fourway_00", "--density", "0.75", "--eval-run", "0"]
EGO_RGB = (255, 0, 255)

needs_cell = pytest.mark.skipif(not (CELL / "policy.pt").is_file(), reason=f"no {CELL}")
needs_xvfb = pytest.mark.skipif(
    shutil.which("Xvfb") is None, reason="Xvfb not installed (apt-get install -y xvfb)"
)
needs_imageio = pytest.mark.skipif(
    importlib.util.find_spec("imageio") is None, reason="imageio not installed (gui extra)"
)


def priqn(*args: str, display: bool = False, timeout: int = 600) -> subprocess.CompletedProcess:
    """``priqn ARGS`` in a subprocess; without ``display`` DISPLAY is unset (headless)."""
    env = dict(os.environ)
    if not display:
        env.pop("DISPLAY", None)
    return subprocess.run(
        [sys.executable, "-m", "priqn.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
        cwd=ROOT,
    )


def libsumo_episode(scene: list[str]) -> pd.Series:
    """The same scene played through libsumo (render_mode=None), in its own process."""
    opts = dict(zip(scene[::2], scene[1::2], strict=True))
    code = (
        "import json, sys\n"
        "from priqn.tools.inspector import InspectConfig\n"
        "from priqn.tools.play import play_run\n"
        f"cfg = InspectConfig(net={opts['--net']!r}, density={float(opts['--density'])}, "
        f"eval_run={int(opts['--eval-run'])})\n"
        f"(r,) = play_run({str(CELL)!r}, cfg, render_mode=None)\n"
        "print(json.dumps({'steps': r.steps, 'outcome': r.outcome, "
        "'returns': [float(x) for x in r.returns]}))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=ROOT
    )
    assert out.returncode == 0, out.stderr[-3000:]
    import json

    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """``priqn play CELL --record DIR`` without a display (it starts Xvfb itself)."""
    out = tmp_path_factory.mktemp("play") / "rec"
    proc = priqn("play", str(CELL), *SCENE, "--episodes", "1", "--record", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "collision after 10 decisions" in proc.stdout, proc.stdout
    return out


def _ego_pixels(png: Path) -> int:
    import imageio.v3 as iio

    rgb = iio.imread(png)[..., :3].astype(int)
    return int((np.abs(rgb - np.array(EGO_RGB)).sum(axis=-1) < 60).sum())


@needs_cell
@needs_xvfb
@needs_imageio
def test_play_records_a_frame_per_decision_with_the_ego_in_colour(recorded):
    frames = sorted((recorded / "frames").glob("*.png"))
    table = pd.read_csv(recorded / "episodes.csv")
    assert len(table) == 1
    # One screenshot as each decision starts, and one of the end.
    assert len(frames) == int(table["steps"][0]) + 1
    # The ego is drawn in its own colour, and the view follows it (it is in every frame).
    assert all(_ego_pixels(f) > 30 for f in frames), [_ego_pixels(f) for f in frames]
    import imageio.v3 as iio

    gif = iio.imread(recorded / "play.gif")
    assert gif.shape[0] == len(frames) and gif.shape[1:3] == iio.imread(frames[0]).shape[:2]
    # No Xvfb or sumo-gui left behind by this test's run.
    left = subprocess.run(["pgrep", "-f", str(recorded)], capture_output=True, text=True)
    assert left.stdout.strip() == ""


@needs_cell
@needs_xvfb
@needs_imageio
def test_the_gui_episode_is_the_libsumo_episode(recorded):
    """Same seed, scene and policy: TraCI + sumo-gui and libsumo end the same way, with
    the same number of decisions and bit-identical per-objective returns."""
    gui = pd.read_csv(recorded / "episodes.csv").iloc[0]
    ref = libsumo_episode(SCENE)
    assert int(gui["steps"]) == ref["steps"] and gui["outcome"] == ref["outcome"]
    got = np.array([gui[f"return_{o}"] for o in OBJECTIVES], dtype=np.float32)
    np.testing.assert_array_equal(got, np.array(ref["returns"], dtype=np.float32))
    # ... and it is the episode priqn evaluate scored for this cell.
    table = pd.read_csv(CELL / "eval" / "episodes.csv")
    row = table[
        (table["net"] == SCENE[1])
        & (table["density"] == float(SCENE[3]))
        & (table["eval_run"] == int(SCENE[5]))
        & (table["episode"] == 0)
    ].iloc[0]
    assert int(row["steps"]) == int(gui["steps"])
    for o in OBJECTIVES:
        assert gui[f"return_{o}"] == pytest.approx(row[f"return_{o}"], abs=1e-5), o


@pytest.mark.slow
@needs_cell
@needs_xvfb
@needs_imageio
def test_a_longer_gui_episode_is_the_libsumo_episode(tmp_path):
    out = tmp_path / "long.gif"
    proc = priqn("play", str(CELL), *LONG_SCENE, "--record", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    ref = libsumo_episode(LONG_SCENE)
    line = proc.stdout.strip().splitlines()[0]
    assert f"{ref['outcome']} after {ref['steps']} decisions" in line, line
    assert ", ".join(f"{x:.3f}" for x in ref["returns"]) in line, line
    assert out.stat().st_size > 0


@needs_xvfb
def test_render_mode_human_opens_sumo_gui_and_follows_the_ego():
    import gymnasium

    import priqn  # noqa: F401  (registers the env)
    from priqn.sim.gui import VIEW, virtual_display

    with virtual_display():
        env = gymnasium.make(
            "priqn/Intersection-v0", family="holdout", obs_size_px=32, render_mode="human"
        )
        try:
            env.reset(seed=1, options={"net": "holdout/tjunction_00", "density": 0.5})
            sim = env.unwrapped.gui.session.sim
            assert sim.gui.getTrackedVehicle(VIEW) == "ego"
            assert env.render() is None
            env.step(12)
            assert "priqn.plan" in sim.polygon.getIDList()
            assert sim.vehicle.getParameter("ego", "action").startswith("a=12")
        finally:
            env.close()
    assert not env.unwrapped.gui.session.is_open


def test_render_mode_is_checked():
    from priqn.env.intersection import IntersectionEnv
    from priqn.errors import PriqnError

    with pytest.raises(PriqnError, match="render_mode: expected 'rgb_array', 'human' or None"):
        IntersectionEnv(render_mode="window")


@needs_cell
def test_a_policy_that_fails_to_load_is_one_line(tmp_path):
    run = tmp_path / "broken"
    shutil.copytree(CELL, run, ignore=shutil.ignore_patterns("eval*"))
    (run / "policy.pt").write_bytes(b"not a torch file")
    (run / "policy.pt.sha256").unlink()
    proc = priqn("play", str(run), "--record", str(tmp_path / "rec"))
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("priqn: error:"), proc.stderr
    assert "policy.pt" in lines[0] and "Traceback" not in proc.stderr


@needs_cell
def test_without_a_display_it_says_how_to_get_one(tmp_path):
    proc = priqn("play", str(CELL), *SCENE)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "xvfb-run -a priqn play" in lines[0], proc.stderr


def test_a_folder_destination_needs_no_imageio(monkeypatch, tmp_path):
    """Frames and episodes.csv need no imageio; only a .gif or .mp4 needs the gui extra."""
    from priqn.errors import PriqnError
    from priqn.tools.play import Record, check_destination

    monkeypatch.setitem(sys.modules, "imageio", None)  # 'import imageio' fails
    folder = str(tmp_path / "rec")
    check_destination(folder)
    rec = Record.of(folder, tmp_path / "scratch")
    assert rec.animation is None and rec.table == tmp_path / "rec" / "episodes.csv"
    for name in ("play.gif", "play.mp4"):
        with pytest.raises(PriqnError, match=r"needs imageio; install the gui extra") as err:
            check_destination(str(tmp_path / name))
        assert "\n" not in str(err.value)
    assert sorted(tmp_path.iterdir()) == []  # the checks create nothing


def test_an_unwritable_destination_is_one_line(tmp_path):
    """``check_destination`` (run before the policy loads) names what is wrong in one line."""
    from priqn.errors import PriqnError
    from priqn.tools.play import check_destination

    (tmp_path / "file").write_text("")
    (tmp_path / "dir.gif").mkdir()
    bad = {
        tmp_path / "file" / "x.gif": "file is not a folder",
        tmp_path / "file" / "rec": "file is not a folder",
        tmp_path / "file": "file is not a folder",
        tmp_path / "dir.gif": "is a folder; expected a file to write",
        tmp_path / "x.png": "expected a folder, or a file ending in .gif or .mp4",
    }
    if Path("/proc/self").is_dir():  # Linux: no files can be made in /proc, even by root
        bad.update({Path("/proc/x.gif"): "cannot write in /proc", Path("/proc/x"): "in /proc"})
    for target, why in bad.items():
        with pytest.raises(PriqnError, match=f"^--record {re.escape(str(target))}: .*{why}"):
            check_destination(str(target))
    # Folders that do not exist yet are fine (made when recording); the check makes nothing.
    check_destination(str(tmp_path / "new" / "deeper" / "x.mp4"))
    check_destination(str(tmp_path / "new" / "rec"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir.gif", "file"]


@needs_cell
@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="no /proc")
def test_an_unwritable_destination_fails_before_anything_plays():
    import time

    start = time.monotonic()
    proc = priqn("play", str(CELL), *SCENE, "--record", "/proc/x.gif", timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("priqn: error: --record /proc/x.gif: cannot write in /proc")
    assert "Traceback" not in proc.stderr and proc.stdout == ""
    assert time.monotonic() - start < 60  # no episode was played (it takes minutes)
