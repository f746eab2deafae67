"""Blackboard scopes with BehaviorTree.CPP remapping rules, stored in py_trees' blackboard.

Every mission instance gets its own namespace in ``py_trees.blackboard.Blackboard.storage``
(``/btrun/<mission>/...``), so several missions (drones) in one process never see each
other's entries. Each SubTree instance gets a child :class:`Scope`:

* ``<SubTree ID="Scan" speed="{scan_speed}"/>``: inside, ``speed`` *is* the parent's
  ``scan_speed`` (reads and writes go through).
* ``<SubTree ID="Scan" speed="0.07"/>``: inside, ``speed`` starts as the text ``"0.07"``.
* ``_autoremap="true"``: any other entry is shared with the parent under the same name,
  except private ones whose name starts with ``_``.
* ``@key`` always means the mission's root scope.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from typing import Any

import py_trees

_MISSING = object()
_counter = itertools.count(1)


class Scope:
    """One blackboard scope (the main tree, or one SubTree instance)."""

    __slots__ = ("prefix", "parent", "remap", "autoremap", "root", "path", "writes", "_store")

    def __init__(
        self,
        path: str,
        parent: Scope | None = None,
        remap: dict[str, str] | None = None,
        autoremap: bool = False,
        namespace: str | None = None,
    ) -> None:
        self.parent = parent
        self.root: Scope = parent.root if parent is not None else self
        self.path = path
        self.remap = dict(remap or {})
        self.autoremap = autoremap
        if parent is None:
            ns = namespace or f"/btrun/mission{next(_counter)}"
            self.prefix = ns + "/"
            #: entries written since the last :meth:`drain_writes` (root scope only)
            self.writes: dict[str, Any] | None = {}
        else:
            self.prefix = f"{parent.prefix}{path}/"
            self.writes = None
        self._store: dict[str, Any] = py_trees.blackboard.Blackboard.storage

    # -- resolution -------------------------------------------------------------
    def _owner(self, key: str) -> tuple[Scope, str]:
        scope, k = self, key
        while True:
            if k.startswith("@"):
                return scope.root, k[1:]
            if scope.prefix + k in scope._store:
                return scope, k
            if scope.parent is None:
                return scope, k
            if k in scope.remap:
                k = scope.remap[k]
                scope = scope.parent
            elif scope.autoremap and not k.startswith("_"):
                scope = scope.parent
            else:
                return scope, k

    def full_key(self, key: str) -> str:
        """The py_trees storage key that ``key`` resolves to from this scope."""
        owner, k = self._owner(key)
        return owner.prefix + k

    def display_key(self, key: str) -> str:
        """A readable name for ``key`` relative to the mission root (``Scan/speed``)."""
        return self.full_key(key)[len(self.root.prefix) :]

    # -- access -----------------------------------------------------------------
    def get(self, key: str, default: Any = _MISSING) -> Any:
        """Return the value of ``key``; raise KeyError if missing and no default is given."""
        full = self.full_key(key)
        try:
            return self._store[full]
        except KeyError:
            if default is _MISSING:
                raise KeyError(key) from None
            return default

    def has(self, key: str) -> bool:
        """True if ``key`` has a value visible from this scope."""
        return self.full_key(key) in self._store

    def set(self, key: str, value: Any) -> None:
        """Write ``key`` (creating it in the scope the remapping rules choose)."""
        full = self.full_key(key)
        self._store[full] = value
        w = self.root.writes
        if w is not None:
            w[full[len(self.root.prefix) :]] = value

    def unset(self, key: str) -> None:
        """Remove ``key`` if present."""
        self._store.pop(self.full_key(key), None)

    def local_items(self) -> Iterator[tuple[str, Any]]:
        """Entries stored directly in this scope (not in child scopes)."""
        n = len(self.prefix)
        for k, v in list(self._store.items()):
            if k.startswith(self.prefix) and "/" not in k[n:]:
                yield k[n:], v

    def all_items(self) -> dict[str, Any]:
        """Every entry of the whole mission (this scope's root), keyed by display name."""
        root = self.root
        n = len(root.prefix)
        return {k[n:]: v for k, v in list(self._store.items()) if k.startswith(root.prefix)}

    def drain_writes(self) -> dict[str, Any]:
        """Return and forget the writes since the last call (for the tick log)."""
        root = self.root
        out = root.writes or {}
        root.writes = {}
        return out

    def clear(self) -> None:
        """Delete every entry of this scope and its child scopes from py_trees' storage."""
        for k in [k for k in self._store if k.startswith(self.prefix)]:
            del self._store[k]
