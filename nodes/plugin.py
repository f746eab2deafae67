"""btrun's own plug-in: the composition root where engine, drivers and perception meet.

Named in ``pyproject.toml``'s ``btrun.plugins`` entry point as ``nodes.plugin:PLUGIN``.
Importing it imports :mod:`nodes` (which registers every leaf). It gives the engine:

* :meth:`DronePlugin.load_target` - a rig file (``rigs/sim.yaml`` by default) with
  ``--set`` overrides, as a :class:`RigTarget`: the platform from
  :mod:`drivers.rig.factory`, the safety supervisor's runner hook
  (:mod:`nodes.safety_hook`) and the run's ``sim``/``vehicle`` and ``safety`` summaries;
  rig problems come back as located :class:`~bt_engine.spec.Problem` s;
* :meth:`DronePlugin.write_report` - the flight report (:mod:`nodes.report`);
* :meth:`DronePlugin.run_sections` - ``motions`` in ``summary.json``: each motion's
  tracking figures (what the report's motion table shows, for campaigns to tabulate);
* :meth:`DronePlugin.file_kinds` - rig, world and fleet files, which ``btrun validate``
  checks as ``btrun rig check`` and ``btrun fleet --check`` do (:mod:`nodes.file_checks`);
* :meth:`DronePlugin.commands` - ``btrun sim serve ...``, ``btrun rig ...``,
  ``btrun fleet ...``, ``btrun gallery ...`` and ``btrun inventory ...`` (the site store).
"""

from __future__ import annotations

import argparse
from typing import Any

import nodes  # noqa: F401  (registers the leaves)
from bt_engine.plugins import Command, FileKind, Platform
from bt_engine.runner import REST_TICK_BUDGET_S
from bt_engine.spec import Loc, MissionError, Problem
from bt_engine.watchdog import busy_factor
from drivers.guard.client import GuardClient
from drivers.rig.factory import make_platform
from drivers.rig.loader import Rig, load_rig
from drivers.settings import ConfigError
from nodes.common import config_problems
from nodes.safety_hook import SafetyHook, make_safety_hook


