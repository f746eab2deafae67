"""Checks that need the plug-in, before anything flies: the missions against the node
registry, and every distinct settings combination against the plug-in's rig loading and
the missions' pre-flight checks.

Each mission is validated once (``btrun validate``). Settings are checked through
:func:`bt_engine.plugins.load_target` once per distinct combination of rig, world and fixed
values; a randomly drawn setting is checked at the values that bound its draws (both ends
of a range, every choice), so no draw can fail later. A plain (blackboard) key must be an
input of every mission of the campaign (``bb.NAME`` is passed on unchecked). Then each
distinct flight (mission, rig settings and blackboard values; not the seed) goes through
what its run checks before take-off (:func:`bt_engine.preflight.check_before_flight`
with ``loads=False``: the nodes' own checks against the rig, such as a climb above the
geofence; no gallery built, no model loaded), on one mission built per mission file whose
resources (the rig's) and blackboard values are set in turn. A problem with a setting's
value is reported where the campaign file wrote that setting, once, with the rig (and the
other values) it was found with.
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
    missing_inputs,
    parse_set_value,
    typed_inputs,
    undeclared_input,
)
from bt_engine.loading import check_mission, load_spec
from bt_engine.mission import Mission
from bt_engine.plugins import load_plugins, load_target
from bt_engine.registry import REGISTRY
from bt_engine.run_inputs import mission_time_limit
from bt_engine.spec import Loc, MissionError, MissionSpec, Problem

#: missions built for the flight checks kept at once (one per mission file and set of
#: blackboard keys: a few are enough; each is closed when it is dropped)
KEPT_MISSIONS = 8


def check_campaign(c: Campaign, rows: Iterable[Row], include_paths: list[str] | None = None) -> int:
    """Raise :class:`MissionError` with every located problem of the campaign's missions and
    settings; return the number of settings combinations checked. ``rows`` is iterated
    once (the lazy :func:`~bt_engine.campaign.rows.expand` is never made a list); only the
    distinct settings combinations are kept."""
    load_plugins()  # registers the plug-ins' leaves
    problems: list[Problem] = []
    passed: dict[str, MissionSpec] = {}  # the missions whose flights are checked (below)
    for path, written in dict(zip(c.mission_paths, c.missions, strict=True)).items():
        warnings: list[Problem] = []
        spec, found = check_mission(path, REGISTRY, include_paths, warnings)
        problems += found
        for w in warnings:
            print(str(w), file=sys.stderr)
        if not found:
            inputs = _check_inputs(c, written, declared_inputs(spec))
            found = inputs or _check_values(c, Mission(spec))
            problems += found
            if not found:
                passed[path] = spec
    targets: dict[tuple, Any] = {}  # rig combination -> its run target (None: refused)
    faults = {case.name: case for case in c.faults or ()}
    flights = _Flights(c, passed)
    try:
        for row in rows:
            drawn = _drawn_keys(c, faults.get(row.fault) if row.fault else None)
            fixed = {k: v for k, v in row.settings.items() if k not in drawn}
            for values in _candidates(fixed, drawn):
                overrides = {k: v for k, v in values.items() if _is_rig_key(k)}
                sig = (row.rig_path, row.world_path, tuple(sorted(overrides.items())))
                if sig not in targets:
                    found, targets[sig] = _check_target(c, row, overrides)
                    problems += found
                if targets[sig] is not None:
                    problems += flights.check(row, sig, targets[sig], values)
    finally:
        flights.close()
    if problems:
        unique = list({(p.loc, p.message): p for p in problems}.values())
        raise MissionError(unique)
    return len(targets)


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
    """The keys a row draws at random (rig settings and blackboard entries) -> the values
    that bound their draws."""
    draws = {**c.random, **(case.draws if case is not None else {})}
    return {k: d.extremes() for k, d in draws.items()}


def _candidates(fixed: dict[str, Any], drawn: dict[str, list[Any]]) -> list[dict]:
    """Settings (as ``--set`` reads them) that cover every bound of the drawn keys (with the
    fixed ones)."""
    n = max((len(v) for v in drawn.values()), default=1)
    out = []
    for i in range(n):
        over = {k: value_text(v) for k, v in fixed.items()}
        over.update({k: value_text(v[min(i, len(v) - 1)]) for k, v in drawn.items()})
        out.append(over)
    return out


def _check_target(c: Campaign, row: Row, overrides: dict[str, str]) -> tuple[list[Problem], Any]:
    """The problems of a rig combination and its run target (None if it has problems, or
    no plug-in flies anything)."""
    over = dict(overrides)
    if row.world_path:
        over["world.path"] = row.world_path
    try:
        target = load_target(row.rig_path, over)
    except MissionError as exc:
        return [_relocate(c, row, p) for p in exc.problems], None
    if target is None and over:
        where = Loc(c.path, 1, 1)
        return [Problem(where, "no vehicle plug-in is installed to use rig settings")], None
    return [], target


class _Flights:
    """What each distinct flight of the campaign would refuse before take-off, as
    :func:`bt_engine.preflight.check_before_flight` finds it with ``loads=False`` (the
    mission's inputs, its time limit, every node's pre-flight check against the rig's
    resources), without loading a target or building a mission per flight: one mission per
    mission file and set of blackboard keys (the last :data:`KEPT_MISSIONS`), its
    resources those of the rig combination checked, its blackboard values set in turn. A
    problem is said once."""

    def __init__(self, c: Campaign, specs: dict[str, MissionSpec]) -> None:
        self.c = c
        self.specs = specs
        self.seen: set[tuple] = set()
        self.said: set[tuple] = set()
        self.missions: dict[tuple, Mission] = {}
        self.missing: dict[tuple, list[Problem]] = {}
        self.values: dict[str, Any] = {}
        self.rigs: dict[tuple, tuple] = {}  # mission key -> the rig combination of its resources

    def check(self, row: Row, sig: tuple, target: Any, values: dict[str, str]) -> list[Problem]:
        """The new problems of ``row``'s flight with these settings (``--set`` texts)."""
        spec = self.specs.get(row.mission_path)
        plain = {k: v for k, v in values.items() if not _is_rig_key(k)}
        flight = (row.mission_path, sig, tuple(sorted(plain.items())))
        if spec is None or flight in self.seen:
            return []
        self.seen.add(flight)
        names = {_entry(k): k for k in plain}  # blackboard entry -> the campaign's key
        bb = {_entry(k): self._value(v) for k, v in plain.items()}
        keys = (row.mission_path, frozenset(bb))
        if keys not in self.missing:  # the same for every flight with these keys
            self.missing[keys] = missing_inputs(spec, set(bb))
        found = self.missing[keys] + typed_inputs(spec, bb)  # (converts bb's values)
        _limit, limit_problem = mission_time_limit(spec, bb)
        found += [limit_problem] if limit_problem is not None else []
        if not found:
            try:
                mission = self._mission(row, sig, target, spec, bb)
            except MissionError as exc:
                found = exc.problems
            else:
                found = mission.preflight(set_keys=set(bb), loads=False)
        return self._located(row, values, names, found)

    def _value(self, text: str) -> Any:
        """``text`` as ``--set`` puts it on the blackboard (a YAML scalar), read once."""
        if text not in self.values:
            self.values[text] = parse_set_value(text)
        return self.values[text]

    def _mission(
        self, row: Row, sig: tuple, target: Any, spec: MissionSpec, bb: dict[str, Any]
    ) -> Mission:
        """The mission of ``row`` with the blackboard ``bb``, on the resources of the rig
        combination ``sig``: one per mission file and set of keys, its resources replaced
        by fresh ones when the rig combination changes (what a node loads before flight,
        such as the world, lives there: it is loaded again for the new rig)."""
        key = (row.mission_path, frozenset(bb))
        resources = {"platform": None, "seed": row.seed, "run_dir": None, "resume_from": None}
        mission = self.missions.pop(key, None)
        if mission is None:
            mission = Mission(spec, resources={**resources, **target.resources()}, blackboard=bb)
            while len(self.missions) >= KEPT_MISSIONS:
                oldest = next(iter(self.missions))
                self.rigs.pop(oldest, None)
                self.missions.pop(oldest).close()
        else:
            if self.rigs.get(key) != sig:
                mission.ctx.resources = {**resources, **target.resources()}
            for k, v in bb.items():
                mission.scope.set(k, v)
        self.missions[key] = mission  # the most recently used last
        self.rigs[key] = sig
        return mission

    def _located(
        self, row: Row, values: dict[str, str], names: dict[str, str], found: list[Problem]
    ) -> list[Problem]:
        """``found`` said once each: a ``--set`` problem where the campaign file wrote the
        setting, with the rig (world, fault) and the other varying values of the flight."""
        out = []
        for p in found:
            key = None
            if p.loc.file == "--set":
                key = next(
                    (
                        names[n]
                        for n in sorted(names, key=len, reverse=True)
                        if p.message.startswith((f"{n}:", f"{n}="))
                    ),
                    None,
                )
                loc = (self.c.key_locs.get(key) if key else None) or Loc(self.c.path, 1, 1)
            else:
                loc = p.loc
            if (loc, p.message) in self.said:
                continue
            self.said.add((loc, p.message))
            context = [f"rig {row.rig or '(default)'}"]
            context += [f"world {row.world}"] if row.world else []
            context += [f"fault {row.fault}"] if row.fault else []
            others = [f"{k}={values[k]}" for k in row.params if k != key and k in values]
            context += [f"with {', '.join(others)}"] if others else []
            out.append(Problem(loc, f"{p.message} ({', '.join(context)})"))
        return out

    def close(self) -> None:
        """Close the missions built (their entries leave the shared blackboard)."""
        while self.missions:
            self.missions.pop(next(iter(self.missions))).close()


def _entry(key: str) -> str:
    """The blackboard entry a plain campaign key sets (``bb.NAME``: ``NAME``)."""
    return key[len(UNCHECKED_PREFIX) :].strip() if key.startswith(UNCHECKED_PREFIX) else key


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
