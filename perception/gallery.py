"""The gallery of enrolled pallets: an SQLite file (or a PostgreSQL schema) of block
embeddings, and matching.

One entry per enrolled pallet side (``"3A"``): the three block embeddings (left to right),
optionally their stripe visibilities, the model version that computed them, the time, and
the source crops (PNG). Matching follows the reference mission: for each entry, the mean of
the three block-to-block distances; the smallest mean wins. On top of that the gallery
reports the runner-up and the margin between them, and answers ``"unknown"`` when the best
distance is too large or the margin too small (thresholds calibrated on a validation set:
see ``docs/perception.md``). Stripes hidden in either crop count less
(:mod:`perception.gallery_math`).

A gallery that keeps up: after a confident identification, :meth:`Gallery.update` may add
the scan as another view of the side (:mod:`perception.gallery_update` decides; a bounded
number of views, the oldest evicted); matching then takes, block by block, the closest
view. Every enrolment, added view, eviction, rollback and removal is written to the file's
``history`` (:meth:`Gallery.history`); :meth:`Gallery.rollback` undoes an added view.

Safety of the file:

* every write is one SQLite transaction, so a process killed during an enrolment leaves the
  previous gallery intact (SQLite's journal rolls the half-written transaction back);
* the file records the model version; opening it with another model is refused, because
  embeddings of two models are not comparable;
* a damaged file is detected (``PRAGMA quick_check``) and reported, never silently used;
* a file of an older schema (before views and history, or before view crops) is upgraded
  in place when opened (:mod:`perception.gallery_schema`).
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
import time
import unicodedata
from collections.abc import Iterator
from typing import Any

import numpy as np

from perception.errors import GalleryError
from perception.gallery_match import Match, MatchingMixin, Thresholds, _Rows
from perception.gallery_math import BLOCKS, block_distances
from perception.gallery_pg import connect_gallery, is_gallery_url, shown
from perception.gallery_schema import (
    READABLE_SCHEMAS,
    SCHEMA_VERSION,
    TABLES,
    check_contents,
    upgrade,
    write_schema,
)
from perception.gallery_update import UpdateDecision, UpdateRule
from perception.gallery_views import ViewsMixin, checked_time
from store.db import db_errors

#: the longest identity a gallery holds (an expected stock's pallet names are held to it)
MAX_IDENTITY_CHARS = 64


def identity_problem(identity: str) -> str | None:
    """Why ``identity`` cannot name a pallet side (empty or longer than
    :data:`MAX_IDENTITY_CHARS`, a control character or line break), else None.

    A WMS's own ids are kept as they are, ``PAL/2026/0001`` included: no identity names a
    file or a URL (``btrun gallery export`` names its files with
    :func:`nodes.gallery.cli.crop_file_stem`)."""
    if not isinstance(identity, str) or not identity or len(identity) > MAX_IDENTITY_CHARS:
        return f"identity must be 1-{MAX_IDENTITY_CHARS} characters, got {identity!r:.80}"
    bad = next(
        (c for c in identity if unicodedata.category(c) in ("Cc", "Zl", "Zp")),
        None,
    )
    if bad is not None:
        return f"identity {identity!r:.80} holds a control character or line break ({bad!r})"
    return None


class Gallery(MatchingMixin, ViewsMixin):
    """An SQLite gallery file bound to one embedding model version.

    >>> g = Gallery.create(":memory:", model_version="pcb-small-v1", dim=4)
    >>> g.enrol("1A", np.eye(3, 4, dtype=np.float32))
    >>> g.identities()
    ['1A']
    """

    def __init__(self, conn: sqlite3.Connection, path: str, model_version: str, dim: int) -> None:
        self.conn, self.path = conn, path
        self.model_version, self.dim = model_version, dim
        self.thresholds = self._load_thresholds()
        self._cache: tuple[list[str], np.ndarray] | None = None
        self._rows: dict[int, _Rows] = {}
        self._grey: dict[str, list[list[np.ndarray]]] | None = None

    # -- opening -------------------------------------------------------------------------
    @classmethod
    def create(cls, path: str, model_version: str, dim: int, exist_ok: bool = False) -> Gallery:
        """Create a new, empty gallery file for ``model_version`` embeddings of size ``dim``
        (``postgresql://...#NAME``: a gallery in PostgreSQL, :mod:`perception.gallery_pg`)."""
        if is_gallery_url(path):
            return cls._create_pg(path, model_version, dim, exist_ok)
        if path != ":memory:" and os.path.exists(path):
            if not exist_ok:
                raise GalleryError(f"{path}: a gallery already exists (remove it or open it)")
            return cls.open(path, model_version)
        if path == ":memory:":
            conn = _connect(path)
            write_schema(conn, model_version, dim)
            return cls(conn, path, model_version, dim)
        # Built under a temporary name, then renamed: a process killed while creating leaves
        # no half-made gallery behind (the next create or open sees no file at all).
        folder = os.path.dirname(os.path.abspath(path))
        tmp = os.path.join(folder, f".{os.path.basename(path)}.{os.getpid()}.creating")
        try:
            if os.path.exists(tmp):
                os.remove(tmp)
            conn = _connect(tmp)
            write_schema(conn, model_version, dim)
            conn.close()
            os.replace(tmp, path)
        except (OSError, sqlite3.Error) as exc:
            if os.path.exists(tmp):
                os.remove(tmp)
            raise GalleryError(
                f"{path}: cannot create the gallery ({exc}): check that the folder exists "
                "and is writable"
            ) from None
        return cls.open(path, model_version)

    @classmethod
    def open(cls, path: str, model_version: str | None = None) -> Gallery:
        """Open an existing gallery; refuse a damaged file or one of another model version;
        upgrade a schema-1 file in place. ``postgresql://...#NAME``: a gallery in
        PostgreSQL (:mod:`perception.gallery_pg`)."""
        if is_gallery_url(path):
            conn, tables = connect_gallery(path)
            return cls._checked(conn, shown(path), tables, model_version)
        if not os.path.exists(path):
            raise GalleryError(
                f"{path}: no gallery file (enrol pallets first: btrun gallery enrol)"
            )
        try:
            conn = _connect(path)
            ok = conn.execute("PRAGMA quick_check").fetchone()[0]
            if ok != "ok":
                raise GalleryError(f"{path}: the gallery file is damaged ({ok}); restore a backup")
            tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master")}
        except sqlite3.DatabaseError as exc:
            raise GalleryError(f"{path}: not a readable gallery file ({exc})") from None
        return cls._checked(conn, path, tables, model_version)

    @classmethod
    def _checked(cls, conn: Any, path: str, tables: set[str], model_version: str | None) -> Gallery:
        """The gallery on ``conn`` once its tables, metadata, schema and vectors pass."""
        if not tables and is_gallery_url(path):
            conn.close()
            raise GalleryError(
                f"{path}: no such gallery in the store (enrol pallets first: btrun gallery "
                "enrol NAME SIDE --store URL)"
            )
        try:
            missing = sorted(TABLES[1] - tables)
            if missing:
                raise GalleryError(
                    f"{path}: not a complete btrun gallery (table {', '.join(missing)} "
                    "missing); restore a backup or enrol into a new file"
                )
            meta = dict(conn.execute("SELECT key, value FROM meta").fetchall())
        except db_errors() as exc:
            what = "gallery" if is_gallery_url(path) else "gallery file"
            raise GalleryError(f"{path}: not a readable {what} ({exc})") from None
        try:
            schema = int(meta["schema_version"])
            stored_version = meta["model_version"]
            dim = int(meta["dim"])
        except (KeyError, ValueError):
            raise GalleryError(f"{path}: not a btrun gallery (metadata missing)") from None
        if schema not in READABLE_SCHEMAS:
            raise GalleryError(
                f"{path}: gallery schema {schema}, this btrun reads {SCHEMA_VERSION} "
                f"(and upgrades 1); use the btrun that wrote it"
            )
        if dim <= 0 or dim > 65536:
            raise GalleryError(f"{path}: embedding size {dim} in its metadata is not valid")
        if TABLES[schema] - tables:
            missing = ", ".join(sorted(TABLES[schema] - tables))
            raise GalleryError(f"{path}: not a complete btrun gallery (table {missing} missing)")
        if schema < SCHEMA_VERSION:
            _upgrade(conn, path, schema)
        problem = check_contents(conn, dim)
        if problem:
            raise GalleryError(f"{path}: {problem}")
        _parse_thresholds(meta, path)
        if model_version is not None and stored_version != model_version:
            raise GalleryError(
                f"{path}: written by model '{stored_version}', but the embedder is "
                f"'{model_version}'; embeddings of different models cannot be compared: "
                "re-enrol the pallets with this model"
            )
        return cls(conn, path, stored_version, dim)

    @classmethod
    def _create_pg(cls, spec: str, model_version: str, dim: int, exist_ok: bool) -> Gallery:
        conn, tables = connect_gallery(spec, create=True)
        if tables:
            conn.close()
            if not exist_ok:
                raise GalleryError(
                    f"{shown(spec)}: a gallery already exists (remove it or open it)"
                )
            return cls.open(spec, model_version)
        try:
            write_schema(conn, model_version, dim)  # one transaction: all tables or none
        except db_errors() as exc:
            conn.close()
            raise GalleryError(f"{shown(spec)}: cannot create the gallery ({exc})") from None
        conn.close()
        return cls.open(spec, model_version)

    def close(self) -> None:
        """Close the file."""
        self.conn.close()

    def __enter__(self) -> Gallery:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- writing ---------------------------------------------------------------------------
    def enrol(
        self,
        identity: str,
        embeddings: np.ndarray,
        crops_png: list[bytes] | None = None,
        source: str = "",
        replace: bool = True,
        visibility: np.ndarray | None = None,
        run: str = "",
    ) -> None:
        """Add (or replace) ``identity`` with its three block embeddings (and, optionally,
        their stripe visibilities (3, parts)), in one transaction. Replacing drops the
        side's added views (a fresh start, recorded in the history)."""
        emb = self._check_vectors(f"enrol {identity}", embeddings)
        vis = self._check_visibility(f"enrol {identity}", visibility)
        why = identity_problem(identity)
        if why is not None:
            raise GalleryError(f"enrol: {why}")
        with self._writing(f"enrol {identity}"), self.conn:  # one transaction: all or none
            exists = self.conn.execute(
                "SELECT 1 FROM entries WHERE identity = ?", (identity,)
            ).fetchone()
            if exists and not replace:
                raise GalleryError(f"enrol: {identity} is already enrolled")
            self.conn.execute("DELETE FROM entries WHERE identity = ?", (identity,))
            now = time.time()
            self.conn.execute(
                "INSERT INTO entries VALUES (?, ?, ?, ?)", (identity, emb.tobytes(), now, source)
            )
            if vis is not None:
                self.conn.execute("INSERT INTO visibility VALUES (?, ?)", (identity, vis.tobytes()))
            for i, png in enumerate(crops_png or []):
                self.conn.execute("INSERT INTO crops VALUES (?, ?, ?)", (identity, i, png))
            self._event(identity, now, "re-enrol" if exists else "enrol", run, note=source)
        self._invalidate()

    def remove(self, identity: str) -> bool:
        """Remove ``identity`` (and its views); return False if it was not enrolled."""
        with self._writing(f"remove {identity}"), self.conn:
            n = self.conn.execute("DELETE FROM entries WHERE identity = ?", (identity,)).rowcount
            if n:
                self._event(identity, time.time(), "remove")
        self._invalidate()
        return n > 0

    def set_thresholds(self, thresholds: Thresholds) -> None:
        """Store the "unknown" thresholds (calibrated on a validation set) in the file."""
        with self._writing("set thresholds"), self.conn:
            self.conn.executemany(
                "INSERT INTO meta VALUES (?, ?) ON CONFLICT (key) DO UPDATE SET value = excluded.value",
                [
                    ("max_distance", repr(thresholds.max_distance)),
                    ("min_margin", repr(thresholds.min_margin)),
                ],
            )
        self.thresholds = thresholds

    def _load_thresholds(self) -> Thresholds:
        meta = dict(self.conn.execute("SELECT key, value FROM meta").fetchall())
        return _parse_thresholds(meta, self.path)

    def _check_vectors(self, what: str, embeddings: np.ndarray) -> np.ndarray:
        emb = np.asarray(embeddings, dtype=np.float32)
        if emb.shape != (BLOCKS, self.dim):
            raise GalleryError(
                f"{what}: expected embeddings of shape {(BLOCKS, self.dim)}, got {emb.shape}"
            )
        if not np.all(np.isfinite(emb)):
            raise GalleryError(f"{what}: embeddings contain NaN or infinity")
        return emb

    def _check_visibility(self, what: str, visibility: np.ndarray | None) -> np.ndarray | None:
        if visibility is None:
            return None
        vis = np.asarray(visibility, dtype=np.float32)
        ok = vis.ndim == 2 and vis.shape[0] == BLOCKS and vis.shape[1] >= 1
        if not ok or self.dim % vis.shape[1] or not np.all((vis >= 0) & (vis <= 1)):
            raise GalleryError(
                f"{what}: visibility must be (3, parts) values in 0..1 with parts dividing "
                f"{self.dim}, got {vis.shape}"
            )
        return vis

    @contextlib.contextmanager
    def _writing(self, what: str) -> Iterator[None]:
        """Turn SQLite's write errors into one clear :class:`GalleryError` (nothing written:
        the transaction is rolled back)."""
        try:
            yield
        except db_errors() as exc:
            hint = (
                "the file or its folder is read-only: check the permissions"
                if "readonly" in str(exc) or "read-only" in str(exc)
                else "the file may be damaged or locked by another process"
            )
            raise GalleryError(f"{self.path}: cannot {what} ({exc}); {hint}") from None

    def _event(
        self,
        identity: str,
        when: float,
        action: str,
        run: str = "",
        distance: float | None = None,
        margin: float | None = None,
        view_id: int | None = None,
        note: str = "",
    ) -> int:
        cur = self.conn.execute(
            "INSERT INTO history (identity, time, action, run, distance, margin, view_id, note) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            (identity, when, action, run, distance, margin, view_id, note),
        )
        return int(cur.lastrowid or 0)

    def _invalidate(self) -> None:
        self._cache = None
        self._rows.clear()
        self._grey = None

    # -- reading ---------------------------------------------------------------------------
    def identities(self) -> list[str]:
        """Enrolled identities, sorted."""
        return [r[0] for r in self.conn.execute("SELECT identity FROM entries ORDER BY identity")]

    def entries(self, limit: int | None = None, offset: int = 0) -> list[dict]:
        """Identity, creation time, source, crop count and active added views of every entry
        (or of ``limit`` entries from ``offset``, in identity order: a page)
        (:class:`GalleryError` if a creation time of a damaged file is not a date)."""
        rows = self.conn.execute(
            "SELECT e.identity, e.created, e.source, "
            "(SELECT COUNT(*) FROM crops c WHERE c.identity = e.identity), "
            "(SELECT COUNT(*) FROM views v WHERE v.identity = e.identity AND v.active) "
            "FROM entries e ORDER BY e.identity" + ("" if limit is None else " LIMIT ? OFFSET ?"),
            () if limit is None else (max(0, int(limit)), max(0, int(offset))),
        )
        return [
            {
                "identity": i,
                "created": checked_time(t, f"{self.path}: entry {i!r:.40}"),
                "source": s,
                "crops": n,
                "views": v,
            }
            for i, t, s, n, v in rows
        ]

    def crops(self, identity: str) -> list[bytes]:
        """The PNG crops stored with ``identity`` (block order)."""
        rows = self.conn.execute(
            "SELECT png FROM crops WHERE identity = ? ORDER BY block", (identity,)
        )
        return [r[0] for r in rows]

    def matrix(self) -> tuple[list[str], np.ndarray]:
        """The enrolment embeddings as ``(identities, array of shape (n, 3, dim))`` (cached;
        added views are not included: :meth:`views` lists them)."""
        if self._cache is None:
            rows = self.conn.execute(
                "SELECT identity, embeddings FROM entries ORDER BY identity"
            ).fetchall()
            ids = [r[0] for r in rows]
            arr = np.frombuffer(b"".join(r[1] for r in rows), dtype=np.float32)
            self._cache = (ids, arr.reshape(len(ids), BLOCKS, self.dim))
        return self._cache

    def __len__(self) -> int:
        return self.conn.execute("SELECT COUNT(*) FROM entries").fetchone()[0]


def _upgrade(conn: sqlite3.Connection, path: str, schema: int) -> None:
    try:
        upgrade(conn, schema)
    except db_errors() as exc:
        raise GalleryError(
            f"{path}: gallery schema {schema} must be upgraded to schema {SCHEMA_VERSION} "
            f"(views, history, view crops) but the file cannot be written ({exc}); copy it "
            "somewhere writable and open it again, or re-enrol"
        ) from None


def _connect(path: str) -> sqlite3.Connection:
    conn = sqlite3.connect(path, isolation_level="DEFERRED", check_same_thread=False)
    conn.execute("PRAGMA foreign_keys = ON")
    # FULL sync: a committed enrolment survives a power cut, not only a killed process.
    conn.execute("PRAGMA synchronous = FULL")
    return conn


def _parse_thresholds(meta: dict[str, str], path: str) -> Thresholds:
    """The "unknown" thresholds stored in a gallery's metadata (checked: distances >= 0)."""
    values = []
    for key, default in (("max_distance", "inf"), ("min_margin", "0")):
        text = meta.get(key, default)
        try:
            v = float(text)
        except (TypeError, ValueError):
            v = float("nan")
        if v != v or v < 0 or (key == "min_margin" and v == float("inf")):
            raise GalleryError(
                f"{path}: threshold {key} = {text!r} is not a distance (the file is damaged); "
                "re-create the gallery (its thresholds come from the embedder) or restore a backup"
            )
        values.append(v)
    return Thresholds(values[0], values[1])


__all__ = [
    "MAX_IDENTITY_CHARS",
    "SCHEMA_VERSION",
    "Gallery",
    "GalleryError",
    "Match",
    "Thresholds",
    "UpdateDecision",
    "UpdateRule",
    "block_distances",
    "identity_problem",
]
