"""Net generation: scenario family → nod/edg XML → ``netconvert`` → ``sumo_nets/<family>/``.

Each net is one unsignalised junction ``J`` at the origin with 3 (T-junction) or 4
(four-way) straight arms. Arm ``i`` ends in dead-end node ``n<i>`` and carries two
one-way edges, ``a<i>_in`` (towards the junction) and ``a<i>_out`` (away from it).
Arms are numbered counter-clockwise by their direction. Arms 0 and 2 form the main
road (higher priority at ``priority`` junctions); arm 1 (and 3) the side road.

Everything a net is drawn from comes from the family seed:
``SeedSequence(family.seed).spawn(n_nets)[i]`` seeds net ``i``'s generator. Drawn
values are rounded (0.1 deg, 0.01 m) so the XML sources are readable and exact.
``netconvert`` stamps its output with the date; that line is rewritten, so the same
seed gives byte-identical files on the same SUMO release.

``manifest.json`` records the family, seed, SUMO version, this generator's version,
the netconvert options, every net's parameters and the SHA-256 of every file, and
the family's traffic settings.
"""

from __future__ import annotations

import hashlib
import math
import re
import subprocess
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from priqn.config import to_dict
from priqn.errors import PriqnError
from priqn.io import atomic_write_bytes, atomic_write_json, sha256_file
from priqn.sim import sumo
from priqn.sim.scenario import NOMINAL_SPACING_DEG, ScenarioFamily

GENERATOR_VERSION = "1"
"""Bump when a change here changes the generated files for the same seed."""

NETCONVERT_OPTIONS: tuple[str, ...] = (
    "--no-turnarounds", "true",  # no U-turns: an intersection task, not a turning one
    "--offset.disable-normalization", "true",  # keep the junction at (0, 0)
    "--junctions.internal-link-detail", "10",  # smoother internal lanes for reference lines
    "--junctions.corner-detail", "5",
    "--default.junctions.keep-clear", "true",
    "--no-warnings", "true",
)  # fmt: skip
"""Options added to every netconvert call (internal links stay on: the ego drives through them)."""

NET_SUFFIXES: tuple[str, ...] = (".nod.xml", ".edg.xml", ".net.xml")
"""Files written per net, in the order netconvert needs them."""

_ARMS = {"tjunction": (0, 1, 2), "fourway": (0, 1, 2, 3)}
_HEADER = re.compile(rb"<!-- generated on \S+ by ")


def draw_params(
    kind: str, family: ScenarioFamily, rng: np.random.Generator, index: int = 0
) -> dict[str, Any]:
    """Draw net ``index``'s parameters (a JSON-able dict) from the family's geometry ranges
    for that net (:meth:`~priqn.sim.scenario.ScenarioFamily.geometry_of`)."""
    g = family.geometry_of(index)
    arms = _ARMS[kind]
    rotation = float(rng.uniform(*g.rotation_deg))
    jitter = rng.uniform(-g.arm_angle_jitter_deg, g.arm_angle_jitter_deg, size=len(arms))
    angles = [
        round((a * NOMINAL_SPACING_DEG + rotation + j) % 360.0, 1)
        for a, j in zip(arms, jitter, strict=True)
    ]
    lengths = [round(float(x), 1) for x in rng.uniform(*g.arm_length_m, size=len(arms))]
    lo, hi = g.lanes_per_direction
    main_lanes, side_lanes = (int(x) for x in rng.integers(lo, hi + 1, size=2))
    lanes = [main_lanes if i % 2 == 0 else side_lanes for i in range(len(arms))]
    return {
        "kind": kind,
        "junction_type": str(g.junction_types[int(rng.integers(len(g.junction_types)))]),
        "rotation_deg": round(rotation, 1),
        "arm_angles_deg": angles,
        "arm_lengths_m": lengths,
        "lanes_per_direction": lanes,
        "lane_width_m": round(float(rng.uniform(*g.lane_width_m)), 2),
        "speed_limit_mps": round(float(rng.uniform(*g.speed_limit_mps)), 2),
        "junction_radius_m": round(float(rng.uniform(*g.junction_radius_m)), 1),
    }


def family_plan(family: ScenarioFamily) -> list[dict[str, Any]]:
    """Every net of the family: ``{"id", "kind", "seed", "params"}``, deterministic in the seed."""
    children = np.random.SeedSequence(family.seed).spawn(family.n_nets)
    plan, counts = [], {}
    for i, child in enumerate(children):
        rng = np.random.default_rng(child)
        if isinstance(family.kind, tuple):
            kind = family.kind[i]
        elif family.kind == "mixed":
            kind = ("tjunction", "fourway")[int(rng.integers(2))]
        else:
            kind = family.kind
        params = draw_params(kind, family, rng, i)
        net_id = f"{kind}_{counts.get(kind, 0):02d}"
        counts[kind] = counts.get(kind, 0) + 1
        plan.append({"id": net_id, "kind": kind, "seed": [family.seed, i], "params": params})
    return plan


def nodes_xml(params: dict[str, Any]) -> bytes:
    """SUMO plain-XML nodes: junction ``J`` at the origin and one dead end per arm."""
    root = ET.Element("nodes")
    ET.SubElement(
        root,
        "node",
        id="J",
        x="0.00",
        y="0.00",
        type=params["junction_type"],
        radius=f"{params['junction_radius_m']:.2f}",
    )
    for i, (ang, length) in enumerate(
        zip(params["arm_angles_deg"], params["arm_lengths_m"], strict=True)
    ):
        x, y = _polar(length, ang)
        ET.SubElement(root, "node", id=f"n{i}", x=f"{x:.2f}", y=f"{y:.2f}", type="dead_end")
    return _to_bytes(root)


