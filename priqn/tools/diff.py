"""``priqn diff RUN_A RUN_B``: are two runs the same training, bit for bit?

The question behind reusing a cell trained at another commit, counting a long run's
snapshot as a short run of its seed, or checking that a refactor left training alone.
Two runs are the same training up to ``N`` decisions when

- **config**: their resolved configurations differ at most in the budget (seed equal;
  :func:`priqn.experiment.policy_difference`, which also asks ε to decay over the same
  decisions);
- **metrics**: their ``metrics.csv`` rows up to decision ``N`` are equal in every column
  but ``wall_s``;
- **weights**: they hold the same policy at ``N`` (``policy.pt`` of a run whose budget is
  ``N``, else the snapshot it kept there, ``checkpoint.keep_at``): the same SHA-256, which
  meta.json records even where the snapshot's weights are not on disk;
- **episodes** (where both evaluated that policy): the same ``episodes.csv`` rows, all
  columns but the run's name.

``N`` is the smaller budget unless ``--upto`` says otherwise. Exit status
(:func:`exit_status`): 0 when config, metrics and weights were all compared and are equal
(and the episodes, where both evaluated), 1 when a part differs (each part names its first
difference), 2 on bad input, 3 when nothing differs but config, metrics or weights could
not be compared (a run short of ``N``, a policy not kept there): not proven the same.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from priqn.errors import PriqnError
from priqn.io import sha256_file
from priqn.run.evaluations import evaluation_dir, recorded_eval_status, snapshot_evaluation
from priqn.run.folder import RunFolder, Status
from priqn.run.metrics import read_metrics

IGNORED_METRICS = ("wall_s",)
"""metrics.csv columns that differ between identical trainings (wall-clock time)."""

IGNORED_EPISODES = ("run",)
"""episodes.csv columns that name the run rather than describe its episodes."""

REQUIRED_PARTS = ("config", "metrics", "weights")
"""The parts that must be compared (and equal) to call two runs the same training; the
episodes are compared where both runs evaluated the policy."""

SAME, DIFFERENT, NOT_COMPARED = 0, 1, 3
"""Exit statuses of ``priqn diff`` (2 is the CLI's own, a bad input)."""


@dataclass(frozen=True)
class Part:
    """One part of the comparison."""

    name: str
    """``config``, ``metrics``, ``weights`` or ``episodes``."""
    same: bool | None
    """Equal, different, or None when it could not be compared (the text says why)."""
    text: str
    """What was compared and, where it differs, the first difference."""


@dataclass(frozen=True)
class Kept:
    """The policy a run holds at a budget."""

    file: str
    """Its file, relative to the run folder (``policy.pt``, ``snapshots/policy-at<N>.pt``)."""
    sha256: str
    """SHA-256 of the file's bytes, or meta.json's record of it where the file is not on disk."""
    path: Path | None
    """The file, None where only its SHA-256 is recorded (snapshot weights not committed)."""
    evaluation: str
    """The evaluation of this policy by name: "" (``eval/``) or ``at<N>``."""


def diff_runs(a: RunFolder, b: RunFolder, upto: int | None = None) -> tuple[int, list[Part]]:
    """``(N, parts)``: the runs compared up to ``N`` decisions (``upto``, else the smaller
    budget), part by part."""
    cfg_a, cfg_b = a.config(), b.config()
    budget = min(cfg_a.total_steps, cfg_b.total_steps)
    if upto is None:
        upto = budget
    elif not 0 < upto <= budget:
        raise PriqnError(f"--upto {upto}: expected 1 to {budget:,}, the smaller run's budget")
    kept = (kept_policy(a, cfg_a.total_steps, upto), kept_policy(b, cfg_b.total_steps, upto))
    parts = [
        _config_part(cfg_a, cfg_b),
        _metrics_part(a, b, upto),
        _weights_part(kept, upto),
        _episodes_part(a, b, kept, upto),
    ]
    return upto, parts


def kept_policy(folder: RunFolder, total_steps: int, budget: int) -> Kept | None:
    """The policy ``folder`` holds at ``budget`` decisions: ``policy.pt`` if that is its
    finished budget, else the snapshot meta.json records; None if it keeps none there."""
    if budget == total_steps and folder.recorded_status() == Status.COMPLETE:
        path = folder.policy_path
        if path.is_file():
            return Kept(path.name, sha256_file(path), path, "")
    entry = (folder.meta().get("snapshots") or {}).get(str(budget))
    if not entry:
        return None
    path = folder.path / entry["file"]
    if path.is_file():  # the bytes themselves where they are there
        return Kept(entry["file"], sha256_file(path), path, snapshot_evaluation(budget))
    return Kept(entry["file"], entry["sha256"], None, snapshot_evaluation(budget))


def _config_part(cfg_a: Any, cfg_b: Any) -> Part:
    from priqn.experiment import policy_difference

    if cfg_a.seed != cfg_b.seed:
        return Part("config", False, f"seed is {cfg_b.seed}, not {cfg_a.seed}")
    why = policy_difference(cfg_a, cfg_b)
    if why is not None:
        return Part("config", False, why)
    budgets = f"{cfg_a.total_steps:,} / {cfg_b.total_steps:,} decisions"
    same = "the same" if cfg_a.total_steps == cfg_b.total_steps else "the same but for the budget"
    return Part("config", True, f"{same} ({budgets}), seed {cfg_a.seed}")


def _rows(rows: list[dict[str, Any]], ignored: tuple[str, ...]) -> list[dict[str, Any]]:
    return [{k: v for k, v in r.items() if k not in ignored} for r in rows]


def _first_difference(
    rows_a: list[dict[str, Any]], rows_b: list[dict[str, Any]], what: str
) -> str | None:
    """Where two row lists first differ, in words; None if equal."""
    for i, (x, y) in enumerate(zip(rows_a, rows_b, strict=False)):
        if x != y:
            key = next(k for k in (*x, *y) if x.get(k) != y.get(k))
            where = ", ".join(f"{k} {x[k]}" for k in ("kind", "step", "net", "episode") if k in x)
            return f"{what} row {i + 1} ({where}): {key} is {y.get(key)!r}, not {x.get(key)!r}"
    if len(rows_a) != len(rows_b):
        return f"{len(rows_a):,} {what} rows against {len(rows_b):,}"
    return None


def _metrics_part(a: RunFolder, b: RunFolder, upto: int) -> Part:
    rows_a, rows_b = (_rows(read_metrics(f.metrics_path, upto), IGNORED_METRICS) for f in (a, b))
    if not rows_a and not rows_b:
        return Part("metrics", None, "neither run has logged a row yet")
    short = [(w, f) for w, f in (("A", a), ("B", b)) if f.trained_to() < upto]
    if short:  # still training (or stopped) short of N: compare as far as both have logged
        n = min(len(rows_a), len(rows_b))
        difference = _first_difference(rows_a[:n], rows_b[:n], "metrics.csv")
        if difference is not None:
            return Part("metrics", False, difference)
        which, folder = short[0]
        return Part(
            "metrics",
            None,
            f"{n:,} rows identical as far as both have logged; {which} has trained "
            f"{folder.trained_to():,} of the {upto:,} decisions",
        )
    difference = _first_difference(rows_a, rows_b, "metrics.csv")
    if difference is not None:
        return Part("metrics", False, difference)
    return Part(
        "metrics",
        True,
        f"{len(rows_a):,} rows up to decision {upto:,} identical "
        f"(every column but {', '.join(IGNORED_METRICS)})",
    )


def _weights_part(kept: tuple[Kept | None, Kept | None], upto: int) -> Part:
    ka, kb = kept
    if ka is None or kb is None:
        which = "A" if ka is None else "B"
        return Part("weights", None, f"{which} keeps no policy at {upto:,} decisions")
    files = f"{ka.file} / {kb.file}"
    if ka.sha256 == kb.sha256:
        return Part("weights", True, f"identical ({files}, SHA-256 {ka.sha256[:12]}…)")
    if ka.path is None or kb.path is None:
        return Part("weights", False, f"SHA-256 differ ({files}); weights not on disk to compare")
    differing = _differing_tensors(ka.path, kb.path)
    if not differing:
        return Part(
            "weights",
            True,
            f"the same policy, files differ in bytes ({files}: another file format or torch)",
        )
    return Part(
        "weights",
        False,
        f"{len(differing)} part(s) of the policy differ ({files}), first {differing[0]}",
    )


def _differing_tensors(path_a: Path, path_b: Path) -> list[str]:
    """Names of the policy's parts that differ between two policy files: the online
    network's tensors, the agent's learned state (nested entries as ``agent.a.b``), the
    observation shapes, action count, step and objectives (:class:`PolicyState`)."""
    import dataclasses

    from priqn.run.checkpoint import load_policy_state

    sa, sb = load_policy_state(path_a), load_policy_state(path_b)
    la, lb = (dict(_leaves(dataclasses.asdict(x))) for x in (sa, sb))
    return [k for k in sorted(set(la) | set(lb)) if not _equal(la.get(k), lb.get(k))]


def _leaves(value: Any, prefix: str = "") -> Any:
    """``(dotted name, leaf)`` of a nested dict of tensors and plain values."""
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _leaves(item, f"{prefix}{key}.")
    else:
        yield prefix.rstrip("."), value


def _equal(x: Any, y: Any) -> bool:
    import torch

    if isinstance(x, torch.Tensor) or isinstance(y, torch.Tensor):
        return isinstance(x, torch.Tensor) and isinstance(y, torch.Tensor) and torch.equal(x, y)
    return bool(x == y)


def _episodes_part(
    a: RunFolder, b: RunFolder, kept: tuple[Kept | None, Kept | None], upto: int
) -> Part:
    if kept[0] is None or kept[1] is None:
        return Part("episodes", None, f"no policy at {upto:,} decisions to compare")
    dirs = []
    for folder, k, which in ((a, kept[0], "A"), (b, kept[1], "B")):
        if recorded_eval_status(folder, k.evaluation) != Status.COMPLETE:
            name = evaluation_dir(folder, k.evaluation).name
            return Part("episodes", None, f"{which} has no complete evaluation {name}/")
        dirs.append(evaluation_dir(folder, k.evaluation))
    from priqn.analysis.load import read_episodes

    rows_a, rows_b = (
        _rows(read_episodes(d, text=True).to_dict("records"), IGNORED_EPISODES) for d in dirs
    )
    difference = _first_difference(rows_a, rows_b, "episodes.csv")
    if difference is not None:
        return Part("episodes", False, difference)
    names = f"{dirs[0].name}/ / {dirs[1].name}/"
    return Part("episodes", True, f"{len(rows_a):,} episodes identical ({names})")


# --------------------------------------------------------------------------- CLI


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Are two runs the same training, bit for bit? Config (but for the budget), "
        "metrics.csv rows, the policy's weights and, where both evaluated it, the "
        "episodes, up to the smaller budget. Exit status 0 when config, metrics and weights "
        "were compared and are equal (episodes too, where both evaluated), 1 when a part "
        "differs, 2 on bad input, 3 when a part could not be compared and none differs."
    )
    parser.add_argument("run_a", metavar="RUN_A", help="a run folder")
    parser.add_argument("run_b", metavar="RUN_B", help="another run folder")
    parser.add_argument(
        "--upto",
        type=int,
        default=None,
        metavar="N",
        help="compare up to N decisions (default: the smaller budget); "
        "weights and episodes need a policy kept at N",
    )


