"""The files btrun's plug-in reads besides missions, for ``btrun validate``: a rig (with
its world), a world, a fleet. Each is told apart by its top-level keys (the keys of its
schema) and checked as the command that reads it would before anything flies."""

from __future__ import annotations

from bt_engine.plugins import FileKind
from bt_engine.spec import Loc, MissionError, Problem, plural
from drivers.rig.loader import load_rig
from drivers.rig.schema import RIG_SCHEMA
from drivers.settings import ConfigError
from drivers.sim.world import load_world
from drivers.sim.world_schema import WORLD_SCHEMA
from nodes.common import config_problems
from nodes.fleet.check import check_fleet
from nodes.fleet.spec import FLEET_SCHEMA
from nodes.gallery.enrol_scan import enrolment_note


def _overrides(sets: list[str]) -> tuple[dict[str, str], list[Problem]]:
    bad = [item for item in sets if "=" not in item]
    problems = [Problem(Loc("--set", 0, 0), f"expected KEY=VALUE, got {item!r}") for item in bad]
    return dict(item.split("=", 1) for item in sets if "=" in item), problems


def check_rig(path: str, sets: list[str], seed: int | None) -> list[Problem]:
    """A rig file with ``--set`` overrides, and its world with the stock of ``seed``
    (default 0), as ``btrun run --rig`` loads them."""
    overrides, problems = _overrides(sets)
    if problems:
        return problems
    try:
        rig = load_rig(path, overrides)
        if rig.kind == "sim":
            rig.load_world(seed or 0)
    except ConfigError as exc:
        return config_problems(exc)
    return []


def check_world(
    path: str, sets: list[str], seed: int | None
) -> list[Problem] | tuple[list[Problem], str]:
    """A world file with ``--set`` overrides of its keys (``racks[0].depth_m=1.1``; a
    ``world.`` in front is allowed, as on a rig) and the stock of ``seed`` (default 0);
    with no problem, what a user should know of its demo gallery's enrolment, if anything."""
    overrides, problems = _overrides(sets)
    if problems:
        return problems
    keys = {k.removeprefix("world."): v for k, v in overrides.items()}
    try:
        world = load_world(path, keys, seed or 0)
    except ConfigError as exc:
        return config_problems(exc)
    note = enrolment_note(world.data)
    return ([], f"note: {note}") if note else []


def check_fleet_file(
    path: str, sets: list[str], seed: int | None
) -> list[Problem] | tuple[list[Problem], str]:
    """A fleet file as ``btrun fleet --check`` checks it (seed None: the file's); with no
    problem, what ``btrun fleet --check`` says of it (the drones and their shares)."""
    try:
        lines = check_fleet(path, sets, seed)
    except MissionError as exc:
        return exc.problems
    return [], f"{plural(len(lines), 'drone')}; " + ", ".join(lines)


#: btrun's file kinds besides missions (:class:`~bt_engine.plugins.FileKind`).
KINDS: dict[str, FileKind] = {
    "fleet": FileKind(
        frozenset(FLEET_SCHEMA.children), check_fleet_file, "btrun fleet FILE (--check)"
    ),
    "rig": FileKind(frozenset(RIG_SCHEMA.children), check_rig, "btrun MISSION --rig FILE"),
    "world": FileKind(
        frozenset(WORLD_SCHEMA.children),
        check_world,
        "the world.path of a rig: btrun MISSION --rig RIG",
    ),
}
