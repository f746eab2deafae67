"""Campaign scaling: 1 vs 2 local workers vs a 2-worker Dask LocalCluster, and the per-run
overhead of the campaign engine.

1. The same campaign (default ``campaigns/pallet_scan.yaml``, its first ``--runs`` rows) runs
   into fresh folders on a local pool of 1 worker, of 2 workers, and on a Dask
   ``LocalCluster(n_workers=2, threads_per_worker=1)``, twice each in the order A B C C B A.
   Printed: wall time and throughput of each (worker start-up included), the ratios, what
   two CPU-bound processes gain over one on the machine at that moment (the ceiling of the
   2-worker ratio on a shared machine), and whether the six result tables are identical
   (the wall-clock columns left out).
2. Overhead per run: ``--square-runs`` flights of ``missions/square.xml`` as plain in-process
   ``btrun run --quiet --no-report`` calls and as a 1-worker campaign, in the order plain,
   campaign, campaign, plain. Printed: mean wall time per run of each and the difference,
   with and without the worker's start-up.

Figures are ratios measured in one run (docs/performance.md, "Campaigns").

Usage::

    .venv/bin/python bench/campaign_scaling.py                       # about 5 minutes on 2 cores
    .venv/bin/python bench/campaign_scaling.py --runs 200 --square-runs 100
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import statistics
import sys
import tempfile
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

from bt_engine.campaign import comparable, load_campaign, read_results, run_campaign  # noqa: E402
from bt_engine.campaign.pool import WorkerProcess  # noqa: E402
from bt_engine.cli import main as btrun  # noqa: E402

SQUARE = os.path.join(REPO, "missions", "square.xml")


BUSY = "x = 0\nfor i in range(30_000_000):\n    x += i\n"


def machine_scaling() -> float:
    """How much 2 CPU-bound processes gain over 1 on this machine right now (2.0: two free
    cores; less when other work shares them): the ceiling of the campaign's own ratio."""
    import subprocess

    def run(n: int) -> float:
        t0 = time.perf_counter()
        procs = [subprocess.Popen([sys.executable, "-c", BUSY]) for _ in range(n)]
        for p in procs:
            p.wait()
        return time.perf_counter() - t0

    one, two = run(1), run(2)
    return 2 * one / two


def timed_campaign(path: str, runs: int, out: str, **kw) -> tuple[float, object]:
    """Run the first ``runs`` rows of the campaign at ``path`` into ``out``; (wall s, run)."""
    c = load_campaign(path)
    t0 = time.perf_counter()
    run = run_campaign(c, out, limit=runs, keep_runs="none", report=False, **kw)
    return time.perf_counter() - t0, run


ORDER = ("pool, 1 worker", "pool, 2 workers", "dask, 2 workers")


def scaling(path: str, runs: int, tmp: str) -> dict[str, float]:
    """Section 1: the three back-ends on the same rows, each twice, in the order A B C C B A
    (a load that drifts during the bench weighs on all three alike)."""
    from dask.distributed import LocalCluster

    print(f"campaign {os.path.relpath(path, REPO)}: first {runs} rows, 3 back-ends, twice each")
    timed_campaign(path, 1, os.path.join(tmp, "warm-up"), workers=1)  # caches (demo gallery)
    ceiling = machine_scaling()
    print(f"  the machine now: 2 busy processes do {ceiling:.2f}x the work of 1")
    walls = dict.fromkeys(ORDER, 0.0)
    folders = []
    for i, name in enumerate(ORDER + ORDER[::-1]):
        out = os.path.join(tmp, f"{i}")
        folders.append(out)
        if name.startswith("dask"):
            with LocalCluster(
                n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
            ) as cluster:  # its start-up (about 1 s) is not counted
                wall, _ = timed_campaign(path, runs, out, scheduler=cluster.scheduler_address)
        else:
            wall, _ = timed_campaign(path, runs, out, workers=1 if "1 worker" in name else 2)
        walls[name] += wall
        print(f"    {name:<18} {wall:6.1f} s", flush=True)
    for name, wall in walls.items():
        print(f"  {name:<18} {wall:7.1f} s for {2 * runs} runs  {2 * runs / wall:6.3f} runs/s")
    r2 = walls[ORDER[0]] / walls[ORDER[1]]
    rd = walls[ORDER[1]] / walls[ORDER[2]]
    print(f"  throughput 2 workers / 1 worker: {r2:.2f}x (target >= 1.8x)")
    after = machine_scaling()
    print(f"  the machine after: 2 busy processes do {after:.2f}x the work of 1")
    print(f"  throughput Dask / local pool (2 workers each): {rd:.2f} (target within 15 %)")
    tables = [comparable(read_results(f)) for f in folders]
    same = all(tables[0].equals(t) for t in tables[1:])
    print(f"  the {len(tables)} result tables identical (wall-clock columns left out): {same}")
    for label, other in zip(ORDER + ORDER[::-1], tables, strict=True):
        for name in tables[0].column_names:  # what differs, if anything
            a, b = tables[0][name].to_pylist(), other[name].to_pylist()
            diff = [(i, x, y) for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y]
            if diff:
                print(f"    {label} differs in {name}: (row, first, this) {diff[:3]}")
    return {"ratio_2_1": r2, "ratio_dask": rd, "identical": float(same)}


