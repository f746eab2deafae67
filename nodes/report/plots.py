"""The flight report's plots (matplotlib, Agg canvas: no display needed).

Each ``plot_*`` function writes PNG file(s) into the run folder and returns the file name(s)
relative to it. Long runs are downsampled to at most ``MAX_POINTS`` samples per line.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import matplotlib

matplotlib.use("Agg")
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter  # noqa: E402

from nodes.report.metrics import GOTO_KINDS, wrap_deg  # noqa: E402

MAX_POINTS = 4000
DPI = 90
POSE, REF, GOAL = "#1f77b4", "#444444", "#d62728"
OUTCOME_COLOURS = {
    "SUCCESS": "#2e7d32",
    "FAILURE": "#c62828",
    "halted": "#f9a825",
    "running": "#78909c",
}


def _every(n: int, limit: int = MAX_POINTS) -> slice:
    return slice(None, None, max(1, math.ceil(n / limit)))


def _figure(
    w: float,
    h: float,
    left: float = 0.85,
    right: float = 0.2,
    top: float = 0.35,
    bottom: float = 0.6,
    hspace: float = 0.0,
    wspace: float = 0.0,
) -> Figure:
    """A figure with fixed margins in inches (constrained layout costs ~0.3 s a figure)."""
    fig = Figure(figsize=(w, h))
    fig.subplots_adjust(
        left=left / w,
        right=1 - right / w,
        top=1 - top / h,
        bottom=bottom / h,
        hspace=hspace,
        wspace=wspace,
    )
    return fig


def _save(fig: Figure, run_dir: str, name: str) -> str:
    fig.savefig(os.path.join(run_dir, name), dpi=DPI, pil_kwargs={"compress_level": 2})
    return name


def _note_if_empty(ax, values: np.ndarray) -> None:
    if not np.isfinite(values).any():
        ax.text(
            0.5,
            0.5,
            "no reference in the trace",
            transform=ax.transAxes,
            ha="center",
            color="#777777",
        )


def _motion_marks(ax, rows: Sequence[dict], t_span: float, label: bool) -> None:
    """Dotted lines at each motion start; its number (the table's #) above the top axis."""
    last = -math.inf
    for r in rows:
        ax.axvline(r["t_start"], color="#bbbbbb", lw=0.7, ls=":", zorder=0)
        if label and r["t_start"] - last > 0.011 * (len(str(r["n"])) + 1) * t_span:
            ax.annotate(
                str(r["n"]),
                (r["t_start"], 1.0),
                xycoords=("data", "axes fraction"),
                xytext=(2, 2),
                textcoords="offset points",
                fontsize=8,
                color="#555555",
            )
            last = r["t_start"]


def pallet_outline(p: dict, length_m: float = 1.2, depth_m: float = 0.8) -> np.ndarray:
    """The footprint corners (x, y) of a pallet from its ground truth (``sim.pallets``)."""
    cx, cy = p["centre_m"]
    f = math.radians(p["facing_deg"])
    n = np.array([math.cos(f), math.sin(f)])  # out of the shown face
    t = np.array([-n[1], n[0]])  # along the face
    c = np.array([cx, cy])
    return np.array(
        [
            c + a * n * depth_m / 2 + b * t * length_m / 2
            for a, b in ((1, 1), (1, -1), (-1, -1), (-1, 1))
        ]
    )


def plot_xy(
    run_dir: str,
    tel: dict,
    rows: Sequence[dict],
    pallets: Sequence[dict] = (),
    faces: Sequence[dict] = (),
) -> str:
    """Top view: pose, reference, start/end, each motion's goal labelled with its #, the
    pallets where the simulator stood them (ground truth, identity written on each) and the
    pallet face the reactive scan estimated (``perception.faces``: first and last)."""
    s = _every(len(tel["t"]))
    x, y, rx, ry = tel["x"][s], tel["y"][s], tel["ref_x"][s], tel["ref_y"][s]
    outlines = [pallet_outline(p) for p in pallets]
    px = [o[:, 0] for o in outlines] or [np.zeros(0)]
    py = [o[:, 1] for o in outlines] or [np.zeros(0)]
    xs = np.concatenate([x, rx[np.isfinite(rx)], [r["goal"][0] for r in rows], *px])
    ys = np.concatenate([y, ry[np.isfinite(ry)], [r["goal"][1] for r in rows], *py])
    xs, ys = xs[np.isfinite(xs)], ys[np.isfinite(ys)]
    span_x, span_y = max(np.ptp(xs), 0.5), max(np.ptp(ys), 0.5)
    height = min(max(7.5 * span_y / span_x, 2.6), 7.5) + 1.6
    fig = _figure(9, height, left=0.8, bottom=0.55, top=0.2)
    ax = fig.add_subplot()
    for i, (p, o) in enumerate(zip(pallets, outlines, strict=True)):
        ax.fill(o[:, 0], o[:, 1], fc="#d7b98e", ec="#8d6e42", lw=1,
                label="pallet (side shown)" if i == 0 else None)  # fmt: skip
        fx, fy = p["face_centre_m"][:2]
        ax.plot([fx], [fy], "|", color="#8d6e42", ms=10)
        ax.annotate(p["identity"], p["centre_m"], ha="center", va="center", fontsize=8,
                    color="#4e3b1f")  # fmt: skip
    shown = [faces[0], faces[-1]] if len(faces) > 1 else list(faces)
    for i, f in enumerate(shown):
        fx, fy = f["centre_m"][:2]
        a = math.radians(f["facing_deg"])
        lx, ly = -math.sin(a) * 0.6, math.cos(a) * 0.6  # half a pallet along the face
        ax.plot([fx - lx, fx + lx], [fy - ly, fy + ly], color="#6a1b9a", lw=2,
                ls=":" if i == 0 and len(shown) > 1 else "-",
                label=f"face estimated ({f['stage']})")  # fmt: skip
    ax.plot(rx, ry, color=REF, ls="--", lw=1, label="reference")
    ax.plot(x, y, color=POSE, lw=1.4, label="pose (mocap)")
    ax.plot(x[:1], y[:1], "^", color="#2e7d32", ms=8, label="start")
    ax.plot(x[-1:], y[-1:], "s", color="#000000", ms=6, mfc="none", label="end")
    # Goals closer than 2 % of the plot's size share one label ("1,7,8").
    tol = 0.02 * max(span_x, span_y)
    groups: list[tuple[float, float, list[int]]] = []
    for r in rows:
        gx, gy = float(r["goal"][0]), float(r["goal"][1])
        if not (math.isfinite(gx) and math.isfinite(gy)):
            continue
        for g in groups:
            if math.hypot(g[0] - gx, g[1] - gy) < tol:
                g[2].append(r["n"])
                break
        else:
            groups.append((gx, gy, [r["n"]]))
    if groups:
        ax.plot(
            [g[0] for g in groups],
            [g[1] for g in groups],
            "x",
            color=GOAL,
            ms=8,
            mew=2,
            zorder=5,
            label="goal (# = table row)",
        )
    for gx, gy, ns in groups:
        text = ",".join(map(str, ns)) if len(ns) <= 6 else f"{ns[0]}..{ns[-1]}"
        ax.annotate(
            text,
            (gx, gy),
            xytext=(6, 6),
            textcoords="offset points",
            fontsize=9,
            color=GOAL,
            bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8},
        )
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8, framealpha=0.85)
    return _save(fig, run_dir, "xy.png")


