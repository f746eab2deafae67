"""Run folders into the site store: ``btrun inventory import RUN_DIR...``.

A run flown before the store existed, or while it was away (its rows stay in the run
folder: the source of truth), is loaded from its ``inventory.json``, tick log header or
fleet record and ``summary.json``.
"""

from __future__ import annotations

import os

from nodes.inventory_log import InventoryError, read_inventory
from nodes.site.recording import flown_as, read_json, run_id, run_info
from store import InventoryStore, StoreError

#: two recorded starts this close (s) are one flight (as the store's own check has it)
_SAME_FLIGHT_S = 1.0


def check_run(run_dir: str) -> list[dict]:
    """The rows of run folder ``run_dir`` as :func:`import_run` would record them;
    :class:`StoreError` for a folder it would refuse (nothing is written)."""
    if not os.path.isdir(run_dir):
        raise StoreError(f"{run_dir}: no such run folder")
    parent = os.path.dirname(os.path.abspath(run_dir))
    if os.path.basename(parent) == "drones" and os.path.exists(
        os.path.join(os.path.dirname(parent), "fleet.json")
    ):
        fleet = os.path.dirname(parent)
        raise StoreError(
            f"{run_dir}: one drone's folder of the fleet run {fleet}: import the fleet's "
            "folder (its inventory merges every drone's)"
        )
    if not os.path.exists(os.path.join(run_dir, "inventory.json")):
        raise StoreError(f"{run_dir}: not an inventory run (no inventory.json)")
    try:
        return read_inventory(run_dir)
    except InventoryError as exc:
        raise StoreError(str(exc)) from None


def import_run(store: InventoryStore, run_dir: str) -> int:
    """Record the run folder ``run_dir`` (its ``inventory.json``, tick log or fleet record
    and ``summary.json``) in ``store``; the number of rows. Idempotent: importing again
    replaces. :class:`StoreError` for a folder without an inventory."""
    rows = check_run(run_dir)
    run = run_id(run_dir)
    info = run_info(run_dir, imported=True)
    rows = own_rows(store, run, flown_as(run_dir), info.get("started"), rows)
    store.begin_run(run, **info)
    n = store.record_rows(run, rows)
    status = read_json(os.path.join(run_dir, "summary.json")).get("status")
    ended_by = os.path.join(run_dir, "summary.json")
    if not isinstance(status, str) and os.path.exists(os.path.join(run_dir, "fleet.json")):
        status, ended_by = _fleet_status(run_dir)  # killed: no fleet summary, its drones'
    if isinstance(status, str):
        try:
            ended = os.path.getmtime(ended_by)
        except OSError:
            ended = None
        store.end_run(run, status, ended)
    return n


def own_rows(
    store: InventoryStore,
    run: str,
    flown: str | None,
    started: float | None,
    rows: list[dict],
) -> list[dict]:
    """The rows of run ``run`` (flown as ``flown``, from ``started``) with the rows it
    found itself under its old name given its new one. A renamed folder's rows still say
    the name it flew under (their ``run``, the store's ``origin``), and the store leaves a
    row out of the history when its origin run holds it; when the store's run of that name
    is another flight (another station's ``inv-001``, another start) the rows were this
    run's, and would have vanished from the history behind it. The same flight recorded
    under the old name (an archived copy imported again) keeps them as its own; rows a
    resumed run carried over from another run keep that run as their origin."""
    if not flown or flown == run:
        return rows
    recorded = store.find_run(flown)
    then = recorded.get("started") if recorded else None
    if then is not None and started is not None and abs(float(then) - started) < _SAME_FLIGHT_S:
        return rows  # a copy of the flight the store holds under its old name
    return [
        {**r, "run": run, "origin": run} if (r.get("origin") or r.get("run")) == flown else r
        for r in rows
    ]


def _fleet_status(run_dir: str) -> tuple[str | None, str]:
    """A killed fleet wrote no summary.json; each drone's guard wrote the drone's: the
    fleet's status is theirs (ABORTED if one was, else FAILURE if one was, else SUCCESS),
    None if no drone has one (the newest summary is the end's time)."""
    drones = os.path.join(run_dir, "drones")
    found, missing = [], 0
    for name in sorted(os.listdir(drones)) if os.path.isdir(drones) else []:
        if not os.path.isdir(os.path.join(drones, name)):
            continue
        path = os.path.join(drones, name, "summary.json")
        status = read_json(path).get("status")
        if isinstance(status, str):
            found.append((status, path))
        else:
            missing += 1
    if not found:
        return None, run_dir
    statuses = {s for s, _ in found} | ({"ABORTED"} if missing else set())
    status = next((s for s in ("ABORTED", "FAILURE") if s in statuses), "SUCCESS")
    newest = max((p for _, p in found), key=lambda p: os.path.getmtime(p))
    return status, newest


__all__ = ["check_run", "import_run", "own_rows"]
