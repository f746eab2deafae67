"""What the console shows of a run folder: its kind, status, rows, rack layout, tracks,
evidence per place and review decisions, read with bounded reads and never written.

A solo inventory (``btrun missions/inventory.xml``) is a folder with ``ticks.jsonl`` and
``inventory.json``; a fleet (``btrun fleet``) has ``fleet.json`` and one folder per drone in
``drones/<name>/``. ``summary.json`` appears when a run ends; until then a run whose tick log
grew in the last :data:`RUNNING_WITHIN_S` seconds is ``RUNNING``.
"""

from __future__ import annotations

import json
import os
import re
import time
from typing import Any

from bt_engine.ticklog import header_path, run_started
from nodes.console.files import ReviewFileError, read_header, read_json, read_review
from nodes.console.paths import NAME, PathRefused, RunsRoot, plain
from nodes.inventory_log import EMPTY, UNKNOWN, InventoryError, grade, read_inventory
from nodes.place_evidence import CANDIDATES_FILE, PLACES_DIR

#: a run whose tick log changed this recently and has no summary is running
RUNNING_WITHIN_S = 30.0
#: the largest tick log read for a track, bytes (a 20-minute flight at 50 Hz is ~15 MB)
MAX_TICKS_BYTES = 256_000_000
#: track points kept per drone (the tick log is decimated to about this many)
TRACK_POINTS = 2_000
#: runs listed on the index page at most
MAX_RUNS = 500
#: statuses and discrepancy categories an operator reviews
REVIEW_STATUSES = ("unknown", "not_identified", "unverified", "mismatch")
PLACE_CODE = re.compile(r"^([A-Za-z]+)-(\d+)-(\d+)$")


def drone_dirs(run_dir: str) -> dict[str, str]:
    """Drone name -> folder relative to the run (``"."`` for a solo run)."""
    drones = os.path.join(run_dir, "drones")
    if os.path.isdir(drones) and plain(drones):
        names = sorted(n for n in os.listdir(drones) if NAME.fullmatch(n) and ".." not in n)
        return {
            n: f"drones/{n}"
            for n in names
            if os.path.isdir(os.path.join(drones, n)) and plain(os.path.join(drones, n))
        }
    return {"": "."}


def is_run(path: str) -> bool:
    """Whether a folder looks like a btrun run or fleet folder."""
    return any(
        os.path.exists(os.path.join(path, f))
        for f in ("ticks.jsonl", "fleet.json", "summary.json", "inventory.json")
    )


def _mtime(path: str) -> float:
    try:
        return os.stat(path).st_mtime
    except OSError:
        return 0.0


def run_status(run_dir: str, summary: Any) -> str:
    """SUCCESS / FAILURE / ABORTED from summary.json; else RUNNING or INCOMPLETE."""
    if isinstance(summary, dict) and isinstance(summary.get("status"), str):
        return summary["status"]
    newest = max(
        (_mtime(os.path.join(run_dir, d, "ticks.jsonl")) for d in drone_dirs(run_dir).values()),
        default=0.0,
    )
    newest = max(newest, _mtime(os.path.join(run_dir, "inventory.json")))
    return "RUNNING" if time.time() - newest < RUNNING_WITHIN_S else "INCOMPLETE"


def read_rows(run_dir: str) -> tuple[list[dict], list[str], str | None]:
    """The inventory rows (checked by :func:`nodes.inventory_log.read_inventory`), the
    planned places and an error line (None if fine)."""
    inv = os.path.join(run_dir, "inventory.json")
    if os.path.lexists(inv) and not plain(inv):
        return (
            [],
            [],
            f"{inv}: reached through a link, not read (the console reads a run's own files)",
        )
    try:
        rows = read_inventory(run_dir)
    except InventoryError as exc:
        return [], [], str(exc)
    doc = read_json(os.path.join(run_dir, "inventory.json"), 64_000_000) or {}
    planned = doc.get("planned") if isinstance(doc, dict) else None
    planned = [p for p in planned if isinstance(p, str)] if isinstance(planned, list) else []
    return with_discrepancies(run_dir, rows), planned, None


