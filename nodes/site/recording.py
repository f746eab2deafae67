"""A run's inventory into the site store: the recorder of a run, and run folders imported.

:func:`recorder_for` gives an inventory log (``nodes.inventory_log.InventoryLog``) its
recorder from the mission's resources: the ``store`` URL (``--store``; None: the default
store beside the run folder, ``docs/store.md``), opened before flight so an unusable store
is one located problem (exit 2). A fleet's drones record nothing themselves: the fleet's
merged log records (:func:`fleet_recorder`).

:func:`nodes.site.importer.import_run` loads a run folder written before (or while the
store was away) into a store: ``btrun inventory import``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from typing import Any

from bt_engine.files import read_text
from bt_engine.ticklog import run_started
from store import default_url, disabled
from store.recorder import RunRecorder, start_recorder


def run_id(run_dir: str) -> str:
    """A run's id in the store: its folder's name."""
    return os.path.basename(os.path.normpath(run_dir))


def read_json(path: str, limit: int = 2_000_000) -> dict:
    """The JSON object in ``path`` (a run record: bounded, regular file), {} if there is
    none or it is not one."""
    if not os.path.isfile(path):
        return {}
    text = read_text(path, [], what="run records", limit=limit)
    try:
        data = json.loads(text or "")
    except (ValueError, RecursionError):
        return {}
    return data if isinstance(data, dict) else {}


def _header(run_dir: str) -> dict:
    try:
        with open(os.path.join(run_dir, "ticks.jsonl"), encoding="utf-8") as f:
            header = json.loads(f.readline(1_000_000)).get("header")
    except (OSError, ValueError, AttributeError, RecursionError):
        return {}
    return header if isinstance(header, dict) else {}


def _text(v: Any) -> str | None:
    return v if isinstance(v, str) and v else None


def _started(run_dir: str, header: dict, fleet: dict) -> float | None:
    """When an imported run started: :func:`bt_engine.ticklog.run_started` (its recorded
    start, else its default folder name's stamp), else the oldest of its record files'
    times."""
    started = run_started(run_id(run_dir), fleet, header)
    if started is not None:
        return started
    times = []
    for name in ("fleet.json", "ticks.jsonl", "inventory.json"):
        try:
            times.append(os.path.getmtime(os.path.join(run_dir, name)))
        except OSError:
            pass
    return min(times) if times else None


def run_info(run_dir: str, imported: bool = False) -> dict[str, Any]:
    """What the store keeps of a run folder (:meth:`InventoryStore.begin_run` keywords):
    mission, rig and seed from its tick log's header (a fleet: ``fleet.json`` and
    ``summary.json``), the folder; ``imported``: the start too (a live run's is now)."""
    header = _header(run_dir)
    fleet = read_json(os.path.join(run_dir, "fleet.json"))
    info: dict[str, Any] = {"folder": os.path.abspath(run_dir)}
    if fleet:
        summary = read_json(os.path.join(run_dir, "summary.json"))
        name = _text(summary.get("fleet")) or _text(fleet.get("fleet"))
        info["fleet"] = os.path.splitext(os.path.basename(name))[0] if name else None
        info["mission"] = _text(summary.get("mission"))
        seed = fleet.get("seed")
    else:
        info["mission"] = _text(header.get("mission"))
        info["rig"] = _text(header.get("rig"))
        seed = header.get("seed")
    info["seed"] = seed if type(seed) is int else None
    if imported:
        info["started"] = _started(run_dir, header, fleet)
    return info


def flown_as(run_dir: str) -> str | None:
    """The run id the folder ``run_dir`` had when it flew (the name of the folder its
    ``fleet.json`` or tick log header records: its rows' ``run`` says that name after the
    folder is renamed), None if neither records it."""
    fleet = read_json(os.path.join(run_dir, "fleet.json"))
    for record in (fleet, _header(run_dir)):
        flown = record.get("run_dir") if record else None
        if isinstance(flown, str) and flown.strip() and "\0" not in flown:
            return run_id(flown.replace("\\", "/")) or None
    return None


def _say(resources: dict) -> Callable[[str], None] | None:
    echo = resources.get("store_echo")
    return echo if callable(echo) else None


def open_recorder(
    url: str | None, run_dir: str, say: Any = None, extra: dict[str, Any] | None = None
) -> RunRecorder | None:
    """The recorder of run folder ``run_dir`` into ``url`` (None: the default store;
    ``none``: no recorder); ``extra``: run facts known better than the folder tells
    (a fleet's name and mission). :class:`StoreError` (one line) if the store cannot be
    used."""
    if disabled(url):
        return None
    url = url or default_url(run_dir)

    def info() -> dict[str, Any]:
        return {**run_info(run_dir), **(extra or {})}

    return start_recorder(url, run_id(run_dir), run_dir, info, say)


def recorder_for(resources: dict) -> RunRecorder | None:
    """The recorder of a mission's inventory (None: no run folder, a fleet's drone, or
    ``--store none``); raises :class:`StoreError` if the store cannot be used."""
    run_dir = resources.get("run_dir")
    if not run_dir or resources.get("inventory_sink") is not None:
        return None
    return open_recorder(resources.get("store"), run_dir, _say(resources))


def finish_recording(resources: dict, run_dir: str | None) -> None:
    """The run is over: mark it ended in the store with summary.json's status (``ended``
    if there is none), then let the recorder go."""
    log = resources.get("inventory")
    recorder = getattr(log, "recorder", None)
    if recorder is None:
        return
    status = read_json(os.path.join(run_dir, "summary.json")).get("status") if run_dir else None
    recorder.finish(status if isinstance(status, str) else "ended")
    log.recorder = None


__all__ = [
    "finish_recording",
    "flown_as",
    "open_recorder",
    "recorder_for",
    "run_id",
    "run_info",
]
