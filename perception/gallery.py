"""The gallery of enrolled pallets: an SQLite file of block embeddings, and matching.

One entry per enrolled pallet side (``"3A"``): the three block embeddings (left to right),
the model version that computed them, the time, and the source crops (PNG). Matching follows
the reference mission: for each entry, the mean of the three block-to-block distances; the
smallest mean wins. On top of that the gallery reports the runner-up and the margin between
them, and answers ``"unknown"`` when the best distance is too large or the margin too small
(thresholds calibrated on a validation set: see ``docs/perception.md``).

Safety of the file:

* every write is one SQLite transaction, so a process killed during an enrolment leaves the
  previous gallery intact (SQLite's journal rolls the half-written transaction back);
* the file records the model version; opening it with another model is refused, because
  embeddings of two models are not comparable;
* a damaged file is detected (``PRAGMA quick_check``) and reported, never silently used.
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

SCHEMA_VERSION = 1
BLOCKS = 3


class GalleryError(Exception):
    """A gallery that cannot be used (missing, damaged, other model, wrong shapes)."""


@dataclass(frozen=True)
class Match:
    """The answer of :meth:`Gallery.match`.

    ``pallet_id`` is the best entry's identity, or ``"unknown"`` when a threshold failed;
    ``best_id`` is always the closest entry. ``ranking`` lists ``(identity, mean distance,
    per-block distances)`` best first.
    """

    pallet_id: str
    best_id: str
    distance: float
    runner_up_id: str | None
    runner_up_distance: float | None
    margin: float
    known: bool
    reason: str
    ranking: list[tuple[str, float, tuple[float, ...]]] = field(default_factory=list)


@dataclass(frozen=True)
class Thresholds:
    """When to answer "unknown": best mean distance above ``max_distance`` or a margin to the
    runner-up below ``min_margin``."""

    max_distance: float = float("inf")
    min_margin: float = 0.0


class Gallery:
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
        self._fast: tuple[np.ndarray, list[np.ndarray], np.ndarray] | None = None

    # -- opening -------------------------------------------------------------------------
    @classmethod
    def create(cls, path: str, model_version: str, dim: int, exist_ok: bool = False) -> Gallery:
        """Create a new, empty gallery file for ``model_version`` embeddings of size ``dim``."""
        if path != ":memory:" and os.path.exists(path):
            if not exist_ok:
                raise GalleryError(f"{path}: a gallery already exists (remove it or open it)")
            return cls.open(path, model_version)
        if path == ":memory:":
            conn = _connect(path)
            _write_schema(conn, model_version, dim)
            return cls(conn, path, model_version, dim)
        # Built under a temporary name, then renamed: a process killed while creating leaves
        # no half-made gallery behind (the next create or open sees no file at all).
        folder = os.path.dirname(os.path.abspath(path))
        tmp = os.path.join(folder, f".{os.path.basename(path)}.{os.getpid()}.creating")
        try:
            if os.path.exists(tmp):
                os.remove(tmp)
            conn = _connect(tmp)
            _write_schema(conn, model_version, dim)
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
        """Open an existing gallery; refuse a damaged file or one of another model version."""
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
            missing = sorted({"meta", "entries", "crops"} - tables)
            if missing:
                raise GalleryError(
                    f"{path}: not a complete btrun gallery (table {', '.join(missing)} "
                    "missing); restore a backup or enrol into a new file"
                )
            meta = dict(conn.execute("SELECT key, value FROM meta").fetchall())
        except sqlite3.DatabaseError as exc:
            raise GalleryError(f"{path}: not a readable gallery file ({exc})") from None
        try:
            schema = int(meta["schema_version"])
            stored_version = meta["model_version"]
            dim = int(meta["dim"])
        except (KeyError, ValueError):
            raise GalleryError(f"{path}: not a btrun gallery (metadata missing)") from None
        if schema != SCHEMA_VERSION:
            raise GalleryError(
                f"{path}: gallery schema {schema}, this btrun reads {SCHEMA_VERSION}"
            )
        if dim <= 0 or dim > 65536:
            raise GalleryError(f"{path}: embedding size {dim} in its metadata is not valid")
        _check_contents(conn, path, dim)
        _parse_thresholds(meta, path)
        if model_version is not None and stored_version != model_version:
            raise GalleryError(
                f"{path}: written by model '{stored_version}', but the embedder is "
                f"'{model_version}'; embeddings of different models cannot be compared: "
                "re-enrol the pallets with this model"
            )
        return cls(conn, path, stored_version, dim)

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
    ) -> None:
        """Add (or replace) ``identity`` with its three block embeddings, in one transaction."""
        emb = np.asarray(embeddings, dtype=np.float32)
        if emb.shape != (BLOCKS, self.dim):
            raise GalleryError(
                f"enrol {identity}: expected embeddings of shape {(BLOCKS, self.dim)}, got {emb.shape}"
            )
        if not np.all(np.isfinite(emb)):
            raise GalleryError(f"enrol {identity}: embeddings contain NaN or infinity")
        if not identity or len(identity) > 64:
            raise GalleryError(f"enrol: identity must be 1-64 characters, got {identity!r}")
        with self._writing(f"enrol {identity}"), self.conn:  # one transaction: all or none
            exists = self.conn.execute(
                "SELECT 1 FROM entries WHERE identity = ?", (identity,)
            ).fetchone()
            if exists and not replace:
                raise GalleryError(f"enrol: {identity} is already enrolled")
            self.conn.execute("DELETE FROM entries WHERE identity = ?", (identity,))
            self.conn.execute(
                "INSERT INTO entries VALUES (?, ?, ?, ?)",
                (identity, emb.tobytes(), time.time(), source),
            )
            for i, png in enumerate(crops_png or []):
                self.conn.execute("INSERT INTO crops VALUES (?, ?, ?)", (identity, i, png))
        self._cache = None

    def remove(self, identity: str) -> bool:
        """Remove ``identity``; return False if it was not enrolled."""
        with self._writing(f"remove {identity}"), self.conn:
            n = self.conn.execute("DELETE FROM entries WHERE identity = ?", (identity,)).rowcount
        self._cache = None
        return n > 0

    def set_thresholds(self, thresholds: Thresholds) -> None:
        """Store the "unknown" thresholds (calibrated on a validation set) in the file."""
        with self._writing("set thresholds"), self.conn:
            self.conn.executemany(
                "INSERT OR REPLACE INTO meta VALUES (?, ?)",
                [
                    ("max_distance", repr(thresholds.max_distance)),
                    ("min_margin", repr(thresholds.min_margin)),
                ],
            )
        self.thresholds = thresholds

    def _load_thresholds(self) -> Thresholds:
        meta = dict(self.conn.execute("SELECT key, value FROM meta").fetchall())
        return _parse_thresholds(meta, self.path)

    @contextlib.contextmanager
    def _writing(self, what: str) -> Iterator[None]:
        """Turn SQLite's write errors into one clear :class:`GalleryError` (nothing written:
        the transaction is rolled back)."""
        try:
            yield
        except sqlite3.Error as exc:
            hint = (
                "the file or its folder is read-only: check the permissions"
                if "readonly" in str(exc) or "read-only" in str(exc)
                else "the file may be damaged or locked by another process"
            )
            raise GalleryError(f"{self.path}: cannot {what} ({exc}); {hint}") from None

    # -- reading ---------------------------------------------------------------------------
    def identities(self) -> list[str]:
        """Enrolled identities, sorted."""
        return [r[0] for r in self.conn.execute("SELECT identity FROM entries ORDER BY identity")]

    def entries(self) -> list[dict]:
        """Identity, creation time, source and crop count of every entry."""
        rows = self.conn.execute(
            "SELECT e.identity, e.created, e.source, COUNT(c.block) FROM entries e "
            "LEFT JOIN crops c ON c.identity = e.identity GROUP BY e.identity ORDER BY e.identity"
        )
        return [{"identity": i, "created": t, "source": s, "crops": n} for i, t, s, n in rows]

    def crops(self, identity: str) -> list[bytes]:
        """The PNG crops stored with ``identity`` (block order)."""
        rows = self.conn.execute(
            "SELECT png FROM crops WHERE identity = ? ORDER BY block", (identity,)
        )
        return [r[0] for r in rows]

    def matrix(self) -> tuple[list[str], np.ndarray]:
        """All embeddings as ``(identities, array of shape (n, 3, dim))`` (cached)."""
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

    def match(
        self, query: np.ndarray, top_k: int = 5, thresholds: Thresholds | None = None
    ) -> Match:
        """Match three block embeddings (left to right) against every entry.

        Distance between two blocks: Euclidean distance of the embeddings; per entry: the mean
        of the three block-to-block distances (the reference rule).
        """
        q = np.asarray(query, dtype=np.float32)
        if q.shape != (BLOCKS, self.dim):
            raise GalleryError(
                f"match: expected a query of shape {(BLOCKS, self.dim)}, got {q.shape}"
            )
        ids, g = self.matrix()
        if not ids:
            raise GalleryError(f"{self.path}: the gallery is empty: enrol pallets first")
        # Screen every entry with one matrix-vector product per block (|g|^2 + |q|^2 - 2 g.q),
        # then recompute the best candidates exactly, so reported distances are exact.
        screen = self._screen(q, g)
        k = min(len(ids), max(top_k, 2) + 16)
        cand = np.argpartition(screen, k - 1)[:k] if k < len(ids) else np.arange(len(ids))
        cand = np.sort(cand)
        exact = block_distances(q, g[cand])
        means = exact.mean(axis=1)
        local = np.argsort(means, kind="stable")
        order, per_block = cand[local], exact[local]
        means = means[local]
        th = thresholds or self.thresholds
        best = int(order[0])
        second = int(order[1]) if len(order) > 1 else None
        d1 = float(means[0])
        d2 = float(means[1]) if second is not None else None
        margin = (d2 - d1) if d2 is not None else float("inf")
        reason = ""
        if d1 > th.max_distance:
            reason = f"best distance {d1:.3f} above the threshold {th.max_distance:.3f}"
        elif margin < th.min_margin:
            reason = f"margin {margin:.3f} to {ids[second]} below the threshold {th.min_margin:.3f}"
        ranking = [
            (ids[i], float(means[j]), tuple(float(x) for x in per_block[j]))
            for j, i in enumerate(order[:top_k])
        ]
        return Match(
            pallet_id=ids[best] if not reason else "unknown",
            best_id=ids[best],
            distance=d1,
            runner_up_id=ids[second] if second is not None else None,
            runner_up_distance=d2,
            margin=margin,
            known=not reason,
            reason=reason,
            ranking=ranking,
        )

    def _screen(self, q: np.ndarray, g: np.ndarray) -> np.ndarray:
        """Approximate mean block distances to every entry (float32 dot products)."""
        if self._fast is None or self._fast[0] is not g:
            blocks = [np.ascontiguousarray(g[:, b]) for b in range(BLOCKS)]
            sq = np.stack([np.einsum("nd,nd->n", x, x) for x in blocks], axis=1)
            self._fast = (g, blocks, sq)
        _, blocks, sq = self._fast
        dots = np.stack([blocks[b] @ q[b] for b in range(BLOCKS)], axis=1)
        d2 = sq + np.einsum("bd,bd->b", q, q)[None, :] - 2.0 * dots
        return np.sqrt(np.maximum(d2, 0.0)).mean(axis=1)


def block_distances(query: np.ndarray, gallery: np.ndarray) -> np.ndarray:
    """Euclidean distances of each query block to the same block of every entry: (n, 3)."""
    diff = gallery - query[None, :, :]
    return np.sqrt(np.einsum("nbd,nbd->nb", diff, diff))


def _connect(path: str) -> sqlite3.Connection:
    conn = sqlite3.connect(path, isolation_level="DEFERRED", check_same_thread=False)
    conn.execute("PRAGMA foreign_keys = ON")
    # FULL sync: a committed enrolment survives a power cut, not only a killed process.
    conn.execute("PRAGMA synchronous = FULL")
    return conn


def _write_schema(conn: sqlite3.Connection, model_version: str, dim: int) -> None:
    """Create the tables and the metadata of an empty gallery (one transaction)."""
    with conn:
        conn.executescript(
            """
            CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
            CREATE TABLE entries (
                identity TEXT PRIMARY KEY,
                embeddings BLOB NOT NULL,
                created REAL NOT NULL,
                source TEXT NOT NULL DEFAULT ''
            );
            CREATE TABLE crops (
                identity TEXT NOT NULL REFERENCES entries(identity) ON DELETE CASCADE,
                block INTEGER NOT NULL,
                png BLOB NOT NULL,
                PRIMARY KEY (identity, block)
            );
            """
        )
        conn.executemany(
            "INSERT INTO meta VALUES (?, ?)",
            [
                ("schema_version", str(SCHEMA_VERSION)),
                ("model_version", model_version),
                ("dim", str(dim)),
                ("created", repr(time.time())),
            ],
        )


def _check_contents(conn: sqlite3.Connection, path: str, dim: int) -> None:
    """Every entry holds exactly three embeddings of ``dim`` float32 numbers."""
    want = BLOCKS * dim * 4
    try:
        bad = conn.execute(
            "SELECT identity, length(embeddings) FROM entries WHERE length(embeddings) != ? "
            "OR typeof(embeddings) != 'blob' LIMIT 1",
            (want,),
        ).fetchone()
    except sqlite3.DatabaseError as exc:
        raise GalleryError(f"{path}: the entries table cannot be read ({exc})") from None
    if bad is not None:
        raise GalleryError(
            f"{path}: entry {bad[0]!r} holds {bad[1]} bytes of embeddings, expected {want} "
            f"(3 blocks x {dim} numbers): the file is damaged or from another model; "
            "remove the entry (btrun gallery remove) or re-enrol"
        )


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
