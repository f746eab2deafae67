"""The runner's trace: every tick's record kept in memory for the report, bounded.

The records are summarised as the tick log summarises them (a value past 16 kB becomes a
note), and past :data:`TRACE_LIMIT_BYTES` the trace thins itself (every 2nd, then 4th ...
tick kept; status changes while they fit; always the newest tick).
"""

from __future__ import annotations

from typing import Any

from bt_engine.ticklog import summarise_messages, summarise_value

#: About how many bytes of memory the trace's records may take before it is decimated (a
#: 20-minute flight at 50 Hz takes about 45 MB, and is never thinned).
TRACE_LIMIT_BYTES = 128 * 1024 * 1024


def _value_cost(value: Any, depth: int = 0) -> int:
    """About the bytes a (summarised, JSON-friendly) value takes in memory."""
    if isinstance(value, str):
        return 50 + len(value)
    if isinstance(value, (list, tuple)):
        if depth > 4:
            return 64 + 40 * len(value)
        return 64 + sum(8 + _value_cost(v, depth + 1) for v in value)
    if isinstance(value, dict):
        if depth > 4:
            return 64 + 100 * len(value)
        return 64 + sum(50 + _value_cost(v, depth + 1) for v in value.values())
    return 32


def record_cost(rec: dict) -> int:
    """About the bytes one trace record takes in memory (what :class:`Trace` budgets)."""
    cost = 240
    for key in ("changed", "done"):
        part = rec.get(key)
        if part:
            cost += 100 * len(part)
    vehicle = rec.get("vehicle")
    if vehicle:
        cost += 64 + 48 * len(vehicle)
    bb = rec.get("bb")
    if bb:
        cost += sum(100 + _value_cost(v) for v in bb.values())
    msgs = rec.get("messages")
    if msgs:
        cost += sum(60 + _value_cost(m) for m in msgs)
    return cost


def summarised(record: dict) -> dict:
    """``record`` as the trace keeps it: its blackboard writes and messages summarised as
    the tick log writes them (a copy if there are any; the other keys are shared)."""
    bb, msgs = record.get("bb"), record.get("messages")
    if not bb and not msgs:
        return record
    rec = dict(record)
    if bb:
        rec["bb"] = {k: summarise_value(v) for k, v in bb.items()}
    if msgs:
        rec["messages"] = summarise_messages(msgs)
    return rec


def _has_events(rec: dict) -> bool:
    return bool(rec.get("changed") or rec.get("done") or rec.get("messages"))


class Trace(list):
    """The runner's per-tick records in memory (the report and the plug-ins' summary sections
    read them), bounded.

    A record is kept as the tick log writes it: its blackboard writes and messages
    summarised (:func:`~bt_engine.ticklog.summarise_value`,
    :func:`~bt_engine.ticklog.summarise_messages`: a value past 16 kB becomes a note), the
    other keys as they are. Once the records take about ``limit_bytes``
    (:func:`record_cost`), the history is decimated: :attr:`stride` doubles and only the
    records of ticks that are multiples of it are kept, and those that carry events (status
    changes, finished leaves, messages) while these take under half the budget; after that,
    events are decimated the same way (:attr:`thin_events`). The newest record is always
    kept. A normal flight (under about an hour at 50 Hz) keeps every tick.
    """

    def __init__(self, limit_bytes: int = TRACE_LIMIT_BYTES) -> None:
        super().__init__()
        self.limit_bytes = limit_bytes
        #: 1: every tick is kept; N: plain records of ticks that are multiples of N
        self.stride = 1
        #: True once records with events are decimated too
        self.thin_events = False
        #: about the bytes the records take now
        self.cost = 0
        self._tail_cost = 0
        self._tail_spare = False  # the newest record is only kept because it is the newest

    def _keep(self, rec: dict) -> bool:
        tick = rec.get("tick")
        if not isinstance(tick, int) or tick % self.stride == 0:
            return True
        return not self.thin_events and _has_events(rec)

    def append(self, record: dict) -> None:
        """Keep ``record`` summarised (:func:`summarised`); decimate if past the budget."""
        self.keep(summarised(record))

    def keep(self, rec: dict) -> None:
        """Keep ``rec``, already :func:`summarised`; decimate if past the budget."""
        if self._tail_spare:  # the previous newest record is off the grid: it goes
            super().pop()
            self.cost -= self._tail_cost
        cost = record_cost(rec)
        super().append(rec)
        self.cost += cost
        self._tail_cost = cost
        self._tail_spare = self.stride > 1 and not self._keep(rec)
        if self.cost > self.limit_bytes:
            self._thin()

    def _thin(self) -> None:
        """Double the stride until the records take under half the budget."""
        while self.cost > self.limit_bytes // 2 and len(self) > 2:
            self.stride *= 2
            newest = self[-1]
            kept = [r for r in self[:-1] if self._keep(r)]
            kept.append(newest)
            self[:] = kept
            costs = [record_cost(r) for r in kept]
            self.cost = sum(costs)
            events = sum(c for r, c in zip(kept, costs, strict=True) if _has_events(r))
            if events > self.limit_bytes // 4:
                self.thin_events = True
            self._tail_cost = costs[-1]
        self._tail_spare = self.stride > 1 and not self._keep(self[-1])
