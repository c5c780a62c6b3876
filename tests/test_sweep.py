"""priqn sweep: grid expansion, completeness, scheduling semantics, Ctrl-C, Ray.

Scheduling tests run the real sweep machinery (child processes, logs, retries,
progress, summary) with fast cell bodies from a small module written to a temp
folder (``--cell-fn fakecells:fake``); they write the same ``meta.json`` files a real
training and evaluation write. The real train + evaluate + report path runs in the
slow tests at the end (``pytest -m slow tests/test_sweep.py``).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from fake_runs import tiny_grid

from priqn.errors import PriqnError
from priqn.io import atomic_write_json
from priqn.paths import experiments_dir
from priqn.run.evaluations import evaluated, evaluation_dir, kept_evaluations
from priqn.run.folder import RunFolder, Status
from priqn.sweep import (
    Cell,
    cell_state,
    default_jobs,
    describe_failure,
    expand,
    is_complete,
    load_experiment,
    run_sweep,
)
from priqn.sweep import cells as sweep_cells
from priqn.sweep.cells import time_left, training_fraction_done, training_minutes_to_go
from priqn.sweep.commit import commit_complete_cells
from priqn.sweep.scheduler import SweepFolder

FAKE_CELLS = '''
"""Fast cell bodies for tests; behaviour picked by the policy name."""
import os
import signal
import time

from priqn.errors import PriqnError
from priqn.io import atomic_write_json, atomic_write_text


def _meta(cell, status):
    atomic_write_json(cell.run_dir / "meta.json", {"status": status, "seed": cell.seed})


def fake(cell):
    calls = cell.run_dir.parent / "calls"
    calls.mkdir(parents=True, exist_ok=True)
    atomic_write_text(calls / f"{cell.policy}__seed{cell.seed}.{os.getpid()}", cell.name)
    p = cell.policy
    if p.startswith("boom"):
        raise RuntimeError(f"boom in {cell.name}")
    if p.startswith("flaky"):
        marker = cell.run_dir.parent / f"{p}__seed{cell.seed}.tried"
        if not marker.exists():
            atomic_write_text(marker, "1")
            raise RuntimeError("first attempt fails")
    if p.startswith("bad-input"):
        raise PriqnError("x.toml [evaluate].episodes: unknown key")
    if p.startswith("crash"):
        os.kill(os.getpid(), signal.SIGKILL)
    if p.startswith("lies"):
        return
    if p.startswith("orphan"):
        import subprocess
        import sys

        child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
        atomic_write_text(cell.run_dir / "orphan_pid", str(child.pid))
    if p.startswith("nap"):
        time.sleep(8)  # long enough that two cells overlap
    if p.startswith("doze"):  # first attempt: runs until stopped; a resumed one completes
        marker = cell.run_dir.parent / f"{p}__seed{cell.seed}.dozed"
        if not marker.exists():
            atomic_write_text(marker, "1")
            _meta(cell, "running")
            atomic_write_text(cell.run_dir / "pid", str(os.getpid()))
            time.sleep(120)
    if p.startswith("sleepy"):
        _meta(cell, "running")
        atomic_write_text(cell.run_dir / "pid", str(os.getpid()))
        time.sleep(120)
    _meta(cell, "complete")
    atomic_write_json(cell.run_dir / "eval" / "meta.json", {"status": "complete"})
'''


@pytest.fixture()
def fake_cells(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    """Write the fake cell module and put it on the children's PYTHONPATH."""
    mod_dir = tmp_path / "mods"
    mod_dir.mkdir()
    (mod_dir / "fakecells.py").write_text(FAKE_CELLS)
    path = os.pathsep.join(p for p in [str(mod_dir), os.environ.get("PYTHONPATH", "")] if p)
    monkeypatch.setenv("PYTHONPATH", path)
    return "fakecells:fake"


def write_experiment(tmp_path: Path, policies: list[str], seeds: list[int], **extra: str) -> Path:
    body = [
        "[experiment]",
        'name = "fake"',
        f"seeds = {seeds}",
        f'runs_dir = "{(tmp_path / "runs").as_posix()}"',
        *(f"{k} = {v}" for k, v in extra.items()),
        "[resources]",
        "cpus_per_cell = 1",
    ]
    for p in policies:
        body += ["[[policy]]", f'name = "{p}"', 'agent = "iqn"']
    path = tmp_path / "fake.toml"
    path.write_text("\n".join(body) + "\n")
    return path


def calls(tmp_path: Path) -> list[str]:
    d = tmp_path / "runs" / "fake" / "calls"
    return sorted(p.name.rsplit(".", 1)[0] for p in d.iterdir()) if d.is_dir() else []


# --------------------------------------------------------------------------- grid expansion

# Table II rows: (name, agent, comparator, train_preorder, eps, preorder)
TABLE2 = [
    ("iqn", "iqn", None, None, None, None),
    ("ensemble", "ensemble-iqn", None, None, None, None),
    ("ma-iqn", "ma-iqn", None, None, None, None),
    ("pr-iqn-mv-tp-eps0.4", "pr-iqn", "mv", True, 0.4, "total"),
    ("pr-iqn-cvar-tp-eps0.4", "pr-iqn", "cvar", True, 0.4, "total"),
    ("pr-iqn-qd-eps0.4", "pr-iqn", "qd", False, 0.4, "total"),
    ("pr-iqn-qd-tp-eps0.4", "pr-iqn", "qd", True, 0.4, "total"),
    ("pr-iqn-qd-eps0.2", "pr-iqn", "qd", False, 0.2, "total"),
    ("pr-iqn-qd-tp-eps0.2", "pr-iqn", "qd", True, 0.2, "total"),
    ("pr-iqn-qd-eps0.2-partial", "pr-iqn", "qd", False, 0.2, "partial"),
    ("pr-iqn-qd-tp-eps0.2-partial", "pr-iqn", "qd", True, 0.2, "partial"),
]


def test_table2_expands_to_the_papers_33_cells(tmp_path: Path) -> None:
    exp = load_experiment(experiments_dir() / "table2.toml", runs_dir=tmp_path)
    cells = expand(exp)
    assert len(cells) == 33
    assert len({c.name for c in cells}) == 33 and len({c.run_dir for c in cells}) == 33
    assert [c.name for c in cells[:4]] == [
        "table2/iqn__seed0",
        "table2/iqn__seed1",
        "table2/iqn__seed2",
        "table2/ensemble__seed0",
    ]
    for i, (name, agent, comparator, tp, eps, preorder) in enumerate(TABLE2):
        row = cells[3 * i : 3 * i + 3]
        assert [c.seed for c in row] == [0, 1, 2]
        for c in row:
            assert c.policy == name and c.agent == agent
            assert c.run_dir == tmp_path / "table2" / f"{name}__seed{c.seed}"
            assert (c.net, c.preset, c.experiment) == ("all", "paper", "table2")
            assert c.evaluate["densities"] == [0.5, 0.75, 1.0] and c.evaluate["eval_runs"] == 3
        expected = []
        if agent == "pr-iqn":
            expected = [
                ("agent.comparator", comparator),
                ("agent.train_preorder", tp),
                ("agent.eps", eps),
                ("agent.preorder", preorder),
            ]
        assert list(row[0].values) == expected, name


PAPER_ROW_LABELS = [
    "IQN",
    "Ensemble",
    "MA-IQN",
    "Pr-IQN MV ✓ 0.4 ✗",
    "Pr-IQN CVaR ✓ 0.4 ✗",
    "Pr-IQN QD ✗ 0.4 ✗",
    "Pr-IQN QD ✓ 0.4 ✗",
    "Pr-IQN QD ✗ 0.2 ✗",
    "Pr-IQN QD ✓ 0.2 ✗",
    "Pr-IQN QD ✗ 0.2 ✓",
    "Pr-IQN QD ✓ 0.2 ✓",
]


def test_table2_cells_train_the_papers_rows(tmp_path: Path) -> None:
    """Each row's resolved TrainConfig renders the Table II label, in the paper's order."""
    from priqn.run.train_config import policy_labels
    from priqn.sweep import build_train_config

    cells = expand(load_experiment(experiments_dir() / "table2.toml", runs_dir=tmp_path))
    labels = [policy_labels(build_train_config(c))["label"] for c in cells[::3]]
    assert labels == PAPER_ROW_LABELS
    seeds = {(c.policy, build_train_config(c).seed) for c in cells[:6]}
    assert seeds == {
        ("iqn", 0),
        ("iqn", 1),
        ("iqn", 2),
        ("ensemble", 0),
        ("ensemble", 1),
        ("ensemble", 2),
    }


def test_cell_spec_round_trips_through_json(tmp_path: Path) -> None:
    cell = expand(load_experiment(experiments_dir() / "table2.toml", runs_dir=tmp_path))[-1]
    spec = json.loads(json.dumps(cell.to_spec()))
    assert spec["name"] == "table2/pr-iqn-qd-tp-eps0.2-partial__seed2"
    assert Cell.from_spec(spec) == cell


