"""Safe to share (issue 35): loading someone else's run folder executes no code.

A crafted ``policy.pt`` / ``checkpoints/latest.pt`` -- a pickle whose ``__reduce__`` runs
a shell command, with a valid ``.sha256`` sidecar -- is refused in one line by every entry
point that reads a run folder, and the command never runs (the marker file it would
create stays absent). Weights that do not fit the network, and a config.toml naming a
module inside the run folder, are refused in one line too. Every committed policy.pt
loads through the safe path.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from priqn.config import dumps_toml, load_toml
from priqn.errors import PriqnError
from priqn.io import CHECKSUM_SUFFIX, atomic_torch_save
from priqn.objectives import OBJECTIVES
from priqn.run import checkpoint
from priqn.run.checkpointer import load_policy
from priqn.run.folder import RunFolder

ROOT = Path(__file__).resolve().parents[1]
COMMITTED = sorted((ROOT / "results").glob("**/policy.pt"))
"""Every policy.pt under results/ (the committed cells; ~110)."""
CELL = ROOT / "results/headline/ensemble__seed10"
"""A committed, evaluated cell: what an outsider copies and edits."""


class Payload:
    """Unpickling this runs ``touch <marker>`` in a shell (what the outsider's file does)."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self) -> tuple:
        return (os.system, (f"touch {shlex.quote(self.marker)}",))


def plant(path: Path, marker: Path, **fields) -> None:
    """Replace ``path`` with a crafted pickle and its matching sidecar (the rule of
    :func:`priqn.io.atomic_torch_save`), shaped like a priqn file."""
    data = {"online": Payload(marker), "agent": {}, "obs_shapes": {}, "num_actions": 25}
    atomic_torch_save({**data, "step": 1, **fields}, path)
    assert (path.parent / (path.name + CHECKSUM_SUFFIX)).is_file()


def copy_cell(dest: Path, with_eval: bool = False) -> Path:
    """The committed cell's files (config, meta, metrics, policy.pt; eval/ if asked)."""
    ignore = None if with_eval else shutil.ignore_patterns("eval*")
    shutil.copytree(CELL, dest, ignore=ignore)
    return dest


def priqn(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    return subprocess.run(
        [sys.executable, "-m", "priqn.cli", *args],
        capture_output=True, text=True, env=env, timeout=600, cwd=cwd,
    )  # fmt: skip


def assert_refused(res: subprocess.CompletedProcess, path: Path, marker: Path) -> None:
    """Exit 2, one line naming ``path``, and the payload never ran."""
    assert not marker.exists(), "the pickle's command ran"
    assert res.returncode == 2, res.stdout[-2000:] + res.stderr[-2000:]
    err = res.stderr.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    assert f"{path}: refused: not a priqn" in err and "posix.system" in err, err


def test_the_crafted_file_would_run_its_command(tmp_path):
    """Control: the planted file is live -- the unsafe loader (weights_only=False, what
    priqn used before issue 35) runs the command. The tests below can fail."""
    marker = tmp_path / "marker"
    plant(tmp_path / "policy.pt", marker)
    torch.load(tmp_path / "policy.pt", weights_only=False)
    assert marker.exists()


@pytest.fixture()
def foreign(tmp_path) -> tuple[Path, Path, Path]:
    """(a copy of a committed cell with a crafted policy.pt, one with a crafted
    checkpoints/latest.pt, the marker file)."""
    marker = tmp_path / "marker"
    bad_policy = copy_cell(tmp_path / "runs" / "bad_policy")
    plant(bad_policy / "policy.pt", marker)
    bad_latest = copy_cell(tmp_path / "runs" / "bad_latest")
    plant(bad_latest / "checkpoints/latest.pt", marker)
    return bad_policy, bad_latest, marker


def test_evaluate_refuses_a_crafted_policy_and_checkpoint(foreign, tmp_path):
    bad_policy, bad_latest, marker = foreign
    quick = ("--episodes", "1", "--eval-runs", "1", "--densities", "0.5")
    assert_refused(priqn("evaluate", str(bad_policy), *quick), bad_policy / "policy.pt", marker)
    latest = bad_latest / "checkpoints/latest.pt"
    assert_refused(priqn("evaluate", str(bad_latest), *quick), latest, marker)


def test_inspect_refuses_a_crafted_policy(foreign, tmp_path):
    bad_policy, _, marker = foreign
    res = priqn("inspect", str(bad_policy), "--out", str(tmp_path / "inspect"))
    assert_refused(res, bad_policy / "policy.pt", marker)


def test_train_resume_refuses_a_crafted_checkpoint(foreign):
    _, bad_latest, marker = foreign
    # As if this code had written it: a resume refuses another commit's checkpoint before
    # reading it, and the crafted file must meet the loader's own refusal.
    from priqn.run.provenance import git_sha

    meta = json.loads((bad_latest / "meta.json").read_text())
    meta["git_sha"] = git_sha()
    (bad_latest / "meta.json").write_text(json.dumps(meta))
    res = priqn("train", "--resume", str(bad_latest), "--device", "cpu")
    assert_refused(res, bad_latest / "checkpoints/latest.pt", marker)


def test_report_and_reference_read_no_torch_file(tmp_path):
    """``priqn report`` reads evaluations (CSV, JSON) and ``evaluate --reference`` reads
    the runs' config.toml: neither unpickles a run's torch files."""
    marker = tmp_path / "marker"
    run = copy_cell(tmp_path / "runs" / "cell", with_eval=True)
    plant(run / "policy.pt", marker)
    plant(run / "checkpoints/latest.pt", marker)
    res = priqn("report", str(run.parent), "--out", str(tmp_path / "report"), "--reps", "10")
    assert not marker.exists()
    assert res.returncode in (0, 2) and res.stderr.strip().count("\n") == 0, res.stderr[-2000:]
    # --reference plays the env of the runs' config.toml (a random driver, one episode).
    out = tmp_path / "reference"
    res = priqn("evaluate", "--reference", "random", str(run), "--out", str(out),
                "--episodes", "1", "--eval-runs", "1", "--densities", "0.5")  # fmt: skip
    assert not marker.exists()
    assert res.returncode == 0, res.stderr[-2000:]


def test_a_config_naming_a_module_in_the_run_folder_is_refused_before_import(tmp_path, monkeypatch):
    """A foreign config.toml may name ``package.module:NAME`` objectives. Run from the
    folder above a run (``python -m`` puts the cwd on sys.path), ``cell.evil:OBJ`` would
    import the run folder's own evil.py: refused, nothing imported."""
    marker = tmp_path / "marker"
    run = copy_cell(tmp_path / "shared" / "cell")
    (run / "evil.py").write_text(f"import os\nos.system('touch {shlex.quote(str(marker))}')\n")
    data = load_toml(run / "config.toml")
    data.setdefault("env", {})["objectives"] = [*OBJECTIVES, "cell.evil:OBJ"]
    (run / "config.toml").write_text(dumps_toml(data))
    res = priqn("evaluate", "cell", "--episodes", "1", "--eval-runs", "1", cwd=run.parent)
    assert not marker.exists(), "the run folder's module was imported"
    assert res.returncode == 2 and res.stderr.strip().count("\n") == 0, res.stderr
    assert "'cell.evil:OBJ'" in res.stderr and "never from a run folder" in res.stderr
    monkeypatch.syspath_prepend(str(run.parent))  # as python -m from there
    with pytest.raises(PriqnError, match="never from a run folder"):
        RunFolder(run).config()
    monkeypatch.chdir(run)  # evil.py itself on sys.path: refused too
    monkeypatch.syspath_prepend(str(run))
    data["env"]["objectives"] = [*OBJECTIVES, "evil:OBJ"]
    (run / "config.toml").write_text(dumps_toml(data))
    with pytest.raises(PriqnError, match="never from a run folder"):
        RunFolder(run).config()
    assert not marker.exists()


@pytest.mark.parametrize("damage", ["name", "shape"])
def test_weights_that_do_not_fit_are_one_line(tmp_path, damage):
    run = copy_cell(tmp_path / "cell")
    state = torch.load(run / "policy.pt", weights_only=True)
    online = dict(state["online"])
    key = next(iter(online))
    if damage == "name":
        online["not_" + key] = online.pop(key)
    else:
        online[key] = torch.zeros(3, 3)
    atomic_torch_save({**state, "online": online}, run / "policy.pt")
    with pytest.raises(PriqnError) as info:
        load_policy(RunFolder(run))
    msg = str(info.value)
    assert msg.startswith(f"{run / 'policy.pt'}: its weights do not fit") and "\n" not in msg
    res = priqn("evaluate", str(run), "--episodes", "1", "--eval-runs", "1")
    assert res.returncode == 2 and res.stderr.strip().count("\n") == 0, res.stderr
    assert "its weights do not fit" in res.stderr


def test_every_committed_policy_loads_through_the_safe_path():
    """All committed policy.pt files are tensors and plain data (format 1, no ``format``
    key); a sample builds its policy through checkpointer.load_policy."""
    assert len(COMMITTED) >= 100, len(COMMITTED)
    for path in COMMITTED:
        state = checkpoint.load_policy_state(path)
        assert state.online and state.num_actions > 0, path
    for path in COMMITTED[:: max(1, len(COMMITTED) // 4)]:
        policy = load_policy(RunFolder(path.parent))
        assert policy.labels["agent"], path
