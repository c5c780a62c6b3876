"""Scenario families: what nets to generate and what traffic to put on them.

A family is one TOML file ``scenarios/<name>.toml`` (see ``docs/scenarios.md``)
loaded into :class:`ScenarioFamily`: a master seed, how many nets, their kind
(T-junction or four-way), ranges for the geometry a net is drawn from
(:class:`GeometrySpec`) and the traffic the environment puts on it
(:class:`TrafficSpec`). Ranges are ``[lo, hi]`` pairs, sampled uniformly.

Generated nets live in ``sumo_nets/<family>/`` with a ``manifest.json`` (shipped in
``priqn/data/``, or generated below the working directory: :mod:`priqn.paths`);
:func:`load_manifest`, :func:`manifest_hash` and :func:`net_path` read them.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path
from typing import Any

from priqn import paths
from priqn.config import from_dict, load_toml, to_dict
from priqn.errors import PriqnError, did_you_mean

KINDS: tuple[str, ...] = ("tjunction", "fourway")
"""Net kinds: a T-junction has 3 arms, a four-way 4."""

JUNCTION_TYPES: tuple[str, ...] = ("priority", "right_before_left", "allway_stop")
"""SUMO node types a family may draw its junction from."""

NOMINAL_SPACING_DEG = 90.0
"""Arms sit at multiples of 90° before jitter (a T-junction leaves one out)."""


def _check_range(
    name: str, rng: tuple[float, ...], *, positive: bool = False, min_lo: float | None = None
) -> None:
    # Ranges are typed tuple[float, ...] (not tuple[float, float]) because
    # priqn.config coerces fixed-length tuples wrongly; the length is checked here.
    if len(rng) != 2:
        raise ValueError(f"{name}: expected a range [lo, hi] of 2 values, got {len(rng)}")
    lo, hi = rng
    if lo > hi:
        raise ValueError(f"{name}: lower bound {lo} exceeds upper bound {hi}; expected [lo, hi]")
    if positive and lo <= 0:
        raise ValueError(f"{name}: expected values > 0, got [{lo}, {hi}]")
    if min_lo is not None and lo < min_lo:
        raise ValueError(f"{name}: expected values >= {min_lo}, got [{lo}, {hi}]")


@dataclasses.dataclass(frozen=True)
class GeometrySpec:
    """Ranges a net's geometry is drawn from (one draw per net, uniform)."""

    arm_angle_jitter_deg: float = 15.0
    """Each arm's direction is its nominal multiple of 90° plus U(-j, j) degrees."""
    min_arm_separation_deg: float = 55.0
    """Arms must stay at least this far apart; checked against the jitter (90 - 2j >= this)."""
    rotation_deg: tuple[float, ...] = (0.0, 0.0)
    """Rotation of the whole junction about its centre [deg], counter-clockwise."""
    arm_length_m: tuple[float, ...] = (100.0, 150.0)
    """Length of each arm from the junction centre to its dead end [m] (>= 80 m: room to accelerate and queue)."""
    lanes_per_direction: tuple[int, ...] = (1, 2)
    """Lanes per direction; drawn per road (the main road's two arms share it, so does a cross road)."""
    lane_width_m: tuple[float, ...] = (3.0, 3.6)
    """Lane width, one value per net [m]."""
    speed_limit_mps: tuple[float, ...] = (8.33, 13.89)
    """Speed limit, one value per net [m/s] (30-50 km/h)."""
    junction_radius_m: tuple[float, ...] = (5.0, 9.0)
    """Turning radius of the junction's corners [m] (netconvert node attribute 'radius')."""
    junction_types: tuple[str, ...] = ("priority", "right_before_left")
    """Junction types drawn uniformly per net (SUMO node types)."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.arm_angle_jitter_deg < 45.0:
            raise ValueError(
                f"arm_angle_jitter_deg: expected 0 <= jitter < 45, got {self.arm_angle_jitter_deg}"
            )
        if self.min_arm_separation_deg <= 0:
            raise ValueError("min_arm_separation_deg: expected a value > 0")
        worst = NOMINAL_SPACING_DEG - 2.0 * self.arm_angle_jitter_deg
        if worst < self.min_arm_separation_deg:
            raise ValueError(
                f"arm_angle_jitter_deg: {self.arm_angle_jitter_deg} lets arms come {worst:g} deg "
                f"close, below min_arm_separation_deg {self.min_arm_separation_deg:g}; lower the jitter"
            )
        _check_range("rotation_deg", self.rotation_deg)
        _check_range("arm_length_m", self.arm_length_m, min_lo=60.0)
        _check_range("lanes_per_direction", self.lanes_per_direction, min_lo=1)
        if self.lanes_per_direction[1] > 4:
            raise ValueError("lanes_per_direction: expected at most 4 lanes per direction")
        _check_range("lane_width_m", self.lane_width_m, min_lo=2.0)
        _check_range("speed_limit_mps", self.speed_limit_mps, positive=True)
        _check_range("junction_radius_m", self.junction_radius_m, positive=True)
        if not self.junction_types:
            raise ValueError("junction_types: expected at least one junction type")
        for jt in self.junction_types:
            if jt not in JUNCTION_TYPES:
                raise ValueError(
                    f"junction_types: unknown type {jt!r} (valid: {', '.join(JUNCTION_TYPES)})"
                )


@dataclasses.dataclass(frozen=True)
class TrafficSpec:
    """Traffic the environment puts on a family's nets (read by ``priqn.env.traffic``)."""

    max_actors: int = 20
    """Most NPC vehicles alive at once; density = active actors / max_actors."""
    vehicle_length_m: tuple[float, ...] = (3.8, 5.2)
    """NPC vehicle length range [m]."""
    vehicle_width_m: tuple[float, ...] = (1.7, 2.0)
    """NPC vehicle width range [m]."""
    speed_factor: tuple[float, ...] = (0.8, 1.1)
    """NPC desired speed as a factor of the lane's speed limit."""
    lateral_offset_m: tuple[float, ...] = (-0.4, 0.4)
    """Random lateral offset of an NPC from its lane centre [m] (positive = left)."""
    lateral_offset_fade_m: float = 18.0
    """Distance before the junction over which lateral offsets fade to zero [m]."""
    obstacles_per_episode: tuple[int, ...] = (0, 2)
    """Number of static obstacles per episode, drawn uniformly from [lo, hi]."""
    obstacle_length_m: tuple[float, ...] = (3.5, 5.0)
    """Static obstacle length range [m]."""
    obstacle_width_m: tuple[float, ...] = (1.6, 2.0)
    """Static obstacle width range [m]."""

    def __post_init__(self) -> None:
        if self.max_actors < 1:
            raise ValueError(f"max_actors: expected an integer >= 1, got {self.max_actors}")
        _check_range("vehicle_length_m", self.vehicle_length_m, positive=True)
        _check_range("vehicle_width_m", self.vehicle_width_m, positive=True)
        _check_range("speed_factor", self.speed_factor, positive=True)
        _check_range("lateral_offset_m", self.lateral_offset_m)
        if self.lateral_offset_fade_m < 0:
            raise ValueError(
                f"lateral_offset_fade_m: expected a value >= 0, got {self.lateral_offset_fade_m}"
            )
        _check_range("obstacles_per_episode", self.obstacles_per_episode, min_lo=0)
        _check_range("obstacle_length_m", self.obstacle_length_m, positive=True)
        _check_range("obstacle_width_m", self.obstacle_width_m, positive=True)