def with_discrepancies(run_dir: str, rows: list[dict]) -> list[dict]:
    """The rows with their discrepancy against the expected stock (``discrepancy``,
    ``expected``, ``moved_from``) when the run wrote ``discrepancies.json``
    (:mod:`nodes.discrepancy`); the rows as they are otherwise."""
    doc = read_json(os.path.join(run_dir, "discrepancies.json"))
    if not isinstance(doc, dict) or doc.get("format") != "btrun-discrepancies-1":
        return rows
    found = {
        d["place"]: d
        for d in doc.get("rows") or []
        if isinstance(d, dict) and isinstance(d.get("place"), str)
    }
    out = []
    for r in rows:
        d = found.get(r["place"])
        if d is not None and isinstance(d.get("category"), str):
            r = {**r, "discrepancy": d["category"]}
            for key in ("expected", "moved_from"):
                if isinstance(d.get(key), str):
                    r[key] = d[key]
        out.append(r)
    seen = {r["place"] for r in rows}
    for place, d in found.items():  # expected places not scanned (yet): in the report too
        if place not in seen and isinstance(d.get("category"), str):
            row = {"place": place, "status": "not_scanned", "discrepancy": d["category"]}
            if isinstance(d.get("expected"), str):
                row["expected"] = d["expected"]
            out.append(row)
    return out


def discrepancy(row: dict) -> str | None:
    """The row's discrepancy category against an expected stock, if the run had one
    (``discrepancy``/``category`` column, or a ``mismatch``/``unverified`` status)."""
    for key in ("discrepancy", "category"):
        v = row.get(key)
        if isinstance(v, str) and v:
            return v
    status = row.get("status")
    return status if status in ("mismatch", "unverified") else None


def reviewed_discrepancies(rows: list[dict], decisions: list[dict]) -> dict[str, dict]:
    """Place -> ``{"category", "moved_from", "expected"}`` of every reviewed place of a run
    that had an expected stock (its rows carry ``discrepancy``): the category of the
    reviewed answer against what the stock expected there
    (:func:`nodes.discrepancy.categorise`), and for a ``mismatch`` or an ``unexpected``
    pallet the place of the run where the stock expects it. A reviewed answer that is the
    expected pallet is ``confirmed``, no more a ``mismatch`` moved from elsewhere."""
    from nodes.discrepancy import MISMATCH, UNEXPECTED, UNLISTED, categorise
    from perception.expected import pallet_key

    latest = {d["place"]: d for d in decisions if isinstance(d.get("place"), str)}
    if not latest:
        return {}
    where: dict[str, str] = {}
    for r in rows:
        expected = r.get("expected")
        if r.get("discrepancy") and r.get("discrepancy") != UNLISTED and expected:
            where.setdefault(pallet_key(str(expected)), r["place"])
    out = {}
    for r in rows:
        d = latest.get(r["place"])
        cat = r.get("discrepancy")
        if d is None or not isinstance(cat, str) or not cat:
            continue
        expected = None if cat == UNLISTED else str(r.get("expected") or "")
        answer = d.get("answer") if isinstance(d.get("answer"), str) else ""
        category, found = categorise(expected, answer or UNKNOWN)
        moved = ""
        if category in (MISMATCH, UNEXPECTED) and found not in (UNKNOWN, EMPTY):
            moved = where.get(pallet_key(found), "")
            moved = "" if moved == r["place"] else moved
        out[r["place"]] = {"category": category, "moved_from": moved, "expected": expected}
    return out


def needs_review(row: dict) -> bool:
    """An exception for the operator: unknown, not identified, unverified or a mismatch."""
    return (
        row.get("status") in REVIEW_STATUSES
        or row.get("answer") == UNKNOWN
        or discrepancy(row) in ("mismatch", "unverified")
    )


def _start_time(name: str, run_dir: str, fleet: Any, header: dict, ticks: str) -> float:
    """The run's start, seconds since 1970: :func:`bt_engine.ticklog.run_started` (its
    recorded start, else its default folder name's stamp), else ``fleet.json``'s or the
    tick log's file time (the time of a copy, not of the run)."""
    started = run_started(name, fleet, header)
    if started is not None:
        return started
    fleet_json = os.path.join(run_dir, "fleet.json")
    return _mtime(fleet_json) if os.path.exists(fleet_json) else _mtime(ticks)


