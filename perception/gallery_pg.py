"""A gallery in PostgreSQL: the same tables as the SQLite file, one schema per gallery.

A gallery is named by ``postgresql://user@host/dbname#NAME`` (the site store's URL and the
gallery's name after ``#``); its tables live in the PostgreSQL schema ``gallery_<name>``,
so one database holds every gallery of a site and several ground stations enrol and
identify against the same pallets. :class:`perception.gallery.Gallery` runs unchanged on
the connection :func:`connect_gallery` returns: a :class:`store.db.PgConnection` that also
speaks the few SQLite idioms the gallery's SQL uses (integer flags as conditions,
``char(0)`` in a key, ``lastrowid``, ``PRAGMA data_version``).
"""

from __future__ import annotations

import re
from typing import Any

from perception.errors import GalleryError
from store.db import PgConnection, StoreError, connect_postgresql, redact

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,40}$")
#: integer flags used as conditions (``WHERE active``) -> ``active <> 0``
_FLAG = re.compile(r"\b(WHERE|AND|OR)\s+((?:\w+\.)?active)\b(?!\s*(?:=|<>|!=|<|>))", re.I)
#: inserts whose new id the gallery reads (``cursor.lastrowid``)
_IDS = {"views": "view_id", "history": "event_id"}
_INSERT = re.compile(r"^\s*INSERT\s+INTO\s+(\w+)", re.I)
#: PostgreSQL text cannot hold NUL: a key built with char(0) travels as \x01
_SEP = "\x01"


def is_gallery_url(spec: str) -> bool:
    """True for a PostgreSQL gallery (``postgresql://...#NAME``)."""
    return spec.lower().startswith(("postgresql://", "postgres://"))


def gallery_url(store_url: str, name: str) -> str:
    """The gallery ``name`` in the store at ``store_url``."""
    return f"{store_url}#{name}"


def split_gallery_url(spec: str) -> tuple[str, str, str]:
    """(store URL, gallery name, schema) of ``postgresql://...#NAME``."""
    url, _, name = spec.rpartition("#")
    if not url or not _NAME.match(name):
        raise GalleryError(
            f"{redact(spec)}: name the gallery after '#' (1-41 letters, digits, _ . -), "
            "e.g. postgresql://btrun@db.site/btrun#pallets"
        )
    schema = "gallery_" + re.sub(r"[^a-z0-9_]", "_", name.lower())
    return url, name, schema


class _Cursor:
    """A psycopg cursor with ``lastrowid`` and NUL separators restored."""

    def __init__(self, cur: Any, lastrowid: int | None = None, restore: bool = False) -> None:
        self._cur, self.lastrowid, self._restore = cur, lastrowid, restore
        self.rowcount = cur.rowcount

    def _fix(self, row: Any) -> Any:
        if row is None or not self._restore:
            return row
        return tuple(v.replace(_SEP, "\0") if isinstance(v, str) else v for v in row)

    def fetchone(self) -> Any:
        return self._fix(self._cur.fetchone())

    def fetchall(self) -> list:
        return [self._fix(r) for r in self._cur.fetchall()]

    def __iter__(self) -> Any:
        return (self._fix(r) for r in self._cur)


class GalleryPgConnection(PgConnection):
    """:class:`store.db.PgConnection` for the gallery's SQL (see the module doc)."""

    def execute(self, sql: str, params: Any = ()) -> Any:
        """Run one statement of the gallery's SQLite SQL on PostgreSQL."""
        text = sql.strip()
        if text.upper() == "PRAGMA DATA_VERSION":  # changes by other connections
            text = "SELECT COALESCE(MAX(event_id), 0) FROM history"
        elif text.upper().startswith("BEGIN"):
            return _Cursor(self.raw.execute("SELECT 1"))  # ``with conn`` is the transaction
        text = _FLAG.sub(r"\1 \2 <> 0", text)
        restore = "char(0)" in text
        text = text.replace("char(0)", f"chr({ord(_SEP)})")
        m = _INSERT.match(text)
        table = m.group(1).lower() if m else ""
        if table in _IDS and "RETURNING" not in text.upper():
            cur = super().execute(f"{text} RETURNING {_IDS[table]}", params)
            return _Cursor(cur, int(cur.fetchone()[0]))
        return _Cursor(super().execute(text, params), restore=restore)


def connect_gallery(spec: str, create: bool = False) -> tuple[GalleryPgConnection, set[str]]:
    """A connection to the gallery ``spec`` (its schema made when ``create``) and the
    tables it has (none: no such gallery yet); :class:`GalleryError` in one line if the
    server cannot be reached."""
    url, _, schema = split_gallery_url(spec)
    try:
        base = connect_postgresql(url, schema, create=create)
    except StoreError as exc:
        raise GalleryError(f"{exc}") from None
    conn = GalleryPgConnection(base.raw, base.shown)
    tables = {
        r[0]
        for r in conn.execute(
            "SELECT table_name FROM information_schema.tables WHERE table_schema = ?",
            (schema,),
        )
    }
    return conn, tables


def shown(spec: str) -> str:
    """The gallery URL for messages (no password)."""
    return redact(spec)


__all__ = [
    "GalleryPgConnection",
    "connect_gallery",
    "gallery_url",
    "is_gallery_url",
    "shown",
    "split_gallery_url",
]
