"""The env's pool of nets and what it keeps per net: road map, rasters, routes, obstacle sites.

A :class:`ScenePool` knows which nets ``reset`` may draw (the families of
``EnvConfig.family`` under ``EnvConfig.nets_dir``, ``./sumo_nets/`` or the shipped nets;
or your own ``.net.xml`` files, ``EnvConfig.nets``)
and builds a :class:`Scene` per net the first time it is used, then keeps it: parsing
a net and rasterising its road takes 0.1-0.3 s, a reset afterwards only milliseconds.
A scene also caches, per ego route, the cells of that route's bit
(:meth:`Scene.route_raster`), so a reset on a known (net, route) draws nothing.

Nothing here talks to SUMO: lane lengths and widths come from the parsed net.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from priqn.config import from_dict
from priqn.env import geometry, planner
from priqn.env.path_braking import NpcPaths
from priqn.env.traffic import ObstacleSite
from priqn.errors import PriqnError
from priqn.io import read_json
from priqn.sim.roadmap import CROP_MARGIN_M, EgoRoute, RoadMap
from priqn.sim.scenario import TrafficSpec
from priqn.sim.session import check_net

FAMILIES: dict[str, tuple[str, ...]] = {
    "tjunction": ("tjunction",),
    "fourway": ("fourway",),
    "all": ("tjunction", "fourway"),
    "holdout": ("holdout",),
}
"""Net pools by ``EnvConfig.family``: 'all' joins both training pools. Any other
generated family is a pool of its own nets (:func:`pool_families`)."""


def pool_families(family: str) -> tuple[str, ...]:
    """The scenario families the pool ``family`` draws from: those :data:`FAMILIES` names,
    else the family itself (a family generated beside them, e.g. ``out-of-range``)."""
    return FAMILIES.get(family, (family,))


def known_pools(nets_dir: str = "") -> list[str]:
    """Every pool name ``EnvConfig.family`` may take with this ``nets_dir`` ('' = ./sumo_nets
    and the shipped nets): the names of :data:`FAMILIES`, then every other family with a
    manifest there."""
    from priqn.sim.scenario import list_generated

    generated = list_generated(Path(nets_dir) if nets_dir else None)
    return [*FAMILIES, *(f for f in generated if f not in FAMILIES)]


SITE_END_MARGIN_M = 5.0
"""Obstacle sites keep this far from the dead end / the start of an arm [m]."""
SITE_MIN_LENGTH_M = 10.0
"""A lane stretch shorter than this offers no obstacle site [m]."""
SITE_REACH_M = CROP_MARGIN_M
"""Obstacle sites lie within this distance of the junction along their lane [m]: on the long
arm of an own net an obstacle stays where the map covers it and the ego can meet it."""


@dataclasses.dataclass
class Scene:
    """Everything the env derives from one net, built once per process."""

    net: str
    """``"family/net_id"``."""
    roadmap: RoadMap
    """Lanes, routes, drivable area (sumolib)."""
    raster: geometry.MapRaster
    """Drivable area and lane markings, no route bit."""
    references: dict[str, planner.ReferenceLine]
    """Planner reference line per ego route name."""
    traffic: TrafficSpec
    """The family's traffic settings (from the manifest beside the net)."""
    _route_cells: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    _sites: dict[float, list[ObstacleSite]] = dataclasses.field(default_factory=dict)

    def route_raster(self, route: EgoRoute) -> geometry.MapRaster:
        """A fresh copy of the map raster with ``route``'s bit set.

        The route is drawn once per (net, route) and kept as the flat indices of its
        cells (~0.1 MB per route instead of a whole raster); later calls copy the base
        raster and set those cells, identical to ``raster.with_route(...)``.
        """
        cells = self._route_cells.get(route.name)
        if cells is None:
            drawn = self.raster.with_route(route.reference_xy, route.lane_width_m)
            cells = np.flatnonzero(drawn.bits & geometry.ROUTE).astype(np.int32)
            self._route_cells[route.name] = cells
        bits = self.raster.bits.copy()
        bits.ravel()[cells] |= geometry.ROUTE
        return geometry.MapRaster(bits, self.raster.origin_xy, self.raster.resolution_m)

    @functools.cached_property
    def npc_paths(self) -> NpcPaths:
        """The paths NPCs drive through the junction (``traffic.path_braking``), built once."""
        return NpcPaths(self.roadmap)

    def prepare_routes(self) -> None:
        """Draw every ego route now (so that no reset draws one)."""
        for route in self.roadmap.ego_routes:
            self.route_raster(route)

    def obstacle_sites(self, route: EgoRoute, clearance_m: float) -> list[ObstacleSite]:
        """Where obstacles may stand in an episode on ``route``.

        The rightmost car lane of every arm edge, at least ``clearance_m`` and at most
        :data:`SITE_REACH_M` from the junction (and :data:`SITE_END_MARGIN_M` from the arm's
        far end); on the ego's approach
        edge also at least ``clearance_m`` ahead of the ego's start. Stretches shorter
        than :data:`SITE_MIN_LENGTH_M` are dropped.
        """
        sites = self._sites.get(clearance_m)
        if sites is None:
            rm = self.roadmap
            incoming = {r[0] for r in rm.npc_routes}
            outgoing = {r[-1] for r in rm.npc_routes}
            sites = []
            rightmost: dict[str, str] = {}  # edge -> its rightmost car lane
            for lane in rm.lanes.values():  # a roadmap lists an edge's car lanes rightmost first
                if not lane.internal:
                    rightmost.setdefault(lane.edge_id, lane.lane_id)
            for edge in sorted(incoming | outgoing):
                lane = rm.lanes[rightmost[edge]]
                if edge in incoming:
                    lo = max(SITE_END_MARGIN_M, lane.length_m - SITE_REACH_M)
                    hi = lane.length_m - clearance_m
                else:
                    lo = clearance_m
                    hi = min(lane.length_m - SITE_END_MARGIN_M, SITE_REACH_M)
                if hi - lo > SITE_MIN_LENGTH_M:
                    sites.append(ObstacleSite(lane.lane_id, edge, lane.index, lo, hi, lane.width_m))
            self._sites[clearance_m] = sites
        out = []
        for site in sites:
            if site.edge_id == route.edges[0]:
                lo = max(site.s_min_m, route.start_pos_m + clearance_m)
                if site.s_max_m - lo <= SITE_MIN_LENGTH_M:
                    continue
                site = dataclasses.replace(site, s_min_m=lo)
            out.append(site)
        return out


