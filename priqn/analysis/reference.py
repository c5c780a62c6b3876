"""Reference drivers in a report: ``priqn report RUNS --reference DIR [--reference DIR ...]``.

A reference folder is what ``priqn evaluate --reference sumo|random --out DIR`` writes: its
``eval/`` (and any ``eval-nets-<hash>/``) holds a reference driver's episodes on the same
scenes as the runs' (same protocol, same scene rule). :func:`load_references` reads them and
checks that they are comparable to the runs: the same hold-out set, the same evaluation
settings and the same env (bar what only a policy sees). The report shows them as extra
rows of Table II, the outcome breakdown and the generalisation tables, after the policies:
never ranked, never marked best / second, and never in the claims or rliable (those read
the runs' episodes only).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from priqn.analysis.load import EVAL_SETTINGS, SORT_COLUMNS, Evaluation, RunInfo, read_evaluation
from priqn.config import config_differences, flatten
from priqn.errors import PriqnError
from priqn.evaluation.protocol import NETS_HASH_CHARS, NETS_PREFIX, recorded_env_config
from priqn.evaluation.reference import REFERENCES, SCENE_NEUTRAL_FIELDS
from priqn.io import read_json
from priqn.run.episodes import resolve_outcomes
from priqn.run.evaluations import evaluation_dir, recorded_eval_status
from priqn.run.folder import RunFolder, Status

ENV_NEUTRAL_FIELDS: frozenset[str] = SCENE_NEUTRAL_FIELDS | {"ego_driver"}
"""EnvConfig fields a reference's env may differ in from the runs' (who drives is the point)."""


@dataclasses.dataclass(frozen=True)
class References:
    """The reference drivers of a report."""

    episodes: pd.DataFrame
    """Their hold-out episodes (``EPISODE_COLUMNS``, one outcome each, sorted); empty if none."""
    runs: tuple[RunInfo, ...]
    """One per reference folder (name = the folder as given)."""
    by_nets: dict[str, pd.DataFrame]
    """Nets hash -> their episodes on those nets (only nets the runs were evaluated on)."""

    @property
    def labels(self) -> list[str]:
        """Their row labels, in the order of :data:`priqn.evaluation.reference.REFERENCES`."""
        return [r.label for r in self.runs]


def no_references() -> References:
    """A report without reference drivers."""
    return References(pd.DataFrame(), (), {})


def load_references(
    dirs: Sequence[str | Path], evaluation: Evaluation, groups: Sequence[Any] = ()
) -> References:
    """Read and check the reference folders ``dirs`` against the runs' ``evaluation``.

    Each must hold a complete reference evaluation (``DIR/eval/``) on the runs' hold-out set
    with the runs' evaluation settings and env; otherwise a one-line error naming the
    folder. For each of ``groups`` (:class:`~priqn.analysis.generalisation.NetsEvaluation`,
    the runs' evaluations on other nets) a complete ``DIR/eval-nets-<hash>/`` on the same
    nets is read too, and must have that group's settings.
    """
    from priqn.analysis.generalisation import GENERALISATION_SETTINGS
    from priqn.evaluation.reference import reference_label

    if not dirs:
        return no_references()
    frames, infos, by_nets = [], [], {}
    run_env = _runs_env(evaluation)
    for d in dirs:
        folder = RunFolder(d)
        if recorded_eval_status(folder) != Status.COMPLETE:
            raise PriqnError(
                f"{folder.path}: no complete reference evaluation in {folder.eval_dir.name}/; make "
                f"one with 'priqn evaluate --reference sumo --out {folder.path}' (the runs' settings)"
            )
        frame, info = read_evaluation(str(d), folder.path, folder.eval_dir, reference=True)
        if info.holdout_hash != evaluation.holdout_hash:
            raise PriqnError(
                f"{folder.path}: evaluated on another hold-out set than the runs (hash "
                f"{info.holdout_hash[:12]} vs {evaluation.holdout_hash[:12]}); re-evaluate it"
            )
        _check_settings(folder.path, info.eval_config, evaluation.eval_config, EVAL_SETTINGS)
        env = recorded_env_config(
            read_json(folder.eval_dir / RunFolder.META).get("env_config") or {}
        )
        # Keys one record lacks (written before the field existed) are not compared; the
        # traffic, with every default filled in (recorded_env_config), always is.
        only_one = {
            k for k in set(flatten(run_env)) ^ set(flatten(env)) if not k.startswith("traffic.")
        }
        ignore = ENV_NEUTRAL_FIELDS | only_one
        diff = config_differences(run_env, env, ignore=ignore) if run_env and env else []
        if diff:
            key, a, b = diff[0]
            raise PriqnError(
                f"{folder.path}: its env differs from the runs' ({key} {b!r} vs {a!r}); "
                f"evaluate it with 'priqn evaluate RUNS --reference ... --out {folder.path} --force'"
            )
        if info.label in {i.label for i in infos}:
            raise PriqnError(f"{folder.path}: a second {info.label!r}; give each driver once")
        frames.append(frame)
        infos.append(info)
        for group in groups:
            name = f"{NETS_PREFIX}{group.nets_hash[:NETS_HASH_CHARS]}"
            if recorded_eval_status(folder, name) != Status.COMPLETE:
                continue
            nets_frame, nets_info = read_evaluation(
                str(d), folder.path, evaluation_dir(folder, name), reference=True
            )
            if nets_info.holdout_hash != group.nets_hash:
                continue
            _check_settings(
                folder.path / name, nets_info.eval_config, group.eval_config,
                GENERALISATION_SETTINGS,
            )  # fmt: skip
            by_nets.setdefault(group.nets_hash, []).append((nets_frame, nets_info))
    order = [reference_label(name) for name in REFERENCES]
    infos.sort(key=lambda i: order.index(i.label) if i.label in order else len(order))
    episodes = resolve_outcomes(pd.concat(frames, ignore_index=True))
    nets = {
        h: _sorted(resolve_outcomes(pd.concat([f for f, _ in parts], ignore_index=True)))
        for h, parts in by_nets.items()
    }
    return References(_sorted(episodes), tuple(infos), nets)


def _sorted(episodes: pd.DataFrame) -> pd.DataFrame:
    """``episodes`` in the loader's canonical row order."""
    return episodes.sort_values(list(SORT_COLUMNS), kind="mergesort").reset_index(drop=True)


def _runs_env(evaluation: Evaluation) -> dict[str, Any]:
    """The env config recorded by the first run's evaluation ({} if none recorded)."""
    for info in evaluation.runs:
        meta = read_json(info.path / info.eval_dir / RunFolder.META)
        if meta.get("env_config"):
            return recorded_env_config(meta["env_config"])
    return {}


def _check_settings(
    where: Path, mine: dict[str, Any], runs: dict[str, Any], keys: Sequence[str]
) -> None:
    """One line naming ``where`` and the first of ``keys`` whose recorded setting differs."""
    for key in keys:
        if mine.get(key) != runs.get(key):
            raise PriqnError(
                f"{where}: evaluated with {key} {mine.get(key)!r}, the runs with "
                f"{runs.get(key)!r}; evaluate the reference with the runs' settings"
            )
