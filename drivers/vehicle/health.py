"""Health tracking of a data source: age of the last new sample, rate and drops."""

from __future__ import annotations

import math
from collections import deque

from drivers.vehicle.types import SourceHealth


class RateWindow:
    """Sample times over the last ``window_s`` seconds: the measured rate of a stream."""

    def __init__(self, window_s: float = 1.0) -> None:
        self.window_s = window_s
        self._times: deque[float] = deque()

    def add(self, t_s: float) -> None:
        """Record a sample at time ``t_s`` (any monotonic clock, used consistently)."""
        self._times.append(t_s)

    def shift(self, dt_s: float) -> None:
        """Move every recorded time by ``dt_s`` (the clock was set back or on)."""
        self._times = deque(t + dt_s for t in self._times)

    def rate_hz(self, now_s: float) -> float:
        """Samples per second over the window ending at ``now_s``."""
        times = self._times
        while times and times[0] < now_s - self.window_s:
            times.popleft()
        return len(times) / self.window_s


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
        self._rate = RateWindow(window_s)

    def sample(self, t_s: float, changed: bool = True) -> None:
        """Record a sample received at mission time ``t_s``."""
        self.samples += 1
        self._rate.add(t_s)
        if changed:
            self.last_new_s = t_s

    def shift(self, dt_s: float) -> None:
        """Move the recorded sample times by ``dt_s``: the clock was set back (mission time 0
        at the first tick), and ages and rates must not read the old times as future ones."""
        self.last_new_s += dt_s  # -inf stays -inf
        self._rate.shift(dt_s)

    def drop(self, count: int = 1) -> None:
        """Record ``count`` samples that should have arrived and did not."""
        self.drops += count

    def report(self, now_s: float) -> SourceHealth:
        """Health at mission time ``now_s``."""
        age = now_s - self.last_new_s if self.last_new_s > -math.inf else math.inf
        return SourceHealth(
            name=self.name,
            connected=self.connected,
            age_s=age,
            rate_hz=self._rate.rate_hz(now_s),
            drops=self.drops,
            samples=self.samples,
            healthy=self.connected and age <= self.stale_after_s,
        )
