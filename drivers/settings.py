"""A tiny schema language for rig and world files, with located errors.

Rig and world files are YAML. They are validated against a :class:`Field` tree built once per
file kind (see :mod:`drivers.rig.loader` and :mod:`drivers.sim.world`). Validation walks the nodes
that PyYAML's ``compose()`` returns, so every problem carries the file, line and column of
the offending key or value, and all problems are collected before anything is reported::

    rigs/sim.yaml:12:3: unknown key 'setpoint_mod' (did you mean 'setpoint_mode'?)
    rigs/sim.yaml:14:14: control.rate_hz: expected a number, got 'fast'

:func:`apply_overrides` applies ``--set dotted.key=value`` pairs to validated data with the
same type checks.

The files themselves are read and validated by :mod:`drivers.settings_yaml`
(:func:`~drivers.settings_yaml.load_yaml_file`, bounded reading in
:func:`~drivers.settings_yaml.read_settings_text`), which builds on this module: this one is
the bottom of drivers/ and imports nothing of the project.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import math
import re
from dataclasses import dataclass, field
from typing import Any

import yaml


def did_you_mean(name: str, candidates: list[str]) -> str:
    """Return `` (did you mean 'x'?)`` for the closest candidate, or an empty string."""
    close = difflib.get_close_matches(name, candidates, n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


class SettingProblem(str):
    """One located problem: reads as ``file:line:col: message`` and keeps its parts.

    ``file`` is ``--set`` (line and column 0) for a problem with a command-line override.
    """

    file: str
    line: int
    col: int
    message: str

    def __new__(cls, file: str, line: int, col: int, message: str) -> SettingProblem:
        text = f"--set {message}" if file == "--set" else f"{file}:{line}:{col}: {message}"
        obj = super().__new__(cls, text)
        obj.file, obj.line, obj.col, obj.message = file, line, col, message
        return obj

    @classmethod
    def at_node(cls, filename: str, node: yaml.Node, message: str) -> SettingProblem:
        """A problem at a composed YAML node's start."""
        mark = node.start_mark
        return cls(filename, mark.line + 1, mark.column + 1, message)


class ConfigError(Exception):
    """A rig or world file (or a ``--set`` override) is invalid.

    ``problems`` lists every problem as a :class:`SettingProblem` (a ``str`` reading
    ``file:line:col: message``, with the parts as attributes).
    """

    def __init__(self, problems: list[SettingProblem]) -> None:
        super().__init__("\n".join(problems))
        self.problems = list(problems)


@dataclass
class Field:
    """One setting: its type, default, documentation and limits.

    ``kind`` is one of ``float``, ``int``, ``bool``, ``str``, ``choice``, ``vec``, ``map``
    (fixed keys in ``children``), ``dict`` (free keys, values of type ``item``), ``list``
    (items of type ``item``) or ``any``.
    """

    kind: str
    default: Any = None
    doc: str = ""
    choices: tuple = ()
    min: float | None = None
    max: float | None = None
    children: dict[str, Field] = field(default_factory=dict)
    item: Field | None = None
    length: int | None = None
    nullable: bool = False
    required: bool = False


#: Where each setting was written: ``dotted.path -> (file, line, col)``.
Marks = dict[str, tuple[str, int, int]]


def problem_at(marks: Marks, key: str, default_file: str, message: str) -> SettingProblem:
    """A problem located where ``key`` was written (else at the file's start)."""
    file, line, col = marks.get(key, (default_file, 1, 1))
    return SettingProblem(file, line, col, message)


