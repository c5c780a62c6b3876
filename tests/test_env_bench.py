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
           "--max-workers", "1", "--obs-size", "32", "--json", str(out)]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "env/floor" in proc.stdout
    data = json.loads(out.read_text())
    row = data["density"]["0.5"]
    assert row["env"]["decisions"] == 10 and row["floor"]["decisions"] == 10
    assert row["ratio"] == row["floor"]["decisions_per_s"] / row["env"]["decisions_per_s"] > 0
    assert data["vector"]["1"]["decisions"] == 10


def test_bench_env_rejects_bad_densities() -> None:
    cmd = [sys.executable, "-m", "priqn.cli", "bench", "env", "--densities", "half"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip() == (
        "priqn: error: --densities 'half': expected numbers like 0.5,0.75,1.0"
    )
