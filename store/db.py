"""Database URLs and connections: SQLite files and PostgreSQL servers behind one face.

A store URL is one of:

* ``sqlite:///runs/site.sqlite`` (relative), ``sqlite:////srv/btrun/site.sqlite``
  (absolute: four slashes, as SQLAlchemy writes it) or a plain file path;
* ``postgresql://user:password@host:5432/dbname`` (``postgres://`` too; any libpq URL
  parameter such as ``?host=/run/postgresql`` or ``sslmode=require``), reached with
  psycopg 3.

:func:`connect` opens either as a :class:`Database`, whose methods take SQLite-style SQL
(``?`` placeholders) and run it on both: on PostgreSQL the placeholders become ``%s`` and
``executescript`` DDL is translated (``BLOB`` -> ``BYTEA``, ``REAL`` -> ``DOUBLE PRECISION``,
``INTEGER PRIMARY KEY AUTOINCREMENT`` -> an identity column). SQL that both understand is
written once (``ON CONFLICT ... DO UPDATE``, ``RETURNING``); the rest asks
:attr:`Database.dialect`. ``with db:`` is one transaction on both (commit, or roll back on
an exception), as :class:`sqlite3.Connection` does.

An SQLite store file is opened in WAL mode with a busy timeout, so several processes (two
fleets on one ground station) write to it at once without "database is locked".
"""

from __future__ import annotations

import os
import re
import sqlite3
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit, urlunsplit

#: How long an SQLite writer waits for another writer's transaction, in ms.
SQLITE_BUSY_TIMEOUT_MS = 30_000
#: How long connecting to a PostgreSQL server may take before the store is unreachable, in s.
PG_CONNECT_TIMEOUT_S = 5


class StoreError(Exception):
    """A store that cannot be used (bad URL, unreachable server, damaged or newer schema),
    said in one line without a password."""


@dataclass(frozen=True)
class StoreURL:
    """A parsed store URL: ``kind`` (``sqlite`` or ``postgresql``), ``target`` (the file
    path, or the libpq URL) and ``shown`` (the URL without its password, for messages)."""

    kind: str
    target: str
    shown: str


def parse_url(text: str) -> StoreURL:
    """Parse a store URL or a plain SQLite file path (see the module doc)."""
    text = (text or "").strip()
    if not text:
        raise StoreError("empty store URL (sqlite:///FILE or postgresql://...)")
    scheme, sep, rest = text.partition("://")
    if not sep:
        _not_a_path(text)
        return StoreURL("sqlite", text, text)
    scheme = scheme.lower()
    if scheme == "sqlite":
        if not rest.startswith("/") or rest == "/":
            raise StoreError(
                f"store URL {text!r}: expected sqlite:///relative/file or sqlite:////absolute/file"
            )
        path = rest[1:]
        return StoreURL("sqlite", path, text)
    if scheme in ("postgresql", "postgres"):
        return StoreURL("postgresql", text, redact(text))
    raise StoreError(
        f"store URL {redact(text)!r}: unknown scheme {scheme!r} "
        "(sqlite:///FILE or postgresql://user@host/dbname)"
    )


#: ``name:`` at the start of a store argument: a URL's scheme (a drive letter is one letter)
_SCHEME = re.compile(r"([A-Za-z][A-Za-z0-9+.-]+):")


def _not_a_path(text: str) -> None:
    """Refuse a store argument without ``://`` that is a mistyped URL or a libpq
    ``key=value`` string rather than an SQLite file path (it was taken as one: a file
    named ``postgresql:/host/db`` was made in the working directory, or one named after a
    connection string, password and all)."""
    if "=" in text and re.search(r"\s", text):
        raise StoreError(
            "a libpq key=value string is not a store URL: give postgresql://USER@HOST/DBNAME "
            "(the password in ~/.pgpass or $PGPASSWORD)"
        )
    m = _SCHEME.match(text)
    if m:
        scheme = m.group(1).lower()
        known = {"sqlite": "sqlite:///FILE", "postgresql": "postgresql://USER@HOST/DBNAME"}
        known["postgres"] = known["postgresql"]
        want = known.get(scheme, "sqlite:///FILE or postgresql://USER@HOST/DBNAME")
        shown = re.sub(r"(?i)(password=)[^&\s]*", r"\1***", re.sub(r":[^:@/]*@", ":***@", text))
        raise StoreError(f"store URL {shown!r}: expected {want} (no '://' after the scheme)")


