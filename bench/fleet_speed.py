"""Lock-step speed of the site fleet (issue 27): x real time and CPU of ``btrun fleet``.

Flies ``btrun fleet fleets/site_4.yaml --seed S --quiet --no-report`` (4 drones, 144 places,
one lock-step clock) in a fresh process per run, for the tree of git commit ``--new``
(default HEAD; ``git archive``, so uncommitted edits are left out) and, with
``--baseline REF``, for that tree with ``--paths`` taken from commit REF (default: the
whole tree of REF), alternating the two (A B, then B A, ...) so a busy machine slows them
alike. Per variant and seed it prints the mission time, the wall time of the lock-step run
(``summary.json``'s ``wall_time_s``, what ``btrun fleet`` prints as "x real time"), the
whole process's CPU time (user + sys, start-up and models included), and, against the
baseline, whether the answers (``inventory.csv`` without its ``run`` column) and the tick
logs (every line after the header) are the same. Each run also prints how many cores the
process kept busy in each 5 s of wall time (Linux ``/proc``): where the run is held to one
core and where it already uses both. The machine has 2 cores shared with other work: CPU
time is the steadier figure, wall time the target's. It prints figures; it is not a test::

    .venv/bin/python bench/fleet_speed.py --seeds 100 --baseline 81e31af \
        --paths perception/verify.py perception/gallery_match.py perception/synth/render.py \
        drivers/sim/renderers/pallet.py
    .venv/bin/python bench/fleet_speed.py --seeds 100 200 --rounds 2
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FLEET = "fleets/site_4.yaml"


def tree(ref: str, dest: str, paths: list[str] | None = None, base: str = "") -> str:
    """A copy of the repository at commit ``ref`` (``git archive``); with ``paths``, the
    tree of commit ``base`` with those files taken from ``ref``."""
    os.makedirs(dest)
    archive = subprocess.run(
        ["git", "-C", REPO, "archive", base if paths else ref], check=True, capture_output=True
    )
    subprocess.run(["tar", "-x", "-C", dest], input=archive.stdout, check=True)
    for path in paths or []:
        blob = subprocess.run(
            ["git", "-C", REPO, "show", f"{ref}:{path}"], check=True, capture_output=True
        )
        with open(os.path.join(dest, path), "wb") as f:
            f.write(blob.stdout)
    return dest


def _cpu_ticks(pid: int) -> int | None:
    """User + system CPU of process ``pid`` in clock ticks (Linux ``/proc``; None elsewhere
    or once it has ended)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return int(fields[11]) + int(fields[12])  # utime, stime (fields 14 and 15 of stat)


def fly(where: str, seed: int, out: str, window_s: float = 5.0) -> dict:
    """One ``btrun fleet`` run of the tree at ``where`` (its own packages first on the
    path), with the cores it kept busy in each ``window_s`` of wall time (``cores``)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "bt_engine.cli", "fleet", FLEET, "--seed", str(seed)]
    cmd += ["--out", out, "--quiet", "--no-report"]
    hz = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    cores: list[float] = []
    with subprocess.Popen(
        cmd, cwd=where, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    ) as proc:
        last, last_t = 0, t0
        while True:
            try:
                stdout, stderr = proc.communicate(timeout=window_s)
                break
            except subprocess.TimeoutExpired:
                now_ticks, now = _cpu_ticks(proc.pid), time.perf_counter()
                if now_ticks is not None:
                    cores.append((now_ticks - last) / hz / (now - last_t))
                    last, last_t = now_ticks, now
    elapsed = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    try:
        with open(os.path.join(out, "summary.json"), encoding="utf-8") as f:
            s = json.load(f)
    except OSError:
        sys.exit(f"{where}: btrun fleet failed ({proc.returncode}):\n{stdout}\n{stderr}")
    return {
        "mission_s": s["mission_time_s"],
        "wall_s": s["wall_time_s"],
        "cpu_s": cpu,
        "process_s": elapsed,
        "status": s["status"],
        "out": out,
        "cores": cores,
    }


def answers(out: str) -> list[dict]:
    """``inventory.csv``'s rows without the ``run`` column (the run folder's name)."""
    with open(os.path.join(out, "inventory.csv"), encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        r.pop("run", None)
    return rows


def ticks(out: str) -> dict[str, list[str]]:
    """Each drone's tick log without its header line (which names the tree's files)."""
    found = {}
    drones = os.path.join(out, "drones")
    for d in sorted(os.listdir(drones)):
        with open(os.path.join(drones, d, "ticks.jsonl"), encoding="utf-8") as f:
            found[d] = f.read().split("\n")[1:]
    return found


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[100])
    ap.add_argument("--new", default="HEAD", help="git commit flown as 'new' (git archive)")
    ap.add_argument("--baseline", default="", help="git commit to compare with (git archive)")
    ap.add_argument(
        "--paths", nargs="*", default=None, help="only these files from --baseline (else all)"
    )
    ap.add_argument("--rounds", type=int, default=1, help="runs per variant and seed")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="fleet_speed_") as tmp:
        variants = [("new", tree(args.new, os.path.join(tmp, "new")))]
        if args.baseline:
            base = tree(args.baseline, os.path.join(tmp, "baseline"), args.paths, args.new)
            variants.insert(0, ("baseline", base))
        results: dict[tuple[str, int], list[dict]] = {}
        for r in range(args.rounds):
            order = variants if r % 2 == 0 else variants[::-1]
            for seed in args.seeds:
                for name, where in order:
                    out = os.path.join(tmp, f"{name}-{seed}-{r}")
                    res = fly(where, seed, out)
                    results.setdefault((name, seed), []).append(res)
                    print(
                        f"{name:8} seed {seed}: {res['status']}, {res['mission_s']:.1f} s mission "
                        f"in {res['wall_s']:.1f} s wall ({res['mission_s'] / res['wall_s']:.2f}x "
                        f"real time), {res['cpu_s']:.1f} s CPU (process {res['process_s']:.1f} s)",
                        flush=True,
                    )
                    trace = " ".join(f"{c:.1f}" for c in res["cores"])
                    print(f"{'':8} cores busy per 5 s of wall: {trace}", flush=True)
        print("\nvariant   seed  mission (s)  wall (s)  x real time  CPU (s)  x per CPU second")
        for (name, seed), runs in results.items():
            wall = statistics.median(x["wall_s"] for x in runs)
            cpu = statistics.median(x["cpu_s"] for x in runs)
            mission = runs[0]["mission_s"]
            print(
                f"{name:8} {seed:5} {mission:12.1f} {wall:9.1f} {mission / wall:12.2f} "
                f"{cpu:8.1f} {mission / cpu:17.2f}"
            )
        if args.baseline:
            for seed in args.seeds:
                base, new = results[("baseline", seed)][0], results[("new", seed)][0]
                same_rows = answers(base["out"]) == answers(new["out"])
                same_ticks = ticks(base["out"]) == ticks(new["out"])
                print(
                    f"seed {seed}: answers {'the same' if same_rows else 'DIFFER'}, "
                    f"tick logs {'the same' if same_ticks else 'DIFFER'}"
                )


if __name__ == "__main__":
    main()