@dataclasses.dataclass(frozen=True)
class ScenarioFamily:
    """One scenario family: a seeded pool of generated nets plus its traffic settings."""

    seed: int
    """Master seed; net i is drawn from ``SeedSequence(seed).spawn(n_nets)[i]``."""
    n_nets: int
    """Number of nets in the family."""
    kind: str | tuple[str, ...] = "tjunction"
    """'tjunction', 'fourway', 'mixed' (drawn per net), or one kind per net (a list of n_nets)."""
    name: str = ""
    """Family name; defaults to the TOML file's stem and must match it if given."""
    description: str = ""
    """One sentence on what the family is for."""
    geometry: GeometrySpec = dataclasses.field(default_factory=GeometrySpec)
    """Geometry ranges."""
    traffic: TrafficSpec = dataclasses.field(default_factory=TrafficSpec)
    """Traffic settings."""
    net_geometry: tuple[dict[str, Any], ...] = ()
    """Per-net changes to ``geometry``: empty (every net drawn from ``geometry``), or one
    table per net in net order (``[[net_geometry]]``), whose keys replace ``geometry``'s
    for that net only, e.g. ``lane_width_m = [2.6, 2.9]`` for one net and ``[3.9, 4.3]`` for
    the next (an empty table keeps ``geometry``). Each net's geometry is checked like
    ``geometry`` (:meth:`geometry_of`)."""

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ValueError(f"seed: expected an integer >= 0, got {self.seed}")
        if not 1 <= self.n_nets <= 1000:
            raise ValueError(f"n_nets: expected 1..1000, got {self.n_nets}")
        if isinstance(self.kind, str):
            if self.kind not in (*KINDS, "mixed"):
                raise ValueError(
                    f"kind: unknown kind {self.kind!r} (valid: {', '.join(KINDS)}, mixed, "
                    "or a list with one kind per net)"
                )
        else:
            if len(self.kind) != self.n_nets:
                raise ValueError(
                    f"kind: a list of kinds needs one per net: got {len(self.kind)} for n_nets={self.n_nets}"
                )
            for k in self.kind:
                if k not in KINDS:
                    raise ValueError(f"kind: unknown kind {k!r} (valid: {', '.join(KINDS)})")
        if self.net_geometry:
            if len(self.net_geometry) != self.n_nets:
                raise ValueError(
                    f"net_geometry: needs one table per net: got {len(self.net_geometry)} "
                    f"for n_nets={self.n_nets}"
                )
            for i in range(self.n_nets):
                self.geometry_of(i)  # checked like [geometry]

    def geometry_of(self, i: int) -> GeometrySpec:
        """The geometry ranges net ``i`` is drawn from: ``geometry`` with ``net_geometry[i]``'s
        keys replaced (``geometry`` itself when there is no ``net_geometry``)."""
        if not self.net_geometry:
            return self.geometry
        where = f"net_geometry[{i}]"
        try:
            return from_dict(
                GeometrySpec, {**to_dict(self.geometry), **self.net_geometry[i]}, where
            )
        except PriqnError as exc:
            raise ValueError(str(exc)) from None


