"""``btrun``: run, validate, show, convert, list nodes, replay, campaign.

Exit codes: 0 mission SUCCESS (or command done), 1 mission FAILURE/ABORTED, 2 invalid input.
Bad input is reported as ``file:line:col: message`` lines, never as a traceback.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys

from bt_engine.arg_types import port_number, positive
from bt_engine.files import write_output
from bt_engine.plugins import Command, PluginError, plugin_commands
from bt_engine.spec import MissionError, MissionSpec, Problem

COMMANDS = ("run", "validate", "show", "convert", "nodes", "replay", "campaign")
_MORE = re.compile(r"\.\.\. and (\d+) more problems\b")


def _print_problems(problems: list[Problem], stream=None) -> None:
    stream = stream or sys.stderr
    n = 0
    for p in problems:
        print(str(p), file=stream)
        more = _MORE.match(p.message)  # a list cut short: "... and 19950 more problems"
        n += int(more.group(1)) if more else 1
    print(f"{n} problem{'s' if n != 1 else ''} found; nothing was run.", file=stream)


def _include_path(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--include-path",
        action="append",
        default=[],
        metavar="DIR",
        help="a folder <include>/include: may read from, besides the mission's own folder; "
        "repeatable",
    )


def _parser(extra: dict[str, Command] | None = None) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="btrun",
        description="Fly behaviour-tree missions (BehaviorTree.CPP XML or YAML) on the "
        "simulator or a real Crazyflie.",
        epilog="`btrun MISSION` is short for `btrun run MISSION`.",
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    r = sub.add_parser("run", help="run a mission (default command)")
    r.add_argument("mission", help="mission file (.xml, .yaml)")
    r.add_argument("--rig", help="rig file (default: rigs/sim.yaml, the simulator)")
    r.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="set a mission input (height=1.5: a port of the main tree or an entry the "
        "mission reads; anything else is refused, with a 'did you mean'), an undeclared "
        "blackboard entry on purpose (bb.NAME=VALUE, unchecked) or a rig/world setting "
        "(world.scan_pallet=3A, clock.mode=realtime; every key: btrun rig settings); "
        "repeatable",
    )
    r.add_argument(
        "--seed", type=int, default=None, help="random seed of the simulator (default 0)"
    )
    r.add_argument(
        "--rate",
        type=positive("a tick rate in Hz", 1000.0),
        default=50.0,
        help="tick rate in Hz (default 50)",
    )
    r.add_argument("--out", help="run folder (default runs/<mission>-<time>)")
    r.add_argument(
        "--resume",
        metavar="RUN",
        help="continue an interrupted run from its folder: the same rig, seed and --set "
        "items unless given again; leaves that keep their work in the run folder (the "
        "inventory) carry it over and skip what is done",
    )
    r.add_argument(
        "--store",
        metavar="URL",
        help="site store the run's inventory rows are recorded in: sqlite:///FILE or "
        "postgresql://... (default: site.sqlite beside the run folder, or $BTRUN_STORE; "
        "none: record nothing; docs/store.md)",
    )
    r.add_argument(
        "--max-time",
        type=positive("a time in s"),
        default=None,
        help="mission time limit in s (default: the mission's max_time input, else 900)",
    )
    r.add_argument(
        "--realtime",
        nargs="?",
        const=1.0,
        type=positive("a factor", 100.0),
        metavar="FACTOR",
        help="pace the run on the wall clock (optionally FACTOR times real time)",
    )
    r.add_argument(
        "--tick-budget",
        type=positive("a time in s"),
        default=None,
        metavar="S",
        help="wall-clock seconds one tick may take before the watchdog stops the tree and "
        "lands (default: 5 in real time, 10 lock-step; 600 while the drone is on the "
        "ground; 1 s after Ctrl-C)",
    )
    r.add_argument("--quiet", "-q", action="store_true", help="print only the result")
    r.add_argument("--no-report", action="store_true", help="skip the flight report")
    r.add_argument(
        "--no-mcap",
        action="store_true",
        help="do not record run.mcap (the tick log is kept; a seeded simulated run "
        "re-flies identically to record it)",
    )
    r.add_argument(
        "--groot",
        nargs="?",
        const=1667,
        type=port_number(65534),  # and PORT+1
        metavar="PORT",
        help="serve Groot2 live monitoring on PORT (default 1667) and PORT+1 (docs/monitoring.md)",
    )
    r.add_argument(
        "--foxglove",
        nargs="?",
        const=8765,
        type=port_number(),
        metavar="PORT",
        help="serve the run live to Foxglove (WebSocket on 127.0.0.1:PORT, default 8765; "
        "the channels of run.mcap; docs/monitoring.md)",
    )
    r.add_argument(
        "--groot-address",
        default="127.0.0.1",
        metavar="ADDR",
        help="interface the Groot2 server binds (default 127.0.0.1, loopback only)",
    )
    _include_path(r)

    v = sub.add_parser(
        "validate",
        help="check mission files; report every problem (with --rig or --set: also against a "
        "rig and its world, as btrun run checks before take-off, flying nothing); rig, "
        "world, fleet and campaign files are checked as their commands would",
    )
    v.add_argument(
        "files", nargs="+", help="missions (.xml, .yaml), or rig, world, fleet and campaign files"
    )
    v.add_argument(
        "--rig",
        help="also check each mission against this rig and its world: the --set items, the "
        "rig and world files and every node's pre-flight check (a place the world does not "
        "have); nothing is built or flown",
    )
    v.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="as btrun run --set (checked against each mission and the rig; without --rig: "
        "the default rig); repeatable",
    )
    v.add_argument(
        "--seed",
        type=int,
        default=None,
        help="seed of the world's stock drawn (default 0; a fleet file's own)",
    )
    _include_path(v)

    s = sub.add_parser("show", help="print a mission's tree")
    s.add_argument("mission", help="mission file (.xml, .yaml)")
    s.add_argument("--format", choices=("text", "dot", "svg", "png"), default="text")
    s.add_argument("--output", "-o", help="output file (for dot/svg/png)")
    _include_path(s)

    c = sub.add_parser("convert", help="convert a mission between XML and YAML")
    c.add_argument("source", help="the mission file (.xml or .yaml)")
    c.add_argument("dest", help="the file to write, in the other format (.yaml or .xml)")
    _include_path(c)

    n = sub.add_parser("nodes", help="list the nodes missions can use")
    n.add_argument("--kind", choices=("action", "condition", "control", "decorator"))
    n.add_argument("--groot", metavar="FILE", help="write a Groot2 TreeNodesModel palette")
    n.add_argument("--markdown", metavar="FILE", help="write the node reference (Markdown)")
    n.add_argument("--verbose", "-v", action="store_true", help="full descriptions")

    rp = sub.add_parser("replay", help="step through a run's tick log")
    rp.add_argument("log", help="ticks.jsonl or the run folder")
    rp.add_argument("--tick", type=int, help="show the tree at this tick and exit")
    rp.add_argument("--all", action="store_true", help="print every tick that changed something")
    rp.add_argument(
        "--repair",
        action="store_true",
        help="only make the run's run.mcap readable again after a killed run (rebuild its "
        "summary and index, the original kept as run.mcap.orig; replay does it by itself)",
    )
    cp = sub.add_parser(
        "campaign",
        help="fly a campaign: missions x rigs x worlds x seeds x settings x faults "
        "(docs/campaigns.md)",
    )
    from bt_engine.campaign.command import setup as campaign_setup

    campaign_setup(cp)
    _include_path(cp)
    for name, command in (extra or {}).items():
        command.setup(sub.add_parser(name, help=command.help))
    return p


def main(argv: list[str] | None = None, earlier_interrupts: list[str] | None = None) -> int:
    """Entry point of the ``btrun`` command; returns the exit code.

    ``earlier_interrupts``: SIGINT/SIGTERM the launcher (``btrun_launcher``, the console
    script) caught while this package was being imported; a run then ends before it flies.
    """
    from bt_engine.interrupts import catch_early_interrupts, release_early_interrupts

    # before anything slow: a Ctrl-C is never lost
    early = catch_early_interrupts(earlier_interrupts)
    try:
        return _main(argv, early)
    finally:
        try:
            release_early_interrupts(early)
        except KeyboardInterrupt:
            pass  # the run (if any) already acted on it


def _command_typo(word: str, commands: list[str]) -> str | None:
    """What to say when ``word`` (not a command) is no mission file either but reads like a
    misspelt command (``btrun vaildate ...``); None to run it as a mission."""
    import difflib

    if os.path.exists(word) or os.path.splitext(word)[1] or os.sep in word:
        return None  # a file, or meant as one: `btrun run` says what is wrong with it
    close = difflib.get_close_matches(word, commands, n=1, cutoff=0.7)
    if not close:
        return None
    return (
        f"unknown command '{word}' (did you mean '{close[0]}'?); "
        f"commands: {', '.join(commands)}; a mission file runs as `btrun MISSION`"
    )


def _main(argv: list[str] | None, early: dict | None) -> int:
    from bt_engine.interrupts import release_early_interrupts, sigterm_interrupts

    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        extra = plugin_commands(COMMANDS)
    except PluginError as exc:
        print(f"btrun: {exc}", file=sys.stderr)
        return 2
    if argv and argv[0] not in COMMANDS and argv[0] not in extra and not argv[0].startswith("-"):
        typo = _command_typo(argv[0], [*COMMANDS, *extra])
        if typo:
            print(f"btrun: {typo}", file=sys.stderr)
            return 2
        argv.insert(0, "run")
    parser = _parser(extra)
    try:
        args = parser.parse_args(argv)
        if args.command != "run":
            release_early_interrupts(early)
            sigterm_interrupts()  # a kill stops it as Ctrl-C does: what it made is cleaned up
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 1
    if args.command is None:
        parser.print_help()
        return 2
    from bt_engine.loading import default_include_paths

    try:
        # --include-path reaches every loader the command calls (run: bt_engine.run_cmd)
        with default_include_paths(getattr(args, "include_path", None) or ()):
            if args.command in extra:
                return extra[args.command].run(args)
            if args.command == "run":
                from bt_engine.run_cmd import run_command

                return run_command(args)
            return globals()[f"_cmd_{args.command}"](args)
    except MissionError as exc:
        _print_problems(exc.problems)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 1
    except BrokenPipeError:
        return 0


def _cmd_validate(args) -> int:
    from bt_engine.file_kinds import check_other_file
    from bt_engine.loading import check_mission
    from bt_engine.preflight import check_before_flight
    from bt_engine.registry import REGISTRY

    worst = 0
    all_problems: list[Problem] = []
    against_rig = bool(args.rig or args.set)
    seed = 0 if args.seed is None else args.seed
    for f in args.files:
        other = check_other_file(f, args.set, args.seed, args.rig)
        if other is not None:  # a rig, a world, a fleet, a campaign: its own checks
            kind, problems, found = other
            if problems:
                all_problems += problems
                worst = 2
            else:
                print(f"{f}: ok ({kind}" + (f"; {found})" if found else ")"))
            continue
        warnings: list[Problem] = []
        spec, problems = check_mission(f, REGISTRY, args.include_path, warnings)
        for w in warnings:  # file:line:col: warning: ... (validation still passes)
            print(str(w), file=sys.stderr)
        if against_rig and not problems:
            problems = check_before_flight(spec, args.rig, args.set, seed)
        elif not problems:  # the values the file gives through the blackboard: no rig needed
            problems = _file_value_problems(spec)
        if problems:
            all_problems += problems
            worst = 2
        else:
            print(f"{f}: ok")
    if all_problems:
        _print_problems(all_problems)
    return worst


def _file_value_problems(spec: MissionSpec) -> list[Problem]:
    """:meth:`bt_engine.mission.Mission.value_problems` of a mission built without a
    vehicle ([] if it cannot be built so: ``btrun run`` says why)."""
    from bt_engine.mission import Mission

    try:
        mission = Mission(spec)
    except Exception:  # noqa: BLE001 - a node that needs a rig to be built at all
        return []
    try:
        return mission.value_problems()
    finally:
        mission.close()


def _load_valid(path: str, include_paths: list[str]):
    from bt_engine.file_kinds import not_a_mission
    from bt_engine.loading import check_mission
    from bt_engine.registry import REGISTRY

    spec, problems = check_mission(path, REGISTRY, include_paths)
    if problems:
        other = not_a_mission(path)  # a rig or a fleet given as the mission
        raise MissionError([other] if other is not None else problems)
    return spec


def _cmd_show(args) -> int:
    from bt_engine.display import dot_source, render_dot, spec_rows, tree_lines

    spec = _load_valid(args.mission, args.include_path)
    if args.format == "text":
        print(f"{spec.main_tree_id()}  ({args.mission})")
        print("\n".join(tree_lines(spec_rows(spec))))
        return 0
    dot = dot_source(spec)
    if args.format == "dot":
        if args.output:
            why = write_output(args.output, dot)
            if why:
                print(f"btrun show: {why}", file=sys.stderr)
                return 2
        else:
            print(dot, end="")
        return 0
    out = args.output or os.path.splitext(os.path.basename(args.mission))[0] + f".{args.format}"
    try:
        render_dot(dot, args.format, out)
    except (RuntimeError, OSError, subprocess.CalledProcessError) as exc:
        print(f"btrun show: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out}")
    return 0


def _cmd_convert(args) -> int:
    """Write SRC in the format of DEST; nothing is written if SRC has any problem that
    ``btrun validate SRC`` would say (load or validation: an unknown enum value was
    converted with exit 0 and a warning, although the docs said nothing is written)."""
    from bt_engine.loading import convert_file
    from bt_engine.registry import REGISTRY

    _load_valid(args.source, args.include_path)  # MissionError: located, exit 2
    problems = convert_file(args.source, args.dest, REGISTRY, args.include_path)
    if problems:
        raise MissionError(problems)
    print(f"wrote {args.dest}")
    return 0


def _cmd_nodes(args) -> int:
    from bt_engine.catalogue import catalogue_markdown, catalogue_text, groot_palette
    from bt_engine.registry import REGISTRY

    wrote = False
    for path, make, what in (
        (args.groot, groot_palette, "Groot2 palette"),
        (args.markdown, catalogue_markdown, "node reference"),
    ):
        if not path:
            continue
        why = write_output(path, make(REGISTRY))
        if why:
            print(f"btrun nodes: {why}", file=sys.stderr)
            return 2
        print(f"wrote {what} {path}")
        wrote = True
    if not wrote:
        print(catalogue_text(REGISTRY, args.kind, args.verbose), end="")
    return 0


def _cmd_campaign(args) -> int:
    from bt_engine.campaign.command import run

    return run(args)


def _cmd_replay(args) -> int:
    from bt_engine.replay import replay

    return replay(args.log, args.tick, args.all, args.repair)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
