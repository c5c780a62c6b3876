"""The one way reports write CSV text, Markdown tables and their numbers (priqn.analysis.render)."""

from __future__ import annotations

import math

import pandas as pd
import pytest

from priqn.analysis.artifacts import write_csv
from priqn.analysis.render import (
    csv_text,
    interval,
    markdown_table,
    percent,
    points,
    points_interval,
)


def test_markdown_table_by_hand() -> None:
    assert markdown_table(["a", "b"], [["1", "2"], ["x", "y"]]) == (
        "| a | b |\n|---|---|\n| 1 | 2 |\n| x | y |"
    )
    assert markdown_table(["Policy", "n", "rate"], [["IQN", "3", "0.5"]], "lrr") == (
        "| Policy | n | rate |\n|:--|--:|--:|\n| IQN | 3 | 0.5 |"
    )
    assert markdown_table(["only"], []) == "| only |\n|---|"
    with pytest.raises(ValueError, match="one letter per column"):
        markdown_table(["a", "b"], [], "l")


def test_number_formats_by_hand() -> None:
    # Shares as percentages, differences of shares in signed points, by hand.
    assert percent(0.1234) == "12.3 %"
    assert percent(0.125, 0) == "12 %"  # rounds half to even, as Python's format does
    assert percent(1.0) == "100.0 %"
    assert points(0.021) == "+2.1"
    assert points(-0.177) == "-17.7"
    assert points(0.0) == "+0.0"
    assert points(None) == points(math.nan) == "–"  # none: a one-seed row, no paper figure
    assert interval(-0.032, 0.01) == "[-3.2, +1.0]"
    assert points_interval(0.021, -0.032, 0.074) == "+2.1 [-3.2, +7.4]"


def test_csv_text_and_write_csv(tmp_path) -> None:
    frame = pd.DataFrame({"x": [0.1 + 0.2, 1.0], "name": ["a", "b"]})
    # 10 significant digits by default; \n line ends; no index.
    assert csv_text(frame) == "x,name\n0.3,a\n1,b\n"
    assert csv_text(frame, float_format="%.3f") == "x,name\n0.300,a\n1.000,b\n"
    assert csv_text(frame, float_format=None) == "x,name\n0.30000000000000004,a\n1.0,b\n"
    write_csv(tmp_path / "t.csv", frame)
    assert (tmp_path / "t.csv").read_text() == csv_text(frame)
