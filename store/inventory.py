"""The site store of inventories: every run and every row it found, in SQLite or PostgreSQL.

Tables (schema :data:`SCHEMA_VERSION`, written in SQL both databases read):

* ``store_schema``: one row per schema version applied (the upgrade path: :data:`STEPS`,
  each step one transaction, taken under a lock so two processes opening a new store at
  once create it once);
* ``runs``: one row per run folder (its name is the run id): mission, rig, fleet, seed,
  host and folder, started / ended (seconds since 1970), status (``running`` until the
  run ends, then the mission's: ``SUCCESS``, ``FAILURE``, ``ABORTED``);
* ``inventory_rows``: one row per (run, place) with the inventory row's columns and
  ``origin``, the run that found it (a resumed run keeps the rows it carried over, with
  the run they came from).

Writing is idempotent: a row re-recorded for the same (run, place) replaces the old one
(``ON CONFLICT ... DO UPDATE``), so a resumed or re-imported run never duplicates, and each
call is one transaction, so two fleets recording at once lose nothing.
"""

from __future__ import annotations

import difflib
import os
import socket
import time
from collections.abc import Iterable
from typing import Any

from store.db import (
    StoreError,
    connect_postgresql,
    connect_sqlite,
    db_errors,
    dialect_of,
    parse_url,
    rows_as_dicts,
    split_script,
)
from store.diff import diff_rows, flown_by

SCHEMA_VERSION = 1

#: The schema steps: version -> DDL bringing the previous version to it.
STEPS: dict[int, str] = {
    1: """
CREATE TABLE runs (
    run TEXT PRIMARY KEY,
    mission TEXT,
    rig TEXT,
    fleet TEXT,
    seed BIGINT,
    host TEXT,
    folder TEXT,
    started DOUBLE PRECISION,
    ended DOUBLE PRECISION,
    status TEXT NOT NULL DEFAULT 'running'
);
CREATE TABLE inventory_rows (
    run TEXT NOT NULL REFERENCES runs(run) ON DELETE CASCADE,
    place TEXT NOT NULL,
    answer TEXT,
    status TEXT,
    best_id TEXT,
    distance DOUBLE PRECISION,
    margin DOUBLE PRECISION,
    blocks_seen BIGINT,
    mission_time_s DOUBLE PRECISION,
    drone TEXT,
    origin TEXT,
    reason TEXT,
    recorded DOUBLE PRECISION NOT NULL,
    PRIMARY KEY (run, place)
);
CREATE INDEX inventory_rows_place ON inventory_rows(place);
CREATE INDEX runs_started ON runs(started)
""",
}

#: The columns of a stored row, as the run folder's ``inventory.json`` names them (``run``
#: there is the run that found the row: ``origin`` here).
ROW_FIELDS = (
    "place",
    "answer",
    "status",
    "best_id",
    "distance",
    "margin",
    "blocks_seen",
    "mission_time_s",
    "drone",
    "origin",
    "reason",
)
RUN_FIELDS = (
    "run",
    "mission",
    "rig",
    "fleet",
    "seed",
    "host",
    "folder",
    "started",
    "ended",
    "status",
)
#: An advisory lock id (PostgreSQL) taken while the schema is created or upgraded.
_SCHEMA_LOCK = 2028_0028


def default_url(run_dir: str | None = None) -> str:
    """The store used without ``--store``: ``$BTRUN_STORE`` if set, else ``site.sqlite``
    beside the run folder (``runs/site.sqlite`` for the default ``runs/<name>-<time>``),
    else (no run folder: the inventory commands) ``runs/site.sqlite``."""
    env = os.environ.get("BTRUN_STORE", "").strip()
    if env:
        return env
    if run_dir:
        parent = os.path.dirname(os.path.abspath(os.path.normpath(run_dir)))
        return os.path.join(parent, "site.sqlite")
    return os.path.join("runs", "site.sqlite")


def disabled(url: str | None) -> bool:
    """``--store none`` (or ``off``): record nothing."""
    return (url or "").strip().lower() in ("none", "off")


