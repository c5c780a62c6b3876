"""``priqn scenario``: generate nets from scenario families, list them, draw one.

Examples::

    priqn scenario generate                     # every family, into ./sumo_nets/
    priqn scenario generate --family holdout --check   # verify the nets in use
    priqn scenario list
    priqn scenario show holdout/fourway_00 --out fourway_00.png
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Sub-commands ``generate``, ``list`` and ``show``."""
    sub = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    gen = sub.add_parser(
        "generate",
        help="generate ./sumo_nets/<family>/ from the scenario families",
        description="Write nod/edg XML, run netconvert and write manifest.json per family. "
        "Families are read from ./scenarios/<name>.toml or the ones shipped with priqn; nets go "
        "to ./sumo_nets/ (or --out), which priqn then uses instead of the shipped nets.",
    )
    gen.add_argument(
        "--family",
        action="append",
        metavar="NAME",
        help="family name or TOML path (repeatable; default: every family priqn knows)",
    )
    gen.add_argument(
        "--check",
        action="store_true",
        help="regenerate into a temp folder and compare SHA-256 with the manifest of the nets "
        "in use (--out, ./sumo_nets or shipped); writes nothing",
    )
    gen.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="DIR",
        help="write families under DIR instead of ./sumo_nets/",
    )
    sub.add_parser("list", help="list scenario families and generated nets")
    show = sub.add_parser("show", help="draw a net (lanes, junction, ego routes) as a PNG")
    show.add_argument(
        "net", metavar="NET", help="'family/net_id' (e.g. holdout/fourway_00) or a .net.xml path"
    )
    show.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="PNG",
        help="output file (default: ./<net_id>.png)",
    )


def run(args: argparse.Namespace) -> int:
    """Dispatch to the chosen action."""
    return {"generate": _generate, "list": _list, "show": _show}[args.action](args)


def _generate(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from priqn import paths
    from priqn.errors import PriqnError
    from priqn.sim import netgen
    from priqn.sim.scenario import list_families, load_family, load_manifest

    names = args.family or list_families()
    if not names:
        raise PriqnError("no scenario families (*.toml) in ./scenarios/ or shipped with priqn")
    families = [load_family(n) for n in names]  # validate all before writing any
    total = sum(f.n_nets for f in families)
    failures = []
    with tempfile.TemporaryDirectory(prefix="priqn-check-") as tmp:
        root = Path(tmp) if args.check else (args.out or paths.generate_dir())
        with tqdm(total=total, unit="net", disable=not sys.stderr.isatty()) as bar:
            for fam in families:
                bar.set_description(fam.name)
                netgen.generate_family(fam, root, progress=lambda _id: bar.update(1))
                if not args.check:
                    continue
                committed_root = args.out or paths.nets_root_for(fam.name)
                committed = load_manifest(fam.name, committed_root)
                fresh = load_manifest(fam.name, root)
                problems = _compare(committed, fresh)
                problems += netgen.verify_family_files(committed_root / fam.name, committed)
                failures += [f"{fam.name}: {p}" for p in problems]
                if not problems:
                    print(f"{fam.name}: {len(fresh['nets'])} nets match the committed manifest")
        if not args.check:
            for fam in families:
                print(f"{fam.name}: {fam.n_nets} nets -> {root / fam.name}/ (manifest.json)")
    if failures:
        for line in failures[:20]:
            print(line, file=sys.stderr)
        raise PriqnError(
            f"{len(failures)} difference(s) between regenerated and committed nets; "
            "run 'priqn scenario generate' and commit, or check the SUMO version"
        )
    return 0


def _compare(committed: dict, fresh: dict) -> list[str]:
    problems = []
    if committed.get("sumo_version") != fresh.get("sumo_version"):
        problems.append(
            f"SUMO version {fresh.get('sumo_version')} differs from the manifest's "
            f"{committed.get('sumo_version')}"
        )
    old = {n: sha for net in committed["nets"] for n, sha in net["files"].items()}
    new = {n: sha for net in fresh["nets"] for n, sha in net["files"].items()}
    for name in sorted(set(old) | set(new)):
        if name not in new:
            problems.append(f"{name}: in the manifest but no longer generated")
        elif name not in old:
            problems.append(f"{name}: generated but not in the manifest")
        elif old[name] != new[name]:
            problems.append(f"{name}: regenerated SHA-256 differs from the manifest")
    return problems


def _list(args: argparse.Namespace) -> int:
    from priqn import paths
    from priqn.errors import PriqnError
    from priqn.sim.scenario import list_families, list_generated, load_manifest, manifest_hash

    generated = set(list_generated())
    for name in list_families():
        if name in generated:
            m = load_manifest(name)
            ids = ", ".join(n["id"] for n in m["nets"])
            root = paths.nets_root_for(name)
            where = "shipped" if root == paths.nets_dir() else str(root)
            print(
                f"{name}: {len(m['nets'])} nets ({where}), manifest {manifest_hash(name)[:12]} [{ids}]"
            )
        else:
            print(f"{name}: not generated (run 'priqn scenario generate --family {name}')")
    orphans = sorted(generated - set(list_families()))
    for name in orphans:
        print(f"{name}: generated, but there is no scenario family {name}.toml")
    if not list_families() and not generated:
        raise PriqnError("no scenario families and no generated nets (./scenarios, ./sumo_nets)")
    return 0


def _show(args: argparse.Namespace) -> int:
    from priqn.sim.roadmap import RoadMap
    from priqn.sim.scenario import net_path
    from priqn.sim.show import draw_net

    path = net_path(args.net)
    roadmap = RoadMap.load(path)
    out = args.out or Path(f"{roadmap.net_id}.png")
    draw_net(roadmap, out)
    counts = ", ".join(f"{c} {len(roadmap.routes_for(c))}" for c in roadmap.commands())
    print(f"{roadmap.net_ref}: {len(roadmap.ego_routes)} ego routes ({counts}) -> {out}")
    return 0
