"""Shared test helpers."""

from __future__ import annotations

import os

import torch

# Two cores: keep torch from oversubscribing when tests run beside SUMO workers.
torch.set_num_threads(1)
os.environ.setdefault("MPLBACKEND", "Agg")
