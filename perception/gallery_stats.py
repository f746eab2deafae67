"""What a gallery holds, in a few figures (``btrun gallery stats``), and one page of it.

A site's gallery holds thousands of pallet sides; listing them all is no way to look at
it. :func:`gallery_stats` counts (sides, pallets, added views, crops), names the model
and the thresholds, and says when the file last changed and how big it is;
:func:`page_bounds` cuts the sorted side list into pages for ``btrun gallery list``.
"""

from __future__ import annotations

import math
import os
from typing import Any

#: meta key of the seconds a generated gallery took to build (the demo gallery writes it)
BUILD_SECONDS_KEY = "build_seconds"


def pallet_of(identity: str) -> str:
    """The pallet of a side name: ``103B`` -> ``103``, ``7A`` -> ``7`` (a digit followed by
    one letter); any other name is its own pallet."""
    s = str(identity).strip()
    if len(s) >= 2 and s[-1].isalpha() and s[-2].isdigit():
        return s[:-1]
    return s


def gallery_stats(gallery: Any) -> dict:
    """Figures of an open :class:`perception.gallery.Gallery`: ``sides``, ``pallets``,
    ``views`` (active added views), ``sides_with_crops``, ``model_version``,
    ``max_distance``, ``min_margin``, ``size_bytes`` (None in memory), ``last_update``
    (epoch seconds of the latest enrolment, added view or history event; None if empty),
    ``build_seconds`` (None unless the file was generated) and ``schema``."""
    conn = gallery.conn
    ids = [r[0] for r in conn.execute("SELECT identity FROM entries")]
    one = lambda sql: conn.execute(sql).fetchone()[0]  # noqa: E731
    times = [
        one("SELECT MAX(created) FROM entries"),
        one("SELECT MAX(added) FROM views"),
        one("SELECT MAX(time) FROM history"),
    ]
    meta = dict(conn.execute("SELECT key, value FROM meta").fetchall())
    size = None
    if gallery.path != ":memory:" and os.path.exists(gallery.path):
        size = os.path.getsize(gallery.path)
    build = _number(meta.get(BUILD_SECONDS_KEY))
    return {
        "sides": len(ids),
        "pallets": len({pallet_of(i) for i in ids}),
        "views": one("SELECT COUNT(*) FROM views WHERE active"),
        "sides_with_crops": one("SELECT COUNT(DISTINCT identity) FROM crops"),
        "model_version": gallery.model_version,
        "max_distance": gallery.thresholds.max_distance,
        "min_margin": gallery.thresholds.min_margin,
        "size_bytes": size,
        "last_update": max((t for t in times if _number(t) is not None), default=None),
        "build_seconds": build,
        "schema": meta.get("schema_version"),
    }


def page_bounds(total: int, page: int, per_page: int) -> tuple[int, int, int]:
    """(offset, count, pages) of 1-based ``page`` of ``per_page`` items out of ``total``
    (``ValueError`` for a page beyond the last or a size below 1)."""
    if per_page < 1:
        raise ValueError(f"--per-page must be at least 1, got {per_page}")
    pages = max(1, math.ceil(total / per_page))
    if not 1 <= page <= pages:
        raise ValueError(f"page {page} does not exist: {pages} page(s) of {per_page}")
    offset = (page - 1) * per_page
    return offset, min(per_page, total - offset), pages


def _number(value: Any) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


__all__ = ["BUILD_SECONDS_KEY", "gallery_stats", "page_bounds", "pallet_of"]
