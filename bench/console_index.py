"""Server CPU of the operator console's runs index (``GET /api/runs``) over a big runs folder.

A site keeps its runs: a folder of 500 site inventories is about a year of daily runs. The
index lists each run's status, places, accuracy, discrepancies and reviews; this bench
copies one run folder ``--copies`` times into a temporary runs folder and times
:func:`nodes.console.runs.list_runs`:

* ``every run read`` (the baseline, measured in the same process): each refresh reads every
  run's inventory, summary and reviews again (the index before its cache);
* ``first refresh``: the console's first listing (every run read, the cache filled);
* ``refresh, nothing changed``: what every later refresh of the page costs;
* ``refresh, one review``: one run's ``review.json`` rewritten (a decision), the others kept.

    .venv/bin/python bench/console_index.py --run runs/inventory-20261128-050000 --copies 500
    .venv/bin/python bench/console_index.py          # a synthetic site run (144 places)

Prints CPU milliseconds per refresh and the ratios against the baseline.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time

if __package__ in (None, ""):
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from nodes.console import runs as runs_module
from nodes.console.files import write_review
from nodes.console.paths import RunsRoot
from nodes.inventory_log import write_inventory


def synthetic_run(folder: str) -> None:
    """A finished site inventory: 144 places (2 aisles, 4 faces, 12 bays, 3 levels), a
    tenth of them unknown, its summary's grades and two review decisions."""
    places = [f"{r}-{b:02d}-{lv}" for r in "ABCD" for b in range(1, 13) for lv in (1, 2, 3)]
    rows = []
    for i, p in enumerate(places):
        status = "unknown" if i % 10 == 3 else ("empty" if i % 7 == 0 else "identified")
        answer = f"{100 + i}A" if status == "identified" else ""
        rows.append({"place": p, "answer": answer, "status": status, "drone": "site"})
    os.makedirs(folder)
    header = {"mission": "missions/inventory.xml", "started": "2026-11-28T05:00:00Z"}
    with open(os.path.join(folder, "ticks.jsonl"), "w", encoding="utf-8") as f:
        f.write(json.dumps({"header": header}) + "\n")
    write_inventory(folder, rows, places)
    grades = {p: "right" for p in places}
    summary = {"status": "SUCCESS", "inventory": {"accuracy": 1.0, "grades": grades}}
    with open(os.path.join(folder, "summary.json"), "w", encoding="utf-8") as f:
        json.dump(summary, f)
    write_review(folder, [{"place": places[3], "answer": "117B", "decision": "confirm"}])


def cpu_ms(fn) -> float:
    start = time.process_time()
    fn()
    return (time.process_time() - start) * 1000.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", help="a run folder to copy (default: a synthetic site run)")
    ap.add_argument("--copies", type=int, default=500, help="runs in the folder (default 500)")
    ap.add_argument("--rounds", type=int, default=3, help="refreshes timed per case (median)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="console-index-") as tmp:
        source = os.path.join(tmp, "source")
        if args.run:
            shutil.copytree(args.run, source, symlinks=True)
        else:
            synthetic_run(source)
        root = os.path.join(tmp, "runs")
        os.makedirs(root)
        for i in range(args.copies):
            shutil.copytree(source, os.path.join(root, f"run-{i:04d}"), symlinks=True)
        runs_root = RunsRoot(root)

        def listing() -> None:
            assert len(runs_module.list_runs(runs_root)) == min(args.copies, runs_module.MAX_RUNS)

        def uncached() -> None:
            runs_module._LISTED.clear()
            listing()

        def median(fn) -> float:
            return sorted(cpu_ms(fn) for _ in range(args.rounds))[args.rounds // 2]

        baseline = median(uncached)
        runs_module._LISTED.clear()
        first = cpu_ms(listing)
        unchanged = median(listing)
        one = os.path.join(root, "run-0000")

        def after_review() -> None:
            write_review(one, [{"place": "A-01-1", "answer": "101A", "decision": "confirm"}])
            listing()

        reviewed = median(after_review)
    print(
        f"runs index of {args.copies} runs ({'copies of ' + args.run if args.run else 'synthetic site runs, 144 places'}), CPU ms per refresh:"
    )
    print(f"  every run read (baseline)   {baseline:8.1f}")
    print(f"  first refresh               {first:8.1f}   {first / baseline:5.2f}x the baseline")
    print(f"  refresh, nothing changed    {unchanged:8.1f}   {unchanged / baseline:5.3f}x")
    print(f"  refresh, one review         {reviewed:8.1f}   {reviewed / baseline:5.3f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