def test_cell_values_stay_typed_through_json(tmp_path: Path) -> None:
    """A cell's typed values (a traffic setting, the set strings parsed once, the Pr-IQN
    options, keep_at) survive to_spec -> JSON -> from_spec and resolve the same config; the
    spec's ``overrides`` strings (what a child at an older commit reads) parse back to them."""
    from priqn.config import parse_override, to_dict
    from priqn.sweep.cells import build_train_config

    path = _grid(
        tmp_path,
        '[experiment]\nname = "typed"\nseeds = [0]\nsteps = 9000\ntraffic = "rude"\n'
        'set = ["env.traffic.impatience=0.25", "agent.reward_scheme=hln-4"]\n'
        '[[policy]]\nname = "pr"\nagent = "pr-iqn"\ncomparator = "cvar"\neps = 0\n'
        'preorder = "partial"\ntraffic = "rude-finite"\nkeep_at = [3000, 6000]\n'
        'set = ["agent.eps=[0.1, 0.2, 0.3, 0.4, 0.5]"]\n',
    )
    cell = expand(load_experiment(path, runs_dir=tmp_path))[0]
    assert cell.values == (
        ("env.traffic.yield_to_ego_prob", 0.0),
        ("env.traffic.impatience", 0.25),
        ("agent.reward_scheme", "hln-4"),
        ("env.traffic.yield_to_ego_prob", 0.0),
        ("env.traffic.top_up", False),
        ("agent.comparator", "cvar"),
        ("agent.eps", 0.0),
        ("agent.preorder", "partial"),
        ("checkpoint.keep_at", (3000, 6000)),
        ("agent.eps", (0.1, 0.2, 0.3, 0.4, 0.5)),
    )
    assert cell.traffic == "rude-finite"  # the row's setting, which its run records
    spec = json.loads(json.dumps(cell.to_spec()))
    back = Cell.from_spec(spec)
    assert back == cell and back.values == cell.values
    assert tuple(parse_override(o) for o in spec["overrides"]) == tuple(
        (k, list(v) if isinstance(v, tuple) else v) for k, v in cell.values
    )
    old = {k: v for k, v in spec.items() if k != "values"}  # a spec from an older driver
    assert Cell.from_spec(old) == cell
    cfg = build_train_config(back)
    assert to_dict(cfg) == to_dict(build_train_config(cell))
    assert cfg.checkpoint.keep_at == (3000, 6000) and cfg.agent.eps == (0.1, 0.2, 0.3, 0.4, 0.5)
    assert cfg.env.traffic.top_up is False and cfg.env.traffic.impatience == 0.25


def test_seed_order_runs_every_row_before_the_next_seed(tmp_path: Path) -> None:
    cells = expand(load_experiment(experiments_dir() / "table2_cpu.toml", runs_dir=tmp_path))
    assert len(cells) == 39
    assert [c.seed for c in cells] == [0] * 13 + [1] * 13 + [2] * 13
    assert [c.policy for c in cells[:13]] == [c.policy for c in cells[13:26]]
    assert (
        cells[0].name == "table2_cpu/iqn__seed0" and cells[1].name == "table2_cpu/ensemble__seed0"
    )
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[experiment]\nname = "x"\norder = "random"\n[[policy]]\nname = "a"\nagent = "iqn"\n'
    )
    with pytest.raises(PriqnError, match="order: expected one of policy, seed, cost, got 'random'"):
        load_experiment(bad)


def _grid(tmp_path: Path, body: str, name: str = "g.toml") -> Path:
    path = tmp_path / name
    path.write_text(body)
    return path


_COSTED = """
[experiment]
name = "x"
seeds = [0, 1]
order = "{order}"
[[policy]]
name = "cheap"
agent = "iqn"
[[policy]]
name = "dear"
agent = "ensemble-iqn"
cost = 2.5
[[policy]]
name = "mid"
agent = "ma-iqn"
cost = 1.5
"""


def test_cost_orders_start_the_costliest_cells_first(tmp_path: Path) -> None:
    def order(kind: str) -> list[str]:
        exp = load_experiment(_grid(tmp_path, _COSTED.format(order=kind)), runs_dir=tmp_path)
        return [c.name.split("/")[1] for c in expand(exp)]

    assert order("cost") == [
        "dear__seed0",
        "dear__seed1",
        "mid__seed0",
        "mid__seed1",
        "cheap__seed0",
        "cheap__seed1",
    ]
    assert order("seed") == [
        "dear__seed0",
        "mid__seed0",
        "cheap__seed0",
        "dear__seed1",
        "mid__seed1",
        "cheap__seed1",
    ]
    assert order("policy") == [  # file order, as before
        "cheap__seed0",
        "cheap__seed1",
        "dear__seed0",
        "dear__seed1",
        "mid__seed0",
        "mid__seed1",
    ]


def test_headline_design_parses_and_matches_table2_cpu_rows(tmp_path: Path) -> None:
    from dataclasses import replace

    from priqn.config import config_differences, to_dict
    from priqn.sweep.cells import build_train_config

    exp = load_experiment(experiments_dir() / "headline.toml", runs_dir=tmp_path)
    seq = exp.sequential
    assert seq is not None and seq.seeds_per_look == 5 and seq.interims == (5, 10, 15, 20)
    assert {f: len(c) for f, c in seq.families().items()} == {"primary": 2, "secondary": 2}
    assert list(seq.prior_seeds) + list(exp.experiment.seeds) == list(range(20))
    # The rows train exactly as table2_cpu's (only the seed differs), so its seeds 0-2 count.
    old = {c.policy: c for c in expand(load_experiment(experiments_dir() / "table2_cpu.toml"))}
    for cell in expand(exp)[:4]:
        twin = old[cell.policy]
        mine = build_train_config(replace(cell, seed=twin.seed))
        assert config_differences(to_dict(build_train_config(twin)), to_dict(mine)) == []


_SEQ = """
[experiment]
name = "x"
seeds = [2, 3]
[[policy]]
name = "a"
agent = "iqn"
[[policy]]
name = "b"
agent = "ma-iqn"
[sequential]
interims = {interims}
prior_runs = "old"
prior_seeds = [0, 1]
[[sequential.comparison]]
name = "a > b"
family = "primary"
a = "a"
b = "{b}"
"""


@pytest.mark.parametrize(
    ("interims", "b", "message"),
    [
        (
            "[2, 4]",
            "c",
            r"\[\[sequential.comparison\]\] #1.b: no \[\[policy\]\] named 'c' \(valid: a, b\)",
        ),
        ("[2, 3]", "b", r"\[sequential\].interims: expected equally spaced looks n, 2n"),
        ("[3, 6]", "b", r"prior_seeds \+ \[experiment\].seeds must be 0, 1, ..., 5"),
        ("[2, 4]", "a", r"a and b are the same policy 'a'"),
    ],
)
def test_sequential_design_mistakes_are_one_line(
    tmp_path: Path, interims: str, b: str, message: str
) -> None:
    with pytest.raises(PriqnError, match=message):
        load_experiment(_grid(tmp_path, _SEQ.format(interims=interims, b=b)))
    ok = load_experiment(_grid(tmp_path, _SEQ.format(interims="[2, 4]", b="b"), "ok.toml"))
    assert ok.sequential is not None and ok.sequential.comparisons[0].b == "b"


def test_smoke_grid_is_small(tmp_path: Path) -> None:
    exp = load_experiment(experiments_dir() / "smoke.toml", runs_dir=tmp_path)
    cells = expand(exp)
    assert 1 <= len(cells) <= 4
    assert {c.agent for c in cells} >= {"iqn", "pr-iqn"}
    assert exp.experiment.steps is not None and exp.experiment.steps <= 5000


