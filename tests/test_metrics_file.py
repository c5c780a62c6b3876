"""metrics.csv appended to as it grows (:class:`priqn.run.metrics.MetricsFile`) gives the bytes
the whole rewrite (:func:`write_metrics`) gives, also across a resume and a torn row."""

from __future__ import annotations

from pathlib import Path

from priqn.run.metrics import METRIC_COLUMNS, MetricsFile, read_metrics, write_metrics


def _row(step: int, kind: str = "train") -> dict:
    return {"kind": kind, "step": step, "episode": step // 10, "wall_s": step / 7, "loss": "",
            "return_safety": -0.5, "success": step % 2, "net": "tjunction/t_00",
            "command": "left, then \"right\""}  # fmt: skip


def test_appending_gives_the_bytes_of_the_rewrite(tmp_path: Path) -> None:
    rows: list[dict] = []
    file = MetricsFile(tmp_path / "metrics.csv", METRIC_COLUMNS, rows)
    assert not file.path.exists()  # nothing before the first flush, as before
    file.flush(rows)  # no rows yet: the header alone, as the rewrite writes it
    write_metrics(tmp_path / "whole.csv", rows, METRIC_COLUMNS)
    assert file.path.read_bytes() == (tmp_path / "whole.csv").read_bytes()
    for batch in ([10, 20], [], [30], [40, 50, 60]):
        rows += [_row(s) for s in batch]
        file.flush(rows)
        write_metrics(tmp_path / "whole.csv", rows, METRIC_COLUMNS)
        assert file.path.read_bytes() == (tmp_path / "whole.csv").read_bytes()
    assert file.written == 6


def test_a_resume_truncates_to_its_checkpoint_then_appends(tmp_path: Path) -> None:
    path = tmp_path / "metrics.csv"
    write_metrics(path, [_row(s) for s in (10, 20, 30, 40)], METRIC_COLUMNS)
    kept = read_metrics(path, max_step=20)  # the checkpoint was at 20
    file = MetricsFile(path, METRIC_COLUMNS, kept)
    assert [r["step"] for r in read_metrics(path)] == ["10", "20"]  # truncated at once
    rows = kept + [_row(30), _row(35, "eval")]
    file.flush(rows)
    write_metrics(tmp_path / "whole.csv", rows, METRIC_COLUMNS)
    assert path.read_bytes() == (tmp_path / "whole.csv").read_bytes()


def test_a_row_torn_by_a_crash_ends_the_rows_read(tmp_path: Path) -> None:
    path = tmp_path / "metrics.csv"
    write_metrics(path, [_row(s) for s in (10, 20, 30)], METRIC_COLUMNS)
    text = path.read_text(encoding="utf-8")
    path.write_text(text + text.splitlines()[-1][:12], encoding="utf-8")  # "train,3" of a 4th
    assert [r["step"] for r in read_metrics(path)] == ["10", "20", "30"]
    assert [r["step"] for r in read_metrics(path, max_step=1000)] == ["10", "20", "30"]


def test_the_bench_writes_the_same_file_both_ways() -> None:
    from priqn.bench.loop import metrics_writes

    m = metrics_writes(decisions=5000, episode_length=100)
    assert m["same"] and m["writes"] == 5 and m["rows"] == 50
    assert m["rewrite_s"] > 0 and m["append_s"] > 0