def run(args: argparse.Namespace) -> int:
    a, b = RunFolder(args.run_a), RunFolder(args.run_b)
    upto, parts = diff_runs(a, b, args.upto)
    print(f"A {a.path} (code {str(a.meta().get('git_sha'))[:12]})")
    print(f"B {b.path} (code {str(b.meta().get('git_sha'))[:12]})")
    for part in parts:
        mark = {True: "same", False: "DIFFERS", None: "not compared"}[part.same]
        print(f"  {part.name:<9} {mark:<13} {part.text}")
    print(f"up to {upto:,} decisions, {verdict(parts)}")
    return exit_status(parts)


def exit_status(parts: list[Part]) -> int:
    """:data:`DIFFERENT` when a part differs, else :data:`NOT_COMPARED` when one of
    :data:`REQUIRED_PARTS` could not be compared, else :data:`SAME`."""
    if any(p.same is False for p in parts):
        return DIFFERENT
    if any(p.same is None for p in parts if p.name in REQUIRED_PARTS):
        return NOT_COMPARED
    return SAME


def verdict(parts: list[Part]) -> str:
    """The comparison in words: the runs differ, are the same training (config, metrics
    and weights equal), or showed no difference in the parts that could be compared."""
    if any(p.same is False for p in parts):
        return "the runs differ"
    missing = [p.name for p in parts if p.same is None and p.name in REQUIRED_PARTS]
    if not missing:
        return "the runs are the same training"
    return (
        f"no difference in the parts compared, but not proven the same training "
        f"(not compared: {', '.join(missing)})"
    )
