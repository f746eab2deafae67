"""``btrun replay``: step through a tick log and show the tree at each tick."""

from __future__ import annotations

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
    """Replay the log at ``path`` (a ``ticks.jsonl`` or a run folder); return an exit code."""
    if os.path.isdir(path):
        path = os.path.join(path, "ticks.jsonl")
    if not os.path.exists(path):
        print(f"{path}:0:0: tick log not found", file=sys.stderr)
        return 2
    header, records = read_log(path)
    if not header or not records:
        print(f"{path}:1:1: not a btrun tick log (no header or no ticks)", file=sys.stderr)
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
