"""Run folders into the site store: ``btrun inventory import RUN_DIR...``.

A run flown before the store existed, or while it was away (its rows stay in the run
folder: the source of truth), is loaded from its ``inventory.json``, tick log header or
fleet record and ``summary.json``.
"""

from __future__ import annotations

import os

from nodes.inventory_log import InventoryError, read_inventory
from nodes.site.recording import read_json, run_id, run_info
from store import InventoryStore, StoreError


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
    store.begin_run(run, **run_info(run_dir, imported=True))
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


__all__ = ["import_run"]
