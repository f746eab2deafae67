"""``btrun run``: load, validate, build, fly (simulated or real), log and summarise."""

from __future__ import annotations

import json
import os
import sys
import time
from typing import Any

import yaml

from bt_engine.clock import SimClock, WallClock
from bt_engine.display import spec_rows
from bt_engine.mission import Mission, check_file
from bt_engine.plugins import load_plugins, rig_loader
from bt_engine.registry import REGISTRY
from bt_engine.runner import Runner
from bt_engine.spec import Loc, MissionError, Problem
from bt_engine.ticklog import TickLog, to_jsonable


def parse_sets(items: list[str]) -> tuple[dict[str, Any], dict[str, str], list[Problem]]:
    """Split ``--set KEY=VALUE`` items into blackboard entries and rig/world overrides.

    Dotted keys (``world.scan_pallet``, ``control.setpoint_mode``) are rig/world settings;
    a leading ``rig.`` is stripped. Plain keys are blackboard entries. Blackboard values are read as YAML scalars (numbers,
    booleans), otherwise kept as text; ports convert them when read.
    """
    bb: dict[str, Any] = {}
    rig: dict[str, str] = {}
    problems: list[Problem] = []
    for i, item in enumerate(items, 1):
        if "=" not in item:
            problems.append(Problem(Loc("--set", i, 1), f"expected KEY=VALUE, got {item!r}"))
            continue
        key, value = item.split("=", 1)
        key = key.strip()
        if not key:
            problems.append(Problem(Loc("--set", i, 1), f"empty key in {item!r}"))
            continue
        if "." in key:
            rig[key[4:] if key.startswith("rig.") else key] = value
        else:
            try:
                parsed = yaml.safe_load(value) if value.strip() else ""
            except yaml.YAMLError:
                parsed = value
            bb[key] = parsed if isinstance(parsed, (int, float, bool, str, list)) else value
    return bb, rig, problems


def _run_dir(args) -> str:
    if args.out:
        return args.out
    stem = os.path.splitext(os.path.basename(args.mission))[0]
    return os.path.join("runs", f"{stem}-{time.strftime('%Y%m%d-%H%M%S')}")


def _config_problems(exc: Exception) -> list[Problem]:
    out = []
    for line in getattr(exc, "problems", [str(exc)]):
        if isinstance(line, Problem):
            out.append(line)
            continue
        parts = str(line).split(":", 3)
        if len(parts) == 4 and parts[1].isdigit() and parts[2].isdigit():
            out.append(Problem(Loc(parts[0], int(parts[1]), int(parts[2])), parts[3].strip()))
        else:
            out.append(Problem(Loc("rig", 0, 0), str(line)))
    return out


class _PlainLog:
    """Non-TTY progress: one line per action start/finish and node messages."""

    def __init__(self, mission: Mission, quiet: bool) -> None:
        self.quiet = quiet
        self.actions = {
            n.path: n
            for n in mission.nodes
            if not n.children and n.kind == "Action" and n.category != "built-in"
        }

    def __call__(self, runner: Runner) -> None:
        if self.quiet:
            return
        rec = runner.last_record
        t = rec.get("t", 0.0)
        events = dict(rec.get("changed", {}))
        events.update(rec.get("done", {}))
        for path, st in events.items():
            node = self.actions.get(path)
            if node is not None and st in ("RUNNING", "SUCCESS", "FAILURE"):
                print(f"[{t:8.2f} s] {node.describe():<32} {st}", flush=True)
        for m in rec.get("messages", ()):
            print(f"[{t:8.2f} s] {m}", flush=True)


