"""``btrun fleet FLEET.yaml``: fly every drone of a fleet file in one run.

Each drone gets its own mission instance (own blackboard, resources, tick log, ``run.mcap``,
summary and report under ``drones/<name>/``) and its own rig section (its pad as start
position, its URI); in simulation all of them run in this process on one lock-step clock
(deterministic per seed), in SITL each starts its own emulator, on hardware each connects to
its own Crazyflie. The places are split between the drones (:mod:`nodes.fleet.plan`); the
airspace and the separation guard (:mod:`drivers.safety.airspace`) keep them apart. One
merged inventory (``inventory.csv`` / ``inventory.json``), one ``summary.json`` and one
``report.html`` with every track are written in the fleet's run folder.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from typing import Any

from bt_engine.arg_types import positive
from bt_engine.clock import SimClock, WallClock
from bt_engine.files import atomic_write_text
from bt_engine.fleet import FleetRunner
from bt_engine.run_cmd import (
    PreparedRun,
    finish,
    make_runner,
    prepare,
    real_time_words,
    release,
    run_dir_problem,
    start_mission_clock,
    used_run_dir_problem,
)
from bt_engine.spec import Loc, MissionError, Problem, plural
from bt_engine.ticklog import started_now
from drivers.safety.airspace import Airspace, SeparationGuard
from drivers.safety.policies import SafetyConfig
from nodes.fleet.check import (
    check_fleet,
    common_sets,
    drone_sets,
    given_sets,
    layout,
    planned_places,
    previous_run,
    resumed_seed,
    rig_and_world,
    split,
    truth,
)
from nodes.fleet.spec import FleetSpec, load_fleet
from nodes.inventory_log import InventoryError, InventoryLog, discrepancy_lines, pace, pace_line

DRONE_CONTACT_M = 0.12  # two Crazyflie collision spheres (2 x 0.06 m) touch
LANDING_CLEARANCE_M = 0.12  # a spot a landing moves to is this clear of obstacles


def setup(p: argparse.ArgumentParser) -> None:
    """The ``btrun fleet`` options."""
    p.add_argument("fleet", help="fleet file (fleets/*.yaml)")
    p.add_argument("--seed", type=int, default=None, help="seed (default: the fleet file's)")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="for every drone, after the fleet file's set: (blackboard, rig, world)",
    )
    p.add_argument("--out", help="run folder (default runs/<fleet>-<time>)")
    p.add_argument(
        "--rate",
        type=positive("a tick rate in Hz", 1000.0),
        default=50.0,
        help="tick rate in Hz (default 50)",
    )
    p.add_argument(
        "--max-time", type=positive("a time in s"), default=None, help="mission time limit, s"
    )
    p.add_argument(
        "--resume",
        metavar="RUN",
        help="continue an interrupted fleet run: its inventory's answered places are kept "
        "and not flown again",
    )
    p.add_argument(
        "--store",
        metavar="URL",
        help="site store the merged inventory is recorded in (sqlite:///FILE, "
        "postgresql://...; default site.sqlite beside the run folder; docs/store.md)",
    )
    p.add_argument(
        "--check",
        action="store_true",
        help="check the fleet file, its rig and world, the place split and each drone's "
        "mission with its settings, as before take-off; fly nothing",
    )
    p.add_argument("--quiet", "-q", action="store_true", help="print only the results")
    p.add_argument("--no-report", action="store_true", help="skip the reports")
    p.add_argument("--no-mcap", action="store_true", help="do not record each drone's run.mcap")


def _drone_args(spec: FleetSpec, args: Any, sets: list[str], seed: int, out: str) -> Any:
    return argparse.Namespace(
        mission=spec.mission,
        rig=spec.rig,
        set=sets,
        seed=seed,
        rate=args.rate,
        out=out,
        max_time=args.max_time or spec.data["max_time_s"],
        realtime=None,
        tick_budget=None,
        quiet=True,
        no_report=args.no_report,
        no_mcap=getattr(args, "no_mcap", False),
        groot=None,
        groot_address=None,
        include_path=[],
        resume=None,
    )


def run(args: Any) -> int:
    """``btrun fleet``: check, fly, merge, report; the exit code (0: every drone SUCCESS).
    With ``--check``: the checks alone (exit 0: every input is fit to fly)."""
    if getattr(args, "check", False):
        lines = check_fleet(args.fleet, args.set, args.seed, args.resume)
        print(f"{args.fleet}: ok ({plural(len(lines), 'drone')}; " + ", ".join(lines) + ")")
        return 0
    previous = previous_run(args.resume)
    spec = load_fleet(args.fleet, given_sets(args.set, previous))  # pads in the world flown
    seed = resumed_seed(previous, args.seed, args.resume)
    seed = spec.data["seed"] if seed is None else seed
    out = args.out or os.path.join("runs", f"{spec.data['name']}-{time.strftime('%Y%m%d-%H%M%S')}")
    bad_dir = run_dir_problem(out) or (used_run_dir_problem(out) if args.out else None)
    if bad_dir is not None:  # before any drone, store or guard is started
        raise MissionError([bad_dir])
    common = common_sets(spec, args.set, previous)
    rig, world = rig_and_world(spec, common, seed)
    try:
        merged = InventoryLog(out, args.resume, "fleet", truth(rig, world), None, layout(world))
    except InventoryError as exc:
        raise MissionError([exc.problem()]) from None
    merged.recorder = _recorder(args, out, spec)
    shares = _split(spec, world, merged, common)
    os.makedirs(out, exist_ok=True)
    atomic_write_text(
        os.path.join(out, "fleet.json"),
        json.dumps(
            {
                "fleet": os.path.abspath(spec.path),
                "seed": seed,
                "started": started_now(),
                "set": [item for item in common if item.partition("=")[0] != "places"],
                "cwd": os.getcwd(),  # what relative paths in "set" are relative to
                "run_dir": os.path.abspath(out),  # the folder's name then (it may be renamed)
                "places": merged.planned if shares is not None else None,
            },
            indent=1,
        ),
    )
    printer = _RowPrinter(merged, args.quiet)
    clock = WallClock(1.0) if rig.realtime_factor else SimClock()
    runs: dict[str, PreparedRun] = {}
    try:
        for d in spec.drones:
            if shares is not None and not shares[d.name]:
                if not args.quiet:
                    print(f"btrun fleet: {d.name} has no place left to fly; it stays on its pad")
                continue
            sets = drone_sets(d, common, shares[d.name] if shares is not None else None)
            ns = _drone_args(spec, args, sets, seed, os.path.join(out, "drones", d.name))
            runs[d.name] = prepare(
                ns,
                clock=clock,
                resources={
                    "drone": d.name,
                    "inventory_sink": printer,
                    "inventory_run": merged.run,  # rows name the fleet's run folder
                },
                warn=not runs,
            )
    except BaseException:
        for r in runs.values():
            if r.platform is not None:
                r.platform.shutdown("another drone of the fleet could not be prepared")
            release(r.target, *r.hooks, written=False)
        raise
    return _fly(spec, args, runs, merged, out, seed, printer)


def _recorder(args: Any, out: str, spec: FleetSpec) -> Any:
    """The merged inventory's recorder into the site store (docs/store.md); a store that
    cannot be used is refused before anything flies."""
    from nodes.site.recording import open_recorder
    from store import StoreError

    extra = {"fleet": spec.data["name"], "mission": os.path.abspath(spec.mission)}
    try:
        return open_recorder(getattr(args, "store", None), out, extra=extra)
    except StoreError as exc:
        raise MissionError([Problem(Loc("--store", 0, 0), str(exc))]) from None


def _split(
    spec: FleetSpec, world: Any, merged: InventoryLog, common: list[str]
) -> dict[str, list[str]] | None:
    """Each drone's places not yet answered (None: neither the fleet file nor --set names
    places); the merged inventory learns the planned places."""
    places = planned_places(spec, world, common)
    if places is None:
        return None
    merged.planned = list(places)
    done = merged.finished()
    return split(spec, world, [p for p in places if p not in done])


class _RowPrinter:
    """The drones' inventory sink: merge each drone's rows, print each new one."""

    def __init__(self, merged: InventoryLog, quiet: bool) -> None:
        self.merged, self.quiet = merged, quiet
        self.seen: set[tuple[str, Any]] = set()

    def __call__(self, log: InventoryLog) -> None:
        self.merged.absorb(log)
        if self.quiet:
            return
        for place, row in log.rows.items():
            key = (place, row.get("mission_time_s"))
            if place in log.carried or key in self.seen:
                continue
            self.seen.add(key)
            print(
                f"[{row.get('mission_time_s') or 0:8.2f} s] {log.drone} {place}: "
                f"{row.get('answer') or '-'} ({row.get('status')})",
                flush=True,
            )


def _geofence_of(r: PreparedRun) -> Any:
    """The drone's geofence test with its margin (a point it may step aside to), or None
    when its safety supervisor does not check one."""
    for hook in r.hooks:  # nodes.safety_hook.SafetyHook: its supervisor's config
        config = getattr(getattr(hook, "supervisor", None), "config", None)
        if isinstance(config, SafetyConfig) and config.geofence_enabled:
            return lambda p, c=config: c.inside(p, c.geofence_margin_m)
    return None


def _clear_of(runs: dict[str, PreparedRun]) -> Any:
    """Whether a point is clear of the simulated world's obstacles for a drone (a spot a
    landing may move to); None without a simulated world (a real site's obstacles are not
    known here: a landing then moves only inside the geofence)."""
    for r in runs.values():
        world = getattr(r.platform, "world", None)
        if world is not None and hasattr(world, "collision"):
            return lambda p, w=world: w.collision(p[0], p[1], p[2], LANDING_CLEARANCE_M) is None
    return None


def _contact(runs: dict[str, PreparedRun]) -> tuple[float, list[str]] | None:
    """The closest two drones stand at the end (a drone that came down onto another, or
    landed on it after the separation guard stopped watching: an emergency landing) and
    which; None for a single drone."""
    at = [(n, tuple(r.platform.vehicle.position)) for n, r in runs.items()]
    pairs = [(math.dist(p, q), [a, b]) for i, (a, p) in enumerate(at) for b, q in at[i + 1 :]]
    return min(pairs) if pairs else None


def _fly(
    spec: FleetSpec,
    args: Any,
    runs: dict[str, PreparedRun],
    merged: InventoryLog,
    out: str,
    seed: int,
    printer: _RowPrinter,
) -> int:
    sep = spec.data["separation"]
    airspace = Airspace(sep["minimum_m"])
    vehicles = {}
    for name, r in runs.items():
        v = r.platform.vehicle
        v.name = name
        airspace.add(v, _geofence_of(r))
        vehicles[name] = v
    airspace.clear = _clear_of(runs)
    guard = SeparationGuard(vehicles, sep["minimum_m"], sep["hold_margin_m"])
    if runs:  # one clock for all drones: mission time 0 is the fleet's first tick
        start_mission_clock(next(iter(runs.values())).clock, [r.platform for r in runs.values()])
    runners = {name: make_runner(r) for name, r in runs.items()}
    fleet = FleetRunner(runners, hooks=[airspace, guard])
    if not args.quiet:
        mode = (
            "real time"
            if not getattr(fleet.clock, "is_simulated", False)
            else f"lock-step, seed {seed}"
        )
        print(
            f"btrun fleet: {spec.data['name']}: {plural(len(runs), 'drone')} ({mode}); run folder {out}"
        )
    wall0 = time.perf_counter()
    try:
        results = fleet.run(args.max_time or spec.data["max_time_s"])
    finally:
        for r in runs.values():
            r.log.close()
    wall = time.perf_counter() - wall0
    codes = {}
    try:
        for name, r in runs.items():
            codes[name] = finish(r, runners[name], results[name], echo=False)
    finally:  # each drone's guard process: its summary is written (or never will be)
        for r in runs.values():
            release(r.target, *r.hooks, written=r.summary is not None)
    summary = _summary(spec, runs, results, merged, airspace, guard, seed, wall, out)
    if not args.no_report:
        from nodes.fleet.report import write_fleet_report

        summary["report"] = os.path.relpath(write_fleet_report(out, summary, runners, runs), out)
    atomic_write_text(os.path.join(out, "summary.json"), json.dumps(summary, indent=2))
    if merged.recorder is not None:  # the run's end and its last rows in the site store
        merged.recorder.finish(summary["status"])
    _print(summary, out, args.fleet)
    ok = all(c == 0 for c in codes.values()) and runs and summary["status"] == "SUCCESS"
    return 0 if ok else 1


def _summary(
    spec: FleetSpec,
    runs: dict[str, PreparedRun],
    results: dict[str, Any],
    merged: InventoryLog,
    airspace: Airspace,
    guard: SeparationGuard,
    seed: int,
    wall_s: float,
    out: str,
) -> dict:
    drones = {}
    world_hits = []
    for name, r in runs.items():
        res = results[name]
        s = r.summary or {}
        truth = s.get("sim") or s.get("vehicle") or {}
        inv = s.get("inventory") or {}
        hits = truth.get("collisions") or []
        world_hits += [{"drone": name, **h} for h in hits]
        drones[name] = {
            "status": res.status,
            "reason": res.reason,
            "mission_time_s": round(res.mission_time_s, 3),
            "ticks": res.ticks,
            "run_dir": os.path.relpath(r.run_dir, out),
            "places": inv.get("places", 0),
            "answered": inv.get("places", 0) - (inv.get("status") or {}).get("not_scanned", 0),
            "battery_swaps": (truth.get("battery") or {}).get("swaps"),
            "landed": truth.get("landed"),
            "collisions": len(hits),
            "waits": r.platform.vehicle.waits,
            "pauses": r.platform.vehicle.pauses,
            "asides": r.platform.vehicle.asides,
        }
    statuses = [d["status"] for d in drones.values()]
    mission_time = max((d["mission_time_s"] for d in drones.values()), default=0.0)
    inventory = merged.run_summary() if merged.planned else None
    if inventory is not None:  # the fleet's pace: over the fleet's mission time
        inventory.update(pace(inventory["places_answered"], mission_time, len(drones)))
    sep = guard.summary()
    sep["airspace_waits"] = airspace.waits
    sep["airspace_asides"] = airspace.asides  # steps aside that broke a mutual wait
    sep["landings_moved"] = airspace.landings_moved  # beside a drone standing there
    sep["airspace_events"] = airspace.events[:200]
    closest, pair = sep.get("closest_m"), sep.get("closest_pair")
    end = _contact(runs)
    if end is not None and (closest is None or end[0] < closest):
        closest, pair = round(end[0], 3), end[1]
        sep["closest_m"], sep["closest_pair"] = closest, pair
    touched = closest is not None and closest < DRONE_CONTACT_M
    status = (
        "SUCCESS"
        if statuses and all(s == "SUCCESS" for s in statuses)
        else ("ABORTED" if "ABORTED" in statuses else "FAILURE")
    )
    return {
        "fleet": spec.data["name"],
        "file": os.path.abspath(spec.path),
        "mission": spec.mission,
        "seed": seed,
        # two drones that touched: never a success, whatever their missions returned
        "status": "FAILURE" if touched and status == "SUCCESS" else status,
        "mission_time_s": mission_time,
        "wall_time_s": round(wall_s, 3),
        "drones": drones,
        "inventory": inventory,
        "separation": sep,
        "collisions": {
            "world": world_hits,
            "drones": 1 if touched else 0,
            "drone_pair": pair if touched else None,
        },
    }


def _print(summary: dict, out: str, fleet_file: str = "FLEET") -> None:
    """The fleet's console lines; an interrupted run (or places left without an answer)
    ends with the command that continues it."""
    print(
        f"fleet {summary['fleet']}: {summary['status']} ({plural(len(summary['drones']), 'drone')}, "
        f"{summary['mission_time_s']:.1f} s mission time, {summary['wall_time_s']:.1f} s wall, "
        f"{real_time_words(summary['mission_time_s'], summary['wall_time_s'])})"
    )
    for name, d in summary["drones"].items():
        places = f", {d['answered']} of {plural(d['places'], 'place')} answered"
        print(
            f"  {name}: {d['status']}: {d['reason']} ({d['mission_time_s']:.1f} s"
            f"{places if summary.get('inventory') else ''})"
        )
    inv = summary.get("inventory")
    if inv:
        for line in discrepancy_lines(inv, out):  # the counts per category lead
            print(line)
        parts = [f"{v} {k.replace('_', ' ')}" for k, v in inv["status"].items()]
        line = f"inventory: {plural(inv['places'], 'place')}, " + ", ".join(parts)
        if inv.get("carried_over"):
            line += f" ({inv['carried_over']} carried over from the resumed run)"
        print(line)
        if inv.get("places_per_hour") is not None:
            print(pace_line(inv))
        if "right" in inv:
            print(
                f"inventory against the simulator: {inv['right']} of {inv['places']} right, "
                f"{inv['wrong']} wrong identities accepted"
            )
        print(f"inventory: {os.path.join(out, 'inventory.csv')}")
    s = summary["separation"]
    closest = "-" if s["closest_m"] is None else f"{s['closest_m']:.2f} m"
    print(
        f"separation: closest {closest} (minimum {s['minimum_m']:g} m), {s['violations']} "
        f"violations, {s['holds']} holds, {s['airspace_waits']} airspace waits"
        + (f", {s['airspace_asides']} steps aside" if s.get("airspace_asides") else "")
    )
    if (summary.get("collisions") or {}).get("drones"):
        a, b = summary["collisions"].get("drone_pair") or ["?", "?"]
        print(
            f"collision: {a} and {b} came within {s['closest_m']:.2f} m of each other "
            f"(touching below {DRONE_CONTACT_M:g} m): the fleet failed"
        )
    if s.get("landings_moved"):
        print(f"landing: {plural(s['landings_moved'], 'landing')} moved beside a drone there")
    if summary.get("report"):
        print(f"report: {os.path.join(out, summary['report'])}")
    print(f"run folder: {out}")
    left = (inv or {}).get("not_scanned_places") or []
    statuses = [d["status"] for d in summary["drones"].values()]
    if left or "ABORTED" in statuses:
        why = f"{plural(len(left), 'place')} not answered" if left else "interrupted"
        print(f"{why}: continue with btrun fleet {fleet_file} --resume {out}")
    sys.stdout.flush()
