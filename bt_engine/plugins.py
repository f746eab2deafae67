"""The plug-in contract: the engine's only door to vehicles, reports and extra commands.

The engine imports no drone code. A plug-in is an object that satisfies :class:`Plugin`,
named in the ``btrun.plugins`` entry-point group (``name = "package.module:attribute"``;
btrun's own is ``nodes.plugin:PLUGIN``) or, for a plug-in that is not installed as a
package, in the ``BTRUN_PLUGINS`` environment variable (comma-separated, same spelling).
Importing a plug-in registers its leaves in :data:`bt_engine.registry.REGISTRY`.

What a plug-in provides (:class:`Plugin`):

* :meth:`Plugin.load_target` - read a rig file plus ``--set`` overrides into a
  :class:`RunTarget`: what the mission flies on (it builds the platform and the extra hooks,
  such as a safety supervisor). Bad input raises :class:`~bt_engine.spec.MissionError`
  with located :class:`~bt_engine.spec.Problem` s.
* :meth:`Plugin.write_report` - write the flight report of a finished run.
* :meth:`Plugin.commands` - subcommands of ``btrun`` (:class:`Command`).

The first plug-in that provides a capability is the one used. Mission resources that
report on the run implement :class:`RunReporter`.

Optional: a plug-in may also have ``run_sections(trace, mission) -> dict``: sections of
``summary.json`` computed from the finished run's per-tick trace (btrun's own adds
``motions``, the tracking figures of every motion); see :func:`run_sections`. And
``file_kinds() -> dict[str, FileKind]``: the other files it reads (btrun's own: rigs,
worlds, fleets), which ``btrun validate`` then checks as their command would
(:mod:`bt_engine.preflight`).
"""

from __future__ import annotations

import importlib
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from importlib import metadata
from typing import Any, Protocol, runtime_checkable

ENTRY_POINT_GROUP = "btrun.plugins"
ENV_VAR = "BTRUN_PLUGINS"


class Platform(Protocol):
    """What a run target's platform gives the runner (see ``bt_engine.runner.Hooks``).

    A platform that steps its vehicle on a thread of its own may also give
    ``between_steps()`` (a context manager: held, no step runs) and ``clock_shifted(dt_s)``
    (move every time it keeps by ``dt_s``): :func:`bt_engine.run_cmd.start_mission_clock`
    uses both when it sets a wall clock to mission time 0 before the first tick."""

    vehicle: Any

    def before_tick(self, t_s: float) -> None:
        """Bring everything up to mission time ``t_s`` (a simulator steps here)."""

    def after_tick(self, t_s: float) -> None:
        """Called after the tree was ticked at ``t_s``."""

    def shutdown(self, reason: str) -> None:
        """Bring the vehicle down and release it."""

    def summary(self) -> dict:
        """End state and ground truth for ``summary.json``."""

    def telemetry_row(self) -> dict:
        """A small dict of vehicle state for the tick log."""


class RunTarget(Protocol):
    """What a mission flies on, loaded by a plug-in from a rig file and overrides."""

    #: The rig file (shown in messages and the tick-log header), if any.
    path: str | None
    #: Mission seconds per wall second if the target runs in real time, else None (lock-step).
    realtime_factor: float | None

    def make_platform(self, clock: Any, seed: int) -> Platform:
        """Build the platform on the mission clock; all randomness derives from ``seed``."""

    def resources(self) -> dict[str, Any]:
        """Objects the target lends the mission's leaves (``mission.ctx.resources``)."""

    def make_hooks(self, platform: Platform, mission: Any) -> list[Any]:
        """Runner hooks that must run *before* the platform's own (e.g. the safety
        supervisor, which must land the drone before the platform shuts down)."""

    def at_rest(self, platform: Platform) -> bool:
        """True while a slow tick can harm nothing (e.g. the vehicle on the ground): the
        tick watchdog then allows a long tick (a gallery built before take-off)."""

    def run_summary(self, platform: Platform, hooks: list[Any]) -> dict[str, Any]:
        """The target's part of ``summary.json`` once the run is over (e.g. ``sim``: ground
        truth, ``safety``: what the supervisor did), by key.

        Optional: ``progress() -> float | None``, when (``time.monotonic()``) a lock-step
        tick last did bounded work (btrun's simulator: a pallet face textured); the tick
        watchdog's budget then counts from then."""


@dataclass(frozen=True)
class Command:
    """A ``btrun`` subcommand added by a plug-in."""

    help: str
    setup: Callable[[Any], None]  # setup(argparse.ArgumentParser)
    run: Callable[[Any], int]  # run(parsed args) -> exit code


