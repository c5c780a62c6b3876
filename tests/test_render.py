"""The one way reports write CSV text and Markdown tables (priqn.analysis.render)."""

from __future__ import annotations

import pandas as pd
import pytest

from priqn.analysis.artifacts import write_csv
from priqn.analysis.render import csv_text, markdown_table


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


def test_csv_text_and_write_csv(tmp_path) -> None:
    frame = pd.DataFrame({"x": [0.1 + 0.2, 1.0], "name": ["a", "b"]})
    # 10 significant digits by default; \n line ends; no index.
    assert csv_text(frame) == "x,name\n0.3,a\n1,b\n"
    assert csv_text(frame, float_format="%.3f") == "x,name\n0.300,a\n1.000,b\n"
    assert csv_text(frame, float_format=None) == "x,name\n0.30000000000000004,a\n1.0,b\n"
    write_csv(tmp_path / "t.csv", frame)
    assert (tmp_path / "t.csv").read_text() == csv_text(frame)
