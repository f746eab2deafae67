"""Quality campaign of the flight issue: seeded simulated flights of ``missions/square.xml``.

Each flight runs with the reference imperfections (Vicon-grade mocap noise, a few degrees of
onboard yaw bias that wanders, light gusts) and a different seed. A flight passes when the
mission succeeds and every GoTo completes within its 3 cm / 15 deg thresholds and settles
within 3 s of arrival (settle: from first entering both thresholds to the start of the
final stay inside, as in the flight report). The campaign passes when at least 49 of 50
flights do (the same fraction for ``--flights N``). Prints figures; exit code 0 on a pass.

    .venv/bin/python bench/square_quality.py [--flights 50] [--gust 0.1] [--seed0 0]
        [--set key=value ...] [--report DIR]   # DIR: flight report of the worst flight
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

import nodes  # noqa: E402,F401  (registers the drone leaves)
from bt_engine import Mission, Runner, SimClock  # noqa: E402
from drivers.rig.factory import make_platform  # noqa: E402
from drivers.rig.loader import load_rig  # noqa: E402
from nodes.report import motion_metrics, telemetry_arrays, write_report  # noqa: E402

MISSION = os.path.join(REPO, "missions", "square.xml")
POS_THRESHOLD_M = 0.03
YAW_THRESHOLD_DEG = 15.0
SETTLE_LIMIT_S = 3.0
PASS_FRACTION = 49 / 50


def reference_overrides(gust_mps: float) -> dict[str, str]:
    """The reference imperfections as rig overrides (docs/rig-settings.md lists the keys)."""
    return {
        "sensors.mocap.position_noise_std_m": "0.00005",  # upper end of Vicon on a Crazyflie
        "sensors.mocap.orientation_noise_std_deg": "0.1",
        "sensors.onboard.yaw_bias_deg": "3.0",  # onboard yaw - true yaw, random sign per seed
        "sensors.onboard.yaw_bias_wander_deg": "1.0",
        "wind.gust_std_mps": f"{gust_mps:g}",
        "wind.gust_time_constant_s": "2.0",
    }


def fly(rig, seed: int) -> dict:
    """One flight: the GoTo rows of the report's motion table, and whether it passed."""
    clock = SimClock()
    platform = make_platform(rig, clock, seed)
    m = Mission.from_file(MISSION, clock=clock, vehicle=platform.vehicle)
    runner = Runner(m, hooks=[platform], telemetry=platform.telemetry_row)
    result = runner.run(max_time_s=120.0)
    tel = telemetry_arrays(runner.trace)
    motions = m.ctx.resources.get("motions", [])
    rows = (
        [r for r in motion_metrics(motions, tel) if r["kind"] == "GoTo"] if tel is not None else []
    )
    why = []
    if result.status != "SUCCESS":
        why.append(f"mission {result.status}: {result.reason}")
    if len(rows) != 4:
        why.append(f"{len(rows)} GoTos ran, expected 4")
    for r in rows:
        if r["result"] != "SUCCESS":
            why.append(f"{r['label']} {r['result']}")
        if r["final_dist"] > POS_THRESHOLD_M or abs(r["final_yaw_deg"]) > YAW_THRESHOLD_DEG:
            why.append(
                f"{r['label']} ended {r['final_dist'] * 100:.1f} cm / {r['final_yaw_deg']:.1f} deg off"
            )
        if r["settle"] is None or r["settle"] > SETTLE_LIMIT_S:
            settle = "never" if r["settle"] is None else f"{r['settle']:.2f} s"
            why.append(f"{r['label']} settle {settle} (limit {SETTLE_LIMIT_S:g} s)")
    summary = {
        "status": result.status,
        "reason": result.reason,
        "ticks": result.ticks,
        "mission_time_s": result.mission_time_s,
        "wall_time_s": result.wall_time_s,
        "mission": MISSION,
        "seed": seed,
        "rate_hz": 50.0,
        "sim": platform.summary(),
    }
    return {"seed": seed, "rows": rows, "why": why, "run": (runner.trace, summary, m)}


def _dist(name: str, values: list[float], unit: str, spec: str = ".3f") -> str:
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    if not v.size:
        return f"{name:<28} (no values)"
    q = np.percentile(v, [0, 50, 95, 100])
    cells = "  ".join(
        f"{k} {format(x, spec)}" for k, x in zip(("min", "median", "p95", "max"), q, strict=True)
    )
    return f"{name:<28} {cells} {unit}  (n={v.size})"


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
        "--report", metavar="DIR", help="write the flight report of the worst flight here"
    )
    args = parser.parse_args()
    overrides = reference_overrides(args.gust)
    overrides.update(item.split("=", 1) for item in args.set)
    rig = load_rig(None, overrides)
    print(
        f"square quality: {args.flights} flights of {os.path.relpath(MISSION, REPO)}, seeds "
        f"{args.seed0}..{args.seed0 + args.flights - 1}"
    )
    print("rig overrides: " + ", ".join(f"{k}={v}" for k, v in overrides.items()))
    wall0 = time.perf_counter()
    flights = []
    for i in range(args.flights):
        f = fly(rig, args.seed0 + i)
        if args.report is None:
            f.pop("run")  # keep memory flat on long campaigns
        flights.append(f)
        if f["why"]:
            print(f"  seed {f['seed']}: FAILED - " + "; ".join(f["why"]))
    wall = time.perf_counter() - wall0
    rows = [r for f in flights for r in f["rows"]]
    passed = sum(not f["why"] for f in flights)
    need = math.ceil(PASS_FRACTION * args.flights - 1e-9)
    print(_dist("settle time", [r["settle"] for r in rows], "s", ".2f"))
    print(_dist("time to reach", [r["reach"] for r in rows], "s", ".2f"))
    print(_dist("final position error", [r["final_dist"] * 100 for r in rows], "cm", ".2f"))
    print(_dist("final |yaw error|", [abs(r["final_yaw_deg"]) for r in rows], "deg", ".2f"))
    print(_dist("max tracking error", [r["track_max"] * 100 for r in rows], "cm", ".1f"))
    print(_dist("RMS tracking error", [r["track_rms"] * 100 for r in rows], "cm", ".1f"))
    verdict = "PASS" if passed >= need else "FAIL"
    print(f"passed flights: {passed}/{args.flights} (need {need}): {verdict}")
    print(f"wall time: {wall:.1f} s ({wall / max(args.flights, 1):.2f} s a flight)")
    if args.report and flights:

        def badness(f: dict) -> tuple:
            settles = [math.inf if r["settle"] is None else r["settle"] for r in f["rows"]]
            return bool(f["why"]), max(settles, default=math.inf)

        worst = max(flights, key=badness)
        path = write_report(args.report, *worst["run"])
        print(f"worst flight (seed {worst['seed']}) report: {path}")
    return 0 if verdict == "PASS" else 1


if __name__ == "__main__":
    sys.exit(main())