class ScenePool:
    """The nets of a pool and their :class:`Scene` cache.

    ``family``: a pool name (:func:`pool_families`); ``nets_dir``: folder holding
    ``<family>/manifest.json`` and the nets ('' = ``./sumo_nets/`` or the shipped nets);
    ``marking_width_m``: width the lane markings are rasterised with. ``nets``: your own
    ``.net.xml`` files or folders of them instead of a family (no manifest needed), each
    driven through ``junction`` (an id; '' = its junction with the most approaches).
    """

    def __init__(
        self,
        family: str,
        nets_dir: str,
        marking_width_m: float,
        nets: Sequence[str] = (),
        junction: str = "",
    ) -> None:
        self.root: Path | None = Path(nets_dir) if nets_dir else None
        """The nets folder given (None = ./sumo_nets or the shipped nets)."""
        self.marking_width_m = marking_width_m
        self.junction = junction or None
        self._own: dict[str, Path] = own_net_files(nets) if nets else {}
        self.refs: tuple[str, ...] = (
            tuple(self._own) if nets else tuple(_pool_refs(pool_families(family), self.root))
        )
        """The nets ``reset`` draws from, ``"family/net_id"`` (own nets: ``"<folder>/<stem>"``)."""
        self._scenes: dict[str, Scene] = {}

    def __len__(self) -> int:
        return len(self.refs)

    def net_file(self, net: str) -> Path:
        """The ``.net.xml`` of ``"family/net_id"``; a one-line error if there is none."""
        from priqn.sim.scenario import net_path

        if self._own:
            if net not in self._own:
                raise PriqnError(f"net {net!r}: not one of env.nets ({', '.join(self.refs)})")
            return self._own[net]
        if self.root is None:
            return net_path(net)
        parts = Path(net).parts
        if len(parts) != 2:
            raise PriqnError(f"net {net!r}: expected 'family/net_id' (e.g. holdout/fourway_00)")
        path = self.root / parts[0] / f"{parts[1]}.net.xml"
        if not path.is_file():
            raise PriqnError(
                f"{path}: no such net (nets_dir {self.root}); pick one of: {', '.join(self.refs)}"
            )
        return path

    def scene(self, net: str) -> Scene:
        """The scene of ``"family/net_id"`` (parsed at the first call, then cached)."""
        scene = self._scenes.get(net)
        if scene is None:
            path = self.net_file(net)
            check_net(path)  # a malformed net would crash libsumo (and the process)
            roadmap = RoadMap.load(path, junction=self.junction)
            raster = geometry.MapRaster.from_roadmap(roadmap, marking_width_m=self.marking_width_m)
            refs = {r.name: planner.ReferenceLine(r.reference_xy) for r in roadmap.ego_routes}
            scene = Scene(net, roadmap, raster, refs, _traffic_spec(roadmap))
            self._scenes[net] = scene
        return scene

    def preload(self) -> int:
        """Build every scene of the pool and draw its routes now; returns how many scenes."""
        for net in self.refs:
            self.scene(net).prepare_routes()
        return len(self.refs)


