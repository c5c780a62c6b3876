"""Reference drivers: ``priqn evaluate --reference sumo|random`` and ``priqn report --reference``.

The env's SUMO driver runs in a spawned process (libsumo: one simulation per process); the
reference evaluations go through the CLI with a tiny episode count; the report side uses
hand-written episode tables (tests/test_analysis.py's ``write_run``).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from fake_runs import HASH, IQN, iqn_value, pr_value, write_run
from test_generalisation import NETS_HASH, write_nets_evaluation

from priqn.analysis.report import make_report
from priqn.errors import PriqnError
from priqn.evaluation.cli import configure_parser, run
from priqn.evaluation.protocol import EPISODE_COLUMNS, EvalConfig, make_scenes
from priqn.evaluation.reference import ReferenceDriver, reference_label

SUMO = reference_label("sumo")
RANDOM = reference_label("random")
TINY_EVAL = ["--episodes", "1", "--eval-runs", "1", "--densities", "0.5", "--workers", "1"]


def test_reference_drivers_act_and_label() -> None:
    assert (SUMO, RANDOM) == ("SUMO driver (reference)", "Random actions (reference)")
    random = ReferenceDriver("random", 25)
    a = [int(random.act({}, np.random.default_rng(7))[0]) for _ in range(3)]
    assert len(set(a)) == 1 and 0 <= a[0] < 25  # the scene's generator decides
    draws = {int(random.act({}, rng)[0]) for rng in [np.random.default_rng(0)] for _ in range(200)}
    assert draws == set(range(25))
    assert ReferenceDriver("sumo", 25).act({}, np.random.default_rng(0)).tolist() == [0]
    labels = ReferenceDriver("sumo", 25).labels
    assert labels["agent"] == "sumo" and labels["label"] == SUMO and labels["train_seed"] == 0
    with pytest.raises(PriqnError, match="--reference bus: expected one of sumo, random"):
        ReferenceDriver("bus", 25)


def _drive_by_sumo(queue: multiprocessing.Queue) -> None:
    from priqn.env.config import EnvConfig
    from priqn.env.intersection import IntersectionEnv

    env = IntersectionEnv(EnvConfig(family="holdout", obs_size_px=32, ego_driver="sumo"))
    out = []
    for actions in ((0, 24), (12, 3)):  # different actions, same scene: the same episode
        env.reset(seed=1, options={"density": 0.5})
        sim = env._session.sim
        modes = (sim.vehicle.getSpeedMode("ego"), sim.vehicle.getLaneChangeMode("ego"))
        t = 0
        while True:
            obs, reward, terminated, truncated, info = env.step(actions[t % 2])
            t += 1
            if terminated or truncated:
                break
        out.append((modes, t, info["success"], info["route_progress"], info["returns"].tolist()))
    env.close()
    queue.put(out)


def test_the_sumo_driver_drives_the_ego_and_ignores_the_action() -> None:
    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_drive_by_sumo, args=(queue,))
    proc.start()
    a, b = queue.get(timeout=180)
    proc.join(timeout=30)
    assert a == b
    modes, steps, success, progress, returns = a
    assert modes == (31, 1621)  # SUMO's defaults: its own safe speeds and lane changes
    assert success and progress == 1.0 and steps < 100  # seed 1 at density 0.5: it gets there
    assert returns[0] == 0.0 and returns[3] > 0  # no crash; progress earned


def _priqn(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "priqn.cli", *args],
        cwd=cwd, capture_output=True, text=True, timeout=600,
    )  # fmt: skip


def test_reference_evaluations_write_the_standard_episode_table(tmp_path: Path) -> None:
    for name in ("sumo", "random"):
        proc = _priqn("evaluate", "--reference", name, *TINY_EVAL, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.strip() == f"reference/{name}/eval/episodes.csv"
    sumo = pd.read_csv(tmp_path / "reference/sumo/eval/episodes.csv")
    rand = pd.read_csv(tmp_path / "reference/random/eval/episodes.csv")
    assert list(sumo.columns) == list(EPISODE_COLUMNS) and len(sumo) == 3
    assert set(sumo["label"]) == {SUMO} and set(rand["label"]) == {RANDOM}
    assert set(sumo["agent"]) == {"sumo"} and (sumo["train_seed"] == 0).all()
    # The hold-out scenes of every policy evaluated with these settings.
    cfg = EvalConfig(episodes_per_cell=1, eval_runs=1, densities=(0.5,))
    scenes = make_scenes(cfg, ["fourway_00", "fourway_01", "tjunction_00"])
    assert list(sumo["reset_seed"]) == [s.reset_seed for s in scenes] == list(rand["reset_seed"])
    meta = json.loads((tmp_path / "reference/sumo/eval/meta.json").read_text())
    assert meta["reference"] == "sumo" and meta["env_config"]["ego_driver"] == "sumo"
    assert meta["status"] == "complete"
    # Errors: one line, before anything runs.
    parser = argparse.ArgumentParser()
    configure_parser(parser)
    for argv, match in (
        (["--reference", "sumo", "--acting", "near-greedy"], "--acting applies to trained"),
        (["--out", "x", "runs/"], "^--out: only with --reference"),
        ([], "^no runs given"),
    ):
        with pytest.raises(PriqnError, match=match):
            run(parser.parse_args(argv))


# ----------------------------------------------------------------------------- the report


def write_reference(root: Path, name: str, value, **kw) -> Path:
    """A reference folder as ``priqn evaluate --reference NAME --out root/NAME`` writes it."""
    config = {"agent": name, "comparator": None, "train_preorder": None, "eps": None,
              "partial_order": None}  # fmt: skip
    write_run(root, name, reference_label(name), config, 0, value, **kw)
    (root / name / "config.toml").unlink()  # a reference folder is no run
    for meta_path in (root / name).glob("eval*/meta.json"):
        meta = json.loads(meta_path.read_text())
        meta_path.write_text(json.dumps({**meta, "reference": name}))
    return root / name


def always(outcome: str):
    def value(seed, r, d, net, e):
        return {"success": outcome == "success", "collision": outcome == "collision"}

    return value


def test_report_shows_reference_rows_unranked_and_claims_ignore_them(
    runs: Path, tmp_path: Path
) -> None:
    plain = make_report(runs, tmp_path / "plain", seed=0, reps=20, command="c").read_text()
    refs = tmp_path / "reference"
    sumo = write_reference(refs, "sumo", always("success"))  # better than every policy
    rand = write_reference(refs, "random", always("collision"))
    out = tmp_path / "with"
    report = make_report(
        runs, out, seed=0, reps=20, command="c", references=(rand, sumo)
    ).read_text()

    table2 = (out / "tables/table2.md").read_text()
    ref_rows = [line for line in table2.splitlines() if "(reference)*" in line]
    assert len(ref_rows) == 2 * 2  # two drivers x two densities
    assert all("**" not in r and "<u>" not in r for r in ref_rows)  # never marked
    assert ref_rows[0].startswith("| *SUMO driver (reference)* | – | – | – | – | 0.000 ± 0.000 |")
    assert ref_rows[1].startswith("| *Random actions (reference)* |")  # REFERENCES order
    # The policies' rows (and their marks) are exactly those of the report without them.
    plain_t2 = (tmp_path / "plain/tables/table2.md").read_text().splitlines()
    assert [line for line in table2.splitlines() if "(reference)" not in line] == plain_t2
    # Claims, rliable and Table I never see them.
    for name in ("claims.csv", "rliable_aggregates.csv", "table1.md", "table1.csv"):
        assert (out / "tables" / name).read_bytes() == (
            tmp_path / "plain/tables" / name
        ).read_bytes()
    csv = pd.read_csv(out / "tables/table2.csv")
    assert csv.loc[csv["reference"], "label"].tolist() == [SUMO, RANDOM] * 2
    assert "reference" not in pd.read_csv(tmp_path / "plain/tables/table2.csv").columns
    outcomes = pd.read_csv(out / "tables/outcomes_by_command.csv")
    assert outcomes["label"].tolist()[-2:] == [SUMO, RANDOM]
    assert outcomes.set_index("label").loc[SUMO, "success"] == 1.0
    assert "\\textit{SUMO driver (reference)}" in (out / "tables/table2.tex").read_text()
    assert "are reference drivers on the same scenes" in report
    assert f"| {sumo} | *{SUMO}* | – | `{HASH[:16]}` |" in report
    assert "reference drivers" not in plain and "(reference)" not in plain
    meta = json.loads((out / "meta.json").read_text())
    assert [r["label"] for r in meta["references"]] == [SUMO, RANDOM]


def test_reference_inputs_are_checked(runs: Path, tmp_path: Path) -> None:
    refs = tmp_path / "reference"
    write_run(tmp_path / "other", "iqn_x", "IQN", IQN, 0, iqn_value)
    cases = [
        (tmp_path / "nowhere", "no complete reference evaluation"),
        (tmp_path / "other" / "iqn_x", "a run's evaluation, not a reference driver's"),
    ]
    other = {"family": "holdout", "densities": [0.5], "eval_runs": 2, "episodes_per_cell": 2,
             "seed": 2026, "commands": [], "max_episode_steps": 0}  # fmt: skip
    cases.append((write_reference(refs, "sumo", always("success"), eval_config=other),
                  r"evaluated with densities \[0.5\], the runs with \[0.5, 1.0\]"))  # fmt: skip
    cases.append((write_reference(refs, "random", always("success"), holdout="f" * 64),
                  "evaluated on another hold-out set than the runs"))  # fmt: skip
    for folder, match in cases:
        with pytest.raises(PriqnError, match=match) as exc:
            make_report(runs, tmp_path / "r", seed=0, reps=20, references=(folder,))
        assert "\n" not in str(exc.value)
    # A reference folder among the runs is refused, not ranked.
    write_reference(runs, "sumo", always("success"))
    with pytest.raises(PriqnError, match="reference driver's evaluation, not a run's") as exc:
        make_report(runs, tmp_path / "r", seed=0, reps=20)


def test_reference_rows_in_the_generalisation_table(runs: Path, tmp_path: Path) -> None:
    for seed in (0, 1):
        write_nets_evaluation(runs, f"iqn_s{seed}", "IQN", IQN, seed, pr_value)
    sumo = write_reference(tmp_path / "reference", "sumo", always("success"))
    write_nets_evaluation(
        tmp_path / "reference", "sumo", SUMO,
        {"agent": "sumo", "comparator": None, "train_preorder": None, "eps": None,
         "partial_order": None}, 0, always("success"),
    )  # fmt: skip
    meta_path = sumo / f"eval-nets-{NETS_HASH[:8]}" / "meta.json"
    meta_path.write_text(json.dumps({**json.loads(meta_path.read_text()), "reference": "sumo"}))
    (sumo / "config.toml").unlink(missing_ok=True)
    report = make_report(runs, tmp_path / "r", seed=0, reps=20, references=(sumo,)).read_text()
    section = report.split("## Generalisation — other nets", 1)[1].split("\n## ", 1)[0]
    assert "| IQN | 2 | 32 |" in section
    assert f"| *{SUMO}* | – | 16 | 1.000 ± 0.000 |" in section
    csv = pd.read_csv(tmp_path / f"r/tables/generalisation_{NETS_HASH[:8]}.csv")
    assert csv["reference"].tolist() == [False, True]


def _record_traffic(meta_path: Path, traffic: dict) -> None:
    """Write ``traffic`` as the ``env_config.traffic`` an evaluation's meta.json records."""
    meta = json.loads(meta_path.read_text())
    meta_path.write_text(json.dumps({**meta, "env_config": {"traffic": traffic}}))


