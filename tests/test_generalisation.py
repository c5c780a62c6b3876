"""Evaluation on your own nets (``priqn evaluate --nets``) and the report's Generalisation section.

Fast tests use plain netconvert nets (built as tests/test_own_nets.py builds them) and
hand-written episode tables (tests/test_analysis.py's ``write_run``); the end-to-end test
(slow) trains a tiny run and evaluates it on three netconvert nets through the CLI.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from fake_runs import EVAL_CONFIG, IQN, PR, iqn_value, pr_value, write_run
from test_own_nets import netconvert, write_net

from priqn.analysis.generalisation import generalisation_table, load_generalisation
from priqn.analysis.load import load_evaluation
from priqn.analysis.report import make_report
from priqn.errors import PriqnError
from priqn.evaluation.cli import config_from_args, configure_parser
from priqn.evaluation.protocol import (
    EvalConfig,
    eval_dir_of,
    evaluation_name,
    is_nets_evaluation,
    make_scenes,
)
from priqn.evaluation.targets import evaluation_nets, nets_hash
from priqn.run.folder import RunFolder

CROSS_NODES = (
    '<node id="C" x="0" y="0" type="priority"/><node id="W" x="-120" y="0"/>'
    '<node id="E" x="120" y="0"/><node id="S" x="0" y="-120"/><node id="N" x="0" y="120"/>'
)
CROSS_EDGES = "".join(
    f'<edge id="{a}2C" from="{a}" to="C" priority="{p}"/><edge id="C2{a}" from="C" to="{a}" priority="{p}"/>'
    for a, p in (("W", 2), ("E", 2), ("S", 1), ("N", 1))
)


def three_nets(folder: Path) -> Path:
    """A T-junction, a road with two junctions and a four-way cross: plain netconvert nets."""
    folder.mkdir(parents=True, exist_ok=True)
    netconvert("tjunction", folder)
    netconvert("grid", folder)
    write_net(folder, "cross", CROSS_NODES, CROSS_EDGES)
    for extra in folder.glob("*.*.xml"):  # keep only the nets (write_net leaves nod/edg files)
        if not extra.name.endswith(".net.xml"):
            extra.unlink()
    return folder


@pytest.fixture(scope="module")
def nets(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return three_nets(tmp_path_factory.mktemp("gen") / "my_nets")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser()
    configure_parser(parser)
    return parser


# ----------------------------------------------------------------------------- evaluate --nets


def test_nets_flags_folder_names_and_scenes() -> None:
    parser = _parser()
    cfg = config_from_args(parser.parse_args(["r", "--nets", "a/", "b.net.xml", "--junction", "J"]))
    assert (cfg.nets, cfg.junction, cfg.family) == (("a/", "b.net.xml"), "J", "holdout")
    assert config_from_args(parser.parse_args(["r", "--family", "fourway"])).family == "fourway"
    with pytest.raises(PriqnError, match=r"^--junction J: only with --nets"):
        config_from_args(parser.parse_args(["r", "--junction", "J"]))
    with pytest.raises(PriqnError, match=r"^--family and --nets: pick one"):
        config_from_args(parser.parse_args(["r", "--family", "x", "--nets", "a/"]))
    assert EvalConfig(nets="my_nets/").nets == ("my_nets/",)  # one path (TOML, --set)

    h = "0123456789abcdef" * 4
    assert evaluation_name(cfg, h) == "nets-01234567"
    assert evaluation_name(dataclasses_replace(cfg, acting="near-greedy"), h) == (
        "nets-01234567-near-greedy"
    )
    assert eval_dir_of(RunFolder("runs/x"), cfg, h) == Path("runs/x/eval-nets-01234567")
    with pytest.raises(ValueError, match="needs their nets_hash"):
        evaluation_name(cfg)
    assert is_nets_evaluation("nets-01234567") and not is_nets_evaluation("near-greedy")

    # A run trained through junction B of its own net meets the hold-out nets at their own
    # junction (it used to carry env.junction there and fail), and its --nets at --junction.
    from priqn.env.config import EnvConfig
    from priqn.evaluation.targets import evaluation_env

    trained = EnvConfig(nets=("grid.net.xml",), junction="B")
    holdout_env = evaluation_env(trained, EvalConfig(max_episode_steps=7), None)
    assert (holdout_env.nets, holdout_env.junction, holdout_env.family) == ((), "", "holdout")
    assert holdout_env.max_episode_steps == 7
    nets_meta = {"nets": [{"path": "/x/a.net.xml"}]}
    own_env = evaluation_env(trained, EvalConfig(nets=("x/",), junction="J"), nets_meta)
    assert (own_env.nets, own_env.junction) == (("/x/a.net.xml",), "J")

    # The hold-out seed rule, on the nets' own names (sorted): same indices, same seeds.
    own = EvalConfig(nets=("x/",), episodes_per_cell=2, densities=(0.5, 1.0))
    scenes = make_scenes(own, ["my_nets/tjunction", "my_nets/cross"])
    holdout = make_scenes(EvalConfig(episodes_per_cell=2, densities=(0.5, 1.0)), ["b", "a"])
    assert [s.net for s in scenes[:4]] == ["my_nets/cross"] * 4
    assert [(s.reset_seed, s.act_seed) for s in scenes] == [
        (s.reset_seed, s.act_seed) for s in holdout
    ]


def dataclasses_replace(cfg: EvalConfig, **fields: object) -> EvalConfig:
    import dataclasses

    return dataclasses.replace(cfg, **fields)


def test_evaluation_nets_records_path_sha256_junction(nets: Path, tmp_path: Path) -> None:
    cfg = EvalConfig(nets=(str(nets),))
    manifest = evaluation_nets(cfg, ("left", "straight", "right"))
    ids = [n["id"] for n in manifest["nets"]]
    assert ids == ["my_nets/cross", "my_nets/grid", "my_nets/tjunction"]
    for net in manifest["nets"]:
        path = Path(net["path"])
        assert path.is_absolute() and path.parent == nets.resolve()
        assert net["files"] == {path.name: hashlib.sha256(path.read_bytes()).hexdigest()}
    assert [n["junction"] for n in manifest["nets"]] == ["C", "A", "C"]
    # The hash names what is driven on, not where the files lie; a junction changes it.
    moved = shutil.copytree(nets, tmp_path / "elsewhere" / "my_nets")
    again = evaluation_nets(EvalConfig(nets=(str(moved),)), ("left",))
    assert nets_hash(again) == nets_hash(manifest)
    grid_b = evaluation_nets(
        EvalConfig(nets=(str(nets / "grid.net.xml"),), junction="B"), ("left",)
    )
    grid_a = evaluation_nets(EvalConfig(nets=(str(nets / "grid.net.xml"),)), ("left",))
    assert grid_b["nets"][0]["junction"] == "B" and nets_hash(grid_b) != nets_hash(grid_a)


def test_nets_that_cannot_be_used_are_one_line(nets: Path, tmp_path: Path) -> None:
    road = write_net(
        tmp_path,
        "road",
        '<node id="a" x="0" y="0"/><node id="b" x="200" y="0"/>',
        '<edge id="ab" from="a" to="b"/><edge id="ba" from="b" to="a"/>',
    )
    broken = tmp_path / "broken.net.xml"
    broken.write_text("not a net\n")
    cases = [
        ((str(road),), "", r"road\.net\.xml: no intersection \(a node joining 3"),
        ((str(broken),), "", r"broken\.net\.xml: SUMO failed to start"),
        ((str(tmp_path / "nope"),), "", r"^--nets: .*nope: no such file or folder"),
        ((str(tmp_path / "road.nod.xml"),), "", r"^--nets: .* is not a \.net\.xml file"),
        ((str(nets),), "Z", r"junction 'Z' is not an intersection of this net"),
    ]
    for entries, junction, match in cases:
        with pytest.raises(PriqnError, match=match) as exc:
            evaluation_nets(EvalConfig(nets=entries, junction=junction), ("left",))
        assert "\n" not in str(exc.value)
    # A command the junction does not offer: one-way roads from W, to S and E: no left turn.
    one_way = write_net(
        tmp_path,
        "oneway",
        '<node id="C" x="0" y="0"/><node id="W" x="-120" y="0"/><node id="E" x="120" y="0"/>'
        '<node id="S" x="0" y="-120"/>',
        '<edge id="W2C" from="W" to="C"/><edge id="C2E" from="C" to="E"/>'
        '<edge id="C2S" from="C" to="S"/>',
    )
    with pytest.raises(
        PriqnError, match=r"junction C has no 'left' route \(it offers: straight, right\)"
    ):
        evaluation_nets(EvalConfig(nets=(str(one_way),), commands=("left",)), ())
    with pytest.raises(PriqnError, match=r"junction C has no 'left' route"):
        evaluation_nets(EvalConfig(nets=(str(one_way),)), ("left",))  # the run's commands
    assert evaluation_nets(EvalConfig(nets=(str(one_way),)), ("left", "right"))["nets"]


# ----------------------------------------------------------------------------- the report


NETS_HASH = "b" * 64
NETS_CONFIG = {**EVAL_CONFIG, "nets": ["my_nets/"], "junction": ""}
NETS_META = [
    {
        "id": "my_nets/a",
        "path": "/x/my_nets/a.net.xml",
        "files": {"a.net.xml": "c" * 64},
        "junction": "C",
    }
]


def write_nets_evaluation(
    root: Path, name: str, label: str, config: dict, seed: int, value, **kw
) -> Path:
    """An ``eval-nets-<hash>/`` beside a run's ``eval/``, as ``priqn evaluate --nets`` writes it."""
    folder = f"eval-nets-{NETS_HASH[:8]}"
    kw.setdefault("holdout", NETS_HASH)
    kw.setdefault("eval_config", NETS_CONFIG)
    write_run(root, name, label, config, seed, value, eval_dir_name=folder, **kw)
    meta_path = root / name / folder / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta_path.write_text(json.dumps({**meta, "nets": NETS_META, "nets_hash": kw["holdout"]}))
    return root / name / folder