def redact(url: str) -> str:
    """``url`` with its password (user:PASSWORD@host, or ?password=...) replaced by ``***``."""
    try:
        parts = urlsplit(url)
    except ValueError:
        return "<store URL>"
    netloc = parts.netloc
    if "@" in netloc:
        creds, _, host = netloc.rpartition("@")
        if ":" in creds:
            creds = creds.split(":", 1)[0] + ":***"
        netloc = f"{creds}@{host}"
    query = re.sub(r"(?i)(password=)[^&]*", r"\1***", parts.query)
    return urlunsplit((parts.scheme, netloc, parts.path, query, parts.fragment))


def db_errors() -> tuple[type[BaseException], ...]:
    """The exception classes a database call may raise (sqlite3's, and psycopg's when it is
    installed)."""
    try:
        import psycopg
    except ImportError:
        return (sqlite3.Error,)
    return (sqlite3.Error, psycopg.Error)


_PG_DDL = [
    (re.compile(r"\bINTEGER\s+PRIMARY\s+KEY\s+AUTOINCREMENT\b", re.I),
     "BIGINT GENERATED BY DEFAULT AS IDENTITY PRIMARY KEY"),
    (re.compile(r"\bBLOB\b", re.I), "BYTEA"),
    (re.compile(r"\bREAL\b", re.I), "DOUBLE PRECISION"),
]  # fmt: skip


def pg_sql(sql: str) -> str:
    """SQLite-style SQL for psycopg: ``?`` -> ``%s`` and a literal ``%`` -> ``%%``, outside
    quoted strings and names."""
    out: list[str] = []
    quote = ""
    for ch in sql:
        if quote:
            out.append(ch)
            if ch == quote:
                quote = ""
        elif ch in ("'", '"'):
            quote = ch
            out.append(ch)
        elif ch == "?":
            out.append("%s")
        elif ch == "%":
            out.append("%%")
        else:
            out.append(ch)
    return "".join(out)


def pg_ddl(script: str) -> str:
    """SQLite DDL as PostgreSQL DDL (types; see the module doc)."""
    for pattern, repl in _PG_DDL:
        script = pattern.sub(repl, script)
    return script


def split_script(script: str) -> list[str]:
    """The statements of an SQL script (split at ``;``; the scripts here quote none)."""
    return [s.strip() for s in script.split(";") if s.strip()]


class PgConnection:
    """A psycopg 3 connection with the face of :class:`sqlite3.Connection` that the stores
    and the gallery use: ``execute`` (``?`` placeholders) returning a cursor,
    ``executemany``, ``executescript`` (SQLite DDL translated), ``with conn:`` as one
    transaction (nested: a savepoint), ``close``. Statements outside ``with`` commit at
    once (autocommit)."""

    dialect = "postgresql"

    def __init__(self, conn: Any, shown: str) -> None:
        self.raw, self.shown = conn, shown
        self._tx: list[Any] = []

    def execute(self, sql: str, params: Sequence[Any] = ()) -> Any:
        """Run one statement; the psycopg cursor (``fetchone``, ``fetchall``, iteration,
        ``rowcount``)."""
        return self.raw.execute(pg_sql(sql), tuple(params))

    def executemany(self, sql: str, seq: Iterable[Sequence[Any]]) -> Any:
        """Run one statement for each parameter tuple."""
        cur = self.raw.cursor()
        cur.executemany(pg_sql(sql), [tuple(p) for p in seq])
        return cur

    def executescript(self, script: str) -> None:
        """Run a script of SQLite DDL (translated), statement by statement."""
        for stmt in split_script(pg_ddl(script)):
            self.raw.execute(stmt)

    def __enter__(self) -> PgConnection:
        tx = self.raw.transaction()
        tx.__enter__()
        self._tx.append(tx)
        return self

    def __exit__(self, *exc: Any) -> None:
        self._tx.pop().__exit__(*exc)

    def close(self) -> None:
        """Close the connection (an open transaction is rolled back)."""
        self.raw.close()


