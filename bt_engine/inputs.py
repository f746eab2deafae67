"""A mission's inputs: what ``--set NAME=VALUE`` may give it and how a value is read.

The inputs are the main tree's ``<TreeNodesModel>`` ports and the entries the mission reads
on its root blackboard (:func:`declared_inputs`; ``max_time`` is btrun's own in every
mission); one declared without a default that nothing writes must be given
(:func:`missing_inputs`); a declared ``type="int"`` holds (:func:`typed_inputs`).
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Collection
from typing import Any

import yaml

from bt_engine.ports import PortValueError, StringType, declared_type
from bt_engine.registry import REGISTRY, Registry
from bt_engine.spec import Loc, MissionSpec, Problem
from bt_engine.validate import (
    port_read_entries,
    referenced_entries,
    root_inputs,
    written_entries,
)


def mission_inputs(spec: MissionSpec) -> dict[str, Any]:
    """Default values of the mission's input ports.

    A mission declares its inputs the BehaviorTree.CPP way: a ``<SubTree ID="...">`` entry
    in ``<TreeNodesModel>`` for the main tree, with ``<input_port name=... default=...>``.
    The runner seeds the blackboard with these defaults; ``--set name=value`` overrides them.
    """
    main = spec.main_tree_id()
    model = spec.models.get(main) if main else None
    if model is None:
        return {}
    return {
        p.name: p.default
        for p in model.ports.values()
        if p.direction in ("input", "inout")
        and p.default is not None
        and not p.name.startswith("__")
    }


#: The input name that is btrun's own, in every mission: its mission-time limit in s
#: (``--set max_time=S``; :func:`bt_engine.run_inputs.mission_time_limit`).
MAX_TIME_INPUT = "max_time"

#: Prefix of a ``--set`` key (and of a campaign or fleet setting) that puts an entry on the
#: blackboard unchecked: ``--set bb.NAME=VALUE`` sets ``NAME`` even if the mission does not
#: declare it (an entry a plug-in leaf reads without a port).
UNCHECKED_PREFIX = "bb."


_PLAIN_NUMBER = re.compile(r"[-+]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][-+]?\d+)?", re.ASCII)
_PLAIN_INT = re.compile(r"[-+]?\d+", re.ASCII)


def parse_set_value(text: str) -> Any:
    """A ``--set`` blackboard value as it goes on the blackboard: a YAML scalar or list
    (numbers, booleans), otherwise the text; the ports convert it when read."""
    try:
        parsed = yaml.safe_load(text) if text.strip() else ""
    except (yaml.YAMLError, RecursionError, ValueError):  # a list nested 500 deep, ...
        return text
    if isinstance(parsed, str) and _PLAIN_NUMBER.fullmatch(text.strip()):
        parsed = float(text.strip())  # 1e3: YAML 1.1 reads an exponent only after a dot
    if isinstance(parsed, (int, float)) and not isinstance(parsed, bool):
        # YAML 1.1 reads 010 as 8, 1:30 as 90 and 0_5 as 5: only plain decimal numbers
        # are numbers here; any other text is left to the ports, which refuse or read it
        t = text.strip()
        if isinstance(parsed, float) and not math.isfinite(parsed):
            return parsed  # .nan, .inf: said by the ports as no finite number
        if not _PLAIN_NUMBER.fullmatch(t):
            return text
        return int(t, 10) if _PLAIN_INT.fullmatch(t) else float(t)
    if isinstance(parsed, bool) and text.strip().lower() not in ("true", "false"):
        return text  # YAML 1.1's yes/no/on/off: a bool port reads them, a text port keeps them
    return parsed if isinstance(parsed, (int, float, bool, str, list)) else text


class Inputs(set):
    """A mission's inputs (a set of names) and, in ``inner``, where names that are not
    inputs are read: inside SubTrees that never see the root blackboard's entry."""

    inner: dict[str, Any]