def test_generalisation_is_reported_apart_from_table2(runs: Path, tmp_path: Path) -> None:
    before = make_report(runs, tmp_path / "before", seed=0, reps=20, command="c").read_text()
    table2 = (tmp_path / "before/tables/table2.md").read_text()
    # On the other nets the two policies swap: IQN does what Pr-IQN did on the hold-out set.
    for seed in (0, 1):
        write_nets_evaluation(runs, f"iqn_s{seed}", "IQN", IQN, seed, pr_value)
        write_nets_evaluation(runs, f"pr_s{seed}", "Pr-IQN QD ✓ 0.2 ✗", PR, seed, iqn_value)

    # Table II's loader never reads them; the generalisation loader reads only them.
    ev = load_evaluation(runs)
    assert [r.eval_dir for r in ev.runs] == ["eval"] * 4
    (group,), unfinished = load_generalisation(runs)
    assert unfinished == [] and group.nets_hash == NETS_HASH and group.nets == tuple(NETS_META)
    assert [r.name for r in group.runs] == [f"{r}/eval-nets-bbbbbbbb" for r in
                                             ("iqn_s0", "iqn_s1", "pr_s0", "pr_s1")]  # fmt: skip

    # By hand: IQN units (seed x eval run) all have 1 off-road of 8 episodes (pr_value).
    table = generalisation_table(group.episodes)
    assert list(table["label"]) == ["IQN", "Pr-IQN QD ✓ 0.2 ✗"]
    iqn = table.iloc[0]
    assert (iqn["seeds"], iqn["units"], iqn["episodes"]) == (2, 4, 32)
    assert iqn["off_road_mean"] == pytest.approx(1 / 8) and iqn["off_road_std"] == 0.0
    assert iqn["success_mean"] == pytest.approx(7 / 8) and iqn["timeout_mean"] == 0.0
    pr = table.iloc[1]  # iqn_value: unit success 0, .5, .5, 1 -> mean .5, std .408
    assert pr["success_mean"] == pytest.approx(0.5)
    assert pr["success_std"] == pytest.approx(0.4082, abs=1e-4)
    assert pr["collision_mean"] == pytest.approx(0.5)

    out = tmp_path / "after"
    after = make_report(runs, out, seed=0, reps=20, command="c").read_text()
    assert (out / "tables/table2.md").read_text() == table2  # never mixed into Table II
    start = after.index("## Generalisation — other nets")
    end = after.index("\n## ", start) + 1
    section = after[start:end]
    assert after[:start] + after[end:] == before  # nothing else changed
    assert (
        "| IQN | 2 | 32 | 0.875 ± 0.000 | 0.000 ± 0.000 | 0.125 ± 0.000 | 0.000 ± 0.000 |"
        in section
    )
    assert "| my_nets/a | C | a.net.xml | `cccccccccccccccc` |" in section
    csv = pd.read_csv(out / "tables/generalisation_bbbbbbbb.csv")
    assert list(csv["label"]) == ["IQN", "Pr-IQN QD ✓ 0.2 ✗"]
    meta = json.loads((out / "meta.json").read_text())
    assert meta["generalisation"][0]["nets_hash"] == NETS_HASH


