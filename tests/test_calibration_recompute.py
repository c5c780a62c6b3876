"""Every committed calibration report's distance table recomputes from the committed
episodes, without priqn's analysis code (issue 62).

For each report under docs/results/ whose meta.json is a calibration's, the rule is read
from its experiment file with tomllib and applied by hand with pandas: each hold-out
episode's outcome by the precedence collision > off-road > timeout > success; per cell
(row, training seed) and density the share of each outcome; per row the mean over its
seeds; the L1 distance to the target's mix over the 4 outcomes x densities. The table's
L1, per-outcome parts and seed counts must match to its 6 printed decimals, and the
chosen row must be the nearest.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pandas as pd
import pytest

REPO = Path(__file__).resolve().parent.parent
OUTCOMES = ["success", "collision", "off_road", "timeout"]
PRECEDENCE = ["collision", "off_road", "timeout", "success"]


def _calibration_reports() -> list[Path]:
    out = []
    for meta in sorted((REPO / "docs" / "results").rglob("meta.json")):
        record = json.loads(meta.read_text())
        if record.get("kind") == "calibration" or "distances" in record:
            out.append(meta.parent)
    return out


REPORTS = _calibration_reports()


def _outcome(episode: pd.Series) -> str:
    flags = {k: str(episode[k]).lower() == "true" for k in PRECEDENCE}
    return next(k for k in PRECEDENCE if flags[k])


def recompute(design: dict, runs: Path) -> pd.DataFrame:
    """The distance table of ``design`` (a parsed experiment file) from ``runs``."""
    cal, densities = design["calibration"], design["calibration"]["densities"]
    rows = []
    for policy in design["policy"]:
        for seed in design["experiment"]["seeds"]:
            cell = runs / f"{policy['name']}__seed{seed}"
            meta = cell / "meta.json"
            if not meta.exists() or json.loads(meta.read_text()).get("status") != "complete":
                continue
            episodes = pd.read_csv(cell / "eval" / "episodes.csv")
            if episodes.empty:
                continue
            episodes["outcome"] = episodes.apply(_outcome, axis=1)
            for density in densities:
                at = episodes[episodes["density"] == density]
                for o in OUTCOMES:
                    rows.append((policy["name"], seed, o, density, (at["outcome"] == o).mean()))
    cells = pd.DataFrame(rows, columns=["row", "seed", "outcome", "density", "rate"])
    mean = cells.groupby(["row", "outcome", "density"])["rate"].mean()
    table = []
    for row, frame in cells.groupby("row", sort=False):
        parts = {
            o: sum(abs(mean[(row, o, d)] - cal[o][i]) for i, d in enumerate(densities))
            for o in OUTCOMES
        }
        table.append(
            {"row": row, "l1": sum(parts.values()), "seeds": frame.seed.nunique(), **parts}
        )
    return pd.DataFrame(table)


@pytest.mark.skipif(not REPORTS, reason="no committed calibration report")
@pytest.mark.parametrize("report", REPORTS, ids=[p.name for p in REPORTS])
def test_the_distance_table_recomputes_from_the_committed_episodes(report: Path) -> None:
    meta = json.loads((report / "meta.json").read_text())
    [table_path] = list(report.rglob("distances.csv"))
    committed = pd.read_csv(table_path).set_index("row")
    name = meta.get("file") or f"{meta['experiment']}.toml"
    design = tomllib.loads((REPO / "priqn" / "data" / "experiments" / name).read_text())
    runs = REPO / design["experiment"].get("runs_dir", "results") / design["experiment"]["name"]
    fresh = recompute(design, runs).set_index("row")
    assert sorted(fresh.index) == sorted(committed.index)
    for row in committed.index:
        assert int(fresh.loc[row, "seeds"]) == int(committed.loc[row, "seeds"]), row
        for column in ["l1", *OUTCOMES]:
            assert fresh.loc[row, column] == pytest.approx(committed.loc[row, column], abs=1e-6), (
                row,
                column,
            )
    nearest = fresh["l1"].idxmin()
    assert meta["chosen"] == nearest
