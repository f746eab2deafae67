"""Weathered and painted pallets in flight: enrol by flying, then identify by flying.

For each world (``worlds/warehouse.yaml``: fresh wood; ``worlds/warehouse_weathered.yaml``:
grey, silver, dark and wet wood, one pallet painted blue / red), every side 1A .. 5B is
enrolled into a new gallery file by flying ``missions/enroll_pallet.xml`` (lock-step
simulator, ``rigs/sim.yaml`` with its imperfections), then identified by flying
``missions/pallet_scan.xml`` against that gallery ``--runs`` times with other seeds.
``--age A`` scans the pallets aged by A (0..1: stains, dust, scratches, faded stamps,
moisture since enrolment; ``world.pallet_look.age``) and, with ``--update``, lets
IdentifyPallet add confident scans to the gallery.

These are simulated flights: they are not comparable with the reference study's real
flights (docs/performance.md keeps the two apart).

    .venv/bin/python bench/weathered_flights.py                     # 2 worlds x 10 sides x 2
    .venv/bin/python bench/weathered_flights.py --worlds weathered --runs 1 --age 0.6
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from multiprocessing import get_context

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
SIDES = [f"{n}{s}" for n in "12345" for s in "AB"]
WORLDS = {
    "fresh": os.path.join(REPO, "worlds", "warehouse.yaml"),
    "weathered": os.path.join(REPO, "worlds", "warehouse_weathered.yaml"),
}


def fly(job: tuple[str, str, int, dict[str, str]]) -> dict:
    """One ``btrun run`` in this process; the figures of its summary.json."""
    mission, side, seed, sets = job
    from flight_run import run_summary

    argv = ["run", os.path.join(REPO, "missions", mission), "--seed", str(seed), "--quiet"]
    argv.append("--no-report")
    for k, v in {"world.scan_pallet": side, **sets}.items():
        argv += ["--set", f"{k}={v}"]
    s = run_summary(argv)
    bb = s.get("blackboard") or {}
    perception = s.get("perception") or {}
    idents = perception.get("identifications") or [{}]
    return {
        "mission": mission,
        "side": side,
        "seed": seed,
        "status": s.get("status"),
        "reason": s.get("reason"),
        "blocks": max(perception.get("blocks") or [0]),
        "answer": bb.get("pallet_id"),
        "distance": idents[-1].get("distance"),
        "margin": idents[-1].get("margin"),
        "update": idents[-1].get("gallery_update"),
    }


def _init() -> None:
    import torch

    torch.set_num_threads(1)


def run_world(name: str, args: argparse.Namespace, pool, folder: str) -> dict:
    """Enrol every side by flying, then identify each ``args.runs`` times."""
    gallery = os.path.join(folder, f"{name}.sqlite")
    base = {"world.path": WORLDS[name], "gallery": gallery}
    enrol = [
        ("enroll_pallet.xml", side, 500 + i, {**base, "pallet": side})
        for i, side in enumerate(SIDES)
    ]
    # one enrolment at a time: they write the same gallery file
    enrolled = [fly(job) for job in enrol]
    ok = [r["side"] for r in enrolled if r["status"] == "SUCCESS"]
    sets = dict(base)
    if args.age:
        sets["world.pallet_look.age"] = str(args.age)
    if args.update:
        sets["update_gallery"] = "true"
    jobs = [
        ("pallet_scan.xml", side, 1000 + 37 * r + i, sets)
        for r in range(args.runs)
        for i, side in enumerate(SIDES)
    ]
    if args.update:  # scans of one side update its views: keep their order
        flights = [fly(j) for j in jobs]
    else:
        flights = pool.map(fly, jobs) if pool else [fly(j) for j in jobs]
    return {"world": name, "enrolled": enrolled, "enrolled_ok": ok, "flights": flights}


def report(res: dict) -> list[str]:
    """Lines of the table for one world."""
    fl = res["flights"]
    right = [f for f in fl if f["answer"] == f["side"]]
    unknown = [f for f in fl if f["answer"] == "unknown"]
    wrong = [f for f in fl if f["answer"] not in (None, "unknown", f["side"])]
    none = [f for f in fl if f["answer"] is None]
    out = [
        f"{res['world']:<10} enrolled {len(res['enrolled_ok'])}/{len(SIDES)} "
        f"(three blocks in the enrolment flight: "
        f"{sum(r['blocks'] >= 3 for r in res['enrolled'])}/{len(SIDES)})",
        f"{'':<10} identification flights: {len(fl)}, three blocks {sum(f['blocks'] >= 3 for f in fl)}, "
        f"right {len(right)}, unknown {len(unknown)}, wrong {len(wrong)}, no answer {len(none)}",
    ]
    if right:
        out.append(
            f"{'':<10} smallest right margin {min(f['margin'] for f in right):.3f}, "
            f"largest right distance {max(f['distance'] for f in right):.3f}"
        )
    for f in unknown + wrong + none:
        out.append(
            f"{'':<10}   {f['side']} seed {f['seed']}: {f['answer']} ({f['status']} {f['reason'] or ''})"
        )
    return out


def main(argv: list[str] | None = None) -> int:
    """Fly, print the table, optionally keep the rows."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--worlds", nargs="*", default=list(WORLDS), choices=list(WORLDS))
    ap.add_argument("--runs", type=int, default=2, help="identification flights per side")
    ap.add_argument("--age", type=float, default=0.0, help="ageing since enrolment, 0..1")
    ap.add_argument("--update", action="store_true", help="IdentifyPallet update_gallery=true")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--json", default="")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    pool = get_context("fork").Pool(args.workers, initializer=_init) if args.workers > 1 else None
    results = []
    try:
        with tempfile.TemporaryDirectory() as folder:
            for name in args.worlds:
                results.append(run_world(name, args, pool, folder))
                print("\n".join(report(results[-1])), flush=True)
    finally:
        if pool:
            pool.close()
            pool.join()
    print(f"{time.perf_counter() - t0:.0f} s (simulated flights; not comparable with real ones)")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"args": vars(args), "results": results}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
