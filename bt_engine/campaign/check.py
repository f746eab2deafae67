"""Checks that need the plug-in, before anything flies: the missions against the node
registry, and every distinct settings combination against the plug-in's rig loading.

Each mission is validated once (``btrun validate``). Settings are checked through
:func:`bt_engine.plugins.load_target` once per distinct combination of rig, world and fixed
values; a randomly drawn setting is checked at the values that bound its draws (both ends
of a range, every choice), so no draw can fail later. A plain (blackboard) key must be an
input of every mission of the campaign (``bb.NAME`` is passed on unchecked). A problem with
a setting's value is reported where the campaign file wrote that setting.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from typing import Any

from bt_engine.campaign.rows import Row, value_text
from bt_engine.campaign.spec import Campaign, FaultCase
from bt_engine.inputs import (
    UNCHECKED_PREFIX,
    declared_inputs,
    parse_set_value,
    undeclared_input,
)
from bt_engine.loading import check_mission, load_spec
from bt_engine.mission import Mission
from bt_engine.plugins import load_plugins, load_target
from bt_engine.registry import REGISTRY
from bt_engine.spec import Loc, MissionError, Problem


def check_campaign(c: Campaign, rows: Iterable[Row], include_paths: list[str] | None = None) -> int:
    """Raise :class:`MissionError` with every located problem of the campaign's missions and
    settings; return the number of settings combinations checked. ``rows`` is iterated
    once (the lazy :func:`~bt_engine.campaign.rows.expand` is never made a list); only the
    distinct settings combinations are kept."""
    load_plugins()  # registers the plug-ins' leaves
    problems: list[Problem] = []
    for path, written in dict(zip(c.mission_paths, c.missions, strict=True)).items():
        warnings: list[Problem] = []
        spec, found = check_mission(path, REGISTRY, include_paths, warnings)
        problems += found
        for w in warnings:
            print(str(w), file=sys.stderr)
        if not found:
            inputs = _check_inputs(c, written, declared_inputs(spec))
            problems += inputs or _check_values(c, Mission(spec))
    checked: set[tuple] = set()
    faults = {case.name: case for case in c.faults or ()}
    for row in rows:
        drawn = _drawn_keys(c, faults.get(row.fault) if row.fault else None)
        fixed = {k: v for k, v in row.settings.items() if _is_rig_key(k) and k not in drawn}
        for overrides in _candidates(fixed, drawn):
            sig = (row.rig_path, row.world_path, tuple(sorted(overrides.items())))
            if sig in checked:
                continue
            checked.add(sig)
            problems += _check_target(c, row, overrides)
    if problems:
        unique = list({(p.loc, p.message): p for p in problems}.values())
        raise MissionError(unique)
    return len(checked)


def mission_node_ids(c: Campaign, include_paths: list[str] | None = None) -> set[str]:
    """The node IDs the campaign's missions use (as the files write them; SubTrees
    expanded from their files): what every worker must know (its plug-ins loaded)."""
    ids: set[str] = set()
    for path in dict.fromkeys(c.mission_paths):
        spec = load_spec(path, include_paths)
        for tree in spec.trees.values():
            for node in tree.root.walk() if tree.root is not None else ():
                if node.type != "SubTree" and REGISTRY.get(node.type) is not None:
                    ids.add(node.type)
    return ids


def _is_rig_key(key: str) -> bool:
    """A dotted key is a rig/world setting, except ``bb.NAME`` (a blackboard entry)."""
    return "." in key and not key.startswith(UNCHECKED_PREFIX)


def _check_inputs(c: Campaign, mission: str, declared: set[str]) -> list[Problem]:
    """Every plain (blackboard) key the campaign sets that ``mission`` does not declare,
    located where the campaign file wrote it."""
    keys = [*c.fixed, *c.grid, *c.cycle, *c.random]
    for case in c.faults or ():
        keys += [*case.sets, *case.draws]
    out = []
    for key in dict.fromkeys(keys):
        message = None if "." in key else undeclared_input(key, declared, mission)
        if message is not None:
            out.append(Problem(c.key_locs.get(key) or Loc(c.path, 1, 1), message))
    return out


def _check_values(c: Campaign, mission: Mission) -> list[Problem]:
    """Every value the campaign gives a plain (blackboard) key that a port reading it cannot
    take, by type (``grid: {sweep_speed: [0.5, fast]}``) or by the port's range
    (``shots: [0, 60]`` for a count of 1 to 50), located where the campaign file wrote the
    key: each value of a grid or a cycle, the fixed ones, the bounds of a draw."""
    values: dict[str, list[Any]] = {}

    def add(key: str, vals: Iterable[Any]) -> None:
        if "." not in key:  # not a rig setting, nor a bb. entry passed on unchecked
            values.setdefault(key, []).extend(vals)

    for key, v in c.fixed.items():
        add(key, [v])
    for key, vs in [*c.grid.items(), *c.cycle.items()]:
        add(key, vs)
    for key, d in c.random.items():
        add(key, d.extremes())
    for case in c.faults or ():
        for key, v in case.sets.items():
            add(key, [v])
        for key, d in case.draws.items():
            add(key, d.extremes())
    out = []
    for key, vals in values.items():
        for text in dict.fromkeys(value_text(x) for x in vals):  # as a run's --set reads it
            mission.scope.set(key, parse_set_value(text))
            found = mission.set_value_problems({key}) or _range_problems(mission, key)
            if found:  # the first bad value of a key says it
                where = c.key_locs.get(key) or Loc(c.path, 1, 1)
                out.append(Problem(where, found[0].message))
                break
    return out


def _range_problems(mission: Mission, key: str) -> list[Problem]:
    """The problems of the ranges (``low``/``high``) of the ports that read ``key`` (through
    SubTree remapping too), as a run's ``--set key=...`` gets them before flight: the
    range part of :meth:`~bt_engine.mission.Mission.preflight`, without the nodes' own
    checks (those need the rig)."""
    found = mission._preflight(lambda node: True, {key}, False)
    return [p for p in found if p.loc.file == "--set"]


def _drawn_keys(c: Campaign, case: FaultCase | None) -> dict[str, list[Any]]:
    """The dotted keys a row draws at random -> the values that bound their draws."""
    draws = {**c.random, **(case.draws if case is not None else {})}
    return {k: d.extremes() for k, d in draws.items() if _is_rig_key(k)}


def _candidates(fixed: dict[str, Any], drawn: dict[str, list[Any]]) -> list[dict]:
    """Override sets that cover every bound of the drawn keys (with the fixed ones)."""
    n = max((len(v) for v in drawn.values()), default=1)
    out = []
    for i in range(n):
        over = {k: value_text(v) for k, v in fixed.items()}
        over.update({k: value_text(v[min(i, len(v) - 1)]) for k, v in drawn.items()})
        out.append(over)
    return out


def _check_target(c: Campaign, row: Row, overrides: dict[str, str]) -> list[Problem]:
    over = dict(overrides)
    if row.world_path:
        over["world.path"] = row.world_path
    try:
        target = load_target(row.rig_path, over)
    except MissionError as exc:
        return [_relocate(c, row, p) for p in exc.problems]
    if target is None and over:
        return [Problem(Loc(c.path, 1, 1), "no vehicle plug-in is installed to use rig settings")]
    return []


def _relocate(c: Campaign, row: Row, p: Problem) -> Problem:
    """A ``--set`` problem moves to where the campaign file wrote the setting."""
    if p.loc.file != "--set":
        return p
    key = p.message.split("=", 1)[0].strip()
    loc = c.key_locs.get(key)
    if key == "world.path" and row.world_path:
        loc = c.file_locs.get(row.world_path)
    context = f"rig {row.rig or '(default)'}" + (f", fault {row.fault}" if row.fault else "")
    return Problem(loc or Loc(c.path, 1, 1), f"{p.message} ({context})")