@pytest.mark.parametrize(
    ("snippet", "message"),
    [
        ('[experiment]\nname = "x"\nseed = [0]\n', "[experiment]: unknown key 'seed'"),
        ('[experiment]\nname = "x"\nseeds = []\n', "[experiment].seeds: empty"),
        ('[experiment]\nname = "x"\nseeds = [1, 1]\n', "duplicate seeds"),
        ('[experiment]\nname = "a b"\n', "not a safe folder name"),
        ('[experiment]\nname = "x"\n[evaluat]\n', "unknown section 'evaluat'"),
        ('[experiment]\nname = "x"\n', "expected one or more [[policy]]"),
        ("[[policy]]\nname='a'\nagent='iqn'\n", "missing [experiment]"),
        (
            '[experiment]\nname = "x"\n[[policy]]\nname = "a"\nagent = "iqn"\neps = 0.2\n',
            "[[policy]] a.eps: applies only to agent 'pr-iqn'",
        ),
        (
            '[experiment]\nname = "x"\n[[policy]]\nname = "a"\nagent = "pr-iqn"\ncomparator = "median"\n',
            "[[policy]] a.comparator: expected one of 'qd', 'mv', 'cvar'",
        ),
        (
            '[experiment]\nname = "x"\n[[policy]]\nname = "a"\nagent = "iqn"\n'
            '[[policy]]\nname = "a"\nagent = "iqn"\n',
            "duplicate policy name 'a'",
        ),
        (
            '[experiment]\nname = "x"\nset = ["lr"]\n[[policy]]\nname = "a"\nagent = "iqn"\n',
            "[experiment].set: 'lr' is not KEY=VALUE",
        ),
        (
            '[experiment]\nname = "x"\n[resources]\ncpus_per_cell = 0\n'
            '[[policy]]\nname = "a"\nagent = "iqn"\n',
            "cpus_per_cell must be > 0",
        ),
    ],
)
def test_experiment_file_errors_are_one_line(tmp_path: Path, snippet: str, message: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(snippet)
    with pytest.raises(PriqnError) as info:
        load_experiment(path)
    text = str(info.value)
    assert message in text and str(path) in text and "\n" not in text


def test_unknown_experiment_name_lists_known_ones() -> None:
    with pytest.raises(PriqnError, match="no such experiment file.*table2"):
        load_experiment("tabel2")


# --------------------------------------------------------------------------- completeness


def test_cell_state_reads_only_the_run_folder(tmp_path: Path) -> None:
    run = tmp_path / "r"
    assert cell_state(run) == "new"
    atomic_write_json(run / "meta.json", {"status": "running"})
    assert cell_state(run) == "running" and not is_complete(run)
    atomic_write_json(run / "meta.json", {"status": "failed"})
    assert cell_state(run) == "failed"
    atomic_write_json(run / "meta.json", {"status": "complete"})
    assert cell_state(run) == "trained" and not is_complete(run)
    atomic_write_json(run / "eval" / "meta.json", {"status": "running"})
    assert cell_state(run) == "trained"
    atomic_write_json(run / "eval" / "meta.json", {"status": "complete"})
    assert cell_state(run) == "complete" and is_complete(run)
    (run / "meta.json").write_text("{half a json")
    assert cell_state(run) == "new"


def test_control_evaluations_belong_to_the_greedy_baselines_cells(tmp_path: Path) -> None:
    """table2_cpu asks for near-greedy controls: its IQN / Ensemble / MA-IQN cells are
    complete only once their eval-near-greedy*/ are; Pr-IQN cells have no control."""
    cells = expand(load_experiment(experiments_dir() / "table2_cpu.toml", runs_dir=tmp_path))
    with_control = {c.agent for c in cells if c.controls == ("near-greedy", "near-greedy-eps0.005")}
    assert with_control == {"iqn", "ensemble-iqn", "ma-iqn"}
    assert all(c.controls == () for c in cells if c.agent == "pr-iqn")
    assert Cell.from_spec(json.loads(json.dumps(cells[0].to_spec()))) == cells[0]

    run = tmp_path / "r"
    atomic_write_json(run / "meta.json", {"status": "complete"})
    atomic_write_json(run / "eval" / "meta.json", {"status": "complete"})
    assert cell_state(run) == "complete"
    assert cell_state(run, ("near-greedy",)) == "trained"
    atomic_write_json(run / "eval-near-greedy" / "meta.json", {"status": "complete"})
    assert is_complete(run, ("near-greedy",))


def test_a_run_folder_is_evaluated_with_each_kept_snapshot(tmp_path: Path) -> None:
    """What a report counts as complete without a sweep's cell: the snapshots that
    meta.json records as kept name the evaluations (``eval-at<N>/``) it waits for."""
    folder = RunFolder(tmp_path / "r")
    atomic_write_json(folder.meta_path, {"status": "complete", "snapshots": {"60000": "ab"}})
    atomic_write_json(folder.eval_meta_path, {"status": "complete"})
    assert kept_evaluations(folder) == ["at60000"]
    assert evaluated(folder) and not evaluated(folder, kept_evaluations(folder))
    atomic_write_json(evaluation_dir(folder, "at60000") / "meta.json", {"status": "complete"})
    assert evaluated(folder, kept_evaluations(folder))
    atomic_write_json(folder.meta_path, {"status": "running", "snapshots": {"60000": "ab"}})
    assert not evaluated(folder, kept_evaluations(folder))

    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[experiment]\nname = "x"\ncontrols = ["coin"]\n[[policy]]\nname = "a"\nagent = "iqn"\n'
    )
    with pytest.raises(PriqnError, match="controls: control 'coin': expected near-greedy or"):
        load_experiment(bad)
    bad.write_text(bad.read_text().replace('"coin"', '"near-greedy-eps0.2"'))
    with pytest.raises(PriqnError, match="controls: write 'near-greedy-eps0.2' as 'near-greedy'"):
        load_experiment(bad)


def test_cell_error_prefers_the_marked_line(tmp_path: Path) -> None:
    from priqn.sweep import ERROR_MARK, cell_error

    log = tmp_path / "x.log"
    log.write_text(f"step 1\r step 2\n{ERROR_MARK}ValueError: bad\nsome late warning\n\n")
    assert cell_error(log) == "ValueError: bad"
    log.write_text("loading\nSegmentation fault\n")
    assert cell_error(log) == "Segmentation fault"
    assert cell_error(tmp_path / "missing.log") == ""


def test_describe_failure() -> None:
    assert describe_failure(1, "RuntimeError: x") == "RuntimeError: x"
    assert describe_failure(-9, "") == "killed by SIGKILL (out of memory?)"
    assert describe_failure(0, "").startswith("exited normally but its run is not marked complete")
    assert describe_failure(3, "") == "exited with status 3 and no output"


def test_default_jobs_divides_cores_by_cell_cpus() -> None:
    from priqn.sweep import ResourceSpec

    cores = len(os.sched_getaffinity(0))
    assert default_jobs(ResourceSpec(cpus_per_cell=1)) == cores
    assert default_jobs(ResourceSpec(cpus_per_cell=1000)) == 1


# --------------------------------------------------------------------------- scheduling (fake cells)


def test_failures_are_isolated_retried_once_and_reported(tmp_path: Path, fake_cells: str) -> None:
    exp = load_experiment(write_experiment(tmp_path, ["ok", "boom", "flaky"], [0, 1]))
    res = run_sweep(
        exp, jobs=2, cell_fn=fake_cells, report=False, progress=False, log=lambda m: None
    )
    assert sorted(res.completed) == [
        "fake/flaky__seed0",
        "fake/flaky__seed1",
        "fake/ok__seed0",
        "fake/ok__seed1",
    ]
    assert sorted(res.failed) == ["fake/boom__seed0", "fake/boom__seed1"]
    assert res.failed["fake/boom__seed1"] == "RuntimeError: boom in fake/boom__seed1"
    assert sorted(res.retried) == sorted(
        ["fake/boom__seed0", "fake/boom__seed1"] + ["fake/flaky__seed0", "fake/flaky__seed1"]
    )
    # boom: 2 attempts each; flaky: 2 attempts each; ok: 1 each.
    assert calls(tmp_path).count("boom__seed0") == 2 and calls(tmp_path).count("ok__seed0") == 1
    assert len(calls(tmp_path)) == 2 * 2 + 2 * 2 + 2
    logs = tmp_path / "runs" / "fake" / ".sweep" / "logs"
    log = (logs / "boom__seed0.attempt2.log").read_text()
    assert "Traceback" in log  # the whole traceback is kept for the user
    assert log.rstrip().endswith("priqn sweep: cell failed: RuntimeError: boom in fake/boom__seed0")
    summary = json.loads((tmp_path / "runs" / "fake" / ".sweep" / "summary.json").read_text())
    assert summary["cells"]["fake/boom__seed0"]["error"] == "RuntimeError: boom in fake/boom__seed0"
    assert summary["cells"]["fake/ok__seed1"]["state"] == "complete"
    assert not list((tmp_path / "runs").rglob("*.tmp"))

    # Re-run: complete cells are skipped, only the failed ones are tried again.
    before = calls(tmp_path)
    res2 = run_sweep(
        exp, jobs=2, cell_fn=fake_cells, report=False, progress=False, log=lambda m: None
    )
    assert sorted(res2.skipped) == sorted(res.completed) and res2.completed == []
    assert sorted(res2.failed) == sorted(res.failed)
    new = list(calls(tmp_path))
    for c in before:
        new.remove(c)
    assert sorted(new) == ["boom__seed0"] * 2 + ["boom__seed1"] * 2


def test_rerunning_a_finished_sweep_does_no_work(tmp_path: Path, fake_cells: str) -> None:
    exp = load_experiment(write_experiment(tmp_path, ["a", "b"], [0, 1, 2]))
    res = run_sweep(
        exp, jobs=2, cell_fn=fake_cells, report=False, progress=False, log=lambda m: None
    )
    assert len(res.completed) == 6 and not res.failed and not res.skipped
    n = len(calls(tmp_path))
    assert n == 6
    messages: list[str] = []
    res2 = run_sweep(
        exp, jobs=2, cell_fn=fake_cells, report=False, progress=False, log=messages.append
    )
    assert len(res2.skipped) == 6 and res2.completed == [] and not res2.failed
    assert len(calls(tmp_path)) == n
    assert messages == ["priqn sweep fake: all 6 cells already complete"]


def test_failure_kinds_and_only_filter(tmp_path: Path, fake_cells: str) -> None:
    exp = load_experiment(write_experiment(tmp_path, ["crash", "lies", "bad-input", "ok"], [0]))
    res = run_sweep(
        exp,
        jobs=2,
        retries=0,
        only=["fake/crash*", "fake/lies*", "fake/bad-input*"],
        cell_fn=fake_cells,
        report=False,
        progress=False,
        log=lambda m: None,
    )
    assert res.retried == [] and res.completed == []
    assert res.failed["fake/crash__seed0"].startswith("killed by SIGKILL")
    assert res.failed["fake/lies__seed0"].startswith(
        "exited normally but its run is not marked complete"
    )
    assert res.failed["fake/bad-input__seed0"] == (
        "priqn: error: x.toml [evaluate].episodes: unknown key"
    )
    assert "ok__seed0" not in calls(tmp_path)
    with pytest.raises(PriqnError, match="matches no cell"):
        run_sweep(exp, only=["nothing*"], cell_fn=fake_cells, report=False, progress=False)


def test_a_cells_leftover_processes_are_killed(tmp_path: Path, fake_cells: str) -> None:
    exp = load_experiment(write_experiment(tmp_path, ["orphan"], [0]))
    res = run_sweep(exp, cell_fn=fake_cells, report=False, progress=False, log=lambda m: None)
    assert res.completed == ["fake/orphan__seed0"]
    pid = int((tmp_path / "runs" / "fake" / "orphan__seed0" / "orphan_pid").read_text())
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            break
        # killed but maybe not reaped yet by its (gone) parent: check the state
        stat = Path(f"/proc/{pid}/stat")
        if stat.exists() and stat.read_text().split(") ")[1].startswith("Z"):
            break
        time.sleep(0.1)
    else:
        pytest.fail(f"process {pid} started by the cell is still running")


def test_one_sweep_per_experiment_folder(tmp_path: Path, fake_cells: str) -> None:
    exp = load_experiment(write_experiment(tmp_path, ["ok"], [0]))
    lock = SweepFolder(exp.runs_dir).lock()
    with lock, pytest.raises(PriqnError, match="another 'priqn sweep'"):
        run_sweep(exp, cell_fn=fake_cells, report=False, progress=False)


