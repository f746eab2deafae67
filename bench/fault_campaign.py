"""Fault campaign: seeded simulated runs of missions/pallet_scan.xml with one fault each.

The faults a rig can schedule are ``campaigns/faults.yaml``, run by the campaign engine
(``btrun campaign``: worker processes, each run an in-process ``btrun run`` with its own
run folder, a crashed or hung run recorded as such). The fault is injected at a random
(seeded) mission time through the rig's ``faults.*`` settings, except:

* ``geofence``: the geofence's far x wall stands 5-8 cm beyond the scan line and a gust of
  3-4 m/s pushes the drone towards it while it aligns and scans (a wall drawn across the
  way to the pallet, as this row once did, is refused before flight now);
* ``camera_stall``: the rig's own ``pallet`` renderer streams (as in the default rig), then
  the camera stops delivering frames.

Five faults need a process of their own, and keep one ``btrun run`` process per run:

* ``leaf_exception``: the child process makes ``GoTo`` raise once the mission time passes;
* ``sigint`` / ``sigterm``: the real ``btrun`` executable, paced at ``--realtime`` times real
  time, receives the signal at a random wall time after its tick log appears (a signal during
  Python start-up, before the runner exists, kills the process with nothing flying yet).
* ``gil_hold`` / ``kill9``: what only the guard process can survive. A software Crazyflie in
  a process of its own (``btrun sim serve crazyflie --mocap``) flies ``missions/square.xml``
  through btrun in real time; 3-20 s into the flight ``GoTo`` blocks in native code holding
  the GIL, or btrun is SIGKILLed. Landed = the drone's own state read back through a fresh
  cflib connection (below 10 cm, not flying); logs complete = the guard's summary.json.

For every run the table counts: ended landed and disarmed / crashed / still flying (ground
truth of the simulator), and logs complete (``ticks.jsonl`` parses line by line, its last
record is the last tick of ``summary.json``, ``summary.json`` has a ``safety`` key).

Usage::

    .venv/bin/python bench/fault_campaign.py --runs 20            # about 3 minutes on 2 CPUs
    .venv/bin/python bench/fault_campaign.py --runs 3 --faults gust,sigterm
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)
MISSION = os.path.join(REPO, "missions", "pallet_scan.xml")
CAMPAIGN = os.path.join(REPO, "campaigns", "faults.yaml")
BIN = os.path.dirname(sys.executable)

#: fault type -> what it does (table order)
FAULT_TYPES: dict[str, str] = {
    "link_loss": "radio link down 0.2-1.5 s",
    "mocap_dropout": "mocap frames lost (for good)",
    "mocap_freeze": "mocap repeats its last frame (for good)",
    "camera_stall": "camera stops (report only)",
    "battery_sag": "battery sags 0.5-1.0 V",
    "gust": "gust up to 3 m/s per axis, 1-4 s",
    "geofence": "x wall 5-8 cm past the scan line, gust towards it",
    "leaf_exception": "GoTo raises RuntimeError",
    "sigint": "SIGINT 0.1-2.8 s after start",
    "sigterm": "SIGTERM 0.1-2.8 s after start",
    "link_loss_long": "link down for good (limit)",
    "gil_hold": "a leaf holds the GIL in flight (SITL, guard)",
    "kill9": "SIGKILL of btrun in flight (SITL, guard)",
}
DEFAULT_FAULTS = [f for f in FAULT_TYPES if f != "link_loss_long"]
#: faults that need a process of their own (the others are campaigns/faults.yaml)
PROCESS_FAULTS = ("leaf_exception", "sigint", "sigterm", "gil_hold", "kill9")
#: process faults flown on a software Crazyflie in a process of its own, which outlives
#: btrun: the guard process lands it (docs/safety.md); its state is read back through cflib
GUARD_FAULTS = ("gil_hold", "kill9")


def plan(fault: str, i: int, base_seed: int) -> dict[str, Any]:
    """The seeded parameters of run ``i`` of a fault of :data:`PROCESS_FAULTS`."""
    if fault not in PROCESS_FAULTS:
        raise ValueError(f"{fault} is a campaign fault (campaigns/faults.yaml)")
    rng = random.Random(f"campaign/{base_seed}/{fault}/{i}")
    at = round(rng.uniform(3.0, 55.0), 2)
    job: dict[str, Any] = {"fault": fault, "i": i, "seed": base_seed * 1000 + i, "at_s": at}
    if fault in ("sigint", "sigterm"):
        job["at_s"] = None
        job["wall_s"] = round(rng.uniform(0.1, 2.8), 2)
    if fault in GUARD_FAULTS:  # square.xml in real time: in flight between 3 and 20 s
        job["at_s"] = round(rng.uniform(3.0, 20.0), 2)
    job["sets"] = []
    return job


def campaign_results(
    faults: list[str], runs: int, base_seed: int, out: str, workers: int
) -> list[dict[str, Any]]:
    """Run the rig faults of ``campaigns/faults.yaml`` through the campaign engine; the
    outcome of every run in :func:`run_one`'s shape."""
    from bt_engine.campaign import load_campaign, run_campaign

    c = load_campaign(CAMPAIGN)
    c.faults = [case for case in c.faults or () if case.name in faults]
    if not c.faults:
        return []
    c.seeds = list(range(base_seed * 1000, base_seed * 1000 + runs))
    run = run_campaign(c, out, workers=workers, keep_runs="all")
    results = []
    for row in run.table:
        run_dir = os.path.join(out, row["run_dir"]) if row["run_dir"] else ""
        complete, summary, why = check_logs(run_dir) if run_dir else (False, None, "no folder")
        shown = ""
        if os.path.exists(os.path.join(run_dir, "console.log")):  # what the run printed
            with open(os.path.join(run_dir, "console.log"), encoding="utf-8") as f:
                shown = f.read()
        params = {k: row[k] for k in c.parameters() if row.get(k) is not None}
        job = {"fault": row["fault"], "i": row["seed"] - base_seed * 1000, "seed": row["seed"]}
        res: dict[str, Any] = {
            "job": {**job, "sets": [f"{k}={v}" for k, v in params.items()]},
            "rc": None,
            "complete": complete,
            "why": why,
            "wall_s": row["wall_s"],
            "stderr": "",
            "status": row["status"],
            "reason": row["reason"],
            "final": row["final_state"],
            "disarmed": row["disarmed"],
            "crashed": row["crashed"],
            "landed": row["landed"],
            "fault": row["supervisor_fault"],
            "t_s": row["fault_t_s"],
            "mission_time_s": row["mission_time_s"],
            "traceback_on_screen": "Traceback" in shown,
        }
        results.append(res)
    return results


