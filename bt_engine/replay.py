"""``btrun replay``: step through a tick log (or a run's ``run.mcap``) and show the tree at
each tick."""

from __future__ import annotations

import json
import os
import sys

from bt_engine.display import Row, tree_lines
from bt_engine.ticklog import read_log


def states_at(header: dict, records: list[dict], tick: int) -> tuple[list[str], dict]:
    """Node statuses (pre-order) and blackboard after ``tick`` (1-based), rebuilt from the log."""
    paths = [n[0] for n in header.get("nodes", [])]
    status = {p: "IDLE" for p in paths}
    bb: dict = {}
    for rec in records:
        if rec.get("tick", 0) > tick:
            break
        status.update(rec.get("changed", {}))
        bb.update(rec.get("bb", {}))
    return [status[p] for p in paths], bb


#: the MCAP channels and metadata the tick records are rebuilt from (see docs/monitoring.md)
MCAP_STATUS, MCAP_BB, MCAP_VEHICLE, MCAP_HEADER = (
    "/tree/status",
    "/blackboard",
    "/vehicle/telemetry",
    "btrun.header",
)


def read_mcap(path: str) -> tuple[dict, list[dict]]:
    """Read a run's ``run.mcap`` back into ``(header, tick_records)`` as
    :func:`bt_engine.ticklog.read_log` returns them from ``ticks.jsonl`` (tick, t, status,
    changed, done, bb, messages, vehicle). A file cut short (a killed run) gives the ticks
    up to its last complete chunk."""
    from mcap.records import Channel, Message, Metadata
    from mcap.stream_reader import StreamReader

    header: dict = {}
    topics: dict[int, str] = {}
    ticks: dict[int, dict] = {}
    bb: dict[int, dict] = {}
    vehicle: dict[int, dict] = {}
    with open(path, "rb") as f:
        try:
            for rec in StreamReader(f).records:
                if isinstance(rec, Channel):
                    topics[rec.id] = rec.topic
                elif isinstance(rec, Metadata) and rec.name == MCAP_HEADER:
                    header = json.loads(rec.metadata.get("header", "{}"))
                elif isinstance(rec, Message):
                    topic = topics.get(rec.channel_id)
                    if topic == MCAP_STATUS:
                        msg = json.loads(rec.data)
                        ticks[msg["tick"]] = msg
                    elif topic == MCAP_BB:
                        msg = json.loads(rec.data)
                        bb.setdefault(msg["tick"], {})[msg["key"]] = msg["value"]
                    elif topic == MCAP_VEHICLE:
                        msg = json.loads(rec.data)
                        vehicle[msg["tick"]] = msg["vehicle"]
        except Exception:  # noqa: BLE001  (a torn end: keep what was read)
            pass
    records = []
    for tick in sorted(ticks):
        msg = ticks[tick]
        rec = {k: msg[k] for k in ("tick", "t", "status", "changed", "done") if k in msg}
        if tick in bb:
            rec["bb"] = bb[tick]
        if "messages" in msg:
            rec["messages"] = msg["messages"]
        if tick in vehicle:
            rec["vehicle"] = vehicle[tick]
        records.append(rec)
    return header, records


def _rows(header: dict) -> list[Row]:
    return [Row(n[0], n[1], n[2], tuple(n[3])) for n in header.get("nodes", [])]


def _show(header: dict, records: list[dict], tick: int) -> None:
    rec = next((r for r in records if r.get("tick") == tick), {})
    st, bb = states_at(header, records, tick)
    print(f"tick {tick}  t={rec.get('t', 0):.2f} s  root {rec.get('status', '?')}")
    print("\n".join(tree_lines(_rows(header), st)))
    if bb:
        print("blackboard: " + ", ".join(f"{k}={v!r}" for k, v in sorted(bb.items())))


def replay(path: str, tick: int | None = None, show_all: bool = False) -> int:
    """Replay the log at ``path`` (a ``ticks.jsonl``, a run's ``run.mcap`` or a run folder);
    return an exit code."""
    if os.path.isdir(path):
        path = os.path.join(path, "ticks.jsonl")
    if not os.path.exists(path):
        print(f"{path}:0:0: tick log not found", file=sys.stderr)
        return 2
    is_mcap = path.endswith(".mcap")
    header, records = read_mcap(path) if is_mcap else read_log(path)
    if not header or not records:
        what = "btrun run.mcap" if is_mcap else "btrun tick log"
        print(f"{path}:1:1: not a {what} (no header or no ticks)", file=sys.stderr)
        return 2
    last = records[-1]["tick"]
    if tick is not None:
        if not 1 <= tick <= last:
            print(f"btrun replay: tick {tick} is outside 1..{last}", file=sys.stderr)
            return 2
        _show(header, records, tick)
        return 0
    if show_all or not sys.stdin.isatty():
        for rec in records:
            if rec.get("changed") or rec.get("bb") or rec is records[-1]:
                _show(header, records, rec["tick"])
                print()
        return 0
    cur = 1
    while True:
        _show(header, records, cur)
        cmd = input(f"[{cur}/{last}] Enter=next  p=previous  g N=go to  e=end  q=quit > ").strip()
        if cmd == "q":
            return 0
        if cmd == "p":
            cur = max(1, cur - 1)
        elif cmd == "e":
            cur = last
        elif cmd.startswith("g"):
            try:
                cur = min(last, max(1, int(cmd[1:].strip())))
            except ValueError:
                print("usage: g N")
        else:
            cur = min(last, cur + 1)
