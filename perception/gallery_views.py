"""A gallery that keeps up: added views, the audit trail, rollbacks.

The :class:`ViewsMixin` half of :class:`perception.gallery.Gallery`: after a confident
identification :meth:`ViewsMixin.update` adds the scan as a view of the side when
:func:`perception.gallery_update.decide` allows it (bounded: the oldest added view is
evicted), :meth:`ViewsMixin.rollback` undoes one, and :meth:`ViewsMixin.history` reads the
``history`` table every change is written to.
"""

from __future__ import annotations

import math
import time
from typing import Any

import cv2
import numpy as np

from perception import gallery_math as gm
from perception.errors import GalleryError
from perception.gallery_match import Match, Thresholds
from perception.gallery_math import block_distances
from perception.gallery_update import UpdateDecision, UpdateRule, decide

#: The latest time a gallery may record (the end of the year 9999), in seconds since 1970.
LATEST_TIME_S = 253_402_300_799.0


def checked_time(value: Any, where: str) -> float:
    """``value`` (a gallery's time column) as seconds since 1970, or :class:`GalleryError`
    saying ``where`` it was if it is not a date (text, NaN, 1e300: a damaged file)."""
    if type(value) in (int, float) and math.isfinite(value) and 0 <= value <= LATEST_TIME_S:
        return float(value)
    raise GalleryError(
        f"{where}: time {value!r:.40} is not a date; the gallery file is damaged (restore a backup)"
    )


def _is_text(v: Any) -> bool:
    return v is None or isinstance(v, str)


def _is_number(v: Any) -> bool:
    return v is None or (type(v) in (int, float) and math.isfinite(v))


#: What each column of a history row must hold (besides ``time``: :func:`checked_time`).
_EVENT_COLUMNS = {
    "event": (lambda v: type(v) is int, "an integer"),
    "identity": (lambda v: isinstance(v, str), "text"),
    "action": (lambda v: isinstance(v, str), "text"),
    "run": (_is_text, "text"),
    "distance": (_is_number, "a number"),
    "margin": (_is_number, "a number"),
    "view": (lambda v: v is None or type(v) is int, "an integer"),
    "note": (_is_text, "text"),
}


def png_bytes(crop: np.ndarray) -> bytes:
    """A crop as PNG bytes, as the gallery stores enrolment and view crops."""
    ok, buf = cv2.imencode(".png", crop)
    if not ok:
        raise GalleryError(f"a crop of shape {np.shape(crop)} cannot be encoded as PNG")
    return buf.tobytes()