#: the most earlier runs whose start a resumed run's export looks up
_MAX_EARLIER_RUNS = 20


def run_starts(root: RunsRoot, name: str, record: Any, started: float, rows: list) -> dict:
    """Run name -> its start (seconds since 1970, None: not known) for every ``run`` the
    rows name: a resumed run carries rows answered in earlier runs, whose times count from
    their own run's start (a run folder beside this one, found by name). The run's own name
    is its folder's and the one it had when it flew (``record``: fleet.json or the tick
    log's header, ``run_dir``); a run from before that was recorded takes a name it cannot
    find for its own."""
    recorded = record.get("run_dir") if isinstance(record, dict) else None
    own = {name}
    if isinstance(recorded, str) and recorded:
        own.add(os.path.basename(os.path.normpath(recorded)))
    out: dict[str, float | None] = dict.fromkeys(own, started)
    others = sorted({r.get("run") for r in rows if isinstance(r.get("run"), str)} - own - {""})
    for other in others[:_MAX_EARLIER_RUNS]:
        try:
            other_dir = root.run_dir(other)
        except PathRefused:
            out[other] = None if isinstance(recorded, str) else started
            continue
        fleet = read_json(os.path.join(other_dir, "fleet.json"), 1_000_000)
        first = os.path.join(other_dir, next(iter(drone_dirs(other_dir).values())), "ticks.jsonl")
        out[other] = _start_time(other, other_dir, fleet, read_header(first), first)
    return out


def layout_of(rows: list[dict], planned: list[str], summary: Any, world: Any) -> dict:
    """Place -> [rack, bay, level]: the summary's layout, else the world's, else parsed from
    the names (``A-03-2``)."""
    inv = summary.get("inventory") if isinstance(summary, dict) else None
    lay = inv.get("layout") if isinstance(inv, dict) else None
    if isinstance(lay, dict) and lay:
        return {str(k): list(v) for k, v in lay.items() if isinstance(v, list) and len(v) == 3}
    if world is not None and getattr(world, "places", None):
        return {n: [p.rack, p.bay, p.level] for n, p in world.places.items()}
    out = {}
    for name in list(planned) + [r["place"] for r in rows]:
        m = PLACE_CODE.match(name)
        if m:
            out[name] = [m.group(1), int(m.group(2)), int(m.group(3))]
    return out


_WORLDS: dict[tuple, Any] = {}


def world_of(header: dict) -> Any:
    """The simulated world a run flew (its rig, seed and ``world.*`` sets); None if it
    cannot be loaded (a real drone's run, a moved rig file). A relative rig path is the
    run's (:func:`bt_engine.ticklog.header_path`), not the console's."""
    rig_path = header_path(header, header.get("rig") or header.get("rig_arg"))
    if rig_path is None or not os.path.isfile(rig_path):
        return None
    sets = [s for s in header.get("sets") or [] if isinstance(s, str) and s.startswith("world.")]
    key = (rig_path, tuple(sets), header.get("seed"))
    if key not in _WORLDS:
        try:
            from drivers.rig.loader import load_rig

            rig = load_rig(rig_path, dict(s.split("=", 1) for s in sets if "=" in s))
            world = rig.load_world(int(header.get("seed") or 0)) if rig.kind == "sim" else None
        except Exception:  # noqa: BLE001 - a run's world is a nicety of the map
            world = None
        if len(_WORLDS) > 32:
            _WORLDS.clear()
        _WORLDS[key] = world
    return _WORLDS[key]


