"""What ``btrun run`` reads from its command line before it builds anything: the ``--set``
items (:func:`parse_sets`), the mission's time limit (:func:`mission_time_limit`), the run
folder (:func:`run_dir_problem`) and ``--resume`` (:func:`resume_settings`); each bad value
a located :class:`~bt_engine.spec.Problem`. :mod:`bt_engine.run_cmd` uses them (and keeps
their names importable)."""

from __future__ import annotations

import math
import os
from collections.abc import Collection
from typing import Any

from bt_engine.inputs import (
    MAX_TIME_INPUT,
    UNCHECKED_PREFIX,
    parse_set_value,
    undeclared_input,
)
from bt_engine.spec import Loc, Problem
from bt_engine.ticklog import header_path


def parse_sets(
    items: list[str], declared: Collection[str] | None = None, mission: str = "the mission"
) -> tuple[dict[str, Any], dict[str, str], list[Problem]]:
    """Split ``--set KEY=VALUE`` items into blackboard entries and rig/world overrides.

    ``bb.NAME`` puts ``NAME`` on the blackboard unchecked. Other dotted keys
    (``world.scan_pallet``, ``control.setpoint_mode``) are rig/world settings; a leading
    ``rig.`` is stripped. Plain keys are blackboard entries and, when ``declared`` (the
    mission's inputs, :func:`bt_engine.inputs.declared_inputs`) is given, must be one of
    them: an undeclared key is a problem ("did you mean"), so a typo never flies with the
    default. Blackboard values are read as YAML scalars (numbers, booleans), otherwise kept
    as text; ports convert them when read.
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
        if key.startswith(UNCHECKED_PREFIX):
            key = key[len(UNCHECKED_PREFIX) :].strip()
            if not key:
                problems.append(Problem(Loc("--set", i, 1), f"no entry name after bb. in {item!r}"))
                continue
        elif "." in key:
            rig[key[4:] if key.startswith("rig.") else key] = value
            continue
        elif declared is not None:
            message = undeclared_input(key, declared, mission)
            if message is not None:
                problems.append(Problem(Loc("--set", 0, 0), message))
                continue
        bb[key] = parse_set_value(value)
    return bb, rig, problems


def set_texts(items: list[str]) -> dict[str, str]:
    """The text each ``--set KEY=VALUE`` blackboard item gave, by entry name (the last one
    wins, as in :func:`parse_sets`): a text input keeps it as written."""
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if key.startswith(UNCHECKED_PREFIX):
            key = key[len(UNCHECKED_PREFIX) :].strip()
        if sep and key and "." not in key:
            out[key] = value
    return out


#: the mission-time limit of a run when neither ``--max-time`` nor the mission says (s)
DEFAULT_MAX_TIME_S = 900.0
#: the main tree's input that sets its own limit (``<input_port name="max_time" ...>``)


def mission_time_limit(spec: Any, bb: dict[str, Any]) -> tuple[float, Problem | None]:
    """The run's mission-time limit when ``--max-time`` is not given: ``--set max_time=S``,
    else the default of the main tree's ``max_time`` input (a sweep of a whole site with
    its battery changes takes longer than :data:`DEFAULT_MAX_TIME_S`), else that; and a
    located problem if the value is not a time > 0."""
    main = spec.main_tree_id()
    model = spec.models.get(main) if main else None
    port = model.ports.get(MAX_TIME_INPUT) if model is not None else None
    if MAX_TIME_INPUT in bb:
        raw, where = bb[MAX_TIME_INPUT], Loc("--set", 0, 0)
    elif port is not None and port.default not in (None, ""):
        raw, where = port.default, model.loc  # type: ignore[union-attr]
    else:
        return DEFAULT_MAX_TIME_S, None
    try:
        value = float(raw)
    except (TypeError, ValueError):
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        why = f"{MAX_TIME_INPUT}: the mission's time limit must be a time in s > 0, got {raw!r}"
        return DEFAULT_MAX_TIME_S, Problem(where, why)
    return value, None


def run_dir_problem(run_dir: str, option: str = "--out") -> Problem | None:
    """Why the run folder ``run_dir`` cannot be made (a file in its place or above it, a
    folder that cannot be written), located at ``option``; None if it can, as far as can
    be told without making it (a refused run makes no folder)."""
    path = os.path.abspath(run_dir)
    where = Loc(option, 0, 0)
    if os.path.exists(path) and not os.path.isdir(path):
        return Problem(where, f"{run_dir}: a file is there; the run folder must be a folder")
    parent = path
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if parent != path and not os.path.isdir(parent):
        return Problem(where, f"{run_dir}: {parent} is a file, so no folder can be made in it")
    if not os.access(parent, os.W_OK | os.X_OK):
        what = "write in" if parent == path else "make a folder in"
        return Problem(where, f"{run_dir}: cannot {what} {parent} (permission denied)")
    return None


#: the files that make a folder a run folder (a solo run's, a fleet's)
RUN_FILES = ("ticks.jsonl", "summary.json", "fleet.json", "inventory.json")


def used_run_dir_problem(run_dir: str, option: str = "--out") -> Problem | None:
    """Why ``--out run_dir`` is refused when it holds a run already: flying there would
    write a new tick log and rows over the old run's and leave its crops and report beside
    them, and the site store (its run id is the folder's name) would mix the two flights'
    rows under one run. None for a new or empty folder, or one without run files."""
    found = [f for f in RUN_FILES if os.path.lexists(os.path.join(run_dir, f))]
    if not found:
        return None
    return Problem(
        Loc(option, 0, 0),
        f"{run_dir}: holds a run already (its {found[0]}): give a new folder to --out "
        "(or none: runs/<mission>-<time>), --resume it to go on with it, or remove it "
        "to fly there again",
    )


def resume_settings(args) -> list[Problem]:
    """``--resume RUN``: take the rig and seed of the interrupted run from its tick log's
    header where this call does not give them, and its ``--set`` items followed by this
    call's (a key given again takes the new value) (in place on ``args``);
    problems if RUN is no run folder, flew another mission or another seed."""
    previous = getattr(args, "resume", None)
    if not previous:
        if getattr(args, "seed", None) is None:
            args.seed = 0
        return []
    from bt_engine.ticklog import read_log

    where = Loc("--resume", 0, 0)
    log = os.path.join(previous, "ticks.jsonl")
    if not os.path.isfile(log):
        record = os.path.join(previous, "fleet.json")
        if os.path.lexists(record):
            import json

            from bt_engine.files import read_text

            fleet = "FLEET.yaml"
            text = read_text(record, [], what="fleet records", limit=1_000_000)
            try:
                named = json.loads(text or "")["fleet"]
                if isinstance(named, str) and named:
                    rel = os.path.relpath(named)
                    fleet = named if rel.startswith("..") else rel
            except (ValueError, KeyError, TypeError, RecursionError):
                pass
            return [
                Problem(
                    where,
                    f"{previous} is a fleet run: continue it with "
                    f"btrun fleet {fleet} --resume {previous}",
                )
            ]
        return [Problem(where, f"{previous} is not a run folder (no ticks.jsonl in it)")]
    header, _ = read_log(log, header_only=True)
    flown = header.get("mission")
    if flown and os.path.abspath(flown) != os.path.abspath(args.mission):
        return [Problem(where, f"{previous} flew {flown}: resume it with that mission")]
    seed = int(header.get("seed") or 0)
    if args.seed is not None and args.seed != seed:  # another stock than the one answered
        return [
            Problem(
                where,
                f"{previous} flew seed {seed}, not {args.seed}: a resumed run keeps its seed "
                "(in simulation it draws the stock the carried answers were made in); "
                "leave --seed out",
            )
        ]
    args.seed = seed
    if args.rig is None and header.get("rig_arg"):
        args.rig = header_path(header, header["rig_arg"])  # resumed from another folder
    if isinstance(header.get("sets"), list):  # kept; a key given again takes its new value
        again = {str(item).partition("=")[0].strip() for item in args.set or []}
        carried, problems = carried_sets(header, [str(item) for item in header["sets"]], again)
        if problems:
            return problems
        args.set = carried + list(args.set or [])
    return []


def carried_sets(
    header: dict, items: list[str], again: set[str] = frozenset()
) -> tuple[list[str], list[Problem]]:
    """The interrupted run's ``--set`` items as a run from this folder must read them: a
    value that named a file relative to the folder the run was started from (the header's
    ``cwd``: ``expected=stock.csv``) becomes that file's absolute path, so a resume from
    another folder reads the same file, not another of the same name or none. A relative
    file name found only here, not there, is a problem (unless ``again`` holds its key: this
    call gives it anew)."""
    cwd = header.get("cwd") if isinstance(header, dict) else None
    if not isinstance(cwd, str) or not cwd or os.path.abspath(cwd) == os.getcwd():
        return items, []
    out, problems = [], []
    for item in items:
        key, eq, value = item.partition("=")
        name = value.strip()
        path = header_path(header, name) if eq and name and not os.path.isabs(name) else None
        if path is not None and os.path.exists(path):
            out.append(f"{key}={path}")
            continue
        if path is not None and os.path.isfile(name) and key.strip() not in again:
            problems.append(
                Problem(
                    Loc("--resume", 0, 0),
                    f"the interrupted run's --set {item} named a file relative to {cwd}, "
                    f"where it no longer is; {name} here may be another file: give "
                    f"--set {key.strip()}=... again (an absolute path)",
                )
            )
        out.append(item)
    return out, problems