def own_net_files(entries: Sequence[str], where: str = "env.nets") -> dict[str, Path]:
    """``"<folder>/<stem>" -> path`` for ``env.nets``: ``.net.xml`` files and folders of them.

    A missing path, a file that is not a ``.net.xml``, a folder without one, or two nets
    that would get the same name is a one-line error naming ``where`` (the setting or flag
    the entries came from: ``env.nets``, ``--nets``).
    """
    files: list[Path] = []
    for entry in entries:
        p = Path(entry)
        if p.is_dir():
            found = sorted(p.glob("*.net.xml"))
            if not found:
                raise PriqnError(f"{where}: {p} holds no .net.xml file")
            files += found
        elif p.is_file() and p.name.endswith(".net.xml"):
            files.append(p)
        elif p.exists():
            raise PriqnError(f"{where}: {p} is not a .net.xml file or a folder of them")
        else:
            raise PriqnError(f"{where}: {p}: no such file or folder")
    out: dict[str, Path] = {}
    for f in files:
        ref = f"{f.parent.name or '.'}/{f.name.removesuffix('.net.xml')}"
        if ref in out and out[ref].resolve() != f.resolve():
            raise PriqnError(f"{where}: {out[ref]} and {f} would both be net {ref!r}; rename one")
        out[ref] = f
    return out


def _pool_refs(families: Sequence[str], root: Path | None) -> list[str]:
    """The nets of ``families``; a bad ``nets_dir`` is described as it is, in one line."""
    from priqn.sim.scenario import family_net_refs, list_generated

    if root is not None:
        if not root.is_dir():
            raise PriqnError(
                f"env.nets_dir: {root} is not a folder; expected a folder with "
                f"<family>/manifest.json for {', '.join(families)} (or '' for sumo_nets/)"
            )
        missing = [f for f in families if not (root / f / "manifest.json").is_file()]
        if missing:
            have = list_generated(root)
            there = f"it holds {', '.join(have)}" if have else "it holds no family"
            raise PriqnError(
                f"env.nets_dir: {root} has no {missing[0]}/manifest.json ({there}); generate "
                f"nets there with 'priqn scenario generate --family {missing[0]} --out {root}'"
            )
    pool: list[str] = []
    for fam in families:
        pool += family_net_refs(fam, root)
    if not pool:
        where = root / families[0] if root is not None else families[0]
        raise PriqnError(f"{where}: the manifest lists no nets; regenerate the family")
    return pool


def _traffic_spec(roadmap: RoadMap) -> TrafficSpec:
    """The family's TrafficSpec from the manifest beside the net (defaults if there is none)."""
    manifest = roadmap.net_path.parent / "manifest.json"
    if not manifest.is_file():
        return TrafficSpec()
    data = read_json(manifest)
    traffic = data.get("traffic") if isinstance(data, dict) else None
    if not traffic:
        return TrafficSpec()
    return from_dict(TrafficSpec, traffic, where=f"{manifest} [traffic]")