def edges_xml(params: dict[str, Any]) -> bytes:
    """SUMO plain-XML edges: ``a<i>_in`` and ``a<i>_out`` for each arm."""
    root = ET.Element("edges")
    for i, lanes in enumerate(params["lanes_per_direction"]):
        priority = "3" if i % 2 == 0 else "2"  # main road (arms 0, 2) over side road
        for eid, frm, to in ((f"a{i}_in", f"n{i}", "J"), (f"a{i}_out", "J", f"n{i}")):
            ET.SubElement(
                root,
                "edge",
                attrib={"id": eid, "from": frm, "to": to},
                priority=priority,
                numLanes=str(lanes),
                speed=f"{params['speed_limit_mps']:.2f}",
                width=f"{params['lane_width_m']:.2f}",
                disallow="pedestrian",
            )
    return _to_bytes(root)


def build_net(net_id: str, params: dict[str, Any]) -> dict[str, bytes]:
    """Write nod/edg XML, run netconvert, return ``{file name: bytes}`` for the three files."""
    nod, edg = nodes_xml(params), edges_xml(params)
    names = {s: f"{net_id}{s}" for s in NET_SUFFIXES}
    with tempfile.TemporaryDirectory(prefix="priqn-netgen-") as tmp:
        t = Path(tmp)
        (t / names[".nod.xml"]).write_bytes(nod)
        (t / names[".edg.xml"]).write_bytes(edg)
        cmd = [
            sumo.binary("netconvert"),
            "--node-files", names[".nod.xml"],
            "--edge-files", names[".edg.xml"],
            "--output-file", names[".net.xml"],
            *NETCONVERT_OPTIONS,
        ]  # fmt: skip
        try:
            proc = subprocess.run(
                cmd, cwd=t, capture_output=True, text=True, env=sumo.subprocess_env(), timeout=120
            )
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise PriqnError(f"netconvert for net {net_id!r}: could not run ({exc})") from exc
        out = t / names[".net.xml"]
        if proc.returncode != 0 or not out.is_file():
            msg = _first_error(proc.stderr) or f"exit status {proc.returncode}"
            raise PriqnError(f"netconvert for net {net_id!r} failed: {msg}")
        net = _HEADER.sub(b"<!-- generated by ", out.read_bytes(), count=1)
    return {names[".nod.xml"]: nod, names[".edg.xml"]: edg, names[".net.xml"]: net}


def generate_family(
    family: ScenarioFamily,
    out_root: Path,
    *,
    net_ids: Sequence[str] | None = None,
    progress: Callable[[str], None] | None = None,
) -> Path:
    """Generate every net of ``family`` into ``out_root/<family>/`` plus ``manifest.json``.

    ``net_ids`` limits generation to some nets (the manifest then lists only those,
    which is for tests); files of nets no longer in the family are removed. Returns the
    family folder. ``progress`` is called with each net id after it is written.
    """
    plan = family_plan(family)
    if net_ids is not None:
        unknown = sorted(set(net_ids) - {p["id"] for p in plan})
        if unknown:
            raise PriqnError(f"family {family.name!r}: no net {unknown[0]!r} in its plan")
        plan = [p for p in plan if p["id"] in set(net_ids)]
    out = Path(out_root) / family.name
    nets = []
    for entry in plan:
        files = build_net(entry["id"], entry["params"])
        for name, data in files.items():
            atomic_write_bytes(out / name, data)
        nets.append({**entry, "files": {n: sha256_bytes(d) for n, d in files.items()}})
        if progress is not None:
            progress(entry["id"])
    if net_ids is None:
        keep = {n for net in nets for n in net["files"]}
        for stale in sorted(out.glob("*.xml")):
            if stale.name not in keep and stale.name.endswith(NET_SUFFIXES):
                stale.unlink()
    atomic_write_json(out / "manifest.json", manifest_dict(family, nets))
    return out


def manifest_dict(family: ScenarioFamily, nets: list[dict[str, Any]]) -> dict[str, Any]:
    """The manifest written beside a family's nets (no timestamps: it is reproducible)."""
    manifest = {
        "family": family.name,
        "description": family.description,
        "seed": family.seed,
        "sumo_version": sumo.sumo_version(),
        "generator_version": GENERATOR_VERSION,
        "netconvert_options": list(NETCONVERT_OPTIONS),
        "geometry": to_dict(family.geometry),
        "traffic": to_dict(family.traffic),
        "nets": nets,
    }
    if family.net_geometry:  # only then: the manifests of families without it stay as they were
        manifest["net_geometry"] = to_dict(family.net_geometry)
    return manifest


def sha256_bytes(data: bytes) -> str:
    """Hex SHA-256 of ``data``."""
    return hashlib.sha256(data).hexdigest()


def verify_family_files(family_dir: Path, manifest: dict[str, Any]) -> list[str]:
    """Problems (one line each) where files in ``family_dir`` differ from ``manifest``."""
    problems = []
    for net in manifest["nets"]:
        for name, sha in net["files"].items():
            p = Path(family_dir) / name
            if not p.is_file():
                problems.append(f"{p}: missing")
            elif sha256_file(p) != sha:
                problems.append(f"{p}: SHA-256 differs from the manifest")
    return problems


# --------------------------------------------------------------------------- internals


def _polar(length_m: float, angle_deg: float) -> tuple[float, float]:
    a = math.radians(angle_deg)
    return length_m * math.cos(a) + 0.0, length_m * math.sin(a) + 0.0


def _to_bytes(root: ET.Element) -> bytes:
    ET.indent(root, space="    ")
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


def _first_error(stderr: str) -> str:
    lines = [ln.strip() for ln in stderr.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("Error")]
    return (errors or lines or [""])[0]