def check_logs(run_dir: str) -> tuple[bool, dict | None, str]:
    """(complete, summary, why not): tick log parses to the last tick, summary present."""
    spath = os.path.join(run_dir, "summary.json")
    if not os.path.exists(spath):
        return False, None, "no summary.json"
    try:
        with open(spath) as f:
            summary = json.load(f)
    except ValueError:
        return False, None, "summary.json does not parse"
    last = None
    try:
        with open(os.path.join(run_dir, "ticks.jsonl"), encoding="utf-8") as f:
            for n, line in enumerate(f):
                rec = json.loads(line)
                if n == 0 and "header" not in rec:
                    return False, summary, "no header line"
                if "tick" in rec:
                    if last is not None and rec["tick"] != last + 1:
                        return False, summary, f"tick {last} followed by {rec['tick']}"
                    last = rec["tick"]
    except (OSError, ValueError) as exc:
        return False, summary, f"tick log: {exc}"
    if last != summary.get("ticks"):
        return False, summary, f"last logged tick {last}, summary says {summary.get('ticks')}"
    if "safety" not in summary:
        return False, summary, "no safety summary"
    return True, summary, ""


def drone_state(uri: str) -> dict[str, Any]:
    """The drone's own state through a fresh cflib connection (independent of btrun):
    height, armed, flying (supervisor.info bits 1 and 4)."""
    import cflib.crtp
    from cflib.crazyflie import Crazyflie
    from cflib.crazyflie.log import LogConfig
    from cflib.crazyflie.syncCrazyflie import SyncCrazyflie
    from cflib.crazyflie.syncLogger import SyncLogger

    cflib.crtp.init_drivers()
    with (
        tempfile.TemporaryDirectory(prefix="btrun-check-toc-") as cache,
        SyncCrazyflie(uri, cf=Crazyflie(rw_cache=cache)) as scf,
    ):
        conf = LogConfig("check", 20)
        conf.add_variable("stateEstimate.z", "float")
        conf.add_variable("supervisor.info", "uint16_t")
        with SyncLogger(scf, conf) as logger:
            for _stamp, data, _conf in logger:
                info = int(data["supervisor.info"])
                return {
                    "z_m": data["stateEstimate.z"],
                    "armed": bool(info & (1 << 1)),
                    "flying": bool(info & (1 << 4)),
                }
    raise RuntimeError(f"{uri}: no log data")


