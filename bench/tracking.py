"""Go-to tracking quality: overshoot at the goal and tracking error against the reference.

Flies ``missions/square.xml`` and ``missions/pallet_scan.xml`` in the lock-step simulator
(default rig, seeded) and prints, per mission and seed, for every GoTo: the overshoot (how
far the pose went past the goal along the direction of travel; for a go-to that does not
translate, the largest distance from the goal after it first came within 1 cm) and the
largest distance between the pose and the reference while the go-to ran. The last line of
each flight is the simulator's whole-flight ``max_tracking_error_m`` (true position against
the reference, take-off and landing included).

    .venv/bin/python bench/tracking.py [--seeds 0 1 2] [--mission square pallet_scan]
        [--set key=value ...]
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

from tests.helpers import sim_mission  # noqa: E402

MISSIONS = {
    "square": os.path.join(REPO, "missions", "square.xml"),
    "pallet_scan": os.path.join(REPO, "missions", "pallet_scan.xml"),
}


def goto_figures(trace: list[dict], motions: list[dict]) -> list[dict]:
    """Overshoot and max tracking error (m) of every GoTo in a flown trace."""
    rows = [r for r in trace if "vehicle" in r and "ref_x" in r["vehicle"]]
    t = np.array([r["t"] for r in rows])
    pos = np.array([[r["vehicle"][k] for k in ("x", "y", "z")] for r in rows])
    ref = np.array([[r["vehicle"][k] for k in ("ref_x", "ref_y", "ref_z")] for r in rows])
    out = []
    for m in motions:
        if m.get("kind") != "GoTo" or m.get("t_start") is None:
            continue
        t0 = m["t_start"]
        t1 = m["t_end"] if m.get("t_end") is not None else t[-1]
        w = (t >= t0 - 1e-9) & (t <= t1 + 1e-9)
        if not w.any():
            continue
        goal = np.asarray(m["goal"], dtype=float)
        p, r = pos[w], ref[w]
        start = r[0]
        d = goal - start
        length = float(np.linalg.norm(d))
        if length > 0.05:
            overshoot = max(0.0, float(((p - goal) @ (d / length)).max()))
        else:
            dist = np.linalg.norm(p - goal, axis=1)
            near = np.nonzero(dist < 0.01)[0]
            overshoot = float(dist[near[0] :].max()) if near.size else float(dist.max())
        out.append(
            {
                "name": m.get("name", "?"),
                "length": length,
                "overshoot": overshoot,
                "track_max": float(np.linalg.norm(p - r, axis=1).max()),
                "duration": t1 - t0,
            }
        )
    return out


def fly(mission: str, seed: int, overrides: dict[str, str]) -> tuple[list[dict], dict, str]:
    """One flight: GoTo figures, the platform summary, and the mission status."""
    m, runner, platform = sim_mission(MISSIONS[mission], seed=seed, overrides=overrides)
    result = runner.run(max_time_s=300.0)
    figs = goto_figures(runner.trace, m.ctx.resources.get("motions", []))
    return figs, platform.summary(), result.status


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--mission", nargs="+", default=list(MISSIONS), choices=list(MISSIONS))
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    a = ap.parse_args(argv)
    overrides = dict(kv.split("=", 1) for kv in a.set)
    worst_os = worst_tr = 0.0
    for mission in a.mission:
        for seed in a.seeds:
            figs, summary, status = fly(mission, seed, overrides)
            print(f"{mission} seed {seed}: {status}")
            for f in figs:
                print(
                    f"  {f['name']:<14} {f['length']:5.2f} m  overshoot {f['overshoot'] * 100:5.2f} cm"
                    f"  max track {f['track_max'] * 100:5.2f} cm  {f['duration']:5.2f} s"
                )
                worst_os = max(worst_os, f["overshoot"])
                worst_tr = max(worst_tr, f["track_max"])
            sim = summary.get("sim", summary)
            print(f"  sim.max_tracking_error_m {sim.get('max_tracking_error_m')}")
    print(
        f"worst go-to overshoot {worst_os * 100:.2f} cm, worst go-to tracking {worst_tr * 100:.2f} cm"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