def test_generalisation_inputs_are_checked(runs: Path, tmp_path: Path) -> None:
    write_nets_evaluation(runs, "iqn_s0", "IQN", IQN, 0, pr_value)
    write_nets_evaluation(runs, "pr_s0", "Pr-IQN QD ✓ 0.2 ✗", PR, 0, pr_value, status="running")
    with pytest.raises(
        PriqnError, match=r"1 evaluation\(s\) on other nets not complete: pr_s0/eval-nets"
    ):
        load_generalisation(runs)
    groups, unfinished = load_generalisation(runs, partial=True)
    assert unfinished == ["pr_s0/eval-nets-bbbbbbbb"] and len(groups[0].runs) == 1
    with pytest.raises(PriqnError, match="not complete"):
        make_report(runs, tmp_path / "r", seed=0, reps=20)
    report = make_report(runs, tmp_path / "r", seed=0, reps=20, partial=True).read_text()
    assert "left out of the generalisation tables: pr_s0/eval-nets-bbbbbbbb" in report

    shutil.rmtree(runs / "pr_s0" / "eval-nets-bbbbbbbb")
    other = {**NETS_CONFIG, "episodes_per_cell": 1}
    write_nets_evaluation(runs, "pr_s0", "Pr-IQN QD ✓ 0.2 ✗", PR, 0, pr_value, eval_config=other)
    with pytest.raises(
        PriqnError, match=r"evaluated on nets bbbbbbbb with different episodes_per_cell"
    ) as exc:
        load_generalisation(runs)
    assert "\n" not in str(exc.value)


