"""Where priqn finds its data and where it writes.

What ships with the package (found through :mod:`importlib.resources`, so it works from
a checkout, an editable install and an installed wheel alike) lives in ``priqn/data/``:

- ``scenarios/<family>.toml``: the scenario families;
- ``sumo_nets/<family>/``: the generated nets of each family, with ``manifest.json``;
- ``experiments/<name>.toml``: the experiment grids of ``priqn sweep``.

What priqn writes goes below the current working directory (or a ``--out``):
``runs/``, ``reports/``, and ``sumo_nets/`` for ``priqn scenario generate``. A folder of
the same name in the working directory is looked at *before* the shipped one, per
item: ``./scenarios/<family>.toml``, ``./sumo_nets/<family>/manifest.json`` and
``./experiments/<name>.toml`` override what ships, so what you generate or write is
what you train on.
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

PACKAGE_DIR: Path = Path(str(importlib.resources.files("priqn")))
"""The installed ``priqn`` package folder."""

DATA_DIR: Path = PACKAGE_DIR / "data"
"""Data shipped with the package: ``scenarios/``, ``sumo_nets/``, ``experiments/``."""

SCENARIOS = "scenarios"
NETS = "sumo_nets"
EXPERIMENTS = "experiments"


def shipped(kind: str) -> Path:
    """The shipped folder of ``kind`` (:data:`SCENARIOS`, :data:`NETS`, :data:`EXPERIMENTS`)."""
    return DATA_DIR / kind


def local(kind: str) -> Path:
    """The working directory's folder of ``kind`` (may not exist)."""
    return Path.cwd() / kind


def search_path(kind: str) -> list[Path]:
    """Folders of ``kind`` to look in, first match wins: the working directory's, then shipped.

    The two are one folder when priqn runs from inside its own ``priqn/data/``.
    """
    out = []
    for d in (local(kind), shipped(kind)):
        if d.is_dir() and all(d.resolve() != o.resolve() for o in out):
            out.append(d)
    return out


def scenarios_dir() -> Path:
    """Folder of the shipped scenario-family TOML files."""
    return shipped(SCENARIOS)


def nets_dir() -> Path:
    """Folder of the shipped nets, one sub-folder per family."""
    return shipped(NETS)


def experiments_dir() -> Path:
    """Folder of the shipped experiment grids."""
    return shipped(EXPERIMENTS)


def generate_dir() -> Path:
    """Where ``priqn scenario generate`` writes without ``--out``: ``./sumo_nets``."""
    return local(NETS)


def nets_root_for(family: str) -> Path:
    """The nets folder holding ``family``: ``./sumo_nets`` if it has the family, else shipped."""
    for d in search_path(NETS):
        if (d / family / "manifest.json").is_file():
            return d
    return nets_dir()