class RigTarget:
    """A validated rig as the engine's :class:`~bt_engine.plugins.RunTarget`."""

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        self.path: str | None = rig.path
        self.realtime_factor: float | None = rig.realtime_factor

    def resources(self) -> dict[str, Any]:
        """The validated :class:`~drivers.rig.loader.Rig` as ``rig`` (perception leaves read
        its camera settings and world)."""
        return {"rig": self.rig}

    def make_platform(self, clock: Any, seed: int) -> Platform:
        """The platform of the rig (:func:`drivers.rig.factory.make_platform`), with a guard
        process (:mod:`drivers.guard`) when ``btrun`` runs it (it sets ``run_dir``) and the
        rig's ``guard.enabled`` is on."""
        self.guard = self._make_guard()
        try:
            platform = make_platform(self.rig, clock, seed, guard=self.guard)
        except ConfigError as exc:
            raise MissionError(config_problems(exc)) from None
        if self.guard is not None:
            self.guard.at_rest = lambda: self.at_rest(platform)
        return platform

    def _make_guard(self) -> GuardClient | None:
        g = self.rig.data["guard"]
        run_dir = getattr(self, "run_dir", None)
        if not g["enabled"] or run_dir is None:
            return None
        # the tick watchdog raises at one budget and, in real time, lands at two: the guard
        # acts only on a tick that outlived both
        budget = float(getattr(self, "tick_budget_s", None) or 10.0)
        return GuardClient(
            run_dir,
            record=getattr(self, "run_record", None),
            silence_s=g["silence_s"],
            rest_silence_s=g["rest_silence_s"],
            land_speed_mps=g["land_speed_mps"],
            land_max_s=g["land_max_s"],
            tick_limit_s=2 * budget + g["tick_grace_s"],
            rest_tick_limit_s=2 * max(budget, REST_TICK_BUDGET_S) + g["tick_grace_s"],
            # lock-step: the watchdog's budget stretches on a busy host and counts from a
            # tick's last progress; so does this limit
            tick_limit_scale=busy_factor if getattr(self, "lock_step", False) else None,
            progress=self.progress if getattr(self, "lock_step", False) else None,
        )

    def finished(self, summary_written: bool = True) -> None:
        """The run is over: stop its perception worker, let the guard process go
        (idempotent)."""
        mission = getattr(self, "mission", None)
        if mission is not None:  # the site store: the run's end and its last rows
            from nodes.site.recording import finish_recording

            self.mission = None
            finish_recording(mission.ctx.resources, getattr(self, "run_dir", None))
            session = mission.ctx.resources.get("perception")
            if session is not None:  # its worker thread and galleries (nodes.perception_session)
                session.close()
        guard = getattr(self, "guard", None)
        if guard is not None:
            guard.finished(summary_written)

    def make_hooks(self, platform: Platform, mission: Any) -> list[Any]:
        """The safety supervisor's hook (first, so it lands before the platform stops), then
        the ``run.mcap`` recorder (:mod:`nodes.mcap_log`) when the run has a folder
        (``run_dir``, set by ``btrun``)."""
        from nodes.mcap_log import make_mcap_recorder

        self.mission = mission  # finished() ends its inventory's recording
        hook = make_safety_hook(self.rig, platform, mission)
        hooks: list[Any] = [hook] if hook is not None else []
        guard = getattr(self, "guard", None)
        if guard is not None:  # first: its tick marks span the other hooks' work
            hooks.insert(0, guard)
        recorder = None
        if getattr(self, "record_mcap", True):  # btrun run --no-mcap; campaign rows
            tee = self._foxglove()
            recorder = make_mcap_recorder(
                getattr(self, "run_dir", None), platform, mission, hook, tee
            )
            if recorder is None and tee is not None:
                tee.close()
        return hooks + ([recorder] if recorder is not None else [])

    def _foxglove(self) -> Any:
        """The live Foxglove server of ``btrun run --foxglove [PORT]`` (None without it);
        a port that cannot be served is refused before anything flies."""
        port = getattr(self, "foxglove_port", None)
        if port is None:
            return None
        from nodes.foxglove_live import FoxgloveError, FoxgloveTee

        try:
            tee = FoxgloveTee(port)
        except FoxgloveError as exc:
            raise MissionError([Problem(Loc("--foxglove", 0, 0), str(exc))]) from None
        print(f"btrun: Foxglove live on ws://{tee.host}:{tee.port}", flush=True)
        return tee

    def at_rest(self, platform: Platform) -> bool:
        """On the ground (not flying): a long tick there harms nothing."""
        return not platform.vehicle.is_flying

    def progress(self) -> float | None:
        """When (``time.monotonic()``) a lock-step tick last did bounded work: a pallet face
        textured, each once (the first frame facing a larger site's racks makes a hundred,
        0.1 s each). The tick watchdog and the guard count a lock-step tick's time from its
        last progress; real time keeps its budgets."""
        from perception.synth.texture_lookahead import last_texture_made

        return last_texture_made()

    def run_summary(self, platform: Platform, hooks: list[Any]) -> dict[str, Any]:
        """``sim`` (simulator ground truth) or ``vehicle`` (a real drone), and ``safety``."""
        out: dict[str, Any] = {"sim" if self.rig.kind == "sim" else "vehicle": platform.summary()}
        for hook in hooks:
            if isinstance(hook, SafetyHook):
                out["safety"] = hook.summary()
            elif isinstance(hook, GuardClient):
                out["guard"] = hook.summary()
        return out