def run_command(args) -> int:
    """Run a mission from parsed CLI arguments; return the exit code."""
    bb, rig_over, problems = parse_sets(args.set)
    spec, mission_problems = check_file(args.mission, REGISTRY)
    problems += mission_problems
    if problems:
        raise MissionError(problems)
    loader = rig_loader()
    rig = None
    if loader is not None:
        try:
            rig = loader(args.rig, rig_over)
        except Exception as exc:  # ConfigError from the rig loader: located problems
            if not hasattr(exc, "problems"):
                raise
            raise MissionError(_config_problems(exc)) from None
    elif args.rig or rig_over:
        raise MissionError(
            [
                Problem(
                    Loc(args.rig or "--set", 0, 0), "no vehicle plug-in is installed to use a rig"
                )
            ]
        )
    factor = args.realtime or getattr(rig, "realtime_factor", None)
    clock = WallClock(factor) if factor else SimClock()
    platform = rig.make_platform(clock, args.seed) if rig is not None else None
    resources = {"platform": platform, "rig": rig, "seed": args.seed}
    mission = Mission(
        spec,
        clock=clock,
        vehicle=getattr(platform, "vehicle", None),
        resources=resources,
        blackboard=bb,
    )
    run_dir = _run_dir(args)
    os.makedirs(run_dir, exist_ok=True)
    rows = spec_rows(spec)
    header = {
        "mission": os.path.abspath(args.mission),
        "rig": getattr(rig, "path", None),
        "seed": args.seed,
        "rate_hz": args.rate,
        "nodes": [
            [n.path, r.label, r.depth, list(r.last_flags)]
            for n, r in zip(mission.nodes, rows, strict=False)
        ],
    }
    log = TickLog(os.path.join(run_dir, "ticks.jsonl"), header)
    telemetry = getattr(platform, "telemetry_row", None)
    tty = sys.stdout.isatty() and not args.quiet
    hooks = [platform] if platform is not None else []
    supervisor = None  # a plug-in's safety supervisor: first hook, so it lands before the platform
    for mod in load_plugins() if platform is not None else ():
        make = getattr(mod, "make_supervisor", None)
        if make is not None:
            supervisor = make(rig, platform, mission)
            if supervisor is not None:
                hooks.insert(0, supervisor)
            break
    runner = Runner(mission, args.rate, hooks=hooks, log=log, telemetry=telemetry)
    if not args.quiet:
        where = f"rig {getattr(rig, 'path', '-')}" if rig is not None else "no vehicle"
        mode = f"real time x{factor:g}" if factor else f"lock-step, seed {args.seed}"
        print(f"btrun: {args.mission} on {where} ({mode}), {args.rate:g} Hz; run folder {run_dir}")
    if tty:
        from bt_engine.display import LiveView

        with LiveView(rows, args.mission) as view:

            def on_tick(r: Runner) -> None:
                run = [n for n in mission.running_nodes() if not n.children]
                doing = run[-1].describe() if run else "-"
                view.update(
                    [n.bt_status.value for n in mission.nodes],
                    f"t={clock.now():7.2f} s  tick {mission.ticks}  running: {doing}",
                )

            runner.on_tick = on_tick
            result = runner.run(args.max_time)
            on_tick(runner)
    else:
        runner.on_tick = _PlainLog(mission, args.quiet)
        result = runner.run(args.max_time)
    log.close()
    summary: dict[str, Any] = {
        "status": result.status,
        "reason": result.reason,
        "ticks": result.ticks,
        "mission_time_s": round(result.mission_time_s, 4),
        "wall_time_s": round(result.wall_time_s, 4),
        "mission": os.path.abspath(args.mission),
        "seed": args.seed,
        "rate_hz": args.rate,
        "blackboard": to_jsonable(mission.scope.all_items()),
    }
    if platform is not None and hasattr(platform, "summary"):
        summary["sim" if getattr(rig, "kind", "sim") == "sim" else "vehicle"] = to_jsonable(
            platform.summary()
        )
    if supervisor is not None and hasattr(supervisor, "summary"):
        summary["safety"] = to_jsonable(supervisor.summary())
    for name, res in mission.ctx.resources.items():  # plug-in objects that report on the run
        if name not in summary and callable(getattr(res, "run_summary", None)):
            summary[name] = to_jsonable(res.run_summary())
    if runner.error_traceback:
        with open(os.path.join(run_dir, "error.log"), "w") as f:
            f.write(runner.error_traceback)
        summary["error_log"] = "error.log"
    report = None
    if not args.no_report:
        for mod in load_plugins():
            fn = getattr(mod, "write_report", None)
            if fn is not None:
                report = fn(run_dir, runner.trace, summary, mission)
                break
    if report:
        summary["report"] = os.path.relpath(report, run_dir)
    tmp = os.path.join(run_dir, "summary.json.tmp")
    with open(tmp, "w") as f:
        json.dump(summary, f, indent=2)
    os.replace(tmp, os.path.join(run_dir, "summary.json"))
    # plug-in objects may give the run's headline (e.g. the identified pallet)
    headlines = [
        line
        for res in mission.ctx.resources.values()
        if callable(getattr(res, "result_lines", None))
        for line in res.result_lines()
    ]
    mission.close()
    speed = result.mission_time_s / result.wall_time_s if result.wall_time_s > 0 else 0.0
    print(
        f"{result.status}: {result.reason} "
        f"({result.ticks} ticks, {result.mission_time_s:.2f} s mission time, "
        f"{result.wall_time_s:.2f} s wall, {speed:.0f}x real time)"
    )
    for line in headlines:
        print(line)
    if report:
        print(f"report: {report}")
    print(f"run folder: {run_dir}")
    return 0 if result.status == "SUCCESS" else 1
