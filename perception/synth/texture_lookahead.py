"""Quad textures made ahead of need on a worker thread (the renderer's texture look-ahead).

:func:`perception.synth.render.render_scene` with ``lookahead_m`` > 0 queues the untextured
quads that face the camera and lie in front of it, but are not in the frame yet
(:func:`_look_ahead`), so the second core makes their textures while the first draws; every
drawing thread makes sure a quad's texture is made before it draws it (``_TEXTURES.ready``).
A texture is a pure function of its quad, so who makes it, and when, changes no pixel.
"""

from __future__ import annotations

import atexit
import os
import threading
import time
from collections import deque

import numpy as np

from perception.synth.scene import Quad


class _Textures:
    """Quad textures made ahead of need on one worker thread (:func:`render_scene`'s
    ``lookahead_m``), so the second core makes them while the first draws.

    A quad's texture is a pure function of the quad (made on first use, deterministically:
    :attr:`perception.synth.scene.Quad.levels`), so who makes it, and when, changes no pixel.
    Each quad is made once: whoever starts it (the worker or a drawing thread) registers it,
    and a drawing thread that needs a texture being made waits for it."""

    def __init__(self) -> None:
        self._reset()
        # a forked child has no worker: it starts afresh (what was being made is made again)
        os.register_at_fork(after_in_child=self._reset)

    def _reset(self) -> None:
        self._lock = threading.Condition(threading.Lock())
        self._making: dict[int, threading.Event] = {}  # id(quad) -> set when made
        self._queue: deque[Quad] = deque()
        self._queued: set[int] = set()
        self._thread: threading.Thread | None = None
        self._closed = False
        #: time.monotonic() when a texture was last made (on any thread), None before any:
        #: a lock-step tick's progress
        self.last_made: float | None = None

    def close(self, timeout_s: float = 10.0) -> None:
        """Drop what is queued and let the worker finish the texture it is making (at the
        interpreter's exit: a daemon thread still inside OpenCV when Python finalises is
        ended from within OpenCV's C++ frames, and the process aborts with "terminate
        called without an active exception" after its work is done). Later wants are
        ignored; drawing threads still make what they need themselves."""
        with self._lock:
            self._closed = True
            self._queue.clear()
            self._queued.clear()
            self._lock.notify_all()
            thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout_s)

    def ready(self, quad: Quad) -> None:
        """Make sure ``quad``'s texture is made (here, or by the worker: then wait)."""
        if not callable(quad.texture):
            return
        with self._lock:
            event = self._making.get(id(quad))
            mine = event is None and callable(quad.texture)
            if mine:
                event = self._making[id(quad)] = threading.Event()
        if mine:
            self._make(quad, event)
        elif event is not None:
            event.wait()
        quad.levels  # noqa: B018  (made here if the worker could not)

    def want(self, quads: list[Quad]) -> None:
        """Queue ``quads`` (nearest first) to be made on the worker thread."""
        with self._lock:
            if self._closed:
                return
            for q in quads:
                if id(q) not in self._queued and id(q) not in self._making and callable(q.texture):
                    self._queue.append(q)
                    self._queued.add(id(q))
            if self._queue:
                if self._thread is None:
                    self._thread = threading.Thread(
                        target=self._run, name="texture-lookahead", daemon=True
                    )
                    self._thread.start()
                self._lock.notify()

    def _make(self, quad: Quad, event: threading.Event) -> None:
        try:
            quad.levels  # noqa: B018
            self.last_made = time.monotonic()
        finally:
            with self._lock:
                self._making.pop(id(quad), None)
            event.set()

    def _run(self) -> None:
        while True:
            with self._lock:
                while not self._queue and not self._closed:
                    self._lock.wait()
                if self._closed:
                    return
                quad = self._queue.popleft()
                self._queued.discard(id(quad))
                if id(quad) in self._making or not callable(quad.texture):
                    continue
                event = self._making[id(quad)] = threading.Event()
            try:
                self._make(quad, event)
            except Exception:  # noqa: BLE001 - a drawing thread makes it again and raises
                pass


_TEXTURES = _Textures()
atexit.register(_TEXTURES.close)  # before Python finalises: no worker left inside OpenCV


def last_texture_made() -> float | None:
    """When (``time.monotonic()``) this process last made a quad texture (a pallet's relief
    face, about 0.1 s each: work that only the world's size bounds, each face once); None
    before the first."""
    return _TEXTURES.last_made


def _look_ahead(objects: list[Quad], near: np.ndarray, rel: np.ndarray, reach_m: float) -> None:
    """Queue the untextured quads of ``near`` (facing the camera, in front of it, not in
    this frame) within ``reach_m`` of the camera for the texture worker, nearest first."""
    idx = np.flatnonzero(near)
    if not len(idx):
        return
    d2 = np.sum(rel[idx] ** 2, axis=1)
    close = d2 < reach_m * reach_m
    idx, d2 = idx[close], d2[close]
    want = [objects[i] for i in idx[np.argsort(d2, kind="stable")].tolist()]
    want = [q for q in want if callable(q.texture)]
    if want:
        _TEXTURES.want(want)
