"""Where the project's folders are.

Nets and scenario specs live in the repository (``pip install -e .`` keeps them next
to the package); runs and reports go below the current working directory.
"""

from __future__ import annotations

from pathlib import Path

REPO_ROOT: Path = Path(__file__).resolve().parent.parent
"""The checkout that holds ``priqn/``, ``scenarios/`` and ``sumo_nets/``."""


def scenarios_dir() -> Path:
    """Folder of scenario-family TOML files (``scenarios/``)."""
    return REPO_ROOT / "scenarios"


def nets_dir() -> Path:
    """Folder of generated nets, one sub-folder per family (``sumo_nets/``)."""
    return REPO_ROOT / "sumo_nets"


def experiments_dir() -> Path:
    """Folder of experiment grids for ``priqn sweep`` (``experiments/``)."""
    return REPO_ROOT / "experiments"
