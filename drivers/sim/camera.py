"""Simulated AI-deck camera: a hook that asks a renderer for a frame at the camera rate.

Without a renderer the camera produces no frames (``poll`` returns None) and the Vehicle's
camera health stays "no samples". A renderer is a callable ``renderer(pose, t_s,
previous=None) -> image`` named in :data:`drivers.sim.renderers.RENDERERS` and chosen by the
rig (``sensors.camera.renderer``), so rig files never name arbitrary code; ``previous`` is
the ``(t_s, pose)`` of the frame before (for motion blur).

Rendering is lazy: a frame is captured (time, pose) at the camera rate, delivered after the
latency, and its image is rendered only when someone reads ``frame.image``. A mission that
flies without looking at the camera pays nothing for it; a perception leaf pays for exactly
the frames it consumes. The result is the same image either way for a given run (the noise
generator advances only for rendered frames, in delivery order, which the seed fixes).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from drivers.sim.renderers import Renderer
from drivers.vehicle.types import Pose


class LazyCameraFrame:
    """A frame shaped like :class:`~drivers.vehicle.types.CameraFrame` (``image``, ``t_s``, ``pose``,
    ``index``, ``meta``) whose image is rendered on the first read of ``image``."""

    __slots__ = ("_image", "_render", "t_s", "pose", "index", "meta")

    #: one render at a time: in real time the perception worker renders on its own thread,
    #: and a second reader of the same frame must wait for the image, not read None
    _lock = threading.Lock()

    def __init__(
        self, render: Callable[[], Any], t_s: float, pose: Pose, index: int, meta: dict
    ) -> None:
        self._image: Any = None
        self._render: Callable[[], Any] | None = render
        self.t_s, self.pose, self.index, self.meta = t_s, pose, index, meta

    @property
    def image(self) -> Any:
        """The frame's image (rendered now if it was not yet)."""
        if self._render is not None:
            with LazyCameraFrame._lock:
                if self._render is not None:
                    self._image = self._render()
                    self._render = None
        return self._image

    @property
    def rendered(self) -> bool:
        """True once the image exists."""
        return self._render is None

    def __repr__(self) -> str:
        return f"LazyCameraFrame(index={self.index}, t_s={self.t_s:.3f}, rendered={self.rendered})"


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
        self.rendered = 0  # frames whose image was actually rendered
        self._pending: list[LazyCameraFrame] = []
        self._previous: tuple[float, Pose] | None = None

    def set_renderer(self, renderer: Renderer | None) -> None:
        """Attach (or detach) the renderer."""
        self.renderer = renderer

    def capture(self, t_s: float, pose: Pose) -> None:
        """Capture one frame at ``t_s`` (rendered when read) if a renderer is attached and
        the camera runs."""
        if self.renderer is None or self.stalled:
            self._previous = None
            return
        renderer, previous = self.renderer, self._previous
        self._previous = (t_s, pose)

        def render() -> Any:
            self.rendered += 1
            return renderer(pose, t_s, previous=previous)

        self.index += 1
        self._pending.append(LazyCameraFrame(render, t_s, pose, self.index, {"format": "bayer_bg"}))

    def poll(self, now_s: float) -> LazyCameraFrame | None:
        """The newest frame delivered by ``now_s`` (older undelivered ones are skipped)."""
        ready = [f for f in self._pending if f.t_s + self.latency_s <= now_s + 1e-9]
        if not ready:
            return None
        self._pending = [f for f in self._pending if f.t_s + self.latency_s > now_s + 1e-9]
        return ready[-1]
