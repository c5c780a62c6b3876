"""``priqn diff``: two runs compared part by part (config, metrics, weights, episodes).

One tiny trained run, copied; each copy is changed in one place by hand, and the part
that reads that place must name it (the rest stay equal). The prefix case (a long run's
snapshot against a short run) is in ``tests/test_train.py::test_long_run_prefix_is_the_short_run``.
"""

from __future__ import annotations

import csv
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from test_train import TINY, cli

from priqn.errors import PriqnError
from priqn.io import atomic_write_json
from priqn.run.folder import RunFolder
from priqn.run.metrics import write_metrics
from priqn.tools.diff import diff_runs, verdict


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("diff")
    out = cli("--agent", "iqn", "--steps", "120", "--num-envs", "1", "--runs-dir", str(root),
              "--name", "a", "--device", "cpu", "--set", "evaluation.interval_steps=0", *TINY)  # fmt: skip
    assert out.returncode == 0, out.stderr
    return root / "a"


def copy_of(run: Path, tmp_path: Path, name: str = "b") -> Path:
    return Path(shutil.copytree(run, tmp_path / name))


def parts(a: Path, b: Path, upto: int | None = None) -> dict[str, tuple[bool | None, str]]:
    _, found = diff_runs(RunFolder(a), RunFolder(b), upto)
    return {p.name: (p.same, p.text) for p in found}


def diff_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "priqn.cli", "diff", *args],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip


def test_a_copy_is_the_same_training(trained: Path, tmp_path: Path) -> None:
    b = copy_of(trained, tmp_path)
    found = parts(trained, b)
    assert {k: same for k, (same, _) in found.items()} == {
        "config": True, "metrics": True, "weights": True, "episodes": None,
    }  # fmt: skip
    assert found["config"][1] == "the same (120 / 120 decisions), seed 0"
    assert found["episodes"][1] == "A has no complete evaluation eval/"
    out = diff_cli(str(trained), str(b))
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines()[-1] == "up to 120 decisions, the runs are the same training"

    # A policy file written without the format key (as before checkpoint format 2): other
    # bytes, the same policy.
    import torch

    data = torch.load(b / "policy.pt", weights_only=True)
    del data["format"]
    torch.save(data, b / "policy.pt")
    (b / "policy.pt.sha256").unlink(missing_ok=True)
    assert parts(trained, b)["weights"] == (
        True,
        "the same policy, files differ in bytes (policy.pt / policy.pt: another file format or torch)",
    )


def test_each_part_names_its_first_difference(trained: Path, tmp_path: Path) -> None:

    from priqn.run.checkpoint import load_policy_state, save

    b = copy_of(trained, tmp_path)
    # metrics: the loss of the second row
    with (b / "metrics.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    loss = rows[1]["loss"]
    rows[1]["loss"] = "12345.0"
    write_metrics(RunFolder(b).metrics_path, rows, list(rows[0]))
    # config: the seed
    text = (b / "config.toml").read_text()
    (b / "config.toml").write_text(text.replace("seed = 0\n", "seed = 1\n", 1))
    # weights: one bias nudged
    state = load_policy_state(b / "policy.pt")
    key = next(k for k in state.online if k.endswith("bias"))
    state.online[key] = state.online[key] + 1.0
    save(state, b / "policy.pt")
    # episodes: both evaluated (two hand-written rows), one outcome differs
    for run, success in ((trained, "True"), (b, "False")):
        folder = RunFolder(run)
        atomic_write_json(folder.eval_meta_path, {"status": "complete"})
        folder.eval_episodes_path.write_text(
            f"run,net,episode,success\n{run.name},holdout/x,0,True\n{run.name},holdout/x,1,{success}\n"
        )
    found = parts(trained, b)
    assert found["config"] == (False, "seed is 1, not 0")
    assert found["metrics"][0] is False
    assert found["metrics"][1].startswith("metrics.csv row 2 (kind train, step ")
    assert found["metrics"][1].endswith(f": loss is '12345.0', not '{loss}'")
    assert found["weights"] == (
        False, f"1 part(s) of the policy differ (policy.pt / policy.pt), first online.{key}",
    )  # fmt: skip
    assert found["episodes"] == (
        False, "episodes.csv row 2 (net holdout/x, episode 1): success is 'False', not 'True'",
    )  # fmt: skip
    out = diff_cli(str(trained), str(b))
    assert out.returncode == 1
    assert out.stdout.splitlines()[-1] == "up to 120 decisions, the runs differ"
    assert "  episodes  DIFFERS" in out.stdout


def test_a_run_short_of_the_budget_is_compared_as_far_as_it_got(
    trained: Path, tmp_path: Path
) -> None:
    """B stopped at its last checkpoint (60 of 120 decisions): the rows both logged are
    compared, nothing is called the same training, and a changed row still differs."""
    b = copy_of(trained, tmp_path)
    meta = RunFolder(b).meta()
    atomic_write_json(b / "meta.json", {**meta, "status": "running", "steps_done": 60})
    (b / "policy.pt").unlink()
    found = diff_runs(RunFolder(trained), RunFolder(b))[1]
    assert [p.same for p in found] == [True, None, None, None]
    assert found[1].text.endswith("B has trained 60 of the 120 decisions")
    assert verdict(found) == (
        "no difference in the parts compared, but not proven the same training "
        "(not compared: metrics, weights)"
    )
    out = diff_cli(str(trained), str(b))
    assert out.returncode == 3 and "the runs are the same training" not in out.stdout
    assert out.stdout.splitlines()[-1].endswith("(not compared: metrics, weights)")


def test_bad_input_is_one_line(trained: Path, tmp_path: Path) -> None:
    with pytest.raises(PriqnError, match=r"--upto 500: expected 1 to 120, the smaller"):
        parts(trained, trained, upto=500)
    out = diff_cli(str(trained), str(tmp_path / "nothing"))
    assert out.returncode == 2
    assert (
        out.stderr.strip()
        == f"priqn: error: {tmp_path / 'nothing'}: not a run folder (no config.toml)"
    )