def family_toml(name_or_path: str | Path) -> Path:
    """Path of a family's TOML: an existing file path, or a name in ``./scenarios/`` or shipped."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.is_file() or len(p.parts) > 1:
        if not p.is_file():
            raise PriqnError(f"{p}: scenario file not found")
        return p
    for d in paths.search_path(paths.SCENARIOS):
        candidate = d / f"{p.name}.toml"
        if candidate.is_file():
            return candidate
    known = ", ".join(list_families()) or "none"
    raise PriqnError(f"unknown scenario family {str(name_or_path)!r} (available: {known})")


def load_family(name_or_path: str | Path) -> ScenarioFamily:
    """Load ``scenarios/<name>.toml`` (or a TOML path) into a :class:`ScenarioFamily`.

    A malformed file, an unknown key, a wrong type or a bad range raises a one-line
    :class:`PriqnError` naming the file and the field.
    """
    path = family_toml(name_or_path)
    data = load_toml(path)
    where = str(path)
    stem = path.name.removesuffix(".toml")
    given = data.get("name", "")
    if given and given != stem:
        raise PriqnError(
            f"{where}.name: {given!r} differs from the file name {stem!r}; make them equal"
        )
    fam = from_dict(ScenarioFamily, data, where)
    return dataclasses.replace(fam, name=stem)


def list_families() -> list[str]:
    """Names of the families in ``./scenarios/`` and shipped (sorted)."""
    return sorted(
        {
            p.name.removesuffix(".toml")
            for d in paths.search_path(paths.SCENARIOS)
            for p in d.glob("*.toml")
        }
    )


def load_manifest(family: str, root: Path | None = None) -> dict[str, Any]:
    """Read ``<root>/<family>/manifest.json`` (no root: ``./sumo_nets`` if it has it, else shipped)."""
    path = (root if root is not None else paths.nets_root_for(family)) / family / "manifest.json"
    if not path.is_file():
        generated = list_generated(root)
        raise PriqnError(
            f"{path}: no manifest for family {family!r}; run 'priqn scenario generate "
            f"--family {family}' (generated families: {', '.join(generated) or 'none'})"
            + did_you_mean(family, generated)
        )
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise PriqnError(f"{path}: not a valid manifest ({exc}); regenerate it") from exc
    if not isinstance(data, dict) or not isinstance(data.get("nets"), list):
        raise PriqnError(f"{path}: manifest has no 'nets' list; regenerate it")
    for i, net in enumerate(data["nets"]):
        files = net.get("files") if isinstance(net, dict) else None
        if not isinstance(net, dict) or "id" not in net or not files or not isinstance(files, dict):
            raise PriqnError(
                f"{path}: nets[{i}] needs an 'id' and the SHA-256 of its 'files' (a manifest is "
                "written by 'priqn scenario generate'); for nets of your own use env.nets / "
                "--net FILE, which need no manifest (docs/your-own-net.md)"
            )
    return data


def manifest_hash(family: str, root: Path | None = None) -> str:
    """SHA-256 over a family's file hashes, identifying the exact nets an experiment used.

    The hashed text is one line ``<net_id>/<file> <sha256>`` per file, sorted, joined by
    newlines, so it changes iff a net file changes, appears or disappears.
    """
    return hash_of_manifest(load_manifest(family, root))


def hash_of_manifest(manifest: dict[str, Any]) -> str:
    """The :func:`manifest_hash` of an already loaded manifest dict."""
    lines = sorted(
        f"{net['id']}/{name} {sha}"
        for net in manifest["nets"]
        for name, sha in net["files"].items()
    )
    return hashlib.sha256("\n".join(lines).encode()).hexdigest()


def list_generated(root: Path | None = None) -> list[str]:
    """Families that have a manifest under ``root`` (no root: ``./sumo_nets`` and shipped; sorted)."""
    dirs = [root] if root is not None else paths.search_path(paths.NETS)
    return sorted({p.parent.name for d in dirs if d.is_dir() for p in d.glob("*/manifest.json")})


def list_nets(root: Path | None = None) -> list[str]:
    """Every generated net as ``"<family>/<net_id>"`` (sorted; no root: what ``net_path`` finds)."""
    if root is not None:
        fams = {f: root for f in list_generated(root)}
    else:
        fams = {f: paths.nets_root_for(f) for f in list_generated()}
    return sorted(
        f"{fam}/{p.name.removesuffix('.net.xml')}"
        for fam, d in fams.items()
        for p in (d / fam).glob("*.net.xml")
    )


def family_net_refs(family: str, root: Path | None = None) -> list[str]:
    """The nets of one generated family as ``"<family>/<net_id>"``, in manifest order."""
    return [f"{family}/{net['id']}" for net in load_manifest(family, root)["nets"]]


def net_path(net_ref: str | Path) -> Path:
    """``"family/net_id"`` (or a path to a ``.net.xml``) → the net file's path.

    A missing net raises a one-line error that lists the generated nets.
    """
    ref = str(net_ref)
    p = Path(ref)
    if ref.endswith(".net.xml"):
        if p.is_file():
            return p
        path = p
    else:
        if len(p.parts) != 2:
            raise PriqnError(
                f"net {ref!r}: expected 'family/net_id' (e.g. holdout/fourway_00) or a .net.xml path"
            )
        root = paths.nets_root_for(p.parts[0])
        path = root / p.parts[0] / f"{p.parts[1]}.net.xml"
        if path.is_file():
            return path
        path = path.relative_to(root.parent)  # 'sumo_nets/<family>/<id>.net.xml'
    shown = path
    nets = list_nets()
    same_family = [n for n in nets if n.split("/")[0] == path.parent.name]
    listing = ", ".join(same_family or nets) if nets else "none generated yet"
    raise PriqnError(
        f"{shown}: no such net; run 'priqn scenario generate' or pick one of: {listing}"
    )
