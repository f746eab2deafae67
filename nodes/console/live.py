"""A running inventory as a stream of events: drones on the map, places filling in.

:class:`RunFollower` polls the files a run writes as it goes, with bounded reads: each
drone's ``ticks.jsonl`` (new bytes since the last poll, at most :data:`MAX_READ_BYTES`; the
newest ``vehicle`` row is the drone's position), ``inventory.json`` (rewritten atomically
after every place: read again when its size or time changes), ``review.json`` and
``summary.json`` (the run ended). The console turns its events into server-sent events.
"""

from __future__ import annotations

import os
from typing import Any

from nodes.console.files import read_json, read_review
from nodes.console.paths import plain
from nodes.console.runs import drone_dirs, read_rows, run_status, vehicle_point

#: the most bytes read from one tick log per poll (the rest is read at the next poll)
MAX_READ_BYTES = 4_000_000
#: when a follower starts, this much of each tick log's end is read for the positions
TAIL_BYTES = 64_000
#: track points sent per drone per poll at most (the page appends them to the track)
POINTS_PER_POLL = 50


def _stamp(path: str) -> tuple[int, int] | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_mtime_ns, st.st_size)


class RunFollower:
    """What changed in a run folder since the last :meth:`poll`."""

    def __init__(self, run_dir: str) -> None:
        self.run_dir = run_dir
        self.drones = drone_dirs(run_dir)
        self.offsets: dict[str, int] = {}
        self.partial: dict[str, bytes] = {}
        self.stamps: dict[str, tuple[int, int] | None] = {}
        self.done = False
        for name, rel in self.drones.items():
            path = os.path.join(run_dir, rel, "ticks.jsonl")
            try:
                size = os.path.getsize(path)
            except OSError:
                size = 0
            self.offsets[name] = max(0, size - TAIL_BYTES)
            self.partial[name] = b""

    def _new_points(self, name: str) -> list[list[float]]:
        path = os.path.join(self.run_dir, self.drones[name], "ticks.jsonl")
        if not plain(path):  # a link: never followed out of the runs folder
            return []
        try:
            with open(path, "rb") as f:
                f.seek(self.offsets[name])
                chunk = f.read(MAX_READ_BYTES)
        except OSError:
            return []
        if not chunk:
            return []
        self.offsets[name] += len(chunk)
        lines = (self.partial[name] + chunk).split(b"\n")
        self.partial[name] = lines.pop()[-MAX_READ_BYTES:]
        return [p for p in (vehicle_point(line) for line in lines) if p is not None]

    def poll(self) -> list[tuple[str, Any]]:
        """The events since the last poll: ``drones`` (name -> [t, x, y, z] and the new
        track points), ``rows`` (the inventory, when it changed), ``review`` and ``status``
        (then :attr:`done`)."""
        events: list[tuple[str, Any]] = []
        if set(drone_dirs(self.run_dir)) != set(self.drones):  # a fleet's folders appear
            self.__init__(self.run_dir)  # type: ignore[misc]
        drones = {}
        for name in self.drones:
            points = self._new_points(name)
            if points:
                step = max(1, len(points) // POINTS_PER_POLL)
                drones[name or "drone"] = {"at": points[-1], "track": points[::step]}
        if drones:
            events.append(("drones", drones))
        inv = os.path.join(self.run_dir, "inventory.json")
        stamp = _stamp(inv)
        if stamp != self.stamps.get(inv):
            self.stamps[inv] = stamp
            rows, planned, error = read_rows(self.run_dir)
            events.append(("rows", {"rows": rows, "planned": planned, "error": error}))
        rev = os.path.join(self.run_dir, "review.json")
        stamp = _stamp(rev)
        if stamp != self.stamps.get(rev):
            self.stamps[rev] = stamp
            events.append(("review", read_review(self.run_dir)))
        summary_path = os.path.join(self.run_dir, "summary.json")
        if os.path.exists(summary_path):
            summary = read_json(summary_path)
            if isinstance(summary, dict) and "status" in summary:
                events.append(("status", {"status": run_status(self.run_dir, summary)}))
                self.done = True
                return events
        if run_status(self.run_dir, None) == "INCOMPLETE":  # silent, and no summary will come
            events.append(("status", {"status": "INCOMPLETE"}))  # (its guard died with it):
            self.done = True  # the page says so and the stream ends, freeing its slot
        return events
