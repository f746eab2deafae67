"""Settings files (rig, world, fleet) read and validated, with located errors.

:func:`load_yaml_file` validates a YAML file against a :class:`~drivers.settings.Field` tree
(the schema language of :mod:`drivers.settings`). Validation walks the nodes that PyYAML's
``compose()`` returns, so every problem carries the file, line and column of the offending
key or value, and all problems are collected before anything is reported. Object tags,
anchors and aliases are refused before anything is constructed.

Settings files are read by :func:`read_settings_text`: regular files only (a named pipe would
block the reader forever and ``/dev/zero`` never ends, so both are refused before they are
opened), at most :data:`MAX_SETTINGS_BYTES`, UTF-8 text without NUL bytes; each refusal is
one located problem. (``bt_engine.files`` does the same for mission files; drivers/ does not
import the engine.)

This module imports :mod:`drivers.settings` (the bottom of drivers/, which imports nothing
of the project) and nothing else of the project.
"""

from __future__ import annotations

import os
import stat
from typing import Any

import yaml

from drivers.settings import (
    ConfigError,
    Field,
    Marks,
    SettingProblem,
    check_value,
    defaults,
    did_you_mean,
)


def _at(filename: str, node: yaml.Node, message: str) -> SettingProblem:
    return SettingProblem.at_node(filename, node, message)


def _validate_node(
    node: yaml.Node,
    spec: Field,
    path: str,
    filename: str,
    loader: yaml.SafeLoader,
    marks: Marks | None = None,
) -> tuple[Any, list[SettingProblem]]:
    """Validate a composed YAML node; messages carry the node's file:line:col."""
    if marks is not None:
        mark = node.start_mark
        marks[path] = (filename, mark.line + 1, mark.column + 1)
    label = path or "(top level)"
    if spec.kind == "map" and isinstance(node, yaml.MappingNode):
        out, problems, seen = {}, [], set()
        for key_node, value_node in node.value:
            if not isinstance(key_node, yaml.ScalarNode):  # e.g. "? [a, b]": a list as a key
                problems.append(_at(filename, key_node, "a key must be a plain name"))
                continue
            key = key_node.value
            sub_path = f"{path}.{key}" if path else key
            if key in seen:
                problems.append(_at(filename, key_node, f"duplicate key '{key}'"))
                continue
            seen.add(key)
            if key not in spec.children:
                hint = did_you_mean(str(key), list(spec.children))
                problems.append(_at(filename, key_node, f"unknown key '{key}'{hint}"))
                continue
            out[key], p = _validate_node(
                value_node, spec.children[key], sub_path, filename, loader, marks
            )
            problems += p
        for key, sub_spec in spec.children.items():
            if key not in out and key not in seen:
                if sub_spec.required:
                    problems.append(_at(filename, node, f"{label}: missing required key '{key}'"))
                out[key] = defaults(sub_spec)
        return out, problems
    if spec.kind == "dict" and isinstance(node, yaml.MappingNode):
        out, problems = {}, []
        for key_node, value_node in node.value:
            if not isinstance(key_node, yaml.ScalarNode):
                problems.append(_at(filename, key_node, "a key must be a plain name"))
                continue
            key = str(key_node.value)
            out[key], p = _validate_node(
                value_node, spec.item or Field("any"), f"{path}.{key}", filename, loader, marks
            )
            problems += p
        return out, problems
    if spec.kind == "list" and isinstance(node, yaml.SequenceNode):
        out, problems = [], []
        for i, item_node in enumerate(node.value):
            v, p = _validate_node(
                item_node, spec.item or Field("any"), f"{path}[{i}]", filename, loader, marks
            )
            out.append(v)
            problems += p
        return out, problems
    value = loader.construct_object(node, deep=True)
    value, messages = check_value(value, spec, label)
    return value, [_at(filename, node, m) for m in messages]


_PLAIN_TAGS = {
    "tag:yaml.org,2002:" + t for t in ("str", "int", "float", "bool", "null", "map", "seq")
}


def _unsafe_nodes(root: yaml.Node, filename: str, limit: int = 100_000) -> list[SettingProblem]:
    """Refuse what a settings file never needs: object tags and anchors/aliases (whose
    expansion can blow up), before anything is constructed."""
    problems: list[SettingProblem] = []
    seen: set[int] = set()
    stack = [root]
    count = 0
    while stack and len(problems) < 20:
        node = stack.pop()
        count += 1
        if count > limit:
            problems.append(_at(filename, node, f"more than {limit} values: not a settings file"))
            break
        if id(node) in seen:
            problems.append(_at(filename, node, "YAML anchors and aliases are not allowed here"))
            continue
        seen.add(id(node))
        if node.tag not in _PLAIN_TAGS:
            problems.append(_at(filename, node, f"YAML tag '{node.tag}' is not allowed here"))
            continue
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                stack += [v, k]
        elif isinstance(node, yaml.SequenceNode):
            stack += list(reversed(node.value))
    return problems


