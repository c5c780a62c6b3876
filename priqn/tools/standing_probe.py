"""``priqn probe``: is an ego standing inside the junction hit, under each traffic?

A scripted ego drives its route at a steady 6 m/s until its centre is ``--into`` metres past
the stop line (inside the junction, across the paths of the other arms' traffic), then
brakes to a stand and stays there until the episode ends. Nothing it does depends on the
traffic, so the share of episodes in which it is hit measures the traffic alone: SUMO's
polite drivers, ``rude`` NPCs (``junctionModel.ignoreIDs``) that drive into it, or ``tm``
NPCs that brake for it (docs/environment.md, "Traffic"). Each setting plays the same scenes
(hold-out nets, seeds ``--seed`` + episode) in its own process (one SUMO per process).

Per episode: whether the ego was hit, whether it was standing then (below 0.1 m/s), and
how long it had stood [s]. The table: per setting, the share hit, hit while standing, and
hit after standing at least 2 s (the hits an NPC had time to avoid).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import multiprocessing
from pathlib import Path
from typing import Any

CRUISE_MPS = 6.0
"""The scripted ego's speed until it stands [m/s]."""
STANDING_MPS = 0.1
"""Below this speed the ego counts as standing [m/s]."""
LATE_S = 2.0
"""A hit after the ego has stood this long is one the NPC had time to avoid [s]."""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--traffic",
        default="sumo,rude,tm",
        help="comma-separated named traffic settings (default: sumo,rude,tm)",
    )
    parser.add_argument("--density", type=float, default=1.0, help="traffic density (default 1.0)")
    parser.add_argument(
        "--episodes", type=int, default=60, help="episodes per setting (default 60)"
    )
    parser.add_argument(
        "--into", type=float, default=4.0, help="metres past the stop line the ego stands (4)"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the first scene (default 0)")
    parser.add_argument("--csv", type=Path, default=None, help="also write every episode here")


def run(args: argparse.Namespace) -> int:
    """Entry point: each setting in its own process, then the table (and ``--csv``)."""
    from priqn.checks import check_density
    from priqn.env.traffic import traffic_names
    from priqn.errors import PriqnError
    from priqn.io import check_writable

    names = traffic_names(args.traffic)
    check_density(args.density, "--density")
    if args.episodes < 1:
        raise PriqnError("--episodes: expected >= 1")
    if args.csv is not None:  # before any episode, not after all of them
        check_writable(args.csv, "--csv")
    ctx = multiprocessing.get_context("spawn")
    rows: list[dict[str, Any]] = []
    with concurrent.futures.ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        for name in names:
            spec = {"traffic": name, "density": args.density, "episodes": args.episodes,
                    "into_m": args.into, "seed": args.seed}  # fmt: skip
            rows += pool.submit(probe, spec).result()
    print(summary(rows, args))
    if args.csv is not None:
        import pandas as pd

        from priqn.analysis.artifacts import write_csv

        write_csv(args.csv, pd.DataFrame(rows), float_format="%.3f")
    return 0


def summary(rows: list[dict[str, Any]], args: argparse.Namespace) -> str:
    """The table: per setting, episodes and the shares hit (markdown)."""
    lines = [
        f"standing ego, {args.into:g} m into the junction; density {args.density:g}; "
        f"{args.episodes} episodes a setting (hold-out nets, seeds {args.seed}+)",
        "",
        "| traffic | episodes | hit | hit standing | hit after standing >= 2 s | "
        "median stood before a hit [s] |",
        "|---|---|---|---|---|---|",
    ]
    for name in dict.fromkeys(r["traffic"] for r in rows):
        mine = [r for r in rows if r["traffic"] == name]
        hit = [r for r in mine if r["hit"]]
        standing = [r for r in hit if r["hit_standing"]]
        late = [r for r in standing if r["stood_s"] >= LATE_S]
        stood = sorted(r["stood_s"] for r in standing)
        median = f"{stood[len(stood) // 2]:.1f}" if stood else "-"
        n = len(mine)
        lines.append(
            f"| {name} | {n} | {len(hit) / n:.0%} | {len(standing) / n:.0%} | "
            f"{len(late) / n:.0%} | {median} |"
        )
    return "\n".join(lines)


def probe(spec: dict[str, Any]) -> list[dict[str, Any]]:
    """One setting's episodes (runs in a spawned process, its progress bar on the
    inherited stderr): one row per episode."""
    import numpy as np
    from tqdm import tqdm

    from priqn.env.config import EnvConfig
    from priqn.env.intersection import IntersectionEnv
    from priqn.env.traffic import TRAFFIC_SETTINGS

    cfg = EnvConfig(family="holdout", obs_size_px=32, max_episode_steps=100)
    cfg = TRAFFIC_SETTINGS[spec["traffic"]].apply(cfg)
    env = IntersectionEnv(cfg)
    table = env.action_table()
    cruise = int(np.argmin(np.abs(table[:, 0] - CRUISE_MPS) + np.abs(table[:, 1])))
    stop = int(np.argmin(np.abs(table[:, 0]) + np.abs(table[:, 1])))
    rows = []
    bar = tqdm(total=spec["episodes"], desc=f"probe {spec['traffic']}", unit="ep", disable=None)
    try:
        for i in range(spec["episodes"]):
            env.reset(seed=spec["seed"] + i, options={"density": spec["density"]})
            ep = env._episode
            stand_s = ep.route.s_junction_entry_m + spec["into_m"]
            stood, steps, info = 0, 0, {}
            done = False
            while not done:
                at = env._episode.ego
                action = cruise if at.frenet.s < stand_s - 0.5 * CRUISE_MPS else stop
                _, _, term, trunc, info = env.step(action)
                steps += 1
                speed = float(env._episode.ego.kinematics[0])
                stood = stood + 1 if speed < STANDING_MPS else 0
                done = term or trunc
            hit = bool(info.get("collision"))
            rows.append({
                "traffic": spec["traffic"], "seed": spec["seed"] + i, "net": ep.scene.net,
                "command": ep.command, "hit": hit, "hit_standing": hit and stood > 0,
                "stood_s": stood * cfg.decision_interval_s if hit else 0.0,
                "decisions": steps,
            })  # fmt: skip
            bar.update(1)
    finally:
        bar.close()
        env.close()
    return rows
