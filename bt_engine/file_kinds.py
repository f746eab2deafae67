"""The files btrun reads besides missions, told apart by their top-level keys: a campaign
(the engine's own) and the plug-ins' kinds (btrun's: rigs, worlds, fleets).

:func:`check_other_file` checks such a file as the command that reads it would, flying
nothing (``btrun validate``); :func:`not_a_mission` says what a file given to ``btrun run``
is when it is not a mission.
"""

from __future__ import annotations

from collections.abc import Callable

import yaml

from bt_engine.files import read_text
from bt_engine.plugins import FileKind, load_plugins
from bt_engine.spec import Loc, MissionError, Problem
from bt_engine.yaml_io import TOP_KEYS as MISSION_KEYS

#: File suffixes read as YAML (a mission in YAML, a rig, a campaign, ...).
YAML_SUFFIXES = (".yaml", ".yml")


def top_level_keys(path: str) -> set[str] | None:
    """The top-level keys of a YAML file holding a mapping; None for anything else (XML, a
    file that cannot be read or parsed: the mission loader then says what is wrong)."""
    if not path.lower().endswith(YAML_SUFFIXES):
        return None
    text = read_text(path, [], what="btrun files")
    if text is None:
        return None
    try:  # the node graph only: aliases are never expanded, values never built
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except (yaml.YAMLError, RecursionError, ValueError):
        return None
    if not isinstance(node, yaml.MappingNode):
        return None
    return {str(k.value) for k, _ in node.value if isinstance(k, yaml.ScalarNode)}


def is_empty_yaml(path: str) -> bool:
    """True for a YAML file holding no value at all: 0 bytes, blank lines, comments, a bare
    ``---``. Its kind cannot be told (a mission? a rig?): it is refused as such, where a
    mission's check would call it a bad mission and a rig's load would take the defaults."""
    if not path.lower().endswith(YAML_SUFFIXES):
        return False
    text = read_text(path, [], what="btrun files")
    if text is None:
        return False
    empty = (
        yaml.StreamStartToken,
        yaml.StreamEndToken,
        yaml.DocumentStartToken,
        yaml.DocumentEndToken,
        yaml.DirectiveToken,
    )
    try:
        return all(isinstance(t, empty) for t in yaml.scan(text, Loader=yaml.SafeLoader))
    except (yaml.YAMLError, RecursionError, ValueError):
        return False


def _campaign_check(path: str, sets: list[str], seed: int | None) -> list[Problem]:
    from bt_engine.campaign.check import check_campaign
    from bt_engine.campaign.rows import expand
    from bt_engine.campaign.spec import load_campaign

    try:
        c = load_campaign(path)
        check_campaign(c, expand(c))
    except MissionError as exc:
        return exc.problems
    return []


def _kinds() -> dict[str, FileKind]:
    from bt_engine.campaign.spec import TOP_KEYS as CAMPAIGN_KEYS

    kinds = {
        "campaign": FileKind(
            frozenset(CAMPAIGN_KEYS),
            _campaign_check,
            "btrun campaign FILE --out DIR",
            takes_sets=False,
        )
    }
    for plugin in load_plugins():
        fn: Callable[[], dict[str, FileKind]] | None = getattr(plugin, "file_kinds", None)
        for name, kind in (fn() if fn is not None else {}).items():
            kinds.setdefault(name, kind)
    return kinds


def file_kind(path: str) -> tuple[str, FileKind] | None:
    """The kind of a YAML file that is not a mission (``("rig", ...)``), judged by its
    top-level keys: the kind that knows the most of them, if it knows more than a mission
    does. None for a mission (or anything not told apart: it is read as a mission)."""
    keys = top_level_keys(path)
    if not keys:
        return None
    best, best_score = None, len(keys & set(MISSION_KEYS))
    for name, kind in _kinds().items():
        score = len(keys & kind.keys)
        if score > best_score:
            best, best_score = (name, kind), score
    return best


def check_other_file(
    path: str, sets: list[str], seed: int | None, rig: str | None
) -> tuple[str, list[Problem], str] | None:
    """Check a file that is not a mission as the command that reads it would, flying
    nothing: ``(kind, problems, found)`` (``found``: what the check says the file holds,
    or ""); None if ``path`` is read as a mission. An empty YAML file is refused here
    (kind ``empty``): nothing says what it was meant to be."""
    if is_empty_yaml(path):
        names = sorted(_kinds())
        kinds = f"{', '.join(names[:-1])} or {names[-1]}" if len(names) > 1 else names[0]
        message = (
            f"the file is empty: expected a mission (a mapping with `trees:`) or a {kinds} "
            "file (its settings as a mapping)"
        )
        return "empty", [Problem(Loc(path, 1, 1), message)], ""
    found = file_kind(path)
    if found is None:
        return None
    name, kind = found
    problems = []
    if rig:
        problems.append(
            Problem(
                Loc("--rig", 0, 0),
                f"applies to missions only: {path} is a {name} file (used as: {kind.usage})",
            )
        )
    if sets and not kind.takes_sets:
        problems.append(
            Problem(
                Loc("--set", 0, 0),
                f"does not apply to {path}, a {name} file (used as: {kind.usage})",
            )
        )
    if problems:
        return name, problems, ""
    result = kind.check(path, sets, seed)
    if (  # (problems, found); a plain tuple of problems is problems
        isinstance(result, tuple)
        and len(result) == 2
        and isinstance(result[0], (list, tuple))
        and isinstance(result[1], str)
    ):
        return name, list(result[0]), result[1]
    return name, list(result), ""


def not_a_mission(path: str) -> Problem | None:
    """For ``btrun run``: a located problem saying what ``path`` is if it is a file of
    another kind (a rig, a fleet, ...), or None."""
    found = file_kind(path)
    if found is None:
        return None
    name, kind = found
    return Problem(
        Loc(path, 1, 1), f"this is a {name} file, not a mission; it is used as: {kind.usage}"
    )
