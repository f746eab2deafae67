"""What ``btrun fleet`` checks before anything flies, and ``btrun fleet --check`` (and
``btrun validate FLEET``) checks alone: the fleet file, its rig and world with the seed's
stock, the places and their split, and each drone's mission with that drone's settings
(its places, pad, landing pads, ``set:``) as ``btrun run`` checks before take-off.

The settings each drone's mission gets are made here for both, so what is checked is what
flies.
"""

from __future__ import annotations

import json
import os
from typing import Any

from bt_engine.files import read_text
from bt_engine.loading import check_mission
from bt_engine.preflight import check_before_flight
from bt_engine.registry import REGISTRY
from bt_engine.run_inputs import carried_sets
from bt_engine.spec import Loc, MissionError, Problem, plural
from drivers.safety.policies import SafetyConfig
from drivers.settings import ConfigError
from nodes.common import config_problems
from nodes.fleet.plan import split_places
from nodes.fleet.spec import DroneSpec, FleetSpec, load_fleet, place_drones, rig_overrides
from nodes.inventory import resolve_places
from nodes.inventory_log import InventoryError, InventoryLog


def text(value: Any) -> str:
    """A fleet file's ``set:`` value as a ``--set`` value (lists and maps as JSON)."""
    return (
        json.dumps(value) if isinstance(value, (list, dict, bool)) or value is None else str(value)
    )


def common_sets(spec: FleetSpec | None, sets: list[str], previous: dict | None = None) -> list[str]:
    """The settings of every drone: the fleet file's ``set:`` (resuming, the settings the
    ``previous`` run flew with, its places among them), then the command's ``--set``."""
    if previous is None:
        base = [f"{k}={text(v)}" for k, v in spec.data["set"].items()]
    else:
        again = {item.partition("=")[0].strip() for item in sets}
        base, problems = carried_sets({"cwd": previous.get("cwd")}, list(previous["set"]), again)
        if problems:
            raise MissionError(problems)
        if previous["places"] is not None:
            base.append("places=" + ";".join(previous["places"]))
    return base + list(sets)


def given_sets(sets: list[str], previous: dict | None = None) -> list[str]:
    """The settings of every drone beyond the fleet file's ``set:``: resuming, the ones the
    ``previous`` run flew with (its places among them), then the command's ``--set``."""
    return list(sets) if previous is None else common_sets(None, list(sets), previous)


def rig_and_world(spec: FleetSpec, common: list[str], seed: int) -> tuple[Any, Any]:
    """The fleet's rig with the common rig and world settings, and its world with the
    seed's stock, the drones placed in it (their pads' positions there: the world flown,
    ``--set world.path=`` included) and checked there; raises :class:`MissionError` with
    located problems."""
    from drivers.rig.loader import load_rig

    over = {}
    for item in common:
        key, _, value = item.partition("=")
        over[key] = value
    try:
        rig = load_rig(spec.rig, rig_overrides(over), own_start=False)  # the drones' starts
        world = rig.load_world(seed)
    except ConfigError as exc:
        raise MissionError(config_problems(exc)) from None
    problems = place_drones(spec, rig, world) or start_problems(spec, rig)
    if problems:
        raise MissionError(problems)
    return rig, world


def start_problems(spec: FleetSpec, rig: Any) -> list[Problem]:
    """A drone that would start outside the rig's geofence (a breach the moment it took
    off), located where the fleet file gives its pad or start."""
    fence = SafetyConfig.from_dict(rig.data["safety"])
    if not fence.geofence_enabled or rig.data["link"] != "sim":
        return []
    out = []
    for d in spec.drones:
        if fence.inside(d.start_m):
            continue
        key = f"drones[{d.index}].pad" if d.pad else f"drones[{d.index}].start_m"
        start = ", ".join(f"{v:g}" for v in d.start_m)
        on = f" ({d.pad})" if d.pad else ""
        out.append(
            Problem(
                spec.loc(key),
                f"{d.name}: its start ({start}){on} is outside the rig's geofence "
                f"({fence.box_words()}): expected a start inside it",
            )
        )
    return out


def previous_run(resume: str | None) -> dict | None:
    """What fleet run folder ``resume`` (``--resume RUN``) flew, from its ``fleet.json``:
    ``seed``, ``set`` (its settings but places) and ``places`` (its planned places, None:
    each drone's mission had its own). None without ``resume``; raises
    :class:`MissionError` when RUN is not a fleet run folder."""
    if not resume:
        return None
    path = os.path.join(resume, "fleet.json")
    if not os.path.lexists(path):
        raise MissionError(
            [Problem(Loc("--resume", 0, 0), f"{resume} is not a fleet run folder (no fleet.json)")]
        )
    problems: list[Problem] = []
    raw = read_text(path, problems, what="fleet records")  # regular and bounded
    if raw is None:
        raise MissionError(problems)
    try:
        record = json.loads(raw)
    except (ValueError, RecursionError):
        record = None
    if not isinstance(record, dict) or type(record.get("seed")) is not int:
        raise MissionError([Problem(Loc(path, 1, 1), "not a fleet record: no integer 'seed'")])
    sets, places = record.get("set", []), record.get("places")
    if not (isinstance(sets, list) and all(isinstance(x, str) and "=" in x for x in sets)):
        raise MissionError(
            [Problem(Loc(path, 1, 1), "not a fleet record: 'set' is not a list of KEY=VALUE")]
        )
    if places is not None and not (
        isinstance(places, list) and all(isinstance(x, str) for x in places)
    ):
        raise MissionError(
            [Problem(Loc(path, 1, 1), "not a fleet record: 'places' is not a list of places")]
        )
    return {"seed": record["seed"], "set": sets, "places": places, "cwd": record.get("cwd")}


