"""The fleet's ``report.html``: every drone's status and track in one top view, the
separation figures, the merged inventory drawn rack by rack, links to each drone's report."""

from __future__ import annotations

import html
import math
import os
from typing import Any

from bt_engine.spec import plural

COLOURS = ("#1565c0", "#c62828", "#2e7d32", "#6a1b9a")


def plot_tracks(out: str, runners: dict[str, Any], runs: dict[str, Any]) -> str | None:
    """Top view: the rack steel and pallets of the world, the pads, each drone's track."""
    from matplotlib.figure import Figure

    from nodes.report.metrics import telemetry_arrays

    fig = Figure(figsize=(9, 6.5))
    ax = fig.add_subplot(1, 1, 1)
    world = None
    for r in runs.values():
        world = (r.mission.ctx.resources or {}).get("world") or world
    if world is not None:
        for b in world.boxes:
            c, s = math.cos(b.yaw_rad), math.sin(b.yaw_rad)
            pts = [
                (sx * b.hx, sy * b.hy) for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1), (-1, -1))
            ]
            xs = [b.cx + c * x - s * y for x, y in pts]
            ys = [b.cy + s * x + c * y for x, y in pts]
            colour = "#d7b98e" if b.name.startswith("pallet") else "#90a4ae"
            ax.fill(xs, ys, fc=colour, ec="none")
        for k, (name, (x, y)) in enumerate(world.pads().items()):
            ax.plot([x], [y], "o", ms=14, mfc="none", mec="#555")
            # pads a metre apart: names alternately below and above, so they do not overlap
            dy = -0.45 if k % 2 == 0 else 0.3
            ax.annotate(name, (x, y + dy), ha="center", fontsize=7, color="#555")
    drawn = False
    for i, (name, runner) in enumerate(runners.items()):
        tel = telemetry_arrays(runner.trace)
        if tel is None:
            continue
        colour = COLOURS[i % len(COLOURS)]
        ax.plot(tel["x"], tel["y"], lw=1.0, color=colour, label=name)
        ax.plot(tel["x"][:1], tel["y"][:1], "^", color=colour, ms=7)
        drawn = True
    if not drawn:
        return None
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(True, lw=0.3)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "tracks.png"), dpi=110)
    return "tracks.png"


def write_fleet_report(
    out: str, summary: dict, runners: dict[str, Any], runs: dict[str, Any]
) -> str:
    """Write ``report.html`` (and its PNGs) in the fleet's run folder; return its path."""
    from nodes.report.html import answer_section
    from nodes.report.inventory import inventory_section

    esc = html.escape
    rows = []
    for name, d in summary["drones"].items():
        link = os.path.join(d["run_dir"], "report.html")
        target = (
            f'<a href="{esc(link, quote=True)}">{esc(name)}</a>'
            if os.path.exists(os.path.join(out, link))
            else esc(name)
        )
        rows.append(
            f"<tr><td class=l>{target}</td><td class='l {esc(d['status'])}'>{esc(d['status'])}</td>"
            f"<td class=l>{esc(str(d['reason']))}</td><td>{d['mission_time_s']:.1f}</td>"
            f"<td>{d['answered']} / {d['places']}</td><td>{d.get('battery_swaps') or 0}</td>"
            f"<td>{d['waits']}</td><td>{d['pauses']}</td><td>{d['collisions']}</td></tr>"
        )
    sep = summary["separation"]
    closest = "-" if sep["closest_m"] is None else f"{sep['closest_m']:.2f} m"
    status = summary["status"]
    parts = [
        "<!DOCTYPE html><html lang=en><head><meta charset=utf-8>",
        f"<title>btrun fleet {esc(summary['fleet'])}: {esc(status)}</title>",
        "<style>body{font-family:system-ui,sans-serif;margin:1.5em auto;max-width:1100px;"
        "padding:0 1em}table{border-collapse:collapse;font-size:.9em}th,td{border:1px solid "
        "#ddd;padding:.25em .5em;text-align:right}td.l,th.l{text-align:left}.SUCCESS{color:"
        "#1a7f37}.FAILURE,.ABORTED{color:#c62828}img{max-width:100%}.wide{overflow-x:auto}"
        "</style></head><body>",
        f"<h1>fleet {esc(summary['fleet'])}: <span class='{esc(status)}'>{esc(status)}</span></h1>",
        f"<p>{plural(len(summary['drones']), 'drone')}, seed {summary['seed']}, "
        f"{summary['mission_time_s']:.1f} s mission time, {summary['wall_time_s']:.1f} s wall.</p>",
        answer_section(summary),  # the merged inventory's answer first, as the console's
        "<h2>Drones</h2><table><tr><th class=l>drone</th><th class=l>status</th>"
        "<th class=l>reason</th><th>mission time (s)</th><th>places answered</th><th>battery "
        "changes</th><th>airspace waits</th><th>holds</th><th>collisions</th></tr>",
        *rows,
        "</table>",
        "<h2>Separation</h2>",
        f"<p>closest approach {closest} (minimum {sep['minimum_m']:g} m), {sep['violations']} "
        f"violations, {sep['holds']} holds by the guard, {sep['airspace_waits']} motions that "
        f"waited for the airspace, {sep.get('airspace_asides', 0)} steps aside out of a mutual "
        "wait.</p>",
    ]
    png = plot_tracks(out, runners, runs)
    if png:
        parts.append(f'<h2>Tracks (top view)</h2><img src="{png}" alt="every drone\'s track">')
    parts.append(inventory_section(out, summary))
    parts.append("<p>Written by btrun fleet (nodes/fleet/); see docs/fleets.md.</p></body></html>")
    path = os.path.join(out, "report.html")
    with open(path, "w", encoding="utf-8") as f:
        f.write("\n".join(parts))
    return path
