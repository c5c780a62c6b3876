"""The traffic report (``priqn report RUNS --traffic NAME``) on fake runs a person can count.

Two seeds of two rows, 16 episodes per evaluation (2 runs x 2 nets x 2 densities x 2
episodes). IQN: under its own traffic episode 0 collides and episode 1 succeeds; under
``tm-carla`` episode 0 on net a succeeds too, so success goes 0.5 -> 0.75 and violations
0.5 -> 0.25 for both seeds. Pr-IQN: every episode succeeds, but seed 1's episode 0 times
out, under both traffics (success 1.0 and 0.5).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fake_runs import IQN, PR, write_run

from priqn.analysis.artifacts import render
from priqn.analysis.reports import choose_kind
from priqn.analysis.request import ReportRequest, report_command
from priqn.analysis.traffic_report import traffic_report
from priqn.errors import PriqnError


def _iqn(carla: bool):
    def value(seed, r, d, net, e):
        success = e == 1 or (carla and net == "holdout/a")
        return {"success": success, "collision": not success}

    return value


def _pr(seed, r, d, net, e):
    timeout = seed == 1 and e == 0
    return {"success": not timeout, "timeout": timeout}


def _runs(root: Path, limit_under_carla: int = 100) -> Path:
    for seed in (0, 1):
        for row, label, config, own, carla in (
            ("iqn", "IQN", IQN, _iqn(False), _iqn(True)),
            ("pr", "Pr-IQN QD ✓ 0.2 ✗", PR, _pr, _pr),
        ):
            name = f"{row}__seed{seed}"
            write_run(root, name, label, config, seed, own)
            write_run(root, name, label, config, seed, carla, eval_dir_name="eval-traffic-tm-carla")
            (root / name / "meta.json").write_text(json.dumps({"status": "complete"}))
            for folder, limit in (("eval", 100), ("eval-traffic-tm-carla", limit_under_carla)):
                meta = root / name / folder / "meta.json"
                data = json.loads(meta.read_text())
                meta.write_text(json.dumps({**data, "env_config": {"max_episode_steps": limit}}))
    return root


def test_changes_rows_and_scenes_by_hand(tmp_path: Path) -> None:
    runs = _runs(tmp_path / "runs")
    report = traffic_report(runs, "tm-carla", "cmd", partial=False)
    tables = {name: t for s in report.sections for name, t in s.tables.items()}
    changes = tables["traffic_changes"].set_index("label")
    iqn, pr = changes.loc["IQN"], changes.loc["Pr-IQN QD ✓ 0.2 ✗"]
    assert (iqn["success_in"], iqn["success_out"], iqn["success_change"]) == (0.5, 0.75, 0.25)
    assert (iqn["success_change_lo"], iqn["success_change_hi"]) == (0.25, 0.25)  # no spread
    assert (iqn["violation_change"], pr["success_change"], pr["timeout_in"]) == (-0.25, 0, 0.25)
    rows = tables["traffic_rows"].set_index("traffic")
    assert rows.loc["own", "a"] == "Pr-IQN QD ✓ 0.2 ✗" and rows.loc["own", "b"] == "IQN"
    assert rows.loc["own", "success"] == 0.25 and rows.loc["tm-carla", "success"] == 0.0
    moved = tables["traffic_transitions"].set_index(["label", "own"])
    assert moved.loc[("IQN", "collision"), "episodes"] == 16
    assert moved.loc[("IQN", "collision"), "success"] == 0.5
    assert moved.loc[("IQN", "success"), "success"] == 1.0
    assert moved.loc[("Pr-IQN QD ✓ 0.2 ✗", "timeout"), "timeout"] == 1.0
    text = render(tmp_path / "out", report).read_text()
    assert "| IQN | 2 | 50.0 % | 75.0 % | +25.0 [+25.0, +25.0] |" in text
    assert (tmp_path / "out" / "figures" / "traffic_seeds.png").is_file()
    assert json.loads((tmp_path / "out" / "meta.json").read_text())["kind"] == "traffic"


def test_a_run_without_the_evaluation_is_refused_or_left_out(tmp_path: Path) -> None:
    runs = _runs(tmp_path / "runs")
    write_run(runs, "iqn__seed2", "IQN", IQN, 2, _iqn(False))
    with pytest.raises(PriqnError, match=r"eval-traffic-tm-carla: no complete evaluation; run "
                       r"'priqn evaluate .*iqn__seed2 --traffic tm-carla'"):  # fmt: skip
        traffic_report(runs, "tm-carla", "cmd", partial=False)
    report = traffic_report(runs, "tm-carla", "cmd", partial=True)
    assert report.meta["left_out"] == [str(runs / "iqn__seed2")]
    assert "**Partial:** 1 run(s)" in report.text()


def test_another_episode_limit_is_refused(tmp_path: Path) -> None:
    runs = _runs(tmp_path / "runs", limit_under_carla=200)
    with pytest.raises(PriqnError, match="other scenes or another episode limit"):
        traffic_report(runs, "tm-carla", "cmd", partial=False)


def test_the_kind_and_its_command(tmp_path: Path) -> None:
    request = ReportRequest(Path("results/x"), Path("docs/results/t"), traffic="tm-carla",
                            partial=True)  # fmt: skip
    assert choose_kind(request) == "traffic"
    assert report_command(request, "traffic") == (
        "priqn report results/x --traffic tm-carla --out docs/results/t --partial"
    )
    with pytest.raises(PriqnError, match="one report at a time"):
        choose_kind(ReportRequest(Path("r"), Path("o"), horizon=(600,), traffic="tm"))
