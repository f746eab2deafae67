"""Plug-in discovery: packages that add nodes (and a vehicle platform) to the engine.

The engine imports no drone code. A plug-in is a module named in the ``btrun.plugins``
entry-point group (btrun's own ``nodes`` package is one). Importing it registers its nodes
in :data:`bt_engine.registry.REGISTRY`; if it defines ``load_rig(path, overrides)`` the CLI
uses it to build the platform (simulator or real drone) a mission flies on.
"""

from __future__ import annotations

import importlib
from importlib import metadata
from types import ModuleType

_loaded: list[ModuleType] | None = None
FALLBACK = ("nodes",)


def load_plugins() -> list[ModuleType]:
    """Import every plug-in once and return the modules (errors propagate: a broken plug-in
    must not be silently ignored)."""
    global _loaded
    if _loaded is not None:
        return _loaded
    names: list[str] = []
    try:
        eps = metadata.entry_points(group="btrun.plugins")
        names = [ep.value for ep in eps]
    except Exception:  # pragma: no cover - very old importlib.metadata
        names = []
    if not names:
        names = list(FALLBACK)
    mods = []
    for name in names:
        try:
            mods.append(importlib.import_module(name))
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise
    _loaded = mods
    return mods


def rig_loader():
    """The first plug-in's ``load_rig`` function, or None if no plug-in provides one."""
    for mod in load_plugins():
        fn = getattr(mod, "load_rig", None)
        if fn is not None:
            return fn
    return None
