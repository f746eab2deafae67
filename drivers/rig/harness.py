"""A lock-step harness for tests and scripts: a SimClock, a platform and a tick loop.

    h = SimHarness.create(seed=1)
    p = h.vehicle.takeoff(0.5)
    h.run_until(lambda: p.settled, timeout_s=10)

Ticks exactly like the runner (advance the clock, ``before_tick``, your code, ``after_tick``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from drivers.rig.factory import make_platform
from drivers.rig.loader import load_rig
from drivers.sim.sim_platform import SimPlatform
from drivers.vehicle.vehicle import Vehicle


class StepClock:
    """A lock-step mission clock: ``now()`` moves only when :meth:`advance` is called."""

    is_simulated = True

    def __init__(self) -> None:
        self._steps = 0
        self._step_s = 0.0
        self._base = 0.0

    def now(self) -> float:
        """Mission time (s)."""
        return self._base + self._steps * self._step_s

    def advance(self, dt_s: float) -> None:
        """Move on by ``dt_s`` (counted in whole steps, so long runs do not drift)."""
        if dt_s != self._step_s:
            self._base, self._steps, self._step_s = self.now(), 0, dt_s
        self._steps += 1

    def sleep_until(self, t_s: float) -> None:
        """Jump to ``t_s`` (a lock-step clock never waits)."""
        if t_s > self.now():
            self._base, self._steps, self._step_s = t_s, 0, 0.0


class SimHarness:
    """Clock + simulated platform, stepped tick by tick at ``tick_hz``."""

    def __init__(self, platform: SimPlatform, clock: Any, tick_hz: float = 50.0) -> None:
        self.platform, self.clock, self.period_s = platform, clock, 1.0 / tick_hz

    @classmethod
    def create(
        cls,
        seed: int = 0,
        overrides: dict[str, str] | None = None,
        rig_path: str | None = None,
        tick_hz: float = 50.0,
    ) -> SimHarness:
        """Load a rig (default ``rigs/sim.yaml``) with ``overrides`` and build the platform."""
        clock = StepClock()
        platform = make_platform(load_rig(rig_path, overrides), clock, seed)
        return cls(platform, clock, tick_hz)

    @property
    def vehicle(self) -> Vehicle:
        """The platform's Vehicle."""
        return self.platform.vehicle

    @property
    def now_s(self) -> float:
        """Mission time."""
        return self.clock.now()

    def tick(self, on_tick: Callable[[], None] | None = None) -> None:
        """One runner tick."""
        self.clock.advance(self.period_s)
        self.platform.before_tick(self.clock.now())
        if on_tick is not None:
            on_tick()
        self.platform.after_tick(self.clock.now())

    def run_for(self, duration_s: float, on_tick: Callable[[], None] | None = None) -> None:
        """Tick for ``duration_s`` of mission time."""
        end = self.clock.now() + duration_s - 1e-9
        while self.clock.now() < end:
            self.tick(on_tick)

    def run_until(
        self,
        condition: Callable[[], bool],
        timeout_s: float = 30.0,
        on_tick: Callable[[], None] | None = None,
    ) -> bool:
        """Tick until ``condition()`` is true (returns True) or ``timeout_s`` passes (False)."""
        end = self.clock.now() + timeout_s
        while self.clock.now() < end:
            self.tick(on_tick)
            if condition():
                return True
        return False