def run_guarded(job: dict[str, Any], out: str) -> dict[str, Any]:
    """A :data:`GUARD_FAULTS` job: ``btrun sim serve crazyflie --mocap`` in a process of its
    own, ``btrun`` flying missions/square.xml on it through the guard; at ``at_s`` a leaf
    holds the GIL (child mode) or btrun is SIGKILLed; then the drone's state is read back
    through cflib."""
    run_dir = os.path.join(out, f"{job['fault']}-{job['i']:03d}")
    btrun = [sys.executable, "-c", "from bt_engine.cli import main; raise SystemExit(main())"]
    emu = subprocess.Popen(
        [*btrun, "sim", "serve", "crazyflie", "--mocap", "--port", "0"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    t0 = time.monotonic()
    res: dict[str, Any] = {"job": job, "complete": False, "why": ""}
    try:
        uri = emu.stdout.readline().split()[3].rstrip(",")  # type: ignore[union-attr]
        common = ["run", os.path.join(REPO, "missions", "square.xml"), "--rig", "rigs/sitl.yaml"]
        for item in ("crazyflie.sitl=false", f"crazyflie.uri={uri}", "aideck.enabled=false",
                     "crazyflie.pose_source=none", "control.pose_source=onboard"):  # fmt: skip
            common += ["--set", item]
        common += ["--out", run_dir, "--quiet", "--no-report", "--seed", str(job["seed"])]
        if job["fault"] == "gil_hold":
            cmd = [sys.executable, os.path.abspath(__file__), "--child", json.dumps(job), "--"]
        else:
            cmd = btrun
        proc = subprocess.Popen(cmd + common, cwd=REPO, stderr=subprocess.PIPE, text=True,
                                stdout=subprocess.DEVNULL)  # fmt: skip
        if job["fault"] == "kill9":
            log = os.path.join(run_dir, "ticks.jsonl")
            while not os.path.exists(log) and proc.poll() is None:
                time.sleep(0.05)
            try:
                proc.wait(timeout=job["at_s"])
            except subprocess.TimeoutExpired:
                proc.kill()
        try:
            _, err = proc.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
        end = time.monotonic() + 20.0
        summary = None
        while summary is None and time.monotonic() < end:  # the guard lands, then writes
            try:
                with open(os.path.join(run_dir, "summary.json")) as f:
                    summary = json.load(f)
            except (OSError, ValueError):
                time.sleep(0.1)
        state = drone_state(uri)
        guard = (summary or {}).get("guard", {})
        landed = state["z_m"] < 0.1 and not state["flying"]
        res.update(
            rc=proc.returncode,
            complete=summary is not None and guard.get("took_over") is True,
            why="" if summary is not None else "no summary.json",
            status=(summary or {}).get("status"),
            reason=guard.get("reason") or (summary or {}).get("reason"),
            final="landed" if landed else "flying",
            disarmed=not state["armed"],
            drone=state,
            traceback_on_screen="Traceback" in err,
            stderr=err[-2000:],
        )
    finally:
        emu.terminate()
        emu.wait(10)
    res["wall_s"] = time.monotonic() - t0
    return res


def run_one(job: dict[str, Any], out: str, realtime: float) -> dict[str, Any]:
    """Run one job as a child process; return its outcome."""
    if job["fault"] in GUARD_FAULTS:
        return run_guarded(job, out)
    run_dir = os.path.join(out, f"{job['fault']}-{job['i']:03d}")
    common = [
        "run",
        MISSION,
        "--quiet",
        "--no-report",
        "--seed",
        str(job["seed"]),
        "--out",
        run_dir,
        "--max-time",
        "200",
    ]
    for s in job["sets"]:
        common += ["--set", s]
    t0 = time.monotonic()
    if job["fault"] in ("sigint", "sigterm"):
        exe = os.path.join(BIN, "btrun")
        cmd = [exe] if os.path.exists(exe) else [sys.executable, "-m", "bt_engine.cli"]
        proc = subprocess.Popen(
            cmd + common + ["--realtime", str(realtime)],
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        log = os.path.join(run_dir, "ticks.jsonl")
        start = time.monotonic() + 30.0
        while not os.path.exists(log) and proc.poll() is None and time.monotonic() < start:
            time.sleep(0.01)  # the runner is up (before that the drone is not flying yet)
        try:
            proc.wait(timeout=job["wall_s"])
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGINT if job["fault"] == "sigint" else signal.SIGTERM)
        try:
            _, err = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
        rc = proc.returncode
    else:
        proc2 = subprocess.run(
            [sys.executable, os.path.abspath(__file__), "--child", json.dumps(job), "--"] + common,
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=300,
        )
        rc, err = proc2.returncode, proc2.stderr
    complete, summary, why = check_logs(run_dir)
    res: dict[str, Any] = {
        "job": job,
        "rc": rc,
        "complete": complete,
        "why": why,
        "wall_s": time.monotonic() - t0,
        "stderr": err[-2000:],
    }
    if summary is not None:
        saf, sim = summary.get("safety", {}), summary.get("sim", {})
        res.update(
            status=summary.get("status"),
            reason=summary.get("reason"),
            final=saf.get("final_state"),
            disarmed=saf.get("disarmed"),
            crashed=sim.get("crashed"),
            landed=sim.get("landed"),
            fault=saf.get("fault"),
            t_s=saf.get("t_s"),
            mission_time_s=summary.get("mission_time_s"),
            traceback_on_screen="Traceback" in err,
        )
    return res


def child(job: dict[str, Any], argv: list[str]) -> int:
    """Child mode: install the job's test-only patches, then run ``btrun``."""
    from bt_engine.cli import main

    if job["fault"] == "leaf_exception":
        import nodes.flight as flight

        original = flight.GoTo.on_running
        at = float(job["at_s"])

        def on_running(self):  # type: ignore[no-untyped-def]
            if self.now() >= at:
                raise RuntimeError("injected leaf bug (fault campaign)")
            return original(self)

        flight.GoTo.on_running = on_running  # type: ignore[method-assign]
    if job["fault"] == "gil_hold":
        import ctypes

        import nodes.flight as flight

        original_goto = flight.GoTo.on_running
        at_s = float(job["at_s"])

        def hold(self):  # type: ignore[no-untyped-def]
            if self.now() >= at_s:  # native code that keeps the GIL: nothing in-process runs
                ctypes.PyDLL(None).sleep(600)
            return original_goto(self)

        flight.GoTo.on_running = hold  # type: ignore[method-assign]
    return int(main(argv) or 0)


def table(results: list[dict[str, Any]], faults: list[str]) -> str:
    """The per-fault table (Markdown)."""
    head = (
        "| fault | injected | runs | landed+disarmed | crashed | flying | logs complete "
        "| ABORTED by fault | traceback on screen |"
    )
    rows = [head, "|" + "---|" * 9]
    for f in faults:
        rs = [r for r in results if r["job"]["fault"] == f]
        landed = sum(1 for r in rs if r.get("final") == "landed" and r.get("disarmed"))
        crashed = sum(1 for r in rs if r.get("final") == "crashed")
        flying = sum(1 for r in rs if r.get("final") not in ("landed", "crashed"))
        complete = sum(1 for r in rs if r["complete"])
        aborted = sum(1 for r in rs if r.get("status") == "ABORTED")
        tb = sum(1 for r in rs if r.get("traceback_on_screen"))
        rows.append(
            f"| {f} | {FAULT_TYPES[f]} | {len(rs)} | {landed} | {crashed} | {flying} "
            f"| {complete} | {aborted} | {tb} |"
        )
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    """Command line entry point."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--child"]:
        return child(json.loads(argv[1]), argv[3:])
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=20, help="runs per fault type (default 20)")
    ap.add_argument("--seed", type=int, default=1, help="campaign seed (default 1)")
    ap.add_argument(
        "--faults",
        default=",".join(DEFAULT_FAULTS),
        help=f"comma-separated subset of {', '.join(FAULT_TYPES)}",
    )
    ap.add_argument(
        "--jobs",
        type=int,
        default=max(2, (os.cpu_count() or 2)),
        help="parallel runs: campaign workers, then process runs (default: CPUs)",
    )
    ap.add_argument(
        "--realtime",
        type=float,
        default=20.0,
        help="pace of the signal runs (x real time, default 20)",
    )
    ap.add_argument("--out", default=None, help="keep the run folders here (default: temp)")
    ap.add_argument("--json", default=None, help="write every run's outcome to this file")
    args = ap.parse_args(argv)
    faults = [f.strip() for f in args.faults.split(",") if f.strip()]
    unknown = [f for f in faults if f not in FAULT_TYPES]
    if unknown:
        ap.error(f"unknown fault types {unknown}; known: {list(FAULT_TYPES)}")
    out = args.out or tempfile.mkdtemp(prefix="fault_campaign-")
    t0 = time.monotonic()
    rig_faults = [f for f in faults if f not in PROCESS_FAULTS]
    results = campaign_results(
        rig_faults, args.runs, args.seed, os.path.join(out, "campaign"), args.jobs
    )
    jobs = [plan(f, i, args.seed) for f in faults if f in PROCESS_FAULTS for i in range(args.runs)]
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        results += list(pool.map(lambda j: run_one(j, out, args.realtime), jobs))
    wall = time.monotonic() - t0
    print(table(results, faults))
    print(
        f"\n{len(results)} runs in {wall:.0f} s wall (--runs {args.runs} --seed {args.seed}, "
        f"--jobs {args.jobs}, signals at --realtime {args.realtime:g})"
    )
    bad = [r for r in results if not r["complete"] or r.get("final") != "landed"]
    for r in bad[:15]:
        j = r["job"]
        print(
            f"  {j['fault']} #{j['i']} seed {j['seed']}: {r.get('status')} "
            f"{r.get('reason')!s:.90} final={r.get('final')} logs={r['why'] or 'ok'}"
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1, default=str)
    if args.out is None:
        shutil.rmtree(out, ignore_errors=True)
    return 0 if not [r for r in bad if r["job"]["fault"] != "link_loss_long"] else 1


if __name__ == "__main__":
    sys.exit(main())
