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

from bt_engine.loading import check_mission
from bt_engine.preflight import check_before_flight
from bt_engine.registry import REGISTRY
from bt_engine.spec import Loc, MissionError
from drivers.settings import ConfigError
from nodes.common import config_problems
from nodes.fleet.plan import split_places
from nodes.fleet.spec import DroneSpec, FleetSpec, load_fleet
from nodes.inventory import resolve_places


def text(value: Any) -> str:
    """A fleet file's ``set:`` value as a ``--set`` value (lists and maps as JSON)."""
    return (
        json.dumps(value) if isinstance(value, (list, dict, bool)) or value is None else str(value)
    )


def common_sets(spec: FleetSpec, sets: list[str]) -> list[str]:
    """The settings of every drone: the fleet file's ``set:``, then the command's ``--set``."""
    return [f"{k}={text(v)}" for k, v in spec.data["set"].items()] + list(sets)


def rig_and_world(spec: FleetSpec, common: list[str], seed: int) -> tuple[Any, Any]:
    """The fleet's rig with the common rig and world settings, and its world with the
    seed's stock; raises :class:`MissionError` with located problems."""
    from drivers.rig.loader import load_rig

    over = {}
    for item in common:
        key, _, value = item.partition("=")
        if "." in key:
            over[key[4:] if key.startswith("rig.") else key] = value
    try:
        rig = load_rig(spec.rig, over)
        return rig, rig.load_world(seed)
    except ConfigError as exc:
        raise MissionError(config_problems(exc)) from None


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


def check_fleet(path: str, sets: list[str] | None = None, seed: int | None = None) -> list[str]:
    """Check fleet file ``path`` with ``--set`` items ``sets`` and ``seed`` (None: the
    file's) as ``btrun fleet`` does before take-off, flying nothing. Returns one line per
    drone that flies (``cf1: 36 places``); raises :class:`MissionError` with every located
    problem."""
    spec = load_fleet(path)
    seed = spec.data["seed"] if seed is None else seed
    common = common_sets(spec, list(sets or []))
    _, world = rig_and_world(spec, common, seed)
    places = planned_places(spec, world, common)
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
        lines.append(f"{d.name}: " + (f"{len(mine)} places" if mine is not None else "ok"))
    if problems:
        raise MissionError(problems)
    return lines