def check_value(value: Any, spec: Field, path: str) -> tuple[Any, list[str]]:
    """Type-check a plain Python ``value`` against ``spec``; return (value, messages)."""
    if value is None:
        if spec.nullable or spec.kind == "any":
            return None, []
        return value, [f"{path}: a value is required"]
    kind = spec.kind
    if kind == "any":
        return value, []
    if kind in ("float", "int"):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        if kind == "int":
            ok = ok and float(value).is_integer()
        if not ok:
            want = "an integer" if kind == "int" else "a number"
            hint = ""
            if isinstance(value, str) and re.fullmatch(
                r"[-+]?\d+(\.\d*)?[eE][-+]?\d+", value.strip()
            ):
                hint = (
                    " (YAML 1.1 reads an exponent without a dot and a sign as text: write 1.0e+3)"
                )
            return value, [f"{path}: expected {want}, got {value!r}{hint}"]
        if not math.isfinite(value):  # YAML's .nan and .inf: no setting means either
            return value, [f"{path}: expected a finite number, got {value!r}"]
        value = int(value) if kind == "int" else float(value)
        if spec.min is not None and value < spec.min:
            return value, [f"{path}: {value} is below the minimum {spec.min}"]
        if spec.max is not None and value > spec.max:
            return value, [f"{path}: {value} is above the maximum {spec.max}"]
        return value, []
    if kind == "bool":
        if not isinstance(value, bool):
            return value, [f"{path}: expected true or false, got {value!r}"]
        return value, []
    if kind in ("str", "choice"):
        if isinstance(value, (int, float)) and not isinstance(value, bool) and kind == "str":
            value = str(value)
        if not isinstance(value, str):
            return value, [f"{path}: expected a string, got {value!r}"]
        if kind == "choice" and value not in spec.choices:
            hint = did_you_mean(value, [str(c) for c in spec.choices])
            return value, [f"{path}: {value!r} is not one of {list(spec.choices)}{hint}"]
        return value, []
    if kind == "vec":
        if not isinstance(value, (list, tuple)) or (
            spec.length is not None and len(value) != spec.length
        ):
            return value, [f"{path}: expected a list of {spec.length} numbers, got {value!r}"]
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            return value, [f"{path}: expected numbers, got {value!r}"]
        if not all(math.isfinite(v) for v in value):
            return value, [f"{path}: expected finite numbers, got {value!r}"]
        return [float(v) for v in value], []
    if kind in ("map", "dict"):
        if not isinstance(value, dict):
            return value, [f"{path}: expected a mapping, got {value!r}"]
        out, problems = {}, []
        if kind == "map":
            for key in value:
                if key not in spec.children:
                    hint = did_you_mean(str(key), list(spec.children))
                    problems.append(f"{path}: unknown key '{key}'{hint}")
            for key, sub_spec in spec.children.items():
                if key in value:
                    out[key], p = check_value(value[key], sub_spec, f"{path}.{key}")
                    problems += p
                else:
                    out[key] = defaults(sub_spec)
            return out, problems
        for key, sub in value.items():
            out[str(key)], p = check_value(sub, spec.item or Field("any"), f"{path}.{key}")
            problems += p
        return out, problems
    if kind == "list":
        if not isinstance(value, list):
            return value, [f"{path}: expected a list, got {value!r}"]
        out, problems = [], []
        for i, sub in enumerate(value):
            v, p = check_value(sub, spec.item or Field("any"), f"{path}[{i}]")
            out.append(v)
            problems += p
        return out, problems
    raise ValueError(f"unknown field kind {kind!r}")


def defaults(spec: Field) -> Any:
    """Return the default value of ``spec`` (a mapping's defaults filled in recursively)."""
    if spec.kind == "map":
        return {key: defaults(sub) for key, sub in spec.children.items()}
    return copy.deepcopy(spec.default)


#: ``name[3]`` in an override key: the list item 3 of ``name`` (the same as ``name.3``)
_INDEX = re.compile(r"\[\s*([^\]]*?)\s*\]")


def key_parts(dotted: str) -> list[str]:
    """The parts of a ``--set`` style key, list indexes dotted or in brackets alike
    (``row_slots[0].x_m`` and ``row_slots.0.x_m``: ``["row_slots", "0", "x_m"]``)."""
    return _INDEX.sub(r".\1", dotted).split(".")


def written_by(key: str, overrides: Any) -> bool:
    """True if a ``--set`` key of ``overrides`` wrote ``key`` or a part of it
    (``stock.empty_places`` wrote ``stock``; ``stock`` wrote ``stock.not_enrolled[0]``)."""
    mine = key_parts(key)
    for k in overrides:
        theirs = key_parts(k)
        n = min(len(mine), len(theirs))
        if mine[:n] == theirs[:n]:
            return True
    return False


def _index_problem(part: str, length: int, name: str) -> str | None:
    """Why ``part`` is no index of the list ``name`` of ``length`` items (None: it is)."""
    items = f"{name} has {length} item{'s' if length != 1 else ''}" + (
        f" ({name}.0 .. {name}.{length - 1}, or {name}[0])" if length else ""
    )
    if not part.isdigit():
        return f"'{part}' is not an index: {items}"
    if int(part) >= length:
        return f"index {int(part)} is out of range: {items}"
    return None


