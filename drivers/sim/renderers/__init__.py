"""Camera renderers of the simulator, by name: what ``sensors.camera.renderer`` may say.

A renderer is a callable ``renderer(pose, t_s, previous=None) -> image``; a factory builds one
from ``world=``, ``camera=`` (the rig's ``sensors.camera`` settings) and ``rng=``. Rig files
only ever name an entry of :data:`RENDERERS`, never code. A new renderer is a module in this
package plus one line in the table; tests and plug-ins may add entries with
:func:`register_renderer`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

Renderer = Callable[..., Any]  # renderer(pose, t_s, previous=None) -> image
RendererFactory = Callable[..., Renderer]


def _pallet(**kwargs: Any) -> Renderer:
    from drivers.sim.renderers.pallet import make_pallet_renderer  # torch-free, but cv2-heavy

    return make_pallet_renderer(**kwargs)


#: name -> factory; ``none`` (no camera frames) is not an entry.
RENDERERS: dict[str, RendererFactory] = {
    "pallet": _pallet,  # synthetic AI-deck view of the world's pallets (docs/camera.md)
}


def register_renderer(name: str, factory: RendererFactory) -> None:
    """Add (or replace) the renderer ``name``: ``factory(world=, camera=, rng=)``."""
    RENDERERS[name] = factory


def renderer_names() -> list[str]:
    """Names a rig may give as ``sensors.camera.renderer`` (besides ``none``)."""
    return sorted(RENDERERS)


def make_renderer(name: str | None, **kwargs: Any) -> Renderer | None:
    """Build the renderer ``name`` (None or ``none`` -> no renderer). Raises ValueError."""
    if name in (None, "none"):
        return None
    if name not in RENDERERS:
        raise ValueError(f"unknown camera renderer '{name}' (known: {renderer_names()})")
    return RENDERERS[name](**kwargs)
