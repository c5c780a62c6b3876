"""``priqn sweep NAME --commit``: commit a grid's complete cells to git as they land.

A grid that outlasts a working session keeps its results in git, one small commit per
batch of finished cells (docs/sweeps.md): the files a complete cell leaves after
``.gitignore`` (config, meta, metrics, evaluation tables, ``policy.pt``; never
checkpoints or replay buffers). This finds the experiment's complete cells that git
reports as new or changed, stages exactly their folders and commits only those paths
(``git commit -- PATHS``), so other staged or unstaged work in the checkout stays out.
A running, trained-but-unevaluated or failed cell is never committed, nor is a cell of a
sequential design trained at a commit its ``code_commits`` does not list or from a
checkout with uncommitted changes.
"""

from __future__ import annotations

import subprocess
from dataclasses import dataclass
from pathlib import Path

from priqn.errors import PriqnError
from priqn.experiment import Experiment
from priqn.run.folder import RunFolder, Status
from priqn.sweep.cells import Cell, expand


def _git(root: Path, *args: str, ok: tuple[int, ...] = (0,)) -> subprocess.CompletedProcess:
    """Run ``git -C root ARGS``; a one-line PriqnError with git's complaint when it is
    missing or exits with a status outside ``ok``."""
    try:
        out = subprocess.run(
            ["git", "-C", str(root), *args], capture_output=True, text=True, timeout=60
        )
    except FileNotFoundError as e:
        raise PriqnError("--commit: git is not installed (expected `git` on PATH)") from e
    if out.returncode not in ok:
        why = (out.stderr.strip().splitlines() or ["no message"])[-1]
        raise PriqnError(f"--commit: git {args[0]} failed in {root}: {why}")
    return out


def _ignored(root: Path, path: Path) -> bool:
    """Whether git ignores ``path`` (``git check-ignore``: 0 ignored, 1 not)."""
    return _git(root, "check-ignore", "-q", "--", str(path), ok=(0, 1)).returncode == 0


def uncommitted_complete_cells(exp: Experiment) -> tuple[Path, list[Cell]]:
    """The git work tree holding ``exp.runs_dir`` and the complete cells in it that git
    reports as new or changed (ignored files do not count), in grid order."""
    runs = Path(exp.runs_dir).absolute()
    probe = next(p for p in (runs, *runs.parents) if p.is_dir())  # runs may not exist yet
    try:
        root = Path(_git(probe, "rev-parse", "--show-toplevel").stdout.strip())
    except PriqnError as e:
        raise PriqnError(
            f"--commit: {runs} is not inside a git work tree (expected a checkout to commit to)"
        ) from e
    if _ignored(root, runs.resolve()):
        raise PriqnError(
            f"--commit: {runs} is ignored by git (.gitignore); keep a grid you commit in a "
            "folder git tracks, e.g. --runs-dir results"
        )
    if not runs.is_dir():
        return root, []
    status = _git(
        root, "status", "--porcelain", "-z", "--untracked-files=all", "--", str(runs.resolve())
    ).stdout
    # -z: "XY PATH\0" entries (a rename adds its old path as one more entry), paths
    # relative to the work tree's root.
    changed = {root / entry[3:] for entry in status.split("\0") if len(entry) > 3}
    cells = []
    for cell in expand(exp):
        folder = cell.run_dir.resolve()
        touched = any(p == folder or folder in p.parents for p in changed)
        if touched and cell.state() == Status.COMPLETE:
            cells.append(cell)
    return root, cells


def commit_message(exp: Experiment, cells: list[Cell]) -> str:
    """One line naming the experiment, the cells, their budget and the code they ran."""
    shas = sorted({str(RunFolder(c.run_dir).meta().get("git_sha") or "?")[:12] for c in cells})
    names = ", ".join(c.run_dir.name for c in cells)
    return (
        f"{exp.experiment.name}: {len(cells)} cell(s) complete: {names} "
        f"({'/'.join(str(s) for s in sorted({c.steps or 0 for c in cells}))} decisions each; "
        f"code {', '.join(shas)}; "
        "priqn sweep --commit)"
    )


@dataclass(frozen=True)
class Committed:
    """What ``--commit`` did."""

    sha: str | None
    """The new commit (12 hex digits); None when there was nothing to commit."""
    cells: list[Cell]
    """The cells it holds."""
    refused: list[Cell]
    """Complete cells left uncommitted: trained at code the sequential design refuses
    (:meth:`~priqn.experiment.Experiment.code_problem`; its report refuses them too)."""


def commit_complete_cells(exp: Experiment) -> Committed:
    """Stage and commit every complete, uncommitted cell of ``exp`` in one commit."""
    root, found = uncommitted_complete_cells(exp)
    refused = [
        c
        for c in found
        if exp.code_problem(str(RunFolder(c.run_dir).meta().get("git_sha") or "")) is not None
    ]
    cells = [c for c in found if c not in refused]
    if not cells:
        return Committed(None, [], refused)
    paths = [str(c.run_dir.resolve().relative_to(root)) for c in cells]
    _git(root, "add", "--", *paths)
    _git(root, "commit", "--quiet", "-m", commit_message(exp, cells), "--", *paths)
    sha = _git(root, "rev-parse", "--short=12", "HEAD").stdout.strip()
    return Committed(sha, cells, refused)
