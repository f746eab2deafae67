"""The flight report's figures: telemetry columns, per-motion tracking metrics, action spans.

Pure functions of the run's per-tick trace and the motion records the flight leaves keep in
``mission.ctx.resources["motions"]`` (numpy only, no plotting): :func:`wrap_deg`,
:func:`wrap_rad`, :func:`rms`, :func:`settle_time`, :func:`telemetry_arrays`,
:func:`motion_metrics` (the tracking table's rows), :func:`motion_summary` (the same for
``summary.json``), :func:`short_labels` and
:func:`action_spans`. Usable on their own, e.g. by ``bench/square_quality.py``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

#: Motions whose distance-to-go and yaw error get their own plot.
GOTO_KINDS = ("GoTo", "FollowPath")
_VEHICLE_KEYS = ("x", "y", "z", "yaw", "ref_x", "ref_y", "ref_z", "ref_yaw")


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


def _finite(x: Any) -> float | None:
    return float(x) if x is not None and math.isfinite(float(x)) else None


def motion_summary(motions: Sequence[dict], tel: dict[str, np.ndarray]) -> list[dict]:
    """The motion table as ``summary.json``'s ``motions``: per motion its ``n``, ``label``,
    ``node``, ``kind``, ``result``, thresholds and figures in SI units with the unit in the
    key (``reach_s``, ``settle_s``, ``final_dist_m``, ``final_yaw_deg``, ``track_max_m``,
    ``track_rms_m``; null: not measured, e.g. never settled)."""
    return [
        {
            "n": r["n"],
            "label": r["label"],
            "node": r["node"],
            "kind": r["kind"],
            "result": r["result"],
            "pos_threshold_m": _finite(r["pos_thr"]),
            "yaw_threshold_deg": _finite(r["yaw_thr_deg"]),
            "t_start_s": _finite(r["t_start"]),
            "duration_s": _finite(r["duration"]),
            "reach_s": _finite(r["reach"]),
            "settle_s": _finite(r["settle"]),
            "final_dist_m": _finite(r["final_dist"]),
            "final_yaw_deg": _finite(r["final_yaw_deg"]),
            "track_max_m": _finite(r["track_max"]),
            "track_rms_m": _finite(r["track_rms"]),
        }
        for r in motion_metrics(motions, tel)
    ]


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
