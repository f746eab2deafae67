"""The gallery file's SQLite schema, its versions and the checks run when one is opened.

The same DDL makes a gallery in PostgreSQL (:mod:`perception.gallery_pg`: types translated
by :func:`store.db.pg_ddl`).

Schema 2 (this btrun) adds to schema 1's ``meta``, ``entries`` and ``crops``:

* ``visibility``: per enrolled side, the stripe visibilities of its three blocks (optional);
* ``views``: views added to an identity after confident identifications (a gallery that
  keeps up): embeddings, visibilities, when, which run, the distance and margin of the
  identification, whether the view is active and which later view evicted it;
* ``history``: the audit trail, one row per enrolment, added view, eviction, rollback
  and removal.

Schema 3 adds ``view_crops``: the three block crops (PNG) of an added view, so the texture
verifier (:mod:`perception.verify`) compares a scan with how the side looked lately, too.

An older file is upgraded in place when opened (one transaction per step: schema 1 to 2
adds the tables and an ``enrol`` history row per existing side; 2 to 3 adds
``view_crops``). A read-only older file cannot be upgraded and is refused with a message
that says so.
"""

from __future__ import annotations

import sqlite3
import time

from store.db import pg_ddl

SCHEMA_VERSION = 3
READABLE_SCHEMAS = (1, 2, 3)

_V1 = """
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

_V2_ADDED = """
CREATE TABLE visibility (
    identity TEXT PRIMARY KEY REFERENCES entries(identity) ON DELETE CASCADE,
    stripes BLOB NOT NULL
);
CREATE TABLE views (
    view_id INTEGER PRIMARY KEY AUTOINCREMENT,
    identity TEXT NOT NULL REFERENCES entries(identity) ON DELETE CASCADE,
    embeddings BLOB NOT NULL,
    stripes BLOB,
    added REAL NOT NULL,
    run TEXT NOT NULL DEFAULT '',
    distance REAL,
    margin REAL,
    active INTEGER NOT NULL DEFAULT 1,
    evicted_by INTEGER
);
CREATE INDEX views_identity ON views(identity, active);
CREATE TABLE history (
    event_id INTEGER PRIMARY KEY AUTOINCREMENT,
    identity TEXT NOT NULL,
    time REAL NOT NULL,
    action TEXT NOT NULL,
    run TEXT NOT NULL DEFAULT '',
    distance REAL,
    margin REAL,
    view_id INTEGER,
    note TEXT NOT NULL DEFAULT ''
);
CREATE INDEX history_identity ON history(identity);
"""

_V3_ADDED = """
CREATE TABLE view_crops (
    view_id INTEGER NOT NULL REFERENCES views(view_id) ON DELETE CASCADE,
    block INTEGER NOT NULL,
    png BLOB NOT NULL,
    PRIMARY KEY (view_id, block)
);
"""

#: tables every readable file has, by schema
TABLES = {
    1: {"meta", "entries", "crops"},
    2: {"meta", "entries", "crops", "visibility", "views", "history"},
    3: {"meta", "entries", "crops", "visibility", "views", "history", "view_crops"},
}


def write_schema(conn: sqlite3.Connection, model_version: str, dim: int) -> None:
    """Create the tables and the metadata of an empty gallery (one transaction)."""
    with conn:
        conn.executescript(_V1 + _V2_ADDED + _V3_ADDED)
        conn.executemany(
            "INSERT INTO meta VALUES (?, ?)",
            [
                ("schema_version", str(SCHEMA_VERSION)),
                ("model_version", model_version),
                ("dim", str(dim)),
                ("created", repr(time.time())),
            ],
        )


def _step(conn: sqlite3.Connection, script: str, to: int, extra: str = "") -> None:
    with conn:
        conn.execute("BEGIN IMMEDIATE")  # DDL opens no transaction by itself
        if getattr(conn, "dialect", "sqlite") == "postgresql":
            script = pg_ddl(script)
        for stmt in script.split(";"):
            if stmt.strip():
                conn.execute(stmt)
        if extra:
            conn.execute(extra)
        conn.execute("UPDATE meta SET value = ? WHERE key = 'schema_version'", (str(to),))


def upgrade(conn: sqlite3.Connection, schema: int) -> None:
    """Upgrade a gallery of an older ``schema`` to :data:`SCHEMA_VERSION`, one transaction
    per step (see the module doc)."""
    if schema < 2:
        _step(
            conn,
            _V2_ADDED,
            2,
            "INSERT INTO history (identity, time, action, note) "
            "SELECT identity, created, 'enrol', 'upgraded from gallery schema 1' FROM entries",
        )
    if schema < 3:
        _step(conn, _V3_ADDED, 3)


def check_contents(conn: sqlite3.Connection, dim: int) -> str | None:
    """The first problem with the stored vectors (wrong byte count), or None."""
    want = 3 * dim * 4
    # PostgreSQL's bytea column holds only bytes; an SQLite column may hold any type
    blob = (
        ""
        if getattr(conn, "dialect", "sqlite") == "postgresql"
        else "OR typeof(embeddings) != 'blob' "
    )
    for table in ("entries", "views"):
        bad = conn.execute(
            f"SELECT identity, length(embeddings) FROM {table} WHERE length(embeddings) != ? "  # noqa: S608
            f"{blob}LIMIT 1",
            (want,),
        ).fetchone()
        if bad is not None:
            where = "entry" if table == "entries" else "a view of"
            return (
                f"{where} {bad[0]!r} holds {bad[1]} bytes of embeddings, expected {want} "
                f"(3 blocks x {dim} numbers): the file is damaged or from another model; "
                "remove the entry (btrun gallery remove) or re-enrol"
            )
    return None


__all__ = [
    "READABLE_SCHEMAS",
    "SCHEMA_VERSION",
    "TABLES",
    "check_contents",
    "upgrade",
    "write_schema",
]