#: The largest rig, world or fleet file read, in bytes (as a mission file).
MAX_SETTINGS_BYTES = 5_000_000

_NOT_REGULAR = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def _position(data: bytes | str, index: int) -> tuple[int, int]:
    """(line, column), 1-based, of character (or byte) ``index`` of ``data``."""
    newline = b"\n" if isinstance(data, bytes) else "\n"
    line_start = data.rfind(newline, 0, index) + 1  # type: ignore[arg-type]
    return data.count(newline, 0, index) + 1, index - line_start + 1  # type: ignore[arg-type]


def read_settings_text(path: str, what: str = "settings files") -> str:
    """The text of the settings file ``path``; raises :class:`ConfigError` with one located
    problem if it is not a regular file (checked before it is opened; opened non-blocking
    and checked again), is larger than :data:`MAX_SETTINGS_BYTES`, cannot be read, is not
    UTF-8 or holds a NUL byte. ``what`` names the files in the messages (``rig files``)."""

    def refuse(message: str, line: int = 1, col: int = 1) -> ConfigError:
        return ConfigError([SettingProblem(path, line, col, message)])

    def not_regular(mode: int) -> ConfigError | None:
        if stat.S_ISREG(mode):
            return None
        kind = next((name for test, name in _NOT_REGULAR if test(mode)), "not a regular file")
        return refuse(f"{path} is {kind}, not a regular file; {what} are read from ordinary files")

    try:
        real = os.path.realpath(path)
        error = not_regular(os.stat(real).st_mode)  # before opening: a FIFO would block
        if error is not None:
            raise error
        fd = os.open(real, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
        with os.fdopen(fd, "rb") as f:
            st = os.fstat(f.fileno())
            error = not_regular(st.st_mode)
            if error is not None:
                raise error
            if st.st_size > MAX_SETTINGS_BYTES:
                raise refuse(f"file is {st.st_size} bytes; the limit is {MAX_SETTINGS_BYTES}")
            data = f.read(MAX_SETTINGS_BYTES + 1)
    except OSError as exc:
        raise refuse(f"cannot read file: {exc.strerror or exc}") from None
    except ValueError as exc:  # a path holding a NUL byte
        raise refuse(f"cannot read file: {exc}") from None
    if len(data) > MAX_SETTINGS_BYTES:
        raise refuse(f"file is larger than {MAX_SETTINGS_BYTES} bytes (the limit); not read")
    nul = data.find(b"\0")
    if nul >= 0:
        raise refuse(
            f"the file holds a NUL byte (byte {nul}); {what} are YAML text", *_position(data, nul)
        )
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise refuse(f"not UTF-8 text (byte {exc.start})", *_position(data, exc.start)) from None


def _yaml_problem(path: str, text: str, exc: yaml.YAMLError) -> SettingProblem:
    """A YAML error as one located problem (a control character, a syntax error)."""
    if isinstance(exc, yaml.reader.ReaderError):
        line, col = _position(text, max(exc.position, 0))
        char = exc.character
        shown = f"#x{char:04x}" if isinstance(char, int) else repr(char)
        return SettingProblem(path, line, col, f"character {shown} is not allowed in YAML")
    mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
    line, col = (mark.line + 1, mark.column + 1) if mark else (1, 1)
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    return SettingProblem(path, line, col, f"YAML syntax error: {problem}")


def load_yaml_file(
    path: str,
    spec: Field,
    text: str | None = None,
    marks: Marks | None = None,
    what: str = "settings files",
) -> dict:
    """Read (:func:`read_settings_text`, unless ``text`` is given) and validate the YAML
    file at ``path`` against ``spec``.

    Returns the validated data with defaults filled in. Raises :class:`ConfigError` listing
    every problem (syntax errors included) as ``file:line:col: message``. If ``marks`` is
    given it receives ``dotted.path -> (file, line, col)`` for every node, so callers can
    locate their own semantic checks. ``what`` names the files in a refusal of the file
    itself (``rig files are read from ordinary files``).
    """
    if text is None:
        text = read_settings_text(path, what)
    try:
        loader = yaml.SafeLoader(text)  # refuses control characters at once
    except yaml.YAMLError as exc:
        raise ConfigError([_yaml_problem(path, text, exc)]) from None
    try:
        node = loader.get_single_node()
    except yaml.YAMLError as exc:
        raise ConfigError([_yaml_problem(path, text, exc)]) from None
    finally:
        loader.dispose()
    if node is None:
        return defaults(spec)
    unsafe = _unsafe_nodes(node, path)
    if unsafe:
        raise ConfigError(unsafe)
    if not isinstance(node, yaml.MappingNode):
        raise ConfigError([_at(path, node, "expected a mapping at the top level")])
    data, problems = _validate_node(node, spec, "", path, loader, marks)
    if problems:
        raise ConfigError(problems)
    return data