def connect_postgresql(url: str, schema: str | None = None, create: bool = False) -> PgConnection:
    """A :class:`PgConnection` to ``url``; with ``schema`` its tables are looked up there
    (``search_path``), created first when ``create``. :class:`StoreError` (one line, no
    password) if psycopg is missing or the server cannot be reached."""
    shown = redact(url)
    try:
        import psycopg
    except ImportError:
        raise StoreError(
            f"{shown}: PostgreSQL needs psycopg 3 (pip install 'psycopg[binary]')"
        ) from None
    try:
        raw = psycopg.connect(url, autocommit=True, connect_timeout=PG_CONNECT_TIMEOUT_S)
    except psycopg.Error as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise StoreError(f"{shown}: cannot connect ({first})") from None
    conn = PgConnection(raw, shown)
    if schema is not None:
        try:
            if create:
                raw.execute(f'CREATE SCHEMA IF NOT EXISTS "{schema}"')
            raw.execute(f'SET search_path TO "{schema}"')
        except psycopg.Error as exc:
            raw.close()
            raise StoreError(f"{shown}: schema {schema}: {exc}".splitlines()[0]) from None
    return conn


def _lower(value: Any) -> Any:
    """SQLite's ``LOWER``, in Unicode (Python's ``str.lower``), as PostgreSQL's."""
    return value.lower() if isinstance(value, str) else value


def connect_sqlite(
    path: str, create: bool = True, check: Callable[[sqlite3.Connection], None] | None = None
) -> sqlite3.Connection:
    """An SQLite connection for a store file shared by processes: WAL journal, a busy
    timeout of :data:`SQLITE_BUSY_TIMEOUT_MS`, foreign keys on; the folder is made when
    ``create``. ``check`` sees the connection before anything is written to the file (the
    WAL switch writes its header) and may raise. :class:`StoreError` if the file cannot be
    opened."""
    if not create and not os.path.exists(path):
        raise StoreError(f"{path}: no store file")
    try:
        folder = os.path.dirname(os.path.abspath(path))
        if create:
            os.makedirs(folder, exist_ok=True)
        conn = sqlite3.connect(
            path,
            timeout=SQLITE_BUSY_TIMEOUT_MS / 1000,
            isolation_level="DEFERRED",
            check_same_thread=False,
        )
        conn.execute(f"PRAGMA busy_timeout = {SQLITE_BUSY_TIMEOUT_MS}")
        # SQLite's LOWER folds ASCII only: a pallet 'ÄB-7A' was never found in any case
        conn.create_function("lower", 1, _lower, deterministic=True)
        if check is not None:
            try:
                check(conn)
            except BaseException:
                conn.close()
                raise
        _wal(conn)
        conn.execute("PRAGMA foreign_keys = ON")
    except (OSError, sqlite3.Error) as exc:
        raise StoreError(f"{path}: cannot open the store file ({exc})") from None
    return conn


def _wal(conn: sqlite3.Connection) -> None:
    """Put the store file in WAL mode (it stays so). Switching needs the file to itself,
    and SQLite answers "database is locked" at once, without its busy timeout, when
    another process opens the new file at that moment (two fleets starting on one store
    did, about one start in five with six at once): the mode is only switched when it is
    not WAL yet, and a locked switch is tried again until the busy timeout."""
    deadline = time.monotonic() + SQLITE_BUSY_TIMEOUT_MS / 1000
    while True:
        try:
            mode = conn.execute("PRAGMA journal_mode").fetchone()[0]
            if str(mode).lower() != "wal":
                conn.execute("PRAGMA journal_mode = WAL")
            return
        except sqlite3.OperationalError as exc:
            if "locked" not in str(exc) or time.monotonic() > deadline:
                raise
            time.sleep(0.02)  # another connection holds the file for a moment


def dialect_of(conn: Any) -> str:
    """``postgresql`` for a :class:`PgConnection`, else ``sqlite``."""
    return getattr(conn, "dialect", "sqlite")


def rows_as_dicts(cursor: Any, keys: Sequence[str]) -> Iterator[dict]:
    """Each row of ``cursor`` as a dict of ``keys``."""
    for row in cursor:
        yield dict(zip(keys, row, strict=True))


__all__ = [
    "PgConnection",
    "StoreError",
    "StoreURL",
    "connect_postgresql",
    "connect_sqlite",
    "db_errors",
    "dialect_of",
    "parse_url",
    "pg_ddl",
    "pg_sql",
    "redact",
    "rows_as_dicts",
]
