"""Simulated AI-deck camera: a hook that asks a renderer for a frame at the camera rate.

The renderer is built by another part of the project; until one is registered, the camera
produces no frames (``poll`` returns None) and the Vehicle's camera health stays "no
samples". A renderer is a callable ``renderer(pose, t_s) -> image`` registered by name with
:func:`register_renderer` and chosen by the rig (``sensors.camera.renderer``), so rig files
never name arbitrary code.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from drivers.types import CameraFrame, Pose

Renderer = Callable[[Pose, float], Any]
RendererFactory = Callable[..., Renderer]

_RENDERERS: dict[str, RendererFactory] = {}


def register_renderer(name: str, factory: RendererFactory) -> None:
    """Make a renderer available to rigs as ``sensors.camera.renderer: <name>``.

    ``factory(world=..., camera=..., rng=...)`` returns the ``renderer(pose, t_s)`` callable.
    """
    _RENDERERS[name] = factory


def renderer_names() -> list[str]:
    """Names of the registered renderers."""
    return sorted(_RENDERERS)


def make_renderer(name: str | None, **kwargs: Any) -> Renderer | None:
    """Build the renderer ``name`` (None or "none" -> no renderer)."""
    if name in (None, "none"):
        return None
    import drivers.sim.renderer  # noqa: F401  (registers the "pallet" renderer)

    if name not in _RENDERERS:
        raise ValueError(f"unknown camera renderer '{name}' (known: {renderer_names()})")
    return _RENDERERS[name](**kwargs)


class SimCamera:
    """Frames at ``rate_hz`` from the renderer, each with its capture time and pose."""

    def __init__(
        self, rate_hz: float = 15.0, renderer: Renderer | None = None, latency_s: float = 0.05
    ) -> None:
        self.rate_hz, self.period_s = rate_hz, 1.0 / rate_hz
        self.renderer = renderer
        self.latency_s = latency_s
        self.stalled = False
        self.index = 0
        self._pending: list[CameraFrame] = []

    def set_renderer(self, renderer: Renderer | None) -> None:
        """Attach (or detach) the renderer."""
        self.renderer = renderer

    def capture(self, t_s: float, pose: Pose) -> None:
        """Render one frame at ``t_s`` if a renderer is attached and the camera runs."""
        if self.renderer is None or self.stalled:
            return
        image = self.renderer(pose, t_s)
        if image is None:
            return
        self.index += 1
        self._pending.append(CameraFrame(image, t_s, pose, self.index))

    def poll(self, now_s: float) -> CameraFrame | None:
        """The newest frame delivered by ``now_s`` (older undelivered ones are skipped)."""
        ready = [f for f in self._pending if f.t_s + self.latency_s <= now_s + 1e-9]
        if not ready:
            return None
        self._pending = [f for f in self._pending if f.t_s + self.latency_s > now_s + 1e-9]
        return ready[-1]
