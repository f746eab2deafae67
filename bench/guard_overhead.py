"""What the guard costs: the square flown on SITL with the guard owning the link and without.

Each run is the real ``btrun`` executable flying ``missions/square.xml`` on
``rigs/sitl.yaml`` (the real cflib driver against the in-process CRTP emulator, 100 Hz
control loop), once with the guard (the default: the cflib link lives in the guard process,
every set-point crosses the Unix socket) and once with ``--set guard.enabled=false`` (the
baseline: cflib in the mission process). Figures, from each run's summary.json:

* set-point latency through the guard: mission process send -> guard forward (p50/p99/max);
* set-point period as forwarded to cflib by the guard at 100 Hz (p50/p99/max): the jitter
  the drone sees;
* the mission process's control-loop period p99 (both runs) and the largest tracking error
  of the square (both runs): the ratio guard / baseline.

Usage::

    .venv/bin/python bench/guard_overhead.py [--runs 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BTRUN = [sys.executable, "-c", "from bt_engine.cli import main; raise SystemExit(main())"]


def fly(out: str, guard: bool) -> dict:
    """One square on SITL; its summary.json."""
    cmd = [*BTRUN, "missions/square.xml", "--rig", "rigs/sitl.yaml", "--out", out]
    cmd += ["--quiet", "--no-report", "--no-mcap", "--set", "aideck.enabled=false"]
    if not guard:
        cmd += ["--set", "guard.enabled=false"]
    subprocess.run(cmd, cwd=REPO, check=True, capture_output=True, timeout=180)
    with open(os.path.join(out, "summary.json")) as f:
        return json.load(f)


def main(argv: list[str] | None = None) -> int:
    """Fly the pairs and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="pairs of flights")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.runs):
            on = fly(os.path.join(tmp, f"on{i}"), True)
            off = fly(os.path.join(tmp, f"off{i}"), False)
            g = on["guard"]
            rows.append(
                {
                    "lat_p50": g["setpoint_latency_ms"]["p50"],
                    "lat_p99": g["setpoint_latency_ms"]["p99"],
                    "lat_max": g["setpoint_latency_ms"]["max"],
                    "per_p50": g["setpoint_period_ms"]["p50"],
                    "per_p99": g["setpoint_period_ms"]["p99"],
                    "per_max": g["setpoint_period_ms"]["max"],
                    "ctl_on": on["vehicle"]["control"]["period_p99_ms"],
                    "ctl_off": off["vehicle"]["control"]["period_p99_ms"],
                    "err_on": on["vehicle"].get("max_tracking_error_m"),
                    "err_off": off["vehicle"].get("max_tracking_error_m"),
                    "status": (on["status"], off["status"]),
                }
            )
            print(f"pair {i + 1}/{args.runs}: {rows[-1]}", flush=True)

    def med(key: str) -> float:
        return statistics.median(r[key] for r in rows)

    print()
    print("| figure (median of runs) | with guard | baseline (no guard) | ratio |")
    print("|---|---|---|---|")
    print(f"| set-point latency through the guard p50 / p99 / max (ms) | "
          f"{med('lat_p50'):.3f} / {med('lat_p99'):.3f} / {med('lat_max'):.3f} | - | - |")  # fmt: skip
    print(f"| set-point period at the guard p50 / p99 / max (ms, 100 Hz) | "
          f"{med('per_p50'):.2f} / {med('per_p99'):.2f} / {med('per_max'):.2f} | - | - |")  # fmt: skip
    print(f"| control-loop period p99 in the mission process (ms) | {med('ctl_on'):.2f} | "
          f"{med('ctl_off'):.2f} | {med('ctl_on') / med('ctl_off'):.2f} |")  # fmt: skip
    print(f"| largest tracking error of the square (m) | {med('err_on'):.4f} | "
          f"{med('err_off'):.4f} | {med('err_on') / med('err_off'):.2f} |")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