def _sweep_cli(exp_path: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "priqn.cli", "sweep", str(exp_path), "--no-report", *extra]


def test_cli_exit_status_summary_and_list(tmp_path: Path, fake_cells: str) -> None:
    exp_path = write_experiment(tmp_path, ["ok", "boom"], [0])
    out = subprocess.run(
        _sweep_cli(exp_path, "--cell-fn", fake_cells, "-j", "2"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 1, out.stderr
    assert "1 complete (0 skipped, 1 run now), 1 failed" in out.stdout
    assert "FAILED fake/boom__seed0: RuntimeError: boom in fake/boom__seed0" in out.stdout
    listed = subprocess.run(
        _sweep_cli(exp_path, "--list"), capture_output=True, text=True, timeout=60
    )
    assert listed.returncode == 0
    states = dict(line.split()[:2] for line in listed.stdout.splitlines())
    assert states == {"fake/ok__seed0": "complete", "fake/boom__seed0": "new"}
    assert listed.stderr.splitlines() == [
        "fake: 2 cells: 1 complete, 1 new",
        "fake: time left for 1 cell(s): unknown until boom has a complete cell to time it by",
    ]
    only = subprocess.run(
        _sweep_cli(exp_path, "--list", "--only", "fake/boom*"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert [line.split()[:2] for line in only.stdout.splitlines()] == [["fake/boom__seed0", "new"]]
    assert only.stderr.splitlines()[0] == "fake: 1 cells: 1 new"
    bad = subprocess.run(
        _sweep_cli(exp_path, "--jobs", "0"), capture_output=True, text=True, timeout=60
    )
    assert bad.returncode == 2 and bad.stderr.strip() == (
        "priqn: error: --jobs 0: expected a positive number of cells"
    )


def test_time_left_times_the_cells_left_by_their_rows_complete_cells(tmp_path: Path) -> None:
    exp = load_experiment(write_experiment(tmp_path, ["a", "b"], [0, 1, 2, 3], steps="1000"))
    cells = {c.name: c for c in expand(exp)}

    def complete(name: str, train_s: float, eval_s: float) -> None:
        d = cells[name].run_dir
        atomic_write_json(d / "meta.json", {"status": "complete", "wall_s": train_s})
        atomic_write_json(d / "eval" / "meta.json", {"status": "complete", "wall_s": eval_s})

    # Row a's cells took 10, 20 and 40 min (training + evaluation): median 20 min.
    complete("fake/a__seed0", 540, 60)
    complete("fake/a__seed1", 1140, 60)
    complete("fake/a__seed2", 2340, 60)
    # Row b: one cell, 30 min. b's seed 1 is training (pid 1 lives), 3/4 of its steps logged.
    complete("fake/b__seed0", 1740, 60)
    running = cells["fake/b__seed1"].run_dir
    atomic_write_json(
        running / "meta.json", {"status": "running", "pid": 1, "host": socket.gethostname()}
    )
    (running / "metrics.csv").write_text("phase,step\ntrain,500\ntrain,750\n")
    # a's seed 3 is trained and its evaluation missing: only a's median evaluation is left.
    atomic_write_json(cells["fake/a__seed3"].run_dir / "meta.json", {"status": "complete"})
    left = [cells[n] for n in ("fake/a__seed3", "fake/b__seed1", "fake/b__seed2")]
    est = time_left(exp, left, slots=2)
    assert est.minutes_per_cell == {"a": pytest.approx(20.0), "b": pytest.approx(30.0)}
    # b1 (running, so it holds a slot first) has a quarter of b's 29 training minutes left
    # plus its 1-min evaluation: 8.25 min; a3 has 1 min; b2 (30 min) takes the slot a3
    # frees at 1 min and ends at 31 min.
    assert est.hours == pytest.approx(31 / 60)
    assert time_left(exp, left, slots=1).hours == pytest.approx((8.25 + 1 + 30) / 60)
    # A row without a complete cell cannot be timed.
    exp_c = load_experiment(write_experiment(tmp_path, ["a", "c"], [0, 1, 2, 3]))
    c_cells = [c for c in expand(exp_c) if c.policy == "c"]
    est = time_left(exp_c, c_cells, 2)
    assert (est.hours, est.untimed) == (None, ("c",))


def test_time_left_scales_a_rows_time_from_its_groups_other_budget(tmp_path: Path) -> None:
    """a-long (4,000 decisions, one snapshot) has no complete cell; its group's 1,000-decision
    cells took 9 and 19 min of training (median 14 min per 1,000 decisions) and 1 min per
    evaluation: 56 min of training plus 2 evaluations, 58 min."""
    path = tmp_path / "grp.toml"
    path.write_text(
        '[experiment]\nname = "fake"\nseeds = [0, 1]\nsteps = 1000\n'
        'set = ["exploration.decay_steps=300"]\n'
        f'runs_dir = "{(tmp_path / "runs").as_posix()}"\n'
        "[resources]\ncpus_per_cell = 1\n"
        '[[policy]]\nname = "a"\nagent = "iqn"\n'
        '[[policy]]\nname = "a-long"\ngroup = "a"\nagent = "iqn"\nsteps = 4000\n'
        "seeds = [2]\nkeep_at = [1000]\n"
    )
    exp = load_experiment(path)
    cells = {c.name: c for c in expand(exp)}
    for name, train_s in (("fake/a__seed0", 540), ("fake/a__seed1", 1140)):
        d = cells[name].run_dir
        atomic_write_json(d / "meta.json", {"status": "complete", "wall_s": train_s})
        atomic_write_json(d / "eval" / "meta.json", {"status": "complete", "wall_s": 60})
    est = time_left(exp, [cells["fake/a-long__seed2"]], slots=1)
    assert est.scaled == ("a-long",) and est.untimed == ()
    assert est.minutes_per_cell["a-long"] == pytest.approx(58.0)
    assert est.hours == pytest.approx(58 / 60)


def test_list_says_how_far_each_started_cell_is(tmp_path: Path) -> None:
    """``--list`` gives a training cell's decisions logged of its budget (the preset's,
    from meta.json, where the row names none), and a trained cell's missing evaluations;
    an interrupted cell is timed by what it has logged too, since it resumes."""
    exp_path = write_experiment(tmp_path, ["a"], [0, 1, 2])
    cells = {c.name: c for c in expand(load_experiment(exp_path))}
    assert cells["fake/a__seed0"].steps is None
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
    stopped = cells["fake/a__seed0"].run_dir
    atomic_write_json(
        stopped / "meta.json",
        {"status": "running", "pid": int(dead), "host": socket.gethostname(), "total_steps": 2000},
    )
    (stopped / "metrics.csv").write_text("phase,step\ntrain,250\ntrain,500\n")
    trained = cells["fake/a__seed1"].run_dir
    atomic_write_json(trained / "meta.json", {"status": "complete", "wall_s": 540})
    atomic_write_json(trained / "eval" / "meta.json", {"status": "running"})
    assert cells["fake/a__seed0"].state() == Status.INTERRUPTED
    assert training_fraction_done(cells["fake/a__seed0"]) == 0.25
    listed = subprocess.run(
        _sweep_cli(exp_path, "--list"), capture_output=True, text=True, timeout=60
    )
    lines = {line.split()[0]: line for line in listed.stdout.splitlines()}
    assert lines["fake/a__seed0"].split()[1] == "interrupted"
    assert lines["fake/a__seed0"].endswith("  500/2,000 decisions")
    assert lines["fake/a__seed1"].endswith("  to evaluate: eval")
    assert lines["fake/a__seed2"].endswith("a__seed2")  # new: nothing to say
    atomic_write_json(trained / "eval" / "meta.json", {"status": "complete", "wall_s": 60})
    # a's one complete cell took 10 min, 1 of them evaluation: seed 0 has 3/4 of 9 min of
    # training left plus 1 min of evaluation; seed 2 the whole 10 min.
    left = [cells["fake/a__seed0"], cells["fake/a__seed2"]]
    assert time_left(load_experiment(exp_path), left, slots=1).hours == pytest.approx(
        (6.75 + 1 + 10) / 60
    )


def test_list_says_how_long_a_training_cell_has_to_go_at_its_recent_pace(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A cell resumed at 400 of 2,000 decisions: its rows up to the resume do not count
    (their wall clock is another session's); since then 500 -> 800 took 40 s and
    800 -> 1,000 took 100 s. Over the whole session 500 decisions in 140 s, so 1,000 to go
    take 280 s; over a 200-decision window 2 decisions a second, so 500 s."""
    exp_path = write_experiment(tmp_path, ["a"], [0, 1])
    cell, done = expand(load_experiment(exp_path))
    atomic_write_json(done.run_dir / "meta.json", {"status": "complete", "wall_s": 540})
    atomic_write_json(done.run_dir / "eval" / "meta.json", {"status": "complete", "wall_s": 60})
    meta = {"status": "running", "pid": 1, "host": socket.gethostname(), "total_steps": 2000,
            "sessions": [{"from_step": 0}, {"from_step": 400}]}  # fmt: skip
    atomic_write_json(cell.run_dir / "meta.json", meta)
    assert training_minutes_to_go(cell) is None  # nothing logged yet
    (cell.run_dir / "metrics.csv").write_text(
        "kind,step,wall_s\ntrain,200,5000\ntrain,400,9000\n"
        "train,500,10\ntrain,800,50\ntrain,900,100\ntrain,1000,150\n"
    )
    assert training_minutes_to_go(cell) == pytest.approx(280 / 60)
    monkeypatch.setattr(sweep_cells, "PACE_WINDOW", 200)
    assert training_minutes_to_go(cell) == pytest.approx(500 / 60)
    assert sweep_cells.cell_progress(cell, Status.RUNNING) == (
        "1,000/2,000 decisions, about 8 min of training to go"
    )
    # Time left counts it by that pace, plus its row's evaluation (1 min), not by the
    # row's 9 min of training less the half logged.
    assert time_left(load_experiment(exp_path), [cell], 1).hours == pytest.approx((500 + 60) / 3600)
    # A stopped cell has no pace: it resumes when a sweep starts it again.
    assert sweep_cells.cell_progress(cell, Status.INTERRUPTED) == "1,000/2,000 decisions"


@pytest.mark.parametrize("backend", ["local", pytest.param("ray", marks=pytest.mark.ray)])
def test_ctrl_c_stops_running_cells_and_leaves_them_incomplete(
    tmp_path: Path, fake_cells: str, backend: str
) -> None:
    if backend == "ray":
        pytest.importorskip("ray")
    exp_path = write_experiment(tmp_path, ["sleepy"], [0])
    sweep = subprocess.Popen(
        _sweep_cli(exp_path, "--cell-fn", fake_cells, *(["--ray"] if backend == "ray" else [])),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # Ctrl-C in a terminal signals the whole foreground group
    )
    pid_file = tmp_path / "runs" / "fake" / "sleepy__seed0" / "pid"
    deadline = time.monotonic() + 60
    while not pid_file.exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert pid_file.exists(), "the cell never started"
    cell_pid = int(pid_file.read_text())
    os.killpg(sweep.pid, signal.SIGINT)
    _, err = sweep.communicate(timeout=60)
    assert sweep.returncode == 130, err
    assert "interrupted" in err
    with pytest.raises(ProcessLookupError):
        os.kill(cell_pid, 0)
    run_dir = tmp_path / "runs" / "fake" / "sleepy__seed0"
    assert cell_state(run_dir) == "running"
    # The cell got SIGINT (not just a kill): it could mark its run interrupted.
    log = tmp_path / "runs" / "fake" / ".sweep" / "logs" / "sleepy__seed0.attempt1.log"
    assert log.read_text().rstrip().endswith("priqn sweep: cell failed: interrupted")
    summary = json.loads((tmp_path / "runs" / "fake" / ".sweep" / "summary.json").read_text())
    assert summary["interrupted"] is True
    assert summary["cells"]["fake/sleepy__seed0"]["state"] == "running"


def test_ray_missing_is_a_one_line_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)
    exp = load_experiment(write_experiment(tmp_path, ["ok"], [0]))
    with pytest.raises(PriqnError, match=r"pip install 'priqn\[ray\]'"):
        run_sweep(exp, use_ray=True, report=False, progress=False, log=lambda m: None)


@pytest.mark.ray
def test_ray_local_cluster_gives_the_same_cells_as_the_local_pool(
    tmp_path: Path, fake_cells: str
) -> None:
    pytest.importorskip("ray")
    policies = ["ok", "boom", "flaky"]
    local_dir, ray_dir = tmp_path / "local", tmp_path / "ray"
    local_dir.mkdir()
    ray_dir.mkdir()
    quiet = {"report": False, "progress": False, "log": lambda m: None, "cell_fn": fake_cells}
    local = run_sweep(load_experiment(write_experiment(local_dir, policies, [0])), jobs=2, **quiet)
    on_ray = run_sweep(
        load_experiment(write_experiment(ray_dir, policies, [0])), use_ray=True, **quiet
    )
    assert (
        sorted(on_ray.completed)
        == sorted(local.completed)
        == ["fake/flaky__seed0", "fake/ok__seed0"]
    )
    assert (
        on_ray.failed
        == local.failed
        == {"fake/boom__seed0": "RuntimeError: boom in fake/boom__seed0"}
    )
    assert (ray_dir / "runs" / "fake" / ".sweep" / "logs" / "ok__seed0.attempt1.log").is_file()


def test_option_names_match_the_preorder_module() -> None:
    """The names experiment files accept (priqn.agents.config) are the ones the preorder
    module implements: one comparator function per name, one shipped file per preset."""
    from priqn import preorder
    from priqn.agents.config import COMPARATOR_NAMES, PREORDER_PRESETS

    assert tuple(preorder.COMPARATOR_FUNCTIONS) == tuple(COMPARATOR_NAMES)
    for name in PREORDER_PRESETS:
        assert preorder.Preorder.preset(name).objectives


# --------------------------------------------------------------------------- the real path (slow)


def _complete_cells(runs_dir: Path) -> list[str]:
    return sorted(p.name for p in runs_dir.iterdir() if p.is_dir() and is_complete(p))


@pytest.mark.slow
def test_smoke_grid_end_to_end_locally_then_on_ray(tmp_path: Path) -> None:
    """experiments/smoke.toml for real: train, evaluate, report; re-run does nothing; Ray agrees."""
    smoke = experiments_dir() / "smoke.toml"
    expected = sorted(c.run_dir.name for c in expand(load_experiment(smoke, runs_dir=tmp_path)))
    env = dict(os.environ, MPLBACKEND="Agg")
    cmd = [sys.executable, "-m", "priqn.cli", "sweep", str(smoke)]

    local = subprocess.run(
        [*cmd, "--runs-dir", "local"], cwd=tmp_path, env=env, capture_output=True, text=True
    )
    assert local.returncode == 0, local.stdout + local.stderr
    assert _complete_cells(tmp_path / "local" / "smoke") == expected
    assert (tmp_path / "reports" / "smoke" / "report.md").is_file()

    again = subprocess.run(
        [*cmd, "--runs-dir", "local", "--no-report"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
    )
    assert again.returncode == 0 and "all 2 cells already complete" in again.stderr

    pytest.importorskip("ray")
    on_ray = subprocess.run(
        [*cmd, "--runs-dir", "ray", "--ray", "--no-report"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
    )
    assert on_ray.returncode == 0, on_ray.stdout + on_ray.stderr
    assert _complete_cells(tmp_path / "ray" / "smoke") == expected


@pytest.mark.ray
@pytest.mark.parametrize(
    ("address", "message"),
    [
        ("nonsense", "--ray nonsense: expected auto, HOST:PORT"),
        ("127.0.0.1:1", "--ray 127.0.0.1:1: cannot reach a Ray head there"),
        ("ray://127.0.0.1:1", "--ray ray://127.0.0.1:1: cannot reach a Ray head there"),
    ],
)
def test_bad_ray_address_fails_fast(tmp_path: Path, address: str, message: str) -> None:
    pytest.importorskip("ray")
    exp = load_experiment(write_experiment(tmp_path, ["ok"], [0]))
    with pytest.raises(PriqnError, match=message):
        run_sweep(exp, use_ray=True, ray_address=address, report=False, progress=False)


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ray_node(env: dict[str, str], *args: str) -> subprocess.Popen:
    """``ray start ... --block`` in its own session (SIGTERM stops what it started)."""
    ray_bin = Path(sys.executable).with_name("ray")
    return subprocess.Popen(
        [str(ray_bin), "start", *args, "--block", "--disable-usage-stats"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


def _wait_for_port(port: int, timeout_s: float = 120) -> None:
    import socket

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return
        except OSError:
            time.sleep(0.2)


@pytest.mark.slow
@pytest.mark.ray
def test_connects_to_an_existing_ray_cluster(tmp_path: Path, fake_cells: str) -> None:
    """`ray start --head` (token auth), then `priqn sweep --ray HOST:PORT`."""
    import secrets

    pytest.importorskip("ray")
    port = _free_port()
    env = dict(os.environ, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(32))
    head = _ray_node(env, "--head", f"--port={port}", "--num-cpus=2", "--include-dashboard=false")
    try:
        _wait_for_port(port)
        exp_path = write_experiment(tmp_path, ["ok", "boom"], [0])
        out = subprocess.run(
            _sweep_cli(exp_path, "--cell-fn", fake_cells, "--ray", f"127.0.0.1:{port}"),
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert out.returncode == 1, out.stderr
        assert f"Ray cluster 127.0.0.1:{port}: 2 CPU / 0 GPU" in out.stderr
        assert "FAILED fake/boom__seed0: RuntimeError: boom in fake/boom__seed0" in out.stdout
        assert is_complete(tmp_path / "runs" / "fake" / "ok__seed0")
    finally:
        head.send_signal(signal.SIGTERM)  # `ray start --block` stops the processes it started
        head.wait(timeout=120)


@pytest.mark.slow
@pytest.mark.ray
def test_two_node_ray_cluster_runs_cells_on_both_nodes(tmp_path: Path, fake_cells: str) -> None:
    """A head and a worker node (1 CPU each) on this machine; two 1-CPU cells that overlap
    must run on different nodes, into the one runs folder."""
    import re
    import secrets

    pytest.importorskip("ray")
    port = _free_port()
    env = dict(os.environ, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(32))
    nodes = [
        _ray_node(env, "--head", f"--port={port}", "--num-cpus=1", "--include-dashboard=false")
    ]
    try:
        _wait_for_port(port)
        nodes.append(_ray_node(env, f"--address=127.0.0.1:{port}", "--num-cpus=1"))
        probe = (
            f"import ray, time; ray.init(address='127.0.0.1:{port}', log_to_driver=False)\n"
            "t = time.time()\n"
            "while len([n for n in ray.nodes() if n['Alive']]) < 2 and time.time() - t < 120:\n"
            "    time.sleep(0.5)\n"
            "print(len([n for n in ray.nodes() if n['Alive']]))"
        )
        alive = subprocess.run(
            [sys.executable, "-c", probe], env=env, capture_output=True, text=True, timeout=200
        )
        assert alive.stdout.strip().endswith("2"), alive.stderr[-2000:]
        exp_path = write_experiment(tmp_path, ["nap-a", "nap-b"], [0])
        out = subprocess.run(
            _sweep_cli(exp_path, "--cell-fn", fake_cells, "--ray", f"127.0.0.1:{port}"),
            env=env, capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        assert out.returncode == 0, out.stderr
        runs = tmp_path / "runs" / "fake"
        assert is_complete(runs / "nap-a__seed0") and is_complete(runs / "nap-b__seed0")
        logs = " ".join(p.read_text() for p in (runs / ".sweep" / "logs").glob("*.log"))
        ran_on = set(re.findall(r"on Ray node (\w+)", logs))
        assert len(ran_on) == 2, logs
    finally:
        for proc in reversed(nodes):
            proc.send_signal(signal.SIGTERM)  # `ray start --block` stops what it started
        for proc in reversed(nodes):
            proc.wait(timeout=120)


def test_unknown_agent_names_the_file_and_the_policy(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(
        '[experiment]\nname = "bad"\nseeds = [0]\n[[policy]]\nname = "x"\nagent = "dqn"\n'
    )
    with pytest.raises(PriqnError, match=rf"{path} \[\[policy\]\] x.agent: unknown agent 'dqn'"):
        load_experiment(path)
    out = subprocess.run(
        [sys.executable, "-m", "priqn.cli", "sweep", str(path), "--list"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert out.returncode == 2 and "new" not in out.stdout  # no cell listed as if it were fine


# --------------------------------------------------------------------------- two cells at a time


def test_ctrl_c_with_two_cells_in_flight_then_resume(tmp_path: Path, fake_cells: str) -> None:
    """jobs=2: a second sweep of the folder is refused while two cells run; Ctrl-C stops
    both (incomplete, never started cells untouched); the next sweep completes them all."""
    exp_path = write_experiment(tmp_path, ["doze", "ok"], [0, 1])
    sweep = subprocess.Popen(
        _sweep_cli(exp_path, "--cell-fn", fake_cells, "--jobs", "2"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    runs = tmp_path / "runs" / "fake"
    pid_files = [runs / f"doze__seed{s}" / "pid" for s in (0, 1)]
    try:
        deadline = time.monotonic() + 60
        while not all(p.exists() for p in pid_files) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert all(p.exists() for p in pid_files), "the two cells never ran together"
        second = subprocess.run(
            _sweep_cli(exp_path, "--cell-fn", fake_cells),
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert second.returncode == 2
        assert "another 'priqn sweep' is running this experiment" in second.stderr
        cell_pids = [int(p.read_text()) for p in pid_files]
        os.killpg(sweep.pid, signal.SIGINT)
        _, err = sweep.communicate(timeout=60)
    finally:
        if sweep.poll() is None:
            os.killpg(sweep.pid, signal.SIGKILL)
            sweep.wait()
    assert sweep.returncode == 130, err
    assert "stopping 2 running cell(s)" in err
    for pid in cell_pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
    summary = json.loads((runs / ".sweep" / "summary.json").read_text())
    assert summary["interrupted"] is True
    states = {name: cell["state"] for name, cell in summary["cells"].items()}
    assert states == {
        "fake/doze__seed0": "running",
        "fake/doze__seed1": "running",
        "fake/ok__seed0": "new",
        "fake/ok__seed1": "new",
    }
    for s in (0, 1):
        log = runs / ".sweep" / "logs" / f"doze__seed{s}.attempt1.log"
        assert log.read_text().rstrip().endswith("priqn sweep: cell failed: interrupted")
    assert calls(tmp_path) == ["doze__seed0", "doze__seed1"]  # the queued cells never started

    res = run_sweep(
        load_experiment(exp_path),
        jobs=2,
        cell_fn=fake_cells,
        report=False,
        progress=False,
        log=lambda m: None,
    )
    assert res.skipped == [] and not res.failed and not res.interrupted
    assert sorted(res.completed) == sorted(states)
    assert calls(tmp_path) == ["doze__seed0"] * 2 + ["doze__seed1"] * 2 + ["ok__seed0", "ok__seed1"]


def test_default_preset_cells_count_as_one_cpu(
    tmp_path: Path, fake_cells: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two default-preset cells at a time on 2 cores (docs/sweeps.md, "Local machine");
    ``--jobs`` still overrides the default."""
    import dataclasses

    from priqn.sweep import ResourceSpec

    assert ResourceSpec().cpus_per_cell == 1
    shipped = {
        name: load_experiment(experiments_dir() / f"{name}.toml", runs_dir=tmp_path)
        for name in ("smoke", "readme", "sensitivity", "headline", "table2_cpu", "table2")
    }
    for name in ("smoke", "readme", "sensitivity", "headline"):
        assert shipped[name].experiment.preset == "default"
        assert shipped[name].resources.cpus_per_cell == 1, name
    assert shipped["table2_cpu"].resources.cpus_per_cell == 2  # complete; ran one at a time
    assert shipped["table2"].resources.cpus_per_cell == 8  # paper preset: 8 env workers

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    assert default_jobs(shipped["smoke"].resources) == 2
    assert default_jobs(shipped["table2_cpu"].resources) == 1
    exp = load_experiment(write_experiment(tmp_path, ["ok"], [0]))
    exp = dataclasses.replace(exp, resources=ResourceSpec())
    for jobs, expected in ((None, "2 cell(s) at a time"), (1, "1 cell(s) at a time")):
        messages: list[str] = []
        sub = dataclasses.replace(
            exp, experiment=dataclasses.replace(exp.experiment, name=f"fake-{jobs}")
        )
        res = run_sweep(
            sub, jobs=jobs, cell_fn=fake_cells, report=False, progress=False, log=messages.append
        )
        assert res.completed == [f"fake-{jobs}/ok__seed0"]
        assert expected in messages[0], messages


def test_bench_sweep_arithmetic() -> None:
    """Cells per hour, the concurrent / sequential ratio and the jobs it recommends."""
    from priqn.bench.sweep import (
        RECOMMEND_THRESHOLD,
        cells_per_hour,
        concurrency_ratio,
        recommend_jobs,
    )

    assert cells_per_hour(2, 3600.0) == pytest.approx(2.0)
    assert cells_per_hour(2, 1800.0) == pytest.approx(4.0)
    sequential, concurrent = cells_per_hour(2, 200.0), cells_per_hour(2, 128.0)
    assert concurrency_ratio(sequential, concurrent) == pytest.approx(200.0 / 128.0)
    assert concurrency_ratio(sequential, sequential) == pytest.approx(1.0)
    assert RECOMMEND_THRESHOLD == 1.05
    assert recommend_jobs(1.56, 2) == 2
    assert recommend_jobs(1.06, 3) == 3
    assert recommend_jobs(1.05, 2) == 1  # within the noise: one at a time
    assert recommend_jobs(0.8, 2) == 1
    for bad in ((2, 0.0), (-1, 10.0)):
        with pytest.raises(ValueError):
            cells_per_hour(*bad)
    with pytest.raises(ValueError):
        concurrency_ratio(0.0, 1.0)


def test_bench_sweep_forecast_arithmetic() -> None:
    """Per-cell 1000 / 800 / 500 decisions/s at 1 / 2 / 4 cells at a time, 33 runs of 2M:
    one run alone 2000 s; the grid 33 x 2000 s = 18.3 h one at a time, 17 waves x 2500 s =
    11.8 h two at a time, 9 waves x 4000 s = 10.0 h four at a time (the fewest)."""
    from priqn.bench.sweep import grid_forecast

    one, n, grid = grid_forecast({1: 1000.0, 2: 800.0, 4: 500.0}, 33, 2_000_000)
    assert one == pytest.approx(2000 / 3600) and n == 4 and grid == pytest.approx(10.0)
    assert grid_forecast({1: 1000.0, 2: 400.0}, 33, 2_000_000)[1:] == (1, pytest.approx(18 + 1 / 3))
    assert grid_forecast({1: 1000.0, 2: 500.0}, 2, 3600)[1] == 1  # a tie: fewer cells
    for bad in ({2: 800.0}, {1: 0.0}, {}):
        with pytest.raises(ValueError):
            grid_forecast(bad, 33, 2_000_000)


def test_bench_sweep_scaling_prints_the_forecast_with_its_worker_count(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Levels 1 / 2 / 4 on 16 cores with ``--workers share`` (16, 8, 4 workers a cell),
    steady 100 / 2 x 150 / 4 x 125 decisions/s: 4 cells give 500 (5.00x one); the
    forecast of one 2M run is 2,000,000 / 100 s = 5.56 h at 16 workers; the 33-run grid
    at 4 cells is 9 waves x 2,000,000 / 125 s = 40.0 h (2 cells: 17 x 3.70 h = 63.0 h)."""
    import argparse

    from priqn.bench import sweep

    steady = {1: 100.0, 2: 150.0, 4: 125.0}  # per cell, by cells at a time

    def fake_levels(args, plans, gpus=None):  # noqa: ANN001, ANN202
        cell = {
            n: {"decisions_per_s": r / 2, "steady_decisions_per_s": r} for n, r in steady.items()
        }
        return [{"wall_s": 60.0, "cells": [cell[n]] * n} for _, n, _, _ in plans]

    monkeypatch.setattr(sweep, "measure_modes", fake_levels)
    monkeypatch.setattr(sweep, "usable_cores", lambda: 16)
    parser = argparse.ArgumentParser()
    sweep.configure_parser(parser)
    args = parser.parse_args(["--cells", "1,2,4", "--workers", "share"])
    assert sweep.run_scaling(args, [1, 2, 4]) == 0
    out = capsys.readouterr().out
    assert "most decisions/s: 4 cell(s) at a time (5.00x one cell)" in out
    assert "one 2,000,000-decision run 5.56 h (num_envs=16;" in out
    assert "33 such runs 40.0 h at 4 cell(s) at a time" in out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--steps", "0"], "--steps 0: expected a positive number"),
        (["--jobs", "1"], "--jobs 1: expected 2 or more"),
        (["--cells", "2", "--jobs", "3"], "--cells 2: expected at least --jobs (3) cells"),
        (["--workers", "4,8", "--cells", "1,2"], "--workers 4,8: a list of worker counts needs"),
        (["--workers", "share"], "--workers share: expected a --cells list"),
        (["--workers", "0"], "--workers 0: expected a positive number"),
    ],
)
def test_bench_sweep_rejects_options_that_measure_nothing(argv: list[str], message: str) -> None:
    """A one-line error before any cell starts."""
    import argparse

    from priqn.bench import sweep as bench_sweep

    parser = argparse.ArgumentParser()
    bench_sweep.configure_parser(parser)
    with pytest.raises(PriqnError) as err:
        bench_sweep.run(parser.parse_args(argv))
    assert str(err.value).startswith(message)


@pytest.mark.slow
def test_bench_sweep_times_real_cells_one_then_two_at_a_time(tmp_path: Path) -> None:
    """``priqn bench sweep`` end to end with a tiny budget: both modes, same cells."""
    from priqn.bench.sweep import cells_per_hour, concurrency_ratio, recommend_jobs

    out = tmp_path / "bench.json"
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    cmd = [sys.executable, "-m", "priqn.cli", "bench", "sweep", "--steps", "300", "--cells", "2",
           "--device", "cpu", "--json", str(out)]  # fmt: skip
    env = dict(os.environ, TMPDIR=str(scratch))
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900, env=env)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    data = json.loads(out.read_text())
    seq, conc = data["sequential"], data["concurrent"]
    assert (seq["jobs"], conc["jobs"]) == (1, 2)
    for mode in (seq, conc):
        assert [c["seed"] for c in mode["cells"]] == [0, 1]
        assert all(c["decisions_per_s"] > 0 and c["elapsed_s"] > 0 for c in mode["cells"])
        assert mode["cells_per_hour"] == pytest.approx(cells_per_hour(2, mode["wall_s"]))
    assert data["ratio"] == pytest.approx(
        concurrency_ratio(seq["cells_per_hour"], conc["cells_per_hour"])
    )
    assert data["recommended_jobs"] == recommend_jobs(data["ratio"], 2)
    assert data["cores"] >= 1
    assert "concurrent / sequential:" in proc.stdout
    assert f"recommended: jobs={data['recommended_jobs']}" in proc.stdout
    assert proc.stderr.count(" done in ") == 4  # a line per finished cell
    # The temporary runs folder is gone (torch keeps its own inductor cache in TMPDIR: any
    # training run makes one, compile on or off, at aa4f06e already).
    assert [p for p in scratch.iterdir() if not p.name.startswith("torchinductor_")] == []


def test_commit_commits_only_complete_cells_and_only_their_folders(tmp_path: Path) -> None:
    env = {
        **os.environ,
        "GIT_AUTHOR_NAME": "t",
        "GIT_AUTHOR_EMAIL": "t@example.org",
        "GIT_COMMITTER_NAME": "t",
        "GIT_COMMITTER_EMAIL": "t@example.org",
    }

    def git(*args: str) -> str:
        out = subprocess.run(
            ["git", "-C", str(tmp_path), *args], capture_output=True, text=True, env=env
        )
        assert out.returncode == 0, out.stderr
        return out.stdout

    exp_path = write_experiment(tmp_path, ["a"], [0, 1, 2], steps="1000")
    cells = {c.name: c for c in expand(load_experiment(exp_path))}
    git("init", "-q")
    (tmp_path / ".gitignore").write_text("checkpoints/\n")
    (tmp_path / "notes.txt").write_text("work in progress\n")
    git("add", "notes.txt")  # staged work of the user's, which --commit must leave alone
    # Seed 0 complete (with a checkpoint .gitignore keeps out), seed 1 trained but not
    # evaluated, seed 2 not started.
    done = cells["fake/a__seed0"].run_dir
    atomic_write_json(done / "meta.json", {"status": "complete", "git_sha": "0123456789abcdef"})
    atomic_write_json(done / "eval" / "meta.json", {"status": "complete"})
    (done / "checkpoints").mkdir()
    (done / "checkpoints" / "latest.pt").write_bytes(b"big")
    atomic_write_json(cells["fake/a__seed1"].run_dir / "meta.json", {"status": "complete"})

    run = subprocess.run(
        _sweep_cli(exp_path, "--commit"), capture_output=True, text=True, env=env, timeout=60
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("priqn sweep fake: committed 1 cell(s) as ")
    assert run.stdout.rstrip().endswith(": a__seed0")
    assert git("log", "--format=%s").splitlines() == [
        "fake: 1 cell(s) complete: a__seed0 (1000 decisions each; code 0123456789ab; "
        "priqn sweep --commit)"
    ]
    assert git("show", "--name-only", "--format=", "HEAD").split() == [
        "runs/fake/a__seed0/eval/meta.json",
        "runs/fake/a__seed0/meta.json",
    ]
    assert git("diff", "--cached", "--name-only").split() == ["notes.txt"]  # still staged
    again = subprocess.run(
        _sweep_cli(exp_path, "--commit"), capture_output=True, text=True, env=env, timeout=60
    )
    assert again.stdout == "priqn sweep fake: no complete cell to commit\n"
    # A changed file in a committed complete cell is committed again.
    (done / "eval" / "episodes.csv").write_text("x\n1\n")
    done = commit_complete_cells(load_experiment(exp_path))
    assert done.sha is not None and [c.name for c in done.cells] == ["fake/a__seed0"]


def test_commit_outside_a_git_work_tree_is_one_line(tmp_path: Path) -> None:
    exp_path = write_experiment(tmp_path, ["a"], [0])
    (tmp_path / "runs" / "fake").mkdir(parents=True)
    with pytest.raises(PriqnError, match=r"^--commit: .*/runs/fake is not inside a git work tree"):
        commit_complete_cells(load_experiment(exp_path))
    # Inside one, but a folder git ignores (the scratch runs/): refused, not "nothing to do".
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    (tmp_path / ".gitignore").write_text("/runs/\n")
    with pytest.raises(PriqnError, match=r"^--commit: .*/runs/fake is ignored by git"):
        commit_complete_cells(load_experiment(exp_path))


BUDGETS_GRID = (
    tiny_grid("budgets", 200)
    + """
[[policy]]
name = "iqn-400"
group = "iqn"
agent = "iqn"
seeds = [1]
steps = 400
keep_at = [200]
[[policy]]
name = "iqn"
agent = "iqn"
seeds = [2]
"""
)


def test_a_long_rows_cell_keeps_and_evaluates_its_snapshots(tmp_path: Path) -> None:
    """A row with keep_at trains once and is complete only with eval-at<N>/ beside eval/;
    the kept policy is evaluated, its SHA-256 in meta.json; a group answers both budgets."""
    from priqn.sweep.child import train_and_evaluate

    path = tmp_path / "budgets.toml"
    path.write_text(BUDGETS_GRID)
    exp = load_experiment(path, runs_dir=tmp_path / "runs")
    cells = {c.policy: c for c in expand(exp)}
    assert [c.name for c in expand(exp)] == ["budgets/iqn-400__seed1", "budgets/iqn__seed2"]
    long = cells["iqn-400"]
    assert long.steps == 400 and long.snapshots == (200,)
    assert long.evaluations == ("", "at200")
    assert exp.cell_at("iqn", 1, 200)[1:] == (long.run_dir, "at200")
    assert exp.cell_at("iqn", 2, 200)[1:] == (cells["iqn"].run_dir, "")
    assert exp.cell_at("iqn", 2, 400) is None
    train_and_evaluate(long)
    assert long.is_complete()
    meta = json.loads((long.run_dir / "meta.json").read_text())
    assert meta["steps_done"] == 400 and set(meta["snapshots"]) == {"200"}
    kept = json.loads((long.run_dir / "eval-at200" / "meta.json").read_text())
    assert kept["status"] == "complete" and kept["eval_config"]["snapshot"] == 200
    (long.run_dir / "eval-at200" / "meta.json").unlink()
    assert long.state() == "trained"


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("seeds = [2]\n", 'seeds = [2]\ngroup = "iqn-400"\n', "'iqn' is a row of group 'iqn-400'"),
        (
            'name = "iqn"\nagent = "iqn"',
            'name = "iqn"\nagent = "pr-iqn"',
            "rows of group 'iqn' train one policy",
        ),
        (
            "keep_at = [200]",
            "keep_at = [400]",
            r"keep_at: expected ascending budgets below the row.s steps \(400\)",
        ),
        (
            "seeds = [2]\n",
            'seeds = [2]\nreuse = {"old" = [2]}\n',
            "seed 2 is both trained here and reused from old",
        ),
    ],
)
def test_row_group_mistakes_are_one_line(tmp_path: Path, old: str, new: str, message: str) -> None:
    path = tmp_path / "budgets.toml"
    assert old in BUDGETS_GRID
    path.write_text(BUDGETS_GRID.replace(old, new, 1))
    with pytest.raises(PriqnError, match=message):
        load_experiment(path, runs_dir=tmp_path)


def test_a_group_whose_decay_differs_in_decisions_is_refused(tmp_path: Path) -> None:
    """Without an absolute ε decay the long row's first 200 decisions are not the short
    row's: the sweep refuses before any work."""
    from priqn.sweep.cells import validate

    path = tmp_path / "budgets.toml"
    path.write_text(BUDGETS_GRID.replace('"exploration.decay_steps=60"', '"log_interval_steps=50"'))
    with pytest.raises(PriqnError, match=r"ε decays over 60 decisions, not 120 .*'iqn-400'"):
        validate(load_experiment(path, runs_dir=tmp_path))


def test_explain_design_reaches_every_seed_at_every_budget(tmp_path: Path) -> None:
    """explain.toml (issue 33): four questions over two groups trained to 60k and 240k;
    every question's seeds exist at its budget, and the 240k cells keep 60k and 120k."""
    exp = load_experiment(experiments_dir() / "explain.toml", runs_dir=tmp_path)
    assert [q.name for q in exp.designs] == ["budget", "safety-60k", "safety-240k", "weights"]
    assert {q.endpoint for q in exp.designs} == {"success", "violation"}
    cells = expand(exp)
    long = [c for c in cells if c.steps == 240000]
    assert len(long) == 20 and all(c.snapshots == (60000, 120000) for c in long)
    assert len(cells) == 80  # 20 halving + 2 x 10 long + 2 x 20 short
    safety = exp.designs[1]
    sources = [exp.cell_at("iqn", k, 60000)[2] for k in safety.seeds]
    assert sources == ["at60000"] * 10 + [""] * 20
    assert (
        str(exp.cell_at("pr-iqn-qd-tp-eps0.2", 4, 60000)[1])
        == "results/headline/pr-iqn-qd-tp-eps0.2__seed4"
    )


# --------------------------------------------------------------------------- GPU shares (local)

GPU_CELLS = '''
"""A cell body that records its CUDA_VISIBLE_DEVICES and when it ran."""
import os
import time

from priqn.io import atomic_write_json


def gpu(cell):
    start = time.time()
    time.sleep(1.5)  # long enough that the pool's cells overlap
    out = cell.run_dir.parent / "gpu-calls"
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(
        out / f"{cell.policy}-seed{cell.seed}.json",
        {"gpu": os.environ.get("CUDA_VISIBLE_DEVICES"), "start": start, "end": time.time()},
    )
    atomic_write_json(cell.run_dir / "meta.json", {"status": "complete", "seed": cell.seed})
    atomic_write_json(cell.run_dir / "eval" / "meta.json", {"status": "complete"})
'''


def _most_at_once(spans: list[tuple[float, float]]) -> int:
    events = sorted([(s, 1) for s, _ in spans] + [(e, -1) for _, e in spans])
    now = best = 0
    for _, step in events:
        now += step
        best = max(best, now)
    return best


def test_gpu_shares_bound_and_spread_local_cells() -> None:
    from priqn.experiment import ResourceSpec
    from priqn.sweep.backends import GpuShares, local_slots

    quarter = GpuShares(["0", "1"], 0.25)
    assert quarter.capacity == 8
    assert [quarter.acquire() for _ in range(4)] == ["0", "1", "0", "1"]  # spread
    quarter.release("0")
    assert quarter.acquire() == "0"
    assert GpuShares(["0", "1", "2"], 1 / 3).capacity == 9  # rounding: 3 a GPU, not 2
    assert GpuShares(["4", "5", "6"], 2).capacity == 1  # groups of two whole GPUs
    assert GpuShares(["4", "5", "6", "7"], 2).acquire() == "4,5"
    res = ResourceSpec(cpus_per_cell=2, gpus_per_cell=0.5)
    assert local_slots(res, 16, GpuShares(["0"], 0.5)) == 2  # the GPU bounds
    assert local_slots(res, 16, GpuShares(["0", "1", "2", "3", "4", "5"], 0.5)) == 8  # CPUs
    assert local_slots(res, 16, None) == 8
    for ids, share, message in (
        ([], 0.5, "no CUDA GPU torch can see"),
        (["0"], 1.5, "expected a whole number"),
        (["0"], 2, "has 1 GPU"),
    ):
        with pytest.raises(PriqnError, match=message):
            GpuShares(ids, share)


def test_local_sweep_pins_cells_to_gpu_shares(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two faked GPUs at 0.5 a cell and 8 cores: 4 cells at a time (not 8), 2 per GPU,
    each cell's child sees only its GPU."""
    from priqn.sweep import backends

    mod_dir = tmp_path / "mods"
    mod_dir.mkdir()
    (mod_dir / "gpucells.py").write_text(GPU_CELLS)
    monkeypatch.setenv(
        "PYTHONPATH", os.pathsep.join([str(mod_dir), os.environ.get("PYTHONPATH", "")])
    )
    monkeypatch.delenv("CUDA_VISIBLE_DEVICES", raising=False)
    monkeypatch.setattr(backends, "gpu_count", lambda: 2)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(8)), raising=False)
    path = write_experiment(tmp_path, ["a", "b"], [0, 1, 2, 3])
    path.write_text(path.read_text().replace("cpus_per_cell = 1", "gpus_per_cell = 0.5"))
    exp = load_experiment(path)
    assert exp.resources.gpus_per_cell == 0.5
    assert default_jobs(exp.resources) == 4
    messages: list[str] = []
    res = run_sweep(exp, cell_fn="gpucells:gpu", report=False, progress=False, log=messages.append)
    assert len(res.completed) == 8 and not res.failed
    assert "4 cell(s) at a time, 0.5 GPU each on 2 GPU(s)" in messages[0]
    calls = [json.loads(p.read_text()) for p in (exp.runs_dir / "gpu-calls").iterdir()]
    assert len(calls) == 8
    by_gpu: dict[str, list[tuple[float, float]]] = {}
    for c in calls:
        by_gpu.setdefault(c["gpu"], []).append((c["start"], c["end"]))
    assert set(by_gpu) == {"0", "1"}  # every cell pinned to one GPU, both GPUs used
    assert _most_at_once([span for spans in by_gpu.values() for span in spans]) <= 4
    assert all(_most_at_once(spans) <= 2 for spans in by_gpu.values())


def test_local_sweep_ignores_gpu_shares_without_a_gpu(
    tmp_path: Path, fake_cells: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """table2.toml asks for a GPU a cell (for Ray); a CPU machine still runs it locally."""
    from priqn.sweep import backends

    monkeypatch.setattr(backends, "gpu_count", lambda: 0)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    path = write_experiment(tmp_path, ["ok"], [0])
    exp = load_experiment(path, gpus_per_cell=1.0)
    assert default_jobs(exp.resources) == 2
    messages: list[str] = []
    res = run_sweep(exp, cell_fn=fake_cells, report=False, progress=False, log=messages.append)
    assert res.completed == ["fake/ok__seed0"]
    assert any("torch sees no CUDA GPU here: cells run on the CPU" in m for m in messages)


def test_bench_sweep_scaling_arithmetic_and_cells_option() -> None:
    from priqn.bench.sweep import aggregate_rate, parse_cells, scaling_ratios

    assert parse_cells("2") == [2]
    assert parse_cells("8,2,4") == [1, 2, 4, 8]  # one cell alone is the baseline
    for bad in ("0", "x", "", "1,-2"):
        with pytest.raises(PriqnError, match=f"--cells {bad}: expected"):
            parse_cells(bad)
    assert aggregate_rate([100.0, 80.0]) == pytest.approx(180.0)
    assert aggregate_rate([100.0, None]) is None
    assert scaling_ratios([100.0, 180.0, None]) == [1.0, 1.8, None]
    assert scaling_ratios([None, 5.0]) == [None, None]


def test_bench_sweep_cells_take_further_overrides(tmp_path: Path) -> None:
    import argparse

    from priqn.bench.sweep import _workers, configure_parser, parse_workers, train_command

    cmd = train_command(tmp_path, "c", 3, "iqn", "tjunction", 800, "cuda", ("learner.compile=off",))
    sets = [cmd[i + 1] for i, arg in enumerate(cmd) if arg == "--set"]
    assert sets[-1] == "learner.compile=off" and "replay.learning_starts=200" in sets
    assert cmd[cmd.index("--device") + 1] == "cuda"
    assert cmd[cmd.index("--preset") + 1] == "default"
    paper = train_command(tmp_path, "c", 0, "pr-iqn", "tjunction", 800, "cuda", preset="paper")
    assert paper[paper.index("--preset") + 1] == "paper"
    # Env workers per cell: the preset's, a number, or the cores split over a level's cells.
    assert parse_workers("") == [] and parse_workers("share") == []
    assert parse_workers("16,4,8") == [16, 4, 8]
    parser = argparse.ArgumentParser()
    configure_parser(parser)
    assert _workers(parser.parse_args([]), 4, 16) == ()
    assert _workers(parser.parse_args(["--workers", "6"]), 4, 16) == ("num_envs=6",)
    share = parser.parse_args(["--workers", "share"])
    assert [_workers(share, n, 16) for n in (1, 2, 4, 8, 32)] == [
        ("num_envs=16",), ("num_envs=8",), ("num_envs=4",), ("num_envs=2",), ("num_envs=1",)
    ]  # fmt: skip


def test_bench_sweep_steady_rate_leaves_the_start_out() -> None:
    """Episodes end at decisions 100, 400, 600, 1000 at 10, 12, 14, 18 s of wall time: the
    second half starts with the episode at 600 (>= 500), so the steady rate is
    (1000 - 600) / (18 - 14) = 100 decisions/s, while the whole run gave 1000 / 18 = 55.6."""
    from priqn.bench.sweep import steady_rate

    episodes = [(100, 10.0), (400, 12.0), (600, 14.0), (1000, 18.0)]
    assert steady_rate(episodes) == pytest.approx(100.0)
    assert steady_rate(episodes, from_fraction=0.0) == pytest.approx(900 / 8)
    assert steady_rate(episodes[:1]) is None  # one episode: no interval
    assert steady_rate([]) is None