class ViewsMixin:
    """Views and history for :class:`perception.gallery.Gallery` (it provides ``conn``,
    ``path``, ``thresholds``, ``matrix()``, ``identities()``, ``_check_vectors()``,
    ``_check_visibility()``, ``_writing()``, ``_event()`` and ``_invalidate()``)."""

    def views(self, identity: str, active_only: bool = True) -> list[dict]:
        """The views added to ``identity``: id, time, run, distance, margin, active."""
        q = "SELECT view_id, added, run, distance, margin, active, evicted_by FROM views "
        q += "WHERE identity = ?" + (" AND active" if active_only else "") + " ORDER BY view_id"
        keys = ("view_id", "added", "run", "distance", "margin", "active", "evicted_by")
        return [dict(zip(keys, r, strict=True)) for r in self.conn.execute(q, (identity,))]

    def history(self, identity: str | None = None) -> list[dict]:
        """The audit trail (oldest first), of one identity or of all; :class:`GalleryError`
        if a row of a damaged file holds what no event can (a time that is not a date)."""
        q = "SELECT event_id, identity, time, action, run, distance, margin, view_id, note "
        q += "FROM history" + (" WHERE identity = ?" if identity else "") + " ORDER BY event_id"
        keys = ("event", "identity", "time", "action", "run", "distance", "margin", "view", "note")
        args = (identity,) if identity else ()
        events = [dict(zip(keys, r, strict=True)) for r in self.conn.execute(q, args)]
        for e in events:  # a damaged file: one line saying which event, not a traceback
            where = f"{self.path}: history event {e['event']!r:.20}"
            e["time"] = checked_time(e["time"], where)
            for key, (ok, want) in _EVENT_COLUMNS.items():
                if not ok(e[key]):
                    raise GalleryError(
                        f"{where}: {key} {e[key]!r:.40} is not {want}; the gallery file is "
                        "damaged (restore a backup)"
                    )
        return events

    def update(
        self,
        match: Match,
        query: np.ndarray,
        visibility: np.ndarray | None = None,
        run: str = "",
        rule: UpdateRule | None = None,
        thresholds: Thresholds | None = None,
        crops: list[np.ndarray] | None = None,
    ) -> UpdateDecision:
        """Add the scan ``query`` (and its three BGR ``crops``, for the texture verifier) as
        a view of ``match.pallet_id`` if ``rule`` finds the answer confident enough
        (:func:`perception.gallery_update.decide`); evict the oldest added view beyond
        ``rule.max_views``. Every change goes to the history."""
        rule = rule or UpdateRule()
        th = thresholds or self.thresholds
        ident = match.pallet_id
        emb = self._check_vectors("update", query)
        vis = self._check_visibility("update", visibility)
        anchor = None
        if match.known and ident in self.identities():
            anchor = self._enrolment_distance(ident, emb, vis)
        decision = decide(match, th, rule, anchor)
        if not decision.update:
            return decision
        note = f"{anchor:.3f} from the enrolment view" if anchor is not None else ""
        args = (match.distance, match.margin, rule.max_views, "add view", note)
        self._insert_view(ident, emb, vis, crops, run, *args)
        return decision

    def add_view(
        self,
        identity: str,
        query: np.ndarray,
        visibility: np.ndarray | None = None,
        crops: list[np.ndarray] | None = None,
        run: str = "",
        note: str = "",
        max_views: int | None = None,
    ) -> int:
        """Add the scan ``query`` as a view of ``identity`` because a person said so (an
        operator's review of an exception), without :func:`perception.gallery_update.decide`:
        the history's ``operator view`` event records ``run`` and ``note`` (who, why), and
        :meth:`rollback` undoes it like any added view. Returns the view id.

        Raises:
            GalleryError: ``identity`` is not enrolled.
        """
        if identity not in self.identities():
            raise GalleryError(f"add view: {identity} is not enrolled in {self.path}")
        emb = self._check_vectors("add view", query)
        vis = self._check_visibility("add view", visibility)
        limit = UpdateRule().max_views if max_views is None else max_views
        return self._insert_view(
            identity, emb, vis, crops, run, None, None, limit, "operator view", note
        )

    def _insert_view(
        self,
        ident: str,
        emb: np.ndarray,
        vis: np.ndarray | None,
        crops: list[np.ndarray] | None,
        run: str,
        distance: float | None,
        margin: float | None,
        max_views: int,
        action: str,
        note: str,
    ) -> int:
        """Insert one view (and its crops) with its history event; evict the oldest active
        views beyond ``max_views``. Returns the view id."""
        now = time.time()
        with self._writing(f"add a view to {ident}"), self.conn:
            cur = self.conn.execute(
                "INSERT INTO views (identity, embeddings, stripes, added, run, distance, margin) "
                "VALUES (?, ?, ?, ?, ?, ?, ?)",
                (
                    ident,
                    emb.tobytes(),
                    vis.tobytes() if vis is not None else None,
                    now,
                    run,
                    distance,
                    margin,
                ),
            )
            view_id = int(cur.lastrowid or 0)
            for b, crop in enumerate(crops or []):
                self.conn.execute(
                    "INSERT INTO view_crops VALUES (?, ?, ?)", (view_id, b, png_bytes(crop))
                )
            self._event(ident, now, action, run, distance, margin, view_id, note)
            active = [
                r[0]
                for r in self.conn.execute(
                    "SELECT view_id FROM views WHERE identity = ? AND active ORDER BY view_id",
                    (ident,),
                )
            ]
            for old in active[: max(0, len(active) - max_views)]:
                self.conn.execute(
                    "UPDATE views SET active = 0, evicted_by = ? WHERE view_id = ?", (view_id, old)
                )
                self._event(ident, now, "evict view", run, view_id=old, note=f"by view {view_id}")
        self._invalidate()
        return view_id

    def _enrolment_distance(self, identity: str, emb: np.ndarray, vis: np.ndarray | None) -> float:
        """Side distance of a scan to ``identity``'s enrolment view alone."""
        ids, enrol = self.matrix()
        i = ids.index(identity)
        if vis is None:
            per = block_distances(emb.astype(np.float64), enrol[i : i + 1].astype(np.float64))
        else:
            row = self.conn.execute(
                "SELECT stripes FROM visibility WHERE identity = ?", (identity,)
            ).fetchone()
            ev = np.frombuffer(row[0], np.float32) if row is not None else None
            ev = ev.reshape(1, *vis.shape) if ev is not None and ev.size == vis.size else None
            per = block_distances(emb, enrol[i : i + 1], vis, ev)
        return float(gm.side_distance(per, gm.block_weights(vis))[0])

    def rollback(self, identity: str, view_id: int | None = None, run: str = "") -> int:
        """Undo an added view of ``identity`` (default: the latest active one): deactivate
        it and restore the views it evicted. Returns the view id rolled back.

        Raises:
            GalleryError: not enrolled, no such active view, or nothing to roll back.
        """
        if identity not in self.identities():
            raise GalleryError(f"rollback: {identity} is not enrolled in {self.path}")
        active = [v["view_id"] for v in self.views(identity)]
        if view_id is None:
            if not active:
                raise GalleryError(f"rollback: {identity} has no added view to roll back")
            view_id = active[-1]
        elif view_id not in active:
            raise GalleryError(f"rollback: {identity} has no active view {view_id} (see history)")
        now = time.time()
        with self._writing(f"roll back view {view_id} of {identity}"), self.conn:
            self.conn.execute("UPDATE views SET active = 0 WHERE view_id = ?", (view_id,))
            back = [
                r[0]
                for r in self.conn.execute(
                    "SELECT view_id FROM views WHERE evicted_by = ?", (view_id,)
                )
            ]
            self.conn.execute(
                "UPDATE views SET active = 1, evicted_by = NULL WHERE evicted_by = ?", (view_id,)
            )
            note = f"restored view {', '.join(map(str, back))}" if back else ""
            self._event(identity, now, "rollback", run, view_id=view_id, note=note)
        self._invalidate()
        return view_id


__all__ = ["ViewsMixin", "png_bytes"]