def plot_position(run_dir: str, tel: dict, rows: Sequence[dict]) -> str:
    """x, y, z against the reference over time, and the tracking error |pose - reference|."""
    s = _every(len(tel["t"]))
    t = tel["t"][s]
    fig = _figure(9, 8, top=0.3, hspace=0.12)
    axes = fig.subplots(4, 1, sharex=True, gridspec_kw={"height_ratios": [1, 1, 1, 0.8]})
    for ax, k in zip(axes[:3], "xyz", strict=False):
        ax.plot(t, tel["ref_" + k][s], color=REF, ls="--", lw=1, label="reference")
        ax.plot(t, tel[k][s], color=POSE, lw=1.2, label="pose")
        ax.set_ylabel(f"{k} (m)")
    err = np.sqrt(sum((tel[k][s] - tel["ref_" + k][s]) ** 2 for k in "xyz"))
    axes[3].plot(t, err * 100, color=GOAL, lw=1)
    _note_if_empty(axes[3], err)
    axes[3].set_ylabel("|pose - ref| (cm)")
    axes[3].set_ylim(bottom=0)
    axes[3].set_xlabel("mission time (s); dotted lines: motion starts, numbered as in the table")
    axes[0].legend(loc="upper right", fontsize=8, ncol=2)
    span = float(t[-1] - t[0]) or 1.0
    for i, ax in enumerate(axes):
        ax.grid(True, alpha=0.3)
        _motion_marks(ax, rows, span, label=i == 0)
    return _save(fig, run_dir, "position.png")


