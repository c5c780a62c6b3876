"""The horizon (``priqn report RUNS --horizon 200,600``, descriptive): the same policies on the
same scenes at longer evaluation-only episode limits (``priqn evaluate --max-episode-steps
N``, ``eval-limit<N>/``), beside their own evaluation (``eval/``).

The observation holds no clock, so a longer limit changes no decision of a policy: an
episode that ended before the shorter limit ends the same way, and one the shorter limit
cut goes on. Two tables:

* **mix** — per row (policy label), limit and density: the share of episodes ending in each
  outcome, averaged over the row's training seeds (each seed's share first), and the
  seed count; over the scenes each run played at every limit (:func:`common_scenes`);
* **where the timeouts go** — per row and longer limit: of the episodes the row's own limit
  cut (timeout), the share that end in each outcome at the longer limit, matched scene by
  scene (evaluation run, net, density, episode). Also the share of all episodes whose
  outcome differs: anything but the timeouts would mean the limit changed more than the cut.

:func:`horizon_report` (kind ``horizon``) builds them as sections, rendered like every
report's (:func:`priqn.analysis.artifacts.render`): ``horizon.md``,
``tables/horizon_mix.csv``, ``tables/horizon_timeouts.csv`` and ``meta.json``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from priqn.analysis.load import find_run_dirs, read_episodes
from priqn.analysis.mixes import common_scenes, mix_table, paired_outcomes
from priqn.analysis.render import markdown_table, percent
from priqn.analysis.sections import Report, Section
from priqn.errors import PriqnError
from priqn.evaluation.protocol import LIMIT_PREFIX
from priqn.io import read_json
from priqn.objectives import OUTCOMES
from priqn.run.evaluations import evaluation_dir, recorded_eval_status
from priqn.run.folder import RunFolder, Status


def limit_episodes(runs: str | Path, limits: Sequence[int]) -> pd.DataFrame:
    """Every run's episodes at its own limit and at each of ``limits``, one frame with a
    ``limit`` column (decisions) and the outcome of each episode; a run lacking a complete
    ``eval-limit<N>/`` is a one-line error naming the command that makes it."""
    frames = []
    for run in find_run_dirs(runs):
        folder = RunFolder(run)
        own = int(read_json(folder.eval_dir / RunFolder.META)["env_config"]["max_episode_steps"])
        for limit, name in ((own, ""), *((n, f"{LIMIT_PREFIX}{n}") for n in limits)):
            eval_dir = evaluation_dir(folder, name)
            if recorded_eval_status(folder, name) != Status.COMPLETE:
                raise PriqnError(
                    f"{eval_dir}: no complete evaluation; run 'priqn evaluate {run}"
                    + (f" --max-episode-steps {limit}'" if name else "'")
                )
            frame = read_episodes(eval_dir)
            frame["limit"] = limit
            frame["own_limit"] = own
            frames.append(frame)
    if not frames:
        raise PriqnError(f"{runs}: no evaluated runs")
    return common_scenes(pd.concat(frames, ignore_index=True), "limit")


def timeout_table(episodes: pd.DataFrame) -> pd.DataFrame:
    """Per row and longer limit: the episodes its own limit cut, what they end in at the
    longer limit (shares), and the share of all episodes whose outcome changed otherwise."""
    at_own = episodes["limit"] == episodes["own_limit"]
    rows = []
    for (label, limit), longer in episodes[~at_own].groupby(["label", "limit"]):
        joined = paired_outcomes(episodes[at_own], longer)
        cut = joined[joined["outcome_base"] == "timeout"]
        other = joined[joined["outcome_base"] != "timeout"]
        row: dict[str, Any] = {"label": label, "limit": int(limit), "episodes": len(joined)}
        row["cut_at_own_limit"] = len(cut) / max(len(joined), 1)
        for o in OUTCOMES:
            row[f"cut_then_{o}"] = float((cut["outcome"] == o).mean()) if len(cut) else 0.0
        row["others_changed"] = (
            float((other["outcome"] != other["outcome_base"]).mean()) if len(other) else 0.0
        )
        rows.append(row)
    return pd.DataFrame(rows)


def horizon_report(
    runs: str | Path,
    limits: Sequence[int],
    command: str,
    experiment: str | None = None,
) -> Report:
    """The horizon report of ``runs`` (kind ``horizon``): ``horizon.md`` with the mix
    (``tables/horizon_mix.csv``) and where the timeouts go (``tables/horizon_timeouts.csv``);
    ``command`` and ``experiment`` (the name of the experiment whose runs these are, or
    None) go to ``meta.json``. Reads the runs, writes nothing (render it with
    :func:`priqn.analysis.artifacts.render`)."""
    if not limits or any(n <= 0 for n in limits):
        raise PriqnError(f"--horizon {list(limits)}: expected limits > 0, e.g. 200,600")
    episodes = limit_episodes(runs, limits)
    mix, moved = mix_table(episodes, "limit"), timeout_table(episodes)
    own = sorted(set(episodes["own_limit"]))
    sections = [
        _title_section(runs, limits, own, command),
        _mix_section(mix),
        _timeouts_section(moved),
    ]
    fields = {
        "limits": [int(n) for n in limits],
        "own_limits": [int(n) for n in own],
        "runs": sorted(set(episodes["run"])),
    }
    return Report("horizon", "horizon.md", sections, command, experiment, fields)


def _title_section(
    runs: str | Path, limits: Sequence[int], own: Sequence[int], command: str
) -> Section:
    return Section(
        [
            f"# The horizon: {Path(runs).name} at longer evaluation-only limits (descriptive)",
            "",
            f"Made by `{command}`. The runs' own limit: {', '.join(map(str, own))} decisions; "
            f"the same scenes at {', '.join(map(str, limits))}. The observation holds no clock, "
            "so the policies decide as before; only where an episode is cut changes.",
            "",
        ]
    )


def _mix_section(mix: pd.DataFrame) -> Section:
    """The mix per row, limit and density (:func:`mix_table`)."""
    table = markdown_table(
        ["row", "limit", "density", "seeds", *OUTCOMES],
        [
            [
                r.label,
                str(r.limit),
                f"{r.density:g}",
                str(r.seeds),
                *(percent(getattr(r, o)) for o in OUTCOMES),
            ]
            for r in mix.itertuples()
        ],
    )
    heading = "## Outcome mix per row, limit and density (mean over training seeds)"
    return Section([heading, "", table, ""], tables={"horizon_mix": mix})


def _timeouts_section(moved: pd.DataFrame) -> Section:
    """Where the timeouts of the runs' own limits go (:func:`timeout_table`)."""
    table = markdown_table(
        [
            "row",
            "limit",
            "episodes",
            "cut at own limit",
            *(f"cut, then {o}" for o in OUTCOMES),
            "others changed",
        ],
        [
            [
                r.label,
                str(r.limit),
                str(r.episodes),
                percent(r.cut_at_own_limit),
                *(percent(getattr(r, f"cut_then_{o}")) for o in OUTCOMES),
                percent(r.others_changed),
            ]
            for r in moved.itertuples()
        ],
    )
    return Section(
        [
            "## Where the timeouts go",
            "",
            "Of the episodes each row's own limit cut, the share that end in each outcome at the "
            "longer limit (the same scenes); the last column: the other episodes whose outcome "
            "changed (0 unless something besides the limit differs).",
            "",
            table,
            "",
        ],
        tables={"horizon_timeouts": moved},
    )