# ----------------------------------------------------------------------------- end to end


TINY_TRAIN = [
    "--agent", "iqn", "--steps", "20", "--num-envs", "1", "--device", "cpu",
    "--set", "env.obs_size_px=32", "--set", "env.max_episode_steps=15",
    "--set", "replay.learning_starts=10", "--set", "learner.batch_size=4",
    "--set", "evaluation.interval_steps=100000", "--set", "checkpoint.interval_steps=100000",
]  # fmt: skip
TINY_EVAL = ["--episodes", "1", "--eval-runs", "1", "--densities", "0.5", "--workers", "1"]


def _priqn(*args: str, cwd: Path, ok: bool = True) -> subprocess.CompletedProcess:
    proc = subprocess.run(
        [sys.executable, "-m", "priqn.cli", *args],
        cwd=cwd, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    if ok:
        assert proc.returncode == 0, f"priqn {' '.join(args)}:\n{proc.stdout}\n{proc.stderr}"
    return proc


def _tree(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


@pytest.mark.slow
def test_evaluate_on_a_folder_of_netconvert_nets_end_to_end(tmp_path: Path) -> None:
    nets = three_nets(tmp_path / "my_nets")
    runs = tmp_path / "runs"
    _priqn("train", *TINY_TRAIN, "--runs-dir", str(runs), "--name", "iqn_s0", cwd=tmp_path)
    run = runs / "iqn_s0"
    _priqn("evaluate", str(run), *TINY_EVAL, cwd=tmp_path)
    holdout = _tree(run / "eval")

    # A net that cannot be used stops before any episode, in one line, and writes nothing.
    bad = tmp_path / "bad"
    bad.mkdir()
    shutil.copy(nets / "cross.net.xml", bad)
    (bad / "broken.net.xml").write_text("<net>\n")
    proc = _priqn("evaluate", str(run), "--nets", str(bad), *TINY_EVAL, cwd=tmp_path, ok=False)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert "broken.net.xml: SUMO failed to start" in proc.stderr
    assert not list(run.glob("eval-nets-*"))

    proc = _priqn("evaluate", str(run), "--nets", "my_nets/", *TINY_EVAL, cwd=tmp_path)
    (folder,) = run.glob("eval-nets-*")
    assert proc.stdout.strip() == str(folder / "episodes.csv")
    assert _tree(run / "eval") == holdout  # the hold-out evaluation is untouched
    meta = json.loads((folder / "meta.json").read_text())
    assert meta["status"] == "complete" and folder.name == f"eval-nets-{meta['nets_hash'][:8]}"
    for net in meta["nets"]:
        path = Path(net["path"])
        assert path.parent == nets.resolve()
        assert net["files"] == {path.name: hashlib.sha256(path.read_bytes()).hexdigest()}
    episodes = pd.read_csv(folder / "episodes.csv")
    assert sorted(episodes["net"]) == ["my_nets/cross", "my_nets/grid", "my_nets/tjunction"]
    assert episodes["holdout_hash"].eq(meta["nets_hash"]).all()

    # Resumable: a lost cell is played again, the others are kept.
    cells = sorted((folder / "cells").iterdir())
    kept = {c.name: c.stat().st_mtime_ns for c in cells[1:]}
    cells[0].unlink()
    (folder / "meta.json").write_text(json.dumps({**meta, "status": "running"}))
    _priqn("evaluate", str(run), "--nets", "my_nets/", *TINY_EVAL, cwd=tmp_path)
    assert {c.name: c.stat().st_mtime_ns for c in sorted((folder / "cells").iterdir())[1:]} == kept
    pd.testing.assert_frame_equal(pd.read_csv(folder / "episodes.csv"), episodes)

    _priqn("report", str(runs), "--out", str(tmp_path / "rep"), "--reps", "20", cwd=tmp_path)
    report = (tmp_path / "rep" / "report.md").read_text()
    assert "## Generalisation — other nets" in report and "| my_nets/grid | A |" in report
    assert "my_nets" not in (tmp_path / "rep" / "tables" / "table2.csv").read_text()