class DronePlugin:
    """The :class:`~bt_engine.plugins.Plugin` of btrun's drone leaves."""

    name = "btrun-drone"

    def load_target(self, rig_path: str | None, overrides: dict[str, str]) -> RigTarget:
        """Load and validate a rig file (None: ``rigs/sim.yaml``) with ``--set`` overrides."""
        try:
            return RigTarget(load_rig(rig_path, overrides))
        except ConfigError as exc:
            raise MissionError(config_problems(exc)) from None

    def write_report(self, run_dir: str, trace: Any, summary: dict, mission: Any) -> str | None:
        """Write the flight report of a run; return its path (None if nothing to plot)."""
        from nodes.report import write_report  # matplotlib: only when a report is wanted

        return write_report(run_dir, trace, summary, mission)

    def run_sections(self, trace: Any, mission: Any) -> dict[str, Any]:
        """``motions``: one entry per motion leaf run (the report's motion table)."""
        motions = list(getattr(getattr(mission, "ctx", None), "resources", {}).get("motions", ()))
        if not motions:
            return {}
        from nodes.report.metrics import motion_summary, telemetry_arrays

        tel = telemetry_arrays(trace)
        return {"motions": motion_summary(motions, tel)} if tel is not None else {}

    def file_kinds(self) -> dict[str, FileKind]:
        """Rig, world and fleet files, for ``btrun validate`` (:mod:`nodes.file_checks`)."""
        from nodes import file_checks

        return file_checks.KINDS

    def commands(self) -> dict[str, Command]:
        """``btrun sim serve crazyflie|aideck ...`` and ``btrun gallery ...``."""
        from nodes.console import cli as console_cli
        from nodes.fleet import run as fleet_run
        from nodes.gallery import cli as gallery_cli
        from nodes.site import cli as site_cli

        return {
            "sim": Command(
                "simulator tools (btrun sim serve crazyflie|aideck)", _sim_setup, _sim_run
            ),
            "rig": Command(
                "rig files: btrun rig settings [--markdown] | btrun rig check RIG [--set k=v]",
                _rig_setup,
                _rig_run,
            ),
            "fleet": Command(
                "fly several drones at once: btrun fleet fleets/aisle_2.yaml (docs/fleets.md)",
                fleet_run.setup,
                fleet_run.run,
            ),
            "gallery": Command(
                "enrolled pallets: btrun gallery list|enrol|remove|export|evaluate|demo",
                gallery_cli.setup,
                gallery_cli.run,
            ),
            "console": Command(
                "the operator console in a browser: btrun console [--runs DIR] (docs/console.md)",
                console_cli.setup,
                console_cli.run,
            ),
            "inventory": Command(
                "the site store: btrun inventory history PLACE | diff RUN_A RUN_B | runs | "
                "import RUN_DIR... (docs/store.md)",
                site_cli.setup,
                site_cli.run,
            ),
        }


def _sim_setup(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="sim_command", metavar="SUBCOMMAND", required=True)
    serve = sub.add_parser(
        "serve",
        help="run a software Crazyflie (CRTP over UDP) or AI-deck (CPX over TCP) on "
        "loopback, for cfclient or the AI-deck viewers",
    )
    serve.add_argument("device", choices=("crazyflie", "aideck"))
    serve.add_argument("args", nargs=argparse.REMAINDER, help="options of the emulator (--help)")


def _sim_run(args: argparse.Namespace) -> int:
    from drivers.rig.serve import SERVERS

    return int(SERVERS[args.device](list(args.args)) or 0)


def _rig_setup(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="rig_command", metavar="SUBCOMMAND", required=True)
    st = sub.add_parser("settings", help="every rig setting with its type, default and meaning")
    st.add_argument("--markdown", action="store_true", help="as docs/rig-settings.md")
    ck = sub.add_parser("check", help="validate a rig file (and its world); exit 2 if invalid")
    ck.add_argument("rig", help="rig file")
    ck.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")


def _rig_run(args: argparse.Namespace) -> int:
    from drivers.rig.schema import RIG_SCHEMA, settings_markdown
    from drivers.settings import describe

    if args.rig_command == "settings":
        print(
            settings_markdown() if args.markdown else "\n".join(describe(RIG_SCHEMA)),
            end="" if args.markdown else "\n",
        )
        return 0
    from nodes.file_checks import check_rig  # the same check as btrun validate RIG

    problems = check_rig(args.rig, args.set, None)
    if problems:
        raise MissionError(problems)
    print(f"{args.rig}: ok")
    return 0


#: The plug-in object the entry point names.
PLUGIN = DronePlugin()