@dataclass(frozen=True)
class FileKind:
    """A kind of YAML file a plug-in reads besides missions (a rig, a fleet): told apart by
    its top-level ``keys``; ``check(path, sets, seed)`` returns every located problem, as
    the command that reads the file would find them before flying (``seed`` None: the
    file's or the command's default), or ``(problems, found)``: ``found`` is what a file
    without problems holds, in a few words (``btrun validate`` prints it after "ok");
    ``usage`` says how the file is used."""

    keys: frozenset[str]
    check: Callable[[str, list[str], int | None], list | tuple[list, str]]
    usage: str
    #: whether ``--set KEY=VALUE`` items apply to the file (as to the command using it)
    takes_sets: bool = True


@runtime_checkable
class Plugin(Protocol):
    """A btrun plug-in: every member is required (return None / {} for what it lacks)."""

    #: A short name (messages).
    name: str

    def load_target(self, rig_path: str | None, overrides: dict[str, str]) -> RunTarget | None:
        """Load a rig file (None: the plug-in's default) with ``--set`` overrides. Raises
        :class:`~bt_engine.spec.MissionError` with located problems; None if this plug-in
        flies nothing."""

    def write_report(self, run_dir: str, trace: Any, summary: dict, mission: Any) -> str | None:
        """Write the flight report of a finished run; return its path (None: no report)."""

    def commands(self) -> dict[str, Command]:
        """Extra ``btrun`` subcommands, by name."""


@runtime_checkable
class RunReporter(Protocol):
    """A mission resource (``mission.ctx.resources``) that reports on the run: its
    ``run_summary()`` goes into ``summary.json`` under its resource name and its
    ``result_lines()`` are printed at the end (e.g. the identified pallet)."""

    def run_summary(self) -> dict[str, Any]:
        """JSON-friendly figures of the run."""

    def result_lines(self) -> list[str]:
        """Headline lines for the console."""


_loaded: list[Plugin] | None = None


def _entry_point_names() -> list[str]:
    try:
        return [ep.value for ep in metadata.entry_points(group=ENTRY_POINT_GROUP)]
    except Exception:  # pragma: no cover - very old importlib.metadata
        return []


def _names() -> list[str]:
    names = _entry_point_names()
    extra = [n.strip() for n in os.environ.get(ENV_VAR, "").split(",") if n.strip()]
    return list(dict.fromkeys(names + extra))


class PluginError(Exception):
    """A plug-in that cannot be loaded: its name, where it was named, and why (one line)."""


def _where_raised(exc: BaseException) -> str:
    """`` (file:line)`` of the innermost frame of ``exc``'s traceback in the plug-in's own
    code (not importlib's, not the engine's: a node the registry refuses is located at its
    class); empty if there is none."""
    import traceback

    engine = os.path.dirname(os.path.abspath(__file__)) + os.sep
    frames = [
        f
        for f in traceback.extract_tb(exc.__traceback__)
        if "importlib" not in f.filename and not os.path.abspath(f.filename).startswith(engine)
    ]
    return f" ({frames[-1].filename}:{frames[-1].lineno})" if frames else ""


def _syntax_said(exc: SyntaxError) -> str:
    """A plug-in's syntax error as ``path:line:col: Kind: message`` and the offending line
    (Python's own text names the file without its folder: ``(plug.py, line 2)``)."""
    where = os.path.abspath(exc.filename) if exc.filename else "<plug-in>"
    where += f":{exc.lineno}" if exc.lineno else ""
    where += f":{exc.offset}" if exc.lineno and exc.offset else ""
    said = f"{where}: {type(exc).__name__}: {exc.msg}"
    line = (exc.text or "").rstrip("\n")
    if line.strip():
        said += f" in {line.strip()!r}"
    return said


def _load(spec: str, source: str = "") -> Plugin:
    module, _, attr = spec.partition(":")
    named = f"plug-in {spec!r}" + (f" ({source})" if source else "")
    try:
        obj: Any = importlib.import_module(module)
        for part in attr.split(".") if attr else ():
            obj = getattr(obj, part)
    except SyntaxError as exc:  # the plug-in's own source: file:line:col and the line
        raise PluginError(f"{named} could not be loaded: {_syntax_said(exc)}") from exc
    except SystemExit as exc:  # sys.exit() at import ended btrun with its code, silently
        raise PluginError(
            f"{named} could not be loaded: it called sys.exit({exc.code!r}) while being "
            f"imported{_where_raised(exc)}"
        ) from exc
    except Exception as exc:  # any failure of a third party's import: one located line
        raise PluginError(
            f"{named} could not be loaded: {type(exc).__name__}: {exc}{_where_raised(exc)}"
        ) from exc
    if not isinstance(obj, Plugin):
        obj = _adapted(obj, named)
    return obj


