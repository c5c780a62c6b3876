"""Draw a net as a PNG: lanes, markings, junction and every ego route by command.

``priqn scenario show NET`` calls :func:`draw_net`; a person looks at the picture to
check what the generator made (which turns exist, where the ego starts and ends).
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from priqn.io import atomic_write_bytes
from priqn.sim.roadmap import COMMANDS, RoadMap

COMMAND_COLOURS: dict[str, str] = {"left": "#1f77b4", "straight": "#2ca02c", "right": "#d62728"}
"""Route colour per command (also used by the environment's debug pictures)."""

_ROAD = "#5a5a5a"
_INTERNAL = "#6e6e6e"
_JUNCTION = "#767676"
_GROUND = "#e9efe4"


def net_params(net_path: Path) -> dict[str, Any] | None:
    """The net's ``params`` from its family's ``manifest.json``, if there is one."""
    manifest = Path(net_path).parent / "manifest.json"
    if not manifest.is_file():
        return None
    try:
        data = json.loads(manifest.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError):
        return None
    stem = Path(net_path).name.removesuffix(".net.xml")
    for net in data.get("nets", []):
        if net.get("id") == stem:
            return net.get("params")
    return None


def draw_net(roadmap: RoadMap, out_png: Path, *, dpi: int = 130) -> Path:
    """Render ``roadmap`` into ``out_png`` (written atomically); returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Polygon

    fig, (ax, axz) = plt.subplots(1, 2, figsize=(14, 7.6), dpi=dpi, layout="constrained")
    for a in (ax, axz):
        _draw_roads(a, roadmap, Polygon)
    _draw_routes(ax, roadmap, zoom=False)
    drawn = _draw_routes(axz, roadmap, zoom=True)

    xmin, ymin, xmax, ymax = roadmap.bounds_m
    pad = 6.0
    ax.set_xlim(xmin - pad, xmax + pad)
    ax.set_ylim(ymin - pad, ymax + pad)
    pts = np.concatenate([roadmap.junction_polygon_xy, *drawn])
    cx, cy = (pts.min(axis=0) + pts.max(axis=0)) / 2
    half = max(np.ptp(pts[:, 0]), np.ptp(pts[:, 1])) / 2 + 4.0
    axz.set_xlim(cx - half, cx + half)
    axz.set_ylim(cy - half, cy + half)
    for a, title in ((ax, "whole net"), (axz, "junction (zoom)")):
        a.set_aspect("equal")
        a.set_facecolor(_GROUND)
        a.set_title(title, fontsize=10)
        a.set_xlabel("x [m] (east)")
        a.set_ylabel("y [m] (north)")
        a.tick_params(labelsize=8)
    _label_arms(ax, roadmap)

    counts = {c: len(roadmap.routes_for(c)) for c in COMMANDS}
    handles = [
        Line2D([0], [0], color=COMMAND_COLOURS[c], lw=2.5, label=f"{c} ({counts[c]} routes)")
        for c in COMMANDS
    ]
    handles += [
        Line2D([0], [0], marker="o", color="w", markerfacecolor="k", ms=6, label="ego start"),
        Line2D([0], [0], marker="*", color="w", markerfacecolor="0.5", mec="k", ms=11, label="goal"),
        Line2D([0], [0], marker="o", color="w", markerfacecolor="0.5", mec="k", ms=5,
               label="junction entry / exit"),
    ]  # fmt: skip
    ax.legend(handles=handles, loc="best", fontsize=8, framealpha=0.9)

    fig.suptitle(_title(roadmap), fontsize=11)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    out = Path(out_png)
    atomic_write_bytes(out, buf.getvalue())
    return out


def _title(roadmap: RoadMap) -> str:
    params = net_params(roadmap.net_path)
    head = f"{roadmap.net_ref} — {roadmap.junction_type} junction"
    if not params:
        return head
    lanes = "/".join(str(n) for n in params.get("lanes_per_direction", []))
    angles = ", ".join(f"{a:g}" for a in params.get("arm_angles_deg", []))
    return (
        f"{head}\n{params.get('kind', '')}: arms at {angles} deg, lanes per direction {lanes}, "
        f"lane width {params.get('lane_width_m', 0):.2f} m, "
        f"speed limit {params.get('speed_limit_mps', 0):.1f} m/s "
        f"({params.get('speed_limit_mps', 0) * 3.6:.0f} km/h), "
        f"corner radius {params.get('junction_radius_m', 0):.1f} m"
    )


def _draw_roads(ax, roadmap: RoadMap, Polygon) -> None:
    ax.add_patch(
        Polygon(roadmap.junction_polygon_xy, closed=True, fc=_JUNCTION, ec="none", zorder=1)
    )
    for lane_id, poly in zip(roadmap.lane_ids, roadmap.lane_polygons_xy, strict=True):
        internal = lane_id.startswith(":")
        ax.add_patch(
            Polygon(
                poly,
                closed=True,
                fc=_INTERNAL if internal else _ROAD,
                ec=_INTERNAL if internal else _ROAD,
                lw=0.3,
                zorder=1 if internal else 2,
            )
        )
    for line, kind in zip(roadmap.marking_polylines_xy, roadmap.marking_kinds, strict=True):
        style = {
            "edge": {"color": "white", "lw": 1.2, "ls": "-"},
            "centre": {"color": "#f2c200", "lw": 1.2, "ls": "-"},
            "lane": {"color": "white", "lw": 0.9, "ls": (0, (4, 4))},
        }[kind]
        ax.plot(line[:, 0], line[:, 1], zorder=3, solid_capstyle="butt", **style)


def _draw_routes(ax, roadmap: RoadMap, *, zoom: bool) -> list[np.ndarray]:
    """Whole view: start → goal, thin. Zoom: 15 m before the junction to 12 m after it."""
    drawn = []
    for route in roadmap.ego_routes:
        colour = COMMAND_COLOURS[route.command]
        s = route.s_m
        if zoom:
            lo, hi = route.s_junction_entry_m - 15.0, route.s_junction_exit_m + 12.0
        else:
            lo, hi = route.start_s_m, route.goal_s_m
        keep = (s >= lo) & (s <= hi)
        xy = route.reference_xy[keep]
        if len(xy) < 2:
            continue
        drawn.append(xy)
        lw = 2.2 if zoom else 1.3
        ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=lw, alpha=0.9, zorder=5)
        tail, head = (xy[-5] if len(xy) > 5 else xy[0]), xy[-1]
        ax.annotate(
            "",
            xy=head,
            xytext=tail,
            arrowprops={"arrowstyle": "-|>", "color": colour, "lw": lw, "mutation_scale": 14},
            zorder=6,
        )
        if zoom:
            for s_mark in (route.s_junction_entry_m, route.s_junction_exit_m):
                ax.plot(*route.point_at(s_mark), marker="o", color=colour, mec="k", ms=4, zorder=7)
        else:
            ax.plot(*route.point_at(route.start_s_m), marker="o", color="k", ms=5, zorder=7)
            goal = route.point_at(route.goal_s_m)
            ax.plot(*goal, marker="*", color=colour, ms=9, mec="k", mew=0.5, zorder=7)
    return drawn


def _label_arms(ax, roadmap: RoadMap) -> None:
    seen = set()
    for route in roadmap.ego_routes:
        edge = route.edges[0]
        if edge in seen:
            continue
        seen.add(edge)
        p = route.reference_xy[0]
        ax.annotate(
            edge,
            p,
            fontsize=8,
            ha="center",
            va="center",
            bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "0.6", "alpha": 0.9},
            zorder=8,
        )
