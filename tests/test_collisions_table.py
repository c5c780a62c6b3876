"""The collisions-by-kind table (priqn/analysis/collisions.py) on four collisions by hand.

One row (IQN, `tm`), two seeds: at density 0.5 one `ego-cut-in` the NPC struck (could not
stop) and one `rear-end` the ego struck; at density 1.0 one `ego-standing-in-path` the NPC
struck (could have stopped) and one `obstacle`. So per density: 2 collisions, a half of
each of their kinds, the NPC struck 1 of 2, a TM-like NPC would have prevented 0 of 2 at
0.5 and 1 of 2 at 1.0; pooled ("all"): 4 collisions, 2 seeds, NPC struck 2 of 4,
preventable 1 of 4, each kind a quarter.
"""

from __future__ import annotations

import pandas as pd
import pytest

from priqn.analysis.artifacts import render
from priqn.analysis.collisions import collisions_report, kind_table


def _collisions() -> pd.DataFrame:
    rows = [
        (0, 0.5, "ego-cut-in", "npc", "False"),
        (1, 0.5, "rear-end", "ego", ""),
        (0, 1.0, "ego-standing-in-path", "npc", "True"),
        (1, 1.0, "obstacle", "ego", ""),
    ]
    return pd.DataFrame(
        [
            {"cell": f"iqn__seed{seed}", "traffic": "tm", "label": "IQN", "train_seed": seed,
             "density": density, "collision_kind": kind, "collision_striker": striker,
             "collision_tm_would_prevent": prevent, "replayed_collision": True}
            for seed, density, kind, striker, prevent in rows
        ]
    )  # fmt: skip


def test_shares_per_density_and_pooled_by_hand() -> None:
    table = kind_table(_collisions()).set_index("density")
    assert list(table.index) == [0.5, 1.0, "all"]
    assert table.loc[0.5, "collisions"] == 2 and table.loc["all", "collisions"] == 4
    assert table.loc["all", "seeds"] == 2
    assert table.loc[0.5, "ego-cut-in"] == 0.5 and table.loc[0.5, "rear-end"] == 0.5
    assert table.loc[0.5, "tm_would_prevent"] == 0.0
    assert table.loc[1.0, "tm_would_prevent"] == 0.5
    assert table.loc["all", "npc_struck"] == 0.5
    assert table.loc["all", "tm_would_prevent"] == pytest.approx(0.25)
    assert table.loc["all", "obstacle"] == pytest.approx(0.25)


def test_the_report_prints_the_pooled_row(tmp_path) -> None:
    text = render(
        tmp_path / "r", collisions_report(_collisions(), "priqn mechanism x --collisions")
    ).read_text()
    assert "| tm | IQN | all | 4 | 2 |" in text
    assert "| tm | IQN | 1 | 2 | 2 |" in text


def test_a_replay_under_other_traffic_reports_what_it_prevented(tmp_path) -> None:
    # The four collisions replayed under `tm-strict`: the cut-in and the obstacle collide
    # again, the rear-end and the standing ego do not. So 2 of 4 prevented (50 %), and the
    # kinds table describes the 2 that still collide: one at each density.
    frame = _collisions()
    frame.insert(2, "replay_traffic", "tm-strict")
    frame["replayed_collision"] = [True, False, False, True]
    text = render(tmp_path / "r", collisions_report(frame, "cmd", "tm-strict")).read_text()
    assert "| tm | IQN | 4 | 2 | 50 % |" in text
    assert "2 of 4 still end in a collision" in text
    assert "| tm | IQN | all | 2 | 2 |" in text
    prevented = pd.read_csv(tmp_path / "r" / "tables" / "prevented.csv")
    assert prevented.loc[0, "prevented"] == 0.5
    # None collides again: the report says so, without a kinds table.
    frame["replayed_collision"] = False
    text = render(tmp_path / "r2", collisions_report(frame, "cmd", "tm-strict")).read_text()
    assert "0 of 4 still end in a collision" in text and "| tm | IQN | all |" not in text