def test_reference_traffic_compares_as_played(runs: Path, tmp_path: Path) -> None:
    # The runs recorded tm's path braking in the older flat form (the knobs beside
    # path_braking = true); a reference in the table form with the same knobs drove the
    # same traffic, and is accepted.
    flat = {"yield_to_ego_prob": 0.0, "path_braking": True, "path_look_ahead_s": 4.35}
    for meta_path in runs.glob("*/eval/meta.json"):
        _record_traffic(meta_path, flat)
    refs = tmp_path / "reference"
    same = write_reference(refs, "sumo", always("success"))
    _record_traffic(same / "eval" / "meta.json",
                    {"yield_to_ego_prob": 0.0, "path_braking": {"look_ahead_s": 4.35}})  # fmt: skip
    make_report(runs, tmp_path / "r", seed=0, reps=20, references=(same,))
    # Path braking off in the reference is other traffic, though every key it lacks is
    # one the runs' record has: refused, naming the key.
    off = write_reference(refs, "random", always("success"))
    _record_traffic(off / "eval" / "meta.json", {"yield_to_ego_prob": 0.0})
    with pytest.raises(PriqnError, match=r"its env differs from the runs' \(traffic\.path_braking"):
        make_report(runs, tmp_path / "r2", seed=0, reps=20, references=(off,))
    # A record written before traffic settings existed played SUMO's drivers (the defaults):
    # accepted beside runs that recorded the defaults, refused beside tm's path braking.
    before = write_reference(tmp_path / "before", "sumo", always("success"))
    meta_path = before / "eval" / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta_path.write_text(json.dumps({**meta, "env_config": {"max_episode_steps": 0}}))
    with pytest.raises(PriqnError, match=r"its env differs from the runs' \(traffic\."):
        make_report(runs, tmp_path / "r3", seed=0, reps=20, references=(before,))
    for meta_path in runs.glob("*/eval/meta.json"):
        _record_traffic(meta_path, {})
    make_report(runs, tmp_path / "r4", seed=0, reps=20, references=(before,))
