"""Quality campaign of the flight issue: seeded simulated flights of ``missions/square.xml``.

The flights are ``campaigns/square_quality.yaml`` run by the campaign engine (``btrun
campaign``: one worker process per core). Each flight runs with the reference imperfections
(Vicon-grade mocap noise, a few degrees of onboard yaw bias that wanders, light gusts) and a
different seed. A flight passes when the mission succeeds and every GoTo completes within
its 3 cm / 15 deg thresholds and settles within 3 s of arrival (settle: from first entering
both thresholds to the start of the final stay inside, as in the flight report). The
campaign passes when at least 49 of 50 flights do (the same fraction for ``--flights N``).
Prints figures; exit code 0 on a pass.

    .venv/bin/python bench/square_quality.py [--flights 50] [--gust 0.1] [--seed0 0]
        [--set key=value ...] [--workers N] [--out DIR]
        [--report DIR]   # DIR: flight report of the worst flight (flown again, same seed)
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
import tempfile

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

from bt_engine.campaign import load_campaign, run_campaign  # noqa: E402
from bt_engine.campaign.rows import value_text  # noqa: E402
from bt_engine.cli import main as btrun  # noqa: E402

CAMPAIGN = os.path.join(REPO, "campaigns", "square_quality.yaml")
MISSION = os.path.join(REPO, "missions", "square.xml")
POS_THRESHOLD_M = 0.03
YAW_THRESHOLD_DEG = 15.0
SETTLE_LIMIT_S = 3.0
PASS_FRACTION = 49 / 50


def why_failed(row: dict) -> list[str]:
    """Why a flight (a row of the results table) did not pass; empty if it passed."""
    why = []
    if row["status"] != "SUCCESS":
        why.append(f"mission {row['status']}: {row['reason']}")
    results = row["goto_results"] or []
    if len(results) != 4:
        why.append(f"{len(results)} GoTos ran, expected 4")
    cols = ("goto_labels", "goto_results", "final_dist_m", "final_yaw_deg", "settle_s")
    for label, result, dist, yaw, settle in zip(*(row[c] or [] for c in cols), strict=False):
        if result != "SUCCESS":
            why.append(f"{label} {result}")
        if dist is None or yaw is None or dist > POS_THRESHOLD_M or abs(yaw) > YAW_THRESHOLD_DEG:
            why.append(
                f"{label} ended {(dist or math.nan) * 100:.1f} cm / {yaw or math.nan:.1f} deg off"
            )
        if settle is None or settle > SETTLE_LIMIT_S:
            shown = "never" if settle is None else f"{settle:.2f} s"
            why.append(f"{label} settle {shown} (limit {SETTLE_LIMIT_S:g} s)")
    return why


def _dist(name: str, values: list, unit: str, spec: str = ".3f") -> str:
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    if not v.size:
        return f"{name:<28} (no values)"
    q = np.percentile(v, [0, 50, 95, 100])
    cells = "  ".join(
        f"{k} {format(x, spec)}" for k, x in zip(("min", "median", "p95", "max"), q, strict=True)
    )
    return f"{name:<28} {cells} {unit}  (n={v.size})"


def _all(table: list[dict], column: str, scale: float = 1.0, absolute: bool = False) -> list:
    out = []
    for row in table:
        for x in row[column] or []:
            if x is not None:
                out.append(abs(x) * scale if absolute else x * scale)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--flights", type=int, default=50, help="number of seeded flights (default 50)"
    )
    parser.add_argument(
        "--gust", type=float, default=0.1, help="gust standard deviation, m/s (default 0.1)"
    )
    parser.add_argument("--seed0", type=int, default=0, help="first seed (default 0)")
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="more rig overrides"
    )
    parser.add_argument(
        "--workers", type=int, default=None, help="worker processes (default: cores)"
    )
    parser.add_argument("--out", help="keep the campaign folder here (default: a temporary one)")
    parser.add_argument(
        "--report", metavar="DIR", help="write the flight report of the worst flight here"
    )
    args = parser.parse_args()
    c = load_campaign(CAMPAIGN)
    c.seeds = list(range(args.seed0, args.seed0 + args.flights))
    c.fixed["wind.gust_std_mps"] = args.gust
    c.fixed.update(item.split("=", 1) for item in args.set)
    print(
        f"square quality: {args.flights} flights of {os.path.relpath(MISSION, REPO)}, seeds "
        f"{args.seed0}..{args.seed0 + args.flights - 1} (campaign "
        f"{os.path.relpath(CAMPAIGN, REPO)})"
    )
    print("rig overrides: " + ", ".join(f"{k}={v}" for k, v in c.fixed.items()))
    out = args.out or tempfile.mkdtemp(prefix="square_quality-")
    try:
        run = run_campaign(c, out, workers=args.workers, keep_runs="none")
    finally:
        if args.out is None:
            shutil.rmtree(out, ignore_errors=True)
    table = run.table
    for row in table:
        why = why_failed(row)
        if why:
            print(f"  seed {row['seed']}: FAILED - " + "; ".join(why))
    passed = sum(not why_failed(row) for row in table)
    need = math.ceil(PASS_FRACTION * args.flights - 1e-9)
    print(_dist("settle time", _all(table, "settle_s"), "s", ".2f"))
    print(_dist("time to reach", _all(table, "reach_s"), "s", ".2f"))
    print(_dist("final position error", _all(table, "final_dist_m", 100), "cm", ".2f"))
    print(_dist("final |yaw error|", _all(table, "final_yaw_deg", absolute=True), "deg", ".2f"))
    print(_dist("max tracking error", _all(table, "track_max_m", 100), "cm", ".1f"))
    print(_dist("RMS tracking error", _all(table, "track_rms_m", 100), "cm", ".1f"))
    verdict = "PASS" if passed >= need else "FAIL"
    print(f"passed flights: {passed}/{args.flights} (need {need}): {verdict}")
    print(
        f"wall time: {run.wall_s:.1f} s ({run.wall_s / max(len(run.ran), 1):.2f} s a flight "
        f"on {args.workers or os.cpu_count()} workers)"
        + (f"; campaign report: {run.report}" if args.out else "")
    )
    if args.report and table:

        def badness(row: dict) -> tuple:
            settles = [math.inf if s is None else s for s in row["settle_s"] or []]
            return bool(why_failed(row)), max(settles, default=math.inf)

        worst = max(table, key=badness)
        sets = [f"{k}={value_text(v)}" for k, v in c.fixed.items()]
        argv = ["run", MISSION, "--seed", str(worst["seed"]), "--max-time", "120", "--quiet"]
        argv += [x for s in sets for x in ("--set", s)] + ["--out", args.report]
        btrun(argv)  # lock-step: the same flight again, now with its report
        print(
            f"worst flight (seed {worst['seed']}) report: {os.path.join(args.report, 'report.html')}"
        )
    return 0 if verdict == "PASS" else 1


if __name__ == "__main__":
    sys.exit(main())
