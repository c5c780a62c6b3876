"""Bad inputs: each is refused in one line (``priqn: error: ...``, exit status 2) naming
the flag or field and what is expected, and a refused command leaves nothing behind: no
run folder, no empty output folder. Run in-process through :func:`priqn.cli.main`."""

from __future__ import annotations

import concurrent.futures
import sys
from pathlib import Path

import pytest
from test_train import TINY

from priqn.cli import main
from priqn.config import dumps_toml, to_dict
from priqn.env.config import EnvConfig
from priqn.env.traffic import TRAFFIC_SETTINGS
from priqn.errors import PriqnError, did_you_mean
from priqn.io import atomic_write_json
from priqn.run.train_config import PRESETS, TrainConfig, resolve_config

IQN_CELL = Path(__file__).resolve().parents[1] / "results" / "paper-point-tm" / "iqn__seed98"
"""A committed, evaluated IQN cell (read only)."""


def refused(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    """``priqn ARGV``'s one-line error (exit status 2, no traceback)."""
    rc = main(list(argv))
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2, err
    assert len(err) == 1 and err[0].startswith("priqn: error: "), err
    return err[0].removeprefix("priqn: error: ")


def contents(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_a_negative_seed_is_one_line_before_anything_is_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs = tmp_path / "runs"
    train = ("train", "--runs-dir", str(runs), "--steps", "50")
    assert refused(capsys, *train, "--seed", "-1") == "--seed -1: expected an integer >= 0"
    assert refused(capsys, *train, "--set", "seed=-1") == (
        "--set seed: expected an integer >= 0, got -1"
    )
    assert contents(tmp_path) == []


def test_cuda_where_there_is_none_is_refused_before_the_run_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    argv = ("train", "--runs-dir", str(tmp_path / "runs"), "--steps", "50", "--device", "cuda")
    for _ in range(2):  # the same command again: refused the same way, not "already exists"
        assert refused(capsys, *argv) == (
            "device: 'cuda' requested but CUDA is not available here (expected auto or cpu)"
        )
    assert contents(tmp_path) == []


def test_a_junction_the_nets_lack_leaves_no_run_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Only an env worker finds it (after the run folder is written): the failed start is
    taken back, so the same command runs again (no "use --resume", no --force)."""
    argv = ("train", "--agent", "iqn", "--runs-dir", str(tmp_path / "runs" / "new"),
            "--steps", "50", "--num-envs", "1", "--device", "cpu",
            "--set", "evaluation.interval_steps=0", "--set", "env.junction=J42", *TINY)  # fmt: skip
    for _ in range(2):
        error = refused(capsys, *argv)
        assert error.endswith("junction 'J42' is not an intersection of this net "
                              "(intersections, >= 3 arms, most approaches first: J)")  # fmt: skip
        assert contents(tmp_path) == []


def test_the_sensor_query_range_must_be_positive() -> None:
    with pytest.raises(PriqnError) as e:
        resolve_config(overrides=["env.sensor_query_range_m=-5"])
    assert str(e.value) == "--set env.sensor_query_range_m: expected a radius > 0 m, got -5.0"
    with pytest.raises(PriqnError, match=r"sensor_query_range_m: expected a radius > 0 m"):
        resolve_config(overrides=["env.sensor_query_range_m=0"])
    # The default, every preset and every named traffic setting pass.
    assert EnvConfig().sensor_query_range_m > 0
    for preset in PRESETS:
        for name in TRAFFIC_SETTINGS:
            cfg = resolve_config(preset=preset, values=TRAFFIC_SETTINGS[name].values())
            assert cfg.env.sensor_query_range_m > 0


def fake_run(folder: Path, policy: bool) -> Path:
    """A complete 100-decision run folder with one metrics row and, if ``policy``, a
    policy.pt (its bytes are all ``priqn diff`` compares of it)."""
    folder.mkdir(parents=True)
    (folder / "config.toml").write_text(dumps_toml(to_dict(TrainConfig(total_steps=100))))
    atomic_write_json(folder / "meta.json", {"status": "complete", "total_steps": 100})
    (folder / "metrics.csv").write_text("kind,step,loss,wall_s\ntrain,50,0.5,1.0\n")
    if policy:
        (folder / "policy.pt").write_bytes(b"weights")
    return folder


def test_diff_exits_3_when_a_part_could_not_be_compared(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a = fake_run(tmp_path / "a", policy=True)
    assert main(["diff", str(a), str(fake_run(tmp_path / "same", policy=True))]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == (
        "up to 100 decisions, the runs are the same training"
    )
    assert main(["diff", str(a), str(fake_run(tmp_path / "b", policy=False))]) == 3
    out = capsys.readouterr().out.splitlines()
    assert "  weights   not compared  B keeps no policy at 100 decisions" in out
    assert out[-1] == (
        "up to 100 decisions, no difference in the parts compared, but not proven the same "
        "training (not compared: weights)"
    )


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc is Linux's")
def test_probe_refuses_an_unwritable_csv_before_any_episode(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_episodes(*args: object, **kwargs: object) -> None:
        raise AssertionError("episodes started before --csv was checked")

    monkeypatch.setattr(concurrent.futures, "ProcessPoolExecutor", no_episodes)
    assert refused(capsys, "probe", "--csv", "/proc/x/p.csv", "--episodes", "1") == (
        "--csv /proc/x/p.csv: cannot write (No such file or directory)"
    )
    (tmp_path / "file").write_text("")
    error = refused(capsys, "probe", "--csv", str(tmp_path / "file" / "p.csv"))
    assert error.startswith(f"--csv {tmp_path / 'file' / 'p.csv'}: cannot write")
    assert contents(tmp_path) == ["file"]


def test_report_on_no_runs_leaves_no_output_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "empty").mkdir()
    out = tmp_path / "reports" / "x"
    assert refused(capsys, "report", str(tmp_path / "empty"), "--out", str(out)) == (
        f"{tmp_path / 'empty'}: no runs here; train with 'priqn train' and evaluate with "
        "'priqn evaluate'"
    )
    assert refused(capsys, "report", str(tmp_path / "missing"), "--out", str(out)) == (
        f"{tmp_path / 'missing'}: no such folder; expected a folder of runs (e.g. runs/)"
    )
    assert contents(tmp_path) == ["empty"]


@pytest.mark.skipif(not (IQN_CELL / "policy.pt").is_file(), reason="IQN cell not committed")
def test_mechanism_on_an_iqn_run_leaves_no_output_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ("mechanism", str(IQN_CELL), "--out", str(tmp_path / "mech"), "--episodes", "1",
            "--decisions", str(tmp_path / "cache"))  # fmt: skip
    assert refused(capsys, *argv) == (
        f"{IQN_CELL}: the run's agent is iqn; the mechanism needs a Pr-IQN run"
    )
    assert contents(tmp_path) == []


def test_wording_points_to_the_flag_and_the_nearest_name(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    train = ("train", "--runs-dir", str(tmp_path / "runs"))
    assert refused(capsys, *train, "--set", "env.traffic=tm") == (
        "--set env.traffic: expected a table of traffic.* fields, got 'tm'; "
        "to pick a named setting use --traffic tm"
    )
    assert refused(capsys, *train, "--set", "learner.batch_size=x") == (
        "--set learner.batch_size: expected an integer, got 'x'"
    )
    assert refused(capsys, *train, "--set", "learner.lrr=1").endswith(
        "; did you mean 'learner.lr'?"
    )
    assert refused(capsys, *train, "--set", "env.family=fourwy").startswith(
        "--set env.family: unknown pool 'fourwy' ("
    )
    for flag, typo, meant in (("--preset", "papr", "paper"), ("--net", "fourwy", "fourway"),
                              ("--agent", "pr-iq", "pr-iqn")):  # fmt: skip
        assert refused(capsys, *train, flag, typo).endswith(f"; did you mean {meant!r}?")
    assert refused(capsys, "sweep", "headlin", "--list").endswith("; did you mean 'headline'?")
    assert contents(tmp_path) == []
    assert did_you_mean("zzz", ["iqn", "pr-iqn"]) == ""
