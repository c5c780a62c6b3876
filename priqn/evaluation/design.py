"""A pre-registered evaluation-only design (``evaluations/<name>.toml``): committed policies
of earlier experiments played on another scenario family, and the questions asked of them.

An experiment file (:mod:`priqn.experiment`) trains a grid; an evaluation design trains
nothing. It names, per source design, the committed cells to evaluate (``[[source]]``: the
rows, the seeds, the traffic they were trained and are evaluated under, the evaluation
limit), the protocol every source shares (``[evaluate]``: its ``EvalConfig`` fields, the
family replaced by the design's) and the comparison (``[design]``: ``a`` − ``b``, the
paper's difference, α). Each evaluation goes to ``<cell>/eval-family-<family>/``
(:func:`~priqn.evaluation.protocol.evaluation_name`), never into ``eval/``.

Torch-free; every mistake is one line naming the file and the key (:func:`load_design`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from priqn import paths
from priqn.config import from_dict, load_toml
from priqn.errors import PriqnError

EVALUATIONS = "evaluations"
"""Folder of the evaluation designs, shipped in ``priqn/data/`` or in the working directory."""

ROLES: tuple[str, ...] = ("primary", "secondary")
"""Values of ``[[source]].role``."""


@dataclass(frozen=True)
class DesignSpec:
    """The ``[design]`` table: what is evaluated on, and the comparison."""

    name: str
    """Design name; must equal the file's stem."""
    family: str
    """Scenario family every source is evaluated on (``priqn evaluate --family``)."""
    a: str
    """Row name of the policy whose difference is taken (Pr-IQN*)."""
    b: str
    """Row name it is compared with (IQN)."""
    description: str = ""
    """One sentence on the question."""
    alpha: float = 0.05
    """Family-wise error of each endpoint's Holm family (across the sources)."""
    paper_success_difference: float = 0.149
    """The paper's success difference a − b (fraction), the one-sided success test's target."""
    feature_skew_split_deg: float = 18.0
    """A net counts as more skewed when its largest arm jitter is above this [deg]."""

    def __post_init__(self) -> None:
        if not 0.0 < self.alpha < 1.0:
            raise ValueError(f"alpha: expected 0 < alpha < 1, got {self.alpha}")
        if self.a == self.b:
            raise ValueError(f"a and b: compare two different rows, got {self.a!r} twice")


@dataclass(frozen=True)
class SourceSpec:
    """One ``[[source]]``: the committed cells of an earlier design, and how they are played."""

    experiment: str
    """The experiment whose cells these are (``experiments/<name>.toml``)."""
    role: str
    """``primary`` or ``secondary``: how the design's report ranks it (Holm covers both)."""
    runs_dir: str
    """Folder of the committed cells (``<row>__seed<seed>/``), relative to the repository."""
    rows: tuple[str, ...]
    """Row (policy) names evaluated; must include the design's ``a`` and ``b``."""
    seeds: tuple[int, ...]
    """Training seeds evaluated (every committed one)."""
    traffic: str
    """The traffic the cells trained under and are evaluated under (their ``env.traffic``)."""
    max_episode_steps: int = 0
    """The source design's evaluation limit [decisions]; 0: the run's own."""
    in_range: str = ""
    """The in-range hold-out evaluation the drop is measured from ("" = ``eval/``)."""

    def __post_init__(self) -> None:
        if self.role not in ROLES:
            raise ValueError(f"role: expected one of {', '.join(ROLES)}, got {self.role!r}")
        if not self.rows or len(set(self.rows)) != len(self.rows):
            raise ValueError(f"rows: expected distinct row names, got {list(self.rows)}")
        if not self.seeds or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds: expected distinct training seeds, got {list(self.seeds)}")
        from priqn.env.traffic import TRAFFIC_SETTINGS

        if self.traffic not in TRAFFIC_SETTINGS:
            raise ValueError(
                f"traffic: unknown setting {self.traffic!r} (valid: {', '.join(TRAFFIC_SETTINGS)})"
            )
        if self.max_episode_steps < 0:
            raise ValueError(f"max_episode_steps: expected >= 0, got {self.max_episode_steps}")

    def cell_dirs(self, root: str | Path = ".") -> list[Path]:
        """Every cell folder this source evaluates, ``<runs_dir>/<row>__seed<seed>``
        (``priqn.experiment.cell_dir_name``, spelled here: the experiment imports this room)."""
        return [
            Path(root) / self.runs_dir / f"{row}__seed{seed}"
            for row in self.rows
            for seed in self.seeds
        ]