class InventoryStore:
    """Runs and their inventory rows in one database (see the module doc).

    >>> s = InventoryStore.open("sqlite:///:memory:")
    >>> s.begin_run("inv-1", mission="missions/inventory.xml")
    >>> s.record_rows("inv-1", [{"place": "A-01-1", "answer": "3A", "status": "identified"}])
    1
    >>> [r["answer"] for r in s.history("A-01-1")]
    ['3A']
    """

    def __init__(self, conn: Any, shown: str) -> None:
        self.conn, self.shown = conn, shown
        self.dialect = dialect_of(conn)

    # -- opening ----------------------------------------------------------------------------
    @classmethod
    def open(cls, url: str, create: bool = True) -> InventoryStore:
        """Open (and create or upgrade) the store at ``url``; :class:`StoreError` in one
        line if it cannot be reached or holds a newer schema."""
        u = parse_url(url)
        if u.kind == "postgresql":
            conn: Any = connect_postgresql(u.target)
        else:
            check = lambda c: cls(c, u.shown)._refuse_foreign(create)  # noqa: E731
            conn = connect_sqlite(u.target, create=create, check=check)
        store = cls(conn, u.shown)
        try:
            if u.kind == "postgresql":
                store._refuse_foreign(create)
            store._migrate()
        except StoreError:
            store.close()
            raise
        except db_errors() as exc:
            store.close()
            raise StoreError(f"{u.shown}: not a usable store ({_first_line(exc)})") from None
        return store

    def close(self) -> None:
        """Close the connection."""
        try:
            self.conn.close()
        except db_errors():
            pass

    def __enter__(self) -> InventoryStore:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def version(self) -> int:
        """The schema version of the store (0: empty)."""
        row = self.conn.execute("SELECT MAX(version) FROM store_schema").fetchone()
        return int(row[0] or 0)

    def _tables(self) -> set[str]:
        if self.dialect == "sqlite":
            q = "SELECT name FROM sqlite_master WHERE type = 'table'"
        else:
            q = "SELECT table_name FROM information_schema.tables "
            q += "WHERE table_schema = current_schema()"
        return {str(r[0]) for r in self.conn.execute(q)}

    def _refuse_foreign(self, create: bool) -> None:
        """:class:`StoreError` for a database that is not a btrun store: an SQLite file
        with other tables (a gallery named by mistake was made a store), tables named as
        the store's without its schema record (PostgreSQL: other tables are the site's
        own), or, for a command that only reads (``create`` False), no store at all; it
        is then left as it was."""
        tables = self._tables()
        if "store_schema" in tables:
            return
        clash = tables & {"runs", "inventory_rows"} if self.dialect == "postgresql" else tables
        if clash:
            names = ", ".join(sorted(clash)[:4]) + (", ..." if len(clash) > 4 else "")
            raise StoreError(f"{self.shown}: not a btrun site store (it holds tables {names})")
        if not create:
            raise StoreError(
                f"{self.shown}: no site store there yet (fly an inventory with --store, "
                "or btrun inventory import RUN_DIR)"
            )

    def _migrate(self) -> None:
        with self._tx():
            if self.dialect == "postgresql":
                self.conn.execute("SELECT pg_advisory_xact_lock(?)", (_SCHEMA_LOCK,))
            self.conn.execute(
                "CREATE TABLE IF NOT EXISTS store_schema "
                "(version BIGINT PRIMARY KEY, applied DOUBLE PRECISION NOT NULL)"
            )
            current = self.version()
            if current > SCHEMA_VERSION:
                raise StoreError(
                    f"{self.shown}: store schema {current}, this btrun knows up to "
                    f"{SCHEMA_VERSION}: use a newer btrun"
                )
            for version in range(current + 1, SCHEMA_VERSION + 1):
                for stmt in split_script(STEPS[version]):
                    self.conn.execute(stmt)
                self.conn.execute("INSERT INTO store_schema VALUES (?, ?)", (version, time.time()))

    def _tx(self) -> Any:
        """One write transaction (SQLite: ``BEGIN IMMEDIATE``, so a writer waits for the
        other at its start, never fails half-way on a lock upgrade)."""
        if self.dialect == "sqlite":
            return _SqliteImmediate(self.conn)
        return self.conn

    # -- writing ----------------------------------------------------------------------------
    def begin_run(
        self,
        run: str,
        mission: str | None = None,
        rig: str | None = None,
        fleet: str | None = None,
        seed: int | None = None,
        folder: str | None = None,
        started: float | None = None,
        host: str | None = None,
    ) -> None:
        """Record (or update) run ``run``. A run id already recorded by another host or
        folder is refused: two folders of one name must not mix their rows; unless it is
        the same flight (the same recorded ``started``): a run folder moved or archived,
        imported again from where it is now."""
        host = host if host is not None else socket.gethostname()
        folder = os.path.abspath(folder) if folder else None
        with self._tx():
            row = self.conn.execute(
                "SELECT host, folder, started FROM runs WHERE run = ?", (run,)
            ).fetchone()
            moved = started is not None and row is not None and row[2] is not None
            moved = moved and abs(float(row[2]) - started) < 1.0
            if row is not None and folder and row[1] and (row[0], row[1]) != (host, folder):
                if not moved:
                    raise StoreError(
                        f"{self.shown}: run {run} is already recorded from {row[0]}:{row[1]}; "
                        "name this run's folder differently (--out when flying; rename the "
                        "folder to import it)"
                    )
            self.conn.execute(
                "INSERT INTO runs (run, mission, rig, fleet, seed, host, folder, started) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT (run) DO UPDATE SET "
                "mission = COALESCE(excluded.mission, runs.mission), "
                "rig = COALESCE(excluded.rig, runs.rig), "
                "fleet = COALESCE(excluded.fleet, runs.fleet), "
                "seed = COALESCE(excluded.seed, runs.seed), "
                "host = excluded.host, folder = COALESCE(excluded.folder, runs.folder), "
                "started = COALESCE(runs.started, excluded.started)",
                (run, mission, rig, fleet, seed, host, folder, started or time.time()),
            )

    def check_run(self, run: str, folder: str, host: str | None = None) -> None:
        """Refuse (:class:`StoreError`) a run id that another host or folder recorded."""
        host = host if host is not None else socket.gethostname()
        row = self.conn.execute("SELECT host, folder FROM runs WHERE run = ?", (run,)).fetchone()
        if row is not None and row[1] and (row[0], row[1]) != (host, os.path.abspath(folder)):
            raise StoreError(
                f"{self.shown}: run {run} is already recorded from {row[0]}:{row[1]}; "
                "name this run's folder differently (--out when flying; rename the "
                "folder to import it)"
            )

    def record_rows(self, run: str, rows: Iterable[dict]) -> int:
        """Record inventory rows of ``run`` (each replaces the row of its place), in one
        transaction; the number of rows written. A row's ``run`` key is the run that
        found it (``origin``; default ``run``)."""
        now = time.time()
        values = []
        for r in rows:
            origin = r.get("origin") or r.get("run") or run
            values.append((run, *[origin if k == "origin" else r.get(k) for k in ROW_FIELDS], now))
        if not values:
            return 0
        cols = ", ".join(ROW_FIELDS)
        updates = ", ".join(f"{k} = excluded.{k}" for k in ROW_FIELDS[1:])
        with self._tx():
            self.conn.executemany(
                f"INSERT INTO inventory_rows (run, {cols}, recorded) "  # noqa: S608
                f"VALUES ({', '.join('?' * (len(ROW_FIELDS) + 2))}) "
                f"ON CONFLICT (run, place) DO UPDATE SET {updates}, recorded = excluded.recorded",
                values,
            )
        return len({v[1] for v in values})  # a place listed twice is one row

    def end_run(self, run: str, status: str, ended: float | None = None) -> None:
        """Mark ``run`` ended with the mission's ``status``."""
        with self._tx():
            self.conn.execute(
                "UPDATE runs SET status = ?, ended = ? WHERE run = ?",
                (status, ended or time.time(), run),
            )

    # -- reading ----------------------------------------------------------------------------
    def runs(self, limit: int | None = None) -> list[dict]:
        """The recorded runs, oldest first (the newest ``limit``), each with its row count."""
        q = f"SELECT {', '.join('r.' + k for k in RUN_FIELDS)}, "  # noqa: S608
        q += "(SELECT COUNT(*) FROM inventory_rows i WHERE i.run = r.run) FROM runs r "
        q += "ORDER BY r.started DESC, r.run DESC"
        if limit:
            q += f" LIMIT {int(limit)}"
        out = list(rows_as_dicts(self.conn.execute(q), (*RUN_FIELDS, "rows")))
        return out[::-1]

    def find_run(self, run: str) -> dict | None:
        """The run ``run`` as :meth:`run` gives it, None if the store has no such run."""
        cur = self.conn.execute(
            f"SELECT {', '.join(RUN_FIELDS)} FROM runs WHERE run = ?",  # noqa: S608
            (run,),
        )
        found = list(rows_as_dicts(cur, RUN_FIELDS))
        return found[0] if found else None

    def run(self, run: str) -> dict:
        """The run ``run``; :class:`StoreError` with a "did you mean" if it is unknown (a
        name that differs only in case first)."""
        found = self.find_run(run)
        if found is not None:
            return found
        names = [r[0] for r in self.conn.execute("SELECT run FROM runs")]
        same = [n for n in names if n.casefold() == run.casefold()]
        close = same[:1] or difflib.get_close_matches(run, names, n=1, cutoff=0.6)
        hint = f" (did you mean {close[0]}?)" if close else ""
        if not names:
            hint = " (the store has no run yet: fly one, or btrun inventory import RUN_DIR)"
        raise StoreError(f"{self.shown}: no run {run!r}{hint}")

    def rows(self, run: str) -> list[dict]:
        """Every inventory row of ``run``, by place."""
        self.run(run)
        cur = self.conn.execute(
            f"SELECT {', '.join(ROW_FIELDS)} FROM inventory_rows "  # noqa: S608
            "WHERE run = ? ORDER BY place",
            (run,),
        )
        return list(rows_as_dicts(cur, ROW_FIELDS))

    def history(self, place: str, limit: int | None = None) -> list[dict]:
        """What was found at ``place``, run by run (oldest first; the newest ``limit``):
        rows found by the run itself, with the run's start, status, ``rig`` and ``fleet``
        (what flew it: one store may hold several sites). A row a resumed run carried over
        is left out when the run that found it is in the store with that very finding (it
        is in that run's history); one whose finder is not (never recorded, or this very
        run under the folder's old name: a renamed or copied folder), or holds another
        answer there (a run of that name from another station), is the only record and is
        shown."""
        return self._found_rows("i.place = ?", place, limit)

    def answers_like(self, text: str, limit: int | None = None) -> list[dict]:
        """Rows whose answer contains ``text`` in any case (the caller picks the pallet's
        own), run by run (oldest first; the newest ``limit``), with the run's start and
        status; rows a resumed run carried over are left out as in :meth:`history`."""

        def like(t: str) -> str:
            return "%" + t.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_") + "%"

        # in any case (LOWER: Python's on SQLite, the database's on PostgreSQL), and as
        # written (the database's case folding may differ from Python's: final sigma, İ)
        where = "(LOWER(i.answer) LIKE ? ESCAPE '\\' OR i.answer LIKE ? ESCAPE '\\')"
        return self._found_rows(where, (like(text.lower()), like(text)), limit)

    def _found_rows(self, where: str, value: str | tuple, limit: int | None) -> list[dict]:
        """The rows matching ``where`` (``?`` given ``value``: one, or a tuple) that their
        own run found (see :meth:`history`), with the run's start and status, oldest first."""
        keys = ("run", "started", "run_status", "rig", "fleet", *ROW_FIELDS)
        q = "SELECT i.run, r.started, r.status, r.rig, r.fleet, "
        q += ", ".join(f"i.{k}" for k in ROW_FIELDS)
        q += " FROM inventory_rows i JOIN runs r ON r.run = i.run "
        q += f"WHERE {where} AND (i.origin IS NULL OR i.origin = i.run "
        q += "OR NOT EXISTS (SELECT 1 FROM inventory_rows o WHERE o.run = i.origin "
        q += "AND o.place = i.place AND (o.answer = i.answer "
        q += "OR (o.answer IS NULL AND i.answer IS NULL)))) "
        q += "ORDER BY r.started DESC, i.run DESC, i.place"
        if limit:
            q += f" LIMIT {int(limit)}"
        params = value if isinstance(value, tuple) else (value,)
        return list(rows_as_dicts(self.conn.execute(q, params), keys))[::-1]

    def counts(self) -> dict[str, tuple[int, int]]:
        """Run -> (rows, answered rows: every status but ``not_scanned``), in one query.

        >>> s = InventoryStore.open("sqlite:///:memory:")
        >>> s.begin_run("inv-1")
        >>> s.record_rows("inv-1", [{"place": "A", "status": "identified"},
        ...                         {"place": "B", "status": "not_scanned"}])
        2
        >>> s.counts()
        {'inv-1': (2, 1)}
        """
        cur = self.conn.execute(
            "SELECT run, COUNT(*), SUM(CASE WHEN status = 'not_scanned' THEN 0 ELSE 1 END) "
            "FROM inventory_rows GROUP BY run"
        )
        return {r[0]: (int(r[1]), int(r[2] or 0)) for r in cur}

    def places(self) -> list[str]:
        """Every place with a row in the store."""
        cur = self.conn.execute("SELECT DISTINCT place FROM inventory_rows ORDER BY place")
        return [r[0] for r in cur]

    def diff_warning(self, run_a: str, run_b: str) -> str | None:
        """Why a diff of runs ``run_a`` and ``run_b`` may compare two sites (they were flown
        by different rigs or fleets: a place of one name may be another rack), else None."""
        a, b = self.run(run_a), self.run(run_b)
        fa, fb = flown_by(a), flown_by(b)
        if fa is None or fb is None or fa == fb:
            return None
        return (
            f"{run_a} was flown by {fa}, {run_b} by {fb}: if they are different sites, "
            "places of one name are different racks and every change below is meaningless"
        )

    def diff(self, run_a: str, run_b: str) -> list[dict]:
        """What changed from run ``run_a``'s inventory to ``run_b``'s, place by place:
        ``change`` is ``appeared`` (empty in A, a pallet in B), ``disappeared`` (a pallet
        in A, empty in B), ``turned`` (the same pallet showing its other side: ``109A`` ->
        ``109B``), ``changed`` (another answer), ``only in A`` / ``only in B`` (the place
        has an answer in one run only). Unchanged places are left out."""
        return diff_rows(self.rows(run_a), self.rows(run_b))


class _SqliteImmediate:
    """``with``: BEGIN IMMEDIATE ... COMMIT (ROLLBACK on an exception) on an sqlite3
    connection."""

    def __init__(self, conn: Any) -> None:
        self.conn = conn

    def __enter__(self) -> Any:
        if self.conn.in_transaction:
            self.conn.commit()
        self.conn.execute("BEGIN IMMEDIATE")
        return self.conn

    def __exit__(self, kind: Any, *rest: Any) -> None:
        if kind is None:
            self.conn.commit()
        else:
            self.conn.rollback()


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def open_store(url: str | None, create: bool = True) -> InventoryStore:
    """:meth:`InventoryStore.open` of ``url`` (None: :func:`default_url`)."""
    return InventoryStore.open(url or default_url(), create=create)


__all__ = [
    "ROW_FIELDS",
    "SCHEMA_VERSION",
    "STEPS",
    "InventoryStore",
    "StoreError",
    "default_url",
    "disabled",
    "flown_by",
    "open_store",
]
