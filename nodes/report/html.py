"""The flight report of a run: ``report.html`` and its PNG plots, written into the run folder.

``write_report(run_dir, trace, summary, mission)`` is called by ``btrun run`` at the end of a
flight (see ``docs/report.md``). It reads the per-tick trace (vehicle pose and reference,
node status changes) and the motion records the flight leaves keep in
``mission.ctx.resources["motions"]``, and writes:

* ``report.html``: run summary, simulator ground truth, the tracking-error table (one row
  per motion, from :mod:`nodes.report.metrics`), the perception section
  (:mod:`nodes.report.perception`) and the plots, linked relatively (copy the folder, the
  report still works);
* ``xy.png``, ``position.png``, ``yaw.png``, ``goto_errors.png``, ``timeline.png``
  (:mod:`nodes.report.plots`).
"""

from __future__ import annotations

import html
import json
import math
import os
from collections.abc import Iterable, Sequence
from typing import Any

from bt_engine.spec import plural
from nodes.report.metrics import action_spans, motion_metrics, short_labels, telemetry_arrays


def _action_leaves(mission: Any) -> list[str] | None:
    nodes = getattr(mission, "nodes", None)
    if not nodes:
        return None
    return [n.path for n in nodes if n.kind == "Action" and not n.children]


def write_report(run_dir: str, trace: Sequence[dict], summary: dict, mission: Any) -> str | None:
    """Write ``report.html`` and its PNG plots into ``run_dir``; return the HTML path.

    Returns None (and writes nothing) when the trace holds no vehicle data.
    """
    tel = telemetry_arrays(trace)
    if tel is None:
        return None
    import nodes.report.plots as plots  # matplotlib: only once there is something to plot

    os.makedirs(run_dir, exist_ok=True)
    ctx = getattr(mission, "ctx", None)
    motions = list(getattr(ctx, "resources", {}).get("motions", ()))
    rows = motion_metrics(motions, tel)
    spans = action_spans(trace, _action_leaves(mission))
    figures = [
        (
            "Trajectory (top view)",
            plots.plot_xy(
                run_dir,
                tel,
                rows,
                ((summary or {}).get("sim") or {}).get("pallets", ()),
                ((summary or {}).get("perception") or {}).get("faces", ()),
            ),
        ),
        ("Position and reference per axis", plots.plot_position(run_dir, tel, rows)),
        ("Yaw and reference", plots.plot_yaw(run_dir, tel, rows)),
    ]
    figures += [
        ("Distance to go and yaw error per go-to", plots.plot_goto_errors(run_dir, tel, rows)),
        (
            "When each action ran",
            plots.plot_timeline(run_dir, spans, short_labels([s[0] for s in spans])),
        ),
    ]
    from nodes.report.inventory import inventory_section
    from nodes.report.perception import perception_section

    extra = inventory_section(run_dir, summary or {}) + perception_section(run_dir, mission)
    path = os.path.join(run_dir, "report.html")
    with open(path, "w", encoding="utf-8") as f:
        f.write(
            _html(summary or {}, mission, rows, [(c, n) for c, n in figures if n], trace, extra)
        )
    return path


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:1.5em auto;
max-width:1100px;padding:0 1em;color:#222;line-height:1.4}
h1{font-size:1.5em;margin-bottom:.2em}h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:.9em;margin:.5em 0}
th,td{border:1px solid #ddd;padding:.25em .5em;text-align:right;white-space:nowrap}
.wide{overflow-x:auto;max-width:100%}.wide td.l{white-space:normal;min-width:12em}
th{background:#f4f4f4}td.l,th.l{text-align:left}tr:nth-child(even) td{background:#fafafa}
.kv td:first-child{text-align:left;color:#555}.kv td{text-align:left;white-space:normal}
.SUCCESS{color:#1a7f37;font-weight:600}.FAILURE,.ABORTED,.bad{color:#c62828;font-weight:600}
.halted,.running{color:#8a6d00;font-weight:600}
img{max-width:100%;border:1px solid #eee;margin:.4em 0}.note{color:#555;font-size:.9em}
"""


def _fmt(v: Any, spec: str = ".3f", scale: float = 1.0) -> str:
    """A number for the tables; an em dash for missing values; never "-0.00"."""
    if isinstance(v, str):  # summary.json keeps inf and nan as text ("inf")
        try:
            v = float(v)
        except ValueError:
            return html.escape(v)
    if v is None or isinstance(v, bool) or (isinstance(v, float) and not math.isfinite(v)):
        return "\u2014"
    text = format(v * scale, spec)
    return text[1:] if text.startswith("-") and not text.strip("-0.") else text


def _kv_table(items: Iterable[tuple[str, Any]]) -> str:
    cells = []
    for k, v in items:
        if isinstance(v, dict):
            v = ", ".join(f"{a} {b}" for a, b in v.items())
        elif isinstance(v, (list, tuple)):
            v = json.dumps(v) if v else "none"
        cells.append(f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(str(v))}</td></tr>")
    return '<table class="kv">' + "".join(cells) + "</table>"


def _motion_table(rows: list[dict]) -> str:
    head = (
        "<tr><th>#</th><th class=l>motion</th><th class=l>kind</th><th>goal x, y, z (m)</th>"
        "<th>goal yaw (deg)</th><th>thresholds</th><th class=l>result</th><th>duration (s)</th>"
        "<th>to reach (s)</th><th>track max (cm)</th><th>track RMS (cm)</th>"
        "<th>final pos err (cm)</th><th>final yaw err (deg)</th><th>settle (s)</th></tr>"
    )
    body = []
    for r in rows:
        g = r["goal"]
        pos_bad = " bad" if r["final_dist"] > r["pos_thr"] else ""
        yaw_bad = " bad" if abs(r["final_yaw_deg"]) > r["yaw_thr_deg"] else ""
        tip = html.escape(r["node"] + (f" - {r['reason']}" if r["reason"] else ""), quote=True)
        body.append(
            f'<tr class="motion"><td>{r["n"]}</td><td class=l title="{tip}">{html.escape(r["label"])}</td>'
            f"<td class=l>{html.escape(r['kind'])}</td>"
            f"<td>{_fmt(g[0], '.2f')}, {_fmt(g[1], '.2f')}, {_fmt(g[2], '.2f')}</td>"
            f"<td>{_fmt(r['goal_yaw_deg'], '.1f')}</td>"
            f"<td>{_fmt(r['pos_thr'], '.1f', 100)} cm / {_fmt(r['yaw_thr_deg'], '.0f')}&deg;</td>"
            f'<td class="l {html.escape(r["result"])}">{html.escape(r["result"])}</td>'
            f"<td>{_fmt(r['duration'], '.2f')}</td><td>{_fmt(r['reach'], '.2f')}</td>"
            f"<td>{_fmt(r['track_max'], '.1f', 100)}</td><td>{_fmt(r['track_rms'], '.1f', 100)}</td>"
            f'<td class="{pos_bad}">{_fmt(r["final_dist"], ".2f", 100)}</td>'
            f'<td class="{yaw_bad}">{_fmt(r["final_yaw_deg"], ".1f")}</td>'
            f"<td>{_fmt(r['settle'], '.2f')}</td></tr>"
        )
    return '<div class="wide"><table>' + head + "".join(body) + "</table></div>"


def discrepancy_counts(inv: dict) -> str:
    """``discrepancies: 12 confirmed, 1 mismatch, ...`` of a summary's ``inventory`` (and,
    in simulation, how many rows are right)."""
    c = inv.get("discrepancies") or {}
    line = "discrepancies: " + ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in c.items())
    g = inv.get("discrepancy_grades")
    if g:
        line += (
            f"; against the simulator {g['right']} right, {len(g['false_alarms'])} false "
            f"alarms, {len(g['missed'])} missed"
        )
    return line


def answer_section(summary: dict) -> str:
    """The run's answer first, as the console's lines give it: each identification (pallet,
    distance, margin, what decided it) and, for an inventory, the places and counts."""
    esc = html.escape
    items = []
    inv = summary.get("inventory") or {}
    if inv.get("discrepancies"):  # with an expected stock the counts per category lead
        items.append(discrepancy_counts(inv))
    if inv.get("places"):
        status = inv.get("status") or {}
        counts = ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in status.items() if n)
        line = f"inventory: {plural(inv['places'], 'place')}, {counts}"
        if "right" in inv:
            line += (
                f"; against the simulator {inv['right']} right, {inv.get('unknown', 0)} "
                f"unknown, {inv.get('wrong', 0)} wrong"
            )
        items.append(line)
    else:
        for r in (summary.get("perception") or {}).get("identifications") or []:
            if "failed" in r:
                items.append(f"pallet: failed: {r['failed']}")
                continue
            items.append(
                f"pallet: {r.get('pallet_id')} (distance {_fmt(r.get('distance'))}, margin "
                f"{_fmt(r.get('margin'))}, decided by {r.get('decided_by') or 'embedding'})"
            )
    if not items:
        return ""
    return "<h2>Answer</h2><ul>" + "".join(f"<li>{esc(i)}</li>" for i in items[:20]) + "</ul>"


def _pallets_table(pallets: list) -> str:
    """The simulator's pallets (``sim.pallets``): one row per pallet."""
    rows = []
    for p in pallets:
        if not isinstance(p, dict):
            continue
        centre = p.get("centre_m") or []
        rows.append(
            f"<tr><td class=l>{html.escape(str(p.get('identity', '')))}</td>"
            f"<td class=l>{html.escape(str(p.get('slot', '')))}</td>"
            f"<td>{', '.join(_fmt(c, '.2f') for c in centre)}</td>"
            f"<td>{_fmt(p.get('base_z_m'), '.2f')}</td><td>{_fmt(p.get('facing_deg'), '.1f')}</td></tr>"
        )
    return (
        "<h3>Pallets</h3><table><tr><th class=l>identity</th><th class=l>place</th>"
        "<th>centre (m)</th><th>base z (m)</th><th>facing (deg)</th></tr>"
        + "".join(rows)
        + "</table>"
    )


def _html(
    summary: dict,
    mission: Any,
    rows: list[dict],
    figures: list[tuple[str, str]],
    trace: Sequence[dict],
    extra: str = "",
) -> str:
    esc = html.escape
    spec = getattr(mission, "spec", None)
    mission_file = summary.get("mission") or getattr(spec, "file", "") or "?"
    tree = spec.main_tree_id() if spec is not None else None
    status = str(summary.get("status", getattr(getattr(mission, "status", None), "value", "?")))
    truth = summary.get("sim") or summary.get("vehicle") or {}
    seed = summary.get("seed", truth.get("seed"))
    run = [
        ("mission", mission_file + (f" (tree {tree})" if tree else "")),
        ("status", status),
        ("reason", summary.get("reason", "")),
        ("seed", seed),
        ("ticks", f"{summary.get('ticks', len(trace))} at {summary.get('rate_hz', 50):g} Hz"),
        ("mission time", f"{_fmt(summary.get('mission_time_s'), '.2f')} s"),
        ("wall time", f"{_fmt(summary.get('wall_time_s'), '.2f')} s"),
    ]
    out = [
        "<!DOCTYPE html><html lang=en><head><meta charset=utf-8>",
        f"<title>btrun report: {esc(os.path.basename(mission_file))} {esc(status)}</title>",
        f"<style>{_CSS}</style></head><body>",
        f'<h1>{esc(os.path.basename(mission_file))}: <span class="{esc(status)}">{esc(status)}</span></h1>',
        f"<p>{esc(str(summary.get('reason', '')))}</p>",
        answer_section(summary),
        "<h2>Run</h2>",
        _kv_table(run),
    ]
    if truth:
        label = "Simulator ground truth" if "sim" in summary else "Vehicle"
        plain = [(k, v) for k, v in truth.items() if k != "pallets"]
        out += [f"<h2>{label}</h2>", _kv_table(plain)]
        if truth.get("pallets"):
            out.append(_pallets_table(truth["pallets"]))
    out += [
        "<h2>Motions</h2>",
        '<p class="note">Errors use the pose the vehicle flew on (motion capture). Track = |pose - reference| '
        "during the motion; final errors are what the leaf saw when it finished (red: outside "
        "the threshold); settle = time from first entering both thresholds to the start of the "
        "final stay inside (\u2014: never settled). Hover over a motion for its node path.</p>",
        _motion_table(rows) if rows else "<p>No motion records.</p>",
    ]
    messages = [(r["t"], m) for r in trace for m in r.get("messages", ())]
    if messages:
        items = "".join(f"<li>{_fmt(t, '.2f')} s: {esc(str(m))}</li>" for t, m in messages[:100])
        more = (
            f"<li>... and {len(messages) - 100} more (ticks.jsonl)</li>"
            if len(messages) > 100
            else ""
        )
        out += ["<h2>Messages</h2>", f"<ul>{items}{more}</ul>"]
    if extra:
        out.append(extra)
    for caption, name in figures:
        out += [
            f"<h2>{esc(caption)}</h2>",
            f'<img src="{esc(name, quote=True)}" alt="{esc(caption, quote=True)}">',
        ]
    out.append(
        '<p class="note">Written by btrun (nodes/report/); see docs/report.md.</p></body></html>'
    )
    return "\n".join(out)
