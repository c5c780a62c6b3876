"""A run's ``learning_curve.png``: drawn from its metrics.csv rows while it trains (on
the session's writer thread, :mod:`priqn.run.writer`) and by nothing else. It lives
with the run's files, not in :mod:`priqn.analysis`, so the training loop imports no
report code; it is not a report figure (90 dpi PNG only, no PDF, no meta.json)."""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

from priqn.io import atomic_write_bytes  # noqa: E402
from priqn.objectives import names_in_columns  # noqa: E402


def training_curve_figure(rows: Sequence[Mapping[str, Any]], title: str) -> plt.Figure:
    """A run's learning_curve.png: success rate, per-objective returns, loss, episode length
    from its metrics.csv rows (training episodes and in-training evaluations)."""
    df = pd.DataFrame(list(rows))
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), constrained_layout=True)
    fig.suptitle(title)
    if df.empty:
        for ax in axes.flat:
            ax.text(0.5, 0.5, "no finished episode yet", ha="center", transform=ax.transAxes)
    else:
        for col in (
            "step",
            "success",
            "collision",
            "off_road",
            "length",
            "loss",
            "return_weighted",
        ):
            df[col] = pd.to_numeric(df[col], errors="coerce")
        objectives = names_in_columns(list(df.columns))  # the run's env.objectives
        for o in objectives:
            df[f"return_{o}"] = pd.to_numeric(df[f"return_{o}"], errors="coerce")
        tr, ev = df[df["kind"] == "train"], df[df["kind"] == "eval"]
        win = max(1, min(50, len(tr) // 5 or 1))
        ax = axes[0, 0]
        if len(tr):
            ax.plot(
                tr["step"], tr["success"].rolling(win, min_periods=1).mean(), label="train success"
            )
            ax.plot(
                tr["step"],
                tr["collision"].rolling(win, min_periods=1).mean(),
                label="train collision",
            )
            ax.plot(
                tr["step"],
                tr["off_road"].rolling(win, min_periods=1).mean(),
                label="train off-road",
            )
        if len(ev):
            g = ev.groupby("step")[["success", "collision"]].mean()
            ax.plot(g.index, g["success"], "o-", label="eval success (hold-out)")
            ax.plot(g.index, g["collision"], "x--", label="eval collision (hold-out)")
        ax.set(
            xlabel="env decisions",
            ylabel="rate",
            ylim=(-0.02, 1.02),
            title=f"rolling {win} episodes",
        )
        ax.legend(fontsize=8)
        ax = axes[0, 1]
        for o in objectives:
            if len(tr):
                ax.plot(tr["step"], tr[f"return_{o}"].rolling(win, min_periods=1).mean(), label=o)
        ax.set(xlabel="env decisions", ylabel="episode return", title="train return per objective")
        ax.legend(fontsize=8)
        ax = axes[1, 0]
        if len(tr):
            ax.plot(tr["step"], tr["loss"], ".", ms=2)
        ax.set(xlabel="env decisions", ylabel="quantile Huber loss", title="loss (at episode end)")
        ax = axes[1, 1]
        if len(tr):
            ax.plot(tr["step"], tr["length"].rolling(win, min_periods=1).mean())
        ax.set(xlabel="env decisions", ylabel="decisions", title="episode length")
    return fig


def write_training_curve(rows: Sequence[Mapping[str, Any]], path: Path, title: str) -> None:
    """:func:`training_curve_figure` as a PNG at ``path`` (atomically)."""
    fig = training_curve_figure(rows, title)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
