"""The flight report of a run: ``report.html`` and PNG plots, written into the run folder.

``write_report(run_dir, trace, summary, mission)`` is called by ``btrun run`` at the end of a
flight (see ``docs/report.md``). It reads the per-tick trace (vehicle pose and reference,
node status changes) and the motion records the flight leaves keep in
``mission.ctx.resources["motions"]``, and writes:

* ``report.html``: run summary, simulator ground truth, the tracking-error table (one row
  per motion), and the plots, linked relatively (copy the folder, the report still works);
* ``xy.png``, ``position.png``, ``yaw.png``, ``goto_errors.png``, ``timeline.png``.

The pure helpers (:func:`wrap_deg`, :func:`rms`, :func:`settle_time`,
:func:`telemetry_arrays`, :func:`motion_metrics`, :func:`action_spans`) are usable on
their own, e.g. by ``bench/square_quality.py``.
"""

from __future__ import annotations

import html
import json
import math
import os
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

#: Motions whose distance-to-go and yaw error get their own plot.
GOTO_KINDS = ("GoTo", "FollowPath")
_VEHICLE_KEYS = ("x", "y", "z", "yaw", "ref_x", "ref_y", "ref_z", "ref_yaw")


# -- pure helpers --------------------------------------------------------------------------
def wrap_deg(a: Any) -> Any:
    """Wrap angles in degrees to [-180, 180)."""
    return (np.asarray(a, dtype=float) + 180.0) % 360.0 - 180.0


def wrap_rad(a: Any) -> Any:
    """Wrap angles in radians to [-pi, pi)."""
    return (np.asarray(a, dtype=float) + math.pi) % (2.0 * math.pi) - math.pi


def rms(values: Iterable[float]) -> float:
    """Root mean square of the finite values (NaN if there are none)."""
    v = np.asarray(list(values) if not isinstance(values, np.ndarray) else values, dtype=float)
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v * v))) if v.size else math.nan


def settle_time(t: Sequence[float], inside: Sequence[bool]) -> float | None:
    """Time from first entering the tolerances to the start of the final stay inside.

    ``inside[i]`` says whether the errors at ``t[i]`` are within the thresholds. Returns
    None when the samples never enter, or are not inside at the end (never settled); 0.0
    when the first entry is also the last.
    """
    ins = np.asarray(inside, dtype=bool)
    if ins.size == 0 or not ins[-1]:
        return None
    first = int(np.argmax(ins))
    outside = np.flatnonzero(~ins)
    entry = int(outside[-1]) + 1 if outside.size else 0
    return float(t[entry] - t[first])


def telemetry_arrays(trace: Sequence[dict]) -> dict[str, np.ndarray] | None:
    """Columns of the trace's vehicle rows: ``t`` and the _VEHICLE_KEYS (NaN where missing)."""
    rows = [(r["t"], r["vehicle"]) for r in trace if r.get("vehicle")]
    if not rows:
        return None
    nan = math.nan
    cols = {"t": np.fromiter((t for t, _ in rows), float, len(rows))}
    for k in _VEHICLE_KEYS:
        cols[k] = np.fromiter((v.get(k, nan) for _, v in rows), float, len(rows))
    return cols


def _window(tel: dict[str, np.ndarray], t0: float, t1: float) -> slice:
    t = tel["t"]
    return slice(
        int(np.searchsorted(t, t0 - 1e-9, "left")), int(np.searchsorted(t, t1 + 1e-9, "right"))
    )


def motion_metrics(motions: Sequence[dict], tel: dict[str, np.ndarray]) -> list[dict]:
    """One row of figures per motion record (distances in m, angles in degrees, times in s).

    Keys: n, label, node, kind, goal, goal_yaw_deg, pos_thr, yaw_thr_deg, result, reason,
    t_start, t_end, duration, reach, track_max, track_rms, final_dist, final_yaw_deg,
    settle. Errors are measured on the trace's pose (what the vehicle flew on); the final
    errors are the ones the leaf saw when it finished.
    """
    labels = short_labels([m.get("node", m.get("name", "?")) for m in motions])
    t_last = float(tel["t"][-1])
    rows = []
    for i, (m, label) in enumerate(zip(motions, labels, strict=True), 1):
        t0 = float(m.get("t_start") or 0.0)
        t1 = float(m["t_end"]) if m.get("t_end") is not None else t_last
        w = _window(tel, t0, t1)
        t = tel["t"][w]
        goal = np.asarray(m.get("goal") or (math.nan,) * 3, dtype=float)
        pos = np.stack([tel["x"][w], tel["y"][w], tel["z"][w]], axis=1)
        ref = np.stack([tel["ref_x"][w], tel["ref_y"][w], tel["ref_z"][w]], axis=1)
        dist = np.linalg.norm(pos - goal, axis=1)
        goal_yaw = m.get("goal_yaw_rad")
        yaw_err = np.degrees(
            wrap_rad((goal_yaw if goal_yaw is not None else math.nan) - tel["yaw"][w])
        )
        track = np.linalg.norm(pos - ref, axis=1)
        track = track[np.isfinite(track)]
        pos_thr = float(m.get("pos_threshold_m") or math.nan)
        yaw_thr = math.degrees(float(m.get("yaw_threshold_rad") or math.nan))
        inside = (dist <= pos_thr) & (np.abs(yaw_err) <= yaw_thr)
        final_dist = m.get("final_distance_m")
        final_yaw = m.get("final_yaw_error_rad")
        if inside.size and final_dist is not None and final_yaw is not None:
            # the last sample is judged as the leaf judged it (the trace rounds to 0.1 mm)
            inside[-1] = final_dist <= pos_thr and abs(math.degrees(final_yaw)) <= yaw_thr
        result = m.get("result", "?")
        rows.append(
            {
                "n": i,
                "label": label,
                "node": m.get("node", ""),
                "kind": m.get("kind", "?"),
                "goal": goal,
                "goal_yaw_deg": math.degrees(goal_yaw) if goal_yaw is not None else math.nan,
                "pos_thr": pos_thr,
                "yaw_thr_deg": yaw_thr,
                "result": "halted" if result == "IDLE" else result,
                "reason": m.get("reason", ""),
                "t_start": t0,
                "t_end": t1,
                "duration": t1 - t0,
                "reach": m["t_reached"] - t0 if m.get("t_reached") is not None else None,
                "track_max": float(track.max()) if track.size else math.nan,
                "track_rms": rms(track),
                "final_dist": float(final_dist)
                if final_dist is not None
                else (float(dist[-1]) if dist.size else math.nan),
                "final_yaw_deg": math.degrees(final_yaw)
                if final_yaw is not None
                else (float(yaw_err[-1]) if yaw_err.size else math.nan),
                "settle": settle_time(t, inside) if t.size else None,
                "window": w,
            }
        )
    return rows


