"""`priqn bench env` smoke run: the CLI in a subprocess with a tiny budget."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path


def test_bench_env_cli_smoke(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    cmd = [sys.executable, "-m", "priqn.cli", "bench", "env", "--family", "tjunction",
           "--densities", "0.5", "--decisions", "10", "--vector-decisions", "10",
           "--max-workers", "1", "--obs-size", "32", "--repeats", "2", "--json", str(out)]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "env/floor" in proc.stdout and "risk us/step" in proc.stdout
    data = json.loads(out.read_text())
    row = data["density"]["0.5"]
    assert row["env"]["decisions"] == 10 and row["floor"]["decisions"] == 10
    assert row["ratio"] == row["floor"]["decisions_per_s"] / row["env"]["decisions_per_s"] > 0
    assert len(row["env_runs"]) == len(row["floor_runs"]) == len(row["ratio_runs"]) == 2
    assert row["ratio"] == min(row["ratio_runs"])  # the run with the median_low ratio
    env = row["env"]
    assert env["risk_us_per_step"] > 0 and env["parts_ms"]["risk_ms"] > 0
    # The sensors timed beside their reference on the same states, outputs equal.
    assert env["sensors_ref_ms"] > 0 and env["sensors_mismatches"] == 0
    assert env["parts_ms"]["sensors_ms"] > 0 and "median of pairs" in proc.stdout
    vs = env["sensors_vs_ref"]
    assert vs["mean_ratio"] > 0 and vs["median_ratio"] > 0 and vs["ref_median_ms"] > 0
    assert env["reset_ms"] > 0 and set(env["episode"]) == {
        "count",
        "decisions",
        "ms",
        "decisions_per_s",
    }
    assert data["vector"]["1"]["decisions"] == 10


def test_bench_env_rejects_bad_densities() -> None:
    cmd = [sys.executable, "-m", "priqn.cli", "bench", "env", "--densities", "half"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip() == (
        "priqn: error: --densities 'half': expected numbers like 0.5,0.75,1.0"
    )


def test_vs_highway_measures_both_in_one_command(tmp_path: Path) -> None:
    import pytest

    pytest.importorskip("highway_env", reason="optional: pip install 'priqn[bench]'")
    out = tmp_path / "bench.json"
    cmd = [sys.executable, "-m", "priqn.cli", "bench", "env", "--family", "tjunction",
           "--densities", "0.5", "--decisions", "10", "--max-workers", "0", "--obs-size", "32",
           "--repeats", "1", "--vs", "highway", "--json", str(out)]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    data = json.loads(out.read_text())
    for env_id in ("intersection-v0", "intersection-v2"):
        hw = data["highway"][env_id]
        assert hw["decisions"] == 10 and hw["decisions_per_s"] > 0 and hw["decision_s"] == 1.0
        assert env_id in proc.stdout
    assert "priqn density 0.5" in proc.stdout


def test_vs_highway_without_highway_env_is_one_line(monkeypatch) -> None:
    import argparse
    import importlib.util

    import pytest

    from priqn.bench import env as bench_env
    from priqn.errors import PriqnError

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util,
        "find_spec",
        lambda name, *a: None if name == "highway_env" else real(name, *a),
    )
    with pytest.raises(PriqnError, match=r"--vs highway: HighwayEnv is not installed; pip install"):
        bench_env._versus_highway({}, [], argparse.Namespace(decisions=10, seed=0))


def test_bench_train_bf16_times_each_agent_twice_in_one_command() -> None:
    from priqn.bench.train import updates_per_second

    rows = updates_per_second("default", ["iqn"], 4, 0.05, "cpu", rounds=1, bf16=True)
    assert [(r["agent"], r["bf16"]) for r in rows] == [("iqn", False), ("iqn", True)]
    assert all(r["updates_per_s"] > 0 and r["obs_px"] == 64 for r in rows)
    plain = updates_per_second("default", ["iqn"], 4, 0.05, "cpu", rounds=1)
    assert [r["bf16"] for r in plain] == [False]


def test_bench_train_twin_ratios_pair_each_case_with_its_one_switch() -> None:
    """A constructed bench: compiled / eager and nondeterministic / deterministic (CUDA) are
    each the twin's updates/s over the baseline's, one line per pair; on the CPU there is no
    nondeterministic case, even when asked."""
    from priqn.bench.train import twin_ratios, updates_per_second

    def case(agent: str, compile_: str, det: bool, ups: float) -> dict:
        return {"agent": agent, "bf16": False, "compile": compile_, "deterministic": det,
                "device": "cuda", "updates_per_s": ups, "ms_per_update": 1000 / ups}  # fmt: skip

    rows = [case("iqn", "off", True, 100.0), case("iqn", "off", False, 140.0),
            case("iqn", "on", True, 300.0), case("iqn", "on", False, 280.0),
            case("iqn", "graphs", True, 250.0)]  # fmt: skip
    assert twin_ratios(rows) == [
        "iqn: on / eager on cuda: 3.00x updates/s (10.00 -> 3.33 ms/update)",
        "iqn: graphs / eager on cuda: 2.50x updates/s (10.00 -> 4.00 ms/update)",
        "iqn: nondeterministic / deterministic on cuda: 1.40x updates/s (10.00 -> 7.14 ms/update)",
        "iqn nondet: on / eager on cuda: 2.00x updates/s (7.14 -> 3.57 ms/update)",
        "iqn on: nondeterministic / deterministic on cuda: 0.93x updates/s (3.33 -> 3.57 ms/update)",
    ]
    assert twin_ratios(rows[:1]) == []
    read = dict(case("iqn", "off", True, 80.0), read_each=True)  # a host sync per update
    assert twin_ratios([rows[0], read]) == [
        "iqn read: at log time / every update on cuda: 1.25x updates/s (12.50 -> 10.00 ms/update)"
    ]
    cpu = updates_per_second("default", ["iqn"], 4, 0.05, "cpu", rounds=1, nondeterministic=True)
    assert [(r["agent"], r["deterministic"]) for r in cpu] == [("iqn", False)]


def test_bench_counts_sensor_mismatches_and_keeps_the_reference_out_of_the_step() -> None:
    """The wrapper that times the reference sensors beside the new ones notices a difference."""
    import numpy as np

    from priqn.bench.env import _with_reference
    from priqn.env.geometry import Boxes, MapRaster
    from priqn.env.sensors import SensorConfig, Sensors, synthetic_crossroads

    sensors = Sensors(SensorConfig(size_px=32))
    polys, marks, _ = synthetic_crossroads()
    raster = MapRaster.from_roadmap_arrays(polys, marks, 0.2, sensors.cfg.marking_width_m)
    ego = Boxes.make([1.75, -15.0], np.pi / 2, 4.5, 1.8, 1.5)
    actors = Boxes.make([[1.75, -5.0]], np.pi / 2, 4.5, 1.8, 1.5)
    totals = {"sensors_ms": 0.0, "sensors_ref_ms": 0.0, "sensors_mismatches": 0,
              "excluded_s": 0.0, "sensors_pairs": []}  # fmt: skip
    observe = _with_reference(sensors, [True], totals)
    bev, lidar = observe(raster, ego, actors, np.zeros(1))
    assert totals["sensors_mismatches"] == 0 and len(totals["sensors_pairs"]) == 1
    assert totals["excluded_s"] >= totals["sensors_ref_ms"] > 0
    real = sensors.observe
    sensors.observe = lambda *a: (np.zeros_like(bev), lidar)  # a wrong BEV
    observe = _with_reference(sensors, [True], totals)
    observe(raster, ego, actors, np.zeros(1))
    assert totals["sensors_mismatches"] == 1
    sensors.observe = real
    outside = _with_reference(sensors, [False], totals)  # resets: not timed, not compared
    outside(raster, ego, actors, np.zeros(1))
    assert len(totals["sensors_pairs"]) == 2


def test_bench_env_without_the_reference_sensors(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    cmd = [sys.executable, "-m", "priqn.cli", "bench", "env", "--family", "tjunction",
           "--densities", "0.5", "--decisions", "10", "--max-workers", "0", "--obs-size", "32",
           "--repeats", "1", "--no-sensors-ref", "--sensors", "numpy", "--json", str(out)]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    data = json.loads(out.read_text())
    assert data["config"]["sensors"] == "numpy" and "sensors=numpy" in proc.stdout
    env = data["density"]["0.5"]["env"]
    assert env["sensors_ref_ms"] == 0 and env["parts_ms"]["sensors_ms"] > 0
    assert "(not timed)" in proc.stdout


def test_bench_train_replay_storage_times_each_storage_against_host() -> None:
    """``--replay-storage``: every agent samples and learns from the same full buffer in
    each storage, host first; each other storage's line is its rates over host's."""
    from priqn.bench.feed import feed_rates, ratio_lines

    rows = feed_rates("default", ["iqn"], ("host", "device"), 4, 0.05, "cpu", 400, rounds=1)
    assert [(r["agent"], r["storage"]) for r in rows] == [("iqn", "host"), ("iqn", "device")]
    assert all(r["samples_per_s"] > 0 and r["updates_per_s"] > 0 for r in rows)
    assert all(r["transitions"] == 400 and r["update_kind"] == "eager" for r in rows)

    def row(storage: str, samples: float, updates: float) -> dict:
        return {"agent": "iqn", "storage": storage, "device": "cuda",
                "samples_per_s": samples, "updates_per_s": updates}  # fmt: skip

    made = [row("host", 100.0, 50.0), row("device", 400.0, 80.0), row("pinned", 200.0, 60.0)]
    assert ratio_lines(made) == [
        "iqn: device / host on cuda: 4.00x samples/s (10.00 -> 2.50 ms/sample), "
        "1.60x updates/s with sampling (20.00 -> 12.50 ms/update)",
        "iqn: pinned / host on cuda: 2.00x samples/s (10.00 -> 5.00 ms/sample), "
        "1.20x updates/s with sampling (20.00 -> 16.67 ms/update)",
    ]
