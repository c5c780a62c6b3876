"""Each sweep cell's thread limits come from its CPU share (issue 61) and are recorded."""

from __future__ import annotations

from pathlib import Path

from priqn.run.provenance import THREAD_VARIABLES, thread_limits
from priqn.sweep.process import thread_env
from priqn.sweep.scheduler import _spec_extra


def test_a_cell_gets_its_cpu_share_of_threads_unless_the_sweep_sets_them() -> None:
    assert _spec_extra("f", None, 1.0)["threads"] == 1
    assert _spec_extra("f", Path("x"), 4.0)["threads"] == 4
    assert _spec_extra("f", None, 0.5)["threads"] == 1  # at least one
    assert thread_env(2, {}) == dict.fromkeys(THREAD_VARIABLES, "2")
    # A limit in the sweep's own environment wins (it is not overwritten).
    assert "OMP_NUM_THREADS" not in thread_env(2, {"OMP_NUM_THREADS": "8"})


def test_meta_records_the_limits(monkeypatch) -> None:
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    limits = thread_limits()
    assert limits["OMP_NUM_THREADS"] == "3" and limits["MKL_NUM_THREADS"] is None
    assert isinstance(limits["torch"], int) and limits["torch"] >= 1