class _LeafOnlyPlugin:
    """A plug-in whose ``load_target`` / ``write_report`` are None or whose ``commands`` is a
    dict (what their methods would return), given the methods the engine calls."""

    def __init__(self, obj: Any) -> None:
        self._obj = obj
        self.name = obj.name

    def __getattr__(self, attr: str) -> Any:  # optional members (run_sections, file_kinds)
        if attr == "_obj":  # not set yet (a copy being made): no recursion
            raise AttributeError(attr)
        return getattr(self._obj, attr)

    def load_target(self, rig_path: str | None, overrides: dict[str, str]) -> Any:
        member = self._obj.load_target
        return None if member is None else member(rig_path, overrides)

    def write_report(self, run_dir: str, trace: Any, summary: dict, mission: Any) -> Any:
        member = self._obj.write_report
        return None if member is None else member(run_dir, trace, summary, mission)

    def commands(self) -> dict[str, Command]:
        member = self._obj.commands
        return dict(member) if isinstance(member, dict) else member()


def _adapted(obj: Any, named: str) -> Plugin:
    """``obj`` as a plug-in when its members are there and are methods, None (for
    ``load_target`` and ``write_report``: the plug-in flies nothing, writes no report) or a
    dict (``commands``); else :class:`PluginError` naming each member that is wrong."""
    needs = ("name", "load_target", "write_report", "commands")
    missing = [m for m in needs if not hasattr(obj, m)]
    if missing:
        raise PluginError(
            f"{named} is not a plug-in object: it lacks {', '.join(missing)} (a plug-in has "
            "name, load_target, write_report and commands: bt_engine.plugins.Plugin)"
        )
    wrong = []
    if not isinstance(obj.name, str):
        wrong.append(f"name is {type(obj.name).__name__}, not a string")
    for member in ("load_target", "write_report"):
        value = getattr(obj, member)
        if value is not None and not callable(value):
            wrong.append(f"{member} is {type(value).__name__}, not a method or None")
    if not (callable(obj.commands) or isinstance(obj.commands, dict)):
        wrong.append(f"commands is {type(obj.commands).__name__}, not a method or a dict")
    if wrong:
        raise PluginError(
            f"{named} is not a plug-in object: {'; '.join(wrong)} (bt_engine.plugins.Plugin)"
        )
    return _LeafOnlyPlugin(obj)  # type: ignore[return-value]


def load_plugins() -> list[Plugin]:
    """Import every plug-in once and return them. A broken plug-in is never silently
    ignored: :class:`PluginError` says which, where it was named and why."""
    global _loaded
    if _loaded is None:
        installed = set(_entry_point_names())
        _loaded = [
            _load(spec, "an installed entry point" if spec in installed else ENV_VAR)
            for spec in _names()
        ]
    return _loaded


def load_target(rig_path: str | None, overrides: dict[str, str]) -> RunTarget | None:
    """The run target of the first plug-in that flies something, or None."""
    for plugin in load_plugins():
        target = plugin.load_target(rig_path, overrides)
        if target is not None:
            return target
    return None


def write_report(run_dir: str, trace: Any, summary: dict, mission: Any) -> str | None:
    """The first report a plug-in writes for the run (its path), or None."""
    for plugin in load_plugins():
        path = plugin.write_report(run_dir, trace, summary, mission)
        if path is not None:
            return path
    return None


def run_sections(trace: Any, mission: Any) -> dict[str, Any]:
    """The ``summary.json`` sections the plug-ins compute from a finished run's trace (the
    optional ``run_sections(trace, mission)`` member; the first plug-in wins a key)."""
    out: dict[str, Any] = {}
    for plugin in load_plugins():
        fn = getattr(plugin, "run_sections", None)
        if fn is not None:
            for key, value in (fn(trace, mission) or {}).items():
                out.setdefault(key, value)
    return out


def plugin_commands(reserved: tuple[str, ...] = ()) -> dict[str, Command]:
    """Every plug-in's extra subcommands, by name (the first plug-in wins a clash);
    :class:`PluginError` for a name that is one of btrun's own commands (``reserved``) or
    no command word (every ``btrun`` call failed with argparse's traceback)."""
    out: dict[str, Command] = {}
    for plugin in reversed(load_plugins()):
        commands = plugin.commands()
        for name in commands:
            if not isinstance(name, str) or not re.fullmatch(r"[a-z][a-z0-9_-]*", name):
                raise PluginError(
                    f"plug-in {plugin.name!r}: command name {name!r:.40} (expected a word of "
                    "lower-case letters, digits, '-' and '_')"
                )
            if name in reserved:
                raise PluginError(
                    f"plug-in {plugin.name!r}: command {name!r} is one of btrun's own "
                    f"commands ({', '.join(reserved)}): name it otherwise"
                )
        out.update(commands)
    return out