def _unwrap_deg(a: np.ndarray) -> np.ndarray:
    """Unwrap an angle series in degrees, ignoring NaNs (kept as NaN)."""
    out = np.full_like(a, np.nan)
    ok = np.isfinite(a)
    if ok.any():
        out[ok] = np.degrees(np.unwrap(np.radians(a[ok])))
    return out


def plot_yaw(run_dir: str, tel: dict, rows: Sequence[dict]) -> str:
    """Yaw and its reference in degrees (unwrapped, on the same branch), goal yaws, error."""
    t = tel["t"]
    ref = _unwrap_deg(np.degrees(tel["ref_yaw"]))
    # The pose is drawn on the reference's branch (ref + wrapped error); before the first
    # reference it is unwrapped on its own, starting in [-180, 180).
    raw = _unwrap_deg(np.degrees(tel["yaw"]))
    err = wrap_deg(np.degrees(tel["yaw"]) - ref)
    yaw = np.where(np.isfinite(ref), ref + err, raw)
    s = _every(len(t))
    fig = _figure(9, 5, top=0.3, hspace=0.12)
    ax, ax2 = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    ax.plot(t[s], ref[s], color=REF, ls="--", lw=1, label="reference")
    ax.plot(t[s], yaw[s], color=POSE, lw=1.2, label="yaw")
    first = True
    for r in rows:
        if not math.isfinite(r["goal_yaw_deg"]):
            continue
        i = min(r["window"].stop, len(t)) - 1
        base = ref[i] if math.isfinite(ref[i]) else yaw[i]
        g = base + float(wrap_deg(r["goal_yaw_deg"] - base))
        ax.hlines(
            g,
            r["t_start"],
            r["t_end"],
            color=GOAL,
            lw=2.5,
            alpha=0.6,
            label="goal yaw" if first else None,
        )
        first = False
    ax.set_ylabel("yaw (deg)")
    ax.legend(loc="best", fontsize=8)
    ax2.plot(t[s], err[s], color=GOAL, lw=1)
    _note_if_empty(ax2, err)
    ax2.axhline(0, color="#888888", lw=0.6)
    ax2.set_ylabel("yaw - ref (deg)")
    ax2.set_xlabel("mission time (s); dotted lines: motion starts, numbered as in the table")
    span = float(t[-1] - t[0]) or 1.0
    for i, a in enumerate((ax, ax2)):
        a.grid(True, alpha=0.3)
        _motion_marks(a, rows, span, label=i == 0)
    return _save(fig, run_dir, "yaw.png")