def resumed_seed(previous: dict | None, seed: int | None, resume: str | None) -> int | None:
    """The seed a fleet run flies: ``seed`` (``--seed``), else the one the ``previous`` run
    (:func:`previous_run` of ``resume``) flew; None: neither (the fleet file's then).
    Raises :class:`MissionError` when ``seed`` is not the one the previous run flew."""
    if previous is None:
        return seed
    if seed is not None and seed != previous["seed"]:
        raise MissionError(
            [
                Problem(
                    Loc("--resume", 0, 0),
                    f"{resume} flew seed {previous['seed']}, not {seed}: a resumed fleet keeps "
                    "its seed (the stock the carried answers were made in); leave --seed out",
                )
            ]
        )
    return previous["seed"]


def truth(rig: Any, world: Any) -> Any:
    """The merged inventory's ground truth (simulation only; None on hardware)."""
    if rig.kind != "sim" or world is None:
        return None
    return lambda: (world.places_truth(), set(world.not_enrolled()))


def layout(world: Any) -> dict[str, list]:
    """Place -> [rack, bay, level] of ``world`` (empty without places)."""
    return {n: [p.rack, p.bay, p.level] for n, p in (getattr(world, "places", None) or {}).items()}


def carried(resume: str | None, world: Any) -> set[str]:
    """The places run folder ``resume`` answered (empty without one); raises
    :class:`MissionError` when its inventory cannot be read or names places ``world`` lacks."""
    if not resume:
        return set()
    try:
        return InventoryLog(None, resume, "fleet", None, None, layout(world)).finished()
    except InventoryError as exc:
        raise MissionError([exc.problem()]) from None


def planned_places(spec: FleetSpec, world: Any, common: list[str]) -> list[str] | None:
    """The places the fleet is to answer (None: neither the fleet file nor ``--set`` names
    places; each drone's mission then has its own). A ``places=`` among the common settings
    replaces the fleet file's list; raises :class:`MissionError` for an unknown place."""
    given = [item.partition("=")[2] for item in common if item.partition("=")[0] == "places"]
    value = given[-1] if given else spec.data["places"]
    if value is None:
        return None
    base = os.path.dirname(os.path.abspath(spec.path))
    where = Loc("--set", 0, 0) if given else spec.loc("places")
    places, problems = resolve_places(value, world, where, base)
    if problems:
        raise MissionError(problems)
    return list(places)


def split(spec: FleetSpec, world: Any, todo: list[str]) -> dict[str, list[str]]:
    """Each drone's places among ``todo`` (by drone name, in flying order)."""
    starts = {d.name: d.start_m for d in spec.drones}
    return split_places(todo, world, starts, spec.data["split"])


def drone_sets(d: DroneSpec, common: list[str], places: list[str] | None) -> list[str]:
    """The ``--set`` items drone ``d``'s mission flies with: the common ones (without
    ``places``), its own ``set:``, its pad as start, its URI and landing pads, its places."""
    sets = [item for item in common if item.partition("=")[0] != "places"]
    sets += [f"{k}={text(v)}" for k, v in d.sets.items()]
    sets.append(f"sim.start_m=[{d.start_m[0]}, {d.start_m[1]}, {d.start_m[2]}]")
    if d.uri:
        sets.append(f"crazyflie.uri={d.uri}")
    if d.landing_pads:
        sets.append("landing_pads=" + ";".join(d.landing_pads))
    if places is not None:
        sets.append("places=" + ";".join(places))
    return sets


def check_fleet(
    path: str, sets: list[str] | None = None, seed: int | None = None, resume: str | None = None
) -> list[str]:
    """Check fleet file ``path`` with ``--set`` items ``sets``, ``seed`` (None: the file's)
    and ``resume`` (``--resume RUN``: its seed, its inventory, the places it left) as
    ``btrun fleet`` does before take-off, flying nothing. Returns one line per drone
    (``cf1: 36 places``); raises :class:`MissionError` with every located problem."""
    previous = previous_run(resume)
    spec = load_fleet(path, given_sets(list(sets or []), previous))  # pads in the world flown
    seed = resumed_seed(previous, seed, resume)
    seed = spec.data["seed"] if seed is None else seed
    common = common_sets(spec, list(sets or []), previous)
    _, world = rig_and_world(spec, common, seed)
    done = carried(resume, world)
    places = planned_places(spec, world, common)
    if places is not None:
        places = [p for p in places if p not in done]
    shares = split(spec, world, places) if places is not None else None
    mission, problems = check_mission(spec.mission, REGISTRY)
    if problems:
        raise MissionError(problems)
    lines: list[str] = []
    for d in spec.drones:
        mine = shares[d.name] if shares is not None else None
        if mine is not None and not mine:
            lines.append(f"{d.name}: no place to fly; it stays on its pad")
            continue
        sets = drone_sets(d, common, mine)
        # once a drone has a problem, no other drone's check builds a gallery for nothing
        found = check_before_flight(mission, spec.rig, sets, seed, loads=not problems)
        problems += [p for p in found if p not in problems]
        lines.append(f"{d.name}: " + (plural(len(mine), "place") if mine is not None else "ok"))
    if problems:
        raise MissionError(problems)
    return lines