def track(ticks: str, points: int = TRACK_POINTS) -> list[list[float]]:
    """The drone's track from its tick log: ``[t, x, y, z]`` decimated to about ``points``."""
    out: list[list[float]] = []
    if not plain(ticks):
        return []
    try:
        size = os.path.getsize(ticks)
        with open(ticks, "rb") as f:
            if size > MAX_TICKS_BYTES:  # only the newest part of a huge log
                f.seek(size - MAX_TICKS_BYTES)
                f.readline()
            for line in f:
                p = vehicle_point(line)
                if p is not None:
                    out.append(p)
    except OSError:
        return []
    step = max(1, len(out) // points)
    return out[::step] + ([out[-1]] if out and (len(out) - 1) % step else [])


def vehicle_point(line: bytes) -> list[float] | None:
    """``[t, x, y, z]`` of one tick line with a vehicle row, else None."""
    if b'"vehicle"' not in line:
        return None
    try:
        rec = json.loads(line)
        v = rec["vehicle"]
        return [float(rec["t"]), float(v["x"]), float(v["y"]), float(v["z"])]
    except (ValueError, KeyError, TypeError, RecursionError):
        return None


def evidence(run_dir: str, rel_drone: str, place: str) -> dict | None:
    """A place's crops (paths relative to the run) and candidates, if it has any."""
    if not NAME.fullmatch(place) or ".." in place:
        return None
    base = os.path.normpath(os.path.join(rel_drone, PLACES_DIR, place)).replace(os.sep, "/")
    folder = os.path.join(run_dir, base)
    if not os.path.isdir(folder) or not plain(folder):
        return None
    crops = sorted(
        (
            n
            for n in os.listdir(folder)
            if re.fullmatch(r"block_\d+\.png", n) and plain(os.path.join(folder, n))
        ),
        key=lambda n: int(n[6:-4]),
    )
    doc = read_json(os.path.join(folder, CANDIDATES_FILE), 1_000_000) or {}
    cands = doc.get("candidates") if isinstance(doc, dict) else None
    ok = [
        [str(c[0]), c[1] if isinstance(c[1], (int, float)) else None]
        for c in (cands if isinstance(cands, list) else [])
        if isinstance(c, list) and len(c) == 2
    ]
    return {"crops": [f"{base}/{n}" for n in crops], "candidates": ok[:20]}


def evidence_of(run_dir: str, rel_drone: str, place: str) -> dict | None:
    """A place's evidence in its drone's folder, else in the run's own ``places/`` (where
    a resumed fleet keeps the places it carried over: :func:`nodes.place_evidence.
    carry_evidence`)."""
    found = evidence(run_dir, rel_drone, place)
    if found is None and os.path.normpath(rel_drone) != ".":
        found = evidence(run_dir, ".", place)
    return found


def run_info(root: RunsRoot, name: str, full: bool = False) -> dict:
    """What the index (``full`` False) or a run's page (``full`` True) shows of run ``name``."""
    run_dir = root.run_dir(name)
    summary = read_json(os.path.join(run_dir, "summary.json"))
    if os.path.lexists(os.path.join(run_dir, "summary.json")) and not isinstance(summary, dict):
        summary = None
        problems = ["summary.json cannot be read (damaged, or reached through a link)"]
    else:
        problems = []
    fleet = read_json(os.path.join(run_dir, "fleet.json"), 1_000_000)
    drones = drone_dirs(run_dir)
    first = os.path.join(run_dir, next(iter(drones.values())), "ticks.jsonl")
    header = read_header(first)
    rows, planned, error = read_rows(run_dir)
    if error:
        problems.append(error)
    try:
        reviews = read_review(run_dir, strict=True)
        review_error = None
    except ReviewFileError as exc:  # the operators' decisions cannot be read: said, and
        reviews, review_error = [], str(exc)  # no export is made without them
        problems.append(review_error)
    mission = (summary or {}).get("mission") if isinstance(summary, dict) else None
    mission = mission or header.get("mission") or ""
    world = world_of(header) if full or not isinstance(summary, dict) else None
    inv = summary.get("inventory") if isinstance(summary, dict) else None
    inv = inv if isinstance(inv, dict) else {}
    grades = inv.get("grades") if isinstance(inv.get("grades"), dict) else None
    truth = inv.get("truth") if isinstance(inv.get("truth"), dict) else None
    if grades is None and world is not None and getattr(world, "stock", None):
        stock, not_enrolled = world.places_truth(), set(world.not_enrolled())
        places = list(dict.fromkeys(planned + [r["place"] for r in rows]))
        by = {r["place"]: r for r in rows}
        grades = {}
        for p in places:
            grades[p] = grade((by.get(p) or {}).get("answer") or "", stock.get(p), not_enrolled)
        truth = {p: stock.get(p) for p in places}
    places_n = len(set(planned) | {r["place"] for r in rows})
    answered = sum(1 for r in rows if r.get("status") != "not_scanned")
    after_review = reviewed_discrepancies(rows, reviews)
    discrepancies: dict[str, int] = {}
    for r in rows:  # as the export counts them: a review's answer recategorises its place
        cat = after_review[r["place"]]["category"] if r["place"] in after_review else None
        cat = cat or discrepancy(r)
        if cat and cat != "confirmed":
            discrepancies[cat] = discrepancies.get(cat, 0) + 1
    status = run_status(run_dir, summary)
    accuracy, accuracy_over = inv.get("accuracy"), "planned"
    done = {r["place"] for r in rows if r.get("status") != "not_scanned"}
    if grades and (accuracy is None or answered < places_n):
        # a place not reached (yet: RUNNING; ever: an interrupted run) is not a wrong answer:
        # the accuracy is over the places answered, and the page says how many were not
        counted = {p: g for p, g in grades.items() if p in done}
        if answered < places_n or status == "RUNNING":
            accuracy_over = "answered"
        else:
            counted = grades
        right = sum(1 for g in counted.values() if g == "right")
        accuracy = round(right / len(counted), 4) if counted else None
    exceptions = [r["place"] for r in rows if needs_review(r)]
    started = _start_time(name, run_dir, fleet, header, first)
    info: dict[str, Any] = {
        "name": name,
        "kind": "fleet" if fleet is not None or drones.get("") is None else "run",
        "mission": os.path.basename(mission) if isinstance(mission, str) else "",
        "status": status,
        "started": started,
        "modified": max(_mtime(run_dir), _mtime(os.path.join(run_dir, "inventory.json"))),
        "places": places_n,
        "answered": answered,
        "accuracy": accuracy,
        "accuracy_over": accuracy_over,
        "discrepancies": discrepancies,
        "exceptions": len(exceptions),
        "reviewed": len({d["place"] for d in reviews}),
        "drones": [d for d in drones if d],
        "error": "; ".join(problems) or None,
        "rows_error": error,
        # nothing to export: no inventory.json (a run stopped before its first place, or a
        # folder that is no inventory): never a header-only file handed over as a count
        "no_inventory": error is None and not rows and not planned,
        "review_error": review_error,
    }
    if not full:
        return info
    info["run_starts"] = run_starts(root, name, fleet or header, started, rows)
    by_drone = {n: rel for n, rel in drones.items()}
    ev = {}
    for r in rows:
        rel = by_drone.get(r.get("drone") or "", by_drone.get("", "."))
        if r.get("drone") not in by_drone and "" not in by_drone:
            rel = next(iter(by_drone.values()))
        found = evidence_of(run_dir, rel, r["place"])
        if found is not None:
            ev[r["place"]] = found
    positions = {}
    if world is not None:
        for n, p in getattr(world, "places", {}).items():
            positions[n] = [round(p.row_m[0], 3), round(p.row_m[1], 3), round(p.row_m[2], 3)]
    pads = []
    if world is not None:
        for pad in (getattr(world, "data", None) or {}).get("pads") or []:
            try:
                pads.append({"name": pad["name"], "xy": list(pad["position_m"][:2])})
            except (KeyError, TypeError):
                continue
    if after_review:
        rows = [
            {
                **r,
                "reviewed_discrepancy": after_review[r["place"]]["category"],
                "reviewed_moved_from": after_review[r["place"]]["moved_from"],
            }
            if r["place"] in after_review
            else r
            for r in rows
        ]
    info.update(
        rows=rows,
        planned=planned,
        layout=layout_of(rows, planned, summary, world),
        positions=positions,
        pads=pads,
        grades=grades or {},
        truth=truth or {},
        evidence=ev,
        tracks={
            (n or "drone"): track(os.path.join(run_dir, rel, "ticks.jsonl"))
            for n, rel in drones.items()
        },
        review=reviews,
        queue=exceptions,
        report=os.path.isfile(os.path.join(run_dir, "report.html")),
        header={"rig": header.get("rig"), "seed": header.get("seed"), "sets": header.get("sets")},
    )
    return info


#: the files whose change changes what the index shows of a run
_LISTED_FILES = (
    ".",
    "summary.json",
    "fleet.json",
    "inventory.json",
    "discrepancies.json",
    "review.json",
    "ticks.jsonl",
    "drones",
)
#: (runs folder, run name) -> (its files' signature, what the index showed of it)
_LISTED: dict[tuple[str, str], tuple[tuple, dict]] = {}


def _signature(run_dir: str) -> tuple:
    """What the index's line of a run depends on: the time, size and inode of its files
    (an atomic rewrite changes all three) and of the first drone's tick log."""
    paths = [os.path.join(run_dir, f) for f in _LISTED_FILES]
    drones = drone_dirs(run_dir)
    paths.append(os.path.join(run_dir, next(iter(drones.values())), "ticks.jsonl"))
    out = []
    for path in paths:
        try:
            st = os.stat(path)
        except OSError:
            out.append(None)
            continue
        out.append((st.st_mtime_ns, st.st_size, st.st_ino))
    return tuple(out)


def _listed_info(root: RunsRoot, name: str) -> dict:
    """:func:`run_info` of the index, read again only when the run's files changed: a
    refresh of a runs folder of 500 site runs had read every inventory each time (about 3 s
    of CPU). A run without a summary is read every time: whether it is ``RUNNING`` depends
    on the clock, not only on its files."""
    run_dir = root.run_dir(name)
    key, sig = (root.root, name), _signature(run_dir)
    hit = _LISTED.get(key)
    if hit is not None and hit[0] == sig:
        return dict(hit[1])
    info = run_info(root, name)
    if sig[1] is not None and info["status"] != "RUNNING":
        _LISTED[key] = (sig, info)
    return dict(info)


def list_runs(root: RunsRoot, skipped: list[str] | None = None) -> list[dict]:
    """Every run and fleet folder directly under the root, the latest started first (at most
    :data:`MAX_RUNS`: the folders written last; a review or a copy changes a folder's time,
    not its start). Run folders the console cannot serve are appended to ``skipped`` (one
    line each, why), so that the page can say why a run is missing."""
    found = []
    try:
        entries = list(os.scandir(root.root))
    except OSError:
        return []
    for e in entries:
        if not NAME.fullmatch(e.name) or ".." in e.name:
            if skipped is not None and e.is_dir() and is_run(os.path.join(root.root, e.name)):
                skipped.append(f"{e.name!r:.80} (a name the console does not serve)")
            continue
        try:
            path = root.run_dir(e.name)
        except PathRefused as exc:
            if skipped is not None and exc.status == 403:
                skipped.append(f"{e.name!r:.80} (a link out of the runs folder)")
            continue
        if is_run(path):
            stamp = max(_mtime(path), _mtime(os.path.join(path, "summary.json")))
            found.append((stamp, e.name, path, e.is_symlink()))
    real = {path: name for _, name, path, link in found if not link}
    kept = []
    for stamp, name, path, link in found:  # a link to a run listed by its own name: once
        if link and path in real:
            if skipped is not None:
                skipped.append(f"{name!r:.80} (a link to run {real[path]!r:.80})")
            continue
        real.setdefault(path, name)
        if real[path] == name:
            kept.append((stamp, name))
    found = kept
    found.sort(reverse=True)
    if len(found) > MAX_RUNS and skipped is not None:  # said, not silently cut
        skipped.append(
            f"{len(found) - MAX_RUNS} older runs (the newest {MAX_RUNS} of {len(found)} are "
            "listed; move old run folders to an archive folder)"
        )
    out = []
    for _, name in found[:MAX_RUNS]:
        try:
            out.append(_listed_info(root, name))
        except (PathRefused, OSError):
            continue
    if len(_LISTED) > 2 * MAX_RUNS:  # runs moved away: forget them
        _LISTED.clear()
    out.sort(key=lambda r: (r["started"] or 0.0, r["name"]), reverse=True)
    return out


__all__ = ["EMPTY", "evidence_of", "list_runs", "needs_review", "run_info", "read_rows", "track"]