def plot_goto_errors(run_dir: str, tel: dict, rows: Sequence[dict]) -> str | None:
    """Distance to go (log scale) and yaw error of every go-to against the time since it
    started, one colour per go-to, thresholds dashed; a dot where it reached its goal."""
    gotos = [r for r in rows if r["kind"] in GOTO_KINDS and r["window"].stop > r["window"].start]
    if not gotos:
        return None
    fig = _figure(9, 6.2, right=2.3, top=0.3, hspace=0.3)
    ad, ay = fig.subplots(2, 1, sharex=True)
    colours = matplotlib.colormaps["tab10" if len(gotos) <= 10 else "tab20"].colors
    y_lim = 0.0
    for i, r in enumerate(gotos):
        w = r["window"]
        s = _every(w.stop - w.start, 1500)
        t = tel["t"][w][s] - r["t_start"]
        pos = np.stack([tel[k][w][s] for k in "xyz"], axis=1)
        dist = np.maximum(np.linalg.norm(pos - r["goal"], axis=1), 1e-4)
        yaw_err = wrap_deg(r["goal_yaw_deg"] - np.degrees(tel["yaw"][w][s]))
        c = colours[i % len(colours)]
        label = f"#{r['n']} {r['label']}" + (
            "" if r["result"] == "SUCCESS" else f" ({r['result']})"
        )
        ad.plot(t, dist, color=c, lw=1.2, label=label if i < 24 else None)
        ay.plot(t, yaw_err, color=c, lw=1.2)
        if r["reach"] is not None:
            k = min(int(np.searchsorted(t, r["reach"] - 1e-9)), len(t) - 1)
            ad.plot(t[k], dist[k], "o", color=c, ms=4)
            ay.plot(t[k], yaw_err[k], "o", color=c, ms=4)
        y_lim = max(y_lim, float(np.nanmax(np.abs(yaw_err), initial=0.0)))
    for thr in sorted({r["pos_thr"] for r in gotos}):
        ad.axhline(thr, color=GOAL, ls="--", lw=1)
        ad.annotate(
            f"{thr * 100:g} cm",
            (0.0, thr),
            xycoords=("axes fraction", "data"),
            xytext=(3, 3),
            textcoords="offset points",
            fontsize=8,
            color=GOAL,
        )
    thrs = sorted({r["yaw_thr_deg"] for r in gotos})
    for thr in thrs:
        for sign in (1, -1):
            ay.axhline(sign * thr, color=GOAL, ls="--", lw=1)
        ay.annotate(
            f"\u00b1{thr:g} deg",
            (0.0, thr),
            xycoords=("axes fraction", "data"),
            xytext=(3, 3),
            textcoords="offset points",
            fontsize=8,
            color=GOAL,
        )
    lim = min(max(2 * thrs[-1], y_lim * 1.1), 185)
    ay.set_ylim(-lim, lim)
    ad.set_ylabel("distance to goal (m)")
    ay.set_ylabel("goal yaw - yaw (deg)")
    ay.set_xlabel("time since the go-to started (s); dot: goal reached")
    ad.set_yscale("log")
    ad.yaxis.set_minor_locator(LogLocator(subs=(2.0, 5.0)))  # fewer minor ticks: ~0.2 s less
    ad.yaxis.set_minor_formatter(NullFormatter())
    ad.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))  # 0.01, not 10^-2
    ad.grid(True, which="major", alpha=0.3)
    ay.grid(True, alpha=0.3)
    if len(gotos) > 24:
        ad.plot([], [], " ", label=f"... and {len(gotos) - 24} more")
    ad.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    return _save(fig, run_dir, "goto_errors.png")


def plot_timeline(
    run_dir: str, spans: Sequence[tuple[str, float, float, str]], labels: Sequence[str]
) -> str | None:
    """Gantt chart of the actions: one row per action node, bars coloured by outcome."""
    if not spans:
        return None
    order: dict[str, int] = {}
    for path, *_ in spans:
        order.setdefault(path, len(order))
    names = {p: lab for (p, *_), lab in zip(spans, labels, strict=True)}
    t0 = min(s[1] for s in spans)
    t1 = max(s[2] for s in spans)
    min_w = max((t1 - t0) * 0.003, 1e-3)
    fig = _figure(9, 1.0 + 0.3 * len(order), left=1.9, top=0.15, bottom=0.55)
    ax = fig.add_subplot()
    by_row: dict[tuple[int, str], list[tuple[float, float]]] = {}
    for path, a, b, outcome in spans:
        by_row.setdefault((order[path], outcome), []).append((a, max(b - a, min_w)))
    for (row, outcome), bars in by_row.items():
        ax.broken_barh(bars, (row - 0.35, 0.7), facecolors=OUTCOME_COLOURS.get(outcome, "#78909c"))
    ax.set_yticks(range(len(order)), [names[p] for p in order], fontsize=8)
    ax.set_ylim(len(order) - 0.5, -0.5)
    ax.set_xlabel("mission time (s)")
    ax.grid(True, axis="x", alpha=0.3)
    seen = {o for _, _, _, o in spans}
    handles = [Patch(color=c, label=o) for o, c in OUTCOME_COLOURS.items() if o in seen]
    ax.legend(handles=handles, loc="upper right", fontsize=8)
    return _save(fig, run_dir, "timeline.png")
