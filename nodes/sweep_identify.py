"""The sweep's identifications: a finished place's block views fused and matched against
the gallery (verification against the expected stock first), at once in lock-step or on a
worker thread of their own in real time, so the tick never waits."""

from __future__ import annotations

import queue
import threading
from typing import Any

from nodes.identify import expected_for, identify_described
from nodes.perception_session import PerceptionError, identification_record


class Identifications:
    """Identify finished places: at once (lock-step) or on one worker thread (real time)."""

    #: real time: a place identification waiting longer than this fails the pass, s
    MAX_WAIT_S = 60.0

    def __init__(self, leaf: Any, threaded: bool) -> None:
        self.leaf, self.threaded = leaf, threaded
        self.results: list[tuple[Any, Any, BaseException | None]] = []
        self.pending = 0
        self._lock = threading.Lock()
        self._queue: queue.Queue | None = None
        if threaded:
            self._queue = queue.Queue()
            threading.Thread(target=self._work, name="sweep-identify", daemon=True).start()

    def submit(self, w: Any) -> None:
        """Identify the place ``w`` (its three crops)."""
        if self._queue is None:
            self.results.append(self._identify(w))
            return
        with self._lock:
            self.pending += 1
        self._queue.put(w)

    def _work(self) -> None:
        assert self._queue is not None
        while True:
            w = self._queue.get()
            if w is None:
                return
            out = self._identify(w)
            with self._lock:
                self.results.append(out)
                self.pending -= 1

    def _identify(self, w: Any) -> tuple[Any, Any, BaseException | None]:
        try:
            return w, identify_views(self.leaf, w.ordered_views(), w.name), None
        except BaseException as exc:  # handed to the tick thread
            return w, None, exc

    def done(self) -> list[tuple[Any, Any, BaseException | None]]:
        """The identifications finished since the last call."""
        with self._lock:
            out, self.results = self.results, []
        return out

    def idle(self) -> bool:
        """True when nothing is waiting to be identified."""
        with self._lock:
            return self.pending == 0 and not self.results

    def drain(self) -> list[tuple[Any, Any, BaseException | None]]:
        """Stop the worker; what finished meanwhile."""
        if self._queue is not None:
            self._queue.put(None)
        return self.done()


def identify_views(leaf: Any, place_views: list[list], place: str) -> Any:
    """Embed the views of a place's three blocks (``place_views``: per block its crops,
    best first), average each block's views (:func:`perception.sweep.fuse_views`) and match
    them against the pass's gallery with the gallery's
    thresholds and texture verification, verifying 1:1 first against the pallet the expected
    stock names for ``place`` (:func:`nodes.identify.identify_scan`, as IdentifyPallet
    does); the match. The session
    keeps the identification for the report."""
    from perception.errors import ModelError
    from perception.gallery import GalleryError
    from perception.sweep import fuse_views

    session, embedder, g = leaf.session, leaf.embedder, leaf.gallery
    views = [v for v in place_views if v]
    crops = [v[0] for v in views]
    try:
        desc = embedder.describe([c for v in views for c in v])
        vectors, vis = fuse_views(
            desc.vectors, desc.visibility, [len(v) for v in views], embedder.config.parts
        )
        match = identify_described(
            g,
            vectors,
            vis if embedder.occlusion_aware else None,
            crops,
            g.thresholds,
            expected=expected_for(leaf.ctx, place),
            top_k=5,
        )
    except (GalleryError, ModelError) as exc:
        raise PerceptionError(f"identification at {place}: {exc}") from None
    record = identification_record(
        match, g.thresholds, crops, t_s=leaf.now(), key=f"sweep:{place}", node=leaf.describe()
    )
    record["place"] = place
    session.identifications.append(record)
    return match
