"""The fleet file: which mission, on which rig, with which drones, pads and URIs.

Example (``fleets/aisle_2.yaml``)::

    name: aisle_2
    mission: ../missions/inventory.xml
    rig: ../rigs/aisle.yaml
    places: all                 # split between the drones (the mission's places input)
    drones:
      - {name: cf1, pad: pad-1}
      - {name: cf2, pad: pad-2}

Paths are relative to the fleet file. Everything is checked before anything flies and every
problem is reported at once, located (``file:line:col: message``): 1 to 4 drones with
distinct names, a pad of the world or a start position for each (not both), no pad shared
(landing pads included), start positions at least the minimum separation apart, no
Crazyflie used twice however its URI is spelled (:func:`_check_uris`), the rig, the mission
and the place list. The pads are those of the world that is flown: the rig's, after the
fleet's ``set:`` and the command's ``--set`` (:func:`place_drones`). The fleet's name and
the drones' names become folder names (the run folder, ``drones/<name>/``), so they must
match :data:`SAFE_NAME` (no ``/``, no ``..``): a fleet file cannot write outside ``--out``.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from typing import Any

from bt_engine.files import file_kind
from bt_engine.inputs import UNCHECKED_PREFIX, declared_inputs, undeclared_input
from bt_engine.spec import Loc, MissionError, Problem
from drivers.settings import ConfigError, Field, Marks, problem_at
from drivers.settings_yaml import load_yaml_file
from nodes.common import config_problems

F = Field


def M(children: dict, doc: str = "") -> Field:  # noqa: N802 - schema shorthand
    """A mapping of fixed keys."""
    return Field("map", children=children, doc=doc)


MAX_DRONES = 4
#: Names used as folder names (the fleet's, each drone's): a letter or digit, then up to 63
#: letters, digits, ``_``, ``.`` or ``-``; never ``..``.
SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


def name_problem(name: str) -> str | None:
    """Why ``name`` cannot be a folder name of a fleet run (None: it can)."""
    if SAFE_NAME.fullmatch(name) and ".." not in name:
        return None
    return (
        f"{name!r:.80} cannot be a folder name: use 1 to 64 letters, digits, '_', '.' or '-', "
        "starting with a letter or digit, without '..'"
    )


DRONE = M(
    {
        "name": F(
            "str", None, "drone name (its run folder, its rows' drone column)", required=True
        ),
        "pad": F(
            "str",
            None,
            "the world pad it takes off from, lands and changes batteries on",
            nullable=True,
        ),
        "start_m": F(
            "vec", None, "start position x, y, z in m (instead of a pad)", length=3, nullable=True
        ),
        "landing_pads": F(
            "list",
            [],
            "other world pads it may land on at the end (the nearest of them and its pad; "
            "the mission's landing_pads input), e.g. [pad-5]: a pad at the aisle's far end",
            item=F("str"),
        ),
        "uri": F(
            "str", None, "its Crazyflie's URI (sets crazyflie.uri; real links only)", nullable=True
        ),
        "set": F("dict", {}, "KEY: VALUE for this drone only (as --set)", item=F("any")),
    }
)
FLEET_SCHEMA = M(
    {
        "name": F("str", "fleet", "fleet name (the run folder's name)"),
        "mission": F(
            "str", None, "mission every drone flies (relative to this file)", required=True
        ),
        "rig": F(
            "str",
            None,
            "rig of every drone (relative to this file; default: rigs/sim.yaml)",
            nullable=True,
        ),
        "seed": F("int", 0, "seed of the simulation (the world's stock, noise, gusts)"),
        "places": F(
            "str",
            None,
            "places to split between the drones (the mission's places input): all, names or "
            "patterns, or a .csv file; none: the mission's own",
            nullable=True,
        ),
        "split": F(
            "choice",
            "bays",
            "bays: each drone a block of neighbouring bays (the block nearest its pad); "
            "faces: each drone whole rack faces (a sweep; no face shared); "
            "round_robin: place by place in turn",
            choices=("bays", "faces", "round_robin"),
        ),
        "set": F(
            "dict",
            {},
            "KEY: VALUE for every drone (blackboard, rig and world, as --set)",
            item=F("any"),
        ),
        "separation": M(
            {
                "minimum_m": F("float", 0.5, "drones never closer than this (m)", min=0.1),
                "hold_margin_m": F(
                    "float",
                    0.2,
                    "the guard holds a drone closing in within minimum + this + its stop (m)",
                    min=0.0,
                ),
            }
        ),
        "max_time_s": F("float", 3600.0, "mission time limit of the whole fleet (s)", min=1.0),
        "drones": F("list", [], f"1 to {MAX_DRONES} drones", item=DRONE),
    }
)


@dataclass
class DroneSpec:
    """One drone of a fleet, with where each of its settings was written."""

    name: str
    start_m: tuple[float, float, float]
    pad: str | None
    uri: str | None
    sets: dict[str, Any]
    index: int
    landing_pads: tuple[str, ...] = ()


@dataclass
class FleetSpec:
    """A validated fleet file."""

    path: str
    data: dict
    marks: Marks
    drones: list[DroneSpec]
    mission: str
    rig: str | None

    def loc(self, key: str) -> Loc:
        """Where ``key`` (dotted) was written in the fleet file."""
        file, line, col = self.marks.get(key, (self.path, 1, 1))
        return Loc(file, line, col)


def _relative(base: str, path: str | None) -> str | None:
    if not path:
        return None
    if os.path.isabs(path):
        return path
    here = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(base)), path))
    if not os.path.exists(here) and os.path.exists(path):
        return path
    shown = os.path.relpath(here)  # as messages show it: missions/x.xml, not /a/fleets/../
    return here if shown.startswith(os.pardir) else shown


def _check_inputs(mission: str, data: dict, at: Any) -> None:
    """Every plain (blackboard) key of the fleet's ``set`` and of each drone's ``set`` that
    the mission does not declare (``bb.NAME`` passes unchecked), located where it is
    written, with a "did you mean". A mission that does not load is left to its own check."""
    from bt_engine.loading import load_spec

    spec = load_spec(mission)
    if spec.load_problems:
        return
    declared = declared_inputs(spec)
    sections = [("set", data["set"])]
    sections += [(f"drones[{i}].set", d["set"]) for i, d in enumerate(data["drones"])]
    for section, sets in sections:
        for key in map(str, sets):
            message = None if "." in key else undeclared_input(key, declared, data["mission"])
            if message is not None:
                at(f"{section}.{key}", message)


#: Rig settings every drone of a fleet shares (one world, one clock, one kind of link): a
#: drone's own ``set:`` cannot change them.
SHARED_SETTINGS = ("world", "clock", "link")


def _check_own_sets(data: dict, at: Any) -> None:
    """A drone's own ``set:`` changing what the drones share (the world they fly in, the
    clock, the link kind), located where it is written: one drone in another world would
    take off from pads, and answer places, that the others do not have."""
    for i, d in enumerate(data["drones"]):
        for key in map(str, d["set"]):
            bare = key[4:] if key.startswith("rig.") else key
            if "." in key and bare.partition(".")[0] in SHARED_SETTINGS:
                at(
                    f"drones[{i}].set.{key}",
                    f"{key} cannot be set for one drone ({d['name']!r}): the drones of a fleet "
                    "share one world, clock and link kind; set it in the fleet's set: (or with "
                    "--set) for every drone",
                )


def load_fleet(path: str, overrides: list[str] | None = None) -> FleetSpec:
    """Read and check a fleet file; raises :class:`MissionError` with every located problem.

    The drones' pads are resolved in the world of the fleet's rig with the fleet file's
    ``set:`` and then ``overrides`` (``KEY=VALUE`` items, as ``--set``: the command's, a
    resumed run's) applied, as the fleet flies; :func:`nodes.fleet.check.rig_and_world`
    places them again (:func:`place_drones`) in the very world it loads for the flight."""
    from drivers.rig.loader import load_rig

    marks: Marks = {}
    try:
        data = load_yaml_file(path, FLEET_SCHEMA, marks=marks, what="fleet files")
    except ConfigError as exc:
        raise MissionError(config_problems(exc)) from None
    if data["mission"] is None:  # an empty document: the schema's defaults, no mission
        raise MissionError(
            [
                Problem(
                    Loc(path, 1, 1),
                    "the fleet file is empty: expected at least mission: (the mission every "
                    f"drone flies) and drones: (1 to {MAX_DRONES} drones)",
                )
            ]
        )
    problems: list[Problem] = []

    def at(key: str, message: str) -> None:
        p = problem_at(marks, key, path, message)
        problems.append(Problem(Loc(p.file, p.line, p.col), p.message))

    why = name_problem(data["name"])
    if why is not None:
        at("name", f"fleet name {why}")
    mission = _relative(path, data["mission"]) or ""
    kind = file_kind(mission)
    if kind is not None:  # a FIFO or a device: refused here, never opened
        at("mission", f"mission file {data['mission']!r} is {kind}, not a regular file")
    elif not os.path.isfile(mission):
        at("mission", f"mission file {data['mission']!r} not found (relative to {path})")
    else:
        _check_inputs(mission, data, at)
    _check_own_sets(data, at)
    rig_path = _relative(path, data["rig"])
    common = {str(k): v for k, v in data["set"].items()}
    for item in overrides or []:
        key, _, value = item.partition("=")
        common[key] = value
    world = None
    try:
        rig = load_rig(rig_path, rig_overrides(common), own_start=False)  # the drones' starts
        world = rig.load_world(data["seed"])
    except ConfigError as exc:
        problems += config_problems(exc)
        rig = None
    n = len(data["drones"])
    if not 1 <= n <= MAX_DRONES:
        at("drones", f"a fleet flies 1 to {MAX_DRONES} drones, got {n}")
    drones: list[DroneSpec] = []
    seen: dict[str, str] = {}
    for i, d in enumerate(data["drones"]):
        key = f"drones[{i}]"
        why = name_problem(d["name"])
        if why is not None:
            at(f"{key}.name", f"drone name {why}")
        if d["name"] in seen:
            at(f"{key}.name", f"two drones named {d['name']!r}")
        seen.setdefault(d["name"], key)
        if d["pad"] is not None and d["start_m"] is not None:
            start = ", ".join(f"{float(v):g}" for v in d["start_m"])
            at(
                f"{key}.start_m",
                f"drone {d['name']!r} has both a pad ({d['pad']!r}) and start_m ({start}): "
                "expected one of them (pad: it starts on that pad; start_m: elsewhere)",
            )
        drones.append(
            DroneSpec(
                d["name"],
                (0.0, 0.0, 0.0),  # placed below, in the rig's world
                d["pad"],
                d["uri"],
                dict(d["set"]),
                i,
                tuple(d["landing_pads"]),
            )
        )
    if rig is not None:  # no rig: its world's pads are unknown
        _place(data, drones, rig, world, at)
    if problems:
        raise MissionError(problems)
    return FleetSpec(path, data, marks, drones, mission, rig_path)


def rig_overrides(common: dict[str, Any]) -> dict[str, Any]:
    """The rig and world settings (``rig.KEY``/``KEY.SUB``, ``world.KEY``) among settings
    ``common`` (KEY -> value), as :func:`drivers.rig.loader.load_rig` takes them; blackboard
    inputs (``name``, ``bb.name``) left out."""
    return {
        (k[4:] if k.startswith("rig.") else k): v
        for k, v in common.items()
        if "." in k and not k.startswith(UNCHECKED_PREFIX)
    }


def place_drones(spec: FleetSpec, rig: Any, world: Any) -> list[Problem]:
    """Place ``spec``'s drones in ``world`` (the world flown: its rig's, with every setting
    applied), ``rig`` the rig flown: each drone's start is its pad's position there (or its
    ``start_m``), and its pads, landing pads, start separation and URI are checked there.
    Returns the located problems (none: the drones' starts are set)."""
    problems: list[Problem] = []

    def at(key: str, message: str) -> None:
        problems.append(Problem(spec.loc(key), message))

    _place(spec.data, spec.drones, rig, world, at)
    return problems


def _place(data: dict, drones: list[DroneSpec], rig: Any, world: Any, at: Any) -> None:
    """Set each drone's start in ``world`` and check pads, separation and URIs (``at``)."""
    pads = world.pads() if world is not None else {}
    for d in drones:
        raw = data["drones"][d.index]
        key = f"drones[{d.index}]"
        start = None
        if raw["start_m"] is not None:
            start = tuple(float(v) for v in raw["start_m"])
        elif raw["pad"] is not None:
            if raw["pad"] not in pads:
                at(f"{key}.pad", _not_a_pad(raw["pad"], pads))
            else:
                x, y = pads[raw["pad"]]
                start = (float(x), float(y), 0.0)
        else:
            at(key, f"drone {d.name!r} needs a pad (one of the world's pads) or start_m")
        for j, name in enumerate(d.landing_pads):
            if name not in pads:
                at(f"{key}.landing_pads[{j}]", _not_a_pad(name, pads))
        d.start_m = start or (0.0, 0.0, 0.0)
    _check_shared(data, drones, at)
    _check_uris(drones, rig, at)


def _not_a_pad(name: str, pads: dict) -> str:
    known = ", ".join(pads) or "none: the world has no pads"
    return f"pad {name!r} is not a pad of the world ({known})"


def _check_shared(data: dict, drones: list[DroneSpec], at: Any) -> None:
    """Pads used twice, start positions closer than the minimum separation."""
    minimum = data["separation"]["minimum_m"]
    by_pad: dict[str, str] = {}
    for d in drones:
        if d.pad is not None and data["drones"][d.index]["start_m"] is None:
            if d.pad in by_pad:
                at(
                    f"drones[{d.index}].pad",
                    f"pad {d.pad!r} is {by_pad[d.pad]}'s already: one drone per pad",
                )
                continue
            by_pad[d.pad] = d.name
    for d in drones:
        for j, name in enumerate(d.landing_pads):
            owner = by_pad.get(name)
            if owner is not None and owner != d.name:
                at(
                    f"drones[{d.index}].landing_pads[{j}]",
                    f"pad {name!r} is {owner}'s already: a drone lands only on its own pads",
                )
                continue
            by_pad[name] = d.name
    for i, a in enumerate(drones):
        for b in drones[i + 1 :]:
            gap = math.dist(a.start_m, b.start_m)
            shared = a.pad is not None and a.pad == b.pad
            if gap < minimum and not shared:
                key = "start_m" if data["drones"][b.index]["start_m"] is not None else "pad"
                at(
                    f"drones[{b.index}].{key}",
                    f"{b.name} starts {gap:.2f} m from {a.name} (at least the minimum separation "
                    f"{minimum:g} m)",
                )


def _check_uris(drones: list[DroneSpec], rig: Any, at: Any) -> None:
    """No two drones on one Crazyflie (a real link; SITL picks free ports itself), however
    their URIs are spelled: compared by :func:`~drivers.crazyflie.link_lock.link_identity`
    (for ``radio://``: channel and address, the address in any case, cflib's default
    E7E7E7E7E7 when left out; the dongle and the data rate do not tell drones apart)."""
    from drivers.crazyflie.link_lock import link_identity

    if rig is None or rig.kind != "crazyflie" or rig.data["crazyflie"]["sitl"]:
        return
    default = rig.data["crazyflie"]["uri"]
    by_link: dict[str, tuple[str, str]] = {}
    for d in drones:
        own = [v for k, v in d.sets.items() if str(k) in ("crazyflie.uri", "rig.crazyflie.uri")]
        uri = (d.uri or str((own or [None])[-1] or default)).strip()
        key = f"drones[{d.index}].uri" if d.uri else f"drones[{d.index}]"
        link = link_identity(uri)
        if link in by_link:
            other, other_uri = by_link[link]
            if uri == other_uri:
                at(key, f"{d.name} and {other} both use {uri}: give each drone its own uri")
            elif link.startswith("radio channel "):
                at(
                    key,
                    f"{d.name} and {other} both use the Crazyflie on {link} ({uri} and "
                    f"{other_uri}; the address's case, the dongle and the data rate do not "
                    "tell drones apart): give each drone its own uri",
                )
            else:
                at(
                    key,
                    f"{d.name} and {other} both use {link} ({uri} and {other_uri}): give "
                    "each drone its own uri",
                )
        by_link.setdefault(link, (d.name, uri))
