"""Mission files in, mission files out: the one module that knows both formats.

:mod:`bt_engine.xml_io` and :mod:`bt_engine.yaml_io` (writing: :mod:`bt_engine.yaml_writer`)
each read and write one format and know nothing of each other; an ``<include>`` (XML) or
``include:`` (YAML) of either format is resolved here (:class:`Includes`) and handed to the
right loader. :func:`load_spec` reads a mission file of either format, :func:`convert_file`
writes one format from the other.

An include may only read files inside the main mission file's folder (and its subfolders)
or inside an *include path* (``load_spec(path, include_paths=[...])``, ``btrun ...
--include-path DIR``); symbolic links are resolved before the check, so a mission cannot read
``/etc/passwd`` or ``/proc/self/environ`` through an include.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
from collections.abc import Iterable, Iterator

from bt_engine.files import read_text, write_output
from bt_engine.registry import Registry
from bt_engine.spec import Loc, MissionSpec, Problem
from bt_engine.validate import validate
from bt_engine.xml_io import dump_xml, merge_xml
from bt_engine.xml_io import load_xml as _load_xml
from bt_engine.yaml_io import load_yaml as _load_yaml
from bt_engine.yaml_io import merge_yaml
from bt_engine.yaml_writer import dump_yaml

#: Deepest chain of includes.
MAX_INCLUDE_DEPTH = 20


#: Include paths used when a loader is given none (``btrun --include-path`` sets them for
#: the command it runs: see :func:`default_include_paths`).
_DEFAULT_INCLUDE_PATHS: contextvars.ContextVar[tuple[str, ...]] = contextvars.ContextVar(
    "btrun_include_paths", default=()
)


@contextlib.contextmanager
def default_include_paths(folders: Iterable[str]) -> Iterator[None]:
    """Within the ``with`` block, loaders called without ``include_paths`` use ``folders``."""
    token = _DEFAULT_INCLUDE_PATHS.set(tuple(folders))
    try:
        yield
    finally:
        _DEFAULT_INCLUDE_PATHS.reset(token)


def allowed_folders(path: str, include_paths: Iterable[str] | None = None) -> tuple[str, ...]:
    """The folders the includes of the mission ``path`` may read from (with subfolders): the
    mission's own folder, then ``include_paths`` (default: :func:`default_include_paths`),
    symbolic links resolved."""
    extra = _DEFAULT_INCLUDE_PATHS.get() if include_paths is None else include_paths
    folders = [os.path.dirname(os.path.abspath(path)), *extra]
    return tuple(dict.fromkeys(os.path.realpath(f) for f in folders))


def _inside(path: str, folder: str) -> bool:
    try:
        return os.path.commonpath([path, folder]) == folder
    except ValueError:  # another drive (Windows)
        return False


def merge_file(
    path: str, text: str, spec: MissionSpec, stack: tuple[str, ...], include: Includes
) -> None:
    """Load ``path`` (read into ``text``) into ``spec`` with the loader of its format."""
    if path.endswith((".yaml", ".yml")):
        merge_yaml(path, text, spec, stack, include)
    else:
        merge_xml(path, text, spec, stack, include)


class Includes:
    """Resolves the includes of one mission, only inside ``folders`` (see
    :func:`allowed_folders`); called as ``include(ref, loc, including, spec, stack)``."""

    def __init__(self, folders: tuple[str, ...]) -> None:
        self.folders = folders
        #: files merged already: two libraries that include one helper read it once (its
        #: trees were "defined twice", at the same place)
        self.merged: set[str] = set()

    def __call__(
        self, ref: str, loc: Loc, including: str, spec: MissionSpec, stack: tuple[str, ...]
    ) -> None:
        """Resolve the include ``ref`` written at ``loc`` in the file ``including`` (relative
        to it) and merge it into ``spec``; loops, depth, files outside the allowed folders and
        missing files become problems."""
        if "\0" in ref:  # no file name holds one (and os.path would raise)
            spec.load_problems.append(Problem(loc, "include: a file path cannot hold a NUL byte"))
            return
        full = os.path.normpath(os.path.join(os.path.dirname(including), ref))
        real = os.path.realpath(full)
        if real in {os.path.realpath(s) for s in stack}:
            chain = " -> ".join(os.path.basename(s) for s in stack) + f" -> {ref}"
            spec.load_problems.append(Problem(loc, f"include loop: {chain}"))
            return
        if not any(_inside(real, f) for f in self.folders):
            shown = ref if real == ref else f"{ref} ({real})"
            spec.load_problems.append(
                Problem(
                    loc,
                    f"include outside the mission folder: {shown} (allowed: "
                    f"{', '.join(self.folders)}; add --include-path)",
                )
            )
            return
        if len(stack) > MAX_INCLUDE_DEPTH:
            spec.load_problems.append(
                Problem(loc, f"includes nested more than {MAX_INCLUDE_DEPTH} deep")
            )
            return
        if not os.path.exists(full):
            spec.load_problems.append(
                Problem(
                    loc,
                    f"included file not found: {full} (a path is read from the including "
                    "file's folder, as BehaviorTree.CPP reads it; --include-path allows a "
                    "folder, it is not searched)",
                )
            )
            return
        if real in self.merged:
            return
        self.merged.add(real)
        spec.includes.append(full)
        text = read_text(full, spec.load_problems, loc)
        if text is not None:
            merge_file(full, text, spec, stack + (os.path.abspath(full),), self)


def load_xml(
    path: str, text: str | None = None, include_paths: Iterable[str] | None = None
) -> MissionSpec:
    """Load an XML mission (includes of either format resolved, inside the mission's folder
    and ``include_paths``)."""
    return _load_xml(path, text, Includes(allowed_folders(path, include_paths)))


def load_yaml(
    path: str, text: str | None = None, include_paths: Iterable[str] | None = None
) -> MissionSpec:
    """Load a YAML mission (includes of either format resolved, inside the mission's folder
    and ``include_paths``)."""
    return _load_yaml(path, text, Includes(allowed_folders(path, include_paths)))


def load_spec(path: str, include_paths: Iterable[str] | None = None) -> MissionSpec:
    """Read a mission file (``.xml``, ``.yaml``/``.yml``) into a spec (problems kept inside).

    Includes may read files in the mission's folder (and below) and in ``include_paths``
    (default: those of :func:`default_include_paths`, normally none).
    """
    ext = os.path.splitext(path)[1].lower()
    if ext in (".yaml", ".yml"):
        return load_yaml(path, include_paths=include_paths)
    if ext != ".xml" and os.path.exists(path):
        spec = MissionSpec(file=path)
        spec.load_problems.append(
            Problem(
                Loc(path, 1, 1), f"unknown mission file type '{ext}' (expected .xml, .yaml or .yml)"
            )
        )
        return spec
    if not os.path.exists(path):
        spec = MissionSpec(file=path)
        spec.load_problems.append(
            Problem(Loc(path, 1, 1), f"mission file not found{_missing_hint(path)}")
        )
        return spec
    return load_xml(path, include_paths=include_paths)


def _missing_hint(path: str) -> str:
    """`` (did you mean 'missions/square.xml'?)`` for a mission path that does not exist:
    the closest mission file by name in its folder or in ``missions/`` of that folder;
    empty if none is close."""
    import difflib

    folder = os.path.dirname(path) or "."
    found: dict[str, str] = {}
    for where in (folder, os.path.join(folder, "missions")):
        try:
            names = sorted(os.listdir(where))
        except OSError:
            continue
        for name in names:
            if name.lower().endswith((".xml", ".yaml", ".yml")):
                shown = os.path.normpath(os.path.join(where, name))
                found.setdefault(name, shown)
                found.setdefault(os.path.splitext(name)[0], shown)
    close = difflib.get_close_matches(os.path.basename(path), list(found), n=1, cutoff=0.75)
    return f" (did you mean '{found[close[0]]}'?)" if close else ""


def check_mission(
    path: str,
    registry: Registry,
    include_paths: Iterable[str] | None = None,
    warnings: list[Problem] | None = None,
) -> tuple[MissionSpec, list[Problem]]:
    """Load and validate ``path``: the spec and its errors (warnings appended to
    ``warnings`` if given)."""
    spec = load_spec(path, include_paths)
    return spec, validate(spec, registry, warnings)


def convert_file(
    src: str,
    dst: str,
    registry: Registry | None = None,
    include_paths: Iterable[str] | None = None,
) -> list[Problem]:
    """Convert a mission between XML and YAML (the format of ``dst`` by its extension).

    Nothing is written if ``src`` has load problems; they are returned. Returns ``[]`` on
    success.
    """
    spec = load_spec(src, include_paths)
    if spec.load_problems:
        return sorted(spec.load_problems, key=lambda p: (p.loc.file, p.loc.line, p.loc.col))
    ext = os.path.splitext(dst)[1].lower()
    if ext in (".yaml", ".yml"):
        text = dump_yaml(spec, registry)
    elif ext == ".xml":
        roots = [r for t in spec.trees.values() for r in [t.root, *t.extra_roots] if r]
        for holder in [spec, *spec.trees.values(), *(n for r in roots for n in r.walk())]:
            holder.comments = [_xml_comment(c) for c in holder.comments]
        text = dump_xml(spec)
    else:
        return [
            Problem(Loc(dst, 0, 0), f"unknown output type '{ext}' (expected .xml, .yaml or .yml)")
        ]
    why = write_output(dst, text)
    return [Problem(Loc(dst, 0, 0), why)] if why else []


def _xml_comment(text: str) -> str:
    """XML comments may not contain ``--`` (common in YAML comments such as ``# --- x ---``)."""
    while "--" in text:
        text = text.replace("--", "- -")
    return text
