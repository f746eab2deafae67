"""Health tracking of a data source: age of the last new sample, rate and drops."""

from __future__ import annotations

import math
from collections import deque

from drivers.types import SourceHealth


class HealthTracker:
    """Track when samples of one source arrive.

    Call :meth:`sample` for every new sample, :meth:`drop` for every sample known to be
    missing (sequence gap, dropped frame) and :meth:`report` for a :class:`SourceHealth`.
    A sample whose content equals the previous one (``changed=False``) counts towards the
    rate but not towards freshness: a frozen mocap server repeating the last pose is stale.
    """

    def __init__(self, name: str, stale_after_s: float, window_s: float = 1.0) -> None:
        self.name, self.stale_after_s, self.window_s = name, stale_after_s, window_s
        self.connected = True
        self.last_new_s = -math.inf
        self.samples = 0
        self.drops = 0
        self._times: deque[float] = deque()

    def sample(self, t_s: float, changed: bool = True) -> None:
        """Record a sample received at mission time ``t_s``."""
        self.samples += 1
        self._times.append(t_s)
        if changed:
            self.last_new_s = t_s

    def drop(self, count: int = 1) -> None:
        """Record ``count`` samples that should have arrived and did not."""
        self.drops += count

    def report(self, now_s: float) -> SourceHealth:
        """Health at mission time ``now_s``."""
        times = self._times
        while times and times[0] < now_s - self.window_s:
            times.popleft()
        age = now_s - self.last_new_s if self.last_new_s > -math.inf else math.inf
        return SourceHealth(
            name=self.name,
            connected=self.connected,
            age_s=age,
            rate_hz=len(times) / self.window_s,
            drops=self.drops,
            samples=self.samples,
            healthy=self.connected and age <= self.stale_after_s,
        )
