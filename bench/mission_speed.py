"""Per-run speed of the pallet mission with perception, as a campaign worker flies it.

Each variant runs in its own warm server process (this script with ``--serve``: imports,
torch and both models loaded by one warm-up flight that is not counted, like a campaign
worker after its first row) and flies ``missions/pallet_scan.xml`` in-process
(``bt_engine.cli.main``, lock-step, tick log and run.mcap on, no report) for every seed,
the side at the scan slot cycling 1A .. 5B as in ``campaigns/pallet_scan.yaml``. Variants:

* ``new``: this tree as it is;
* ``every-frame``: this tree with ``perception.min_view_change_px=0`` (every frame
  rendered and detected, the other speed-ups kept);
* ``campaign row``: this tree as a campaign worker flies a row (``--no-mcap``: campaigns
  record run.mcap only with ``mcap: true``);
* ``baseline`` (with ``--baseline REF``): the tree of git commit REF (``git archive``).

Flights alternate between the variants (A B C, then C B A, ...), one at a time, so a busy
machine slows them alike; the ratios are measured within the run. For each variant it prints
the median wall time per run, x real time, frames rendered and detected per run and the CPU
time per stage (thread time: render, detector, white balance, face fit, physics, run.mcap,
tick log, safety; "rest" = the engine, the leaves, the vehicle), and it checks that every
variant gave the same answers (pallet_id and blocks found per seed). With ``--campaign N``
it also times ``btrun campaign campaigns/pallet_scan.yaml --workers 1 --limit N`` (worker
start-up included) per tree, in the order A B B A. It prints figures; it is not a test::

    .venv/bin/python bench/mission_speed.py --baseline 78f7873 --campaign 8
    .venv/bin/python bench/mission_speed.py --seeds 3 --rounds 1      # quick
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from typing import Any

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SIDES = ["1A", "1B", "2A", "2B", "3A", "3B", "4A", "4B", "5A", "5B"]
MISSION = "missions/pallet_scan.xml"
EVERY_FRAME = ["perception.min_view_change_px=0"]

#: stage -> (module, class, method); a method missing in a tree is not timed there
STAGES = {
    "render": ("drivers.sim.renderers.pallet", "PalletRenderer", "__call__"),
    "detector": ("perception.detector", "BlockDetector", "detect_batch"),
    "white balance": ("perception.white_balance", None, "preprocess"),
    "face fit": ("perception.face", "FaceTracker", "fit"),
    "physics": ("drivers.sim.sim_platform", "SimPlatform", "step_to"),
    "run.mcap": ("nodes.mcap_log", "McapRecorder", "after_tick"),
    "tick log": ("bt_engine.runner", "Runner", "_record"),
    "safety": ("nodes.safety_hook", "SafetyHook", "after_tick"),
}


# ------------------------------------------------------------------------------ server side
def install_timers() -> dict[str, list[float]]:
    """Wrap every stage's function to add up its calls and thread time; return the totals
    (stage -> [calls, seconds]), reset by the caller between flights."""
    import importlib

    totals: dict[str, list[float]] = {}
    for stage, (module, cls, name) in STAGES.items():
        owner: Any = importlib.import_module(module)
        if cls is not None:
            owner = getattr(owner, cls, None)
        real = getattr(owner, name, None) if owner is not None else None
        if real is None:
            continue
        acc = totals.setdefault(stage, [0, 0.0])

        def timed(*args, _real=real, _acc=acc, **kwargs):
            t0 = time.thread_time()
            try:
                return _real(*args, **kwargs)
            finally:
                _acc[0] += 1
                _acc[1] += time.thread_time() - t0

        setattr(owner, name, timed)
    return totals


def fly(seed: int, sets: list[str], out: str, totals: dict[str, list[float]]) -> dict:
    """One in-process ``btrun`` flight; its answers and figures."""
    from bt_engine.cli import main

    for acc in totals.values():
        acc[0], acc[1] = 0, 0.0
    side = SIDES[(seed - 100) % len(SIDES)]
    args = [MISSION, "--seed", str(seed), "--out", out, "-q", "--no-report"]
    for item in [f"world.scan_pallet={side}", "wind.gust_std_mps=0.05", *sets]:
        args += [item] if item.startswith("--") else ["--set", item]  # a flag, or a setting
    t0, c0 = time.perf_counter(), time.thread_time()
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(args)
    wall, cpu = time.perf_counter() - t0, time.thread_time() - c0
    with open(os.path.join(out, "summary.json"), encoding="utf-8") as f:
        s = json.load(f)
    shutil.rmtree(out, ignore_errors=True)
    perception = s.get("perception") or {}
    return {
        "seed": seed,
        "side": side,
        "code": code,
        "wall_s": wall,
        "cpu_s": cpu,
        "mission_s": s.get("mission_time_s"),
        "pallet_id": (s.get("blackboard") or {}).get("pallet_id"),
        "blocks": perception.get("blocks"),
        "rendered": totals.get("render", [0])[0],
        "detected": perception.get("frames_processed"),
        "stages": {k: v[1] for k, v in totals.items()},
    }


def serve(tree: str) -> int:
    """Fly the jobs read from stdin (one JSON object a line) with the code of ``tree``."""
    os.chdir(tree)
    sys.path.insert(0, tree)
    import torch

    torch.set_num_threads(1)  # as a campaign worker (bt_engine.campaign.pool)
    totals = install_timers()
    tmp = tempfile.mkdtemp(prefix="mission_speed-")
    for k, line in enumerate(sys.stdin):
        job = json.loads(line)
        rec = fly(job["seed"], job["sets"], os.path.join(tmp, str(k)), totals)
        print(json.dumps(rec), flush=True)
    shutil.rmtree(tmp, ignore_errors=True)
    return 0


# ------------------------------------------------------------------------------ client side
class Server:
    """A warm ``--serve`` process for one tree."""

    def __init__(self, tree: str) -> None:
        env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
        self.proc = subprocess.Popen(
            [sys.executable, os.path.abspath(__file__), "--serve", tree],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=env,
            cwd=tree,
        )

    def fly(self, seed: int, sets: list[str]) -> dict:
        """Fly one job and wait for its record."""
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps({"seed": seed, "sets": sets}) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise SystemExit("a server process died")
        return json.loads(line)

    def close(self) -> None:
        """End the process."""
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        self.proc.wait(timeout=60)


def baseline_tree(ref: str, tmp: str) -> str:
    """A copy of the repository at commit ``ref`` (``git archive``)."""
    dest = os.path.join(tmp, "baseline")
    os.makedirs(dest)
    archive = subprocess.run(
        ["git", "-C", REPO, "archive", ref], check=True, capture_output=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", dest], input=archive, check=True)
    return dest


def _median(rows: list[dict], key: str) -> float:
    return statistics.median(r[key] for r in rows)


def report(results: dict[str, list[dict]]) -> bool:
    """Print the table per variant and the answers check; True if the answers agree."""
    names = list(results)
    ref = names[0]
    stages = sorted({s for rows in results.values() for r in rows for s in r["stages"]})
    print(f"\n{'per run (median)':<26}" + "".join(f"{n:>14}" for n in names))
    lines = [
        ("wall s", lambda rows: _median(rows, "wall_s"), "{:.2f}"),
        (
            "x real time",
            lambda rows: statistics.median(r["mission_s"] / r["wall_s"] for r in rows),
            "{:.1f}",
        ),  # noqa: E501
        ("CPU s", lambda rows: _median(rows, "cpu_s"), "{:.2f}"),
        ("mission s", lambda rows: _median(rows, "mission_s"), "{:.1f}"),
        ("frames rendered", lambda rows: _median(rows, "rendered"), "{:.0f}"),
        ("frames detected", lambda rows: _median(rows, "detected"), "{:.0f}"),
    ]
    for label, fn, fmt in lines:
        print(f"{label:<26}" + "".join(f"{fmt.format(fn(results[n])):>14}" for n in names))
    for stage in stages:
        cells = []
        for n in names:
            vals = [r["stages"][stage] for r in results[n] if stage in r["stages"]]
            cells.append(f"{statistics.median(vals):.3f}" if vals else "-")
        print(f"{'  CPU s, ' + stage:<26}" + "".join(f"{c:>14}" for c in cells))
    rest = []
    for n in names:
        rest.append(statistics.median(r["cpu_s"] - sum(r["stages"].values()) for r in results[n]))
    print(f"{'  CPU s, rest':<26}" + "".join(f"{v:>14.3f}" for v in rest))
    base_wall = _median(results[ref], "wall_s")
    print(f"{'wall ratio to ' + ref:<26}" + "".join(
        f"{base_wall / _median(results[n], 'wall_s'):>13.2f}x" for n in names))  # fmt: skip
    same = True
    for n in names[1:]:
        for a, b in zip(results[ref], results[n], strict=True):
            if (a["pallet_id"], a["blocks"], a["code"]) != (b["pallet_id"], b["blocks"], b["code"]):
                same = False
                print(
                    f"DIFFERENT answer, seed {a['seed']} ({a['side']}): {ref} {a['pallet_id']} "
                    f"blocks {a['blocks']}, {n} {b['pallet_id']} blocks {b['blocks']}"
                )
    right = {n: sum(r["pallet_id"] == r["side"] for r in results[n]) for n in names}
    print(
        f"answers (pallet_id, blocks per scan, exit code) per seed: "
        f"{'identical' if same else 'DIFFER'} across variants; right: "
        + ", ".join(f"{n} {right[n]}/{len(results[n])}" for n in names)
    )
    return same


def campaign(trees: dict[str, str], limit: int, tmp: str) -> None:
    """Time ``btrun campaign ... --workers 1 --limit N`` per tree (A B B A)."""
    names = list(trees)
    order = names + names[::-1]
    walls: dict[str, list[float]] = {n: [] for n in names}
    answers: dict[str, list[str]] = {}
    for k, n in enumerate(order):
        out = os.path.join(tmp, f"campaign-{k}")
        cmd = [sys.executable, "-m", "bt_engine.cli", "campaign", "campaigns/pallet_scan.yaml"]
        cmd += ["--workers", "1", "--limit", str(limit), "--out", out, "--keep-runs", "none"]
        t0 = time.perf_counter()
        subprocess.run(cmd, cwd=trees[n], check=True, capture_output=True)
        walls[n].append(time.perf_counter() - t0)
        with open(os.path.join(out, "results.csv"), encoding="utf-8", newline="") as f:
            answers.setdefault(n, [r["pallet_id"] for r in csv.DictReader(f)])
        shutil.rmtree(out, ignore_errors=True)
    print(f"\nbtrun campaign campaigns/pallet_scan.yaml --workers 1 --limit {limit} (A B B A)")
    for n in names:
        w = statistics.mean(walls[n])
        print(
            f"  {n:<12} {', '.join(f'{x:.1f}' for x in walls[n])} s: "
            f"{limit / w:.3f} runs/s ({w / limit:.2f} s a run, start-up included)"
        )
    if len(names) > 1:
        a, b = walls[names[0]], walls[names[-1]]
        print(
            f"  throughput {names[-1]} / {names[0]}: {statistics.mean(a) / statistics.mean(b):.2f}x"
        )
    same = len({tuple(v) for v in answers.values()}) == 1
    print(f"  pallet_id per row identical: {same} ({answers[names[-1]]})")


def main(argv: list[str] | None = None) -> int:
    """Parse the options, fly the variants, print the figures."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="seeds 100.. (sides cycle 1A..5B)")
    ap.add_argument("--rounds", type=int, default=2, help="flights per seed and variant")
    ap.add_argument("--baseline", default="", help="git commit to compare with (git archive)")
    ap.add_argument("--campaign", type=int, default=0, metavar="N", help="also time N rows")
    ap.add_argument("--serve", metavar="TREE", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.serve:
        return serve(args.serve)
    load = os.getloadavg()
    print(f"load average at the start: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    tmp = tempfile.mkdtemp(prefix="mission_speed-")
    try:
        trees = {"new": REPO}
        variants: list[tuple[str, str, list[str]]] = []
        if args.baseline:
            trees = {"baseline": baseline_tree(args.baseline, tmp), "new": REPO}
            variants.append(("baseline", trees["baseline"], []))
        variants += [
            ("every-frame", REPO, EVERY_FRAME),
            ("new", REPO, []),
            ("campaign row", REPO, ["--no-mcap"]),
        ]
        servers = {tree: Server(tree) for tree in {v[1] for v in variants}}
        seeds = list(range(100, 100 + args.seeds))
        for _, tree, sets in variants:  # warm-up: imports, models, gallery
            servers[tree].fly(seeds[0], sets)
        results: dict[str, list[dict]] = {name: [] for name, _, _ in variants}
        for rnd in range(args.rounds):
            for seed in seeds:
                order = variants if (rnd * len(seeds) + seed) % 2 == 0 else variants[::-1]
                for name, tree, sets in order:
                    results[name].append(servers[tree].fly(seed, sets))
            print(f"round {rnd + 1}/{args.rounds} done", file=sys.stderr)
        for s in servers.values():
            s.close()
        for rows in results.values():
            rows.sort(key=lambda r: r["seed"])
        print(f"{MISSION}, seeds {seeds[0]}..{seeds[-1]}, {args.rounds} round(s), warm processes")
        same = report(results)
        if args.campaign:
            campaign(trees, args.campaign, tmp)
        load = os.getloadavg()
        print(f"load average at the end: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
