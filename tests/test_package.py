"""priqn as an installed package: data through importlib.resources, output below the cwd.

The fast tests check the lookup rules of :mod:`priqn.paths` (a working-directory folder
wins over what ships, per item). The slow test builds the wheel, installs it into a
fresh venv and uses it from an empty folder, as a new user would.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

from priqn import paths
from priqn.errors import PriqnError
from priqn.sim.scenario import family_toml, list_families, load_manifest, net_path
from priqn.sweep import resolve_experiment_path

REPO = Path(__file__).resolve().parent.parent


def test_shipped_data_is_found_from_any_working_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert {"tjunction", "fourway", "holdout"} <= set(list_families())
    assert family_toml("holdout") == paths.scenarios_dir() / "holdout.toml"
    assert net_path("holdout/fourway_00") == paths.nets_dir() / "holdout" / "fourway_00.net.xml"
    assert resolve_experiment_path("smoke") == paths.experiments_dir() / "smoke.toml"
    assert paths.generate_dir() == tmp_path / "sumo_nets"


def test_working_directory_overrides_shipped_data_per_item(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    # A generated holdout family in ./sumo_nets wins; tjunction still comes from what ships.
    shutil.copytree(paths.nets_dir() / "holdout", tmp_path / "sumo_nets" / "holdout")
    assert paths.nets_root_for("holdout") == tmp_path / "sumo_nets"
    assert paths.nets_root_for("tjunction") == paths.nets_dir()
    assert net_path("holdout/fourway_00") == tmp_path / "sumo_nets/holdout/fourway_00.net.xml"
    assert load_manifest("holdout") == load_manifest("holdout", paths.nets_dir())
    # Own experiment and scenario files by bare name.
    (tmp_path / "experiments").mkdir()
    (tmp_path / "experiments" / "mine.toml").write_text("[experiment]\nname = 'mine'\n")
    assert resolve_experiment_path("mine") == tmp_path / "experiments" / "mine.toml"
    with pytest.raises(PriqnError, match="known in ./experiments/ and shipped: .*mine.*smoke"):
        resolve_experiment_path("nope")
    (tmp_path / "scenarios").mkdir()
    shutil.copy(paths.scenarios_dir() / "holdout.toml", tmp_path / "scenarios" / "myholdout.toml")
    assert "myholdout" in list_families()
    assert family_toml("myholdout") == tmp_path / "scenarios" / "myholdout.toml"


def _run(cmd: list[str], cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess:
    res = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, f"{cmd}: {res.stdout[-3000:]}\n{res.stderr[-3000:]}"
    return res


@pytest.mark.slow
def test_wheel_works_outside_the_checkout(tmp_path: Path) -> None:
    """Build the wheel, install it in a fresh venv, use it from an empty folder."""
    # Build from a copy: setuptools builds in-tree, and a stale build/ could leak into it.
    src = tmp_path / "src"
    junk = (".git", ".venv", "venv", "build", "dist", "runs", "results", "reports", "*.egg-info")
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(*junk, "__pycache__", ".*_cache"))
    dist = tmp_path / "dist"
    _run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", str(dist), str(src)],
        cwd=tmp_path,
        env=dict(os.environ),
    )  # fmt: skip
    (wheel,) = dist.glob("priqn-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert not any(n.startswith("analysis/") for n in names), "no top-level 'analysis' package"
    for needed in (
        "priqn/analysis/report.py",
        "priqn/data/scenarios/holdout.toml",
        "priqn/data/sumo_nets/holdout/manifest.json",
        "priqn/data/sumo_nets/tjunction/tjunction_00.net.xml",
        "priqn/data/experiments/smoke.toml",
        "priqn/presets/train_default.toml",
    ):
        assert needed in names, needed

    # A fresh venv whose dependencies come from this one's site-packages (no download):
    # a plain path in a .pth file adds the folder but runs none of its own .pth files,
    # so the editable install of the checkout stays invisible.
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", str(venv)], cwd=tmp_path, env=dict(os.environ))
    py = venv / "bin" / "python"
    fresh_site = Path(
        _run(
            [str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
            tmp_path,
            dict(os.environ),
        ).stdout.strip()
    )
    (fresh_site / "priqn_test_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    _run(
        [str(py), "-m", "pip", "install", "-q", "--no-deps", "--no-index", str(wheel)],
        tmp_path,
        dict(os.environ),
    )

    work = tmp_path / "empty"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "SUMO_HOME")}
    env["MPLBACKEND"] = "Agg"
    where = _run([str(py), "-c", "import priqn; print(priqn.__file__)"], work, env).stdout
    assert str(fresh_site) in where, f"priqn imported from {where}, not the installed wheel"

    listing = _run([str(venv / "bin" / "priqn"), "scenario", "list"], work, env).stdout
    assert "holdout: 3 nets (shipped)" in listing, listing
    _run(
        [
            str(py),
            "-c",
            "import gymnasium, priqn; env = gymnasium.make('priqn/Intersection-v0');"
            "obs, info = env.reset(seed=0); env.step(env.action_space.sample()); env.close()",
        ],
        work,
        env,
    )
    _run([str(venv / "bin" / "priqn"), "sweep", "smoke"], work, env)
    cells = sorted((work / "runs" / "smoke").glob("*__seed0/meta.json"))
    assert cells and all(json.loads(m.read_text())["status"] == "complete" for m in cells)
    assert (work / "reports" / "smoke" / "report.md").is_file()
    assert sorted(p.name for p in work.iterdir()) == ["reports", "runs"]
