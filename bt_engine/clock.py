"""Mission clocks.

Every time-based node (``Timeout``, ``Delay``, ``Sleep``, action time-outs) reads the
mission clock injected by the runner, never ``time.*`` directly. Two clocks exist:

* :class:`SimClock` advances only when told to. The runner advances it by one tick period
  before each tick, and the simulator steps its physics up to :meth:`SimClock.now`, so a
  run is as fast as the CPU allows and fully deterministic.
* :class:`WallClock` follows ``time.monotonic`` and paces real flights (optionally scaled
  for faster- or slower-than-real-time runs against emulators).
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """What the engine needs from a clock: the mission time in seconds."""

    def now(self) -> float:
        """Return the mission time in seconds since the clock started."""

    def sleep_until(self, t_s: float) -> None:
        """Block (wall clock) or jump (simulated clock) until mission time ``t_s``."""


class SimClock:
    """A simulated clock that moves only when advanced (lock-step simulation).

    >>> c = SimClock()
    >>> c.advance(0.02)
    >>> round(c.now(), 3)
    0.02
    """

    is_simulated = True

    def __init__(self, start_s: float = 0.0) -> None:
        self._t = float(start_s)
        # Integer tick counting avoids float drift over long runs.
        self._base = float(start_s)
        self._steps = 0
        self._step_s = 0.0

    def now(self) -> float:
        """Return the current simulated time in seconds."""
        return self._t

    def advance(self, dt_s: float) -> None:
        """Move the clock forward by ``dt_s`` seconds (must be >= 0)."""
        if dt_s < 0:
            raise ValueError(f"cannot move a clock backwards (dt={dt_s})")
        if dt_s == self._step_s:
            self._steps += 1
        else:
            self._base = self._t
            self._steps = 1
            self._step_s = dt_s
        self._t = self._base + self._steps * self._step_s

    def sleep_until(self, t_s: float) -> None:
        """Jump to ``t_s`` if it lies in the future (never waits)."""
        if t_s > self._t:
            self._base = t_s
            self._t = t_s
            self._steps = 0
            self._step_s = 0.0


class WallClock:
    """Wall-clock time since construction, optionally scaled by ``factor``.

    ``factor=2`` runs mission time twice as fast as real time (for watching a simulated
    flight quickly); real flights use ``factor=1``.
    """

    is_simulated = False

    def __init__(self, factor: float = 1.0) -> None:
        if factor <= 0:
            raise ValueError(f"clock factor must be > 0, got {factor}")
        self._factor = factor
        self._t0 = time.monotonic()

    def now(self) -> float:
        """Return the scaled seconds elapsed since the clock was created."""
        return (time.monotonic() - self._t0) * self._factor

    def restart_at(self, t_s: float) -> None:
        """Read ``t_s`` now: the time spent since then (loading models, building a gallery
        before the first tick, with the drone on the ground) is not mission time, so the
        first tick does not find the simulator, the tick log and the summary that far
        behind. Threads pacing themselves on this clock must resynchronise on a jump back."""
        self._t0 = time.monotonic() - t_s / self._factor

    def sleep_until(self, t_s: float) -> None:
        """Sleep until mission time ``t_s`` (returns at once if it has passed)."""
        remaining = (t_s - self.now()) / self._factor
        if remaining > 0:
            time.sleep(remaining)
