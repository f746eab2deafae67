"""``btrun run``: prepare (load, validate, build), fly (tick, log), finish (summarise, report).

Each step is a function: :func:`prepare` refuses bad input before anything flies,
:func:`fly` ticks the mission, :func:`finish` writes ``summary.json`` (built by
:func:`bt_engine.summary.build_summary`) and the report.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TextIO

from bt_engine.clock import SimClock, WallClock
from bt_engine.display import spec_rows
from bt_engine.inputs import declared_inputs, missing_inputs, typed_inputs
from bt_engine.loading import check_mission
from bt_engine.mission import Mission
from bt_engine.plugins import Platform, RunTarget, load_target, run_sections, write_report
from bt_engine.registry import REGISTRY
from bt_engine.run_inputs import (  # noqa: F401 - importable from here as before
    mission_time_limit,
    parse_sets,
    resume_settings,
    run_dir_problem,
    set_texts,
    used_run_dir_problem,
)
from bt_engine.runner import Runner, RunResult
from bt_engine.spec import Loc, MissionError, Problem
from bt_engine.summary import (
    build_summary,
    handled_failure_lines,
    reserve_space,
    result_lines,
    timing_line,
    write_summary,
)
from bt_engine.ticklog import TickLog, started_now


def _run_dir(args) -> str:
    if getattr(args, "out", None):
        return args.out
    stem = os.path.splitext(os.path.basename(args.mission))[0]
    return os.path.join("runs", f"{stem}-{time.strftime('%Y%m%d-%H%M%S')}")


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


#: Default wall-clock budget of one tick (``--tick-budget``): in real time the drone waits
#: for the tree; in lock-step the simulated drone cannot drift, only a hang must end, and
#: soon (a campaign or CI waits for it). A slow first tick (models, the demo gallery) runs
#: on the ground, where the runner allows REST_TICK_BUDGET_S (bt_engine/runner.py).
REALTIME_TICK_BUDGET_S = 5.0
LOCKSTEP_TICK_BUDGET_S = 10.0


@dataclass
class PreparedRun:
    """Everything a run needs, built and checked before anything flies."""

    args: Any
    mission: Mission
    target: RunTarget | None
    platform: Platform | None
    hooks: list[Any]
    clock: Any
    factor: float | None
    run_dir: str
    rows: list[Any]
    log: TickLog
    #: the Groot2 monitoring server (``--groot``), also in ``hooks``; closed by run_command
    groot: Any = None
    #: summary.json's content once :func:`finish` wrote it
    summary: dict | None = None


def real_time_words(mission_s: float, wall_s: float) -> str:
    """How many times real time a run went: ``1.3x real time`` (one decimal below 10, where
    the decimal matters), ``8x real time``; ``-`` for a run that took no wall time."""
    if wall_s <= 0.0:
        return "- x real time"
    speed = mission_s / wall_s
    return f"{speed:.1f}x real time" if speed < 9.95 else f"{speed:.0f}x real time"


def wall_echo(stream: TextIO | None = None) -> Callable[[str], None]:
    """A printer of messages stamped with the wall time since now (``[wall   1.2 s] ...``),
    for work outside the mission clock (models and galleries loading before the first
    tick); ``stream``: default stdout."""
    wall0 = time.monotonic()

    def echo(msg: str) -> None:
        print(f"[wall {time.monotonic() - wall0:6.1f} s] {msg}", file=stream, flush=True)

    return echo


def prepare(
    args, clock: Any = None, resources: dict[str, Any] | None = None, warn: bool = True
) -> PreparedRun:
    """Load and validate the mission, the ``--set`` items and the rig (raises
    :class:`MissionError` with every located problem: nothing flies), then build the clock,
    platform, mission, run folder, tick log and hooks; finally let every node check its
    inputs against the run target (:meth:`Mission.preflight`).

    A fleet passes its shared ``clock`` and extra mission ``resources`` (the drone's name,
    where its inventory rows go); ``warn=False`` leaves the validation warnings unprinted
    (the fleet prints them once)."""
    resume_problems = resume_settings(args)
    if resume_problems:
        raise MissionError(resume_problems)
    warnings: list[Problem] = []
    spec, problems = check_mission(args.mission, REGISTRY, None, warnings)
    if problems:  # a rig or a fleet given as the mission: say what it is, not its keys
        from bt_engine.file_kinds import not_a_mission

        other = not_a_mission(args.mission)
        if other is not None:
            raise MissionError([other])
    for w in warnings if warn else ():  # file:line:col: warning: ... (the mission still flies)
        print(str(w), file=sys.stderr)
    declared = None if problems else declared_inputs(spec)  # a typo never flies the default
    bb, rig_over, set_problems = parse_sets(args.set, declared, args.mission)
    problems += set_problems
    if declared is not None and not set_problems:  # an input no one gives: refused, not
        problems += missing_inputs(spec, set(bb))  # found by the first leaf in the air
        problems += typed_inputs(spec, bb, set_texts(args.set))  # and one of no value of its type
    if getattr(args, "max_time", None) is None and not problems:
        args.max_time, limit_problem = mission_time_limit(spec, bb)
        problems += [limit_problem] if limit_problem is not None else []
    if problems:
        raise MissionError(problems)
    target = load_target(args.rig, rig_over)
    if target is None and (args.rig or rig_over):
        where = Loc(args.rig or "--set", 0, 0)
        raise MissionError([Problem(where, "no vehicle plug-in is installed to use a rig")])
    factor = args.realtime or (target.realtime_factor if target is not None else None)
    if clock is None:
        clock = WallClock(factor) if factor else SimClock()
    run_dir = _run_dir(args)
    bad_dir = run_dir_problem(run_dir)
    if bad_dir is not None:  # before a guard or a platform is started
        release(target, written=False)
        raise MissionError([bad_dir])
    if target is not None:  # what a guard process needs before the platform is built
        target.run_dir = run_dir  # type: ignore[attr-defined]
        target.run_record = {  # type: ignore[attr-defined]
            "mission": os.path.abspath(args.mission),
            "seed": args.seed,
            "rig": target.path,
        }
        target.tick_budget_s = tick_budget(args, factor)  # type: ignore[attr-defined]
        target.lock_step = not factor  # type: ignore[attr-defined]
    platform = target.make_platform(clock, args.seed) if target is not None else None
    mission = Mission(
        spec,
        clock=clock,
        vehicle=platform.vehicle if platform is not None else None,
        resources={
            "platform": platform,
            "seed": args.seed,
            "run_dir": run_dir,
            "resume_from": getattr(args, "resume", None),
            "store": getattr(args, "store", None),  # opaque: the plug-in's site store URL
            **(target.resources() if target is not None else {}),
            **(resources or {}),
        },
        blackboard=bb,
    )
    if not getattr(args, "quiet", False):  # models and galleries load now: say so as it goes
        mission.ctx.echo = wall_echo()
    try:
        preflight = mission.preflight(set_keys=set(bb))
    except BaseException:  # a Ctrl-C that stopped a gallery build: nothing has flown
        if platform is not None:
            platform.shutdown("interrupted before flight")
        release(target, written=False)
        mission.close()
        raise
    mission.ctx.echo = None
    before_flight = list(mission.ctx.messages)  # shown already; kept in the tick log header
    mission.ctx.messages.clear()
    if preflight:
        if platform is not None:
            platform.shutdown("pre-flight check failed")
        release(target, written=False)
        raise MissionError(preflight)
    try:
        os.makedirs(run_dir, exist_ok=True)
    except OSError as exc:  # what the check above could not foresee (/proc, a full disk)
        if platform is not None:
            platform.shutdown("no run folder")
        release(target, written=False)
        why = exc.strerror or type(exc).__name__
        problem = Problem(Loc("--out", 0, 0), f"{run_dir}: cannot be made ({why})")
        raise MissionError([problem]) from None
    reserve_space(run_dir)  # room for summary.json should the disk fill in flight
    if target is not None:  # a target may write files of its own beside the tick log
        target.run_dir = run_dir  # type: ignore[attr-defined]
        target.record_mcap = not getattr(args, "no_mcap", False)  # type: ignore[attr-defined]
        target.foxglove_port = getattr(args, "foxglove", None)  # type: ignore[attr-defined]
    rows = spec_rows(spec)
    header = {
        "mission": os.path.abspath(args.mission),
        "rig": target.path if target is not None else None,
        "seed": args.seed,
        "rig_arg": args.rig,
        "cwd": os.getcwd(),  # relative paths above and in sets are relative to it
        "run_dir": os.path.abspath(run_dir),  # the folder's name then (it may be renamed)
        "sets": list(args.set),
        "rate_hz": args.rate,
        "started": started_now(),
        "before_flight": before_flight,
        "nodes": [
            [n.path, r.label, r.depth, list(r.last_flags)]
            for n, r in zip(mission.nodes, rows, strict=False)
        ],
    }
    log = TickLog(os.path.join(run_dir, "ticks.jsonl"), header)
    hooks: list[Any] = []
    if target is not None and platform is not None:
        # the target's hooks (the safety supervisor) go first: they land before the platform
        hooks = [*target.make_hooks(platform, mission), platform]
    groot = None
    if getattr(args, "groot", None) is not None:  # after the platform: sees each tick's end
        from bt_engine.groot2 import Groot2Error, Groot2Server

        address = getattr(args, "groot_address", None) or "127.0.0.1"
        try:
            groot = Groot2Server(mission, args.groot, address)
        except Groot2Error as exc:
            log.close()
            raise MissionError([Problem(Loc("--groot", 0, 0), str(exc))]) from None
        hooks.append(groot)
        if not args.quiet:
            print(f"btrun: Groot2 monitor on {address}:{groot.port} (publisher {groot.port + 1})")
    return PreparedRun(
        args, mission, target, platform, hooks, clock, factor, run_dir, rows, log, groot
    )


def tick_budget(args: Any, factor: float | None) -> float:
    """The wall-clock budget of one tick: ``--tick-budget``, else the real-time or the
    lock-step default."""
    budget = getattr(args, "tick_budget", None)
    if budget is None:  # real time: the drone is waiting; lock-step: only a hang matters
        budget = REALTIME_TICK_BUDGET_S if factor else LOCKSTEP_TICK_BUDGET_S
    return float(budget)


def release(*holders: Any, written: bool = True) -> None:
    """Tell every holder with a ``finished(summary_written)`` method (a run target, runner
    hooks such as the guard) that the run is over: ``written`` says summary.json exists.
    Each is called even if another raises."""
    for h in holders:
        fn = getattr(h, "finished", None)
        if fn is None:
            continue
        try:
            fn(written)
        except Exception as exc:  # a holder that cannot close must not hide the others
            print(f"btrun: closing {type(h).__name__}: {exc}", file=sys.stderr)


def make_runner(run: PreparedRun) -> Runner:
    """The runner of a prepared run: its hooks, tick log, telemetry and tick watchdog.

    If a tick never returns even after the watchdog stopped it (a leaf that swallows the
    stop, sleeps or sits in native code), the runner gives up on the main thread: from the
    watchdog thread the run is concluded (the drone lands), :func:`finish` writes
    summary.json and the process ends with the run's exit code (the main thread cannot be
    got back)."""
    args = run.args
    telemetry = run.platform.telemetry_row if run.platform is not None else None
    budget = getattr(args, "tick_budget", None)
    if budget is None:  # real time: the drone is waiting; lock-step: only a hang matters
        budget = REALTIME_TICK_BUDGET_S if run.factor else LOCKSTEP_TICK_BUDGET_S

    def give_up(runner: Runner) -> None:
        code = 1
        try:
            run.log.close()
            assert runner.result is not None
            code = finish(run, runner, runner.result)
        except BaseException:  # noqa: BLE001 - the process ends either way
            import traceback

            traceback.print_exc()
        finally:
            try:  # the guard: the summary is written, the run is over (not a crash)
                release(run.target, *run.hooks, written=run.summary is not None)
            except BaseException:  # noqa: BLE001 - the process ends either way
                pass
            for stream in (sys.stdout, sys.stderr):
                try:
                    stream.flush()
                except Exception:  # noqa: BLE001
                    pass
            os._exit(code)

    return Runner(
        run.mission,
        args.rate,
        hooks=run.hooks,
        log=run.log,
        telemetry=telemetry,
        tick_budget_s=budget,
        at_rest=(
            (lambda: run.target.at_rest(run.platform))  # type: ignore[union-attr]
            if run.target is not None and run.platform is not None
            else None
        ),
        on_give_up=give_up,
        progress=getattr(run.target, "progress", None),
    )


def start_mission_clock(clock: Any, platforms: list[Any]) -> None:
    """Set a wall clock to mission time 0 just before the first tick: connecting to the
    drone, loading models and building galleries are not mission time. Fault times
    (``faults.*.at_s``), the tick log's ``t``, the safety record and ``mission_time_s``
    then share one origin, however long a loaded host took to connect. A lock-step clock
    has no start-up to drop.

    A platform stepping on a thread of its own is held between two steps
    (``between_steps()``) while the clock jumps, and told how far (``clock_shifted(dt)``):
    a step spanning the jump had left the Vehicle on the old time, and the take-off began
    that many seconds late."""
    if not hasattr(clock, "restart_at"):
        return
    with contextlib.ExitStack() as held:
        for p in platforms:
            between = getattr(p, "between_steps", None)
            if between is not None:
                held.enter_context(between())
        before = clock.now()
        clock.restart_at(0.0)
        shift = clock.now() - before
        for p in platforms:
            shifted = getattr(p, "clock_shifted", None)
            if shifted is not None:
                shifted(shift)


def fly(run: PreparedRun) -> tuple[Runner, RunResult]:
    """Tick the mission to its end (live tree view on a terminal, one line per action
    otherwise); the tick log is closed afterwards."""
    args, mission, clock = run.args, run.mission, run.clock
    start_mission_clock(clock, [run.platform])  # a fleet's shared clock: by the fleet
    runner = make_runner(run)
    if not args.quiet:
        where = f"rig {run.target.path or '-'}" if run.target is not None else "no vehicle"
        mode = f"real time x{run.factor:g}" if run.factor else f"lock-step, seed {args.seed}"
        print(
            f"btrun: {args.mission} on {where} ({mode}), {args.rate:g} Hz; run folder {run.run_dir}"
        )
    try:
        if sys.stdout.isatty() and not args.quiet:
            from bt_engine.display import LiveView

            with LiveView(run.rows, args.mission) as view:

                def on_tick(r: Runner) -> None:
                    leaves = [n for n in mission.running_nodes() if not n.children]
                    doing = leaves[-1].describe() if leaves else "-"
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
    finally:
        run.log.close()
    return runner, result


def finish(run: PreparedRun, runner: Runner, result: RunResult, echo: bool = True) -> int:
    """Write summary.json (atomically), error.log and the report; print the outcome and the
    plug-ins' headline lines (unless ``echo`` is false); return the exit code (0 only for
    SUCCESS). The summary is kept in ``run.summary`` once written.

    Nothing that fails here stops summary.json: a part that raises (the run target's or a
    plug-in's sections, the report, error.log; MemoryError, OSError such as EMFILE, a
    TypeError from forged data) is left out and named in the summary's ``errors`` (one line
    each on stderr, never a traceback); if the summary itself cannot be built, its engine
    keys are written (:func:`bt_engine.summary.minimal_summary`).
    """

    from bt_engine.summary import add_error, error_line, minimal_summary

    args, mission = run.args, run.mission
    errors: list[str] = []

    def attempt(what: str, fn: Callable[[], Any], default: Any = None) -> Any:
        try:
            return fn()
        except Exception as exc:  # named in summary.json's errors, never a traceback
            errors.append(error_line(what, exc))
            return default

    sections: dict[str, Any] = {}
    if run.target is not None and run.platform is not None:
        target, platform = run.target, run.platform
        sections = attempt(
            "run target's sections", lambda: dict(target.run_summary(platform, run.hooks)), {}
        )
    extra = attempt("plug-in sections", lambda: dict(run_sections(runner.trace, mission)), {})
    for key, value in extra.items():  # e.g. motions
        sections.setdefault(key, value)
    summary = attempt(
        "summary",
        lambda: build_summary(
            result,
            mission,
            mission_path=args.mission,
            seed=args.seed,
            rate_hz=args.rate,
            sections=sections,
        ),
    )
    if not isinstance(summary, dict):
        summary = minimal_summary(
            result, mission_path=args.mission, seed=args.seed, rate_hz=args.rate
        )
    if runner.error_traceback:

        def save_error_log() -> bool:
            with open(os.path.join(run.run_dir, "error.log"), "w") as f:
                f.write(runner.error_traceback)
            return True

        if attempt("error.log", save_error_log, False):
            summary["error_log"] = "error.log"
    report = None
    if not args.no_report:
        report = attempt(
            "report", lambda: write_report(run.run_dir, runner.trace, summary, mission)
        )
        if report:
            summary["report"] = attempt("report", lambda: os.path.relpath(report, run.run_dir))
    log_failed = getattr(run.log, "failed", None)
    if log_failed:
        add_error(summary, f"ticks.jsonl: {log_failed}")
    for line in errors:
        add_error(summary, line)
    try:
        write_summary(run.run_dir, summary)
        run.summary = summary
    except Exception as exc:  # even the engine's keys could not be written (e.g. no folder)
        add_error(summary, error_line("summary.json not written", exc))
    del errors[:]
    headlines = attempt(
        "headlines",
        lambda: result_lines(mission) + handled_failure_lines(mission, result.reason),
        [],
    )
    attempt("closing the mission", mission.close)
    if not echo:
        return 0 if result.status == "SUCCESS" else 1
    for line in [*summary.get("errors", ()), *errors]:
        print(f"btrun: {line}", file=sys.stderr)
    print(
        f"{result.status}: {result.reason} "
        f"({result.ticks} ticks, {result.mission_time_s:.2f} s mission time, "
        f"{result.wall_time_s:.2f} s wall, "
        f"{real_time_words(result.mission_time_s, result.wall_time_s)})"
    )
    for line in headlines:
        print(line)
    late = timing_line(summary)
    if late:
        print(late)
    if report:
        print(f"report: {report}")
    print(f"run folder: {run.run_dir}")
    return 0 if result.status == "SUCCESS" else 1


def run_command(args) -> int:
    """Run a mission from parsed CLI arguments; return the exit code."""
    used = used_run_dir_problem(args.out) if getattr(args, "out", None) else None
    if used is not None:  # nothing is started: no guard, platform or store
        raise MissionError([used])
    run = prepare(args)
    try:
        runner, result = fly(run)
        return finish(run, runner, result)
    finally:
        if run.groot is not None:
            run.groot.close()
        release(run.target, *run.hooks, written=run.summary is not None)
