"""Fault injection: schedule or inject named faults from tests, rigs and ``--set``.

A platform registers one :class:`FaultHandler` per fault name (the simulator registers
``link_drop``, ``mocap_freeze``, ``mocap_drop``, ``camera_stall``, ``battery_sag``,
``gust``). Tests and rigs then call::

    platform.faults.schedule("link_drop", at_s=12.0)          # at a mission time
    platform.faults.inject("battery_sag", drop_v=0.6)          # now (e.g. at a mission event)
    platform.faults.clear("mocap_freeze")

A ``duration_s`` parameter clears the fault automatically after that time.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any


@dataclass
class FaultHandler:
    """How to start and clear one fault. ``start(**params)`` and ``clear()`` act at once."""

    start: Callable[..., None]
    clear: Callable[[], None]
    doc: str = ""
    params: dict[str, Any] = field(default_factory=dict)  # parameter -> default


@dataclass
class FiredFault:
    """A fault that fired: when, with which parameters, and when it was cleared."""

    name: str
    t_s: float
    params: dict[str, Any]
    cleared_s: float | None = None

    def as_dict(self) -> dict:
        """JSON-friendly form for ``summary.json``."""
        return {
            "name": self.name,
            "t_s": round(self.t_s, 4),
            "params": dict(self.params),
            "cleared_s": None if self.cleared_s is None else round(self.cleared_s, 4),
        }


class FaultInjector:
    """Registry of fault handlers plus a schedule, advanced with :meth:`update`."""

    def __init__(self) -> None:
        self.handlers: dict[str, FaultHandler] = {}
        self.fired: list[FiredFault] = []
        self._pending: list[tuple[float, int, str, dict]] = []
        self._auto_clear: dict[str, float] = {}
        self._active: dict[str, FiredFault] = {}
        self._now_s = 0.0
        self._counter = 0

    def register(self, name: str, handler: FaultHandler) -> None:
        """Make fault ``name`` available."""
        self.handlers[name] = handler

    def _check(self, name: str, params: dict) -> None:
        if name not in self.handlers:
            raise ValueError(f"unknown fault '{name}'{did_you_mean(name, list(self.handlers))}")
        allowed = set(self.handlers[name].params) | {"duration_s"}
        for key in params:
            if key not in allowed:
                hint = did_you_mean(key, sorted(allowed))
                raise ValueError(f"fault '{name}' has no parameter '{key}'{hint}")

    def schedule(self, name: str, at_s: float, **params: Any) -> None:
        """Fire fault ``name`` at mission time ``at_s`` (checked at the next update)."""
        self._check(name, params)
        self._counter += 1
        self._pending.append((float(at_s), self._counter, name, params))
        self._pending.sort()

    def inject(self, name: str, **params: Any) -> None:
        """Fire fault ``name`` now."""
        self._check(name, params)
        handler = self.handlers[name]
        merged = {**handler.params, **{k: v for k, v in params.items() if k != "duration_s"}}
        handler.start(**merged)
        record = FiredFault(name, self._now_s, dict(params))
        self.fired.append(record)
        self._active[name] = record
        duration = params.get("duration_s")
        if duration is not None:
            self._auto_clear[name] = self._now_s + float(duration)

    def clear(self, name: str) -> None:
        """End fault ``name`` now (no effect if it is not active)."""
        self._check(name, {})
        self.handlers[name].clear()
        self._auto_clear.pop(name, None)
        record = self._active.pop(name, None)
        if record is not None:
            record.cleared_s = self._now_s

    def active(self) -> list[str]:
        """Names of the faults currently active."""
        return sorted(self._active)

    def update(self, t_s: float) -> None:
        """Fire scheduled faults due at ``t_s`` and clear those whose duration ended."""
        self._now_s = t_s
        while self._pending and self._pending[0][0] <= t_s + 1e-9:
            _, _, name, params = self._pending.pop(0)
            self.inject(name, **params)
        for name, end_s in list(self._auto_clear.items()):
            if t_s >= end_s - 1e-9:
                self.clear(name)

    def summary(self) -> list[dict]:
        """Every fault that fired, for ``summary.json``."""
        return [f.as_dict() for f in self.fired]


def did_you_mean(name: str, candidates: list[str]) -> str:
    """Return `` (did you mean 'x'?)`` for the closest candidate, or an empty string."""
    close = difflib.get_close_matches(name, candidates, n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""