def apply_overrides(
    data: dict, overrides: dict[str, str] | None, spec: Field, prefix: str = ""
) -> dict:
    """Return a copy of validated ``data`` with ``--set`` style overrides applied.

    Each key is a dotted path (``control.rate_hz``); an item of a list is addressed by its
    index, dotted or in brackets (``row_slots.0.x_m`` or ``row_slots[0].x_m``). Each value
    is a string parsed as YAML (``"0.5"`` -> 0.5, ``"[1, 0, 0]"`` -> list, ``"null"`` ->
    None) and type-checked against the schema. Unknown keys get a "did you mean", an index
    out of range the list's length. All problems are raised at once.
    ``prefix`` (e.g. ``"world."``) is how the user wrote the keys' parent on the command
    line; messages name the keys with it.
    """
    out = copy.deepcopy(data)
    problems: list[SettingProblem] = []
    for dotted, raw in (overrides or {}).items():
        where = f"{prefix}{dotted}={raw}"
        parts = key_parts(dotted)
        node_spec, target = spec, out
        ok = True
        for i, part in enumerate(parts):
            last = i == len(parts) - 1
            if node_spec.kind == "list" and isinstance(target, list):
                why = _index_problem(part, len(target), prefix + ".".join(parts[:i]))
                if why is not None:
                    problems.append(SettingProblem("--set", 0, 0, f"{where}: {why}"))
                    ok = False
                    break
                part = int(part)  # type: ignore[assignment]
                child = node_spec.item or Field("any")
            elif node_spec.kind == "map":
                if part not in node_spec.children:
                    head = ".".join(parts[:i])
                    names = [
                        f"{prefix}{head}.{k}" if head else f"{prefix}{k}"
                        for k in node_spec.children
                    ]
                    hint = did_you_mean(prefix + ".".join(parts[: i + 1]), names)
                    problems.append(
                        SettingProblem(
                            "--set", 0, 0, f"{where}: unknown key '{prefix}{dotted}'{hint}"
                        )
                    )
                    ok = False
                    break
                child = node_spec.children[part]
            elif node_spec.kind == "dict":
                child = node_spec.item or Field("any")
            else:
                problems.append(
                    SettingProblem(
                        "--set", 0, 0, f"{where}: '{'.'.join(parts[:i])}' has no sub-keys"
                    )
                )
                ok = False
                break
            if last:
                try:
                    value = yaml.safe_load(raw) if isinstance(raw, str) else raw
                except yaml.YAMLError:
                    value = raw
                if child.kind in ("str", "choice") and isinstance(value, (int, float)):
                    value = str(raw)
                value, messages = check_value(value, child, dotted)
                if messages:
                    problems += [SettingProblem("--set", 0, 0, f"{where}: {m}") for m in messages]
                    ok = False
                    break
                target[part] = value
            else:
                if isinstance(target, dict) and target.get(part) is None:
                    target[part] = {}
                target = target[part]
                node_spec = child
        del ok
    if problems:
        raise ConfigError(problems)
    return out


def describe(spec: Field, prefix: str = "") -> list[str]:
    """List every setting as ``dotted.key (kind, default): doc`` lines (for docs and help)."""
    lines = []
    for key, sub in spec.children.items():
        name = f"{prefix}{key}"
        if sub.kind == "map":
            lines += describe(sub, name + ".")
        else:
            lines.append(f"{name} ({sub.kind}, default {sub.default!r}): {sub.doc}")
    return lines


# ---------------------------------------------------------------------- settings as dataclasses
def setting(default: Any, doc: str, **spec: Any) -> Any:
    """A dataclass field that is also a settings-file entry: one declaration for both.

    ``spec`` holds the :class:`Field` limits (``min``, ``max``, ``choices``, ``nullable``,
    ``kind``) and ``key``, the dotted key in the file when it differs from the field name
    (``geofence.min_m`` for ``geofence_min_m``). :func:`schema_of` builds the file's schema
    from these fields and :func:`from_settings` the dataclass from validated data.
    """
    meta = {"setting": {"doc": doc, **spec}}
    if isinstance(default, (list, dict, tuple)):
        return dataclasses.field(default_factory=lambda: copy.deepcopy(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _kind_of(default: Any, meta: dict[str, Any]) -> str:
    if meta.get("kind"):
        return meta["kind"]
    if meta.get("choices"):
        return "choice"
    if isinstance(default, bool):
        return "bool"
    if isinstance(default, (int, float)):
        return "float"
    if isinstance(default, (list, tuple)):
        return "vec"
    return "str"


def _settings(cls: type) -> list[tuple[dataclasses.Field, dict[str, Any], Any]]:
    out = []
    for f in dataclasses.fields(cls):
        meta = f.metadata.get("setting")
        if meta is None:
            continue
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
        out.append((f, meta, default))
    return out


def schema_of(cls: type, doc: str = "") -> Field:
    """The ``map`` schema of a settings dataclass (fields declared with :func:`setting`)."""
    root = Field("map", doc=doc)
    for f, meta, default in _settings(cls):
        kind = _kind_of(default, meta)
        limits = {k: v for k, v in meta.items() if k in ("min", "max", "nullable", "choices")}
        if kind == "vec":
            default = list(default)
            limits["length"] = len(default)
        spec = Field(kind, default, meta["doc"], **limits)
        parts = meta.get("key", f.name).split(".")
        node = root
        for part in parts[:-1]:
            node = node.children.setdefault(part, Field("map"))
        node.children[parts[-1]] = spec
    return root


def from_settings(cls: type, data: dict[str, Any] | None, **extra: Any) -> Any:
    """Build the settings dataclass ``cls`` from validated data (missing or null keys keep
    their defaults; vectors become tuples); ``extra`` sets other fields."""
    kw: dict[str, Any] = dict(extra)
    for f, meta, default in _settings(cls):
        value: Any = data or {}
        for part in meta.get("key", f.name).split("."):
            value = value.get(part) if isinstance(value, dict) else None
        if value is None:
            continue
        if isinstance(default, tuple):
            value = tuple(float(v) for v in value)
        elif isinstance(default, float) and not isinstance(value, bool):
            value = float(value)
        kw[f.name] = value
    return cls(**kw)
