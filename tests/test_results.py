"""Committed results: every report under docs/results/ regenerates byte for byte.

Each committed report records the command that made it (``meta.json`` ``command``);
re-running that command on the committed run folders under ``results/`` must give the
same files, so a reader can trust that the tables and figures come from those runs.
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
RESULTS = REPO / "docs" / "results"
REPORTS = sorted(p.parent for p in RESULTS.glob("**/meta.json"))


@pytest.mark.slow
@pytest.mark.parametrize("report", REPORTS, ids=[str(p.relative_to(RESULTS)) for p in REPORTS])
def test_committed_report_regenerates_byte_identically(report: Path, tmp_path: Path) -> None:
    command = json.loads((report / "meta.json").read_text())["command"]
    argv = shlex.split(command)
    assert argv[:2] in (["priqn", "report"], ["priqn", "mechanism"]), command
    # The same relative paths in a scratch folder: results/<grid> points at the committed
    # runs (every grid: a sequential experiment also reads its prior grid's cells, a
    # mechanism report cells of several grids), the report goes to docs/results/<name>
    # there (so the recorded command matches).
    (tmp_path / "results").mkdir()
    for grid in (REPO / "results").iterdir():
        if grid.is_dir():
            (tmp_path / "results" / grid.name).symlink_to(grid, target_is_directory=True)
    env = dict(os.environ, MPLBACKEND="Agg")
    proc = subprocess.run(
        [sys.executable, "-m", "priqn.cli", *argv[1:]],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        # A mechanism report replays its cells when ~/.cache holds no rows of them (about
        # 20 min for the 40 paper-point cells on 2 cores); a report reads run folders only.
        timeout=3600 if argv[1] == "mechanism" else 900,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    fresh = tmp_path / report.relative_to(REPO)
    committed = sorted(p.relative_to(report) for p in report.rglob("*") if p.is_file())
    assert sorted(p.relative_to(fresh) for p in fresh.rglob("*") if p.is_file()) == committed
    differ = [str(p) for p in committed if (report / p).read_bytes() != (fresh / p).read_bytes()]
    assert not differ, f"regenerated files differ: {differ}"