def short_labels(paths: Sequence[str]) -> list[str]:
    """The shortest path suffixes that tell the given node paths apart (a/b/goto -> b/goto)."""
    parts = [p.split("/") for p in paths]
    out = []
    for i, p in enumerate(parts):
        k = 1
        while k < len(p) and any(
            j != i and q[-k:] == p[-k:] and q != p for j, q in enumerate(parts)
        ):
            k += 1
        out.append("/".join(p[-k:]))
    return out


def action_spans(
    trace: Sequence[dict], leaves: Sequence[str] | None = None
) -> list[tuple[str, float, float, str]]:
    """When each action ran: ``(path, t_start, t_end, outcome)`` from the trace's statuses.

    Outcome is SUCCESS, FAILURE, halted, or running (still going when the trace ends). A
    synchronous action has t_start == t_end. ``leaves`` limits the paths (None: every path
    that appears in a ``done`` entry); spans that start together keep the order of ``leaves``.
    """
    if leaves is None:
        leaves = sorted({p for r in trace for p in r.get("done", ())})
    rank = {p: i for i, p in enumerate(leaves)}
    wanted = set(leaves)
    started: dict[str, float] = {}
    spans: list[tuple[str, float, float, str]] = []
    t = 0.0
    for r in trace:
        changed, done = r.get("changed"), r.get("done")
        if not changed and not done:
            continue
        t = r["t"]
        changed, done = changed or {}, done or {}
        for path in wanted.intersection(changed.keys() | done.keys()):
            st = changed.get(path)
            final = done.get(path) or (st if st in ("SUCCESS", "FAILURE") else None)
            if final:
                spans.append((path, started.pop(path, t), t, final))
            elif st == "IDLE" and path in started:
                spans.append((path, started.pop(path), t, "halted"))
            if st == "RUNNING":
                started.setdefault(path, t)
    t_end = trace[-1]["t"] if trace else t
    spans += [(p, t0, t_end, "running") for p, t0 in started.items()]
    return sorted(spans, key=lambda s: (s[1], s[2], rank[s[0]]))


def _action_leaves(mission: Any) -> list[str] | None:
    nodes = getattr(mission, "nodes", None)
    if not nodes:
        return None
    return [n.path for n in nodes if n.kind == "Action" and not n.children]


# -- the report ----------------------------------------------------------------------------
def write_report(run_dir: str, trace: Sequence[dict], summary: dict, mission: Any) -> str | None:
    """Write ``report.html`` and its PNG plots into ``run_dir``; return the HTML path.

    Returns None (and writes nothing) when the trace holds no vehicle data.
    """
    tel = telemetry_arrays(trace)
    if tel is None:
        return None
    from nodes import report_plots as plots

    os.makedirs(run_dir, exist_ok=True)
    ctx = getattr(mission, "ctx", None)
    motions = list(getattr(ctx, "resources", {}).get("motions", ()))
    rows = motion_metrics(motions, tel)
    spans = action_spans(trace, _action_leaves(mission))
    figures = [
        ("Trajectory (top view)", plots.plot_xy(run_dir, tel, rows)),
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
    from nodes.report_perception import perception_section

    extra = perception_section(run_dir, mission)
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
th{background:#f4f4f4}td.l,th.l{text-align:left}tr:nth-child(even) td{background:#fafafa}
.kv td:first-child{text-align:left;color:#555}.kv td{text-align:left;white-space:normal}
.SUCCESS{color:#1a7f37;font-weight:600}.FAILURE,.ABORTED,.bad{color:#c62828;font-weight:600}
.halted,.running{color:#8a6d00;font-weight:600}
img{max-width:100%;border:1px solid #eee;margin:.4em 0}.note{color:#555;font-size:.9em}
"""


def _fmt(v: Any, spec: str = ".3f", scale: float = 1.0) -> str:
    """A number for the tables; an em dash for missing values; never "-0.00"."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
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
    return "<table>" + head + "".join(body) + "</table>"


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
        "<h2>Run</h2>",
        _kv_table(run),
    ]
    if truth:
        label = "Simulator ground truth" if "sim" in summary else "Vehicle"
        out += [f"<h2>{label}</h2>", _kv_table(truth.items())]
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
        '<p class="note">Written by btrun (nodes/report.py); see docs/report.md.</p></body></html>'
    )
    return "\n".join(out)