@dataclass(frozen=True)
class EvaluationDesign:
    """A whole evaluation design file."""

    design: DesignSpec
    """The ``[design]`` table."""
    source: tuple[SourceSpec, ...]
    """The ``[[source]]`` tables, primary first."""
    evaluate: dict[str, Any] = dataclasses.field(default_factory=dict)
    """``[evaluate]``: EvalConfig fields every source's evaluation shares (family excluded)."""

    def __post_init__(self) -> None:
        if not self.source:
            raise ValueError("source: expected at least one [[source]]")
        names = [s.experiment for s in self.source]
        if len(set(names)) != len(names):
            raise ValueError(f"source: an experiment listed twice: {names}")
        for s in self.source:
            for row in (self.design.a, self.design.b):
                if row not in s.rows:
                    raise ValueError(f"source {s.experiment!r}: rows lack the design's row {row!r}")
        if "family" in self.evaluate or "nets" in self.evaluate:
            raise ValueError("evaluate: the family is [design].family; set no family or nets here")

    def eval_config(self, source: SourceSpec) -> Any:
        """The :class:`~priqn.evaluation.protocol.EvalConfig` that evaluates ``source``'s cells."""
        from priqn.evaluation.protocol import EvalConfig

        values = {
            **self.evaluate,
            "family": self.design.family,
            "max_episode_steps": source.max_episode_steps,
        }
        return from_dict(EvalConfig, values, where=f"{self.design.name} [evaluate]")

    def cells(self) -> int:
        """How many cells the design evaluates."""
        return sum(len(s.rows) * len(s.seeds) for s in self.source)


FEATURES = ("lane width", "skew", "junction radius", "lanes", "kind", "junction type")
"""The net features a design's report tables violations by, in its order."""


def net_features(family: str, skew_split_deg: float) -> list[dict[str, str]]:
    """One record per net of ``family`` (``net``: ``<family>/<id>`` as the episode tables name
    it) and its level of each feature the design tables: lane width and junction radius
    against the hold-out family's ranges, skew (largest arm jitter against
    ``skew_split_deg``), lanes per direction, kind and junction type."""
    from priqn.sim.scenario import NOMINAL_SPACING_DEG, load_family, load_manifest

    train = load_family("holdout").geometry

    def against(value: float, lo_hi: tuple[float, float], unit: str) -> str:
        lo, hi = lo_hi
        if value < lo:
            return f"below training (< {lo:g} {unit})"
        return f"above training (> {hi:g} {unit})" if value > hi else "in training range"

    rows = []
    for net in load_manifest(family)["nets"]:
        p = net["params"]
        jitter = [
            abs((a - i * NOMINAL_SPACING_DEG - p["rotation_deg"] + 180.0) % 360.0 - 180.0)
            for i, a in enumerate(p["arm_angles_deg"])
        ]
        skew = max(jitter)
        rows.append(
            {
                "net": f"{family}/{net['id']}",
                "lane width": against(p["lane_width_m"], train.lane_width_m, "m"),
                "skew": f"largest jitter {'>' if skew > skew_split_deg else '<='} {skew_split_deg:g} deg",
                "junction radius": against(p["junction_radius_m"], train.junction_radius_m, "m"),
                "lanes": "3 on every arm" if min(p["lanes_per_direction"]) >= 3 else "1-2",
                "kind": p["kind"],
                "junction type": p["junction_type"],
            }
        )
    return rows


def design_path(name_or_path: str | Path) -> Path:
    """An existing TOML path, or ``evaluations/<name>.toml`` (working directory, then shipped)."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or len(p.parts) > 1:
        if not p.is_file():
            raise PriqnError(f"{p}: evaluation design not found")
        return p
    for d in paths.search_path(EVALUATIONS):
        if (d / f"{p.name}.toml").is_file():
            return d / f"{p.name}.toml"
    raise PriqnError(f"unknown evaluation design {str(name_or_path)!r} (no {EVALUATIONS}/{p}.toml)")


def load_design(name_or_path: str | Path) -> EvaluationDesign:
    """Load and check an evaluation design (one-line :class:`PriqnError` on any mistake)."""
    path = design_path(name_or_path)
    data = load_toml(path)
    design = from_dict(EvaluationDesign, data, str(path))
    stem = path.name.removesuffix(".toml")
    if design.design.name != stem:
        raise PriqnError(
            f"{path}.design.name: {design.design.name!r} differs from the file name {stem!r}"
        )
    design.eval_config(design.source[0])  # the [evaluate] fields are EvalConfig's
    return design
