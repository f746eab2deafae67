"""The site store as the console sees it (docs/store.md): the runs it knows that have no
folder under ``--runs`` (recorded by another ground station, or a folder moved away) and a
place's history across runs.

The store is only read. It is opened once at start (:func:`check_store`: an unreachable
store is one line and exit code 2); later a store that fails (a lost server, a removed
file) is a note on the pages, which keep working from the runs folder, and it is tried
again at most every :data:`RETRY_S` seconds, so a dead server never holds up a page for
its connect timeout on every request.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from typing import Any, NoReturn, TypeVar

from nodes.console.paths import PathRefused, RunsRoot
from nodes.place_evidence import PLACE_NAME
from nodes.site.cli import close_place
from store import InventoryStore, StoreError, disabled, parse_url, redact
from store.db import db_errors

#: seconds before a store that failed is tried again
RETRY_S = 10.0
#: the newest runs of a place's history shown
HISTORY_LIMIT = 200
#: the store file the console uses by default when the runs folder has one
DEFAULT_FILE = "site.sqlite"
T = TypeVar("T")


def resolve_url(given: str | None, runs: str) -> str | None:
    """The store the console reads: ``--store URL`` (``none``: no store), else
    ``$BTRUN_STORE``, else ``RUNS/site.sqlite`` if that file exists, else None."""
    if given is not None:
        return None if disabled(given) else given
    env = os.environ.get("BTRUN_STORE", "").strip()
    if env:
        return None if disabled(env) else env
    path = os.path.join(runs, DEFAULT_FILE)
    return path if os.path.isfile(path) else None


def open_read(url: str) -> InventoryStore:
    """The store at ``url``, never created (a missing SQLite file is a
    :class:`StoreError`, not a new empty store)."""
    return InventoryStore.open(url, create=False)


def check_store(url: str) -> str:
    """Open and close the store once; its URL as shown (no password), or
    :class:`StoreError` in one line."""
    with open_read(url) as s:
        s.runs(limit=1)
        return s.shown


def check_place(place: str) -> str:
    """``place`` if it is a place name (:data:`nodes.place_evidence.PLACE_NAME`, no
    ``..``), else :class:`PathRefused` (400)."""
    if not isinstance(place, str) or not PLACE_NAME.fullmatch(place) or ".." in place:
        raise PathRefused(f"place name {place!r:.80} refused", 400)
    return place


def _status_of(status: Any) -> str:
    return status if isinstance(status, str) and status else "unknown"


class SiteStore:
    """One connection to the store, shared by the console's threads under a lock, opened
    again after a failure (not sooner than :data:`RETRY_S`)."""

    def __init__(self, url: str) -> None:
        self.url = url
        try:
            self.shown = parse_url(url).shown
        except StoreError:
            self.shown = redact(url)
        self._store: InventoryStore | None = None
        self._lock = threading.Lock()
        self._failed_at = 0.0
        self.error: str | None = None

    def close(self) -> None:
        """Close the connection (the next read opens it again)."""
        with self._lock:
            if self._store is not None:
                self._store.close()
                self._store = None

    def _use(self, read: Callable[[InventoryStore], T]) -> T:
        """``read(store)``; :class:`StoreError` (and :attr:`error` set) if the store cannot
        be read now."""
        with self._lock:
            store = self._store
            if store is None:
                if self.error is not None and time.monotonic() - self._failed_at < RETRY_S:
                    raise StoreError(self.error)
                try:
                    store = self._store = open_read(self.url)
                except StoreError as exc:
                    self._fail(str(exc))
            try:
                value = read(store)
            except db_errors() as exc:
                store.close()
                self._store = None
                text = str(exc).strip()
                self._fail(f"{self.shown}: cannot read ({text.splitlines()[0] if text else exc!r})")
            self.error = None
            return value

    def _fail(self, message: str) -> NoReturn:
        self.error, self._failed_at = message, time.monotonic()
        raise StoreError(message)

    def other_runs(self, root: RunsRoot, limit: int) -> list[dict]:
        """The store's runs without a folder under ``root``, newest first (at most
        ``limit``), shaped like :func:`nodes.console.runs.run_info`'s entries with
        ``source`` ``store`` (and the host that recorded them); :class:`StoreError` if the
        store cannot be read."""
        runs, counts = self._use(lambda s: (s.runs(limit), s.counts()))
        out = []
        for r in reversed(runs):  # the store lists them oldest first
            if _has_folder(root, r["run"]):
                continue
            rows, answered = counts.get(r["run"], (0, 0))
            mission = r.get("mission") if isinstance(r.get("mission"), str) else ""
            out.append(
                {
                    "name": r["run"],
                    "kind": "fleet" if r.get("fleet") else "run",
                    "mission": os.path.basename(mission),
                    "status": _status_of(r.get("status")),
                    "started": r.get("started"),
                    "modified": r.get("ended") or r.get("started"),
                    "places": rows,
                    # the store records the rows a run wrote, not the places it planned: a
                    # run that did not finish may have planned more than it answered
                    "places_known": rows > answered or _status_of(r.get("status")) == "SUCCESS",
                    "answered": answered,
                    "accuracy": None,
                    "discrepancies": {},
                    "exceptions": 0,
                    "reviewed": 0,
                    "drones": [],
                    "error": None,
                    "source": "store",
                    "host": r.get("host"),
                }
            )
        return out

    def history(self, root: RunsRoot, place: str) -> list[dict]:
        """What the store holds of ``place`` run by run, oldest first (the newest
        :data:`HISTORY_LIMIT`), each with ``here`` (the run has a folder under ``root``);
        :class:`PathRefused` for a bad place name (400) or one the store has no row for
        (404, with a "did you mean"); :class:`StoreError` if the store cannot be read."""
        check_place(place)

        def read(s: InventoryStore) -> tuple[list[dict], list[str]]:
            found = s.history(place, HISTORY_LIMIT)
            return found, ([] if found else s.places())

        found, places = self._use(read)
        if not found:
            close = close_place(place, places)  # case and leading zeros first
            hint = f" (did you mean {close[0]}?)" if close else ""
            raise PathRefused(f"the store has no row for place {place!r}{hint}", 404)
        keys = ("run", "started", "answer", "status", "best_id", "distance", "margin")
        keys += ("drone", "reason", "run_status", "rig", "fleet")
        out = [{**{k: h.get(k) for k in keys}, "here": _has_folder(root, h["run"])} for h in found]
        for h in out:  # the rig file's name: another station's folders are not shown
            if isinstance(h["rig"], str):
                h["rig"] = os.path.basename(h["rig"].replace("\\", "/")) or None
        return out


def _has_folder(root: RunsRoot, run: Any) -> bool:
    """Whether run ``run`` is a folder under the runs folder (a name that cannot be one is
    not)."""
    try:
        root.run_dir(run)
    except PathRefused:
        return False
    return True
