"""Shared test helpers."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch
from fake_runs import IQN, PR, iqn_value, pr_value, write_run

# Two cores: keep torch from oversubscribing when tests run beside SUMO workers.
torch.set_num_threads(1)
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture()
def runs(tmp_path: Path) -> Path:
    """Two training seeds each of IQN and Pr-IQN, evaluated (``fake_runs``), under ``tmp_path/runs``."""
    root = tmp_path / "runs"
    for seed in (0, 1):
        write_run(root, f"iqn_s{seed}", "IQN", IQN, seed, iqn_value)
        write_run(root, f"pr_s{seed}", "Pr-IQN QD ✓ 0.2 ✗", PR, seed, pr_value)
    return root
