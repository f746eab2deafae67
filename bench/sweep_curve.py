"""The sweep's speed-vs-accuracy curve (issue 27): how a pass answers places at each speed.

Each row flies ``missions/inventory.xml`` on ``rigs/site.yaml`` over the places given (default:
one level of each of two faces, 24 places), with ``rescan_places=false`` so that every place
is answered by the pass alone or left for the rescan, at one pass speed and one emulated host
(``host_frame_time``: a host needing that long per frame drops the frames that arrive
meanwhile, as the real-time perception worker does). Motion blur is the simulated camera's
(its exposure, the drone's speed) and the camera runs at 15 frames/s. Per speed: places
right / unknown (an enrolled pallet answered unknown) / wrong / missed (answered empty where
a pallet stands) / left for the rescan, frames looked at per place, and the pass's time per
place. The figures and the chosen speed are in docs/performance.md (Sweep).

Usage::

    .venv/bin/python bench/sweep_curve.py                          # seeds 100, speeds 0.1 .. 1.0
    .venv/bin/python bench/sweep_curve.py --seeds 200 201 --host 0 0.1 --json curve.json
    .venv/bin/python bench/sweep_curve.py --speeds 0.8 --places "A-*-2"
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import re
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

SPEEDS = (0.1, 0.2, 0.3, 0.5, 0.7, 0.8, 0.9, 1.0)


def fly(job: tuple[float, float, int, str, str]) -> dict:
    """One sweep at one speed and host time; the grade of every place."""
    speed, host, seed, places, out, second = job
    import torch

    torch.set_num_threads(1)
    from bt_engine.cli import main
    from drivers.sim.world import load_world

    args = [
        os.path.join(REPO, "missions", "inventory.xml"),
        "--rig",
        os.path.join(REPO, "rigs", "site.yaml"),
        "--seed",
        str(seed),
        "--out",
        out,
        "-q",
        "--no-report",
        "--no-mcap",
    ]
    for s in (
        f"places={places}",
        f"sweep_speed={speed}",
        f"host_frame_time={host}",
        "rescan_places=false",
        f"second_look_speed={second}",
    ):
        args += ["--set", s]
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(args)
    wall = time.perf_counter() - t0
    doc = json.load(open(os.path.join(out, "inventory.json")))
    world = load_world(os.path.join(REPO, "worlds", "site.yaml"), seed=seed)
    truth, not_enrolled = world.places_truth(), set(world.not_enrolled())
    counts = {"right": 0, "unknown": 0, "wrong": 0, "missed": 0, "rescan": 0}
    for r in doc["rows"]:
        t = truth[r["place"]]
        if r["status"] == "not_scanned":
            counts["rescan"] += 1
        elif t is None:
            counts["right" if r["answer"] == "empty" else "wrong"] += 1
        elif r["answer"] == "empty":
            counts["missed"] += 1
        elif t in not_enrolled:
            counts["right" if r["answer"] == "unknown" else "wrong"] += 1
        elif r["answer"] == t:
            counts["right"] += 1
        else:
            counts["unknown" if r["answer"] == "unknown" else "wrong"] += 1
    frames, pass_s, looks = 0, 0.0, 0
    with open(os.path.join(out, "ticks.jsonl")) as f:
        for line in f:
            for m in json.loads(line).get("messages", ()):
                hit = re.match(r"sweep \S+: (\d+) answered, .* (\d+) frames looked at", m)
                if hit:
                    frames += int(hit.group(2))
                again = re.match(r"sweep \S+: \d+ answered, (\d+) looked at again", m)
                if again:
                    looks += int(again.group(1))
    starts: dict[str, float] = {}
    with open(os.path.join(out, "ticks.jsonl")) as f:
        for line in f:
            rec = json.loads(line)
            for m in rec.get("messages", ()):
                if re.match(r"sweep \S+: \d+ places", m):
                    starts[m.split(":")[0]] = rec["t"]
                elif re.match(r"sweep \S+: \d+ answered", m):
                    pass_s += rec["t"] - starts.get(m.split(":")[0], rec["t"])
    n = len(doc["rows"]) or 1
    return {
        "speed": speed,
        "host_frame_s": host,
        "seed": seed,
        "code": code,
        "places": len(doc["rows"]),
        **counts,
        "second_looks": looks,
        "frames_per_place": round(frames / n, 1),
        "pass_s_per_place": round(pass_s / n, 2),
        "wall_s": round(wall, 1),
    }


def main() -> int:
    """Fly every (speed, host, seed), print the curve."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--speeds", type=float, nargs="+", default=list(SPEEDS))
    ap.add_argument("--host", type=float, nargs="+", default=[0.0], help="host_frame_time, s")
    ap.add_argument("--seeds", type=int, nargs="+", default=[100])
    ap.add_argument("--places", default="A-*-1;C-*-2")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--second-look",
        type=float,
        default=0.3,
        help="second_look_speed, m/s (0: none, as before the second look)",
    )
    ap.add_argument("--json", help="write every row here")
    args = ap.parse_args()
    root = tempfile.mkdtemp(prefix="sweep-curve-")
    jobs = [
        (v, h, s, args.places, os.path.join(root, f"v{v}_h{h}_s{s}"), args.second_look)
        for h in args.host
        for v in args.speeds
        for s in args.seeds
    ]
    print(
        f"{'speed':>5} {'host s':>6} {'seed':>4} {'right':>7} {'unk':>4} {'wrong':>5} "
        f"{'miss':>4} {'rescan':>6} {'2nd look':>8} {'frames/pl':>9} {'s/place':>7}"
    )
    rows = []
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for r in pool.map(fly, jobs):
            rows.append(r)
            print(
                f"{r['speed']:>5.2f} {r['host_frame_s']:>6.2f} {r['seed']:>4} "
                f"{r['right']:>3}/{r['places']:<3} {r['unknown']:>4} {r['wrong']:>5} "
                f"{r['missed']:>4} {r['rescan']:>6} {r['second_looks']:>8} {r['frames_per_place']:>9} "
                f"{r['pass_s_per_place']:>7}",
                flush=True,
            )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
