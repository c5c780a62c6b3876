"""What an evaluation plays: the runs under some paths, the nets (the hold-out family, or
your own ``.net.xml`` files, every one checked before any episode) and the run's env set to
play them."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from priqn.errors import PriqnError
from priqn.evaluation.protocol import EvalConfig
from priqn.io import sha256_file
from priqn.run.folder import RunFolder


def find_runs(paths: Iterable[str | Path]) -> list[Path]:
    """Run folders named by ``paths``: a run folder itself, or a folder of runs."""
    runs: list[Path] = []
    for p in map(Path, paths):
        if not p.is_dir():
            raise PriqnError(f"{p}: no such folder")
        if RunFolder(p).is_run():
            runs.append(p)
            continue
        inner = sorted(c for c in p.iterdir() if RunFolder(c).is_run())
        if not inner:
            raise PriqnError(f"{p}: neither a run folder (config.toml) nor a folder of runs")
        runs.extend(inner)
    return runs


def evaluation_nets(cfg: EvalConfig, commands: Sequence[str]) -> dict[str, Any]:
    """The manifest of ``cfg.nets``, every net checked now, before any episode.

    ``{"junction", "nets": [{"id", "path", "files": {name: sha256}, "junction"}, ...]}``,
    sorted by id, in the format of a run's ``nets.json``: ``id`` is the net's name
    (``"<folder>/<stem>"`` of its resolved path, the name the env and the episode table
    use), ``path`` its absolute path, ``junction`` the junction driven through. A path that
    is no ``.net.xml`` (or folder of them), a net SUMO cannot load, one without a usable
    intersection or without a route for the evaluated ``commands`` (``cfg.commands``, else
    at least one of the run's ``commands``) is a one-line :class:`PriqnError` naming it.
    """
    from priqn.env.scenes import own_net_files
    from priqn.sim.roadmap import RoadMap
    from priqn.sim.session import check_net

    files = own_net_files([str(Path(n).resolve()) for n in cfg.nets], where="--nets")
    entries = []
    for ref, path in sorted(files.items()):
        check_net(path)  # SUMO can load it (libsumo would crash a worker on a broken net)
        roadmap = RoadMap.load(path, junction=cfg.junction or None)
        offered = roadmap.commands()
        wanted = cfg.commands or tuple(commands)
        missing = [c for c in cfg.commands if c not in offered]
        if missing or not any(c in offered for c in wanted):
            raise PriqnError(
                f"{path}: junction {roadmap.junction_id} has no {(missing or wanted)[0]!r} route "
                f"(it offers: {', '.join(offered)}); evaluate other commands or pick another "
                "junction with --junction"
            )
        entries.append(
            {
                "id": ref,
                "path": str(path),
                "files": {path.name: sha256_file(path)},
                "junction": roadmap.junction_id,
            }
        )
    return {"junction": cfg.junction, "nets": entries}


def nets_hash(manifest: dict[str, Any]) -> str:
    """SHA-256 identifying what an evaluation on your own nets drives on: one line
    ``<id>/<file> <sha256> junction <id>`` per net, sorted (moving the files keeps it)."""
    import hashlib

    lines = sorted(
        f"{net['id']}/{name} {sha} junction {net['junction']}"
        for net in manifest["nets"]
        for name, sha in net["files"].items()
    )
    return hashlib.sha256("\n".join(lines).encode()).hexdigest()


def evaluation_target(
    cfg: EvalConfig, commands: Sequence[str]
) -> tuple[list[str], str, dict[str, Any] | None]:
    """``(net ids, hash, nets manifest)`` of what ``cfg`` evaluates on: the hold-out family
    (its manifest hash; no nets manifest) or ``cfg.nets`` (checked now, :func:`evaluation_nets`;
    their :func:`nets_hash`). ``commands``: the env's, for the check of ``cfg.nets``."""
    if cfg.nets:
        nets = evaluation_nets(cfg, commands)
        return [n["id"] for n in nets["nets"]], nets_hash(nets), nets
    from priqn.sim.scenario import load_manifest, manifest_hash

    return _net_ids(load_manifest(cfg.family)), manifest_hash(cfg.family), None


def evaluation_env(env_config: Any, cfg: EvalConfig, nets: dict[str, Any] | None) -> Any:
    """``env_config`` (a run's EnvConfig) set to play ``cfg``'s scenes: on the checked files
    of ``nets`` by their absolute paths, else on the hold-out family (also for a run trained
    on its own nets or junction); ``cfg.traffic``'s NPCs instead of the run's, if set;
    ``cfg.episode_limit``, else ``cfg.max_episode_steps``, if set. A value the env refuses
    (a family with no nets) is one line naming the env's field."""
    try:
        return _evaluation_env(env_config, cfg, nets)
    except ValueError as exc:
        raise PriqnError(f"evaluation env.{exc}") from None


def _evaluation_env(env_config: Any, cfg: EvalConfig, nets: dict[str, Any] | None) -> Any:
    if nets is not None:
        files = tuple(n["path"] for n in nets["nets"])
        env_cfg = dataclasses.replace(env_config, nets=files, junction=cfg.junction)
    else:
        env_cfg = dataclasses.replace(env_config, family=cfg.family, nets=(), junction="")
    if cfg.traffic:
        from priqn.env.traffic import traffic_setting

        # its NPCs only (an unknown name: one line listing the valid ones)
        env_cfg = dataclasses.replace(env_cfg, traffic=traffic_setting(cfg.traffic).behaviour)
    limit = cfg.episode_limit or cfg.max_episode_steps
    if limit:
        env_cfg = dataclasses.replace(env_cfg, max_episode_steps=limit)
    return env_cfg


def _net_ids(manifest: Any) -> list[str]:
    nets = manifest.get("nets") if isinstance(manifest, dict) else getattr(manifest, "nets", None)
    if not nets:
        raise PriqnError("hold-out manifest lists no nets; run 'priqn scenario generate'")
    ids = [n["id"] if isinstance(n, dict) else getattr(n, "id", n) for n in nets]
    return sorted(str(i) for i in ids)