def declared_inputs(spec: MissionSpec, registry: Registry | None = None) -> Inputs:
    """The blackboard entries a mission takes from outside (``--set NAME=VALUE``).

    They are the ports of the main tree's ``<TreeNodesModel>`` entry (with or without a
    default) and every entry the mission reads on its root blackboard: ``{name}``
    references on any port and the names its scripts read, in the main tree and in the
    SubTrees that see the root's entry (remapped ``{name}``, ``_autoremap``, ``{@name}``).
    """
    found, inner = root_inputs(spec, registry or REGISTRY)
    names = Inputs(found | {MAX_TIME_INPUT})  # btrun's own: the mission's time limit
    names.inner = inner
    main = spec.main_tree_id()
    model = spec.models.get(main) if main else None
    if model is not None:
        names.update(p.name for p in model.ports.values() if not p.name.startswith("__"))
    return names


def missing_inputs(
    spec: MissionSpec, given: Collection[str], registry: Registry | None = None
) -> list[Problem]:
    """The main tree's declared inputs without a default that the mission reads, nothing in
    it writes and ``given`` (the ``--set`` entries) does not hold: the first leaf to read
    one would fail in flight (``{target}, which is not set``), so the run is refused."""
    main = spec.main_tree_id()
    model = spec.models.get(main) if main else None
    if model is None:
        return []
    reg = registry or REGISTRY
    written = written_entries(spec, reg)
    if written is None:
        return []
    read = referenced_entries(spec, reg)
    return [
        Problem(
            model.loc,
            f"mission input '{p.name}' has no default and nothing in the mission writes it: "
            f"give it with --set {p.name}=VALUE (or a default in <TreeNodesModel>)",
        )
        for p in model.ports.values()
        if p.direction == "input"
        and p.default is None
        and not p.name.startswith("__")
        and p.name not in given
        and p.name not in written
        and p.name in read
    ]


def typed_inputs(
    spec: MissionSpec, bb: dict[str, Any], raw: dict[str, str] | None = None
) -> list[Problem]:
    """``--set`` values (in ``bb``, changed in place) of main-tree inputs whose
    ``<TreeNodesModel>`` port declares a type (``type="int"``): a value of another type is a
    problem (a script reading it failed in flight), a number or truth value is put on the
    blackboard as that type (``--set laps=5.0`` for an int input: 5), and a text input
    (``type="std::string"``) gets its text as written in ``raw`` (name -> text)."""
    main = spec.main_tree_id()
    model = spec.models.get(main) if main else None
    if model is None:
        return []
    out = []
    by_ports = port_read_entries(spec, REGISTRY)  # a port reading it says it, and where
    for port in model.ports.values():
        kind = declared_type(port.type)
        if kind is None or port.name not in bb or bb[port.name] is None:
            continue
        if isinstance(kind, StringType) and raw is not None and port.name in raw:
            bb[port.name] = raw[port.name]  # text as written: 0042 is not the number 42
            continue
        if port.name in by_ports or port.name == MAX_TIME_INPUT:  # (the time limit's own)
            continue
        try:
            value = kind.convert(bb[port.name])
        except PortValueError as exc:
            out.append(
                Problem(
                    Loc("--set", 0, 0),
                    f"{port.name}={bb[port.name]}: {exc} (the input is declared "
                    f'type="{port.type}" at {model.loc})',
                )
            )
            continue
        if isinstance(value, (bool, int, float)):
            bb[port.name] = value
    return out


def undeclared_input(key: str, declared: Collection[str], mission: str) -> str | None:
    """The one-line message for a blackboard key the mission does not declare (None when it
    does): a "did you mean" from ``declared``, the mission's inputs, the ``bb.`` way out."""
    if key in declared:
        return None
    where = getattr(declared, "inner", {}).get(key)
    if where is not None:
        return (
            f"{key}: {mission} reads '{key}' only inside a SubTree ({where}) whose calls give "
            f"it a value of their own, so --set {key} would change nothing; pass it in from "
            f'the main tree ({key}="{{{key}}}" in the SubTree calls, or _autoremap="true") '
            f"to set it from the command line"
        )
    close = difflib.get_close_matches(key, sorted(declared), n=1, cutoff=0.6)
    hint = f"; did you mean {close[0]}?" if close else ""
    listed = sorted(declared)
    inputs = ", ".join(listed[:12]) + (f", ... ({len(listed)} in all)" if len(listed) > 12 else "")
    return (
        f"{key}: {mission} has no input '{key}'{hint} (its inputs: {inputs or 'none'}; "
        f"{UNCHECKED_PREFIX}{key} puts it on the blackboard unchecked)"
    )
