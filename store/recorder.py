"""Recording a run's inventory rows into the site store as the run writes them.

A :class:`RunRecorder` takes every state of the run's inventory (:meth:`RunRecorder.record`,
called at each row) and writes the rows that changed on a thread of its own, so a slow or
unreachable store never holds up a tick: the flight goes on, the run folder's files stay
the source of truth, and a message says what the store missed. Rows that failed are tried
again with the next write (the store coming back gets them all). :meth:`RunRecorder.finish`
marks the run ended and waits (bounded) for the last rows; a recorder never finished is
flushed when the process exits.
"""

from __future__ import annotations

import atexit
import sys
import threading
from collections.abc import Callable
from typing import Any

from store.db import StoreError, db_errors
from store.inventory import InventoryStore

#: How long the end of a run waits for the store to take its last rows, in s.
FINISH_TIMEOUT_S = 15.0


class RunRecorder:
    """The store side of one run's inventory (see the module doc).

    ``store``: an open :class:`InventoryStore` (checked before flight), closed by the
    recorder; ``url``: to reconnect after a failure; ``info``: called once on the
    recorder's thread, the run's :meth:`InventoryStore.begin_run` keywords (mission, rig,
    seed... read from the run folder once it exists); ``say``: where messages go.
    """

    def __init__(
        self,
        store: InventoryStore,
        url: str,
        run: str,
        info: Callable[[], dict[str, Any]] | None = None,
        say: Callable[[str], None] | None = None,
        folder: str | None = None,
    ) -> None:
        self.store: InventoryStore | None = store
        self.folder = folder or "RUN_DIR"  # said in the import command a user may need
        self.url, self.run = url, run
        self.shown = store.shown
        self._info = info or dict
        self._say = say or (lambda m: print(f"btrun: {m}", file=sys.stderr, flush=True))
        self._pending: dict[str, dict] = {}  # place -> the latest row not yet written
        self._queued: dict[str, dict] = {}  # place -> the latest row handed over
        self._end: str | None = None
        self._begun = False
        self._failing = False
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._idle = threading.Event()
        self._idle.set()
        self._stop = False
        self.written = 0
        self._thread = threading.Thread(target=self._loop, name="btrun-store", daemon=True)
        self._thread.start()
        atexit.register(self.close)

    # -- the run's side (never blocks on the store) ----------------------------------------
    def record(self, rows: list[dict]) -> None:
        """The run's inventory as it is now: its changed rows are written soon."""
        with self._lock:
            for r in rows:
                place = r.get("place")
                if place and self._queued.get(place) != r:
                    self._queued[place] = dict(r)
                    self._pending[place] = dict(r)
            self._idle.clear()
        self._wake.set()

    def finish(self, status: str, timeout: float = FINISH_TIMEOUT_S) -> bool:
        """Mark the run ended with ``status``, wait up to ``timeout`` s for the store, then
        close it; True if everything was written."""
        with self._lock:
            self._end = status
            self._idle.clear()
        self._wake.set()
        done = self._idle.wait(timeout)
        if not done:
            self._say(
                f"store {self.shown}: the last rows of {self.run} are not recorded yet; the "
                f"run folder has them (btrun inventory import {self.folder} --store ...)"
            )
        ok = done and not self._failing
        self.close(timeout=0.0)
        return ok

    def close(self, timeout: float = FINISH_TIMEOUT_S) -> None:
        """Write what is pending (bounded wait), stop the thread, close the store."""
        if self._stop:
            return
        self._wake.set()
        self._idle.wait(timeout)
        self._stop = True
        self._wake.set()
        self._thread.join(timeout=2.0)
        atexit.unregister(self.close)
        if self.store is not None and not self._thread.is_alive():
            self.store.close()
            self.store = None

    # -- the recorder's thread -------------------------------------------------------------
    def _loop(self) -> None:
        while not self._stop:
            self._wake.wait(timeout=5.0 if self._failing else None)
            self._wake.clear()
            if self._stop:
                break
            self._drain()

    def _drain(self) -> None:
        with self._lock:
            rows, self._pending = self._pending, {}
            end = self._end
        try:
            store = self._connected()
            if not self._begun:
                store.begin_run(self.run, **self._info())
                self._begun = True
            if rows:
                self.written += store.record_rows(self.run, list(rows.values()))
            if end is not None:
                store.end_run(self.run, end)
            if self._failing:
                self._say(f"store {self.shown}: recording again ({self.run})")
            self._failing = False
            with self._lock:
                if end is not None and self._end == end:
                    self._end = None
                if not self._pending and self._end is None:
                    self._idle.set()
        except Exception as exc:  # the flight goes on; the run folder keeps the rows
            with self._lock:
                for place, row in rows.items():
                    self._pending.setdefault(place, row)  # a newer row wins
            if not self._failing:
                why = str(exc).strip().splitlines()[0] if str(exc).strip() else repr(exc)
                self._say(
                    f"store {self.shown}: cannot record {self.run} ({why}); the flight goes "
                    "on and the run folder keeps every row; trying again"
                )
            self._failing = True
            self._drop_connection()

    def _connected(self) -> InventoryStore:
        if self.store is None:
            self.store = InventoryStore.open(self.url)
        return self.store

    def _drop_connection(self) -> None:
        if self.store is not None:
            try:
                self.store.close()
            except db_errors():
                pass
            self.store = None


def start_recorder(
    url: str,
    run: str,
    folder: str,
    info: Callable[[], dict[str, Any]] | None = None,
    say: Callable[[str], None] | None = None,
) -> RunRecorder:
    """Open the store at ``url`` now (before flight: :class:`StoreError` in one line if it
    cannot be used, or if another host or folder recorded a run of this name) and start
    recording run ``run`` (its folder ``folder``)."""
    store = InventoryStore.open(url)
    try:
        store.check_run(run, folder)
    except StoreError:
        store.close()
        raise
    except db_errors() as exc:
        store.close()
        raise StoreError(f"{store.shown}: {exc}".splitlines()[0]) from None
    return RunRecorder(store, url, run, info, say, folder)


__all__ = ["FINISH_TIMEOUT_S", "RunRecorder", "start_recorder"]
