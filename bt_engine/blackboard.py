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

Every entry also has a *sequence id*, as in BehaviorTree.CPP (``Blackboard::Entry::
sequence_id``): the number of writes since it was created (0 for an entry that does not
exist). ``SkipUnlessUpdated``, ``WaitValueUpdate`` and ``WasEntryUpdated`` compare it with
the id they saw last. It costs one dictionary update per write, nothing per read or tick.
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

    __slots__ = (
        "prefix",
        "parent",
        "remap",
        "autoremap",
        "root",
        "path",
        "writes",
        "seq",
        "defaults",
        "_store",
    )

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
            #: writes per storage key since the entry was created (the whole mission's)
            self.seq: dict[str, int] = {}
        else:
            self.prefix = f"{parent.prefix}{path}/"
            self.writes = None
            self.seq = parent.seq
        self._store: dict[str, Any] = py_trees.blackboard.Blackboard.storage
        #: a ``_autoremap`` SubTree's ``<TreeNodesModel>`` port defaults: read only while
        #: no scope the name reaches holds the entry (:meth:`get`)
        self.defaults: dict[str, Any] | None = None

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
            found = self._model_default(key)
            if found is not _MISSING:
                return found
            if default is _MISSING:
                raise KeyError(key) from None
            return default

    def has(self, key: str) -> bool:
        """True if ``key`` has a value visible from this scope."""
        return self.full_key(key) in self._store or self._model_default(key) is not _MISSING

    def _model_default(self, key: str) -> Any:
        """The ``<TreeNodesModel>`` default of ``key`` of a ``_autoremap`` SubTree the name
        reaches (the nearest), for an entry no scope holds: BehaviorTree.CPP shares the
        parent's entry under ``_autoremap`` and fails where the parent has none; btrun then
        reads the default the model declares (a write still goes to the parent)."""
        scope: Scope | None = self
        k = key
        while scope is not None and not k.startswith("@"):
            if scope.defaults is not None and k in scope.defaults:
                return scope.defaults[k]
            if scope.parent is None:
                break
            if k in scope.remap:
                k, scope = scope.remap[k], scope.parent
            elif scope.autoremap and not k.startswith("_"):
                scope = scope.parent
            else:
                break
        return _MISSING

    def set(self, key: str, value: Any) -> None:
        """Write ``key`` (creating it in the scope the remapping rules choose)."""
        full = self.full_key(key)
        seq = self.seq
        n = seq.get(full)
        if n is None:  # its first counted write; an entry stored directly (a SubTree's
            n = 1 if full in self._store else 0  # literal port) was written once
        seq[full] = n + 1
        self._store[full] = value
        w = self.root.writes
        if w is not None:
            w[full[len(self.root.prefix) :]] = value

    def unset(self, key: str) -> None:
        """Remove ``key`` if present."""
        full = self.full_key(key)
        self._store.pop(full, None)
        self.seq.pop(full, None)

    def unset_local(self, key: str) -> None:
        """Remove ``key`` only if it is stored in this scope itself, as BehaviorTree.CPP's
        ``Blackboard::unset``: an entry reached through remapping, ``_autoremap`` or
        ``@`` is left alone."""
        full = self.prefix + key
        if full in self._store:
            del self._store[full]
            self.seq.pop(full, None)

    def sequence_id(self, key: str) -> int:
        """Writes to ``key`` since its entry was created; 0 if it does not exist
        (BehaviorTree.CPP's ``sequence_id``)."""
        full = self.full_key(key)
        if full not in self._store:
            return 0
        return self.seq.get(full, 1)

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
        for k in [k for k in self.seq if k.startswith(self.prefix)]:
            del self.seq[k]