def overhead(runs: int, tmp: str) -> dict[str, float]:
    """Section 2: plain square.xml runs vs the same runs as a 1-worker campaign, in the order
    plain, campaign, campaign, plain (a drifting load weighs on both alike)."""
    print(f"overhead: {runs} flights of missions/square.xml, twice each way")
    argv = ["run", SQUARE, "--quiet", "--no-report"]
    with contextlib.redirect_stdout(io.StringIO()):
        btrun([*argv, "--out", os.path.join(tmp, "plain-warm")])
    t0 = time.perf_counter()
    wp = WorkerProcess()
    wp._start()
    startup = time.perf_counter() - t0
    wp.close()
    spec = os.path.join(tmp, "square.yaml")
    with open(spec, "w", encoding="utf-8") as f:
        f.write(f"missions: [{SQUARE}]\nseeds: {{start: 0, count: {runs}}}\n")
    plain: list[float] = []
    rows: list[float] = []
    inside: list[float] = []  # the btrun run part of each row, timed by its worker
    campaign = 0.0
    for step, kind in enumerate(("plain", "campaign", "campaign", "plain")):
        if kind == "plain":
            with contextlib.redirect_stdout(io.StringIO()):
                for i in range(runs):
                    t0 = time.perf_counter()
                    btrun([*argv, "--seed", str(i), "--out", os.path.join(tmp, f"p{step}-{i}")])
                    plain.append(time.perf_counter() - t0)
        else:
            wall, run = timed_campaign(spec, runs, os.path.join(tmp, f"square-{step}"), workers=1)
            campaign += wall
            rows += [row["wall_s"] for row in run.table]  # type: ignore[attr-defined]
            inside += [rec["run_s"] for rec in run.records.values()]  # type: ignore[attr-defined]
    n = 2 * runs
    mean_plain, per_run = sum(plain) / n, campaign / n
    steady = per_run - startup / runs
    print(f"  plain btrun run (in-process, no report)   {mean_plain * 1000:7.1f} ms a run")
    print(f"  campaign, 1 worker: wall / runs           {per_run * 1000:7.1f} ms a run")
    print(f"  same, less the worker start-up ({startup:.2f} s)  {steady * 1000:7.1f} ms a run")
    print(
        f"  medians: plain {statistics.median(plain) * 1000:.1f} ms, a row inside its worker "
        f"{statistics.median(rows) * 1000:.1f} ms"
    )
    print(
        f"  vs plain runs: {100 * (steady - mean_plain) / mean_plain:+.1f} % without the "
        f"start-up, {100 * (per_run - mean_plain) / mean_plain:+.1f} % with one start-up per "
        f"{runs} runs (two processes: includes their speed difference and the load's drift)"
    )
    mean_inside = sum(inside) / len(inside)
    print(
        f"  campaign overhead per run (row wall less its btrun run part, same process): "
        f"{(steady - mean_inside) * 1000:.1f} ms = {100 * (steady - mean_inside) / mean_inside:.1f} "
        f"% of a run ({mean_inside * 1000:.1f} ms) without the start-up, "
        f"{100 * (per_run - mean_inside) / mean_inside:.1f} % with it (target < 5 %)"
    )
    return {"plain_ms": mean_plain * 1000, "campaign_ms": per_run * 1000}


def main(argv: list[str] | None = None) -> int:
    """Run both sections; exit 1 if the three tables differ."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--campaign", default=os.path.join(REPO, "campaigns", "pallet_scan.yaml"), metavar="FILE"
    )
    ap.add_argument("--runs", type=int, default=8, help="rows of the campaign (default 8)")
    ap.add_argument("--square-runs", type=int, default=40, help="square flights (default 40)")
    args = ap.parse_args(argv)
    print(f"{os.cpu_count()} cores; load average {os.getloadavg()[0]:.2f} at the start")
    with tempfile.TemporaryDirectory(prefix="campaign_scaling-") as tmp:
        t0 = time.perf_counter()
        figures = scaling(args.campaign, args.runs, tmp)
        overhead(args.square_runs, tmp)
        print(f"bench wall time {time.perf_counter() - t0:.0f} s")
    return 0 if figures["identical"] else 1


if __name__ == "__main__":
    sys.exit(main())
